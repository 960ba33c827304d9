/* FMI 3.0 layer over the mbsfmu engine (native FMUs, `mbsfmu build --kind native --fmi 3`): Co-Simulation and
 * Model Exchange, the counterpart of fmi2.c over the same engine API.
 *
 * One fmi3Instance = one engine instance plus the FMI bookkeeping: the host's environment and logger, the
 * instance name, the interface (co-simulation or model exchange), the phase of its FMI 3.0 state machine and
 * the logging switches. The compiled scene is read from <resourcePath>scene.bin at instantiation. What does not
 * depend on the FMI version is shared with fmi2.c: the phases, the "allowed in" check and the registries of live
 * instances and FMU states (call_guard.c), the logging switches, loading the scene and FMU state bytes
 * (fmi_services.c) and the bodies of the calls (fmi_calls.c: this file converts arguments and checks phases).
 *
 * Variables: FMI 3.0's (mbs_model_var3: runs of rows of the engine's variable table as arrays, every other row a
 * scalar; compiler/variables.py: fmi3_variables numbers them for the modelDescription), Float64 arrays and scalars and
 * String scalars, plus the independent variable `time` after the last one (value reference = their count).
 * Values of arrays are flat, row after row. Co-simulation without event mode or early return; with an
 * intermediateUpdate callback given at instantiation, fmi3DoStep calls it after every accepted internal step of the
 * engine's integrator and at the step's end (the engine's step observer, mbs_set_step_observer), in intermediate
 * update mode (P_UPDATE): fmi3GetFloat64 of the outputs (intermediateUpdate="true" in the modelDescription) and
 * of time reads that point, every other call gets fmi3Error.
 * Model exchange: the continuous states are the engine's [y; ẏ] (quaternions as the engine keeps them: the host
 * integrates their four components, nothing renormalizes them); no event indicators, no time events.
 *
 * Status mapping and messages as in fmi2.c: calls in the wrong phase or with bad arguments get fmi3Error and
 * change nothing, a failed step or evaluation fmi3Discard, every message through the host's logger with the
 * modelDescription's categories (logStatusWarning .. logStatusFatal, logAll).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "fmi_calls.h"
#include "fmu_files.h"
#include "mbs_engine.h"

/* phases and "allowed in" masks (call_guard.h: the FMI state machines' phases are the same in 3.0) */
#define P_SET (P_INSTANTIATED | P_INIT | P_RUNNING)                /* inputs and parameters may be set */
#define P_STATES (I_ME | P_EVENT | P_CONT | P_TERMINATED | P_ERROR) /* model exchange: the host's states exist */

/* the version-independent part first (fmi_calls.h: the core functions take it) */
typedef struct {
    MbsFmiHead h;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    fmi3IntermediateUpdateCallback intermediate_update;  /* the host's, or NULL */
    size_t nrows;              /* the rows of the engine's variable table: room in rows[] */
    unsigned rows[];           /* the rows of the variables of one call (expand) */
} Fmu;
MBS_FMI_SAME_STATUS(fmi3_status_is_core_status, fmi3OK, fmi3Warning, fmi3Discard, fmi3Error, fmi3Fatal);

/* the live instances and FMU states (MbsFmuState, fmi_services.h) this library handed out (call_guard.h) */
static MbsRegistry instances, states;

/* ---- logging ---- */
static void emit(fmi3LogMessageCallback log, fmi3InstanceEnvironment env, fmi3Status st, const char *msg) {
    if (log)
        log(env, st, mbs_fmi_category[st <= fmi3Fatal ? st : 0], msg);
}

static void emit_head(const MbsFmiHead *h, int st, const char *category, const char *msg) {
    ((const Fmu *)h)->log(((const Fmu *)h)->env, (fmi3Status)st, category, msg);
}

#define engine_status(f, rc, what) ((fmi3Status)mbs_fmi_status((f), (rc), (what)))
#define CORE(call) return (fmi3Status)(call)
/* The call `fn` is allowed in the phases `mask`: otherwise fmi3Error with a message, nothing changes. */
#define CHECK(mask, fn)                                                                                       \
    MbsFmiHead *f = (MbsFmiHead *)instance;                                                                   \
    if (!mbs_fmi_allowed(&instances, f, (mask), (fn), "NULL instance"))                                       \
        return fmi3Error

static fmi3ValueReference time_vr(const MbsFmiHead *f) { return (fmi3ValueReference)mbs_model_nvars3(f->model); }

/* The rows of the variables vr[0..n) (the independent variable: none) into ((Fmu *)f)->rows from `at` on, in order;
 * their number, and *nvalues (if given) the values they hold (time one). -1 with a message: an unknown value
 * reference, or more rows than there is room for (a variable asked for many times over). */
static long expand(MbsFmiHead *f, const fmi3ValueReference vr[], size_t n, size_t at, size_t *nvalues, const char *fn) {
    Fmu *u = (Fmu *)f;
    size_t i, k = at;
    int first, rows, r;
    if (nvalues)
        *nvalues = 0;
    for (i = 0; i < n; i++) {
        if (vr[i] == time_vr(f)) {
            if (nvalues)
                ++*nvalues;
            continue;
        }
        if ((first = mbs_model_var3(f->model, vr[i], &rows)) < 0) {
            mbs_fmi_logf(f, fmi3Error, "%s: unknown value reference %u", fn, vr[i]);
            return -1;
        }
        if (k + (size_t)rows > u->nrows) {
            mbs_fmi_logf(f, fmi3Error, "%s: %lu value references ask for more values than the FMU has variables",
                         fn, (unsigned long)n);
            return -1;
        }
        for (r = 0; r < rows; r++)
            u->rows[k++] = (unsigned)(first + r);
        if (nvalues)
            *nvalues += (size_t)rows;
    }
    return (long)(k - at);
}

/* As many values as the variables hold (an array all its elements). */
static int bad_count(MbsFmiHead *f, size_t nvalues, size_t want, const char *fn) {
    if (nvalues == want)
        return 0;
    mbs_fmi_logf(f, fmi3Error, "%s: %lu values given for variables that hold %lu", fn, (unsigned long)nvalues,
                 (unsigned long)want);
    return 1;
}

/* ---- common functions ---- */
const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    CHECK(P_ANY | P_UPDATE, "fmi3SetDebugLogging");
    CORE(mbs_fmi_set_debug_logging(f, loggingOn != fmi3False, nCategories, categories, "fmi3SetDebugLogging"));
}

/* <resourcePath>scene.bin: FMI 3.0 gives an absolute path ending in a separator (a file: URI, as FMI 2.0
 * gave, is accepted too). 0, or 1 with the reason in err. */
static int scene_path(const char *resources, char *out, size_t n, char *err, size_t errlen) {
    size_t len;
    int absolute;
    if (!resources || !*resources) {
        snprintf(err, errlen, "no resource path given (the FMU's resources folder holds scene.bin)");
        return 1;
    }
    if (strncmp(resources, "file:", 5) == 0)
        return mbs_resource_path(resources, "scene.bin", out, n, err, errlen);
    len = strlen(resources);
    absolute = resources[0] == '/' || resources[0] == '\\' ||
               (len > 2 && resources[1] == ':' && (resources[2] == '\\' || resources[2] == '/'));
    if (!absolute) {
        snprintf(err, errlen, "resource path '%.200s' is not absolute", resources);
        return 1;
    }
    if ((size_t)snprintf(out, n, "%s%sscene.bin", resources,
                         resources[len - 1] == '/' || resources[len - 1] == '\\' ? "" : "/") >= n) {
        snprintf(err, errlen, "resource path too long (%lu characters)", (unsigned long)len);
        return 1;
    }
    return 0;
}

static fmi3Instance instantiate(const char *fn, int iface, fmi3String instanceName, fmi3String token,
                                fmi3String resourcePath, fmi3Boolean loggingOn, fmi3InstanceEnvironment env,
                                fmi3LogMessageCallback log) {
    char path[4096], err[1024], msg[1200];
    MbsModel *model;
    Fmu *f;
    if (!log) {  /* nobody to tell: stderr (FMI 3.0 allows no logger, this FMU wants one for its messages) */
        fprintf(stderr, "mbsfmu: %s: no logMessage callback\n", fn);
        return NULL;
    }
    if (!instanceName || !*instanceName) {
        snprintf(msg, sizeof msg, "%s: no instance name", fn);
        emit(log, env, fmi3Error, msg);
        return NULL;
    }
    if (!token) {
        snprintf(msg, sizeof msg, "%s: no instantiationToken given", fn);
        emit(log, env, fmi3Error, msg);
        return NULL;
    }
    if (scene_path(resourcePath, path, sizeof path, err, sizeof err) ||
        !(model = mbs_fmi_load_scene(path, token, err, sizeof err))) {
        snprintf(msg, sizeof msg, "%s: %s", fn, err);
        emit(log, env, fmi3Error, msg);
        return NULL;
    }
    if (!(f = (Fmu *)mbs_fmi_alloc(sizeof *f + 2 * (size_t)mbs_model_nvars(model) * sizeof f->rows[0], instanceName))) {
        snprintf(msg, sizeof msg, "%s: out of memory", fn);
        emit(log, env, fmi3Error, msg);
        mbs_model_free(model);
        return NULL;
    }
    f->env = env;
    f->log = log;
    f->nrows = 2 * (size_t)mbs_model_nvars(model);  /* a directional derivative's knowns and unknowns */
    f->h.emit = emit_head;
    if (!mbs_fmi_start(&f->h, &instances, &states, model, iface, loggingOn != fmi3False)) {
        snprintf(msg, sizeof msg, "%s: cannot create the engine instance (out of memory?)", fn);
        emit(log, env, fmi3Error, msg);
        return NULL;
    }
    return f;
}

/* The engine's step observer: the host's intermediateUpdate at the internal point t (the engine shows it), in
 * intermediate update mode. Only reading: no inputs set, the point is an accepted step, no early return. */
static void intermediate_update(void *env, double t, const double *x) {
    Fmu *u = (Fmu *)env;
    fmi3Boolean early = fmi3False;
    fmi3Float64 early_time = t;
    int phase = u->h.phase;
    (void)x;
    u->h.phase = P_UPDATE;
    u->intermediate_update(u->env, t, fmi3False, fmi3True, fmi3True, fmi3False, &early, &early_time);
    u->h.phase = phase;
}

/* Readable in intermediate update mode: the variables marked intermediateUpdate="true" (fmu/common.py: the
 * outputs, functions of the internal point (t, x)) and time. */
static int intermediate(const MbsFmiHead *f, fmi3ValueReference vr) {
    int rows, first = mbs_model_var3(f->model, vr, &rows), kind = first < 0 ? -1 : mbs_model_var_kind(f->model, first);
    return vr == time_vr(f) || kind == MBS_V_Y || kind == MBS_V_YD || kind == MBS_V_OUT || kind == MBS_V_VM;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    /* hasEventMode and early return are false: the FMU never uses them, whatever the host could handle. Every
     * intermediate variable may be read in the callback, whichever the host named. */
    Fmu *f;
    (void)visible, (void)eventModeUsed, (void)earlyReturnAllowed, (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    f = (Fmu *)instantiate("fmi3InstantiateCoSimulation", I_CS, instanceName, instantiationToken, resourcePath,
                           loggingOn, instanceEnvironment, logMessage);
    if (f && intermediateUpdate) {
        f->intermediate_update = intermediateUpdate;
        mbs_set_step_observer(f->h.sim, intermediate_update, f);
    }
    return f;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)visible;
    return instantiate("fmi3InstantiateModelExchange", I_ME, instanceName, instantiationToken, resourcePath, loggingOn,
                       instanceEnvironment, logMessage);
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName, (void)instantiationToken, (void)resourcePath, (void)visible, (void)loggingOn;
    (void)clockUpdate, (void)lockPreemption, (void)unlockPreemption;
    emit(logMessage, instanceEnvironment, fmi3Error,
         "fmi3InstantiateScheduledExecution: this FMU offers co-simulation and model exchange only");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) {
    MbsFmiHead *f = (MbsFmiHead *)instance;
    if (mbs_reg_find(&instances, f) && f->phase == P_UPDATE) {  /* the step in progress holds it */
        mbs_fmi_logf(f, fmi3Error, "fmi3FreeInstance: not allowed in intermediate update mode (inside the "
                     "intermediateUpdate callback); the instance stays");
        return;
    }
    mbs_fmi_free_instance(&instances, (MbsFmiHead *)instance, "fmi3FreeInstance");
}

/* ---- life cycle ---- */
fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    fmi3Status st;
    CHECK(P_INSTANTIATED, "fmi3EnterInitializationMode");
    st = (fmi3Status)mbs_fmi_setup(f, toleranceDefined, tolerance, startTime, stopTimeDefined, stopTime,
                                   "fmi3EnterInitializationMode");
    if (st == fmi3OK)
        f->phase = P_INIT;
    return st;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    CHECK(P_INIT, "fmi3ExitInitializationMode");
    CORE(mbs_fmi_exit_init(f, "fmi3ExitInitializationMode"));
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    CHECK(P_RUNNING, "fmi3Terminate");
    f->phase = P_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    CHECK(P_ANY, "fmi3Reset");
    CORE(mbs_fmi_reset(f, "fmi3Reset"));
}

/* ---- variables ---- */
/* Each variable's rows through mbs_get_reals, the independent variable from the instance. */
fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          fmi3Float64 values[], size_t nValues) {
    size_t i, want, at = 0;
    long n;
    CHECK(P_ANY | P_UPDATE, "fmi3GetFloat64");
    for (i = 0; f->phase == P_UPDATE && valueReferences && i < nValueReferences; i++)
        if (!intermediate(f, valueReferences[i])) {
            mbs_fmi_logf(f, fmi3Error, "fmi3GetFloat64: value reference %u is not an intermediate variable "
                         "(intermediateUpdate=\"true\": the outputs and time) and cannot be read in intermediate "
                         "update mode", valueReferences[i]);
            return fmi3Error;
        }
    if (mbs_fmi_bad_array(f, valueReferences, values, nValueReferences, "fmi3GetFloat64") ||
        expand(f, valueReferences, nValueReferences, 0, &want, "fmi3GetFloat64") < 0 ||
        bad_count(f, nValues, want, "fmi3GetFloat64"))
        return fmi3Error;
    for (i = 0; i < nValueReferences; i++) {
        if (valueReferences[i] == time_vr(f)) {
            values[at++] = mbs_initialized(f->sim) ? mbs_time(f->sim) : f->t_start;
            continue;
        }
        n = expand(f, valueReferences + i, 1, 0, NULL, "fmi3GetFloat64");
        if (mbs_get_reals(f->sim, ((Fmu *)f)->rows, (size_t)n, values + at) != MBS_OK)
            return engine_status(f, MBS_ERROR, "fmi3GetFloat64");
        at += (size_t)n;
    }
    return fmi3OK;
}

/* All values at once (parameters that must change together: one call); on a refusal nothing is set. */
fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          const fmi3Float64 values[], size_t nValues) {
    size_t i, want;
    long n;
    CHECK(P_SET, "fmi3SetFloat64");
    if (mbs_fmi_bad_array(f, valueReferences, values, nValueReferences, "fmi3SetFloat64"))
        return fmi3Error;
    for (i = 0; i < nValueReferences; i++)
        if (valueReferences[i] == time_vr(f)) {
            mbs_fmi_logf(f, fmi3Error, "fmi3SetFloat64: the independent variable (time) cannot be set: fmi3SetTime "
                         "or fmi3DoStep move it");
            return fmi3Error;
        }
    if ((n = expand(f, valueReferences, nValueReferences, 0, &want, "fmi3SetFloat64")) < 0 ||
        bad_count(f, nValues, want, "fmi3SetFloat64"))
        return fmi3Error;
    CORE(mbs_fmi_set_reals(f, ((Fmu *)f)->rows, (size_t)n, values, "fmi3SetFloat64"));
}

#define UNKNOWN_VR "%s: value reference %u is not a String"  /* (fn, vr): mbs_fmi_vr */

/* Strings are scalars: a value reference holding more than one value (a Float64 array) is not one. */
static long string_rows(MbsFmiHead *f, const fmi3ValueReference vr[], size_t nvr, const void *values, size_t nValues,
                        const char *fn) {
    size_t want;
    long n;
    if (mbs_fmi_bad_array(f, vr, values, nvr, fn) || (n = expand(f, vr, nvr, 0, &want, fn)) < 0 ||
        bad_count(f, nValues, nvr, fn))
        return -1;
    if (want != nvr || (size_t)n != nvr) {
        mbs_fmi_logf(f, fmi3Error, "%s: a value reference is the time or a Float64 array, not a String", fn);
        return -1;
    }
    return n;
}

fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         fmi3String values[], size_t nValues) {
    long n;
    CHECK(P_ANY, "fmi3GetString");
    if ((n = string_rows(f, valueReferences, nValueReferences, values, nValues, "fmi3GetString")) < 0)
        return fmi3Error;
    CORE(mbs_fmi_get_strings(f, ((Fmu *)f)->rows, (size_t)n, values, UNKNOWN_VR, "fmi3GetString"));
}

fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         const fmi3String values[], size_t nValues) {
    long n;
    CHECK(P_SET, "fmi3SetString");
    if ((n = string_rows(f, valueReferences, nValueReferences, values, nValues, "fmi3SetString")) < 0)
        return fmi3Error;
    CORE(mbs_fmi_set_strings(f, ((Fmu *)f)->rows, (size_t)n, values, UNKNOWN_VR, "fmi3SetString"));
}

/* The model has Float64 and String variables only. */
static fmi3Status no_such_type(fmi3Instance instance, size_t nvr, const char *fn) {
    CHECK(P_ANY, fn);
    CORE(mbs_fmi_no_such_type(f, nvr, " (Float64 and String only)", fn));
}
#define NO_SUCH_TYPE(GET, SET, T)                                                                                     \
    fmi3Status GET(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, T values[], size_t nValues) {   \
        (void)vr, (void)values, (void)nValues;                                                                        \
        return no_such_type(instance, nvr, #GET);                                                                     \
    }                                                                                                                 \
    fmi3Status SET(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const T values[],             \
                   size_t nValues) {                                                                              \
        (void)vr, (void)values, (void)nValues;                                                                        \
        return no_such_type(instance, nvr, #SET);                                                                     \
    }
NO_SUCH_TYPE(fmi3GetFloat32, fmi3SetFloat32, fmi3Float32)
NO_SUCH_TYPE(fmi3GetInt8, fmi3SetInt8, fmi3Int8)
NO_SUCH_TYPE(fmi3GetUInt8, fmi3SetUInt8, fmi3UInt8)
NO_SUCH_TYPE(fmi3GetInt16, fmi3SetInt16, fmi3Int16)
NO_SUCH_TYPE(fmi3GetUInt16, fmi3SetUInt16, fmi3UInt16)
NO_SUCH_TYPE(fmi3GetInt32, fmi3SetInt32, fmi3Int32)
NO_SUCH_TYPE(fmi3GetUInt32, fmi3SetUInt32, fmi3UInt32)
NO_SUCH_TYPE(fmi3GetInt64, fmi3SetInt64, fmi3Int64)
NO_SUCH_TYPE(fmi3GetUInt64, fmi3SetUInt64, fmi3UInt64)
NO_SUCH_TYPE(fmi3GetBoolean, fmi3SetBoolean, fmi3Boolean)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                         fmi3Binary values[], size_t nValues) {
    (void)vr, (void)valueSizes, (void)values, (void)nValues;
    return no_such_type(instance, nvr, "fmi3GetBinary");
}
fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    (void)vr, (void)valueSizes, (void)values, (void)nValues;
    return no_such_type(instance, nvr, "fmi3SetBinary");
}
fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[]) {
    (void)vr, (void)values;
    return no_such_type(instance, nvr, "fmi3GetClock");
}
fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[]) {
    (void)vr, (void)values;
    return no_such_type(instance, nvr, "fmi3SetClock");
}

/* ---- what this FMU does not provide: fmi3Error with a message ---- */
static fmi3Status not_provided(fmi3Instance instance, const char *fn, const char *why) {
    CHECK(P_ANY | P_FATAL, fn);
    mbs_fmi_logf(f, fmi3Error, "%s: not provided (%s)", fn, why);
    return fmi3Error;
}
#define NOT_PROVIDED(fn, why) return not_provided(instance, #fn, why)

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference, (void)nDependencies;
    NOT_PROVIDED(fmi3GetNumberOfVariableDependencies, "the modelDescription lists no dependencies");
}
fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent, (void)elementIndicesOfDependent, (void)independents, (void)elementIndicesOfIndependents;
    (void)dependencyKinds, (void)nDependencies;
    NOT_PROVIDED(fmi3GetVariableDependencies, "the modelDescription lists no dependencies");
}
/* Directional and adjoint derivatives: the engine's over the rows the variables hold (knowns: states and inputs;
 * unknowns: derivatives, outputs, states), seeds and sensitivities flat as fmi3GetFloat64's values. */
typedef int (*EngineDerivative)(MbsInstance *, const unsigned *, size_t, const unsigned *, size_t, const double *,
                                double *);
static fmi3Status derivative(MbsFmiHead *f, EngineDerivative fn, int adjoint, const fmi3ValueReference unknowns[],
                             size_t nUnknowns, const fmi3ValueReference knowns[], size_t nKnowns,
                             const fmi3Float64 seed[], size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity,
                             const char *name) {
    size_t nu, nk;
    long ru, rk;
    if (mbs_fmi_bad_array(f, unknowns, unknowns, nUnknowns, name) || mbs_fmi_bad_array(f, knowns, knowns, nKnowns, name) ||
        (ru = expand(f, unknowns, nUnknowns, 0, &nu, name)) < 0 ||
        (rk = expand(f, knowns, nKnowns, (size_t)ru, &nk, name)) < 0 ||
        bad_count(f, nSeed, adjoint ? nu : nk, name) || bad_count(f, nSensitivity, adjoint ? nk : nu, name))
        return fmi3Error;
    if ((size_t)ru != nu || (size_t)rk != nk) {
        mbs_fmi_logf(f, fmi3Error, "%s: the independent variable (time) is neither a known nor an unknown here", name);
        return fmi3Error;
    }
    return engine_status(f, fn(f->sim, ((Fmu *)f)->rows, nu, ((Fmu *)f)->rows + nu, nk, seed, sensitivity), name);
}

#define P_DERIVATIVES (P_INIT | P_RUNNING | P_TERMINATED | P_ERROR)
fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    CHECK(P_DERIVATIVES, "fmi3GetDirectionalDerivative");
    return derivative(f, mbs_directional_derivative, 0, unknowns, nUnknowns, knowns, nKnowns, seed, nSeed, sensitivity,
                      nSensitivity, "fmi3GetDirectionalDerivative");
}
fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity) {
    CHECK(P_DERIVATIVES, "fmi3GetAdjointDerivative");
    return derivative(f, mbs_adjoint_derivative, 1, unknowns, nUnknowns, knowns, nKnowns, seed, nSeed, sensitivity,
                      nSensitivity, "fmi3GetAdjointDerivative");
}
fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    NOT_PROVIDED(fmi3EnterConfigurationMode, "no structural parameters");
}
fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    NOT_PROVIDED(fmi3ExitConfigurationMode, "no structural parameters");
}
fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[]) {
    (void)vr, (void)nvr, (void)intervals, (void)qualifiers;
    NOT_PROVIDED(fmi3GetIntervalDecimal, "no clocks");
}
fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions, (void)qualifiers;
    NOT_PROVIDED(fmi3GetIntervalFraction, "no clocks");
}
fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 shifts[]) {
    (void)vr, (void)nvr, (void)shifts;
    NOT_PROVIDED(fmi3GetShiftDecimal, "no clocks");
}
fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                fmi3UInt64 counters[], fmi3UInt64 resolutions[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    NOT_PROVIDED(fmi3GetShiftFraction, "no clocks");
}
fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                  const fmi3Float64 intervals[]) {
    (void)vr, (void)nvr, (void)intervals;
    NOT_PROVIDED(fmi3SetIntervalDecimal, "no clocks");
}
fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                   const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    NOT_PROVIDED(fmi3SetIntervalFraction, "no clocks");
}
fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                               const fmi3Float64 shifts[]) {
    (void)vr, (void)nvr, (void)shifts;
    NOT_PROVIDED(fmi3SetShiftDecimal, "no clocks");
}
fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                const fmi3UInt64 counters[], const fmi3UInt64 resolutions[]) {
    (void)vr, (void)nvr, (void)counters, (void)resolutions;
    NOT_PROVIDED(fmi3SetShiftFraction, "no clocks");
}
fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    NOT_PROVIDED(fmi3EvaluateDiscreteStates, "no clocks or discrete states");
}
fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference, (void)activationTime;
    NOT_PROVIDED(fmi3ActivateModelPartition, "no scheduled execution");
}
fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    NOT_PROVIDED(fmi3EnterStepMode, "hasEventMode=false: co-simulation goes to step mode at "
                 "fmi3ExitInitializationMode");
}
fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 orders[], fmi3Float64 values[], size_t nValues) {
    (void)vr, (void)nvr, (void)orders, (void)values, (void)nValues;
    NOT_PROVIDED(fmi3GetOutputDerivatives, "maxOutputDerivativeOrder=0");
}

/* ---- FMU state: the engine's byte layout, in memory and serialized (fmi_services.c) ---- */
fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    CHECK(P_ANY, "fmi3GetFMUState");
    CORE(mbs_fmi_get_state(f, FMUState, "fmi3GetFMUState"));
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    CHECK(P_ANY, "fmi3SetFMUState");
    CORE(mbs_fmi_set_state(f, FMUState, "fmi3SetFMUState"));
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    CHECK(P_ANY, "fmi3FreeFMUState");
    CORE(mbs_fmi_free_state(f, FMUState, "fmi3FreeFMUState"));
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size) {
    CHECK(P_ANY, "fmi3SerializedFMUStateSize");
    CORE(mbs_fmi_state_size(f, FMUState, size, "fmi3SerializedFMUStateSize"));
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size) {
    CHECK(P_ANY, "fmi3SerializeFMUState");
    CORE(mbs_fmi_serialize(f, FMUState, serializedState, size, "fmi3SerializeFMUState"));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState) {
    CHECK(P_ANY, "fmi3DeserializeFMUState");
    CORE(mbs_fmi_deserialize(f, serializedState, size, FMUState, "fmi3DeserializeFMUState"));
}

/* ---- co-simulation ---- */
static int null_outputs(MbsFmiHead *f, const void *a, const void *b, const void *c, const void *d, const char *fn) {
    if (a && b && c && d)
        return 0;
    mbs_fmi_logf(f, fmi3Error, "%s: NULL output argument", fn);
    return 1;
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    fmi3Status st;
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(I_CS | P_STEP, "fmi3DoStep");
    if (null_outputs(f, eventHandlingNeeded, terminateSimulation, earlyReturn, lastSuccessfulTime, "fmi3DoStep"))
        return fmi3Error;
    if (mbs_fmi_bad_step(f, currentCommunicationPoint, communicationStepSize, "fmi3DoStep"))
        return fmi3Error;
    /* a refused or failed step leaves the instance at its last good point: the phase stays */
    st = engine_status(f, mbs_do_step(f->sim, currentCommunicationPoint, communicationStepSize), "fmi3DoStep");
    *eventHandlingNeeded = fmi3False;
    *earlyReturn = fmi3False;
    *terminateSimulation = st == fmi3Discard;  /* as fmi2Terminated after a discarded FMI 2 step */
    *lastSuccessfulTime = mbs_time(f->sim);
    return st;
}

/* ---- model exchange ---- */
fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    CHECK(I_ME | P_CONT, "fmi3EnterEventMode");
    f->phase = P_EVENT;
    return fmi3OK;
}

/* No discrete states, event indicators or time events: nothing changes at an event. */
fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    CHECK(I_ME | P_EVENT, "fmi3UpdateDiscreteStates");
    if (null_outputs(f, discreteStatesNeedUpdate, terminateSimulation, nominalsOfContinuousStatesChanged,
                     valuesOfContinuousStatesChanged, "fmi3UpdateDiscreteStates") ||
        null_outputs(f, nextEventTimeDefined, nextEventTime, f, f, "fmi3UpdateDiscreteStates"))
        return fmi3Error;
    *discreteStatesNeedUpdate = *terminateSimulation = fmi3False;
    *nominalsOfContinuousStatesChanged = *valuesOfContinuousStatesChanged = *nextEventTimeDefined = fmi3False;
    *nextEventTime = 0.0;
    return fmi3OK;
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    CHECK(I_ME | P_EVENT, "fmi3EnterContinuousTimeMode");
    f->phase = P_CONT;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(I_ME | P_CONT, "fmi3CompletedIntegratorStep");
    if (null_outputs(f, enterEventMode, terminateSimulation, f, f, "fmi3CompletedIntegratorStep"))
        return fmi3Error;
    *enterEventMode = *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    CHECK(I_ME | P_EVENT | P_CONT, "fmi3SetTime");
    CORE(mbs_fmi_ok_or_error(f, mbs_set_time(f->sim, time), "fmi3SetTime"));
}

/* The host's array has exactly the model's length (fmi3GetNumberOfContinuousStates). */
static int bad_states(MbsFmiHead *f, const void *x, size_t n, const char *fn) {
    if (x && n == mbs_fmi_nstates(f))
        return 0;
    mbs_fmi_logf(f, fmi3Error, "%s: %s %lu states, the model has %d", fn, x ? "" : "NULL array for",
                 (unsigned long)n, (int)mbs_fmi_nstates(f));
    return 1;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    CHECK(I_ME | P_CONT, "fmi3SetContinuousStates");
    CORE(mbs_fmi_ok_or_error(f, mbs_set_state(f->sim, continuousStates, nContinuousStates),
                             "fmi3SetContinuousStates"));
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[], size_t nContinuousStates) {
    CHECK(P_STATES, "fmi3GetContinuousStates");
    if (bad_states(f, continuousStates, nContinuousStates, "fmi3GetContinuousStates"))
        return fmi3Error;
    memcpy(continuousStates, mbs_state(f->sim), nContinuousStates * sizeof(double));
    return fmi3OK;
}

/* ẋ at the time and states the host set: fmi3Discard where it is not defined (singular M, gimbal lock: the
 * host's integrator may retry with a smaller step), fmi3Error for an input or parameter the engine refuses. */
fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    CHECK(P_STATES, "fmi3GetContinuousStateDerivatives");
    return engine_status(f, mbs_derivatives(f->sim, derivatives, nContinuousStates),
                         "fmi3GetContinuousStateDerivatives");
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[], size_t nContinuousStates) {
    CHECK(I_ME | P_ANY, "fmi3GetNominalsOfContinuousStates");
    if (bad_states(f, nominals, nContinuousStates, "fmi3GetNominalsOfContinuousStates"))
        return fmi3Error;
    memcpy(nominals, mbs_nominals(f->sim), nContinuousStates * sizeof *nominals);  /* fixed at build */
    return fmi3OK;
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators) {
    (void)eventIndicators;
    CHECK(I_ME | P_ANY, "fmi3GetEventIndicators");
    if (nEventIndicators == 0)
        return fmi3OK;
    mbs_fmi_logf(f, fmi3Error, "fmi3GetEventIndicators: %lu event indicators asked for, the model has none",
          (unsigned long)nEventIndicators);
    return fmi3Error;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    CHECK(I_ME | P_ANY, "fmi3GetNumberOfEventIndicators");
    if (null_outputs(f, nEventIndicators, f, f, f, "fmi3GetNumberOfEventIndicators"))
        return fmi3Error;
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    CHECK(I_ME | P_ANY, "fmi3GetNumberOfContinuousStates");
    if (null_outputs(f, nContinuousStates, f, f, f, "fmi3GetNumberOfContinuousStates"))
        return fmi3Error;
    *nContinuousStates = mbs_fmi_nstates(f);
    return fmi3OK;
}
