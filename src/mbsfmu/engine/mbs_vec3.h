/* Small 3-vector and 3×3 (row-major) helpers shared by tree.c, dynamics.c and elastic.c, over the evaluation's
 * scalar `real` (mbs_model.h), and the scalar math they need. */
#ifndef MBS_VEC3_H
#define MBS_VEC3_H

#include <math.h>

#include "mbs_model.h"

static inline void cross(const real *a, const real *b, real *c)
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}
static inline void mv(const real *A, const real *x, real *y)   /* y = A x */
{
    for (int r = 0; r < 3; r++) y[r] = A[3 * r] * x[0] + A[3 * r + 1] * x[1] + A[3 * r + 2] * x[2];
}
static inline void mtv(const real *A, const real *x, real *y)  /* y = Aᵀ x */
{
    for (int r = 0; r < 3; r++) y[r] = A[r] * x[0] + A[3 + r] * x[1] + A[6 + r] * x[2];
}
static inline void mm(const real *A, const real *B, real *C)   /* C = A B */
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            C[3 * r + c] = A[3 * r] * B[c] + A[3 * r + 1] * B[3 + c] + A[3 * r + 2] * B[6 + c];
}

/* spatial vectors (dynamics.c, elastic.c): y = A x for a 6 × 6 row-major A; a force f = (n, F) at point o + d added
 * to out at o: (n + d × F, F) */
static inline void mat6v(const real *restrict A, const real *restrict x, real *restrict y)
{
    for (int r = 0; r < 6; r++)
        y[r] = A[6 * r] * x[0] + A[6 * r + 1] * x[1] + A[6 * r + 2] * x[2] + A[6 * r + 3] * x[3] +
               A[6 * r + 4] * x[4] + A[6 * r + 5] * x[5];
}
static inline void add_force_at(const real *d, const real *f, real *out)
{
    real dxF[3];
    cross(d, f + 3, dxF);
    for (int r = 0; r < 3; r++) { out[r] += f[r] + dxF[r]; out[3 + r] += f[3 + r]; }
}

#ifdef MBS_CX
#ifndef CMPLX  /* C11's; a C99 library may lack it */
#define CMPLX(x, y) ((double)(x) + _Complex_I * (double)(y))
#endif
/* f(a + ib) = f(a) + i b f'(a): exact to rounding, as the complex step keeps b ≪ |a| + 1 (deriv.c); csqrt where
 * a ≤ 0 (a norm at zero: the one-sided rate) */
static inline real r_sqrt(real z)
{
    const double a = creal(z);
    if (!(a > 0.0)) return csqrt(z);
    const double s = sqrt(a);
    return CMPLX(s, cimag(z) / (2.0 * s));
}
static inline real r_sin(real z) { return CMPLX(sin(creal(z)), cimag(z) * cos(creal(z))); }
static inline real r_cos(real z) { return CMPLX(cos(creal(z)), -cimag(z) * sin(creal(z))); }
#else
#define r_sqrt sqrt
#define r_sin sin
#define r_cos cos
#endif

#endif
