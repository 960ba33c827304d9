/* Dense LU with partial pivoting, real and complex (layout and conventions in linalg.h).
 *
 * Right-looking Doolittle elimination (Golub & Van Loan, Alg. 3.4.1): at step k pick the row with the
 * largest |a_ik| (complex: |re| + |im| as LAPACK's izamax), swap it up, store the multipliers
 * l_ik = a_ik / a_kk below the diagonal and update the trailing rows.  The inner loops run along rows,
 * which are contiguous in row-major storage.
 */
#include "linalg.h"

#include <math.h>

int mbs_lu_factor(int n, double *A, int *piv)
{
    for (int k = 0; k < n; ++k) {
        int p = k;
        double amax = fabs(A[k * n + k]);
        for (int i = k + 1; i < n; ++i)
            if (fabs(A[i * n + k]) > amax) { amax = fabs(A[i * n + k]); p = i; }
        piv[k] = p;
        if (amax == 0.0) {
            for (int j = k + 1; j < n; ++j) piv[j] = j; /* keep the pivot vector valid */
            return k + 1;
        }
        if (p != k)
            for (int j = 0; j < n; ++j) { double s = A[k * n + j]; A[k * n + j] = A[p * n + j]; A[p * n + j] = s; }
        const double *rk = A + k * n;
        double rpiv = 1.0 / rk[k];
        for (int i = k + 1; i < n; ++i) {
            double *ri = A + i * n;
            double l = ri[k] *= rpiv;
            if (l != 0.0)
                for (int j = k + 1; j < n; ++j) ri[j] -= l * rk[j];
        }
    }
    return 0;
}

void mbs_lu_solve(int n, const double *LU, const int *piv, double *b)
{
    for (int k = 0; k < n; ++k)  /* b ← P⁻¹·b */
        if (piv[k] != k) { double s = b[k]; b[k] = b[piv[k]]; b[piv[k]] = s; }
    for (int i = 1; i < n; ++i) {  /* L·z = b, unit diagonal */
        double s = b[i];
        for (int j = 0; j < i; ++j) s -= LU[i * n + j] * b[j];
        b[i] = s;
    }
    for (int i = n - 1; i >= 0; --i) {  /* U·x = z */
        double s = b[i];
        for (int j = i + 1; j < n; ++j) s -= LU[i * n + j] * b[j];
        b[i] = s / LU[i * n + i];
    }
}

/* 1/(a + ib) by Smith's algorithm (no overflow for large |a|, |b|). */
static void zrecip(double a, double b, double *re, double *im)
{
    if (fabs(a) >= fabs(b)) {
        double r = b / a, d = a + b * r;
        *re = 1.0 / d;
        *im = -r / d;
    } else {
        double r = a / b, d = a * r + b;
        *re = r / d;
        *im = -1.0 / d;
    }
}

int mbs_zlu_factor(int n, double *A, int *piv)
{
    for (int k = 0; k < n; ++k) {
        int p = k;
        double amax = -1.0;
        for (int i = k; i < n; ++i) {
            const double *a = A + 2 * (i * n + k);
            double m = fabs(a[0]) + fabs(a[1]);
            if (m > amax) { amax = m; p = i; }
        }
        piv[k] = p;
        if (amax == 0.0) {
            for (int j = k + 1; j < n; ++j) piv[j] = j;
            return k + 1;
        }
        if (p != k)
            for (int j = 0; j < 2 * n; ++j) {
                double s = A[2 * k * n + j]; A[2 * k * n + j] = A[2 * p * n + j]; A[2 * p * n + j] = s;
            }
        const double *rk = A + 2 * k * n;
        double pr, pi;
        zrecip(rk[2 * k], rk[2 * k + 1], &pr, &pi);
        for (int i = k + 1; i < n; ++i) {
            double *ri = A + 2 * i * n;
            double ar = ri[2 * k], ai = ri[2 * k + 1];
            double lr = ar * pr - ai * pi, li = ar * pi + ai * pr;
            ri[2 * k] = lr;
            ri[2 * k + 1] = li;
            if (lr != 0.0 || li != 0.0)
                for (int j = k + 1; j < n; ++j) {
                    double ur = rk[2 * j], ui = rk[2 * j + 1];
                    ri[2 * j] -= lr * ur - li * ui;
                    ri[2 * j + 1] -= lr * ui + li * ur;
                }
        }
    }
    return 0;
}

void mbs_zlu_solve(int n, const double *LU, const int *piv, double *b)
{
    for (int k = 0; k < n; ++k)
        if (piv[k] != k) {
            int p = piv[k];
            double sr = b[2 * k], si = b[2 * k + 1];
            b[2 * k] = b[2 * p]; b[2 * k + 1] = b[2 * p + 1];
            b[2 * p] = sr; b[2 * p + 1] = si;
        }
    for (int i = 1; i < n; ++i) {
        double sr = b[2 * i], si = b[2 * i + 1];
        const double *li = LU + 2 * i * n;
        for (int j = 0; j < i; ++j) {
            sr -= li[2 * j] * b[2 * j] - li[2 * j + 1] * b[2 * j + 1];
            si -= li[2 * j] * b[2 * j + 1] + li[2 * j + 1] * b[2 * j];
        }
        b[2 * i] = sr; b[2 * i + 1] = si;
    }
    for (int i = n - 1; i >= 0; --i) {
        double sr = b[2 * i], si = b[2 * i + 1];
        const double *ui = LU + 2 * i * n;
        for (int j = i + 1; j < n; ++j) {
            sr -= ui[2 * j] * b[2 * j] - ui[2 * j + 1] * b[2 * j + 1];
            si -= ui[2 * j] * b[2 * j + 1] + ui[2 * j + 1] * b[2 * j];
        }
        double dr, di;
        zrecip(ui[2 * i], ui[2 * i + 1], &dr, &di);
        b[2 * i] = sr * dr - si * di;
        b[2 * i + 1] = sr * di + si * dr;
    }
}

int mbs_lu_pivots_valid(int n, const int *piv)
{
    for (int k = 0; k < n; ++k)
        if (piv[k] < k || piv[k] >= n) return 0;
    return 1;
}
