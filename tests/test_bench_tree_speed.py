"""The tree benchmark (benchmarks/tree_speed.py) on tiny sizes: its tables, CSV files and figure, the same model on
every side (the deviations it reports), the C loop, and the growth exponents it states."""

import csv

import numpy as np
import pytest

pytest.importorskip("pinocchio")
from benchmarks import tree_speed  # noqa: E402


def test_tiny_run_writes_the_report(tmp_path):
    robots = "solo12" if tree_speed.robot_files() else "none"
    robot_rows, refused, chain_rows = tree_speed.main(["--out", str(tmp_path), "--sizes", "12", "--robots", robots,
                                                       "--rounds", "3", "--seconds", "0.03", "--quiet"])
    assert [r["n"] for r in chain_rows] == [12] and len(robot_rows) == (robots != "none")
    for r in chain_rows + robot_rows:
        peers = [p for p in tree_speed.PEERS if f"{p}_us" in r]
        assert "pinocchio" in peers
        for p in peers:  # each peer timed on the same tree: its ÿ is ours
            assert r[f"deviation_{p}"] < 1e-9 and r[f"ratio_{p}"] == pytest.approx(r["mbsfmu_us"] / r[f"{p}_us"])
        assert 0 < r["ctypes_us"] < r["mbsfmu_us"] <= r["mbsfmu_median_us"] and r["c_us"] > 0
    assert chain_rows[0]["rss_mb"] >= chain_rows[0]["rss_python_mb"] > 10 and chain_rows[0]["pin_data_mb"] >= 0
    with open(tmp_path / "tree_speed_chains.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["n"]) for r in rows] == [12] and float(rows[0]["ratio_pinocchio"]) > 0
    text = (tmp_path / "tree_speed.md").read_text()
    assert "| 12 |" in text and "Target N = 100: ratio to Pinocchio ≤ 1.5 → not measured" in text
    if robot_rows:
        assert "solo12.urdf | free | 18 |" in text
    assert (tmp_path / "tree_speed.png").stat().st_size > 10_000


def test_growth_exponents_of_power_laws():
    """Times ∝ N³ and ∝ N give exponents 3 and 1, each from N = 100 to the largest size it was timed at."""
    rows = [{"n": n, "mbsfmu_us": 2e-3 * n ** 3, **({"pinocchio_us": 0.1 * n} if n <= 1000 else {})}
            for n in (10, 100, 1000, 3000)] + [{"n": 10000, "refused": "too big"}]
    s = tree_speed.slope(rows)
    assert s["mbsfmu"] == (pytest.approx(3), (100, 3000)) and s["pinocchio"] == (pytest.approx(1), (100, 1000))
    assert "mujoco" not in s


def test_timed_calls_cycle_through_distinct_states():
    """Each timed call is at the next state of the cycle, the same for both peers, so the engine's kinematics (kept
    while the state's bits stay the same) run on every call: after mbsfmu's call k its ÿ is the one at state k, and
    pin.aba's answer of call k, mapped back, is that same ÿ (Pinocchio against the engine, state by state)."""
    from pinocchio_twin import from_pin_acceleration, to_pin
    pair = tree_speed.Pair(tree_speed.chain_scene(5), states=3)
    pair.add_pinocchio()
    npos = pair.sim.npos
    assert not np.allclose(pair.ydd[0], pair.ydd[1]) and not np.allclose(pair.ydd[1], pair.ydd[2])
    for k in range(7):
        y, yd = pair.states[k % 3]
        pair.calls["mbsfmu"]()
        assert np.array_equal(pair.out[npos:], pair.ydd[k % 3])
        _, v, _, P = to_pin(pair.ev, y, yd, free_flyer=True)
        a = from_pin_acceleration(pair.ev, y, v, pair.calls["pinocchio"](), P, free_flyer=True)
        assert np.max(np.abs(a - pair.ydd[k % 3])) < 1e-12 * max(1.0, np.max(np.abs(a)))
