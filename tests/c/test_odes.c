/* Test systems for the explicit integrators and the driver (tests/test_engine_integrators.py), compiled
 * with the engine's integrator sources into one shared library and driven through ctypes.
 *
 * test_ode_new(name, p, np) returns an MbsOde (first member of a heap block that owns the parameters;
 * free with test_ode_free; test_ode_set(ode, i, v) changes parameter i, e.g. an input) for one of:
 *   "harmonic"   y'' = −ω² y (n = 2), p = {ω}
 *   "vdp"        Van der Pol y'' = μ((1 − y²)y' − y) (n = 2), p = {μ}
 *   "kepler"     planar two-body orbit r'' = −r/|r|³ (n = 4: x, y, vx, vy), no parameters
 *   "rigid"      torque-free rigid body: unit quaternion q (body → world, [w, x, y, z]) and body angular
 *                velocity ω, p = {I1, I2, I3}; npos = 4, nvel = 3, normalize
 *   "decay"      ẋ_i = −λ_i x_i (n = np), p = {λ_1 …}
 *   "ramp"       ẋ = u (n = 1), p = {u}: a held input for inputs_changed
 *   "blowup"     ẋ = x² (n = 1): from x(0) = 1 a pole at t = 1 (step-size underflow)
 *   "nan_after"  ẋ = −x (n = 2) until t = p[0], NaN afterwards
 *   "fail_after" ẋ = −x (n = 2) until t = p[0], then MBS_F_SINGULAR with a message
 *   "wide"       ẋ_i = −x_i (n = p[0]): as many states as asked, for the integrators' memory bound
 *   "confined"   ẋ0 = 1, ẋ1 = −λ (x1 − x0) (n = 2), p = {λ}, defined only for |x_i| <= 10 (MBS_F_SINGULAR
 *                beyond): f is small at x = 0, its Jacobian huge: an explicit method's first trial stages fly
 *                out of the domain (as a real robot with a near-massless damped joint does)
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "mbs_integrator.h"

enum { HARMONIC, VDP, KEPLER, RIGID, DECAY, RAMP, BLOWUP, NAN_AFTER, FAIL_AFTER, WIDE, CONFINED, NKINDS };

typedef struct {
    MbsOde ode; /* first member: the pointer handed out is also the block's address */
    int kind, m;
    double p[8];
} TestOde;

static int f_harmonic(void *ctx, double t, const double *x, double *xd)
{
    const TestOde *P = (const TestOde *)ctx;
    (void)t;
    xd[0] = x[1];
    xd[1] = -P->p[0] * P->p[0] * x[0];
    return MBS_F_OK;
}

static int f_vdp(void *ctx, double t, const double *x, double *xd)
{
    const TestOde *P = (const TestOde *)ctx;
    (void)t;
    xd[0] = x[1];
    xd[1] = P->p[0] * ((1.0 - x[0] * x[0]) * x[1] - x[0]);
    return MBS_F_OK;
}

static int f_kepler(void *ctx, double t, const double *x, double *xd)
{
    double r3 = pow(x[0] * x[0] + x[1] * x[1], 1.5);
    (void)ctx;
    (void)t;
    xd[0] = x[2];
    xd[1] = x[3];
    xd[2] = -x[0] / r3;
    xd[3] = -x[1] / r3;
    return MBS_F_OK;
}

/* q' = ½ q ⊗ (0, ω); Euler's equations I ω' = (I ω) × ω */
static int f_rigid(void *ctx, double t, const double *x, double *xd)
{
    const TestOde *P = (const TestOde *)ctx;
    const double *q = x, *w = x + 4, *I = P->p;
    (void)t;
    xd[0] = 0.5 * (-q[1] * w[0] - q[2] * w[1] - q[3] * w[2]);
    xd[1] = 0.5 * (q[0] * w[0] + q[2] * w[2] - q[3] * w[1]);
    xd[2] = 0.5 * (q[0] * w[1] - q[1] * w[2] + q[3] * w[0]);
    xd[3] = 0.5 * (q[0] * w[2] + q[1] * w[1] - q[2] * w[0]);
    xd[4] = (I[1] - I[2]) * w[1] * w[2] / I[0];
    xd[5] = (I[2] - I[0]) * w[2] * w[0] / I[1];
    xd[6] = (I[0] - I[1]) * w[0] * w[1] / I[2];
    return MBS_F_OK;
}

static void normalize_rigid(void *ctx, double *x)
{
    double s = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3]);
    (void)ctx;
    x[0] /= s;
    x[1] /= s;
    x[2] /= s;
    x[3] /= s;
}

static int f_decay(void *ctx, double t, const double *x, double *xd)
{
    const TestOde *P = (const TestOde *)ctx;
    int i;
    (void)t;
    for (i = 0; i < P->m; i++) xd[i] = -P->p[i] * x[i];
    return MBS_F_OK;
}

static int f_ramp(void *ctx, double t, const double *x, double *xd)
{
    (void)t;
    (void)x;
    xd[0] = ((const TestOde *)ctx)->p[0];
    return MBS_F_OK;
}

static int f_blowup(void *ctx, double t, const double *x, double *xd)
{
    (void)ctx;
    (void)t;
    xd[0] = x[0] * x[0];
    return MBS_F_OK;
}

static int f_nan_after(void *ctx, double t, const double *x, double *xd)
{
    double bad = t > ((const TestOde *)ctx)->p[0] ? NAN : 0.0;
    xd[0] = -x[0] + bad;
    xd[1] = -x[1] + bad;
    return MBS_F_OK;
}

static int f_fail_after(void *ctx, double t, const double *x, double *xd)
{
    if (t > ((const TestOde *)ctx)->p[0]) return MBS_F_SINGULAR;
    xd[0] = -x[0];
    xd[1] = -x[1];
    return MBS_F_OK;
}

static const char *message(void *ctx)
{
    (void)ctx;
    return "mass matrix is singular (test)";
}

static int f_confined(void *ctx, double t, const double *x, double *xd)
{
    const TestOde *P = (const TestOde *)ctx;
    (void)t;
    if (!(fabs(x[0]) <= 10.0 && fabs(x[1]) <= 10.0)) return MBS_F_SINGULAR;
    xd[0] = 1.0;
    xd[1] = -P->p[0] * (x[1] - x[0]);
    return MBS_F_OK;
}

static int f_wide(void *ctx, double t, const double *x, double *xd)
{
    const TestOde *P = (const TestOde *)ctx;
    (void)t;
    for (int i = 0; i < P->ode.n; i++) xd[i] = -x[i];
    return MBS_F_OK;
}

MbsOde *test_ode_new(const char *name, const double *p, int np)
{
    static const char *const names[] = {"harmonic", "vdp", "kepler", "rigid", "decay", "ramp", "blowup",
                                        "nan_after", "fail_after", "wide", "confined"};
    int kind, i;
    TestOde *P;
    for (kind = 0; kind < NKINDS && strcmp(name, names[kind]) != 0; kind++) {}
    if (kind == NKINDS || np < 0 || np > 8) return NULL;
    P = (TestOde *)calloc(1, sizeof *P);
    if (!P) return NULL;
    P->kind = kind;
    P->m = np;
    for (i = 0; i < np; i++) P->p[i] = p[i];
    P->ode.ctx = P;
    P->ode.message = message;
    P->ode.n = 2;
    switch (kind) {
    case HARMONIC: P->ode.f = f_harmonic; break;
    case VDP: P->ode.f = f_vdp; break;
    case KEPLER: P->ode.f = f_kepler; P->ode.n = 4; break;
    case RIGID: P->ode.f = f_rigid; P->ode.n = 7; P->ode.normalize = normalize_rigid; break;
    case DECAY: P->ode.f = f_decay; P->ode.n = np; break;
    case CONFINED: P->ode.f = f_confined; break;
    case WIDE: P->ode.f = f_wide; P->ode.n = np == 1 && p[0] >= 1 && p[0] <= 1e7 ? (int)p[0] : 1; break;
    case RAMP: P->ode.f = f_ramp; P->ode.n = 1; break;
    case BLOWUP: P->ode.f = f_blowup; P->ode.n = 1; break;
    case NAN_AFTER: P->ode.f = f_nan_after; break;
    default: P->ode.f = f_fail_after; break;
    }
    P->ode.npos = kind == RIGID ? 4 : P->ode.n / 2;
    P->ode.nvel = P->ode.n - P->ode.npos;
    return &P->ode;
}

void test_ode_set(MbsOde *ode, int i, double v)
{
    if (i >= 0 && i < 8) ((TestOde *)ode)->p[i] = v;
}

void test_ode_free(MbsOde *ode) { free(ode); }
