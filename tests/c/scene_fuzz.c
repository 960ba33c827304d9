/* Fuzzing the compiled-scene loader (tests/test_scene_fuzz.py): built with ASan + UBSan together with the engine,
 * it mutates compiled scenes in memory and runs each mutant through what fmi2Instantiate and the first steps run:
 * mbs_model_load, then for a loaded one mbs_instance_new, every variable read, mbs_initialize, a few steps,
 * output points and a state round trip. Every mutant must be refused with a message or run; a sanitizer report
 * ends the process ($FUZZ_PROGRESS holds the case it was in: the driver restarts after it).
 *
 *   scene_fuzz FIRST scene.bin...   → "FUZZ-INTACT i ran|refused why" per scene (FIRST = 0), "FUZZ-BAD ..." per
 *                                     defect, "FUZZ cases N refused R ran K failed F abandoned A maxms T maxalloc B"
 *
 * Cases are numbered over the scenes in order; per scene: every int field (section table, header, the int
 * sections) set to edge values, random bit flips, truncations, section rows swapped, special doubles.
 * Case k is the same mutant on every run (FIRST skips the ones before), so a report is reproducible;
 * FUZZ_LAST=k with FIRST=k runs that one case and prints what it changed and what came of it.
 * "failed": loaded, then initialization or a step refused with a message (or abandoned, see STEP_CPU_S).
 */
#define _DEFAULT_SOURCE  /* setitimer, sigsetjmp, pwrite */
#include <limits.h>
#include <setjmp.h>
#include <signal.h>
#include <sys/time.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <fcntl.h>
#include <unistd.h>

#include "mbs_engine.h"

/* the sanitizer runtime's interface (declared here: gcc ships no <sanitizer/allocator_interface.h>) */
size_t __sanitizer_get_current_allocated_bytes(void);

#define MAX_FIELDS 200000
#define N_FLIPS 300
#define N_TRUNC 120
#define N_DOUBLES 200
#define STEPS 3
#define STEP_H 1e-6
#define ALLOC_PER_BYTE 64       /* an instance may own this many bytes per byte of its compiled scene ... */
#define ALLOC_BASE (1 << 20)    /* ... plus this */
#define SLOW_MS 5000.0          /* a case slower than this (wall time, on a shared machine) is a defect ... */
#define STEP_CPU_S 0.5          /* ... but its steps may use this much CPU, then they are abandoned (a scene that needs
                                 * many integrator steps is slow by its physics: up to max_steps per step) ... */
#define MIN_EVALS 1000          /* ... if they went into at least this many right-hand sides */

typedef struct { size_t off; int width; } Field;   /* a 4- or 8-byte integer of the file */
typedef struct { unsigned char *b; size_t len; Field *f; int nf; int32_t counts[16]; int ncounts;
                 size_t dbl[2]; size_t ndbl[2]; int nsec; } Scene;

/* the case being run and the counts before it, in the progress file: a sanitizer report ends the process, the
 * driver reads where and what was counted */
static int progress = -1;
static void mark(long k, long refused, long ran, long failed, long abandoned)
{
    const int64_t rec[5] = {k, refused, ran, failed, abandoned};
    if (progress >= 0) (void)!pwrite(progress, rec, sizeof rec, 0);
}

static uint64_t rng_state;
static uint64_t rnd(void)  /* splitmix64 */
{
    uint64_t z = (rng_state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

static unsigned char *read_file(const char *path, size_t *len)
{
    FILE *fp = fopen(path, "rb");
    if (!fp) return NULL;
    fseek(fp, 0, SEEK_END);
    long n = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    unsigned char *b = malloc((size_t)n);
    if (b && fread(b, 1, (size_t)n, fp) != (size_t)n) { free(b); b = NULL; }
    fclose(fp);
    *len = (size_t)n;
    return b;
}

/* The fields of an intact compiled scene (its own section table is trusted here). */
static void scan(Scene *s)
{
    int32_t nsec;
    memcpy(&nsec, s->b + 72, 4);
    s->nsec = nsec;
    s->f = malloc(MAX_FIELDS * sizeof(Field));
    s->nf = 0;
    s->f[s->nf++] = (Field){4, 4};   /* format version */
    s->f[s->nf++] = (Field){72, 4};  /* section count */
    for (int k = 0; k < nsec; k++) {
        size_t row = 76 + 24 * (size_t)k;
        int32_t id, kind;
        int64_t off, cnt;
        memcpy(&id, s->b + row, 4); memcpy(&kind, s->b + row + 4, 4);
        memcpy(&off, s->b + row + 8, 8); memcpy(&cnt, s->b + row + 16, 8);
        s->f[s->nf++] = (Field){row, 4};
        s->f[s->nf++] = (Field){row + 4, 4};
        s->f[s->nf++] = (Field){row + 8, 8};
        s->f[s->nf++] = (Field){row + 16, 8};
        if (kind == 0)
            for (int64_t i = 0; i < cnt && s->nf < MAX_FIELDS; i++) s->f[s->nf++] = (Field){(size_t)off + 4 * (size_t)i, 4};
        if (kind == 1 && (id == 10 || id == 11)) { s->dbl[id - 10] = (size_t)off; s->ndbl[id - 10] = (size_t)cnt; }
        if (id == 0)  /* the header's counts: n-1, n, n+1 of these are edge values of every field */
            for (int c = 0; c < 14 && c < cnt; c++) memcpy(&s->counts[s->ncounts++], s->b + off + 4 * c, 4);
    }
}

#define N_EDGES 8
static int cases_of(const Scene *s) { return N_EDGES * s->nf + N_FLIPS + N_TRUNC + 2 * s->nsec * s->nsec + N_DOUBLES; }

static void put(unsigned char *b, Field f, int64_t v)
{
    if (f.width == 4) { int32_t w = (int32_t)v; memcpy(b + f.off, &w, 4); }
    else memcpy(b + f.off, &v, 8);
}
static int64_t get(const unsigned char *b, Field f)
{
    if (f.width == 4) { int32_t w; memcpy(&w, b + f.off, 4); return w; }
    int64_t v; memcpy(&v, b + f.off, 8); return v;
}

/* Mutant k of scene s into buf (a copy of the scene); returns its length. */
static size_t mutate(const Scene *s, int k, unsigned char *buf)
{
    memcpy(buf, s->b, s->len);
    rng_state = (uint64_t)k * 2654435761ull + s->len;
    if (k < N_EDGES * s->nf) {                   /* one field to an edge value; n: one of the header's counts */
        Field f = s->f[k / N_EDGES];
        const int64_t n = s->counts[rnd() % (unsigned)s->ncounts];
        const int64_t edge[N_EDGES] = {0, -1, 1, n - 1, n, n + 1, f.width == 4 ? INT_MAX : INT64_MAX,
                                       f.width == 4 ? INT_MIN : INT64_MIN};
        put(buf, f, edge[k % N_EDGES]);
        return s->len;
    }
    k -= N_EDGES * s->nf;
    if (k < N_FLIPS) {                           /* 1 to 4 random bits */
        int nbits = 1 + (int)(rnd() % 4);
        for (int i = 0; i < nbits; i++) { size_t bit = rnd() % (s->len * 8); buf[bit / 8] ^= (unsigned char)(1u << (bit % 8)); }
        return s->len;
    }
    k -= N_FLIPS;
    if (k < N_TRUNC) return k < 80 ? (size_t)k : rnd() % s->len;  /* every short length, then anywhere */
    k -= N_TRUNC;
    if (k < 2 * s->nsec * s->nsec) {             /* two section rows swapped: whole rows, or their data ranges */
        int a = (k / 2) / s->nsec, b = (k / 2) % s->nsec;
        unsigned char tmp[24];
        size_t ra = 76 + 24 * (size_t)a, rb = 76 + 24 * (size_t)b, part = k % 2 ? 8 : 0, w = k % 2 ? 16 : 24;
        memcpy(tmp, buf + ra + part, w);
        memcpy(buf + ra + part, buf + rb + part, w);
        memcpy(buf + rb + part, tmp, w);
        return s->len;
    }
    k -= 2 * s->nsec * s->nsec;
    {                                            /* special doubles in D or the elastic data */
        static const double special[] = {NAN, INFINITY, -INFINITY, 0.0, -0.0, 1e308, -1e308, 4.9e-324, 1e-300, -1.0};
        int which = s->ndbl[1] && (rnd() & 1);
        if (s->ndbl[which]) {
            size_t i = rnd() % s->ndbl[which];
            double v = special[rnd() % (sizeof special / sizeof *special)];
            memcpy(buf + s->dbl[which] + 8 * i, &v, 8);
        }
        return s->len;
    }
}

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static int bad = 0;
static void complain(const char *what, long k, const char *detail)
{
    printf("FUZZ-BAD %s case %ld: %s\n", what, k, detail);
    bad++;
}

static sigjmp_buf abandon;
static long n_abandoned = 0;
static void on_timer(int sig) { (void)sig; siglongjmp(abandon, 1); }
static void cpu_timer(double seconds)
{
    struct itimerval t = {{0, 0}, {(time_t)seconds, (suseconds_t)((seconds - (double)(time_t)seconds) * 1e6)}};
    setitimer(ITIMER_PROF, &t, NULL);
}

static void logger(void *env, int status, const char *msg) { (void)env; (void)status; (void)strlen(msg); }

/* What a host does with a loaded scene. Returns 1 if it ran its steps, 0 if refused with a message. */
static int run(const MbsModel *m, long k, size_t base, size_t len, size_t *peak, long *evals)
{
    MbsInstance *s = mbs_instance_new(m, logger, NULL);
    if (!s) { complain("instance", k, "mbs_instance_new returned NULL"); return 0; }
    const int nv = mbs_model_nvars(m);
    unsigned *vr = malloc(((size_t)nv + 1) * sizeof *vr);
    double *val = malloc(((size_t)nv + 1) * sizeof *val), x;
    for (int i = 0; i < nv; i++) {
        vr[i] = (unsigned)i;
        const char *name = mbs_model_var_name(m, i);
        if (name) (void)strlen(name);
        mbs_get_real(s, i, &x);
    }
    const int ok = mbs_initialize(s, 0.0) == MBS_OK;
    volatile int steps = 0, abandoned = 0;
    if (ok) {
        if (sigsetjmp(abandon, 1)) abandoned = 1;
        else {
            cpu_timer(STEP_CPU_S);
            for (double t = 0.0; steps < STEPS; steps++, t += STEP_H) {
                if (mbs_do_step(s, t, STEP_H) != MBS_OK) break;
                mbs_get_reals(s, vr, (size_t)nv, val);
            }
        }
        cpu_timer(0.0);
    }
    const int ran = ok && steps == STEPS;
    long stats[6];
    mbs_stats(s, stats, NULL);
    *evals = stats[2];
    if (abandoned) {
        n_abandoned++;
        if (stats[2] < MIN_EVALS) complain("slow", k, "a few steps took long with few right-hand side evaluations");
        mbs_instance_free(s);  /* stopped inside a step: nothing of it is read again */
        free(vr);
        free(val);
        return 0;
    }
    if (!ran && !mbs_message(s)[0]) complain("silent", k, "initialization or a step failed without a message");
    size_t used = __sanitizer_get_current_allocated_bytes() - base;
    if (used > *peak) *peak = used;
    if (used > ALLOC_PER_BYTE * len + ALLOC_BASE) {
        char d[96];
        snprintf(d, sizeof d, "%zu bytes allocated for a %zu-byte scene", used, len);
        complain("alloc", k, d);
    }
    size_t n = mbs_state_size(s);
    void *st = malloc(n);
    if (st && mbs_state_save(s, st, n) == MBS_OK) mbs_state_load(s, st, n);
    free(st);
    free(vr);
    free(val);
    mbs_instance_free(s);
    return ran;
}

int main(int argc, char **argv)
{
    if (argc < 3) { fprintf(stderr, "usage: scene_fuzz FIRST scene.bin...\n"); return 2; }
    setvbuf(stdout, NULL, _IOLBF, 0);
    signal(SIGPROF, on_timer);
    const char *pf = getenv("FUZZ_PROGRESS");
    if (pf) progress = open(pf, O_WRONLY | O_CREAT | O_TRUNC, 0600);
    const long first = atol(argv[1]), last = getenv("FUZZ_LAST") ? atol(getenv("FUZZ_LAST")) : -1;
    const int nscenes = argc - 2;
    Scene *sc = calloc((size_t)nscenes, sizeof *sc);
    size_t maxlen = 0;
    for (int i = 0; i < nscenes; i++) {
        if (!(sc[i].b = read_file(argv[2 + i], &sc[i].len))) { fprintf(stderr, "cannot read %s\n", argv[2 + i]); return 2; }
        scan(&sc[i]);
        if (sc[i].len > maxlen) maxlen = sc[i].len;
    }
    for (int i = 0; first == 0 && i < nscenes; i++) {  /* the intact scenes first: each runs or says why not */
        char err[512] = "";
        long evals = 0;
        size_t peak0 = 0, base = __sanitizer_get_current_allocated_bytes();
        MbsModel *m = mbs_model_load(sc[i].b, sc[i].len, err, sizeof err);
        const int ran = m && run(m, -1 - i, base, sc[i].len, &peak0, &evals);
        printf("FUZZ-INTACT %d %s %s\n", i, ran ? "ran" : "refused", m ? "" : err);
        mbs_model_free(m);
    }
    unsigned char *buf = malloc(maxlen);
    long k = 0, total = 0, refused = 0, ran = 0, failed = 0;
    double maxms = 0.0;
    size_t peak = 0;
    for (int i = 0; i < nscenes; i++) {
        const int n = cases_of(&sc[i]);
        for (int c = 0; c < n; c++, k++) {
            if (k < first || (last >= 0 && k > last)) continue;
            mark(k, refused, ran, failed, n_abandoned);
            size_t len = mutate(&sc[i], c, buf);
            /* the loader gets exactly len bytes: a copy of that size, so ASan sees any read past them */
            unsigned char *exact = malloc(len ? len : 1);
            memcpy(exact, buf, len);
            if (last >= 0) {  /* one case at a time: what it changed and what came of it */
                printf("case %ld (scene %d mutant %d", k, i, c);
                if (c < N_EDGES * sc[i].nf)
                    printf(", byte %zu: %lld -> %lld", sc[i].f[c / N_EDGES].off, (long long)get(sc[i].b, sc[i].f[c / N_EDGES]),
                           (long long)get(buf, sc[i].f[c / N_EDGES]));
                for (size_t j = 0; c >= N_EDGES * sc[i].nf && j < len && j < sc[i].len; j++)
                    if (buf[j] != sc[i].b[j]) printf(", byte %zu: %#x -> %#x", j, sc[i].b[j], buf[j]);
                printf(")\n");
            }
            char err[512] = "";
            long evals = 0;
            double t0 = now_ms();
            size_t base = __sanitizer_get_current_allocated_bytes();
            MbsModel *m = mbs_model_load(exact, len, err, sizeof err);
            total++;
            if (last >= 0) printf("  %s\n", m ? "loaded" : err);
            if (!m) {
                refused++;
                if (!err[0]) complain("silent", k, "refused without a message");
            } else {
                if (run(m, k, base, len, &peak, &evals)) ran++;
                else failed++;
                mbs_model_free(m);
            }
            free(exact);
            double ms = now_ms() - t0;
            if (last >= 0) printf("  %.1f ms, %ld evaluations\n", ms, evals);
            if (ms > maxms) maxms = ms;
            if (ms > SLOW_MS) { char d[64]; snprintf(d, sizeof d, "%.0f ms", ms); complain("slow", k, d); }
        }
    }
    printf("FUZZ cases %ld refused %ld ran %ld failed %ld abandoned %ld maxms %.1f maxalloc %zu bad %d\n", total,
           refused, ran, failed, n_abandoned, maxms, peak, bad);
    for (int i = 0; i < nscenes; i++) { free(sc[i].b); free(sc[i].f); }
    free(sc);
    free(buf);
    return bad ? 1 : 0;
}
