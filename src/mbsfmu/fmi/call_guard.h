/* The FMI call-order and state guard (the FMI 2.0 phases, which FMI 3.0 shares), one for both FMU kinds.
 * fmi/fmi2.c (native FMUs) and fmu/shim.c (the pythonfmu kind's loader
 * shim) compile call_guard.c alike; the FMI 3.0 layer fmi/fmi3.c too (its phases are the same). It holds
 *   - the phases of the FMI 2.0 state machines as bit masks, their names and the "allowed in" check with its
 *     message,
 *   - the registries of the instances and FMU states a library handed out (a host's pointer is compared with
 *     them, never followed unless found).
 * (The FMU state header both kinds check is the engine's: engine/state_header.h.)
 */
#ifndef MBS_CALL_GUARD_H
#define MBS_CALL_GUARD_H

#include <stddef.h>
#include <stdint.h>

/* phases (co-simulation steps in P_STEP, model exchange moves between P_EVENT and P_CONT); a mask may also name
 * the interface (I_CS, I_ME) a call belongs to, without one it is both's */
enum { P_INSTANTIATED = 1, P_INIT = 2, P_STEP = 4, P_EVENT = 8, P_CONT = 16, P_TERMINATED = 32, P_ERROR = 64,
       P_FATAL = 128, I_CS = 256, I_ME = 512,
       P_UPDATE = 1024 };  /* FMI 3.0's intermediate update mode: inside the host's callback during fmi3DoStep */
/* P_UPDATE is in no mask but the calls' that name it: every other call is refused inside the callback */
#define P_ANY (P_INSTANTIATED | P_INIT | P_STEP | P_EVENT | P_CONT | P_TERMINATED | P_ERROR)
#define P_RUNNING (P_STEP | P_EVENT | P_CONT)  /* initialized, not terminated */

const char *mbs_phase_name(int phase);
/* 0 if `fn` may be called in `phase` of an instance of interface `iface` (I_CS or I_ME) by `mask`; else 1 with
 * the message in buf */
int mbs_phase_refuses(int mask, int phase, int iface, const char *fn, char *buf, size_t len);

/* A registry of pointers; each call holds one small lock (instances may live on several threads). */
typedef struct { void **item; size_t n, cap; } MbsRegistry;
int mbs_reg_find(MbsRegistry *r, const void *p);
int mbs_reg_add(MbsRegistry *r, void *p);  /* 0: out of memory */
int mbs_reg_drop(MbsRegistry *r, const void *p);
/* the first item with match(item, ctx), NULL if none */
void *mbs_reg_first(MbsRegistry *r, int (*match)(void *item, void *ctx), void *ctx);
/* drop every item with match(item, ctx) and release it */
void mbs_reg_drop_all(MbsRegistry *r, int (*match)(void *item, void *ctx), void *ctx, void (*release)(void *item));

#endif
