"""Command line: subprocess runs (one-line errors, exit 1, no traceback), simulate with an input
CSV and a plot, crosscheck layout accepted by fmpy's cross-check validation, fmutool -check."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "models" / "double_pendulum.yaml"


def cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "mbsfmu.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=300, cwd=cwd)


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli")
    r = cli("build", MODEL, "-o", out)
    assert r.returncode == 0, r.stderr
    return out / "double_pendulum.fmu"


def test_help_has_examples():
    r = cli("--help")
    assert r.returncode == 0 and "examples:" in r.stdout and "crosscheck" in r.stdout


@pytest.mark.parametrize("args", [
    ("build", "nonexistent.yaml"),
    ("info", "nonexistent.fmu"),
    ("validate", "nonexistent.fmu"),
    ("simulate", "nonexistent.fmu"),
    ("check", "BROKEN"),
])
def test_errors_are_one_line(args, tmp_path):
    if args[-1] == "BROKEN":
        bad = tmp_path / "broken.yaml"
        bad.write_text("mbsfmu: 1\nname: broken\nbodies:\n  a: {parent: nowhere}\n")
        args = args[:-1] + (bad,)
    r = cli(*args, cwd=tmp_path)
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_build_progress_for_several_scenes(tmp_path):
    r = cli("build", REPO / "models" / "pendulum.yaml", MODEL, "-o", tmp_path)
    assert r.returncode == 0, r.stderr
    assert "[1/2]" in r.stdout and "[2/2]" in r.stdout
    assert (tmp_path / "double_pendulum.fmu").exists()


def test_simulate_with_input_and_plot(fmu, tmp_path):
    inp = tmp_path / "u.csv"
    inp.write_text("time,q.phi1\n0,0\n0.1,0.5\n0.2,0.5\n")
    png = tmp_path / "out.png"
    csv = tmp_path / "res.csv"
    r = cli("simulate", fmu, "--input", inp, "--stop", 0.2, "--plot", png, "--csv", csv)
    assert r.returncode == 0, r.stderr
    assert png.stat().st_size > 1000
    header = csv.read_text().splitlines()[0].split(",")
    assert header[0] == "time" and "y.phi1" in header and "yd.phi2" in header
    bad = tmp_path / "bad.csv"
    bad.write_text("time,nope\n0,1\n")
    r = cli("simulate", fmu, "--input", bad, "--stop", 0.1)
    assert r.returncode == 1 and "nope" in r.stderr and "Traceback" not in r.stderr


def test_info_and_validate(fmu):
    r = cli("info", fmu)
    assert r.returncode == 0 and "outputs" in r.stdout
    r = cli("validate", fmu)
    assert r.returncode == 0 and "valid" in r.stdout


def test_crosscheck_layout_validates(tmp_path):
    from fmpy.cross_check.validate_vendor_repo import validate_test_fmu
    d = tmp_path / "fmus" / "2.0" / "cs" / "linux64" / "mbsfmu" / "0.1.0" / "double_pendulum"
    r = cli("crosscheck", MODEL, "--out", d)
    assert r.returncode == 0, r.stderr
    for suffix in (".fmu", "_ref.csv", "_ref.opt", "_in.csv"):
        assert (d / f"double_pendulum{suffix}").is_file(), suffix
    assert validate_test_fmu(str(d)) == []


def test_fmutool_check(fmu):
    exe = shutil.which("fmutool")
    if exe is None:
        pytest.skip("fmu-manipulation-toolbox not installed")
    r = subprocess.run([exe, "-input", str(fmu), "-check"], capture_output=True, text=True, timeout=120)
    text = r.stdout + r.stderr
    assert r.returncode == 0, text
    assert "compliant with FMI-2.0" in text and "No semantic error" in text
    assert "ERROR" not in text.upper().replace("NO SEMANTIC ERROR", "")
