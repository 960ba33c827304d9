"""Generalized-α (Chung & Hulbert 1993) on the second-order form v̇ = accel(t, y, v), ẏ ~ v.

Formulation of Arnold & Brüls (2007), valid on Lie groups via problem.retract:
    y₊ = retract(y, h·v + h²(½−β)·a + h²β·a₊)
    v₊ = v + h(1−γ)·a + hγ·a₊
    (1−α_m)·a₊ + α_m·a = (1−α_f)·v̇₊ + α_f·v̇,     v̇₊ = accel(t₊, y₊, v₊)
with α_m = (2ρ∞−1)/(ρ∞+1), α_f = ρ∞/(ρ∞+1), γ = ½ + α_f − α_m, β = ¼(γ + ½)²  (second order, ρ∞ = spectral
radius at h·ω → ∞). Newton iterates on v̇₊ with the matrix S = I − c(h²β·K + hγ·D), c = (1−α_f)/(1−α_m),
K = ∂accel/∂y (tangent), D = ∂accel/∂v. Fixed step when h is given; otherwise adaptive by step doubling
(Richardson estimate of the local error, order 2 ⇒ local error h³).
"""

import math

import numpy as np
from scipy.linalg.lapack import dgetrf, dgetrs

from mbsfmu.errors import IntegrationError

from .base import Integrator
from .initial_step import initial_step
from .norms import error_norm

_EPS = np.finfo(float).eps
_SQRT_EPS = math.sqrt(_EPS)
NEWTON_MAXITER = 8
MIN_FACTOR, MAX_FACTOR, SAFE = 0.2, 5.0, 0.9
KEEP_H_LOW, KEEP_H_HIGH = 1.0, 1.2  # keep h (and the LU of S) when the controller asks for ≤ 20 % growth
JAC_RATE = 1e-2                     # refresh K, D when Newton contracts slower than this
MAX_SPLIT_DEPTH = 10                # fixed-step mode: halve a failing step at most this often


def alpha_coefficients(rho_inf):
    """Chung–Hulbert parameters (α_m, α_f, β, γ) for spectral radius ρ∞ ∈ [0, 1]."""
    if not 0.0 <= rho_inf <= 1.0:
        raise ValueError(f"rho_inf must lie in [0, 1] (got {rho_inf})")
    am = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0)
    af = rho_inf / (rho_inf + 1.0)
    gamma = 0.5 + af - am
    beta = 0.25 * (gamma + 0.5) ** 2
    return am, af, beta, gamma


class GenAlpha(Integrator):
    """Second-order implicit method with controllable high-frequency damping (ρ∞, default 0.8)."""

    method = "gen_alpha"
    _state_keys = ("vdot", "a", "K", "D", "current_jac", "lu_cache", "faccon", "last_rejected",
                   "recompute_jac")

    def __init__(self, problem, rho_inf=0.8, **kw):
        super().__init__(problem, **kw)
        self.npos, self.nvel = int(problem.npos), int(problem.nvel)
        if self.npos + self.nvel != self.n:
            raise ValueError(f"gen_alpha needs n = npos + nvel (got {self.n} != {self.npos} + {self.nvel})")
        self.rho_inf = float(rho_inf)
        self.coef = alpha_coefficients(self.rho_inf)
        retract = getattr(problem, "retract", None)
        if retract is None:
            if self.npos != self.nvel:
                raise ValueError("gen_alpha needs problem.retract when npos != nvel")
            retract = _vector_add
        self._retract = retract
        self.newton_tol = max(10.0 * _EPS / self.rtol, min(0.03, self.rtol ** 0.5))
        self._reset_history()

    def _reset_history(self):
        """Forget accelerations, iteration-matrix data and controller memory."""
        self.vdot = None
        self.a = None
        self.K = self.D = None
        self.current_jac = False
        self.lu_cache = {}
        self.faccon = 1.0
        self.last_rejected = False
        self.recompute_jac = False

    def _invalidate_derivative(self):
        """New inputs: restart the acceleration history (a = v̇ at the new inputs), as after a discontinuity."""
        self.vdot = None

    # ------------------------------------------------------------ Jacobian and iteration matrix
    def _accel(self, t, y, v):
        """problem.accel with bookkeeping (counted as a right-hand-side evaluation)."""
        self.stats["rhs_evaluations"] += 1
        return self.problem.accel(t, y, v)

    def _new_jacobian(self):
        """K = ∂accel/∂y along retract directions and D = ∂accel/∂v at the current point."""
        t, x, npos, nv = self.t, self.x, self.npos, self.nvel
        y, v = x[:npos], x[npos:]
        jac = getattr(self.problem, "jac", None)
        if jac is not None and npos == nv:
            # first-order Jacobian [[0, I], [K, D]]: the lower block row is what we need
            J = np.asarray(jac(t, x), dtype=float)
            K, D = J[npos:, :npos].copy(), J[npos:, npos:].copy()
        else:
            acc0 = self._accel(t, y, v)
            K = np.empty((nv, nv))
            D = np.empty((nv, nv))
            dy = np.zeros(nv)
            for j in range(nv):
                d = _SQRT_EPS * max(1.0, abs(y[j])) if npos == nv else _SQRT_EPS
                dy[j] = d
                K[:, j] = (self._accel(t, self._retract(y, dy), v) - acc0) / d
                dy[j] = 0.0
                vp = v.copy()
                vp[j] += _SQRT_EPS * max(1.0, abs(v[j]))
                D[:, j] = (self._accel(t, y, vp) - acc0) / (vp[j] - v[j])
        if not (np.isfinite(K).all() and np.isfinite(D).all()):
            raise IntegrationError("Jacobian of the accelerations is not finite", t)
        self.K, self.D = K, D
        self.stats["jac_evaluations"] += 1
        self.current_jac = True
        self.lu_cache = {}

    def _lu(self, h):
        """LU of S(h) = I − c(h²β·K + hγ·D); cached for the (at most two) step sizes in use."""
        lu = None
        for hc, luc in self.lu_cache.items():
            # S only steers the simplified Newton iteration (the residual decides the solution), so a
            # factorization for a step size equal up to rounding is as good and saves refactoring
            if abs(hc - h) <= 1e-10 * h:
                lu = luc
                break
        if lu is None:
            am, af, beta, gamma = self.coef
            c = (1.0 - af) / (1.0 - am)
            S = (-c * h * h * beta) * self.K - (c * h * gamma) * self.D
            S[np.diag_indices_from(S)] += 1.0
            lu_, piv, info = dgetrf(S, overwrite_a=True)
            self.stats["lu_decompositions"] += 1
            if info != 0:
                return None
            if len(self.lu_cache) >= 2:
                self.lu_cache.pop(next(iter(self.lu_cache)))
            lu = self.lu_cache[h] = (lu_, piv)
        return lu

    # ------------------------------------------------------------ one generalized-α step
    def _ga_step(self, t, y, v, vd, a, h):
        """Solve one step by simplified Newton on v̇₊; returns (status, y₊, v₊, v̇₊, a₊, iterations, rate)."""
        am, af, beta, gamma = self.coef
        c = (1.0 - af) / (1.0 - am)
        lu = self._lu(h)
        if lu is None:
            return "singular", None, None, None, None, 0, None
        lu_, piv = lu
        a_base = (af * vd - am * a) / (1.0 - am)
        dy_base = h * v + (h * h * (0.5 - beta)) * a
        v_base = v + (h * (1.0 - gamma)) * a
        hb, hg = h * h * beta, h * gamma
        sc = self.atol + self.rtol * np.abs(v)
        t1 = t + h
        w = vd  # predictor: acceleration unchanged over the step
        faccon = max(self.faccon, _EPS) ** 0.8
        tol = self.newton_tol
        dnorm_old = rate = None
        retract, accel = self._retract, self.problem.accel
        for k in range(NEWTON_MAXITER):
            a1 = a_base + c * w
            r = w - accel(t1, retract(y, dy_base + hb * a1), v_base + hg * a1)
            self.stats["rhs_evaluations"] += 1
            dw = dgetrs(lu_, piv, r)[0]
            w = w - dw
            q = (hg * c) * dw / sc  # Newton correction seen in the velocities
            dnorm = math.sqrt(q.dot(q) / q.size)
            if not math.isfinite(dnorm):
                return "nonfinite", None, None, None, None, k + 1, rate
            if dnorm_old is not None:
                rate = dnorm / dnorm_old
                if rate >= 0.99:
                    return "diverged", None, None, None, None, k + 1, rate
                faccon = rate / (1.0 - rate)
            if faccon * dnorm <= tol or dnorm == 0.0:
                self.faccon = faccon
                a1 = a_base + c * w
                return "ok", retract(y, dy_base + hb * a1), v_base + hg * a1, w, a1, k + 1, rate
            dnorm_old = max(dnorm, _EPS)
        return "slow", None, None, None, None, NEWTON_MAXITER, rate

    def _step_retry(self, t, y, v, vd, a, h):
        """_ga_step, refreshing a stale Jacobian once when Newton fails."""
        while True:
            res = self._ga_step(t, y, v, vd, a, h)
            if res[0] == "ok" or self.current_jac or res[0] == "nonfinite":
                return res
            self._new_jacobian()

    # ------------------------------------------------------------ drivers
    def _start(self, t_end):
        """Acceleration at the current point (restarts a = v̇), Jacobian, and HINIT in adaptive mode."""
        if self.vdot is None:
            npos = self.npos
            self.vdot = self._accel(self.t, self.x[:npos], self.x[npos:])
            self._check_start_derivative(self.vdot)
            self.a = self.vdot.copy()
        if self.K is None:
            self._new_jacobian()
        if self.h is None and self.h_fixed is None:
            f0 = self.problem.f(self.t, self.x)
            self.stats["rhs_evaluations"] += 1
            self.h, nf = initial_step(self.problem.f, self.t, self.x, f0, 2,
                                      self.rtol, self.atol, self.max_step, t_end)
            self.stats["rhs_evaluations"] += nf

    def _advance(self, t_end):
        """Fixed mode: equal substeps ≤ h; adaptive mode: the common driver with step doubling."""
        if self.h_fixed is None:
            return super()._advance(t_end)
        self._start(t_end)
        h_max = min(self.h_fixed, self.max_step)
        t0, span = self.t, t_end - self.t
        nsub = max(1, math.ceil(span / h_max * (1.0 - 1e-12)))
        if nsub > self.max_steps:
            raise IntegrationError(f"maximum number of steps ({self.max_steps}) exceeded: fixed step "
                                   f"{h_max:.3g} over an interval of {span:.3g}", self.t)
        for i in range(1, nsub + 1):
            t_new = t_end if i == nsub else t0 + span * i / nsub
            self._fixed_step(t_new, span / nsub, 0)
        self.h = span / nsub

    def _fixed_step(self, t_new, h, depth):
        """One fixed step of nominal size h to t_new; if Newton fails with a fresh Jacobian, split it in halves."""
        t, npos = self.t, self.npos
        st, y1, v1, vd1, a1, nit, rate = self._step_retry(t, self.x[:npos], self.x[npos:], self.vdot, self.a, h)
        if st != "ok":
            self.stats["rejected"] += 1
            if depth >= MAX_SPLIT_DEPTH:
                what = "non-finite accelerations" if st == "nonfinite" else f"Newton iteration {st}"
                raise IntegrationError(f"gen_alpha: {what} even at step size {h:.3g} "
                                       f"(fixed step split {depth} times)", t)
            self._fixed_step(t + 0.5 * h, 0.5 * h, depth + 1)
            self._fixed_step(t_new, 0.5 * h, depth + 1)
            return
        self._commit(t_new, y1, v1, vd1, a1, nit, rate)

    def _commit(self, t_new, y1, v1, vd1, a1, nit, rate):
        """Move to the accepted point (normalized), remember accelerations, decide on a Jacobian refresh."""
        x_new = np.concatenate((y1, v1))
        if not np.isfinite(x_new).all():
            raise IntegrationError("gen_alpha produced a non-finite state", self.t)
        if self._normalize is not None:
            x_new = np.asarray(self._normalize(x_new), dtype=float)
        self.t, self.x, self.vdot, self.a = t_new, x_new, vd1, a1
        self.stats["steps"] += 1
        self.current_jac = False
        if nit > 2 and rate is not None and rate > JAC_RATE:
            self._new_jacobian()

    def _attempt(self, t_new, h):
        """Adaptive step by doubling: one step h vs two steps h/2, error = (x_two − x_one)/(2²−1)."""
        t, x, npos = self.t, self.x, self.npos
        y, v = x[:npos], x[npos:]
        h2 = 0.5 * h
        big = res = self._step_retry(t, y, v, self.vdot, self.a, h)
        if res[0] == "ok":
            res = self._step_retry(t, y, v, self.vdot, self.a, h2)
            if res[0] == "ok":
                # same nominal h2 for both halves so one cached LU serves both
                res = self._step_retry(t + h2, res[1], res[2], res[3], res[4], h2)
        if res[0] != "ok":
            self.last_rejected = True
            self.last_failure = "newton"
            if res[0] == "nonfinite":
                return self._trial_nonfinite(h, "accelerations")
            self.h = 0.25 * h  # Newton failure even with a fresh Jacobian: much smaller step
            return None
        end = res
        _, y1, v1, vd1, a1, nit, rate = end
        x_one = np.concatenate((big[1], big[2]))
        x_two = np.concatenate((y1, v1))
        err = error_norm((x_two - x_one) / 3.0, x, x_two, self.atol, self.rtol)
        if not math.isfinite(err):
            return self._trial_nonfinite(h, "accelerations")
        fac = MAX_FACTOR if err == 0.0 else SAFE * err ** (-1.0 / 3.0)
        if err > 1.0:
            self.h = h * max(MIN_FACTOR, fac)
            self.last_rejected = True
            self.last_failure = "error"
            return None
        fac = min(MAX_FACTOR, fac)
        if self.last_rejected:
            fac = min(fac, 1.0)
        if KEEP_H_LOW <= fac <= KEEP_H_HIGH:
            fac = 1.0  # same h next step: both cached LU factorizations stay valid
        self.h = h * fac
        self.last_rejected = False
        self.vdot, self.a = vd1, a1
        self.current_jac = False
        self.recompute_jac = nit > 2 and rate is not None and rate > JAC_RATE
        return x_two

    def _accepted(self):
        """Refresh K, D at the new point when Newton converged slowly."""
        if self.recompute_jac:
            self._new_jacobian()


def _vector_add(y, dy):
    """Retraction for plain coordinates: y + dy."""
    return y + dy
