/* FMI 2.0 co-simulation instances of one FMU on threads, one instance per thread (what the standard allows), for
 * ThreadSanitizer (tests/test_fmu_threads.py builds the FMU's sources and this host with -fsanitize=thread):
 *
 *   fmu_threads LIB RESOURCE_URI GUID [rounds]
 *
 * Thread 0 keeps one instance, steps it and takes its FMU state again and again into the state it got before
 * (fmi2GetFMUstate with that state: the state is handed to its owner again); threads 1..3 each instantiate,
 * initialize, step, take a state and free the instance, `rounds` times (fmi2FreeInstance frees the states the
 * instance handed out: a scan of the FMU's registry of states, thread 0's among them).
 * Prints "DONE" and exits 0; 2: usage or dlopen, 3: instantiate failed, 4: a call failed. */
#define _POSIX_C_SOURCE 200112L
#include <dlfcn.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>

typedef struct {
    void (*logger)(void *, const char *, int, const char *, const char *, ...);
    void *(*alloc)(size_t, size_t);
    void (*free)(void *);
    void *step_finished, *env;
} Callbacks;

static void *(*instantiate)(const char *, int, const char *, const char *, const Callbacks *, int, int);
static int (*setup)(void *, int, double, double, int, double);
static int (*enter)(void *), (*exit_init)(void *), (*do_step)(void *, double, double, int);
static int (*get_state)(void *, void **), (*free_state)(void *, void **);
static void (*free_instance)(void *);
static const char *uri, *guid;
static int rounds = 200;

static void logger(void *env, const char *inst, int status, const char *cat, const char *msg, ...)
{
    (void)env;
    fprintf(stderr, "LOG %d %s %s: %s\n", status, cat ? cat : "", inst ? inst : "", msg ? msg : "");
}

static const Callbacks callbacks = {logger, calloc, free, NULL, NULL};

static void *started(const char *name)
{
    void *c = instantiate(name, 1, guid, uri, &callbacks, 0, 0);
    if (!c) {
        printf("INSTANTIATE %s failed\n", name);
        exit(3);
    }
    if (setup(c, 0, 0.0, 0.0, 0, 0.0) || enter(c) || exit_init(c)) {
        printf("INITIALIZE %s failed\n", name);
        exit(4);
    }
    return c;
}

static void must(int status, const char *what)
{
    if (status) {
        printf("%s: status %d\n", what, status);
        exit(4);
    }
}

static void *keeper(void *arg)
{
    void *c = started("keeper"), *state = NULL;
    double t = 0.0;
    (void)arg;
    for (int i = 0; i < 20 * rounds; i++) {
        must(do_step(c, t, 1e-3, 1), "keeper fmi2DoStep");
        t += 1e-3;
        must(get_state(c, &state), "keeper fmi2GetFMUstate");  /* the same state again */
    }
    must(free_state(c, &state), "keeper fmi2FreeFMUstate");
    free_instance(c);
    return NULL;
}

static void *cycler(void *arg)
{
    char name[32];
    snprintf(name, sizeof name, "cycler%d", *(int *)arg);
    for (int i = 0; i < rounds; i++) {
        void *c = started(name), *state = NULL;
        must(do_step(c, 0.0, 1e-3, 1), "cycler fmi2DoStep");
        must(get_state(c, &state), "cycler fmi2GetFMUstate");
        free_instance(c);  /* its state goes with it */
    }
    return NULL;
}

int main(int argc, char **argv)
{
    if (argc < 4) {
        fprintf(stderr, "usage: fmu_threads LIB RESOURCE_URI GUID [rounds]\n");
        return 2;
    }
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        printf("DLOPEN %s\n", dlerror());
        return 2;
    }
    uri = argv[2];
    guid = argv[3];
    if (argc > 4) rounds = atoi(argv[4]);
    *(void **)&instantiate = dlsym(lib, "fmi2Instantiate");
    *(void **)&setup = dlsym(lib, "fmi2SetupExperiment");
    *(void **)&enter = dlsym(lib, "fmi2EnterInitializationMode");
    *(void **)&exit_init = dlsym(lib, "fmi2ExitInitializationMode");
    *(void **)&do_step = dlsym(lib, "fmi2DoStep");
    *(void **)&get_state = dlsym(lib, "fmi2GetFMUstate");
    *(void **)&free_state = dlsym(lib, "fmi2FreeFMUstate");
    *(void **)&free_instance = dlsym(lib, "fmi2FreeInstance");
    pthread_t th[4];
    int ids[4] = {0, 1, 2, 3};
    pthread_create(&th[0], NULL, keeper, NULL);
    for (int k = 1; k < 4; k++) pthread_create(&th[k], NULL, cycler, &ids[k]);
    for (int k = 0; k < 4; k++) pthread_join(th[k], NULL);
    printf("DONE\n");
    return 0;
}
