/* Dense LU with partial pivoting for small real and complex n×n systems (radau5, gen_alpha).
 *
 * Layout: row-major, A[i*n + j] = A_ij.  Complex numbers are stored as interleaved (re, im) pairs of
 * doubles, so a complex n×n matrix is 2·n·n doubles and entry (i, j) is A[2*(i*n + j)] + i·A[2*(i*n + j)+1]
 * (plain doubles instead of <complex.h>: the same bytes on every compiler, also MSVC, and trivially
 * snapshot-able).
 *
 * Pivots follow LAPACK's getrf convention, 0-based: row k was swapped with row piv[k] (k <= piv[k] < n)
 * before elimination step k.  Factor routines return 0, or k+1 when the pivot of column k is exactly zero
 * (the matrix is singular; the factors are then incomplete and must not be used), like LAPACK's info.
 * No allocation, no global state.
 */
#ifndef MBS_LINALG_H
#define MBS_LINALG_H

/* A = P·L·U in place (L unit lower, U upper, both in A). */
int mbs_lu_factor(int n, double *A, int *piv);
/* b ← A⁻¹·b with the factors of mbs_lu_factor. */
void mbs_lu_solve(int n, const double *LU, const int *piv, double *b);

/* The same for a complex matrix (2·n·n doubles) and a complex right-hand side (2·n doubles). */
int mbs_zlu_factor(int n, double *A, int *piv);
void mbs_zlu_solve(int n, const double *LU, const int *piv, double *b);

/* 1 when piv is a valid pivot vector of an n×n factorization (k <= piv[k] < n), else 0: snapshots. */
int mbs_lu_pivots_valid(int n, const int *piv);

#endif
