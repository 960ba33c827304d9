"""benchmarks/me_vs_cs (fmpy's model exchange against co-simulation of one native FMU): the quick run's files, and its
errors against the reference behave as each solver's order says (seconds: the double pendulum over 0.2 s)."""
import csv

import pytest

pytest.importorskip("fmpy")
from benchmarks import me_vs_cs  # noqa: E402
from mbsfmu.fmu import native  # noqa: E402

pytestmark = pytest.mark.skipif(native.compiler() is None, reason="no C compiler (cc, gcc, clang or $CC)")


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("me_vs_cs")
    (res,) = me_vs_cs.main(["--out", str(out), "--quick", "--stop", "0.2", "--cases", "double_pendulum"])
    return out, res


def test_report_files(quick):
    out, res = quick
    with open(out / "me_vs_cs.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == me_vs_cs.COLUMNS and len(rows) == len(res["rows"])
    assert {(r["interface"], r["method"]) for r in rows} == {("ME", "CVode"), ("ME", "Euler"), ("CS", "dop853"),
                                                             ("CS", "rk4")}
    assert all(float(r["cpu_ms"]) > 0 for r in rows)
    text = (out / "me_vs_cs.md").read_text()
    assert "| error ≤ | ME:CVode | ME:Euler |" in text and "CVode / CS" in text
    assert (out / "me_vs_cs.double_pendulum.png").stat().st_size > 10_000


def test_errors_follow_the_solvers(quick):
    """Against the engine's dop853 at rtol 1e-13 (scipy's DOP853 agrees to the floor): CVode's error falls with its
    rtol; explicit Euler is first order (64 times the steps: about 64 times less error); the engine's dop853 under
    co-simulation is below 1e-8 at rtol 1e-8."""
    _, res = quick
    assert res["floor"] < 1e-11
    err = {(r["interface"], r["method"], r["setting"]): r["error"] for r in res["rows"]}
    cvode = [e for (i, m, _), e in err.items() if m == "CVode"]
    assert len(cvode) == 3 and cvode[0] > cvode[1] > cvode[2] and cvode[2] < 1e-8, cvode
    e1, e64 = [e for (i, m, _), e in err.items() if m == "Euler"]
    assert 30 < e1 / e64 < 130, (e1, e64)
    assert err["CS", "dop853", "rtol=1e-08"] < 1e-8


def test_cheapest_at_a_level():
    rows = [dict(interface="ME", method="CVode", setting="a", error=1e-7, cpu_ms=3.0),
            dict(interface="ME", method="CVode", setting="b", error=1e-5, cpu_ms=1.0),
            dict(interface="CS", method="rk4", setting="c", error=1e-6, cpu_ms=2.0),
            dict(interface="CS", method="dop853", setting="d", error=1e-8, cpu_ms=2.5)]
    assert me_vs_cs.cheapest(rows, 1e-6, "ME:CVode")["setting"] == "a"
    assert me_vs_cs.cheapest(rows, 1e-6, "CS")["setting"] == "c"
    assert me_vs_cs.cheapest(rows, 1e-8, "CS")["setting"] == "d"
    assert me_vs_cs.cheapest(rows, 1e-8, "ME:Euler") is None
