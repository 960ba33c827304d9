"""Jacobians of the first-order right-hand side: analytic when the problem offers one, else finite differences."""

import numpy as np

from mbsfmu.errors import IntegrationError

_SQRT_EPS = np.sqrt(np.finfo(float).eps)


def fd_jacobian(f, t, x, f0):
    """Forward-difference df/dx, column j with increment sqrt(eps·max(1e-5, |x_j|)) (Hairer's RADAU5 choice)."""
    n = x.size
    J = np.empty((n, n))
    delta = _SQRT_EPS * np.sqrt(np.maximum(1e-5, np.abs(x)))
    xp = x.copy()
    for j in range(n):
        xj = xp[j]
        xp[j] = xj + delta[j]
        d = xp[j] - xj  # the increment actually representable in floating point
        J[:, j] = (f(t, xp) - f0) / d
        xp[j] = xj
    return J


def problem_jacobian(problem, t, x, f0):
    """df/dx from problem.jac when present (and not None), else by finite differences; returns (J, rhs_evals)."""
    jac = getattr(problem, "jac", None)
    if jac is not None:
        J = np.array(jac(t, x), dtype=float)
        nf = 0
    else:
        J = fd_jacobian(problem.f, t, x, f0)
        nf = x.size
    if not np.isfinite(J).all():
        raise IntegrationError("Jacobian of the right-hand side is not finite", t)
    return J, nf
