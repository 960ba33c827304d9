"""DOP853: Dormand–Prince 8(5,3) with Hairer's combined 5th/3rd-order error estimate, FSAL."""

import math

import numpy as np

from . import dop853_tables as T
from .erk import FsalIntegrator, erk_stages

S = T.N_STAGES  # 12 stages; the 13th row of K holds the FSAL stage f(t+h, x_new)
# one tableau for the 12 stages, the FSAL row (= b, c = 1) and the 3 extra stages of the dense output
AX = np.zeros((T.N_STAGES_EXTENDED, T.N_STAGES_EXTENDED))
AX[:S + 1, :S + 1] = T.A
AX[S + 1:] = T.A_EXTRA
C = np.ascontiguousarray(T.C)
E3 = np.ascontiguousarray(T.E3)
E5 = np.ascontiguousarray(T.E5)
D = np.ascontiguousarray(T.D)

# Hairer's DOP853 defaults: safety 0.9, 1/3 <= hnew/h <= 6, no PI part (beta = 0), exponent 1/8
SAFE, FAC1, FAC2, EXPO1 = 0.9, 0.333, 6.0, 1.0 / 8.0


def dop853_error(K, h, sc):
    """Hairer's estimate: |h|·‖e5‖² / sqrt(‖e5‖² + 0.01‖e3‖²) in the RMS sense (robust for large h)."""
    e5 = (E5 @ K) / sc
    e3 = (E3 @ K) / sc
    n5 = e5.dot(e5)
    n3 = e3.dot(e3)
    if n5 == 0.0 and n3 == 0.0:
        return 0.0
    return abs(h) * n5 / math.sqrt((n5 + 0.01 * n3) * sc.size)


class Dop853(FsalIntegrator):
    """Explicit 8th-order pair for smooth problems at tight tolerances."""

    method = "dop853"
    _state_keys = ("k1", "last_rejected")
    order = 7  # HINIT uses the error-estimator order
    _has_dense = True

    def __init__(self, problem, **kw):
        super().__init__(problem, **kw)
        # stages 0..11, FSAL stage 12, and the three extra stages of the continuous extension
        self._Kx = np.empty((T.N_STAGES_EXTENDED, self.n))
        self._K = self._Kx[:S + 1]
        self._reset_history()

    def _reset_history(self):
        """Forget FSAL stage and rejection flag."""
        self.k1 = None
        self.last_rejected = False

    def _attempt(self, t_new, h):
        """One DOP853 step (12 stages + FSAL) with error test and I-controller."""
        t, x, K = self.t, self.x, self._K
        K[0] = self.k1
        x_new = erk_stages(self.problem, t, x, h, AX, C, self._Kx, 1, S + 1, t_new)  # row S = b: FSAL stage
        self.stats["rhs_evaluations"] += S
        sc = self.atol + self.rtol * np.maximum(np.abs(x), np.abs(x_new))
        err = dop853_error(K, h, sc)
        if not math.isfinite(err):
            return self._trial_nonfinite(h)
        fac11 = err ** EXPO1
        fac = max(1.0 / FAC2, min(1.0 / FAC1, fac11 / SAFE))
        if err > 1.0:
            self.h = h / min(1.0 / FAC1, fac11 / SAFE)
            self.last_rejected = True
            return None
        h_new = h / fac
        if self.last_rejected:
            h_new = min(h_new, h)
        self.last_rejected = False
        self.h = h_new
        self.k1 = K[S].copy()
        return x_new

    def _dense_coeffs(self, t_old, x_old, x_new, h):
        """Order-7 continuous extension: 3 extra stages, then [x_old; F0..F6] as in SciPy's DOP853."""
        K = self._Kx
        erk_stages(self.problem, t_old, x_old, h, AX, C, K, S + 1, T.N_STAGES_EXTENDED, t_old + h)
        self.stats["rhs_evaluations"] += T.N_STAGES_EXTENDED - S - 1
        Q = np.empty((T.INTERPOLATOR_POWER + 1, self.n))
        dy = x_new - x_old
        Q[0] = x_old
        Q[1] = dy
        Q[2] = h * K[0] - dy
        Q[3] = 2.0 * dy - h * (K[S] + K[0])
        Q[4:] = (h * D) @ K
        return Q
