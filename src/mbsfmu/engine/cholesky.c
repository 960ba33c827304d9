/* Cholesky factorization of the (small, dense) symmetric positive definite matrices of the equations: M on the
 * dense path, joint and modal blocks on the recursive one; real and (deriv.c) complex. */
#include <math.h>

#include "mbs_model.h"
#include "mbs_vec3.h"

/* M = L Lᵀ in place (row-major, L in the lower triangle). 0 on success, 1 if M is not positive definite. */
int mbs_cholesky(int n, real *M)
{
    for (int j = 0; j < n; j++) {
        real s = M[j * n + j];
        for (int k = 0; k < j; k++) s -= M[j * n + k] * M[j * n + k];
        if (RE(s) <= 0.0) return 1; /* NaN passes on as NaN: the integrator shrinks h */
        real d = r_sqrt(s);
        M[j * n + j] = d;
        for (int i = j + 1; i < n; i++) {
            real t = M[i * n + j];
            for (int k = 0; k < j; k++) t -= M[i * n + k] * M[j * n + k];
            M[i * n + j] = t / d;
        }
    }
    return 0;
}

/* r ← (L Lᵀ)⁻¹ r with the factor of mbs_cholesky */
void mbs_cholesky_apply(int n, const real *L, real *r)
{
    for (int i = 0; i < n; i++) {
        real s = r[i];
        for (int k = 0; k < i; k++) s -= L[i * n + k] * r[k];
        r[i] = s / L[i * n + i];
    }
    for (int i = n - 1; i >= 0; i--) {
        real s = r[i];
        for (int k = i + 1; k < n; k++) s -= L[k * n + i] * r[k];
        r[i] = s / L[i * n + i];
    }
}

/* Solve M a = r in place (M overwritten by its Cholesky factor). 0 on success, 1 if M is not positive definite. */
int mbs_cholesky_solve(int n, real *M, real *r)
{
    if (mbs_cholesky(n, M)) return 1;
    mbs_cholesky_apply(n, M, r);
    return 0;
}
