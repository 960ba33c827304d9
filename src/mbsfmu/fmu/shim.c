/* mbsfmu FMI 2.0 loader shim (generated from src/mbsfmu/fmu/shim.c; do not edit in an FMU).
 *
 * This library is the FMU binary a host loads. It forwards every fmi2* function to the real
 * pythonfmu binary next to it (MBSFMU_REAL_LIBRARY, loaded RTLD_LOCAL), after making sure that
 *   1. a Python runtime is available with global symbols (pythonfmu's binary does not link
 *      libpython): the one already in the process, else the libpython recorded at build time
 *      (MBSFMU_LIBPYTHON), else its soname (MBSFMU_LIBPYTHON_SONAME) from the default search path;
 *   2. the interpreter is initialized by *this* shim (from the host's thread, signal handlers left
 *      alone) and never finalized: pythonfmu then skips its own Py_Initialize/Py_Finalize, whose
 *      finalization from a worker thread with numpy loaded aborts C hosts at exit.
 * When no Python can be loaded, fmi2Instantiate logs the reason through the FMI logger and
 * returns NULL.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <pthread.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <wchar.h>

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
typedef int fmi2Status;   /* fmi2OK=0 Warning Discard Error Fatal Pending */
typedef int fmi2Type;
typedef int fmi2StatusKind;
typedef void (*fmi2CallbackLogger)(fmi2ComponentEnvironment, fmi2String, fmi2Status, fmi2String,
                                   fmi2String, ...);
typedef struct {
    fmi2CallbackLogger logger;
    void* (*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void*);
    void (*stepFinished)(fmi2ComponentEnvironment, fmi2Status);
    fmi2ComponentEnvironment componentEnvironment;
} fmi2CallbackFunctions;

#define fmi2Error 3

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
                     "shared libpython, with numpy and scipy) at the same path as on the build "
                     "machine (%s), or its libpython on the library search path.",
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
    real = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!real) {
        snprintf(error, sizeof error, "mbsfmu: cannot load %s: %s", path, dlerror());
        return -1;
    }
    real_finalize = (void (*)(void))dlsym(real, "finalizePythonInterpreter");
    if (real_finalize) atexit(release_pystate);   /* see release_pystate */
    return 0;
}

static void* sym(const char* name) {
    void* f = real ? dlsym(real, name) : NULL;
    if (!f) {
        fprintf(stderr, "mbsfmu: %s missing in the pythonfmu binary\n", name);
        abort();
    }
    return f;
}

#define FWD(ret, name, params, args)                                   \
    EXPORT ret name params {                                           \
        static ret(*f) params = NULL;                                  \
        if (!f) f = (ret(*) params)sym(#name);                         \
        return f args;                                                 \
    }

EXPORT const char* fmi2GetTypesPlatform(void) { return "default"; }
EXPORT const char* fmi2GetVersion(void) { return "2.0"; }

EXPORT fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String guid,
                                     fmi2String resources, const fmi2CallbackFunctions* cb,
                                     fmi2Boolean visible, fmi2Boolean loggingOn) {
    pthread_mutex_lock(&lock);
    int ok = ensure_python() == 0 && load_real() == 0;
    pthread_mutex_unlock(&lock);
    if (!ok) {
        if (cb && cb->logger)
            cb->logger(cb->componentEnvironment, instanceName ? instanceName : "", fmi2Error,
                       "logStatusError", "%s", error);
        else
            fprintf(stderr, "%s\n", error);
        return NULL;
    }
    fmi2Component (*f)(fmi2String, fmi2Type, fmi2String, fmi2String, const fmi2CallbackFunctions*,
                       fmi2Boolean, fmi2Boolean) =
        (fmi2Component(*)(fmi2String, fmi2Type, fmi2String, fmi2String,
                          const fmi2CallbackFunctions*, fmi2Boolean, fmi2Boolean))sym("fmi2Instantiate");
    return f(instanceName, fmuType, guid, resources, cb, visible, loggingOn);
}

EXPORT void fmi2FreeInstance(fmi2Component c) {
    static void (*f)(fmi2Component) = NULL;
    if (!c) return;
    if (!f) f = (void (*)(fmi2Component))sym("fmi2FreeInstance");
    f(c);
}

FWD(fmi2Status, fmi2SetDebugLogging, (fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]), (c, on, n, cats))
FWD(fmi2Status, fmi2SetupExperiment, (fmi2Component c, fmi2Boolean td, fmi2Real tol, fmi2Real t0, fmi2Boolean sd, fmi2Real t1), (c, td, tol, t0, sd, t1))
FWD(fmi2Status, fmi2EnterInitializationMode, (fmi2Component c), (c))
FWD(fmi2Status, fmi2ExitInitializationMode, (fmi2Component c), (c))
FWD(fmi2Status, fmi2Terminate, (fmi2Component c), (c))
FWD(fmi2Status, fmi2Reset, (fmi2Component c), (c))
FWD(fmi2Status, fmi2GetReal, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]), (c, vr, n, v))
FWD(fmi2Status, fmi2GetInteger, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]), (c, vr, n, v))
FWD(fmi2Status, fmi2GetBoolean, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]), (c, vr, n, v))
FWD(fmi2Status, fmi2GetString, (fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]), (c, vr, n, v))
FWD(fmi2Status, fmi2SetReal, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]), (c, vr, n, v))
FWD(fmi2Status, fmi2SetInteger, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]), (c, vr, n, v))
FWD(fmi2Status, fmi2SetBoolean, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]), (c, vr, n, v))
FWD(fmi2Status, fmi2SetString, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]), (c, vr, n, v))
FWD(fmi2Status, fmi2GetFMUstate, (fmi2Component c, fmi2FMUstate* s), (c, s))
FWD(fmi2Status, fmi2SetFMUstate, (fmi2Component c, fmi2FMUstate s), (c, s))
FWD(fmi2Status, fmi2FreeFMUstate, (fmi2Component c, fmi2FMUstate* s), (c, s))
FWD(fmi2Status, fmi2SerializedFMUstateSize, (fmi2Component c, fmi2FMUstate s, size_t* n), (c, s, n))
FWD(fmi2Status, fmi2SerializeFMUstate, (fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n), (c, s, b, n))
FWD(fmi2Status, fmi2DeSerializeFMUstate, (fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate* s), (c, b, n, s))
FWD(fmi2Status, fmi2GetDirectionalDerivative, (fmi2Component c, const fmi2ValueReference u[], size_t nu, const fmi2ValueReference z[], size_t nz, const fmi2Real dv[], fmi2Real dz[]), (c, u, nu, z, nz, dv, dz))
FWD(fmi2Status, fmi2SetRealInputDerivatives, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], const fmi2Real v[]), (c, vr, n, o, v))
FWD(fmi2Status, fmi2GetRealOutputDerivatives, (fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], fmi2Real v[]), (c, vr, n, o, v))
FWD(fmi2Status, fmi2DoStep, (fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean nsp), (c, t, h, nsp))
FWD(fmi2Status, fmi2CancelStep, (fmi2Component c), (c))
FWD(fmi2Status, fmi2GetStatus, (fmi2Component c, fmi2StatusKind k, fmi2Status* v), (c, k, v))
FWD(fmi2Status, fmi2GetRealStatus, (fmi2Component c, fmi2StatusKind k, fmi2Real* v), (c, k, v))
FWD(fmi2Status, fmi2GetIntegerStatus, (fmi2Component c, fmi2StatusKind k, fmi2Integer* v), (c, k, v))
FWD(fmi2Status, fmi2GetBooleanStatus, (fmi2Component c, fmi2StatusKind k, fmi2Boolean* v), (c, k, v))
FWD(fmi2Status, fmi2GetStringStatus, (fmi2Component c, fmi2StatusKind k, fmi2String* v), (c, k, v))
