/* The engine's right-hand side in a C loop (benchmarks/tree_speed.py): the cost of mbs_rhs without Python.
 *
 *   rhs_loop ENGINE.so SCENE.bin X.bin CALLS BATCHES [column]   → prints "RHS <µs per call of the best batch>"
 *
 * With `column` (benchmarks/directional_cost.py), batches of mbs_rhs and of one directional derivative column (the host's
 * calls: set the state, then J·seed of every der(·) along a seed over all states) alternate, and it prints
 * "RHS <µs> COLUMN <µs>".
 *
 * Many short batches: on a shared machine the best one is the one no other process interrupted.
 * X.bin: one or more states [y; ẏ] as little-endian doubles, called in turn (the engine keeps its kinematics
 * while the state's bits stay the same: a single state would time that cache). The engine library is opened
 * with dlopen (the in-process one of mbsfmu.engine.build.library_path), so that this loop runs exactly the code
 * ctypes calls. */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

typedef void *(*load_fn)(const char *, char *, size_t);
typedef void *(*new_fn)(const void *, void *, void *);
typedef int (*rhs_fn)(void *, double, const double *, double *);
typedef int (*count_fn)(const void *);
typedef int (*init_fn)(void *, double);
typedef int (*set_state_fn)(void *, const double *, size_t);
typedef int (*dir_fn)(void *, const unsigned *, size_t, const unsigned *, size_t, const double *, double *);

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

int main(int argc, char **argv) {
    if (argc != 6 && argc != 7) {
        fprintf(stderr, "usage: rhs_loop ENGINE.so SCENE.bin X.bin CALLS BATCHES [column]\n");
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
    const int column = argc == 7;
    unsigned *known = NULL, *unknown = NULL;
    size_t nk = 0, nu = 0;
    double *seed = NULL, *sens = NULL;
    dir_fn dir = (dir_fn)dlsym(lib, "mbs_directional_derivative");
    set_state_fn set_state = (set_state_fn)dlsym(lib, "mbs_set_state");
    if (column) {  /* knowns: the states y.*, yd.*; unknowns: their derivatives der(·) */
        count_fn nvars = (count_fn)dlsym(lib, "mbs_model_nvars");
        typedef const char *(*name_fn)(const void *, int);
        name_fn vname = (name_fn)dlsym(lib, "mbs_model_var_name");
        int nv = nvars(m);
        known = malloc(nv * sizeof *known), unknown = malloc(nv * sizeof *unknown);
        seed = malloc(nv * sizeof *seed), sens = malloc(nv * sizeof *sens);
        for (int vr = 0; vr < nv; vr++) {
            const char *name = vname(m, vr);
            if (!strncmp(name, "y.", 2) || !strncmp(name, "yd.", 3)) { seed[nk] = 1.0 / (1.0 + nk); known[nk++] = vr; }
            else if (!strncmp(name, "der(", 4)) unknown[nu++] = vr;
        }
        if (((init_fn)dlsym(lib, "mbs_initialize"))(s, 0.0) > 1) { fprintf(stderr, "mbs_initialize failed\n"); return 1; }
    }
    double best = 1e300, best_col = 1e300;
    for (long b = 0; b < batches; b++) {
        double t0 = now();
        for (long k = 0, j = 0; k < calls; k++, j = j + 1 < states ? j + 1 : 0)
            if (rhs(s, 0.0, x + j * n, xdot) > 1) {
                fprintf(stderr, "mbs_rhs failed\n");
                return 1;
            }
        double dt = (now() - t0) / calls;
        if (dt < best) best = dt;
        if (!column) continue;
        t0 = now();
        for (long k = 0, j = 0; k < calls; k++, j = j + 1 < states ? j + 1 : 0)
            if (set_state(s, x + j * n, n) > 1 || dir(s, unknown, nu, known, nk, seed, sens) > 1) {
                fprintf(stderr, "mbs_directional_derivative failed\n");
                return 1;
            }
        dt = (now() - t0) / calls;
        if (dt < best_col) best_col = dt;
    }
    if (column) printf("RHS %.6g COLUMN %.6g\n", best * 1e6, best_col * 1e6);
    else printf("RHS %.6g\n", best * 1e6);
    return 0;
}
