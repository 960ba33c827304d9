/* Engine internals shared by model.c, expr.c, the evaluation's stages (tree.c, forces.c, dynamics.c, cholesky.c,
 * forward.c, elastic.c) and the instance's files (instance.h).
 *
 * The compiled scene (written by compiler/scene_file.py) is two flat arrays: I (int32) and D (double), reached
 * through a table of sections. The model keeps them read-only; every instance copies D, because the
 * parameters of an instance re-bind the numbers in its copy (bind programs), and keeps its own workspace
 * (Pinocchio's Model/Data split: nothing is written into the model during evaluation).
 */
#ifndef MBS_MODEL_H
#define MBS_MODEL_H

#include <stddef.h>
#include <stdint.h>
#include "mbs_engine.h"
#include "mbs_layout.h"

/* The scalar of the evaluation (tree.c, dynamics.c, elastic.c): double, or, where deriv.c compiles the same files
 * again with MBS_CX, a complex number that carries a directional derivative through them (complex step:
 * f(x + i h v) = f(x) + i h f'(x) v + O(h²), no subtraction, so exact to rounding for tiny h). Code written over
 * `real` only compares real parts (RE) and calls the math of mbs_vec3.h (r_sqrt, r_sin, r_cos). */
#ifdef MBS_CX
#include <complex.h>
#undef I  /* complex.h's imaginary unit; I is an inertia here (C99 7.3.1 allows the #undef) */
typedef double _Complex real;
#define RE(x) creal(x)
/* the complex twins of the evaluation functions (deriv.c) */
#define mbs_body_d mbs_cx_body_d
#define mbs_kinematics mbs_cx_kinematics
#define mbs_position_rates mbs_cx_position_rates
#define mbs_cholesky mbs_cx_cholesky
#define mbs_cholesky_apply mbs_cx_cholesky_apply
#define mbs_cholesky_solve mbs_cx_cholesky_solve
#define mbs_mass_matrix_and_bias mbs_cx_mass_matrix_and_bias
#define mbs_applied_forces mbs_cx_applied_forces
#define mbs_eval_rhs mbs_cx_eval_rhs
#define mbs_composites mbs_cx_composites
#define mbs_aba mbs_cx_aba
#define mbs_crba_rnea mbs_cx_crba_rnea
#define mbs_body_force mbs_cx_body_force
#define mbs_point mbs_cx_point
#define mbs_add_JtF mbs_cx_add_JtF
#define mbs_elastic_work_size mbs_cx_elastic_work_size
#define mbs_elastic_kinematics mbs_cx_elastic_kinematics
#define mbs_elastic_node_frame mbs_cx_elastic_node_frame
#define mbs_elastic_node_point mbs_cx_elastic_node_point
#define mbs_elastic_node_J_R mbs_cx_elastic_node_J_R
#define mbs_elastic_equations mbs_cx_elastic_equations
#define mbs_elastic_body mbs_cx_elastic_body
#define mbs_elastic_child mbs_cx_elastic_child
#define mbs_elastic_eliminate mbs_cx_elastic_eliminate
#define mbs_elastic_accelerations mbs_cx_elastic_accelerations
#define mbs_elastic_node_acceleration mbs_cx_elastic_node_acceleration
#define mbs_elastic_node_force mbs_cx_elastic_node_force
#define mbs_elastic_inverse mbs_cx_elastic_inverse
#define mbs_elastic_modal_force mbs_cx_elastic_modal_force
#define mbs_elastic_von_mises mbs_cx_elastic_von_mises
#else
typedef double real;
#define RE(x) (x)
#endif

/* ---- the compiled scene: two flat arrays reached through a table of sections, laid out as mbs_layout.h
 * declares (compiler/scene_file.py writes it from the same declaration) ---- */

struct MbsModel {
    char guid[FH_GUID_END_ - FH_GUID + 1];  /* the file's FH_GUID bytes, NUL-terminated */
    int32_t hdr[H_SIZE];
    const int32_t *ib, *iforce, *quat, *plain, *vars, *out, *prog, *code, *elastic_i, *stress_i;
    const double *D, *elastic_d, *stress_d;  /* defaults: the instance copies D */
    int n_elastic_i, n_elastic_d, nstress, n_stress_d;  /* nstress: rows of S_STRESS_I */
    const char **coord_name, **body_name, **var_name;  /* into the blob */
    const int32_t *read;               /* vr → offset into the instance's [y; ẏ; output points] block, -1 else */
    const double *vdom;                /* S_VDOM */
    const int32_t *rules;              /* S_RULES */
    const char *rule_names;            /* S_RULE_NAMES */
    const double *limits;              /* S_LIMITS */
    int nrules, n_rule_names;
    int32_t *first3;                   /* FMI 3.0 variable k: rows first3[k] .. first3[k + 1] - 1 (S_ARRAYS) */
    int nvars3;
    unsigned char *flexed;             /* per body: at a node of an elastic body or below one (S orthogonal only to
                                        * first order there, seed 004); NULL in rigid scenes */
    size_t *elastic_block;             /* per elastic body and one more: where its block starts in elastic.c's
                                        * workspace after the scratch (Block); NULL in rigid scenes */
    int dense;                         /* evaluation path (mbs_dense_path): 1 dense Jacobians (tree.c), 0 recursive (dynamics.c) */
    int stride;                        /* doubles of one body's workspace on that path */
    void *blob;                        /* owned copy of the compiled scene */
};

/* A body's int row (S_BODY_I) by name: a view of the MBS_BODY_I fields, which the checks below hold to the
 * layout's offsets at compile time (a field moved in mbs_layout.h without this view stops the build). */
typedef struct {
    int32_t parent, jtype, npos, nvel, massive, pos[7], vel[6], drv[7];
    int32_t rot, irot, irot_mask, elastic, node, carrier; /* see MBS_BODY_I */
} MbsBodyI;
#define MBS_VIEW_CHECK(name, cond) typedef char mbs_view_check_##name[(cond) ? 1 : -1]
#define MBS_BODY_FIELD(member, FIELD) \
    MBS_VIEW_CHECK(member, offsetof(MbsBodyI, member) == sizeof(int32_t) * FIELD && \
                   sizeof(((MbsBodyI *)0)->member) == sizeof(int32_t) * (FIELD##_END_ + 1 - FIELD))
MBS_BODY_FIELD(parent, IB_PARENT); MBS_BODY_FIELD(jtype, IB_JTYPE); MBS_BODY_FIELD(npos, IB_NPOS);
MBS_BODY_FIELD(nvel, IB_NVEL); MBS_BODY_FIELD(massive, IB_MASSIVE); MBS_BODY_FIELD(pos, IB_POS);
MBS_BODY_FIELD(vel, IB_VEL); MBS_BODY_FIELD(drv, IB_DRV); MBS_BODY_FIELD(rot, IB_ROT); MBS_BODY_FIELD(irot, IB_IROT);
MBS_BODY_FIELD(irot_mask, IB_IROT_MASK); MBS_BODY_FIELD(elastic, IB_ELASTIC); MBS_BODY_FIELD(node, IB_NODE);
MBS_BODY_FIELD(carrier, IB_CARRIER);
MBS_VIEW_CHECK(body_size, sizeof(MbsBodyI) == sizeof(int32_t) * IB);
static inline const MbsBodyI *mbs_body_i(const MbsModel *m, int i) { return (const MbsBodyI *)(m->ib + (size_t)i * IB); }

/* A force element's int row (S_FORCE_I) by name, checked the same way against MBS_FORCE_I */
typedef struct {
    int32_t type, a, b, frame, src, node_a, node_b; /* see MBS_FORCE_I */
} MbsForceI;
#define MBS_FORCE_FIELD(member, FIELD) \
    MBS_VIEW_CHECK(force_##member, offsetof(MbsForceI, member) == sizeof(int32_t) * FIELD && \
                   sizeof(((MbsForceI *)0)->member) == sizeof(int32_t) * (FIELD##_END_ + 1 - FIELD))
MBS_FORCE_FIELD(type, IF_TYPE); MBS_FORCE_FIELD(a, IF_A); MBS_FORCE_FIELD(b, IF_B); MBS_FORCE_FIELD(frame, IF_FRAME);
MBS_FORCE_FIELD(src, IF_SRC); MBS_FORCE_FIELD(node_a, IF_NODE_A); MBS_FORCE_FIELD(node_b, IF_NODE_B);
MBS_VIEW_CHECK(force_size, sizeof(MbsForceI) == sizeof(int32_t) * IF);
static inline const MbsForceI *mbs_force_i(const MbsModel *m, int k) { return (const MbsForceI *)(m->iforce + (size_t)k * IF); }

/* A body's and a force element's double rows of D by name, checked the same way against MBS_BODY_D and
 * MBS_FORCE_D (the bind programs write them as numbers of D; the engine reads fields) */
typedef struct {
    real a1[3], a2[3], at[3], R0[9], m, c[3], I[9];     /* derived: used per step */
    real a1_raw[3], a2_raw[3], rot_raw[9], irot_raw[9];  /* raw: written by the bind programs */
} MbsBodyD;
#define MBS_DOUBLE_FIELD(T, member, FIELD) \
    MBS_VIEW_CHECK(T##_##member, offsetof(T, member) == sizeof(real) * FIELD && \
                   sizeof(((T *)0)->member) == sizeof(real) * (FIELD##_END_ + 1 - FIELD))
MBS_DOUBLE_FIELD(MbsBodyD, a1, DB_A1); MBS_DOUBLE_FIELD(MbsBodyD, a2, DB_A2); MBS_DOUBLE_FIELD(MbsBodyD, at, DB_AT);
MBS_DOUBLE_FIELD(MbsBodyD, R0, DB_R0); MBS_DOUBLE_FIELD(MbsBodyD, m, DB_M); MBS_DOUBLE_FIELD(MbsBodyD, c, DB_C);
MBS_DOUBLE_FIELD(MbsBodyD, I, DB_I);
MBS_DOUBLE_FIELD(MbsBodyD, a1_raw, DB_A1_RAW);
MBS_DOUBLE_FIELD(MbsBodyD, a2_raw, DB_A2_RAW); MBS_DOUBLE_FIELD(MbsBodyD, rot_raw, DB_ROT_RAW);
MBS_DOUBLE_FIELD(MbsBodyD, irot_raw, DB_IROT_RAW);
MBS_VIEW_CHECK(bodyd_size, sizeof(MbsBodyD) == sizeof(real) * DB);
typedef struct {
    real k, d, l, at_a[3], at_b[3], vec[3];  /* see MBS_FORCE_D */
} MbsForceD;
MBS_DOUBLE_FIELD(MbsForceD, k, DF_K); MBS_DOUBLE_FIELD(MbsForceD, d, DF_D); MBS_DOUBLE_FIELD(MbsForceD, l, DF_L);
MBS_DOUBLE_FIELD(MbsForceD, at_a, DF_AT_A); MBS_DOUBLE_FIELD(MbsForceD, at_b, DF_AT_B);
MBS_DOUBLE_FIELD(MbsForceD, vec, DF_VEC);
MBS_VIEW_CHECK(forced_size, sizeof(MbsForceD) == sizeof(real) * DF);
static inline const MbsBodyD *mbs_body_row(const MbsModel *m, const real *D, int i) { return (const MbsBodyD *)(D + m->hdr[H_D_BODY] + (size_t)i * DB); }
static inline const MbsForceD *mbs_force_row(const MbsModel *m, const real *D, int k) { return (const MbsForceD *)(D + m->hdr[H_D_FORCE] + (size_t)k * DF); }

#define NB(m) ((m)->hdr[H_NB])
#define NPOS(m) ((m)->hdr[H_NPOS])
#define NVEL(m) ((m)->hdr[H_NVEL])

/* What the tree functions read and write for one evaluation: the model, the instance's bound numbers and
 * workspace. */
typedef struct {
    const MbsModel *m;
    const real *D;        /* bound numbers of the instance */
    const real *td;       /* time-dependent numbers: p, v, a per drive, then 3 per vector force slot */
    const real *x;        /* [y; ẏ] */
    const real *q_in;     /* generalized-force inputs (nvel) or NULL */
    real *work;           /* per body m->stride numbers, then 6 nvel scratch (dense path) */
    real *M, *k, *q, *xdot;
    void *elastic_work;   /* elastic.c's workspace (NULL for rigid scenes) */
} MbsEval;

/* per-body workspace layout (tree.c): the kinematics, then on the dense path the Jacobian rows J_R, J_T (3 × f
 * each), on the recursive path the articulated-body quantities (dynamics.c, spatial vectors at the world origin) */
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
#define AB_NV 26          /* free (not driven) velocity coordinates of the joint */
#define AB_S 27           /* their motion subspace S: 6 × nv, column after column */
#define AB_IA 63          /* spatial inertia, articulated (ABA) or composite (CRBA), 6 × 6 */
#define AB_P 99           /* bias force: I â + v ×* I v, gravity and accelerations of driven coordinates in â */
#define AB_F 105          /* applied spatial force (gravity, force elements) */
#define AB_W 111          /* U L⁻ᵀ, 6 × nv (U = I_A S, L Lᵀ = D = Sᵀ U; nv ≤ 5: a free joint's A⁻¹, B⁻¹ instead) */
#define AB_L 141          /* Cholesky factor L of D, nv × nv (nv ≤ 5: a free joint's factor of I_A is in AB_IA) */
#define AB_Z 166          /* L⁻¹ u (a free joint: its Δa) */
#define AB_ACC 172        /* spatial acceleration beyond the bias (Σ S ÿ of the path to the root) */
#define AB_MC 178         /* mass, centre of mass (body frame), inertia about it (body axes) of the body with the */
#define AB_CC 179         /* bodies welded to it (IB_CARRIER): written at bind time (mbs_composites), read per step */
#define AB_IC 182
#define AB_R0C 191        /* the joint frame (R0, at) in the frame of the parent's carrier if the parent is welded */
#define AB_ATC 200        /* (mbs_welded), else the parent's: written at bind time (mbs_composites) */
#define AB_SIZE 203

/* The evaluation path, chosen by the compiler (compiler/scene_file.py: dense_path) and read from the header here: the dense
 * equations (tree.c, elastic.c: per-body Jacobian rows, M assembled and factored: cubic in the coordinates) for
 * the smallest scenes, where they are the faster; the articulated-body algorithm (dynamics.c: linear in the
 * bodies) for the others. Either evaluates every scene. */
static inline int mbs_dense_path(const int32_t *hdr) { return hdr[H_DENSE] == 1; }
/* doubles of an instance's evaluation workspace: per body, scratch (two 3 × f Jacobians) and M on the dense path */
static inline double mbs_work_doubles(const int32_t *hdr)
{
    const double nb = hdr[H_NB], f = hdr[H_NVEL];
    return mbs_dense_path(hdr) ? nb * W_SIZE(f) + 6 * f + f * f : nb * AB_SIZE;
}
static inline real *mbs_body_work(const MbsEval *e, int i) { return e->work + (size_t)i * e->m->stride; }
/* On the recursive path the kinematics skip a body welded to a moving carrier (IB_CARRIER): the dynamics read only
 * the carriers, and its frame, where something reads it (mbs_point, a force's body axes), is its carrier's and the
 * constant offset AB_R0C, AB_ATC. */
static inline int mbs_welded(const MbsModel *m, int i)
{
    const int c = mbs_body_i(m, i)->carrier;
    return !m->dense && c >= 0 && c != i;
}
/* the dense path's M: the last f × f of the workspace (after the bodies and the 6 f scratch) */
static inline size_t mbs_work_M_offset(const int32_t *hdr) { return (size_t)hdr[H_NB] * W_SIZE(hdr[H_NVEL]) + 6 * (size_t)hdr[H_NVEL]; }

/* deriv.c: directional derivatives by complex step. At the state x (time numbers td, which hold the force inputs)
 * with the generalized-force inputs q_in (NULL: none), along the seeds dx, dq_in and dfin (the force inputs', 3 per
 * input; NULL: zero): the derivatives of ẋ, of the output points (6 each) and of the stresses into whichever of
 * dxdot, dout, dvm is not NULL. work: mbs_tangent_work_size bytes, which keep the bound numbers D between calls
 * (rebind: D changed since the last call). Returns 0 or MBS_F_SINGULAR. */
typedef struct {
    const double *D, *td, *x, *q_in, *dx, *dq_in, *dfin;
    double *dxdot, *dout, *dvm;
    int rebind;
} MbsTangent;
size_t mbs_tangent_work_size(const MbsModel *m);
int mbs_tangent(const MbsModel *m, const MbsTangent *t, void *work);

/* model.c */
typedef struct { int8_t npos, nvel, naxes, rot, gimbal; } MbsJointType;  /* a row of MBS_JOINTS (mbs_layout.h) */
extern const MbsJointType mbs_joints[J_N];
typedef struct { int8_t set, state, role; } MbsVarKind;  /* a row of MBS_VAR_KINDS: VK_* below */
enum { VK_READ = 0, VK_TUNABLE = 1, VK_FIXED = 2, VK_INPUT = 3, VK_KNOWN = 1, VK_UNKNOWN = 2 };
extern const MbsVarKind mbs_var_kinds[MBS_V_N];
const char *mbs_var_name_of(const MbsModel *m, int kind, int index); /* name of variable (MBS_V_*, index), "?" none */
/* expr.c: run the programs of one stage (0 bind: targets in D; 1 time: targets in td). NaN/Inf results
 * are left in place: callers check. */
int mbs_validate_code(const MbsModel *m, char *err, size_t errlen);
void mbs_run_programs(const MbsModel *m, int stage, double *D, double *td, double t);
/* tree.c: kinematics, the dense path's M and k, numbers derived at bind time */
const MbsBodyD *mbs_body_d(const MbsEval *e, int i);
void mbs_kinematics(const MbsEval *e);
void mbs_position_rates(const MbsEval *e);            /* ẏ_pos = Z(y) ẏ into e->xdot */
void mbs_point(const MbsEval *e, int i, const real *r_b, real *x, real *v, real *J);
void mbs_add_JtF(const MbsEval *e, int i, const real *J, const real *F, double sign, real *q);
void mbs_mass_matrix_and_bias(const MbsEval *e);
void mbs_derive(const MbsModel *m, double *D);        /* axes, rotations from the raw numbers */
void mbs_initial_state(const MbsModel *m, const double *D, double *x0);
/* forces.c */
void mbs_applied_forces(const MbsEval *e);
void mbs_body_force(const MbsEval *e, int i, const real *x, const real *F, double sign); /* F at x (x NULL: a torque) */
/* cholesky.c */
int mbs_cholesky(int n, real *M);                   /* M = L Lᵀ in place (lower); 0, or 1 if not positive definite */
void mbs_cholesky_apply(int n, const real *L, real *r); /* r ← (L Lᵀ)⁻¹ r */
int mbs_cholesky_solve(int n, real *M, real *r);
/* forward.c */
int mbs_eval_rhs(const MbsEval *e);                   /* ẋ: 0, or MBS_F_SINGULAR */
/* dynamics.c: the recursive path (!m->dense) */
void mbs_composites(const MbsModel *m, const real *D, real *work);  /* at bind: the carriers' inertias */
int mbs_aba(const MbsEval *e);                        /* ÿ into e->xdot: 0, or MBS_F_SINGULAR */
void mbs_crba_rnea(const MbsEval *e);                 /* M, k, q (inspection: mbs_equations) */
/* elastic.c (only for scenes with elastic bodies; F_ELASTIC) */
#ifdef MBS_WITH_ELASTIC
size_t mbs_elastic_work_size(const MbsModel *m);
void mbs_elastic_kinematics(const MbsEval *e, int body);     /* after the body's own frame is known */
/* attachment frame of child body c at node P of its elastic parent: S_P, r, ω, v, a, ᾱ, J_R, J_T (3 × f each) */
void mbs_elastic_node_frame(const MbsEval *e, int child, real *S_P, real *r, real *w, real *v,
                            real *a, real *al, real *J_R, real *J_T);
void mbs_elastic_node_point(const MbsEval *e, int body, int node, real *r, real *v, real *J_T);
void mbs_elastic_node_J_R(const MbsEval *e, int body, int node, real *J_R);
void mbs_elastic_equations(const MbsEval *e);               /* adds to M, k, q (dense path) */
/* the recursive path (dynamics.c; elastic.c says what each does) */
void mbs_elastic_body(const MbsEval *e, int body, real *IA, real *P, real *F);
void mbs_elastic_child(const MbsEval *e, int child, const real *I_c, const real *p_c);
int mbs_elastic_eliminate(const MbsEval *e, int body, real *IA, real *p);
void mbs_elastic_accelerations(const MbsEval *e, int body, const real *acc, real *ydd);
void mbs_elastic_node_acceleration(const MbsEval *e, int child, const real *ydd, real *acc);
void mbs_elastic_node_force(const MbsEval *e, int body, int node, const real *F, int torque, double sign);
void mbs_elastic_inverse(const MbsEval *e, int body, const real *acc, const real *ydd, int what, real *f);
void mbs_elastic_modal_force(const MbsEval *e, int body, real *out);
int mbs_elastic_validate(const MbsModel *m, char *err, size_t errlen);
/* at bind: structural parameters (they fed the beam generator) must keep their compiled values */
int mbs_elastic_changed_structure(const MbsModel *m, const double *D, double *compiled);  /* a structural parameter, -1 */
/* von Mises stress of stress node k (S_STRESS_I) at state x */
real mbs_elastic_von_mises(const MbsModel *m, int k, const real *x);
#endif

#endif
