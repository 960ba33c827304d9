/* The scene's domains and rules over a host's values (rules.c): the model's tables only, no instance. */
#ifndef MBS_RULES_H
#define MBS_RULES_H
#include <stddef.h>

#include "mbs_model.h"

extern const int mbs_rule_size[R_N];                                /* numbers of D each rule reads (mbs_layout.h) */
int mbs_in_domain(const double *d, double v);                       /* v in domain d (S_VDOM row) */
void mbs_domain_text(const double *d, char *buf, size_t len);       /* the domain as a reader writes it */
/* NULL if rule holds for v (the rule's count of numbers), else what is wrong (written into buf) */
const char *mbs_rule_problem(const MbsModel *m, int rule, const double *v, char *buf, size_t len);
/* 1 (message in buf) if a Cardan joint is in gimbal lock at x, or crossed it since x_before (may be NULL) */
int mbs_gimbal(const MbsModel *m, const double *x, const double *x_before, char *buf, size_t len);
#endif
