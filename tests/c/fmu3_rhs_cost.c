/* Cost of model exchange through the FMI 3.0 layer against the engine in-process (issue 27's target: within
 * 1.3x): fmi3SetContinuousStates + fmi3GetContinuousStateDerivatives of a native FMI 3.0 FMU, and mbs_rhs of the
 * in-process engine library on the same compiled scene, each 200,000 times at states that differ in the last bits
 * (no cached derivative), best of 5.
 *
 *   cc -O2 -std=c99 -o fmu3_rhs_cost tests/c/fmu3_rhs_cost.c -ldl
 *   ./fmu3_rhs_cost FMU/binaries/x86_64-linux/ID.so FMU/resources/ TOKEN ENGINE_LIB FMU/resources/scene.bin
 *
 * ENGINE_LIB: python -m mbsfmu.engine.build prints it; TOKEN: the modelDescription's instantiationToken.
 */
#define _POSIX_C_SOURCE 200112L
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
typedef void (*LogMessage)(void *, int, const char *, const char *);
static void lg(void *e, int s, const char *c, const char *m) { (void)e; printf("LOG %d %s %s\n", s, c, m); }
static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }
int main(int argc, char **argv) {
    if (argc < 6) { fprintf(stderr, "usage: %s FMU_LIB RESOURCES TOKEN ENGINE_LIB SCENE_BIN\n", argv[0]); return 2; }
    void *so = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL), *eng = dlopen(argv[4], RTLD_NOW | RTLD_LOCAL);
    if (!so || !eng) { printf("dlopen %s\n", dlerror()); return 2; }
    void *(*inst)(const char *, const char *, const char *, int, int, void *, LogMessage) =
        dlsym(so, "fmi3InstantiateModelExchange");
    int (*enter)(void *, int, double, double, int, double) = dlsym(so, "fmi3EnterInitializationMode");
    int (*exit_)(void *) = dlsym(so, "fmi3ExitInitializationMode");
    int (*upd)(void *, char *, char *, char *, char *, char *, double *) = dlsym(so, "fmi3UpdateDiscreteStates");
    int (*cont)(void *) = dlsym(so, "fmi3EnterContinuousTimeMode");
    int (*nx_)(void *, size_t *) = dlsym(so, "fmi3GetNumberOfContinuousStates");
    int (*getx)(void *, double *, size_t) = dlsym(so, "fmi3GetContinuousStates");
    int (*setx)(void *, const double *, size_t) = dlsym(so, "fmi3SetContinuousStates");
    int (*der)(void *, double *, size_t) = dlsym(so, "fmi3GetContinuousStateDerivatives");
    void *c = inst("b", argv[3], argv[2], 0, 0, NULL, lg);
    char b[5]; double ne; size_t n;
    enter(c, 0, 0, 0, 0, 0); exit_(c); upd(c, b, b + 1, b + 2, b + 3, b + 4, &ne); cont(c); nx_(c, &n);
    double *x = calloc(n, 8), *dx = calloc(n, 8), s = 0; getx(c, x, n);
    int N = 200000;
    double best_fmu = 1e9, best_eng = 1e9;
    /* in-process engine: the same model, mbs_rhs */
    void *(*load)(const char *, char *, size_t) = dlsym(eng, "mbs_model_load_file");
    void *(*newi)(void *, void *, void *) = dlsym(eng, "mbs_instance_new");
    int (*init)(void *, double) = dlsym(eng, "mbs_initialize");
    int (*rhs)(void *, double, const double *, double *) = dlsym(eng, "mbs_rhs");
    char err[256]; void *m = load(argv[5], err, sizeof err); void *e = newi(m, NULL, NULL); init(e, 0.0);
    for (int rep = 0; rep < 5; rep++) {
        double t0 = now();
        for (int i = 0; i < N; i++) { x[0] += 1e-12; setx(c, x, n); der(c, dx, n); s += dx[0]; }
        double t1 = now();
        for (int i = 0; i < N; i++) { x[0] += 1e-12; rhs(e, 0.0, x, dx); s += dx[0]; }
        double t2 = now();
        if (t1 - t0 < best_fmu) best_fmu = t1 - t0;
        if (t2 - t1 < best_eng) best_eng = t2 - t1;
    }
    printf("states %zu: fmi3 set+derivatives %.3f us, engine mbs_rhs %.3f us, ratio %.2f%s\n", n, best_fmu / N * 1e6,
           best_eng / N * 1e6, best_fmu / best_eng, s == s ? "" : " (NaN)");
    return 0;
}
