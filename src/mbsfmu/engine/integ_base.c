/* The common integrator driver: options, reset, advance to exact communication points with the step size
 * carried over, dense output (ahead point + segment), advance_many, stats, snapshots, messages.
 * Methods plug in through MbsMethodClass (integ_base.h); each public call goes to the class's MbsIntegOps:
 * mbs_single_ops (below) for a method of hooks, a composite's own (auto, integ_auto.c). */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "integ_base.h"

#define METHOD_NAME(code, name, ...) name,
const char *const mbs_method_names[MBS_NMETHODS] = {MBS_METHODS(METHOD_NAME)};
#undef METHOD_NAME
#define METHOD_LISTED(code, name, ...) ", " name
#define METHODS_LISTED (MBS_METHODS(METHOD_LISTED)) /* ", rk4, dopri5, ..." */

#define METHOD_CLASS(code, name, cls, ...) [code] = &mbs_##cls##_class,
static const MbsMethodClass *const method_classes[MBS_NMETHODS] = {MBS_METHODS(METHOD_CLASS)};
#undef METHOD_CLASS

#define SNAP_HEADER 24 /* "MBSI", method, n, dense (int32 each), history bytes (uint64) */

/* ------------------------------------------------------------------------------------------- messages */

/* Python's format(v, ".<digits>g") is C's %.<digits>g (trailing zeros stripped, exponent of 2 digits at least) */
static void fmt_g(char *buf, double v, int digits)
{
    snprintf(buf, 32, "%.*g", digits < 1 ? 1 : digits > 17 ? 17 : digits, v);
}

/* the shortest %g that reads back as the same double (Python's repr, close enough for messages) */
static void fmt_repr(char *buf, double v)
{
    int digits;
    for (digits = 1; digits < 17; digits++) {
        fmt_g(buf, v, digits);
        if (strtod(buf, NULL) == v) return;
    }
    fmt_g(buf, v, 17);
}

void mbs_msg_set(MbsIntegrator *it, const char *s)
{
    it->msg[0] = '\0';
    it->msg_len = 0;
    mbs_msg_add(it, s);
}

void mbs_msg_add(MbsIntegrator *it, const char *s)
{
    size_t k = strlen(s);
    if (k > MBS_MSG_LEN - 1 - it->msg_len) k = MBS_MSG_LEN - 1 - it->msg_len;
    memcpy(it->msg + it->msg_len, s, k);
    it->msg_len += k;
    it->msg[it->msg_len] = '\0';
}

void mbs_msg_num(MbsIntegrator *it, double v, int digits)
{
    char b[40];
    fmt_g(b, v, digits);
    mbs_msg_add(it, b);
}

void mbs_msg_long(MbsIntegrator *it, long long v)
{
    char b[32];
    snprintf(b, sizeof b, "%lld", v);
    mbs_msg_add(it, b);
}

/* error text for mbs_integ_new: a + v (repr) + b, truncated to errlen */
static void err_put(char *err, size_t errlen, const char *a, const double *v, const char *b)
{
    char num[40] = "";
    size_t k = 0;
    const char *parts[3];
    int i;
    if (!err || !errlen) return;
    if (v) fmt_repr(num, *v);
    parts[0] = a;
    parts[1] = num;
    parts[2] = b ? b : "";
    for (i = 0; i < 3; i++) {
        const char *s = parts[i];
        while (*s && k + 1 < errlen) err[k++] = *s++;
    }
    err[k] = '\0';
}

/* ------------------------------------------------------------------------------------------- helpers */

int mbs_all_finite(int n, const double *v)
{
    double s = 0.0;
    int k;
    for (k = 0; k < n; k++) s += v[k] * 0.0; /* 0 unless some entry is NaN or Inf */
    return s == 0.0;
}

void mbs_integ_normalize(MbsIntegrator *it, double *x)
{
    if (it->ode.normalize) it->ode.normalize(it->ode.ctx, x);
}

int mbs_integ_f(MbsIntegrator *it, double t, const double *x, double *xdot)
{
    int r = it->ode.f(it->ode.ctx, t, x, xdot);
    it->c->rhs_evaluations++;
    if (r != MBS_F_OK) {
        const char *m = it->ode.message ? it->ode.message(it->ode.ctx) : NULL;
        mbs_msg_set(it, m && *m ? m : "right-hand side failed");
    }
    return r;
}

double mbs_err_norm(int n, const double *err, const double *x_old, const double *x_new, double atol, double rtol)
{
    double s = 0.0;
    int k;
    for (k = 0; k < n; k++) {
        double e = err[k] / (atol + rtol * mbs_pymax(fabs(x_old[k]), fabs(x_new[k])));
        s += e * e;
    }
    return sqrt(s / n);
}

int mbs_integ_check_start(MbsIntegrator *it, const double *f0)
{
    if (mbs_all_finite(it->n, f0)) return 0;
    mbs_msg_set(it, "right-hand side returned non-finite values (NaN or Inf) at the current state");
    return 1;
}

int mbs_integ_trial_nonfinite(MbsIntegrator *it, double h, const char *what)
{
    MbsCommon *c = it->c;
    c->nonfinite++;
    if (c->nonfinite > MBS_MAX_NONFINITE_TRIALS) {
        mbs_msg_set(it, what);
        mbs_msg_add(it, " returned non-finite values (NaN or Inf) even for step size ");
        mbs_msg_num(it, h, 3);
        return MBS_FAIL;
    }
    c->h = 0.25 * h;
    return MBS_REJECT;
}

int mbs_integ_stage_failed(MbsIntegrator *it, double h)
{
    MbsCommon *c = it->c;
    if (c->steps > 0 || ++c->nonfinite > MBS_MAX_NONFINITE_TRIALS) return MBS_FAIL;  /* the ODE's message is set */
    c->h = 0.25 * h;
    return MBS_REJECT;
}

/* HINIT: h from ‖x‖/‖f‖ and a difference quotient of f for the second derivative (Hairer I, II.4). */
int mbs_integ_initial_step(MbsIntegrator *it, const double *f0, int order, double t_end)
{
    MbsCommon *c = it->c;
    const double *x = it->x;
    double *x1 = it->tmp1, *f1 = it->tmp2;
    double t = c->t, span = t_end - t, d0 = 0.0, d1 = 0.0, d2 = 0.0, h0, h1, dmax;
    int n = it->n, k;
    for (k = 0; k < n; k++) {
        double sc = it->atol + it->rtol * fabs(x[k]);
        d0 += (x[k] / sc) * (x[k] / sc);
        d1 += (f0[k] / sc) * (f0[k] / sc);
    }
    d0 = sqrt(d0 / n);
    d1 = sqrt(d1 / n);
    h0 = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
    h0 = mbs_pymin(mbs_pymin(h0, it->max_step), span);
    for (k = 0; k < n; k++) x1[k] = x[k] + h0 * f0[k]; /* explicit Euler trial step */
    if (mbs_integ_f(it, t + h0, x1, f1)) return 1;
    for (k = 0; k < n; k++) {
        double sc = it->atol + it->rtol * fabs(x[k]);
        double q = (f1[k] - f0[k]) / sc;
        d2 += q * q;
    }
    d2 = sqrt(d2 / n) / h0;
    c->has_h = 1;
    if (!isfinite(d2)) { /* unusable trial point (NaN there): start very small, the controller grows h */
        c->h = mbs_pymax(h0 * 1e-3, 1e-12 * mbs_pymax(fabs(t), 1.0));
        return 0;
    }
    dmax = mbs_pymax(d1, d2);
    h1 = dmax <= 1e-15 ? mbs_pymax(1e-6, h0 * 1e-3) : pow(0.01 / dmax, 1.0 / (order + 1));
    c->h = mbs_pymin(mbs_pymin(100.0 * h0, h1), it->max_step);
    return 0;
}

int mbs_integ_fixed_substeps_many(MbsIntegrator *it, double span, double h_max, double ulps, long *nsub)
{
    double q = isfinite(h_max) ? ceil(span / h_max * (1.0 - 1e-12) - ulps / h_max) : 1.0;
    if (!(q >= 1.0)) q = 1.0;
    if (q > (double)it->max_steps) {
        mbs_msg_set(it, "maximum number of steps (");
        mbs_msg_long(it, it->max_steps);
        mbs_msg_add(it, ") exceeded: fixed step ");
        mbs_msg_num(it, h_max, 3);
        mbs_msg_add(it, " over an interval of ");
        mbs_msg_num(it, span, 3);
        return 1;
    }
    *nsub = (long)q;
    return 0;
}

/* ------------------------------------------------------------------------------------------- driver */

/* Make t_end (inside the step ending at the ahead point) the visible point. */
static void land(MbsIntegrator *it, double t_end)
{
    MbsCommon *c = it->c;
    if (t_end == c->t_int) {
        c->t = c->t_int;
        memcpy(it->x, it->x_int, (size_t)it->n * sizeof(double));
        c->has_ahead = c->has_seg = 0;
        return;
    }
    it->cls->dense_eval(it, it->Q, (t_end - c->seg_t) / c->seg_h, it->x);
    mbs_integ_normalize(it, it->x);
    c->t = t_end;
}

static void failure_reason(MbsIntegrator *it)
{
    if (it->c->last_failure == MBS_LAST_NEWTON) {
        mbs_msg_add(it, "Newton iteration does not converge even with a fresh Jacobian at the minimum step "
                        "(singular or discontinuous right-hand side?)");
        return;
    }
    mbs_msg_add(it, "the local error tolerance (rtol=");
    mbs_msg_num(it, it->rtol, 6);
    mbs_msg_add(it, ", atol=");
    mbs_msg_num(it, it->atol, 6);
    mbs_msg_add(it, ") cannot be met — singularity, discontinuity or too strict tolerances");
}

/* The adaptive driver: the proposed h is clipped to hit t_end exactly (or, with dense output, steps past it),
 * and the unclipped h is carried over to the next call.
 * Right after f jumped (c->restarted: inputs or parameters changed at t) the advance lands exactly on t_end even
 * with dense output, and a first step shortened to land there proposes the next h itself. A master that changes
 * inputs at one point usually changes them at the next, so a step past t_end would be thrown away there, and the
 * point would come from the continuous extension of a step much longer than the interval: its error is that of
 * the long step (not of the short one the interval needs), and where the error estimate is ~0 (a solution
 * polynomial in t, e.g. a free mass under a held force) h grew tenfold per restart until interpolating near the
 * step's start lost every digit (2e-3 off at rtol 1e-10 for a slider pushed by a ramp). */
int mbs_integ_adaptive(MbsIntegrator *it, double t_end)
{
    const MbsMethodClass *cls = it->cls;
    MbsCommon *c = it->c;
    size_t nb = (size_t)it->n * sizeof(double);
    double min_step;
    long attempts = 0;
    int dense = it->dense && !c->restarted, first = c->restarted; /* first: the proposal predates the jump */
    if (cls->start(it, t_end)) return 1;
    min_step = 10.0 * MBS_EPS * mbs_pymax(fabs(c->t), fabs(t_end));
    while (c->t < t_end) {
        double t = c->t, h_prop, remaining, t_new, h;
        int clipped, r;
        if (++attempts > it->max_steps) {
            mbs_msg_set(it, "maximum number of steps (");
            mbs_msg_long(it, it->max_steps);
            mbs_msg_add(it, ") exceeded in one communication interval (step size ");
            mbs_msg_num(it, c->h, 3);
            mbs_msg_add(it, "); the problem may be stiff — try method radau5 or auto");
            return 1;
        }
        h_prop = mbs_pymin(c->h, it->max_step);
        remaining = t_end - t;
        if (remaining < min_step) {
            /* t_end within ~10 ulp of t: the same instant up to rounding, land without a step */
            c->t = t_end;
            break;
        }
        if (dense) { /* natural step, possibly past t_end: the continuous extension gives x(t_end) */
            t_new = t + h_prop;
            clipped = 0;
        } else { /* stretch by up to 1 % rather than leave a tiny last step (as Hairer's DOPRI5) */
            clipped = 1.01 * h_prop >= remaining && remaining <= it->max_step * (1.0 + 1e-9);
            t_new = clipped ? t_end : t + h_prop;
            if (t_new >= t_end) {
                t_new = t_end;
                clipped = 1;
            }
        }
        h = t_new - t;
        if (h < min_step) {
            mbs_msg_set(it, "step size underflow (h=");
            mbs_msg_num(it, h, 3);
            mbs_msg_add(it, "): ");
            failure_reason(it);
            return 1;
        }
        r = cls->attempt(it, t_new, h, it->xnew);
        if (r == MBS_FAIL) return 1;
        if (r == MBS_REJECT) {
            c->rejected++;
            continue;
        }
        c->nonfinite = 0;
        mbs_integ_normalize(it, it->xnew);
        memcpy(it->xold, it->x, nb);
        memcpy(it->x, it->xnew, nb);
        c->t = t_new;
        c->steps++;
        if (cls->accepted && cls->accepted(it)) return 1;
        mbs_integ_observe(it, t_end);
        if (dense && t_new > t_end) {
            /* the stages of this step are still in scratch: build its continuous extension */
            if (cls->dense_coeffs(it, t, it->xold, it->x, h, it->Q)) return 1;
            c->seg_t = t;
            c->seg_h = h;
            c->has_seg = 1;
            c->t_int = t_new;
            memcpy(it->x_int, it->x, nb);
            c->has_ahead = 1;
            c->h = mbs_pymin(c->h, it->max_step);
            land(it, t_end);
            return 0;
        }
        /* a step shortened to land on the point says little about the next one: keep the larger proposal
         * unless this step itself asked for a reduction */
        if (clipped && h < h_prop && c->h >= h && !first) c->h = mbs_pymax(c->h, h_prop);
        first = 0;
        c->h = mbs_pymin(c->h, it->max_step);
        if (cls->stop_early && cls->stop_early(it)) return 0;
    }
    c->restarted = 0;
    return 0;
}

static void drop_ahead(MbsIntegrator *it)
{
    if (it->c->has_ahead) {
        it->c->has_ahead = 0;
        it->cls->invalidate_derivative(it); /* the FSAL stage belongs to the ahead point */
    }
    it->c->has_seg = 0;
}

/* ------------------------------------------------------------------------------------------- public API */

int mbs_method_index(const char *name)
{
    int i;
    if (!name) return -1;
    for (i = 0; i < MBS_NMETHODS; i++)
        if (strcmp(name, mbs_method_names[i]) == 0) return i;
    return -1;
}

static size_t align8(size_t k) { return (k + 7u) & ~(size_t)7u; }

/* Common option checks and normalization. */
int mbs_integ_take_options(MbsIntegrator *it, const MbsOde *ode, const MbsIntegOptions *opt, int has_dense, char *err,
                           size_t errlen)
{
    const char *name = it->cls->name;
    double ms = opt->max_step;
    if (!ode || !ode->f || ode->n < 1 || ode->npos < 0 || ode->nvel < 0) {
        err_put(err, errlen, "the ODE needs n >= 1 and a right-hand side f", NULL, NULL);
        return 1;
    }
    if (!(opt->rtol > 0)) {
        err_put(err, errlen, "need rtol > 0 and atol >= 0 (got rtol=", &opt->rtol, ")");
        return 1;
    }
    if (!(opt->atol >= 0)) {
        err_put(err, errlen, "need rtol > 0 and atol >= 0 (got atol=", &opt->atol, ")");
        return 1;
    }
    if (ms == 0.0) ms = INFINITY; /* 0 (zero-initialized options): no limit */
    if (!(ms > 0)) {
        err_put(err, errlen, "max_step must be > 0 (got ", &opt->max_step, ")");
        return 1;
    }
    if (!(opt->h >= 0) || isinf(opt->h)) {
        err_put(err, errlen, "fixed step h must be > 0 (got ", &opt->h, ")");
        return 1;
    }
    if (opt->max_steps < 0) {
        double v = (double)opt->max_steps;
        err_put(err, errlen, "max_steps must be >= 0 (got ", &v, ")");
        return 1;
    }
    if (opt->dense == 1 && !has_dense) {
        err_put(err, errlen, "method '", NULL, NULL);
        err_put(err + strlen(err), errlen - strlen(err), name, NULL, "' has no dense output");
        return 1;
    }
    it->ode = *ode;
    it->n = ode->n;
    /* Hairer caps rtol from below so that the error test never asks for less than ~10 ulp */
    it->rtol = mbs_pymax(opt->rtol, 10.0 * MBS_EPS);
    it->atol = opt->atol;
    it->max_step = ms;
    it->h_fixed = opt->h;
    it->rho_inf = opt->rho_inf;
    it->max_steps = opt->max_steps ? opt->max_steps : 1000000L;
    it->dense = opt->dense < 0 ? has_dense : opt->dense != 0;
    return 0;
}

MbsIntegrator *mbs_integ_new(int method, const MbsOde *ode, const MbsIntegOptions *opt, char *err, size_t errlen)
{
    MbsIntegrator *it;
    if (err && errlen) err[0] = '\0';
    if (method < 0 || method >= MBS_NMETHODS) {
        err_put(err, errlen, "unknown integrator method; valid: ", NULL, METHODS_LISTED + 2);
        return NULL;
    }
    if (!opt) {
        err_put(err, errlen, "no integrator options given", NULL, NULL);
        return NULL;
    }
    it = (MbsIntegrator *)calloc(1, sizeof(MbsIntegrator));
    if (!it) {
        err_put(err, errlen, "out of memory", NULL, NULL);
        return NULL;
    }
    it->method = method;
    it->cls = method_classes[method];
    if (it->cls->ops->setup(it, ode, opt, err, errlen)) {
        mbs_integ_free(it);
        return NULL;
    }
    return it;
}

/* A single method: options, then one history block and one work block of the sizes its class asks for. */
static int single_setup(MbsIntegrator *it, const MbsOde *ode, const MbsIntegOptions *opt, char *err, size_t errlen)
{
    const MbsMethodClass *cls = it->cls;
    MbsSizes sz;
    size_t n, m, off_x, nwork_d, work_bytes;
    if (mbs_integ_take_options(it, ode, opt, cls->dense_rows > 0, err, errlen)) return 1;
    memset(&sz, 0, sizeof sz);
    cls->sizes(it->n, ode->nvel, opt, &sz);
    n = (size_t)it->n;
    m = (size_t)cls->dense_rows;
    it->off_ms = align8(sizeof(MbsCommon));
    off_x = align8(it->off_ms + sz.state);
    it->off_ha = off_x + (2 * n + m * n) * sizeof(double);
    it->off_hi = it->off_ha + sz.hist * sizeof(double);
    it->hist_bytes = align8(it->off_hi + sz.hist_int * sizeof(int));
    nwork_d = 4 * n + sz.work;
    work_bytes = nwork_d * sizeof(double) + sz.work_int * sizeof(int);
    if ((double)it->hist_bytes * 2 + (double)work_bytes + (double)sz.view > (double)MBS_INTEG_MAX_BYTES) {
        if (err && errlen)
            snprintf(err, errlen, "%s needs %.3g GiB for %d states (limit %.0f GiB): choose an explicit method "
                     "(rk4, dopri5, dop853) for a scene this large", cls->name,
                     ((double)it->hist_bytes * 2 + (double)work_bytes) / (1 << 30), it->n,
                     (double)MBS_INTEG_MAX_BYTES / (1 << 30));
        return 1;
    }
    it->hist = (unsigned char *)calloc(1, it->hist_bytes);
    it->hist_tmp = (unsigned char *)calloc(1, it->hist_bytes);
    it->work = (double *)calloc(1, work_bytes ? work_bytes : 1);
    it->view = sz.view ? calloc(1, sz.view) : NULL;
    if (!it->hist || !it->hist_tmp || !it->work || (sz.view && !it->view)) {
        err_put(err, errlen, "out of memory", NULL, NULL);
        return 1;
    }
    it->c = (MbsCommon *)it->hist;
    it->ms = it->hist + it->off_ms;
    it->x = (double *)(it->hist + off_x);
    it->x_int = it->x + n;
    it->Q = it->x_int + n;
    it->ha = (double *)(it->hist + it->off_ha);
    it->hi = (int *)(it->hist + it->off_hi);
    it->xnew = it->work;
    it->xold = it->xnew + n;
    it->tmp1 = it->xold + n;
    it->tmp2 = it->tmp1 + n;
    it->wa = it->tmp2 + n;
    it->wi = (int *)(it->work + nwork_d);
    it->c->t = NAN;
    if (cls->init && cls->init(it, err, errlen)) return 1;
    cls->reset_history(it);
    return 0;
}

void mbs_integ_free(MbsIntegrator *it)
{
    if (!it) return;
    mbs_integ_free(it->sub[0]);
    mbs_integ_free(it->sub[1]);
    free(it->hist);
    free(it->hist_tmp);
    free(it->work);
    free(it->view);
    free(it);
}

int mbs_integ_method(const MbsIntegrator *it) { return it->method; }

int mbs_integ_reset(MbsIntegrator *it, double t0, const double *x0) { return it->cls->ops->reset(it, t0, x0); }

static int single_reset(MbsIntegrator *it, double t0, const double *x0)
{
    MbsCommon *c = it->c;
    mbs_msg_set(it, "");
    if (!isfinite(t0) || !x0 || !mbs_all_finite(it->n, x0)) {
        mbs_msg_set(it, "initial state is not finite");
        return 1;
    }
    c->t = t0;
    memcpy(it->x, x0, (size_t)it->n * sizeof(double));
    c->has_h = 0;
    c->steps = c->rejected = c->rhs_evaluations = c->jac_evaluations = c->lu_decompositions = 0;
    c->nonfinite = 0;
    c->last_failure = MBS_LAST_NONE;
    c->has_ahead = c->has_seg = c->restarted = 0;
    c->started = 1;
    it->cls->reset_history(it);
    return 0;
}

void mbs_integ_inputs_changed(MbsIntegrator *it) { it->cls->ops->inputs_changed(it); }

void mbs_integ_set_observer(MbsIntegrator *it, MbsStepObserver fn, void *env)
{
    int k;
    it->observe = fn;
    it->observe_env = env;
    for (k = 0; k < 2; k++) /* a composite's children take the steps */
        if (it->sub[k]) mbs_integ_set_observer(it->sub[k], fn, env);
}

static void single_inputs_changed(MbsIntegrator *it)
{
    /* with dense output restart from the visible (interpolated) state, so the new inputs act from t on;
     * cached derivatives (FSAL stage, f at the step start) are stale; the next advance lands on its end
     * (mbs_integ_adaptive) */
    drop_ahead(it);
    it->cls->invalidate_derivative(it);
    it->c->restarted = 1;
}

static int single_advance(MbsIntegrator *it, double t_end)
{
    MbsCommon *c = it->c;
    it->msg[0] = '\0', it->msg_len = 0;
    if (!c->started) {
        mbs_msg_set(it, "mbs_integ_reset(t0, x0) must be called before mbs_integ_advance()");
        return 1;
    }
    if (!(t_end >= c->t)) {
        char b[40];
        fmt_repr(b, t_end);
        mbs_msg_set(it, "cannot integrate backwards (t_end=");
        mbs_msg_add(it, b);
        mbs_msg_add(it, " < t)");
        return 1;
    }
    if (t_end == c->t) return 0;
    if (c->has_ahead && t_end <= c->t_int) {
        land(it, t_end);
        return 0;
    }
    if (c->has_ahead) { /* continue stepping from the internal point (its FSAL stage is still valid) */
        c->t = c->t_int;
        memcpy(it->x, it->x_int, (size_t)it->n * sizeof(double));
        c->has_ahead = c->has_seg = 0;
        mbs_integ_observe(it, t_end); /* accepted in an earlier advance past its end: a point of this one */
    }
    return it->cls->advance ? it->cls->advance(it, t_end) : mbs_integ_adaptive(it, t_end);
}

int mbs_integ_advance(MbsIntegrator *it, double t_end)
{
    /* a fixed-step method stepping on from its last point (what a master does) calls it directly; small
     * enough to inline into the caller, which saves a call per communication point (a composite has no
     * step hooks: its advance is its ops') */
    if (it->cls->advance && it->c->started && !it->c->has_ahead && t_end > it->c->t) {
        it->msg[0] = '\0', it->msg_len = 0;
        return it->cls->advance(it, t_end);
    }
    return it->cls->ops->advance(it, t_end);
}

int mbs_integ_advance_many(MbsIntegrator *it, const double *ts, int m, double *X)
{
    int n = it->n, i = 0, j, k;
    for (k = 0; k < m; k++) {
        if (!(k == 0 || ts[k] >= ts[k - 1]) || !isfinite(ts[k])) {
            mbs_msg_set(it, "advance_many: the times must be finite and increasing");
            return 1;
        }
    }
    while (i < m) {
        MbsIntegrator *a;
        MbsCommon *c;
        if (mbs_integ_advance(it, ts[i])) return 1;
        memcpy(X + (size_t)i * n, mbs_integ_x(it), (size_t)n * sizeof(double));
        i++;
        a = it->cls->ops->active(it);
        c = a->c;
        if (!c->has_ahead) continue;
        /* points strictly inside the step come from its continuous extension (its end lands exactly) */
        for (j = i; j < m && ts[j] < c->t_int; j++) {
            double *row = X + (size_t)j * n;
            a->cls->dense_eval(a, a->Q, (ts[j] - c->seg_t) / c->seg_h, row);
            mbs_integ_normalize(a, row);
        }
        if (j > i) {
            c->t = ts[j - 1];
            memcpy(a->x, X + (size_t)(j - 1) * n, (size_t)n * sizeof(double));
        }
        i = j;
    }
    return 0;
}

static MbsIntegrator *single_active(const MbsIntegrator *it) { return (MbsIntegrator *)it; }

double mbs_integ_t(const MbsIntegrator *it) { return it->cls->ops->active(it)->c->t; }

const double *mbs_integ_x(const MbsIntegrator *it) { return it->cls->ops->active(it)->x; }

double mbs_integ_h(const MbsIntegrator *it)
{
    const MbsCommon *c = it->cls->ops->active(it)->c;
    return c->has_h ? c->h : NAN;
}

void mbs_integ_stats(const MbsIntegrator *it, MbsStats *out) { it->cls->ops->stats(it, out); }

static void single_stats(const MbsIntegrator *it, MbsStats *out)
{
    const MbsCommon *c = it->c;
    out->steps = (long)c->steps;
    out->rejected = (long)c->rejected;
    out->rhs_evaluations = (long)c->rhs_evaluations;
    out->jac_evaluations = (long)c->jac_evaluations;
    out->lu_decompositions = (long)c->lu_decompositions;
    out->switched = 0;
    out->switched_at = NAN;
}

const char *mbs_integ_message(const MbsIntegrator *it) { return it->msg; }

/* ------------------------------------------------------------------------------------------- snapshots */

void mbs_put_i32(unsigned char *p, long v)
{
    int k;
    unsigned long u = (unsigned long)v;
    for (k = 0; k < 4; k++) p[k] = (unsigned char)((u >> (8 * k)) & 0xffu);
}

long mbs_get_i32(const unsigned char *p)
{
    unsigned long u = 0;
    int k;
    for (k = 0; k < 4; k++) u |= (unsigned long)p[k] << (8 * k);
    return (long)(u & 0x7fffffffUL) - (long)(u & 0x80000000UL);
}

size_t mbs_integ_snapshot_size(const MbsIntegrator *it) { return it->cls->ops->snapshot_size(it); }

void mbs_integ_snapshot_save(const MbsIntegrator *it, unsigned char *buf) { it->cls->ops->snapshot_save(it, buf); }

int mbs_integ_snapshot_load(MbsIntegrator *it, const unsigned char *buf, size_t len)
{
    return it->cls->ops->snapshot_load(it, buf, len);
}

static size_t single_snapshot_size(const MbsIntegrator *it) { return SNAP_HEADER + it->hist_bytes; }

static void single_snapshot_save(const MbsIntegrator *it, unsigned char *buf)
{
    unsigned long long hb = it->hist_bytes;
    int k;
    memcpy(buf, "MBSI", 4);
    mbs_put_i32(buf + 4, it->method);
    mbs_put_i32(buf + 8, it->n);
    mbs_put_i32(buf + 12, it->dense);
    for (k = 0; k < 8; k++) buf[16 + k] = (unsigned char)((hb >> (8 * k)) & 0xffu);
    memcpy(buf + SNAP_HEADER, it->hist, it->hist_bytes);
}

static int flag_ok(int v) { return v == 0 || v == 1; }

/* 0 when the candidate history in it->hist_tmp is consistent with this integrator. */
static int check_candidate(const MbsIntegrator *it)
{
    const MbsCommon *c = (const MbsCommon *)it->hist_tmp;
    if (!flag_ok(c->started) || !flag_ok(c->has_h) || !flag_ok(c->has_ahead) || !flag_ok(c->has_seg) ||
        !flag_ok(c->restarted))
        return 1;
    if (c->nonfinite < 0 || c->nonfinite > MBS_MAX_NONFINITE_TRIALS) return 1;
    if (c->last_failure < MBS_LAST_NONE || c->last_failure > MBS_LAST_NEWTON) return 1;
    if (c->steps < 0 || c->rejected < 0 || c->rhs_evaluations < 0 || c->jac_evaluations < 0 ||
        c->lu_decompositions < 0)
        return 1;
    if (c->has_ahead != c->has_seg || (c->has_ahead && (!it->dense || !c->started))) return 1;
    if (it->cls->check && it->cls->check(it, it->hist_tmp + it->off_ms, (const int *)(it->hist_tmp + it->off_hi)))
        return 1;
    return 0;
}

/* Validate a snapshot into it->hist_tmp (0 = valid); mbs_integ_snapshot_commit then makes it current. */
int mbs_integ_snapshot_check(MbsIntegrator *it, const unsigned char *buf, size_t len)
{
    unsigned long long hb = 0;
    int k;
    if (!buf || len != SNAP_HEADER + it->hist_bytes || memcmp(buf, "MBSI", 4) != 0) return 1;
    for (k = 0; k < 8; k++) hb |= (unsigned long long)buf[16 + k] << (8 * k);
    if (mbs_get_i32(buf + 4) != it->method || mbs_get_i32(buf + 8) != it->n || mbs_get_i32(buf + 12) != it->dense ||
        hb != (unsigned long long)it->hist_bytes)
        return 1;
    memcpy(it->hist_tmp, buf + SNAP_HEADER, it->hist_bytes);
    return check_candidate(it);
}

void mbs_integ_snapshot_commit(MbsIntegrator *it)
{
    memcpy(it->hist, it->hist_tmp, it->hist_bytes);
    mbs_msg_set(it, "");
}

static int single_snapshot_load(MbsIntegrator *it, const unsigned char *buf, size_t len)
{
    if (mbs_integ_snapshot_check(it, buf, len)) return 1;
    mbs_integ_snapshot_commit(it);
    return 0;
}

const MbsIntegOps mbs_single_ops = {single_setup, single_reset, single_inputs_changed, single_advance, single_active,
                                    single_stats, single_snapshot_size, single_snapshot_save, single_snapshot_load};
