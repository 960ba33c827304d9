/* elastic.c's complex twin for deriv.c's directional derivatives: a file of its own, so that a rigid scene's
 * engine (and FMU) carries no elastic code */
#define MBS_CX 1
#include "elastic.c"
