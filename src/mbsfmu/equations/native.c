/* Compiled right-hand side for rigid trees: the same recursion as tree.py (seed 000), in C.
 *
 *   kinematics:  S_i, o_i, ω_i, v_i, ā_i, ᾱ_i, J_Ri, J_Ti of every body origin, parents first
 *   M = Σ m J_Tcᵀ J_Tc + J_Rᵀ I_w J_R,   k = Σ m J_Tcᵀ ā_c + J_Rᵀ (I_w ᾱ + ω × I_w ω),   q = Σ J_Tᵀ f + J_Rᵀ l
 *   ÿ = M⁻¹ (q − k) by Cholesky, ẏ_pos = Z(y)·ẏ (quaternions: ṗ = G(p) ω)
 *
 * All data live in arrays owned by Python (numpy); this file only reads the model tables and writes the
 * workspace. Layouts are defined once in native.py (IB_*, DB_*, IF_*, DF_* offsets) and mirrored here.
 */
#include <math.h>
#include <string.h>

enum { J_FIXED, J_REVOLUTE, J_PRISMATIC, J_CYLINDRICAL, J_UNIVERSAL, J_PLANAR,
       J_SPH_QUAT, J_SPH_CARDAN, J_FREE_QUAT, J_FREE_CARDAN };
enum { F_JOINT_SPRING, F_SPRING, F_FORCE, F_TORQUE };

/* int table per body */
enum { IB_PARENT, IB_JTYPE, IB_NPOS, IB_NVEL, IB_MASSIVE, IB_POS, IB_VEL = IB_POS + 7, IB_DRV = IB_VEL + 6, IB = IB_DRV + 7 };
/* double table per body */
enum { DB_A1, DB_A2 = 3, DB_AT = 6, DB_R0 = 9, DB_M = 18, DB_C = 19, DB_I = 22, DB = 31 };
/* force tables */
enum { IF_TYPE, IF_A, IF_B, IF_FRAME, IF = 4 };
enum { DF_K, DF_D, DF_L, DF_AT_A = 3, DF_AT_B = 6, DF_VEC = 9, DF = 12 };

typedef struct {
    int nb, npos, nvel, nforce, nquat, nplain, has_gravity, ndrv, nvec;
    const int *ib;        /* nb × IB */
    const double *db;     /* nb × DB */
    const int *iforce;    /* nforce × IF */
    double *dforce;       /* nforce × DF (DF_VEC of the time-dependent elements is copied from td) */
    const double *g;      /* 3 */
    const int *quat;      /* nquat × 7: 4 position indices, 3 velocity indices */
    const int *plain_pos, *plain_vel;
    const int *vec_rows;  /* the nvec force/torque elements whose vector depends on t or inputs */
    const double *td;     /* time-dependent numbers from Python: p, v, a per drive (ndrv), then 3 per vec_rows */
    const double *x;      /* [y; ẏ] */
    const double *q_in;   /* generalized-force inputs (nvel) */
    double *work;         /* nb × (26 + 6 nvel), then 6 nvel scratch */
    double *M, *k, *q;    /* nvel×nvel, nvel, nvel */
    double *xdot;         /* npos + nvel */
} Tree;

/* ---- small 3-vector / 3×3 helpers (row-major) ---- */
static void cross(const double *a, const double *b, double *c)
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}
static void mv(const double *A, const double *x, double *y)
{
    for (int r = 0; r < 3; r++) y[r] = A[3 * r] * x[0] + A[3 * r + 1] * x[1] + A[3 * r + 2] * x[2];
}
static void mm(const double *A, const double *B, double *C)
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            C[3 * r + c] = A[3 * r] * B[c] + A[3 * r + 1] * B[3 + c] + A[3 * r + 2] * B[6 + c];
}
static void axis_angle(const double *a, double ang, double *R)
{
    double x = a[0], y = a[1], z = a[2], c = cos(ang), s = sin(ang), C = 1.0 - c;
    R[0] = c + x * x * C;     R[1] = x * y * C - z * s; R[2] = x * z * C + y * s;
    R[3] = y * x * C + z * s; R[4] = c + y * y * C;     R[5] = y * z * C - x * s;
    R[6] = z * x * C - y * s; R[7] = z * y * C + x * s; R[8] = c + z * z * C;
}
static void quat_to_matrix(const double *p, double *S)
{
    double p0 = p[0], p1 = p[1], p2 = p[2], p3 = p[3];
    S[0] = 1 - 2 * (p2 * p2 + p3 * p3); S[1] = 2 * (p1 * p2 - p0 * p3);     S[2] = 2 * (p1 * p3 + p0 * p2);
    S[3] = 2 * (p1 * p2 + p0 * p3);     S[4] = 1 - 2 * (p1 * p1 + p3 * p3); S[5] = 2 * (p2 * p3 - p0 * p1);
    S[6] = 2 * (p1 * p3 - p0 * p2);     S[7] = 2 * (p2 * p3 + p0 * p1);     S[8] = 1 - 2 * (p1 * p1 + p2 * p2);
}

/* Joint motion in the joint frame (joints.py): R_rel, d_rel, H_R, H_T (3 × nv, column-major per joint
 * velocity: H[3*j + r]), b_R, b_T. Zero parts are written as zeros. */
static void cardan(const double *p, const double *v, double *R, double *H, double *b_R)
{
    double ca = cos(p[0]), sa = sin(p[0]), cb = cos(p[1]), sb = sin(p[1]), cc = cos(p[2]), sc = sin(p[2]);
    double Sx[9] = {1, 0, 0, 0, ca, -sa, 0, sa, ca}, Sy[9] = {cb, 0, sb, 0, 1, 0, -sb, 0, cb};
    double Sz[9] = {cc, -sc, 0, sc, cc, 0, 0, 0, 1}, Sxy[9];
    mm(Sx, Sy, Sxy);
    mm(Sxy, Sz, R);
    double h1[3] = {1, 0, 0}, h2[3] = {Sx[1], Sx[4], Sx[7]}, h3[3] = {Sxy[2], Sxy[5], Sxy[8]};
    double w1[3], w2[3], c1[3], c2[3];
    for (int r = 0; r < 3; r++) {
        w1[r] = h1[r] * v[0];
        w2[r] = w1[r] + h2[r] * v[1];
        H[r] = h1[r]; H[3 + r] = h2[r]; H[6 + r] = h3[r];
    }
    cross(w1, h2, c1);
    cross(w2, h3, c2);
    for (int r = 0; r < 3; r++) b_R[r] = c1[r] * v[1] + c2[r] * v[2];
}

static void joint_motion(int type, const double *db, const double *p, const double *v,
                         double *R, double *d, double *H_R, double *H_T, double *b_R, double *b_T)
{
    static const double E[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    const double *a = db + DB_A1, *a2 = db + DB_A2;
    memcpy(R, E, sizeof E);
    memset(d, 0, 3 * sizeof(double));
    memset(H_R, 0, 18 * sizeof(double));
    memset(H_T, 0, 18 * sizeof(double));
    memset(b_R, 0, 3 * sizeof(double));
    memset(b_T, 0, 3 * sizeof(double));
    switch (type) {
    case J_REVOLUTE:
        axis_angle(a, p[0], R);
        memcpy(H_R, a, 3 * sizeof(double));
        break;
    case J_PRISMATIC:
        for (int r = 0; r < 3; r++) d[r] = a[r] * p[0];
        memcpy(H_T, a, 3 * sizeof(double));
        break;
    case J_CYLINDRICAL:
        axis_angle(a, p[1], R);
        for (int r = 0; r < 3; r++) { d[r] = a[r] * p[0]; H_T[r] = a[r]; H_R[3 + r] = a[r]; }
        break;
    case J_UNIVERSAL: {
        double S1[9], S2[9], h2[3], c[3];
        axis_angle(a, p[0], S1);
        axis_angle(a2, p[1], S2);
        mm(S1, S2, R);
        mv(S1, a2, h2);
        cross(a, h2, c);
        for (int r = 0; r < 3; r++) { H_R[r] = a[r]; H_R[3 + r] = h2[r]; b_R[r] = c[r] * (v[0] * v[1]); }
        break;
    }
    case J_PLANAR: {
        double n[3];
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

/* per-body workspace: S(9) o w v a al (5×3), the range [lo, hi) of columns where J_R, J_T can be nonzero
 * (the body's and its ancestors' velocity coordinates: loops skip the rest), then J_R, J_T (3 × nvel each) */
#define W_S 0
#define W_O 9
#define W_W 12
#define W_V 15
#define W_A 18
#define W_AL 21
#define W_LO 24
#define W_HI 25
#define W_J 26
#define W_SIZE(f) (26 + 6 * (f))

static double *body_work(const Tree *m, int i) { return m->work + (size_t)i * W_SIZE(m->nvel); }
static int col_lo(const double *wk) { return (int)wk[W_LO]; }
static int col_hi(const double *wk) { return (int)wk[W_HI]; }

/* Recursive kinematics of all body origins (tree.py: kinematics). */
static void kinematics(const Tree *m)
{
    static const double Z[3] = {0, 0, 0};
    const int f = m->nvel;
    const double *y = m->x, *yd = m->x + m->npos;
    for (int i = 0; i < m->nb; i++) {
        const int *ib = m->ib + i * IB;
        const double *db = m->db + i * DB;
        double *wk = body_work(m, i);
        double *J_R = wk + W_J, *J_T = J_R + 3 * f;
        const int par = ib[IB_PARENT], nv = ib[IB_NVEL], np = ib[IB_NPOS];
        const double *o_p, *w_p, *v_p, *a_p, *al_p;
        double S_J[9], rho[3] = {0, 0, 0};
        int lo = f, hi = 0;
        if (par < 0) {
            o_p = w_p = v_p = a_p = al_p = Z;
            memset(J_R, 0, 6 * f * sizeof(double));
            memcpy(S_J, db + DB_R0, sizeof S_J);
            memcpy(rho, db + DB_AT, sizeof rho);
        } else {
            const double *pw = body_work(m, par);
            const double *S_p = pw + W_S;
            o_p = pw + W_O; w_p = pw + W_W; v_p = pw + W_V; a_p = pw + W_A; al_p = pw + W_AL;
            memcpy(J_R, pw + W_J, 6 * f * sizeof(double));
            lo = col_lo(pw);
            hi = col_hi(pw);
            mm(S_p, db + DB_R0, S_J);
            mv(S_p, db + DB_AT, rho);
        }
        double p[7], v[6], acc[6] = {0}, R[9], d[3], H_R[18], H_T[18], b_R[3], b_T[3];
        for (int k = 0; k < np; k++) {
            int pi = ib[IB_POS + k], s = ib[IB_DRV + k];
            p[k] = pi >= 0 ? y[pi] : m->td[3 * s];
        }
        for (int k = 0; k < nv; k++) {
            int vi = ib[IB_VEL + k], s = ib[IB_DRV + k];
            if (vi >= 0) v[k] = yd[vi];
            else { v[k] = m->td[3 * s + 1]; acc[k] = m->td[3 * s + 2]; }
        }
        joint_motion(ib[IB_JTYPE], db, p, v, R, d, H_R, H_T, b_R, b_T);
        double w_rel_j[3] = {0, 0, 0}, v_rel_j[3] = {0, 0, 0};
        for (int k = 0; k < nv; k++)
            for (int r = 0; r < 3; r++) {
                w_rel_j[r] += H_R[3 * k + r] * v[k];
                v_rel_j[r] += H_T[3 * k + r] * v[k];
                /* prescribed accelerations of driven coordinates join the bias terms */
                b_R[r] += H_R[3 * k + r] * acc[k];
                b_T[r] += H_T[3 * k + r] * acc[k];
            }
        double dd[3], w_rel[3], v_rel[3], SbR[3], SbT[3], t1[3], t2[3];
        mv(S_J, d, dd);
        mv(S_J, w_rel_j, w_rel);
        mv(S_J, v_rel_j, v_rel);
        mv(S_J, b_R, SbR);
        mv(S_J, b_T, SbT);
        for (int r = 0; r < 3; r++) rho[r] += dd[r];
        double *w = wk + W_W, *al = wk + W_AL, *o = wk + W_O, *vv = wk + W_V, *a = wk + W_A;
        /* ω = ω_p + ω_rel;  ᾱ = ᾱ_p + ω_p × ω_rel + S_J b_R */
        cross(w_p, w_rel, t1);
        for (int r = 0; r < 3; r++) { w[r] = w_p[r] + w_rel[r]; al[r] = al_p[r] + t1[r] + SbR[r]; }
        /* v = v_p + ω_p × ρ + v_rel;  ā = ā_p + ᾱ_p × ρ + ω_p × (ω_p × ρ) + 2 ω_p × v_rel + S_J b_T */
        double wxr[3], axr[3], wwxr[3];
        cross(w_p, rho, wxr);
        cross(al_p, rho, axr);
        cross(w_p, wxr, wwxr);
        cross(w_p, v_rel, t2);
        for (int r = 0; r < 3; r++) {
            o[r] = o_p[r] + rho[r];
            vv[r] = v_p[r] + wxr[r] + v_rel[r];
            a[r] = a_p[r] + axr[r] + wwxr[r] + 2.0 * t2[r] + SbT[r];
        }
        /* J_T = J_Tp − ρ̃ J_Rp, then the joint's own columns */
        for (int c = lo; c < hi; c++) {
            double jr[3] = {J_R[c], J_R[f + c], J_R[2 * f + c]}, x[3];
            cross(rho, jr, x);
            for (int r = 0; r < 3; r++) J_T[r * f + c] -= x[r];
        }
        for (int k = 0; k < nv; k++) {
            int col = ib[IB_VEL + k];
            if (col < 0) continue;
            if (col < lo) lo = col;
            if (col + 1 > hi) hi = col + 1;
            double hr[3], ht[3];
            mv(S_J, H_R + 3 * k, hr);
            mv(S_J, H_T + 3 * k, ht);
            for (int r = 0; r < 3; r++) { J_R[r * f + col] += hr[r]; J_T[r * f + col] += ht[r]; }
        }
        mm(S_J, R, wk + W_S);
        wk[W_LO] = lo;
        wk[W_HI] = hi;
    }
}

/* World position, velocity and J_T (3 × f, columns [lo, hi) of body i only) of a point fixed on body i
 * (r_b in the body frame); i < 0: a point of the world. */
static void point(const Tree *m, int i, const double *r_b, double *x, double *v, double *J)
{
    const int f = m->nvel;
    if (i < 0) {
        memcpy(x, r_b, 3 * sizeof(double));
        memset(v, 0, 3 * sizeof(double));
        return;
    }
    const double *wk = body_work(m, i), *J_R = wk + W_J, *J_T = J_R + 3 * f;
    double r[3], wxr[3];
    mv(wk + W_S, r_b, r);
    cross(wk + W_W, r, wxr);
    for (int k = 0; k < 3; k++) { x[k] = wk[W_O + k] + r[k]; v[k] = wk[W_V + k] + wxr[k]; }
    for (int c = col_lo(wk); c < col_hi(wk); c++) {
        double jr[3] = {J_R[c], J_R[f + c], J_R[2 * f + c]}, s[3];
        cross(r, jr, s);
        for (int k = 0; k < 3; k++) J[k * f + c] = J_T[k * f + c] - s[k];
    }
}

/* q += Jᵀ F for a 3 × f Jacobian of body i (its columns [lo, hi)) */
static void add_JtF(const Tree *m, int i, const double *J, const double *F, double sign, double *q)
{
    const int f = m->nvel;
    const double *wk = body_work(m, i);
    for (int c = col_lo(wk); c < col_hi(wk); c++) q[c] += sign * (J[c] * F[0] + J[f + c] * F[1] + J[2 * f + c] * F[2]);
}

/* M, k and the gravity part of q (tree.py: mass_matrix_and_bias); J is 3 × f scratch. */
static void mass_matrix_and_bias(const Tree *m, double *J)
{
    const int f = m->nvel;
    double *M = m->M, *k = m->k, *q = m->q;
    memset(M, 0, (size_t)f * f * sizeof(double));
    memset(k, 0, f * sizeof(double));
    memset(q, 0, f * sizeof(double));
    for (int i = 0; i < m->nb; i++) {
        const int *ib = m->ib + i * IB;
        if (!ib[IB_MASSIVE]) continue;
        const double *db = m->db + i * DB, *wk = body_work(m, i), *J_R = wk + W_J, *S = wk + W_S;
        const double *w = wk + W_W, *al = wk + W_AL, mass = db[DB_M];
        double xc[3], vc[3], c[3], wxc[3], axc[3], wwxc[3], a_c[3];
        point(m, i, db + DB_C, xc, vc, J);  /* J_T of the centre of mass */
        mv(S, db + DB_C, c);
        cross(w, c, wxc);
        cross(al, c, axc);
        cross(w, wxc, wwxc);
        for (int r = 0; r < 3; r++) a_c[r] = wk[W_A + r] + axc[r] + wwxc[r];
        /* I_w = S I Sᵀ: world-frame inertia about the centre of mass */
        double SI[9], I_w[9], Iw_w[3], Iw_al[3], gyr[3];
        mm(S, db + DB_I, SI);
        for (int r = 0; r < 3; r++)
            for (int cc = 0; cc < 3; cc++) I_w[3 * r + cc] = SI[3 * r] * S[3 * cc] + SI[3 * r + 1] * S[3 * cc + 1] + SI[3 * r + 2] * S[3 * cc + 2];
        mv(I_w, w, Iw_w);
        mv(I_w, al, Iw_al);
        cross(w, Iw_w, gyr);
        double mg[3] = {0, 0, 0}, mac[3], rot[3];
        if (m->has_gravity) for (int r = 0; r < 3; r++) mg[r] = mass * m->g[r];
        for (int r = 0; r < 3; r++) { mac[r] = mass * a_c[r]; rot[r] = Iw_al[r] + gyr[r]; }
        add_JtF(m, i, J, mac, 1.0, k);
        add_JtF(m, i, J_R, rot, 1.0, k);
        add_JtF(m, i, J, mg, 1.0, q);
        const int lo = col_lo(wk), hi = col_hi(wk);
        for (int cj = lo; cj < hi; cj++) {
            /* columns of I_w J_R and m J_T */
            double IJ[3], jr[3] = {J_R[cj], J_R[f + cj], J_R[2 * f + cj]};
            mv(I_w, jr, IJ);
            for (int ci = lo; ci <= cj; ci++) {
                double s = mass * (J[ci] * J[cj] + J[f + ci] * J[f + cj] + J[2 * f + ci] * J[2 * f + cj])
                         + J_R[ci] * IJ[0] + J_R[f + ci] * IJ[1] + J_R[2 * f + ci] * IJ[2];
                M[ci * f + cj] += s;
            }
        }
    }
    for (int i = 0; i < f; i++)
        for (int j = 0; j < i; j++) M[i * f + j] = M[j * f + i];
}

/* q from the force elements and the generalized-force inputs (tree.py: applied_forces). */
static void applied_forces(const Tree *m, double *Ja, double *Jb)
{
    const int f = m->nvel;
    const double *y = m->x, *yd = m->x + m->npos;
    double *q = m->q;
    if (m->q_in) for (int c = 0; c < f; c++) q[c] += m->q_in[c];
    for (int e = 0; e < m->nforce; e++) {
        const int *fi = m->iforce + e * IF;
        const double *fd = m->dforce + e * DF;
        switch (fi[IF_TYPE]) {
        case F_JOINT_SPRING: {
            int pi = fi[IF_A], vi = fi[IF_B];
            q[vi] -= fd[DF_K] * (y[pi] - fd[DF_L]) + fd[DF_D] * yd[vi];
            break;
        }
        case F_SPRING: {
            double xa[3], va[3], xb[3], vb[3], dx[3], dv[3];
            point(m, fi[IF_A], fd + DF_AT_A, xa, va, Ja);
            point(m, fi[IF_B], fd + DF_AT_B, xb, vb, Jb);
            for (int r = 0; r < 3; r++) { dx[r] = xb[r] - xa[r]; dv[r] = vb[r] - va[r]; }
            double l = sqrt(dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2]);
            if (l < 1e-12) break; /* direction undefined at zero length: no force rather than NaN */
            double e3[3] = {dx[0] / l, dx[1] / l, dx[2] / l};
            double mag = fd[DF_K] * (l - fd[DF_L]) + fd[DF_D] * (e3[0] * dv[0] + e3[1] * dv[1] + e3[2] * dv[2]);
            double F[3] = {mag * e3[0], mag * e3[1], mag * e3[2]}; /* pulls B toward A */
            if (fi[IF_A] >= 0) add_JtF(m, fi[IF_A], Ja, F, 1.0, q);
            if (fi[IF_B] >= 0) add_JtF(m, fi[IF_B], Jb, F, -1.0, q);
            break;
        }
        case F_FORCE:
        case F_TORQUE: {
            int i = fi[IF_A];
            const double *wk = body_work(m, i);
            double vec[3], xp[3], vp[3];
            if (fi[IF_FRAME]) mv(wk + W_S, fd + DF_VEC, vec);
            else memcpy(vec, fd + DF_VEC, sizeof vec);
            if (fi[IF_TYPE] == F_TORQUE) add_JtF(m, i, wk + W_J, vec, 1.0, q);
            else { point(m, i, fd + DF_AT_A, xp, vp, Ja); add_JtF(m, i, Ja, vec, 1.0, q); }
            break;
        }
        }
    }
}

/* Solve M a = r in place (M overwritten by its Cholesky factor). 0 on success, 1 if M is not positive definite. */
static int cholesky_solve(int n, double *M, double *r)
{
    for (int j = 0; j < n; j++) {
        double s = M[j * n + j];
        for (int k = 0; k < j; k++) s -= M[j * n + k] * M[j * n + k];
        if (s <= 0.0) return 1; /* NaN passes on as NaN, like numpy's solve: the integrator shrinks h */
        double d = sqrt(s);
        M[j * n + j] = d;
        for (int i = j + 1; i < n; i++) {
            double t = M[i * n + j];
            for (int k = 0; k < j; k++) t -= M[i * n + k] * M[j * n + k];
            M[i * n + j] = t / d;
        }
    }
    for (int i = 0; i < n; i++) {
        double s = r[i];
        for (int k = 0; k < i; k++) s -= M[i * n + k] * r[k];
        r[i] = s / M[i * n + i];
    }
    for (int i = n - 1; i >= 0; i--) {
        double s = r[i];
        for (int k = i + 1; k < n; k++) s -= M[k * n + i] * r[k];
        r[i] = s / M[i * n + i];
    }
    return 0;
}

/* Kinematics only (output points): S, o, ω, v of every body in the workspace. */
int mbs_kinematics(const Tree *m)
{
    kinematics(m);
    return 0;
}

/* M, k, q at the state m->x (scratch: 6 f doubles after the workspace of the bodies). */
int mbs_equations(const Tree *m)
{
    for (int k = 0; k < m->nvec; k++)
        memcpy(m->dforce + (size_t)m->vec_rows[k] * DF + DF_VEC, m->td + 3 * (m->ndrv + k), 3 * sizeof(double));
    double *scratch = m->work + (size_t)m->nb * W_SIZE(m->nvel);
    kinematics(m);
    mass_matrix_and_bias(m, scratch);
    applied_forces(m, scratch, scratch + 3 * m->nvel);
    return 0;
}

/* ẋ = [Z(y) ẏ; M⁻¹(q − k)]. Returns 0, or 1 when M is not positive definite. */
int mbs_rhs(const Tree *m)
{
    const int f = m->nvel, np = m->npos;
    const double *y = m->x, *yd = m->x + np;
    double *xd = m->xdot;
    mbs_equations(m);
    for (int c = 0; c < f; c++) xd[np + c] = m->q[c] - m->k[c];
    if (cholesky_solve(f, m->M, xd + np)) return 1;
    for (int i = 0; i < m->nplain; i++) xd[m->plain_pos[i]] = yd[m->plain_vel[i]];
    for (int j = 0; j < m->nquat; j++) {
        const int *qi = m->quat + 7 * j;
        double p0 = y[qi[0]], p1 = y[qi[1]], p2 = y[qi[2]], p3 = y[qi[3]];
        double w0 = yd[qi[4]], w1 = yd[qi[5]], w2 = yd[qi[6]];
        /* ṗ = ½ p ⊗ (0, ω), body-frame ω */
        xd[qi[0]] = 0.5 * (-p1 * w0 - p2 * w1 - p3 * w2);
        xd[qi[1]] = 0.5 * (p0 * w0 - p3 * w1 + p2 * w2);
        xd[qi[2]] = 0.5 * (p3 * w0 + p0 * w1 - p1 * w2);
        xd[qi[3]] = 0.5 * (-p2 * w0 + p1 * w1 + p0 * w2);
    }
    return 0;
}

/* Gimbal lock of Cardan joints (|cos b| < 1e-3, as Evaluator.singularity_message): 1 if any. */
static int gimbal(const Tree *m)
{
    for (int i = 0; i < m->nb; i++) {
        const int *ib = m->ib + i * IB;
        int k = ib[IB_JTYPE] == J_SPH_CARDAN ? 1 : ib[IB_JTYPE] == J_FREE_CARDAN ? 4 : -1;
        if (k >= 0 && ib[IB_POS + k] >= 0 && fabs(cos(m->x[ib[IB_POS + k]])) < 1e-3) return 1;
    }
    return 0;
}

/* Explicit Runge-Kutta stages i0..s-1 in one call (inputs are held over the step):
 *   k_i = f(t_i, x + h Σ_j a_ij k_j),  A row-major with leading dimension lda, K rows of length n.
 * td: NULL when nothing depends on t, else the time-dependent numbers of every stage time t_i
 * (row i, ntd = 3 (ndrv + nvec) per row), evaluated by Python beforehand: stage times are known in advance.
 * xs returns the argument of the last stage evaluated (for an FSAL row: x_new).
 * Returns 0; 1 if M is not positive definite, 2 at gimbal lock (xs holds that state). */
int mbs_erk_stages(const Tree *m, int i0, int s, const double *A, int lda, double h, const double *x,
                   double *K, double *xs, const double *td)
{
    const int n = m->npos + m->nvel, ntd = 3 * (m->ndrv + m->nvec);
    Tree st = *m;
    st.x = xs;
    for (int i = i0; i < s; i++) {
        if (td) st.td = td + (size_t)i * ntd;
        const double *a = A + (size_t)i * lda;
        for (int r = 0; r < n; r++) {
            double acc = 0.0;
            for (int j = 0; j < i; j++) acc += a[j] * K[(size_t)j * n + r];
            xs[r] = x[r] + h * acc;
        }
        if (gimbal(&st)) return 2;
        st.xdot = K + (size_t)i * n;
        if (mbs_rhs(&st)) return 1;
    }
    return 0;
}
