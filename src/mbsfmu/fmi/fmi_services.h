/* Services below the calls (fmi_calls.c calls them; they know no FMI call).
 * What the FMI layers of native FMUs (fmi2.c, fmi3.c) share beyond call_guard.h (phases, registries, state
 * header), whatever the FMI version: the host's logging switches, loading the compiled scene a host names, and
 * FMU states in the engine's byte layout (mbs_state_save) taken, checked, copied and freed in a layer's
 * registry of handed-out states. */
#ifndef MBS_FMI_SERVICES_H
#define MBS_FMI_SERVICES_H

#include <stddef.h>

#include "call_guard.h"
#include "mbs_engine.h"

/* Log categories, indexed by status (OK, Warning, Discard, Error, Fatal: fmi2Status and fmi3Status alike); the
 * names are those of the modelDescription (common.LOG_CATEGORIES). */
#define MBS_NCAT 5
extern const char *const mbs_fmi_category[MBS_NCAT];
/* The host's logging switches: messages of status warning and above unless their category is switched off;
 * status OK (logAll) only with logging on. */
typedef struct { int on, category_on[MBS_NCAT]; } MbsLogSwitches;
void mbs_log_init(MbsLogSwitches *l, int logging_on);
int mbs_log_wanted(const MbsLogSwitches *l, int status);  /* status outside OK..Fatal: never */
/* fmiXSetDebugLogging: every category checked before anything changes. 0, or 1 with the reason in err. */
int mbs_log_set(MbsLogSwitches *l, int logging_on, size_t n, const char *const categories[], char *err,
                size_t errlen);

/* The compiled scene at path, refused unless its GUID (the FMI 2 guid, the FMI 3 instantiationToken) is
 * `guid`: NULL with the reason in err. */
MbsModel *mbs_fmi_load_scene(const char *path, const char *guid, char *err, size_t errlen);

typedef struct {
    const void *owner;         /* freed with its instance (mbs_fmu_states_free_owned) */
    size_t len;
    unsigned char bytes[];     /* mbs_state_save's layout */
} MbsFmuState;

/* A state of `states` of len bytes owned by owner: st itself if it has that length (handed over under the
 * registry's lock: its last owner may be freed on another thread), else a new one that replaces st (st dropped
 * and freed); NULL if out of memory (st untouched). */
MbsFmuState *mbs_fmu_state_sized(MbsRegistry *states, MbsFmuState *st, const void *owner, size_t len);
/* A new state of `states` holding a copy of bytes; NULL if out of memory. */
MbsFmuState *mbs_fmu_state_copy(MbsRegistry *states, const void *owner, const void *bytes, size_t len);
void mbs_fmu_states_free_owned(MbsRegistry *states, const void *owner);
/* Whether bytes from a host load into sim: loaded, then sim's own state loaded back (the engine's load checks
 * the header first and changes nothing on failure). MBS_OK; MBS_ERROR (mbs_message says why); -1: sim's own
 * state did not load back; -2: out of memory. */
int mbs_fmu_state_check(MbsInstance *sim, const void *bytes, size_t len);

#endif
