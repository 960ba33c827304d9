/* The engine's right-hand side in a C loop (bench/tree_speed.py): the cost of mbs_rhs without Python.
 *
 *   rhs_loop ENGINE.so SCENE.bin X.bin CALLS BATCHES   → prints "RHS <µs per call of the best batch>"
 *
 * Many short batches: on a shared machine the best one is the one no other process interrupted.
 * X.bin: one or more states [y; ẏ] as little-endian doubles, called in turn (the engine keeps its kinematics
 * while the state's bits stay the same: a single state would time that cache). The engine library is opened
 * with dlopen (the in-process one of mbsfmu.engine.build.library_path), so that this loop runs exactly the code
 * ctypes calls. */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

typedef void *(*load_fn)(const char *, char *, size_t);
typedef void *(*new_fn)(const void *, void *, void *);
typedef int (*rhs_fn)(void *, double, const double *, double *);
typedef int (*count_fn)(const void *);

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

int main(int argc, char **argv) {
    if (argc != 6) {
        fprintf(stderr, "usage: rhs_loop ENGINE.so SCENE.bin X.bin CALLS BATCHES\n");
        return 2;
    }
    void *lib = dlopen(argv[1], RTLD_NOW);
    if (!lib) {
        fprintf(stderr, "%s\n", dlerror());
        return 1;
    }
    load_fn load = (load_fn)dlsym(lib, "mbs_model_load_file");
    new_fn inst_new = (new_fn)dlsym(lib, "mbs_instance_new");
    rhs_fn rhs = (rhs_fn)dlsym(lib, "mbs_rhs");
    count_fn npos = (count_fn)dlsym(lib, "mbs_model_npos"), nvel = (count_fn)dlsym(lib, "mbs_model_nvel");
    char err[1024];
    void *m = load(argv[2], err, sizeof err);
    if (!m) {
        fprintf(stderr, "%s\n", err);
        return 1;
    }
    void *s = inst_new(m, NULL, NULL);
    if (!s) { /* no mbs_initialize: mbs_rhs needs none (and auto's radau5 workspace is refused for large trees) */
        fprintf(stderr, "instance\n");
        return 1;
    }
    long n = npos(m) + nvel(m), states = 0;
    FILE *f = fopen(argv[3], "rb");
    if (f && !fseek(f, 0, SEEK_END)) states = ftell(f) / (long)(n * sizeof(double));
    double *x = states > 0 ? malloc(states * n * sizeof *x) : NULL, *xdot = malloc(n * sizeof *xdot);
    if (!x || !xdot || fseek(f, 0, SEEK_SET) || fread(x, sizeof *x, states * n, f) != (size_t)(states * n)) {
        fprintf(stderr, "states: a multiple of %ld doubles expected\n", n);
        return 1;
    }
    fclose(f);
    long calls = atol(argv[4]), batches = atol(argv[5]);
    double best = 1e300;
    for (long b = 0; b < batches; b++) {
        double t0 = now();
        for (long k = 0, j = 0; k < calls; k++, j = j + 1 < states ? j + 1 : 0)
            if (rhs(s, 0.0, x + j * n, xdot) > 1) {
                fprintf(stderr, "mbs_rhs failed\n");
                return 1;
            }
        double dt = (now() - t0) / calls;
        if (dt < best) best = dt;
    }
    printf("RHS %.6g\n", best * 1e6);
    return 0;
}
