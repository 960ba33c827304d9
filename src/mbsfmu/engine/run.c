/* Running: initialization, communication steps and runs over time points (co-simulation, in-process). */
#include "instance.h"

/* The integrator accepted an internal step at (t, x): the observer sees the instance there (outputs computed for
 * that point when read), changes refused. mbs_do_step moves the instance to the step's end afterwards. */
void mbs_observe_point(void *ctx, double t, const double *x)
{
    MbsInstance *s = ctx;
    if (x != s->x) memcpy(s->x, x, (size_t)s->n * sizeof(double));
    s->time = t;
    s->out_valid = s->der_valid = 0;
    s->observing = 1;
    s->observe(s->observe_env, t, s->x);
    s->observing = 0;
    s->out_valid = s->der_valid = 0;
}

int mbs_set_step_observer(MbsInstance *s, mbs_step_observer fn, void *env)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_set_step_observer");
    s->observe = fn;
    s->observe_env = env;
    if (s->integ) mbs_integ_set_observer(s->integ, fn ? mbs_observe_point : NULL, s);
    return MBS_OK;
}

int mbs_initialize(MbsInstance *s, double t0)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_initialize");
    char err[512];
    if (!isfinite(t0)) return mbs_report(s, MBS_ERROR, "start time is not finite");
    int rc = mbs_start_state(s);
    if (rc) return rc;
    mbs_integ_free(s->integ);
    s->integ = mbs_new_integrator(s, s->method, err, sizeof err);
    if (!s->integ) return mbs_report(s, MBS_ERROR, "integrator %s: %s", mbs_method_names[s->method], err);
    if (mbs_integ_reset(s->integ, t0, s->x)) return mbs_report(s, MBS_ERROR, "%s", mbs_integ_message(s->integ));
    s->time = t0;
    s->initialized = 1;
    s->rhs_ok = 0;
    s->params_dirty = 0;
    memset(s->u_applied, 0, (size_t)s->nu * sizeof(double));  /* apply_inputs compares against this */
    s->inputs_dirty = 1;
    return MBS_OK;
}

/* Before a step at t: bind changed parameters and inputs, check that t is the current time. */
static int prepare(MbsInstance *s, double t)
{
    if (!s->initialized) return mbs_report(s, MBS_ERROR, "the instance is not initialized");
    int rc = mbs_pending(s, MBS_DISCARD, "step refused");
    if (rc) return rc;
    if (!isfinite(t) || fabs(t - s->time) > 1e-9 * (fabs(t) > 1.0 ? fabs(t) : 1.0))
        return mbs_report(s, MBS_ERROR, "do_step called at t=%.17g but the simulation is at t=%.17g", t, s->time);
    return MBS_OK;
}

/* The integrator stopped at its last good point: move there and say why. */
static int failed(MbsInstance *s)
{
    char extra[512] = "";
    const char *why = mbs_integ_message(s->integ);
    s->time = mbs_integ_t(s->integ);
    memcpy(s->x, mbs_integ_x(s->integ), (size_t)s->n * sizeof(double));
    if (mbs_gimbal(s->m, s->x, NULL, extra, sizeof extra) && strstr(why, "gimbal")) extra[0] = 0;
    return mbs_report(s, MBS_DISCARD, "t = %.9g: %s%s%s", s->time, why, extra[0] ? "; " : "", extra);
}

int mbs_do_step(MbsInstance *s, double t, double h)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_do_step");
    s->out_valid = s->der_valid = 0;
    int rc = prepare(s, t);
    if (rc) return rc;
    if (!(h >= 0) || !isfinite(h)) return mbs_report(s, MBS_ERROR, "communication step size %g is not a non-negative number", h);
    const int cardan = s->m->hdr[H_NCARDAN] > 0;
    if (cardan) memcpy(s->x_before, s->x, (size_t)s->n * sizeof(double));
    if (mbs_integ_advance(s->integ, t + h)) return failed(s);
    s->time = mbs_integ_t(s->integ);
    memcpy(s->x, mbs_integ_x(s->integ), (size_t)s->n * sizeof(double));
    /* a coarse step may jump across b = ±90° without landing near it */
    if (cardan && mbs_gimbal(s->m, s->x, s->x_before, s->msg, sizeof s->msg))
        return mbs_report(s, MBS_DISCARD, "t = %.9g: %s", s->time, s->msg);
    if (s->observe) mbs_observe_point(s, s->time, s->x);  /* the step's end: its last internal point, or interpolated */
    return MBS_OK;
}

int mbs_run(MbsInstance *s, const double *ts, int n, double *X)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_run");
    s->out_valid = s->der_valid = 0;
    if (n < 1) return mbs_report(s, MBS_ERROR, "no time points");
    int rc = prepare(s, ts[0]);
    if (rc) return rc;
    for (int k = 1; k < n; k++)
        if (!(ts[k] > ts[k - 1])) return mbs_report(s, MBS_ERROR, "time points must increase (%g after %g)", ts[k], ts[k - 1]);
    memcpy(X, s->x, (size_t)s->n * sizeof(double));
    if (s->m->hdr[H_NCARDAN]) {  /* the gimbal check looks at every consecutive pair of points */
        for (int k = 1; k < n; k++) {
            if ((rc = mbs_do_step(s, ts[k - 1], ts[k] - ts[k - 1]))) return rc;
            memcpy(X + (size_t)k * s->n, s->x, (size_t)s->n * sizeof(double));
        }
        return MBS_OK;
    }
    if (n > 1 && mbs_integ_advance_many(s->integ, ts + 1, n - 1, X + s->n)) return failed(s);
    s->time = mbs_integ_t(s->integ);
    memcpy(s->x, mbs_integ_x(s->integ), (size_t)s->n * sizeof(double));
    return MBS_OK;
}

double mbs_time(const MbsInstance *s) { return s->time; }
int mbs_initialized(const MbsInstance *s) { return s->initialized; }
const double *mbs_state(const MbsInstance *s) { return s->x; }
const double *mbs_nominals(const MbsInstance *s) { return s->m->D + s->m->hdr[H_D_NOMINAL]; }

void mbs_stats(const MbsInstance *s, long out[6], double *switched_at)
{
    MbsStats st;
    memset(&st, 0, sizeof st);
    st.switched_at = NAN;
    if (s->integ) mbs_integ_stats(s->integ, &st);
    out[0] = st.steps; out[1] = st.rejected; out[2] = st.rhs_evaluations; out[3] = st.jac_evaluations;
    out[4] = st.lu_decompositions; out[5] = st.switched;
    if (switched_at) *switched_at = st.switched_at;
}

