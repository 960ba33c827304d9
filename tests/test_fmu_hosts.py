"""Real-runtime FMU in real hosts: ecos (C++ co-simulation engine, subprocess, no LD_PRELOAD),
state rollback / serialization into a fresh instance, fmi2Reset, long runs with flat memory."""
from __future__ import annotations

import csv
import os
import shutil
import stat
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "models" / "double_pendulum.yaml"
STEP = 0.01


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    import mbsfmu
    return mbsfmu.build_fmu(MODEL, tmp_path_factory.mktemp("hosts"))


def _open(fmu_path, tmp_path, tag):
    md = read_model_description(str(fmu_path))
    d = fmpy.extract(str(fmu_path), str(tmp_path / tag))
    f = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=tag)
    f.instantiate(loggingOn=False)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    return f, vr


def _init(f, t0=0.0):
    f.setupExperiment(startTime=t0)
    f.enterInitializationMode()
    f.exitInitializationMode()


def _outputs(fmu_path):
    md = read_model_description(str(fmu_path))
    return [v.name for v in md.modelVariables if v.causality == "output"]


# ---- ecos --------------------------------------------------------------------------------------

def _ecos(tmp_path):
    """The `ecos` command-line engine from the ecospy wheel, or a skip reason."""
    try:
        import ecospy  # noqa: F401
    except ImportError:
        return None, "ecospy not installed (pip install ecospy)"
    import importlib.util
    spec = importlib.util.find_spec("ecospy")
    bindir = Path(spec.origin).parent / "binaries"
    src = bindir / "ecos"
    if not src.exists():
        return None, f"no ecos binary in {bindir}"
    exe = tmp_path / "ecos"
    shutil.copy(src, exe)  # the wheel ships it without the executable bit
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    ldd = subprocess.run(["ldd", str(exe)], capture_output=True, text=True)
    missing = [ln.split()[0] for ln in ldd.stdout.splitlines() if "not found" in ln]
    if missing:
        return None, f"ecos needs {', '.join(missing)} (Debian: apt-get install libtbb12)"
    return exe, None


def _clean_env():
    return {k: v for k, v in os.environ.items()
            if not k.startswith("PYTHON") and k not in ("LD_PRELOAD", "LD_LIBRARY_PATH")}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="linux host test")
def test_ecos_subprocess_matches_fmpy(fmu, tmp_path):
    exe, why = _ecos(tmp_path)
    if exe is None:
        pytest.skip(why)
    work = tmp_path / "run"
    work.mkdir()
    stop = 0.5
    r = subprocess.run([str(exe), "simulate", "--path", str(fmu), "--stopTime", str(stop),
                        "--stepSize", str(STEP), "--noParallel"],
                       cwd=work, env=_clean_env(), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-2000:])
    out = work / f"{fmu.stem}.csv"
    assert out.exists(), r.stdout[-2000:]
    with out.open() as fh:
        rows = list(csv.reader(fh))
    header = [h.strip() for h in rows[0]]
    data = rows[1:]
    res = simulate_fmu(str(fmu), stop_time=stop, step_size=STEP, output_interval=STEP,
                       output=_outputs(fmu))
    worst = 0.0
    for name in _outputs(fmu):
        col = header.index(f"instance::{name}[REAL]")
        t_e = np.array([float(row[1]) for row in data])
        y_e = np.array([float(row[col]) for row in data])
        y_f = np.interp(t_e, res["time"], res[name])
        worst = max(worst, float(np.max(np.abs(y_e - y_f))))
    # ecos's CSV writer prints 6 decimals: equality up to rounding (the C host test below checks
    # all 17 digits through the same shim)
    assert len(data) >= int(stop / STEP)
    assert worst <= 5.1e-7, worst


# ---- FMU state with the real runtime -------------------------------------------------------------

def _run(f, vr, t, n, names=("y.phi1", "y.phi2", "yd.phi1", "yd.phi2")):
    out = []
    for _ in range(n):
        f.setReal([vr["q.phi1"]], [0.3 * np.sin(5 * t)])
        f.doStep(t, STEP)
        t += STEP
        out.append(f.getReal([vr[k] for k in names]))
    return t, out


def test_rollback_is_bit_identical_and_state_restores_in_fresh_instance(fmu, tmp_path):
    f, vr = _open(fmu, tmp_path, "a")
    _init(f)
    t, _ = _run(f, vr, 0.0, 30)
    state = f.getFMUstate()
    blob = f.serializeFMUstate(state)
    t1, first = _run(f, vr, t, 40)
    f.setFMUstate(state)
    t2, again = _run(f, vr, t, 40)
    assert t1 == t2 and first == again  # bit-identical, integrator history included
    # a FRESH instance (other unpack directory) restores the serialized state
    g, vg = _open(fmu, tmp_path, "b")
    _init(g)
    s = g.deSerializeFMUstate(blob)
    g.setFMUstate(s)
    _, fresh = _run(g, vg, t, 40)
    assert fresh == first
    g.freeFMUstate(s)
    f.freeFMUstate(state)
    for x in (f, g):
        x.terminate()
        x.freeInstance()


def test_reset_returns_to_start(fmu, tmp_path):
    f, vr = _open(fmu, tmp_path, "r")
    _init(f)
    _, first = _run(f, vr, 0.0, 20)
    f.reset()
    assert f.getReal([vr["y.phi1"]])[0] == pytest.approx(first[0][0], abs=0.1)  # start value again
    _init(f)
    _, again = _run(f, vr, 0.0, 20)
    assert again == first
    f.terminate()
    f.freeInstance()


def test_ten_thousand_steps_flat_memory(fmu, tmp_path):
    f, vr = _open(fmu, tmp_path, "m")
    _init(f)
    t = 0.0
    h = 1e-4  # short steps: the FMI layer, not the integration, dominates
    def rss():
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    for _ in range(1000):  # warm up caches
        f.doStep(t, h)
        t += h
    tracemalloc.start()
    r0, (m0, _) = rss(), tracemalloc.get_traced_memory()
    for i in range(10000):
        f.setReal([vr["q.phi1"]], [0.0])
        f.doStep(t, h)
        t += h
        f.getReal([vr["y.phi1"], vr["y.phi2"]])
    m1, _ = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    r1 = rss()
    assert m1 - m0 < 2_000_000, m1 - m0
    assert r1 - r0 < 20_000_000, r1 - r0
    f.terminate()
    f.freeInstance()
