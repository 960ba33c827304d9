/* Elastic bodies in the tree (seed 004, floating frame of reference): the same equations as bodies/ffrf.py and
 * bodies/tree.py, on the mass invariants that compiler/elastic_tables.py computed at compile time.
 *
 *   z_II = J_z ẏ,  J_z = [Sᵀ J_T; Sᵀ J_R; E_q]   (R components: v_R, ω_R, q̇)
 *   M += J_zᵀ M_zz(q) J_z,   k += J_zᵀ (M_zz z̄ + h(q, q̇, ω)),   q += J_zᵀ (f_g + f_e),   z̄ = [Sᵀ ā; Sᵀ ᾱ; 0]
 *   node P: r_IP = r_IR + S (R_RP + Φ_P q),   S_IP = S (E + (Ψ_P q)~)
 *
 * J_z is never formed: its frame rows act on the few columns [lo, hi) the reference frame moves with, its
 * elastic rows are the identity on the body's own q̇ columns. The q-dependent invariants cost one pass over
 * B (B·q) and one over G (G·q and G·q̇ together); everything else is O(n).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "mbs_model.h"
#include "mbs_vec3.h"

#define MAX_MODES 4096

/* one body's invariants and node data inside S_ELASTIC_D */
typedef struct {
    int n, nodes, q0, qd0, stiff;
    const double *m, *S0, *S_RR, *J_sum, *C_t, *A, *C_r0, *JPsi, *G, *B, *M_ee, *K, *D, *K_a, *K_w, *node;
} Inv;

/* an elastic body's int row by name, checked against MBS_ELASTIC_I (one number per field) */
typedef struct { int32_t body, n, nodes, q, qd, stiff, d; } ElasticRow;
#define ELASTIC_FIELD(member, FIELD) MBS_VIEW_CHECK(elastic_##member, offsetof(ElasticRow, member) == sizeof(int32_t) * FIELD)
ELASTIC_FIELD(body, EI_BODY); ELASTIC_FIELD(n, EI_N); ELASTIC_FIELD(nodes, EI_NODES); ELASTIC_FIELD(q, EI_Q);
ELASTIC_FIELD(qd, EI_QD); ELASTIC_FIELD(stiff, EI_STIFF); ELASTIC_FIELD(d, EI_D);
MBS_VIEW_CHECK(elastic_size, sizeof(ElasticRow) == sizeof(int32_t) * EI);
static const ElasticRow *row(const MbsModel *m, int e) { return (const ElasticRow *)(m->elastic_i + EH + EI * e); }

#define ED_SIZE(code, size, per_mode, per_mode2, stiff) {size, per_mode, per_mode2, stiff},
static const int ed_size[ED_N][4] = {MBS_ELASTIC_D(ED_SIZE)};  /* the arrays' sizes c + b n + a n², stiffening only */

static Inv inv_of(const MbsModel *m, int e)
{
    const ElasticRow *r = row(m, e);
    const size_t n = (size_t)r->n;
    const double *p = m->elastic_d + r->d, *a[ED_N];
    for (int k = 0; k < ED_N; k++) {  /* in MBS_ELASTIC_D's order; the stiffening pair only when the body has it */
        const int absent = !r->stiff && ed_size[k][3];
        a[k] = absent ? NULL : p;
        if (!absent) p += ed_size[k][0] + ed_size[k][1] * n + ed_size[k][2] * n * n;
    }
    Inv v = {.n = r->n, .nodes = r->nodes, .q0 = r->q, .qd0 = r->qd, .stiff = r->stiff,
             .m = a[ED_M], .S0 = a[ED_S0], .S_RR = a[ED_S_RR], .J_sum = a[ED_J_SUM], .C_t = a[ED_C_T], .A = a[ED_A],
             .C_r0 = a[ED_C_R0], .JPsi = a[ED_JPSI], .G = a[ED_G], .B = a[ED_B], .M_ee = a[ED_M_EE], .K = a[ED_K],
             .D = a[ED_D], .K_a = a[ED_K_A], .K_w = a[ED_K_W], .node = p};
    return v;
}
/* node P: R_RP (3), Φ_P (3×n), Ψ_P (3×n) */
static const double *node_R(const Inv *v, int P) { return v->node + (size_t)P * (3 + 6 * v->n); }
static const double *node_Phi(const Inv *v, int P) { return node_R(v, P) + 3; }
static const double *node_Psi(const Inv *v, int P) { return node_R(v, P) + 3 + 3 * v->n; }

/* ---- workspace: per elastic body its frame columns [lo, hi) before widening; then scratch for one body ---- */
static int max_modes(const MbsModel *m)
{
    int nmax = 0;
    for (int e = 0; e < m->elastic_i[EH_NE]; e++) if (row(m, e)->n > nmax) nmax = row(m, e)->n;
    return nmax;
}

/* the scratch of one body's equations (body_terms, project): its numbers from the start of the workspace */
static size_t scratch_size(const MbsModel *m)
{
    const size_t n = (size_t)max_modes(m), f = (size_t)NVEL(m);
    return 2 * (size_t)m->elastic_i[EH_NE] + 6 * f + 9 * n * n + 24 * n + 64;
}

size_t mbs_elastic_work_size(const MbsModel *m)
{
    return (scratch_size(m) + m->elastic_block[m->elastic_i[EH_NE]]) * sizeof(real);
}

/* Per elastic body on the recursive path (dynamics.c), after the scratch: its coupling U = Ŝ M_re (6 × n, column
 * after column; in the articulated pass W = U L⁻ᵀ), M_ee with what its children add (then its factor L), its k and q
 * parts k_e, q_e and the modal bias β (then z = L⁻¹ β). */
typedef struct { real *U, *L, *k_e, *q_e, *beta; } Block;
static Block block(const MbsEval *e, int el)
{
    const MbsModel *m = e->m;
    real *p = (real *)e->elastic_work + scratch_size(m) + m->elastic_block[el];
    const size_t n = (size_t)row(m, el)->n;
    Block b = {p, p + 6 * n, p + 6 * n + n * n, p + 7 * n + n * n, p + 8 * n + n * n};
    return b;
}

/* ---- small helpers (row-major 3×3, 3-vectors) ---- */
static real dot(const real *a, const real *b, int n)
{
    real s = 0.0;
    for (int k = 0; k < n; k++) s += a[k] * b[k];
    return s;
}
static real dotd(const double *a, const real *b, int n)  /* the body's data · the state */
{
    real s = 0.0;
    for (int k = 0; k < n; k++) s += a[k] * b[k];
    return s;
}
/* y = A x for A (3×n) */
static void mv3n(const double *A, const real *x, int n, real *y)
{
    for (int r = 0; r < 3; r++) y[r] = dotd(A + r * n, x, n);
}
static void matvec(const double *A, const real *x, int n, real *y)  /* n×n */
{
    for (int r = 0; r < n; r++) y[r] = dotd(A + (size_t)r * n, x, n);
}

/* ---- kinematics ---- */
void mbs_elastic_kinematics(const MbsEval *e, int body)
{
    const MbsModel *m = e->m;
    const int el = mbs_body_i(m, body)->elastic;
    const ElasticRow *r = row(m, el);
    real *wk = mbs_body_work(e, body), *cols = (real *)e->elastic_work + 2 * el;
    cols[0] = wk[W_LO];  /* the reference frame's own columns, for J_z */
    cols[1] = wk[W_HI];
    if (r->qd < RE(wk[W_LO])) wk[W_LO] = r->qd;
    if (r->qd + r->n > RE(wk[W_HI])) wk[W_HI] = r->qd + r->n;
}

/* Node P of elastic body i: ρ = S (R_RP + Φ_P q) (world), its elastic velocity u = S Φ_P q̇, and the node's
 * position, velocity, bias acceleration (a may be NULL) and J_T (3 × f over the body's columns; may be NULL). */
static void node_motion(const MbsEval *e, int i, int P, real *rho, real *r, real *v, real *a, real *J_T)
{
    const MbsModel *m = e->m;
    const int f = NVEL(m);
    const Inv in = inv_of(m, mbs_body_i(m, i)->elastic);
    const real *wk = mbs_body_work(e, i), *S = wk + W_S, *w = wk + W_W;
    const real *q = e->x + in.q0, *qd = e->x + NPOS(m) + in.qd0;
    const double *Phi = node_Phi(&in, P), *R = node_R(&in, P);
    real rR[3], uR[3], u[3], wxr[3];
    mv3n(Phi, q, in.n, rR);
    mv3n(Phi, qd, in.n, uR);
    for (int k = 0; k < 3; k++) rR[k] += R[k];
    mv(S, rR, rho);
    mv(S, uR, u);
    cross(w, rho, wxr);
    for (int k = 0; k < 3; k++) { r[k] = wk[W_O + k] + rho[k]; v[k] = wk[W_V + k] + wxr[k] + u[k]; }
    if (a) {
        real axr[3], wwxr[3], wxu[3];
        cross(wk + W_AL, rho, axr);
        cross(w, wxr, wwxr);
        cross(w, u, wxu);
        for (int k = 0; k < 3; k++) a[k] = wk[W_A + k] + axr[k] + wwxr[k] + 2.0 * wxu[k];
    }
    if (!J_T) return;
    const real *JR = wk + W_J, *JT = JR + 3 * f;
    for (int c = (int)wk[W_LO]; c < (int)wk[W_HI]; c++) {  /* J_T − ρ̃ J_R */
        real jr[3] = {JR[c], JR[f + c], JR[2 * f + c]}, x[3];
        cross(rho, jr, x);
        for (int k = 0; k < 3; k++) J_T[k * f + c] = JT[k * f + c] - x[k];
    }
    for (int c = 0; c < in.n; c++) {                         /* + S Φ_P on the elastic columns */
        real ph[3] = {Phi[c], Phi[in.n + c], Phi[2 * in.n + c]}, s[3];
        mv(S, ph, s);
        for (int k = 0; k < 3; k++) J_T[k * f + in.qd0 + c] += s[k];
    }
}

void mbs_elastic_node_point(const MbsEval *e, int body, int node, real *r, real *v, real *J_T)
{
    real rho[3];
    node_motion(e, body, node, rho, r, v, NULL, J_T);
}

/* J_R + S Ψ_P on the elastic columns (3 × f over the body's columns) */
void mbs_elastic_node_J_R(const MbsEval *e, int body, int node, real *J_R)
{
    const MbsModel *m = e->m;
    const int f = NVEL(m);
    const Inv in = inv_of(m, mbs_body_i(m, body)->elastic);
    const real *wk = mbs_body_work(e, body), *S = wk + W_S;
    const double *Psi = node_Psi(&in, node);
    for (int k = 0; k < 3; k++)
        for (int c = (int)wk[W_LO]; c < (int)wk[W_HI]; c++) J_R[k * f + c] = wk[W_J + k * f + c];
    for (int c = 0; c < in.n; c++) {
        real ps[3] = {Psi[c], Psi[in.n + c], Psi[2 * in.n + c]}, s[3];
        mv(S, ps, s);
        for (int k = 0; k < 3; k++) J_R[k * f + in.qd0 + c] += s[k];
    }
}

/* The frame a child joint sits on at node P of its elastic parent (tree.py: node_frame). J_R, J_T: full 3 × f
 * (NULL on the recursive path). */
void mbs_elastic_node_frame(const MbsEval *e, int child, real *S_P, real *r, real *w, real *v, real *a,
                            real *al, real *J_R, real *J_T)
{
    const MbsModel *m = e->m;
    const int f = NVEL(m), i = mbs_body_i(m, child)->parent, P = mbs_body_i(m, child)->node;
    const Inv in = inv_of(m, mbs_body_i(m, i)->elastic);
    const real *wk = mbs_body_work(e, i), *S = wk + W_S, *wp = wk + W_W;
    const double *Psi = node_Psi(&in, P);
    const real *q = e->x + in.q0, *qd = e->x + NPOS(m) + in.qd0;
    real rho[3], th[3], thd[3], w_rel[3], E_th[9];
    if (J_T) memcpy(J_T, wk + W_J + 3 * f, 3 * (size_t)f * sizeof(real));
    node_motion(e, i, P, rho, r, v, a, J_T);
    mv3n(Psi, q, in.n, th);
    mv3n(Psi, qd, in.n, thd);
    /* S_P = S (E + θ̃) */
    const real Et[9] = {1, -th[2], th[1], th[2], 1, -th[0], -th[1], th[0], 1};
    memcpy(E_th, Et, sizeof Et);
    for (int r_ = 0; r_ < 3; r_++)
        for (int c = 0; c < 3; c++)
            S_P[3 * r_ + c] = S[3 * r_] * E_th[c] + S[3 * r_ + 1] * E_th[3 + c] + S[3 * r_ + 2] * E_th[6 + c];
    mv(S, thd, w_rel);
    real wxw[3];
    cross(wp, w_rel, wxw);
    for (int k = 0; k < 3; k++) { w[k] = wp[k] + w_rel[k]; al[k] = wk[W_AL + k] + wxw[k]; }
    if (!J_R) return;  /* the recursive path: no Jacobians */
    memcpy(J_R, wk + W_J, 3 * (size_t)f * sizeof(real));
    for (int c = 0; c < in.n; c++) {
        real ps[3] = {Psi[c], Psi[in.n + c], Psi[2 * in.n + c]}, s[3];
        mv(S, ps, s);
        for (int k = 0; k < 3; k++) J_R[k * f + in.qd0 + c] += s[k];
    }
}

/* ---- equations of one elastic body (ffrf.py: mass_matrix, quadratic_forces, gravity_forces, elastic_forces)
 * in R components (v_R, ω_R, q̈): M_zz = [M_rr M_re; M_er M_ee] with M_rr = [m E, −(m c)~; (m c)~, I] and
 * M_re's column k [C_t e_k − (K_a q)_k e_x; C_r e_k]; k's rows [kr; ke] = M_zz z̄ + h, q's [gr; qe]. Then
 * projected with J_z into M, k, q (dense path) or as the body's blocks in world axes (recursive path) ---- */
typedef struct {
    Inv in;
    double mass;
    real mc[3], I[9], kr[6], gr[6];
    real *Cr, *Kaq, *ke, *qe;  /* C_r (3 × n), K_a q, ke, qe (n): in the scratch */
} Terms;

static void body_terms(const MbsEval *e, int el, Terms *T)
{
    const MbsModel *m = e->m;
    const int f = NVEL(m), body = row(m, el)->body;
    const Inv in = T->in = inv_of(m, el);
    const int n = in.n;
    const real *wk = mbs_body_work(e, body), *S = wk + W_S;
    const real *q = e->x + in.q0, *qd = e->x + NPOS(m) + in.qd0;
    real *Jf = (real *)e->elastic_work + 2 * m->elastic_i[EH_NE];  /* 6 × f: [Sᵀ J_T; Sᵀ J_R] (project) */
    real *Bq = Jf + 6 * f, *Cr = Bq + 9 * (size_t)n * n, *Gqd = Cr + 3 * n, *ke = Gqd + 3 * n, *qe = ke + n;
    real *Kaq = qe + n, *Kq = Kaq + n, *tmp = Kq + n;
    real *mc = T->mc, *I = T->I, *kr = T->kr, *gr = T->gr;
    T->Cr = Cr; T->Kaq = Kaq; T->ke = ke; T->qe = qe;
    real w[3], aR[3], alR[3], Ctqd[3], Aq[9], Aqd[9], Ssym[9], W[9];
    const double mass = T->mass = in.m[0];
    mtv(S, wk + W_W, w);
    mtv(S, wk + W_A, aR);
    mtv(S, wk + W_AL, alR);

    /* first moment m·c = S0 + C_t q (− ½ qᵀK_a q e_x), C_t q̇ */
    mv3n(in.C_t, q, n, mc);
    mv3n(in.C_t, qd, n, Ctqd);
    for (int k = 0; k < 3; k++) mc[k] += in.S0[k];
    if (in.stiff) { matvec(in.K_a, q, n, Kaq); mc[0] -= 0.5 * dot(q, Kaq, n); }
    else memset(Kaq, 0, (size_t)n * sizeof(real));

    /* Σ m u uᵀ = S_RR + Aq + Aqᵀ + B:qq and W = Σ m u (Φq̇)ᵀ = A q̇ + B:q q̇ (Bq_ijl = Σ_k B_ijkl q_k) */
    for (int ij = 0; ij < 9; ij++) {
        const double *Aij = in.A + ij * n, *Bij = in.B + (size_t)ij * n * n;
        real *bq = Bq + ij * n;
        Aq[ij] = dotd(Aij, q, n);
        Aqd[ij] = dotd(Aij, qd, n);
        for (int l = 0; l < n; l++) bq[l] = dotd(Bij + (size_t)l * n, q, n);
        Ssym[ij] = dot(bq, q, n);
        W[ij] = Aqd[ij] + dot(bq, qd, n);
    }
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) Ssym[3 * i + j] += in.S_RR[3 * i + j] + Aq[3 * i + j] + Aq[3 * j + i];
    const real trS = Ssym[0] + Ssym[4] + Ssym[8], trW = W[0] + W[4] + W[8];
    for (int k = 0; k < 9; k++) I[k] = (k % 4 == 0 ? trS : 0.0) - Ssym[k] + in.J_sum[k];

    /* C_r = C_r0 + G q (3 × n) and Gqd_mk = Σ_l G_mkl q̇_l, in one pass over G */
    memset(Gqd, 0, 3 * (size_t)n * sizeof(real));
    for (int i = 0; i < 3; i++)
        for (int l = 0; l < n; l++) {
            const double *g = in.G + ((size_t)i * n + l) * n;
            real *acc = Gqd + i * n;
            Cr[i * n + l] = in.C_r0[i * n + l] + dotd(g, q, n);
            for (int k = 0; k < n; k++) acc[k] += qd[l] * g[k];
        }

    /* frame rows: kr = M_rr z̄_r + h_r; gravity gr */
    real t1[3], t2[3], t3[3];
    cross(w, mc, t1);
    cross(w, t1, t2);                 /* ω̃ω̃ m·c */
    cross(w, Ctqd, t3);
    cross(mc, alR, t1);
    for (int k = 0; k < 3; k++) kr[k] = mass * aR[k] - t1[k] + t2[k] + 2.0 * t3[k];
    real Iw[3], Ial[3], Jq[3], mca[3];
    mv(I, w, Iw);
    mv(I, alR, Ial);
    mv3n(in.JPsi, qd, n, Jq);
    for (int k = 0; k < 3; k++) Jq[k] += Iw[k];
    cross(w, Jq, t1);                 /* ω × (I ω + JΨ q̇) */
    cross(mc, aR, mca);
    for (int k = 0; k < 3; k++)
        kr[3 + k] = mca[k] + Ial[k] + t1[k] + 2.0 * (w[k] * trW - (W[k] * w[0] + W[3 + k] * w[1] + W[6 + k] * w[2]));

    /* elastic rows: ke = M_er z̄_r + h_e */
    const real ww = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
    for (int k = 0; k < n; k++) {
        /* Σ_ij (ω̃ω̃)_ij (A_ijk + Bq_ijk) = ωᵀ X ω − |ω|² tr X */
        real X[9];
        for (int ij = 0; ij < 9; ij++) X[ij] = in.A[ij * n + k] + Bq[ij * n + k];
        real Xw[3];
        mv(X, w, Xw);
        ke[k] = dot(w, Xw, 3) - ww * (X[0] + X[4] + X[8])
              - 2.0 * (w[0] * Gqd[k] + w[1] * Gqd[n + k] + w[2] * Gqd[2 * n + k])
              + in.C_t[k] * aR[0] + in.C_t[n + k] * aR[1] + in.C_t[2 * n + k] * aR[2]
              + Cr[k] * alR[0] + Cr[n + k] * alR[1] + Cr[2 * n + k] * alR[2];
    }

    /* applied: gravity (frame and q rows) and elastic forces −K q − D q̇ */
    matvec(in.K, q, n, Kq);
    matvec(in.D, qd, n, tmp);
    real gR[3] = {0, 0, 0};
    if (m->hdr[H_HAS_GRAVITY]) mtv(S, e->D + m->hdr[H_D_G], gR);
    cross(mc, gR, t1);
    for (int k = 0; k < 3; k++) { gr[k] = mass * gR[k]; gr[3 + k] = t1[k]; }
    for (int k = 0; k < n; k++)
        qe[k] = in.C_t[k] * gR[0] + in.C_t[n + k] * gR[1] + in.C_t[2 * n + k] * gR[2] - Kq[k] - tmp[k];

    if (in.stiff) {  /* dynamic stiffening (ffrf.py): a_x / g_x and centrifugal parts */
        real *Kaqd = tmp;
        matvec(in.K_a, qd, n, Kaqd);
        real wx_ex[3] = {0, w[2], -w[1]};             /* ω × e_x */
        const real c = 2.0 * dot(q, Kaqd, n);
        for (int k = 0; k < 3; k++) kr[k] -= c * wx_ex[k];
        kr[0] -= dot(qd, Kaqd, n);
        matvec(in.K_w, q, n, Kaqd);
        const real wyz = w[1] * w[1] + w[2] * w[2];
        for (int k = 0; k < n; k++) {
            ke[k] += wyz * Kaqd[k] - Kaq[k] * aR[0];
            qe[k] -= gR[0] * Kaq[k];
        }
    }

}

/* the dense path: M += J_zᵀ M_zz J_z, k += J_zᵀ [kr; ke], q += J_zᵀ [gr; qe] */
static void project(const MbsEval *e, int el, const Terms *T)
{
    const MbsModel *m = e->m;
    const int f = NVEL(m), n = T->in.n, e0 = T->in.qd0;
    const Inv in = T->in;
    const real *wk = mbs_body_work(e, row(m, el)->body), *S = wk + W_S, *JR = wk + W_J, *JT = JR + 3 * f;
    const real *cols = (real *)e->elastic_work + 2 * el, *mc = T->mc, *I = T->I, *kr = T->kr, *gr = T->gr;
    const real *Cr = T->Cr, *Kaq = T->Kaq, *ke = T->ke, *qe = T->qe;
    const int lo = (int)cols[0], hi = (int)cols[1];
    const double mass = T->mass;
    real *Jf = (real *)e->elastic_work + 2 * m->elastic_i[EH_NE];
    real *M = e->M, *kk = e->k, *qq = e->q;
    for (int c = lo; c < hi; c++) {
        real jt[3] = {JT[c], JT[f + c], JT[2 * f + c]}, jr[3] = {JR[c], JR[f + c], JR[2 * f + c]};
        mtv(S, jt, Jf + 6 * c);
        mtv(S, jr, Jf + 6 * c + 3);
    }
    real Mrr[36];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            Mrr[6 * r + c] = r == c ? mass : 0.0;
            Mrr[6 * (3 + r) + 3 + c] = I[3 * r + c];
        }
    /* −m·c~ (upper right), m·c~ (lower left) */
    const real mx[9] = {0, -mc[2], mc[1], mc[2], 0, -mc[0], -mc[1], mc[0], 0};
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) { Mrr[6 * r + 3 + c] = -mx[3 * r + c]; Mrr[6 * (3 + r) + c] = mx[3 * r + c]; }
    for (int c = lo; c < hi; c++) {
        const real *jc = Jf + 6 * c;
        real MJ[6];
        for (int r = 0; r < 6; r++) MJ[r] = dot(Mrr + 6 * r, jc, 6);
        for (int c2 = lo; c2 < hi; c2++) M[(size_t)c2 * f + c] += dot(Jf + 6 * c2, MJ, 6);
        kk[c] += dot(jc, kr, 6);
        qq[c] += dot(jc, gr, 6);
        for (int k = 0; k < n; k++) {
            /* M_re column k: [C_t e_k − (K_a q)_k e_x; C_r e_k] */
            real s = jc[0] * (in.C_t[k] - Kaq[k]) + jc[1] * in.C_t[n + k] + jc[2] * in.C_t[2 * n + k]
                     + jc[3] * Cr[k] + jc[4] * Cr[n + k] + jc[5] * Cr[2 * n + k];
            M[(size_t)c * f + e0 + k] += s;
            M[(size_t)(e0 + k) * f + c] += s;
        }
    }
    for (int k = 0; k < n; k++) {
        for (int l = 0; l < n; l++) M[(size_t)(e0 + k) * f + e0 + l] += in.M_ee[(size_t)k * n + l];
        kk[e0 + k] += ke[k];
        qq[e0 + k] += qe[k];
    }
}

void mbs_elastic_equations(const MbsEval *e)
{
    for (int el = 0; el < e->m->elastic_i[EH_NE]; el++) {
        Terms T;
        body_terms(e, el, &T);
        project(e, el, &T);
    }
}

/* ---- the recursive path (dynamics.c): an elastic body in the articulated-body algorithm, a node with n more
 * coordinates. In world axes about its origin o, (ω, v) order, Ŝ = diag(S, S):
 *
 *   f = I_e Δa + U q̈ + P − F,   Uᵀ Δa + M_ee q̈ + β = 0,
 *   I_e = Ŝ M_rr Ŝᵀ, U = Ŝ M_re, P = Ŝ kr, F = Ŝ gr, β = ke − qe − τ (τ: inputs and forces at its nodes on q).
 *
 * A child c at node P moves with Δa_c = X Δa + Y q̈ (X: the shift from o to o_c; Y = [S Ψ_P; S Φ_P − d × S Ψ_P],
 * d = o_c − r_P) and adds Xᵀ I_c Y to U, Yᵀ I_c Y to M_ee, Yᵀ p_c to β. Eliminating q̈ leaves its joint the frame's
 * I_e − U M_ee⁻¹ Uᵀ and p − U M_ee⁻¹ β; on the way down q̈ = −M_ee⁻¹ (β + Uᵀ Δa). Ŝ, not a rotation, because at a
 * node S is orthogonal only to first order (seed 004): the projection equals the dense path's J_zᵀ M_zz J_z. ---- */

static real *scratch(const MbsEval *e) { return (real *)e->elastic_work + 2 * e->m->elastic_i[EH_NE] + 6 * NVEL(e->m); }

static void sandwich(const real *S, const real *X, real *out)  /* S X Sᵀ for a symmetric X */
{
    real SX[9];
    mm(S, X, SX);
    for (int r = 0; r < 3; r++)
        for (int c = r; c < 3; c++)
            out[3 * r + c] = out[3 * c + r] = SX[3 * r] * S[3 * c] + SX[3 * r + 1] * S[3 * c + 1] + SX[3 * r + 2] * S[3 * c + 2];
}

/* the body's I_e, P, F added to IA (6 × 6), P, F; U, M_ee, ke, qe and β = ke − qe into its block */
void mbs_elastic_body(const MbsEval *e, int body, real *IA, real *P, real *F)
{
    const int el = mbs_body_i(e->m, body)->elastic;
    Terms T;
    body_terms(e, el, &T);
    const Inv in = T.in;
    const int n = in.n;
    const real *S = mbs_body_work(e, body) + W_S;
    const Block b = block(e, el);
    /* S I Sᵀ, S (m c)~ Sᵀ = (cof(S) m c)~ (cof: the cofactors; S itself for a rotation), m S Sᵀ */
    const real *mc = T.mc, cof[9] = {S[4] * S[8] - S[5] * S[7], S[5] * S[6] - S[3] * S[8], S[3] * S[7] - S[4] * S[6],
                                     S[2] * S[7] - S[1] * S[8], S[0] * S[8] - S[2] * S[6], S[1] * S[6] - S[0] * S[7],
                                     S[1] * S[5] - S[2] * S[4], S[2] * S[3] - S[0] * S[5], S[0] * S[4] - S[1] * S[3]};
    real A[9], h[3];
    sandwich(S, T.I, A);
    mv(cof, mc, h);
    const real B[9] = {0, -h[2], h[1], h[2], 0, -h[0], -h[1], h[0], 0};
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            IA[6 * r + c] += A[3 * r + c];
            IA[6 * r + 3 + c] += B[3 * r + c];
            IA[6 * (3 + r) + c] -= B[3 * r + c];
            IA[6 * (3 + r) + 3 + c] += T.mass * (S[3 * r] * S[3 * c] + S[3 * r + 1] * S[3 * c + 1] + S[3 * r + 2] * S[3 * c + 2]);
        }
    real x[3];
    mv(S, T.kr + 3, x); for (int r = 0; r < 3; r++) P[r] += x[r];
    mv(S, T.kr, x);     for (int r = 0; r < 3; r++) P[3 + r] += x[r];
    mv(S, T.gr + 3, x); for (int r = 0; r < 3; r++) F[r] += x[r];
    mv(S, T.gr, x);     for (int r = 0; r < 3; r++) F[3 + r] += x[r];
    for (int k = 0; k < n; k++) {
        const real cr[3] = {T.Cr[k], T.Cr[n + k], T.Cr[2 * n + k]};
        const real ct[3] = {in.C_t[k] - T.Kaq[k], in.C_t[n + k], in.C_t[2 * n + k]};
        mv(S, cr, b.U + 6 * k);
        mv(S, ct, b.U + 6 * k + 3);
        b.k_e[k] = T.ke[k];
        b.q_e[k] = T.qe[k];
        b.beta[k] = T.ke[k] - T.qe[k];
    }
    for (size_t k = 0; k < (size_t)n * n; k++) b.L[k] = in.M_ee[k];
}

/* the elastic parent of child c (at its node P) and d = o_c − r_P */
static Inv node_offset(const MbsEval *e, int child, real *d)
{
    const MbsModel *m = e->m;
    const MbsBodyI *bc = mbs_body_i(m, child);
    const Inv in = inv_of(m, mbs_body_i(m, bc->parent)->elastic);
    const real *wi = mbs_body_work(e, bc->parent), *oc = mbs_body_work(e, child) + W_O;
    const double *R = node_R(&in, bc->node);
    real rR[3], rho[3];
    mv3n(node_Phi(&in, bc->node), e->x + in.q0, in.n, rR);
    for (int k = 0; k < 3; k++) rR[k] += R[k];
    mv(wi + W_S, rR, rho);
    for (int k = 0; k < 3; k++) d[k] = oc[k] - wi[W_O + k] - rho[k];
    return in;
}

/* Y of child c at node P of its elastic parent: n columns of 6, the motion at o_c per unit q̈ of the parent */
static void node_columns(const MbsEval *e, int child, real *Y)
{
    const int P = mbs_body_i(e->m, child)->node;
    real d[3];
    const Inv in = node_offset(e, child, d);
    const int n = in.n;
    const real *S = mbs_body_work(e, mbs_body_i(e->m, child)->parent) + W_S;
    const double *Phi = node_Phi(&in, P), *Psi = node_Psi(&in, P);
    for (int k = 0; k < n; k++) {
        const real ps[3] = {Psi[k], Psi[n + k], Psi[2 * n + k]}, ph[3] = {Phi[k], Phi[n + k], Phi[2 * n + k]};
        real *y = Y + 6 * k, dxw[3];
        mv(S, ps, y);
        mv(S, ph, y + 3);
        cross(d, y, dxw);
        for (int r = 0; r < 3; r++) y[3 + r] -= dxw[r];
    }
}

/* child c at a node of its elastic parent, articulated (I_c; NULL: a free joint, which passes only its force p_c):
 * the parent's U += Xᵀ I_c Y, M_ee += Yᵀ I_c Y (lower triangle), β += Yᵀ p_c */
void mbs_elastic_child(const MbsEval *e, int child, const real *I_c, const real *p_c)
{
    const MbsModel *m = e->m;
    const int i = mbs_body_i(m, child)->parent, el = mbs_body_i(m, i)->elastic, n = row(m, el)->n;
    const Block b = block(e, el);
    real *Y = scratch(e), *G = Y + 6 * (size_t)n, d[3];
    node_columns(e, child, Y);
    for (int k = 0; k < n; k++) b.beta[k] += dot(Y + 6 * k, p_c, 6);
    if (!I_c) return;
    const real *oc = mbs_body_work(e, child) + W_O, *oi = mbs_body_work(e, i) + W_O;
    for (int r = 0; r < 3; r++) d[r] = oc[r] - oi[r];
    for (int k = 0; k < n; k++) {
        mat6v(I_c, Y + 6 * k, G + 6 * k);
        add_force_at(d, G + 6 * k, b.U + 6 * k);  /* the force I_c Y_k at o_c moved to o */
    }
    for (int k = 0; k < n; k++)
        for (int l = 0; l <= k; l++) b.L[(size_t)n * k + l] += dot(Y + 6 * k, G + 6 * l, 6);
}

/* before the body's own joint: q̈ eliminated, with M_ee = L Lᵀ, W = U L⁻ᵀ, z = L⁻¹ (β − τ) (W, z in place of U,
 * β): I_A −= W Wᵀ, p −= W z. 1 if M_ee with its children is not positive definite. */
int mbs_elastic_eliminate(const MbsEval *e, int body, real *IA, real *p)
{
    const MbsModel *m = e->m;
    const int el = mbs_body_i(m, body)->elastic, n = row(m, el)->n;
    const real *tau = e->q + row(m, el)->qd;
    const Block b = block(e, el);
    real *restrict W = b.U, *restrict z = b.beta;
    const real *restrict L = b.L;
    if (mbs_cholesky(n, b.L)) return 1;
    real WWt[21] = {0}, Wz[6] = {0};  /* the upper triangle of W Wᵀ, row after row; W z */
    for (int k = 0; k < n; k++) {  /* row k of L⁻¹ [Uᵀ β − τ], accumulated into W Wᵀ and W z as it is found */
        const real *Lk = L + (size_t)n * k;
        real w[6], zk = z[k] - tau[k];
        for (int r = 0; r < 6; r++) w[r] = W[6 * k + r];
        for (int j = 0; j < k; j++) {
            for (int r = 0; r < 6; r++) w[r] -= Lk[j] * W[6 * j + r];
            zk -= Lk[j] * z[j];
        }
        const real il = 1.0 / Lk[k];
        for (int r = 0; r < 6; r++) W[6 * k + r] = w[r] *= il;
        z[k] = zk *= il;
        for (int r = 0, t = 0; r < 6; r++) {
            Wz[r] += w[r] * zk;
            for (int c = r; c < 6; c++) WWt[t++] += w[r] * w[c];
        }
    }
    for (int r = 0, t = 0; r < 6; r++) {
        p[r] -= Wz[r];
        for (int c = r; c < 6; c++, t++) IA[6 * r + c] = IA[6 * c + r] = IA[6 * r + c] - WWt[t];
    }
    return 0;
}

/* after the body's Δa (acc): q̈ = −L⁻ᵀ (z + Wᵀ Δa) into ydd */
void mbs_elastic_accelerations(const MbsEval *e, int body, const real *acc, real *ydd)
{
    const MbsModel *m = e->m;
    const int el = mbs_body_i(m, body)->elastic, n = row(m, el)->n;
    const Block b = block(e, el);
    real *x = ydd + row(m, el)->qd;
    for (int k = 0; k < n; k++) x[k] = -(b.beta[k] + dot(b.U + 6 * k, acc, 6));
    for (int k = n - 1; k >= 0; k--) {
        for (int j = k + 1; j < n; j++) x[k] -= b.L[(size_t)n * j + k] * x[j];
        x[k] /= b.L[(size_t)n * k + k];
    }
}

/* a child at a node: acc (its parent's Δa moved to o_c) += Y q̈ of the parent: (S Ψ_P q̈, S Φ_P q̈ − d × S Ψ_P q̈) */
void mbs_elastic_node_acceleration(const MbsEval *e, int child, const real *ydd, real *acc)
{
    const int P = mbs_body_i(e->m, child)->node;
    real d[3], a[3], al[3], w[3], v[3], dxw[3];
    const Inv in = node_offset(e, child, d);
    const real *S = mbs_body_work(e, mbs_body_i(e->m, child)->parent) + W_S, *qdd = ydd + in.qd0;
    mv3n(node_Psi(&in, P), qdd, in.n, al);
    mv3n(node_Phi(&in, P), qdd, in.n, a);
    mv(S, al, w);
    mv(S, a, v);
    cross(d, w, dxw);
    for (int r = 0; r < 3; r++) { acc[r] += w[r]; acc[3 + r] += v[r] - dxw[r]; }
}

/* the part on the body's q of a force F (torque: a moment) at its node P, (S Φ_P)ᵀ F or (S Ψ_P)ᵀ F, into e->q
 * (the frame's part is the caller's) */
void mbs_elastic_node_force(const MbsEval *e, int body, int node, const real *F, int torque, double sign)
{
    const MbsModel *m = e->m;
    const Inv in = inv_of(m, mbs_body_i(m, body)->elastic);
    const int n = in.n;
    const double *C = torque ? node_Psi(&in, node) : node_Phi(&in, node);
    real SF[3], *q = e->q + in.qd0;
    mtv(mbs_body_work(e, body) + W_S, F, SF);
    for (int k = 0; k < n; k++) q[k] += sign * (C[k] * SF[0] + C[n + k] * SF[1] + C[2 * n + k] * SF[2]);
}

/* inverse dynamics (inspection, dynamics.c: equations): the body's f += U q̈, its β = Uᵀ Δa + M_ee q̈ (what = 0),
 * ke (1) or qe (2); mbs_elastic_child(e, c, NULL, f_c) adds the children's Yᵀ f_c, mbs_elastic_modal_force reads β */
void mbs_elastic_inverse(const MbsEval *e, int body, const real *acc, const real *ydd, int what, real *f)
{
    const MbsModel *m = e->m;
    const int el = mbs_body_i(m, body)->elastic, n = row(m, el)->n;
    const Block b = block(e, el);
    const real *qdd = ydd + row(m, el)->qd;
    for (int k = 0; k < n; k++) {
        if (what) { b.beta[k] = what == 1 ? b.k_e[k] : b.q_e[k]; continue; }
        b.beta[k] = dot(b.U + 6 * k, acc, 6);
        for (int l = 0; l < n; l++) b.beta[k] += b.L[(size_t)n * k + l] * qdd[l];
        for (int r = 0; r < 6; r++) f[r] += b.U[6 * k + r] * qdd[k];
    }
}

void mbs_elastic_modal_force(const MbsEval *e, int body, real *out)
{
    const MbsModel *m = e->m;
    const int el = mbs_body_i(m, body)->elastic;
    const Block b = block(e, el);
    for (int k = 0; k < row(m, el)->n; k++) out[row(m, el)->qd + k] += b.beta[k];
}

#ifndef MBS_CX  /* load and bind time: the double build only */
static int64_t block_size(int64_t n, int64_t N, int stiff)
{
    return 1 + 3 + 9 + 9 + 3 * n + 9 * n + 3 * n + 3 * n + 3 * n * n + 9 * n * n + 3 * n * n
           + (stiff ? 2 * n * n : 0) + N * (3 + 6 * n);
}

/* ---- load-time checks: every count, offset and index, so that a corrupt file cannot reach memory it
 * does not own ---- */
#define FAIL(...) do { snprintf(err, errlen, __VA_ARGS__); return 1; } while (0)

static int in_range(int v, int lo, int hi) { return v >= lo && v < hi; }

int mbs_elastic_validate(const MbsModel *m, char *err, size_t errlen)
{
    const int32_t *I = m->elastic_i;
    const int ni = m->n_elastic_i, nb = NB(m);
    if (!I || ni < EH) FAIL("corrupt elastic section (missing)");
    const int ne = I[EH_NE], nfix = I[EH_NFIX];
    if (!in_range(ne, 1, nb + 1) || nfix < 0 || (int64_t)EH + (int64_t)EI * ne + nfix > ni)
        FAIL("corrupt elastic section (counts)");
    int64_t off = 0;
    for (int el = 0; el < ne; el++) {
        const ElasticRow *r = row(m, el);
        const int b = r->body, n = r->n, N = r->nodes;
        if (!in_range(b, 0, nb) || mbs_body_i(m, b)->elastic != el || !in_range(n, 1, MAX_MODES + 1) ||
            N < 1 || !in_range(r->stiff, 0, 2) || r->d != off ||
            !in_range(r->q, 0, NPOS(m)) || r->q + n > NPOS(m) || !in_range(r->qd, 0, NVEL(m)) ||
            r->qd + n > NVEL(m) || N > m->n_elastic_d)
            FAIL("corrupt elastic section (row %d for body %d: the body must name this row back; modes 1..%d, nodes >= 1, "
                 "coordinates and data inside their tables)", el, b, MAX_MODES);
        off += block_size(n, N, r->stiff);
        if (off > m->n_elastic_d) FAIL("corrupt elastic section (data of body %d)", el);
    }
    if (off + nfix != m->n_elastic_d) FAIL("corrupt elastic section (data length)");
    /* and back: a body names the row that names it (or none), so rows and elastic bodies pair one to one */
    for (int i = 0; i < nb; i++) {
        const int el = mbs_body_i(m, i)->elastic;
        if (el >= 0 && (el >= ne || row(m, el)->body != i))
            FAIL("corrupt body table (body %d names elastic data %d; the scene has %d, and that one belongs to another body)", i, el, ne);
    }
    const int32_t *fix = I + EH + EI * ne;  /* structural parameters */
    for (int k = 0; k < nfix; k++) if (!in_range(fix[k], 0, m->hdr[H_NPARAM])) FAIL("corrupt elastic section (parameter)");
    /* node indices wherever a node is named */
    for (int i = 0; i < nb; i++) {
        const MbsBodyI *bi = mbs_body_i(m, i);
        if (bi->node < 0) continue;
        int p = bi->parent, el = p >= 0 ? mbs_body_i(m, p)->elastic : -1;
        if (el < 0 || bi->node >= row(m, el)->nodes) FAIL("corrupt body table (node of body %d)", i);
    }
    for (int k = 0; k < m->hdr[H_NFORCE]; k++) {
        const MbsForceI *fi = mbs_force_i(m, k);
        for (int end = 0; end < 2; end++) {
            int node = end ? fi->node_b : fi->node_a, b = end ? fi->b : fi->a;
            if (node < 0) continue;
            if (fi->type == FE_JOINT_SPRING || (end && fi->type != FE_SPRING)) FAIL("corrupt force table (node of element %d)", k);
            int el = b >= 0 ? mbs_body_i(m, b)->elastic : -1;
            if (el < 0 || node >= row(m, el)->nodes) FAIL("corrupt force table (node of element %d)", k);
        }
    }
    for (int o = 0; o < m->hdr[H_NOUT]; o++) {
        int b = m->out[3 * o], node = m->out[3 * o + 1];
        if (node < 0) continue;
        int el = mbs_body_i(m, b)->elastic;
        if (el < 0 || node >= row(m, el)->nodes) FAIL("corrupt output table (node of output %d)", o);
    }
    int64_t at = 0;  /* stress nodes: their modes one after another, 6 × n of their body's n */
    for (int k = 0; k < m->nstress; k++) {
        const int el = m->stress_i[2 * k];
        if (!in_range(el, 0, ne) || m->stress_i[2 * k + 1] != at) FAIL("corrupt stress section (row %d)", k);
        at += 6 * (int64_t)row(m, el)->n;
    }
    if (at != m->n_stress_d) FAIL("corrupt stress section (data length)");
    return 0;
}

#endif

/* σ_c = Σ_k σ_ck q_k (Voigt xx yy zz xy yz zx), then σ_vm = √(½((σxx−σyy)² + (σyy−σzz)² + (σzz−σxx)²)
 * + 3(σxy² + σyz² + σzx²)) */
real mbs_elastic_von_mises(const MbsModel *m, int k, const real *x)
{
    const ElasticRow *r = row(m, m->stress_i[2 * k]);
    const double *modes = m->stress_d + m->stress_i[2 * k + 1];
    const real *q = x + r->q;
    real s[6];
    for (int c = 0; c < 6; c++) s[c] = dotd(modes + (size_t)c * r->n, q, r->n);
    const real a = s[0] - s[1], b = s[1] - s[2], c = s[2] - s[0];
    return r_sqrt(0.5 * (a * a + b * b + c * c) + 3.0 * (s[3] * s[3] + s[4] * s[4] + s[5] * s[5]));
}

#ifndef MBS_CX
/* Structural parameters (they fed the finite-element data): the bound value must be the one the data were
 * computed with. The index of the first that is not (its compiled value in *compiled), else -1. */
int mbs_elastic_changed_structure(const MbsModel *m, const double *D, double *compiled)
{
    const int32_t *I = m->elastic_i;
    const int nfix = I[EH_NFIX];
    const int32_t *fix = I + EH + EI * I[EH_NE];
    const double *val = m->elastic_d + m->n_elastic_d - nfix;
    for (int k = 0; k < nfix; k++)
        if (D[fix[k]] != val[k]) return *compiled = val[k], fix[k];
    return -1;
}
#endif
