/* The FMI call-order and state guard both FMU kinds and both FMI versions compile (call_guard.h). */
#include "call_guard.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---- phases ---- */
const char *mbs_phase_name(int phase) {
    switch (phase) {
    case P_INSTANTIATED: return "instantiated";
    case P_INIT: return "initialization mode";
    case P_STEP: return "step mode";
    case P_EVENT: return "event mode";
    case P_CONT: return "continuous-time mode";
    case P_TERMINATED: return "terminated";
    case P_ERROR: return "error";
    case P_UPDATE: return "intermediate update mode (inside the intermediateUpdate callback)";
    default: return "fatal";
    }
}

int mbs_phase_refuses(int mask, int phase, int iface, const char *fn, char *buf, size_t len) {
    if ((mask & (I_CS | I_ME)) && !(mask & iface))
        snprintf(buf, len, "%s: a %s function, but this instance is %s", fn,
                 mask & I_CS ? "co-simulation" : "model-exchange", iface == I_CS ? "co-simulation" : "model exchange");
    else if (!(mask & phase))
        snprintf(buf, len, "%s: not allowed in phase '%s'%s", fn, mbs_phase_name(phase),
                 phase == P_ERROR ? " (after a failed call: only Reset, SetFMUstate, getters and "
                                    "FreeInstance)" : "");
    else
        return 0;
    return 1;
}

/* ---- registries: one small lock for all ---- */
#if defined(_MSC_VER)
#include <windows.h>
static volatile LONG registry_lock = 0;
#define LOCK() while (InterlockedExchange(&registry_lock, 1)) {}
#define UNLOCK() InterlockedExchange(&registry_lock, 0)
#else
static volatile int registry_lock = 0;
#define LOCK() while (__atomic_exchange_n(&registry_lock, 1, __ATOMIC_ACQUIRE)) {}
#define UNLOCK() __atomic_store_n(&registry_lock, 0, __ATOMIC_RELEASE)
#endif

int mbs_reg_find(MbsRegistry *r, const void *p) {
    int found = 0;
    size_t i;
    if (!p) return 0;
    LOCK();
    for (i = 0; i < r->n && !found; i++) found = r->item[i] == p;
    UNLOCK();
    return found;
}

int mbs_reg_add(MbsRegistry *r, void *p) {
    int ok = 1;
    LOCK();
    if (r->n == r->cap) {
        size_t cap = r->cap ? 2 * r->cap : 8;
        void **grown = (void **)realloc(r->item, cap * sizeof *grown);
        if (grown) r->item = grown, r->cap = cap;
        else ok = 0;
    }
    if (ok) r->item[r->n++] = p;
    UNLOCK();
    return ok;
}

int mbs_reg_drop(MbsRegistry *r, const void *p) {
    int found = 0;
    size_t i;
    LOCK();
    for (i = 0; i < r->n && !found; i++)
        if (r->item[i] == p) r->item[i] = r->item[--r->n], found = 1;
    UNLOCK();
    return found;
}

void *mbs_reg_first(MbsRegistry *r, int (*match)(void *item, void *ctx), void *ctx) {
    void *found = NULL;
    size_t i;
    LOCK();
    for (i = 0; i < r->n && !found; i++)
        if (match(r->item[i], ctx)) found = r->item[i];
    UNLOCK();
    return found;
}

void mbs_reg_drop_all(MbsRegistry *r, int (*match)(void *item, void *ctx), void *ctx, void (*release)(void *item)) {
    size_t i;
    LOCK();
    for (i = 0; i < r->n;) {
        void *item = r->item[i];
        if (match(item, ctx)) {
            r->item[i] = r->item[--r->n];
            release(item);
        } else
            i++;
    }
    UNLOCK();
}

