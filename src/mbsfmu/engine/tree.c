/* Rigid-tree equations (seed 000), the engine's per-step core: the same recursion as equations/tree.py.
 *
 *   kinematics:  S_i, o_i, ω_i, v_i, ā_i, ᾱ_i, J_Ri, J_Ti of every body origin, parents first
 *   M = Σ m J_Tcᵀ J_Tc + J_Rᵀ I_w J_R,   k = Σ m J_Tcᵀ ā_c + J_Rᵀ (I_w ᾱ + ω × I_w ω),   q: forces.c
 *   ẏ_pos = Z(y)·ẏ (quaternions: ṗ = G(p) ω); ÿ: forward.c
 *
 * Reads the model's tables and the instance's bound numbers (MbsEval), writes only the workspace.
 */
#include <math.h>
#include <string.h>

#include "mbs_integrator.h"
#include "mbs_model.h"
#include "mbs_vec3.h"

static void axis_angle(const real *a, real ang, real *R)
{
    real x = a[0], y = a[1], z = a[2], c = r_cos(ang), s = r_sin(ang), C = 1.0 - c;
    R[0] = c + x * x * C;     R[1] = x * y * C - z * s; R[2] = x * z * C + y * s;
    R[3] = y * x * C + z * s; R[4] = c + y * y * C;     R[5] = y * z * C - x * s;
    R[6] = z * x * C - y * s; R[7] = z * y * C + x * s; R[8] = c + z * z * C;
}
static void quat_to_matrix(const real *p, real *S)
{
    real p0 = p[0], p1 = p[1], p2 = p[2], p3 = p[3];
    S[0] = 1 - 2 * (p2 * p2 + p3 * p3); S[1] = 2 * (p1 * p2 - p0 * p3);     S[2] = 2 * (p1 * p3 + p0 * p2);
    S[3] = 2 * (p1 * p2 + p0 * p3);     S[4] = 1 - 2 * (p1 * p1 + p3 * p3); S[5] = 2 * (p2 * p3 - p0 * p1);
    S[6] = 2 * (p1 * p3 - p0 * p2);     S[7] = 2 * (p2 * p3 + p0 * p1);     S[8] = 1 - 2 * (p1 * p1 + p2 * p2);
}

/* Joint motion in the joint frame (joints.py): R_rel, d_rel, H_R, H_T (3 × nv, column-major per joint
 * velocity: H[3*j + r]) and b_R (b_T is zero for every joint type). Zero parts are written as zeros. */
static void cardan(const real *p, const real *v, real *R, real *H, real *b_R)
{
    real ca = r_cos(p[0]), sa = r_sin(p[0]), cb = r_cos(p[1]), sb = r_sin(p[1]), cc = r_cos(p[2]), sc = r_sin(p[2]);
    real Sx[9] = {1, 0, 0, 0, ca, -sa, 0, sa, ca}, Sy[9] = {cb, 0, sb, 0, 1, 0, -sb, 0, cb};
    real Sz[9] = {cc, -sc, 0, sc, cc, 0, 0, 0, 1}, Sxy[9];
    mm(Sx, Sy, Sxy);
    mm(Sxy, Sz, R);
    real h1[3] = {1, 0, 0}, h2[3] = {Sx[1], Sx[4], Sx[7]}, h3[3] = {Sxy[2], Sxy[5], Sxy[8]};
    real w1[3], w2[3], c1[3], c2[3];
    for (int r = 0; r < 3; r++) {
        w1[r] = h1[r] * v[0];
        w2[r] = w1[r] + h2[r] * v[1];
        H[r] = h1[r]; H[3 + r] = h2[r]; H[6 + r] = h3[r];
    }
    cross(w1, h2, c1);
    cross(w2, h3, c2);
    for (int r = 0; r < 3; r++) b_R[r] = c1[r] * v[1] + c2[r] * v[2];
}

static void zero3(real *a) { a[0] = a[1] = a[2] = 0.0; }

/* the parts of a joint's motion that may be nonzero (joint_motion): the offset d_rel, the columns H_T, b_R */
enum { JM_D = 1, JM_T = 2, JM_B = 4 };
static const int JM_PARTS[J_N] = {[J_PRISMATIC] = JM_D | JM_T, [J_CYLINDRICAL] = JM_D | JM_T, [J_UNIVERSAL] = JM_B,
                                  [J_PLANAR] = JM_D | JM_T, [J_SPH_CARDAN] = JM_B, [J_FREE_QUAT] = JM_D | JM_T,
                                  [J_FREE_CARDAN] = JM_D | JM_T | JM_B};

static void joint_motion(int type, int nv, const MbsBodyD *bd, const real *p, const real *v,
                         real *R, real *d, real *H_R, real *H_T, real *b_R)
{
    const real *a = bd->a1, *a2 = bd->a2;
    static const real E[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(R, E, sizeof E);
    /* three at a time, only the joint's columns: a memset of these small arrays compiles to `rep stos`,
     * whose start-up cost was a third of the kinematics */
    zero3(d), zero3(b_R);
    for (int k = 0; k < nv; k++) zero3(H_R + 3 * k), zero3(H_T + 3 * k);
    switch (type) {
    case J_REVOLUTE:
        axis_angle(a, p[0], R);
        memcpy(H_R, a, 3 * sizeof(real));
        break;
    case J_PRISMATIC:
        for (int r = 0; r < 3; r++) d[r] = a[r] * p[0];
        memcpy(H_T, a, 3 * sizeof(real));
        break;
    case J_CYLINDRICAL:
        axis_angle(a, p[1], R);
        for (int r = 0; r < 3; r++) { d[r] = a[r] * p[0]; H_T[r] = a[r]; H_R[3 + r] = a[r]; }
        break;
    case J_UNIVERSAL: {
        real S1[9], S2[9], h2[3], c[3];
        axis_angle(a, p[0], S1);
        axis_angle(a2, p[1], S2);
        mm(S1, S2, R);
        mv(S1, a2, h2);
        cross(a, h2, c);
        for (int r = 0; r < 3; r++) { H_R[r] = a[r]; H_R[3 + r] = h2[r]; b_R[r] = c[r] * (v[0] * v[1]); }
        break;
    }
    case J_PLANAR: {
        real n[3];
        cross(a, a2, n);
        axis_angle(n, p[2], R);
        for (int r = 0; r < 3; r++) {
            d[r] = a[r] * p[0] + a2[r] * p[1];
            H_T[r] = a[r]; H_T[3 + r] = a2[r]; H_R[6 + r] = n[r];
        }
        break;
    }
    case J_SPH_QUAT:
        quat_to_matrix(p, R);
        for (int j = 0; j < 3; j++)
            for (int r = 0; r < 3; r++) H_R[3 * j + r] = R[3 * r + j];
        break;
    case J_SPH_CARDAN:
        cardan(p, v, R, H_R, b_R);
        break;
    case J_FREE_QUAT:
        quat_to_matrix(p + 3, R);
        for (int r = 0; r < 3; r++) d[r] = p[r];
        for (int j = 0; j < 3; j++)
            for (int r = 0; r < 3; r++) {
                H_R[3 * (3 + j) + r] = R[3 * r + j];
                H_T[3 * j + r] = (r == j);
            }
        break;
    case J_FREE_CARDAN:
        cardan(p + 3, v + 3, R, H_R + 9, b_R);
        for (int r = 0; r < 3; r++) d[r] = p[r];
        for (int j = 0; j < 3; j++)
            for (int r = 0; r < 3; r++) H_T[3 * j + r] = (r == j);
        break;
    default:
        break;
    }
}


static real *body_work(const MbsEval *e, int i) { return mbs_body_work(e, i); }
static int col_lo(const real *wk) { return (int)wk[W_LO]; }
static int col_hi(const real *wk) { return (int)wk[W_HI]; }

const MbsBodyD *mbs_body_d(const MbsEval *e, int i) { return mbs_body_row(e->m, e->D, i); }

/* Joint frame of body i's parent side: S_p, o_p, ω_p, v_p, ā_p, ᾱ_p, J_Rp, J_Tp, the offset ρ and S_J
 * (tree.py: attachment). On the dense path J_R, J_T of the body start as the parent's; [lo, hi) their nonzero
 * columns. */
static void attachment(const MbsEval *e, int i, real *S_J, real *rho, const real **o_p,
                       const real **w_p, const real **v_p, const real **a_p, const real **al_p, real *J_R,
                       int *lo, int *hi, real *node_buf)
{
    static const real Z[3] = {0, 0, 0};
    const MbsModel *m = e->m;
    const MbsBodyI *bi = mbs_body_i(m, i);
    const int f = NVEL(m), par = bi->parent;
    const MbsBodyD *bd = mbs_body_d(e, i);
    if (par < 0) {
        *o_p = *w_p = *v_p = *a_p = *al_p = Z;
        if (m->dense) memset(J_R, 0, 6 * (size_t)f * sizeof(real));
        memcpy(S_J, bd->R0, 9 * sizeof(real));
        memcpy(rho, bd->at, 3 * sizeof(real));
        *lo = f;
        *hi = 0;
        return;
    }
    const real *pw = body_work(e, par), *R0 = bd->R0, *at = bd->at;
    if (!m->dense) {  /* a welded parent's frame is its carrier's (mbs_welded) */
        const real *wk = body_work(e, i);
        R0 = wk + AB_R0C;
        at = wk + AB_ATC;
        if (mbs_welded(m, par)) pw = body_work(e, mbs_body_i(m, par)->carrier);
    }
    *lo = col_lo(pw);
    *hi = col_hi(pw);
#ifdef MBS_WITH_ELASTIC
    if (bi->node >= 0) {  /* at a node of an elastic parent: it moves with r_IP, S_IP (seed 004) */
        real S_P[9], *nb_ = node_buf;
        mbs_elastic_node_frame(e, i, S_P, nb_, nb_ + 3, nb_ + 6, nb_ + 9, nb_ + 12, m->dense ? J_R : NULL,
                               m->dense ? J_R + 3 * f : NULL);
        *o_p = nb_; *w_p = nb_ + 3; *v_p = nb_ + 6; *a_p = nb_ + 9; *al_p = nb_ + 12;
        mm(S_P, bd->R0, S_J);
        memset(rho, 0, 3 * sizeof(real));
        *lo = (int)pw[W_LO];   /* the parent's columns, widened to its elastic coordinates */
        *hi = (int)pw[W_HI];
        return;
    }
#else
    (void)node_buf;
#endif
    const real *S_p = pw + W_S;
    *o_p = pw + W_O; *w_p = pw + W_W; *v_p = pw + W_V; *a_p = pw + W_A; *al_p = pw + W_AL;
    if (m->dense) memcpy(J_R, pw + W_J, 6 * (size_t)f * sizeof(real));
    mm(S_p, R0, S_J);
    mv(S_p, at, rho);
}

/* The free columns of body i's joint as spatial motions at its origin (dynamics.c): (s_R, s_T), world axes. */
static void motion_subspace(const MbsBodyI *bi, const real *s_R, const real *s_T, real *wk)
{
    int n = 0;
    for (int k = 0; k < bi->nvel; k++) {
        if (bi->vel[k] < 0) continue;
        real *s = wk + AB_S + 6 * n++;
        for (int r = 0; r < 3; r++) { s[r] = s_R[3 * k + r]; s[3 + r] = s_T[3 * k + r]; }
    }
    wk[AB_NV] = n;
}

/* Recursive kinematics of all body origins (tree.py: kinematics): S, o, ω, v, ᾱ, ā, and on the dense path
 * J_R, J_T, on the recursive one the joints' motion subspaces. */
void mbs_kinematics(const MbsEval *e)
{
    const MbsModel *m = e->m;
    const int f = NVEL(m);
    const real *y = e->x, *yd = e->x + NPOS(m);
    for (int i = 0; i < NB(m); i++) {
        if (mbs_welded(m, i)) continue;
        const MbsBodyI *bi = mbs_body_i(m, i);
        const MbsBodyD *bd = mbs_body_d(e, i);
        real *wk = body_work(e, i);
        real *J_R = wk + W_J, *J_T = J_R + 3 * f;
        const int nv = bi->nvel, np = bi->npos;
        const real *o_p, *w_p, *v_p, *a_p, *al_p;
        real S_J[9], rho[3], node_buf[15];
        int lo, hi;
        attachment(e, i, S_J, rho, &o_p, &w_p, &v_p, &a_p, &al_p, J_R, &lo, &hi, node_buf);
        real p[7], v[6], acc[6] = {0}, R[9], d[3], H_R[18], H_T[18], b_R[3];
        for (int k = 0; k < np; k++) {
            int pi = bi->pos[k], s = bi->drv[k];
            p[k] = pi >= 0 ? y[pi] : e->td[3 * s];
        }
        for (int k = 0; k < nv; k++) {
            int vi = bi->vel[k], s = bi->drv[k];
            if (vi >= 0) v[k] = yd[vi];
            else { v[k] = e->td[3 * s + 1]; acc[k] = e->td[3 * s + 2]; }
        }
        joint_motion(bi->jtype, nv, bd, p, v, R, d, H_R, H_T, b_R);
        /* the joint's columns in world axes s = S_J H, and ω_rel = Σ s_R ẏ, v_rel = Σ s_T ẏ; the prescribed
         * accelerations of driven coordinates join the bias terms: S_J b + Σ s ÿ_prescribed (zero parts skipped) */
        const int parts = JM_PARTS[bi->jtype];
        real s_R[18], s_T[18], w_rel[3] = {0, 0, 0}, v_rel[3] = {0, 0, 0}, SbR[3] = {0, 0, 0}, SbT[3] = {0, 0, 0};
        for (int k = 0; k < nv; k++) {
            mv(S_J, H_R + 3 * k, s_R + 3 * k);
            if (parts & JM_T) mv(S_J, H_T + 3 * k, s_T + 3 * k);
            else zero3(s_T + 3 * k);
            for (int r = 0; r < 3; r++) {
                w_rel[r] += s_R[3 * k + r] * v[k];
                v_rel[r] += s_T[3 * k + r] * v[k];
            }
            if (bi->vel[k] < 0)
                for (int r = 0; r < 3; r++) { SbR[r] += s_R[3 * k + r] * acc[k]; SbT[r] += s_T[3 * k + r] * acc[k]; }
        }
        if (parts & JM_D) {
            real dd[3];
            mv(S_J, d, dd);
            for (int r = 0; r < 3; r++) rho[r] += dd[r];
        }
        if (parts & JM_B) {
            real Sb[3];
            mv(S_J, b_R, Sb);
            for (int r = 0; r < 3; r++) SbR[r] += Sb[r];
        }
        real *w = wk + W_W, *al = wk + W_AL, *o = wk + W_O, *vv = wk + W_V, *a = wk + W_A, wxr[3];
        /* ω = ω_p + ω_rel;  v = v_p + ω_p × ρ + v_rel */
        cross(w_p, rho, wxr);
        for (int r = 0; r < 3; r++) {
            w[r] = w_p[r] + w_rel[r];
            o[r] = o_p[r] + rho[r];
            vv[r] = v_p[r] + wxr[r] + v_rel[r];
        }
        mm(S_J, R, wk + W_S);
        real t1[3], t2[3], axr[3], wwxr[3];
        /* ᾱ = ᾱ_p + ω_p × ω_rel + S_J b_R;  ā = ā_p + ᾱ_p × ρ + ω_p × (ω_p × ρ) + 2 ω_p × v_rel (+ the drives') */
        cross(w_p, w_rel, t1);
        cross(al_p, rho, axr);
        cross(w_p, wxr, wwxr);
        cross(w_p, v_rel, t2);
        for (int r = 0; r < 3; r++) {
            al[r] = al_p[r] + t1[r] + SbR[r];
            a[r] = a_p[r] + axr[r] + wwxr[r] + 2.0 * t2[r] + SbT[r];
        }
        if (!m->dense) {
            motion_subspace(bi, s_R, s_T, wk);
            continue;
        }
        /* J_T = J_Tp − ρ̃ J_Rp, then the joint's own columns */
        for (int c = lo; c < hi; c++) {
            real jr[3] = {J_R[c], J_R[f + c], J_R[2 * f + c]}, x[3];
            cross(rho, jr, x);
            for (int r = 0; r < 3; r++) J_T[r * f + c] -= x[r];
        }
        for (int k = 0; k < nv; k++) {
            int col = bi->vel[k];
            if (col < 0) continue;
            if (col < lo) lo = col;
            if (col + 1 > hi) hi = col + 1;
            for (int r = 0; r < 3; r++) { J_R[r * f + col] += s_R[3 * k + r]; J_T[r * f + col] += s_T[3 * k + r]; }
        }
        wk[W_LO] = lo;
        wk[W_HI] = hi;
#ifdef MBS_WITH_ELASTIC
        if (bi->elastic >= 0) mbs_elastic_kinematics(e, i);  /* may widen [lo, hi) to its q columns */
#endif
    }
}

/* World position, velocity and J_T (3 × f, columns [lo, hi) of body i only; dense path) of a point fixed on
 * body i (r_b in the body frame); i < 0: a point of the world. */
void mbs_point(const MbsEval *e, int i, const real *r_b, real *x, real *v, real *J)
{
    const int f = NVEL(e->m);
    if (i < 0) {
        memcpy(x, r_b, 3 * sizeof(real));
        memset(v, 0, 3 * sizeof(real));
        return;
    }
    real r_c[3];
    if (mbs_welded(e->m, i)) {  /* the point on the carrier */
        const real *wk = body_work(e, i);
        mv(wk + AB_R0C, r_b, r_c);
        for (int k = 0; k < 3; k++) r_c[k] += wk[AB_ATC + k];
        r_b = r_c;
        i = mbs_body_i(e->m, i)->carrier;
    }
    const real *wk = body_work(e, i), *J_R = wk + W_J, *J_T = J_R + 3 * f;
    real r[3], wxr[3];
    mv(wk + W_S, r_b, r);
    cross(wk + W_W, r, wxr);
    for (int k = 0; k < 3; k++) { x[k] = wk[W_O + k] + r[k]; v[k] = wk[W_V + k] + wxr[k]; }
    if (!J) return;
    for (int c = col_lo(wk); c < col_hi(wk); c++) {
        real jr[3] = {J_R[c], J_R[f + c], J_R[2 * f + c]}, s[3];
        cross(r, jr, s);
        for (int k = 0; k < 3; k++) J[k * f + c] = J_T[k * f + c] - s[k];
    }
}

/* q += sign Jᵀ F for a 3 × f Jacobian of body i (its columns [lo, hi)) */
void mbs_add_JtF(const MbsEval *e, int i, const real *J, const real *F, double sign, real *q)
{
    const int f = NVEL(e->m);
    const real *wk = body_work(e, i);
    for (int c = col_lo(wk); c < col_hi(wk); c++) q[c] += sign * (J[c] * F[0] + J[f + c] * F[1] + J[2 * f + c] * F[2]);
}

/* M, k and the gravity part of q (tree.py: mass_matrix_and_bias); scratch: 3 × f after the bodies. */
void mbs_mass_matrix_and_bias(const MbsEval *e)
{
    const MbsModel *m = e->m;
    const int f = NVEL(m);
    const real *g = e->D + m->hdr[H_D_G];
    real *M = e->M, *k = e->k, *q = e->q, *J = e->work + (size_t)NB(m) * W_SIZE(f);
    memset(M, 0, (size_t)f * f * sizeof(real));
    memset(k, 0, f * sizeof(real));
    memset(q, 0, f * sizeof(real));
    for (int i = 0; i < NB(m); i++) {
        const MbsBodyI *bi = mbs_body_i(m, i);
        if (!bi->massive) continue;
        const MbsBodyD *bd = mbs_body_d(e, i);
        const real *wk = body_work(e, i), *J_R = wk + W_J, *S = wk + W_S;
        const real *w = wk + W_W, *al = wk + W_AL, mass = bd->m;
        real xc[3], vc[3], c[3], wxc[3], axc[3], wwxc[3], a_c[3];
        mbs_point(e, i, bd->c, xc, vc, J);  /* J_T of the centre of mass */
        mv(S, bd->c, c);
        cross(w, c, wxc);
        cross(al, c, axc);
        cross(w, wxc, wwxc);
        for (int r = 0; r < 3; r++) a_c[r] = wk[W_A + r] + axc[r] + wwxc[r];
        /* I_w = S I Sᵀ: world-frame inertia about the centre of mass */
        real SI[9], I_w[9], Iw_w[3], Iw_al[3], gyr[3];
        mm(S, bd->I, SI);
        for (int r = 0; r < 3; r++)
            for (int cc = 0; cc < 3; cc++) I_w[3 * r + cc] = SI[3 * r] * S[3 * cc] + SI[3 * r + 1] * S[3 * cc + 1] + SI[3 * r + 2] * S[3 * cc + 2];
        mv(I_w, w, Iw_w);
        mv(I_w, al, Iw_al);
#ifdef MBS_WITH_ELASTIC
        if (m->hdr[H_FEATURES] & F_ELASTIC) {
            /* S (ω_b × I ω_b), ω_b = Sᵀω, as tree.py: at a node S = S_R (E + θ̃) is orthogonal only to first
             * order (seed 004), and then this differs from ω × I_w ω */
            real wb[3], Iwb[3], g_b[3];
            for (int r = 0; r < 3; r++) wb[r] = S[r] * w[0] + S[3 + r] * w[1] + S[6 + r] * w[2];
            mv(bd->I, wb, Iwb);
            cross(wb, Iwb, g_b);
            mv(S, g_b, gyr);
        } else
#endif
        cross(w, Iw_w, gyr);
        real mg[3] = {0, 0, 0}, mac[3], rot[3];
        if (m->hdr[H_HAS_GRAVITY]) for (int r = 0; r < 3; r++) mg[r] = mass * g[r];
        for (int r = 0; r < 3; r++) { mac[r] = mass * a_c[r]; rot[r] = Iw_al[r] + gyr[r]; }
        mbs_add_JtF(e, i, J, mac, 1.0, k);
        mbs_add_JtF(e, i, J_R, rot, 1.0, k);
        mbs_add_JtF(e, i, J, mg, 1.0, q);
        const int lo = col_lo(wk), hi = col_hi(wk);
        for (int cj = lo; cj < hi; cj++) {
            /* columns of I_w J_R and m J_T */
            real IJ[3], jr[3] = {J_R[cj], J_R[f + cj], J_R[2 * f + cj]};
            mv(I_w, jr, IJ);
            for (int ci = lo; ci <= cj; ci++) {
                real s = mass * (J[ci] * J[cj] + J[f + ci] * J[f + cj] + J[2 * f + ci] * J[2 * f + cj])
                         + J_R[ci] * IJ[0] + J_R[f + ci] * IJ[1] + J_R[2 * f + ci] * IJ[2];
                M[ci * f + cj] += s;
            }
        }
    }
    for (int i = 0; i < f; i++)
        for (int j = 0; j < i; j++) M[i * f + j] = M[j * f + i];
#ifdef MBS_WITH_ELASTIC
    if (m->hdr[H_FEATURES] & F_ELASTIC) mbs_elastic_equations(e);
#endif
}

/* ẏ_pos = Z(y) ẏ into e->xdot: plain coordinates their velocities, quaternions ṗ = G(p) ω */
void mbs_position_rates(const MbsEval *e)
{
    const MbsModel *m = e->m;
    const real *y = e->x, *yd = e->x + NPOS(m);
    real *xd = e->xdot;
    const int nplain = m->hdr[H_NPLAIN];
    for (int i = 0; i < nplain; i++) xd[m->plain[i]] = yd[m->plain[nplain + i]];
    for (int j = 0; j < m->hdr[H_NQUAT]; j++) {
        const int *qi = m->quat + 7 * j;
        real p0 = y[qi[0]], p1 = y[qi[1]], p2 = y[qi[2]], p3 = y[qi[3]];
        real w0 = yd[qi[4]], w1 = yd[qi[5]], w2 = yd[qi[6]];
        /* ṗ = ½ p ⊗ (0, ω), body-frame ω */
        xd[qi[0]] = 0.5 * (-p1 * w0 - p2 * w1 - p3 * w2);
        xd[qi[1]] = 0.5 * (p0 * w0 - p3 * w1 + p2 * w2);
        xd[qi[2]] = 0.5 * (p3 * w0 + p0 * w1 - p1 * w2);
        xd[qi[3]] = 0.5 * (-p2 * w0 + p1 * w1 + p0 * w2);
    }
}

#ifndef MBS_CX  /* (deriv.c's complex twin evaluates; binding stays here) */
/* ---- bind time: derived numbers from the raw ones (after the bind programs ran) ---- */
static void unit(const double *a, double *u)
{
    double n = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    for (int r = 0; r < 3; r++) u[r] = a[r] / n;
}

/* rotation from a raw spec: 1 axis-angle (axis 3, angle), 2 matrix (9, row-major); else identity */
static void rotation(int code, const double *raw, double *R)
{
    static const double E[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    if (code == 1) {
        double a[3];
        unit(raw, a);
        axis_angle(a, raw[3], R);
    } else if (code == 2) {
        memcpy(R, raw, 9 * sizeof(double));
    } else {
        memcpy(R, E, sizeof E);
    }
}

void mbs_derive(const MbsModel *m, double *D)
{
    for (int i = 0; i < NB(m); i++) {
        const MbsBodyI *bi = mbs_body_i(m, i);
        MbsBodyD *bd = (MbsBodyD *)mbs_body_row(m, D, i);  /* mbs_derive writes the derived fields */
        const int naxes = mbs_joints[bi->jtype].naxes;
        if (naxes >= 1) unit(bd->a1_raw, bd->a1);
        if (naxes == 2) unit(bd->a2_raw, bd->a2);
        rotation(bi->rot, bd->rot_raw, bd->R0);
    }
}

/* Unit quaternion (scalar first, p0 >= 0) of a rotation matrix (Shepperd), as rotations.matrix_to_quat. */
static void matrix_to_quat(const double *S, double *p)
{
    double t = S[0] + S[4] + S[8], c[4] = {t, S[0], S[4], S[8]}, r;
    int i = 0;
    for (int k = 1; k < 4; k++) if (c[k] > c[i]) i = k;
    if (i == 0) { r = sqrt(1 + t) * 2; p[0] = 0.25 * r; p[1] = (S[7] - S[5]) / r; p[2] = (S[2] - S[6]) / r; p[3] = (S[3] - S[1]) / r; }
    else if (i == 1) { r = sqrt(1 + 2 * S[0] - t) * 2; p[0] = (S[7] - S[5]) / r; p[1] = 0.25 * r; p[2] = (S[1] + S[3]) / r; p[3] = (S[2] + S[6]) / r; }
    else if (i == 2) { r = sqrt(1 + 2 * S[4] - t) * 2; p[0] = (S[2] - S[6]) / r; p[1] = (S[1] + S[3]) / r; p[2] = 0.25 * r; p[3] = (S[5] + S[7]) / r; }
    else { r = sqrt(1 + 2 * S[8] - t) * 2; p[0] = (S[3] - S[1]) / r; p[1] = (S[2] + S[6]) / r; p[2] = (S[5] + S[7]) / r; p[3] = 0.25 * r; }
    if (p[0] < 0) for (int k = 0; k < 4; k++) p[k] = -p[k];
}

/* y(0), ẏ(0): the bound raw values (D's x0 block, written by programs), with the initial rotations of
 * spherical/free joints turned into their quaternion or Cardan angles (evaluator.initial_state). */
void mbs_initial_state(const MbsModel *m, const double *D, double *x0)
{
    const int n = NPOS(m) + NVEL(m);
    memcpy(x0, D + m->hdr[H_D_X0], (size_t)n * sizeof(double));
    for (int i = 0; i < NB(m); i++) {
        const MbsBodyI *bi = mbs_body_i(m, i);
        const MbsBodyD *bd = mbs_body_row(m, D, i);
        const MbsJointType *jt = &mbs_joints[bi->jtype];
        const int off = jt->rot;
        double S[9], p[4];
        if (off < 0) continue;
        if (jt->gimbal < 0) {  /* a quaternion */
            rotation(bi->irot, bd->irot_raw, S);
            matrix_to_quat(S, p);
            for (int k = 0; k < 4; k++) if (bi->pos[off + k] >= 0) x0[bi->pos[off + k]] = p[k];
        } else if (bi->irot) {  /* Cardan angles */
            rotation(bi->irot, bd->irot_raw, S);
            double s02 = S[2] < -1.0 ? -1.0 : S[2] > 1.0 ? 1.0 : S[2];
            double ang[3] = {atan2(-S[5], S[8]), asin(s02), atan2(-S[1], S[0])};
            for (int k = 0; k < 3; k++) {
                int idx = bi->pos[off + k];
                if (idx >= 0 && (bi->irot_mask >> k & 1)) x0[idx] = ang[k];
            }
        }
    }
}
#endif
