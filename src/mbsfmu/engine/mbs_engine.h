/* mbsfmu engine — public interface (Python compiles, C runs).
 *
 * One C library, independent of any particular scene: the scene is data (the compiled scene, written by
 * mbsfmu/compiler/scene_file.py) that mbs_model_load reads.  Everything that runs per step lives behind this
 * header: equations M(y,t)·ÿ + k(y,ẏ,t) = q, force elements, drives and expressions (bytecode), elastic
 * bodies, integrators, instance state.  The same library serves in-process runs (ctypes), the pythonfmu
 * FMU and the native FMU (fmi2.c).
 *
 * Rules: an MbsModel is immutable after loading and may be shared by many instances; an MbsInstance owns
 * all its memory (allocated in mbs_instance_new, never per step); no global state; every failure is a
 * status code plus a message (mbs_message, and the logger when one is given).
 */
#ifndef MBS_ENGINE_H
#define MBS_ENGINE_H

#include <stddef.h>

#include "mbs_layout.h"

#ifdef __cplusplus
extern "C" {
#endif

#if defined(_WIN32) && defined(MBS_SHARED)
#define MBS_API __declspec(dllexport)
#else
#define MBS_API
#endif

/* Status codes, ordered like fmi2Status (OK, Warning, Discard, Error). */
enum { MBS_OK = 0, MBS_WARNING = 1, MBS_DISCARD = 2, MBS_ERROR = 3 };

/* Kinds of variables MBS_V_* (the compiled scene's variable table), the format version and the integrator
 * codes: mbs_layout.h. */

typedef void (*mbs_logger)(void *env, int status, const char *message);

typedef struct MbsModel MbsModel;
typedef struct MbsInstance MbsInstance;

/* ---- the compiled scene ---- */
MBS_API MbsModel *mbs_model_load(const void *bytes, size_t len, char *err, size_t errlen);
MBS_API MbsModel *mbs_model_load_file(const char *path, char *err, size_t errlen); /* a regular file only, at most
                                                   MBS_SCENE_FILE_LIMIT bytes (fmu_files.h): never waits on a FIFO */
MBS_API void mbs_model_free(MbsModel *m);
MBS_API const char *mbs_model_guid(const MbsModel *m);   /* the FMU's GUID, written by Python */
MBS_API int mbs_model_nvars(const MbsModel *m);          /* rows of the variable table */
MBS_API int mbs_model_var_kind(const MbsModel *m, int vr); /* MBS_V_*, -1 out of range */
MBS_API const char *mbs_model_var_name(const MbsModel *m, int vr); /* the FMU variable's name, NULL out of range */
/* FMI 3.0's variables: runs of rows as arrays (compiler/variables.py: fmi3_variables), every other row a scalar;
 * mbs_model_var3: the first row of FMI 3.0 variable vr3 and its number of rows, -1 out of range */
MBS_API int mbs_model_nvars3(const MbsModel *m);
MBS_API int mbs_model_var3(const MbsModel *m, unsigned vr3, int *rows);
MBS_API int mbs_model_npos(const MbsModel *m);
MBS_API int mbs_model_nvel(const MbsModel *m);

/* ---- instances ---- */
MBS_API MbsInstance *mbs_instance_new(const MbsModel *m, mbs_logger log, void *log_env);
MBS_API void mbs_instance_free(MbsInstance *s);
MBS_API int mbs_reset(MbsInstance *s);                   /* back to the state after mbs_instance_new */

/* Variables by value reference (vr = row of the variable table). Setting an output, an unknown vr, a
 * fixed parameter after initialization or a value outside its domain → MBS_ERROR, nothing changed; a
 * non-finite input → accepted, the next step returns MBS_DISCARD. Getting before mbs_initialize gives the initial state at the parameters set so far. */
MBS_API int mbs_set_real(MbsInstance *s, int vr, double value);
/* n values at once: each checked against its variable's domain (the compiled scene's table, scene/domains.py),
 * parameters together against the rules of the numbers they derive; on a refusal nothing is set (MBS_ERROR,
 * the message names the variable, its value and the valid range or the quantity it made invalid) and *bad
 * (if given) is the offending entry, or n when only the combination of parameters is refused. */
MBS_API int mbs_set_reals(MbsInstance *s, const unsigned *vr, size_t n, const double *value, size_t *bad);
MBS_API int mbs_get_real(MbsInstance *s, int vr, double *value);
MBS_API int mbs_get_reals(MbsInstance *s, const unsigned *vr, size_t n, double *value);  /* fmi2GetReal's n */
MBS_API int mbs_set_string(MbsInstance *s, int vr, const char *value); /* integrator.method */
MBS_API int mbs_get_string(MbsInstance *s, int vr, const char **value);

/* Replace the scene's initial value of state entry `index` (of [y; ẏ]) before initialization (parameter
 * studies vary initial values this way): a finite number as the scene's `initial:` values (else MBS_ERROR);
 * mbs_reset restores the scene's values. */
MBS_API int mbs_set_start(MbsInstance *s, int index, double value);

/* Exit of initialization mode: bind parameters, initial state, build the integrator. */
MBS_API int mbs_initialize(MbsInstance *s, double t0);
/* Advance from t (= current time) to t + h with inputs held. MBS_DISCARD: the step failed, the
 * instance stays at its last good point (mbs_time) and mbs_message says why. */
MBS_API int mbs_do_step(MbsInstance *s, double t, double h);
/* States at the times ts[0..n-1] (ts[0] = now): rows [y; ẏ] into X (n × (npos+nvel)); the same steps as
 * n-1 do_steps, points inside one dense-output step interpolated together. */
MBS_API int mbs_run(MbsInstance *s, const double *ts, int n, double *X);
/* The step observer: inside mbs_do_step, fn(env, t, x) after every accepted internal step strictly inside the step
 * and once at its end (every method; auto: both phases' steps; mbs_run: its internal points, and its time points where it steps
 * point by point), in increasing t.
 * During the call the instance shows that point (mbs_time, mbs_state, variables; outputs computed for it when
 * read) and refuses every call that changes it (set, step, reset, state load: MBS_ERROR with a message); afterwards
 * it is at the step's end. fn NULL: none (then a step costs one branch more). Nothing is allocated per step. */
typedef void (*mbs_step_observer)(void *env, double t, const double *x);
MBS_API int mbs_set_step_observer(MbsInstance *s, mbs_step_observer fn, void *env);
MBS_API double mbs_time(const MbsInstance *s);
MBS_API int mbs_initialized(const MbsInstance *s);  /* 1 after mbs_initialize (or a state loaded from then) */
MBS_API const double *mbs_state(const MbsInstance *s);  /* [y; ẏ], npos + nvel */
MBS_API const double *mbs_nominals(const MbsInstance *s);  /* nominal values of [y; ẏ] (compiler/variables.py) */
MBS_API const char *mbs_message(const MbsInstance *s);   /* last failure, "" if none */
/* steps, rejected, rhs_evaluations, jac_evaluations, lu_decompositions, switched (0/1) */
MBS_API void mbs_stats(const MbsInstance *s, long out[6], double *switched_at);

/* ---- model exchange: the host integrates the continuous states x = [y; ẏ] (npos + nvel entries) ----
 * After mbs_initialize, the host sets the time and x (finite numbers, else MBS_ERROR and nothing changes);
 * mbs_derivatives gives ẋ there with the inputs and parameters set (MBS_ERROR: an input or parameter the host
 * set is refused; MBS_DISCARD: ẋ is not defined or not finite at this state, e.g. a singular mass matrix, an
 * intermediate overflowing at an extreme state). Quaternions are
 * states as the engine keeps them: ṗ = G(p)·ω keeps |p| only as well as the host integrates it (the engine
 * never changes x here; mbs_do_step normalizes after each step). Variables of kind MBS_V_DER read ẋ too. */
MBS_API int mbs_set_time(MbsInstance *s, double t);
MBS_API int mbs_set_state(MbsInstance *s, const double *x, size_t n);
MBS_API int mbs_derivatives(MbsInstance *s, double *xdot, size_t n);

/* ---- directional derivatives: J = ∂(unknowns)/∂(knowns) at (time, x) with the inputs and parameters set ----
 * Knowns: continuous states (y.*, yd.*) and inputs; unknowns: derivatives (MBS_V_DER), outputs (output points,
 * stresses) and states. Exact to rounding (complex step through the evaluation itself, deriv.c), one evaluation
 * per column. mbs_directional_derivative: sensitivity = J seed (seed per known, sensitivity per unknown);
 * mbs_adjoint_derivative: sensitivityᵀ = seedᵀ J (seed per unknown, sensitivity per known), one column per known. A value reference of another kind, a non-finite seed: MBS_ERROR;
 * a singular mass matrix, a derivative that is not finite: MBS_DISCARD. */
MBS_API int mbs_directional_derivative(MbsInstance *s, const unsigned *unknown, size_t nunknown, const unsigned *known,
                                       size_t nknown, const double *seed, double *sensitivity);
MBS_API int mbs_adjoint_derivative(MbsInstance *s, const unsigned *unknown, size_t nunknown, const unsigned *known,
                                   size_t nknown, const double *seed, double *sensitivity);

/* ---- state: in-memory snapshot and serialized bytes are the same fixed layout ----
 * header: magic "MBSS", state format version, model GUID, payload length, checksum; then the payload.
 * mbs_state_load validates everything and leaves the instance unchanged on any error. */
MBS_API size_t mbs_state_size(const MbsInstance *s);
MBS_API int mbs_state_save(const MbsInstance *s, void *buf, size_t len);
MBS_API int mbs_state_load(MbsInstance *s, const void *buf, size_t len);

/* ---- evaluation at a given state with the current inputs and parameters (tests, mbsfmu.compile) ---- */
MBS_API int mbs_equations(MbsInstance *s, double t, const double *x, double *M, double *k, double *q);
/* ẋ = f(t, x) into xdot, which may overlap x; a singular mass matrix: MBS_ERROR, ẋ not finite: MBS_DISCARD */
MBS_API int mbs_rhs(MbsInstance *s, double t, const double *x, double *xdot);
/* world position (3) and velocity (3) of output point o */
MBS_API int mbs_output_point(MbsInstance *s, int o, const double *x, double t, double out[6]);
/* von Mises stress (Pa) of stress node k (an FE body's `stress:`) at state x */
MBS_API int mbs_von_mises(MbsInstance *s, int k, const double *x, double *out);

#ifdef __cplusplus
}
#endif
#endif
