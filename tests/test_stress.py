"""Fast stress cases: NaN/Inf refused cleanly, gimbal-lock message, stiff spring with radau5/auto."""

import csv
from pathlib import Path

import numpy as np
import pytest

from mbsfmu.reports import stress
from mbsfmu.reports.work_precision import comm_points


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


def test_stress_of_a_scene_of_ones_own(tmp_path, capsys):
    """Issue 34, item 22: `mbsfmu stress SCENE --quick` runs the scene over the quick methods, writes the
    case × method summary (table and plot); its errors hold against scipy's integration of the pendulum's
    own ODE (rod hinged at one end plus a sphere at L, written here from scratch) and mbsfmu.simulate's run."""
    import math
    import numpy as np
    from scipy.integrate import solve_ivp
    import mbsfmu
    from mbsfmu.cli import main
    scene = Path(__file__).resolve().parents[1] / "models" / "pendulum.yaml"
    assert main(["stress", str(scene), "--quick", "--no-progress", "--out", str(tmp_path)]) == 0
    rows = list(csv.DictReader((tmp_path / "stress.csv").open()))
    assert [(r["case"], r["method"], r["status"], r["expected"]) for r in rows] == [
        ("pendulum", m, "completed", "yes") for m in stress.QUICK_METHODS]
    assert (tmp_path / "stress.png").stat().st_size > 5000
    md = (tmp_path / "stress.md").read_text()
    assert "| case | dopri5 | radau5 | rk4 |" in md and "\n| pendulum | " in md
    L, m_rod, m_bob, r_bob, g = 0.8, 0.3, 1.0, 0.031, 9.81
    I_O = m_rod * L**2 / 3 + m_bob * (L**2 + 0.4 * r_bob**2)
    w2 = g * (m_rod * L / 2 + m_bob * L) / I_O
    stop = 1.0  # a tenth of the experiment's 10 s
    ts = np.linspace(0, stop, 101)
    ref = solve_ivp(lambda t, x: [x[1], -w2 * math.sin(x[0])], (0, stop), [math.pi / 6, 0.0], t_eval=ts,
                    method="DOP853", rtol=1e-13, atol=1e-14).y[0]
    for r in rows:
        _, Y, _ = mbsfmu.simulate(str(scene), stop=stop, method=r["method"], rtol=1e-6, atol=1e-8)
        assert float(r["error"]) == pytest.approx(np.abs(Y[:, 0] - ref).max(), rel=1e-3, abs=1e-11), r
    with pytest.raises(SystemExit) as e:
        main(["stress", str(scene), "--cases", "nan_input", "--out", str(tmp_path)])
    assert e.value.code == 2
    assert "--cases chooses among the built-in cases" in capsys.readouterr().err
