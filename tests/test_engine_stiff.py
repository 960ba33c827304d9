"""Engine (C): LU linear algebra, radau5 and gen_alpha, checked against independent references.

The C sources are compiled with `cc -O2 -shared -fPIC -std=c99` into a temporary directory and driven through ctypes; the tests skip when no C compiler is available.
"""

import ctypes
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
from test_engine_integrators import METHODS, Options, Stats
from test_engine_integrators import Integ as IntegBase  # the ctypes wrapper of one MbsIntegrator

ROOT = Path(__file__).resolve().parents[1]
ENGINE = ROOT / "src" / "mbsfmu" / "engine"
CDIR = Path(__file__).resolve().parent / "c"
CC = shutil.which("cc") or shutil.which("gcc")

pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler (cc/gcc) on PATH")

_dbl_p = ctypes.POINTER(ctypes.c_double)
_int_p = ctypes.POINTER(ctypes.c_int)


def _build(tmp_dir, name, sources):
    """Compile sources into one shared library; return the loaded library.  (Warnings are errors only in
    test_own_sources_compile_warning_free, for this task's files: the other engine files are not ours.)"""
    out = tmp_dir / f"lib{name}.so"
    cmd = [CC, "-O2", "-shared", "-fPIC", "-std=c99", f"-I{ENGINE}",
           "-o", str(out), *map(str, sources), "-lm"]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return ctypes.CDLL(str(out))


def _ptr(a, typ=_dbl_p):
    return a.ctypes.data_as(typ)


# ---------------------------------------------------------------------------- linalg.c
@pytest.fixture(scope="module")
def linalg(tmp_path_factory):
    lib = _build(tmp_path_factory.mktemp("linalg"), "linalg", [ENGINE / "linalg.c"])
    for fn in ("mbs_lu_factor", "mbs_zlu_factor"):
        getattr(lib, fn).argtypes = [ctypes.c_int, _dbl_p, _int_p]
        getattr(lib, fn).restype = ctypes.c_int
    for fn in ("mbs_lu_solve", "mbs_zlu_solve"):
        getattr(lib, fn).argtypes = [ctypes.c_int, _dbl_p, _int_p, _dbl_p]
        getattr(lib, fn).restype = None
    lib.mbs_lu_pivots_valid.argtypes = [ctypes.c_int, _int_p]
    return lib


def _solve(lib, A, b):
    """x = A⁻¹b through the C factor/solve pair (real or complex by dtype)."""
    n = A.shape[0]
    cplx = np.iscomplexobj(A)
    LU = np.ascontiguousarray(A, dtype=complex if cplx else float).copy()
    x = np.ascontiguousarray(b, dtype=LU.dtype).copy()
    piv = np.zeros(n, dtype=np.intc)
    factor, solve = (lib.mbs_zlu_factor, lib.mbs_zlu_solve) if cplx else (lib.mbs_lu_factor, lib.mbs_lu_solve)
    # complex128 is the interleaved (re, im) layout linalg.h documents
    info = factor(n, _ptr(LU.view(float)), _ptr(piv, _int_p))
    if info:
        return info, None, piv
    solve(n, _ptr(LU.view(float)), _ptr(piv, _int_p), _ptr(x.view(float)))
    return 0, x, piv


@pytest.mark.parametrize("n", [1, 2, 5, 17, 40])
def test_lu_real_matches_numpy(linalg, n):
    rng = np.random.default_rng(n)
    A = rng.standard_normal((n, n))
    if n > 1:
        A[0, 0] = 0.0  # forces a row exchange at the first step
    b = rng.standard_normal(n)
    info, x, piv = _solve(linalg, A, b)
    assert info == 0
    assert linalg.mbs_lu_pivots_valid(n, _ptr(piv, _int_p)) == 1
    ref = np.linalg.solve(A, b)
    assert np.allclose(x, ref, rtol=1e-11, atol=1e-11 * np.abs(ref).max())


@pytest.mark.parametrize("n", [1, 3, 8, 25])
def test_lu_complex_matches_numpy(linalg, n):
    rng = np.random.default_rng(100 + n)
    A = rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n))
    b = rng.standard_normal(n) + 1j * rng.standard_normal(n)
    info, x, _ = _solve(linalg, A, b)
    assert info == 0
    ref = np.linalg.solve(A, b)
    assert np.allclose(x, ref, rtol=1e-11, atol=1e-11 * np.abs(ref).max())


def test_lu_radau_like_shifted_matrices(linalg):
    """The matrices radau5 factors: μ/h·I − J with a stiff J (eigenvalues spread over 8 decades)."""
    rng = np.random.default_rng(7)
    n = 12
    Qm, _ = np.linalg.qr(rng.standard_normal((n, n)))
    J = Qm @ np.diag(-np.logspace(0, 8, n)) @ Qm.T
    h = 1e-3
    for mu in (3.637834252744496, 2.681082873627752 - 3.050430199247411j):
        M = mu / h * np.eye(n) - J
        b = rng.standard_normal(n) + (1j * rng.standard_normal(n) if np.iscomplex(mu) else 0)
        info, x, _ = _solve(linalg, M, b)
        assert info == 0
        ref = np.linalg.solve(M, b)
        # backward-stable solve: relative error bounded by cond(M)·eps
        assert np.linalg.norm(x - ref) <= 1e-13 * np.linalg.cond(M) * np.linalg.norm(ref)


@pytest.mark.parametrize("cplx", [False, True])
def test_lu_singular_reports_column(linalg, cplx):
    A = np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [1.0, 0.0, 1.0]], dtype=complex if cplx else float)
    info, _, piv = _solve(linalg, A, np.ones(3))
    # column 0 pivots on row 1, column 1 then pivots on the independent row, column 2 is left zero
    assert info == 3
    assert linalg.mbs_lu_pivots_valid(3, _ptr(piv, _int_p)) == 1
    info, _, _ = _solve(linalg, np.zeros((2, 2), dtype=A.dtype), np.ones(2))
    assert info == 1


def test_lu_pivot_validation(linalg):
    for piv, ok in (([0, 1, 2], 1), ([2, 2, 2], 1), ([1, 0, 2], 0), ([0, 3, 2], 0), ([-1, 1, 2], 0)):
        p = np.array(piv, dtype=np.intc)
        assert linalg.mbs_lu_pivots_valid(3, _ptr(p, _int_p)) == ok


# ---------------------------------------------------------------------------- integrators
def _engine_sources():
    """Integrator sources of the engine (the driver needs every method's class) and the test systems."""
    return sorted(ENGINE.glob("integ_*.c")) + [ENGINE / "linalg.c", CDIR / "stiff_odes.c"]


@pytest.fixture(scope="module")
def eng(tmp_path_factory):
    return _declare(_build(tmp_path_factory.mktemp("stiff"), "stiff", _engine_sources()))


def _declare(lib):
    """ctypes signatures of the integrator API (as test_engine_integrators.Integ calls it) and the test systems."""
    vp = ctypes.c_void_p
    sigs = {
        "stiff_problem_new": (vp, [ctypes.c_char_p, _dbl_p, ctypes.c_int]),
        "stiff_problem_free": (None, [vp]),
        "stiff_method_state_offset": (ctypes.c_size_t, [vp]),
        "mbs_integ_new": (vp, [ctypes.c_int, vp, ctypes.POINTER(Options), ctypes.c_char_p, ctypes.c_size_t]),
        "mbs_integ_free": (None, [vp]),
        "mbs_integ_reset": (ctypes.c_int, [vp, ctypes.c_double, _dbl_p]),
        "mbs_integ_inputs_changed": (None, [vp]),
        "mbs_integ_advance": (ctypes.c_int, [vp, ctypes.c_double]),
        "mbs_integ_advance_many": (ctypes.c_int, [vp, _dbl_p, ctypes.c_int, _dbl_p]),
        "mbs_integ_t": (ctypes.c_double, [vp]),
        "mbs_integ_x": (_dbl_p, [vp]),
        "mbs_integ_h": (ctypes.c_double, [vp]),
        "mbs_integ_stats": (None, [vp, ctypes.POINTER(Stats)]),
        "mbs_integ_message": (ctypes.c_char_p, [vp]),
        "mbs_integ_snapshot_size": (ctypes.c_size_t, [vp]),
        "mbs_integ_snapshot_save": (None, [vp, ctypes.c_char_p]),
        "mbs_integ_snapshot_load": (ctypes.c_int, [vp, ctypes.c_char_p, ctypes.c_size_t]),
    }
    for name, (res, args) in sigs.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    lib.have = {m: True for m in METHODS}
    return lib


class StiffProblem:
    """A system of stiff_odes.c, owned by the C library."""

    def __init__(self, lib, name, params):
        self.lib = lib
        p = np.array(params, dtype=float).reshape(-1)
        self.ptr = lib.stiff_problem_new(name.encode(), _ptr(p), p.size)
        assert self.ptr

    def __del__(self):
        self.lib.stiff_problem_free(self.ptr)


class Integ(IntegBase):
    """One C integrator on one stiff_odes.c system, started at (t0, x0)."""

    def __init__(self, lib, problem, params, method, x0, t0=0.0, **kw):
        super().__init__(lib, method, StiffProblem(lib, problem, params), len(x0), **kw)
        assert self.reset(t0, x0) == 0

    def state_offset(self):
        """Byte offset of the method's POD struct (Radau5State / GenAlphaState) in a snapshot."""
        return self.lib.stiff_method_state_offset(self.ptr)


def test_own_sources_compile_warning_free(tmp_path):
    """linalg.c, integ_radau5.c, integ_gen_alpha.c: C99, -Wall -Wextra -pedantic clean."""
    for src in ("linalg.c", "integ_radau5.c", "integ_gen_alpha.c"):
        res = subprocess.run([CC, "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2", "-c",
                              str(ENGINE / src), "-o", str(tmp_path / "x.o")], capture_output=True, text=True)
        assert res.returncode == 0, res.stderr


# ---------------------------------------------------------------------------- radau5
def _robertson(t, x):
    r1, r2, r3 = 0.04 * x[0], 3e7 * x[1] ** 2, 1e4 * x[1] * x[2]
    return [-r1 + r3, r1 - r2 - r3, r2]


def _vdp(mu):
    return lambda t, x: [x[1], mu * ((1.0 - x[0] ** 2) * x[1] - x[0])]


def _vdp_jac(mu):
    return lambda t, x: [[0.0, 1.0], [mu * (-2.0 * x[0] * x[1] - 1.0), mu * (1.0 - x[0] ** 2)]]


def test_radau5_robertson_matches_scipy(eng):
    from scipy.integrate import solve_ivp
    ts = np.array([0.4, 4.0, 40.0])
    ref = solve_ivp(_robertson, (0, 40), [1.0, 0, 0], method="Radau", rtol=1e-10, atol=1e-16, t_eval=ts).y.T
    for dense in (0, 1):
        it = Integ(eng, "robertson", [], "radau5", [1.0, 0.0, 0.0], rtol=1e-8, atol=1e-14, dense=dense)
        X = np.array([it.advance(t) for t in ts])
        assert np.all(np.abs(X - ref) <= 2e-7 * np.abs(ref)), (dense, X / ref - 1)
        assert abs(X[-1].sum() - 1.0) < 1e-12  # mass conservation: linear invariant, kept by Radau IIA
        s = it.stats
        assert s["steps"] < 200 and s["jac_evaluations"] < s["steps"] and s["lu_decompositions"] <= s["steps"] + s["rejected"]


def test_radau5_van_der_pol_published_reference(eng):
    """Hairer's VDPOL (ε = 1e-6, y(0) = (2, 0)): y(2) = (1.706167732170483, −0.8928097010247975) from the
    test set for IVP solvers (Hairer & Wanner, Solving ODEs II; Mazzia & Magherini)."""
    ref = np.array([1.706167732170483, -0.8928097010247975])
    errs = []
    for rtol in (1e-6, 1e-9):
        it = Integ(eng, "vdp", [1e6], "radau5", [2.0, 0.0], rtol=rtol, atol=rtol)
        x = it.advance(2.0)
        errs.append(np.max(np.abs(x - ref) / np.abs(ref)))
        assert it.t == 2.0 and it.stats["steps"] < 3000
    assert errs[0] < 1e-5 and errs[1] < 1e-7 and errs[1] < errs[0] / 10


def test_radau5_van_der_pol_mu1000_matches_scipy_and_dense_output(eng):
    """μ = 1e3 over [0, 3] (one relaxation period with two fast transitions): scipy Radau at rtol 1e-10 as the
    reference; the collocation-polynomial dense output (dense=1) vs exact landing (dense=0) agree within the
    tolerance, and advance_many repeats the per-point dense run."""
    from scipy.integrate import solve_ivp
    mu = 1e3
    ts = np.linspace(0.05, 3.0, 60)
    ref = solve_ivp(_vdp(mu), (0, 3), [2.0, 0.0], method="Radau", rtol=1e-10, atol=1e-10, jac=_vdp_jac(mu),
                    t_eval=ts).y.T
    runs = {}
    for dense in (0, 1):
        it = Integ(eng, "vdp", [mu], "radau5", [2.0, 0.0], rtol=1e-8, atol=1e-8, dense=dense)
        runs[dense] = np.array([it.advance(t) for t in ts])
        runs[dense, "stats"] = it.stats
        scale = 1e-8 * (1.0 + np.abs(ref))
        assert np.max(np.abs(runs[dense] - ref) / scale) < 100, dense
    # dense output steps past the points: fewer steps than landing on each of the 60 points
    assert runs[1, "stats"]["steps"] < runs[0, "stats"]["steps"]
    assert np.max(np.abs(runs[1] - runs[0]) / (1e-8 * (1.0 + np.abs(ref)))) < 100
    it = Integ(eng, "vdp", [mu], "radau5", [2.0, 0.0], rtol=1e-8, atol=1e-8, dense=1)
    many = it.advance_many(ts)
    assert np.allclose(many, runs[1], rtol=1e-13, atol=1e-13)
    assert it.stats["steps"] == runs[1, "stats"]["steps"]


def test_radau5_dense_output_matches_closed_form(eng):
    """Harmonic oscillator, 300 output points read from the collocation polynomials of far fewer steps:
    every interpolated point matches cos/sin to the tolerance."""
    it = Integ(eng, "osc", [1.0], "radau5", [1.0, 0.0], rtol=1e-10, atol=1e-12, dense=1)
    ts = np.linspace(0.01, 6.0, 300)
    X = it.advance_many(ts)
    exact = np.column_stack((np.cos(ts), -np.sin(ts)))
    assert np.max(np.abs(X - exact)) < 1e-8
    assert it.stats["steps"] < 300  # many points per step came from the polynomial


# ---------------------------------------------------------------------------- gen_alpha
def _ga_amplification(rho_inf, hw):
    """Amplification matrix of generalized-α on y'' = −ω²y (ω = 1, h = hw) in the variables (y, v, a), from
    the method's linear recurrence with Chung & Hulbert's parameters: closed-form analysis, not the C code."""
    am, af = (2 * rho_inf - 1) / (rho_inf + 1), rho_inf / (rho_inf + 1)
    g = 0.5 + af - am
    b = 0.25 * (g + 0.5) ** 2
    h, w2 = hw, 1.0
    # unknowns (y₊, v₊, a₊): Newmark updates and the α-balance with ÿ = −ω²y
    L = np.array([[1, 0, -h * h * b], [0, 1, -h * g], [(1 - af) * w2, 0, 1 - am]])
    R = np.array([[1, h, h * h * (0.5 - b)], [0, 1, h * (1 - g)], [-af * w2, 0, -am]])
    return np.linalg.solve(L, R)


def test_gen_alpha_second_order(eng):
    """Linear oscillator against cos(ωt): the error falls by ≈ 4 when h halves."""
    w, T_end = 2.0, 2.0
    errs = []
    for h in (0.02, 0.01, 0.005):
        it = Integ(eng, "osc", [w], "gen_alpha", [1.0, 0.0], h=h, rho_inf=0.8, rtol=1e-10, atol=1e-12)
        y, v = it.advance(T_end)
        errs.append(np.hypot(y - np.cos(w * T_end), (v + w * np.sin(w * T_end)) / w))
        assert it.stats["steps"] == round(T_end / h)
    ratios = [errs[0] / errs[1], errs[1] / errs[2]]
    assert all(3.7 < r < 4.3 for r in ratios), ratios


@pytest.mark.parametrize("rho_inf", [0.0, 0.5, 0.8])
def test_gen_alpha_damps_stiff_mode_as_rho_inf(eng, rho_inf):
    """Slow mode (h·ω = 0.01) and stiff mode (h·ω = 1000): the stiff mode follows, step by step, the
    amplification matrix of the method, whose spectral radius is ρ∞ + O(1/(h·ω)); the slow mode is kept."""
    h, w_stiff, nsteps = 0.01, 1e5, 20
    it = Integ(eng, "osc", [1.0, w_stiff], "gen_alpha", [1.0, 1.0, 0.0, 0.0], h=h, rho_inf=rho_inf,
               rtol=1e-10, atol=1e-14)
    A = _ga_amplification(rho_inf, h * w_stiff)
    assert abs(max(abs(np.linalg.eigvals(A))) - rho_inf) < 0.011
    z = np.array([1.0, 0.0, -1.0])  # (y, v/ω, a/ω²) of the stiff mode; a starts as ÿ(0)
    amp = [1.0]
    for k in range(1, nsteps + 1):
        x = it.advance(k * h)
        z = A @ z
        # the stiff mode follows the recurrence to the Newton tolerance (relative to the initial amplitude)
        assert abs(x[1] - z[0]) < 1e-7 and abs(x[3] / w_stiff - z[1]) < 1e-7, (k, x[1], z[0])
        amp.append(np.hypot(x[1], x[3] / w_stiff))
    if rho_inf == 0.0:
        assert amp[-1] < 1e-6
    else:  # decay per step over the last 10 steps: ρ(A), times ≤ 2^(1/10) from the double root's k·ρ^k
        rate = (amp[-1] / amp[-11]) ** 0.1
        rho = max(abs(np.linalg.eigvals(A)))
        assert rho * 0.99 < rate < rho * 1.08, (rate, rho)
    t = nsteps * h
    assert np.hypot(x[0] - np.cos(t), x[2] + np.sin(t)) < 1e-4  # slow mode follows the exact solution


@pytest.mark.parametrize("hw", [0.3, 100.0])
def test_gen_alpha_rho_inf_1_conserves_energy(eng, hw):
    """ρ∞ = 1 (trapezoidal rule): no numerical damping, the energy of an undamped oscillator is kept over
    500 steps, also for a stiff h·ω; ρ∞ = 0.8 visibly dissipates the stiff case."""
    w = 10.0
    h = hw / w
    for rho_inf in (1.0, 0.8):
        it = Integ(eng, "osc", [w], "gen_alpha", [1.0, 0.0], h=h, rho_inf=rho_inf, rtol=1e-10, atol=1e-14)
        y, v = it.advance(500 * h)
        energy = 0.5 * (v * v + w * w * y * y) / (0.5 * w * w)
        if rho_inf == 1.0:
            assert abs(energy - 1.0) < 1e-7, energy
        elif hw > 1:
            assert energy < 1e-6


def test_gen_alpha_adaptive_meets_tolerance(eng):
    """Step doubling: the global error of the nonlinear Van der Pol (μ = 5) follows the tolerance (scipy
    reference; local error control of an order-2 method: global error a few dozen times rtol); a tighter
    tolerance costs more steps."""
    from scipy.integrate import solve_ivp
    mu, ts = 5.0, [1.0, 3.0, 6.0]
    ref = solve_ivp(_vdp(mu), (0, 6), [2.0, 0.0], method="Radau", rtol=1e-11, atol=1e-11, t_eval=ts).y.T
    steps, errs = [], []
    for rtol in (1e-4, 1e-6):
        it = Integ(eng, "vdp", [mu], "gen_alpha", [2.0, 0.0], rtol=rtol, atol=rtol, rho_inf=0.8)
        X = np.array([it.advance(t) for t in ts])
        errs.append(np.max(np.abs(X - ref) / (1.0 + np.abs(ref))))
        steps.append(it.stats["steps"])
    assert errs[0] < 1e-2 and errs[1] < 3e-4 and errs[1] < errs[0] / 10, errs
    assert steps[1] > 2 * steps[0]


def _top_invariants(x, I, mgl):
    """Energy and the vertical component of the world angular momentum of the heavy top."""
    w0, x1, y1, z1 = x[:4]
    R = np.array([[1 - 2 * (y1 * y1 + z1 * z1), 2 * (x1 * y1 - w0 * z1), 2 * (x1 * z1 + w0 * y1)],
                  [2 * (x1 * y1 + w0 * z1), 1 - 2 * (x1 * x1 + z1 * z1), 2 * (y1 * z1 - w0 * x1)],
                  [2 * (x1 * z1 - w0 * y1), 2 * (y1 * z1 + w0 * x1), 1 - 2 * (x1 * x1 + y1 * y1)]])
    w = x[4:]
    Iw = I * w
    return 0.5 * w @ Iw + mgl * R[2, 2], (R @ Iw)[2], R @ Iw


@pytest.mark.parametrize("method,kw", [("radau5", {"rtol": 1e-9, "atol": 1e-9}),
                                       ("gen_alpha", {"rtol": 1e-7, "atol": 1e-7}),
                                       ("gen_alpha", {"h": 1e-3})])
def test_quaternion_top_unit_norm_and_invariants(eng, method, kw):
    """Heavy top (unit quaternion + body rates, retract q ⊗ exp(δ/2)): |q| = 1 after every step; energy and
    vertical angular momentum conserved; torque-free (m·g·l = 0) the whole angular momentum vector is."""
    I = np.array([1.0, 2.0, 3.0])
    q0 = np.array([np.cos(0.2), np.sin(0.2), 0.0, 0.0])  # tilted 0.4 rad about x
    x0 = np.concatenate((q0, [0.3, 0.2, 5.0]))
    tol = 1e-6 if "h" in kw else 3e-6
    for mgl in (2.0, 0.0):
        it = Integ(eng, "top", [*I, mgl], method, x0, rho_inf=0.8, **kw)
        E0, Lz0, L0 = _top_invariants(x0, I, mgl)
        for t in np.linspace(0.1, 2.0, 20):
            x = it.advance(t)
            assert abs(np.linalg.norm(x[:4]) - 1.0) < 1e-14
            E, Lz, L = _top_invariants(x, I, mgl)
            assert abs(E - E0) < tol * abs(E0) and abs(Lz - Lz0) < tol * np.linalg.norm(L0), (t, E - E0, Lz - Lz0)
            if mgl == 0.0:
                assert np.linalg.norm(L - L0) < tol * np.linalg.norm(L0)


# ---------------------------------------------------------------------------- snapshots and failures
SNAP_CASES = {
    "radau5_dense": ("vdp", [10.0], "radau5", [2.0, 0.0], dict(rtol=1e-6, atol=1e-6, dense=1)),
    "radau5_land": ("robertson", [], "radau5", [1.0, 0.0, 0.0], dict(rtol=1e-6, atol=1e-12, dense=0)),
    "gen_alpha_fixed": ("top", [1.0, 2.0, 3.0, 2.0], "gen_alpha",
                        [np.cos(0.2), np.sin(0.2), 0, 0, 0.3, 0.2, 5.0], dict(h=2e-3)),
    "gen_alpha_adaptive": ("vdp", [5.0], "gen_alpha", [2.0, 0.0], dict(rtol=1e-6, atol=1e-6)),
}


def _snap_case(eng, name):
    problem, params, method, x0, kw = SNAP_CASES[name]
    return Integ(eng, problem, params, method, x0, **kw)


@pytest.mark.parametrize("name", sorted(SNAP_CASES))
def test_snapshot_then_continue_is_bit_identical(eng, name):
    """Save mid-run (Jacobian, LU pair, controller and collocation/acceleration history inside), continue;
    load the bytes into the same and into a fresh integrator: the continuation repeats bit for bit."""
    ts = np.linspace(0.3, 1.5, 5)
    a = _snap_case(eng, name)
    a.advance(0.25)
    raw = a.save()
    first = a.advance_many(ts)
    stats = a.stats
    assert a.load(raw) == 0
    assert np.array_equal(a.advance_many(ts), first) and a.stats == stats
    b = _snap_case(eng, name)  # fresh, at t = 0
    assert b.load(raw) == 0
    assert np.array_equal(b.advance_many(ts), first) and b.stats == stats


def _corruptions(method, n, off):
    """(what, byte offset, int32 value) that a valid snapshot must not accept; offsets into the method's
    POD struct (layouts of Radau5State / GenAlphaState) and the pivot arrays (the snapshot's last ints: two of
    n for radau5, of nvel for gen_alpha, whose matrices are nvel × nvel)."""
    if method == "radau5":  # 6 doubles, then have_f0, have_J, current_jac, have_lu, have_old, have_Q, ...
        flags = off + 48
        return [("flag have_lu = 2", flags + 12, 2), ("flag first = -1", flags + 32, -1),
                ("real pivot out of range", -8 * n, n), ("complex pivot below its row", -4 * n + 4 * (n - 1), 0),
                ("negative pivot", -8 * n, -1)]
    flags = off + 24  # faccon, lu_h[2], then have_vdot, have_K, current_jac, last_rejected, recompute_jac, ncache, oldest
    return [("flag have_K = 7", flags + 4, 7), ("ncache = 3", flags + 20, 3), ("ncache = -1", flags + 20, -1),
            ("oldest = 2", flags + 24, 2), ("pivot of slot 0 out of range", -8 * n, 1 << 30)]


@pytest.mark.parametrize("name", ["radau5_dense", "gen_alpha_fixed", "gen_alpha_adaptive"])
def test_corrupt_snapshot_rejected_and_integrator_unchanged(eng, name):
    method = SNAP_CASES[name][2]
    ref = _snap_case(eng, name)
    ref.advance(0.25)
    expected = ref.advance(0.5)
    it = _snap_case(eng, name)
    it.advance(0.25)
    raw = it.save()
    n = it.n if method == "radau5" else {"top": 3, "vdp": 1}[SNAP_CASES[name][0]]  # pivots: n / nvel each
    # the state actually in use: LU pair / an LU slot present, so the pivots are checked
    flags = it.state_offset() + (48 if method == "radau5" else 24)
    assert struct.unpack_from("<i", raw, flags + (12 if method == "radau5" else 20))[0] >= 1
    bad = [("truncated", raw[:-8]), ("extended", raw + b"\0" * 8), ("empty", b"")]
    for what, pos, value in _corruptions(method, n, it.state_offset()):
        buf = bytearray(raw)
        struct.pack_into("<i", buf, pos % len(buf), value)
        bad.append((what, bytes(buf)))
    for what, buf in bad:
        assert it.load(buf) == 1, what
    assert np.array_equal(it.advance(0.5), expected)


def test_snapshot_of_other_method_or_size_rejected(eng):
    r = _snap_case(eng, "radau5_dense")
    g = _snap_case(eng, "gen_alpha_adaptive")  # same n = 2, other method
    r3 = _snap_case(eng, "radau5_land")        # same method, n = 3
    for it in (r, g, r3):
        it.advance(0.1)
    assert g.load(r.save()) == 1 and r.load(g.save()) == 1 and r3.load(r.save()) == 1


@pytest.mark.parametrize("method,kw,expect", [
    ("radau5", {}, "right-hand side returned non-finite values (NaN or Inf) even for step size"),
    # step doubling accepts every step that ends before the NaN region: h shrinks towards t = 0.5 until underflow
    ("gen_alpha", {}, "step size underflow (h="),
    ("gen_alpha", {"h": 0.01}, "gen_alpha: non-finite accelerations even at step size"),
])
def test_nonfinite_rhs_stops_at_last_good_point(eng, method, kw, expect):
    it = Integ(eng, "nan_after", [0.5], method, [1.0, 2.0], rho_inf=0.8, **kw)
    with pytest.raises(RuntimeError, match=expect.replace("(", r"\(").replace(")", r"\)")):
        it.advance(1.0)
    assert it.t <= 0.5 and np.isfinite(it.x).all()
    if method == "radau5":  # a first-order system (gen_alpha reads it as y'' = v̇, another solution)
        assert it.t > 0.49 and np.allclose(it.x, np.exp(-it.t) * np.array([1.0, 2.0]), rtol=1e-5)
    if "h" in kw:
        assert "(fixed step split 10 times)" in it.message


@pytest.mark.parametrize("method", ["radau5", "gen_alpha"])
def test_failing_rhs_message_passed_through(eng, method):
    it = Integ(eng, "fail_after", [0.5], method, [1.0, 2.0], rho_inf=0.8)
    with pytest.raises(RuntimeError, match="test: mass matrix singular"):
        it.advance(1.0)
    assert it.t <= 0.5


def test_start_with_nonfinite_derivative_fails_cleanly(eng):
    for method in ("radau5", "gen_alpha"):
        it = Integ(eng, "nan_after", [-1.0], method, [1.0, 2.0], rho_inf=0.8)
        with pytest.raises(RuntimeError, match="at the current state"):
            it.advance(1.0)
        assert it.t == 0.0


@pytest.mark.parametrize("rho_inf", [-0.1, 1.5, float("nan")])
def test_gen_alpha_rejects_bad_rho_inf(eng, rho_inf):
    with pytest.raises(ValueError, match="rho_inf must lie in"):
        Integ(eng, "osc", [1.0], "gen_alpha", [1.0, 0.0], rho_inf=rho_inf)


def test_gen_alpha_needs_retract_when_npos_differs(eng):
    """robertson declares npos = 3, nvel = 0: no velocities to iterate on → clear error, no crash."""
    with pytest.raises(ValueError, match="gen_alpha needs"):
        Integ(eng, "robertson", [], "gen_alpha", [1.0, 0.0, 0.0])
