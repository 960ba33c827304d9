/* The trivial engine of benchmarks/fmu_speed.py: the smallest implementation of mbs_engine.h that fmi2.c needs,
 * for n independent states x_i' = -a x_i + u integrated with classical RK4 at a fixed internal step of 1 ms.
 *
 * Compiled with fmi/fmi2.c it gives a native FMU of the same FMI layer shape as an mbsfmu native FMU,
 * so that the benchmark separates the cost of the FMI layer and the instance from that of the multibody
 * engine; n is chosen so that the host reads as many outputs from it as from the scene's FMU.
 * Variables: vr 0 parameter a, vr 1 input u, vr 2 .. 2+n-1 outputs x_i.  scene.bin: the GUID, a newline, n.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mbs_engine.h"

#define H_INT 1e-3
#define NMAX 64

struct MbsModel { char guid[64]; int n; char names[NMAX][8]; };
struct MbsInstance {
    const MbsModel *m;
    double a, u, t, x[NMAX];
    int initialized;
};

MbsModel *mbs_model_load_file(const char *path, char *err, size_t errlen) {
    MbsModel *m = calloc(1, sizeof *m);
    char text[128] = "";
    FILE *fp = fopen(path, "rb");
    size_t len = 0;
    if (fp) {
        len = fread(text, 1, sizeof text - 1, fp);
        fclose(fp);
    }
    char *nl = len ? strchr(text, '\n') : NULL;
    if (!m || !nl || nl - text >= (long)sizeof m->guid || (m->n = atoi(nl + 1)) < 1 || m->n > NMAX) {
        snprintf(err, errlen, "cannot read %s (GUID, newline, 1 to %d states)", path, NMAX);
        free(m);
        return NULL;
    }
    memcpy(m->guid, text, (size_t)(nl - text));
    for (int i = 0; i < m->n; i++) snprintf(m->names[i], sizeof m->names[i], "y.x%d", i + 1);
    return m;
}
void mbs_model_free(MbsModel *m) { free(m); }
const char *mbs_model_guid(const MbsModel *m) { return m->guid; }
int mbs_model_nvars(const MbsModel *m) { return 2 + m->n; }
int mbs_model_var_kind(const MbsModel *m, int vr) {
    return vr < 0 || vr >= 2 + m->n ? -1 : vr == 0 ? MBS_V_PARAM : vr == 1 ? MBS_V_QIN : MBS_V_Y;
}
const char *mbs_model_var_name(const MbsModel *m, int vr) {
    return vr < 0 || vr >= 2 + m->n ? NULL : vr == 0 ? "a" : vr == 1 ? "u" : m->names[vr - 2];
}
/* model exchange (fmi2.c serves it too): the states are x_1 .. x_n, no velocities */
int mbs_model_npos(const MbsModel *m) { return m->n; }
int mbs_model_nvel(const MbsModel *m) { (void)m; return 0; }

static void start(MbsInstance *s, const MbsModel *m) {
    memset(s, 0, sizeof *s);
    s->m = m, s->a = 1.0;
    for (int i = 0; i < m->n; i++) s->x[i] = 1.0;
}
MbsInstance *mbs_instance_new(const MbsModel *m, mbs_logger log, void *env) {
    MbsInstance *s = malloc(sizeof *s);
    (void)log, (void)env;
    if (s) start(s, m);
    return s;
}
void mbs_instance_free(MbsInstance *s) { free(s); }
int mbs_reset(MbsInstance *s) { start(s, s->m); return MBS_OK; }

int mbs_set_real(MbsInstance *s, int vr, double v) {
    if (vr == 0) s->a = v;
    else if (vr == 1) s->u = v;
    else return MBS_ERROR;
    return MBS_OK;
}
int mbs_set_reals(MbsInstance *s, const unsigned *vr, size_t n, const double *v, size_t *bad) {
    for (size_t i = 0; i < n; i++)  /* all or nothing, as the engine */
        if (vr[i] > 1) { if (bad) *bad = i; return MBS_ERROR; }
    for (size_t i = 0; i < n; i++) mbs_set_real(s, (int)vr[i], v[i]);
    return MBS_OK;
}
int mbs_get_real(MbsInstance *s, int vr, double *v) {
    if (vr < 0 || vr >= 2 + s->m->n) return MBS_ERROR;
    *v = vr == 0 ? s->a : vr == 1 ? s->u : s->x[vr - 2];
    return MBS_OK;
}
int mbs_get_reals(MbsInstance *s, const unsigned *vr, size_t n, double *v) {
    for (size_t i = 0; i < n; i++)
        if (mbs_get_real(s, (int)vr[i], v + i)) return MBS_ERROR;
    return MBS_OK;
}
int mbs_set_string(MbsInstance *s, int vr, const char *v) { (void)s, (void)vr, (void)v; return MBS_ERROR; }
int mbs_get_string(MbsInstance *s, int vr, const char **v) { (void)s, (void)vr, (void)v; return MBS_ERROR; }

int mbs_initialize(MbsInstance *s, double t0) { s->t = t0; s->initialized = 1; return MBS_OK; }

static double f(const MbsInstance *s, double x) { return -s->a * x + s->u; }

int mbs_do_step(MbsInstance *s, double t, double h) {
    int i, j, n = (int)ceil(h / H_INT - 1e-9);
    double dt = h / n;
    if (!isfinite(s->u)) return MBS_DISCARD;
    for (i = 0; i < n; i++)
        for (j = 0; j < s->m->n; j++) {
            double x = s->x[j], k1 = f(s, x), k2 = f(s, x + 0.5 * dt * k1), k3 = f(s, x + 0.5 * dt * k2),
                   k4 = f(s, x + dt * k3);
            s->x[j] = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4);
        }
    s->t = t + h;
    return MBS_OK;
}
double mbs_time(const MbsInstance *s) { return s->t; }
const double *mbs_state(const MbsInstance *s) { return s->x; }
int mbs_set_time(MbsInstance *s, double t) { s->t = t; return MBS_OK; }
int mbs_set_state(MbsInstance *s, const double *x, size_t n) {
    if (n != (size_t)s->m->n) return MBS_ERROR;
    memcpy(s->x, x, n * sizeof *x);
    return MBS_OK;
}
int mbs_derivatives(MbsInstance *s, double *xdot, size_t n) {
    if (n != (size_t)s->m->n || !isfinite(s->u)) return MBS_ERROR;
    for (size_t j = 0; j < n; j++) xdot[j] = f(s, s->x[j]);
    return MBS_OK;
}
int mbs_initialized(const MbsInstance *s) { return s->initialized; }
const double *mbs_nominals(const MbsInstance *s) {  /* every state's nominal is 1 (at most NMAX states) */
    static double one[NMAX];
    (void)s;
    for (int j = 0; j < NMAX; j++) one[j] = 1.0;
    return one;
}
const char *mbs_message(const MbsInstance *s) { (void)s; return ""; }
int mbs_directional_derivative(MbsInstance *s, const unsigned *u, size_t nu, const unsigned *k, size_t nk,
                               const double *seed, double *sens) {  /* (fmi2.c calls it; the benchmark does not) */
    (void)s, (void)u, (void)nu, (void)k, (void)nk, (void)seed, (void)sens;
    return MBS_ERROR;
}

/* state: the numbers that determine the future */
size_t mbs_state_size(const MbsInstance *s) { return (3 + (size_t)s->m->n) * sizeof(double); }
int mbs_state_save(const MbsInstance *s, void *buf, size_t len) {
    const double head[3] = {s->a, s->u, s->t};
    if (len != mbs_state_size(s)) return MBS_ERROR;
    memcpy(buf, head, sizeof head);
    memcpy((double *)buf + 3, s->x, (size_t)s->m->n * sizeof(double));
    return MBS_OK;
}
int mbs_state_load(MbsInstance *s, const void *buf, size_t len) {
    double head[3];
    if (len != mbs_state_size(s)) return MBS_ERROR;
    memcpy(head, buf, sizeof head);
    s->a = head[0], s->u = head[1], s->t = head[2];
    memcpy(s->x, (const double *)buf + 3, (size_t)s->m->n * sizeof(double));
    return MBS_OK;
}
