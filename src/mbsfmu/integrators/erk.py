"""Stage loop and FSAL start shared by the explicit embedded Runge–Kutta pairs (DOPRI5, DOP853)."""

from .base import Integrator
from .initial_step import initial_step


def erk_stages(f, t, x, h, A, C, K, s):
    """Fill K[1:s] with k_i = f(t + c_i h, x + h Σ_j a_ij k_j); K[0] must already hold f(t, x)."""
    hA = h * A  # one scaling of the tableau instead of one per stage
    for i in range(1, s):
        # (row of h·A) @ K[:i] is a single BLAS call regardless of the number of stages
        K[i] = f(t + C[i] * h, x + hA[i, :i] @ K[:i])
    return hA


class FsalIntegrator(Integrator):
    """Explicit pairs with FSAL (dopri5, dop853): k1 = f(t, x) is cached across steps and calls."""

    def _invalidate_derivative(self):
        """New inputs: the cached first stage is not f at the new inputs."""
        self.k1 = None

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
