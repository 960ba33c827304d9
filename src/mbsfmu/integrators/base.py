"""Common driver: reset/advance to exact communication points, step-size carry-over, stats, state snapshots.

Dense output (dopri5, dop853, radau5 and so auto; on by default, ``dense=False`` stops at every point):
while the inputs are unchanged, advance(t_end) takes its natural step past t_end and returns the
continuous-extension value at t_end.  The integrator then keeps an internal "ahead" point (t_int, x_int)
together with the interpolation coefficients of that last step; the next advance interpolates again when
its target lies inside that step, otherwise it continues stepping from (t_int, x_int).  ``t``/``x`` always
mean the last returned communication point and its (normalized) state.  inputs_changed() drops the ahead
point and restarts from the visible (interpolated) state, so the new inputs are held exactly over the next
interval.  Consequently the visible states differ from a stop-at-every-point run by the interpolation error
(of the order of the tolerance), not bit for bit.  max_step still bounds every internal step.  rk4 and
gen_alpha always land exactly on t_end.
"""

import bisect
import math

import numpy as np

from mbsfmu.errors import IntegrationError

from .norms import all_finite

_EPS = np.finfo(float).eps
# consecutive trial steps with non-finite values tolerated (each shrinks h by 4) before giving up
_MAX_NONFINITE_TRIALS = 3


def new_stats():
    """Fresh counters shared by all methods."""
    return {"steps": 0, "rejected": 0, "rhs_evaluations": 0, "jac_evaluations": 0, "lu_decompositions": 0}


def deep_copy(v):
    """Copy numpy arrays inside dicts/lists/tuples so snapshots never alias live buffers."""
    if isinstance(v, np.ndarray):
        return v.copy()
    if isinstance(v, dict):
        return {k: deep_copy(w) for k, w in v.items()}
    if isinstance(v, (list, tuple)):
        return type(v)(deep_copy(w) for w in v)
    return v


def advance_many(integ, ts):
    """x at each of the increasing times ts (> integ.t): the same steps as one advance() per time, but all times
    inside an accepted dense-output step come from its continuous extension in one product (solve_ivp's t_eval)."""
    ts = [float(t) for t in ts]
    X = np.empty((len(ts), integ.problem.n))
    i = 0
    while i < len(ts):
        X[i] = integ.advance(ts[i])  # steps past ts[i] (dense) or lands on it
        i += 1
        a = getattr(integ, "_active", integ)  # auto: the sub-integrator in charge
        if a._ahead is None:
            continue
        j = bisect.bisect_left(ts, a._ahead[0], lo=i)  # times strictly inside the step (its end lands exactly)
        if j > i:
            t_old, h, Q = a._seg
            Xs = a._dense_weights((np.array(ts[i:j]) - t_old) / h, len(Q)) @ Q
            if a._normalize is not None:
                Xs = a._normalize(Xs)
            X[i:j] = Xs
            a.t, a.x = ts[j - 1], Xs[-1].copy()
            i = j
    return X


class Integrator:
    """Base class: subclasses implement _start (derivative/initial h) and _attempt (one trial step)."""

    method = None
    # attributes (besides t, x, h, stats) that influence future results; subclasses extend
    _state_keys = ()

    # True for methods with a continuous extension (subclasses implement _dense_coeffs, _dense_eval, _dense_weights)
    _has_dense = False

    def __init__(self, problem, rtol=1e-6, atol=1e-8, max_step=math.inf, h=None, max_steps=1_000_000,
                 dense=None):
        if not rtol > 0 or not np.all(np.asarray(atol) >= 0):
            raise ValueError(f"need rtol > 0 and atol >= 0 (got rtol={rtol}, atol={atol})")
        if not max_step > 0:
            raise ValueError(f"max_step must be > 0 (got {max_step})")
        if h is not None and not h > 0:
            raise ValueError(f"fixed step h must be > 0 (got {h})")
        self.problem = problem
        self.n = int(problem.n)
        # Hairer caps rtol from below so that the error test never asks for less than ~10 ulp
        self.rtol = max(float(rtol), 10 * _EPS)
        self.atol = atol if np.ndim(atol) == 0 else np.asarray(atol, dtype=float)
        if np.ndim(self.atol) == 0:
            self.atol = float(self.atol)
        self.max_step = float(max_step)
        self.h_fixed = None if h is None else float(h)
        self.max_steps = int(max_steps)
        self._normalize = getattr(problem, "normalize", None)
        self.t = None
        self.x = None
        self.h = None
        self.stats = new_stats()
        self._nonfinite = 0
        self.last_failure = None  # "error" or "newton": reason of the latest rejection
        if dense and not self._has_dense:
            raise ValueError(f"method {self.method!r} has no dense output")
        self.dense = self._has_dense if dense is None else bool(dense)
        self._ahead = None  # (t_int, x_int): internal accepted point past the visible (t, x), or None
        self._seg = None    # (t_old, h, Q): continuous extension of the step ending at t_int

    # ---------------------------------------------------------------- public API
    def reset(self, t0, x0):
        """Start at (t0, x0) and forget every history item (cached derivatives, step size, Jacobians)."""
        x0 = np.array(x0, dtype=float).reshape(-1)
        if x0.size != self.n:
            raise ValueError(f"initial state has {x0.size} entries, problem.n = {self.n}")
        if not np.isfinite(x0).all() or not math.isfinite(t0):
            raise IntegrationError("initial state is not finite", t0)
        self.t = float(t0)
        self.x = x0
        self.h = None
        self.stats = new_stats()
        self._nonfinite = 0
        self.last_failure = None
        self._ahead = None
        self._seg = None
        self._reset_history()

    def inputs_changed(self):
        """Tell the integrator that f changed discontinuously at the current t (new inputs/parameters)."""
        # cached derivatives (FSAL stage, f at the step start) are stale; Jacobians are kept because
        # Newton's convergence monitor refreshes them when they no longer fit.  With dense output the
        # internal point past t is dropped: restart from the visible (interpolated) state so that the
        # new inputs act exactly from t on.
        self._drop_ahead()
        self._invalidate_derivative()

    def _drop_ahead(self):
        """Forget the internal ahead point (its FSAL stage belongs to it, so drop that too)."""
        if self._ahead is not None:
            self._ahead = None
            self._invalidate_derivative()
        self._seg = None

    def advance(self, t_end):
        """Integrate from self.t to exactly t_end; on failure raise IntegrationError at the last good point."""
        if self.x is None:
            raise IntegrationError("reset(t0, x0) must be called before advance()")
        t_end = float(t_end)
        if not t_end >= self.t:
            raise IntegrationError(f"cannot integrate backwards (t_end={t_end!r} < t)", self.t)
        if t_end > self.t:
            ahead = self._ahead
            if ahead is not None and t_end <= ahead[0]:
                self._land(t_end)
            else:
                if ahead is not None:
                    # continue stepping from the internal point (its FSAL stage is still valid)
                    self.t, self.x = ahead
                    self._ahead = self._seg = None
                self._advance(t_end)
        return self.x.copy()

    def _land(self, t_end):
        """Make t_end (inside the last step) the visible point: interpolate, normalize."""
        t_int, x_int = self._ahead
        if t_end == t_int:
            self.t, self.x = t_int, x_int
            self._ahead = self._seg = None
            return
        t_old, h, Q = self._seg
        x = self._dense_eval(Q, (t_end - t_old) / h)
        if self._normalize is not None:
            x = self._normalize(x)
        self.t, self.x = t_end, x

    def get_state(self):
        """Picklable snapshot of everything that influences future results."""
        s = {"method": self.method, "t": self.t, "x": self.x, "h": self.h, "stats": self.stats,
             "_nonfinite": self._nonfinite, "last_failure": self.last_failure}
        for k in self._state_keys:
            s[k] = getattr(self, k)
        if self.dense:
            s["_ahead"], s["_seg"] = self._ahead, self._seg
        return deep_copy(s)

    def set_state(self, s):
        """Restore a get_state() snapshot; continuing afterwards is bit-identical to the original run."""
        if s.get("method") != self.method:
            raise ValueError(f"state of method {s.get('method')!r} given to a {self.method!r} integrator")
        s = deep_copy(s)
        self._ahead = self._seg = None
        for k, v in s.items():
            if k != "method":
                setattr(self, k, v)

    # ---------------------------------------------------------------- adaptive driver
    def _advance(self, t_end):
        """Adaptive loop: proposed h is clipped to hit t_end exactly, but the unclipped h is carried over."""
        dense = self.dense
        self._start(t_end)
        min_step = 10 * _EPS * max(abs(self.t), abs(t_end))
        attempts = 0
        while self.t < t_end:
            attempts += 1
            if attempts > self.max_steps:
                raise IntegrationError(
                    f"maximum number of steps ({self.max_steps}) exceeded in one communication interval "
                    f"(step size {self.h:.3g}); the problem may be stiff — try method radau5 or auto", self.t)
            t = self.t
            h_prop = min(self.h, self.max_step)
            remaining = t_end - t
            if remaining < min_step:
                # t_end within ~10 ulp of t: the same instant up to rounding (x moves by ≤ h·|f|, far below
                # rounding of t itself), so land on it without a step instead of reporting an underflow
                self.t = t_end
                break
            if dense:
                # natural step, possibly past t_end: the continuous extension gives x(t_end)
                t_new, clipped = t + h_prop, False
            else:
                # stretch by up to 1 % rather than leave a tiny last step (Hairer's DOPRI5 does the same)
                clipped = 1.01 * h_prop >= remaining and remaining <= self.max_step * (1.0 + 1e-9)
                t_new = t_end if clipped else t + h_prop
                if t_new >= t_end:
                    t_new, clipped = t_end, True
            h = t_new - t
            if h < min_step:
                raise IntegrationError(f"step size underflow (h={h:.3g}): {self._failure_reason()}", t)
            x_new = self._attempt(t_new, h)
            if x_new is None:
                self.stats["rejected"] += 1
                continue
            self._nonfinite = 0
            if self._normalize is not None:
                x_new = np.asarray(self._normalize(x_new), dtype=float)
            x_old = self.x
            self.t, self.x = t_new, x_new
            self.stats["steps"] += 1
            self._accepted()
            if dense and t_new > t_end:
                # the stages of this step are still in the work arrays: build its continuous extension
                self._seg = (t, h, self._dense_coeffs(t, x_old, x_new, h))
                self._ahead = (t_new, x_new)
                self.h = min(self.h, self.max_step)
                self._land(t_end)
                return
            # a step shortened to land on the communication point says little about the next step:
            # keep the earlier, larger proposal unless this step itself asked for a reduction
            if clipped and h < h_prop and self.h >= h:
                self.h = max(self.h, h_prop)
            self.h = min(self.h, self.max_step)
            if self._stop_early():
                return

    def _failure_reason(self):
        """Why the steps kept being rejected, for the underflow message."""
        if self.last_failure == "newton":
            return ("Newton iteration does not converge even with a fresh Jacobian at the minimum step "
                    "(singular or discontinuous right-hand side?)")
        return (f"the local error tolerance (rtol={self.rtol:g}, atol={np.max(self.atol):g}) cannot be met — "
                "singularity, discontinuity or too strict tolerances")

    def _trial_nonfinite(self, h, what="right-hand side"):
        """A trial step produced NaN/Inf: shrink h a few times (may be a transient overshoot), then fail."""
        self._nonfinite += 1
        if self._nonfinite > _MAX_NONFINITE_TRIALS:
            raise IntegrationError(f"{what} returned non-finite values (NaN or Inf) even for step size "
                                   f"{h:.3g}", self.t)
        self.h = 0.25 * h
        return None

    def _check_start_derivative(self, fx):
        """The derivative at an accepted point must be finite, otherwise nothing can proceed."""
        if not all_finite(fx):
            raise IntegrationError("right-hand side returned non-finite values (NaN or Inf) at the current state",
                                   self.t)

    # ---------------------------------------------------------------- subclass hooks
    def _reset_history(self):
        """Drop method-specific history (called by reset)."""

    def _invalidate_derivative(self):
        """Drop cached derivatives (called by inputs_changed)."""

    def _start(self, t_end):
        """Make sure the derivative at (t, x) and a proposed step size self.h exist."""
        raise NotImplementedError

    def _attempt(self, t_new, h):
        """One trial step to t_new = t + h: return x_new if accepted (and set self.h), else None."""
        raise NotImplementedError

    def _accepted(self):
        """Hook after (t, x) moved to the accepted (normalized) point."""

    def _dense_coeffs(self, t_old, x_old, x_new, h):
        """Coefficients of the continuous extension of the step just accepted (uses the stage array)."""
        raise NotImplementedError

    def _dense_eval(self, Q, theta):
        """Value of the continuous extension at t_old + theta·h."""
        raise NotImplementedError

    def _dense_weights(self, theta, m):
        """Rows w(θ_i) with x(t_old + θ_i·h) = w(θ_i)·Q (m rows of Q), for an array of θ (advance_many)."""
        raise NotImplementedError

    def _stop_early(self):
        """True makes _advance return before t_end (used by 'auto' to switch method)."""
        return False
