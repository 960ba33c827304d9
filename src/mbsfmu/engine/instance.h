/* An instance: the bound numbers, inputs, state and integrator of one running scene, and the variables the
 * FMU exposes (mbs_engine.h is its API). Its jobs, a file each:
 *   instance.c     lifetime, messages, binding parameters to numbers, inputs held over a step
 *   rules.c        the scene's domains and rules, the values a host sets checked against them; gimbal lock
 *   ode.c          the ODE the integrators see (ẋ at t, x), its integrator, mbs_equations and mbs_rhs
 *   run.c          initialization and stepping (co-simulation, mbs_run)
 *   variables.c    get and set by value reference, output points, start values
 *   exchange.c     model exchange (time, states, ẋ) and directional derivatives
 *   state_bytes.c  FMU state bytes (save, load)
 * Everything is allocated in mbs_instance_new (the integrator at initialization); nothing per step. Failures
 * return MBS_DISCARD/MBS_ERROR with a message (mbs_message, and the logger if any). */
#ifndef MBS_INSTANCE_H
#define MBS_INSTANCE_H
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mbs_integrator.h"
#include "mbs_model.h"
#include "rules.h"

struct MbsInstance {
    const MbsModel *m;
    mbs_logger log;
    void *log_env;
    int n, nu, ntd;
    double *D;            /* bound numbers: the model's D with this instance's parameters */
    double *td;           /* time-dependent numbers (drives, force values; input forces held over a step) */
    double *u;            /* inputs as set: q_in (nvel), then force inputs (3 per input) */
    double *u_applied;    /* inputs held over the current step */
    double *x, *x_before; /* state [y; ẏ] (before initialization: the initial state) */
    double *start;        /* start values that replace the scene's initial state (NaN: none) */
    double *saved;        /* the parameters before a set that may be refused (nparam) */
    double *carries;      /* per body: 1 if it or a body it carries has mass, inertia or elasticity (R_CARRIES) */
    double *work, *M, *k, *q, *xdot, *out;
    double *der;          /* ẋ at (time, x) with the inputs and parameters set, when der_valid (model exchange) */
    void *elastic_work;
    void *tangent;        /* directional derivatives' workspace (deriv.c), made at the first one asked for, */
    double *dx;           /* then the seeds dx (n), du (nu) and dẋ (n), d out (6 nout), d σ (nstress) */
    int tangent_bound;    /* it holds the bound numbers of D (binding clears it) */
    int method;
    double rtol, atol, max_step, step;
    int initialized, params_dirty, inputs_dirty, initial_valid, q_in_active;
    int out_valid;        /* out holds the output points of the current state (a master reads them one by one) */
    int der_valid;
    double *kin_x, kin_t; /* the workspace holds the kinematics at (kin_t, kin_x) when kin_valid */
    int kin_valid;
    int rule_broken;      /* the last bind failed on a rule of the scene (a derived quantity), not otherwise */
    int time_programs;    /* the scene has expressions of t (drives, force values): run them per evaluation */
    int rhs_ok;           /* an evaluation succeeded since initialization (M was regular once) */
    double time;
    MbsIntegrator *integ;
    mbs_step_observer observe;  /* mbs_set_step_observer: NULL, or called at each internal point of a step */
    void *observe_env;
    int observing;        /* inside the observer: the instance shows the internal point, changes are refused */
    char msg[1024];
};

/* Calls that change the instance are refused while the step observer looks at an internal point (mbs_engine.h). */
#define REFUSED_WHILE_OBSERVING(s, fn)                                                                          \
    if ((s)->observing)                                                                                         \
        return mbs_report((s), MBS_ERROR, "%s: not allowed while the step observer runs (the step is in progress at an " \
                          "internal point; variables may be read)", (fn))

/* instance.c */
int mbs_report(MbsInstance *s, int status, const char *fmt, ...);  /* message, logged; returns status */
int mbs_say(MbsInstance *s, const char *fmt, ...);                 /* message, not logged; returns MBS_ERROR */
int mbs_bind(MbsInstance *s);
int mbs_start_state(MbsInstance *s);
int mbs_apply_inputs(MbsInstance *s, int status, const char *refused);
int mbs_pending(MbsInstance *s, int status, const char *refused);
/* ode.c */
MbsEval mbs_evaluation(MbsInstance *s, const double *x, double *xdot);
void mbs_time_numbers(MbsInstance *s, double t);
void mbs_cached_kinematics(MbsInstance *s, const MbsEval *e, double t);
int mbs_ode_f(void *ctx, double t, const double *x, double *xdot);
MbsIntegrator *mbs_new_integrator(MbsInstance *s, int method, char *err, size_t len);
const char *mbs_state_name(const MbsModel *m, int i);
int mbs_finite_result(MbsInstance *s, const char *what, double t, const double *x, const double *v, size_t n,
                      const unsigned *vr);
/* run.c */
void mbs_observe_point(void *ctx, double t, const double *x);
/* exchange.c */
int mbs_update_der(MbsInstance *s);
#endif
