/* Model exchange: the host sets time and states and reads ẋ; directional and adjoint derivatives. */
#include "instance.h"

/* ------------------------------------------------------------------------------------------ model exchange
 * The host integrates x = [y; ẏ]: it sets the time and the states, the engine gives ẋ (mbs_engine.h). */

int mbs_set_time(MbsInstance *s, double t)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_set_time");
    if (!s->initialized) return mbs_report(s, MBS_ERROR, "the instance is not initialized");
    if (!isfinite(t)) return mbs_report(s, MBS_ERROR, "time %g is not finite; the time stays %.17g", t, s->time);
    if (t != s->time) s->time = t, s->out_valid = s->der_valid = 0;
    return MBS_OK;
}

int mbs_set_state(MbsInstance *s, const double *x, size_t n)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_set_state");
    if (!s->initialized) return mbs_report(s, MBS_ERROR, "the instance is not initialized");
    if (!x || n != (size_t)s->n)
        return mbs_report(s, MBS_ERROR, "%zu continuous states given, the model has %d; states unchanged", x ? n : 0, s->n);
    for (int i = 0; i < s->n; i++)
        if (!isfinite(x[i]))
            return mbs_report(s, MBS_ERROR, "continuous state %s = %g is not finite; states unchanged", mbs_state_name(s->m, i), x[i]);
    if (memcmp(s->x, x, n * sizeof *x)) {
        memcpy(s->x, x, n * sizeof *x);
        s->out_valid = s->der_valid = 0;
    }
    return MBS_OK;
}

/* ẋ at (time, x) into s->der, once per time, state, inputs and parameters. Before initialization: at the initial
 * state (as the other getters). The host's inputs or parameters refused: MBS_ERROR; not defined at this state
 * (singular mass matrix, gimbal lock): MBS_DISCARD. */
int mbs_update_der(MbsInstance *s)
{
    if (s->der_valid) return MBS_OK;
    int rc = !s->initialized && !s->initial_valid ? mbs_start_state(s) : MBS_OK;
    if (!rc) rc = mbs_pending(s, MBS_ERROR, "no derivatives");
    if (rc) return rc;
    if (mbs_ode_f(s, s->time, s->x, s->der)) return mbs_report(s, MBS_DISCARD, "t = %.9g: %s", s->time, s->msg);
    if ((rc = mbs_finite_result(s, "the time derivative of", s->time, s->x, s->der, (size_t)s->n, NULL))) return rc;
    s->der_valid = 1;
    return MBS_OK;
}

int mbs_derivatives(MbsInstance *s, double *xdot, size_t n)
{
    if (!xdot || n != (size_t)s->n)
        return mbs_report(s, MBS_ERROR, "room for %zu derivatives, the model has %d", xdot ? n : 0, s->n);
    int rc = mbs_update_der(s);
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
    const int role = known ? VK_KNOWN : VK_UNKNOWN;
    if (kind >= 0 && (mbs_var_kinds[kind].role & role)) return NULL;
    return known ? "a continuous state or an input" : "a derivative, an output or a state";
}

static int check_refs(MbsInstance *s, const char *what, const unsigned *vr, size_t n, int known)
{
    for (size_t i = 0; i < n; i++) {
        const char *want = not_a(s->m, vr[i], known);
        if (want)
            return mbs_report(s, MBS_ERROR, "%s value reference %u (%s) is not %s", what, vr[i],
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
        if (!s->tangent) return mbs_report(s, MBS_ERROR, "no memory for the directional derivatives' workspace");
        s->dx = (double *)((char *)s->tangent + bytes);
    }
    double *dx = s->dx, *du = dx + s->n, *dxdot = du + s->nu, *dout = dxdot + s->n, *dvm = dout + 6 * (size_t)nout;
    int want[MBS_V_N] = {0};
    int rc = !s->initialized && !s->initial_valid ? mbs_start_state(s) : MBS_OK;
    if (!rc) rc = mbs_pending(s, MBS_ERROR, "no directional derivatives");
    if (rc) return rc;
    memset(dx, 0, sizeof(double) * ((size_t)s->n + s->nu));
    for (size_t j = 0; j < nknown; j++) {
        const int kind = m->vars[2 * known[j]], idx = m->vars[2 * known[j] + 1];
        if (!isfinite(seed[j]))
            return mbs_report(s, MBS_ERROR, "the seed of %s is not finite (%g)", m->var_name[known[j]], seed[j]);
        *(kind == MBS_V_Y ? dx + idx : kind == MBS_V_YD ? dx + NPOS(m) + idx : kind == MBS_V_QIN ? du + idx : du + f + idx) += seed[j];
    }
    for (size_t i = 0; i < nunknown; i++) want[m->vars[2 * unknown[i]]] = 1;
    const MbsTangent t = {s->D, s->td, s->x, s->q_in_active ? s->u_applied : NULL, dx, du, du + f,
                          want[MBS_V_DER] ? dxdot : NULL, want[MBS_V_OUT] ? dout : NULL, want[MBS_V_VM] ? dvm : NULL,
                          !s->tangent_bound};
    mbs_time_numbers(s, s->time);
    s->tangent_bound = 1;
    if (mbs_tangent(m, &t, s->tangent))
        return mbs_report(s, MBS_DISCARD, "t = %.9g: no directional derivatives: the mass matrix is singular here", s->time);
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
        return mbs_report(s, MBS_ERROR, "%s derivative: NULL arrays for %zu unknowns and %zu knowns", what, nunknown, nknown);
    int rc = check_refs(s, "unknown", unknown, nunknown, 0);
    return rc ? rc : check_refs(s, "known", known, nknown, 1);
}

int mbs_directional_derivative(MbsInstance *s, const unsigned *unknown, size_t nunknown, const unsigned *known,
                               size_t nknown, const double *seed, double *sensitivity)
{
    int rc = check_all(s, unknown, nunknown, known, nknown, seed, nknown, sensitivity, nunknown, "directional");
    if (!rc && nunknown) rc = tangent(s, unknown, nunknown, known, nknown, seed);  /* none asked: nothing to do */
    for (size_t i = 0; !rc && i < nunknown; i++) sensitivity[i] = tangent_of(s, unknown[i]);
    return rc ? rc : mbs_finite_result(s, "the directional derivative of", s->time, s->x, sensitivity, nunknown, unknown);
}

/* sensitivityᵀ = seedᵀ J: one column of J per known (complex step is forward mode) */
int mbs_adjoint_derivative(MbsInstance *s, const unsigned *unknown, size_t nunknown, const unsigned *known,
                           size_t nknown, const double *seed, double *sensitivity)
{
    int rc = check_all(s, unknown, nunknown, known, nknown, seed, nunknown, sensitivity, nknown, "adjoint");
    for (size_t i = 0; !rc && i < nunknown; i++)
        if (!isfinite(seed[i])) rc = mbs_report(s, MBS_ERROR, "the seed of %s is not finite (%g)", s->m->var_name[unknown[i]], seed[i]);
    const double one = 1.0;
    for (size_t j = 0; !rc && j < nknown; j++) {
        if ((rc = tangent(s, unknown, nunknown, known + j, 1, &one))) break;
        sensitivity[j] = 0.0;
        for (size_t i = 0; i < nunknown; i++) sensitivity[j] += seed[i] * tangent_of(s, unknown[i]);
    }
    return rc ? rc : mbs_finite_result(s, "the adjoint derivative's entry of", s->time, s->x, sensitivity, nknown, known);
}

