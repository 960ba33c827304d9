/* The bodies of the FMI calls, version-independent (fmi_calls.h; the services they use: fmi_services.c): every body fmi2.c and fmi3.c would otherwise
 * write twice. Messages name the calling FMI function (fn); statuses are fmi2Status/fmi3Status numbers. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi_calls.h"

/* ---- logging and checks ---- */
void mbs_fmi_logf(MbsFmiHead *h, int status, const char *fmt, ...) {
    char buf[1024];
    va_list ap;
    if (!mbs_log_wanted(&h->log_switches, status))
        return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    h->emit(h, status, mbs_fmi_category[status >= 0 && status < MBS_NCAT ? status : 0], buf);
}

static void engine_log(void *env, int status, const char *message) {
    MbsFmiHead *h = (MbsFmiHead *)env;
    h->logged = 1;
    mbs_fmi_logf(h, status >= MBS_OK && status <= MBS_ERROR ? status : MBS_ERROR, "%s", message);
}

int mbs_fmi_status(MbsFmiHead *h, int rc, const char *what) {
    if (rc < MBS_OK || rc > MBS_ERROR)
        rc = MBS_ERROR;
    if (rc != MBS_OK && !h->logged)
        mbs_fmi_logf(h, rc, "%s: %s", what, mbs_message(h->sim));
    return rc;  /* the engine's codes are ordered like the FMI statuses (OK, Warning, Discard, Error) */
}

int mbs_fmi_allowed(MbsRegistry *instances, MbsFmiHead *p, int mask, const char *fn, const char *null_name) {
    char why[256];
    if (!mbs_reg_find(instances, p)) {  /* no logger known: stderr */
        fprintf(stderr, "mbsfmu: %s: %s\n", fn,
                p ? "not a live instance of this FMU (freed, or another FMU's)" : null_name);
        return 0;
    }
    p->logged = 0;
    if (!mbs_phase_refuses(mask, p->phase, p->iface, fn, why, sizeof why))
        return 1;
    mbs_fmi_logf(p, MBS_FMI_ERROR, "%s", why);
    return 0;
}

int mbs_fmi_bad_array(MbsFmiHead *h, const void *a, const void *b, size_t n, const char *fn) {
    if (n == 0 || (a && b))
        return 0;
    mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: NULL array for %lu values", fn, (unsigned long)n);
    return 1;
}

size_t mbs_fmi_nstates(const MbsFmiHead *h) {
    return (size_t)mbs_model_npos(h->model) + (size_t)mbs_model_nvel(h->model);
}

/* ---- instances ---- */
MbsFmiHead *mbs_fmi_alloc(size_t size, const char *name) {
    MbsFmiHead *h = (MbsFmiHead *)calloc(1, size);
    if (h && !(h->name = (char *)malloc(strlen(name) + 1))) {
        free(h);
        return NULL;
    }
    if (h)
        strcpy(h->name, name);
    return h;
}

int mbs_fmi_start(MbsFmiHead *h, MbsRegistry *instances, MbsRegistry *states, MbsModel *model, int iface,
                  int logging_on) {
    h->model = model;
    h->iface = iface;
    h->phase = P_INSTANTIATED;
    h->refused_vr = -1;
    h->states = states;
    mbs_log_init(&h->log_switches, logging_on);
    h->sim = mbs_instance_new(model, engine_log, h);
    if (h->sim && mbs_reg_add(instances, h))
        return 1;
    mbs_instance_free(h->sim);
    mbs_model_free(model);
    free(h->name);
    free(h);
    return 0;
}

void mbs_fmi_free_instance(MbsRegistry *instances, MbsFmiHead *p, const char *fn) {
    if (!mbs_reg_drop(instances, p)) {  /* NULL, freed before, or not ours: nothing to free */
        if (p)
            fprintf(stderr, "mbsfmu: %s: not a live instance of this FMU (freed, or another FMU's)\n", fn);
        return;
    }
    mbs_fmu_states_free_owned(p->states, p);  /* the states it handed out go with it */
    mbs_instance_free(p->sim);
    mbs_model_free(p->model);
    free(p->name);
    free(p);
}

int mbs_fmi_set_debug_logging(MbsFmiHead *h, int logging_on, size_t n, const char *const categories[],
                              const char *fn) {
    char err[256];
    if (!mbs_log_set(&h->log_switches, logging_on, n, categories, err, sizeof err))
        return MBS_FMI_OK;
    mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: %s", fn, err);
    return MBS_FMI_ERROR;
}

/* ---- life cycle ---- */
/* The tolerance is the parameter integrator.rtol (as in the pythonfmu kind); the stop time is not needed: the
 * integrator lands on every communication point. */
int mbs_fmi_setup(MbsFmiHead *h, int tolerance_defined, double tolerance, double start, int stop_defined,
                  double stop, const char *fn) {
    if (!isfinite(start) || (tolerance_defined && !(isfinite(tolerance) && tolerance > 0)) ||
        (stop_defined && !(isfinite(stop) && stop >= start))) {
        mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: need a finite start time, a tolerance > 0 and a finite stop time "
                     ">= start when defined (start %g, tolerance %g, stop %g)", fn, start,
                     tolerance_defined ? tolerance : 0.0, stop_defined ? stop : start);
        return MBS_FMI_ERROR;
    }
    h->t_start = start;
    return MBS_FMI_OK;
}

int mbs_fmi_exit_init(MbsFmiHead *h, const char *fn) {
    int st;
    if (h->refused_vr >= 0) {  /* the experiment the host asked for cannot run: no silent default */
        mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: value reference %ld was refused: %s", fn, h->refused_vr, h->refused);
        h->phase = P_ERROR;
        return MBS_FMI_ERROR;
    }
    st = mbs_fmi_status(h, mbs_initialize(h->sim, h->t_start), fn);
    if (st >= MBS_FMI_DISCARD) {
        h->phase = P_ERROR;
        return MBS_FMI_ERROR;
    }
    h->phase = h->iface == I_ME ? P_EVENT : P_STEP;  /* model exchange: event mode first */
    return st;
}

int mbs_fmi_reset(MbsFmiHead *h, const char *fn) {
    int st = mbs_fmi_status(h, mbs_reset(h->sim), fn);
    h->phase = st >= MBS_FMI_DISCARD ? P_ERROR : P_INSTANTIATED;
    h->t_start = 0.0;
    h->refused_vr = -1;
    return st >= MBS_FMI_DISCARD ? MBS_FMI_ERROR : st;
}

/* ---- variables ---- */
int mbs_fmi_setting(MbsFmiHead *h, int vr, int rc, const char *fn) {
    int st = mbs_fmi_status(h, rc, fn);
    if (h->phase & (P_INSTANTIATED | P_INIT)) {
        if (st >= MBS_FMI_ERROR) {
            h->refused_vr = vr;
            snprintf(h->refused, sizeof h->refused, "%s", mbs_message(h->sim));
        } else if (h->refused_vr == vr)
            h->refused_vr = -1;
    }
    return st >= MBS_FMI_ERROR ? MBS_FMI_ERROR : st;
}

int mbs_fmi_set_reals(MbsFmiHead *h, const unsigned vr[], size_t nvr, const double values[], const char *fn) {
    size_t i, bad = 0;
    int rc = mbs_set_reals(h->sim, vr, nvr, values, &bad);
    if (rc != MBS_OK)
        return mbs_fmi_setting(h, (int)vr[bad < nvr ? bad : 0], rc, fn);
    for (i = 0; i < nvr; i++)
        mbs_fmi_setting(h, (int)vr[i], MBS_OK, fn);
    return MBS_FMI_OK;
}

int mbs_fmi_vr(MbsFmiHead *h, unsigned vr, const char *unknown_fmt, const char *fn) {
    if (vr < (unsigned)mbs_model_nvars(h->model))
        return (int)vr;
    mbs_fmi_logf(h, MBS_FMI_ERROR, unknown_fmt, fn, vr);
    return -1;
}

int mbs_fmi_get_strings(MbsFmiHead *h, const unsigned vr[], size_t nvr, const char *values[],
                        const char *unknown_fmt, const char *fn) {
    size_t i;
    for (i = 0; i < nvr; i++) {
        int r = mbs_fmi_vr(h, vr[i], unknown_fmt, fn);
        if (r < 0)
            return MBS_FMI_ERROR;
        if (mbs_get_string(h->sim, r, &values[i]) != MBS_OK)
            return mbs_fmi_status(h, MBS_ERROR, fn);
    }
    return MBS_FMI_OK;
}

int mbs_fmi_set_strings(MbsFmiHead *h, const unsigned vr[], size_t nvr, const char *const values[],
                        const char *unknown_fmt, const char *fn) {
    size_t i;
    for (i = 0; i < nvr; i++) {
        int r = mbs_fmi_vr(h, vr[i], unknown_fmt, fn);
        if (r < 0)
            return MBS_FMI_ERROR;
        if (!values[i]) {
            mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: NULL string for value reference %u", fn, vr[i]);
            return MBS_FMI_ERROR;
        }
        if (mbs_fmi_setting(h, r, mbs_set_string(h->sim, r, values[i]), fn) >= MBS_FMI_ERROR)
            return MBS_FMI_ERROR;
    }
    return MBS_FMI_OK;
}

int mbs_fmi_no_such_type(MbsFmiHead *h, size_t nvr, const char *more, const char *fn) {
    if (nvr == 0)
        return MBS_FMI_OK;
    mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: this model has no variables of that type%s", fn, more);
    return MBS_FMI_ERROR;
}

/* A NULL argument p: 1 with the message "fn: what". */
static int null_arg(MbsFmiHead *h, const void *p, const char *what, const char *fn) {
    if (p)
        return 0;
    mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: %s", fn, what);
    return 1;
}

/* ---- FMU states: the engine's byte layout, in memory and serialized (fmi_services.c) ---- */
/* A state handed out by any live instance of this FMU (same model: it restores into any of them). */
static MbsFmuState *state_of(MbsFmiHead *h, void *s, const char *fn) {
    if (mbs_reg_find(h->states, s))
        return (MbsFmuState *)s;
    mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: not an FMU state of this FMU's live instances (never handed out, or freed)",
                 fn);
    return NULL;
}

int mbs_fmi_get_state(MbsFmiHead *h, void **state, const char *fn) {
    MbsFmuState *st;
    if (null_arg(h, state, "NULL pointer", fn))
        return MBS_FMI_ERROR;
    st = (MbsFmuState *)*state;
    if (st && !state_of(h, st, fn))
        return MBS_FMI_ERROR;
    if (!(st = mbs_fmu_state_sized(h->states, st, h, mbs_state_size(h->sim)))) {
        mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: out of memory", fn);
        return MBS_FMI_ERROR;
    }
    *state = st;
    return mbs_fmi_status(h, mbs_state_save(h->sim, st->bytes, st->len), fn);
}

int mbs_fmi_set_state(MbsFmiHead *h, void *state, const char *fn) {
    char what[128];
    MbsFmuState *st;
    if (!(st = state_of(h, state, fn)))
        return MBS_FMI_ERROR;
    if (mbs_state_load(h->sim, st->bytes, st->len) != MBS_OK) {
        snprintf(what, sizeof what, "%s (instance unchanged)", fn);
        mbs_fmi_status(h, MBS_ERROR, what);
        return MBS_FMI_ERROR;
    }
    if (!mbs_initialized(h->sim))
        h->phase = P_INSTANTIATED;  /* a state from before initialization: initialize again */
    else if (h->iface == I_CS)
        h->phase = P_STEP;
    else if (!(h->phase & (P_EVENT | P_CONT)))
        h->phase = P_EVENT;  /* model exchange: a host that restores while integrating goes on integrating */
    return MBS_FMI_OK;
}

int mbs_fmi_free_state(MbsFmiHead *h, void **state, const char *fn) {
    MbsFmuState *st;
    if (null_arg(h, state, "NULL state pointer", fn))
        return MBS_FMI_ERROR;
    if (!*state)
        return MBS_FMI_OK;  /* freeing NULL is a no-op */
    if (!(st = state_of(h, *state, fn)) || !mbs_reg_drop(h->states, st))
        return MBS_FMI_ERROR;
    free(st);
    *state = NULL;
    return MBS_FMI_OK;
}

int mbs_fmi_state_size(MbsFmiHead *h, void *state, size_t *size, const char *fn) {
    MbsFmuState *st;
    if (!(st = state_of(h, state, fn)))
        return MBS_FMI_ERROR;
    if (null_arg(h, size, "NULL size pointer", fn))
        return MBS_FMI_ERROR;
    *size = st->len;
    return MBS_FMI_OK;
}

int mbs_fmi_serialize(MbsFmiHead *h, void *state, void *out, size_t size, const char *fn) {
    MbsFmuState *st;
    if (!(st = state_of(h, state, fn)))
        return MBS_FMI_ERROR;
    if (null_arg(h, out, "NULL buffer", fn))
        return MBS_FMI_ERROR;
    if (size < st->len) {
        mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: buffer of %lu bytes for a state of %lu", fn, (unsigned long)size,
                     (unsigned long)st->len);
        return MBS_FMI_ERROR;
    }
    memcpy(out, st->bytes, st->len);
    return MBS_FMI_OK;
}

/* Only bytes that load into this instance (mbs_fmu_state_check: its own state restored afterwards) are copied
 * into a new state. */
int mbs_fmi_deserialize(MbsFmiHead *h, const void *bytes, size_t size, void **state, const char *fn) {
    MbsFmuState *st;
    int rc;
    if (!state || !bytes) {
        mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: NULL pointer", fn);
        return MBS_FMI_ERROR;
    }
    rc = mbs_fmu_state_check(h->sim, bytes, size);
    if (rc == -1) {
        h->phase = P_FATAL;
        mbs_fmi_logf(h, MBS_FMI_FATAL, "%s: the instance's own state did not load back: %s", fn,
                     mbs_message(h->sim));
        return MBS_FMI_FATAL;
    }
    if (rc != MBS_OK) {
        if (rc == -2)
            mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: out of memory", fn);
        else
            mbs_fmi_status(h, MBS_ERROR, fn);
        return MBS_FMI_ERROR;
    }
    if (!(st = mbs_fmu_state_copy(h->states, h, bytes, size))) {
        mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: out of memory", fn);
        return MBS_FMI_ERROR;
    }
    *state = st;  /* an output argument: whatever it held is not ours to free */
    return MBS_FMI_OK;
}

/* ---- co-simulation and model exchange ---- */
int mbs_fmi_bad_step(MbsFmiHead *h, double t, double dt, const char *fn) {
    if (isfinite(t) && isfinite(dt) && dt > 0 && t + dt != t)
        return 0;
    mbs_fmi_logf(h, MBS_FMI_ERROR, "%s: bad step t=%g, h=%g (need finite t and h > 0 that advances t)", fn, t, dt);
    return 1;
}

int mbs_fmi_ok_or_error(MbsFmiHead *h, int rc, const char *fn) {
    return mbs_fmi_status(h, rc, fn) == MBS_FMI_OK ? MBS_FMI_OK : MBS_FMI_ERROR;
}
