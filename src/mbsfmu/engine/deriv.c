/* Directional derivatives of ẋ, the output points and the stresses along seeds of the state and the inputs
 * (issue 27: FMI's directional and adjoint derivatives), by complex step through the evaluation itself: tree.c,
 * dynamics.c (and in deriv_elastic.c elastic.c) compiled again over a complex `real` (mbs_model.h, MBS_CX renames
 * their functions to mbs_cx_*). With x + i h dx, f(x + i h dx) = f(x) + i h f'(x) dx + O(h²): the imaginary part
 * over h is the derivative, with no difference taken, so exact to rounding (h so small that h² vanishes). Both
 * evaluation paths and every joint, force element and elastic body are differentiated by the code that
 * evaluates them; nothing is written twice.
 */
#define MBS_CX 1
#include "tree.c"
#include "forces.c"
#include "dynamics.c"
#include "cholesky.c"
#include "forward.c"
/* elastic.c's twin: deriv_elastic.c (a rigid scene's FMU carries no elastic code) */

#include <stdint.h>

#define H_TINY 1e-100  /* |h · seed| at most: its square underflows beside any number the evaluation meets */

static size_t align(size_t n) { return (n + 15) & ~(size_t)15; }

/* the complex numbers of one evaluation: D, td, x, q_in, work, k, q, ẋ; then elastic.c's workspace */
static size_t numbers(const MbsModel *m)
{
    const int32_t *h = m->hdr;
    return (size_t)h[H_ND] + 3 * ((size_t)h[H_NDRV] + h[H_NVEC]) + 2 * ((size_t)h[H_NPOS] + h[H_NVEL]) +
           3 * (size_t)h[H_NVEL] + (size_t)mbs_work_doubles(h);
}

size_t mbs_tangent_work_size(const MbsModel *m)
{
    size_t n = align(numbers(m) * sizeof(real));
#ifdef MBS_WITH_ELASTIC
    if (m->hdr[H_FEATURES] & F_ELASTIC) n += align(mbs_elastic_work_size(m));
#endif
    return n;
}

static void lift(real *to, const double *x, const double *dx, double h, size_t n)  /* x + i h dx */
{
    for (size_t k = 0; k < n; k++) to[k] = CMPLX(x ? x[k] : 0.0, dx ? h * dx[k] : 0.0);
}

static double largest(const double *v, size_t n, double big)
{
    for (size_t k = 0; v && k < n; k++) big = fmax(big, fabs(v[k]));
    return big;
}

int mbs_tangent(const MbsModel *m, const MbsTangent *t, void *work)
{
    const int32_t *hd = m->hdr;
    const int f = hd[H_NVEL], n = hd[H_NPOS] + f, nout = hd[H_NOUT];
    const size_t ntd = 3 * ((size_t)hd[H_NDRV] + hd[H_NVEC]), nin = 3 * (size_t)hd[H_NINPUT];
    double big = largest(t->dx, n, 0.0);
    big = largest(t->dq_in, f, big);
    big = largest(t->dfin, nin, big);
    const double h = big > 0.0 ? H_TINY / big : 1.0;  /* no seed at all: the imaginary parts stay 0 */
    real *D = work, *td = D + hd[H_ND], *x = td + ntd, *q_in = x + n, *w = q_in + f;
    real *k = w + (size_t)mbs_work_doubles(hd), *q = k + f, *xdot = q + f;
    lift(td, t->td, NULL, 0.0, ntd);
    for (size_t j = 0; t->dfin && j < nin; j++) td[3 * (size_t)hd[H_NDRV] + j] += CMPLX(0.0, h * t->dfin[j]);
    lift(x, t->x, t->dx, h, n);
    lift(q_in, t->q_in, t->dq_in, h, f);
    MbsEval e = {m, D, td, x, (t->q_in || t->dq_in) ? q_in : NULL, w, m->dense ? w + mbs_work_M_offset(hd) : NULL,
                 k, q, xdot, (char *)work + align(numbers(m) * sizeof(real))};
    if (t->rebind) {  /* the bound numbers, and on the recursive path the carriers' inertias from them */
        lift(D, t->D, NULL, 0.0, hd[H_ND]);
        if (!m->dense) mbs_composites(m, D, w);
    }
    mbs_kinematics(&e);
    if (t->dout)
        for (int o = 0; o < nout; o++) {
            real r[6];
            const int *oi = m->out + 3 * o;
#ifdef MBS_WITH_ELASTIC
            if (oi[1] >= 0) mbs_elastic_node_point(&e, oi[0], oi[1], r, r + 3, NULL); else
#endif
            mbs_point(&e, oi[0], D + hd[H_D_OUT] + 3 * o, r, r + 3, NULL);
            for (int c = 0; c < 6; c++) t->dout[6 * o + c] = cimag(r[c]) / h;
        }
#ifdef MBS_WITH_ELASTIC
    for (int s = 0; t->dvm && s < m->nstress; s++) t->dvm[s] = cimag(mbs_elastic_von_mises(m, s, x)) / h;
#endif
    if (!t->dxdot) return 0;
    if (mbs_eval_rhs(&e)) return MBS_F_SINGULAR;
    for (int c = 0; c < n; c++) t->dxdot[c] = cimag(xdot[c]) / h;
    return 0;
}
