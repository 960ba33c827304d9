"""The tree benchmark (bench/tree_speed.py) on tiny sizes: its tables, CSV files and figure, the same model on
both sides (the deviation it reports), the C loop, and the growth exponent it states."""

import csv

import pytest

pytest.importorskip("pinocchio")
from mbsfmu.bench import tree_speed  # noqa: E402


def test_tiny_run_writes_the_report(tmp_path):
    robots = "solo12" if tree_speed.robot_files() else "none"
    robot_rows, refused, chain_rows = tree_speed.main(["--out", str(tmp_path), "--sizes", "12", "--robots", robots,
                                                       "--rounds", "3", "--seconds", "0.03", "--quiet"])
    assert [r["n"] for r in chain_rows] == [12] and len(robot_rows) == (robots != "none")
    for r in chain_rows + robot_rows:
        assert r["deviation"] < 1e-10  # Pinocchio timed on the same tree: its ÿ is ours
        assert 0 < r["ctypes_us"] < r["mbsfmu_us"] and r["pin_us"] > 0 and r["c_us"] > 0
        assert r["mbsfmu_median_us"] >= r["mbsfmu_us"] and r["pin_median_us"] >= r["pin_us"]
    assert all(r["rss_mb"] >= r["rss_python_mb"] > 10 for r in chain_rows)
    with open(tmp_path / "tree_speed_chains.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["n"]) for r in rows] == [12] and float(rows[0]["ratio"]) > 0
    text = (tmp_path / "tree_speed.md").read_text()
    assert "| 12 |" in text and "Target N = 100" in text and "tree_speed.png" in text
    if robot_rows:
        assert "solo12.urdf | free | 18 |" in text
    assert (tmp_path / "tree_speed.png").stat().st_size > 10_000


def test_growth_exponent_of_power_laws():
    rows = [{"n": n, "mbsfmu_us": 2e-3 * n ** 3, "pin_us": 0.1 * n} for n in (10, 100, 1000, 3000)] + [{"n": 10000, "refused": "too big"}]
    s = tree_speed.slope(rows)
    assert (s["from"], s["to"]) == (100, 3000)
    assert s["mbsfmu"] == pytest.approx(3) and s["pinocchio"] == pytest.approx(1)
