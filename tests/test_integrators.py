"""Integrators against closed forms and tight reference solutions; orders, stiffness, state snapshots."""

import math
import pickle
import time

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mbsfmu.errors import IntegrationError
from mbsfmu.integrators import METHODS, advance_many, make_integrator, solve

ADAPTIVE = ["dopri5", "dop853", "radau5", "auto", "gen_alpha"]


# ----------------------------------------------------------------------------- test problems
class Oscillator:
    """ÿ = −ω²y (second-order form y, v): y = cos ωt for y(0)=1, v(0)=0."""

    def __init__(self, omega=1.0, damping=0.0):
        self.n, self.npos, self.nvel = 2, 1, 1
        self.w2, self.d = omega * omega, damping
        self.calls = 0

    def accel(self, t, y, v):
        return -self.w2 * y - self.d * v

    def f(self, t, x):
        self.calls += 1
        return np.array([x[1], -self.w2 * x[0] - self.d * x[1]])

    def retract(self, y, dy):
        return y + dy


class Kepler:
    """Planar two-body problem (μ = 1); closed form: energy, angular momentum, period 2π for a = 1."""

    n, npos, nvel = 4, 2, 2

    def f(self, t, x):
        r3 = (x[0] * x[0] + x[1] * x[1]) ** 1.5
        return np.array([x[2], x[3], -x[0] / r3, -x[1] / r3])

    def accel(self, t, y, v):
        return -y / (y[0] * y[0] + y[1] * y[1]) ** 1.5

    def retract(self, y, dy):
        return y + dy

    @staticmethod
    def initial(e):
        # pericentre of an orbit with semi-major axis 1 and eccentricity e
        return np.array([1.0 - e, 0.0, 0.0, math.sqrt((1 + e) / (1 - e))])


class VanDerPol:
    """ẍ = μ(1−x²)ẋ − x as a first-order system."""

    n, npos, nvel = 2, 1, 1

    def __init__(self, mu):
        self.mu = mu

    def f(self, t, x):
        return np.array([x[1], self.mu * (1.0 - x[0] * x[0]) * x[1] - x[0]])

    def accel(self, t, y, v):
        return self.mu * (1.0 - y * y) * v - y

    def retract(self, y, dy):
        return y + dy


class StiffLinear:
    """x' = L(x − cos t) − sin t with L = diag(−1e6, −1): x = cos t + (x0 − 1)·e^{Lt}."""

    n, npos, nvel = 2, 2, 0
    L = np.array([-1e6, -1.0])

    def f(self, t, x):
        return self.L * (x - math.cos(t)) - math.sin(t)

    def exact(self, t, x0):
        return math.cos(t) + (np.asarray(x0) - 1.0) * np.exp(self.L * t)


class Robertson:
    """Robertson's chemical kinetics, the classic stiff test (Hairer & Wanner II, IV.1)."""

    n = 3

    def f(self, t, y):
        a, b, c = 0.04 * y[0], 1e4 * y[1] * y[2], 3e7 * y[1] * y[1]
        return np.array([-a + b, a - b - c, c])


def quat_mul(p, q):
    """Hamilton product p ⊗ q (scalar first)."""
    return np.array([p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
                     p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
                     p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
                     p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]])


def quat_rot(q):
    """Rotation matrix of a unit quaternion."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


class FreeRigidBody:
    """Torque-free rigid body: positions = unit quaternion (4), velocities = body angular velocity (3)."""

    n, npos, nvel = 7, 4, 3
    I = np.array([1.0, 2.0, 3.5])

    def accel(self, t, q, w):
        # Euler's equations I ω̇ = −ω × Iω
        (a, b, c), (A, B, C) = w, self.I * w  # hand-written cross product: np.cross costs ~15 µs
        return np.array([b * C - c * B, c * A - a * C, a * B - b * A]) / -self.I

    def f(self, t, x):
        q, w = x[:4], x[4:]
        qd = 0.5 * quat_mul(q, np.array([0.0, w[0], w[1], w[2]]))
        return np.concatenate((qd, self.accel(t, q, w)))

    def retract(self, q, dth):
        # exponential map: q ⊗ exp(dθ/2), body-frame increment
        a = math.sqrt(dth.dot(dth))
        if a < 1e-12:
            e = np.array([1.0, 0.5 * dth[0], 0.5 * dth[1], 0.5 * dth[2]])
        else:
            s = math.sin(0.5 * a) / a
            e = np.array([math.cos(0.5 * a), s * dth[0], s * dth[1], s * dth[2]])
        return quat_mul(q, e)

    def normalize(self, x):  # x: one state or states as rows (advance_many)
        x = x.copy()
        x[..., :4] /= np.linalg.norm(x[..., :4], axis=-1, keepdims=True)
        return x

    def energy(self, x):
        w = x[4:]
        return 0.5 * w.dot(self.I * w)

    def momentum(self, x):
        return quat_rot(x[:4]) @ (self.I * x[4:])

    x0 = np.array([1.0, 0.0, 0.0, 0.0, 0.3, 2.0, 0.4])  # near the unstable middle axis: non-trivial


def final_error(method, problem, x0, t_end, exact, **opts):
    """Max-norm error of one advance to t_end."""
    integ = make_integrator(method, problem, **opts)
    integ.reset(0.0, x0)
    return np.max(np.abs(integ.advance(t_end) - exact)), integ


# ----------------------------------------------------------------------------- accuracy
@pytest.mark.parametrize("method", METHODS)
def test_harmonic_oscillator_closed_form(method):
    ex = np.array([math.cos(10.0), -math.sin(10.0)])
    err, integ = final_error(method, Oscillator(), [1.0, 0.0], 10.0, ex, rtol=1e-8, atol=1e-10, h=1e-3)
    assert err < 1e-5, (method, err)
    assert integ.t == 10.0


@pytest.mark.parametrize("method", ["dopri5", "dop853", "radau5", "auto", "gen_alpha"])
def test_kepler_period_closed_form(method):
    # after one period T = 2π the orbit returns exactly to the initial state
    x0 = Kepler.initial(0.5)
    # gen_alpha is only second order: local error control at 1e-8 gives a global error near 1e-4
    tol = 1e-8 if method == "gen_alpha" else 1e-9
    err, integ = final_error(method, Kepler(), x0, 2 * math.pi, x0, rtol=tol, atol=tol)
    assert err < (1e-3 if method == "gen_alpha" else 1e-5), (method, err)


@pytest.mark.parametrize("method", ["dopri5", "dop853", "radau5", "auto", "rk4"])
def test_van_der_pol_vs_scipy(method):
    p = VanDerPol(2.0)
    ref = solve_ivp(p.f, (0, 6), [2.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    X, stats = solve(p, method, np.linspace(0, 6, 7), [2.0, 0.0], rtol=1e-8, atol=1e-10, h=1e-3)
    assert np.max(np.abs(X[-1] - ref)) < 1e-5, (method, X[-1] - ref)


# ----------------------------------------------------------------------------- orders
def measured_order(method, h1, h2, problem, x0, t_end, exact, **opts):
    """log2-type order estimate from fixed-step errors at two step sizes."""
    e1, _ = final_error(method, problem, x0, t_end, exact, h=h1, **opts)
    e2, _ = final_error(method, problem, x0, t_end, exact, h=h2, **opts)
    return math.log(e1 / e2) / math.log(h1 / h2)


def test_rk4_order_4():
    ex = np.array([math.cos(2.0), -math.sin(2.0)])
    p = measured_order("rk4", 0.1, 0.05, Oscillator(), [1.0, 0.0], 2.0, ex)
    assert 3.8 < p < 4.2, p


@pytest.mark.parametrize("rho", [0.0, 0.5, 0.8, 1.0])
def test_gen_alpha_order_2(rho):
    ex = np.array([math.cos(2.0), -math.sin(2.0)])
    p = measured_order("gen_alpha", 0.02, 0.01, Oscillator(), [1.0, 0.0], 2.0, ex, rho_inf=rho, rtol=1e-12,
                       atol=1e-14)
    assert 1.85 < p < 2.15, (rho, p)


def test_gen_alpha_order_2_nonlinear():
    # Van der Pol with a Jacobian that changes along the solution (Newton really iterates)
    p = VanDerPol(1.0)
    ex = solve_ivp(p.f, (0, 2), [2.0, 0.0], method="DOP853", rtol=1e-13, atol=1e-13).y[:, -1]
    order = measured_order("gen_alpha", 0.02, 0.01, p, [2.0, 0.0], 2.0, ex, rtol=1e-12, atol=1e-14)
    assert 1.85 < order < 2.2, order


@pytest.mark.parametrize("method,expected", [("dopri5", 5), ("dop853", 8), ("radau5", 5)])
def test_adaptive_order_from_tolerance(method, expected):
    # error ∝ tol^(p/(p+1)) for an order-p method whose local error (order p+1) is controlled;
    # measure the global error vs the number of steps instead: err ∝ N^(-p)
    x0 = Kepler.initial(0.2)
    res = []
    for tol in (1e-6, 1e-9):
        err, integ = final_error(method, Kepler(), x0, 2 * math.pi, x0, rtol=tol, atol=tol)
        res.append((err, integ.stats["steps"]))
    (e1, n1), (e2, n2) = res
    order = math.log(e1 / e2) / math.log(n2 / n1)
    assert expected - 1.2 < order < expected + 1.5, (method, order, res)


# ----------------------------------------------------------------------------- stiffness
def run_stiff(method, t_end=0.01):
    p = StiffLinear()
    x0 = np.array([0.0, 0.0])
    integ = make_integrator(method, p, rtol=1e-6, atol=1e-8)
    integ.reset(0.0, x0)
    t0 = time.perf_counter()
    x = integ.advance(t_end)
    return integ, x, p.exact(t_end, x0), time.perf_counter() - t0


def test_stiff_linear_radau_few_steps_dopri_many():
    r, xr, ex, _ = run_stiff("radau5")
    d, xd, _, _ = run_stiff("dopri5")
    a, xa, _, _ = run_stiff("auto")
    for x in (xr, xd, xa):
        assert np.max(np.abs(x - ex)) < 1e-5
    assert r.stats["steps"] < 60
    assert a.stats["steps"] < 120
    assert d.stats["steps"] > 1000  # stability-limited: h·1e6 ≲ 3.3
    assert a.stats["switched"] and a.switched_at is not None and 0 < a.switched_at < 0.01


def test_robertson_radau_and_auto():
    p = Robertson()
    ref = solve_ivp(p.f, (0, 100), [1, 0, 0], method="Radau", rtol=1e-11, atol=1e-15).y[:, -1]
    for method in ("radau5", "auto"):
        X, st = solve(p, method, [0, 1, 10, 100], [1.0, 0.0, 0.0], rtol=1e-6, atol=1e-10)
        assert np.all(np.abs(X[-1] - ref) <= 1e-5 * np.abs(ref) + 1e-11), (method, X[-1] - ref)
        assert st["steps"] < 200, (method, st)
    assert st["switched"]


def test_auto_stays_nonstiff_on_nonstiff_problem():
    X, st = solve(Kepler(), "auto", [0, 2 * math.pi], Kepler.initial(0.3), rtol=1e-8, atol=1e-8)
    assert not st["switched"] and st["lu_decompositions"] == 0


# ----------------------------------------------------------------------------- communication points
@pytest.mark.parametrize("method", ADAPTIVE)
def test_communication_points_exact_and_step_carried(method):
    p = Oscillator()
    opts = dict(rtol=1e-6, atol=1e-8)
    one = make_integrator(method, p, **opts)
    one.reset(0.0, [1.0, 0.0])
    one.advance(10.0)
    many = make_integrator(method, p, **opts)
    many.reset(0.0, [1.0, 0.0])
    ts = np.linspace(0.0, 10.0, 1001)
    for t in ts[1:]:
        many.advance(t)
        assert many.t == t  # hit exactly, never overstepped
    n1, n2 = one.stats["steps"], many.stats["steps"]
    if getattr(many, "dense", False):
        # dense output: the communication grid does not influence the steps at all
        assert n2 <= n1 + 2, (n1, n2)
    else:
        # every interval needs at least one step, but nothing beyond that (no restart per call)
        assert n2 <= 1000 + 2 * n1 + 10, (n1, n2)
    # no HINIT per call: RHS evaluations stay near the per-step cost (dop853: +3 extra dense stages)
    per_step = {"dopri5": 6, "auto": 6, "dop853": 15}.get(method)
    if per_step:
        assert many.stats["rhs_evaluations"] <= per_step * (n2 + many.stats["rejected"]) + 5
    assert abs(many.x[0] - math.cos(10.0)) < 1e-4


@pytest.mark.parametrize("method", ADAPTIVE)
def test_tiny_interval_does_not_shrink_carried_step(method):
    integ = make_integrator(method, Oscillator(), rtol=1e-6, atol=1e-8)
    integ.reset(0.0, [1.0, 0.0])
    integ.advance(1.0)
    h_before = integ.h
    integ.advance(1.0 + 1e-9)
    assert integ.t == 1.0 + 1e-9
    assert integ.h >= 0.5 * h_before


def test_max_step_respected():
    integ = make_integrator("dopri5", Oscillator(), rtol=1e-3, atol=1e-3, max_step=0.01)
    integ.reset(0.0, [1.0, 0.0])
    integ.advance(1.0)
    assert integ.stats["steps"] >= 100


def test_rk4_fixed_subdivision():
    integ = make_integrator("rk4", Oscillator(), h=0.1)
    integ.reset(0.0, [1.0, 0.0])
    integ.advance(0.25)  # 3 equal steps of 1/12
    assert integ.stats["steps"] == 3 and integ.t == 0.25
    integ.advance(1.25)
    assert integ.stats["steps"] == 13 and integ.t == 1.25


# ----------------------------------------------------------------------------- state snapshots
@pytest.mark.parametrize("method", METHODS)
def test_get_set_state_bit_identical(method):
    p = VanDerPol(5.0) if method != "auto" else Robertson()
    x0 = [2.0, 0.0] if method != "auto" else [1.0, 0.0, 0.0]
    integ = make_integrator(method, p, rtol=1e-6, atol=1e-9, h=0.01)
    integ.reset(0.0, x0)
    integ.advance(0.5)
    snap = pickle.loads(pickle.dumps(integ.get_state()))
    first = [integ.advance(t) for t in (0.7, 1.3, 3.0)]
    stats1 = dict(integ.stats)
    integ.set_state(snap)
    assert integ.t == 0.5
    second = [integ.advance(t) for t in (0.7, 1.3, 3.0)]
    for a, b in zip(first, second):
        assert np.array_equal(a, b)
    assert integ.stats == stats1
    # and into a fresh integrator
    other = make_integrator(method, p, rtol=1e-6, atol=1e-9, h=0.01)
    other.set_state(snap)
    third = [other.advance(t) for t in (0.7, 1.3, 3.0)]
    for a, b in zip(first, third):
        assert np.array_equal(a, b)


# ----------------------------------------------------------------------------- failures
class NaNAfter:
    n, npos, nvel = 2, 1, 1

    def __init__(self, t_bad):
        self.t_bad = t_bad

    def f(self, t, x):
        return np.array([x[1], -x[0] if t < self.t_bad else math.nan])

    def accel(self, t, y, v):
        return -y if t < self.t_bad else np.array([math.nan])

    def retract(self, y, dy):
        return y + dy


@pytest.mark.parametrize("method", METHODS)
def test_nan_in_rhs_raises_at_last_good_point(method):
    integ = make_integrator(method, NaNAfter(0.5), h=0.01)
    integ.reset(0.0, [1.0, 0.0])
    integ.advance(0.3)
    with pytest.raises(IntegrationError) as ei:
        integ.advance(1.0)
    assert "non-finite" in str(ei.value) or "NaN" in str(ei.value)
    assert 0.3 <= integ.t <= 0.5 and np.isfinite(integ.x).all()


def test_nan_at_start_raises():
    integ = make_integrator("dopri5", NaNAfter(-1.0))
    integ.reset(0.0, [1.0, 0.0])
    with pytest.raises(IntegrationError, match="non-finite"):
        integ.advance(1.0)
    assert integ.t == 0.0


def test_finite_time_blowup_reports_underflow_or_nonfinite():
    class Blowup:
        n = 1

        def f(self, t, x):
            return x * x  # x = 1/(1 − t): singular at t = 1

    integ = make_integrator("dopri5", Blowup())
    integ.reset(0.0, [1.0])
    with pytest.raises(IntegrationError, match="underflow|non-finite"):
        integ.advance(2.0)
    assert integ.t < 1.001 and np.isfinite(integ.x).all()  # the numerical pole sits within the tolerance


def test_max_steps_exceeded():
    integ = make_integrator("dopri5", StiffLinear(), max_steps=100)
    integ.reset(0.0, [0.0, 0.0])
    with pytest.raises(IntegrationError, match="maximum number of steps"):
        integ.advance(1.0)
    assert 0.0 < integ.t < 1.0


def test_unknown_method():
    with pytest.raises(ValueError, match="valid"):
        make_integrator("euler", Oscillator())


# ----------------------------------------------------------------------------- quaternions
@pytest.mark.parametrize("method,opts", [("gen_alpha", {"h": 2e-3}), ("gen_alpha", {"rtol": 1e-7}),
                                         ("dopri5", {}), ("radau5", {})])
def test_free_rigid_body_quaternion(method, opts):
    p = FreeRigidBody()
    integ = make_integrator(method, p, **{"rtol": 1e-8, "atol": 1e-10, **opts})
    integ.reset(0.0, p.x0)
    E0, L0 = p.energy(p.x0), p.momentum(p.x0)
    for t in np.linspace(0.5, 10.0, 20):
        x = integ.advance(t)
        assert abs(np.linalg.norm(x[:4]) - 1.0) < 1e-12
    assert abs(p.energy(x) - E0) < 1e-5 * E0, (method, p.energy(x) - E0)
    assert np.max(np.abs(p.momentum(x) - L0)) < 1e-3 * np.linalg.norm(L0)


def test_auto_snapshot_before_switch_is_bit_identical():
    integ = make_integrator("auto", StiffLinear(), rtol=1e-6, atol=1e-8)
    integ.reset(0.0, [0.0, 0.0])
    integ.advance(1e-5)
    assert not integ.stats["switched"]
    snap = pickle.loads(pickle.dumps(integ.get_state()))
    first = [integ.advance(t) for t in (1e-4, 1e-2, 1.0)]
    assert integ.stats["switched"]
    integ.set_state(snap)
    assert not integ.stats["switched"]
    second = [integ.advance(t) for t in (1e-4, 1e-2, 1.0)]
    assert all(np.array_equal(a, b) for a, b in zip(first, second))
    assert integ.switched_at == pytest.approx(integ.switched_at)


class PiecewiseInput:
    """ẍ = u with an input u held constant per communication interval (as in the FMU)."""

    n, npos, nvel = 2, 1, 1

    def __init__(self):
        self.u = 1.0

    def f(self, t, x):
        return np.array([x[1], self.u])

    def accel(self, t, y, v):
        return np.array([self.u])


@pytest.mark.parametrize("method", METHODS)
def test_inputs_changed_drops_cached_derivative(method):
    # u = +1 on [0, 1], −1 on [1, 2]: x(2) = 1, v(2) = 0; piecewise quadratic, so every method is exact
    # up to rounding once cached derivatives (FSAL stage, f at step start, accelerations) are refreshed
    p = PiecewiseInput()
    integ = make_integrator(method, p, rtol=1e-8, atol=1e-10, h=0.1)
    integ.reset(0.0, [0.0, 0.0])
    integ.advance(1.0)
    p.u = -1.0
    integ.inputs_changed()
    x = integ.advance(2.0)
    tol = 1e-3 if method == "gen_alpha" else 1e-9
    assert np.max(np.abs(x - [1.0, 0.0])) < tol, (method, x)


def test_make_integrator_options():
    g = make_integrator("gen_alpha", Oscillator(), rho_inf=0.3, h=0.01)
    assert g.rho_inf == 0.3 and g.method == "gen_alpha"
    with pytest.raises(ValueError):
        make_integrator("gen_alpha", Oscillator(), rho_inf=1.5)
    with pytest.raises(ValueError):
        make_integrator("dopri5", Oscillator(), rtol=0.0)
    assert set(METHODS) >= {"rk4", "dopri5", "dop853", "radau5", "gen_alpha", "auto"}


def test_solve_helper_returns_all_points():
    ts = np.linspace(0, 3, 31)
    X, stats = solve(Oscillator(), "dop853", ts, [1.0, 0.0], rtol=1e-10, atol=1e-12, dense=True)
    assert X.shape == (31, 2)
    assert np.max(np.abs(X[:, 0] - np.cos(ts))) < 1e-8
    assert stats["steps"] < 30  # dense output: fewer steps than output points
    X2, stats2 = solve(Oscillator(), "dop853", ts, [1.0, 0.0], rtol=1e-10, atol=1e-12, dense=False)
    assert np.max(np.abs(X2[:, 0] - np.cos(ts))) < 1e-8
    assert stats2["steps"] >= 30


@pytest.mark.parametrize("method", METHODS)
def test_rounding_level_interval(method):
    integ = make_integrator(method, Oscillator(), h=0.01)
    integ.reset(0.0, [1.0, 0.0])
    integ.advance(1.0)
    t_end = np.nextafter(1.0, 2.0)
    x = integ.advance(t_end)
    assert integ.t == t_end and np.isfinite(x).all()
    integ.advance(2.0)
    assert abs(integ.x[0] - math.cos(2.0)) < 1e-4


class RobertsonJac(Robertson):
    def jac(self, t, y):
        return np.array([[-0.04, 1e4 * y[2], 1e4 * y[1]],
                         [0.04, -1e4 * y[2] - 6e7 * y[1], -1e4 * y[1]],
                         [0.0, 6e7 * y[1], 0.0]])


def test_radau5_uses_analytic_jacobian():
    Xa, sa = solve(RobertsonJac(), "radau5", [0, 10], [1.0, 0.0, 0.0], rtol=1e-6, atol=1e-10)
    Xf, sf = solve(Robertson(), "radau5", [0, 10], [1.0, 0.0, 0.0], rtol=1e-6, atol=1e-10)
    assert np.allclose(Xa[-1], Xf[-1], rtol=1e-4, atol=1e-9)
    assert sa["jac_evaluations"] > 0
    # finite differences cost n RHS evaluations per Jacobian, the analytic one none
    assert sf["rhs_evaluations"] - sa["rhs_evaluations"] >= 3 * sf["jac_evaluations"] - 50


@pytest.mark.parametrize("method", ["dopri5", "dop853", "radau5", "gen_alpha", "rk4"])
def test_max_step_bounds_every_step(method):
    integ = make_integrator(method, Oscillator(), rtol=1e-3, atol=1e-3, max_step=0.01)
    integ.reset(0.0, [1.0, 0.0])
    integ.advance(1.0)
    assert integ.stats["steps"] >= 100 and integ.t == 1.0


def test_gen_alpha_stiff_spring_large_steps():
    # ω = 1e4 stiff spring next to a slow mode: with ρ∞ = 0.5 the fast mode is damped out at h·ω ≫ 1
    class TwoModes:
        n, npos, nvel = 4, 2, 2
        w2 = np.array([1e8, 1.0])

        def accel(self, t, y, v):
            return -self.w2 * y

        def f(self, t, x):
            return np.concatenate((x[2:], -self.w2 * x[:2]))

    integ = make_integrator("gen_alpha", TwoModes(), h=0.01, rho_inf=0.5)
    integ.reset(0.0, [1e-6, 1.0, 0.0, 0.0])
    x = integ.advance(5.0)
    assert integ.stats["steps"] == 500
    assert abs(x[0]) < 1e-8  # fast mode damped (ρ∞^500)
    assert abs(x[1] - math.cos(5.0)) < 5e-3  # slow mode second-order accurate


def test_rk4_unstable_step_fails_cleanly():
    integ = make_integrator("rk4", StiffLinear(), h=1e-3)
    integ.reset(0.0, [0.0, 0.0])
    with pytest.raises(IntegrationError, match="unstable"):
        integ.advance(0.01)
    assert integ.t == 0.0
    # a stable step on the same problem passes
    integ = make_integrator("rk4", StiffLinear(), h=2e-6)
    integ.reset(0.0, [0.0, 0.0])
    x = integ.advance(1e-4)
    assert np.max(np.abs(x - StiffLinear().exact(1e-4, [0.0, 0.0]))) < 1e-6


@pytest.mark.parametrize("h", [0.005, 0.02, 0.05])
def test_rk4_no_false_instability_alarm(h):
    class ForcedFromRest:
        n = 2

        def f(self, t, x):
            return np.array([x[1], math.sin(50.0 * t) + 30.0 * t * t])

    for p, x0 in ((ForcedFromRest(), [0.0, 0.0]), (Kepler(), Kepler.initial(0.6)), (VanDerPol(3.0), [2.0, 0.0])):
        integ = make_integrator("rk4", p, h=h)
        integ.reset(0.0, x0)
        integ.advance(3.0)


# ----------------------------------------------------------------------------- dense output
DENSE = ["dopri5", "dop853", "radau5", "auto"]


class Recording(VanDerPol):
    """Van der Pol that records every (t, x) at which f is evaluated."""

    def __init__(self, mu):
        super().__init__(mu)
        self.log = []

    def f(self, t, x):
        self.log.append((t, np.array(x, copy=True)))
        return super().f(t, x)


@pytest.mark.parametrize("method", DENSE)
def test_dense_output_matches_tight_reference(method):
    p = VanDerPol(2.0)
    ts = np.linspace(0.0, 6.0, 601)
    ref = solve_ivp(p.f, (0.0, 6.0), [2.0, 0.0], method="DOP853", rtol=1e-13, atol=1e-13, t_eval=ts).y.T
    integ = make_integrator(method, p, dense=True, rtol=1e-7, atol=1e-9)
    integ.reset(0.0, [2.0, 0.0])
    X = [integ.x]
    for t in ts[1:]:
        X.append(integ.advance(t))
        assert integ.t == t
    assert integ.stats["steps"] < 300  # far fewer steps than the 600 communication points
    # error of the order of the tolerance at every (mostly interpolated) communication point
    assert np.max(np.abs(np.array(X) - ref)) < 1e-5


@pytest.mark.parametrize("method", DENSE)
def test_dense_step_count_independent_of_grid(method):
    p = Oscillator(3.0)
    one = make_integrator(method, p, dense=True, rtol=1e-8, atol=1e-10)
    one.reset(0.0, [1.0, 0.0])
    x1 = one.advance(1.0)
    many = make_integrator(method, p, dense=True, rtol=1e-8, atol=1e-10)
    many.reset(0.0, [1.0, 0.0])
    for t in np.linspace(0.0, 1.0, 1001)[1:]:
        x = many.advance(t)
    assert many.t == 1.0
    assert abs(many.stats["steps"] - one.stats["steps"]) <= 1, (one.stats, many.stats)
    # extra cost: only the dense-output stages (dop853: 3 per step that crosses communication points)
    extra = 3 * many.stats["steps"] if method == "dop853" else 0
    assert many.stats["rhs_evaluations"] <= one.stats["rhs_evaluations"] + extra + 6, (one.stats, many.stats)
    assert np.max(np.abs(x - x1)) < 1e-7
    off = make_integrator(method, p, rtol=1e-8, atol=1e-10, dense=False)
    off.reset(0.0, [1.0, 0.0])
    for t in np.linspace(0.0, 1.0, 1001)[1:]:
        off.advance(t)
    assert off.stats["steps"] >= 1000


@pytest.mark.parametrize("method", DENSE)
def test_dense_inputs_changed_restarts_at_visible_state(method):
    p = Recording(1.0)
    integ = make_integrator(method, p, dense=True, rtol=1e-6, atol=1e-8)
    integ.reset(0.0, [2.0, 0.0])
    ts = np.linspace(0.0, 1.0, 101)[1:]
    for t in ts[:50]:
        integ.advance(t)
    inner = integ.nonstiff if method == "auto" else integ
    assert inner._ahead is not None and inner._ahead[0] > integ.t  # internal state runs ahead
    t_vis, x_vis = integ.t, integ.x.copy()
    integ.inputs_changed()
    assert integ.t == t_vis and np.array_equal(integ.x, x_vis) and inner._ahead is None
    p.log.clear()
    integ.advance(ts[50])
    # the first evaluation is f at exactly the visible (interpolated) point
    assert p.log[0][0] == t_vis and np.array_equal(p.log[0][1], x_vis)


@pytest.mark.parametrize("method", DENSE)
def test_dense_snapshot_replay_bit_identical(method):
    p = VanDerPol(3.0)
    integ = make_integrator(method, p, dense=True, rtol=1e-6, atol=1e-9)
    integ.reset(0.0, [2.0, 0.0])
    for t in np.arange(1, 38) * 0.01:
        integ.advance(t)
    inner = integ.nonstiff if method == "auto" else integ
    assert inner._ahead is not None
    snap = pickle.loads(pickle.dumps(integ.get_state()))
    grid = np.arange(38, 400) * 0.01
    first = [integ.advance(t) for t in grid]
    stats1 = dict(integ.stats)
    other = make_integrator(method, p, dense=True, rtol=1e-6, atol=1e-9)
    other.set_state(snap)
    assert other.t == 0.37
    second = [other.advance(t) for t in grid]
    assert all(np.array_equal(a, b) for a, b in zip(first, second))
    assert other.stats == stats1


@pytest.mark.parametrize("method", ["dopri5", "dop853", "radau5"])
def test_dense_interpolated_quaternion_normalized(method):
    p = FreeRigidBody()
    integ = make_integrator(method, p, dense=True, rtol=1e-6, atol=1e-8)
    integ.reset(0.0, p.x0)
    for t in np.linspace(0.0, 3.0, 301)[1:]:
        x = integ.advance(t)
        assert abs(np.linalg.norm(x[:4]) - 1.0) < 1e-14
    assert integ.stats["steps"] < 200


def test_dense_option_validation():
    with pytest.raises(ValueError):
        make_integrator("rk4", Oscillator(), dense=True)
    with pytest.raises(ValueError):
        make_integrator("gen_alpha", Oscillator(), dense=True)
    assert make_integrator("radau5", Oscillator()).dense is True
    assert make_integrator("radau5", Oscillator(), dense=False).dense is False
    assert make_integrator("dopri5", Oscillator(), dense=True).dense is True
    assert make_integrator("auto", Oscillator(), dense=True).dense is True


@pytest.mark.parametrize("method", DENSE + ["rk4", "gen_alpha"])
def test_advance_many_takes_the_steps_of_one_advance_per_point(method):
    p = VanDerPol(2.0)
    ts = np.linspace(0.0, 4.0, 801)
    one, many = (make_integrator(method, p, rtol=1e-7, atol=1e-9) for _ in range(2))
    one.reset(0.0, [2.0, 0.0])
    many.reset(0.0, [2.0, 0.0])
    X1 = np.array([one.advance(t) for t in ts[1:]])
    X2 = advance_many(many, ts[1:])
    # same steps; interpolated points differ only by the rounding of a matrix product vs. a vector product
    assert many.stats == one.stats
    assert np.max(np.abs(X1 - X2)) < 1e-13
    assert many.t == ts[-1] and np.array_equal(many.x, X2[-1])
    # continuing after a batch is the same as continuing after single calls
    assert np.max(np.abs(one.advance(4.5) - many.advance(4.5))) < 1e-13


@pytest.mark.parametrize("method", ["dopri5", "dop853", "radau5"])
def test_advance_many_normalizes_interpolated_quaternions(method):
    p = FreeRigidBody()
    integ = make_integrator(method, p, rtol=1e-6, atol=1e-8)
    integ.reset(0.0, p.x0)
    X = advance_many(integ, np.linspace(0.0, 3.0, 301)[1:])
    assert integ.stats["steps"] < 200  # most of the 300 points are interpolated
    assert np.max(np.abs(np.linalg.norm(X[:, :4], axis=1) - 1.0)) < 1e-14
    # conserved quantities of the torque-free body at every point
    assert np.max(np.abs([p.energy(x) - p.energy(p.x0) for x in X])) < 1e-5
    assert np.max(np.abs([p.momentum(x) - p.momentum(p.x0) for x in X])) < 1e-5
