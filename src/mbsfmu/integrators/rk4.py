"""Classical fixed-step Runge–Kutta method of order 4."""

import math

from mbsfmu.errors import IntegrationError

from .base import Integrator
from .norms import all_finite


# RK4's stability interval on the negative real axis ends at h·λ ≈ −2.785; an estimate above HLAMB_MAX while
# the increment is also far larger than the Euler increment means the step is blowing up (not just stiff-ish)
HLAMB_MAX, GROWTH_MAX = 4.0, 4.0


def rk4_step(f, t, x, h, k1):
    """x(t+h) ≈ x + h/6·(k1 + 2k2 + 2k3 + k4), the classical RK4 tableau; also returns the blow-up estimate."""
    h2 = 0.5 * h
    k2 = f(t + h2, x + h2 * k1)
    k3 = f(t + h2, x + h2 * k2)
    k4 = f(t + h, x + h * k3)
    dx = (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)
    return x + dx, unstable(h, k1, k2, k3, k4, dx)


def unstable(h, k1, k2, k3, k4, dx):
    """DOPRI5-style test on RK4 stages: h·‖k4−k3‖/‖x4−x3‖ estimates h·|λ|; returns it when blowing up, else 0."""
    dk = k4 - k3
    dxs = h * (k3 - 0.5 * k2)  # (x + h·k3) − (x + h/2·k2)
    den = dxs.dot(dxs)
    if not den > 0.0:
        return 0.0
    hlamb = h * math.sqrt(dk.dot(dk) / den)
    # reference increment h(‖k1‖ + ‖k2‖), not h‖k1‖ alone: starting at rest (k1 = 0) must not count as growth
    ref = h * (math.sqrt(k1.dot(k1)) + math.sqrt(k2.dot(k2)))
    return hlamb if hlamb > HLAMB_MAX and math.sqrt(dx.dot(dx)) > GROWTH_MAX * ref else 0.0


class RK4(Integrator):
    """Fixed step: each communication interval is split into equal steps no longer than h (or max_step)."""

    method = "rk4"

    def _advance(self, t_end):
        """Equal substeps ≤ h across [t, t_end]; the last one lands exactly on t_end."""
        f = self.problem.f
        h_max = self.h_fixed if self.h_fixed is not None else self.max_step
        h_max = min(h_max, self.max_step)
        t0 = self.t
        span = t_end - t0
        # the tiny relative slack avoids an extra step when span/h is an integer up to rounding
        nsub = max(1, math.ceil(span / h_max * (1.0 - 1e-12))) if math.isfinite(h_max) else 1
        if nsub > self.max_steps:
            raise IntegrationError(f"maximum number of steps ({self.max_steps}) exceeded: fixed step "
                                   f"{h_max:.3g} over an interval of {span:.3g}", self.t)
        stats = self.stats
        for i in range(1, nsub + 1):
            t = self.t
            t_new = t_end if i == nsub else t0 + span * i / nsub
            k1 = f(t, self.x)
            h = t_new - t
            x_new, blowup = rk4_step(f, t, self.x, h, k1)
            stats["rhs_evaluations"] += 4
            if not all_finite(x_new):
                raise IntegrationError("rk4 produced non-finite values (NaN or Inf): right-hand side not finite "
                                       "or step size unstable for this problem", t)
            if blowup:
                raise IntegrationError(f"rk4 is unstable at step size {h:.3g}: the problem is stiff (estimated "
                                       f"h·lambda = {blowup:.3g}, stability limit 2.8); use a smaller step, "
                                       "radau5, gen_alpha or auto", t)
            if self._normalize is not None:
                x_new = self._normalize(x_new)
            self.t, self.x = t_new, x_new
            stats["steps"] += 1
        self.h = span / nsub
