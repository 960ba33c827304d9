/* The bodies of the FMI calls (above fmi_services.h's services, below fmi2.c/fmi3.c's wrappers).
 * The version-independent core of the FMI layers of native FMUs (fmi2.c, fmi3.c), as Reference-FMUs keeps one
 * core under thin per-version wrappers: both versions' instance structs start with an MbsFmiHead, the core
 * functions take it and the calling function's name (for messages) and return a status of the numbers
 * fmi2Status and fmi3Status share (each layer checks them at compile time). The wrappers convert arguments,
 * check the phase (mbs_fmi_allowed) and keep what only their version has. */
#ifndef MBS_FMI_CALLS_H
#define MBS_FMI_CALLS_H

#include <stddef.h>

#include "fmi_services.h"

enum { MBS_FMI_OK = 0, MBS_FMI_WARNING = 1, MBS_FMI_DISCARD = 2, MBS_FMI_ERROR = 3, MBS_FMI_FATAL = 4 };
/* c99: a negative array size where a version's status numbers differ from the core's */
#define MBS_FMI_SAME_STATUS(tag, ok, warning, discard, error, fatal)                                               \
    typedef char tag[(int)(ok) == MBS_FMI_OK && (int)(warning) == MBS_FMI_WARNING &&                              \
                     (int)(discard) == MBS_FMI_DISCARD && (int)(error) == MBS_FMI_ERROR &&                        \
                     (int)(fatal) == MBS_FMI_FATAL ? 1 : -1]

typedef struct MbsFmiHead MbsFmiHead;
struct MbsFmiHead {
    MbsModel *model;
    MbsInstance *sim;
    char *name;
    int iface;                 /* I_CS or I_ME (call_guard.h) */
    int phase;
    MbsLogSwitches log_switches;
    int logged;                /* the engine logged during the current call */
    double t_start;
    long refused_vr;           /* a setting the engine refused before initialization (-1: none); its message */
    char refused[256];         /* fails fmiXExitInitializationMode */
    MbsRegistry *states;       /* the layer's registry of handed-out FMU states */
    /* the version's call of the host's logger (the message is data, never a format string) */
    void (*emit)(const MbsFmiHead *h, int status, const char *category, const char *msg);
};

/* ---- logging and checks ---- */
void mbs_fmi_logf(MbsFmiHead *h, int status, const char *fmt, ...);
/* An engine return code as status; the engine's message is logged unless the engine already did. */
int mbs_fmi_status(MbsFmiHead *h, int rc, const char *what);
/* p is a live instance of `instances` (else a message on stderr, `null_name` for NULL) whose phase allows
 * `mask`: 1; else 0 (with the message through the host's logger), nothing changes. */
int mbs_fmi_allowed(MbsRegistry *instances, MbsFmiHead *p, int mask, const char *fn, const char *null_name);
/* n > 0 values but a NULL array: 1 with a message */
int mbs_fmi_bad_array(MbsFmiHead *h, const void *a, const void *b, size_t n, const char *fn);
size_t mbs_fmi_nstates(const MbsFmiHead *h);

/* ---- instances ---- */
/* A zeroed instance of `size` bytes (head first) named name; NULL if out of memory. */
MbsFmiHead *mbs_fmi_alloc(size_t size, const char *name);
/* After the wrapper filled in its emit: the engine instance of model, registered in instances. 0 if out of
 * memory: h, its name and model freed. */
int mbs_fmi_start(MbsFmiHead *h, MbsRegistry *instances, MbsRegistry *states, MbsModel *model, int iface,
                  int logging_on);
void mbs_fmi_free_instance(MbsRegistry *instances, MbsFmiHead *p, const char *fn);
int mbs_fmi_set_debug_logging(MbsFmiHead *h, int logging_on, size_t n, const char *const categories[],
                              const char *fn);

/* ---- life cycle ---- */
int mbs_fmi_setup(MbsFmiHead *h, int tolerance_defined, double tolerance, double start, int stop_defined,
                  double stop, const char *fn);
int mbs_fmi_exit_init(MbsFmiHead *h, const char *fn);
int mbs_fmi_reset(MbsFmiHead *h, const char *fn);

/* ---- variables ---- */
/* A setting's engine code as status; before initialization a refusal is remembered (refused_vr), a later
 * accepted setting of the same variable clears it. */
int mbs_fmi_setting(MbsFmiHead *h, int vr, int rc, const char *fn);
/* All values at once; on a refusal nothing is set. */
int mbs_fmi_set_reals(MbsFmiHead *h, const unsigned vr[], size_t nvr, const double values[], const char *fn);
/* vr if it is a row of the variable table, else -1 with the message unknown_fmt (fn, vr). */
int mbs_fmi_vr(MbsFmiHead *h, unsigned vr, const char *unknown_fmt, const char *fn);
/* Strings by value reference; a reference outside the table gets the message unknown_fmt (fn, vr). */
int mbs_fmi_get_strings(MbsFmiHead *h, const unsigned vr[], size_t nvr, const char *values[],
                        const char *unknown_fmt, const char *fn);
int mbs_fmi_set_strings(MbsFmiHead *h, const unsigned vr[], size_t nvr, const char *const values[],
                        const char *unknown_fmt, const char *fn);
/* A type the model has no variables of: OK for none, else an error "fn: this model has no variables of that
 * type<more>". */
int mbs_fmi_no_such_type(MbsFmiHead *h, size_t nvr, const char *more, const char *fn);

/* ---- FMU states (MbsFmuState, fmi_services.h) ---- */
int mbs_fmi_get_state(MbsFmiHead *h, void **state, const char *fn);
int mbs_fmi_set_state(MbsFmiHead *h, void *state, const char *fn);
int mbs_fmi_free_state(MbsFmiHead *h, void **state, const char *fn);
int mbs_fmi_state_size(MbsFmiHead *h, void *state, size_t *size, const char *fn);
int mbs_fmi_serialize(MbsFmiHead *h, void *state, void *out, size_t size, const char *fn);
int mbs_fmi_deserialize(MbsFmiHead *h, const void *bytes, size_t size, void **state, const char *fn);

/* ---- co-simulation and model exchange ---- */
/* A communication step from t by dt that is not finite or does not advance t: 1 with a message. */
int mbs_fmi_bad_step(MbsFmiHead *h, double t, double dt, const char *fn);
/* The engine's code as status, any refusal an error (OK or error only). */
int mbs_fmi_ok_or_error(MbsFmiHead *h, int rc, const char *fn);

#endif
