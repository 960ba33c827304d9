"""Dormand–Prince 5(4) with FSAL, Hairer's PI step-size control and DOPRI5's stiffness detection."""

import math

import numpy as np

from .erk import FsalIntegrator, erk_stages
from .norms import error_norm

C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0])
A = np.zeros((7, 7))
A[1, :1] = [1 / 5]
A[2, :2] = [3 / 40, 9 / 40]
A[3, :3] = [44 / 45, -56 / 15, 32 / 9]
A[4, :4] = [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729]
A[5, :5] = [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656]
A[6, :6] = [35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84]  # = b (5th order), FSAL row
# E = b5 - b4 (Hairer's e_i), applied to all 7 stages including the FSAL stage k7
E = np.array([71 / 57600, 0.0, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40])

# Hairer's continuous extension of order 4 (DOPRI5's CONTD5; the same polynomial as SciPy's RK45 P matrix)
D = np.array([-12715105075 / 11282082432, 0.0, 87487479700 / 32700410799, -10690763975 / 1880347072,
              701980252875 / 199316789632, -1453857185 / 822651844, 69997945 / 29380423])

# Hairer's DOPRI5 defaults: safety 0.9, 0.2 <= hnew/h <= 10, PI controller with beta = 0.04
SAFE, FAC1, FAC2, BETA = 0.9, 0.2, 10.0, 0.04
EXPO1 = 0.2 - 0.75 * BETA
# stiffness test: h·|λ| estimate above 3.25 (boundary of the stability region) 15 times, reset after 6 misses
STIFF_HLAMB, STIFF_COUNT, NONSTIFF_RESET = 3.25, 15, 6


def pi_factor(err, facold):
    """Hairer's PI controller: fac = err^(0.2-0.75β) / facold^β, limited to [1/FAC2, 1/FAC1] (as h/hnew)."""
    fac11 = err ** EXPO1
    fac = fac11 / facold ** BETA
    return fac11, max(1.0 / FAC2, min(1.0 / FAC1, fac / SAFE))


class Dopri5(FsalIntegrator):
    """Explicit 5(4) pair; error per step estimated from the embedded 4th-order solution."""

    method = "dopri5"
    _state_keys = ("k1", "facold", "last_rejected", "iasti", "nonsti", "stiff_detected")
    order = 4  # order of the error estimator (HINIT uses it)
    _has_dense = True

    def __init__(self, problem, detect_stiffness=False, stop_when_stiff=False, **kw):
        super().__init__(problem, **kw)
        self.detect_stiffness = detect_stiffness or stop_when_stiff
        self.stop_when_stiff = stop_when_stiff
        self._K = np.empty((7, self.n))
        self._reset_history()

    def _reset_history(self):
        """Forget FSAL stage, controller memory and stiffness counters."""
        self.k1 = None
        self.facold = 1e-4
        self.last_rejected = False
        self.iasti = 0
        self.nonsti = 0
        self.stiff_detected = False


    def _attempt(self, t_new, h):
        """One DOPRI5 step with error test; FSAL: k7 = f(t+h, x_new) becomes next k1."""
        t, x, K = self.t, self.x, self._K
        K[0] = self.k1
        x_new = erk_stages(self.problem, t, x, h, A, C, K, 1, 7, t_new)  # row 7 = b: FSAL stage f(t_new, x_new)
        self.stats["rhs_evaluations"] += 6
        err = error_norm((h * E) @ K, x, x_new, self.atol, self.rtol)
        if not math.isfinite(err):
            return self._trial_nonfinite(h)
        fac11, fac = pi_factor(err, self.facold)
        if err > 1.0:
            # rejection: pure I-control, no growth
            self.h = h / min(1.0 / FAC1, fac11 / SAFE)
            self.last_rejected = True
            return None
        self.facold = max(err, 1e-4)
        h_new = h / fac
        if self.last_rejected:
            h_new = min(h_new, h)  # no growth right after a rejection (Hairer)
        self.last_rejected = False
        self.h = h_new
        if self.detect_stiffness:
            self._stiffness_test(h, K, x, x_new)
        self.k1 = K[6].copy()
        return x_new

    def _dense_coeffs(self, t_old, x_old, x_new, h):
        """Hairer's rcont1..5 of CONTD5, r1 + θ(r2 + (1−θ)(r3 + θ(r4 + (1−θ) r5))), from the stages of the
        accepted step (K[0] = f at start, K[6] = f at end)."""
        K = self._K
        Q = np.empty((5, self.n))
        Q[0] = x_old
        ydiff = np.subtract(x_new, x_old, out=Q[1])
        bspl = np.subtract(h * K[0], ydiff, out=Q[2])
        Q[3] = ydiff - h * K[6] - bspl
        np.dot(h * D, K, out=Q[4])
        return Q

    def _stop_early(self):
        """With stop_when_stiff, hand control back as soon as stiffness is detected."""
        return self.stop_when_stiff and self.stiff_detected

    def _stiffness_test(self, h, K, x, x_new):
        """DOPRI5's test: h·‖k7−k6‖/‖x7−x6‖ estimates h·|λ_dominant|; stiff when it sits at the boundary."""
        x6 = x + (h * A[5, :5]) @ K[:5]  # argument of stage 6 (c6 = 1, same time as x_new)
        dk = K[6] - K[5]
        dx = x_new - x6
        stden = dx.dot(dx)
        if stden > 0.0:
            hlamb = h * math.sqrt(dk.dot(dk) / stden)
            if hlamb > STIFF_HLAMB:
                self.nonsti = 0
                self.iasti += 1
                if self.iasti >= STIFF_COUNT:
                    self.stiff_detected = True
                return
        self.nonsti += 1
        if self.nonsti == NONSTIFF_RESET:
            self.iasti = 0
