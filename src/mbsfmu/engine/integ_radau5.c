/* RADAU5: 3-stage Radau IIA (order 5, L-stable) after Hairer & Wanner, Solving ODEs II, Sec. IV.8.
 *
 * Simplified Newton on the transformed stage system: T⁻¹·A⁻¹·T splits the 3n×3n iteration matrix into one
 * real (γ/h·I − J) and one complex ((α+iβ)/h·I − J) n×n matrix (linalg.c). The Jacobian (forward
 * differences, Hairer's increments) is reused across steps while Newton converges fast; the LU pair is
 * reused while h stays within a factor [1, 1.2] of its old value. Step size: Gustafsson's predictive
 * controller. Dense output is the collocation polynomial of the accepted step (Hairer's CONTR5).
 *
 * History (see integ_base.h): Radau5State (flags and scalars) and the arrays f0, J, the LU pair with
 * its pivots, the collocation polynomial Q and the previous point x_prev.
 */
#include <math.h>
#include <string.h>

#include "integ_base.h"
#include "linalg.h"

#define S6 2.449489742783178098197284 /* √6 */
static const double C[3] = {(4.0 - S6) / 10.0, (4.0 + S6) / 10.0, 1.0};
/* embedded error estimate weights (already divided by the real eigenvalue, as in SciPy's Radau) */
static const double E[3] = {(-13.0 - 7.0 * S6) / 3.0, (-13.0 + 7.0 * S6) / 3.0, -1.0 / 3.0};
/* eigenvalues of A⁻¹: μ_real = 3 + 3^(2/3) − 3^(1/3), μ_complex = 3 + (3^(1/3) − 3^(2/3))/2 − i(3^(5/6) + 3^(7/6))/2 */
#define MU_REAL 3.637834252744495732208418
#define MU_CRE 2.681082873627752133895791
#define MU_CIM (-3.050430199247410569426378)
static const double T[3][3] = {
    {0.09443876248897524, -0.14125529502095421, 0.03002919410514742},
    {0.25021312296533332, 0.20412935229379994, -0.38294211275726192},
    {1.0, 1.0, 0.0}};
static const double TI[3][3] = {
    {4.17871859155190428, 0.32768282076106237, 0.52337644549944951},
    {-4.17871859155190428, -0.32768282076106237, 0.47662355450055044},
    {0.50287263494578682, -2.57192694985560522, 0.59603920482822492}};
/* collocation polynomial: Z(s) = Σ_k Q_k s^(k+1), Q_k = Σ_m P[m][k]·Z_m */
static const double P[3][3] = {
    {13.0 / 3.0 + 7.0 * S6 / 3.0, -23.0 / 3.0 - 22.0 * S6 / 3.0, 10.0 / 3.0 + 5.0 * S6},
    {13.0 / 3.0 - 7.0 * S6 / 3.0, -23.0 / 3.0 + 22.0 * S6 / 3.0, 10.0 / 3.0 - 5.0 * S6},
    {1.0 / 3.0, -8.0 / 3.0, 10.0 / 3.0}};

#define NEWTON_MAXITER 7 /* Hairer's NIT */
#define MIN_FACTOR 0.2
#define MAX_FACTOR 10.0
#define KEEP_LU_LOW 1.0  /* Hairer's QUOT1, QUOT2: keep h (and LU) inside this band */
#define KEEP_LU_HIGH 1.2
#define THET 1e-3        /* Jacobian is recomputed when the Newton contraction rate exceeds this */

enum { NEWTON_OK, NEWTON_NONFINITE, NEWTON_DIVERGED, NEWTON_SLOW, NEWTON_FAIL };

typedef struct {        /* history: POD, no pointers */
    double h_old, err_old, faccon, lu_h, t_prev, h_prev;
    int have_f0, have_J, current_jac, have_lu, have_old, have_Q, last_rejected, recompute_jac, first;
} Radau5State;

typedef struct {        /* arrays carved from the history and work blocks, and constants */
    double newton_tol;
    double *f0, *J, *LUr, *LUc, *Q, *x_prev;    /* history: n, n², n², 2n², 3n (rows Q_0..Q_2), n */
    int *pivr, *pivc;                           /* history: n, n */
    double *Z, *Z0, *W, *F, *dW, *sc, *err, *xs; /* work: 3n, 3n, 3n, 3n, 3n (dW_c interleaved in 1,2), n, n, n */
} Radau5View;

#define ST(it) ((Radau5State *)(it)->ms)
#define VW(it) ((Radau5View *)(it)->view)

static void sizes(int n, int nvel, const MbsIntegOptions *opt, MbsSizes *sz)
{
    (void)nvel, (void)opt;
    size_t N = (size_t)n;
    sz->state = sizeof(Radau5State);
    sz->hist = N + N * N + N * N + 2 * N * N + 3 * N + N;
    sz->hist_int = 2 * N;
    sz->work = 5 * 3 * N + 3 * N;
    sz->work_int = 0;
    sz->view = sizeof(Radau5View);
}

static int init(MbsIntegrator *it, char *err, size_t errlen)
{
    (void)err; (void)errlen;
    size_t n = (size_t)it->n;
    Radau5View *v = VW(it);
    double *h = it->ha, *w = it->wa;
    v->f0 = h; h += n;
    v->J = h; h += n * n;
    v->LUr = h; h += n * n;
    v->LUc = h; h += 2 * n * n;
    v->Q = h; h += 3 * n;
    v->x_prev = h;
    v->pivr = it->hi;
    v->pivc = it->hi + n;
    v->Z = w; w += 3 * n;
    v->Z0 = w; w += 3 * n;
    v->W = w; w += 3 * n;
    v->F = w; w += 3 * n;
    v->dW = w; w += 3 * n;
    v->sc = w; w += n;
    v->err = w; w += n;
    v->xs = w;
    /* Hairer's tolerance transformation: the embedded estimate is only order 3 while the method is order
     * 5, so RADAU5 asks for rtol' = 0.1·rtol^(2/3) (same atol/rtol ratio) to make the global error ≈ rtol */
    double quot = it->atol / it->rtol;
    it->rtol = 0.1 * pow(it->rtol, 2.0 / 3.0);
    it->atol = it->rtol * quot;
    v->newton_tol = fmax(10.0 * MBS_EPS / it->rtol, fmin(0.03, sqrt(it->rtol)));
    return 0;
}

static void reset_history(MbsIntegrator *it)
{
    Radau5State *s = ST(it);
    memset(s, 0, sizeof *s);
    s->faccon = 1.0;
    s->first = 1;
}

/* New inputs: f at the step start (used by the error estimate) is stale.  The collocation polynomial is
 * kept: it only seeds Newton, whose residual uses the new inputs. */
static void invalidate_derivative(MbsIntegrator *it) { ST(it)->have_f0 = 0; }

/* df/dx at the current accepted point by forward differences, column j with increment
 * sqrt(eps·max(1e-5, |x_j|)) (Hairer's choice); invalidates the LU pair.  0, or 1 (message set). */
static int new_jacobian(MbsIntegrator *it)
{
    Radau5State *s = ST(it);
    Radau5View *v = VW(it);
    int n = it->n;
    double *xp = v->xs, *fp = v->err;
    memcpy(xp, it->x, (size_t)n * sizeof *xp);
    for (int j = 0; j < n; ++j) {
        double xj = xp[j];
        xp[j] = xj + sqrt(MBS_EPS) * sqrt(fmax(1e-5, fabs(xj)));
        double d = xp[j] - xj; /* the increment actually representable in floating point */
        if (mbs_integ_f(it, it->c->t, xp, fp)) return 1;
        for (int i = 0; i < n; ++i) v->J[i * n + j] = (fp[i] - v->f0[i]) / d;
        xp[j] = xj;
    }
    if (!mbs_all_finite(n * n, v->J)) {
        mbs_msg_set(it, "Jacobian of the right-hand side is not finite");
        return 1;
    }
    it->c->jac_evaluations++;
    s->have_J = s->current_jac = 1;
    s->have_lu = 0;
    return 0;
}

static int start(MbsIntegrator *it, double t_end)
{
    Radau5State *s = ST(it);
    Radau5View *v = VW(it);
    if (!s->have_f0) {
        if (mbs_integ_f(it, it->c->t, it->x, v->f0) || mbs_integ_check_start(it, v->f0)) return 1;
        s->have_f0 = 1;
    }
    if (!s->have_J && new_jacobian(it)) return 1;
    if (!it->c->has_h && mbs_integ_initial_step(it, v->f0, 3, t_end)) return 1;
    return 0;
}

/* LU factors of (μ_real/h·I − J) and (μ_complex/h·I − J); 1 when one is singular. */
static int lu_pair(MbsIntegrator *it, double h)
{
    Radau5View *v = VW(it);
    int n = it->n;
    for (int k = 0; k < n * n; ++k) {
        v->LUr[k] = -v->J[k];
        v->LUc[2 * k] = -v->J[k];
        v->LUc[2 * k + 1] = 0.0;
    }
    for (int i = 0; i < n; ++i) {
        v->LUr[i * n + i] += MU_REAL / h;
        v->LUc[2 * (i * n + i)] += MU_CRE / h;
        v->LUc[2 * (i * n + i) + 1] += MU_CIM / h;
    }
    int info_r = mbs_lu_factor(n, v->LUr, v->pivr);
    int info_c = mbs_zlu_factor(n, v->LUc, v->pivc);
    return info_r != 0 || info_c != 0;
}

/* Newton start Z0: extrapolated collocation polynomial of the last step, else zero. */
static void starting_guess(MbsIntegrator *it, double h)
{
    Radau5State *s = ST(it);
    Radau5View *v = VW(it);
    int n = it->n;
    if (!s->have_Q) {
        memset(v->Z0, 0, 3 * (size_t)n * sizeof *v->Z0);
        return;
    }
    const double *Q = v->Q;
    for (int i = 0; i < 3; ++i) {
        double si = (it->c->t - s->t_prev + h * C[i]) / s->h_prev;
        double s2 = si * si, s3 = s2 * si;
        for (int j = 0; j < n; ++j)
            v->Z0[i * n + j] = (v->x_prev[j] - it->x[j]) + (si * Q[j] + s2 * Q[n + j] + s3 * Q[2 * n + j]);
    }
}

/* Y = M·X for a 3×3 matrix M and X, Y of 3 rows of n. */
static void mul3(const double M[3][3], const double *X, double *Y, int n)
{
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < n; ++j)
            Y[i * n + j] = M[i][0] * X[j] + M[i][1] * X[n + j] + M[i][2] * X[2 * n + j];
}

/* Simplified Newton on the transformed stages W = T⁻¹Z, from Z0 into Z; status NEWTON_*, *nit, *rate
 * (negative while undefined). */
static int newton(MbsIntegrator *it, double h, int *nit, double *rate)
{
    Radau5State *s = ST(it);
    Radau5View *v = VW(it);
    int n = it->n;
    double t = it->c->t, *Z = v->Z, *W = v->W, *F = v->F, *dW = v->dW;
    double mr = MU_REAL / h, mcr = MU_CRE / h, mci = MU_CIM / h;
    double tol = v->newton_tol;
    /* Hairer: the contraction estimate of the previous step lets a fast iteration stop after one sweep */
    double faccon = pow(fmax(s->faccon, MBS_EPS), 0.8);
    double dnorm_old = -1.0;
    memcpy(Z, v->Z0, 3 * (size_t)n * sizeof *Z);
    mul3(TI, Z, W, n);
    *rate = -1.0;
    for (int k = 0; k < NEWTON_MAXITER; ++k) {
        *nit = k + 1;
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < n; ++j) v->xs[j] = it->x[j] + Z[i * n + j];
            if (mbs_integ_f(it, t + h * C[i], v->xs, F + i * n)) return NEWTON_FAIL;
        }
        /* right-hand sides: real TI[0]·F − μ_r/h·W_0, complex (TI[1] + i·TI[2])·F − μ_c/h·(W_1 + i·W_2) */
        double *dWr = dW, *dWc = dW + n; /* the complex part interleaved over rows 1 and 2 */
        for (int j = 0; j < n; ++j) {
            double f0 = F[j], f1 = F[n + j], f2 = F[2 * n + j], w1 = W[n + j], w2 = W[2 * n + j];
            dWr[j] = TI[0][0] * f0 + TI[0][1] * f1 + TI[0][2] * f2 - mr * W[j];
            dWc[2 * j] = TI[1][0] * f0 + TI[1][1] * f1 + TI[1][2] * f2 - (mcr * w1 - mci * w2);
            dWc[2 * j + 1] = TI[2][0] * f0 + TI[2][1] * f1 + TI[2][2] * f2 - (mcr * w2 + mci * w1);
        }
        mbs_lu_solve(n, v->LUr, v->pivr, dWr);
        mbs_zlu_solve(n, v->LUc, v->pivc, dWc);
        double sum = 0.0;
        for (int j = 0; j < n; ++j) {
            double q0 = dWr[j] / v->sc[j], q1 = dWc[2 * j] / v->sc[j], q2 = dWc[2 * j + 1] / v->sc[j];
            sum += q0 * q0 + q1 * q1 + q2 * q2;
        }
        double dnorm = sqrt(sum / (3.0 * n));
        if (!isfinite(dnorm)) return NEWTON_NONFINITE;
        if (dnorm_old >= 0.0) {
            *rate = dnorm / dnorm_old;
            if (*rate >= 0.99) return NEWTON_DIVERGED;
            faccon = *rate / (1.0 - *rate);
            /* predicted error after the remaining iterations still above tol: give up early */
            if (faccon * dnorm * pow(*rate, NEWTON_MAXITER - 1 - k) > tol) return NEWTON_SLOW;
        }
        for (int j = 0; j < n; ++j) {
            W[j] += dWr[j];
            W[n + j] += dWc[2 * j];
            W[2 * n + j] += dWc[2 * j + 1];
        }
        mul3(T, W, Z, n);
        if (faccon * dnorm <= tol || dnorm == 0.0) {
            s->faccon = faccon;
            return NEWTON_OK;
        }
        dnorm_old = fmax(dnorm, MBS_EPS);
    }
    return NEWTON_SLOW;
}

/* Gustafsson's predictive controller as in RADAU5: min(1, h/h_old·(err_old/err)^¼)·err^(−¼). */
static double predict_factor(const Radau5State *s, double h, double err)
{
    if (err == 0.0) return MAX_FACTOR;
    double mult = s->have_old ? h / s->h_old * pow(s->err_old / err, 0.25) : 1.0;
    return fmin(1.0, mult) * pow(err, -0.25);
}

/* One Radau IIA step: Newton (with Jacobian refresh on failure), error estimate, controller. */
static int attempt(MbsIntegrator *it, double t_new, double h, double *x_new)
{
    Radau5State *s = ST(it);
    Radau5View *v = VW(it);
    MbsCommon *c = it->c;
    int n = it->n, nit = 0, status;
    double t = c->t, rate, *x = it->x, *Z = v->Z, *ev = v->err, *ZE = v->F;
    (void)t_new;
    for (int j = 0; j < n; ++j) v->sc[j] = it->atol + it->rtol * fabs(x[j]);
    starting_guess(it, h);
    for (;;) {
        if (!s->have_lu || s->lu_h != h) {
            c->lu_decompositions++;
            if (lu_pair(it, h)) {
                /* singular iteration matrix (h hits an eigenvalue of J): try a different h */
                s->have_lu = 0;
                c->h = 0.5 * h;
                return MBS_REJECT;
            }
            s->have_lu = 1;
            s->lu_h = h;
        }
        status = newton(it, h, &nit, &rate);
        if (status == NEWTON_OK) break;
        if (status == NEWTON_FAIL) return MBS_FAIL;
        if (!s->current_jac) {
            /* Newton failed with an old Jacobian: refresh it at the step start and retry the same h */
            if (new_jacobian(it)) return MBS_FAIL;
            continue;
        }
        s->have_lu = 0;
        s->last_rejected = 1;
        c->last_failure = MBS_LAST_NEWTON;
        if (status == NEWTON_NONFINITE) return mbs_integ_trial_nonfinite(it, h, "right-hand side");
        c->h = 0.5 * h;
        return MBS_REJECT;
    }

    for (int j = 0; j < n; ++j) {
        x_new[j] = x[j] + Z[2 * n + j];
        ZE[j] = (E[0] * Z[j] + E[1] * Z[n + j] + E[2] * Z[2 * n + j]) / h;
        ev[j] = v->f0[j] + ZE[j];
    }
    mbs_lu_solve(n, v->LUr, v->pivr, ev);
    double err = mbs_err_norm(n, ev, x, x_new, it->atol, it->rtol);
    if (err >= 1.0 && (s->first || s->last_rejected)) {
        /* Hairer's improved estimate (one more solve) filters the stiff components after a rejection */
        for (int j = 0; j < n; ++j) v->xs[j] = x[j] + ev[j];
        if (mbs_integ_f(it, t, v->xs, ev)) return MBS_FAIL;
        for (int j = 0; j < n; ++j) ev[j] += ZE[j];
        mbs_lu_solve(n, v->LUr, v->pivr, ev);
        err = mbs_err_norm(n, ev, x, x_new, it->atol, it->rtol);
    }
    if (!isfinite(err)) {
        s->have_lu = 0;
        return mbs_integ_trial_nonfinite(it, h, "right-hand side");
    }
    double safety = 0.9 * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + nit);
    if (err >= 1.0) {
        c->h = h * fmax(MIN_FACTOR, safety * predict_factor(s, h, err));
        s->last_rejected = 1;
        c->last_failure = MBS_LAST_ERROR;
        s->first = 0;
        return MBS_REJECT;
    }

    s->recompute_jac = nit > 2 && rate > THET;
    double factor = fmin(MAX_FACTOR, safety * predict_factor(s, h, err));
    if (s->last_rejected) factor = fmin(factor, 1.0); /* no growth right after a rejection */
    if (!s->recompute_jac && KEEP_LU_LOW <= factor && factor <= KEEP_LU_HIGH)
        factor = 1.0; /* keep h so the LU pair stays valid */
    s->h_old = h;
    s->err_old = fmax(err, 1e-2);
    s->have_old = 1;
    c->h = h * factor;
    s->last_rejected = s->first = 0;
    /* collocation polynomial for the next starting guess (and the dense output) */
    for (int k = 0; k < 3; ++k)
        for (int j = 0; j < n; ++j)
            v->Q[k * n + j] = P[0][k] * Z[j] + P[1][k] * Z[n + j] + P[2][k] * Z[2 * n + j];
    s->have_Q = 1;
    memcpy(v->x_prev, x, (size_t)n * sizeof *x);
    s->t_prev = t;
    s->h_prev = h;
    s->current_jac = 0;
    return MBS_ACCEPT;
}

/* f at the new (normalized) point; fresh Jacobian there if Newton was slow. */
static int accepted(MbsIntegrator *it)
{
    Radau5State *s = ST(it);
    Radau5View *v = VW(it);
    s->have_f0 = 0;
    if (mbs_integ_f(it, it->c->t, it->x, v->f0) || mbs_integ_check_start(it, v->f0)) return 1;
    s->have_f0 = 1;
    return s->recompute_jac ? new_jacobian(it) : 0;
}

/* Collocation polynomial of the step just accepted: x(t_old + θh) = x_old + Σ_k Q_k θ^(k+1). */
static int dense_coeffs(MbsIntegrator *it, double t_old, const double *x_old, const double *x_new, double h,
                        double *Qd)
{
    size_t n = (size_t)it->n;
    (void)t_old; (void)x_new; (void)h;
    memcpy(Qd, x_old, n * sizeof *Qd);
    memcpy(Qd + n, VW(it)->Q, 3 * n * sizeof *Qd);
    return 0;
}

static void dense_eval(const MbsIntegrator *it, const double *Qd, double theta, double *x)
{
    int n = it->n;
    double t2 = theta * theta, t3 = t2 * theta;
    for (int j = 0; j < n; ++j) x[j] = Qd[j] + theta * Qd[n + j] + t2 * Qd[2 * n + j] + t3 * Qd[3 * n + j];
}

/* Snapshot loading: flags are 0/1 and the pivots of a valid LU pair index inside the matrix. */
static int check(const MbsIntegrator *it, const void *ms, const int *hi)
{
    const Radau5State *s = ms;
    const int flags[] = {s->have_f0, s->have_J, s->current_jac, s->have_lu, s->have_old, s->have_Q,
                         s->last_rejected, s->recompute_jac, s->first};
    for (size_t k = 0; k < sizeof flags / sizeof *flags; ++k)
        if (flags[k] != 0 && flags[k] != 1) return 1;
    if (s->have_lu && (!s->have_J || !mbs_lu_pivots_valid(it->n, hi) || !mbs_lu_pivots_valid(it->n, hi + it->n)))
        return 1;
    return 0;
}

const MbsMethodClass mbs_radau5_class = {
    "radau5", 4, sizes, init, reset_history, invalidate_derivative, start, attempt, accepted, dense_coeffs,
    dense_eval, NULL, NULL, check, &mbs_single_ops,
};
