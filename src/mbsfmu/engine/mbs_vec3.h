/* Small 3-vector and 3×3 (row-major) helpers shared by tree.c and elastic.c. */
#ifndef MBS_VEC3_H
#define MBS_VEC3_H

#include <math.h>

static inline void cross(const double *a, const double *b, double *c)
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}
static inline void mv(const double *A, const double *x, double *y)   /* y = A x */
{
    for (int r = 0; r < 3; r++) y[r] = A[3 * r] * x[0] + A[3 * r + 1] * x[1] + A[3 * r + 2] * x[2];
}
static inline void mtv(const double *A, const double *x, double *y)  /* y = Aᵀ x */
{
    for (int r = 0; r < 3; r++) y[r] = A[r] * x[0] + A[3 + r] * x[1] + A[6 + r] * x[2];
}
static inline void mm(const double *A, const double *B, double *C)   /* C = A B */
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            C[3 * r + c] = A[3 * r] * B[c] + A[3 * r + 1] * B[3 + c] + A[3 * r + 2] * B[6 + c];
}

#endif
