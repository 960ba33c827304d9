/* Time integrators of the engine (mbs_layout.h's MBS_METHODS: rk4, dopri5, dop853, radau5, gen_alpha, auto).
 *
 * Exact landing on communication points, step size carried across them, dense
 * output (dopri5, dop853, radau5, auto) that steps past a point and interpolates, quaternion normalization
 * after every accepted step, stiffness switching (auto), and snapshots after which a repeated step is
 * bit-identical.
 *
 * Memory: everything is allocated in mbs_integ_new; nothing is allocated per step.
 * History that influences future results is kept in plain data (no pointers) so that a snapshot is a copy
 * of bytes; integer fields are range-checked when a snapshot is loaded.
 */
#ifndef MBS_INTEGRATOR_H
#define MBS_INTEGRATOR_H

#include <stddef.h>

#include "mbs_layout.h"

/* keeps a cold path out of its hot caller (which link-time optimization then inlines where it is called) */
#if defined(__GNUC__)
#define MBS_NOINLINE __attribute__((noinline))
#else
#define MBS_NOINLINE
#endif

/* MBS_RK4 ... MBS_AUTO, MBS_NMETHODS and the names: mbs_layout.h's MBS_METHODS */
/* bytes one integrator may hold (history, its copy for rejected steps, scratch): an implicit method's
 * n x n matrices grow with the square of the states, so a scene that the model's workspace admits may still
 * be too large for radau5; mbs_integ_new refuses it with the size instead of allocating tens of GB */
#define MBS_INTEG_MAX_BYTES ((size_t)1 << 30)
extern const char *const mbs_method_names[MBS_NMETHODS]; /* "rk4", "dopri5", ... */
int mbs_method_index(const char *name);                   /* -1 when unknown */

/* Return codes of MbsOde.f */
enum { MBS_F_OK = 0, MBS_F_SINGULAR = 1, MBS_F_GIMBAL = 2 };

/* The system x' = f(t, x), x = [y; v] (npos + nvel = n). */
typedef struct MbsOde {
    int n, npos, nvel;
    void *ctx;
    /* MBS_F_OK, or a failure that no step size cures (singular M, gimbal lock): the integrator stops with
     * message(ctx).  NaN/Inf in xdot are not a failure of f: the integrator shrinks h (a few times). */
    int (*f)(void *ctx, double t, const double *x, double *xdot);
    const char *(*message)(void *ctx);
    void (*normalize)(void *ctx, double *x);                                  /* NULL: no quaternions */
    void (*retract)(void *ctx, const double *y, const double *dy, double *out); /* NULL: out = y + dy */
} MbsOde;

typedef struct {
    double rtol, atol;
    double max_step;   /* <= 0 or inf: no limit */
    double h;          /* fixed step of rk4/gen_alpha; 0: rk4 one step per interval, gen_alpha adaptive */
    double rho_inf;    /* gen_alpha spectral radius */
    long max_steps;    /* per advance; 0: 1e6 */
    int dense;         /* -1 default of the method, 0 off, 1 on */
} MbsIntegOptions;

typedef struct {
    long steps, rejected, rhs_evaluations, jac_evaluations, lu_decompositions;
    int switched;       /* auto: 1 after the switch to radau5 */
    double switched_at; /* auto: time of the switch (NaN before) */
} MbsStats;

typedef struct MbsIntegrator MbsIntegrator;

/* Called after every accepted internal step that ends strictly before the t_end of the advance in progress, with
 * the normalized point (t, x) (the end itself is the caller's to report): each point once, in increasing t, for
 * every method (auto: its children's steps). x is the integrator's: read it, never keep or change it. */
typedef void (*MbsStepObserver)(void *env, double t, const double *x);

/* NULL with a message in err on bad options (rtol <= 0, atol < 0, max_step <= 0 ...). ode is copied. */
MbsIntegrator *mbs_integ_new(int method, const MbsOde *ode, const MbsIntegOptions *opt, char *err, size_t errlen);
void mbs_integ_free(MbsIntegrator *it);
int mbs_integ_method(const MbsIntegrator *it);
int mbs_integ_reset(MbsIntegrator *it, double t0, const double *x0);  /* 0, or 1: non-finite start */
void mbs_integ_inputs_changed(MbsIntegrator *it);                      /* f jumped at the current t */
void mbs_integ_set_observer(MbsIntegrator *it, MbsStepObserver fn, void *env); /* fn NULL: none */
/* Integrate to exactly t_end: 0, or 1 with t/x at the last good point and a message. */
int mbs_integ_advance(MbsIntegrator *it, double t_end);
/* rows x(ts[i]) (ts increasing, > t): the same steps as one advance per time, points inside one
 * dense-output step from its continuous extension (normalized). */
int mbs_integ_advance_many(MbsIntegrator *it, const double *ts, int m, double *X);
double mbs_integ_t(const MbsIntegrator *it);
const double *mbs_integ_x(const MbsIntegrator *it);
double mbs_integ_h(const MbsIntegrator *it);
void mbs_integ_stats(const MbsIntegrator *it, MbsStats *out);
const char *mbs_integ_message(const MbsIntegrator *it);

/* Snapshot: fixed size for a given (method, n); load validates integer fields and sizes and leaves the
 * integrator unchanged on failure (returns 1). */
size_t mbs_integ_snapshot_size(const MbsIntegrator *it);
void mbs_integ_snapshot_save(const MbsIntegrator *it, unsigned char *buf);
int mbs_integ_snapshot_load(MbsIntegrator *it, const unsigned char *buf, size_t len);

#endif
