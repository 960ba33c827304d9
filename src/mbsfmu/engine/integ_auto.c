/* 'auto': DOPRI5 until its stiffness test fires (Hairer's h·|λ| > 3.25, 15 times) or it fails, then RADAU5 for good.
 * Two child integrators; t, x, h come from the one in charge, stats are summed over both phases. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "integ_base.h"

#define AUTO_HEADER 32 /* "MBSA", method, n, dense, phase, 0 (int32 each), switched_at (8 bytes) */

typedef struct {
    double switched_at; /* NaN before the switch */
    int phase;          /* 0: dopri5, 1: radau5 */
} AutoState;

static AutoState *state(const MbsIntegrator *it) { return (AutoState *)it->ms; }

static MbsIntegrator *auto_active(const MbsIntegrator *it) { return it->sub[state(it)->phase]; }

static int auto_setup(MbsIntegrator *it, const MbsOde *ode, const MbsIntegOptions *opt, char *err, size_t errlen)
{
    MbsIntegOptions o = *opt;
    if (mbs_integ_take_options(it, ode, opt, 1, err, errlen)) return 1; /* dense output: its children's */
    o.dense = it->dense;
    o.h = 0.0; /* both children are adaptive */
    it->sub[0] = mbs_integ_new(MBS_DOPRI5, &it->ode, &o, err, errlen);
    if (!it->sub[0]) return 1;
    it->sub[0]->detect_stiffness = it->sub[0]->stop_when_stiff = 1;
    it->sub[1] = mbs_integ_new(MBS_RADAU5, &it->ode, &o, err, errlen);
    if (!it->sub[1]) return 1;
    it->hist_bytes = sizeof(AutoState);
    it->hist = (unsigned char *)calloc(1, it->hist_bytes);
    if (!it->hist) {
        if (err && errlen) {
            strncpy(err, "out of memory", errlen - 1);
            err[errlen - 1] = '\0';
        }
        return 1;
    }
    it->ms = it->hist;
    state(it)->phase = 0;
    state(it)->switched_at = NAN;
    return 0;
}

static int child_failed(MbsIntegrator *it, const MbsIntegrator *child)
{
    mbs_msg_set(it, mbs_integ_message(child));
    return 1;
}

static int auto_reset(MbsIntegrator *it, double t0, const double *x0)
{
    mbs_msg_set(it, "");
    if (mbs_integ_reset(it->sub[0], t0, x0)) return child_failed(it, it->sub[0]);
    state(it)->phase = 0;
    state(it)->switched_at = NAN;
    return 0;
}

static void auto_inputs_changed(MbsIntegrator *it) { mbs_integ_inputs_changed(auto_active(it)); }

/* Hand (t, x) and the current step size to RADAU5, which grows h as stability allows. */
static int switch_to_radau5(MbsIntegrator *it)
{
    MbsIntegrator *ns = it->sub[0], *st = it->sub[1];
    if (mbs_integ_reset(st, ns->c->t, ns->x)) return child_failed(it, st);
    st->c->h = ns->c->h;
    st->c->has_h = ns->c->has_h;
    st->c->restarted = ns->c->restarted; /* a switch inside an advance after an input change still lands */
    state(it)->phase = 1;
    state(it)->switched_at = ns->c->t;
    return 0;
}

static int auto_advance(MbsIntegrator *it, double t_end)
{
    mbs_msg_set(it, "");
    if (state(it)->phase == 0) {
        MbsIntegrator *ns = it->sub[0];
        if (mbs_integ_advance(ns, t_end)) {
            /* DOPRI5 gave up before its stiffness test could fire: stages of every step it tried left the
             * region where the equations are defined (M singular far off, NaN), as on a system stiff from the
             * first step. RADAU5 goes on from the last accepted state with a step of its own choosing, or says
             * why it cannot. */
            if (switch_to_radau5(it)) return 1;
            it->sub[1]->c->has_h = 0;
        }
        /* stiffness may be found in a dense-output step past t_end: switch at the visible point */
        else if ((ns->c->t < t_end || mbs_dopri5_stiff(ns)) && switch_to_radau5(it)) return 1;
    }
    if (state(it)->phase == 1 && mbs_integ_advance(it->sub[1], t_end)) return child_failed(it, it->sub[1]);
    return 0;
}

static void auto_stats(const MbsIntegrator *it, MbsStats *out)
{
    MbsStats s;
    mbs_integ_stats(it->sub[0], out);
    if (state(it)->phase == 1) {
        mbs_integ_stats(it->sub[1], &s);
        out->steps += s.steps;
        out->rejected += s.rejected;
        out->rhs_evaluations += s.rhs_evaluations;
        out->jac_evaluations += s.jac_evaluations;
        out->lu_decompositions += s.lu_decompositions;
    }
    out->switched = state(it)->phase;
    out->switched_at = state(it)->switched_at;
}

/* ---- snapshot: header, then both children's snapshots (fixed size) ---- */

static size_t auto_snapshot_size(const MbsIntegrator *it)
{
    return AUTO_HEADER + mbs_integ_snapshot_size(it->sub[0]) + mbs_integ_snapshot_size(it->sub[1]);
}

static void auto_snapshot_save(const MbsIntegrator *it, unsigned char *buf)
{
    size_t n0 = mbs_integ_snapshot_size(it->sub[0]);
    memcpy(buf, "MBSA", 4);
    mbs_put_i32(buf + 4, it->method);
    mbs_put_i32(buf + 8, it->n);
    mbs_put_i32(buf + 12, it->dense);
    mbs_put_i32(buf + 16, state(it)->phase);
    mbs_put_i32(buf + 20, 0);
    memcpy(buf + 24, &state(it)->switched_at, sizeof(double));
    mbs_integ_snapshot_save(it->sub[0], buf + AUTO_HEADER);
    mbs_integ_snapshot_save(it->sub[1], buf + AUTO_HEADER + n0);
}

static int auto_snapshot_load(MbsIntegrator *it, const unsigned char *buf, size_t len)
{
    size_t n0 = mbs_integ_snapshot_size(it->sub[0]), n1 = mbs_integ_snapshot_size(it->sub[1]);
    long phase;
    if (!buf || len != AUTO_HEADER + n0 + n1 || memcmp(buf, "MBSA", 4) != 0) return 1;
    phase = mbs_get_i32(buf + 16);
    if (mbs_get_i32(buf + 4) != it->method || mbs_get_i32(buf + 8) != it->n || mbs_get_i32(buf + 12) != it->dense ||
        (phase != 0 && phase != 1) || mbs_get_i32(buf + 20) != 0)
        return 1;
    /* both children validated before either changes */
    if (mbs_integ_snapshot_check(it->sub[0], buf + AUTO_HEADER, n0) ||
        mbs_integ_snapshot_check(it->sub[1], buf + AUTO_HEADER + n0, n1))
        return 1;
    mbs_integ_snapshot_commit(it->sub[0]);
    mbs_integ_snapshot_commit(it->sub[1]);
    state(it)->phase = (int)phase;
    memcpy(&state(it)->switched_at, buf + 24, sizeof(double));
    mbs_msg_set(it, "");
    return 0;
}

static const MbsIntegOps auto_ops = {auto_setup, auto_reset, auto_inputs_changed, auto_advance, auto_active,
                                     auto_stats, auto_snapshot_size, auto_snapshot_save, auto_snapshot_load};
const MbsMethodClass mbs_auto_class = {.name = "auto", .ops = &auto_ops};
