/* mbsfmu FMI 2.0 loader shim (generated from src/mbsfmu/fmu/shim.c; do not edit in an FMU).
 *
 * This library is the FMU binary a host loads. It forwards the fmi2* functions to the real pythonfmu
 * binary next to it (MBSFMU_REAL_LIBRARY, loaded RTLD_LOCAL), after making sure that
 *   1. a Python runtime is available with global symbols (pythonfmu's binary does not link
 *      libpython): the one already in the process, else the libpython recorded at build time
 *      (MBSFMU_LIBPYTHON), else its soname (MBSFMU_LIBPYTHON_SONAME) from the default search path;
 *   2. the interpreter is initialized by *this* shim (from the host's thread, signal handlers left
 *      alone) and never finalized: pythonfmu then skips its own Py_Initialize/Py_Finalize, whose
 *      finalization from a worker thread aborts C hosts at exit.
 *
 * It is also the FMU's guard. pythonfmu 0.7.0 turns any Python exception into fmi2Fatal and at the same
 * time releases the instance's Python objects, so the next call on that instance crashes the host; it
 * never checks value references, types, the calling sequence or pointers. So the shim answers fmi2Error
 * itself, with a message through the host's logger, before pythonfmu sees a bad call:
 *   - components: only live instances handed out here are used (a registry; a foreign pointer is never
 *     dereferenced);
 *   - value references, types, causality and variability from the model's variable table, compiled in at
 *     build time (MBSFMU_VARIABLES, from modelDescription.xml);
 *   - the FMI 2.0 co-simulation calling sequence (instantiated -> initialization mode -> step mode ->
 *     terminated; error state; fmi2Reset back to instantiated);
 *   - FMU states: only handles handed out here to a live instance are accepted (one of another instance of
 *     this FMU restores through its bytes); serialized bytes must carry the engine's header (state_bytes.c) with this
 *     model's GUID, a matching length and checksum;
 *   - refusals the slave cannot report (pythonfmu has no fmi2Error): the slave keeps the reason of a failed
 *     initialization, state restore, string set, outright step refusal or discarded step ("discard: ...") in a
 *     hidden String variable, value reference MBSFMU_NVARS (not in modelDescription.xml), which the shim
 *     reads after those calls (and after fmi2Instantiate and fmi2Reset: a slave that cannot load its scene);
 *   - after one fmi2Fatal from pythonfmu the instance is never passed to pythonfmu again;
 *   - the resource location (engine/fmu_files.c, the native FMU's parser) and the files the FMU reads: regular
 *     files of bounded size only, checked before pythonfmu or Python opens them;
 *   - memory: freed instances' pythonfmu components are reused (see "pythonfmu components, reused").
 */
#define _GNU_SOURCE
#include <dirent.h>
#include <dlfcn.h>
#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <wchar.h>

#include "call_guard.h"
#include "fmu_files.h"
#include "state_header.h"
#ifndef MBSFMU_RESOURCE_FILES
#define MBSFMU_RESOURCE_FILES ""
#endif
#define MAX_RESOURCE_ENTRIES 10000   /* files and folders under resources/ (an FMU has a few dozen) */
#define MAX_RESOURCE_DEPTH 8         /* folder levels under resources/ looked into (an FMU has 3) */

#ifndef MBSFMU_VARIABLES
#error "compile with mbsfmu.fmu.build.compile_shim: it defines the model's GUID and variable table"
#endif
#ifndef MBSFMU_LIBPYTHON
#define MBSFMU_LIBPYTHON ""
#endif
#ifndef MBSFMU_LIBPYTHON_SONAME
#define MBSFMU_LIBPYTHON_SONAME ""
#endif
#ifndef MBSFMU_PYTHON_EXECUTABLE
#define MBSFMU_PYTHON_EXECUTABLE ""
#endif
#ifndef MBSFMU_REAL_LIBRARY
#define MBSFMU_REAL_LIBRARY "pythonfmu.so"
#endif

#define EXPORT __attribute__((visibility("default")))

typedef void* fmi2Component;
typedef void* fmi2ComponentEnvironment;
typedef void* fmi2FMUstate;
typedef unsigned int fmi2ValueReference;
typedef double fmi2Real;
typedef int fmi2Integer;
typedef int fmi2Boolean;
typedef char fmi2Char;
typedef const fmi2Char* fmi2String;
typedef char fmi2Byte;
typedef int fmi2Status;
typedef int fmi2Type;
typedef int fmi2StatusKind;
enum { fmi2LastSuccessfulTime = 2, fmi2Terminated = 3 };   /* of fmi2StatusKind */
typedef void (*fmi2CallbackLogger)(fmi2ComponentEnvironment, fmi2String, fmi2Status, fmi2String,
                                   fmi2String, ...);
typedef struct {
    fmi2CallbackLogger logger;
    void* (*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void*);
    void (*stepFinished)(fmi2ComponentEnvironment, fmi2Status);
    fmi2ComponentEnvironment componentEnvironment;
} fmi2CallbackFunctions;

enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal };
enum { fmi2CoSimulation = 1 };

/* ------------------------------------------------------------------------------------ model table */
typedef struct {
    const char* name;
    char type;         /* R Real, S String, I Integer, B Boolean, E Enumeration, - no such vr */
    char causality;    /* p parameter, c calculatedParameter, i input, o output, l local, x independent */
    char variability;  /* k constant, f fixed, t tunable, d discrete, c continuous */
} Var;
static const Var vars[] = {MBSFMU_VARIABLES};
#define MBSFMU_NVARS ((fmi2ValueReference)(sizeof vars / sizeof vars[0]))
static const char* const categories[] = {MBSFMU_LOG_CATEGORIES};
#define NCATEGORIES (sizeof categories / sizeof categories[0])

/* ----------------------------------------------------------------------------- Python and pythonfmu */
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static void* real = NULL;
static char error[4096];

typedef int (*int_void_fn)(void);
typedef void (*void_int_fn)(int);
typedef void* (*ptr_void_fn)(void);
typedef void (*void_wptr_fn)(const wchar_t*);
typedef wchar_t* (*decode_fn)(const char*, size_t*);

/* Make sure an initialized Python interpreter is in the process; 0 on success. */
static int ensure_python(void) {
    int_void_fn is_init = (int_void_fn)dlsym(RTLD_DEFAULT, "Py_IsInitialized");
    void* lib = NULL;
    if (!is_init) {
        const char* tried[2] = {MBSFMU_LIBPYTHON, MBSFMU_LIBPYTHON_SONAME};
        char why[2][1024] = {"", ""};
        for (int i = 0; i < 2 && !lib; i++) {
            if (!tried[i][0]) continue;
            lib = dlopen(tried[i], RTLD_NOW | RTLD_GLOBAL);
            if (!lib) snprintf(why[i], sizeof why[i], "%s", dlerror());
        }
        if (!lib) {
            snprintf(error, sizeof error,
                     "mbsfmu: cannot load the Python runtime this FMU was built with "
                     "(%s: %s; %s: %s). The target machine needs that Python (same version, "
                     "shared libpython) at the same path as on the build machine (%s), or its "
                     "libpython on the library search path.",
                     MBSFMU_LIBPYTHON, why[0][0] ? why[0] : "not tried", MBSFMU_LIBPYTHON_SONAME,
                     why[1][0] ? why[1] : "not tried", MBSFMU_PYTHON_EXECUTABLE);
            return -1;
        }
        is_init = (int_void_fn)dlsym(lib, "Py_IsInitialized");
        if (!is_init) {
            snprintf(error, sizeof error, "mbsfmu: %s has no Py_IsInitialized", MBSFMU_LIBPYTHON);
            return -1;
        }
    }
    if (is_init()) return 0;   /* a Python host, or another FMU of this process did it */
    void* scope = lib ? lib : RTLD_DEFAULT;
    void_int_fn init_ex = (void_int_fn)dlsym(scope, "Py_InitializeEx");
    ptr_void_fn save_thread = (ptr_void_fn)dlsym(scope, "PyEval_SaveThread");
    void_wptr_fn set_program = (void_wptr_fn)dlsym(scope, "Py_SetProgramName");
    decode_fn decode = (decode_fn)dlsym(scope, "Py_DecodeLocale");
    if (!init_ex || !save_thread) {
        snprintf(error, sizeof error, "mbsfmu: the loaded libpython lacks Py_InitializeEx");
        return -1;
    }
    /* The build interpreter's executable as program name: its prefix (stdlib, site-packages,
       a virtual environment's pyvenv.cfg) is found from there. Leaked on purpose (Python keeps
       the pointer). */
    if (set_program && decode && MBSFMU_PYTHON_EXECUTABLE[0] &&
        access(MBSFMU_PYTHON_EXECUTABLE, X_OK) == 0) {
        wchar_t* w = decode(MBSFMU_PYTHON_EXECUTABLE, NULL);
        if (w) set_program(w);
    }
    /* No `site`: everything the FMU runs is in its resources and the standard library, and the
       site-packages' .pth files cost 20-40 ms of start-up (and could shadow the FMU's modules). */
    int* no_site = (int*)dlsym(scope, "Py_NoSiteFlag");
    if (no_site) *no_site = 1;
    init_ex(0);               /* 0: keep the host's signal handlers */
    save_thread();            /* release the GIL; pythonfmu takes it with PyGILState_Ensure */
    return 0;                 /* never finalized: see the header comment */
}

/* Exit-order fix for pythonfmu 0.7.0's binary. It keeps its PyState in a static
   std::shared_ptr `pyState` and releases it twice over: (a) the shared_ptr's C++ destructor,
   registered with __cxa_atexit by the library's constructor, and (b) an ELF destructor
   (onLibraryUnload -> finalizePythonInterpreter: `pyState = nullptr`). On dlclose (b) runs before
   (a) and all is well. At process exit without dlclose of that library (a C host returning from
   main: the shim never dlcloses it), exit() runs the __cxa_atexit handlers first, so (a) frees the
   PyState's control block but leaves its pointer in `pyState`, and _dl_fini then runs (b), whose
   `lock xadd` decrements the use count inside the freed heap chunk, i.e. its bin's bk pointer.
   The next free() that walks that bin aborts ("free(): corrupted unsorted chunks", seen in
   scipy's libgfortran close_units). Fix: call finalizePythonInterpreter ourselves from an exit
   handler registered *after* dlopen ran the library's constructors; handlers run in reverse
   order, so ours resets `pyState` while it is alive, and (a) and (b) then see an empty pointer.
   Python is untouched: the shim initialized it, so pythonfmu's worker thread never finalizes.
   (atexit from a shared object: if the host dlcloses the shim, the handler runs then; also fine.) */
static void (*real_finalize)(void) = NULL;
static void release_pystate(void) {
    if (real_finalize) real_finalize();
}

/* pythonfmu's functions the shim forwards to (Integer/Boolean access, derivatives and fmi2CancelStep are
   answered here: the model has no such variables or capabilities). */
static struct {
    fmi2Component (*instantiate)(fmi2String, fmi2Type, fmi2String, fmi2String,
                                 const fmi2CallbackFunctions*, fmi2Boolean, fmi2Boolean);
    void (*free_instance)(fmi2Component);
    fmi2Status (*set_debug_logging)(fmi2Component, fmi2Boolean, size_t, const fmi2String[]);
    fmi2Status (*setup_experiment)(fmi2Component, fmi2Boolean, fmi2Real, fmi2Real, fmi2Boolean, fmi2Real);
    fmi2Status (*enter_init)(fmi2Component), (*exit_init)(fmi2Component);
    fmi2Status (*terminate)(fmi2Component), (*reset)(fmi2Component);
    fmi2Status (*get_real)(fmi2Component, const fmi2ValueReference[], size_t, fmi2Real[]);
    fmi2Status (*get_string)(fmi2Component, const fmi2ValueReference[], size_t, fmi2String[]);
    fmi2Status (*set_real)(fmi2Component, const fmi2ValueReference[], size_t, const fmi2Real[]);
    fmi2Status (*set_string)(fmi2Component, const fmi2ValueReference[], size_t, const fmi2String[]);
    fmi2Status (*get_state)(fmi2Component, fmi2FMUstate*), (*set_state)(fmi2Component, fmi2FMUstate);
    fmi2Status (*free_state)(fmi2Component, fmi2FMUstate*);
    fmi2Status (*state_size)(fmi2Component, fmi2FMUstate, size_t*);
    fmi2Status (*serialize)(fmi2Component, fmi2FMUstate, fmi2Byte[], size_t);
    fmi2Status (*deserialize)(fmi2Component, const fmi2Byte[], size_t, fmi2FMUstate*);
    fmi2Status (*do_step)(fmi2Component, fmi2Real, fmi2Real, fmi2Boolean);
    fmi2Status (*get_status)(fmi2Component, fmi2StatusKind, fmi2Status*);
    fmi2Status (*get_integer_status)(fmi2Component, fmi2StatusKind, fmi2Integer*);
    fmi2Status (*get_boolean_status)(fmi2Component, fmi2StatusKind, fmi2Boolean*);
    fmi2Status (*get_string_status)(fmi2Component, fmi2StatusKind, fmi2String*);
} R;

static int load_real(void) {
    if (real) return 0;
    Dl_info info;
    if (!dladdr((void*)&ensure_python, &info) || !info.dli_fname) {
        snprintf(error, sizeof error, "mbsfmu: cannot locate the FMU binary (dladdr failed)");
        return -1;
    }
    char path[4096];
    snprintf(path, sizeof path, "%s", info.dli_fname);
    char* slash = strrchr(path, '/');
    size_t dir = slash ? (size_t)(slash - path + 1) : 0;
    snprintf(path + dir, sizeof path - dir, "%s", MBSFMU_REAL_LIBRARY);
    void* lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        snprintf(error, sizeof error, "mbsfmu: cannot load %s: %s", path, dlerror());
        return -1;
    }
    const char* missing = NULL;
#define LOAD(field, name) \
    if (!(*(void**)&R.field = dlsym(lib, name))) missing = name;
    LOAD(instantiate, "fmi2Instantiate") LOAD(free_instance, "fmi2FreeInstance")
    LOAD(set_debug_logging, "fmi2SetDebugLogging") LOAD(setup_experiment, "fmi2SetupExperiment")
    LOAD(enter_init, "fmi2EnterInitializationMode") LOAD(exit_init, "fmi2ExitInitializationMode")
    LOAD(terminate, "fmi2Terminate") LOAD(reset, "fmi2Reset")
    LOAD(get_real, "fmi2GetReal") LOAD(get_string, "fmi2GetString")
    LOAD(set_real, "fmi2SetReal") LOAD(set_string, "fmi2SetString")
    LOAD(get_state, "fmi2GetFMUstate") LOAD(set_state, "fmi2SetFMUstate") LOAD(free_state, "fmi2FreeFMUstate")
    LOAD(state_size, "fmi2SerializedFMUstateSize") LOAD(serialize, "fmi2SerializeFMUstate")
    LOAD(deserialize, "fmi2DeSerializeFMUstate") LOAD(do_step, "fmi2DoStep")
    LOAD(get_status, "fmi2GetStatus")
    LOAD(get_integer_status, "fmi2GetIntegerStatus") LOAD(get_boolean_status, "fmi2GetBooleanStatus")
    LOAD(get_string_status, "fmi2GetStringStatus")
#undef LOAD
    if (missing) {
        snprintf(error, sizeof error, "mbsfmu: %s lacks %s", path, missing);
        return -1;   /* lib stays loaded: its constructors ran (see release_pystate) */
    }
    real = lib;
    /* Stay loaded when the host unloads the FMU (fmpy does after every fmi2FreeInstance), as pythonfmu's library and
       the interpreter do: the pool of components (below) lives in this library. */
    dlopen(info.dli_fname, RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE);
    real_finalize = (void (*)(void))dlsym(real, "finalizePythonInterpreter");
    if (real_finalize) atexit(release_pystate);   /* see release_pystate */
    return 0;
}

/* ------------------------------------------------------------------------- instances and messages */
/* the phases of the co-simulation state machine (call_guard.h, shared with the native FMU) */
enum Phase { INSTANTIATED = P_INSTANTIATED, INIT_MODE = P_INIT, STEP = P_STEP, TERMINATED = P_TERMINATED,
             FAILED = P_ERROR, BROKEN = P_FATAL };
#define P(phase) (phase)
#define LIVE (P(INSTANTIATED) | P(INIT_MODE) | P(STEP) | P(TERMINATED) | P(FAILED))

typedef struct {
    fmi2FMUstate handle;  /* pythonfmu's */
    int phase;            /* the instance's phase the state restores */
} State;

typedef struct Slot Slot;

typedef struct {
    fmi2Component real;        /* pythonfmu's component (slot->real) */
    Slot* slot;
    int phase;
    fmi2CallbackFunctions cb;  /* a copy: the logger for the shim's own messages */
    char name[256];
    State* states;             /* FMU states handed out for this instance */
    int discarded;             /* the last fmi2DoStep was discarded: fmi2Terminated reads true (as the native FMU) */
    size_t nstates, capacity;
} Inst;

static MbsRegistry live;       /* the instances handed out and not yet freed (call_guard.h) */

static Inst* find(fmi2Component c) { return mbs_reg_find(&live, c) ? (Inst*)c : NULL; }

/* Log text through the host's logger (stderr without one). The text is passed as the format with no arguments,
   so any '%' in it (a variable name, a string value, a Python error) is doubled. */
static void log_text(const fmi2CallbackFunctions* cb, const char* inst, fmi2Status status, const char* category,
                     const char* text) {
    char esc[8192];
    size_t j = 0;
    for (const char* p = text; *p && j + 3 < sizeof esc; p++) {
        if (*p == '%') esc[j++] = '%';
        esc[j++] = *p;
    }
    esc[j] = 0;
    if (cb && cb->logger) cb->logger(cb->componentEnvironment, inst, status, category, esc);
    else fprintf(stderr, "%s: %s\n", inst, text);
}

static void say_cb(const fmi2CallbackFunctions* cb, const char* inst, fmi2Status status, const char* fmt, ...) {
    char msg[1536];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    const char* category = status == fmi2Fatal     ? "logStatusFatal"
                           : status == fmi2Discard ? "logStatusDiscard"
                                                   : "logStatusError";
    log_text(cb, inst, status, category, msg);
}
#define say(in, status, ...) say_cb(&(in)->cb, (in)->name, status, __VA_ARGS__)

/* The live instance behind c if fn may be called in its phase (fmi2OK), else why not (fmi2Error). */
static fmi2Status enter(fmi2Component c, const char* fn, unsigned allowed, Inst** out) {
    Inst* in = c ? find(c) : NULL;
    *out = NULL;
    if (!in) {   /* no logger to use: never dereference a pointer the shim did not hand out */
        fprintf(stderr, "mbsfmu: %s: %s\n", fn,
                c ? "not a live instance of this FMU (freed, or another FMU's)" : "NULL component");
        return fmi2Error;
    }
    if (in->phase == BROKEN) {
        say(in, fmi2Error, "%s: pythonfmu reported a fatal error before; this instance is unusable, free it", fn);
        return fmi2Error;
    }
    char why[256];
    if (mbs_phase_refuses((int)allowed, in->phase, I_CS, fn, why, sizeof why)) {
        say(in, fmi2Error, "%s (FMI 2.0 co-simulation calling sequence)", why);
        return fmi2Error;
    }
    *out = in;
    return fmi2OK;
}

/* pythonfmu's answer; after a fmi2Fatal it has released the instance's Python objects, so the
   instance is never handed to it again. */
static fmi2Status done(Inst* in, const char* fn, fmi2Status status) {
    if (status == fmi2Fatal || status < fmi2OK || status > fmi2Fatal) {
        in->phase = BROKEN;
        say(in, fmi2Fatal, "%s: pythonfmu reported a fatal error; this instance is unusable, free it", fn);
        return fmi2Fatal;
    }
    return status;
}

/* The reason the slave refused the last initialization, state restore, string set or step ("" if none),
   read from the hidden String variable MBSFMU_NVARS; reading clears it. NULL if pythonfmu failed. */
static const char* refusal(Inst* in, const char* fn) {
    fmi2ValueReference vr = MBSFMU_NVARS;
    fmi2String text = NULL;
    if (done(in, fn, R.get_string(in->real, &vr, 1, &text)) != fmi2OK) return NULL;
    return text ? text : "";
}

/* 1 if the slave of pythonfmu component `real` (not handed out) started: it holds no refusal. */
static int slave_started(fmi2Component real) {
    fmi2ValueReference vr = MBSFMU_NVARS;
    fmi2String text = NULL;
    return R.get_string(real, &vr, 1, &text) == fmi2OK && text && !*text;
}

/* fmi2Error with the slave's reason after a forwarded call, else the call's status. */
static fmi2Status checked(Inst* in, const char* fn, fmi2Status status) {
    if ((status = done(in, fn, status)) > fmi2Warning) return status;
    const char* why = refusal(in, fn);
    if (!why) return fmi2Fatal;
    if (!*why) return status;
    say(in, fmi2Error, "%s: %s", fn, why);
    return fmi2Error;
}

/* 1 (with the reason in err) if the folder dir holds, at any depth, something Python might open that is neither a
   regular file nor a folder (a FIFO, socket or device: Python's imports also read the .pyc files in __pycache__ that
   no list of the FMU's files names), or more than *budget entries. */
static int special_file(const char* dir, int depth, int* budget, char* err, size_t errlen) {
    DIR* d = depth > MAX_RESOURCE_DEPTH ? NULL : opendir(dir);
    struct dirent* e;
    int bad = 0;
    if (!d) return 0;   /* deeper than anything the FMU imports, missing or unreadable: the listed files tell */
    while (!bad && (e = readdir(d))) {
        char path[4096];
        struct stat st;
        if (!strcmp(e->d_name, ".") || !strcmp(e->d_name, "..")) continue;
        snprintf(path, sizeof path, "%s/%s", dir, e->d_name);
        if (--*budget < 0)
            bad = snprintf(err, errlen, "more than %d files and folders", MAX_RESOURCE_ENTRIES) > 0;
        else if (stat(path, &st) != 0)
            continue;   /* gone, or a dangling link: nothing to open */
        else if (S_ISDIR(st.st_mode))
            bad = special_file(path, depth + 1, budget, err, errlen);
        else if (!S_ISREG(st.st_mode))
            bad = snprintf(err, errlen, "'%.600s' is not a regular file (a FIFO, socket or device)", path) > 0;
    }
    closedir(d);
    return bad;
}

/* The resources folder of fmuResourceLocation `uri` (engine/fmu_files.c: the parser of the native FMU too) as the
   plain path pythonfmu 0.7.0 is given, into dir; NULL, else why not. Every file the FMU reads at run time
   (MBSFMU_RESOURCE_FILES, from the FMU's resources/) must be a regular file of bounded size first: pythonfmu and
   Python read them with blocking opens (a FIFO hangs the host), and pythonfmu calls a NULL class object when its
   script is missing. pythonfmu maps a location to a path by replacing every "%20" with a space and dropping the
   first "file://": a plain path passes unchanged unless it holds those. */
static const char* resources_folder(const char* uri, char* dir, size_t size, char* why, size_t whylen) {
    static const char* const files[] = {MBSFMU_RESOURCE_FILES};
    char file[4096 + 512], err[1024];
    if (mbs_resource_path(uri, "", dir, size, err, sizeof err))
        return snprintf(why, whylen, "%s", err), why;
    if (strstr(dir, "%20") || strstr(dir, "file://"))
        return snprintf(why, whylen, "resources folder %s: pythonfmu 0.7.0 cannot load from a path that contains "
                        "\"%%20\" or \"file://\" (rename the folder, or use a native FMU)", dir), why;
    if (strlen(dir) > 1) dir[strlen(dir) - 1] = 0;   /* no trailing slash: pythonfmu appends "/name" */
    int budget = MAX_RESOURCE_ENTRIES;
    for (size_t i = 0; i < sizeof files / sizeof files[0]; i++) {
        snprintf(file, sizeof file, "%s/%s", dir, files[i]);
        if (files[i][0] && mbs_check_regular(file, MBS_SCENE_FILE_LIMIT, NULL, err, sizeof err))
            return snprintf(why, whylen, "%s is not this FMU's resources folder: %s", dir, err), why;
    }
    if (special_file(dir, 0, &budget, err, sizeof err))
        return snprintf(why, whylen, "%s is not this FMU's resources folder: %s", dir, err), why;
    return NULL;
}

/* ------------------------------------------------------------------------ pythonfmu components, reused */
/* pythonfmu 0.7.0 leaks in every fmi2Instantiate (the resources folder it inserts into sys.path, the class lists
   and their reprs it builds to find the slave class: ~0.8 kB; build.ENTRY keeps that from being the whole slave
   script), and hosts that create and free instances in a loop (optimizers, Monte Carlo) must stay flat. So a freed
   instance's pythonfmu component is reset (a fresh slave) and kept in a pool; fmi2Instantiate of the
   same resources folder takes one from there instead of asking pythonfmu for a new one. pythonfmu keeps a pointer
   to the callbacks it was given: those of the slot, whose logger passes messages on to the instance that owns the
   slot now, under that instance's name (nothing while the slot is idle). */
struct Slot {
    fmi2Component real;
    fmi2CallbackFunctions cb;  /* given to pythonfmu: logger = forward, componentEnvironment = the slot */
    Inst* owner;               /* NULL while idle */
    char dir[4096];            /* the resources folder pythonfmu was given */
};
static Slot** idle = NULL;
static size_t nidle = 0, idle_capacity = 0;

static void forward(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                    fmi2String message, ...) {
    Inst* in = ((Slot*)env)->owner;
    (void)name;
    if (in && message) log_text(&in->cb, in->name, status, category, message);
}

/* An idle slot of resources folder dir, taken from the pool and owned by in; NULL if there is none. Idle slots of
   folders that are gone (fmpy extracts every run into a temporary folder and deletes it) are freed on the way. */
static Slot* take_idle(const char* dir, Inst* in) {
    Slot *slot = NULL, *gone[64];
    size_t ngone = 0;
    pthread_mutex_lock(&lock);
    for (size_t i = nidle; i-- > 0;) {
        int mine = !slot && !strcmp(idle[i]->dir, dir);
        int gone_folder = !mine && ngone < sizeof gone / sizeof gone[0] && access(idle[i]->dir, F_OK) != 0;
        if (mine) slot = idle[i];
        if (gone_folder) gone[ngone++] = idle[i];
        if (mine || gone_folder) idle[i] = idle[--nidle];
    }
    pthread_mutex_unlock(&lock);
    for (size_t i = 0; i < ngone; i++) {
        R.free_instance(gone[i]->real);
        free(gone[i]);
    }
    if (slot) slot->owner = in;
    return slot;
}

/* Back into the pool with a fresh slave (pythonfmu's reset re-creates it); a slot pythonfmu cannot reset is left
   alone (leaked, as after a fatal error). */
static void park(Slot* slot) {
    int ok = R.reset(slot->real) == fmi2OK;
    if (ok && !slave_started(slot->real)) {   /* its scene is gone (the host deleted the folder): not reusable */
        R.free_instance(slot->real);
        free(slot);
        return;
    }
    pthread_mutex_lock(&lock);
    if (ok && nidle == idle_capacity) {
        size_t cap = idle_capacity ? 2 * idle_capacity : 8;
        Slot** grown = realloc(idle, cap * sizeof *grown);
        if (grown) idle = grown, idle_capacity = cap;
    }
    if (ok && nidle < idle_capacity) idle[nidle++] = slot;
    else if (ok) R.free_instance(slot->real), free(slot);
    pthread_mutex_unlock(&lock);
}

/* A pythonfmu component for in: from the pool, else a new one; NULL if pythonfmu cannot create the slave. */
static Slot* slot_for(Inst* in, fmi2String name, fmi2Type type, fmi2String guid, const char* dir, fmi2Boolean visible,
                      fmi2Boolean logging) {
    Slot* slot = take_idle(dir, in);
    if (slot) {
        R.set_debug_logging(slot->real, logging, 0, NULL);
        return slot;
    }
    if (!(slot = calloc(1, sizeof *slot))) return NULL;
    slot->cb = (fmi2CallbackFunctions){forward, calloc, free, NULL, slot};
    slot->owner = in;
    snprintf(slot->dir, sizeof slot->dir, "%s", dir);
    if (!(slot->real = R.instantiate(name, type, guid, dir, &slot->cb, visible, logging))) free(slot), slot = NULL;
    return slot;
}

/* ----------------------------------------------------------------------------------- life cycle */
EXPORT const char* fmi2GetTypesPlatform(void) { return "default"; }
EXPORT const char* fmi2GetVersion(void) { return "2.0"; }

EXPORT fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String guid,
                                     fmi2String resources, const fmi2CallbackFunctions* cb,
                                     fmi2Boolean visible, fmi2Boolean loggingOn) {
    const char* name = instanceName ? instanceName : "";
    char text[8192], dir[4096];
    const char* why = !cb || !cb->logger ? "no callback functions or no logger"
                      : !cb->allocateMemory || !cb->freeMemory ? "no allocateMemory/freeMemory callbacks"
                      : !instanceName || !*instanceName ? "no instance name"
                      : fmuType != fmi2CoSimulation ? "this FMU supports co-simulation only"
                      : !resources ? "no fmuResourceLocation"
                      : !guid ? "no GUID given (NULL)"
                      : strcmp(guid, MBSFMU_GUID) ? "GUID differs from this FMU's " MBSFMU_GUID  /* "" too, as the native FMU */
                      : resources_folder(resources, dir, sizeof dir, text, sizeof text);
    if (why) {
        say_cb(cb, name, fmi2Error, "fmi2Instantiate: %s", why);
        return NULL;
    }
    pthread_mutex_lock(&lock);
    int ok = ensure_python() == 0 && load_real() == 0;
    if (!ok) snprintf(text, sizeof text, "%s", error);
    pthread_mutex_unlock(&lock);
    if (!ok) {
        say_cb(cb, name, fmi2Error, "%s", text);
        return NULL;
    }
    Inst* in = calloc(1, sizeof *in);
    if (in) in->phase = INSTANTIATED;
    if (!in || !mbs_reg_add(&live, in)) {
        free(in);
        say_cb(cb, name, fmi2Error, "fmi2Instantiate: out of memory");
        return NULL;
    }
    in->cb = *cb;
    snprintf(in->name, sizeof in->name, "%s", name);
    in->slot = slot_for(in, instanceName, fmuType, guid, dir, visible, loggingOn);
    if (!in->slot) {
        say_cb(cb, name, fmi2Error, "fmi2Instantiate: the Python slave could not be created from %s "
               "(pythonfmu logs the Python error with loggingOn)", dir);
        mbs_reg_drop(&live, in);
        free(in);
        return NULL;
    }
    in->real = in->slot->real;
    why = refusal(in, __func__);   /* a slave that could not load its scene says why */
    if (why && !*why) return in;
    say_cb(cb, name, fmi2Error, "fmi2Instantiate: %s", why ? why : "the Python slave failed");
    mbs_reg_drop(&live, in);
    in->slot->owner = NULL;
    if (in->phase != BROKEN) R.free_instance(in->real), free(in->slot);   /* else leaked, as after any fatal */
    free(in);
    return NULL;
}

EXPORT void fmi2FreeInstance(fmi2Component c) {
    Inst* in = c ? find(c) : NULL;
    if (!in) {
        if (c) fprintf(stderr, "mbsfmu: %s: not a live instance of this FMU (freed, or another FMU's)\n", __func__);
        return;
    }
    mbs_reg_drop(&live, in);
    in->slot->owner = NULL;
    if (in->phase != BROKEN) {   /* a broken instance is leaked: pythonfmu already released part of it */
        for (size_t i = 0; i < in->nstates; i++) R.free_state(in->real, &in->states[i].handle);
        park(in->slot);
    }
    free(in->states);
    free(in);
}

EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    Inst* in;
    fmi2Status st = enter(c, __func__, LIVE, &in);
    if (st) return st;
    if (n && !cats) return say(in, fmi2Error, "%s: NULL categories", __func__), fmi2Error;
    for (size_t i = 0; i < n; i++) {
        size_t k = 0;
        while (k < NCATEGORIES && !(cats[i] && !strcmp(cats[i], categories[k]))) k++;
        if (k == NCATEGORIES)
            return say(in, fmi2Error, "%s: unknown log category %.80s", __func__, cats[i] ? cats[i] : "(NULL)"),
                   fmi2Error;
    }
    return done(in, __func__, R.set_debug_logging(in->real, on, n, cats));
}

EXPORT fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean td, fmi2Real tol, fmi2Real t0,
                                      fmi2Boolean sd, fmi2Real t1) {
    Inst* in;
    fmi2Status st = enter(c, __func__, P(INSTANTIATED), &in);
    if (st) return st;
    if (!isfinite(t0) || (td && !(isfinite(tol) && tol > 0)) || (sd && !(isfinite(t1) && t1 >= t0)))   /* as native */
        return say(in, fmi2Error, "%s: need a finite start time, a tolerance > 0 and a finite stop time >= start when "
                   "defined (start %g, tolerance %g, stop %g)", __func__, t0, td ? tol : 0.0, sd ? t1 : t0), fmi2Error;
    return done(in, __func__, R.setup_experiment(in->real, td, tol, t0, sd, t1));
}

/* A call without arguments that moves the instance from an `allowed` phase to `next` when pythonfmu agrees. */
static fmi2Status transition(fmi2Component c, const char* fn, unsigned allowed, fmi2Status (*f)(fmi2Component),
                             int next) {
    Inst* in;
    fmi2Status st = enter(c, fn, allowed, &in);
    if (st || (st = done(in, fn, f(in->real))) > fmi2Warning) return st;
    in->phase = next;
    return st;
}

EXPORT fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    return transition(c, __func__, P(INSTANTIATED), R.enter_init, INIT_MODE);
}

EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Inst* in;
    fmi2Status st = enter(c, __func__, P(INIT_MODE), &in);
    if (st) return st;
    st = checked(in, __func__, R.exit_init(in->real));
    if (in->phase != BROKEN) in->phase = st > fmi2Warning ? FAILED : STEP;
    return st;
}

EXPORT fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean no_rollback) {
    Inst* in;
    fmi2Status st = enter(c, __func__, P(STEP), &in);
    if (st) return st;
    if (!isfinite(t) || !isfinite(h) || h <= 0 || t + h == t)   /* as the native FMU (fmi/fmi2.c); FMI 2.0: h > 0 */
        return say(in, fmi2Error, "%s: bad step t=%g, h=%g (need finite t and h > 0 that advances t)", __func__, t, h),
               fmi2Error;
    /* fmi2Discard (the integration failed; the state stays at t) keeps step mode: the master may roll back,
       change inputs, retry or terminate; the slave's reason ("discard: ...") is logged here, since pythonfmu
       passes the slave's messages on only with debug logging. A step the engine refused outright (t is not
       the current time) is fmi2Error with the slave's reason, the instance unchanged, as in the native FMU. */
    if ((st = done(in, __func__, R.do_step(in->real, t, h, no_rollback))) != fmi2Discard) {
        if (st <= fmi2Warning) in->discarded = 0;
        return st;
    }
    const char* why = refusal(in, __func__);
    in->discarded = why && (!*why || !strncmp(why, "discard: ", 9));
    if (!why) return fmi2Fatal;
    if (!strncmp(why, "discard: ", 9)) return say(in, fmi2Discard, "%s: %s", __func__, why + 9), fmi2Discard;
    if (!*why) return say(in, fmi2Discard, "%s: the step failed", __func__), fmi2Discard;
    say(in, fmi2Error, "%s: %s", __func__, why);
    return fmi2Error;
}

EXPORT fmi2Status fmi2Terminate(fmi2Component c) {
    return transition(c, __func__, P(STEP), R.terminate, TERMINATED);
}

EXPORT fmi2Status fmi2Reset(fmi2Component c) {
    Inst* in;
    fmi2Status st = enter(c, __func__, LIVE, &in);
    if (st) return st;
    st = checked(in, __func__, R.reset(in->real));   /* pythonfmu re-creates the slave; it may not load its scene */
    if (in->phase != BROKEN) in->phase = st > fmi2Warning ? FAILED : INSTANTIATED, in->discarded = 0;
    return st;
}

/* ------------------------------------------------------------------------------- variable access */
static const char* type_name(char t) {
    return t == 'R' ? "Real" : t == 'S' ? "String" : t == 'I' ? "Integer" : t == 'B' ? "Boolean" : "Enumeration";
}

/* fmi2OK if every vr[i] is a variable of `type` that may be read (set = 0) or set now, else fmi2Error
   with the first offending reference named in the message. */
static fmi2Status check_refs(Inst* in, const char* fn, const fmi2ValueReference vr[], size_t n,
                             const void* values, char type, int set) {
    if (n && (!vr || !values)) return say(in, fmi2Error, "%s: NULL %s array", fn, vr ? "value" : "value reference"), fmi2Error;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= MBSFMU_NVARS || vars[vr[i]].type == '-')
            return say(in, fmi2Error, "%s: unknown value reference %u (this model has %u variables)", fn, vr[i],
                       MBSFMU_NVARS), fmi2Error;
        const Var* v = &vars[vr[i]];
        if (v->type != type)
            return say(in, fmi2Error, "%s: %s (value reference %u) is a %s variable, not %s", fn, v->name, vr[i],
                       type_name(v->type), type_name(type)), fmi2Error;
        if (!set) continue;
        if (v->causality != 'p' && v->causality != 'i')
            return say(in, fmi2Error, "%s: %s (value reference %u) is not an input or parameter; it cannot be set",
                       fn, v->name, vr[i]), fmi2Error;
        if (in->phase == STEP && v->variability != 't' && v->causality == 'p')
            return say(in, fmi2Error, "%s: %s (value reference %u) is a fixed parameter: set it before "
                       "fmi2ExitInitializationMode", fn, v->name, vr[i]), fmi2Error;
    }
    return fmi2OK;
}

#define GET_OK (LIVE)
#define SET_OK (P(INSTANTIATED) | P(INIT_MODE) | P(STEP))

EXPORT fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Inst* in;
    fmi2Status st = enter(c, __func__, GET_OK, &in);
    if (st || (st = check_refs(in, __func__, vr, n, v, 'R', 0)) || !n) return st;
    return done(in, __func__, R.get_real(in->real, vr, n, v));
}

EXPORT fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    Inst* in;
    fmi2Status st = enter(c, __func__, GET_OK, &in);
    if (!st && !(st = check_refs(in, __func__, vr, n, v, 'S', 0)) && n)
        st = done(in, __func__, R.get_string(in->real, vr, n, v));
    /* hosts that ignore the status (ecos after a failed fmi2Instantiate) would follow garbage pointers */
    for (size_t i = 0; st > fmi2Warning && v && i < n; i++) v[i] = "";
    return st;
}

EXPORT fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    Inst* in;
    fmi2Status st = enter(c, __func__, SET_OK, &in);
    if (st || (st = check_refs(in, __func__, vr, n, v, 'R', 1)) || !n) return st;
    /* a parameter may be refused (its domain, the quantities it derives): the slave says why; inputs alone
       cannot be (a non-finite one is the next step's Discard), so a master's per-step inputs skip the question */
    for (size_t i = 0; i < n; i++)
        if (vars[vr[i]].causality == 'p') return checked(in, __func__, R.set_real(in->real, vr, n, v));
    return done(in, __func__, R.set_real(in->real, vr, n, v));
}

/* 1 if s is valid UTF-8 (pythonfmu's conversion of anything else fails fatally) */
static int utf8(const unsigned char* s) {
    while (*s) {
        int extra = *s < 0x80 ? 0 : (*s & 0xE0) == 0xC0 && *s >= 0xC2 ? 1 : (*s & 0xF0) == 0xE0 ? 2
                    : (*s & 0xF8) == 0xF0 && *s <= 0xF4 ? 3 : -1;
        if (extra < 0) return 0;
        for (s++; extra--; s++)
            if ((*s & 0xC0) != 0x80) return 0;   /* also stops at the terminating 0 */
    }
    return 1;
}

EXPORT fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) {
    Inst* in;
    fmi2Status st = enter(c, __func__, SET_OK, &in);
    if (st || (st = check_refs(in, __func__, vr, n, v, 'S', 1)) || !n) return st;
    for (size_t i = 0; i < n; i++)
        if (!v[i] || !utf8((const unsigned char*)v[i]))
            return say(in, fmi2Error, "%s: the value for %s is %s", __func__, vars[vr[i]].name,
                       v[i] ? "not UTF-8" : "NULL"), fmi2Error;
    return checked(in, __func__, R.set_string(in->real, vr, n, v));
}

/* The model has no Integer or Boolean variables: every reference is refused with its real type. */
#define NO_SUCH_TYPE(fn, T, type, set, allowed)                                                  \
    EXPORT fmi2Status fn(fmi2Component c, const fmi2ValueReference vr[], size_t n, T v) {        \
        Inst* in;                                                                                \
        fmi2Status st = enter(c, __func__, allowed, &in);                                        \
        return st ? st : check_refs(in, __func__, vr, n, v, type, set);                          \
    }
NO_SUCH_TYPE(fmi2GetInteger, fmi2Integer*, 'I', 0, GET_OK)
NO_SUCH_TYPE(fmi2GetBoolean, fmi2Boolean*, 'B', 0, GET_OK)
NO_SUCH_TYPE(fmi2SetInteger, const fmi2Integer*, 'I', 1, SET_OK)
NO_SUCH_TYPE(fmi2SetBoolean, const fmi2Boolean*, 'B', 1, SET_OK)

static fmi2Status unsupported(fmi2Component c, const char* fn, const char* why) {
    Inst* in;
    fmi2Status st = enter(c, fn, LIVE, &in);
    return st ? st : (say(in, fmi2Error, "%s: not supported (%s)", fn, why), fmi2Error);
}

EXPORT fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                               const fmi2ValueReference z[], size_t nz, const fmi2Real du[],
                                               fmi2Real dz[]) {
    (void)u, (void)nu, (void)z, (void)nz, (void)du, (void)dz;
    return unsupported(c, __func__, "providesDirectionalDerivative=false");
}

EXPORT fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                              const fmi2Integer order[], const fmi2Real v[]) {
    (void)vr, (void)n, (void)order, (void)v;
    return unsupported(c, __func__, "canInterpolateInputs=false");
}

EXPORT fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                               const fmi2Integer order[], fmi2Real v[]) {
    (void)vr, (void)n, (void)order, (void)v;
    return unsupported(c, __func__, "maxOutputDerivativeOrder=0");
}

EXPORT fmi2Status fmi2CancelStep(fmi2Component c) {
    return unsupported(c, __func__, "fmi2DoStep is synchronous; there is no step to cancel");
}

/* Status inquiries (FMI 2.0, 4.2.3), answered as the native FMU does: what is not available is fmi2Discard with
   a message; the time of the last successful step comes from pythonfmu; the slave never asks to terminate. */
static fmi2Status status_query(fmi2Component c, const char* fn, const void* value, Inst** in) {
    fmi2Status st = enter(c, fn, P(STEP) | P(TERMINATED) | P(FAILED), in);
    if (!st && !value) {
        say(*in, fmi2Error, "%s: NULL value pointer", fn);
        st = fmi2Error;
    }
    return st;
}

static fmi2Status not_available(Inst* in, const char* fn, int kind) {
    say(in, fmi2Discard, "%s: status kind %d is not available from this FMU", fn, kind);
    return fmi2Discard;
}

EXPORT fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Status* value) {
    Inst* in;
    fmi2Status st = status_query(c, __func__, value, &in);
    return st ? st : not_available(in, __func__, kind);   /* fmi2DoStepStatus: only after fmi2Pending */
}

EXPORT fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Real* value) {
    Inst* in;
    fmi2Status st = status_query(c, __func__, value, &in);
    if (st) return st;
    if (kind != fmi2LastSuccessfulTime) return not_available(in, __func__, kind);
    /* The engine's time, read from the slave's hidden Real after the refusal text, as the native FMU answers: after
       a discarded step the time the integration reached (FMI 2.0: the slave computed a subinterval), where the state
       is and the master goes on. pythonfmu's own answer is the step's start then, and stale after a state restore
       or on a component reused from the pool. */
    fmi2ValueReference time_vr = MBSFMU_NVARS + 1;
    return done(in, __func__, R.get_real(in->real, &time_vr, 1, value));
}

EXPORT fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Integer* value) {
    Inst* in;
    fmi2Status st = status_query(c, __func__, value, &in);
    return st ? st : not_available(in, __func__, kind);
}

EXPORT fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind kind, fmi2Boolean* value) {
    Inst* in;
    fmi2Status st = status_query(c, __func__, value, &in);
    if (st) return st;
    if (kind != fmi2Terminated) return not_available(in, __func__, kind);
    *value = in->discarded;   /* fmi2True after a discarded step, until a good step, reset or restore */
    return fmi2OK;
}

EXPORT fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind kind, fmi2String* value) {
    Inst* in;
    fmi2Status st = status_query(c, __func__, value, &in);
    return st ? st : not_available(in, __func__, kind);
}

/* ------------------------------------------------------------------------------------ FMU states */
static State* find_state(Inst* in, fmi2FMUstate s) {
    for (size_t i = 0; s && i < in->nstates; i++)
        if (in->states[i].handle == s) return &in->states[i];
    return NULL;
}

static fmi2Status keep_state(Inst* in, const char* fn, fmi2FMUstate s, int phase) {
    if (in->nstates == in->capacity) {
        size_t cap = in->capacity ? 2 * in->capacity : 4;
        State* grown = realloc(in->states, cap * sizeof *grown);
        if (!grown) {
            R.free_state(in->real, &s);
            return say(in, fmi2Error, "%s: out of memory", fn), fmi2Error;
        }
        in->states = grown, in->capacity = cap;
    }
    in->states[in->nstates++] = (State){s, phase};
    return fmi2OK;
}

static fmi2Status unknown_state(Inst* in, const char* fn) {
    say(in, fmi2Error, "%s: not an FMU state of this FMU's live instances (never handed out, or freed)", fn);
    return fmi2Error;
}

/* The live instance that holds state handle s (in itself first) and its entry; NULL if none does. A state of
   another instance of this FMU is as good as one's own (same model); handles are compared, never followed. */
typedef struct { fmi2FMUstate handle; State* state; } Held;
static int holds(void* item, void* ctx) {
    Inst* in = item;
    Held* h = ctx;
    return in->phase != BROKEN && (h->state = find_state(in, h->handle)) != NULL;
}

static Inst* holder(Inst* in, fmi2FMUstate s, State** state) {
    Held h = {s, NULL};
    Inst* owner;
    if (!s) return NULL;
    if ((*state = find_state(in, s))) return in;
    owner = mbs_reg_first(&live, holds, &h);
    *state = h.state;
    return owner;
}

/* Restore into `in` a state held by another instance: its bytes, through pythonfmu, into a handle of `in`. */
static fmi2Status set_borrowed(Inst* in, const char* fn, Inst* owner, State* theirs) {
    size_t n = 0;
    fmi2FMUstate mine = NULL;
    fmi2Status st;
    if ((st = done(owner, fn, R.state_size(owner->real, theirs->handle, &n))) > fmi2Warning) return st;
    fmi2Byte* bytes = malloc(n ? n : 1);
    if (!bytes) return say(in, fmi2Error, "%s: out of memory", fn), fmi2Error;
    if ((st = done(owner, fn, R.serialize(owner->real, theirs->handle, bytes, n))) <= fmi2Warning &&
        (st = done(in, fn, R.deserialize(in->real, bytes, n, &mine))) <= fmi2Warning) {
        int phase = theirs->phase;
        if ((st = checked(in, fn, R.set_state(in->real, mine))) <= fmi2Warning) in->phase = phase, in->discarded = 0;
        if (in->phase != BROKEN) R.free_state(in->real, &mine);
    }
    free(bytes);
    return st;
}

EXPORT fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* s) {
    Inst* in;
    fmi2FMUstate got = NULL;
    fmi2Status st = enter(c, __func__, LIVE, &in);
    if (st) return st;
    if (!s) return say(in, fmi2Error, "%s: NULL state pointer", __func__), fmi2Error;
    if (*s && !find_state(in, *s)) return unknown_state(in, __func__);
    if ((st = done(in, __func__, R.get_state(in->real, &got))) > fmi2Warning) return st;
    if (!got) return say(in, fmi2Error, "%s: pythonfmu returned no state", __func__), fmi2Error;
    if (*s) {  /* FMI: a state passed in is overwritten; pythonfmu would leak it */
        State* old = find_state(in, *s);
        old->handle = got, old->phase = in->phase;
        R.free_state(in->real, s);
        *s = got;
        return st;
    }
    if (keep_state(in, __func__, got, in->phase)) return fmi2Error;
    *s = got;
    return st;
}

EXPORT fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) {
    Inst* in;
    fmi2Status st = enter(c, __func__, LIVE, &in);
    if (st) return st;
    State* state;
    Inst* owner = holder(in, s, &state);
    if (!owner) return unknown_state(in, __func__);
    if (owner != in) return set_borrowed(in, __func__, owner, state);
    int phase = state->phase;
    /* the engine checks the payload once more and restores all or nothing: a refusal leaves the phase */
    if ((st = checked(in, __func__, R.set_state(in->real, s))) <= fmi2Warning) in->phase = phase, in->discarded = 0;
    return st;
}

EXPORT fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* s) {
    Inst* in;
    fmi2Status st = enter(c, __func__, LIVE, &in);
    if (st) return st;
    if (!s) return say(in, fmi2Error, "%s: NULL state pointer", __func__), fmi2Error;
    if (!*s) return fmi2OK;
    State* state = find_state(in, *s);
    if (!state) return unknown_state(in, __func__);
    *state = in->states[--in->nstates];
    st = done(in, __func__, R.free_state(in->real, s));
    *s = NULL;
    return st;
}

EXPORT fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t* n) {
    Inst* in;
    fmi2Status st = enter(c, __func__, LIVE, &in);
    if (st) return st;
    State* state;
    Inst* owner = holder(in, s, &state);
    if (!owner) return unknown_state(in, __func__);
    if (!n) return say(in, fmi2Error, "%s: NULL size pointer", __func__), fmi2Error;
    return done(owner, __func__, R.state_size(owner->real, s, n));
}

EXPORT fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte bytes[], size_t n) {
    Inst* in;
    size_t need = 0;
    fmi2Status st = enter(c, __func__, LIVE, &in);
    if (st) return st;
    State* state;
    Inst* owner = holder(in, s, &state);
    if (!owner) return unknown_state(in, __func__);
    if (!bytes) return say(in, fmi2Error, "%s: NULL buffer", __func__), fmi2Error;
    if ((st = done(owner, __func__, R.state_size(owner->real, s, &need))) > fmi2Warning) return st;
    if (n < need)
        return say(in, fmi2Error, "%s: buffer of %zu bytes, the state needs %zu", __func__, n, need), fmi2Error;
    return done(owner, __func__, R.serialize(owner->real, s, bytes, need));  /* pythonfmu copies n bytes */
}

/* The engine's state bytes (state_bytes.c, mbs_state_save): the header of state_header.h, then the payload, which starts
   with its Head {double time, rtol, atol, max_step, step; int32 initialized, method, q_in_active, params_dirty}. */
#define STATE_HEAD (5 * 8 + 4 * 4)

EXPORT fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t n, fmi2FMUstate* s) {
    Inst* in;
    fmi2FMUstate got = NULL;
    int32_t initialized;
    fmi2Status st = enter(c, __func__, LIVE, &in);
    if (st) return st;
    if (!s || (n && !bytes)) return say(in, fmi2Error, "%s: NULL %s", __func__, s ? "bytes" : "state pointer"), fmi2Error;
    const char* why = mbs_state_header_problem(bytes, n, STATE_HEAD, MBSFMU_GUID);
    if (why) return say(in, fmi2Error, "%s: %zu bytes refused: %s; instance unchanged", __func__, n, why), fmi2Error;
    if ((st = done(in, __func__, R.deserialize(in->real, bytes, n, &got))) > fmi2Warning) return st;
    if (!got) return say(in, fmi2Error, "%s: pythonfmu returned no state", __func__), fmi2Error;
    memcpy(&initialized, bytes + MBS_STATE_HEADER + 5 * 8, 4);
    if (keep_state(in, __func__, got, initialized == 1 ? STEP : INSTANTIATED)) return fmi2Error;
    *s = got;
    return st;
}
