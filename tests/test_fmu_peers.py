"""benchmarks/fmu_peers: every peer integrates the scene's physics (correctness only, never timings).

Short intervals (top 0.2 s, double pendulum 1 s, 100 points each): each peer at a setting that should reach
the error it is listed with, checked against the tight reference (mbsfmu dop853 at rtol 1e-13, itself checked
against scipy DOP853). MuJoCo's MJCF is checked on accelerations at random states against the engine.
"""
import math

import numpy as np
import pytest

from benchmarks import fmu_peers as fp

STOP = {"spinning_top": 0.2, "double_pendulum": 1.0}
# (family, method, setting, claimed error): explicit RK methods at the 1e-6 target; generalized-α is second
# order, its claim is looser
CLAIMS = [("fmu", "dop853", {"rtol": 1e-10, "atol": 1e-12}, 1e-6),
          ("fmu", "rk4", {"h": 0.1}, 1e-6),
          ("mbsfmu", "dop853", {"rtol": 1e-10, "atol": 1e-12}, 1e-6),
          ("mbsfmu", "rk4", {"h": 0.1}, 1e-6),   # h as a fraction of the communication step (below)
          ("exudyn", "RK44", {"h": 0.25}, 1e-6),
          ("exudyn", "RK67", {"h": 1.0}, 1e-6),
          ("exudyn", "DOPRI5", {"rtol": 1e-10, "atol": 1e-12}, 1e-6),
          ("exudyn", "GeneralizedAlpha", {"h": 0.05}, 1e-3),
          ("mujoco", "RK4", {"h": 0.1}, 1e-6),
          ("scipy", "DOP853", {"rtol": 1e-10, "atol": 1e-12}, 1e-6),
          ("scipy", "LSODA", {"rtol": 1e-10, "atol": 1e-12}, 1e-6)]
NEEDS = {"exudyn": "exudyn", "mujoco": "mujoco", "fmu": "fmpy"}


@pytest.fixture(scope="module", params=list(fp.CASES))
def case(request, tmp_path_factory):
    spec, ts, params = fp.case(request.param, stop=STOP[request.param])
    try:
        import fmpy  # noqa: F401
        fmu = fp.NativeFMU(fp.MODELS / fp.CASES[request.param][0], tmp_path_factory.mktemp(request.param))
    except ImportError:
        fmu = None
    Yref, _, floor = fp.reference(spec, ts)
    model, _ = fp._model(spec)
    assert floor < 1e-10  # the reference agrees with scipy DOP853 at the same tight tolerance
    return dict(name=request.param, spec=spec, ts=ts, params=params, Yref=Yref, fmu=fmu,
                quats=[np.asarray(q) for q in model.quaternions])


def _scaled(kw, dt):
    return {k: v * dt if k == "h" else v for k, v in kw.items()}


@pytest.mark.parametrize("family,method,kw,claim", CLAIMS, ids=[f"{c[0]}-{c[1]}" for c in CLAIMS])
def test_peer_within_its_claimed_error(case, family, method, kw, claim):
    if family in NEEDS:
        pytest.importorskip(NEEDS[family])
    fn = fp.runner(family, method, case["spec"], case["ts"], case["params"], case["fmu"])
    Y, cpu, _ = fn(**_scaled(kw, case["ts"][1] - case["ts"][0]))
    assert Y.shape == case["Yref"].shape
    err = fp.error(Y, case["Yref"], case["quats"])
    assert err <= claim, f"{family}:{method} error {err:.2e} > {claim:g}"
    assert cpu > 0


def test_mjcf_is_the_scene(case):
    pytest.importorskip("mujoco")
    assert fp.mjcf_check(case["spec"]) < 1e-10


def test_mjcf_refuses_what_it_does_not_map():
    import mbsfmu
    spec = mbsfmu.load(fp.MODELS / "cart_pole.yaml").spec
    with pytest.raises(NotImplementedError):
        fp.mjcf(spec, 1e-3)


def test_quaternion_sign_is_one_rotation():
    rng = np.random.default_rng(0)
    Y = rng.normal(size=(5, 4))
    Z = Y.copy()
    Z[1::2] *= -1
    assert fp.error(Z, Y, [np.arange(4)]) == 0.0
    assert fp.error(Z, Y, []) > 0.1  # without the quaternion block the sign counts
    assert fp.error(Y * np.nan, Y) == math.inf


def test_parameter_override_is_checked():
    spec, _, _ = fp.case("spinning_top", stop=0.1)
    assert next(p["value"] for p in spec["parameters"] if p["name"] == "spin") == 150.0
    with pytest.raises(KeyError):
        fp.with_parameters(spec, {"no_such": 1.0})


def test_native_fmu_run_and_report(tmp_path):
    """The native FMU through fmpy at a tight setting reproduces the reference, and a two-peer case gives a
    report whose best runs are at the target."""
    pytest.importorskip("fmpy")
    pytest.importorskip("mujoco")
    res = fp.run_case("double_pendulum", tmp_path, quick=True, stop=0.5, rounds=1,
                      peers=[("fmu", "dop853"), ("mujoco", "RK4")], log=lambda *_: None)
    assert set(res["best"]) == {("fmu", "dop853"), ("mujoco", "RK4")}
    assert all(b["error"] <= fp.TARGET_ERROR for b in res["best"].values())
    fmu_rows = [r for r in res["rows"] if r["family"] == "fmu"]
    # the FMU's errors fall as the tolerance tightens (it obeys integrator.rtol set as a start value)
    assert fmu_rows[0]["error"] > fmu_rows[-1]["error"]
    md = fp.markdown([res], "test")
    assert "ratio FMU / peer" in md and "mujoco:RK4" in md
    rows = fp.csv_rows(res)
    assert {r["kind"] for r in rows} == {"sweep", "head"}
