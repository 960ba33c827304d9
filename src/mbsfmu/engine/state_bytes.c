/* FMU state bytes: save and load the instance's state (checked, all or nothing). */
#include "instance.h"
#include "state_header.h"

/* ------------------------------------------------------------------------------------------ state bytes
 * header (state_header.h, which both FMU kinds check too): "MBSS", uint32 version, char guid[64], uint64 payload
 * length, uint64 FNV-1a checksum of the payload;
 * payload: Head, parameters (nparam), u, u_applied, x (n), then the integrator snapshot (initialized only). */
#define HEADER_SIZE MBS_STATE_HEADER
typedef struct {
    double time, rtol, atol, max_step, step;
    int32_t initialized, method, q_in_active, params_dirty;
} Head;

static size_t payload_size(const MbsInstance *s, size_t integ_size)
{
    return sizeof(Head) + sizeof(double) * ((size_t)s->m->hdr[H_NPARAM] + 2 * (size_t)s->nu + s->n) + integ_size;
}

size_t mbs_state_size(const MbsInstance *s)
{
    return HEADER_SIZE + payload_size(s, s->initialized ? mbs_integ_snapshot_size(s->integ) : 0);
}

int mbs_state_save(const MbsInstance *s, void *buf, size_t len)
{
    size_t need = mbs_state_size(s), isz = s->initialized ? mbs_integ_snapshot_size(s->integ) : 0;
    if (!buf || len < need) return MBS_ERROR;
    unsigned char *p = buf, *pay = p + HEADER_SIZE;
    Head h = {s->time, s->rtol, s->atol, s->max_step, s->step, s->initialized, s->method, s->q_in_active, s->params_dirty};
    unsigned char *w = pay;
    memcpy(w, &h, sizeof h);                                               w += sizeof h;
    memcpy(w, s->D, sizeof(double) * s->m->hdr[H_NPARAM]);                 w += sizeof(double) * s->m->hdr[H_NPARAM];
    memcpy(w, s->u, sizeof(double) * s->nu);                               w += sizeof(double) * s->nu;
    memcpy(w, s->u_applied, sizeof(double) * s->nu);                       w += sizeof(double) * s->nu;
    memcpy(w, s->x, sizeof(double) * s->n);                                w += sizeof(double) * s->n;
    if (isz) mbs_integ_snapshot_save(s->integ, w);
    uint32_t version = MBS_STATE_VERSION;
    uint64_t plen = payload_size(s, isz), sum = mbs_state_checksum(pay, plen);
    memcpy(p, "MBSS", 4);
    memcpy(p + 4, &version, 4);
    memset(p + 8, 0, 64);
    memcpy((char *)p + 8, s->m->guid, strlen(s->m->guid));
    memcpy(p + 72, &plen, 8);
    memcpy(p + 80, &sum, 8);
    return MBS_OK;
}

int mbs_state_load(MbsInstance *s, const void *buf, size_t len)
{
    REFUSED_WHILE_OBSERVING(s, "mbs_state_load");
    const unsigned char *p = buf;
    uint64_t plen;
    Head h;
    const char *why = mbs_state_header_problem(p, len, sizeof h, s->m->guid);
    if (why) return mbs_report(s, MBS_ERROR, "%s (%zu bytes); state unchanged", why, len);
    memcpy(&plen, p + 72, 8);
    const unsigned char *r = p + HEADER_SIZE;
    memcpy(&h, r, sizeof h);
    if ((h.initialized != 0 && h.initialized != 1) || h.method < 0 || h.method >= MBS_NMETHODS ||
        (h.q_in_active != 0 && h.q_in_active != 1) || (h.params_dirty != 0 && h.params_dirty != 1))
        return mbs_report(s, MBS_ERROR, "FMU state has invalid fields; state unchanged");
    MbsIntegrator *it = NULL;
    size_t isz = 0;
    if (h.initialized) {
        char err[256];
        double save[4] = {s->rtol, s->atol, s->max_step, s->step};
        s->rtol = h.rtol; s->atol = h.atol; s->max_step = h.max_step; s->step = h.step;
        it = mbs_new_integrator(s, h.method, err, sizeof err);
        s->rtol = save[0]; s->atol = save[1]; s->max_step = save[2]; s->step = save[3];
        if (!it) return mbs_report(s, MBS_ERROR, "FMU state: %s; state unchanged", err);
        isz = mbs_integ_snapshot_size(it);
    }
    if (plen != payload_size(s, isz)) { mbs_integ_free(it); return mbs_report(s, MBS_ERROR, "FMU state has the wrong size for this model; state unchanged"); }
    const unsigned char *ip = r + payload_size(s, 0);
    if (it && mbs_integ_snapshot_load(it, ip, isz)) { mbs_integ_free(it); return mbs_report(s, MBS_ERROR, "FMU state: corrupt integrator data; state unchanged"); }
    /* all checks passed: commit */
    const int np = s->m->hdr[H_NPARAM];
    r += sizeof h;
    memcpy(s->D, r, sizeof(double) * np);                r += sizeof(double) * np;
    memcpy(s->u, r, sizeof(double) * s->nu);             r += sizeof(double) * s->nu;
    memcpy(s->u_applied, r, sizeof(double) * s->nu);     r += sizeof(double) * s->nu;
    memcpy(s->x, r, sizeof(double) * s->n);
    s->out_valid = s->der_valid = 0;
    s->time = h.time; s->rtol = h.rtol; s->atol = h.atol; s->max_step = h.max_step; s->step = h.step;
    s->method = h.method;
    s->q_in_active = h.q_in_active;
    s->initialized = h.initialized;
    mbs_integ_free(s->integ);
    s->integ = it;
    memcpy(s->td + 3 * s->m->hdr[H_NDRV], s->u_applied + NVEL(s->m), 3 * (size_t)s->m->hdr[H_NINPUT] * sizeof(double));
    /* numbers from the restored parameters; a failure shows at the next step */
    s->params_dirty = h.params_dirty;
    s->initial_valid = 0;
    if (mbs_bind(s)) s->params_dirty = 1;
    s->inputs_dirty = memcmp(s->u, s->u_applied, sizeof(double) * s->nu) != 0;
    if (!s->initialized) s->initial_valid = 0;
    s->msg[0] = 0;
    return MBS_OK;
}

