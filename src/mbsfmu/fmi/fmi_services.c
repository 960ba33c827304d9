/* Services below the FMI calls, no call of their own: logging switches, scene loading, FMU-state bytes (fmi_services.h). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi_services.h"

/* ---- logging switches ---- */
const char *const mbs_fmi_category[MBS_NCAT] = {"logAll", "logStatusWarning", "logStatusDiscard", "logStatusError",
                                                 "logStatusFatal"};

void mbs_log_init(MbsLogSwitches *l, int logging_on)
{
    int j;
    l->on = logging_on;
    for (j = 0; j < MBS_NCAT; j++) l->category_on[j] = 1;
}

int mbs_log_wanted(const MbsLogSwitches *l, int status)
{
    return status >= 0 && status < MBS_NCAT && l->category_on[status] && (status > 0 || l->on);
}

static int category_index(const char *name)
{
    int j;
    for (j = 0; j < MBS_NCAT; j++)
        if (name && strcmp(name, mbs_fmi_category[j]) == 0) return j;
    return -1;
}

int mbs_log_set(MbsLogSwitches *l, int logging_on, size_t n, const char *const categories[], char *err, size_t errlen)
{
    size_t i;
    int j;
    if (n > 0 && !categories) {
        snprintf(err, errlen, "NULL category list");
        return 1;
    }
    for (i = 0; i < n; i++)
        if (category_index(categories[i]) < 0) {
            snprintf(err, errlen, "unknown log category '%s'", categories[i] ? categories[i] : "(null)");
            return 1;
        }
    l->on = logging_on;
    for (j = 0; j < MBS_NCAT; j++)
        if (n == 0) l->category_on[j] = logging_on;
    for (i = 0; i < n; i++) l->category_on[category_index(categories[i])] = logging_on;
    return 0;
}

/* ---- the compiled scene ---- */
MbsModel *mbs_fmi_load_scene(const char *path, const char *guid, char *err, size_t errlen)
{
    char why[512];
    MbsModel *model = mbs_model_load_file(path, why, sizeof why);
    if (!model) {
        snprintf(err, errlen, "cannot load the compiled scene %s: %s", path, why);
        return NULL;
    }
    if (strcmp(mbs_model_guid(model), guid) != 0) {
        snprintf(err, errlen, "GUID %s does not match this FMU's %s", guid, mbs_model_guid(model));
        mbs_model_free(model);
        return NULL;
    }
    return model;
}

/* ---- FMU states ---- */
/* A new state, not yet registered; NULL if out of memory. */
static MbsFmuState *state_new(const void *owner, size_t len)
{
    MbsFmuState *st = len <= (size_t)-1 - sizeof *st ? (MbsFmuState *)malloc(sizeof *st + len) : NULL;
    if (st) {
        st->owner = owner;
        st->len = len;
    }
    return st;
}

typedef struct { MbsFmuState *st; const void *owner; size_t len; } Claim;

/* A registry match, so under the registry's lock, where mbs_fmu_states_free_owned (FreeInstance of the state's
 * last owner, maybe on another thread) reads owner: st, if still registered and of length len, now owner's. */
static int claim(void *item, void *ctx)
{
    Claim *c = (Claim *)ctx;
    if (item != c->st || c->st->len != c->len) return 0;
    c->st->owner = c->owner;  /* a state passed in may have been another instance's */
    return 1;
}

MbsFmuState *mbs_fmu_state_sized(MbsRegistry *states, MbsFmuState *st, const void *owner, size_t len)
{
    Claim c = {st, owner, len};
    MbsFmuState *fresh;
    if (st && mbs_reg_first(states, claim, &c)) return st;
    fresh = state_new(owner, len);  /* new, or an old one of another size (or freed meanwhile): replace */
    if (!fresh || !mbs_reg_add(states, fresh)) {
        free(fresh);
        return NULL;
    }
    if (st && mbs_reg_drop(states, st)) free(st);
    return fresh;
}

MbsFmuState *mbs_fmu_state_copy(MbsRegistry *states, const void *owner, const void *bytes, size_t len)
{
    MbsFmuState *st = state_new(owner, len);
    if (!st || !mbs_reg_add(states, st)) {
        free(st);
        return NULL;
    }
    memcpy(st->bytes, bytes, len);
    return st;
}

static int owned_by(void *state, void *owner) { return ((MbsFmuState *)state)->owner == owner; }

void mbs_fmu_states_free_owned(MbsRegistry *states, const void *owner)
{
    mbs_reg_drop_all(states, owned_by, (void *)owner, free);
}

int mbs_fmu_state_check(MbsInstance *sim, const void *bytes, size_t len)
{
    size_t own_len = mbs_state_size(sim);
    unsigned char *own = (unsigned char *)malloc(own_len ? own_len : 1);
    int rc;
    if (!own) return -2;
    rc = mbs_state_save(sim, own, own_len);
    if (rc == MBS_OK && (rc = mbs_state_load(sim, bytes, len)) == MBS_OK && mbs_state_load(sim, own, own_len) != MBS_OK)
        rc = -1;
    free(own);
    return rc;
}
