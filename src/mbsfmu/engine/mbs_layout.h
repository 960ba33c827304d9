/* The compiled scene's layout, declared once (issue 23): every section id, table field, type code and size
 * that Python writes (compiler/scene_file.py, compiler/elastic_tables.py) and C reads. The C side gets enums from the lists below;
 * Python reads this file with a strict parser (engine/layout.py, as MuJoCo's mjxmacro.h), so there is no
 * generation step and a native FMU's sources/ carry it as it is.
 *
 * Only four kinds of lines may appear (layout.py refuses anything else):
 *   #define NAME integer                      a constant
 *   #define NAME "TEXT"                       a text constant (letters, digits, _ and .)
 *   #define MBS_LIST(X) X(NAME, args) ...     a list; args are integers, "strings" (Python's names for a code)
 *                                             or C identifiers
 *   enum { MBS_LIST(MBS_CODE) [TOTAL] };      codes 0, 1, ... (TOTAL: their count)
 *   enum { MBS_LIST(MBS_FIELD) TOTAL };       fields of a row, first arg their width: offsets, TOTAL the row size
 *   enum { MBS_LIST(MBS_VALUE) };             first arg the value (bit flags)
 * plus comments, the include guard and the generator macros (MBS_CODE, MBS_FIELD, MBS_VALUE and their helpers).
 */
#ifndef MBS_LAYOUT_H
#define MBS_LAYOUT_H

#define MBS_CODE(...) MBS_CODE_(__VA_ARGS__, ~)
#define MBS_CODE_(name, ...) name,
#define MBS_FIELD(name, width) name, name##_END_ = name + (width) - 1,
#define MBS_VALUE(...) MBS_VALUE_(__VA_ARGS__, ~)
#define MBS_VALUE_(name, value, ...) name = (value),

#define MBS_FORMAT_VERSION 5 /* version of the compiled-scene layout this engine reads (2: H_D_NOMINAL; 3: H_NCARRIER, IB_CARRIER; 4: S_ARRAYS; 5: H_DENSE) */
#define MBS_MAXSTACK 64
/* bytes of per-instance workspace a scene may need (dense per-body Jacobians and M; compile.py refuses a
 * larger scene first, with its size) */
#define MBS_MAX_WORKSPACE 1073741824

/* The file: its head, then FH_NSEC section rows, then the data (8-aligned, little-endian). Its head (bytes): */
#define MBS_SCENE_MAGIC "MBSC"
#define MBS_FILE_HEAD(X) X(FH_MAGIC, 4) X(FH_VERSION, 4) /* int32: MBS_FORMAT_VERSION */ \
    X(FH_GUID, 64)   /* NUL-padded */ \
    X(FH_NSEC, 4)    /* int32: the number of section rows, 1 .. MBS_MAX_SECTIONS */
enum { MBS_FILE_HEAD(MBS_FIELD) FH_SIZE };
#define MBS_MAX_SECTIONS 64
/* a section row (bytes): int32 id, int32 kind (0 int32, 1 double, 2 bytes), int64 byte offset, int64 count */
#define MBS_SECTION_ROW(X) X(SR_ID, 4) X(SR_KIND, 4) X(SR_OFFSET, 8) X(SR_COUNT, 8)
enum { MBS_SECTION_ROW(MBS_FIELD) SR_SIZE };
/* Section ids, with kind: */
#define MBS_SECTIONS(X) \
    X(S_HEADER, 0)      /* H_SIZE: counts and D offsets (below) */ \
    X(S_BODY_I, 0)      /* nb × IB */ \
    X(S_FORCE_I, 0)     /* nforce × IF */ \
    X(S_QUAT, 0)        /* nquat × 7: 4 position, 3 velocity indices of each quaternion */ \
    X(S_PLAIN, 0)       /* 2 × nplain: position indices, then their velocity indices */ \
    X(S_VARS, 0)        /* nvars × 2: kind (MBS_V_*), index */ \
    X(S_OUT_I, 0)       /* nout × 3: body, node (-1: point), quantities (1 position, 2 velocity) */ \
    X(S_PROG, 0)        /* nprog × 4: stage (0 bind, 1 time), target, code offset, code length */ \
    X(S_CODE, 0)        /* ncode: bytecode, (op, arg) pairs */ \
    X(S_ELASTIC_I, 0)   /* EH header, NE × EI rows, NFIX parameter indices (compiler/elastic_tables.py) */ \
    X(S_D, 1)           /* all numbers: parameters, constants, then the regions at the H_D_* offsets */ \
    X(S_ELASTIC_D, 1)   /* elastic bodies' invariants and node data (compiler/elastic_tables.py) */ \
    X(S_NAMES, 2)       /* npos coordinate, nb body, nvars variable names, each NUL-terminated (messages) */ \
    X(S_VDOM, 1)        /* 6 × 3: domain of each settable kind MBS_V_PARAM .. MBS_V_STEP: lo, hi, flags (VD_*) */ \
    X(S_RULES, 0)       /* nrules × 3: rule (R_*), D offset of its first number (R_CARRIES: body), path */ \
    X(S_RULE_NAMES, 2)  /* the rules' scene paths, NUL-terminated (S_RULES holds their offsets) */ \
    X(S_LIMITS, 1)      /* LIM_N: the limits the rules use (below) */ \
    X(S_STRESS_I, 0)    /* nstress × 2: elastic data index, offset in S_STRESS_D (only with stress outputs) */ \
    X(S_STRESS_D, 1)    /* per stress node its 6 × n stress modes, Voigt xx yy zz xy yz zx (compiler/elastic_tables.py) */ \
    X(S_ARRAYS, 0)      /* narrays × 2: first S_VARS row, rows: FMI 3.0's arrays (compiler/variables.py: fmi3_variables) */
enum { MBS_SECTIONS(MBS_CODE) S_NSECTIONS };

/* header scalars (S_HEADER); H_D_*: offsets into D */
#define MBS_HEADER(X) \
    X(H_NB) X(H_NPOS) X(H_NVEL) X(H_NFORCE) X(H_NQUAT) X(H_NPLAIN) X(H_NDRV) X(H_NVEC) X(H_NINPUT) X(H_NPARAM) \
    X(H_NVARS) X(H_NOUT) X(H_NPROG) X(H_NCODE) X(H_HAS_GRAVITY) X(H_METHOD) X(H_NCARDAN) X(H_NCARRIER) X(H_FEATURES) X(H_DENSE) \
    X(H_MAXSTACK) X(H_D_PARAM) X(H_D_CONST) X(H_D_BODY) X(H_D_FORCE) X(H_D_G) X(H_D_X0) X(H_D_NOMINAL) \
    X(H_D_OUT) X(H_D_INTEG) \
    X(H_ND)
enum { MBS_HEADER(MBS_CODE) H_SIZE };

/* feature bits (H_FEATURES): which optional parts of the engine the scene needs */
#define MBS_FEATURES(X) X(F_EXPR, 1, "expr") X(F_ELASTIC, 2, "elastic")
enum { MBS_FEATURES(MBS_VALUE) };

/* joint types: the scene's joint and, for spherical/free joints, their parametrization; position and velocity
 * coordinates (kinematics/joints.py's npos, nvel); the axes it reads (0, 1: axis, 2: axes); where its orientation
 * starts among its positions (-1: none; a quaternion's 4 or Cardan angles' 3); where its Cardan angle b is (the
 * gimbal lock at b = ±90°; -1: no Cardan angles). model.c holds them as mbs_joints. */
#define MBS_JOINTS(X) \
    X(J_FIXED, "fixed", "", 0, 0, 0, -1, -1) X(J_REVOLUTE, "revolute", "", 1, 1, 1, -1, -1) \
    X(J_PRISMATIC, "prismatic", "", 1, 1, 1, -1, -1) X(J_CYLINDRICAL, "cylindrical", "", 2, 2, 1, -1, -1) \
    X(J_UNIVERSAL, "universal", "", 2, 2, 2, -1, -1) X(J_PLANAR, "planar", "", 3, 3, 2, -1, -1) \
    X(J_SPH_QUAT, "spherical", "quaternion", 4, 3, 0, 0, -1) X(J_SPH_CARDAN, "spherical", "cardan", 3, 3, 0, 0, 1) \
    X(J_FREE_QUAT, "free", "quaternion", 7, 6, 0, 3, -1) X(J_FREE_CARDAN, "free", "cardan", 6, 6, 0, 3, 4)
enum { MBS_JOINTS(MBS_CODE) J_N };

/* force element types (the scene's force `type`) */
#define MBS_FORCES(X) \
    X(FE_JOINT_SPRING, "joint_spring_damper") X(FE_SPRING, "spring_damper") X(FE_FORCE, "force") \
    X(FE_TORQUE, "torque")
enum { MBS_FORCES(MBS_CODE) FE_N };

/* int row per body (S_BODY_I): field, width */
#define MBS_BODY_I(X) \
    X(IB_PARENT, 1) X(IB_JTYPE, 1) X(IB_NPOS, 1) X(IB_NVEL, 1) X(IB_MASSIVE, 1) \
    X(IB_POS, 7) X(IB_VEL, 6) X(IB_DRV, 7) \
    X(IB_ROT, 1)        /* joint-frame rotation: 0 none, 1 axis-angle (raw: axis 3, angle), 2 matrix (raw 9) */ \
    X(IB_IROT, 1)       /* initial rotation of spherical/free joints: same codes */ \
    X(IB_IROT_MASK, 1)  /* Cardan: bit k set = angle k comes from the initial rotation */ \
    X(IB_ELASTIC, 1)    /* index of the body's elastic data, -1 rigid */ \
    X(IB_NODE, 1)       /* node of the elastic parent the joint sits at, -1 none */ \
    X(IB_CARRIER, 1)    /* the body that carries it (compiler/scene_file.py: carriers): itself, its parent's carrier, -1 world */
enum { MBS_BODY_I(MBS_FIELD) IB };

/* double row per body: derived (used per step), then raw (written by bind programs) */
#define MBS_BODY_D(X) \
    X(DB_A1, 3) X(DB_A2, 3) X(DB_AT, 3) X(DB_R0, 9) X(DB_M, 1) X(DB_C, 3) X(DB_I, 9) \
    X(DB_A1_RAW, 3) X(DB_A2_RAW, 3) X(DB_ROT_RAW, 9) X(DB_IROT_RAW, 9)
enum { MBS_BODY_D(MBS_FIELD) DB };

/* force rows; IF_SRC: -1 constant, else the td slot (3) */
#define MBS_FORCE_I(X) \
    X(IF_TYPE, 1) X(IF_A, 1) X(IF_B, 1) X(IF_FRAME, 1) X(IF_SRC, 1) X(IF_NODE_A, 1) X(IF_NODE_B, 1)
enum { MBS_FORCE_I(MBS_FIELD) IF };
#define MBS_FORCE_D(X) X(DF_K, 1) X(DF_D, 1) X(DF_L, 1) X(DF_AT_A, 3) X(DF_AT_B, 3) X(DF_VEC, 3)
enum { MBS_FORCE_D(MBS_FIELD) DF };

/* integrator defaults in D (H_D_INTEG) */
#define MBS_INTEG_D(X) X(DI_RTOL) X(DI_ATOL) X(DI_MAX_STEP) X(DI_STEP) X(DI_RHO_INF)
enum { MBS_INTEG_D(MBS_CODE) DI };

/* the integrators (H_METHOD, the integrator.method variable): name, the class that implements it
 * (mbs_<class>_class, integ_base.h), and what sets its accuracy: "tolerance" (rtol, atol: adaptive) or "step"
 * (integrator.step: fixed steps) */
#define MBS_METHODS(X) \
    X(MBS_RK4, "rk4", rk4, "step") X(MBS_DOPRI5, "dopri5", dopri5, "tolerance") \
    X(MBS_DOP853, "dop853", dop853, "tolerance") X(MBS_RADAU5, "radau5", radau5, "tolerance") \
    X(MBS_GEN_ALPHA, "gen_alpha", gen_alpha, "step") X(MBS_AUTO, "auto", auto, "tolerance")
enum { MBS_METHODS(MBS_CODE) MBS_NMETHODS };

/* kinds of variables (S_VARS; value reference = row index): the variable's name for the settable integrator
 * settings; how a host sets it (0 not, 1 a tunable parameter, 2 a fixed one: before initialization, 3 an input);
 * whether its value follows from the state (before initialization: from the initial state); its role in
 * directional derivatives (1 a known, 2 an unknown, 3 both). MBS_V_DER: the time derivative of state entry
 * `index` of [y; ẏ] (the FMUs with model exchange declare them); MBS_V_VM: the von Mises stress of stress node
 * `index` (S_STRESS_I). model.c holds them as mbs_var_kinds. */
#define MBS_VAR_KINDS(X) \
    X(MBS_V_PARAM, "", 1, 0, 0) X(MBS_V_METHOD, "integrator.method", 2, 0, 0) X(MBS_V_RTOL, "integrator.rtol", 2, 0, 0) \
    X(MBS_V_ATOL, "integrator.atol", 2, 0, 0) X(MBS_V_MAX_STEP, "integrator.max_step", 2, 0, 0) \
    X(MBS_V_STEP, "integrator.step", 2, 0, 0) X(MBS_V_QIN, "", 3, 0, 1) X(MBS_V_FIN, "", 3, 0, 1) \
    X(MBS_V_Y, "", 0, 1, 3) X(MBS_V_YD, "", 0, 1, 3) X(MBS_V_OUT, "", 0, 1, 2) X(MBS_V_DER, "", 0, 1, 2) \
    X(MBS_V_VM, "", 0, 1, 2)
enum { MBS_VAR_KINDS(MBS_CODE) MBS_V_N };

/* Domains (scene/domains.py declares them; the loader applies them to a scene's numbers, rules.c to a host's):
 * a variable's domain is lo..hi, 0 besides with VD_ZERO, always finite; a rule holds for the numbers a
 * parameter derives, each rule with how many consecutive numbers of D it reads (0: a body or a td slot). */
#define MBS_VDOM_FLAGS(X) X(VD_LO_OPEN, 1) X(VD_HI_OPEN, 2) X(VD_ZERO, 4)
enum { MBS_VDOM_FLAGS(MBS_VALUE) };
#define MBS_RULES(X) \
    X(R_NONNEG, 1) X(R_MAGNITUDE, 1) X(R_INERTIA, 9) X(R_AXIS, 3) X(R_ROTATION, 9) X(R_CARRIES, 0) \
    X(R_TIMED, 0)       /* a td slot */ \
    X(R_PERPENDICULAR, 6) X(R_NOT_PARALLEL, 6)
enum { MBS_RULES(MBS_CODE) R_N };
/* S_LIMITS: the scene's experiment and the sample count of R_TIMED (limits.DOMAIN_SAMPLES), limits.MAGNITUDE,
 * limits.AXIS_LENGTH */
#define MBS_LIMITS(X) \
    X(LIM_START) X(LIM_STOP) X(LIM_SAMPLES) X(LIM_MAGNITUDE_LO) X(LIM_MAGNITUDE_HI) X(LIM_AXIS_LO) X(LIM_AXIS_HI)
enum { MBS_LIMITS(MBS_CODE) LIM_N };

/* bytecode: ops, and the functions of one and two arguments by their names in expressions */
#define MBS_OPS(X) \
    X(OP_CONST) X(OP_PARAM) X(OP_TIME) X(OP_NEG) X(OP_ADD) X(OP_SUB) X(OP_MUL) X(OP_DIV) X(OP_POW) X(OP_CALL1) \
    X(OP_CALL2) X(OP_SEL_MIN) X(OP_SEL_MAX)
enum { MBS_OPS(MBS_CODE) OP_N };
#define MBS_FN1(X) \
    X(FN_SIN, "sin") X(FN_COS, "cos") X(FN_TAN, "tan") X(FN_ASIN, "asin") X(FN_ACOS, "acos") X(FN_ATAN, "atan") \
    X(FN_SINH, "sinh") X(FN_COSH, "cosh") X(FN_TANH, "tanh") X(FN_EXP, "exp") X(FN_LOG, "log") \
    X(FN_SQRT, "sqrt") X(FN_ABS, "abs")
enum { MBS_FN1(MBS_CODE) FN_N1 };
#define MBS_FN2(X) X(FN_ATAN2, "atan2") X(FN_MIN, "min") X(FN_MAX, "max")
enum { MBS_FN2(MBS_CODE) FN_N2 };

/* S_ELASTIC_I: header, then one row per elastic body (its doubles start at EI_D in S_ELASTIC_D) */
#define MBS_ELASTIC_H(X) X(EH_NE) X(EH_NFIX)
enum { MBS_ELASTIC_H(MBS_CODE) EH };
#define MBS_ELASTIC_I(X) X(EI_BODY) X(EI_N) X(EI_NODES) X(EI_Q) X(EI_QD) X(EI_STIFF) X(EI_D)
enum { MBS_ELASTIC_I(MBS_CODE) EI };

/* S_ELASTIC_D: per elastic body at its EI_D offset these arrays in this order (compiler/elastic_tables.py), each of
 * size + per_mode·n + per_mode2·n² numbers for n modes (row-major, R components; G as [i][l][k] = G_ikl, B as
 * [i][j][l][k] = B_ijkl: the index contracted with q innermost); the last column 1: only with EI_STIFF; then
 * per node R_RP (3), Φ_P (3 × n), Ψ_P (3 × n); after the bodies the NFIX parameter values the data were computed with */
#define MBS_ELASTIC_D(X) \
    X(ED_M, 1, 0, 0, 0) X(ED_S0, 3, 0, 0, 0) X(ED_S_RR, 9, 0, 0, 0) X(ED_J_SUM, 9, 0, 0, 0) X(ED_C_T, 0, 3, 0, 0) \
    X(ED_A, 0, 9, 0, 0) X(ED_C_R0, 0, 3, 0, 0) X(ED_JPSI, 0, 3, 0, 0) X(ED_G, 0, 0, 3, 0) X(ED_B, 0, 0, 9, 0) \
    X(ED_M_EE, 0, 0, 1, 0) X(ED_K, 0, 0, 1, 0) X(ED_D, 0, 0, 1, 0) X(ED_K_A, 0, 0, 1, 1) X(ED_K_W, 0, 0, 1, 1)
enum { MBS_ELASTIC_D(MBS_CODE) ED_N };
#endif
