/* The ODE the integrators see: ẋ = f(t, x) of the instance's scene (kinematics cached per state), its
 * integrator, and the evaluations a caller asks for directly (mbs_equations, mbs_rhs). */
#include "instance.h"

/* ------------------------------------------------------------------------------------------ the ODE */
MbsEval mbs_evaluation(MbsInstance *s, const double *x, double *xdot)
{
    MbsEval e = {s->m, s->D, s->td, x, s->q_in_active ? s->u_applied : NULL, s->work, s->M, s->k, s->q, xdot,
                 s->elastic_work};
    return e;
}

void mbs_time_numbers(MbsInstance *s, double t)
{
#ifdef MBS_WITH_EXPR
    if (s->time_programs) mbs_run_programs(s->m, 1, s->D, s->td, t);
#else
    (void)s; (void)t;
#endif
}

/* The kinematics at (t, x) into the workspace, unless they are there already: the output points read after a
 * step and the next step's first stage (or an FSAL method's last stage and the output points) share one pass.
 * The stamp is t and x's bits (mbs_time_numbers(t) ran before); binding numbers clears it. */
void mbs_cached_kinematics(MbsInstance *s, const MbsEval *e, double t)
{
    int same = s->kin_valid && s->kin_t == t;
    for (int i = 0; same && i < s->n; i++) same = memcmp(s->kin_x + i, e->x + i, sizeof(double)) == 0;  /* bits */
    if (same) return;
    mbs_kinematics(e);
    memcpy(s->kin_x, e->x, (size_t)s->n * sizeof(double));
    s->kin_t = t;
    s->kin_valid = 1;
}

int mbs_ode_f(void *ctx, double t, const double *x, double *xdot)
{
    MbsInstance *s = ctx;
    if (s->m->hdr[H_NCARDAN] && mbs_gimbal(s->m, x, NULL, s->msg, sizeof s->msg)) return MBS_F_GIMBAL;
    mbs_time_numbers(s, t);
    MbsEval e = mbs_evaluation(s, x, xdot);
    mbs_cached_kinematics(s, &e, t);
    if (mbs_eval_rhs(&e)) {
        double big = 0.0;
        for (int i = 0; i < s->n; i++) big = fmax(big, fabs(x[i]));
        if (!s->rhs_ok)
            snprintf(s->msg, sizeof s->msg, "the mass matrix is singular (a chain of bodies without mass or inertia?)");
        else  /* it was regular before: this configuration, or a state an unstable step blew up */
            snprintf(s->msg, sizeof s->msg, "the mass matrix became singular or indefinite (largest |y|, |ẏ| of the "
                     "state: %.3g): bodies without mass or inertia in this configuration, or an unstable step (try a "
                     "smaller step, radau5 or gen_alpha)", big);
        return MBS_F_SINGULAR;
    }
    s->rhs_ok = 1;
    return MBS_F_OK;
}

static const char *ode_message(void *ctx) { return ((MbsInstance *)ctx)->msg; }

/* unit quaternions after each accepted step */
static void ode_normalize(void *ctx, double *x)
{
    const MbsModel *m = ((MbsInstance *)ctx)->m;
    for (int j = 0; j < m->hdr[H_NQUAT]; j++) {
        const int *qi = m->quat + 7 * j;
        double n = sqrt(x[qi[0]] * x[qi[0]] + x[qi[1]] * x[qi[1]] + x[qi[2]] * x[qi[2]] + x[qi[3]] * x[qi[3]]);
        for (int k = 0; k < 4; k++) x[qi[k]] /= n;
    }
}

/* y ⊕ dy: plain coordinates add, quaternions turn by the body-frame rotation vector (rotations.quat_exp_step) */
static void ode_retract(void *ctx, const double *y, const double *dy, double *out)
{
    const MbsModel *m = ((MbsInstance *)ctx)->m;
    const int nplain = m->hdr[H_NPLAIN];
    for (int i = 0; i < nplain; i++) out[m->plain[i]] = y[m->plain[i]] + dy[m->plain[nplain + i]];
    for (int j = 0; j < m->hdr[H_NQUAT]; j++) {
        const int *qi = m->quat + 7 * j;
        const double *w = dy;
        double a = sqrt(w[qi[4]] * w[qi[4]] + w[qi[5]] * w[qi[5]] + w[qi[6]] * w[qi[6]]), d[4];
        if (a < 1e-12) { d[0] = 1.0; for (int k = 0; k < 3; k++) d[k + 1] = 0.5 * w[qi[4 + k]]; }
        else { double sn = sin(0.5 * a) / a; d[0] = cos(0.5 * a); for (int k = 0; k < 3; k++) d[k + 1] = sn * w[qi[4 + k]]; }
        double p0 = y[qi[0]], p1 = y[qi[1]], p2 = y[qi[2]], p3 = y[qi[3]];
        double o[4] = {p0 * d[0] - p1 * d[1] - p2 * d[2] - p3 * d[3], p0 * d[1] + p1 * d[0] + p2 * d[3] - p3 * d[2],
                       p0 * d[2] - p1 * d[3] + p2 * d[0] + p3 * d[1], p0 * d[3] + p1 * d[2] - p2 * d[1] + p3 * d[0]};
        double n = sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2] + o[3] * o[3]);
        for (int k = 0; k < 4; k++) out[qi[k]] = o[k] / n;
    }
}

/* The integrator of `method` over this ODE, with the instance's settings (and its step observer). */
MbsIntegrator *mbs_new_integrator(MbsInstance *s, int method, char *err, size_t len)
{
    const MbsModel *m = s->m;
    MbsOde ode = {s->n, NPOS(m), NVEL(m), s, mbs_ode_f, ode_message, m->hdr[H_NQUAT] ? ode_normalize : NULL,
                  m->hdr[H_NQUAT] ? ode_retract : NULL};
    MbsIntegOptions opt = {s->rtol, s->atol, s->max_step > 0 ? s->max_step : INFINITY, s->step,
                           m->D[m->hdr[H_D_INTEG] + DI_RHO_INF], 0, -1};
    MbsIntegrator *it = mbs_integ_new(method, &ode, &opt, err, len);
    if (it && s->observe) mbs_integ_set_observer(it, mbs_observe_point, s);
    return it;
}

/* ------------------------------------------------------------------------------------------ evaluation */
int mbs_equations(MbsInstance *s, double t, const double *x, double *M, double *k, double *q)
{
    if (!s->initialized && !s->initial_valid && mbs_start_state(s)) return MBS_ERROR;
    if (s->inputs_dirty && mbs_apply_inputs(s, MBS_ERROR, "not evaluated")) return MBS_ERROR;
    mbs_time_numbers(s, t);
    MbsEval e = mbs_evaluation(s, x, s->xdot);
    e.M = M; e.k = k; e.q = q;
    mbs_cached_kinematics(s, &e, t);
    if (!s->m->dense) {
        mbs_crba_rnea(&e);
        return MBS_OK;
    }
    mbs_mass_matrix_and_bias(&e);
    mbs_applied_forces(&e);
    return MBS_OK;
}

/* The name of state entry i: its y.* or yd.* variable's. */
const char *mbs_state_name(const MbsModel *m, int i)
{
    const int kind = i < NPOS(m) ? MBS_V_Y : MBS_V_YD, idx = i < NPOS(m) ? i : i - NPOS(m);
    for (int vr = 0; vr < m->hdr[H_NVARS]; vr++)
        if (m->vars[2 * vr] == kind && m->vars[2 * vr + 1] == idx) return m->var_name[vr];
    return "?";
}

/* What the engine hands out (`what`: ẋ or a derivative, v[0..n), of the state entries, or of the variables vr)
 * must be finite: a finite but extreme state still overflows inside (θ̇ = 1e200 squares to ∞), and NaN then is
 * no answer. MBS_OK, else MBS_DISCARD naming the first entry that is not. (The integrators see ode_f's NaN
 * themselves: a smaller step.) */
int mbs_finite_result(MbsInstance *s, const char *what, double t, const double *x, const double *v, size_t n,
                         const unsigned *vr)
{
    for (size_t i = 0; i < n; i++)
        if (!isfinite(v[i])) {
            double big = 0.0;
            for (int j = 0; j < s->n; j++) big = fmax(big, fabs(x[j]));
            return mbs_report(s, MBS_DISCARD, "t = %.9g: %s %s is %g, not finite at this state (an intermediate "
                          "overflowed, or an expression left its domain; largest |y|, |ẏ|: %.3g)", t, what,
                          vr ? s->m->var_name[vr[i]] : mbs_state_name(s->m, (int)i), v[i], big);
        }
    return MBS_OK;
}

/* x and xdot share memory (rhs(t, x, out=x)): ẋ is then evaluated aside, since the evaluation reads x after it
 * wrote parts of ẋ. */
static int overlap(const double *x, const double *xdot, int n)
{
    const uintptr_t a = (uintptr_t)x, b = (uintptr_t)xdot, len = (uintptr_t)n * sizeof(double);
    return a < b + len && b < a + len;
}

int mbs_rhs(MbsInstance *s, double t, const double *x, double *xdot)
{
    if (!s->initialized && !s->initial_valid && mbs_start_state(s)) return MBS_ERROR;
    if (s->inputs_dirty && mbs_apply_inputs(s, MBS_ERROR, "not evaluated")) return MBS_ERROR;
    double *into = overlap(x, xdot, s->n) ? s->xdot : xdot;
    if (mbs_ode_f(s, t, x, into)) return mbs_report(s, MBS_ERROR, "%s", s->msg);
    int rc = mbs_finite_result(s, "the time derivative of", t, x, into, (size_t)s->n, NULL);
    if (!rc && into != xdot) memmove(xdot, into, (size_t)s->n * sizeof *xdot);
    return rc;
}

