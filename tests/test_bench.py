"""Work-precision benchmark: CSV format, sane numbers, errors decrease with tolerance (quick runs only)."""

import csv
import math
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.reports import work_precision as wp

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "models" / "pendulum.yaml"
if not SCENE.exists():
    SCENE = ROOT / "models" / "double_pendulum.yaml"


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("wp")
    rows = wp.run(str(SCENE), str(out), methods=["dopri5", "rk4", "RK45", "Radau"], quick=True, progress=False,
                  stop=1.0)
    return out, rows


def test_csv_columns_and_sane_numbers(quick_run):
    out, rows = quick_run
    with open(out / "work_precision.csv") as fh:
        r = csv.reader(fh)
        header = next(r)
        body = list(r)
    assert header == ["method", "setting", "cpu_seconds", "error", "steps", "rhs_evaluations"]
    assert len(body) == len(rows) >= 3 + 2 + 3 + 3
    methods = {row[0] for row in body}
    assert {"mbsfmu:dopri5", "mbsfmu:rk4", "scipy:RK45", "scipy:Radau"} <= methods
    for row in body:
        cpu, err, steps, nfev = float(row[2]), float(row[3]), int(row[4]), int(row[5])
        assert 0 < cpu < 30
        assert 0 <= err < 1e-1 and math.isfinite(err)
        assert steps >= 1 and nfev >= steps
    assert (out / "work_precision.png").stat().st_size > 10_000
    text = (out / "summary.md").read_text()
    assert "max over communication points" in text and "| method |" in text


def test_errors_decrease_with_tolerance():
    spec = mbsfmu.load(str(SCENE)).spec
    ts = wp.comm_points(spec, stop=1.0, step=0.25)  # long communication steps: the tolerance decides
    Yref, _, _ = wp.run_mbsfmu(spec, "dop853", ts, rtol=1e-12, atol=1e-14)
    for runner, m in ((wp.run_mbsfmu, "dopri5"), (wp.run_scipy, "RK45")):
        errs = [float(np.max(np.abs(runner(spec, m, ts, rtol=r, atol=r * 1e-2)[0] - Yref))) for r in (1e-3, 1e-6, 1e-9)]
        assert errs[0] > errs[1] > errs[2], (m, errs)
        assert errs[2] < 1e-6


def test_fixed_step_error_decreases():
    spec = mbsfmu.load(str(SCENE)).spec
    ts = wp.comm_points(spec, stop=1.0, step=0.05)
    Yref, _, _ = wp.run_mbsfmu(spec, "dop853", ts, rtol=1e-12, atol=1e-14)
    e1 = np.max(np.abs(wp.run_mbsfmu(spec, "rk4", ts, h=0.05)[0] - Yref))
    e2 = np.max(np.abs(wp.run_mbsfmu(spec, "rk4", ts, h=0.01)[0] - Yref))
    assert e2 < e1 / 100  # fourth order: 5^4 = 625


def test_exudyn_matches_reference():
    pytest.importorskip("exudyn")
    spec = mbsfmu.load(str(ROOT / "models" / "double_pendulum.yaml")).spec
    assert wp.exudyn_supported(spec)[0]
    ts = wp.comm_points(spec, stop=1.0)
    Yref, _, _ = wp.run_mbsfmu(spec, "dop853", ts, rtol=1e-12, atol=1e-14)
    Y, _, _ = wp.run_exudyn(spec, "RK44", ts, h=1e-3)
    assert np.max(np.abs(Y - Yref)) < 1e-7


def test_best_at_and_ratio():
    rows = [{"method": "mbsfmu:a", "setting": "", "cpu_seconds": 2.0, "error": 1e-7},
            {"method": "mbsfmu:b", "setting": "", "cpu_seconds": 1.0, "error": 1e-5},
            {"method": "scipy:c", "setting": "", "cpu_seconds": 0.5, "error": 1e-8}]
    assert wp.best_at(rows, "mbsfmu")["method"] == "mbsfmu:a"
    assert wp.best_at(rows, "scipy")["cpu_seconds"] == 0.5
    assert wp.best_at(rows, "exudyn") is None


def test_exudyn_refuses_scenes_with_force_elements():
    spec = mbsfmu.load(str(ROOT / "models" / "cart_pole.yaml")).spec
    ok, why = wp.exudyn_supported(spec)
    assert not ok and "force" in why
