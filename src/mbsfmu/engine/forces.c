/* Applied forces (seed 000's q = Σ J_Tᵀ f + J_Rᵀ l): the force elements and the generalized-force inputs. On the
 * dense path through the bodies' Jacobians into q; on the recursive path onto the bodies' spatial forces, which
 * the articulated-body algorithm (dynamics.c) carries. */
#include <math.h>
#include <string.h>

#include "mbs_integrator.h"
#include "mbs_model.h"
#include "mbs_vec3.h"

/* x = S_i x_b: a vector in body i's axes in world axes */
static void body_axes(const MbsEval *e, int i, const real *x_b, real *x)
{
    if (mbs_welded(e->m, i)) {
        real x_c[3];
        mv(mbs_body_work(e, i) + AB_R0C, x_b, x_c);
        mv(mbs_body_work(e, mbs_body_i(e->m, i)->carrier) + W_S, x_c, x);
    } else
        mv(mbs_body_work(e, i) + W_S, x_b, x);
}


/* The spatial force on body i (its carrier) of F at x (x NULL: F is a torque); recursive path. */
void mbs_body_force(const MbsEval *e, int i, const real *x, const real *F, double sign)
{
    i = mbs_body_i(e->m, i)->carrier;  /* a welded body's force acts on its carrier; the world's takes none */
    if (i < 0) return;
    real *wk = mbs_body_work(e, i), *f = wk + AB_F, n[3], r_[3];
    if (!x) {
        for (int r = 0; r < 3; r++) f[r] += sign * F[r];
        return;
    }
    for (int r = 0; r < 3; r++) r_[r] = x[r] - wk[W_O + r];
    cross(r_, F, n);
    for (int r = 0; r < 3; r++) { f[r] += sign * n[r]; f[3 + r] += sign * F[r]; }
}

/* World position, velocity and J_T of an attachment: a point on body i, or node P of an elastic body. */
static void force_point(const MbsEval *e, int i, int node, const real *at, real *x, real *v, real *J)
{
#ifdef MBS_WITH_ELASTIC
    if (node >= 0 && i >= 0) { mbs_elastic_node_point(e, i, node, x, v, J); return; }
#else
    (void)node;
#endif
    mbs_point(e, i, at, x, v, J);
}

/* A force F (sign ±1) at a point with Jacobian J on body i, or at its node (-1: none): q += sign JᵀF (dense path),
 * or onto the body's spatial force at x and at a node onto its modal coordinates (recursive path; x NULL: F is a
 * torque). */
static void apply(const MbsEval *e, int i, int node, const real *J, const real *x, const real *F, double sign)
{
    if (e->m->dense) { mbs_add_JtF(e, i, J, F, sign, e->q); return; }
    mbs_body_force(e, i, x, F, sign);
#ifdef MBS_WITH_ELASTIC
    if (node >= 0) mbs_elastic_node_force(e, i, node, F, !x, sign);
#else
    (void)node;
#endif
}

/* q (generalized forces) from the force elements and the generalized-force inputs (tree.py: applied_forces); on
 * the recursive path the forces on bodies go to their spatial forces instead, never through Jacobians. */
void mbs_applied_forces(const MbsEval *e)
{
    const MbsModel *m = e->m;
    const int f = NVEL(m);
    const real *y = e->x, *yd = e->x + NPOS(m);
    real *q = e->q, *Ja = NULL, *Jb = NULL;
    if (m->dense) { Ja = e->work + (size_t)NB(m) * W_SIZE(f); Jb = Ja + 3 * f; }
    if (e->q_in) for (int c = 0; c < f; c++) q[c] += e->q_in[c];
    for (int n = 0; n < m->hdr[H_NFORCE]; n++) {
        const MbsForceI *fi = mbs_force_i(m, n);
        const MbsForceD *fd = mbs_force_row(m, e->D, n);
        switch (fi->type) {
        case FE_JOINT_SPRING: {
            int pi = fi->a, vi = fi->b;
            q[vi] -= fd->k * (y[pi] - fd->l) + fd->d * yd[vi];
            break;
        }
        case FE_SPRING: {
            real xa[3], va[3], xb[3], vb[3], dx[3], dv[3];
            force_point(e, fi->a, fi->node_a, fd->at_a, xa, va, Ja);
            force_point(e, fi->b, fi->node_b, fd->at_b, xb, vb, Jb);
            for (int r = 0; r < 3; r++) { dx[r] = xb[r] - xa[r]; dv[r] = vb[r] - va[r]; }
            real l = r_sqrt(dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2]);
            if (RE(l) < 1e-12) break; /* direction undefined at zero length: no force rather than NaN */
            real e3[3] = {dx[0] / l, dx[1] / l, dx[2] / l};
            real mag = fd->k * (l - fd->l) + fd->d * (e3[0] * dv[0] + e3[1] * dv[1] + e3[2] * dv[2]);
            real F[3] = {mag * e3[0], mag * e3[1], mag * e3[2]}; /* pulls B toward A */
            if (fi->a >= 0) apply(e, fi->a, fi->node_a, Ja, xa, F, 1.0);
            if (fi->b >= 0) apply(e, fi->b, fi->node_b, Jb, xb, F, -1.0);
            break;
        }
        case FE_FORCE:
        case FE_TORQUE: {
            int i = fi->a;
            const real *wk = mbs_body_work(e, i), *src = fi->src >= 0 ? e->td + fi->src : fd->vec;
            real vec[3], xp[3], vp[3];
            if (src[0] == 0.0 && src[1] == 0.0 && src[2] == 0.0) break;
            if (fi->frame) body_axes(e, i, src, vec);
            else memcpy(vec, src, sizeof vec);
            if (fi->type == FE_TORQUE) {
#ifdef MBS_WITH_ELASTIC
                if (fi->node_a >= 0 && m->dense) { mbs_elastic_node_J_R(e, i, fi->node_a, Ja); mbs_add_JtF(e, i, Ja, vec, 1.0, q); break; }
#endif
                apply(e, i, fi->node_a, wk + W_J, NULL, vec, 1.0);
            } else {
                force_point(e, i, fi->node_a, fd->at_a, xp, vp, Ja);
                apply(e, i, fi->node_a, Ja, xp, vec, 1.0);
            }
            break;
        }
        }
    }
}

