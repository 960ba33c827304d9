/* Rigid-tree dynamics in time and memory linear in the bodies (issue 26): ÿ by the articulated-body algorithm
 * (Featherstone's FDab) and, for inspection, M by the composite-rigid-body algorithm and k, q by the recursive
 * Newton–Euler pass. The path of all but the smallest scenes (mbs_dense_path).
 *
 * The recursions run over the carriers only (IB_CARRIER, compile.py: carriers): a body welded to its rigid parent
 * (a fixed joint) moves with it, so its mass, centre of mass and inertia join its carrier's, as Pinocchio merges a
 * URDF's fixed links. mbs_composites derives these merged inertias at bind time, leaves first, into the
 * per-instance workspace (they may depend on parameters); forces on a welded body act on its carrier. The
 * kinematics skip the welded bodies too (mbs_welded): output and force points on them are found through their
 * carrier's frame and a constant offset.
 *
 * Spatial vectors in world axes about each body's origin o (Pinocchio's LOCAL_WORLD_ALIGNED): a motion (ω, v),
 * v the velocity of the body point at o; a force (n, F), n its moment about o. Between a body and its parent only
 * the point moves, by d = o − o_parent: motions m → (ω, v − d × ω), forces f → (n + d × F, F), inertias Tᵀ I T.
 * (About the world origin, with no shifts at all, the inertias of small links far from it lose their digits:
 * iCub's M has λ_min/λ_max ≈ 1e-18.) The kinematics (tree.c) leave per body its frame S, o, ω, v_o, the bias
 * accelerations ā, ᾱ (free ÿ = 0, driven coordinates at their prescribed accelerations) and the free columns S of
 * its joint. Per body
 *
 *     v = (ω, v_o),   â = (ᾱ, ā − ω × v_o),   I = [Ī_o  h̃; h̃ᵀ  m E] (h = m c, c = S c_b),
 *     P = I â + v ×* I v  (k's part),   F = I (0, g) + forces  (q's part),
 *
 * and the body's equation is f = I Δa + P − F with Δa = Σ S ÿ over its path to the root: FDab with the bias
 * accelerations c = 0 and the bias in P (the form MuJoCo uses), which holds for every joint type and drive alike.
 * An elastic body is a node with its modal coordinates besides its joint's (elastic.c: the recursive path).
 */
#include <math.h>
#include <string.h>

#include "mbs_integrator.h"
#include "mbs_model.h"
#include "mbs_vec3.h"

static real dot6(const real *a, const real *b)
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5];
}
static void crossf(const real *v, const real *h, real *f)  /* f = v ×* h = (ω × n + v_O × F, ω × F) */
{
    real a[3], b[3];
    cross(v, h, a);
    cross(v + 3, h + 3, b);
    cross(v, h + 3, f + 3);
    for (int r = 0; r < 3; r++) f[r] = a[r] + b[r];
}

/* f = I v for a rigid body's I = [Ī_O h̃; h̃ᵀ m E] (cheaper than mat6v) */
static void inertia_times(const real *restrict I, const real *restrict h, const real *restrict v, real *restrict f)
{
    real a[3], b[3];
    cross(h, v + 3, a);
    cross(h, v, b);
    for (int r = 0; r < 3; r++) {
        f[r] = I[6 * r] * v[0] + I[6 * r + 1] * v[1] + I[6 * r + 2] * v[2] + a[r];
        f[3 + r] = I[21] * v[3 + r] - b[r];
    }
}

/* A carrier's spatial inertia (with the bodies welded to it: mbs_composites) about its origin in world
 * axes (6 × 6) and its first moment h = m c. */
static void spatial_inertia(const real *wk, real *I, real *h)
{
    const real *S = wk + W_S, m = wk[AB_MC];
    real c[3], SI[9];
    mv(S, wk + AB_CC, c);
    for (int r = 0; r < 3; r++) h[r] = m * c[r];
    mm(S, wk + AB_IC, SI);
    const real cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
    for (int r = 0; r < 3; r++)
        for (int k = 0; k < 3; k++)  /* Ī_o = S Ī Sᵀ + m (c·c E − c cᵀ) */
            I[6 * r + k] = SI[3 * r] * S[3 * k] + SI[3 * r + 1] * S[3 * k + 1] + SI[3 * r + 2] * S[3 * k + 2] +
                           m * ((r == k) * cc - c[r] * c[k]);
    const real ht[9] = {0, -h[2], h[1], h[2], 0, -h[0], -h[1], h[0], 0};
    for (int r = 0; r < 3; r++)
        for (int k = 0; k < 3; k++) {
            I[6 * r + 3 + k] = ht[3 * r + k];
            I[6 * (3 + r) + k] = ht[3 * k + r];
            I[6 * (3 + r) + 3 + k] = (r == k) * m;
        }
}

/* The recursion runs over the carriers (IB_CARRIER: the moving bodies, each with what is welded to it); a
 * carrier's parent in it is its parent's carrier, -1 the world. */
static int carries_itself(const MbsModel *m, int i) { return mbs_body_i(m, i)->carrier == i; }
static int carrier_parent(const MbsModel *m, const MbsBodyI *bi)
{
    return bi->parent < 0 ? -1 : mbs_body_i(m, bi->parent)->carrier;
}

/* I += m (d·d E − d dᵀ): the inertia of mass m at offset d from the reference point (parallel axes) */
static void add_parallel_axes(real m, const real *d, real *I)
{
    const real dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) I[3 * r + c] += m * ((r == c) * dd - d[r] * d[c]);
}

/* Body k (composite wk), welded to its parent at its joint frame (at, R0), joins the parent's composite (wp):
 * m' = m + m_k, c' = (m c + m_k c_k) / m', Ī' = Ī + m (c − c')~ + R0 Ī_k R0ᵀ + m_k (c_k − c')~ with c_k = at + R0 c_k
 * in the parent's frame (~: the parallel-axis term). */
static void weld(const MbsBodyD *bk, const real *wk, real *wp)
{
    real ck[3], RI[9], dc[3], dk[3];
    mv(bk->R0, wk + AB_CC, ck);
    for (int r = 0; r < 3; r++) ck[r] += bk->at[r];
    const real m = wp[AB_MC], mk = wk[AB_MC], mt = m + mk;
    real *c = wp + AB_CC, *I = wp + AB_IC;
    for (int r = 0; r < 3; r++) {
        const real c_ = RE(mt) > 0.0 ? (m * c[r] + mk * ck[r]) / mt : c[r];
        dc[r] = c[r] - c_;
        dk[r] = ck[r] - c_;
        c[r] = c_;
    }
    add_parallel_axes(m, dc, I);
    add_parallel_axes(mk, dk, I);
    mm(bk->R0, wk + AB_IC, RI);
    for (int r = 0; r < 3; r++)
        for (int q = 0; q < 3; q++)
            I[3 * r + q] += RI[3 * r] * bk->R0[3 * q] + RI[3 * r + 1] * bk->R0[3 * q + 1] + RI[3 * r + 2] * bk->R0[3 * q + 2];
    wp[AB_MC] = mt;
}

/* At bind time (after mbs_derive): each body's composite, leaves first: its own mass, centre of mass and inertia
 * joined by the composites of the bodies welded to it, so a carrier's is that of all it carries. The numbers may
 * depend on parameters, so they are derived here, not compiled. */
void mbs_composites(const MbsModel *m, const real *D, real *work)
{
    for (int i = 0; i < NB(m); i++) {
        const MbsBodyD *bd = mbs_body_row(m, D, i);
        real *wk = work + (size_t)i * m->stride;
        wk[AB_MC] = bd->m;
        memcpy(wk + AB_CC, bd->c, 3 * sizeof(real));
        memcpy(wk + AB_IC, bd->I, 9 * sizeof(real));
    }
    for (int i = NB(m) - 1; i >= 0; i--) {
        const MbsBodyI *bi = mbs_body_i(m, i);
        if (bi->carrier != i && bi->parent >= 0)  /* welded to a body (one welded to the world is carried by none) */
            weld(mbs_body_row(m, D, i), work + (size_t)i * m->stride, work + (size_t)bi->parent * m->stride);
    }
    /* parents first: the joint frame in the parent's carrier's frame, R0c = R0c_p R0, atc = atc_p + R0c_p at, where
     * the parent is welded (a fixed joint: its body frame is its joint frame) */
    for (int i = 0; i < NB(m); i++) {
        const MbsBodyD *bd = mbs_body_row(m, D, i);
        const int p = mbs_body_i(m, i)->parent;
        real *wk = work + (size_t)i * m->stride, *R0c = wk + AB_R0C, *atc = wk + AB_ATC;
        if (p >= 0 && mbs_welded(m, p)) {
            const real *wp = work + (size_t)p * m->stride;
            mm(wp + AB_R0C, bd->R0, R0c);
            mv(wp + AB_R0C, bd->at, atc);
            for (int r = 0; r < 3; r++) atc[r] += wp[AB_ATC + r];
        } else {
            memcpy(R0c, bd->R0, 9 * sizeof(real));
            memcpy(atc, bd->at, 3 * sizeof(real));
        }
    }
}

/* Per carrier: I into AB_IA, P into AB_P, gravity's I (0, g) into AB_F (the force elements add to it). */
static void bias_forces(const MbsEval *e)
{
    const MbsModel *m = e->m;
    const real *g = e->D + m->hdr[H_D_G];
    const int gravity = m->hdr[H_HAS_GRAVITY], elastic = m->hdr[H_FEATURES] & F_ELASTIC;
    (void)elastic;
    for (int i = 0; i < NB(m); i++) {
        if (!carries_itself(m, i)) continue;
        real *wk = mbs_body_work(e, i), *I = wk + AB_IA, *P = wk + AB_P, *F = wk + AB_F;
        const real *w = wk + W_W, *al = wk + W_AL;
        real h[3], v[6], a[6], Iv[6];
        spatial_inertia(wk, I, h);
        cross(w, wk + W_V, a + 3);
        for (int r = 0; r < 3; r++) {
            v[r] = w[r];
            v[3 + r] = wk[W_V + r];
            a[r] = al[r];
            a[3 + r] = wk[W_A + r] - a[3 + r];
        }
        inertia_times(I, h, v, Iv);
        inertia_times(I, h, a, P);
        crossf(v, Iv, a);
        for (int r = 0; r < 6; r++) P[r] += a[r];
        if (gravity) {
            cross(h, g, F);
            for (int r = 0; r < 3; r++) F[3 + r] = I[6 * (3 + r) + 3 + r] * g[r];
        } else
            memset(F, 0, 6 * sizeof(real));
#ifdef MBS_WITH_ELASTIC
        if (!elastic) continue;
        if (mbs_body_i(m, i)->elastic >= 0) mbs_elastic_body(e, i, I, P, F);
        if (!m->flexed[i]) continue;
        /* at or below an elastic body's node S is orthogonal only to first order (seed 004): the gyroscopic moment
         * is S (ω_b × I ω_b), ω_b = Sᵀ ω (tree.c, tree.py), not ω × S I Sᵀ ω as in v ×* I v */
        const real *S = wk + W_S;
        real wb[3], Iwb[3], gb[3], gyr[3], SIwb[3], wx[3];
        mtv(S, w, wb);
        mv(wk + AB_IC, wb, Iwb);
        cross(wb, Iwb, gb);
        mv(S, gb, gyr);
        mv(S, Iwb, SIwb);
        cross(w, SIwb, wx);
        for (int r = 0; r < 3; r++) P[r] += gyr[r] - wx[r];
#endif
    }
}

/* d = o_i − o_parent */
static void offset(const MbsEval *e, const real *wk, int parent, real *d)
{
    const real *op = mbs_body_work(e, parent) + W_O;
    for (int r = 0; r < 3; r++) d[r] = wk[W_O + r] - op[r];
}

/* out += Tᵀ I T: the inertia I = [A B; Bᵀ C] about o + d moved to o, [A − B d̃ − (B d̃)ᵀ − d̃ C d̃, B + d̃ C; ., C],
 * by cross products: row r of B d̃ is b_r × d, column c of d̃ C is d × c_c (C symmetric: its rows), row r of
 * d̃ C d̃ is (row r of d̃ C) × d; A's and C's blocks symmetric, one triangle computed */
static void add_inertia_at(const real *d, const real *I, real *out)
{
    real Bd[9], dC[9], dCd[9];
    for (int r = 0; r < 3; r++) {
        cross(I + 6 * r + 3, d, Bd + 3 * r);               /* b_r × d */
        real dc[3];
        cross(d, I + 6 * (3 + r) + 3, dc);                 /* d × c_r: column r of d̃ C */
        for (int k = 0; k < 3; k++) dC[3 * k + r] = dc[k];
    }
    for (int r = 0; r < 3; r++) cross(dC + 3 * r, d, dCd + 3 * r);
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            const real b = I[6 * r + 3 + c] + dC[3 * r + c];
            out[6 * r + 3 + c] += b;
            out[6 * (3 + c) + r] += b;
            if (c < r) continue;
            const real x = I[6 * r + c] - Bd[3 * r + c] - Bd[3 * c + r] - dCd[3 * r + c];
            out[6 * r + c] += x;
            if (c != r) out[6 * c + r] += x;
            const real y = I[6 * (3 + r) + 3 + c];
            out[6 * (3 + r) + 3 + c] += y;
            if (c != r) out[6 * (3 + c) + 3 + r] += y;
        }
}

/* P, F and the generalized forces τ (into e->q) of the current kinematics. */
static void forces(const MbsEval *e)
{
    bias_forces(e);
    memset(e->q, 0, (size_t)NVEL(e->m) * sizeof(real));
    mbs_applied_forces(e);
}

/* A⁻¹ of a 3 × 3 matrix: its adjugate (the cofactors, transposed) over the determinant */
static void inverse3(const real *A, real *Ai)
{
    const real c[9] = {A[4] * A[8] - A[5] * A[7], A[2] * A[7] - A[1] * A[8], A[1] * A[5] - A[2] * A[4],
                       A[5] * A[6] - A[3] * A[8], A[0] * A[8] - A[2] * A[6], A[2] * A[3] - A[0] * A[5],
                       A[3] * A[7] - A[4] * A[6], A[1] * A[6] - A[0] * A[7], A[0] * A[4] - A[1] * A[3]};
    const real det = A[0] * c[0] + A[1] * c[3] + A[2] * c[6], inv = 1.0 / det;
    for (int k = 0; k < 9; k++) Ai[k] = c[k] * inv;
}

/* A free joint's 6 free coordinates (translation, then rotation) span every motion: S = [0 A; B 0] (ω = A ẏ_rot,
 * v = B ẏ_trans) is invertible, so the joint passes the parent only its force f_J = S⁻ᵀ τ = (A⁻ᵀ τ_rot, B⁻ᵀ τ_trans)
 * (I_A − U D⁻¹ Uᵀ = 0, p + U D⁻¹ u = f_J) and the body's Δa = I_A⁻¹ (f_J − p) needs no D = Sᵀ I_A S: I_A
 * Cholesky-factored in place, Δa into z, A⁻¹ and B⁻¹ into W for ÿ = S⁻¹ (Δa − Δa_p) (Featherstone's floating
 * base). */
static int free_joint(const MbsEval *e, const MbsBodyI *bi, real *wk, const real *p, real *f_J)
{
    real *L = wk + AB_IA, *z = wk + AB_Z, *Ai = wk + AB_W, *Bi = Ai + 9, A[9], B[9], tau[6];
    const real *S = wk + AB_S;
    for (int r = 0; r < 3; r++)
        for (int k = 0; k < 3; k++) { A[3 * r + k] = S[6 * (3 + k) + r]; B[3 * r + k] = S[6 * k + 3 + r]; }
    inverse3(A, Ai);
    inverse3(B, Bi);
    for (int k = 0; k < 6; k++) tau[k] = e->q[bi->vel[k]];
    mtv(Ai, tau + 3, f_J);
    mtv(Bi, tau, f_J + 3);
    if (mbs_cholesky(6, L)) return 1;
    for (int r = 0; r < 6; r++) z[r] = f_J[r] - p[r];
    mbs_cholesky_apply(6, L, z);
    return 0;
}

/* Leaves to root: U = I_A S, D = Sᵀ U = L Lᵀ, u = τ − Sᵀ p, W = U L⁻ᵀ, z = L⁻¹ u; the parent gets
 * I_A − W Wᵀ and p + W z, moved to its origin (the root needs no W: its Δa_p is zero); free joints: free_joint.
 * Returns 1 if some D is not positive definite (then M is not). */
static int articulated_inertias(const MbsEval *e)
{
    const MbsModel *m = e->m;
    for (int i = NB(m) - 1; i >= 0; i--) {
        if (!carries_itself(m, i)) continue;
        const MbsBodyI *bi = mbs_body_i(m, i);
        const int parent = carrier_parent(m, bi);
        real *wk = mbs_body_work(e, i), *IA = wk + AB_IA, *W = wk + AB_W, *L = wk + AB_L, *z = wk + AB_Z;
        const real *S = wk + AB_S;
        const int nv = (int)wk[AB_NV];
        real p[6], d[3], *pw = parent < 0 ? NULL : mbs_body_work(e, parent);
        for (int r = 0; r < 6; r++) p[r] = wk[AB_P + r] - wk[AB_F + r];
#ifdef MBS_WITH_ELASTIC
        if (bi->elastic >= 0 && mbs_elastic_eliminate(e, i, IA, p)) return 1;
#endif
        if (nv == 6) {
            real f_J[6];
            if (free_joint(e, bi, wk, p, f_J)) return 1;
            if (pw) {
                offset(e, wk, parent, d);
                add_force_at(d, f_J, pw + AB_P);
#ifdef MBS_WITH_ELASTIC
                if (bi->node >= 0) mbs_elastic_child(e, i, NULL, f_J);
#endif
            }
            continue;
        }
        if (nv == 1) {  /* most joints: D a number, no factorization loop */
            int c = 0;
            while (bi->vel[c] < 0) c++;
            mat6v(IA, S, W);
            const real D = dot6(S, W);
            if (RE(D) <= 0.0) return 1;  /* NaN passes on as NaN, as mbs_cholesky */
            const real l = r_sqrt(D), il = 1.0 / l;
            L[0] = l;
            z[0] = (e->q[bi->vel[c]] - dot6(S, p)) * il;
            for (int r = 0; r < 6; r++) W[r] *= il;
        } else for (int k = 0, c = 0; k < nv; k++, c++) {
            while (bi->vel[c] < 0) c++;  /* the k-th free coordinate */
            real *Wk = W + 6 * k;
            mat6v(IA, S + 6 * k, Wk);  /* U_k */
            for (int j = 0; j <= k; j++) L[nv * k + j] = dot6(S + 6 * j, Wk);
            z[k] = e->q[bi->vel[c]] - dot6(S + 6 * k, p);
        }
        if (nv > 1) {
            if (mbs_cholesky(nv, L)) return 1;
            for (int k = 0; k < nv; k++) {
                real *Wk = W + 6 * k;
                for (int j = 0; j < k; j++) {
                    if (pw) for (int r = 0; r < 6; r++) Wk[r] -= L[nv * k + j] * W[6 * j + r];
                    z[k] -= L[nv * k + j] * z[j];
                }
                if (pw) for (int r = 0; r < 6; r++) Wk[r] /= L[nv * k + k];
                z[k] /= L[nv * k + k];
            }
        }
        if (!pw) continue;
        for (int k = 0; k < nv; k++)
            for (int r = 0; r < 6; r++) p[r] += W[6 * k + r] * z[k];
        for (int r = 0; r < 6; r++)  /* I_A − W Wᵀ is symmetric: one triangle computed */
            for (int c = r; c < 6; c++) {
                real x = IA[6 * r + c];
                for (int k = 0; k < nv; k++) x -= W[6 * k + r] * W[6 * k + c];
                IA[6 * r + c] = IA[6 * c + r] = x;
            }
        offset(e, wk, parent, d);
        add_inertia_at(d, IA, pw + AB_IA);
        add_force_at(d, p, pw + AB_P);
#ifdef MBS_WITH_ELASTIC
        if (bi->node >= 0) mbs_elastic_child(e, i, IA, p);
#endif
    }
    return 0;
}

/* Δa_p: the parent's Δa moved to body i's origin, (α, a − d × α), and at an elastic parent's node its modal part
 * (the parent's q̈ in ydd); zero at the root */
static void parent_acceleration(const MbsEval *e, int i, int parent, const real *ydd, real *acc)
{
    if (parent < 0) {
        memset(acc, 0, 6 * sizeof(real));
        return;
    }
    const real *pa = mbs_body_work(e, parent) + AB_ACC;
    real d[3], dxa[3];
    offset(e, mbs_body_work(e, i), parent, d);
    cross(d, pa, dxa);
    for (int r = 0; r < 3; r++) { acc[r] = pa[r]; acc[3 + r] = pa[3 + r] - dxa[r]; }
#ifdef MBS_WITH_ELASTIC
    if (mbs_body_i(e->m, i)->node >= 0) mbs_elastic_node_acceleration(e, i, ydd, acc);
#else
    (void)ydd;
#endif
}

/* Root to leaves: ÿ = L⁻ᵀ (z − Wᵀ Δa_p) into e->xdot, Δa = Δa_p + S ÿ (Δa_p: the parent's, moved to o). */
static void accelerations(const MbsEval *e)
{
    const MbsModel *m = e->m;
    real *ydd = e->xdot + NPOS(m);
    for (int i = 0; i < NB(m); i++) {
        if (!carries_itself(m, i)) continue;
        const MbsBodyI *bi = mbs_body_i(m, i);
        const int parent = carrier_parent(m, bi);
        real *wk = mbs_body_work(e, i), *acc = wk + AB_ACC, x[6];
        const real *L = wk + AB_L, *S = wk + AB_S, *ap = acc;
        const int nv = (int)wk[AB_NV];
        parent_acceleration(e, i, parent, ydd, acc);
        if (nv == 6) {  /* free_joint: Δa = z, ÿ = S⁻¹ (Δa − Δa_p) */
            real da[6];
            for (int r = 0; r < 6; r++) { da[r] = wk[AB_Z + r] - acc[r]; acc[r] = wk[AB_Z + r]; }
            mv(wk + AB_W + 9, da + 3, x);
            mv(wk + AB_W, da, x + 3);
        } else for (int k = 0; k < nv; k++) x[k] = wk[AB_Z + k] - (parent < 0 ? 0.0 : dot6(wk + AB_W + 6 * k, ap));
        for (int k = nv - 1; nv < 6 && k >= 0; k--) {
            for (int j = k + 1; j < nv; j++) x[k] -= L[nv * j + k] * x[j];
            x[k] /= L[nv * k + k];
            for (int r = 0; r < 6; r++) acc[r] += S[6 * k + r] * x[k];
        }
        for (int k = 0, c = 0; k < nv; k++, c++) {
            while (bi->vel[c] < 0) c++;
            ydd[bi->vel[c]] = x[k];
        }
#ifdef MBS_WITH_ELASTIC
        if (bi->elastic >= 0) mbs_elastic_accelerations(e, i, acc, ydd);
#endif
    }
}

int mbs_aba(const MbsEval *e)
{
    forces(e);
    if (articulated_inertias(e)) return MBS_F_SINGULAR;
    accelerations(e);
    return 0;
}

#ifdef MBS_WITH_ELASTIC
/* Inverse dynamics over the carriers (the inspection of elastic scenes): out += Sᵀ Σ f over each subtree and the
 * modal rows, with per body f = I Δa (+ U q̈) for the accelerations ydd (what 0: M ydd), f = P (1: k) or F (2: q). */
static void inverse(const MbsEval *e, const real *ydd, int what, real *out)
{
    const MbsModel *m = e->m;
    for (int i = 0; i < NB(m); i++) {  /* root to leaves: Δa and each body's own f */
        if (!carries_itself(m, i)) continue;
        const MbsBodyI *bi = mbs_body_i(m, i);
        const int parent = carrier_parent(m, bi);
        real *wk = mbs_body_work(e, i), *acc = wk + AB_ACC, *f = wk + AB_W;
        if (what == 0) {
            parent_acceleration(e, i, parent, ydd, acc);
            for (int k = 0, c = 0; k < (int)wk[AB_NV]; k++, c++) {
                while (bi->vel[c] < 0) c++;
                for (int r = 0; r < 6; r++) acc[r] += wk[AB_S + 6 * k + r] * ydd[bi->vel[c]];
            }
            mat6v(wk + AB_IA, acc, f);
        } else {
            memset(acc, 0, 6 * sizeof(real));
            memcpy(f, wk + (what == 1 ? AB_P : AB_F), 6 * sizeof(real));
        }
        if (bi->elastic >= 0) mbs_elastic_inverse(e, i, acc, ydd, what, f);
    }
    for (int i = NB(m) - 1; i >= 0; i--) {  /* leaves to root: Sᵀ f, f to the parent */
        if (!carries_itself(m, i)) continue;
        const MbsBodyI *bi = mbs_body_i(m, i);
        const int parent = carrier_parent(m, bi);
        const real *wk = mbs_body_work(e, i), *f = wk + AB_W;
        for (int k = 0, c = 0; k < (int)wk[AB_NV]; k++, c++) {
            while (bi->vel[c] < 0) c++;
            out[bi->vel[c]] += dot6(wk + AB_S + 6 * k, f);
        }
        if (bi->elastic >= 0) mbs_elastic_modal_force(e, i, out);
        if (parent < 0) continue;
        real d[3];
        offset(e, wk, parent, d);
        add_force_at(d, f, mbs_body_work(e, parent) + AB_W);
        if (bi->node >= 0) mbs_elastic_child(e, i, NULL, f);
    }
}

/* M by columns (M e_j), k and q of an elastic scene: O(n·N), for inspection */
static void equations_elastic(const MbsEval *e)
{
    const int f = NVEL(e->m);
    real *ydd = e->xdot + NPOS(e->m);
    forces(e);
    memset(e->M, 0, (size_t)f * f * sizeof(real));
    memset(e->k, 0, (size_t)f * sizeof(real));
    memset(ydd, 0, (size_t)f * sizeof(real));
    for (int j = 0; j < f; j++) {  /* M is symmetric: column j into row j */
        ydd[j] = 1.0;
        inverse(e, ydd, 0, e->M + (size_t)j * f);
        ydd[j] = 0.0;
    }
    inverse(e, ydd, 1, e->k);
    inverse(e, ydd, 2, e->q);
}
#endif

/* M (composite inertias I_C = Σ I over the subtree: M_ab = S_bᵀ I_C S_a for b on a's path to the root),
 * k = Sᵀ Σ P and q = τ + Sᵀ Σ F over the subtree. O(n·depth): for inspection, not per step. */
void mbs_crba_rnea(const MbsEval *e)
{
    const MbsModel *m = e->m;
    const int f = NVEL(m);
#ifdef MBS_WITH_ELASTIC
    if (m->hdr[H_FEATURES] & F_ELASTIC) { equations_elastic(e); return; }
#endif
    forces(e);
    memset(e->M, 0, (size_t)f * f * sizeof(real));
    memset(e->k, 0, (size_t)f * sizeof(real));
    for (int i = NB(m) - 1; i >= 0; i--) {
        if (!carries_itself(m, i)) continue;
        const MbsBodyI *bi = mbs_body_i(m, i);
        const int parent = carrier_parent(m, bi);
        real *wk = mbs_body_work(e, i);
        for (int k = 0, c = 0; k < (int)wk[AB_NV]; k++, c++) {
            while (bi->vel[c] < 0) c++;
            const real *s = wk + AB_S + 6 * k;
            real Fa[6];
            e->k[bi->vel[c]] = dot6(s, wk + AB_P);
            e->q[bi->vel[c]] += dot6(s, wk + AB_F);
            mat6v(wk + AB_IA, s, Fa);
            for (int j = i;;) {  /* Fa moved to each ancestor's origin on the way up */
                const MbsBodyI *bj = mbs_body_i(m, j);
                const real *wj = mbs_body_work(e, j);
                for (int l = 0, d = 0; l < (int)wj[AB_NV]; l++, d++) {
                    while (bj->vel[d] < 0) d++;
                    e->M[(size_t)bj->vel[d] * f + bi->vel[c]] = e->M[(size_t)bi->vel[c] * f + bj->vel[d]] =
                        dot6(wj + AB_S + 6 * l, Fa);
                }
                const int pj = carrier_parent(m, bj);
                if (pj < 0) break;
                real d[3], Fj[6] = {0, 0, 0, 0, 0, 0};
                offset(e, wj, pj, d);
                add_force_at(d, Fa, Fj);
                memcpy(Fa, Fj, sizeof Fj);
                j = pj;
            }
        }
        if (parent < 0) continue;
        real d[3], *pw = mbs_body_work(e, parent);
        offset(e, wk, parent, d);
        add_inertia_at(d, wk + AB_IA, pw + AB_IA);
        add_force_at(d, wk + AB_P, pw + AB_P);
        add_force_at(d, wk + AB_F, pw + AB_F);
    }
}
