"""The engine's C integrators (src/mbsfmu/engine/integ_*.c) on test ODEs (tests/c/test_odes.c), via ctypes.

Checked against closed forms, conserved quantities and scipy's DOP853 at rtol 1e-12; plus the driver's
behaviour: exact landing, step size carried over, dense output, snapshots (bit-identical continuation,
validation, random bytes), failure messages."""

import ctypes as C
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from mbsfmu.engine import layout

ROOT = Path(__file__).resolve().parents[1]
ENGINE = ROOT / "src" / "mbsfmu" / "engine"
TEST_ODES = Path(__file__).resolve().parent / "c" / "test_odes.c"
METHODS = list(layout.METHODS)  # the engine's table, in code order (mbs_layout.h: MBS_METHODS)
RK4, DOPRI5, DOP853, RADAU5, GEN_ALPHA, AUTO = (layout.MBS_RK4, layout.MBS_DOPRI5, layout.MBS_DOP853, layout.MBS_RADAU5,
                                                layout.MBS_GEN_ALPHA, layout.MBS_AUTO)


class Options(C.Structure):
    _fields_ = [("rtol", C.c_double), ("atol", C.c_double), ("max_step", C.c_double), ("h", C.c_double),
                ("rho_inf", C.c_double), ("max_steps", C.c_long), ("dense", C.c_int)]


class Stats(C.Structure):
    _fields_ = [("steps", C.c_long), ("rejected", C.c_long), ("rhs_evaluations", C.c_long),
                ("jac_evaluations", C.c_long), ("lu_decompositions", C.c_long), ("switched", C.c_int),
                ("switched_at", C.c_double)]


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler (cc/gcc) on PATH")
    sources = sorted(ENGINE.glob("integ_*.c")) + ([ENGINE / "linalg.c"] if (ENGINE / "linalg.c").exists() else [])
    out = tmp_path_factory.mktemp("integ") / "libinteg.so"
    cmd = [cc, "-O2", "-shared", "-fPIC", "-std=c99", "-Wall", "-Wextra", f"-I{ENGINE}",
           *map(str, sources), str(TEST_ODES), "-o", str(out), "-lm"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    L = C.CDLL(str(out))
    vp, dp = C.c_void_p, C.POINTER(C.c_double)
    L.test_ode_new.restype = vp
    L.test_ode_new.argtypes = [C.c_char_p, dp, C.c_int]
    L.test_ode_set.argtypes = [vp, C.c_int, C.c_double]
    L.test_ode_free.argtypes = [vp]
    L.mbs_integ_new.restype = vp
    L.mbs_integ_new.argtypes = [C.c_int, vp, C.POINTER(Options), C.c_char_p, C.c_size_t]
    L.mbs_integ_free.argtypes = [vp]
    L.mbs_integ_reset.argtypes = [vp, C.c_double, dp]
    L.mbs_integ_inputs_changed.argtypes = [vp]
    L.mbs_integ_advance.argtypes = [vp, C.c_double]
    L.mbs_integ_advance_many.argtypes = [vp, dp, C.c_int, dp]
    for name, res in (("t", C.c_double), ("h", C.c_double), ("x", dp), ("message", C.c_char_p)):
        fn = getattr(L, f"mbs_integ_{name}")
        fn.restype, fn.argtypes = res, [vp]
    L.mbs_integ_stats.argtypes = [vp, C.POINTER(Stats)]
    L.mbs_integ_snapshot_size.restype = C.c_size_t
    L.mbs_integ_snapshot_size.argtypes = [vp]
    L.mbs_integ_snapshot_save.argtypes = [vp, C.c_char_p]
    L.mbs_integ_snapshot_load.argtypes = [vp, C.c_char_p, C.c_size_t]
    L.mbs_method_index.argtypes = [C.c_char_p]
    L.have = {m: not (m in ("radau5", "gen_alpha", "auto") and not (ENGINE / f"integ_{'radau5' if m == 'auto' else m}.c").exists())
              for m in METHODS}
    return L


def _dp(a):
    return a.ctypes.data_as(C.POINTER(C.c_double))


class Ode:
    """A test ODE owned by the C library."""

    def __init__(self, lib, name, *p):
        self.lib = lib
        self._p = np.array(p, dtype=float)
        self.ptr = lib.test_ode_new(name.encode(), _dp(self._p), len(p))
        assert self.ptr

    def set(self, i, v):
        self.lib.test_ode_set(self.ptr, i, v)

    def __del__(self):
        self.lib.test_ode_free(self.ptr)


class Integ:
    """ctypes wrapper of one MbsIntegrator."""

    def __init__(self, lib, method, ode, n, rtol=1e-6, atol=1e-8, max_step=0.0, h=0.0, max_steps=0, dense=-1,
                 rho_inf=0.8):
        if not lib.have[method]:
            pytest.skip(f"{method} not in this build yet")
        self.lib, self.ode, self.n = lib, ode, n
        opt = Options(rtol, atol, max_step, h, rho_inf, max_steps, dense)
        err = C.create_string_buffer(256)
        self.ptr = lib.mbs_integ_new(METHODS.index(method), ode.ptr, C.byref(opt), err, 256)
        if not self.ptr:
            raise ValueError(err.value.decode())

    def __del__(self):
        if getattr(self, "ptr", None):
            self.lib.mbs_integ_free(self.ptr)

    def reset(self, t0, x0):
        x0 = np.ascontiguousarray(x0, dtype=float)
        return self.lib.mbs_integ_reset(self.ptr, t0, _dp(x0))

    def advance(self, t_end):
        if self.lib.mbs_integ_advance(self.ptr, t_end):
            raise RuntimeError(self.message)
        return self.x

    def advance_many(self, ts):
        ts = np.ascontiguousarray(ts, dtype=float)
        X = np.empty((len(ts), self.n))
        if self.lib.mbs_integ_advance_many(self.ptr, _dp(ts), len(ts), _dp(X)):
            raise RuntimeError(self.message)
        return X

    def inputs_changed(self):
        self.lib.mbs_integ_inputs_changed(self.ptr)

    @property
    def x(self):
        return np.ctypeslib.as_array(self.lib.mbs_integ_x(self.ptr), (self.n,)).copy()

    @property
    def t(self):
        return self.lib.mbs_integ_t(self.ptr)

    @property
    def h(self):
        return self.lib.mbs_integ_h(self.ptr)

    @property
    def message(self):
        return self.lib.mbs_integ_message(self.ptr).decode()

    @property
    def stats(self):
        s = Stats()
        self.lib.mbs_integ_stats(self.ptr, C.byref(s))
        d = {k: getattr(s, k) for k, _ in Stats._fields_}
        if math.isnan(d["switched_at"]):
            d["switched_at"] = None  # NaN before a switch; None compares equal
        return d

    def save(self):
        buf = C.create_string_buffer(self.lib.mbs_integ_snapshot_size(self.ptr))
        self.lib.mbs_integ_snapshot_save(self.ptr, buf)
        return buf.raw

    def load(self, raw):
        return self.lib.mbs_integ_snapshot_load(self.ptr, raw, len(raw))


def run_points(integ, ts):
    """x at each communication point by one advance per point."""
    return np.array([integ.advance(t) for t in ts])


def scipy_reference(fun, x0, ts):
    from scipy.integrate import solve_ivp
    sol = solve_ivp(fun, (0.0, ts[-1]), x0, method="DOP853", rtol=1e-12, atol=1e-14, t_eval=ts)
    assert sol.success
    return sol.y.T


def vdp_rhs(mu):
    return lambda t, x: [x[1], mu * ((1 - x[0] ** 2) * x[1] - x[0])]


ADAPTIVE = list(layout.ADAPTIVE)


# ------------------------------------------------------------------ accuracy against independent references

@pytest.mark.parametrize("method", ADAPTIVE + ["rk4"])
def test_harmonic_oscillator_closed_form(lib, method):
    ode = Ode(lib, "harmonic", 2.0)
    kw = dict(h=1e-3) if method == "rk4" else dict(rtol=1e-9, atol=1e-12)
    integ = Integ(lib, method, ode, 2, **kw)
    integ.reset(0.0, [1.0, 0.0])
    ts = np.linspace(0.1, 10.0, 100)
    X = run_points(integ, ts)
    exact = np.column_stack([np.cos(2 * ts), -2 * np.sin(2 * ts)])
    tol = {"rk4": 1e-9, "dopri5": 1e-7, "dop853": 1e-8, "radau5": 1e-6, "auto": 1e-7}[method]
    assert np.max(np.abs(X - exact)) < tol
    assert integ.t == ts[-1]


@pytest.mark.parametrize("method", ADAPTIVE)
def test_van_der_pol_against_scipy(lib, method):
    ts = np.linspace(0.5, 10.0, 20)
    ref = scipy_reference(vdp_rhs(1.0), [2.0, 0.0], ts)
    ode = Ode(lib, "vdp", 1.0)
    integ = Integ(lib, method, ode, 2, rtol=1e-10, atol=1e-12)
    integ.reset(0.0, [2.0, 0.0])
    X = run_points(integ, ts)
    assert np.max(np.abs(X - ref)) < {"radau5": 1e-6}.get(method, 1e-7)


@pytest.mark.parametrize("method", ["dopri5", "dop853"])
def test_kepler_orbit_conserves_energy_and_closes(lib, method):
    e = 0.5  # eccentric orbit, period 2π (a = 1, GM = 1), perihelion at (1 − e, 0)
    x0 = [1 - e, 0.0, 0.0, math.sqrt((1 + e) / (1 - e))]
    ode = Ode(lib, "kepler")
    integ = Integ(lib, method, ode, 4, rtol=1e-11, atol=1e-13)
    integ.reset(0.0, x0)
    X = run_points(integ, np.linspace(0.2, 2 * math.pi, 40))
    energy = 0.5 * (X[:, 2] ** 2 + X[:, 3] ** 2) - 1.0 / np.hypot(X[:, 0], X[:, 1])
    momentum = X[:, 0] * X[:, 3] - X[:, 1] * X[:, 2]
    assert np.max(np.abs(energy + 0.5)) < 1e-9  # E = −GM/(2a)
    assert np.max(np.abs(momentum - x0[0] * x0[3])) < 1e-9
    assert np.max(np.abs(X[-1] - x0)) < 1e-7  # back at perihelion after one period


@pytest.mark.parametrize("method", ["rk4", "dopri5", "dop853", "auto"])
def test_rigid_body_quaternion_normalized_and_invariants(lib, method):
    I = np.array([1.0, 2.0, 3.0])
    w0 = np.array([0.3, 1.0, 0.2])  # near the unstable middle axis: a demanding tumble
    x0 = np.concatenate([[1.0, 0.0, 0.0, 0.0], w0])
    ode = Ode(lib, "rigid", *I)
    kw = dict(h=2e-3) if method == "rk4" else dict(rtol=1e-10, atol=1e-12)
    integ = Integ(lib, method, ode, 7, **kw)
    integ.reset(0.0, x0)
    ts = np.linspace(0.05, 20.0, 200)
    X = run_points(integ, ts)
    assert np.max(np.abs(np.linalg.norm(X[:, :4], axis=1) - 1.0)) < 4e-16 * 8
    w = X[:, 4:]
    energy = 0.5 * (w ** 2) @ I
    assert np.max(np.abs(energy - 0.5 * (w0 ** 2) @ I)) < 1e-8
    # angular momentum is constant in the world frame: R(q)·(I ω)
    q = X[:, :4]
    L_body = w * I
    L_world = np.array([_rotate(qi, li) for qi, li in zip(q, L_body)])
    assert np.max(np.abs(L_world - w0 * I)) < 1e-7


def _rotate(q, v):
    w, x, y, z = q
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    return R @ v


def test_rk4_fourth_order(lib):
    """Global error of rk4 drops by 2⁴ = 16 when h is halved."""
    ode = Ode(lib, "harmonic", 1.0)
    errors = []
    for h in (0.1, 0.05, 0.025):
        integ = Integ(lib, "rk4", ode, 2, h=h)
        integ.reset(0.0, [1.0, 0.0])
        x = integ.advance(5.0)
        errors.append(np.max(np.abs(x - [math.cos(5.0), -math.sin(5.0)])))
        assert integ.stats["steps"] == round(5.0 / h)
        assert integ.stats["rhs_evaluations"] == 4 * round(5.0 / h)
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all(np.abs(ratios - 16.0) < 0.6), ratios


# ------------------------------------------------------------------ driver behaviour

@pytest.mark.parametrize("method", layout.FIXED_STEP)
def test_fixed_step_one_substep_per_point_when_the_master_accumulates_time(lib, method):
    """A fixed-step master (ecos, a C host) accumulates t += h, so at t = 50 s the span it asks for differs
    from h by ulps of t (≈ 1e-11 of a 1 ms step): that must still be one internal step, not two half steps."""
    ode = Ode(lib, "harmonic", 1.0)
    h, n = 1e-3, 50_000
    integ = Integ(lib, method, ode, 2, h=h)
    integ.reset(0.0, [1.0, 0.0])
    t = 0.0
    for _ in range(n):
        t += h
        integ.advance(t)
    assert integ.t == t
    assert integ.stats["steps"] == n

@pytest.mark.parametrize("method", ["dopri5", "dop853", "radau5"])
def test_dense_output_agrees_with_landing_and_saves_steps(lib, method):
    ode = Ode(lib, "vdp", 1.0)
    ts = np.arange(1, 801) * 0.01
    runs = {}
    for dense in (1, 0):
        integ = Integ(lib, method, ode, 2, rtol=1e-8, atol=1e-10, dense=dense)
        integ.reset(0.0, [2.0, 0.0])
        runs[dense] = (run_points(integ, ts), integ.stats)
    (Xd, sd), (Xl, sl) = runs[1], runs[0]
    assert np.max(np.abs(Xd - Xl)) < 1e-6
    ref = scipy_reference(vdp_rhs(1.0), [2.0, 0.0], ts)
    assert np.max(np.abs(Xd - ref)) < 1e-6
    assert sd["steps"] < 0.5 * sl["steps"]  # dense steps past the points instead of landing on all 800


def test_step_size_carried_over_between_points(lib):
    """Landing on 1000 close points: the clipped step does not shrink the next proposal, so the number of
    steps stays near one per point (not a fresh HINIT-sized start per point)."""
    ode = Ode(lib, "harmonic", 1.0)
    integ = Integ(lib, "dopri5", ode, 2, rtol=1e-6, atol=1e-9, dense=0)
    integ.reset(0.0, [1.0, 0.0])
    ts = np.arange(1, 1001) * 0.001
    run_points(integ, ts)
    s = integ.stats
    assert s["steps"] <= 1001 and s["rejected"] == 0
    assert integ.h > 0.01  # the proposal grew far beyond the 1 ms spacing


def test_stretch_by_one_percent(lib):
    """A step that would leave less than 1 % of itself is stretched to land on the point; more than 1 %
    left over takes two steps (x' = 1: zero error, every step is accepted)."""
    ode = Ode(lib, "ramp", 1.0)
    integ = Integ(lib, "dopri5", ode, 1, dense=0)
    integ.reset(0.0, [0.0])
    integ.advance(1.0)
    for over, nsteps in ((1.005, 1), (1.02, 2)):
        n0, t0, h = integ.stats["steps"], integ.t, integ.h
        integ.advance(t0 + over * h)
        assert integ.stats["steps"] == n0 + nsteps and integ.t == t0 + over * h
    assert abs(integ.x[0] - integ.t) < 1e-9 * integ.t


def test_max_step_bounds_internal_steps(lib):
    ode = Ode(lib, "ramp", 1.0)
    for dense in (0, 1):
        integ = Integ(lib, "dop853", ode, 1, max_step=0.01, dense=dense)
        integ.reset(0.0, [0.0])
        integ.advance(1.0)
        assert 100 <= integ.stats["steps"] <= 106  # HINIT starts at 1e-6 here, h grows ×10 per step
        assert integ.h <= 0.01
        assert abs(integ.x[0] - 1.0) < 1e-12


def test_advance_many_matches_per_point(lib):
    ode = Ode(lib, "rigid", 1.0, 2.0, 3.0)
    x0 = [1.0, 0.0, 0.0, 0.0, 0.3, 1.0, 0.2]
    ts = np.arange(1, 501) * 0.01
    a = Integ(lib, "dopri5", ode, 7, rtol=1e-8, atol=1e-10)
    a.reset(0.0, x0)
    Xa = run_points(a, ts)
    b = Integ(lib, "dopri5", ode, 7, rtol=1e-8, atol=1e-10)
    b.reset(0.0, x0)
    Xb = b.advance_many(ts)
    assert a.stats == b.stats
    assert np.max(np.abs(Xa - Xb)) < 1e-13
    assert np.max(np.abs(np.linalg.norm(Xb[:, :4], axis=1) - 1.0)) < 1e-15 * 4
    assert b.t == ts[-1] and np.array_equal(b.x, Xb[-1])
    Xc = b.advance_many(ts[-1] + ts)  # continues from where it stopped
    assert np.all(np.isfinite(Xc)) and b.t == 2 * ts[-1]


def test_inputs_changed_holds_new_input_from_now(lib):
    """x' = u with u switched at t = 1: with dense output the ahead point is dropped, so the new input acts
    exactly from t = 1 (piecewise linear closed form)."""
    ode = Ode(lib, "ramp", 1.0)
    integ = Integ(lib, "dopri5", ode, 1)
    integ.reset(0.0, [0.0])
    integ.advance(1.0)
    ode.set(0, -3.0)
    integ.inputs_changed()
    x = integ.advance(1.5)
    assert abs(x[0] - (1.0 - 1.5)) < 1e-12
    ode.set(0, 2.0)  # without inputs_changed the cached FSAL stage would still say −3 for the first step
    integ.inputs_changed()
    assert abs(integ.advance(2.0)[0] - (-0.5 + 1.0)) < 1e-12


def test_rhs_evaluations_count_every_call(lib):
    """dopri5: 1 (start) + 1 (HINIT) + 6 per attempted step, FSAL; dop853: 12 per attempt (+3 dense)."""
    ode = Ode(lib, "harmonic", 1.0)
    integ = Integ(lib, "dopri5", ode, 2, dense=0)
    integ.reset(0.0, [1.0, 0.0])
    integ.advance(3.0)
    s = integ.stats
    assert s["rhs_evaluations"] == 2 + 6 * (s["steps"] + s["rejected"])
    integ = Integ(lib, "dop853", ode, 2, dense=1)
    integ.reset(0.0, [1.0, 0.0])
    integ.advance(3.0)
    s = integ.stats
    assert s["rhs_evaluations"] == 2 + 12 * (s["steps"] + s["rejected"]) + 3


# ------------------------------------------------------------------ failures and messages

def test_max_steps_message(lib):
    ode = Ode(lib, "vdp", 1000.0)
    integ = Integ(lib, "dopri5", ode, 2, max_steps=50)
    integ.reset(0.0, [2.0, 0.0])
    with pytest.raises(RuntimeError, match=r"maximum number of steps \(50\) exceeded in one communication "
                                           r"interval \(step size .*\); the problem may be stiff"):
        integ.advance(10.0)
    assert 0 < integ.t < 10.0 and np.all(np.isfinite(integ.x))
    rk = Integ(lib, "rk4", ode, 2, h=1e-3, max_steps=100)
    rk.reset(0.0, [2.0, 0.0])
    with pytest.raises(RuntimeError, match=r"maximum number of steps \(100\) exceeded: fixed step 0.001 over "
                                           r"an interval of 1"):
        rk.advance(1.0)


@pytest.mark.parametrize("method", ["dopri5", "dop853"])
@pytest.mark.parametrize("dense", [0, 1])
def test_nonfinite_rhs_shrinks_then_fails_with_message(lib, method, dense):
    """NaN beyond t = 0.5: each non-finite trial quarters h; the fourth in a row stops at the last good point."""
    integ = Integ(lib, method, Ode(lib, "nan_after", 0.5), 2, dense=dense)
    integ.reset(0.0, [1.0, 1.0])
    with pytest.raises(RuntimeError, match=r"^right-hand side returned non-finite values \(NaN or Inf\) even for "
                                           r"step size \d\.\d+e-0\d$"):
        integ.advance(1.0)
    assert 0.49 < integ.t <= 0.5 and integ.stats["rejected"] >= 4
    assert np.max(np.abs(integ.x - math.exp(-integ.t))) < 1e-6  # the last good point


@pytest.mark.parametrize("method", ["dopri5", "dop853"])
def test_underflow_at_a_pole(lib, method):
    """x' = x², x(0) = 1 has a pole at t = 1: h shrinks to ~10 ulp and the message says why."""
    integ = Integ(lib, method, Ode(lib, "blowup"), 1, dense=0)
    integ.reset(0.0, [1.0])
    with pytest.raises(RuntimeError, match=r"step size underflow \(h=.*e-15\): the local error tolerance "
                                           r"\(rtol=1e-06, atol=1e-08\) cannot be met — singularity"):
        integ.advance(2.0)
    assert 1.0 - 1e-6 < integ.t < 1.0 + 1e-6 and np.isfinite(integ.x[0]) and integ.x[0] > 1e5


def test_singular_rhs_stops_at_once(lib):
    ode = Ode(lib, "fail_after", 0.3)
    for method in ("rk4", "dopri5", "dop853", "auto"):
        kw = dict(h=0.01) if method == "rk4" else {}
        integ = Integ(lib, method, ode, 2, **kw)
        integ.reset(0.0, [1.0, 1.0])
        with pytest.raises(RuntimeError, match="mass matrix is singular"):
            integ.advance(1.0)
        assert integ.t <= 0.3
        # the explicit methods stop at once; auto hands over to radau5 once (its step sizes cannot cure it either)
        assert integ.stats["rejected"] == 0 if method != "auto" else integ.stats["switched"] == 1


def test_auto_goes_on_with_radau5_where_the_first_explicit_steps_leave_the_domain(lib):
    """ẋ0 = 1, ẋ1 = −λ(x1 − x0), λ = 1e9, defined only for |x| <= 10: f is small at the start and its Jacobian
    huge, so dopri5's first trial stages fly out of the domain before its stiffness test can fire (a real robot
    with a near-massless damped joint does this); auto goes on with radau5 from the start and ends at the closed
    form x0 = t, x1 = t − (1 − exp(−λt))/λ."""
    lam = 1e9
    ode = Ode(lib, "confined", lam)
    explicit = Integ(lib, "dopri5", ode, 2)
    explicit.reset(0.0, [0.0, 0.0])
    with pytest.raises(RuntimeError, match="mass matrix is singular"):
        explicit.advance(1.0)
    integ = Integ(lib, "auto", ode, 2, rtol=1e-10, atol=1e-14)
    integ.reset(0.0, [0.0, 0.0])
    for t, rtol in ((1e-9, 1e-4), (1.0, 1e-9)):  # in the transient x1 ~ 4e-10: atol 1e-14 is 3e-5 of it
        x = integ.advance(t)
        ref = np.array([t, t - (1 - np.exp(-lam * t)) / lam])
        assert np.allclose(x, ref, rtol=rtol, atol=0), (t, x, ref)
    assert integ.stats["switched"] == 1 and integ.stats["switched_at"] < 1e-6  # within its first steps


def test_common_driver_names_no_method():
    """The common driver (integ_base.c) hands every public call to its class's MbsIntegOps and never asks which
    method or which kind of class it runs (auto is a class like the others, issue 23): its code, comments and
    strings aside, names no method's code, class or name, compares no method, and has no composite branch."""
    import re
    code = re.sub(r"/\*.*?\*/|//[^\n]*", " ", (ENGINE / "integ_base.c").read_text(), flags=re.S)
    code = re.sub(r'"(?:\\.|[^"\\])*"', '""', code)
    words = set(re.findall(r"[A-Za-z_]\w*", code))
    named = {e[0] for e in layout.LISTS["MBS_METHODS"]} | {e[1] for e in layout.LISTS["MBS_METHODS"]}
    named |= {f"mbs_{e[2]}_class" for e in layout.LISTS["MBS_METHODS"]} | {"composite"}
    assert not words & named, words & named
    assert not re.search(r"method\s*[!=]=|[!=]=\s*\w*method\b|cls\s*[!=]=|ops\s*[!=]=", code)


OBSERVER = C.CFUNCTYPE(None, C.c_void_p, C.c_double, C.POINTER(C.c_double))


@pytest.mark.parametrize("method,dense", [(m, d) for m in METHODS for d in (0, -1) if (m, d) != ("rk4", -1)])
def test_observer_sees_every_accepted_step_once(lib, method, dense):
    """mbs_integ_set_observer: each accepted step strictly inside an advance, once, in increasing t; landing steps
    are the caller's (without dense output every advance ends on one: reports = steps − advances). radau5 and
    auto on a stiff linear system (ẋ0 = 1, ẋ1 = −λ(x1 − x0), λ = 1e4: auto's dopri5 finds it stiff
    after the transient and hands over to radau5, whose steps are reported too), the others on van der Pol; the
    points are the trajectory's (the closed form x1 = t − (1 − e^(−λt))/λ; scipy's DOP853 at rtol 1e-12) to the
    tolerance asked for."""
    stiff = method in ("radau5", "auto")  # gen_alpha: a mechanical system (ẏ is the velocity), van der Pol
    ts = np.linspace(0.1, 1.5, 8) if stiff else np.linspace(0.5, 4.0, 8)
    ode = Ode(lib, "confined", 1e4) if stiff else Ode(lib, "vdp", 1.0)
    x0 = np.array([0.0, 0.0] if stiff else [2.0, 0.0])
    it = Integ(lib, method, ode, 2, rtol=1e-8, atol=1e-10, h=0.01 if method == "rk4" else 0.0, dense=dense)
    seen = []
    cb = OBSERVER(lambda env, t, x: seen.append((t, x[0], x[1])))
    lib.mbs_integ_set_observer.argtypes = [C.c_void_p, OBSERVER, C.c_void_p]
    lib.mbs_integ_set_observer(it.ptr, cb, None)
    it.reset(0.0, x0)
    t0 = 0.0
    for t_end in ts:
        n0 = len(seen)
        it.advance(t_end)
        assert all(t0 < t < t_end for t, *_ in seen[n0:]), method
        t0 = t_end
    times = np.array([t for t, *_ in seen])
    assert len(times) > 4 and np.all(np.diff(times) > 0), method
    st = it.stats
    if dense == 0:
        assert len(seen) == st["steps"] - len(ts), (method, len(seen), st)
    if method == "auto":
        assert st["switched"] == 1 and times.min() < st["switched_at"] < times.max(), st
    got = np.array([(a, b) for _, a, b in seen])
    if stiff:
        ref = np.column_stack([times, times - (1 - np.exp(-1e4 * times)) / 1e4])
    else:
        from scipy.integrate import solve_ivp
        ref = solve_ivp(vdp_rhs(1.0), (0.0, ts[-1]), x0, method="DOP853", rtol=1e-12, atol=1e-14,
                        dense_output=True).sol(times).T
    err = np.abs(got - ref).max(axis=0) / np.abs(ref).max(axis=0)
    assert err.max() < 1e-5, (method, err)
