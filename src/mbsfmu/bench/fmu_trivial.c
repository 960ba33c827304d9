/* The trivial engine of bench/fmu_speed.py: the smallest implementation of mbs_engine.h that fmi2.c needs,
 * for one state x' = -a x + u integrated with classical RK4 at a fixed internal step of 1 ms.
 *
 * Compiled with engine/fmi2.c it gives a native FMU of the same FMI layer shape as an mbsfmu native FMU,
 * so that the benchmark separates the cost of the FMI layer and the instance from that of the multibody
 * engine.  Variables: vr 0 parameter a, vr 1 input u, vr 2 output x.  scene.bin holds the GUID only.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mbs_engine.h"

#define H_INT 1e-3

struct MbsModel { char guid[64]; };
struct MbsInstance {
    const MbsModel *m;
    double a, u, t, x;
    int initialized;
};

MbsModel *mbs_model_load_file(const char *path, char *err, size_t errlen) {
    MbsModel *m = calloc(1, sizeof *m);
    FILE *fp = fopen(path, "rb");
    size_t n = 0;
    if (fp) {
        n = fread(m->guid, 1, sizeof m->guid - 1, fp);
        fclose(fp);
    }
    if (!fp || n == 0) {
        snprintf(err, errlen, "cannot read %s", path);
        free(m);
        return NULL;
    }
    m->guid[strcspn(m->guid, "\r\n")] = 0;
    return m;
}
void mbs_model_free(MbsModel *m) { free(m); }
const char *mbs_model_guid(const MbsModel *m) { return m->guid; }
int mbs_model_nvars(const MbsModel *m) { (void)m; return 3; }

MbsInstance *mbs_instance_new(const MbsModel *m, mbs_logger log, void *env) {
    MbsInstance *s = calloc(1, sizeof *s);
    (void)log, (void)env;
    if (s)
        s->m = m, s->a = 1.0, s->x = 1.0;
    return s;
}
void mbs_instance_free(MbsInstance *s) { free(s); }
int mbs_reset(MbsInstance *s) {
    const MbsModel *m = s->m;
    memset(s, 0, sizeof *s);
    s->m = m, s->a = 1.0, s->x = 1.0;
    return MBS_OK;
}

int mbs_set_real(MbsInstance *s, int vr, double v) {
    if (vr == 0) s->a = v;
    else if (vr == 1) s->u = v;
    else return MBS_ERROR;
    return MBS_OK;
}
int mbs_get_real(MbsInstance *s, int vr, double *v) {
    if (vr < 0 || vr > 2) return MBS_ERROR;
    *v = vr == 0 ? s->a : vr == 1 ? s->u : s->x;
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
    int i, n = (int)ceil(h / H_INT - 1e-9);
    double dt = h / n, x = s->x;
    if (!isfinite(s->u)) return MBS_DISCARD;
    for (i = 0; i < n; i++) {
        double k1 = f(s, x), k2 = f(s, x + 0.5 * dt * k1), k3 = f(s, x + 0.5 * dt * k2), k4 = f(s, x + dt * k3);
        x += dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4);
    }
    s->x = x, s->t = t + h;
    return MBS_OK;
}
double mbs_time(const MbsInstance *s) { return s->t; }
int mbs_initialized(const MbsInstance *s) { return s->initialized; }
const char *mbs_message(const MbsInstance *s) { (void)s; return ""; }

/* state: the four numbers that determine the future */
size_t mbs_state_size(const MbsInstance *s) { (void)s; return 4 * sizeof(double); }
int mbs_state_save(const MbsInstance *s, void *buf, size_t len) {
    double v[4] = {s->a, s->u, s->t, s->x};
    if (len != sizeof v) return MBS_ERROR;
    memcpy(buf, v, sizeof v);
    return MBS_OK;
}
int mbs_state_load(MbsInstance *s, const void *buf, size_t len) {
    double v[4];
    if (len != sizeof v) return MBS_ERROR;
    memcpy(v, buf, sizeof v);
    s->a = v[0], s->u = v[1], s->t = v[2], s->x = v[3];
    return MBS_OK;
}
