"""RADAU5: 3-stage Radau IIA (order 5, L-stable) after Hairer & Wanner, Solving ODEs II, Sec. IV.8.

Simplified Newton on the transformed stage system: T⁻¹·A⁻¹·T splits the 3n×3n iteration matrix into one
real (γ/h·I − J) and one complex ((α+iβ)/h·I − J) n×n matrix. The Jacobian is reused across steps while
Newton converges fast; the LU pair is reused while h stays within a factor [1, 1.2] of its old value.
Dense output is the collocation polynomial of the accepted step (Hairer's CONTR5).
"""

import math

import numpy as np
from scipy.linalg.lapack import dgetrf, dgetrs, zgetrf, zgetrs

from .base import Integrator
from .initial_step import initial_step
from .jacobian import problem_jacobian
from .norms import error_norm

_EPS = np.finfo(float).eps
S6 = 6.0 ** 0.5
C = np.array([(4.0 - S6) / 10.0, (4.0 + S6) / 10.0, 1.0])
# embedded error estimate weights (already divided by the real eigenvalue, as in SciPy's Radau)
E = np.array([-13.0 - 7.0 * S6, -13.0 + 7.0 * S6, -1.0]) / 3.0
# eigenvalues of A⁻¹ for the Radau IIA(5) coefficient matrix: one real, one complex-conjugate pair
MU_REAL = 3.0 + 3.0 ** (2.0 / 3.0) - 3.0 ** (1.0 / 3.0)
MU_COMPLEX = 3.0 + 0.5 * (3.0 ** (1.0 / 3.0) - 3.0 ** (2.0 / 3.0)) - 0.5j * (3.0 ** (5.0 / 6.0) + 3.0 ** (7.0 / 6.0))
T = np.array([
    [0.09443876248897524, -0.14125529502095421, 0.03002919410514742],
    [0.25021312296533332, 0.20412935229379994, -0.38294211275726192],
    [1.0, 1.0, 0.0]])
TI = np.array([
    [4.17871859155190428, 0.32768282076106237, 0.52337644549944951],
    [-4.17871859155190428, -0.32768282076106237, 0.47662355450055044],
    [0.50287263494578682, -2.57192694985560522, 0.59603920482822492]])
TI_REAL = TI[0].copy()
TI_COMPLEX = TI[1] + 1j * TI[2]
# collocation polynomial: Z(s) = Σ_k Q_k s^k, Q = Zᵀ·P, used to extrapolate the Newton starting guess
P = np.array([
    [13.0 / 3.0 + 7.0 * S6 / 3.0, -23.0 / 3.0 - 22.0 * S6 / 3.0, 10.0 / 3.0 + 5.0 * S6],
    [13.0 / 3.0 - 7.0 * S6 / 3.0, -23.0 / 3.0 + 22.0 * S6 / 3.0, 10.0 / 3.0 - 5.0 * S6],
    [1.0 / 3.0, -8.0 / 3.0, 10.0 / 3.0]])

_POWERS = np.array([1.0, 2.0, 3.0])
NEWTON_MAXITER = 7          # Hairer's NIT
MIN_FACTOR, MAX_FACTOR = 0.2, 10.0
KEEP_LU_LOW, KEEP_LU_HIGH = 1.0, 1.2   # Hairer's QUOT1, QUOT2: keep h (and LU) inside this band
THET = 1e-3                 # Jacobian is recomputed when the Newton contraction rate exceeds this


def predict_factor(h, h_old, err, err_old):
    """Gustafsson's predictive controller as in RADAU5: min(1, h/h_old·(err_old/err)^¼)·err^(−¼)."""
    if err == 0.0:
        return MAX_FACTOR
    if h_old is None or err_old is None:
        mult = 1.0
    else:
        mult = h / h_old * (err_old / err) ** 0.25
    return min(1.0, mult) * err ** -0.25


def lu_pair(J, h):
    """LU factors of (μ_real/h·I − J) and (μ_complex/h·I − J); None when one is singular."""
    n = J.shape[0]
    idx = np.arange(n)
    Mr = -J
    Mr[idx, idx] += MU_REAL / h
    Mc = -J.astype(complex)
    Mc[idx, idx] += MU_COMPLEX / h
    lur, pivr, info_r = dgetrf(Mr, overwrite_a=True)
    luc, pivc, info_c = zgetrf(Mc, overwrite_a=True)
    if info_r != 0 or info_c != 0:
        return None
    return (lur, pivr), (luc, pivc)


class Radau5(Integrator):
    """Implicit, L-stable, order 5; for stiff problems (large negative eigenvalues, stiff springs)."""

    method = "radau5"
    _has_dense = True
    _state_keys = ("f0", "J", "current_jac", "lu_real", "lu_complex", "lu_h", "h_old", "err_old",
                   "Q", "x_prev", "t_prev", "h_prev", "last_rejected", "faccon", "recompute_jac", "first")

    def __init__(self, problem, **kw):
        super().__init__(problem, **kw)
        # Hairer's tolerance transformation: the embedded estimate is only order 3 while the method is order 5,
        # so RADAU5 asks for rtol' = 0.1·rtol^(2/3) (same atol/rtol ratio) to make the global error ≈ rtol
        quot = self.atol / self.rtol
        self.rtol = 0.1 * self.rtol ** (2.0 / 3.0)
        self.atol = self.rtol * quot
        self.newton_tol = max(10.0 * _EPS / self.rtol, min(0.03, self.rtol ** 0.5))
        self._reset_history()

    def _reset_history(self):
        """Forget derivative, Jacobian, LU factors, controller memory and the collocation polynomial."""
        self.f0 = None
        self.J = None
        self.current_jac = False
        self.lu_real = self.lu_complex = None
        self.lu_h = None
        self.h_old = self.err_old = None
        self.Q = self.x_prev = self.t_prev = self.h_prev = None
        self.last_rejected = False
        self.faccon = 1.0
        self.recompute_jac = False
        self.first = True

    def _invalidate_derivative(self):
        """New inputs: f at the step start (used by the error estimate) is stale."""
        # the collocation polynomial is kept: it only seeds Newton, whose residual uses the new inputs
        self.f0 = None

    def _start(self, t_end):
        """f(t, x), Jacobian and HINIT (order 3 as the error estimator) when not available."""
        if self.f0 is None:
            self.f0 = self.problem.f(self.t, self.x)
            self.stats["rhs_evaluations"] += 1
            self._check_start_derivative(self.f0)
        if self.J is None:
            self._new_jacobian()
        if self.h is None:
            self.h, nf = initial_step(self.problem.f, self.t, self.x, self.f0, 3,
                                      self.rtol, self.atol, self.max_step, t_end)
            self.stats["rhs_evaluations"] += nf

    def _new_jacobian(self):
        """Evaluate df/dx at the current accepted point (invalidates the LU pair)."""
        self.J, nf = problem_jacobian(self.problem, self.t, self.x, self.f0)
        self.stats["rhs_evaluations"] += nf
        self.stats["jac_evaluations"] += 1
        self.current_jac = True
        self.lu_real = self.lu_complex = None

    def _starting_guess(self, h):
        """Newton start Z0: extrapolated collocation polynomial of the last step, else zero."""
        if self.Q is None:
            return np.zeros((3, self.n))
        s = (self.t - self.t_prev + h * C) / self.h_prev
        pw = s[:, None] ** _POWERS  # rows [s, s², s³] at the three new collocation nodes
        return (self.x_prev - self.x) + pw @ self.Q.T

    def _newton(self, t, x, h, Z, sc):
        """Simplified Newton on the transformed stages W = T⁻¹Z; returns (status, iterations, Z, rate)."""
        f = self.problem.f
        lur, pivr = self.lu_real
        luc, pivc = self.lu_complex
        mr, mc = MU_REAL / h, MU_COMPLEX / h
        ch = t + h * C
        W = TI @ Z
        F = np.empty((3, self.n))
        dW = np.empty_like(W)
        tol = self.newton_tol
        # Hairer: the contraction estimate of the previous step lets a fast iteration stop after one sweep
        faccon = max(self.faccon, _EPS) ** 0.8
        dnorm_old = None
        rate = None
        stats = self.stats
        for k in range(NEWTON_MAXITER):
            F[0] = f(ch[0], x + Z[0])
            F[1] = f(ch[1], x + Z[1])
            F[2] = f(ch[2], x + Z[2])
            stats["rhs_evaluations"] += 3
            fr = TI_REAL @ F - mr * W[0]
            fc = TI_COMPLEX @ F - mc * (W[1] + 1j * W[2])
            dW[0] = dgetrs(lur, pivr, fr)[0]
            dWc = zgetrs(luc, pivc, fc)[0]
            dW[1] = dWc.real
            dW[2] = dWc.imag
            q = (dW / sc).ravel()
            dnorm = math.sqrt(q.dot(q) / q.size)
            if not math.isfinite(dnorm):
                return "nonfinite", k + 1, Z, rate
            if dnorm_old is not None:
                rate = dnorm / dnorm_old
                if rate >= 0.99:
                    return "diverged", k + 1, Z, rate
                faccon = rate / (1.0 - rate)
                # predicted error after the remaining iterations still above tol: give up early
                if faccon * dnorm * rate ** (NEWTON_MAXITER - 1 - k) > tol:
                    return "slow", k + 1, Z, rate
            W += dW
            Z = T @ W
            if faccon * dnorm <= tol or dnorm == 0.0:
                self.faccon = faccon
                return "ok", k + 1, Z, rate
            dnorm_old = max(dnorm, _EPS)
        return "slow", NEWTON_MAXITER, Z, rate

    def _attempt(self, t_new, h):
        """One Radau IIA step: Newton (with Jacobian refresh on failure), error estimate, controller."""
        t, x = self.t, self.x
        sc = self.atol + self.rtol * np.abs(x)
        Z0 = self._starting_guess(h)
        while True:
            if self.lu_real is None or self.lu_h != h:
                pair = lu_pair(self.J, h)
                self.stats["lu_decompositions"] += 1
                if pair is None:
                    # singular iteration matrix (h hits an eigenvalue of J): try a different h
                    self.lu_real = self.lu_complex = None
                    self.h = 0.5 * h
                    return None
                (self.lu_real, self.lu_complex), self.lu_h = pair, h
            status, nit, Z, rate = self._newton(t, x, h, Z0, sc)
            if status == "ok":
                break
            if not self.current_jac:
                # Newton failed with an old Jacobian: refresh it at the step start and retry the same h
                self._new_jacobian()
                continue
            self.lu_real = self.lu_complex = None
            self.last_rejected = True
            self.last_failure = "newton"
            if status == "nonfinite":
                return self._trial_nonfinite(h)
            self.h = 0.5 * h
            return None

        x_new = x + Z[2]
        ZE = (E @ Z) / h
        lur, pivr = self.lu_real
        err_vec = dgetrs(lur, pivr, self.f0 + ZE)[0]
        err = error_norm(err_vec, x, x_new, self.atol, self.rtol)
        if err >= 1.0 and (self.first or self.last_rejected):
            # Hairer's improved estimate (one more solve) filters the stiff components after a rejection
            fe = self.problem.f(t, x + err_vec)
            self.stats["rhs_evaluations"] += 1
            err_vec = dgetrs(lur, pivr, fe + ZE)[0]
            err = error_norm(err_vec, x, x_new, self.atol, self.rtol)
        if not math.isfinite(err):
            self.lu_real = self.lu_complex = None
            return self._trial_nonfinite(h)
        safety = 0.9 * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + nit)
        if err >= 1.0:
            factor = predict_factor(h, self.h_old, err, self.err_old)
            self.h = h * max(MIN_FACTOR, safety * factor)
            self.last_rejected = True
            self.last_failure = "error"
            self.first = False
            return None

        self.recompute_jac = nit > 2 and rate is not None and rate > THET
        factor = min(MAX_FACTOR, safety * predict_factor(h, self.h_old, err, self.err_old))
        if self.last_rejected:
            factor = min(factor, 1.0)  # no growth right after a rejection
        if not self.recompute_jac and KEEP_LU_LOW <= factor <= KEEP_LU_HIGH:
            factor = 1.0  # keep h so the LU pair stays valid
        self.h_old, self.err_old = h, max(err, 1e-2)
        self.h = h * factor
        self.last_rejected = False
        self.first = False
        # collocation polynomial for the next starting guess
        self.Q = Z.T @ P
        self.x_prev, self.t_prev, self.h_prev = x, t, h
        self.current_jac = False
        return x_new

    def _dense_coeffs(self, t_old, x_old, x_new, h):
        """Collocation polynomial of the step just accepted: x(t_old + θh) = x_old + Σ_k Q_k θ^k (k = 1…3)."""
        Qd = np.empty((4, self.n))  # C order, like its snapshot copies: the same rounding in replays
        Qd[0], Qd[1:] = x_old, self.Q.T
        return Qd

    def _dense_eval(self, Q, theta):
        """Value of the collocation polynomial at θ ∈ [0, 1] of the step."""
        return np.dot([1.0, theta, theta * theta, theta ** 3], Q)

    def _dense_weights(self, theta, m):
        """Rows [1, θ_i, θ_i², θ_i³]."""
        return theta[:, None] ** np.arange(m)

    def _accepted(self):
        """f at the new (normalized) point; fresh Jacobian there if Newton was slow."""
        self.f0 = self.problem.f(self.t, self.x)
        self.stats["rhs_evaluations"] += 1
        self._check_start_derivative(self.f0)
        if self.recompute_jac:
            self._new_jacobian()
