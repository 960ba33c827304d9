/* An instance: the bound numbers, inputs, state and integrator of one running scene, and the variables the
 * FMU exposes. Everything is allocated in mbs_instance_new (the integrator at initialization); nothing per
 * step. Failures return MBS_DISCARD/MBS_ERROR with a message (mbs_message, and the logger if any). */
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "call_guard.h"
#include "mbs_integrator.h"
#include "mbs_model.h"

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

/* ------------------------------------------------------------------------------------------ messages */
static int report(MbsInstance *s, int status, const char *fmt, ...)
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
static int say(MbsInstance *s, const char *fmt, ...)
{
    char buf[sizeof s->msg];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    memcpy(s->msg, buf, sizeof buf);
    return MBS_ERROR;
}

/* ------------------------------------------------------------------------------------------ domains
 * scene/domains.py declares them: Domain.contains and check() there, in_domain and rule_problem here, the
 * same rules with the same texts (tests/test_domains.py holds the two equal). */
/* Calls that change the instance are refused while the step observer looks at an internal point (mbs_engine.h). */
#define REFUSED_WHILE_OBSERVING(s, fn)                                                                          \
    if ((s)->observing)                                                                                         \
        return report((s), MBS_ERROR, "%s: not allowed while the step observer runs (the step is in progress at an " \
                      "internal point; variables may be read)", (fn))

static int in_domain(const double *d, double v)
{
    const int flags = (int)d[2];
    if (!isfinite(v)) return 0;
    if ((flags & VD_ZERO) && v == 0.0) return 1;
    return ((flags & VD_LO_OPEN) ? v > d[0] : v >= d[0]) && ((flags & VD_HI_OPEN) ? v < d[1] : v <= d[1]);
}

static void domain_text(const double *d, char *buf, size_t len)
{
    const int flags = (int)d[2];
    if (d[0] == -INFINITY && d[1] == INFINITY) { snprintf(buf, len, "a finite number"); return; }
    snprintf(buf, len, "%s%c%g, %g%c", flags & VD_ZERO ? "0 or " : "", flags & VD_LO_OPEN ? '(' : '[', d[0], d[1],
             flags & VD_HI_OPEN ? ')' : ']');
}

/* Eigenvalues of the symmetric part of a 3 × 3 matrix, ascending (cyclic Jacobi: accurate near repeated ones). */
static void eigenvalues3(const double *A, double lam[3])
{
    double a[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) a[3 * r + c] = 0.5 * (A[3 * r + c] + A[3 * c + r]);
    for (int sweep = 0; sweep < 50 && (a[1] != 0 || a[2] != 0 || a[5] != 0); sweep++)
        for (int p = 0; p < 2; p++)
            for (int q = p + 1; q < 3; q++) {
                const double apq = a[3 * p + q];
                if (apq == 0) continue;
                const double th = (a[3 * q + q] - a[3 * p + p]) / (2 * apq);
                const double t = fabs(th) > 1e150 ? 0.5 / th : (th >= 0 ? 1.0 : -1.0) / (fabs(th) + sqrt(th * th + 1));
                const double c = 1 / sqrt(t * t + 1), sn = t * c;
                for (int k = 0; k < 3; k++) {
                    const double kp = a[3 * k + p], kq = a[3 * k + q];
                    a[3 * k + p] = c * kp - sn * kq;
                    a[3 * k + q] = sn * kp + c * kq;
                }
                for (int k = 0; k < 3; k++) {
                    const double pk = a[3 * p + k], qk = a[3 * q + k];
                    a[3 * p + k] = c * pk - sn * qk;
                    a[3 * q + k] = sn * pk + c * qk;
                }
                a[3 * p + q] = a[3 * q + p] = 0.0;
            }
    lam[0] = a[0]; lam[1] = a[4]; lam[2] = a[8];
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2 - i; j++)
            if (lam[j] > lam[j + 1]) { double x = lam[j]; lam[j] = lam[j + 1]; lam[j + 1] = x; }
}

#define RULE_SIZE(code, size) size,
static const int rule_size[R_N] = {MBS_RULES(RULE_SIZE)};  /* numbers of D each rule reads (mbs_layout.h) */

/* NULL if the rule holds for v (rule_size[rule] numbers), else what is wrong (written into buf). */
static const char *rule_problem(const MbsModel *m, int rule, const double *v, char *buf, size_t len)
{
    const double *lim = m->limits;
    for (int k = 0; k < rule_size[rule]; k++)
        if (!isfinite(v[k])) return snprintf(buf, len, "is not finite (%g)", v[k]), buf;
    if (rule == R_NONNEG)
        return v[0] >= 0 ? NULL : (snprintf(buf, len, "must not be negative, got %g", v[0]), buf);
    if (rule == R_MAGNITUDE)
        return v[0] == 0 || (fabs(v[0]) >= lim[LIM_MAGNITUDE_LO] && fabs(v[0]) <= lim[LIM_MAGNITUDE_HI]) ? NULL :
               (snprintf(buf, len, "%g is outside the magnitudes a model can compute with (%g to %g, or 0)", v[0],
                         lim[LIM_MAGNITUDE_LO], lim[LIM_MAGNITUDE_HI]), buf);
    if (rule == R_AXIS) {
        const double length = hypot(hypot(v[0], v[1]), v[2]);
        if (length == 0) return snprintf(buf, len, "must not be the zero vector"), buf;
        return length >= lim[LIM_AXIS_LO] && length <= lim[LIM_AXIS_HI] ? NULL :
               (snprintf(buf, len, "a direction of length %.3g (allowed: %g to %g)", length, lim[LIM_AXIS_LO],
                         lim[LIM_AXIS_HI]), buf);
    }
    if (rule == R_PERPENDICULAR || rule == R_NOT_PARALLEL) {  /* two axes, each checked by its R_AXIS row first */
        const double c = fabs(v[0] * v[3] + v[1] * v[4] + v[2] * v[5]) / hypot(hypot(v[0], v[1]), v[2]) /
                         hypot(hypot(v[3], v[4]), v[5]);
        if (rule == R_PERPENDICULAR)
            return c <= 1e-9 ? NULL : (snprintf(buf, len, "the two in-plane axes must be perpendicular"), buf);
        return c <= 1 - 1e-9 ? NULL : (snprintf(buf, len, "the two axes of a universal joint must not be parallel"), buf);
    }
    if (rule == R_ROTATION) {  /* numpy.allclose(RᵀR, I, atol=1e-6) and det R > 0 */
        int ok = v[0] * (v[4] * v[8] - v[5] * v[7]) - v[1] * (v[3] * v[8] - v[5] * v[6]) + v[2] * (v[3] * v[7] - v[4] * v[6]) > 0;
        for (int r = 0; ok && r < 3; r++)
            for (int c = 0; ok && c < 3; c++) {
                const double dot = v[r] * v[c] + v[3 + r] * v[3 + c] + v[6 + r] * v[6 + c], want = r == c;
                ok = fabs(dot - want) <= 1e-6 + 1e-5 * want;
            }
        return ok ? NULL : (snprintf(buf, len, "is not a proper rotation (orthonormal columns, determinant +1)"), buf);
    }
    if (rule == R_INERTIA) {
        double lam[3];
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++)  /* numpy.allclose(I, Iᵀ, rtol=1e-9, atol=1e-12) */
                if (!(fabs(v[3 * r + c] - v[3 * c + r]) <= 1e-12 + 1e-9 * fabs(v[3 * c + r])))
                    return snprintf(buf, len, "the inertia tensor must be symmetric"), buf;
        eigenvalues3(v, lam);
        const double tol = 1e-9 * fmax(1.0, fmax(fabs(lam[0]), fabs(lam[2])));
        if (lam[0] < -tol)
            return snprintf(buf, len, "the inertia tensor is not positive semi-definite (principal moments %.4g, %.4g, %.4g)",
                            lam[0], lam[1], lam[2]), buf;
        if (lam[0] + lam[1] < lam[2] - tol)
            return snprintf(buf, len, "principal moments %.4g, %.4g, %.4g break the triangle inequality (I1 + I2 >= I3)",
                            lam[0], lam[1], lam[2]), buf;
    }
    return NULL;
}

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
                return say(s, "%s: body '%s' and the bodies it carries have no mass or inertia, so its joint's motion is "
                           "undetermined (singular mass matrix)", path, m->body_name[row[1]]);
            continue;
        }
        const double *v = s->D + row[1];
        if (rule_problem(m, row[0], v, why, sizeof why))
            return rule_size[row[0]] == 1 ? say(s, "%s = %g: %s", path, v[0], why) : say(s, "%s: %s", path, why);
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
                return say(s, "%s = %g at t = %g: must stay finite over the experiment [%g, %g] s",
                           m->rule_names + row[2], s->td[row[1]], t, lim[LIM_START], lim[LIM_STOP]);
        }
    }
    s->rule_broken = 0;
#else
    (void)s;
#endif
    return MBS_OK;
}

/* Gimbal lock of Cardan joints: |cos b| < 1e-3 at x, or b crossed ±90° since x_before (evaluator.py:
 * singularity_message). Writes the message into buf; 1 if locked. */
static int gimbal(const MbsInstance *s, const double *x, const double *x_before, char *buf, size_t len)
{
    const MbsModel *m = s->m;
    if (!m->hdr[H_NCARDAN]) return 0;
    for (int i = 0; i < NB(m); i++) {
        const MbsBodyI *bi = mbs_body_i(m, i);
        int k = bi->jtype == J_SPH_CARDAN ? 1 : bi->jtype == J_FREE_CARDAN ? 4 : -1;
        if (k < 0 || bi->pos[k] < 0) continue;
        int idx = bi->pos[k];
        double c = cos(x[idx]);
        if (fabs(c) < 1e-3 || (x_before && cos(x_before[idx]) * c < 0)) {
            snprintf(buf, len, "gimbal lock: Cardan angle %s = %.6g rad reached ±90°, where the x-y-z angles of body "
                     "'%s' are singular; use parameterization: quaternion", m->coord_name[idx], x[idx], m->body_name[i]);
            return 1;
        }
    }
    return 0;
}

/* ------------------------------------------------------------------------------------------ the ODE */
static MbsEval evaluation(MbsInstance *s, const double *x, double *xdot)
{
    MbsEval e = {s->m, s->D, s->td, x, s->q_in_active ? s->u_applied : NULL, s->work, s->M, s->k, s->q, xdot,
                 s->elastic_work};
    return e;
}

static void time_numbers(MbsInstance *s, double t)
{
#ifdef MBS_WITH_EXPR
    if (s->time_programs) mbs_run_programs(s->m, 1, s->D, s->td, t);
#else
    (void)s; (void)t;
#endif
}

/* The kinematics at (t, x) into the workspace, unless they are there already: the output points read after a
 * step and the next step's first stage (or an FSAL method's last stage and the output points) share one pass.
 * The stamp is t and x's bits (time_numbers(t) ran before); binding numbers clears it. */
static void kinematics(MbsInstance *s, const MbsEval *e, double t)
{
    int same = s->kin_valid && s->kin_t == t;
    for (int i = 0; same && i < s->n; i++) same = memcmp(s->kin_x + i, e->x + i, sizeof(double)) == 0;  /* bits */
    if (same) return;
    mbs_kinematics(e);
    memcpy(s->kin_x, e->x, (size_t)s->n * sizeof(double));
    s->kin_t = t;
    s->kin_valid = 1;
}

static int ode_f(void *ctx, double t, const double *x, double *xdot)
{
    MbsInstance *s = ctx;
    if (s->m->hdr[H_NCARDAN] && gimbal(s, x, NULL, s->msg, sizeof s->msg)) return MBS_F_GIMBAL;
    time_numbers(s, t);
    MbsEval e = evaluation(s, x, xdot);
    kinematics(s, &e, t);
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
/* Parameters → numbers (bind programs, derived axes and rotations), checked against the scene's rules;
 * MBS_ERROR with the message in s->msg (not logged: the caller reports it). */
static int bind(MbsInstance *s)
{
    const MbsModel *m = s->m;
    s->kin_valid = s->tangent_bound = s->rule_broken = 0;
    for (int p = 0; p < m->hdr[H_NPARAM]; p++)
        if (!isfinite(s->D[p])) {
            return say(s, "parameter %s is not finite (%g)", mbs_var_name_of(m, MBS_V_PARAM, p), s->D[p]);
        }
#ifdef MBS_WITH_EXPR
    mbs_run_programs(m, 0, s->D, NULL, 0.0);
#endif
    mbs_derive(m, s->D);
    if (!m->dense) mbs_composites(m, s->D, s->work);
    if (check_rules(s) || check_times(s)) return MBS_ERROR;
#ifdef MBS_WITH_ELASTIC
    if ((m->hdr[H_FEATURES] & F_ELASTIC) && mbs_elastic_bind(m, s->D, s->msg, sizeof s->msg))
        return MBS_ERROR;
#endif
    for (int k = m->hdr[H_D_BODY]; k < m->hdr[H_ND]; k++)
        if (!isfinite(s->D[k]))
            return say(s, "the parameters give a non-finite number in the scene (entry %d of the compiled data): "
                       "check expressions such as sqrt, log or division by a parameter", k);
    return MBS_OK;
}

static int initial_state(MbsInstance *s)
{
    int rc = bind(s);
    if (rc) return report(s, rc, "%s", s->msg);
    mbs_initial_state(s->m, s->D, s->x);
    s->out_valid = s->der_valid = 0;
    for (int i = 0; i < s->n; i++) if (!isnan(s->start[i])) s->x[i] = s->start[i];
    for (int i = 0; i < s->n; i++)
        if (!isfinite(s->x[i])) return report(s, MBS_ERROR, "initial value of %s is not finite", i < NPOS(s->m) ? s->m->coord_name[i] : "a velocity");
    for (int j = 0; j < s->m->hdr[H_NQUAT]; j++) {  /* start values of a quaternion: a rotation, else not used as given */
        const int *qi = s->m->quat + 7 * j;
        const double *x = s->x;
        const double norm = sqrt(x[qi[0]] * x[qi[0]] + x[qi[1]] * x[qi[1]] + x[qi[2]] * x[qi[2]] + x[qi[3]] * x[qi[3]]);
        const int given = !isnan(s->start[qi[0]]) || !isnan(s->start[qi[1]]) || !isnan(s->start[qi[2]]) || !isnan(s->start[qi[3]]);
        if (given && !(fabs(norm - 1) <= 1e-9))
            return report(s, MBS_ERROR, "start values make the quaternion (y0.%s, y0.%s, y0.%s, y0.%s) = (%g, %g, %g, %g) of "
                          "norm %g, not a rotation: give all four components of a unit quaternion", s->m->coord_name[qi[0]],
                          s->m->coord_name[qi[1]], s->m->coord_name[qi[2]], s->m->coord_name[qi[3]], x[qi[0]], x[qi[1]],
                          x[qi[2]], x[qi[3]], norm);
    }
    s->initial_valid = 1;
    return MBS_OK;
}

/* Inputs held over the next step (or evaluation): refuse NaN/Inf with `status` and `refused` (what did not
 * happen); restart the integrator only on a real change. */
static int apply_inputs(MbsInstance *s, int status, const char *refused)
{
    const MbsModel *m = s->m;
    const int f = NVEL(m);
    for (int i = 0; i < s->nu; i++)
        if (!isfinite(s->u[i])) {
            return report(s, status, "input %s is not finite (%g); %s",
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

/* ------------------------------------------------------------------------------------------ variables */
static int derivatives(MbsInstance *s);
static int var(const MbsInstance *s, int vr, int *idx)
{
    int kind = mbs_model_var_kind(s->m, vr);
    if (kind >= 0) *idx = s->m->vars[2 * vr + 1];
    return kind;
}

/* Parameters set together: tried on the bound numbers, kept only if the scene's rules still hold; else every
 * parameter keeps its value and the message names the values set and the quantity they made invalid. */
static int set_parameters(MbsInstance *s, const unsigned *vr, size_t n, const double *value)
{
    const MbsModel *m = s->m;
    const size_t np = (size_t)m->hdr[H_NPARAM];
    memcpy(s->saved, s->D, np * sizeof(double));
    for (size_t i = 0; i < n; i++)
        if (m->vars[2 * vr[i]] == MBS_V_PARAM) s->D[m->vars[2 * vr[i] + 1]] = value[i];
    if (!bind(s)) {
        s->initial_valid = s->out_valid = s->der_valid = 0;
        if (s->initialized) s->params_dirty = 1;
        return MBS_OK;
    }
    char set[256] = "", why[sizeof s->msg];
    size_t used = 0, count = 0;
    const int derived = s->rule_broken;
    memcpy(why, s->msg, sizeof why);
    for (int changed_only = 1; changed_only >= 0 && !count; changed_only--)  /* the values that changed, else all */
        for (size_t i = 0; i < n && used < sizeof set; i++)
            if (m->vars[2 * vr[i]] == MBS_V_PARAM && (!changed_only || value[i] != s->saved[m->vars[2 * vr[i] + 1]]))
                used += (size_t)snprintf(set + used, sizeof set - used, "%s%s = %g", count++ ? ", " : "",
                                         m->var_name[vr[i]], value[i]);
    memcpy(s->D, s->saved, np * sizeof(double));
    bind(s);  /* the numbers of the kept values again */
    return report(s, MBS_ERROR, "%s%s %s; the parameters keep their values", set,
                  !derived ? ":" : count > 1 ? " make" : " makes", why);
}

int mbs_set_reals(MbsInstance *s, const unsigned *vr, size_t n, const double *value, size_t *bad)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_set_reals");
    const MbsModel *m = s->m;
    size_t nparam = 0;
    char valid[96];
    for (size_t i = 0; i < n; i++) {  /* every value against its variable first: nothing changes on a refusal */
        const int kind = vr[i] < (unsigned)m->hdr[H_NVARS] ? m->vars[2 * vr[i]] : -1;
        const double *d = kind >= MBS_V_PARAM && kind <= MBS_V_STEP ? m->vdom + 3 * kind : NULL;
        if (bad) *bad = i;
        switch (kind) {
        case MBS_V_RTOL: case MBS_V_ATOL: case MBS_V_MAX_STEP: case MBS_V_STEP:
            if (s->initialized)
                return report(s, MBS_ERROR, "%s is a fixed parameter: set it before initialization", m->var_name[vr[i]]);
            /* fall through */
        case MBS_V_PARAM:
            if (!in_domain(d, value[i])) {
                const double old = kind == MBS_V_PARAM ? s->D[m->vars[2 * vr[i] + 1]] : kind == MBS_V_RTOL ? s->rtol :
                                   kind == MBS_V_ATOL ? s->atol : kind == MBS_V_MAX_STEP ? s->max_step : s->step;
                domain_text(d, valid, sizeof valid);
                return report(s, MBS_ERROR, "%s = %g is %s (valid: %s); %s keeps %g", m->var_name[vr[i]], value[i],
                              isfinite(value[i]) ? "outside its domain" : "not finite", valid, m->var_name[vr[i]], old);
            }
            nparam += kind == MBS_V_PARAM;
            break;
        case MBS_V_QIN: case MBS_V_FIN:  /* a non-finite input is refused by the next step (fmi2Discard) */
            break;
        case -1:
            return report(s, MBS_ERROR, "unknown value reference %u", vr[i]);
        default:
            return report(s, MBS_ERROR, "value reference %u is %s, not a Real input or parameter", vr[i],
                          kind == MBS_V_METHOD ? "a String" : "an output");
        }
    }
    if (bad) *bad = n;  /* from here on a refusal is the combination's */
    if (nparam && set_parameters(s, vr, n, value)) return MBS_ERROR;
    for (size_t i = 0; i < n; i++) {
        const int kind = m->vars[2 * vr[i]], idx = m->vars[2 * vr[i] + 1];
        if (kind == MBS_V_QIN || kind == MBS_V_FIN) {
            s->u[kind == MBS_V_QIN ? idx : NVEL(m) + idx] = value[i];
            s->inputs_dirty = 1;
            s->der_valid = 0;
        } else if (kind != MBS_V_PARAM)
            *(kind == MBS_V_RTOL ? &s->rtol : kind == MBS_V_ATOL ? &s->atol : kind == MBS_V_MAX_STEP ? &s->max_step : &s->step) = value[i];
    }
    return MBS_OK;
}

int mbs_set_real(MbsInstance *s, int vr, double value)
{
    const unsigned u = vr < 0 ? UINT_MAX : (unsigned)vr;
    return mbs_set_reals(s, &u, 1, &value, NULL);
}

/* World position and velocity (6 numbers each) of the output points o0 .. o1-1 at state x: one kinematics pass. */
static void output_points(MbsInstance *s, const double *x, double t, int o0, int o1, double *r)
{
    const MbsModel *m = s->m;
    time_numbers(s, t);
    MbsEval e = evaluation(s, x, s->xdot);
    kinematics(s, &e, t);
    for (int o = o0; o < o1; o++, r += 6) {
        const int *oi = m->out + 3 * o;
#ifdef MBS_WITH_ELASTIC
        if (oi[1] >= 0) { mbs_elastic_node_point(&e, oi[0], oi[1], r, r + 3, NULL); continue; }
#endif
        mbs_point(&e, oi[0], s->D + m->hdr[H_D_OUT] + 3 * o, r, r + 3, NULL);
    }
}

int mbs_output_point(MbsInstance *s, int o, const double *x, double t, double out[6])
{
    if (o < 0 || o >= s->m->hdr[H_NOUT]) return report(s, MBS_ERROR, "no output point %d", o);
    if (!s->initialized && !s->initial_valid && initial_state(s)) return MBS_ERROR;  /* numbers bound first */
    output_points(s, x, t, o, o + 1, out);
    return MBS_OK;
}

int mbs_von_mises(MbsInstance *s, int k, const double *x, double *out)
{
    if (k < 0 || k >= s->m->nstress) return report(s, MBS_ERROR, "no stress node %d", k);
#ifdef MBS_WITH_ELASTIC  /* (stress nodes exist only with elastic bodies) */
    *out = mbs_elastic_von_mises(s->m, k, x);
#endif
    return MBS_OK;
}

MBS_NOINLINE int mbs_get_real(MbsInstance *s, int vr, double *value)  /* apart from mbs_get_reals' fast loop */
{
    int idx = 0, kind = var(s, vr, &idx), rc;
    if ((kind == MBS_V_Y || kind == MBS_V_YD || kind == MBS_V_OUT || kind == MBS_V_DER || kind == MBS_V_VM) && !s->initialized &&
        !s->initial_valid && (rc = initial_state(s)))
        return rc;
    switch (kind) {
    case MBS_V_PARAM: *value = s->D[idx]; return MBS_OK;
    case MBS_V_RTOL: *value = s->rtol; return MBS_OK;
    case MBS_V_ATOL: *value = s->atol; return MBS_OK;
    case MBS_V_MAX_STEP: *value = s->max_step; return MBS_OK;
    case MBS_V_STEP: *value = s->step; return MBS_OK;
    case MBS_V_QIN: *value = s->u[idx]; return MBS_OK;
    case MBS_V_FIN: *value = s->u[NVEL(s->m) + idx]; return MBS_OK;
    case MBS_V_Y: *value = s->x[idx]; return MBS_OK;
    case MBS_V_YD: *value = s->x[NPOS(s->m) + idx]; return MBS_OK;
    case MBS_V_OUT:
        if (!s->out_valid) {  /* all points at once: one kinematics pass per state, not one per variable */
            if (s->params_dirty && (rc = bind(s))) return report(s, rc, "%s", s->msg);  /* a parameter set since the step */
            output_points(s, s->x, s->time, 0, s->m->hdr[H_NOUT], s->out);
            s->out_valid = 1;
        }
        *value = s->out[idx];
        return MBS_OK;
    case MBS_V_DER:
        if ((rc = derivatives(s))) return rc;
        *value = s->der[idx];
        return MBS_OK;
#ifdef MBS_WITH_ELASTIC
    case MBS_V_VM: *value = mbs_elastic_von_mises(s->m, idx, s->x); return MBS_OK;  /* only with elastic bodies */
#endif
    case -1: return report(s, MBS_ERROR, "unknown value reference %d", vr);
    default: return report(s, MBS_ERROR, "value reference %d is a String", vr);
    }
}

/* n values by value reference: what a master reads after every step (states, output points already computed
 * for this state) straight from the instance's [y; ẏ; output points] block; the rest as mbs_get_real. */
int mbs_get_reals(MbsInstance *s, const unsigned *vr, size_t n, double *value)
{
    const unsigned nvars = (unsigned)s->m->hdr[H_NVARS];
    const int32_t *read = s->m->read;
    const double *block = s->x;  /* [y; ẏ; output points] */
    for (size_t i = 0; i < n; i++) {
        /* entries of the block that hold this state's values (-1 in read, as unsigned, is past any limit) */
        const unsigned limit = !s->initialized ? 0u : (unsigned)(s->n + (s->out_valid ? 6 * s->m->hdr[H_NOUT] : 0));
        for (; i < n && vr[i] < nvars && (unsigned)read[vr[i]] < limit; i++) value[i] = block[read[vr[i]]];
        if (i == n) break;
        if (vr[i] > (unsigned)INT_MAX) return report(s, MBS_ERROR, "unknown value reference %u", vr[i]);
        int rc = mbs_get_real(s, (int)vr[i], value + i);
        if (rc) return rc;
    }
    return MBS_OK;
}

int mbs_set_start(MbsInstance *s, int index, double value)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_set_start");
    char why[160];
    if (index < 0 || index >= s->n) return report(s, MBS_ERROR, "no state entry %d", index);
    if (s->initialized) return report(s, MBS_ERROR, "start values are set before initialization");
    if (rule_problem(s->m, R_MAGNITUDE, &value, why, sizeof why)) {  /* the rule of the scene's `initial:` values */
        const MbsModel *m = s->m;
        const char *name = index < NPOS(m) ? m->coord_name[index] : NULL;
        for (int vr = 0; !name && vr < m->hdr[H_NVARS]; vr++)
            if (m->vars[2 * vr] == MBS_V_YD && m->vars[2 * vr + 1] == index - NPOS(m)) name = m->var_name[vr] + 3;
        return report(s, MBS_ERROR, "%s0.%s = %g%s%s; the start value is unchanged", index < NPOS(m) ? "y" : "yd",
                      name ? name : "?", value, isfinite(value) ? ": " : " is not finite", isfinite(value) ? why : "");
    }
    s->start[index] = value;
    s->initial_valid = s->der_valid = 0;
    return MBS_OK;
}

int mbs_set_string(MbsInstance *s, int vr, const char *value)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_set_string");
    if (mbs_model_var_kind(s->m, vr) != MBS_V_METHOD) return report(s, MBS_ERROR, "value reference %d is not a String parameter", vr);
    if (s->initialized) return report(s, MBS_ERROR, "integrator.method is a fixed parameter: set it before initialization");
    int k = value ? mbs_method_index(value) : -1;
    if (k < 0) {
        char valid[128] = "";
        for (int i = 0; i < MBS_NMETHODS; i++) { strcat(valid, i ? ", " : ""); strcat(valid, mbs_method_names[i]); }
        return report(s, MBS_ERROR, "unknown integrator method '%.60s'; valid: %s", value ? value : "(null)", valid);
    }
    s->method = k;
    return MBS_OK;
}

int mbs_get_string(MbsInstance *s, int vr, const char **value)
{
    if (mbs_model_var_kind(s->m, vr) != MBS_V_METHOD) return report(s, MBS_ERROR, "value reference %d is not a String", vr);
    *value = mbs_method_names[s->method];
    return MBS_OK;
}

/* ------------------------------------------------------------------------------------------ running */
/* The integrator accepted an internal step at (t, x): the observer sees the instance there (outputs computed for
 * that point when read), changes refused. mbs_do_step moves the instance to the step's end afterwards. */
static void observe_point(void *ctx, double t, const double *x)
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
    if (s->integ) mbs_integ_set_observer(s->integ, fn ? observe_point : NULL, s);
    return MBS_OK;
}

static MbsIntegrator *new_integrator(MbsInstance *s, int method, char *err, size_t len)
{
    const MbsModel *m = s->m;
    MbsOde ode = {s->n, NPOS(m), NVEL(m), s, ode_f, ode_message, m->hdr[H_NQUAT] ? ode_normalize : NULL,
                  m->hdr[H_NQUAT] ? ode_retract : NULL};
    MbsIntegOptions opt = {s->rtol, s->atol, s->max_step > 0 ? s->max_step : INFINITY, s->step,
                           m->D[m->hdr[H_D_INTEG] + DI_RHO_INF], 0, -1};
    MbsIntegrator *it = mbs_integ_new(method, &ode, &opt, err, len);
    if (it && s->observe) mbs_integ_set_observer(it, observe_point, s);
    return it;
}

int mbs_initialize(MbsInstance *s, double t0)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_initialize");
    char err[512];
    if (!isfinite(t0)) return report(s, MBS_ERROR, "start time is not finite");
    int rc = initial_state(s);
    if (rc) return rc;
    mbs_integ_free(s->integ);
    s->integ = new_integrator(s, s->method, err, sizeof err);
    if (!s->integ) return report(s, MBS_ERROR, "integrator %s: %s", mbs_method_names[s->method], err);
    if (mbs_integ_reset(s->integ, t0, s->x)) return report(s, MBS_ERROR, "%s", mbs_integ_message(s->integ));
    s->time = t0;
    s->initialized = 1;
    s->rhs_ok = 0;
    s->params_dirty = 0;
    memset(s->u_applied, 0, (size_t)s->nu * sizeof(double));  /* apply_inputs compares against this */
    s->inputs_dirty = 1;
    return MBS_OK;
}

/* Bind the parameters and apply the inputs set since the last step or evaluation; a refusal with `status`. */
static int pending(MbsInstance *s, int status, const char *refused)
{
    if (s->params_dirty) {
        if (bind(s)) return report(s, status, "%s; %s", s->msg, refused);
        s->params_dirty = 0;
        mbs_integ_inputs_changed(s->integ);
    }
    return s->inputs_dirty ? apply_inputs(s, status, refused) : MBS_OK;
}

/* Before a step at t: bind changed parameters and inputs, check that t is the current time. */
static int prepare(MbsInstance *s, double t)
{
    if (!s->initialized) return report(s, MBS_ERROR, "the instance is not initialized");
    int rc = pending(s, MBS_DISCARD, "step refused");
    if (rc) return rc;
    if (!isfinite(t) || fabs(t - s->time) > 1e-9 * (fabs(t) > 1.0 ? fabs(t) : 1.0))
        return report(s, MBS_ERROR, "do_step called at t=%.17g but the simulation is at t=%.17g", t, s->time);
    return MBS_OK;
}

/* The integrator stopped at its last good point: move there and say why. */
static int failed(MbsInstance *s)
{
    char extra[512] = "";
    const char *why = mbs_integ_message(s->integ);
    s->time = mbs_integ_t(s->integ);
    memcpy(s->x, mbs_integ_x(s->integ), (size_t)s->n * sizeof(double));
    if (gimbal(s, s->x, NULL, extra, sizeof extra) && strstr(why, "gimbal")) extra[0] = 0;
    return report(s, MBS_DISCARD, "t = %.9g: %s%s%s", s->time, why, extra[0] ? "; " : "", extra);
}

int mbs_do_step(MbsInstance *s, double t, double h)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_do_step");
    s->out_valid = s->der_valid = 0;
    int rc = prepare(s, t);
    if (rc) return rc;
    if (!(h >= 0) || !isfinite(h)) return report(s, MBS_ERROR, "communication step size %g is not a non-negative number", h);
    const int cardan = s->m->hdr[H_NCARDAN] > 0;
    if (cardan) memcpy(s->x_before, s->x, (size_t)s->n * sizeof(double));
    if (mbs_integ_advance(s->integ, t + h)) return failed(s);
    s->time = mbs_integ_t(s->integ);
    memcpy(s->x, mbs_integ_x(s->integ), (size_t)s->n * sizeof(double));
    /* a coarse step may jump across b = ±90° without landing near it */
    if (cardan && gimbal(s, s->x, s->x_before, s->msg, sizeof s->msg))
        return report(s, MBS_DISCARD, "t = %.9g: %s", s->time, s->msg);
    if (s->observe) observe_point(s, s->time, s->x);  /* the step's end: its last internal point, or interpolated */
    return MBS_OK;
}

int mbs_run(MbsInstance *s, const double *ts, int n, double *X)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_run");
    s->out_valid = s->der_valid = 0;
    if (n < 1) return report(s, MBS_ERROR, "no time points");
    int rc = prepare(s, ts[0]);
    if (rc) return rc;
    for (int k = 1; k < n; k++)
        if (!(ts[k] > ts[k - 1])) return report(s, MBS_ERROR, "time points must increase (%g after %g)", ts[k], ts[k - 1]);
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

/* ------------------------------------------------------------------------------------------ evaluation */
int mbs_equations(MbsInstance *s, double t, const double *x, double *M, double *k, double *q)
{
    if (!s->initialized && !s->initial_valid && initial_state(s)) return MBS_ERROR;
    if (s->inputs_dirty && apply_inputs(s, MBS_ERROR, "not evaluated")) return MBS_ERROR;
    time_numbers(s, t);
    MbsEval e = evaluation(s, x, s->xdot);
    e.M = M; e.k = k; e.q = q;
    kinematics(s, &e, t);
    if (!s->m->dense) {
        mbs_crba_rnea(&e);
        return MBS_OK;
    }
    mbs_mass_matrix_and_bias(&e);
    mbs_applied_forces(&e);
    return MBS_OK;
}

/* The name of state entry i: its y.* or yd.* variable's. */
static const char *state_name(const MbsModel *m, int i)
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
static int finite_result(MbsInstance *s, const char *what, double t, const double *x, const double *v, size_t n,
                         const unsigned *vr)
{
    for (size_t i = 0; i < n; i++)
        if (!isfinite(v[i])) {
            double big = 0.0;
            for (int j = 0; j < s->n; j++) big = fmax(big, fabs(x[j]));
            return report(s, MBS_DISCARD, "t = %.9g: %s %s is %g, not finite at this state (an intermediate "
                          "overflowed, or an expression left its domain; largest |y|, |ẏ|: %.3g)", t, what,
                          vr ? s->m->var_name[vr[i]] : state_name(s->m, (int)i), v[i], big);
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
    if (!s->initialized && !s->initial_valid && initial_state(s)) return MBS_ERROR;
    if (s->inputs_dirty && apply_inputs(s, MBS_ERROR, "not evaluated")) return MBS_ERROR;
    double *into = overlap(x, xdot, s->n) ? s->xdot : xdot;
    if (ode_f(s, t, x, into)) return report(s, MBS_ERROR, "%s", s->msg);
    int rc = finite_result(s, "the time derivative of", t, x, into, (size_t)s->n, NULL);
    if (!rc && into != xdot) memmove(xdot, into, (size_t)s->n * sizeof *xdot);
    return rc;
}

/* ------------------------------------------------------------------------------------------ model exchange
 * The host integrates x = [y; ẏ]: it sets the time and the states, the engine gives ẋ (mbs_engine.h). */

int mbs_set_time(MbsInstance *s, double t)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_set_time");
    if (!s->initialized) return report(s, MBS_ERROR, "the instance is not initialized");
    if (!isfinite(t)) return report(s, MBS_ERROR, "time %g is not finite; the time stays %.17g", t, s->time);
    if (t != s->time) s->time = t, s->out_valid = s->der_valid = 0;
    return MBS_OK;
}

int mbs_set_state(MbsInstance *s, const double *x, size_t n)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_set_state");
    if (!s->initialized) return report(s, MBS_ERROR, "the instance is not initialized");
    if (!x || n != (size_t)s->n)
        return report(s, MBS_ERROR, "%zu continuous states given, the model has %d; states unchanged", x ? n : 0, s->n);
    for (int i = 0; i < s->n; i++)
        if (!isfinite(x[i]))
            return report(s, MBS_ERROR, "continuous state %s = %g is not finite; states unchanged", state_name(s->m, i), x[i]);
    if (memcmp(s->x, x, n * sizeof *x)) {
        memcpy(s->x, x, n * sizeof *x);
        s->out_valid = s->der_valid = 0;
    }
    return MBS_OK;
}

/* ẋ at (time, x) into s->der, once per time, state, inputs and parameters. Before initialization: at the initial
 * state (as the other getters). The host's inputs or parameters refused: MBS_ERROR; not defined at this state
 * (singular mass matrix, gimbal lock): MBS_DISCARD. */
static int derivatives(MbsInstance *s)
{
    if (s->der_valid) return MBS_OK;
    int rc = !s->initialized && !s->initial_valid ? initial_state(s) : MBS_OK;
    if (!rc) rc = pending(s, MBS_ERROR, "no derivatives");
    if (rc) return rc;
    if (ode_f(s, s->time, s->x, s->der)) return report(s, MBS_DISCARD, "t = %.9g: %s", s->time, s->msg);
    if ((rc = finite_result(s, "the time derivative of", s->time, s->x, s->der, (size_t)s->n, NULL))) return rc;
    s->der_valid = 1;
    return MBS_OK;
}

int mbs_derivatives(MbsInstance *s, double *xdot, size_t n)
{
    if (!xdot || n != (size_t)s->n)
        return report(s, MBS_ERROR, "room for %zu derivatives, the model has %d", xdot ? n : 0, s->n);
    int rc = derivatives(s);
    if (!rc) memcpy(xdot, s->der, n * sizeof *xdot);
    return rc;
}

/* ------------------------------------------------------------------------------------------ directional derivatives
 * J = ∂(unknowns)/∂(knowns) at (time, x) with the inputs and parameters set (mbs_engine.h), one column J·seed per
 * complex-step evaluation (deriv.c). */

/* why value reference vr cannot be a known (a state or an input) or an unknown (ẋ, an output, a state); NULL if it can */
static const char *not_a(const MbsModel *m, unsigned vr, int known)
{
    const int kind = vr < (unsigned)m->hdr[H_NVARS] ? m->vars[2 * vr] : -1;
    if (kind == MBS_V_Y || kind == MBS_V_YD) return NULL;
    if (known) return kind == MBS_V_QIN || kind == MBS_V_FIN ? NULL : "a continuous state or an input";
    return kind == MBS_V_DER || kind == MBS_V_OUT || kind == MBS_V_VM ? NULL : "a derivative, an output or a state";
}

static int check_refs(MbsInstance *s, const char *what, const unsigned *vr, size_t n, int known)
{
    for (size_t i = 0; i < n; i++) {
        const char *want = not_a(s->m, vr[i], known);
        if (want)
            return report(s, MBS_ERROR, "%s value reference %u (%s) is not %s", what, vr[i],
                          vr[i] < (unsigned)s->m->hdr[H_NVARS] ? s->m->var_name[vr[i]] : "unknown", want);
    }
    return MBS_OK;
}

/* J seed into the tangent workspace (the knowns and unknowns checked; the instance prepared as for ẋ, before
 * initialization at the initial state); only what the unknowns need is evaluated. */
static int tangent(MbsInstance *s, const unsigned *unknown, size_t nunknown, const unsigned *known, size_t nknown,
                   const double *seed)
{
    const MbsModel *m = s->m;
    const int f = NVEL(m), nout = m->hdr[H_NOUT];
    if (!s->tangent) {
        const size_t bytes = mbs_tangent_work_size(m);  /* a multiple of 16 */
        s->tangent = calloc(1, bytes + sizeof(double) * (2 * (size_t)s->n + s->nu + 6 * (size_t)nout + m->nstress));
        if (!s->tangent) return report(s, MBS_ERROR, "no memory for the directional derivatives' workspace");
        s->dx = (double *)((char *)s->tangent + bytes);
    }
    double *dx = s->dx, *du = dx + s->n, *dxdot = du + s->nu, *dout = dxdot + s->n, *dvm = dout + 6 * (size_t)nout;
    int want[MBS_V_N] = {0};
    int rc = !s->initialized && !s->initial_valid ? initial_state(s) : MBS_OK;
    if (!rc) rc = pending(s, MBS_ERROR, "no directional derivatives");
    if (rc) return rc;
    memset(dx, 0, sizeof(double) * ((size_t)s->n + s->nu));
    for (size_t j = 0; j < nknown; j++) {
        const int kind = m->vars[2 * known[j]], idx = m->vars[2 * known[j] + 1];
        if (!isfinite(seed[j]))
            return report(s, MBS_ERROR, "the seed of %s is not finite (%g)", m->var_name[known[j]], seed[j]);
        *(kind == MBS_V_Y ? dx + idx : kind == MBS_V_YD ? dx + NPOS(m) + idx : kind == MBS_V_QIN ? du + idx : du + f + idx) += seed[j];
    }
    for (size_t i = 0; i < nunknown; i++) want[m->vars[2 * unknown[i]]] = 1;
    const MbsTangent t = {s->D, s->td, s->x, s->q_in_active ? s->u_applied : NULL, dx, du, du + f,
                          want[MBS_V_DER] ? dxdot : NULL, want[MBS_V_OUT] ? dout : NULL, want[MBS_V_VM] ? dvm : NULL,
                          !s->tangent_bound};
    time_numbers(s, s->time);
    s->tangent_bound = 1;
    if (mbs_tangent(m, &t, s->tangent))
        return report(s, MBS_DISCARD, "t = %.9g: no directional derivatives: the mass matrix is singular here", s->time);
    return MBS_OK;
}

/* the derivative of unknown vr that tangent() left */
static double tangent_of(const MbsInstance *s, unsigned vr)
{
    const MbsModel *m = s->m;
    const int kind = m->vars[2 * vr], idx = m->vars[2 * vr + 1];
    const double *dx = s->dx, *dxdot = dx + s->n + s->nu, *dout = dxdot + s->n;
    return kind == MBS_V_DER ? dxdot[idx] : kind == MBS_V_OUT ? dout[idx] : kind == MBS_V_VM ? dout[6 * m->hdr[H_NOUT] + idx] :
           kind == MBS_V_Y ? dx[idx] : dx[NPOS(m) + idx];
}

static int check_all(MbsInstance *s, const unsigned *unknown, size_t nunknown, const unsigned *known, size_t nknown,
                     const double *seed, size_t nseed, const double *sensitivity, size_t nsens, const char *what)
{
    if ((nunknown && !unknown) || (nknown && !known) || (nseed && !seed) || (nsens && !sensitivity))
        return report(s, MBS_ERROR, "%s derivative: NULL arrays for %zu unknowns and %zu knowns", what, nunknown, nknown);
    int rc = check_refs(s, "unknown", unknown, nunknown, 0);
    return rc ? rc : check_refs(s, "known", known, nknown, 1);
}

int mbs_directional_derivative(MbsInstance *s, const unsigned *unknown, size_t nunknown, const unsigned *known,
                               size_t nknown, const double *seed, double *sensitivity)
{
    int rc = check_all(s, unknown, nunknown, known, nknown, seed, nknown, sensitivity, nunknown, "directional");
    if (!rc && nunknown) rc = tangent(s, unknown, nunknown, known, nknown, seed);  /* none asked: nothing to do */
    for (size_t i = 0; !rc && i < nunknown; i++) sensitivity[i] = tangent_of(s, unknown[i]);
    return rc ? rc : finite_result(s, "the directional derivative of", s->time, s->x, sensitivity, nunknown, unknown);
}

/* sensitivityᵀ = seedᵀ J: one column of J per known (complex step is forward mode) */
int mbs_adjoint_derivative(MbsInstance *s, const unsigned *unknown, size_t nunknown, const unsigned *known,
                           size_t nknown, const double *seed, double *sensitivity)
{
    int rc = check_all(s, unknown, nunknown, known, nknown, seed, nunknown, sensitivity, nknown, "adjoint");
    for (size_t i = 0; !rc && i < nunknown; i++)
        if (!isfinite(seed[i])) rc = report(s, MBS_ERROR, "the seed of %s is not finite (%g)", s->m->var_name[unknown[i]], seed[i]);
    const double one = 1.0;
    for (size_t j = 0; !rc && j < nknown; j++) {
        if ((rc = tangent(s, unknown, nunknown, known + j, 1, &one))) break;
        sensitivity[j] = 0.0;
        for (size_t i = 0; i < nunknown; i++) sensitivity[j] += seed[i] * tangent_of(s, unknown[i]);
    }
    return rc ? rc : finite_result(s, "the adjoint derivative's entry of", s->time, s->x, sensitivity, nknown, known);
}

/* ------------------------------------------------------------------------------------------ state bytes
 * header (call_guard.h, which both FMU kinds check too): "MBSS", uint32 version, char guid[64], uint64 payload
 * length, uint64 FNV-1a checksum of the payload;
 * payload: Head, parameters (nparam), u, u_applied, x (n), then the integrator snapshot (initialized only). */
#define HEADER_SIZE MBS_STATE_HEADER
typedef struct {
    double time, rtol, atol, max_step, step;
    int32_t initialized, method, q_in_active, params_dirty;
} Head;

static size_t payload_size(const MbsInstance *s, size_t integ_size)
{
    return sizeof(Head) + sizeof(double) * ((size_t)s->m->hdr[H_NPARAM] + 2 * (size_t)s->nu + s->n) + integ_size;
}

size_t mbs_state_size(const MbsInstance *s)
{
    return HEADER_SIZE + payload_size(s, s->initialized ? mbs_integ_snapshot_size(s->integ) : 0);
}

int mbs_state_save(const MbsInstance *s, void *buf, size_t len)
{
    size_t need = mbs_state_size(s), isz = s->initialized ? mbs_integ_snapshot_size(s->integ) : 0;
    if (!buf || len < need) return MBS_ERROR;
    unsigned char *p = buf, *pay = p + HEADER_SIZE;
    Head h = {s->time, s->rtol, s->atol, s->max_step, s->step, s->initialized, s->method, s->q_in_active, s->params_dirty};
    unsigned char *w = pay;
    memcpy(w, &h, sizeof h);                                               w += sizeof h;
    memcpy(w, s->D, sizeof(double) * s->m->hdr[H_NPARAM]);                 w += sizeof(double) * s->m->hdr[H_NPARAM];
    memcpy(w, s->u, sizeof(double) * s->nu);                               w += sizeof(double) * s->nu;
    memcpy(w, s->u_applied, sizeof(double) * s->nu);                       w += sizeof(double) * s->nu;
    memcpy(w, s->x, sizeof(double) * s->n);                                w += sizeof(double) * s->n;
    if (isz) mbs_integ_snapshot_save(s->integ, w);
    uint32_t version = MBS_STATE_VERSION;
    uint64_t plen = payload_size(s, isz), sum = mbs_state_checksum(pay, plen);
    memcpy(p, "MBSS", 4);
    memcpy(p + 4, &version, 4);
    memset(p + 8, 0, 64);
    memcpy((char *)p + 8, s->m->guid, strlen(s->m->guid));
    memcpy(p + 72, &plen, 8);
    memcpy(p + 80, &sum, 8);
    return MBS_OK;
}

int mbs_state_load(MbsInstance *s, const void *buf, size_t len)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_state_load");
    const unsigned char *p = buf;
    uint64_t plen;
    Head h;
    const char *why = mbs_state_header_problem(p, len, sizeof h, s->m->guid);
    if (why) return report(s, MBS_ERROR, "%s (%zu bytes); state unchanged", why, len);
    memcpy(&plen, p + 72, 8);
    const unsigned char *r = p + HEADER_SIZE;
    memcpy(&h, r, sizeof h);
    if ((h.initialized != 0 && h.initialized != 1) || h.method < 0 || h.method >= MBS_NMETHODS ||
        (h.q_in_active != 0 && h.q_in_active != 1) || (h.params_dirty != 0 && h.params_dirty != 1))
        return report(s, MBS_ERROR, "FMU state has invalid fields; state unchanged");
    MbsIntegrator *it = NULL;
    size_t isz = 0;
    if (h.initialized) {
        char err[256];
        double save[4] = {s->rtol, s->atol, s->max_step, s->step};
        s->rtol = h.rtol; s->atol = h.atol; s->max_step = h.max_step; s->step = h.step;
        it = new_integrator(s, h.method, err, sizeof err);
        s->rtol = save[0]; s->atol = save[1]; s->max_step = save[2]; s->step = save[3];
        if (!it) return report(s, MBS_ERROR, "FMU state: %s; state unchanged", err);
        isz = mbs_integ_snapshot_size(it);
    }
    if (plen != payload_size(s, isz)) { mbs_integ_free(it); return report(s, MBS_ERROR, "FMU state has the wrong size for this model; state unchanged"); }
    const unsigned char *ip = r + payload_size(s, 0);
    if (it && mbs_integ_snapshot_load(it, ip, isz)) { mbs_integ_free(it); return report(s, MBS_ERROR, "FMU state: corrupt integrator data; state unchanged"); }
    /* all checks passed: commit */
    const int np = s->m->hdr[H_NPARAM];
    r += sizeof h;
    memcpy(s->D, r, sizeof(double) * np);                r += sizeof(double) * np;
    memcpy(s->u, r, sizeof(double) * s->nu);             r += sizeof(double) * s->nu;
    memcpy(s->u_applied, r, sizeof(double) * s->nu);     r += sizeof(double) * s->nu;
    memcpy(s->x, r, sizeof(double) * s->n);
    s->out_valid = s->der_valid = 0;
    s->time = h.time; s->rtol = h.rtol; s->atol = h.atol; s->max_step = h.max_step; s->step = h.step;
    s->method = h.method;
    s->q_in_active = h.q_in_active;
    s->initialized = h.initialized;
    mbs_integ_free(s->integ);
    s->integ = it;
    memcpy(s->td + 3 * s->m->hdr[H_NDRV], s->u_applied + NVEL(s->m), 3 * (size_t)s->m->hdr[H_NINPUT] * sizeof(double));
    /* numbers from the restored parameters; a failure shows at the next step */
    s->params_dirty = h.params_dirty;
    s->initial_valid = 0;
    if (bind(s)) s->params_dirty = 1;
    s->inputs_dirty = memcmp(s->u, s->u_applied, sizeof(double) * s->nu) != 0;
    if (!s->initialized) s->initial_valid = 0;
    s->msg[0] = 0;
    return MBS_OK;
}
