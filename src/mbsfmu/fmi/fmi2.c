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
 * The bodies of the calls are the version-independent core (fmi_calls.c, shared with fmi3.c): this file converts
 * arguments, checks phases and keeps what FMI 2.0 alone has (the callbacks, fmi2Terminated after a discard).
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
#include "call_guard.h"
#include "fmi_calls.h"
#include "fmu_files.h"
#include "mbs_engine.h"

/* phases and "allowed in" masks: call_guard.h */
#define P_STATUS (I_CS | P_STEP | P_TERMINATED | P_ERROR)  /* FMI 2.0 co-simulation: after initialization */
#define P_STATES (I_ME | P_EVENT | P_CONT | P_TERMINATED | P_ERROR)  /* model exchange: states and derivatives */

/* the version-independent part first (fmi_calls.h: the core functions take it) */
typedef struct {
    MbsFmiHead h;
    fmi2CallbackFunctions cb;  /* a copy: the host need not keep its struct */
    int discarded;             /* the last fmi2DoStep was discarded: fmi2Terminated reads true (masters such as
                                  fmpy's simulate_fmu then end the run instead of retrying the same step forever) */
} Fmu;
MBS_FMI_SAME_STATUS(fmi2_status_is_core_status, fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal);

/* the live instances and FMU states (MbsFmuState, fmi_services.h) this library handed out (call_guard.h) */
static MbsRegistry instances, states;

/* ---- logging ---- */
static void emit(const fmi2CallbackFunctions *cb, const char *name, fmi2Status st, const char *msg) {
    if (cb && cb->logger)  /* the message is data, never a format string */
        cb->logger(cb->componentEnvironment, name ? name : "", st, mbs_fmi_category[st <= fmi2Fatal ? st : 0], "%s", msg);
}

static void emit_head(const MbsFmiHead *h, int st, const char *category, const char *msg) {
    const fmi2CallbackFunctions *cb = &((const Fmu *)h)->cb;
    cb->logger(cb->componentEnvironment, h->name, (fmi2Status)st, category, "%s", msg);
}

#define engine_status(f, rc, what) ((fmi2Status)mbs_fmi_status((f), (rc), (what)))
#define CORE(call) return (fmi2Status)(call)
/* The call `fn` is allowed in the phases `mask`: otherwise fmi2Error with a message, nothing changes. */
#define CHECK(mask, fn)                                                                                       \
    MbsFmiHead *f = (MbsFmiHead *)c;                                                                          \
    if (!mbs_fmi_allowed(&instances, f, (mask), (fn), "NULL component"))                                      \
        return fmi2Error
#define discarded(f) (((Fmu *)(f))->discarded)

/* ---- common functions ---- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    CHECK(P_ANY, "fmi2SetDebugLogging");
    CORE(mbs_fmi_set_debug_logging(f, loggingOn != fmi2False, nCategories, categories, "fmi2SetDebugLogging"));
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
    if (!(f = (Fmu *)mbs_fmi_alloc(sizeof *f, name))) {
        emit(functions, name, fmi2Error, "fmi2Instantiate: out of memory");
        mbs_model_free(model);
        return NULL;
    }
    f->cb = *functions;
    f->h.emit = emit_head;
    if (!mbs_fmi_start(&f->h, &instances, &states, model, fmuType == fmi2ModelExchange ? I_ME : I_CS,
                       loggingOn != fmi2False)) {
        emit(functions, name, fmi2Error, "fmi2Instantiate: cannot create the engine instance (out of memory?)");
        return NULL;
    }
    return f;
}

void fmi2FreeInstance(fmi2Component c) {
    mbs_fmi_free_instance(&instances, (MbsFmiHead *)c, "fmi2FreeInstance");
}

/* ---- life cycle ---- */
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    CHECK(P_INSTANTIATED, "fmi2SetupExperiment");
    CORE(mbs_fmi_setup(f, toleranceDefined, tolerance, startTime, stopTimeDefined, stopTime, "fmi2SetupExperiment"));
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CHECK(P_INSTANTIATED, "fmi2EnterInitializationMode");
    f->phase = P_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    CHECK(P_INIT, "fmi2ExitInitializationMode");
    CORE(mbs_fmi_exit_init(f, "fmi2ExitInitializationMode"));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CHECK(P_RUNNING, "fmi2Terminate");
    f->phase = P_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    CHECK(P_ANY, "fmi2Reset");
    discarded(f) = 0;
    CORE(mbs_fmi_reset(f, "fmi2Reset"));
}

/* ---- variables ---- */
#define UNKNOWN_VR "%s: unknown value reference %u"  /* (fn, vr): mbs_fmi_vr */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    CHECK(P_ANY, "fmi2GetReal");
    if (mbs_fmi_bad_array(f, vr, value, nvr, "fmi2GetReal"))
        return fmi2Error;
    return mbs_get_reals(f->sim, vr, nvr, value) == MBS_OK ? fmi2OK : engine_status(f, MBS_ERROR, "fmi2GetReal");
}

/* All values at once (parameters that must change together: one call); on a refusal nothing is set. */
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    size_t i;
    CHECK(P_INSTANTIATED | P_INIT | P_RUNNING, "fmi2SetReal");
    if (mbs_fmi_bad_array(f, vr, value, nvr, "fmi2SetReal"))
        return fmi2Error;
    for (i = 0; i < nvr; i++) {
        int kind = mbs_fmi_vr(f, vr[i], UNKNOWN_VR, "fmi2SetReal");
        if (kind >= 0)
            kind = mbs_model_var_kind(f->model, (int)vr[i]);
        if (kind < 0)
            return fmi2Error;
        if (f->phase == P_CONT && kind != MBS_V_QIN && kind != MBS_V_FIN) {  /* FMI 2.0, 3.2.3 */
            mbs_fmi_logf(f, fmi2Error, "fmi2SetReal: %s is not an input: in continuous-time mode only inputs are set "
                  "(parameters in event mode)", mbs_model_var_name(f->model, (int)vr[i]));
            return fmi2Error;
        }
    }
    CORE(mbs_fmi_set_reals(f, vr, nvr, value, "fmi2SetReal"));
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    CHECK(P_ANY, "fmi2GetString");
    if (mbs_fmi_bad_array(f, vr, value, nvr, "fmi2GetString"))
        return fmi2Error;
    CORE(mbs_fmi_get_strings(f, vr, nvr, value, UNKNOWN_VR, "fmi2GetString"));
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    CHECK(P_INSTANTIATED | P_INIT | P_RUNNING, "fmi2SetString");
    if (mbs_fmi_bad_array(f, vr, value, nvr, "fmi2SetString"))
        return fmi2Error;
    CORE(mbs_fmi_set_strings(f, vr, nvr, value, UNKNOWN_VR, "fmi2SetString"));
}

/* The model has no Integer or Boolean variables. */
static fmi2Status no_such_type(fmi2Component c, size_t nvr, const char *fn) {
    CHECK(P_ANY, fn);
    CORE(mbs_fmi_no_such_type(f, nvr, "", fn));
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

/* ---- FMU state: the engine's byte layout, in memory and serialized (fmi_services.c) ---- */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    CHECK(P_ANY, "fmi2GetFMUstate");
    CORE(mbs_fmi_get_state(f, FMUstate, "fmi2GetFMUstate"));
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    fmi2Status st;
    CHECK(P_ANY, "fmi2SetFMUstate");
    if ((st = (fmi2Status)mbs_fmi_set_state(f, FMUstate, "fmi2SetFMUstate")) == fmi2OK)
        discarded(f) = 0;
    return st;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    CHECK(P_ANY, "fmi2FreeFMUstate");
    CORE(mbs_fmi_free_state(f, FMUstate, "fmi2FreeFMUstate"));
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    CHECK(P_ANY, "fmi2SerializedFMUstateSize");
    CORE(mbs_fmi_state_size(f, FMUstate, size, "fmi2SerializedFMUstateSize"));
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size) {
    CHECK(P_ANY, "fmi2SerializeFMUstate");
    CORE(mbs_fmi_serialize(f, FMUstate, serializedState, size, "fmi2SerializeFMUstate"));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    CHECK(P_ANY, "fmi2DeSerializeFMUstate");
    CORE(mbs_fmi_deserialize(f, serializedState, size, FMUstate, "fmi2DeSerializeFMUstate"));
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    /* the engine's: knowns are states and inputs, unknowns derivatives, outputs and states (mbs_engine.h) */
    CHECK(P_INIT | P_RUNNING | P_TERMINATED | P_ERROR, "fmi2GetDirectionalDerivative");
    return engine_status(f, mbs_directional_derivative(f->sim, vUnknown_ref, nUnknown, vKnown_ref, nKnown, dvKnown,
                                                       dvUnknown), "fmi2GetDirectionalDerivative");
}

/* ---- co-simulation ---- */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    CHECK(P_ANY, "fmi2SetRealInputDerivatives");
    (void)vr, (void)nvr, (void)order, (void)value;
    mbs_fmi_logf(f, fmi2Error, "fmi2SetRealInputDerivatives: inputs are held over a step (canInterpolateInputs=false)");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    CHECK(P_ANY, "fmi2GetRealOutputDerivatives");
    (void)vr, (void)nvr, (void)order, (void)value;
    mbs_fmi_logf(f, fmi2Error, "fmi2GetRealOutputDerivatives: not provided (maxOutputDerivativeOrder=0)");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    fmi2Status st;
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(I_CS | P_STEP, "fmi2DoStep");
    if (mbs_fmi_bad_step(f, currentCommunicationPoint, communicationStepSize, "fmi2DoStep"))
        return fmi2Error;
    /* a refused or failed step leaves the instance at its last good point: the phase stays */
    st = engine_status(f, mbs_do_step(f->sim, currentCommunicationPoint, communicationStepSize), "fmi2DoStep");
    if (st != fmi2Error)
        discarded(f) = st == fmi2Discard;
    return st;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    CHECK(P_ANY, "fmi2CancelStep");
    mbs_fmi_logf(f, fmi2Error, "fmi2CancelStep: not supported: fmi2DoStep is synchronous (canRunAsynchronuously=false)");
    return fmi2Error;
}

/* Status queries (FMI 2.0, 4.2.3): what is not available is fmi2Discard, with a message; a NULL output pointer
 * is fmi2Error. The pythonfmu kind's loader shim answers the same. */
static int status_refused(MbsFmiHead *f, const void *value, const char *fn) {
    if (value)
        return 0;
    mbs_fmi_logf(f, fmi2Error, "%s: NULL value pointer", fn);
    return 1;
}
static fmi2Status not_available(MbsFmiHead *f, const char *fn, int kind) {
    mbs_fmi_logf(f, fmi2Discard, "%s: status kind %d is not available from this FMU", fn, kind);
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
    *value = discarded(f) ? fmi2True : fmi2False;  /* after a discarded step, until a good step, reset or restore */
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

/* nx is not the number of continuous states, or the array is missing */
static int bad_count(MbsFmiHead *f, const void *a, size_t nx, const char *fn) {
    if (nx == mbs_fmi_nstates(f))
        return mbs_fmi_bad_array(f, a, a, nx, fn);
    mbs_fmi_logf(f, fmi2Error, "%s: nx = %lu, but the model has %lu continuous states", fn, (unsigned long)nx,
          (unsigned long)mbs_fmi_nstates(f));
    return 1;
}

/* as bad_count, or there are no states yet (not initialized) */
static int bad_states(MbsFmiHead *f, const void *a, size_t nx, const char *fn) {
    if (bad_count(f, a, nx, fn))
        return 1;
    if (!mbs_initialized(f->sim)) {
        mbs_fmi_logf(f, fmi2Error, "%s: the instance is not initialized", fn);
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
        mbs_fmi_logf(f, fmi2Error, "fmi2NewDiscreteStates: NULL event info");
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
        mbs_fmi_logf(f, fmi2Error, "fmi2CompletedIntegratorStep: NULL output pointer");
        return fmi2Error;
    }
    *enterEventMode = fmi2False;  /* no step events; the states are the host's (quaternions are not normalized) */
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    CHECK(I_ME | P_EVENT | P_CONT, "fmi2SetTime");
    CORE(mbs_fmi_ok_or_error(f, mbs_set_time(f->sim, time), "fmi2SetTime"));
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    CHECK(I_ME | P_CONT, "fmi2SetContinuousStates");
    if (bad_states(f, x, nx, "fmi2SetContinuousStates"))
        return fmi2Error;
    CORE(mbs_fmi_ok_or_error(f, mbs_set_state(f->sim, x, nx), "fmi2SetContinuousStates"));
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
    mbs_fmi_logf(f, fmi2Error, "fmi2GetEventIndicators: ni = %lu, but the model has no event indicators", (unsigned long)ni);
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
    CHECK(P_STATES | P_INSTANTIATED | P_INIT, "fmi2GetNominalsOfContinuousStates");
    if (bad_count(f, x_nominal, nx, "fmi2GetNominalsOfContinuousStates"))
        return fmi2Error;
    memcpy(x_nominal, mbs_nominals(f->sim), nx * sizeof *x_nominal);  /* fixed at build (the scene's sizes) */
    return fmi2OK;
}
