/* Test systems for the stiff integrators (tests/test_engine_stiff.py), built with the engine's integrator
 * sources into one shared library and driven through ctypes.
 *
 * stiff_problem_new(name, p, np) returns an MbsOde (first member of a heap block that owns the parameters)
 * for one of:
 *   "robertson"  Robertson's chemical kinetics (n = 3), no parameters
 *   "vdp"        Van der Pol y'' = μ((1 − y²)y' − y), p = {μ}
 *   "osc"        uncoupled undamped oscillators y_i'' = −ω_i² y_i, p = {ω_1 … ω_m}, m ≤ 8
 *   "top"        heavy top with a fixed point: unit quaternion q (body → world, [w, x, y, z]) and body
 *                angular velocity ω, p = {I1, I2, I3, m·g·l} (center of mass at l·e_z in the body frame,
 *                gravity −g·e_z); npos = 4, nvel = 3, normalize and retract (q ⊗ exp(δ/2))
 *   "nan_after"  ẋ = −x (n = 2) until t = p[0], NaN afterwards
 *   "fail_after" ẋ = −x (n = 2) until t = p[0], then MBS_F_SINGULAR with a message
 * stiff_method_state_offset(it): byte offset of the method's POD struct inside a snapshot (corruption tests).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "integ_base.h"

enum { P_ROBERTSON, P_VDP, P_OSC, P_TOP, P_NAN_AFTER, P_FAIL_AFTER };

typedef struct {
    MbsOde ode; /* first member: the pointer handed out is also the block's address */
    int kind, m;
    double p[8];
    long calls;
} StiffProblem;

static int f_robertson(void *ctx, double t, const double *x, double *xd)
{
    (void)ctx; (void)t;
    double r1 = 0.04 * x[0], r2 = 3e7 * x[1] * x[1], r3 = 1e4 * x[1] * x[2];
    xd[0] = -r1 + r3;
    xd[1] = r1 - r2 - r3;
    xd[2] = r2;
    return MBS_F_OK;
}

static int f_vdp(void *ctx, double t, const double *x, double *xd)
{
    const StiffProblem *P = ctx;
    (void)t;
    xd[0] = x[1];
    xd[1] = P->p[0] * ((1.0 - x[0] * x[0]) * x[1] - x[0]);
    return MBS_F_OK;
}

static int f_osc(void *ctx, double t, const double *x, double *xd)
{
    const StiffProblem *P = ctx;
    (void)t;
    for (int i = 0; i < P->m; ++i) {
        xd[i] = x[P->m + i];
        xd[P->m + i] = -P->p[i] * P->p[i] * x[i];
    }
    return MBS_F_OK;
}

/* r = a ⊗ b (Hamilton product, [w, x, y, z]) */
static void qmul(const double *a, const double *b, double *r)
{
    r[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    r[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    r[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    r[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
}

static int f_top(void *ctx, double t, const double *x, double *xd)
{
    const StiffProblem *P = ctx;
    const double *q = x, *w = x + 4, *I = P->p;
    (void)t;
    double wq[4] = {0.0, w[0], w[1], w[2]}, qd[4];
    qmul(q, wq, qd); /* q' = ½ q ⊗ (0, ω) */
    for (int i = 0; i < 4; ++i) xd[i] = 0.5 * qd[i];
    /* world vertical e_z seen in the body frame: third row of R(q) */
    double ez[3] = {2.0 * (q[1] * q[3] - q[0] * q[2]), 2.0 * (q[2] * q[3] + q[0] * q[1]),
                    1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2])};
    /* gravity torque l·e_z × (−m g ez_body) */
    double tau[3] = {P->p[3] * ez[1], -P->p[3] * ez[0], 0.0};
    double Iw[3] = {I[0] * w[0], I[1] * w[1], I[2] * w[2]};
    xd[4] = (tau[0] - (w[1] * Iw[2] - w[2] * Iw[1])) / I[0];
    xd[5] = (tau[1] - (w[2] * Iw[0] - w[0] * Iw[2])) / I[1];
    xd[6] = (tau[2] - (w[0] * Iw[1] - w[1] * Iw[0])) / I[2];
    return MBS_F_OK;
}

static void normalize_top(void *ctx, double *x)
{
    (void)ctx;
    double s = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2] + x[3] * x[3]);
    for (int i = 0; i < 4; ++i) x[i] /= s;
}

static void retract_top(void *ctx, const double *y, const double *dy, double *out)
{
    (void)ctx;
    double a = 0.5 * sqrt(dy[0] * dy[0] + dy[1] * dy[1] + dy[2] * dy[2]);
    double s = a > 1e-8 ? sin(a) / (2.0 * a) : 0.5 - a * a / 12.0; /* sin(a)/|δ| */
    double e[4] = {cos(a), s * dy[0], s * dy[1], s * dy[2]};
    qmul(y, e, out);
}

static int f_after(void *ctx, double t, const double *x, double *xd)
{
    StiffProblem *P = ctx;
    if (t > P->p[0]) {
        if (P->kind == P_FAIL_AFTER) return MBS_F_SINGULAR;
        xd[0] = xd[1] = NAN;
        return MBS_F_OK;
    }
    xd[0] = -x[0];
    xd[1] = -x[1];
    return MBS_F_OK;
}

static const char *message_after(void *ctx)
{
    (void)ctx;
    return "test: mass matrix singular";
}

static int counting_f(void *ctx, double t, const double *x, double *xd)
{
    StiffProblem *P = ctx;
    P->calls++;
    switch (P->kind) {
    case P_ROBERTSON: return f_robertson(ctx, t, x, xd);
    case P_VDP: return f_vdp(ctx, t, x, xd);
    case P_OSC: return f_osc(ctx, t, x, xd);
    case P_TOP: return f_top(ctx, t, x, xd);
    default: return f_after(ctx, t, x, xd);
    }
}

MbsOde *stiff_problem_new(const char *name, const double *p, int np)
{
    static const char *const names[] = {"robertson", "vdp", "osc", "top", "nan_after", "fail_after"};
    int kind = -1;
    for (int i = 0; i < 6; ++i)
        if (strcmp(name, names[i]) == 0) kind = i;
    if (kind < 0 || np < 0 || np > 8) return NULL;
    StiffProblem *P = calloc(1, sizeof *P);
    if (!P) return NULL;
    P->kind = kind;
    P->m = np;
    for (int i = 0; i < np; ++i) P->p[i] = p[i];
    MbsOde *o = &P->ode;
    o->ctx = P;
    o->f = counting_f;
    o->message = message_after;
    switch (kind) {
    case P_ROBERTSON: o->npos = 3; o->nvel = 0; break;
    case P_VDP: o->npos = 1; o->nvel = 1; break;
    case P_OSC: o->npos = o->nvel = np; break;
    case P_TOP: o->npos = 4; o->nvel = 3; o->normalize = normalize_top; o->retract = retract_top; break;
    default: o->npos = 1; o->nvel = 1; break;
    }
    o->n = o->npos + o->nvel;
    return o;
}

long stiff_problem_calls(const MbsOde *o) { return ((const StiffProblem *)o)->calls; }

void stiff_problem_free(MbsOde *o) { free(o); }

size_t stiff_method_state_offset(const MbsIntegrator *it)
{
    return mbs_integ_snapshot_size(it) - it->hist_bytes + it->off_ms;
}
