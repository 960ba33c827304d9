/* Generalized-α (Chung & Hulbert 1993) on the second-order form v̇ = accel(t, y, v), ẏ ~ v.
 *
 * Formulation of Arnold & Brüls (2007), valid on Lie groups via ode->retract:
 *     y₊ = retract(y, h·v + h²(½−β)·a + h²β·a₊)
 *     v₊ = v + h(1−γ)·a + hγ·a₊
 *     (1−α_m)·a₊ + α_m·a = (1−α_f)·v̇₊ + α_f·v̇,     v̇₊ = accel(t₊, y₊, v₊)
 * with α_m = (2ρ∞−1)/(ρ∞+1), α_f = ρ∞/(ρ∞+1), γ = ½ + α_f − α_m, β = ¼(γ + ½)²  (second order, ρ∞ = spectral
 * radius at h·ω → ∞). accel is the velocity part of ode->f. Newton iterates on v̇₊ with the matrix
 * S = I − c(h²β·K + hγ·D), c = (1−α_f)/(1−α_m), K = ∂accel/∂y (tangent, along retract), D = ∂accel/∂v.
 * Fixed step when opt->h is given; otherwise adaptive by step doubling (Richardson estimate of the local
 * error, order 2 ⇒ local error h³).  The LU of S is cached for at most two step sizes (h and h/2).
 *
 * History (see integ_base.h): GenAlphaState and the arrays v̇, a, K, D, the two cached LU with pivots.
 */
#include <math.h>
#include <string.h>

#include "integ_base.h"
#include "linalg.h"

#define NEWTON_MAXITER 8
#define MIN_FACTOR 0.2
#define MAX_FACTOR 5.0
#define SAFE 0.9
#define KEEP_H_LOW 1.0  /* keep h (and the LU of S) when the controller asks for ≤ 20 % growth */
#define KEEP_H_HIGH 1.2
#define JAC_RATE 1e-2   /* refresh K, D when Newton contracts slower than this */
#define MAX_SPLIT_DEPTH 10 /* fixed-step mode: halve a failing step at most this often */

enum { GA_OK, GA_NONFINITE, GA_DIVERGED, GA_SLOW, GA_SINGULAR, GA_FAIL };
static const char *const ga_status[] = {"ok", "nonfinite", "diverged", "slow", "singular", "fail"};

typedef struct {       /* history: POD, no pointers */
    double faccon;
    double lu_h[2];    /* step sizes of the cached LU slots */
    int have_vdot, have_K, current_jac, last_rejected, recompute_jac;
    int ncache, oldest; /* cached LU slots in use (0..2); the slot inserted first (evicted first) */
} GenAlphaState;

typedef struct {       /* one generalized-α step's result (work arrays) */
    double *y, *v, *vd, *a; /* npos, nvel, nvel, nvel */
    int nit;
    double rate;       /* negative while undefined */
} GaStep;

typedef struct {       /* constants, and arrays carved from the history and work blocks */
    int npos, nv;
    double am, af, beta, gamma, c, newton_tol;
    double *vdot, *a, *K, *D, *LU[2];           /* history: nv, nv, nv², nv², nv² each */
    int *piv[2];                                /* history: nv each */
    double *S, *a_base, *dy_base, *v_base, *sc, *w, *dw, *acc0, *dy; /* work: nv², then nv (sized n) each */
    double *xa, *xd;                            /* work: the point [y; v] where f is evaluated, f there */
    int *pivs;                                  /* work: pivots of S while it is factored */
    GaStep big, half, end;
} GenAlphaView;

#define ST(it) ((GenAlphaState *)(it)->ms)
#define VW(it) ((GenAlphaView *)(it)->view)

static void sizes(int n, int nvel, const MbsIntegOptions *opt, MbsSizes *sz)
{
    (void)opt;
    size_t N = (size_t)n, V = (size_t)(nvel >= 1 && nvel <= n ? nvel : n); /* init refuses other nvel */
    sz->state = sizeof(GenAlphaState);
    sz->hist = 2 * V + 4 * V * V;  /* the FMU state: K, D and two LU of S are nvel², not n² */
    sz->hist_int = 2 * V;
    sz->work = V * V + 10 * N + 3 * 4 * N;
    sz->work_int = N;
    sz->view = sizeof(GenAlphaView);
}

static int init(MbsIntegrator *it, char *err, size_t errlen)
{
    GenAlphaView *g = VW(it);
    const MbsOde *o = &it->ode;
    const char *bad = NULL;
    if (!(it->rho_inf >= 0.0 && it->rho_inf <= 1.0)) bad = "rho_inf must lie in [0, 1]";
    else if (o->npos + o->nvel != it->n || o->nvel < 1) bad = "gen_alpha needs n = npos + nvel with nvel >= 1";
    else if (!o->retract && o->npos != o->nvel) bad = "gen_alpha needs problem.retract when npos != nvel";
    if (bad) {
        if (errlen) {
            strncpy(err, bad, errlen - 1);
            err[errlen - 1] = '\0';
        }
        return 1;
    }
    size_t N = (size_t)it->n, nv = (size_t)o->nvel;
    double r = it->rho_inf;
    g->npos = o->npos;
    g->nv = o->nvel;
    g->am = (2.0 * r - 1.0) / (r + 1.0);
    g->af = r / (r + 1.0);
    g->gamma = 0.5 + g->af - g->am;
    g->beta = 0.25 * (g->gamma + 0.5) * (g->gamma + 0.5);
    g->c = (1.0 - g->af) / (1.0 - g->am);
    g->newton_tol = fmax(10.0 * MBS_EPS / it->rtol, fmin(0.03, sqrt(it->rtol)));
    double *h = it->ha, *w = it->wa;
    g->vdot = h; h += nv;
    g->a = h; h += nv;
    g->K = h; h += nv * nv;
    g->D = h; h += nv * nv;
    g->LU[0] = h; h += nv * nv;
    g->LU[1] = h;
    g->piv[0] = it->hi;
    g->piv[1] = it->hi + nv;
    g->pivs = it->wi;
    double **scratch[] = {&g->a_base, &g->dy_base, &g->v_base, &g->sc, &g->w, &g->dw, &g->acc0, &g->dy, &g->xa,
                          &g->xd};
    g->S = w; w += nv * nv;
    for (size_t k = 0; k < sizeof scratch / sizeof *scratch; ++k) { *scratch[k] = w; w += N; }
    GaStep *steps[] = {&g->big, &g->half, &g->end};
    for (int k = 0; k < 3; ++k) { /* y and v adjacent: [y; v] is a state vector */
        steps[k]->y = w;
        steps[k]->v = w + o->npos;
        steps[k]->vd = w + N;
        steps[k]->a = w + N + nv;
        w += 4 * N;
    }
    return 0;
}

static void reset_history(MbsIntegrator *it)
{
    GenAlphaState *s = ST(it);
    memset(s, 0, sizeof *s);
    s->faccon = 1.0;
}

/* New inputs: restart the acceleration history (a = v̇ at the new inputs), as after a discontinuity. */
static void invalidate_derivative(MbsIntegrator *it) { ST(it)->have_vdot = 0; }


/* xa[0:npos] = retract(y, dy) (plain coordinates: y + dy). */
static void put_y(MbsIntegrator *it, const double *y, const double *dy)
{
    GenAlphaView *g = VW(it);
    if (it->ode.retract)
        it->ode.retract(it->ode.ctx, y, dy, g->xa);
    else
        for (int j = 0; j < g->npos; ++j) g->xa[j] = y[j] + dy[j];
}

/* accel at (t, xa) into out (nv): the velocity part of f, one counted evaluation.  0, or 1 (f failed). */
static int accel(MbsIntegrator *it, double t, double *out)
{
    GenAlphaView *g = VW(it);
    if (mbs_integ_f(it, t, g->xa, g->xd)) return 1;
    memcpy(out, g->xd + g->npos, (size_t)g->nv * sizeof *out);
    return 0;
}

/* K = ∂accel/∂y along retract directions and D = ∂accel/∂v at the current point (forward differences). */
static int new_jacobian(MbsIntegrator *it)
{
    GenAlphaState *s = ST(it);
    GenAlphaView *g = VW(it);
    int npos = g->npos, nv = g->nv;
    double t = it->c->t, *y = it->x, *v = it->x + npos, *col = g->w;
    memcpy(g->xa, it->x, (size_t)it->n * sizeof *g->xa);
    if (accel(it, t, g->acc0)) return 1;
    memset(g->dy, 0, (size_t)nv * sizeof *g->dy);
    for (int j = 0; j < nv; ++j) {
        double d = npos == nv ? sqrt(MBS_EPS) * fmax(1.0, fabs(y[j])) : sqrt(MBS_EPS);
        g->dy[j] = d;
        put_y(it, y, g->dy);
        g->dy[j] = 0.0;
        if (accel(it, t, col)) return 1;
        for (int i = 0; i < nv; ++i) g->K[i * nv + j] = (col[i] - g->acc0[i]) / d;
        memcpy(g->xa, y, (size_t)npos * sizeof *y);
        double vj = v[j] + sqrt(MBS_EPS) * fmax(1.0, fabs(v[j]));
        g->xa[npos + j] = vj;
        if (accel(it, t, col)) return 1;
        for (int i = 0; i < nv; ++i) g->D[i * nv + j] = (col[i] - g->acc0[i]) / (vj - v[j]);
        g->xa[npos + j] = v[j];
    }
    if (!mbs_all_finite(nv * nv, g->K) || !mbs_all_finite(nv * nv, g->D)) {
        mbs_msg_set(it, "Jacobian of the accelerations is not finite");
        return 1;
    }
    it->c->jac_evaluations++;
    s->have_K = s->current_jac = 1;
    s->ncache = s->oldest = 0;
    return 0;
}

/* Slot of the LU of S(h) = I − c(h²β·K + hγ·D), cached for the (at most two) step sizes in use; -1 when
 * S is singular. */
static int lu_slot(MbsIntegrator *it, double h)
{
    GenAlphaState *s = ST(it);
    GenAlphaView *g = VW(it);
    int nv = g->nv;
    for (int k = 0; k < s->ncache; ++k) {
        int slot = (s->oldest + k) % 2;
        /* S only steers the simplified Newton iteration (the residual decides the solution), so a
         * factorization for a step size equal up to rounding is as good and saves refactoring */
        if (fabs(s->lu_h[slot] - h) <= 1e-10 * h) return slot;
    }
    double kk = -g->c * h * h * g->beta, kd = g->c * h * g->gamma;
    for (int i = 0; i < nv * nv; ++i) g->S[i] = kk * g->K[i] - kd * g->D[i];
    for (int i = 0; i < nv; ++i) g->S[i * nv + i] += 1.0;
    it->c->lu_decompositions++;
    if (mbs_lu_factor(nv, g->S, g->pivs)) return -1; /* in scratch: a singular S evicts nothing */
    int slot;
    if (s->ncache < 2) {
        slot = s->ncache++;
    } else { /* evict the older one */
        slot = s->oldest;
        s->oldest = 1 - s->oldest;
    }
    memcpy(g->LU[slot], g->S, (size_t)nv * nv * sizeof *g->S);
    memcpy(g->piv[slot], g->pivs, (size_t)nv * sizeof *g->pivs);
    s->lu_h[slot] = h;
    return slot;
}

/* One generalized-α step from (t, y, v, v̇, a) by simplified Newton on v̇₊; the result into r (not aliasing
 * the inputs).  GA_* status. */
static int ga_step(MbsIntegrator *it, double t, const double *y, const double *v, const double *vd,
                   const double *a, double h, GaStep *r)
{
    GenAlphaState *s = ST(it);
    GenAlphaView *g = VW(it);
    int npos = g->npos, nv = g->nv;
    double am = g->am, af = g->af, beta = g->beta, gamma = g->gamma, c = g->c;
    r->nit = 0;
    r->rate = -1.0;
    int slot = lu_slot(it, h);
    if (slot < 0) return GA_SINGULAR;
    double hb = h * h * beta, hg = h * gamma, t1 = t + h, *w = g->w, *dw = g->dw;
    for (int j = 0; j < nv; ++j) {
        g->a_base[j] = (af * vd[j] - am * a[j]) / (1.0 - am);
        g->dy_base[j] = h * v[j] + (h * h * (0.5 - beta)) * a[j];
        g->v_base[j] = v[j] + (h * (1.0 - gamma)) * a[j];
        g->sc[j] = it->atol + it->rtol * fabs(v[j]);
        w[j] = vd[j]; /* predictor: acceleration unchanged over the step */
    }
    double faccon = pow(fmax(s->faccon, MBS_EPS), 0.8), tol = g->newton_tol, dnorm_old = -1.0;
    for (int k = 0; k < NEWTON_MAXITER; ++k) {
        r->nit = k + 1;
        /* (y₊, v₊) at a₊ = a_base + c·w, into xa */
        for (int j = 0; j < nv; ++j) {
            double a1 = g->a_base[j] + c * w[j];
            g->dy[j] = g->dy_base[j] + hb * a1;
            g->xa[npos + j] = g->v_base[j] + hg * a1;
        }
        put_y(it, y, g->dy);
        if (accel(it, t1, dw)) return GA_FAIL;
        for (int j = 0; j < nv; ++j) dw[j] = w[j] - dw[j]; /* residual w − accel(t₊, y₊, v₊) */
        mbs_lu_solve(nv, g->LU[slot], g->piv[slot], dw);
        double sum = 0.0;
        for (int j = 0; j < nv; ++j) {
            w[j] -= dw[j];
            double q = (hg * c) * dw[j] / g->sc[j]; /* Newton correction seen in the velocities */
            sum += q * q;
        }
        double dnorm = sqrt(sum / nv);
        if (!isfinite(dnorm)) return GA_NONFINITE;
        if (dnorm_old >= 0.0) {
            r->rate = dnorm / dnorm_old;
            if (r->rate >= 0.99) return GA_DIVERGED;
            faccon = r->rate / (1.0 - r->rate);
        }
        if (faccon * dnorm <= tol || dnorm == 0.0) {
            s->faccon = faccon;
            for (int j = 0; j < nv; ++j) {
                double a1 = g->a_base[j] + c * w[j];
                g->dy[j] = g->dy_base[j] + hb * a1;
                r->v[j] = g->v_base[j] + hg * a1;
                r->vd[j] = w[j];
                r->a[j] = a1;
            }
            put_y(it, y, g->dy);
            memcpy(r->y, g->xa, (size_t)npos * sizeof *r->y);
            return GA_OK;
        }
        dnorm_old = fmax(dnorm, MBS_EPS);
    }
    return GA_SLOW;
}

/* ga_step, refreshing a stale Jacobian once when Newton fails (GA_FAIL: f or the Jacobian failed). */
static int step_retry(MbsIntegrator *it, double t, const double *y, const double *v, const double *vd,
                      const double *a, double h, GaStep *r)
{
    for (;;) {
        int st = ga_step(it, t, y, v, vd, a, h, r);
        if (st == GA_OK || st == GA_FAIL || st == GA_NONFINITE || ST(it)->current_jac) return st;
        if (new_jacobian(it)) return GA_FAIL;
    }
}

/* Acceleration at the current point (restarts a = v̇), Jacobian, and HINIT in adaptive mode. */
static int start(MbsIntegrator *it, double t_end)
{
    GenAlphaState *s = ST(it);
    GenAlphaView *g = VW(it);
    if (!s->have_vdot) {
        memcpy(g->xa, it->x, (size_t)it->n * sizeof *g->xa);
        if (accel(it, it->c->t, g->vdot)) return 1;
        if (!mbs_all_finite(g->nv, g->vdot)) return mbs_integ_check_start(it, g->xd);
        memcpy(g->a, g->vdot, (size_t)g->nv * sizeof *g->a);
        s->have_vdot = 1;
    }
    if (!s->have_K && new_jacobian(it)) return 1;
    if (!it->c->has_h && it->h_fixed == 0.0) {
        if (mbs_integ_f(it, it->c->t, it->x, g->xd)) return 1;
        if (mbs_integ_initial_step(it, g->xd, 2, t_end)) return 1;
    }
    return 0;
}

/* Move to the accepted point r (normalized), remember accelerations, decide on a Jacobian refresh. */
static int commit(MbsIntegrator *it, double t_new, const GaStep *r)
{
    GenAlphaState *s = ST(it);
    GenAlphaView *g = VW(it);
    if (!mbs_all_finite(it->n, r->y)) { /* r->y, r->v are adjacent: the state [y₊; v₊] */
        mbs_msg_set(it, "gen_alpha produced a non-finite state");
        return 1;
    }
    memcpy(it->x, r->y, (size_t)it->n * sizeof *it->x);
    mbs_integ_normalize(it, it->x);
    it->c->t = t_new;
    memcpy(g->vdot, r->vd, (size_t)g->nv * sizeof *g->vdot);
    memcpy(g->a, r->a, (size_t)g->nv * sizeof *g->a);
    it->c->steps++;
    s->current_jac = 0;
    return r->nit > 2 && r->rate > JAC_RATE ? new_jacobian(it) : 0;
}

/* One fixed step of nominal size h to t_new (inside an advance to t_end); if Newton fails with a fresh Jacobian,
 * split it in halves. */
static int fixed_step(MbsIntegrator *it, double t_new, double h, int depth, double t_end)
{
    GenAlphaView *g = VW(it);
    double t = it->c->t;
    int st = step_retry(it, t, it->x, it->x + g->npos, g->vdot, g->a, h, &g->end);
    if (st == GA_FAIL) return 1;
    if (st != GA_OK) {
        it->c->rejected++;
        if (depth >= MAX_SPLIT_DEPTH) {
            mbs_msg_set(it, "gen_alpha: ");
            if (st == GA_NONFINITE) {
                mbs_msg_add(it, "non-finite accelerations");
            } else {
                mbs_msg_add(it, "Newton iteration ");
                mbs_msg_add(it, ga_status[st]);
            }
            mbs_msg_add(it, " even at step size ");
            mbs_msg_num(it, h, 3);
            mbs_msg_add(it, " (fixed step split ");
            mbs_msg_long(it, depth);
            mbs_msg_add(it, " times)");
            return 1;
        }
        return fixed_step(it, t + 0.5 * h, 0.5 * h, depth + 1, t_end) ||
               fixed_step(it, t_new, 0.5 * h, depth + 1, t_end);
    }
    if (commit(it, t_new, &g->end)) return 1;
    mbs_integ_observe(it, t_end);
    return 0;
}

/* Fixed mode: equal substeps <= h; adaptive mode: the common driver with step doubling. */
static int advance(MbsIntegrator *it, double t_end)
{
    if (it->h_fixed == 0.0) return mbs_integ_adaptive(it, t_end);
    if (start(it, t_end)) return 1;
    double h_max = fmin(it->h_fixed, it->max_step), t0 = it->c->t, span = t_end - t0;
    long nsub;
    if (mbs_integ_fixed_substeps(it, span, h_max, &nsub)) return 1;
    for (long i = 1; i <= nsub; ++i)
        if (fixed_step(it, i == nsub ? t_end : t0 + span * i / nsub, span / nsub, 0, t_end)) return 1;
    it->c->h = span / nsub;
    it->c->has_h = 1;
    return 0;
}

/* Adaptive step by doubling: one step h vs two steps h/2, error = (x_two − x_one)/(2²−1). */
static int attempt(MbsIntegrator *it, double t_new, double h, double *x_new)
{
    GenAlphaState *s = ST(it);
    GenAlphaView *g = VW(it);
    MbsCommon *c = it->c;
    int n = it->n, npos = g->npos;
    double t = c->t, h2 = 0.5 * h, *x = it->x;
    const double *y = x, *v = x + npos;
    (void)t_new;
    int st = step_retry(it, t, y, v, g->vdot, g->a, h, &g->big);
    if (st == GA_OK) {
        st = step_retry(it, t, y, v, g->vdot, g->a, h2, &g->half);
        if (st == GA_OK) /* same nominal h2 for both halves so one cached LU serves both */
            st = step_retry(it, t + h2, g->half.y, g->half.v, g->half.vd, g->half.a, h2, &g->end);
    }
    if (st == GA_FAIL) return MBS_FAIL;
    if (st != GA_OK) {
        s->last_rejected = 1;
        c->last_failure = MBS_LAST_NEWTON;
        if (st == GA_NONFINITE) return mbs_integ_trial_nonfinite(it, h, "accelerations");
        c->h = 0.25 * h; /* Newton failure even with a fresh Jacobian: much smaller step */
        return MBS_REJECT;
    }
    const double *x_one = g->big.y, *x_two = g->end.y; /* [y; v] of one step h and of two steps h/2 */
    for (int j = 0; j < n; ++j) g->S[j] = (x_two[j] - x_one[j]) / 3.0;
    double err = mbs_err_norm(n, g->S, x, x_two, it->atol, it->rtol);
    if (!isfinite(err)) return mbs_integ_trial_nonfinite(it, h, "accelerations");
    double fac = err == 0.0 ? MAX_FACTOR : SAFE * pow(err, -1.0 / 3.0);
    if (err > 1.0) {
        c->h = h * fmax(MIN_FACTOR, fac);
        s->last_rejected = 1;
        c->last_failure = MBS_LAST_ERROR;
        return MBS_REJECT;
    }
    fac = fmin(MAX_FACTOR, fac);
    if (s->last_rejected) fac = fmin(fac, 1.0);
    if (KEEP_H_LOW <= fac && fac <= KEEP_H_HIGH) fac = 1.0; /* same h next step: both cached LU stay valid */
    c->h = h * fac;
    s->last_rejected = 0;
    memcpy(g->vdot, g->end.vd, (size_t)g->nv * sizeof *g->vdot);
    memcpy(g->a, g->end.a, (size_t)g->nv * sizeof *g->a);
    s->current_jac = 0;
    s->recompute_jac = g->end.nit > 2 && g->end.rate > JAC_RATE;
    memcpy(x_new, x_two, (size_t)n * sizeof *x_new);
    return MBS_ACCEPT;
}

/* Refresh K, D at the new point when Newton converged slowly. */
static int accepted(MbsIntegrator *it) { return ST(it)->recompute_jac ? new_jacobian(it) : 0; }

/* Snapshot loading: flags 0/1, cache bookkeeping in range, pivots of the cached LU valid. */
static int check(const MbsIntegrator *it, const void *ms, const int *hi)
{
    const GenAlphaState *s = ms;
    const GenAlphaView *g = it->view;
    const int flags[] = {s->have_vdot, s->have_K, s->current_jac, s->last_rejected, s->recompute_jac};
    for (size_t k = 0; k < sizeof flags / sizeof *flags; ++k)
        if (flags[k] != 0 && flags[k] != 1) return 1;
    if (s->ncache < 0 || s->ncache > 2 || s->oldest < 0 || s->oldest > 1 || (s->ncache < 2 && s->oldest != 0))
        return 1;
    if (s->ncache > 0 && !s->have_K) return 1;
    for (int k = 0; k < s->ncache; ++k)
        if (!mbs_lu_pivots_valid(g->nv, hi + k * g->nv)) return 1;
    return 0;
}

const MbsMethodClass mbs_gen_alpha_class = {
    "gen_alpha", 0, sizes, init, reset_history, invalidate_derivative, start, attempt, accepted, NULL, NULL,
    NULL, advance, check, &mbs_single_ops,
};
