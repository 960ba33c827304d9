/* Explicit Runge–Kutta methods: rk4 (fixed step), dopri5 (Dormand–Prince 5(4), PI control, Hairer's
 * stiffness test) and dop853 (Dormand–Prince 8(5,3)), both FSAL with dense output (Hairer's CONTD5/CONTD8). */
#include <math.h>
#include <string.h>

#include "integ_base.h"

/* ------------------------------------------------------------------------------------------- tableaus */

/* DOPRI5 (Hairer's constants); row 6 is b (5th order), the FSAL stage f(t + h, x_new) */
static const double C5[7] = {0.0, 1.0 / 5, 3.0 / 10, 4.0 / 5, 8.0 / 9, 1.0, 1.0};
static const double A5[7][7] = {
    {0},
    {1.0 / 5},
    {3.0 / 40, 9.0 / 40},
    {44.0 / 45, -56.0 / 15, 32.0 / 9},
    {19372.0 / 6561, -25360.0 / 2187, 64448.0 / 6561, -212.0 / 729},
    {9017.0 / 3168, -355.0 / 33, 46732.0 / 5247, 49.0 / 176, -5103.0 / 18656},
    {35.0 / 384, 0.0, 500.0 / 1113, 125.0 / 192, -2187.0 / 6784, 11.0 / 84}};
/* E = b5 − b4 (Hairer's e_i) over all 7 stages, including the FSAL stage */
static const double E5[7] = {71.0 / 57600, 0.0, -71.0 / 16695, 71.0 / 1920, -17253.0 / 339200, 22.0 / 525, -1.0 / 40};
/* continuous extension of order 4 (CONTD5's d_i) */
static const double D5[7] = {-12715105075.0 / 11282082432, 0.0, 87487479700.0 / 32700410799,
                             -10690763975.0 / 1880347072, 701980252875.0 / 199316789632,
                             -1453857185.0 / 822651844, 69997945.0 / 29380423};
/* Hairer's DOPRI5 defaults: safety 0.9, 0.2 <= hnew/h <= 10, PI controller with beta = 0.04 */
#define SAFE5 0.9
#define FAC1_5 0.2
#define FAC2_5 10.0
#define BETA5 0.04
#define EXPO1_5 (0.2 - 0.75 * BETA5)
/* stiffness: h·|λ| estimate above 3.25 (boundary of the stability region) 15 times, reset after 6 misses */
#define STIFF_HLAMB 3.25
#define STIFF_COUNT 15
#define NONSTIFF_RESET 6

/* DOP853 (Hairer, Nørsett & Wanner; the values of SciPy's dop853_coefficients): 12 stages, the FSAL row
 * (= b, c = 1), and 3 extra stages of the order-7 continuous extension; E3/E5 over the 13 stages. */
static const double C8[16] = {0.0, 0.05260015195876773, 0.0789002279381516, 0.1183503419072274, 0.2816496580927726, 0.3333333333333333, 0.25, 0.3076923076923077, 0.6512820512820513, 0.6, 0.8571428571428571, 1.0, 1.0, 0.1, 0.2, 0.7777777777777778};
static const double A8[16][16] = {
    {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.05260015195876773, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.0197250569845379, 0.0591751709536137, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.02958758547680685, 0.0, 0.08876275643042054, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.2413651341592667, 0.0, -0.8845494793282861, 0.924834003261792, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.037037037037037035, 0.0, 0.0, 0.17082860872947386, 0.12546768756682242, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.037109375, 0.0, 0.0, 0.17025221101954405, 0.06021653898045596, -0.017578125, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.03709200011850479, 0.0, 0.0, 0.17038392571223998, 0.10726203044637328, -0.015319437748624402, 0.008273789163814023, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.6241109587160757, 0.0, 0.0, -3.3608926294469414, -0.868219346841726, 27.59209969944671, 20.154067550477894, -43.48988418106996, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.47766253643826434, 0.0, 0.0, -2.4881146199716677, -0.590290826836843, 21.230051448181193, 15.279233632882423, -33.28821096898486, -0.020331201708508627, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {-0.9371424300859873, 0.0, 0.0, 5.186372428844064, 1.0914373489967295, -8.149787010746927, -18.52006565999696, 22.739487099350505, 2.4936055526796523, -3.0467644718982196, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {2.273310147516538, 0.0, 0.0, -10.53449546673725, -2.0008720582248625, -17.9589318631188, 27.94888452941996, -2.8589982771350235, -8.87285693353063, 12.360567175794303, 0.6433927460157636, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.054293734116568765, 0.0, 0.0, 0.0, 0.0, 4.450312892752409, 1.8915178993145003, -5.801203960010585, 0.3111643669578199, -0.1521609496625161, 0.20136540080403034, 0.04471061572777259, 0.0, 0.0, 0.0, 0.0},
    {0.056167502283047954, 0.0, 0.0, 0.0, 0.0, 0.0, 0.25350021021662483, -0.2462390374708025, -0.12419142326381637, 0.15329179827876568, 0.00820105229563469, 0.007567897660545699, -0.008298, 0.0, 0.0, 0.0},
    {0.03183464816350214, 0.0, 0.0, 0.0, 0.0, 0.028300909672366776, 0.053541988307438566, -0.05492374857139099, 0.0, 0.0, -0.00010834732869724932, 0.0003825710908356584, -0.00034046500868740456, 0.1413124436746325, 0.0, 0.0},
    {-0.42889630158379194, 0.0, 0.0, 0.0, 0.0, -4.697621415361164, 7.683421196062599, 4.06898981839711, 0.3567271874552811, 0.0, 0.0, 0.0, -0.0013990241651590145, 2.9475147891527724, -9.15095847217987, 0.0}};
static const double E8_3[13] = {-0.18980075407240762, 0.0, 0.0, 0.0, 0.0, 4.450312892752409, 1.8915178993145003, -5.801203960010585, -0.4226823213237919, -0.1521609496625161, 0.20136540080403034, 0.02265179219836082, 0.0};
static const double E8_5[13] = {0.01312004499419488, 0.0, 0.0, 0.0, 0.0, -1.2251564463762044, -0.4957589496572502, 1.6643771824549864, -0.35032884874997366, 0.3341791187130175, 0.08192320648511571, -0.022355307863886294, 0.0};
static const double D8[4][16] = {
    {-8.428938276109013, 0.0, 0.0, 0.0, 0.0, 0.5667149535193777, -3.0689499459498917, 2.38466765651207, 2.117034582445028, -0.871391583777973, 2.2404374302607883, 0.6315787787694688, -0.08899033645133331, 18.148505520854727, -9.194632392478356, -4.436036387594894},
    {10.427508642579134, 0.0, 0.0, 0.0, 0.0, 242.28349177525817, 165.20045171727028, -374.5467547226902, -22.113666853125306, 7.733432668472264, -30.674084731089398, -9.332130526430229, 15.697238121770845, -31.139403219565178, -9.35292435884448, 35.81684148639408},
    {19.985053242002433, 0.0, 0.0, 0.0, 0.0, -387.0373087493518, -189.17813819516758, 527.8081592054236, -11.57390253995963, 6.8812326946963, -1.0006050966910838, 0.7777137798053443, -2.778205752353508, -60.19669523126412, 84.32040550667716, 11.99229113618279},
    {-25.69393346270375, 0.0, 0.0, 0.0, 0.0, -154.18974869023643, -231.5293791760455, 357.6391179106141, 93.40532418362432, -37.45832313645163, 104.0996495089623, 29.8402934266605, -43.53345659001114, 96.32455395918828, -39.17726167561544, -149.72683625798564}};
#define S8 12 /* stages; row S8 is the FSAL stage, rows 13..15 the extra stages of the dense output */
#define S8X 16
/* Hairer's DOP853 defaults: safety 0.9, 1/3 <= hnew/h <= 6, no PI part, exponent 1/8 */
#define SAFE8 0.9
#define FAC1_8 0.333
#define FAC2_8 6.0
#define EXPO1_8 (1.0 / 8.0)

/* rk4's stability interval on the negative real axis ends at h·λ ≈ −2.785: an estimate above HLAMB_MAX
 * while the increment is also far larger than the Euler increments means the step is blowing up */
#define RK4_HLAMB_MAX 4.0
#define RK4_GROWTH_MAX 4.0

/* ------------------------------------------------------------------------------------------- shared */

/* k_i = f(t + c_i h, x + h Σ_j a_ij k_j) for i in [i0, s) (rows of K, n each; K[0..i0) filled).  The stage
 * argument goes to arg, that of the last stage to last (the FSAL row: x_new) when last != NULL; acc is
 * scratch.  A stage with c_i = 1 is evaluated at exactly t_end.  0, or 1 when f failed. */
static int erk_stages(MbsIntegrator *it, const double *A, int lda, const double *C, double *K, int i0, int s,
                      double h, const double *x, double t, double t_end, double *acc, double *arg, double *last)
{
    int n = it->n, i, j, k;
    for (i = i0; i < s; i++) {
        const double *a = A + (size_t)i * lda;
        double *y = (i == s - 1 && last) ? last : arg;
        int first = 1;
        for (j = 0; j < i; j++) {
            const double *Kj = K + (size_t)j * n;
            double ha = h * a[j];
            if (a[j] == 0.0) continue;
            if (first) {
                for (k = 0; k < n; k++) acc[k] = ha * Kj[k];
                first = 0;
            } else {
                for (k = 0; k < n; k++) acc[k] += ha * Kj[k];
            }
        }
        if (first)
            memcpy(y, x, (size_t)n * sizeof(double));
        else
            for (k = 0; k < n; k++) y[k] = x[k] + acc[k];
        if (mbs_integ_f(it, C[i] == 1.0 ? t_end : t + C[i] * h, y, K + (size_t)i * n)) return 1;
    }
    return 0;
}

/* out = Σ_j (h·w_j)·K_j over all s stages (zero weights included, so a non-finite stage always shows) */
static void stage_sum(int n, int s, const double *w, double h, const double *K, double *out)
{
    int j, k;
    for (k = 0; k < n; k++) out[k] = (h * w[0]) * K[k];
    for (j = 1; j < s; j++) {
        double hw = h * w[j];
        const double *Kj = K + (size_t)j * n;
        for (k = 0; k < n; k++) out[k] += hw * Kj[k];
    }
}

/* Hairer's nesting Q0 + θ(Q1 + (1−θ)(Q2 + θ(Q3 + …))) as weights w = 1, θ, θ(1−θ), θ²(1−θ), …: x = Σ w_r Q_r */
static void alternating_eval(const MbsIntegrator *it, const double *Q, double theta, double *x)
{
    int n = it->n, m = it->cls->dense_rows, r, k;
    double w = 1.0;
    for (k = 0; k < n; k++) x[k] = Q[k];
    for (r = 1; r < m; r++) {
        const double *Qr = Q + (size_t)r * n;
        w *= (r & 1) ? theta : 1.0 - theta;
        for (k = 0; k < n; k++) x[k] += w * Qr[k];
    }
}

/* FSAL methods' history and scratch: k1 = f(t, x) is cached across steps and calls */
typedef struct {
    double facold;     /* dopri5: PI controller memory */
    int has_k1, last_rejected;
    int iasti, nonsti, stiff_detected; /* dopri5 stiffness test */
} FsalState;

typedef struct {
    double *k1;            /* history: f at the current point (valid when has_k1) */
    double *K, *acc, *arg, *e3; /* scratch: stages (rows), sums, stage argument, dop853's 3rd-order error */
} FsalView;

static void fsal_sizes(int n, int stages, MbsSizes *sz)
{
    sz->state = sizeof(FsalState);
    sz->hist = (size_t)n;
    sz->work = (size_t)n * (stages + 3);
    sz->view = sizeof(FsalView);
}

/* carve k1 (history) and the scratch: stages K (rows), acc, arg, e3 */
static int fsal_carve(MbsIntegrator *it, int stages)
{
    FsalView *v = (FsalView *)it->view;
    size_t n = (size_t)it->n;
    v->k1 = it->ha;
    v->K = it->wa;
    v->acc = v->K + stages * n;
    v->arg = v->acc + n;
    v->e3 = v->arg + n;
    return 0;
}

static void fsal_reset(MbsIntegrator *it)
{
    FsalState *s = (FsalState *)it->ms;
    s->has_k1 = 0;
    s->facold = 1e-4;
    s->last_rejected = 0;
    s->iasti = s->nonsti = s->stiff_detected = 0;
}

static void fsal_invalidate(MbsIntegrator *it) { ((FsalState *)it->ms)->has_k1 = 0; }

/* f(t, x) unless the FSAL stage is cached; HINIT (order of the error estimator) on the very first call */
static int fsal_start(MbsIntegrator *it, double t_end, int order)
{
    FsalState *s = (FsalState *)it->ms;
    FsalView *v = (FsalView *)it->view;
    if (!s->has_k1) {
        if (mbs_integ_f(it, it->c->t, it->x, v->k1) || mbs_integ_check_start(it, v->k1)) return 1;
        s->has_k1 = 1;
    }
    if (!it->c->has_h) return mbs_integ_initial_step(it, v->k1, order, t_end);
    return 0;
}

static int fsal_check(const MbsIntegrator *it, const void *ms, const int *hi)
{
    const FsalState *s = (const FsalState *)ms;
    (void)it;
    (void)hi;
    return !(s->has_k1 == 0 || s->has_k1 == 1) || !(s->last_rejected == 0 || s->last_rejected == 1) ||
           !(s->stiff_detected == 0 || s->stiff_detected == 1) || s->iasti < 0 || s->nonsti < 0;
}

/* ------------------------------------------------------------------------------------------- dopri5 */

static void dopri5_sizes(int n, int nvel, const MbsIntegOptions *opt, MbsSizes *sz)
{
    (void)nvel, (void)opt;
    fsal_sizes(n, 7, sz);
}

static int dopri5_init(MbsIntegrator *it, char *err, size_t errlen)
{
    (void)err;
    (void)errlen;
    return fsal_carve(it, 7);
}

static int dopri5_start(MbsIntegrator *it, double t_end) { return fsal_start(it, t_end, 4); }

/* DOPRI5's test: h·‖k7−k6‖/‖x7−x6‖ estimates h·|λ_dominant|; stiff when it sits at the stability boundary */
static void dopri5_stiffness(MbsIntegrator *it, double h, const double *x6, const double *x_new)
{
    FsalState *s = (FsalState *)it->ms;
    const double *K = ((FsalView *)it->view)->K;
    const double *k6 = K + 5 * (size_t)it->n, *k7 = K + 6 * (size_t)it->n;
    double num = 0.0, den = 0.0;
    int k;
    for (k = 0; k < it->n; k++) {
        double dk = k7[k] - k6[k], dx = x_new[k] - x6[k];
        num += dk * dk;
        den += dx * dx;
    }
    if (den > 0.0 && h * sqrt(num / den) > STIFF_HLAMB) {
        s->nonsti = 0;
        s->iasti++;
        if (s->iasti >= STIFF_COUNT) s->stiff_detected = 1;
        return;
    }
    s->nonsti++;
    if (s->nonsti == NONSTIFF_RESET) s->iasti = 0;
}

static int dopri5_attempt(MbsIntegrator *it, double t_new, double h, double *x_new)
{
    FsalState *s = (FsalState *)it->ms;
    FsalView *v = (FsalView *)it->view;
    const double *x = it->x;
    int n = it->n;
    double err, fac11, fac, h_new;
    memcpy(v->K, v->k1, (size_t)n * sizeof(double));
    /* row 6 = b: x_new, and its stage is the FSAL stage f(t_new, x_new); arg keeps stage 6's argument */
    if (erk_stages(it, &A5[0][0], 7, C5, v->K, 1, 7, h, x, it->c->t, t_new, v->acc, v->arg, x_new))
        return mbs_integ_stage_failed(it, h);
    stage_sum(n, 7, E5, h, v->K, v->acc);
    err = mbs_err_norm(n, v->acc, x, x_new, it->atol, it->rtol);
    if (!isfinite(err)) return mbs_integ_trial_nonfinite(it, h, "right-hand side");
    /* Hairer's PI controller: fac = err^(0.2−0.75β) / facold^β, limited to [1/FAC2, 1/FAC1] (as h/hnew) */
    fac11 = pow(err, EXPO1_5);
    fac = mbs_pymax(1.0 / FAC2_5, mbs_pymin(1.0 / FAC1_5, fac11 / pow(s->facold, BETA5) / SAFE5));
    if (err > 1.0) { /* rejection: pure I-control, no growth */
        it->c->h = h / mbs_pymin(1.0 / FAC1_5, fac11 / SAFE5);
        s->last_rejected = 1;
        return MBS_REJECT;
    }
    s->facold = mbs_pymax(err, 1e-4);
    h_new = h / fac;
    if (s->last_rejected) h_new = mbs_pymin(h_new, h); /* no growth right after a rejection (Hairer) */
    s->last_rejected = 0;
    it->c->h = h_new;
    if (it->detect_stiffness) dopri5_stiffness(it, h, v->arg, x_new);
    memcpy(v->k1, v->K + 6 * (size_t)n, (size_t)n * sizeof(double));
    return MBS_ACCEPT;
}

/* CONTD5's rcont1..5: r1 + θ(r2 + (1−θ)(r3 + θ(r4 + (1−θ) r5))) from the stages of the accepted step */
static int dopri5_dense(MbsIntegrator *it, double t_old, const double *x_old, const double *x_new, double h, double *Q)
{
    const double *K = ((FsalView *)it->view)->K;
    int n = it->n, k;
    double *ydiff = Q + n, *bspl = Q + 2 * (size_t)n, *r4 = Q + 3 * (size_t)n;
    const double *k7 = K + 6 * (size_t)n;
    (void)t_old;
    for (k = 0; k < n; k++) {
        Q[k] = x_old[k];
        ydiff[k] = x_new[k] - x_old[k];
        bspl[k] = h * K[k] - ydiff[k];
        r4[k] = ydiff[k] - h * k7[k] - bspl[k];
    }
    stage_sum(n, 7, D5, h, K, Q + 4 * (size_t)n);
    return 0;
}

static int dopri5_stop_early(const MbsIntegrator *it)
{
    return it->stop_when_stiff && ((const FsalState *)it->ms)->stiff_detected;
}

int mbs_dopri5_stiff(const MbsIntegrator *it) { return ((const FsalState *)it->ms)->stiff_detected; }

const MbsMethodClass mbs_dopri5_class = {
    "dopri5", 5, dopri5_sizes, dopri5_init, fsal_reset, fsal_invalidate, dopri5_start, dopri5_attempt, NULL,
    dopri5_dense, alternating_eval, dopri5_stop_early, NULL, fsal_check, &mbs_single_ops};

/* ------------------------------------------------------------------------------------------- dop853 */

static void dop853_sizes(int n, int nvel, const MbsIntegOptions *opt, MbsSizes *sz)
{
    (void)nvel, (void)opt;
    fsal_sizes(n, S8X, sz);
}

static int dop853_init(MbsIntegrator *it, char *err, size_t errlen)
{
    (void)err;
    (void)errlen;
    return fsal_carve(it, S8X);
}

static int dop853_start(MbsIntegrator *it, double t_end) { return fsal_start(it, t_end, 7); }

static int dop853_attempt(MbsIntegrator *it, double t_new, double h, double *x_new)
{
    FsalState *s = (FsalState *)it->ms;
    FsalView *v = (FsalView *)it->view;
    const double *x = it->x;
    int n = it->n, k;
    double n5 = 0.0, n3 = 0.0, err, fac11, fac, h_new;
    memcpy(v->K, v->k1, (size_t)n * sizeof(double));
    if (erk_stages(it, &A8[0][0], S8X, C8, v->K, 1, S8 + 1, h, x, it->c->t, t_new, v->acc, v->arg, x_new))
        return mbs_integ_stage_failed(it, h);
    /* Hairer's estimate |h|·‖e5‖² / sqrt(‖e5‖² + 0.01‖e3‖²) in the RMS sense (robust for large h) */
    stage_sum(n, S8 + 1, E8_5, 1.0, v->K, v->acc);
    stage_sum(n, S8 + 1, E8_3, 1.0, v->K, v->e3);
    for (k = 0; k < n; k++) {
        double sc = it->atol + it->rtol * mbs_pymax(fabs(x[k]), fabs(x_new[k]));
        double e5 = v->acc[k] / sc, e3 = v->e3[k] / sc;
        n5 += e5 * e5;
        n3 += e3 * e3;
    }
    err = (n5 == 0.0 && n3 == 0.0) ? 0.0 : fabs(h) * n5 / sqrt((n5 + 0.01 * n3) * n);
    if (!isfinite(err)) return mbs_integ_trial_nonfinite(it, h, "right-hand side");
    fac11 = pow(err, EXPO1_8);
    fac = mbs_pymax(1.0 / FAC2_8, mbs_pymin(1.0 / FAC1_8, fac11 / SAFE8));
    if (err > 1.0) {
        it->c->h = h / mbs_pymin(1.0 / FAC1_8, fac11 / SAFE8);
        s->last_rejected = 1;
        return MBS_REJECT;
    }
    h_new = h / fac;
    if (s->last_rejected) h_new = mbs_pymin(h_new, h);
    s->last_rejected = 0;
    it->c->h = h_new;
    memcpy(v->k1, v->K + (size_t)S8 * n, (size_t)n * sizeof(double));
    return MBS_ACCEPT;
}

/* Order-7 continuous extension: 3 extra stages, then [x_old; dy; h·k1 − dy; 2dy − h(k13 + k1); h·D·K] */
static int dop853_dense(MbsIntegrator *it, double t_old, const double *x_old, const double *x_new, double h, double *Q)
{
    FsalView *v = (FsalView *)it->view;
    const double *K = v->K, *k13 = v->K + (size_t)S8 * it->n;
    int n = it->n, r, k;
    if (erk_stages(it, &A8[0][0], S8X, C8, v->K, S8 + 1, S8X, h, x_old, t_old, t_old + h, v->acc, v->arg, NULL))
        return 1;
    for (k = 0; k < n; k++) {
        double dy = x_new[k] - x_old[k];
        Q[k] = x_old[k];
        Q[n + k] = dy;
        Q[2 * n + k] = h * K[k] - dy;
        Q[3 * n + k] = 2.0 * dy - h * (k13[k] + K[k]);
    }
    for (r = 0; r < 4; r++) stage_sum(n, S8X, D8[r], h, K, Q + (size_t)(4 + r) * n);
    return 0;
}

const MbsMethodClass mbs_dop853_class = {
    "dop853", 8, dop853_sizes, dop853_init, fsal_reset, fsal_invalidate, dop853_start, dop853_attempt, NULL,
    dop853_dense, alternating_eval, NULL, NULL, fsal_check, &mbs_single_ops};

/* ------------------------------------------------------------------------------------------- rk4 */

typedef struct {
    double *k1, *k2, *k3, *k4, *xs;
} Rk4View;

static void rk4_sizes(int n, int nvel, const MbsIntegOptions *opt, MbsSizes *sz)
{
    (void)nvel, (void)opt;
    sz->work = 5 * (size_t)n;
    sz->view = sizeof(Rk4View);
}

static int rk4_init(MbsIntegrator *it, char *err, size_t errlen)
{
    Rk4View *v = (Rk4View *)it->view;
    size_t n = (size_t)it->n;
    (void)err;
    (void)errlen;
    v->k1 = it->wa;
    v->k2 = v->k1 + n;
    v->k3 = v->k2 + n;
    v->k4 = v->k3 + n;
    v->xs = v->k4 + n;
    return 0;
}

static void rk4_nothing(MbsIntegrator *it) { (void)it; }

/* DOPRI5-style test on the RK4 stages: h·‖k4−k3‖/‖x4−x3‖ estimates h·|λ|; returns it when the step blows
 * up (also much larger than the Euler increments h(‖k1‖ + ‖k2‖)), else 0 */
static double rk4_unstable(const Rk4View *v, int n, double h, const double *dx)
{
    double dk2 = 0.0, den = 0.0, n1 = 0.0, n2 = 0.0, ndx = 0.0, hlamb, ref;
    int k;
    for (k = 0; k < n; k++) {
        double dk = v->k4[k] - v->k3[k], dxs = h * (v->k3[k] - 0.5 * v->k2[k]); /* (x + h·k3) − (x + h/2·k2) */
        dk2 += dk * dk;
        den += dxs * dxs;
        n1 += v->k1[k] * v->k1[k];
        n2 += v->k2[k] * v->k2[k];
        ndx += dx[k] * dx[k];
    }
    if (!(den > 0.0)) return 0.0;
    hlamb = h * sqrt(dk2 / den);
    /* h(‖k1‖ + ‖k2‖), not h‖k1‖ alone: starting at rest (k1 = 0) must not count as growth */
    ref = h * (sqrt(n1) + sqrt(n2));
    return hlamb > RK4_HLAMB_MAX && sqrt(ndx) > RK4_GROWTH_MAX * ref ? hlamb : 0.0;
}

/* Equal substeps <= h (or max_step) across [t, t_end]; the last lands exactly on t_end. */
static int rk4_advance(MbsIntegrator *it, double t_end)
{
    Rk4View *v = (Rk4View *)it->view;
    MbsCommon *c = it->c;
    double *x = it->x, *dx = it->xnew;
    double h_max = mbs_pymin(it->h_fixed > 0 ? it->h_fixed : it->max_step, it->max_step);
    double t0 = c->t, span = t_end - t0;
    long nsub, i;
    int n = it->n, k;
    if (mbs_integ_fixed_substeps(it, span, h_max, &nsub)) return 1;
    for (i = 1; i <= nsub; i++) {
        double t = c->t, t_new = i == nsub ? t_end : t0 + span * (double)i / (double)nsub;
        double h = t_new - t, h2 = 0.5 * h, blowup;
        if (mbs_integ_f(it, t, x, v->k1)) return 1;
        for (k = 0; k < n; k++) v->xs[k] = x[k] + h2 * v->k1[k];
        if (mbs_integ_f(it, t + h2, v->xs, v->k2)) return 1;
        for (k = 0; k < n; k++) v->xs[k] = x[k] + h2 * v->k2[k];
        if (mbs_integ_f(it, t + h2, v->xs, v->k3)) return 1;
        for (k = 0; k < n; k++) v->xs[k] = x[k] + h * v->k3[k];
        if (mbs_integ_f(it, t + h, v->xs, v->k4)) return 1;
        for (k = 0; k < n; k++) {
            dx[k] = (h / 6.0) * (v->k1[k] + 2.0 * (v->k2[k] + v->k3[k]) + v->k4[k]);
            v->xs[k] = x[k] + dx[k];
        }
        if (!mbs_all_finite(n, v->xs)) {
            mbs_msg_set(it, "rk4 produced non-finite values (NaN or Inf): right-hand side not finite or step "
                            "size unstable for this problem");
            return 1;
        }
        blowup = rk4_unstable(v, n, h, dx);
        if (blowup != 0.0) {
            mbs_msg_set(it, "rk4 is unstable at step size ");
            mbs_msg_num(it, h, 3);
            mbs_msg_add(it, ": the problem is stiff (estimated h·lambda = ");
            mbs_msg_num(it, blowup, 3);
            mbs_msg_add(it, ", stability limit 2.8); use a smaller step, radau5, gen_alpha or auto");
            return 1;
        }
        mbs_integ_normalize(it, v->xs);
        memcpy(x, v->xs, (size_t)n * sizeof(double));
        c->t = t_new;
        c->steps++;
        mbs_integ_observe(it, t_end);
    }
    c->h = nsub == 1 ? span : span / (double)nsub;
    c->has_h = 1;
    return 0;
}

const MbsMethodClass mbs_rk4_class = {
    "rk4", 0, rk4_sizes, rk4_init, rk4_nothing, rk4_nothing, NULL, NULL, NULL, NULL, NULL, NULL, rk4_advance, NULL,
    &mbs_single_ops};
