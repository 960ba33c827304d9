"""Stage loop and FSAL start shared by the explicit embedded Runge–Kutta pairs (DOPRI5, DOP853)."""

from itertools import accumulate
from operator import mul

import numpy as np

from .base import Integrator
from .initial_step import initial_step


def erk_stages(problem, t, x, h, A, C, K, i0, s, t_end):
    """Fill K[i0:s] with k_i = f(t + c_i h, x + h Σ_j a_ij k_j) (K[:i0] already filled) and return the
    argument of the last stage (for an FSAL row: x_new). A stage with c_i = 1 is evaluated at t_end."""
    stages = getattr(problem, "stages", None)  # one compiled loop where the problem has it (rigid scenes)
    xs = stages(A, C, K, i0, s, h, x, t, t_end) if stages is not None else None
    if xs is not None:
        return xs
    f = problem.f
    hA = h * A  # one scaling of the tableau instead of one per stage
    for i in range(i0, s):
        # (row of h·A) @ K[:i] is a single BLAS call regardless of the number of stages
        xs = x + hA[i, :i] @ K[:i]
        K[i] = f(t_end if C[i] == 1.0 else t + C[i] * h, xs)
    return xs


def alternating_weights(theta, m):
    """Weights w with Q0 + θ(Q1 + (1−θ)(Q2 + θ(Q3 + …))) = w·Q (Hairer's CONTD5/CONTD8 nesting), so the
    continuous extension is one matrix–vector product instead of m small vector updates."""
    return list(accumulate([theta, 1.0 - theta] * (m // 2) + [theta] * (m % 2), mul, initial=1.0))[:m]


class FsalIntegrator(Integrator):
    """Explicit pairs with FSAL (dopri5, dop853): k1 = f(t, x) is cached across steps and calls."""

    def _invalidate_derivative(self):
        """New inputs: the cached first stage is not f at the new inputs."""
        self.k1 = None

    def _dense_eval(self, Q, theta):
        """Value of the continuous extension at θ ∈ [0, 1] of the step: w(θ)·Q."""
        return np.dot(alternating_weights(theta, len(Q)), Q)

    def _dense_weights(self, theta, m):
        """w(θ_i) as rows, for an array θ: running products of the factors 1, θ, 1−θ, θ, …"""
        F = np.empty((len(theta), m))
        F[:, 0] = 1.0
        F[:, 1::2] = theta[:, None]
        F[:, 2::2] = (1.0 - theta)[:, None]
        return np.cumprod(F, axis=1)

    def _start(self, t_end):
        """Evaluate f(t, x) unless the FSAL stage is cached; HINIT on the very first call only."""
        if self.k1 is None:
            self.k1 = self.problem.f(self.t, self.x)
            self.stats["rhs_evaluations"] += 1
            self._check_start_derivative(self.k1)
        if self.h is None:
            self.h, nf = initial_step(self.problem.f, self.t, self.x, self.k1, self.order,
                                      self.rtol, self.atol, self.max_step, t_end)
            self.stats["rhs_evaluations"] += nf
