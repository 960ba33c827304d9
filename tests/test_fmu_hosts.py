"""Real-runtime FMU in real hosts: ecos vs fmpy (issue #5), state rollback / serialization into a
fresh instance, fmi2Reset, long runs with flat memory.

ecos is the C++ co-simulation engine of the PyPI wheel `ecospy` (0.7.x; Debian `libtbb12`).
Which host produces which numbers:

* test_ecospy_bit_identical_to_fmpy[proxyfmu]: the full-precision numbers come from ecos with the
  FMU in ecos's separate `proxyfmu` process (a C++ executable, so the FMU's shim loads libpython
  itself; the test checks that process's /proc entries: our copy of the binary, no PYTHON*/
  LD_PRELOAD/LD_LIBRARY_PATH in its environment, libpython mapped). The test process drives it
  through ecospy's C API: `EcosSimulation.step()` then `get_real("instance::<name>")` after every
  step, a plain C double (no text formatting anywhere).
* test_ecospy_bit_identical_to_fmpy[in-process]: the same API with a plain path URI; the FMU loads
  into this pytest process and uses its interpreter.
* Reference for both: fmpy's FMU2Slave in this process, driven on ecos's time grid. ecos's
  fixed_step_algorithm calls fmi2DoStep(t, h) with h the constant step and t accumulated
  (t += h, so t_50 = 0.5000000000000002); it sets no input it was not told to (inputs keep their
  start values), like this reference. Result: bit-identical, every output, every step.
  fmpy's `simulate_fmu` is NOT bit-identical (measured max |diff| 1.2e-14 on outputs of size ~3,
  test bound 1e-12 relative): it steps from t_k = k*h with h_k = (k+1)*h - k*h, which differs
  from 0.01 in the last bit for 48 of the 50 steps, so the integrator aims at slightly different
  end times.
* test_libcosim_bit_identical_to_fmpy[<model>-<kind>]: a third host, OSP's libcosim through its Python binding
  libcosimpy (PyPI; the wheel ships libcosimc and its own FMI Library), runs every shipped model's native and
  pythonfmu FMU in this process. Full precision: a last-value observer's fmi2GetReal after every step. libcosim
  keeps time in integer nanoseconds and hands the FMU t_k = to_double(k·Δ) and h = t_(k+1) − t_k (its
  to_double_time_point / to_double_duration); fmpy's FMU2Slave stepped on that grid gives the same outputs,
  bit for bit (on the ecos grid, t += 0.01, they differ by ~2e-15).
* test_ecos_cli_matches_to_the_last_printed_digit: the `ecos simulate` command line in a
  subprocess with a clean environment (no PYTHONPATH/PYTHONHOME/LD_PRELOAD) is the non-Python
  host case. Its CSV cannot carry full precision: ecos's csv_writer prints reals with
  std::to_string (printf "%f", 6 decimals, no option for more) and the time with the stream
  default (6 significant digits). So the test asserts that every printed cell equals the
  reference value formatted the same way (exact string equality: the CLI's doubles print exactly
  like the bit-identical values) instead of comparing to 5e-7. The CLI stops at t = 0.49 for
  stopTime 0.5: its loop runs while sim.time() + stepSize <= stopTime, and
  0.49000000000000027 + 0.01 > 0.5.
"""
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

ECOS_STEPS = 50  # 0.5 s


def _ecos_binary(dest, name):
    """A copy of the wheel's `name` executable (ecos, proxyfmu) in dest, or (None, skip reason)."""
    try:
        import ecospy  # noqa: F401  (loads libecosc.so: OSError without libtbb)
    except (ImportError, OSError) as exc:
        return None, f"ecospy not usable ({exc}); pip install ecospy, apt-get install libtbb12"
    import importlib.util
    bindir = Path(importlib.util.find_spec("ecospy").origin).parent / "binaries"
    src = bindir / name
    if not src.exists():
        return None, f"no {name} binary in {bindir}"
    exe = Path(dest) / name
    shutil.copy(src, exe)  # the wheel ships them without the executable bit
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    ldd = subprocess.run(["ldd", str(exe)], capture_output=True, text=True)
    missing = [ln.split()[0] for ln in ldd.stdout.splitlines() if "not found" in ln]
    if missing:
        return None, f"{name} needs {', '.join(missing)} (Debian: apt-get install libtbb12)"
    return exe, None


def _host_env_vars():
    return [k for k in os.environ
            if k.startswith("PYTHON") or k in ("LD_PRELOAD", "LD_LIBRARY_PATH")]


def _clean_env():
    drop = set(_host_env_vars())
    return {k: v for k, v in os.environ.items() if k not in drop}


def _fmpy_on_grid(fmu_path, tmp_path, names, steps):
    """fmpy FMU2Slave: doStep(t, h) for each (t, h) of steps, no inputs set → (times, outputs) at the start and
    after each step."""
    f, vr = _open(fmu_path, tmp_path, "grid")
    _init(f)
    refs = [vr[k] for k in names]
    ts, rows = [0.0], [f.getReal(refs)]
    for t, h in steps:
        f.doStep(t, h)
        ts.append(t + h)
        rows.append(f.getReal(refs))
    f.terminate()
    f.freeInstance()
    return np.array(ts), np.array(rows)


def _fmpy_on_ecos_grid(fmu_path, tmp_path, names, n):
    """fmpy FMU2Slave stepped exactly like ecos: doStep(t, STEP), t += STEP."""
    steps, t = [], 0.0
    for _ in range(n):
        steps.append((t, STEP))
        t += STEP
    return _fmpy_on_grid(fmu_path, tmp_path, names, steps)


def _child_processes(exe):
    """/proc directories of this process's children running the executable exe."""
    me, out = os.getpid(), []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            if ppid == me and os.readlink(d / "exe") == str(exe):
                out.append(d)
        except (OSError, ValueError, IndexError):
            continue
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="linux host test")
@pytest.mark.parametrize("where", ["proxyfmu", "in-process"])
def test_ecospy_bit_identical_to_fmpy(fmu, tmp_path, monkeypatch, where):
    names = _outputs(fmu)
    uri = str(fmu)
    if where == "proxyfmu":
        proxy, why = _ecos_binary(tmp_path, "proxyfmu")
        if proxy is None:
            pytest.skip(why)
        # ecos starts "./proxyfmu" from the working directory (or next to /proc/self/exe, here the
        # python binary) and passes this process's environment on: give it a clean one.
        monkeypatch.chdir(tmp_path)
        for k in _host_env_vars():
            monkeypatch.delenv(k)
        uri = f"proxyfmu://localhost?file={fmu}"
    else:
        _, why = _ecos_binary(tmp_path, "ecos")
        if why is not None:
            pytest.skip(why)
    from ecospy import EcosSimulation, EcosSimulationStructure

    ts, rows = [], []
    with EcosSimulationStructure() as ss:
        ss.add_model("instance", uri)
        with EcosSimulation(structure=ss, step_size=STEP) as sim:
            assert sim.init()
            if where == "proxyfmu":  # the FMU really runs in the proxyfmu process, clean env
                procs = _child_processes(proxy)
                assert len(procs) == 1, procs
                env = (procs[0] / "environ").read_bytes().split(b"\0")
                assert not [e for e in env if e.startswith((b"PYTHON", b"LD_PRELOAD=",
                                                            b"LD_LIBRARY_PATH="))]
                assert "libpython" in (procs[0] / "maps").read_text()
            for k in range(ECOS_STEPS + 1):
                if k:
                    sim.step()
                ts.append(sim.get_time())
                rows.append([sim.get_real(f"instance::{name}") for name in names])
            sim.terminate()
    ts, rows = np.array(ts), np.array(rows)

    ref_t, ref = _fmpy_on_ecos_grid(fmu, tmp_path, names, ECOS_STEPS)
    assert ts.tolist() == ref_t.tolist()  # same communication points, bit for bit
    assert rows.tolist() == ref.tolist()  # same outputs, bit for bit
    assert np.ptp(rows, axis=0).min() > 0.1  # the run really moves

    # fmpy's simulate_fmu: same step count, last-bit different step sizes (module docstring)
    res = simulate_fmu(str(fmu), stop_time=ECOS_STEPS * STEP, step_size=STEP,
                       output_interval=STEP, output=names)
    assert len(res) == ECOS_STEPS + 1
    np.testing.assert_allclose(res["time"], ts, rtol=0, atol=1e-15)
    sim_f = np.column_stack([res[name] for name in names])
    scale = np.max(np.abs(rows), axis=0)
    assert np.all(np.abs(sim_f - rows) <= 1e-12 * scale), np.max(np.abs(sim_f - rows))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="linux host test")
def test_ecos_cli_matches_to_the_last_printed_digit(fmu, tmp_path):
    exe, why = _ecos_binary(tmp_path, "ecos")
    if exe is None:
        pytest.skip(why)
    work = tmp_path / "run"
    work.mkdir()
    stop = ECOS_STEPS * STEP
    r = subprocess.run([str(exe), "simulate", "--path", str(fmu), "--stopTime", str(stop),
                        "--stepSize", str(STEP), "--noParallel"],
                       cwd=work, env=_clean_env(), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-2000:])
    out = work / f"{fmu.stem}.csv"
    assert out.exists(), r.stdout[-2000:]
    with out.open() as fh:
        rows = list(csv.reader(fh))
    header = [h.strip() for h in rows[0]]
    data = [[c.strip() for c in row] for row in rows[1:]]
    # sim.time() + stepSize <= stopTime with accumulated time: 49 steps, rows for t = 0 .. 0.49
    assert len(data) == ECOS_STEPS

    names = _outputs(fmu)
    ref_t, ref = _fmpy_on_ecos_grid(fmu, tmp_path, names, ECOS_STEPS)
    cols = [header.index(f"instance::{name}[REAL]") for name in names]
    for k, row in enumerate(data):
        assert row[0] == str(k)
        assert row[1] == f"{ref_t[k]:g}"  # ostream default: 6 significant digits
        # std::to_string(double) == printf("%f"): both round the exact binary value correctly
        assert [row[c] for c in cols] == [f"{v:f}" for v in ref[k]], k


# ---- FMU state with the real runtime -------------------------------------------------------------

# ---- libcosim (libcosimpy) -------------------------------------------------------------------------

MODELS = sorted((REPO / "models").glob("*.yaml"))
COSIM_STEP_NS = 10_000_000  # libcosim's step, integer nanoseconds (0.01 s)


def _libcosim():
    """libcosimpy's modules, or skip (not installed, or its libcosimc does not load here)."""
    try:
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
        from libcosimpy.CosimObserver import CosimObserver
        from libcosimpy.CosimSlave import CosimLocalSlave
        log_output_level(CosimLogLevel.ERROR)  # its FMI Library logs every load at debug level
    except (ImportError, OSError) as exc:
        pytest.skip(f"libcosimpy not usable ({exc}); pip install libcosimpy")
    return CosimExecution, CosimLocalSlave, CosimObserver


def _libcosim_grid(n):
    """(t, h) of each fmi2DoStep libcosim makes: its integer-nanosecond time points as doubles (ns / 1e9, what
    std::chrono's duration<double> makes of them) and h the difference of two of them."""
    t = [k * COSIM_STEP_NS * 1.0 / 1e9 for k in range(n + 1)]
    return [(t[k], t[k + 1] - t[k]) for k in range(n)]


@pytest.mark.parametrize("kind", ["native", "pythonfmu"])
@pytest.mark.parametrize("model", MODELS, ids=lambda p: p.stem)
def test_libcosim_bit_identical_to_fmpy(model, kind, tmp_path):
    import mbsfmu
    CosimExecution, CosimLocalSlave, CosimObserver = _libcosim()
    if kind == "native":
        from mbsfmu.fmu import native
        if native.compiler() is None:
            pytest.skip("no C compiler (cc, gcc, clang or $CC)")
    fmu = mbsfmu.build_fmu(model, tmp_path / kind, kind=kind)
    md = read_model_description(str(fmu))
    names = [v.name for v in md.modelVariables if v.causality == "output"]
    vrs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    execution = CosimExecution.from_step_size(COSIM_STEP_NS)
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name="instance"))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    times, rows = [], []
    for _ in range(ECOS_STEPS):
        assert execution.step(), execution.status().error_code
        times.append(execution.status().current_time)
        rows.append(observer.last_real_values(index, vrs))
    del execution  # frees the instance (fmi2FreeInstance) before the reference's

    grid = _libcosim_grid(ECOS_STEPS)
    assert times == [COSIM_STEP_NS * (k + 1) for k in range(ECOS_STEPS)]
    _, ref = _fmpy_on_grid(fmu, tmp_path, names, grid)
    rows = np.array(rows)
    assert rows.tolist() == ref[1:].tolist()  # same outputs, bit for bit, after every step
    assert np.ptp(np.vstack([ref[:1], rows]), axis=0).max() > 1e-3  # the run really moves


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
