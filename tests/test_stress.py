"""Fast stress cases: NaN/Inf refused cleanly, gimbal-lock message, stiff spring with radau5/auto."""

import numpy as np
import pytest

from mbsfmu.bench import stress
from mbsfmu.bench.work_precision import comm_points


def _case(name):
    return next(c for c in stress.cases() if c.name == name)


@pytest.mark.parametrize("name", ["nan_input", "inf_input", "nan_parameter"])
@pytest.mark.parametrize("method", stress.METHODS)  # every integrator of the engine
def test_non_finite_inputs_fail_cleanly(name, method):
    case = _case(name)
    spec = stress._load_spec(case.scene)
    r = stress.run_one(spec, case, method, comm_points(spec, stop=0.05))
    assert r["status"] == "failed", r["message"]
    assert "not finite" in r["message"]


@pytest.mark.parametrize("method", ["dopri5", "radau5"])
def test_gimbal_lock_message(method):
    case = _case("gimbal_lock")
    spec = stress._load_spec(case.scene)
    r = stress.run_one(spec, case, method, comm_points(spec, stop=2.0))
    assert r["status"] == "failed"
    assert "gimbal lock" in r["message"] and "quaternion" in r["message"]


def test_stiff_spring_radau5_auto_match_reference_and_auto_is_cheap():
    case = _case("stiff_spring")
    spec = stress._load_spec(case.scene)
    ts = comm_points(spec, stop=0.05)
    ref = stress.run_one(spec, case, "radau5", ts, rtol=1e-11, atol=1e-13)
    assert ref["status"] == "completed"
    out = {}
    for m in ("radau5", "auto"):
        r = stress.run_one(spec, case, m, ts)
        assert r["status"] == "completed", r["message"]
        err = np.max(np.abs(r["Y"] - ref["Y"]))
        assert err < 1e-5, (m, err)  # rtol 1e-6 on coordinates of size 0.1
        out[m] = r
    assert out["auto"]["stats"]["switched"]
    # short dopri5 run (0.01 s) to compare work: auto must be in radau5's class, far below dopri5
    ts_short = comm_points(spec, stop=0.01)
    d = stress.run_one(spec, case, "dopri5", ts_short)
    assert d["status"] == "completed"
    n_auto, n_radau = out["auto"]["stats"]["rhs_evaluations"], out["radau5"]["stats"]["rhs_evaluations"]
    assert n_auto < 4 * n_radau
    assert n_auto < d["stats"]["rhs_evaluations"] / 5  # dopri5 over 1/5 of the interval costs more
    assert out["auto"]["wall"] < 5 * out["radau5"]["wall"] + 0.05


def test_run_writes_table(tmp_path):
    rows = stress.run(str(tmp_path), quick=True, progress=False, only=["nan_input", "gimbal_lock"],
                      methods=["dopri5", "radau5"])
    assert {r["status"] for r in rows} == {"failed"}
    assert all(r["expected"] == "yes" for r in rows)
    text = (tmp_path / "stress.md").read_text()
    assert "gimbal lock" in text and "| method | status |" in text
    header = (tmp_path / "stress.csv").read_text().splitlines()[0]
    assert header == ",".join(stress.COLUMNS)
