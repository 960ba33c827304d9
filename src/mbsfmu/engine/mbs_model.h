/* Engine internals shared by model.c, expr.c, tree.c, elastic.c and sim.c.
 *
 * The compiled scene (written by engine/compile.py) is two flat arrays: I (int32) and D (double), reached
 * through a table of sections. The model keeps them read-only; every instance copies D, because the
 * parameters of an instance re-bind the numbers in its copy (bind programs), and keeps its own workspace
 * (Pinocchio's Model/Data split: nothing is written into the model during evaluation).
 */
#ifndef MBS_MODEL_H
#define MBS_MODEL_H

#include <stdint.h>
#include "mbs_engine.h"

/* ---- the compiled scene: "MBSC", int32 format version, char guid[64], int32 nsec, then nsec rows
 * {int32 id, int32 kind (0 int32, 1 double), int64 byte offset, int64 count}, then the data (8-aligned) ----
 * section ids (compile.py: SECTIONS mirrors this list) */
enum {
    S_HEADER = 0,   /* H_SIZE        int   counts and D offsets (below) */
    S_BODY_I = 1,   /* nb × IB        int   */
    S_FORCE_I,      /* nforce × IF    int   */
    S_QUAT,         /* nquat × 7      int   4 position, 3 velocity indices of each quaternion */
    S_PLAIN,        /* 2 × nplain     int   position indices, then their velocity indices */
    S_VARS,         /* nvars × 2      int   kind (MBS_V_*), index */
    S_OUT_I,        /* nout × 3       int   body, node (-1: point), quantities (1 position, 2 velocity) */
    S_PROG,         /* nprog × 4      int   stage (0 bind, 1 time), target, code offset, code length */
    S_CODE,         /* ncode          int   bytecode: (op, arg) pairs */
    S_ELASTIC_I,    /* elastic.c */
    S_D,            /* all numbers    double (layout below) */
    S_ELASTIC_D,    /* elastic.c (double) */
    S_NAMES,        /* bytes: npos coordinate, nb body, nvars variable names, each NUL-terminated (messages) */
    S_VDOM,         /* 6 × 3          double  domain of each settable kind MBS_V_PARAM .. MBS_V_STEP: lo, hi, flags (VD_*) */
    S_RULES,        /* nrules × 3     int   rule (R_*), D offset of its first number (R_CARRIES: body), path */
    S_RULE_NAMES,   /* bytes: the rules' scene paths, NUL-terminated (S_RULES holds their offsets) */
    S_LIMITS,       /* LIM_N          double  the limits the rules use (below) */
    S_NSECTIONS
};

/* header scalars (I[0..H_SIZE-1]) */
enum { H_NB, H_NPOS, H_NVEL, H_NFORCE, H_NQUAT, H_NPLAIN, H_NDRV, H_NVEC, H_NINPUT, H_NPARAM, H_NVARS, H_NOUT,
       H_NPROG, H_NCODE, H_HAS_GRAVITY, H_METHOD, H_NCARDAN, H_FEATURES, H_MAXSTACK,
       /* offsets into D */
       H_D_PARAM, H_D_CONST, H_D_BODY, H_D_FORCE, H_D_G, H_D_X0, H_D_OUT, H_D_INTEG, H_ND,
       H_SIZE };

/* feature bits (H_FEATURES): which optional parts of the engine the scene needs */
enum { F_EXPR = 1, F_ELASTIC = 2 };

enum { J_FIXED, J_REVOLUTE, J_PRISMATIC, J_CYLINDRICAL, J_UNIVERSAL, J_PLANAR,
       J_SPH_QUAT, J_SPH_CARDAN, J_FREE_QUAT, J_FREE_CARDAN };
enum { FE_JOINT_SPRING, FE_SPRING, FE_FORCE, FE_TORQUE };

/* int table per body */
enum { IB_PARENT, IB_JTYPE, IB_NPOS, IB_NVEL, IB_MASSIVE, IB_POS, IB_VEL = IB_POS + 7, IB_DRV = IB_VEL + 6,
       IB_ROT = IB_DRV + 7,  /* joint-frame rotation: 0 none, 1 axis-angle (raw: axis 3, angle), 2 matrix (raw 9) */
       IB_IROT,              /* initial rotation of spherical/free joints: same codes */
       IB_IROT_MASK,         /* Cardan: bit k set = angle k comes from the initial rotation */
       IB_ELASTIC,           /* index of the body's elastic data, -1 rigid */
       IB_NODE,              /* node of the elastic parent the joint sits at, -1 none */
       IB };
/* double table per body: derived (used per step), then raw (written by bind programs) */
enum { DB_A1, DB_A2 = 3, DB_AT = 6, DB_R0 = 9, DB_M = 18, DB_C = 19, DB_I = 22,
       DB_A1_RAW = 31, DB_A2_RAW = 34, DB_ROT_RAW = 37, DB_IROT_RAW = 46, DB = 55 };
/* force tables */
enum { IF_TYPE, IF_A, IF_B, IF_FRAME, IF_SRC, IF_NODE_A, IF_NODE_B, IF };  /* IF_SRC: -1 constant, else td slot (3) */
enum { DF_K, DF_D, DF_L, DF_AT_A = 3, DF_AT_B = 6, DF_VEC = 9, DF = 12 };
/* integrator defaults in D (H_D_INTEG) */
enum { DI_RTOL, DI_ATOL, DI_MAX_STEP, DI_STEP, DI_RHO_INF, DI };

/* Domains (scene/domains.py declares them; the loader applies them to a scene's numbers, sim.c to a host's):
 * a variable's domain is lo..hi, 0 besides with VD_ZERO, always finite; a rule holds for the numbers a
 * parameter derives (R_* = domains.NONNEG ...; numbers per rule: domains.RULE_SIZE). */
enum { VD_LO_OPEN = 1, VD_HI_OPEN = 2, VD_ZERO = 4 };
enum { R_NONNEG, R_MAGNITUDE, R_INERTIA, R_AXIS, R_ROTATION, R_CARRIES, R_TIMED, R_PERPENDICULAR, R_NOT_PARALLEL,
       R_N };  /* R_TIMED: a td slot */
/* S_LIMITS: the scene's experiment and the sample count of R_TIMED (limits.DOMAIN_SAMPLES), limits.MAGNITUDE,
 * limits.AXIS_LENGTH */
enum { LIM_START, LIM_STOP, LIM_SAMPLES, LIM_MAGNITUDE_LO, LIM_MAGNITUDE_HI, LIM_AXIS_LO, LIM_AXIS_HI, LIM_N };
int mbs_rules_validate(const MbsModel *m, char *err, size_t errlen);  /* sim.c: at load, every row in range */

/* bytecode */
enum { OP_CONST, OP_PARAM, OP_TIME, OP_NEG, OP_ADD, OP_SUB, OP_MUL, OP_DIV, OP_POW, OP_CALL1, OP_CALL2,
       OP_SEL_MIN, OP_SEL_MAX, OP_N };
enum { FN_SIN, FN_COS, FN_TAN, FN_ASIN, FN_ACOS, FN_ATAN, FN_SINH, FN_COSH, FN_TANH, FN_EXP, FN_LOG, FN_SQRT,
       FN_ABS, FN_N1 };
enum { FN_ATAN2, FN_MIN, FN_MAX, FN_N2 };
#define MBS_MAXSTACK 64
/* bytes of per-instance workspace a scene may need (dense per-body Jacobians and M; compile.py: MAX_WORKSPACE
 * refuses a larger scene first, with its size) */
#define MBS_MAX_WORKSPACE (1 << 30)

struct MbsModel {
    char guid[64];
    int32_t hdr[H_SIZE];
    const int32_t *ib, *iforce, *quat, *plain, *vars, *out, *prog, *code, *elastic_i;
    const double *D, *elastic_d;      /* defaults: the instance copies D */
    int n_elastic_i, n_elastic_d;
    const char **coord_name, **body_name, **var_name;  /* into the blob */
    const int32_t *read;               /* vr → offset into the instance's [y; ẏ; output points] block, -1 else */
    const double *vdom;                /* S_VDOM */
    const int32_t *rules;              /* S_RULES */
    const char *rule_names;            /* S_RULE_NAMES */
    const double *limits;              /* S_LIMITS */
    int nrules, n_rule_names;
    void *blob;                        /* owned copy of the compiled scene */
};

#define NB(m) ((m)->hdr[H_NB])
#define NPOS(m) ((m)->hdr[H_NPOS])
#define NVEL(m) ((m)->hdr[H_NVEL])

/* What the tree functions read and write for one evaluation: the model, the instance's bound numbers and
 * workspace. */
typedef struct {
    const MbsModel *m;
    const double *D;      /* bound numbers of the instance */
    const double *td;     /* time-dependent numbers: p, v, a per drive, then 3 per vector force slot */
    const double *x;      /* [y; ẏ] */
    const double *q_in;   /* generalized-force inputs (nvel) or NULL */
    double *work;         /* per body W_SIZE(nvel), then 6 nvel scratch */
    double *M, *k, *q, *xdot;
    void *elastic_work;   /* elastic.c's workspace (NULL for rigid scenes) */
} MbsEval;

/* per-body workspace layout (tree.c) */
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

/* model.c */
const double *mbs_body_d(const MbsEval *e, int i);
/* expr.c: run the programs of one stage (0 bind: targets in D; 1 time: targets in td). NaN/Inf results
 * are left in place: callers check. */
int mbs_validate_code(const MbsModel *m, char *err, size_t errlen);
void mbs_run_programs(const MbsModel *m, int stage, double *D, double *td, double t);
/* tree.c */
void mbs_kinematics(const MbsEval *e);
void mbs_mass_matrix_and_bias(const MbsEval *e);
void mbs_applied_forces(const MbsEval *e);
int mbs_eval_rhs(const MbsEval *e);                   /* 0, or MBS_F_SINGULAR */
int mbs_cholesky_solve(int n, double *M, double *r);
void mbs_point(const MbsEval *e, int i, const double *r_b, double *x, double *v, double *J);
void mbs_add_JtF(const MbsEval *e, int i, const double *J, const double *F, double sign, double *q);
void mbs_derive(const MbsModel *m, double *D);        /* axes, rotations from the raw numbers */
void mbs_initial_state(const MbsModel *m, const double *D, double *x0);
/* elastic.c (only for scenes with elastic bodies; F_ELASTIC) */
#ifdef MBS_WITH_ELASTIC
size_t mbs_elastic_work_size(const MbsModel *m);
void mbs_elastic_kinematics(const MbsEval *e, int body);     /* after the body's own frame is known */
/* attachment frame of child body c at node P of its elastic parent: S_P, r, ω, v, a, ᾱ, J_R, J_T (3 × f each) */
void mbs_elastic_node_frame(const MbsEval *e, int child, double *S_P, double *r, double *w, double *v,
                            double *a, double *al, double *J_R, double *J_T);
void mbs_elastic_node_point(const MbsEval *e, int body, int node, double *r, double *v, double *J_T);
void mbs_elastic_node_J_R(const MbsEval *e, int body, int node, double *J_R);
void mbs_elastic_equations(const MbsEval *e);               /* adds to M, k, q */
int mbs_elastic_validate(const MbsModel *m, char *err, size_t errlen);
/* at bind: structural parameters (they fed the beam generator) must keep their compiled values */
int mbs_elastic_bind(const MbsModel *m, const double *D, char *err, size_t errlen);
#endif

#endif
