/* A plain FMI 2.0 master in C: dlopen an FMU binary, run it, print outputs or timings.
 *
 *   fmu_host LIB RESOURCE_URI GUID [-n steps] [-h step] [-o vr,vr,...] [-s vr=value]... [-S vr=text]...
 *            [-p] [-m] [-T] [-L [-r chunks]] [-C cycles] [-E -x states]
 *
 * -E  model exchange (-x: the number of continuous states, at most 256): n explicit Euler steps of h over fmi2GetDerivatives (x += h·ẋ, then fmi2SetTime,
 *     fmi2SetContinuousStates, fmi2CompletedIntegratorStep) instead of fmi2DoStep
 * -p  print "OUT t v1 v2 ..." (%.17g) at t0 and after every step
 * -m  print "LIBPYTHON yes|no": whether any libpython is mapped into this process (/proc/self/maps)
 * -T  timing: "TIME load_ns first_step_ns" (dlopen; fmi2Instantiate .. end of the first fmi2DoStep)
 * -L  loop cost: "LOOP n points_ns one_ns", each the best of -r chunks (default 20) run alternately on two
 *     instances: n steps of h with the outputs read after each, and one step of n*h (the same internal steps
 *     for fixed-step integrators) with the outputs read once
 * -C  instantiate/free loop (optimizers, Monte Carlo): `cycles` times fmi2Instantiate, initialization, n steps,
 *     fmi2FreeInstance; "RSS k kB" (resident set, /proc/self/statm) after cycle k = cycles/10 and k = cycles
 * Exit codes: 0 ok, 2 usage/dlopen, 3 instantiate, 4 a call failed (its status is printed).
 * Needs only libc (and libdl on old glibc); built by tests/test_fmu_native.py and benchmarks/fmu_speed.py.
 * Also builds for Windows with MinGW-w64 (LoadLibrary for dlopen), to run a win64 DLL under wine.
 */
#define _POSIX_C_SOURCE 200112L
#ifdef _WIN32
#include <windows.h>
#define dlopen(path, flags) ((void *)LoadLibraryA(path))
#define dlsym(lib, name) ((void *)GetProcAddress((HMODULE)(lib), name))
#define dlerror() "LoadLibrary failed"
#else
#include <dlfcn.h>
#include <unistd.h>
#endif
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef unsigned int vr_t;
typedef struct {
    void (*logger)(void *, const char *, int, const char *, const char *, ...);
    void *(*alloc)(size_t, size_t);
    void (*free)(void *);
    void *step_finished, *env;
} Callbacks;
typedef struct {
    void *(*instantiate)(const char *, int, const char *, const char *, const Callbacks *, int, int);
    int (*setup)(void *, int, double, double, int, double);
    int (*enter)(void *), (*exit_init)(void *), (*terminate)(void *);
    int (*do_step)(void *, double, double, int);
    int (*get_real)(void *, const vr_t *, size_t, double *);
    int (*set_real)(void *, const vr_t *, size_t, const double *);
    int (*set_string)(void *, const vr_t *, size_t, const char *const *);
    void (*free_instance)(void *);
    int (*new_discrete_states)(void *, void *), (*enter_continuous)(void *), (*set_time)(void *, double);
    int (*get_states)(void *, double *, size_t), (*set_states)(void *, const double *, size_t);
    int (*get_derivatives)(void *, double *, size_t), (*completed_step)(void *, int, int *, int *);
} Fmi;

static void logger(void *env, const char *inst, int status, const char *cat, const char *msg, ...) {
    va_list ap;
    (void)env;
    printf("LOG %d %s %s: ", status, cat ? cat : "", inst ? inst : "");
    va_start(ap, msg);
    vprintf(msg, ap);
    va_end(ap);
    printf("\n");
    fflush(stdout);
}

static double now_ns(void) {
#ifdef _WIN32
    LARGE_INTEGER c, f;
    QueryPerformanceCounter(&c);
    QueryPerformanceFrequency(&f);
    return (double)c.QuadPart * 1e9 / (double)f.QuadPart;
#else
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e9 + ts.tv_nsec;
#endif
}

#define MAXV 256
static struct { vr_t vr; double v; const char *s; } sets[MAXV];
static int nsets;
static int model_exchange;  /* -E */

/* resident set size in kB (Linux: /proc/self/statm counts pages), -1 where unknown */
static long rss_kb(void) {
    long pages = -1, resident = -1;
    FILE *fp = fopen("/proc/self/statm", "r");
    if (fp && fscanf(fp, "%ld %ld", &pages, &resident) != 2) resident = -1;
    if (fp) fclose(fp);
#ifdef _WIN32
    return -1;
#else
    return resident < 0 ? -1 : resident * (sysconf(_SC_PAGESIZE) / 1024);
#endif
}

static int fail(const char *what, int status) {
    printf("FAIL %s %d\n", what, status);
    fflush(stdout);
    return 4;
}

/* instantiate, apply the -s/-S settings, initialize at t = 0 */
static void *start(const Fmi *f, const char *uri, const char *guid, const Callbacks *cb, int *rc) {
    void *c = f->instantiate("host", model_exchange ? 0 : 1, guid, uri, cb, 0, 0);
    double event_info[8];  /* fmi2EventInfo: five fmi2Booleans and a double (32 bytes; room to spare) */
    int i, st = 0;
    *rc = 0;
    if (!c) {
        printf("FAIL fmi2Instantiate\n");
        *rc = 3;
        return NULL;
    }
    for (i = 0; i < nsets && !st; i++)
        st = sets[i].s ? f->set_string(c, &sets[i].vr, 1, &sets[i].s) : f->set_real(c, &sets[i].vr, 1, &sets[i].v);
    if (st || (st = f->setup(c, 0, 0.0, 0.0, 0, 0.0)) || (st = f->enter(c)) || (st = f->exit_init(c)) ||
        (model_exchange && ((st = f->new_discrete_states(c, event_info)) || (st = f->enter_continuous(c))))) {
        *rc = fail("setup/initialization", st);
        return c;
    }
    return c;
}

/* one explicit Euler step of h from t: x += h·ẋ(t, x) (nx <= MAXV states) */
static int euler_step(const Fmi *f, void *c, double t, double h, size_t nx) {
    double x[MAXV], dx[MAXV];
    int st, event = 0, stop = 0;
    size_t i;
    if ((st = f->get_states(c, x, nx)) || (st = f->get_derivatives(c, dx, nx)))
        return st;
    for (i = 0; i < nx; i++)
        x[i] += h * dx[i];
    if ((st = f->set_time(c, t + h)) || (st = f->set_states(c, x, nx)) || (st = f->completed_step(c, 1, &event, &stop)))
        return st;
    return event || stop ? 9 : 0;
}

int main(int argc, char **argv) {
    const char *lib, *uri, *guid;
    vr_t out[MAXV];
    double y[MAXV], h = 0.01, t = 0, t0, t1, t2;
    int nout = 0, n = 10, reps = 20, print = 0, maps = 0, timing = 0, loop = 0, cycles = 0, i, k, st, rc;
    size_t nx = 0;  /* -x: continuous states (model exchange) */
    Fmi f;
    Callbacks cb = {logger, calloc, free, NULL, NULL};
    void *so, *c;
    if (argc < 4) {
        fprintf(stderr, "usage: %s LIB RESOURCE_URI GUID [-n steps] [-h step] [-o vr,...] [-s vr=x] [-S vr=text]"
                        " [-p] [-m] [-T] [-L]\n", argv[0]);
        return 2;
    }
    lib = argv[1], uri = argv[2], guid = argv[3];
    for (i = 4; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : "";
        if (!strcmp(a, "-n")) n = atoi(v), i++;
        else if (!strcmp(a, "-r")) reps = atoi(v), i++;
        else if (!strcmp(a, "-h")) h = atof(v), i++;
        else if (!strcmp(a, "-o")) {
            for (char *p = (char *)v; *p && nout < MAXV; p += strspn(p, ","))
                out[nout++] = (vr_t)strtoul(p, &p, 10);
            i++;
        } else if ((!strcmp(a, "-s") || !strcmp(a, "-S")) && nsets < MAXV && strchr(v, '=')) {
            sets[nsets].vr = (vr_t)strtoul(v, NULL, 10);
            sets[nsets].s = a[1] == 'S' ? strchr(v, '=') + 1 : NULL;
            sets[nsets++].v = atof(strchr(v, '=') + 1);
            i++;
        } else if (!strcmp(a, "-p")) print = 1;
        else if (!strcmp(a, "-m")) maps = 1;
        else if (!strcmp(a, "-T")) timing = 1;
        else if (!strcmp(a, "-L")) loop = 1;
        else if (!strcmp(a, "-C")) cycles = atoi(v), i++;
        else if (!strcmp(a, "-E")) model_exchange = 1;
        else if (!strcmp(a, "-x")) nx = (size_t)atoi(v), i++;
        else { fprintf(stderr, "unknown option %s\n", a); return 2; }
    }

    if (nx > MAXV) { fprintf(stderr, "at most %d continuous states\n", MAXV); return 2; }
    t0 = now_ns();
    so = dlopen(lib, RTLD_NOW | RTLD_LOCAL);
    if (!so) { printf("DLOPEN %s\n", dlerror()); return 2; }
    *(void **)&f.instantiate = dlsym(so, "fmi2Instantiate");
    *(void **)&f.setup = dlsym(so, "fmi2SetupExperiment");
    *(void **)&f.enter = dlsym(so, "fmi2EnterInitializationMode");
    *(void **)&f.exit_init = dlsym(so, "fmi2ExitInitializationMode");
    *(void **)&f.terminate = dlsym(so, "fmi2Terminate");
    *(void **)&f.do_step = dlsym(so, "fmi2DoStep");
    *(void **)&f.get_real = dlsym(so, "fmi2GetReal");
    *(void **)&f.set_real = dlsym(so, "fmi2SetReal");
    *(void **)&f.set_string = dlsym(so, "fmi2SetString");
    *(void **)&f.free_instance = dlsym(so, "fmi2FreeInstance");
    *(void **)&f.new_discrete_states = dlsym(so, "fmi2NewDiscreteStates");
    *(void **)&f.enter_continuous = dlsym(so, "fmi2EnterContinuousTimeMode");
    *(void **)&f.set_time = dlsym(so, "fmi2SetTime");
    *(void **)&f.get_states = dlsym(so, "fmi2GetContinuousStates");
    *(void **)&f.set_states = dlsym(so, "fmi2SetContinuousStates");
    *(void **)&f.get_derivatives = dlsym(so, "fmi2GetDerivatives");
    *(void **)&f.completed_step = dlsym(so, "fmi2CompletedIntegratorStep");
    if (!f.instantiate || !f.do_step || !f.get_real || !f.free_instance) { printf("DLSYM missing\n"); return 2; }
    if (model_exchange && (!f.new_discrete_states || !f.enter_continuous || !f.set_time || !f.get_states ||
                           !f.set_states || !f.get_derivatives || !f.completed_step)) {
        printf("DLSYM model exchange missing\n");
        return 2;
    }
    t1 = now_ns();

    for (k = 1; k <= cycles; k++) {  /* each instance freed before the next: memory must stay flat */
        double tc = 0;
        c = start(&f, uri, guid, &cb, &rc);
        if (rc) return rc;
        for (i = 0; i < n; i++, tc += h)
            if ((st = f.do_step(c, tc, h, 1))) return fail("fmi2DoStep", st);
        f.free_instance(c);
        if (k == cycles / 10 || k == cycles) printf("RSS %d %ld\n", k, rss_kb());
    }
    c = start(&f, uri, guid, &cb, &rc);
    if (rc) return rc;
    if (print) {
        if ((st = f.get_real(c, out, nout, y))) return fail("fmi2GetReal", st);
        printf("OUT %.17g", t);
        for (k = 0; k < nout; k++) printf(" %.17g", y[k]);
        printf("\n");
    }
    for (i = 0; i < n; i++) {
        if (model_exchange) {
            if ((st = euler_step(&f, c, t, h, nx))) return fail("Euler step", st);
        } else if ((st = f.do_step(c, t, h, 1))) return fail("fmi2DoStep", st);
        if (i == 0 && timing) {
            t2 = now_ns();
            printf("TIME %.0f %.0f\n", t1 - t0, t2 - t1);
        }
        t += h;  /* accumulated, like ecos's fixed-step master */
        if ((st = f.get_real(c, out, nout, y))) return fail("fmi2GetReal", st);
        if (print) {
            printf("OUT %.17g", t);
            for (k = 0; k < nout; k++) printf(" %.17g", y[k]);
            printf("\n");
        }
    }
    if (loop) {  /* chunks of n points of h against one step of n*h, alternating, on two fresh instances */
        void *a = start(&f, uri, guid, &cb, &rc), *b;
        double ta, tb, sa = 0, sb = 0, best_a = 1e300, best_b = 1e300;
        if (rc) return rc;
        b = start(&f, uri, guid, &cb, &rc);
        if (rc) return rc;
        for (k = 0; k < reps; k++) {
            ta = now_ns();
            for (i = 0; i < n; i++) {
                if ((st = f.do_step(a, sa, h, 1)) || (st = f.get_real(a, out, nout, y))) return fail("loop", st);
                sa += h;
            }
            ta = now_ns() - ta;
            tb = now_ns();
            if ((st = f.do_step(b, sb, n * h, 1)) || (st = f.get_real(b, out, nout, y))) return fail("one step", st);
            tb = now_ns() - tb;
            sb += n * h;
            best_a = ta < best_a ? ta : best_a;
            best_b = tb < best_b ? tb : best_b;
        }
        printf("LOOP %d %.0f %.0f\n", n, best_a, best_b);
        f.free_instance(a);
        f.free_instance(b);
    }
    if (maps) {
        FILE *fp = fopen("/proc/self/maps", "r");
        char line[4096];
        int found = 0;
        while (fp && fgets(line, sizeof line, fp))
            found |= strstr(line, "libpython") != NULL;
        if (fp) fclose(fp);
        printf("LIBPYTHON %s\n", fp ? (found ? "yes" : "no") : "unknown");
    }
    if ((st = f.terminate(c))) return fail("fmi2Terminate", st);
    f.free_instance(c);
    printf("DONE\n");
    return 0;
}
