/* A plain FMI 3.0 importer in C: dlopen an FMU binary, run it as co-simulation or model exchange, print outputs.
 *
 *   fmu3_host LIB RESOURCE_PATH TOKEN [-n steps] [-h step] [-o vr[:values],vr,...] [-E] [-m]
 *
 * co-simulation (default): fmi3DoStep n times; -E: model exchange, n explicit Euler steps x += h·ẋ over
 * fmi3GetContinuousStateDerivatives (fmi3SetTime, fmi3SetContinuousStates, fmi3CompletedIntegratorStep).
 * -o: the outputs to print, each with the number of values it holds (an array's elements; default 1).
 * Prints "OUT t v1 v2 ..." (%.17g) at t0 and after every step, "DONE" at the end; -m first prints
 * "LIBPYTHON yes|no": whether any libpython is mapped into this process (/proc/self/maps).
 * Exit codes: 0 ok, 2 usage/dlopen, 3 instantiate, 4 a call failed (its status is printed).
 * Needs only libc (and libdl on old glibc); built by tests/test_fmu3.py (tests/c/fmu_host.c is the FMI 2.0 one).
 */
#define _POSIX_C_SOURCE 200112L
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef unsigned int vr_t;
typedef void (*LogMessage)(void *env, int status, const char *category, const char *message);
typedef void *(*InstantiateCS)(const char *, const char *, const char *, int, int, int, int, const vr_t *, size_t,
                               void *, LogMessage, void *);
typedef void *(*InstantiateME)(const char *, const char *, const char *, int, int, void *, LogMessage);

static void logger(void *env, int status, const char *category, const char *message) {
    (void)env;
    printf("LOG %d %s: %s\n", status, category ? category : "", message ? message : "");
    fflush(stdout);
}

static int fail(const char *what, int status) {
    printf("FAIL %s %d\n", what, status);
    fflush(stdout);
    return 4;
}

static void *sym(void *so, const char *name) {
    void *p = dlsym(so, name);
    if (!p) {
        printf("DLSYM %s\n", name);
        exit(2);
    }
    return p;
}

static int libpython_mapped(void) {
    char line[4096];
    int found = 0;
    FILE *fp = fopen("/proc/self/maps", "r");
    while (fp && fgets(line, sizeof line, fp))
        found |= strstr(line, "libpython") != NULL;
    if (fp) fclose(fp);
    return found;
}

#define MAXV 256
int main(int argc, char **argv) {
    vr_t out[MAXV];
    double y[MAXV], h = 0.01, t = 0.0, *x = NULL, *dx = NULL;
    int nout = 0, nvalues = 0, n = 10, me = 0, maps = 0, i, k, st;
    size_t nx = 0;
    void *so, *c;
    int (*enter)(void *, int, double, double, int, double), (*exit_init)(void *), (*terminate)(void *);
    int (*get)(void *, const vr_t *, size_t, double *, size_t);
    void (*free_instance)(void *);
    if (argc < 4) {
        fprintf(stderr, "usage: %s LIB RESOURCE_PATH TOKEN [-n steps] [-h step] [-o vr[:values],...] [-E] [-m]\n", argv[0]);
        return 2;
    }
    for (i = 4; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : "";
        if (!strcmp(a, "-n")) n = atoi(v), i++;
        else if (!strcmp(a, "-h")) h = atof(v), i++;
        else if (!strcmp(a, "-o")) {
            for (char *p = (char *)v; *p && nout < MAXV; p += strspn(p, ",")) {
                out[nout++] = (vr_t)strtoul(p, &p, 10);
                nvalues += *p == ':' ? (int)strtoul(p + 1, &p, 10) : 1;
            }
            if (nvalues > MAXV) { fprintf(stderr, "more than %d values\n", MAXV); return 2; }
            i++;
        } else if (!strcmp(a, "-E")) me = 1;
        else if (!strcmp(a, "-m")) maps = 1;
        else { fprintf(stderr, "unknown option %s\n", a); return 2; }
    }
    if (!(so = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL))) {
        printf("DLOPEN %s\n", dlerror());
        return 2;
    }
    if (maps) printf("LIBPYTHON %s\n", libpython_mapped() ? "yes" : "no");
    enter = sym(so, "fmi3EnterInitializationMode");
    exit_init = sym(so, "fmi3ExitInitializationMode");
    terminate = sym(so, "fmi3Terminate");
    get = sym(so, "fmi3GetFloat64");
    free_instance = sym(so, "fmi3FreeInstance");
    c = me ? ((InstantiateME)sym(so, "fmi3InstantiateModelExchange"))("host", argv[3], argv[2], 0, 0, NULL, logger)
           : ((InstantiateCS)sym(so, "fmi3InstantiateCoSimulation"))("host", argv[3], argv[2], 0, 0, 0, 0, NULL, 0,
                                                                      NULL, logger, NULL);
    if (!c) {
        printf("FAIL instantiate\n");
        return 3;
    }
    if ((st = enter(c, 0, 0.0, 0.0, 0, 0.0)) || (st = exit_init(c)))
        return fail("initialization", st);
    if (me) {
        int (*update)(void *, char *, char *, char *, char *, char *, double *) = sym(so, "fmi3UpdateDiscreteStates");
        int (*cont)(void *) = sym(so, "fmi3EnterContinuousTimeMode");
        int (*count)(void *, size_t *) = sym(so, "fmi3GetNumberOfContinuousStates");
        char b[5];
        double next;
        /* fmi3Boolean is C's bool: one byte each */
        if ((st = update(c, b, b + 1, b + 2, b + 3, b + 4, &next)) || (st = cont(c)) || (st = count(c, &nx)))
            return fail("event mode", st);
        x = calloc(nx + 1, sizeof *x), dx = calloc(nx + 1, sizeof *dx);
        if (!x || !dx || (st = ((int (*)(void *, double *, size_t))sym(so, "fmi3GetContinuousStates"))(c, x, nx)))
            return fail("fmi3GetContinuousStates", st);
    }
    for (k = 0; k <= n; k++) {
        if (k > 0 && !me) {
            char event, term, early;
            double last;
            double next = k * h;  /* the step reaches the k-th point exactly (as fmpy's master steps) */
            if ((st = ((int (*)(void *, double, double, int, char *, char *, char *, double *))sym(so, "fmi3DoStep"))(
                     c, t, next - t, 1, &event, &term, &early, &last)))
                return fail("fmi3DoStep", st);
            t = next;
        } else if (k > 0) {
            char enter_event, term;
            if ((st = ((int (*)(void *, double *, size_t))sym(so, "fmi3GetContinuousStateDerivatives"))(c, dx, nx)))
                return fail("fmi3GetContinuousStateDerivatives", st);
            for (size_t j = 0; j < nx; j++) x[j] += h * dx[j];
            t = k * h;
            if ((st = ((int (*)(void *, double))sym(so, "fmi3SetTime"))(c, t)) ||
                (st = ((int (*)(void *, const double *, size_t))sym(so, "fmi3SetContinuousStates"))(c, x, nx)) ||
                (st = ((int (*)(void *, int, char *, char *))sym(so, "fmi3CompletedIntegratorStep"))(c, 1, &enter_event,
                                                                                                     &term)))
                return fail("model exchange step", st);
        }
        if (nout && (st = get(c, out, (size_t)nout, y, (size_t)nvalues)))
            return fail("fmi3GetFloat64", st);
        printf("OUT %.17g", t);
        for (i = 0; i < nvalues; i++) printf(" %.17g", y[i]);
        printf("\n");
    }
    if ((st = terminate(c)))
        return fail("fmi3Terminate", st);
    free_instance(c);
    free(x), free(dx);
    printf("DONE\n");
    return 0;
}
