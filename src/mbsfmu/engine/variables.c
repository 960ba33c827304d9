/* Variables by value reference (S_VARS): set and get, output points, stress, start values, the method. */
#include "instance.h"

/* ------------------------------------------------------------------------------------------ variables */
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
    if (!mbs_bind(s)) {
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
    mbs_bind(s);  /* the numbers of the kept values again */
    return mbs_report(s, MBS_ERROR, "%s%s %s; the parameters keep their values", set,
                  !derived ? ":" : count > 1 ? " make" : " makes", why);
}

/* the integrator setting a Real kind of VK_FIXED variable holds */
static double *setting(MbsInstance *s, int kind)
{
    return kind == MBS_V_RTOL ? &s->rtol : kind == MBS_V_ATOL ? &s->atol : kind == MBS_V_MAX_STEP ? &s->max_step : &s->step;
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
        if (kind < 0) return mbs_report(s, MBS_ERROR, "unknown value reference %u", vr[i]);
        const int set = mbs_var_kinds[kind].set;
        if (set == VK_READ || kind == MBS_V_METHOD)
            return mbs_report(s, MBS_ERROR, "value reference %u is %s, not a Real input or parameter", vr[i],
                              kind == MBS_V_METHOD ? "a String" : "an output");
        if (set == VK_FIXED && s->initialized)
            return mbs_report(s, MBS_ERROR, "%s is a fixed parameter: set it before initialization", m->var_name[vr[i]]);
        if (set == VK_INPUT) continue;  /* a non-finite input is refused by the next step (fmi2Discard) */
        if (!mbs_in_domain(d, value[i])) {
            const double old = kind == MBS_V_PARAM ? s->D[m->vars[2 * vr[i] + 1]] : *setting(s, kind);
            mbs_domain_text(d, valid, sizeof valid);
            return mbs_report(s, MBS_ERROR, "%s = %g is %s (valid: %s); %s keeps %g", m->var_name[vr[i]], value[i],
                              isfinite(value[i]) ? "outside its domain" : "not finite", valid, m->var_name[vr[i]], old);
        }
        nparam += kind == MBS_V_PARAM;
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
            *setting(s, kind) = value[i];
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
    mbs_time_numbers(s, t);
    MbsEval e = mbs_evaluation(s, x, s->xdot);
    mbs_cached_kinematics(s, &e, t);
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
    if (o < 0 || o >= s->m->hdr[H_NOUT]) return mbs_report(s, MBS_ERROR, "no output point %d", o);
    if (!s->initialized && !s->initial_valid && mbs_start_state(s)) return MBS_ERROR;  /* numbers bound first */
    output_points(s, x, t, o, o + 1, out);
    return MBS_OK;
}

int mbs_von_mises(MbsInstance *s, int k, const double *x, double *out)
{
    if (k < 0 || k >= s->m->nstress) return mbs_report(s, MBS_ERROR, "no stress node %d", k);
#ifdef MBS_WITH_ELASTIC  /* (stress nodes exist only with elastic bodies) */
    *out = mbs_elastic_von_mises(s->m, k, x);
#endif
    return MBS_OK;
}

MBS_NOINLINE int mbs_get_real(MbsInstance *s, int vr, double *value)  /* apart from mbs_get_reals' fast loop */
{
    int idx = 0, kind = var(s, vr, &idx), rc;
    if (kind >= 0 && mbs_var_kinds[kind].state && !s->initialized &&
        !s->initial_valid && (rc = mbs_start_state(s)))
        return rc;
    switch (kind) {
    case MBS_V_PARAM: *value = s->D[idx]; return MBS_OK;
    case MBS_V_RTOL: case MBS_V_ATOL: case MBS_V_MAX_STEP: case MBS_V_STEP: *value = *setting(s, kind); return MBS_OK;
    case MBS_V_QIN: *value = s->u[idx]; return MBS_OK;
    case MBS_V_FIN: *value = s->u[NVEL(s->m) + idx]; return MBS_OK;
    case MBS_V_Y: *value = s->x[idx]; return MBS_OK;
    case MBS_V_YD: *value = s->x[NPOS(s->m) + idx]; return MBS_OK;
    case MBS_V_OUT:
        if (!s->out_valid) {  /* all points at once: one kinematics pass per state, not one per variable */
            if (s->params_dirty && (rc = mbs_bind(s))) return mbs_report(s, rc, "%s", s->msg);  /* a parameter set since the step */
            output_points(s, s->x, s->time, 0, s->m->hdr[H_NOUT], s->out);
            s->out_valid = 1;
        }
        *value = s->out[idx];
        return MBS_OK;
    case MBS_V_DER:
        if ((rc = mbs_update_der(s))) return rc;
        *value = s->der[idx];
        return MBS_OK;
#ifdef MBS_WITH_ELASTIC
    case MBS_V_VM: *value = mbs_elastic_von_mises(s->m, idx, s->x); return MBS_OK;  /* only with elastic bodies */
#endif
    case -1: return mbs_report(s, MBS_ERROR, "unknown value reference %d", vr);
    default: return mbs_report(s, MBS_ERROR, "value reference %d is a String", vr);
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
        if (vr[i] > (unsigned)INT_MAX) return mbs_report(s, MBS_ERROR, "unknown value reference %u", vr[i]);
        int rc = mbs_get_real(s, (int)vr[i], value + i);
        if (rc) return rc;
    }
    return MBS_OK;
}

int mbs_set_start(MbsInstance *s, int index, double value)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_set_start");
    char why[160];
    if (index < 0 || index >= s->n) return mbs_report(s, MBS_ERROR, "no state entry %d", index);
    if (s->initialized) return mbs_report(s, MBS_ERROR, "start values are set before initialization");
    if (mbs_rule_problem(s->m, R_MAGNITUDE, &value, why, sizeof why)) {  /* the rule of the scene's `initial:` values */
        const MbsModel *m = s->m;
        const char *name = index < NPOS(m) ? m->coord_name[index] : NULL;
        for (int vr = 0; !name && vr < m->hdr[H_NVARS]; vr++)
            if (m->vars[2 * vr] == MBS_V_YD && m->vars[2 * vr + 1] == index - NPOS(m)) name = m->var_name[vr] + 3;
        return mbs_report(s, MBS_ERROR, "%s0.%s = %g%s%s; the start value is unchanged", index < NPOS(m) ? "y" : "yd",
                      name ? name : "?", value, isfinite(value) ? ": " : " is not finite", isfinite(value) ? why : "");
    }
    s->start[index] = value;
    s->initial_valid = s->der_valid = 0;
    return MBS_OK;
}

int mbs_set_string(MbsInstance *s, int vr, const char *value)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_set_string");
    if (mbs_model_var_kind(s->m, vr) != MBS_V_METHOD) return mbs_report(s, MBS_ERROR, "value reference %d is not a String parameter", vr);
    if (s->initialized) return mbs_report(s, MBS_ERROR, "integrator.method is a fixed parameter: set it before initialization");
    int k = value ? mbs_method_index(value) : -1;
    if (k < 0) {
        char valid[128] = "";
        for (int i = 0; i < MBS_NMETHODS; i++) { strcat(valid, i ? ", " : ""); strcat(valid, mbs_method_names[i]); }
        return mbs_report(s, MBS_ERROR, "unknown integrator method '%.60s'; valid: %s", value ? value : "(null)", valid);
    }
    s->method = k;
    return MBS_OK;
}

int mbs_get_string(MbsInstance *s, int vr, const char **value)
{
    if (mbs_model_var_kind(s->m, vr) != MBS_V_METHOD) return mbs_report(s, MBS_ERROR, "value reference %d is not a String", vr);
    *value = mbs_method_names[s->method];
    return MBS_OK;
}

