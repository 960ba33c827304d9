/* Inside the integrators: the common driver (integ_base.c) and the methods plugged into it.
 *
 * HOW TO WRITE A METHOD (integ_<name>.c defines `const MbsMethodClass mbs_<name>_class`)
 * --------------------------------------------------------------------------------------
 * The driver does what every method shares: option checks, reset, advance to exact communication
 * points (clip to t_end, the "stretch by 1 %" rule, unclipped h carried over, max_steps and underflow
 * messages), dense output (the ahead point and its segment), normalization after every accepted step,
 * stats, snapshots.  A method supplies the hooks (and its name in mbs_layout.h's MBS_METHODS):
 *
 *   sizes(n, nvel, opt, &sz)   how much memory: sz->state (bytes of the method's POD history struct),
 *                              sz->hist / sz->hist_int (doubles / ints of history arrays), sz->work /
 *                              sz->work_int (doubles / ints of scratch), sz->view (bytes of the method's
 *                              pointer struct).  Called once, before allocation, in mbs_integ_new.
 *   init(it, err, errlen)      after allocation: check method options (return 1 with a message in err),
 *                              set constants (e.g. radau5's rtol transformation changes it->rtol/atol),
 *                              carve arrays: fill the pointer struct it->view from it->ha, it->hi (history)
 *                              and it->wa, it->wi (scratch) at FIXED offsets (the same for equal n).
 *   reset_history(it)          forget everything method-specific (called by mbs_integ_reset).
 *   invalidate_derivative(it)  cached derivatives are stale (inputs_changed, or the ahead point dropped).
 *   start(it, t_end)           make the derivative at (t, x) and a proposed c->h exist (c->has_h = 1):
 *                              mbs_integ_f + mbs_integ_check_start, mbs_integ_initial_step on the
 *                              first call.  0, or 1 = failure with the message set.
 *   attempt(it, t_new, h, x_new)  one trial step from (c->t, it->x) to t_new = t + h (h exactly t_new - t).
 *                              Set c->h to the proposal for the next step (accepted or not) and return
 *                              MBS_ACCEPT with x_new filled, MBS_REJECT (the driver counts it and retries
 *                              with c->h), or MBS_FAIL (message set: stop now, e.g. f returned SINGULAR).
 *                              Non-finite error estimate: return mbs_integ_trial_nonfinite(it, h, what).
 *                              Set c->last_failure (MBS_LAST_ERROR / MBS_LAST_NEWTON) on rejection.
 *   accepted(it)               after (c->t, it->x) moved to the accepted, normalized point.  0 or 1 (fail).
 *   dense_coeffs(it, t_old, x_old, x_new, h, Q)   only when dense_rows > 0: write the dense_rows × n
 *                              coefficients (row-major, row r at Q + r*n) of the continuous extension
 *                              of the step just accepted; the stages are still in the scratch arrays.
 *                              0 or 1 (fail; dop853 evaluates f for its extra stages).
 *   dense_eval(it, Q, theta, x)   x(t_old + theta·h) from Q (called once per interpolated point; plain C,
 *                              so no separate "weights for many theta" hook is needed).
 *   stop_early(it)             1 makes the driver return before t_end (dopri5 in auto: stiffness found).
 *   advance(it, t_end)         NULL: the adaptive driver.  Fixed-step methods (rk4, gen_alpha with h)
 *                              put their own loop here; they may call mbs_integ_adaptive(it, t_end) for
 *                              the adaptive case.  0, or 1 = failure (integrator at the last good point).
 *   check(it, ms, hi)          snapshot loading: ms is a candidate method POD struct, hi the candidate
 *                              int history arrays (same offsets as it->hi).  Return 0 when every integer
 *                              field is in range (flags 0/1, counters >= 0, LU pivots valid via
 *                              mbs_lu_pivots_valid, ...), else 1.  Doubles need no check (NaN is harmless).
 *
 * THE HISTORY RULE.  Everything that influences future results lives in
 *   - the common POD struct MbsCommon (it->c: t, h, ahead point, stats, ...),
 *   - the method's POD struct (it->ms, sz.state bytes: ints and doubles, NO pointers),
 *   - double / int arrays carved from the history block (it->ha: sz.hist doubles, it->hi: sz.hist_int ints),
 * which are all one contiguous block (it->hist, it->hist_bytes): a snapshot is a copy of those bytes, and a
 * restored run repeats bit for bit.  Scratch that never carries information from one advance call to the
 * next (stages, Newton iterates, the trial x_new) lives in the work block (it->wa, it->wi).  Nothing is
 * allocated after mbs_integ_new and nothing big is cleared per step.
 *
 * HELPERS a method calls: mbs_integ_f (ode->f, counted; on failure sets the ODE's message), mbs_err_norm,
 * mbs_integ_observe (a fixed-step advance, after each accepted step),
 * mbs_integ_initial_step, mbs_integ_check_start, mbs_integ_trial_nonfinite, mbs_all_finite,
 * mbs_integ_fixed_substeps (rk4/gen_alpha), mbs_integ_normalize, mbs_pymin/mbs_pymax (Python's NaN
 * semantics), and the message builders mbs_msg_* (no stdio: messages are built by appending strings and
 * numbers formatted like Python's {v:.3g} / {v:g}).  Messages are bare (no "t=...:" prefix; the caller
 * knows mbs_integ_t).  Stats: count c->jac_evaluations / c->lu_decompositions yourself (rhs evaluations
 * are counted by mbs_integ_f); steps and rejections are counted by the driver (by a fixed-step advance).
 *
 * REGISTRATION: one entry in mbs_layout.h's MBS_METHODS (code, name, class, "tolerance" or "step") and a file
 * integ_<name>.c that defines mbs_<class>_class with .ops = &mbs_single_ops; integ_base.c's table, the engine's
 * names, Python's lists (loader, compiler, CLI, benchmarks, docs' check) and build.py (integ_*.c) follow. rk4,
 * dopri5, dop853 live in integ_erk.c; auto (integ_auto.c) is a composite (its own MbsIntegOps) of a dopri5 child
 * with stop_when_stiff and a radau5 child; it sets the radau5 child's c->h/has_h after reset to hand the step
 * size over.
 */
#ifndef MBS_INTEG_INTERNAL_H
#define MBS_INTEG_INTERNAL_H

#include <float.h>
#include <math.h>
#include <stddef.h>
#include "mbs_integrator.h"

#define MBS_EPS 2.220446049250313e-16
#define MBS_MAX_NONFINITE_TRIALS 3 /* consecutive non-finite trials (each shrinks h by 4) before failing */
#define MBS_MSG_LEN 512

enum { MBS_ACCEPT = 0, MBS_REJECT = 1, MBS_FAIL = 2 };           /* attempt() results */
enum { MBS_LAST_NONE = 0, MBS_LAST_ERROR = 1, MBS_LAST_NEWTON = 2 }; /* why the last rejection */

/* Common history (POD; the first bytes of the history block). */
typedef struct {
    double t;            /* visible point (last returned communication point) */
    double h;            /* proposed next step, valid when has_h */
    double t_int;        /* ahead point (x_int), valid when has_ahead */
    double seg_t, seg_h; /* the segment: continuous extension of the step ending at t_int (Q), valid when has_seg */
    long long steps, rejected, rhs_evaluations, jac_evaluations, lu_decompositions;
    int started;         /* reset succeeded: t, x valid */
    int has_h, has_ahead, has_seg;
    int restarted;       /* f jumped at t (inputs or parameters changed): the next advance lands exactly on its end */
    int nonfinite;       /* consecutive non-finite trials, 0..MBS_MAX_NONFINITE_TRIALS */
    int last_failure;    /* MBS_LAST_* */
} MbsCommon;

typedef struct {
    size_t state;          /* bytes of the method's POD history struct */
    size_t hist, hist_int; /* doubles / ints of history arrays */
    size_t work, work_int; /* doubles / ints of scratch */
    size_t view;           /* bytes of the method's pointer struct (it->view) */
} MbsSizes;

/* What the public functions (mbs_integ_*) do, per class: each hands its call to these and names no method. A
 * single method's are the common driver's (mbs_single_ops, integ_base.c: the hooks below do the rest); a
 * composite method ('auto', integ_auto.c) supplies its own and runs child integrators (it->sub) under them. */
typedef struct MbsIntegOps {
    /* options, memory, history; after calloc (it->cls, it->method set). 1 with err set: the caller frees it */
    int (*setup)(MbsIntegrator *it, const MbsOde *ode, const MbsIntegOptions *opt, char *err, size_t errlen);
    int (*reset)(MbsIntegrator *it, double t0, const double *x0);
    void (*inputs_changed)(MbsIntegrator *it);
    int (*advance)(MbsIntegrator *it, double t_end);
    MbsIntegrator *(*active)(const MbsIntegrator *it); /* in charge (itself or a child): t, x, h, dense output */
    void (*stats)(const MbsIntegrator *it, MbsStats *out);
    size_t (*snapshot_size)(const MbsIntegrator *it);
    void (*snapshot_save)(const MbsIntegrator *it, unsigned char *buf);
    int (*snapshot_load)(MbsIntegrator *it, const unsigned char *buf, size_t len);
} MbsIntegOps;
extern const MbsIntegOps mbs_single_ops;

typedef struct MbsMethodClass {
    const char *name;
    int dense_rows;  /* rows of the continuous extension's coefficients Q; 0: no dense output */
    void (*sizes)(int n, int nvel, const MbsIntegOptions *opt, MbsSizes *sz);
    int (*init)(MbsIntegrator *it, char *err, size_t errlen);
    void (*reset_history)(MbsIntegrator *it);
    void (*invalidate_derivative)(MbsIntegrator *it);
    int (*start)(MbsIntegrator *it, double t_end);
    int (*attempt)(MbsIntegrator *it, double t_new, double h, double *x_new);
    int (*accepted)(MbsIntegrator *it);                                   /* NULL: nothing */
    int (*dense_coeffs)(MbsIntegrator *it, double t_old, const double *x_old, const double *x_new, double h,
                        double *Q);                                      /* NULL when dense_rows == 0 */
    void (*dense_eval)(const MbsIntegrator *it, const double *Q, double theta, double *x);
    int (*stop_early)(const MbsIntegrator *it);                           /* NULL: never */
    int (*advance)(MbsIntegrator *it, double t_end);                      /* NULL: mbs_integ_adaptive */
    int (*check)(const MbsIntegrator *it, const void *ms, const int *hi); /* NULL: nothing to check */
    const MbsIntegOps *ops; /* &mbs_single_ops for a method of the hooks above; a composite: its own (no hooks) */
} MbsMethodClass;

struct MbsIntegrator {
    const MbsMethodClass *cls;
    int method;                /* MBS_* */
    MbsOde ode;
    int n;
    /* configuration (not history): from the options, fixed after mbs_integ_new */
    double rtol, atol;      /* rtol capped below at 10 eps; a method's init may transform both */
    double max_step;        /* +inf: no limit */
    double h_fixed;         /* 0: none */
    double rho_inf;
    long max_steps;
    int dense;              /* 1: step past communication points and interpolate */
    int detect_stiffness, stop_when_stiff; /* dopri5 (auto sets both on its child) */

    /* history block: [MbsCommon | method POD | doubles: x, x_int, Q, ha | ints: hi] */
    unsigned char *hist;
    size_t hist_bytes;
    unsigned char *hist_tmp; /* same size: snapshot candidates are validated here before being copied */
    MbsCommon *c;
    void *ms;
    double *x, *x_int, *Q; /* common history arrays: n, n, dense_rows·n */
    double *ha;            /* method history doubles */
    int *hi;               /* method history ints */
    size_t off_ms, off_ha, off_hi; /* byte offsets inside the block (for hist_tmp) */

    /* work block: driver scratch, then the method's */
    double *work;
    double *xnew, *xold, *tmp1, *tmp2; /* n each: trial point, previous point, initial-step scratch */
    double *wa;
    int *wi;
    void *view;            /* method's pointer struct (sz.view bytes) */

    MbsIntegrator *sub[2]; /* auto: dopri5 and radau5 children */
    MbsStepObserver observe; /* NULL: none (mbs_integ_observe) */
    void *observe_env;
    char msg[MBS_MSG_LEN];
    size_t msg_len;
};

/* every method's class: mbs_<class>_class for each MBS_METHODS entry (mbs_layout.h) */
#define MBS_METHOD_CLASS_DECL(code, name, cls, ...) extern const MbsMethodClass mbs_##cls##_class;
MBS_METHODS(MBS_METHOD_CLASS_DECL)
#undef MBS_METHOD_CLASS_DECL

/* Python's min/max of two floats (the first argument wins unless the second compares smaller/larger), so
 * NaN propagates exactly as in the reference implementation. */
static inline double mbs_pymin(double a, double b) { return b < a ? b : a; }
static inline double mbs_pymax(double a, double b) { return b > a ? b : a; }

/* ---- helpers for methods (integ_base.c) ---- */
/* ode->f counted as one evaluation; on MBS_F_SINGULAR/GIMBAL the message is the ODE's: return MBS_FAIL. */
int mbs_integ_f(MbsIntegrator *it, double t, const double *x, double *xdot);
/* Hairer's RMS norm of err / (atol + rtol·max(|x_old|, |x_new|)). */
double mbs_err_norm(int n, const double *err, const double *x_old, const double *x_new, double atol, double rtol);
int mbs_all_finite(int n, const double *v);
/* HINIT (Hairer I, II.4) at (c->t, x) with f0 = f(t, x): sets c->h, c->has_h; 0, or 1 when f failed. */
int mbs_integ_initial_step(MbsIntegrator *it, const double *f0, int order, double t_end);
/* 1 with "right-hand side returned non-finite values ... at the current state" when f0 is not finite. */
int mbs_integ_check_start(MbsIntegrator *it, const double *f0);
/* A trial produced NaN/Inf: c->h = h/4 and MBS_REJECT, or MBS_FAIL after MBS_MAX_NONFINITE_TRIALS. what:
 * "right-hand side" or "accelerations". */
int mbs_integ_trial_nonfinite(MbsIntegrator *it, double h, const char *what);
/* The right-hand side failed (singular M, gimbal lock) at a trial stage. Before the first accepted step the
 * step size is HINIT's guess, which can overshoot an explicit method's stability on a stiff scene and throw the
 * stages out of the region where the equations hold: c->h = h/4 and MBS_REJECT, counted with the non-finite
 * trials. Later (or after MBS_MAX_NONFINITE_TRIALS) MBS_FAIL with the ODE's message: no step size cures it. */
int mbs_integ_stage_failed(MbsIntegrator *it, double h);
/* The common option checks into it (has_dense: the class can interpolate); 0, or 1 with err set. */
int mbs_integ_take_options(MbsIntegrator *it, const MbsOde *ode, const MbsIntegOptions *opt, int has_dense, char *err,
                           size_t errlen);
/* The adaptive driver from (c->t, x) to t_end; 0 or 1. */
int mbs_integ_adaptive(MbsIntegrator *it, double t_end);
/* The fixed-step substep count of rk4 / gen_alpha: equal steps <= h_max over span (max_steps checked,
 * message set): 0 and *nsub, or 1. No extra step when span/h is an integer up to rounding. The slack covers the
 * rounding of the communication times themselves: a master that accumulates t += h hands over spans that differ
 * from h by ulps of t (at t = 100 s, 1e-11 of a 1 ms step), which once took two half steps per point. One step
 * per point, the common case, is decided inline. */
int mbs_integ_fixed_substeps_many(MbsIntegrator *it, double span, double h_max, double ulps, long *nsub);
static inline int mbs_integ_fixed_substeps(MbsIntegrator *it, double span, double h_max, long *nsub)
{
    double ulps = 8.0 * DBL_EPSILON * (fabs(it->c->t) + span);
    if (span * (1.0 - 1e-12) - ulps <= h_max) { *nsub = 1; return 0; }
    return mbs_integ_fixed_substeps_many(it, span, h_max, ulps, nsub);
}
/* The accepted point (c->t, x) to the observer, if any, when it lies strictly before t_end (the advance's end is
 * its caller's to report). Every accepted step passes here once: the adaptive driver, a resumed ahead point
 * (single_advance) and the fixed-step loops (rk4, gen_alpha). */
static inline void mbs_integ_observe(MbsIntegrator *it, double t_end)
{
    if (it->observe && it->c->t < t_end) it->observe(it->observe_env, it->c->t, it->x);
}
/* Normalize x with ode->normalize when present. */
void mbs_integ_normalize(MbsIntegrator *it, double *x);

/* Messages: set, then append pieces. */
void mbs_msg_set(MbsIntegrator *it, const char *s);
void mbs_msg_add(MbsIntegrator *it, const char *s);
void mbs_msg_num(MbsIntegrator *it, double v, int digits); /* like Python's {v:.<digits>g} */
void mbs_msg_long(MbsIntegrator *it, long long v);

/* Snapshot in two phases (auto loads both children atomically): check validates into it->hist_tmp (0 =
 * valid, the integrator untouched), commit makes the checked candidate current. */
int mbs_integ_snapshot_check(MbsIntegrator *it, const unsigned char *buf, size_t len);
void mbs_integ_snapshot_commit(MbsIntegrator *it);
/* little-endian int32 fields of snapshot headers */
void mbs_put_i32(unsigned char *p, long v);
long mbs_get_i32(const unsigned char *p);

/* dopri5 (integ_erk.c): 1 once its stiffness test fired. */
int mbs_dopri5_stiff(const MbsIntegrator *it);

#endif
