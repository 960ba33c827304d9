/* The ODE's right side ẋ = [Z(y) ẏ; ÿ] of the tree: ÿ from M ÿ = q − k on the dense path, from the
 * articulated-body algorithm on the recursive one (the compiler's choice, H_DENSE). */
#include "mbs_integrator.h"
#include "mbs_model.h"

/* ẋ = [Z(y) ẏ; M⁻¹(q − k)] into e->xdot, from the kinematics at e->x already in the workspace (mbs_kinematics):
 * M assembled and factored (dense path) or ÿ by the articulated-body algorithm (recursive path, dynamics.c).
 * Returns 0, or MBS_F_SINGULAR when M is not positive definite. */
int mbs_eval_rhs(const MbsEval *e)
{
    const MbsModel *m = e->m;
    const int f = NVEL(m), np = NPOS(m);
    real *xd = e->xdot;
    if (!m->dense) {
        if (mbs_aba(e)) return MBS_F_SINGULAR;
    } else {
        mbs_mass_matrix_and_bias(e);
        mbs_applied_forces(e);
        for (int c = 0; c < f; c++) xd[np + c] = e->q[c] - e->k[c];
        if (mbs_cholesky_solve(f, e->M, xd + np)) return MBS_F_SINGULAR;
    }
    mbs_position_rates(e);
    return 0;
}
