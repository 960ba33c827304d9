"""Engine (C): LU linear algebra, radau5 and gen_alpha, checked against independent references.

The C sources are compiled with `cc -O2 -shared -fPIC -std=c99 -Wall -Wextra -Werror` into a temporary
directory and driven through ctypes; the tests skip when no C compiler is available.
"""

import ctypes
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
ENGINE = ROOT / "src" / "mbsfmu" / "engine"
CDIR = Path(__file__).resolve().parent / "c"
CC = shutil.which("cc") or shutil.which("gcc")

pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler (cc/gcc) on PATH")

_dbl_p = ctypes.POINTER(ctypes.c_double)
_int_p = ctypes.POINTER(ctypes.c_int)


def _build(tmp_dir, name, sources):
    """Compile sources into one shared library with warnings as errors; return the loaded library."""
    out = tmp_dir / f"lib{name}.so"
    cmd = [CC, "-O2", "-shared", "-fPIC", "-std=c99", "-Wall", "-Wextra", "-Werror", f"-I{ENGINE}",
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
