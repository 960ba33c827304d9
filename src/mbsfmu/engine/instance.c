/* An instance's lifetime, its messages, and the numbers it binds: parameters → numbers checked against the
 * scene's rules, inputs held over a step (instance.h lists the instance's files). */
#include "instance.h"

/* ------------------------------------------------------------------------------------------ messages */
int mbs_report(MbsInstance *s, int status, const char *fmt, ...)
{
    char buf[sizeof s->msg];  /* the arguments may point into s->msg */
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    memcpy(s->msg, buf, sizeof buf);
    if (s->log) s->log(s->log_env, status, s->msg);
    return status;
}

const char *mbs_message(const MbsInstance *s) { return s->msg; }

/* The message without the logger: callers that fail with it report it. */
int mbs_say(MbsInstance *s, const char *fmt, ...)
{
    char buf[sizeof s->msg];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    memcpy(s->msg, buf, sizeof buf);
    return MBS_ERROR;
}

/* ------------------------------------------------------------------------------------------ lifetime */
MbsInstance *mbs_instance_new(const MbsModel *m, mbs_logger log, void *log_env)
{
    MbsInstance *s = calloc(1, sizeof *s);
    if (!s) return NULL;
    const int f = NVEL(m), nd = m->hdr[H_ND];
    s->m = m;
    for (int p = 0; p < m->hdr[H_NPROG]; p++) s->time_programs |= m->prog[4 * p] == 1;
    s->log = log;
    s->log_env = log_env;
    s->n = NPOS(m) + f;
    s->nu = f + 3 * m->hdr[H_NINPUT];
    s->ntd = 3 * (m->hdr[H_NDRV] + m->hdr[H_NVEC]);
    size_t nwork = (size_t)mbs_work_doubles(m->hdr);  /* per body, scratch and M (dense path) */
    size_t total = (size_t)nd + s->ntd + 2 * (size_t)s->nu + 3 * (size_t)s->n + nwork + 2 * (size_t)f + 2 * (size_t)s->n
                   + 6 * (size_t)m->hdr[H_NOUT] + s->n + (size_t)m->hdr[H_NPARAM] + NB(m) + 1;
    double *buf = calloc(total, sizeof(double));
    if (!buf) { free(s); return NULL; }
    s->D = buf;                buf += nd;
    s->td = buf;               buf += s->ntd;
    s->u = buf;                buf += s->nu;
    s->u_applied = buf;        buf += s->nu;
    s->x = buf;                buf += s->n;
    s->out = buf;              buf += 6 * (size_t)m->hdr[H_NOUT];  /* right after x: m->read's block */
    s->x_before = buf;         buf += s->n;
    s->start = buf;            buf += s->n;
    s->saved = buf;            buf += m->hdr[H_NPARAM];
    s->carries = buf;          buf += NB(m);
    s->work = buf;             buf += nwork;
    s->M = m->dense ? s->work + mbs_work_M_offset(m->hdr) : NULL;
    s->k = buf;                buf += f;
    s->q = buf;                buf += f;
    s->xdot = buf;             buf += s->n;
    s->der = buf;              buf += s->n;
    s->kin_x = buf;
#ifdef MBS_WITH_ELASTIC
    if (m->hdr[H_FEATURES] & F_ELASTIC) {
        s->elastic_work = calloc(1, mbs_elastic_work_size(m) + 1);
        if (!s->elastic_work) { free(s->D); free(s); return NULL; }
    }
#endif
    mbs_reset(s);
    return s;
}

void mbs_instance_free(MbsInstance *s)
{
    if (!s) return;
    mbs_integ_free(s->integ);
    free(s->elastic_work);
    free(s->tangent);
    free(s->D);
    free(s);
}

int mbs_reset(MbsInstance *s)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_reset");
    const MbsModel *m = s->m;
    const double *di = m->D + m->hdr[H_D_INTEG];
    memcpy(s->D, m->D, (size_t)m->hdr[H_ND] * sizeof(double));
    memset(s->td, 0, (size_t)s->ntd * sizeof(double));
    memset(s->u, 0, (size_t)s->nu * sizeof(double));
    memset(s->u_applied, 0, (size_t)s->nu * sizeof(double));
    for (int i = 0; i < s->n; i++) s->start[i] = NAN;
    s->method = m->hdr[H_METHOD];
    s->rtol = di[DI_RTOL];
    s->atol = di[DI_ATOL];
    s->max_step = di[DI_MAX_STEP];
    s->step = di[DI_STEP];
    s->initialized = s->params_dirty = s->inputs_dirty = s->initial_valid = s->q_in_active = s->out_valid = s->der_valid = 0;
    s->kin_valid = s->tangent_bound = 0;
    s->time = 0.0;
    s->msg[0] = 0;
    mbs_integ_free(s->integ);
    s->integ = NULL;
    return MBS_OK;
}

/* ------------------------------------------------------------------------------------------ binding */
/* Which bodies carry mass, inertia or an elastic body (the loader's `massless` check, over the bound numbers):
 * parents come before their children, so one sweep from the last body up marks every ancestor. */
static void mark_carried(MbsInstance *s)
{
    const MbsModel *m = s->m;
    for (int i = 0; i < NB(m); i++) {
        const MbsBodyD *bd = mbs_body_row(m, s->D, i);
        s->carries[i] = mbs_body_i(m, i)->elastic >= 0 || bd->m > 0 || bd->I[0] > 0 || bd->I[4] > 0 || bd->I[8] > 0;
    }
    for (int i = NB(m) - 1; i > 0; i--) {
        const int p = mbs_body_i(m, i)->parent;
        if (p >= 0 && s->carries[i]) s->carries[p] = 1;
    }
}

/* The derived-quantity rules of the bound numbers (S_RULES); MBS_ERROR with the first that fails (quiet). */
static int check_rules(MbsInstance *s)
{
    const MbsModel *m = s->m;
    char why[400];
    int marked = 0;
    s->rule_broken = 1;
    for (int r = 0; r < m->nrules; r++) {
        const int32_t *row = m->rules + 3 * r;
        const char *path = m->rule_names + row[2];
        if (row[0] == R_TIMED) continue;  /* check_times */
        if (row[0] == R_CARRIES) {
            if (!marked++) mark_carried(s);
            if (!s->carries[row[1]])
                return mbs_say(s, "%s: body '%s' and the bodies it carries have no mass or inertia, so its joint's motion is "
                           "undetermined (singular mass matrix)", path, m->body_name[row[1]]);
            continue;
        }
        const double *v = s->D + row[1];
        if (mbs_rule_problem(m, row[0], v, why, sizeof why))
            return mbs_rule_size[row[0]] == 1 ? mbs_say(s, "%s = %g: %s", path, v[0], why) : mbs_say(s, "%s: %s", path, why);
    }
    s->rule_broken = 0;
    return MBS_OK;
}

/* The R_TIMED values at the loader's sample times over the scene's experiment (quiet, as check_rules). */
static int check_times(MbsInstance *s)
{
#ifdef MBS_WITH_EXPR
    const MbsModel *m = s->m;
    int timed = 0;
    for (int r = 0; r < m->nrules; r++) timed |= m->rules[3 * r] == R_TIMED;
    if (!timed) return MBS_OK;
    const double *lim = m->limits;
    const int n = (int)lim[LIM_SAMPLES];
    s->rule_broken = 1;
    for (int k = 0; k < n; k++) {
        const double step = (lim[LIM_STOP] - lim[LIM_START]) / (n > 1 ? n - 1 : 1);  /* numpy.linspace's times */
        const double t = k == n - 1 ? lim[LIM_STOP] : lim[LIM_START] + k * step;
        mbs_run_programs(m, 1, s->D, s->td, t);
        for (int r = 0; r < m->nrules; r++) {
            const int32_t *row = m->rules + 3 * r;
            if (row[0] == R_TIMED && !isfinite(s->td[row[1]]))
                return mbs_say(s, "%s = %g at t = %g: must stay finite over the experiment [%g, %g] s",
                           m->rule_names + row[2], s->td[row[1]], t, lim[LIM_START], lim[LIM_STOP]);
        }
    }
    s->rule_broken = 0;
#else
    (void)s;
#endif
    return MBS_OK;
}

/* Parameters → numbers (bind programs, derived axes and rotations), checked against the scene's rules;
 * MBS_ERROR with the message in s->msg (not logged: the caller reports it). */
int mbs_bind(MbsInstance *s)
{
    const MbsModel *m = s->m;
    s->kin_valid = s->tangent_bound = s->rule_broken = 0;
    for (int p = 0; p < m->hdr[H_NPARAM]; p++)
        if (!isfinite(s->D[p])) {
            return mbs_say(s, "parameter %s is not finite (%g)", mbs_var_name_of(m, MBS_V_PARAM, p), s->D[p]);
        }
#ifdef MBS_WITH_EXPR
    mbs_run_programs(m, 0, s->D, NULL, 0.0);
#endif
    mbs_derive(m, s->D);
    if (!m->dense) mbs_composites(m, s->D, s->work);
    if (check_rules(s) || check_times(s)) return MBS_ERROR;
#ifdef MBS_WITH_ELASTIC
    double compiled;
    const int p = (m->hdr[H_FEATURES] & F_ELASTIC) ? mbs_elastic_changed_structure(m, s->D, &compiled) : -1;
    if (p >= 0) {
        const char *name = mbs_var_name_of(m, MBS_V_PARAM, p);
        return mbs_say(s, "parameter %s is structural: it feeds the finite-element data of an elastic body, which the "
                       "engine cannot recompute (compiled with %s = %.17g, set to %.17g); compile the scene again with "
                       "the new value", name, name, compiled, s->D[p]);
    }
#endif
    for (int k = m->hdr[H_D_BODY]; k < m->hdr[H_ND]; k++)
        if (!isfinite(s->D[k]))
            return mbs_say(s, "the parameters give a non-finite number in the scene (entry %d of the compiled data): "
                       "check expressions such as sqrt, log or division by a parameter", k);
    return MBS_OK;
}

int mbs_start_state(MbsInstance *s)
{
    int rc = mbs_bind(s);
    if (rc) return mbs_report(s, rc, "%s", s->msg);
    mbs_initial_state(s->m, s->D, s->x);
    s->out_valid = s->der_valid = 0;
    for (int i = 0; i < s->n; i++) if (!isnan(s->start[i])) s->x[i] = s->start[i];
    for (int i = 0; i < s->n; i++)
        if (!isfinite(s->x[i])) return mbs_report(s, MBS_ERROR, "initial value of %s is not finite", i < NPOS(s->m) ? s->m->coord_name[i] : "a velocity");
    for (int j = 0; j < s->m->hdr[H_NQUAT]; j++) {  /* start values of a quaternion: a rotation, else not used as given */
        const int *qi = s->m->quat + 7 * j;
        const double *x = s->x;
        const double norm = sqrt(x[qi[0]] * x[qi[0]] + x[qi[1]] * x[qi[1]] + x[qi[2]] * x[qi[2]] + x[qi[3]] * x[qi[3]]);
        const int given = !isnan(s->start[qi[0]]) || !isnan(s->start[qi[1]]) || !isnan(s->start[qi[2]]) || !isnan(s->start[qi[3]]);
        if (given && !(fabs(norm - 1) <= 1e-9))
            return mbs_report(s, MBS_ERROR, "start values make the quaternion (y0.%s, y0.%s, y0.%s, y0.%s) = (%g, %g, %g, %g) of "
                          "norm %g, not a rotation: give all four components of a unit quaternion", s->m->coord_name[qi[0]],
                          s->m->coord_name[qi[1]], s->m->coord_name[qi[2]], s->m->coord_name[qi[3]], x[qi[0]], x[qi[1]],
                          x[qi[2]], x[qi[3]], norm);
    }
    s->initial_valid = 1;
    return MBS_OK;
}

/* Inputs held over the next step (or evaluation): refuse NaN/Inf with `status` and `refused` (what did not
 * happen); restart the integrator only on a real change. */
int mbs_apply_inputs(MbsInstance *s, int status, const char *refused)
{
    const MbsModel *m = s->m;
    const int f = NVEL(m);
    for (int i = 0; i < s->nu; i++)
        if (!isfinite(s->u[i])) {
            return mbs_report(s, status, "input %s is not finite (%g); %s",
                          mbs_var_name_of(m, i < f ? MBS_V_QIN : MBS_V_FIN, i < f ? i : i - f), s->u[i], refused);
        }
    s->inputs_dirty = 0;
    if (!memcmp(s->u, s->u_applied, (size_t)s->nu * sizeof(double))) return MBS_OK;
    memcpy(s->u_applied, s->u, (size_t)s->nu * sizeof(double));
    s->q_in_active = 0;
    for (int i = 0; i < f; i++) if (s->u[i] != 0.0) s->q_in_active = 1;
    memcpy(s->td + 3 * m->hdr[H_NDRV], s->u + f, 3 * (size_t)m->hdr[H_NINPUT] * sizeof(double));
    if (s->integ) mbs_integ_inputs_changed(s->integ);
    return MBS_OK;
}

/* Bind the parameters and apply the inputs set since the last step or evaluation; a refusal with `status`. */
int mbs_pending(MbsInstance *s, int status, const char *refused)
{
    if (s->params_dirty) {
        if (mbs_bind(s)) return mbs_report(s, status, "%s; %s", s->msg, refused);
        s->params_dirty = 0;
        mbs_integ_inputs_changed(s->integ);
    }
    return s->inputs_dirty ? mbs_apply_inputs(s, status, refused) : MBS_OK;
}

