/* FMI 2.0 co-simulation and model-exchange layer over the mbsfmu engine (native FMUs, `mbsfmu build --kind
 * native`).
 *
 * One fmi2Component = one engine instance plus the FMI bookkeeping: the host's callbacks (copied), the
 * instance name, its interface (fmi2Instantiate's fmuType), the phase of that interface's FMI 2.0 state machine
 * and the logging switches. Under model exchange the host integrates the engine's state x = [y; ẏ]
 * (mbs_set_time, mbs_set_state, mbs_derivatives); there are no events.  The compiled scene is
 * read from <fmuResourceLocation>/scene.bin at instantiation; the only globals are the registries of the live
 * instances and FMU states (pointers from the host are looked up there, never followed blindly), so any number
 * of instances (of one or several FMUs) can live in one process.
 *
 * Status mapping: the engine's codes are ordered like fmi2Status (OK, Warning, Discard, Error).  Calls in
 * the wrong phase or with bad arguments are refused with fmi2Error and change nothing (a failed step too: the
 * instance stays at its last good point); an error in initialization or a reset puts the instance into the
 * error phase (then only get, state, reset and free).
 *
 * Every message goes through the host's logger with the categories of the modelDescription
 * (logStatusWarning, logStatusDiscard, logStatusError, logStatusFatal, logAll).  Messages of status
 * warning and above are logged unless the host switched their category off (fmi2SetDebugLogging); logAll
 * (status OK) only with loggingOn.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi2_guard.h"
#include "fmi_common.h"
#include "fmu_files.h"
#include "mbs_engine.h"

/* phases and "allowed in" masks: fmi2_guard.h */
#define P_STATUS (I_CS | P_STEP | P_TERMINATED | P_ERROR)  /* FMI 2.0 co-simulation: after initialization */
#define P_STATES (I_ME | P_EVENT | P_CONT | P_TERMINATED | P_ERROR)  /* model exchange: states and derivatives */

typedef struct {
    MbsModel *model;
    MbsInstance *sim;
    fmi2CallbackFunctions cb;  /* a copy: the host need not keep its struct */
    char *name;
    int iface;                 /* I_CS or I_ME */
    int phase;
    MbsLogSwitches log_switches;  /* fmi_common.h */
    int logged;                /* the engine logged during the current call */
    int discarded;             /* the last fmi2DoStep was discarded: fmi2Terminated reads true (masters such as
                                  fmpy's simulate_fmu then end the run instead of retrying the same step forever) */
    double t_start;
    long refused_vr;           /* a parameter the host set before initialization and the engine refused */
    char refused[256];         /* (-1: none); its message fails fmi2ExitInitializationMode */
} Fmu;

/* the live instances and FMU states (MbsFmuState, fmi_common.h) this library handed out (fmi2_guard.h) */
static MbsRegistry instances, states;

/* ---- logging ---- */
static void emit(const fmi2CallbackFunctions *cb, const char *name, fmi2Status st, const char *msg) {
    if (cb && cb->logger)  /* the message is data, never a format string */
        cb->logger(cb->componentEnvironment, name ? name : "", st, mbs_fmi_category[st <= fmi2Fatal ? st : 0], "%s", msg);
}

static void logf_(Fmu *f, fmi2Status st, const char *fmt, ...) {
    char buf[1024];
    va_list ap;
    if (!mbs_log_wanted(&f->log_switches, (int)st))
        return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    emit(&f->cb, f->name, st, buf);
}

static void engine_log(void *env, int status, const char *message) {
    Fmu *f = (Fmu *)env;
    f->logged = 1;
    logf_(f, (fmi2Status)(status >= MBS_OK && status <= MBS_ERROR ? status : MBS_ERROR), "%s", message);
}

/* An engine return code as fmi2Status; the engine's message is logged unless the engine already did. */
static fmi2Status engine_status(Fmu *f, int rc, const char *what) {
    if (rc < MBS_OK || rc > MBS_ERROR)
        rc = MBS_ERROR;
    if (rc != MBS_OK && !f->logged)
        logf_(f, (fmi2Status)rc, "%s: %s", what, mbs_message(f->sim));
    return (fmi2Status)rc;
}

/* The call `fn` is allowed in the phases `mask`: otherwise fmi2Error with a message, nothing changes. */
static int allowed(Fmu *f, int mask, const char *fn) {
    char why[256];
    if (!mbs_reg_find(&instances, f)) {  /* no logger known: stderr */
        fprintf(stderr, "mbsfmu: %s: %s\n", fn, f ? "not a live instance of this FMU (freed, or another FMU's)" : "NULL component");
        return 0;
    }
    f->logged = 0;
    if (!mbs_phase_refuses(mask, f->phase, f->iface, fn, why, sizeof why))
        return 1;
    logf_(f, fmi2Error, "%s", why);
    return 0;
}
#define CHECK(mask, fn) Fmu *f = (Fmu *)c; if (!allowed(f, (mask), (fn))) return fmi2Error

static int bad_array(Fmu *f, const void *a, const void *b, size_t n, const char *fn) {
    if (n == 0 || (a && b))
        return 0;
    logf_(f, fmi2Error, "%s: NULL array for %lu values", fn, (unsigned long)n);
    return 1;
}

/* ---- common functions ---- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    char err[256];
    CHECK(P_ANY, "fmi2SetDebugLogging");
    if (mbs_log_set(&f->log_switches, loggingOn != fmi2False, nCategories, categories, err, sizeof err)) {
        logf_(f, fmi2Error, "fmi2SetDebugLogging: %s", err);
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    char path[4096], err[1024], msg[1200];
    const char *name = instanceName ? instanceName : "";
    MbsModel *model;
    Fmu *f;
    (void)visible;
    if (!functions || !functions->logger) {  /* no logger to tell: stderr (FMI 2.0 requires one) */
        fprintf(stderr, "mbsfmu: fmi2Instantiate: no callback functions or no logger\n");
        return NULL;
    }
    if (!functions->allocateMemory || !functions->freeMemory) {
        emit(functions, name, fmi2Error, "fmi2Instantiate: no allocateMemory/freeMemory callbacks");
        return NULL;
    }
    if (!instanceName || !*instanceName) {
        emit(functions, name, fmi2Error, "fmi2Instantiate: no instance name");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation && fmuType != fmi2ModelExchange) {
        emit(functions, name, fmi2Error, "fmi2Instantiate: fmuType is neither fmi2ModelExchange nor fmi2CoSimulation");
        return NULL;
    }
    if (!fmuGUID) {
        emit(functions, name, fmi2Error, "fmi2Instantiate: no GUID given");
        return NULL;
    }
    if (mbs_resource_path(fmuResourceLocation, "scene.bin", path, sizeof path, err, sizeof err)) {
        snprintf(msg, sizeof msg, "fmi2Instantiate: %s", err);
        emit(functions, name, fmi2Error, msg);
        return NULL;
    }
    model = mbs_fmi_load_scene(path, fmuGUID, err, sizeof err);
    if (!model) {
        snprintf(msg, sizeof msg, "fmi2Instantiate: %s", err);
        emit(functions, name, fmi2Error, msg);
        return NULL;
    }
    f = (Fmu *)calloc(1, sizeof *f);
    if (f)
        f->name = (char *)malloc(strlen(name) + 1);
    if (!f || !f->name) {
        emit(functions, name, fmi2Error, "fmi2Instantiate: out of memory");
        free(f);
        mbs_model_free(model);
        return NULL;
    }
    strcpy(f->name, name);
    f->cb = *functions;
    f->model = model;
    f->iface = fmuType == fmi2ModelExchange ? I_ME : I_CS;
    f->phase = P_INSTANTIATED;
    f->refused_vr = -1;
    mbs_log_init(&f->log_switches, loggingOn != fmi2False);
    f->sim = mbs_instance_new(model, engine_log, f);
    if (!f->sim || !mbs_reg_add(&instances, f)) {
        mbs_instance_free(f->sim);
        emit(functions, name, fmi2Error, "fmi2Instantiate: cannot create the engine instance (out of memory?)");
        mbs_model_free(model);
        free(f->name);
        free(f);
        return NULL;
    }
    return f;
}

void fmi2FreeInstance(fmi2Component c) {
    Fmu *f = (Fmu *)c;
    if (!mbs_reg_drop(&instances, f)) {  /* NULL, freed before, or not ours: nothing to free */
        if (f)
            fprintf(stderr, "mbsfmu: fmi2FreeInstance: not a live instance of this FMU (freed, or another FMU's)\n");
        return;
    }
    mbs_fmu_states_free_owned(&states, f);  /* the states it handed out go with it */
    mbs_instance_free(f->sim);
    mbs_model_free(f->model);
    free(f->name);
    free(f);
}

/* ---- life cycle ---- */
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    CHECK(P_INSTANTIATED, "fmi2SetupExperiment");
    /* The tolerance is the parameter integrator.rtol (as in the pythonfmu kind); the stop time is not
     * needed: the integrator lands on every communication point. */
    if (!isfinite(startTime) || (toleranceDefined && !(isfinite(tolerance) && tolerance > 0)) ||
        (stopTimeDefined && !(isfinite(stopTime) && stopTime >= startTime))) {
        logf_(f, fmi2Error, "fmi2SetupExperiment: need a finite start time, a tolerance > 0 and a finite stop time "
              ">= start when defined (start %g, tolerance %g, stop %g)", startTime, toleranceDefined ? tolerance : 0.0,
              stopTimeDefined ? stopTime : startTime);
        return fmi2Error;
    }
    f->t_start = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CHECK(P_INSTANTIATED, "fmi2EnterInitializationMode");
    f->phase = P_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    fmi2Status st;
    CHECK(P_INIT, "fmi2ExitInitializationMode");
    if (f->refused_vr >= 0) {  /* the experiment the host asked for cannot run: no silent default */
        logf_(f, fmi2Error, "fmi2ExitInitializationMode: value reference %ld was refused: %s", f->refused_vr,
              f->refused);
        f->phase = P_ERROR;
        return fmi2Error;
    }
    st = engine_status(f, mbs_initialize(f->sim, f->t_start), "fmi2ExitInitializationMode");
    if (st >= fmi2Discard) {
        f->phase = P_ERROR;
        return fmi2Error;
    }
    f->phase = f->iface == I_ME ? P_EVENT : P_STEP;
    return st;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CHECK(P_RUNNING, "fmi2Terminate");
    f->phase = P_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    fmi2Status st;
    CHECK(P_ANY, "fmi2Reset");
    st = engine_status(f, mbs_reset(f->sim), "fmi2Reset");
    f->phase = st >= fmi2Discard ? P_ERROR : P_INSTANTIATED;
    f->t_start = 0.0;
    f->refused_vr = -1;
    f->discarded = 0;
    return st >= fmi2Discard ? fmi2Error : st;
}

/* ---- variables ---- */
static int vr_int(Fmu *f, fmi2ValueReference vr, const char *fn) {
    if (vr < (fmi2ValueReference)mbs_model_nvars(f->model))
        return (int)vr;
    logf_(f, fmi2Error, "%s: unknown value reference %u", fn, vr);
    return -1;
}

/* Remember a refused setting before initialization (fmi2ExitInitializationMode fails); a later accepted
 * setting of the same variable clears it. */
static fmi2Status setting(Fmu *f, int vr, int rc, const char *fn) {
    fmi2Status st = engine_status(f, rc, fn);
    if (f->phase & (P_INSTANTIATED | P_INIT)) {
        if (st >= fmi2Error) {
            f->refused_vr = vr;
            snprintf(f->refused, sizeof f->refused, "%s", mbs_message(f->sim));
        } else if (f->refused_vr == vr)
            f->refused_vr = -1;
    }
    return st >= fmi2Error ? fmi2Error : st;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    CHECK(P_ANY, "fmi2GetReal");
    if (bad_array(f, vr, value, nvr, "fmi2GetReal"))
        return fmi2Error;
    return mbs_get_reals(f->sim, vr, nvr, value) == MBS_OK ? fmi2OK : engine_status(f, MBS_ERROR, "fmi2GetReal");
}

/* All values at once (parameters that must change together: one call); on a refusal nothing is set. */
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    size_t i, bad = 0;
    int rc;
    CHECK(P_INSTANTIATED | P_INIT | P_RUNNING, "fmi2SetReal");
    if (bad_array(f, vr, value, nvr, "fmi2SetReal"))
        return fmi2Error;
    for (i = 0; i < nvr; i++) {
        int kind = vr_int(f, vr[i], "fmi2SetReal") < 0 ? -1 : mbs_model_var_kind(f->model, (int)vr[i]);
        if (kind < 0)
            return fmi2Error;
        if (f->phase == P_CONT && kind != MBS_V_QIN && kind != MBS_V_FIN) {  /* FMI 2.0, 3.2.3 */
            logf_(f, fmi2Error, "fmi2SetReal: %s is not an input: in continuous-time mode only inputs are set "
                  "(parameters in event mode)", mbs_model_var_name(f->model, (int)vr[i]));
            return fmi2Error;
        }
    }
    rc = mbs_set_reals(f->sim, vr, nvr, value, &bad);
    if (rc != MBS_OK)
        return setting(f, (int)vr[bad < nvr ? bad : 0], rc, "fmi2SetReal");
    for (i = 0; i < nvr; i++)
        setting(f, (int)vr[i], MBS_OK, "fmi2SetReal");
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    size_t i;
    CHECK(P_ANY, "fmi2GetString");
    if (bad_array(f, vr, value, nvr, "fmi2GetString"))
        return fmi2Error;
    for (i = 0; i < nvr; i++) {
        int r = vr_int(f, vr[i], "fmi2GetString");
        if (r < 0)
            return fmi2Error;
        if (mbs_get_string(f->sim, r, &value[i]) != MBS_OK)
            return engine_status(f, MBS_ERROR, "fmi2GetString");
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    size_t i;
    CHECK(P_INSTANTIATED | P_INIT | P_RUNNING, "fmi2SetString");
    if (bad_array(f, vr, value, nvr, "fmi2SetString"))
        return fmi2Error;
    for (i = 0; i < nvr; i++) {
        int r = vr_int(f, vr[i], "fmi2SetString");
        if (r < 0)
            return fmi2Error;
        if (!value[i]) {
            logf_(f, fmi2Error, "fmi2SetString: NULL string for value reference %u", vr[i]);
            return fmi2Error;
        }
        if (setting(f, r, mbs_set_string(f->sim, r, value[i]), "fmi2SetString") >= fmi2Error)
            return fmi2Error;
    }
    return fmi2OK;
}

/* The model has no Integer or Boolean variables. */
static fmi2Status no_such_type(fmi2Component c, size_t nvr, const char *fn) {
    CHECK(P_ANY, fn);
    if (nvr == 0)
        return fmi2OK;
    logf_(f, fmi2Error, "%s: this model has no variables of that type", fn);
    return fmi2Error;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    (void)vr, (void)value;
    return no_such_type(c, nvr, "fmi2GetInteger");
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[]) {
    (void)vr, (void)value;
    return no_such_type(c, nvr, "fmi2SetInteger");
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    (void)vr, (void)value;
    return no_such_type(c, nvr, "fmi2GetBoolean");
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[]) {
    (void)vr, (void)value;
    return no_such_type(c, nvr, "fmi2SetBoolean");
}

/* ---- FMU state: the engine's byte layout, in memory and serialized (fmi_common.c) ---- */
/* A state handed out by any live instance of this FMU (same model: it restores into any of them). */
static MbsFmuState *state_of(Fmu *f, fmi2FMUstate s, const char *fn) {
    if (mbs_reg_find(&states, s))
        return (MbsFmuState *)s;
    logf_(f, fmi2Error, "%s: not an FMU state of this FMU's live instances (never handed out, or freed)", fn);
    return NULL;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    MbsFmuState *st;
    CHECK(P_ANY, "fmi2GetFMUstate");
    if (!FMUstate) {
        logf_(f, fmi2Error, "fmi2GetFMUstate: NULL pointer");
        return fmi2Error;
    }
    st = (MbsFmuState *)*FMUstate;
    if (st && !state_of(f, st, "fmi2GetFMUstate"))
        return fmi2Error;
    if (!(st = mbs_fmu_state_sized(&states, st, f, mbs_state_size(f->sim)))) {
        logf_(f, fmi2Error, "fmi2GetFMUstate: out of memory");
        return fmi2Error;
    }
    *FMUstate = st;
    return engine_status(f, mbs_state_save(f->sim, st->bytes, st->len), "fmi2GetFMUstate");
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    MbsFmuState *st;
    CHECK(P_ANY, "fmi2SetFMUstate");
    if (!(st = state_of(f, FMUstate, "fmi2SetFMUstate")))
        return fmi2Error;
    if (mbs_state_load(f->sim, st->bytes, st->len) != MBS_OK) {
        engine_status(f, MBS_ERROR, "fmi2SetFMUstate (instance unchanged)");
        return fmi2Error;
    }
    f->discarded = 0;
    if (!mbs_initialized(f->sim))
        f->phase = P_INSTANTIATED;  /* a state from before: initialize again */
    else if (f->iface == I_CS)
        f->phase = P_STEP;
    else if (!(f->phase & (P_EVENT | P_CONT)))
        f->phase = P_EVENT;  /* model exchange: a host that restores while integrating goes on integrating */
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    MbsFmuState *st;
    CHECK(P_ANY, "fmi2FreeFMUstate");
    if (!FMUstate) {
        logf_(f, fmi2Error, "fmi2FreeFMUstate: NULL state pointer");
        return fmi2Error;
    }
    if (!*FMUstate)
        return fmi2OK;  /* FMI 2.0: freeing NULL is a no-op */
    if (!(st = state_of(f, *FMUstate, "fmi2FreeFMUstate")) || !mbs_reg_drop(&states, st))
        return fmi2Error;
    free(st);
    *FMUstate = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    MbsFmuState *st;
    CHECK(P_ANY, "fmi2SerializedFMUstateSize");
    if (!(st = state_of(f, FMUstate, "fmi2SerializedFMUstateSize")))
        return fmi2Error;
    if (!size) {
        logf_(f, fmi2Error, "fmi2SerializedFMUstateSize: NULL size pointer");
        return fmi2Error;
    }
    *size = st->len;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    MbsFmuState *st;
    CHECK(P_ANY, "fmi2SerializeFMUstate");
    if (!(st = state_of(f, FMUstate, "fmi2SerializeFMUstate")))
        return fmi2Error;
    if (!serializedState) {
        logf_(f, fmi2Error, "fmi2SerializeFMUstate: NULL buffer");
        return fmi2Error;
    }
    if (size < st->len) {
        logf_(f, fmi2Error, "fmi2SerializeFMUstate: buffer of %lu bytes for a state of %lu",
              (unsigned long)size, (unsigned long)st->len);
        return fmi2Error;
    }
    memcpy(serializedState, st->bytes, st->len);
    return fmi2OK;
}

/* Only bytes that load into this instance (mbs_fmu_state_check: its own state restored afterwards) are copied
 * into a new state. */
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    MbsFmuState *st;
    int rc;
    CHECK(P_ANY, "fmi2DeSerializeFMUstate");
    if (!FMUstate || !serializedState) {
        logf_(f, fmi2Error, "fmi2DeSerializeFMUstate: NULL pointer");
        return fmi2Error;
    }
    rc = mbs_fmu_state_check(f->sim, serializedState, size);
    if (rc == -1) {
        f->phase = P_FATAL;
        logf_(f, fmi2Fatal, "fmi2DeSerializeFMUstate: the instance's own state did not load back: %s",
              mbs_message(f->sim));
        return fmi2Fatal;
    }
    if (rc != MBS_OK) {
        if (rc == -2)
            logf_(f, fmi2Error, "fmi2DeSerializeFMUstate: out of memory");
        else
            engine_status(f, MBS_ERROR, "fmi2DeSerializeFMUstate");
        return fmi2Error;
    }
    if (!(st = mbs_fmu_state_copy(&states, f, serializedState, size))) {
        logf_(f, fmi2Error, "fmi2DeSerializeFMUstate: out of memory");
        return fmi2Error;
    }
    *FMUstate = st;  /* an output argument: whatever it held is not ours to free */
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    CHECK(P_ANY, "fmi2GetDirectionalDerivative");
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    logf_(f, fmi2Error, "fmi2GetDirectionalDerivative: not provided (providesDirectionalDerivative=false)");
    return fmi2Error;
}

/* ---- co-simulation ---- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    CHECK(P_ANY, "fmi2SetRealInputDerivatives");
    (void)vr, (void)nvr, (void)order, (void)value;
    logf_(f, fmi2Error, "fmi2SetRealInputDerivatives: inputs are held over a step (canInterpolateInputs=false)");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    CHECK(P_ANY, "fmi2GetRealOutputDerivatives");
    (void)vr, (void)nvr, (void)order, (void)value;
    logf_(f, fmi2Error, "fmi2GetRealOutputDerivatives: not provided (maxOutputDerivativeOrder=0)");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    fmi2Status st;
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(I_CS | P_STEP, "fmi2DoStep");
    if (!isfinite(currentCommunicationPoint) || !isfinite(communicationStepSize) || communicationStepSize <= 0 ||
        currentCommunicationPoint + communicationStepSize == currentCommunicationPoint) {
        logf_(f, fmi2Error, "fmi2DoStep: bad step t=%g, h=%g (need finite t and h > 0 that advances t)",
              currentCommunicationPoint, communicationStepSize);
        return fmi2Error;
    }
    /* a refused or failed step leaves the instance at its last good point: the phase stays */
    st = engine_status(f, mbs_do_step(f->sim, currentCommunicationPoint, communicationStepSize), "fmi2DoStep");
    if (st != fmi2Error)
        f->discarded = st == fmi2Discard;
    return st;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    CHECK(P_ANY, "fmi2CancelStep");
    logf_(f, fmi2Error, "fmi2CancelStep: not supported: fmi2DoStep is synchronous (canRunAsynchronuously=false)");
    return fmi2Error;
}

/* Status queries (FMI 2.0, 4.2.3): what is not available is fmi2Discard, with a message; a NULL output pointer
 * is fmi2Error. The pythonfmu kind's loader shim answers the same. */
static int status_refused(Fmu *f, const void *value, const char *fn) {
    if (value)
        return 0;
    logf_(f, fmi2Error, "%s: NULL value pointer", fn);
    return 1;
}
static fmi2Status not_available(Fmu *f, const char *fn, int kind) {
    logf_(f, fmi2Discard, "%s: status kind %d is not available from this FMU", fn, kind);
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    CHECK(P_STATUS, "fmi2GetStatus");
    if (status_refused(f, value, "fmi2GetStatus"))
        return fmi2Error;
    return not_available(f, "fmi2GetStatus", s);  /* fmi2DoStepStatus: only after fmi2Pending, never returned */
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    CHECK(P_STATUS, "fmi2GetRealStatus");
    if (status_refused(f, value, "fmi2GetRealStatus"))
        return fmi2Error;
    if (s != fmi2LastSuccessfulTime)
        return not_available(f, "fmi2GetRealStatus", s);
    *value = mbs_time(f->sim);
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    CHECK(P_STATUS, "fmi2GetIntegerStatus");
    if (status_refused(f, value, "fmi2GetIntegerStatus"))
        return fmi2Error;
    return not_available(f, "fmi2GetIntegerStatus", s);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    CHECK(P_STATUS, "fmi2GetBooleanStatus");
    if (status_refused(f, value, "fmi2GetBooleanStatus"))
        return fmi2Error;
    if (s != fmi2Terminated)
        return not_available(f, "fmi2GetBooleanStatus", s);
    *value = f->discarded ? fmi2True : fmi2False;  /* after a discarded step, until a good step, reset or restore */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    CHECK(P_STATUS, "fmi2GetStringStatus");
    if (status_refused(f, value, "fmi2GetStringStatus"))
        return fmi2Error;
    return not_available(f, "fmi2GetStringStatus", s);
}


/* ---- model exchange (FMI 2.0, chapter 3): the host integrates x = [y; ẏ]; no event indicators, no time
 * events, nothing to do at a completed integrator step (quaternions: docs/fmu.md, "Model exchange") ---- */
static size_t nstates(Fmu *f) { return (size_t)mbs_model_npos(f->model) + (size_t)mbs_model_nvel(f->model); }

/* nx is not the number of continuous states, or the array is missing */
static int bad_count(Fmu *f, const void *a, size_t nx, const char *fn) {
    if (nx == nstates(f))
        return bad_array(f, a, a, nx, fn);
    logf_(f, fmi2Error, "%s: nx = %lu, but the model has %lu continuous states", fn, (unsigned long)nx,
          (unsigned long)nstates(f));
    return 1;
}

/* as bad_count, or there are no states yet (not initialized) */
static int bad_states(Fmu *f, const void *a, size_t nx, const char *fn) {
    if (bad_count(f, a, nx, fn))
        return 1;
    if (!mbs_initialized(f->sim)) {
        logf_(f, fmi2Error, "%s: the instance is not initialized", fn);
        return 1;
    }
    return 0;
}

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    CHECK(I_ME | P_EVENT | P_CONT, "fmi2EnterEventMode");
    f->phase = P_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    CHECK(I_ME | P_EVENT, "fmi2NewDiscreteStates");
    if (!info) {
        logf_(f, fmi2Error, "fmi2NewDiscreteStates: NULL event info");
        return fmi2Error;
    }
    info->newDiscreteStatesNeeded = fmi2False;  /* no discrete states, no events: nothing changes */
    info->terminateSimulation = fmi2False;
    info->nominalsOfContinuousStatesChanged = fmi2False;
    info->valuesOfContinuousStatesChanged = fmi2False;
    info->nextEventTimeDefined = fmi2False;
    info->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    CHECK(I_ME | P_EVENT, "fmi2EnterContinuousTimeMode");
    f->phase = P_CONT;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(I_ME | P_CONT, "fmi2CompletedIntegratorStep");
    if (!enterEventMode || !terminateSimulation) {
        logf_(f, fmi2Error, "fmi2CompletedIntegratorStep: NULL output pointer");
        return fmi2Error;
    }
    *enterEventMode = fmi2False;  /* no step events; the states are the host's (quaternions are not normalized) */
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    CHECK(I_ME | P_EVENT | P_CONT, "fmi2SetTime");
    return engine_status(f, mbs_set_time(f->sim, time), "fmi2SetTime") == fmi2OK ? fmi2OK : fmi2Error;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    CHECK(I_ME | P_CONT, "fmi2SetContinuousStates");
    if (bad_states(f, x, nx, "fmi2SetContinuousStates"))
        return fmi2Error;
    return engine_status(f, mbs_set_state(f->sim, x, nx), "fmi2SetContinuousStates") == fmi2OK ? fmi2OK : fmi2Error;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    CHECK(P_STATES, "fmi2GetDerivatives");
    if (bad_states(f, derivatives, nx, "fmi2GetDerivatives"))
        return fmi2Error;
    /* fmi2Discard where ẋ is not defined (singular mass matrix): the host may retry with a smaller step */
    return engine_status(f, mbs_derivatives(f->sim, derivatives, nx), "fmi2GetDerivatives");
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    CHECK(P_STATES | P_INIT, "fmi2GetEventIndicators");
    (void)eventIndicators;
    if (ni == 0)
        return fmi2OK;
    logf_(f, fmi2Error, "fmi2GetEventIndicators: ni = %lu, but the model has no event indicators", (unsigned long)ni);
    return fmi2Error;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    CHECK(P_STATES, "fmi2GetContinuousStates");
    if (bad_states(f, x, nx, "fmi2GetContinuousStates"))
        return fmi2Error;
    memcpy(x, mbs_state(f->sim), nx * sizeof *x);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    size_t i;
    CHECK(P_STATES | P_INSTANTIATED | P_INIT, "fmi2GetNominalsOfContinuousStates");
    if (bad_count(f, x_nominal, nx, "fmi2GetNominalsOfContinuousStates"))
        return fmi2Error;
    for (i = 0; i < nx; i++)
        x_nominal[i] = 1.0;  /* coordinates of order one (m, rad, modal coordinates): the FMI default */
    return fmi2OK;
}
