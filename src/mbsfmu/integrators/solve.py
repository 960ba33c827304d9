"""Convenience driver: integrate over a list of output times with any method."""

import numpy as np

from .base import advance_many
from .registry import make_integrator


def solve(problem, method, t_eval, x0, **opts):
    """Return (X, stats): X[i] is the state at t_eval[i] (X[0] = x0)."""
    t_eval = np.asarray(t_eval, dtype=float)
    integ = make_integrator(method, problem, **opts)
    integ.reset(t_eval[0], x0)
    X = np.empty((t_eval.size, integ.problem.n))
    X[0] = integ.x
    X[1:] = advance_many(integ, t_eval[1:])
    return X, integ.stats
