"""Starting step size (Hairer, Norsett & Wanner, Solving ODEs I, Sec. II.4, routine HINIT)."""

import math

import numpy as np


def initial_step(f, t, x, f0, order, rtol, atol, max_step, t_end):
    """HINIT: h from ‖x‖/‖f‖ and a second-derivative estimate, h = (0.01/max(d1,d2))^(1/(order+1)).

    Returns (h, rhs_evaluations)."""
    span = t_end - t
    sc = atol + rtol * np.abs(x)
    d0 = math.sqrt(np.mean((x / sc) ** 2))
    d1 = math.sqrt(np.mean((f0 / sc) ** 2))
    h0 = 1e-6 if (d0 < 1e-5 or d1 < 1e-5) else 0.01 * d0 / d1
    h0 = min(h0, max_step, span)
    # explicit Euler trial step gives a difference quotient for the second derivative
    f1 = f(t + h0, x + h0 * f0)
    d2 = math.sqrt(np.mean(((f1 - f0) / sc) ** 2)) / h0
    if not math.isfinite(d2):
        # the trial point is unusable (e.g. NaN there): start very small and let the controller grow h
        return max(h0 * 1e-3, 1e-12 * max(abs(t), 1.0)), 1
    dmax = max(d1, d2)
    h1 = max(1e-6, h0 * 1e-3) if dmax <= 1e-15 else (0.01 / dmax) ** (1.0 / (order + 1))
    return min(100.0 * h0, h1, max_step), 1
