"""Native FMUs (`kind="native"`): the C engine + fmi/fmi2.c, no Python at run time.

References: `mbsfmu.simulate` (in-process engine) and fmpy for the numbers; the FMI 2.0 standard for the
state machine and the state functions; a C host (tests/c/fmu_host.c) in a mount namespace where no Python
installation is visible; ecos (a C++ host); the FMU's own sources/ compiled by this test.
Skipped without a C compiler.
"""
from __future__ import annotations

import ctypes
import glob
import os
import re
import shutil
import struct
import subprocess
import sys
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import (FMU2Slave, calloc, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,  # noqa: E402
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, free)
from fmpy.validation import validate_fmu  # noqa: E402

import mbsfmu  # noqa: E402
from mbsfmu.fmu import native  # noqa: E402
from mbsfmu.simulation import Simulation  # noqa: E402


REPO = Path(__file__).resolve().parents[1]
HOST = REPO / "tests" / "c" / "fmu_host.c"
MODELS = [p.stem for p in sorted((REPO / "models").glob("*.yaml"))]
ELASTIC = {m for m in MODELS if any(b.get("elastic") for b in mbsfmu.load(REPO / "models" / f"{m}.yaml").spec["bodies"])}
STEPS = 50

pytestmark = pytest.mark.skipif(native.compiler() is None, reason="no C compiler (cc, gcc, clang or $CC)")


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """{model: native FMU path} for every shipped model, rigid and elastic."""
    out = tmp_path_factory.mktemp("native")
    return {m: mbsfmu.build_fmu(REPO / "models" / f"{m}.yaml", out, kind="native") for m in MODELS}


@pytest.fixture(scope="module")
def host(tmp_path_factory):
    exe = tmp_path_factory.mktemp("host") / "fmu_host"
    subprocess.run([native.compiler(), "-O2", "-o", str(exe), str(HOST), "-ldl"], check=True)
    return exe


# ---- fmpy helpers: a logger that sees the formatted messages --------------------------------------------
class Log:
    """Messages (instance, status, category, text) of every instance, through fmpy's vararg-formatting
    proxy (which keeps one logger per process: hence one collector, filtered by instance name)."""

    messages: list = []

    def __init__(self):
        from fmpy.logging import addLoggerProxy
        self.cb = fmi2CallbackFunctions()
        self._logger = fmi2CallbackLoggerTYPE(
            lambda env, name, status, cat, msg: Log.messages.append((name.decode(), status, cat.decode(),
                                                                    msg.decode())))
        self.cb.logger = self._logger
        self.cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self.cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(ctypes.byref(self.cb))

    @staticmethod
    def of(name):
        return [m[1:] for m in Log.messages if m[0] == name]


_LOG = None


def callbacks():
    global _LOG
    _LOG = _LOG or Log()
    return _LOG.cb


def open_fmu(fmu, where, tag):
    md = read_model_description(str(fmu))
    d = Path(extract(str(fmu), str(Path(where) / tag))).resolve()
    f = FMU2Slave(guid=md.guid, unzipDirectory=str(d), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=tag)
    f.instantiate(callbacks=callbacks())
    type(f).log = property(lambda self: Log.of(self.instanceName))
    f.vr = {v.name: v.valueReference for v in md.modelVariables}
    f.outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    return f


def start(f, **reals):
    for k, v in reals.items():
        f.setReal([f.vr[k]], [v])
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    return f


def run(f, t, n, h=0.01, q=None):
    """n steps from t (t accumulated as ecos does); rows of all outputs."""
    rows = []
    for _ in range(n):
        if q:
            f.setReal([f.vr[q]], [0.3 * np.sin(5 * t)])
        f.doStep(t, h)
        t += h
        rows.append(f.getReal(f.outputs))
    return t, rows


def fails(status, call, *args):
    with pytest.raises(FMICallException) as e:
        call(*args)
    assert e.value.status == status, e.value
    return e.value


# ---- every shipped model ----------------------------------------------------------------------------
@pytest.mark.parametrize("model", MODELS)
def test_validates_and_equals_in_process_run(built, model):
    fmu = built[model]
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    outs = [v.name for v in md.modelVariables if v.causality == "output"]
    exp = md.defaultExperiment
    stop = min(float(exp.stopTime), 200 * float(exp.stepSize))
    res = simulate_fmu(str(fmu), stop_time=stop, output_interval=float(exp.stepSize), output=outs)
    t, Y, YD = mbsfmu.simulate(mbsfmu.load(REPO / "models" / f"{model}.yaml"), stop=stop)
    assert np.allclose(res["time"], t, rtol=0, atol=1e-12)
    X = np.hstack([Y, YD])
    F = np.column_stack([res[n] for n in [n for n in outs if n.startswith("y.")] +
                         [n for n in outs if n.startswith("yd.")]])
    scale = np.maximum(np.max(np.abs(X), axis=0), 1.0)
    assert np.all(np.abs(F - X) <= 1e-12 * scale), np.max(np.abs(F - X) / scale)
    assert np.ptp(X, axis=0).max() > 1e-3  # the run moves


def test_one_writer_for_both_kinds(built, tmp_path):
    """Same variables, units, structure, experiment, categories; <CoSimulation> differs as listed, and the native
    kind adds model exchange: its derivative variables (and their units) after the rest, the states as the
    outputs' dependencies, <Derivatives>, the derivatives among the initial unknowns."""
    py = mbsfmu.build_fmu(REPO / "models" / "double_pendulum.yaml", tmp_path)
    a = ET.fromstring(zipfile.ZipFile(built["double_pendulum"]).read("modelDescription.xml"))
    b = ET.fromstring(zipfile.ZipFile(py).read("modelDescription.xml"))
    for tag in ("LogCategories", "DefaultExperiment"):
        assert ET.tostring(a.find(tag)) == ET.tostring(b.find(tag)), tag
    for tag in ("UnitDefinitions", "ModelVariables"):  # the pythonfmu kind's, then the derivatives'
        ours, theirs = list(a.find(tag)), list(b.find(tag))
        assert [ET.tostring(e).strip() for e in ours[:len(theirs)]] == [ET.tostring(e).strip() for e in theirs], tag
    derivatives = [i + 1 for i, e in enumerate(a.find("ModelVariables")) if e.get("name").startswith("der(")]
    assert len(derivatives) == len(a.find("ModelVariables")) - len(b.find("ModelVariables")) == 4
    assert [u.get("index") for u in a.find("ModelStructure/Outputs")] == \
        [u.get("index") for u in b.find("ModelStructure/Outputs")]
    assert [int(u.get("index")) for u in a.find("ModelStructure/Derivatives")] == derivatives
    assert [int(u.get("index")) for u in a.find("ModelStructure/InitialUnknowns")] == \
        [int(u.get("index")) for u in b.find("ModelStructure/InitialUnknowns")] + derivatives
    assert b.find("ModelStructure/Derivatives") is None and b.find("ModelExchange") is None
    ca, cb = a.find("CoSimulation"), b.find("CoSimulation")
    assert {k for k in ca.attrib if ca.attrib[k] != cb.attrib.get(k)} <= set(native.COSIMULATION)
    assert ca.attrib["needsExecutionTool"] == "false" and ca.attrib["canSerializeFMUstate"] == "true"
    listed = [f.get("name") for f in ca.find("SourceFiles")]
    names = zipfile.ZipFile(built["double_pendulum"]).namelist()
    assert "fmi2.c" in listed and all(f"sources/{n}" in names for n in listed)
    assert sorted(n[8:] for n in names if n.startswith("sources/") and n.endswith(".c")) == sorted(listed)
    # and the same numbers (both kinds run the engine)
    outs = [e.get("name") for e in a.find("ModelVariables") if e.get("causality") == "output"]
    ra, rb = (simulate_fmu(str(x), stop_time=1.0, output_interval=0.01, output=outs,
                           start_values={"q.phi1": 0.5}) for x in (built["double_pendulum"], py))
    A, B = (np.column_stack([r[n] for n in outs]) for r in (ra, rb))
    assert np.all(np.abs(A - B) <= 1e-12 * np.maximum(np.abs(B).max(axis=0), 1.0)), np.abs(A - B).max()


def test_binary_depends_on_libc_and_libm_only_and_exports_fmi_only(built, tmp_path):
    so = tmp_path / "m.so"
    so.write_bytes(zipfile.ZipFile(built["double_pendulum"]).read("binaries/linux64/double_pendulum.so"))
    if shutil.which("readelf") is None:
        pytest.skip("readelf not installed")
    dyn = subprocess.run(["readelf", "-d", "-W", str(so)], capture_output=True, text=True, check=True).stdout
    needed = {ln.split("[")[1].rstrip("]") for ln in dyn.splitlines() if "(NEEDED)" in ln}
    assert needed <= {"libc.so.6", "libm.so.6"} and "libc.so.6" in needed, needed
    syms = subprocess.run(["readelf", "--dyn-syms", "-W", str(so)], capture_output=True, text=True,
                          check=True).stdout
    exported = {ln.split()[-1] for ln in syms.splitlines()
                if " FUNC " in ln and " GLOBAL " in ln and " UND " not in ln}
    assert exported and all(s.startswith("fmi2") for s in exported), exported
    assert {"fmi2Instantiate", "fmi2DoStep", "fmi2SerializeFMUstate", "fmi2GetTypesPlatform"} <= exported


def test_only_elastic_scenes_carry_elastic_code(built):
    assert ELASTIC and len(ELASTIC) < len(MODELS)
    for m, fmu in built.items():
        names = zipfile.ZipFile(fmu).namelist()
        assert ("sources/elastic.c" in names) == (m in ELASTIC), m
        assert f"binaries/linux64/{fmu.stem}.so" in names and "resources/scene.bin" in names


@pytest.mark.parametrize("method", ["dopri5", "radau5"])
def test_a_force_changing_every_step_meets_the_tolerance(built, method):
    """fmpy pushes cart_pole's cart with a force resampled at every point (held over the step). Reference: scipy's
    DOP853 at rtol 1e-12 on the engine's right-hand side with the same held force, interval by interval. Each
    restart used to be interpolated in a dense step far past the point: radau5 was 200× its tolerance off."""
    from scipy.integrate import solve_ivp
    h, n = 0.01, 100
    ts = h * np.arange(n + 1)
    force = 2 * np.sin(7 * ts) + (ts >= 0.5)
    sim = Simulation(mbsfmu.load(REPO / "models" / "cart_pole.yaml").spec)
    sim.initialize(0.0)
    ref = [sim.x]
    for k in range(n):
        sim.set("F_cart.x", force[k])
        ref.append(solve_ivp(sim.f, ts[k:k + 2], ref[-1], method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1])
    ref = np.array(ref)
    names = ["q.x", "q.phi", "F_cart.x", "F_cart.y", "F_cart.z"]
    signal = np.array([(t, 0, 0, f, 0, 0) for t, f in zip(ts, force)],
                      dtype=[("time", float)] + [(m, float) for m in names])
    outs = ["y.x", "y.phi", "yd.x", "yd.phi"]
    for rtol in (1e-6, 1e-9):
        res = simulate_fmu(str(built["cart_pole"]), stop_time=n * h, output_interval=h, input=signal, output=outs,
                           start_values={"integrator.method": method, "integrator.rtol": rtol,
                                         "integrator.atol": 1e-2 * rtol})
        err = np.abs(np.column_stack([res[o] for o in outs]) - ref)
        assert np.all(err <= 10 * (rtol * np.max(np.abs(ref), axis=0) + 1e-2 * rtol)), (rtol, err.max(axis=0))


# ---- FMU state ----------------------------------------------------------------------------------------------
def test_state_rollback_and_fresh_instance_bit_identical(built, tmp_path):
    fmu = built["double_pendulum"]
    f = start(open_fmu(fmu, tmp_path, "a"))
    t, _ = run(f, 0.0, 30, q="q.phi1")
    state = f.getFMUstate()
    blob = f.serializeFMUstate(state)
    t1, first = run(f, t, 40, q="q.phi1")
    f.setFMUstate(state)
    t2, again = run(f, t, 40, q="q.phi1")
    assert t1 == t2 and first == again
    g = open_fmu(fmu, tmp_path, "b")  # fresh instance, not initialized
    s = g.deSerializeFMUstate(blob)
    g.setFMUstate(s)  # an initialized state brings step mode with it (as in the pythonfmu kind): no initialization
    _, fresh = run(g, t, 40, q="q.phi1")
    assert fresh == first
    assert np.ptp(np.array(first), axis=0).max() > 0.01
    for x, st in ((f, state), (g, s)):
        x.freeFMUstate(st)
        x.terminate()
        x.freeInstance()


def _bad_states(good, foreign):
    corrupt = bytearray(good)
    corrupt[len(good) // 2] ^= 0x40  # one bit in the payload
    header = bytearray(good)
    header[4] += 1  # format version
    return {"corrupt": bytes(corrupt), "truncated": good[:-8], "extended": good + b"\0" * 8,
            "version": bytes(header), "foreign": foreign, "empty": b"", "garbage": os.urandom(len(good))}


def test_corrupt_truncated_foreign_state_refused_instance_unchanged(built, tmp_path):
    f = start(open_fmu(built["double_pendulum"], tmp_path, "a"))
    ref = start(open_fmu(built["double_pendulum"], tmp_path, "ref"))
    other = start(open_fmu(built["pendulum"], tmp_path, "other"))
    t, _ = run(f, 0.0, 20, q="q.phi1")
    run(ref, 0.0, 20, q="q.phi1")
    run(other, 0.0, 20)
    s = f.getFMUstate()
    good = f.serializeFMUstate(s)
    so = other.getFMUstate()
    foreign = other.serializeFMUstate(so)
    for what, data in _bad_states(good, foreign).items():
        n = len(f.log)
        fails(3, f.deSerializeFMUstate, data)
        assert len(f.log) > n and f.log[-1][:2] == (3, "logStatusError"), (what, f.log[n:])
    assert f.log[-1][2]  # a message, e.g. "... another model ..."
    assert any("another model" in m for *_, m in f.log), f.log
    _, mine = run(f, t, 30, q="q.phi1")
    _, theirs = run(ref, t, 30, q="q.phi1")
    assert mine == theirs  # unchanged, bit for bit
    for x in (f, ref, other):
        x.terminate()
        x.freeInstance()


# ---- the FMI 2.0 state machine and error reporting ----------------------------------------------------------
def test_wrong_call_order_is_refused_with_a_message(built, tmp_path):
    f = open_fmu(built["double_pendulum"], tmp_path, "a")
    fails(3, f.doStep, 0.0, 0.01)                 # before initialization
    fails(3, f.exitInitializationMode)            # without enter
    fails(3, f.terminate)                         # not initialized
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    fails(3, f.enterInitializationMode)           # twice
    fails(3, f.setupExperiment, None, 0.0)        # too late
    fails(3, f.doStep, 0.0, 0.01)                 # still in initialization mode
    f.exitInitializationMode()
    fails(3, f.setReal, [f.outputs[0]], [1.0])    # an output
    fails(3, f.setReal, [10_000], [1.0])          # unknown value reference
    fails(3, f.getReal, [10_000])
    fails(3, f.getInteger, [0])                   # no Integer variables
    fails(3, f.setString, [f.vr["integrator.method"]], ["rk4"])  # fixed after initialization
    fails(3, f.doStep, 0.5, 0.01)                 # not the current time
    f.doStep(0.0, 0.01)                           # the refusals changed nothing
    f.terminate()
    fails(3, f.terminate)                         # twice
    fails(3, f.doStep, 0.01, 0.01)                # after terminate
    fails(3, f.setReal, [f.vr["q.phi1"]], [1.0])
    assert f.getReal([f.vr["y.phi1"]])            # reading is allowed
    errors = [m for s, c, m in f.log if s == 3 and c == "logStatusError"]
    # one message per refusal above (15); the log may hold earlier tests' too
    assert len(errors) >= 15 and any("not allowed in phase 'terminated'" in m for m in errors), errors
    f.reset()                                     # back to instantiated
    start(f)
    f.doStep(0.0, 0.01)
    f.terminate()
    f.freeInstance()


def test_nan_input_discards_the_step_with_a_logged_message(built, tmp_path):
    f = start(open_fmu(built["double_pendulum"], tmp_path, "a"))
    ref = start(open_fmu(built["double_pendulum"], tmp_path, "ref"))
    t, _ = run(f, 0.0, 10)
    run(ref, 0.0, 10)
    y = f.getReal(f.outputs)
    for bad in (float("nan"), float("inf")):
        f.setReal([f.vr["q.phi1"]], [bad])
        fails(2, f.doStep, t, 0.01)
        assert f.log[-1][:2] == (2, "logStatusDiscard") and "not finite" in f.log[-1][2], f.log[-1]
        assert f.getReal(f.outputs) == y  # stays at the last good point
    f.setReal([f.vr["q.phi1"]], [0.0])
    _, a = run(f, t, 10)
    _, b = run(ref, t, 10)
    assert a == b
    for x in (f, ref):
        x.terminate()
        x.freeInstance()


@pytest.mark.parametrize("setting", [("integrator.method", "euler"), ("integrator.rtol", -1.0)])
def test_bad_integrator_setting_fails_exit_of_initialization(built, tmp_path, setting):
    name, value = setting
    f = open_fmu(built["double_pendulum"], tmp_path, "a")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    # the engine refuses it at once (outside its domain), and initialization cannot go on without it
    fails(3, f.setString if isinstance(value, str) else f.setReal, [f.vr[name]], [value])
    fails(3, f.exitInitializationMode)
    assert f.log[-1][:2] == (3, "logStatusError") and f.log[-1][2], f.log
    fails(3, f.doStep, 0.0, 0.01)  # error phase: no steps
    f.reset()
    start(f)
    f.doStep(0.0, 0.01)
    f.freeInstance()


def test_bad_method_then_good_method_initializes(built, tmp_path):
    f = open_fmu(built["double_pendulum"], tmp_path, "a")
    vr = f.vr["integrator.method"]
    fails(3, f.setString, [vr], ["euler"])
    f.setString([vr], ["rk4"])
    start(f)
    assert f.getString([vr]) == [b"rk4"]
    f.freeInstance()


def test_instantiate_failures_are_logged_not_crashes(built, tmp_path):
    fmu = built["pendulum"]
    md = read_model_description(str(fmu))
    d = Path(extract(str(fmu), str(tmp_path / "dir with space %41"))).resolve()
    lib = ctypes.CDLL(str(d / "binaries" / "linux64" / "pendulum.so"))
    lib.fmi2Instantiate.restype = ctypes.c_void_p
    lib.fmi2Instantiate.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_char_p,
                                    ctypes.c_void_p, ctypes.c_int, ctypes.c_int]
    lib.fmi2FreeInstance.argtypes = [ctypes.c_void_p]
    res = d / "resources"
    guid = md.guid.encode()
    name = f"x{os.getpid()}".encode()

    def inst(uri, g=guid, kind=1, cb=ctypes.byref(callbacks())):
        c = lib.fmi2Instantiate(name, kind, g, uri, cb, 0, 0)
        if c:
            lib.fmi2FreeInstance(c)
        return bool(c)

    quoted = res.as_uri()  # percent-escaped: ' ' -> %20, '%' -> %25
    assert "%20" in quoted and "%25" in quoted
    for ok in (quoted, quoted + "/", "file://localhost" + quoted[7:], "file:" + quoted[7:]):
        assert inst(ok.encode()), (ok, Log.of(name.decode()))
    assert not Log.of(name.decode())
    def last():
        return Log.of(name.decode())[-1][2]

    for bad, why in ((b"http://host/x", "not a file URI"), (b"file://elsewhere/x", "local absolute path"),
                     (str(res).encode(), "not a file URI"),  # FMI 2.0: a URI, not a path
                     ((d / "nothing").as_uri().encode(), "cannot load"), (quoted.encode() + b"%4", "percent")):
        assert not inst(bad) and why in last(), (bad, last())
    assert not inst(quoted.encode(), g=b"{not-the-guid}") and "does not match" in last()
    assert not inst(quoted.encode(), kind=2) and "neither fmi2ModelExchange nor fmi2CoSimulation" in last()
    assert not inst(quoted.encode(), cb=None)  # no callbacks: NULL, nothing to call
    log = Log.of(name.decode())
    assert len(log) == 7 and all(s == 3 and c == "logStatusError" for s, c, _ in log)


def test_null_pointers_and_sizes_do_not_crash(built, tmp_path):
    f = start(open_fmu(built["pendulum"], tmp_path, "a"))
    lib, c = f.dll, f.component
    P = ctypes.c_void_p
    for name, args in (("fmi2GetReal", (c, None, 3, None)), ("fmi2SetReal", (c, None, 1, None)),
                       ("fmi2GetString", (c, None, 1, None)), ("fmi2SetFMUstate", (c, None)),
                       ("fmi2GetFMUstate", (c, None)), ("fmi2SerializedFMUstateSize", (c, None, None)),
                       ("fmi2DeSerializeFMUstate", (c, None, 5, None)), ("fmi2DoStep", (None, 0.0, 0.1, 1)),
                       ("fmi2SetDebugLogging", (c, 1, 1, None)), ("fmi2GetDirectionalDerivative", (c, None, 2, None, 1, None, None))):
        fn = getattr(lib, name)
        fn.restype = ctypes.c_int
        fn.argtypes = [P] + [ctypes.c_double if isinstance(a, float) else ctypes.c_size_t if isinstance(a, int) else P
                             for a in args[1:]]
        assert fn(*args) == 3, name
    lib.fmi2FreeInstance.argtypes = [P]
    lib.fmi2FreeInstance(None)
    f.setDebugLogging(True, ["logAll"])
    fails(3, f.setDebugLogging, True, ["noSuchCategory"])
    f.doStep(0.0, 0.01)
    f.terminate()
    f.freeInstance()


def test_many_instances_in_one_process_are_independent(built, tmp_path):
    fmu = built["pendulum"]
    fs = [start(open_fmu(fmu, tmp_path, f"i{k}")) for k in range(4)]
    q = next(v for k, v in fs[0].vr.items() if k.startswith("q."))
    for k, f in enumerate(fs):
        f.setReal([q], [(0.0, 0.1, 0.2, 0.3)[k]])
    ts = [0.0] * 4
    for _ in range(20):  # interleaved
        for k, f in enumerate(fs):
            f.doStep(ts[k], 0.01)
            ts[k] += 0.01
    rows = [f.getReal(f.outputs) for f in fs]
    alone = start(open_fmu(fmu, tmp_path, "alone"))
    alone.setReal([q], [0.3])
    t = 0.0
    for _ in range(20):
        alone.doStep(t, 0.01)
        t += 0.01
    assert alone.getReal(alone.outputs) == rows[3]
    assert len({tuple(r) for r in rows}) == 4
    for f in fs + [alone]:
        f.freeInstance()


# ---- plain C host without Python, ecos, sources/ ------------------------------------------------------------
def _unpack(fmu, where):
    md = read_model_description(str(fmu))
    d = Path(extract(str(fmu), str(where))).resolve()
    outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    return d, md, outs


def _host_rows(stdout):
    rows = [list(map(float, ln.split()[1:])) for ln in stdout.splitlines() if ln.startswith("OUT ")]
    return np.array(rows)


def _fmpy_rows(fmu, tmp_path, n, h):
    f = start(open_fmu(fmu, tmp_path, "fmpy"))
    t, rows = 0.0, [[0.0] + f.getReal(f.outputs)]
    for _ in range(n):
        f.doStep(t, h)
        t += h
        rows.append([t] + f.getReal(f.outputs))
    f.terminate()
    f.freeInstance()
    return np.array(rows)


def _python_dirs():
    """Installation prefixes of every Python this machine has (to hide them)."""
    dirs = {sys.prefix, sys.base_prefix, sys.exec_prefix, os.path.dirname(os.path.dirname(sys.executable))}
    dirs |= set(glob.glob("/usr/lib/python3*")) | set(glob.glob("/usr/local/lib/python3*"))
    dirs |= {os.environ.get("PYENV_ROOT") or os.path.expanduser("~/.pyenv")}
    dirs = sorted(os.path.realpath(d) for d in dirs if d not in ("/", "/usr", "/usr/local") and os.path.isdir(d))
    return [d for d in dirs if not any(d.startswith(o + "/") for o in dirs)]  # outermost only


def run_without_python(runs, tmp_path):
    """Run each command of `runs` ({key: argv}) in one user+mount namespace where every Python installation is
    hidden and no Python on PATH starts; {key: its standard output}, in the order of `runs`. Skips where no such
    namespace can be made."""
    keys = list(runs)
    empty = tmp_path / "empty"
    empty.mkdir()
    script = "".join(f'mount --bind "{empty}" "{p}" || exit 97\n' for p in _python_dirs()) + \
        f'"{sys.executable}" -c pass 2>/dev/null && exit 98\n' \
        'for p in python3 python; do command -v $p >/dev/null && $p -c pass 2>/dev/null && exit 98; done\n' + \
        "".join(f'echo "RUN {i}"; ' + " ".join(f'"{a}"' for a in runs[k]) + " || exit 96\n" for i, k in enumerate(keys))
    r = subprocess.run(["unshare", "-rm", "sh", "-c", script], capture_output=True, text=True,
                       env={"PATH": "/usr/bin:/bin"}, timeout=300)
    if r.returncode == 97 or (r.returncode == 1 and r.stderr.startswith("unshare")):
        pytest.skip(f"no user+mount namespace here: {r.stderr.strip()[:200]}")
    assert r.returncode == 0, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    parts = re.split(r"^RUN (\d+)\n", r.stdout, flags=re.M)[1:]
    assert [int(i) for i in parts[::2]] == list(range(len(keys))), r.stdout[-2000:]
    return dict(zip(keys, parts[1::2]))


def test_plain_c_host_without_python_equals_fmpy(built, host, tmp_path):
    """Every shipped model's native FMU in a plain C host, in one mount namespace where every Python
    installation is hidden (and no libpython is mapped): the same numbers as fmpy, bit for bit."""
    runs = {}
    for m in MODELS:
        d, md, outs = _unpack(built[m], tmp_path / m)
        lib = d / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
        runs[m] = [str(host), str(lib), (d / "resources").as_uri(), md.guid,
                   "-o", ",".join(map(str, outs)), "-n", str(STEPS), "-h", "0.01", "-p", "-m"]
    chunks = run_without_python(runs, tmp_path)
    for m, out in chunks.items():
        assert "LIBPYTHON no" in out and "DONE" in out, m
        rows = _host_rows(out)
        ref = _fmpy_rows(built[m], tmp_path / f"fmpy_{m}", STEPS, 0.01)
        assert rows.shape == ref.shape and rows.tolist() == ref.tolist(), m  # bit for bit (%.17g round-trips)
        assert np.ptp(rows[:, 1:], axis=0).max() > 1e-3, m  # it moved


@pytest.mark.parametrize("model", ["double_pendulum", "robot_arm_elastic"])
def test_ecos_runs_the_native_fmu(built, tmp_path, model):
    from test_fmu_hosts import _clean_env, _ecos_binary
    exe, why = _ecos_binary(tmp_path, "ecos")
    if exe is None:
        pytest.skip(why)
    fmu = built[model]
    work = tmp_path / "run"
    work.mkdir()
    r = subprocess.run([str(exe), "simulate", "--path", str(fmu), "--stopTime", str(STEPS * 0.01), "--stepSize",
                        "0.01", "--noParallel"], cwd=work, env=_clean_env(), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-2000:])
    lines = (work / f"{fmu.stem}.csv").read_text().splitlines()
    header = [h.strip() for h in lines[0].split(",")]
    md = read_model_description(str(fmu))
    names = [v.name for v in md.modelVariables if v.causality == "output"]
    cols = [header.index(f"instance::{n}[REAL]") for n in names]
    ref = _fmpy_rows(fmu, tmp_path, STEPS, 0.01)
    data = [[c.strip() for c in ln.split(",")] for ln in lines[1:]]
    assert len(data) >= STEPS - 1
    for k, row in enumerate(data):  # ecos prints %f: compare the printed digits
        assert [row[c] for c in cols] == [f"{v:f}" for v in ref[k, 1:]], k


def test_sources_compile_into_an_equal_library(built, host, tmp_path):
    fmu = built["double_pendulum"]
    d, md, outs = _unpack(fmu, tmp_path / "x")
    src = d / "sources"
    fresh = tmp_path / "fresh.so"
    # the README's command line: no -D flags, only the files of sources/
    subprocess.run([native.compiler(), "-O2", "-std=c99", "-shared", "-fPIC", "-fvisibility=hidden", f"-I{src}",
                    "-o", str(fresh), *map(str, sorted(src.glob("*.c"))), "-lm"], check=True)
    shipped = d / "binaries/linux64/double_pendulum.so"
    common = [(d / "resources").as_uri(), md.guid, "-o", ",".join(map(str, outs)), "-n", "30", "-p"]
    a = subprocess.run([str(host), str(shipped), *common], capture_output=True, text=True, check=True).stdout
    b = subprocess.run([str(host), str(fresh), *common], capture_output=True, text=True, check=True).stdout
    assert _host_rows(a).tolist() == _host_rows(b).tolist() and len(_host_rows(a)) == 31
    listed = [f.get("name") for f in ET.fromstring((d / "modelDescription.xml").read_bytes())
              .find("CoSimulation").find("SourceFiles")]
    assert sorted(listed) == sorted(p.name for p in src.glob("*.c"))


@pytest.mark.slow
def test_sources_build_with_their_cmakelists(built, host, tmp_path):
    if shutil.which("cmake") is None or subprocess.run(["cmake", "--version"], capture_output=True).returncode:
        pytest.skip("cmake not installed")
    fmu = built["pendulum"]
    d, md, outs = _unpack(fmu, tmp_path / "x")
    b = tmp_path / "build"
    subprocess.run(["cmake", "-S", str(d / "sources"), "-B", str(b), "-DCMAKE_BUILD_TYPE=Release"], check=True,
                   capture_output=True)
    subprocess.run(["cmake", "--build", str(b)], check=True, capture_output=True)
    lib = b / "pendulum.so"
    assert lib.exists(), list(b.iterdir())
    common = [(d / "resources").as_uri(), md.guid, "-o", ",".join(map(str, outs)), "-n", "20", "-p"]
    a = subprocess.run([str(host), str(d / "binaries/linux64/pendulum.so"), *common], capture_output=True,
                       text=True, check=True).stdout
    c = subprocess.run([str(host), str(lib), *common], capture_output=True, text=True, check=True).stdout
    assert np.allclose(_host_rows(a), _host_rows(c), rtol=1e-13, atol=1e-13)


def test_win64_dll_when_mingw_is_installed(built):
    names = zipfile.ZipFile(built["pendulum"]).namelist()
    if shutil.which(native.MINGW) is None:
        assert "binaries/win64/pendulum.dll" not in names
        readme = zipfile.ZipFile(built["pendulum"]).read("sources/README").decode()
        assert native.MINGW in readme
        pytest.skip(f"{native.MINGW} not installed (gcc-mingw-w64-x86-64): no dll, the README says why")
    dll = zipfile.ZipFile(built["pendulum"]).read("binaries/win64/pendulum.dll")
    assert dll[:2] == b"MZ"
    pe = struct.unpack_from("<I", dll, 0x3C)[0]
    assert dll[pe:pe + 4] == b"PE\0\0" and struct.unpack_from("<H", dll, pe + 4)[0] == 0x8664  # x86-64
    assert b"fmi2DoStep" in dll and b"fmi2Instantiate" in dll  # export names


def test_win64_dll_runs_under_wine(built, host, tmp_path):
    """The win64 DLL of every shipped model, run under wine by the same C host built for Windows, gives the
    linux64 binary's numbers (another compiler and C library)."""
    if shutil.which(native.MINGW) is None or shutil.which("wine") is None:
        pytest.skip(f"needs {native.MINGW} (Debian gcc-mingw-w64-x86-64) and wine (Debian wine64)")
    exe = tmp_path / "fmu_host.exe"
    subprocess.run([native.MINGW, "-O2", "-D__USE_MINGW_ANSI_STDIO=1", "-o", str(exe), str(HOST)], check=True)
    env = {**os.environ, "WINEDEBUG": "-all", "WINEDLLOVERRIDES": "mscoree,mshtml="}  # no Mono/Gecko prompts
    for m, fmu in built.items():
        d, md, outs = _unpack(fmu, tmp_path / m)
        ident = md.coSimulation.modelIdentifier
        common = [(d / "resources").as_uri(), md.guid, "-o", ",".join(map(str, outs)), "-n", str(STEPS), "-h",
                  "0.01", "-p"]
        lin = subprocess.run([str(host), str(d / "binaries" / "linux64" / f"{ident}.so"), *common],
                             capture_output=True, text=True, check=True).stdout
        win = subprocess.run(["wine", str(exe), str(d / "binaries" / "win64" / f"{ident}.dll"), *common], env=env,
                             capture_output=True, text=True, timeout=300)
        assert win.returncode == 0 and "DONE" in win.stdout, (m, win.stdout[-2000:], win.stderr[-2000:])
        a, b = _host_rows(win.stdout), _host_rows(lin)
        assert a.shape == b.shape == (STEPS + 1, len(outs) + 1), m
        # each signal to 1e-12 of its largest value over the run (absolute 1e-12 below 1): elastic coordinates
        # (~1e-5 m) pass by that absolute slack, and a von Mises stress in Pa (~1e5) follows them, so where it is
        # small it differs as they do (fe_stress: 5e-12 relative at 6e3 Pa, 7e-14 of its largest value)
        scale = np.maximum(np.abs(b).max(axis=0), 1.0)
        assert np.all(np.abs(a - b) <= 1e-12 * (np.abs(b) + scale)), (m, np.max(np.abs(a - b) / scale))


def test_command_line_builds_native(tmp_path):
    from mbsfmu.cli import main
    assert main(["build", "--kind", "native", str(REPO / "models" / "pendulum.yaml"), "-o", str(tmp_path)]) == 0
    xml = ET.fromstring(zipfile.ZipFile(tmp_path / "pendulum.fmu").read("modelDescription.xml"))
    assert xml.find("CoSimulation").get("needsExecutionTool") == "false"
    r = subprocess.run([sys.executable, str(REPO / "build_fmu.py"), str(REPO / "models" / "pendulum.yaml"), "--kind",
                        "native", "-o", str(tmp_path / "b")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "binaries/linux64/pendulum.so" in zipfile.ZipFile(tmp_path / "b" / "pendulum.fmu").namelist()
    with pytest.raises(SystemExit) as e:
        main(["build", "--kind", "nonsense", str(REPO / "models" / "pendulum.yaml")])
    assert e.value.code == 2
    with pytest.raises(ValueError, match="unknown FMU kind"):
        mbsfmu.build_fmu(REPO / "models" / "pendulum.yaml", tmp_path, kind="nonsense")


def test_an_elastic_scene_on_the_recursive_path_equals_in_process_run(tmp_path):
    """An arm of three beams of 8 modes (27 coordinates: the compiler picks the articulated-body algorithm, elastic
    bodies as its nodes) as a native FMU under fmpy: the in-process run's y, ẏ to 1e-12."""
    from benchmarks.elastic_paths import arm
    from mbsfmu.compiler.scene_file import carriers, dense_path
    from mbsfmu.compiler.model import Model
    from mbsfmu.scene.load import Scene
    spec = arm(3, 8)
    assert not dense_path(Model(spec), carriers(Model(spec)))
    scene = Scene(spec, "arm.yaml", ())
    fmu = mbsfmu.build_fmu(scene, tmp_path, kind="native")
    assert validate_fmu(str(fmu)) == []
    outs = [v.name for v in read_model_description(str(fmu)).modelVariables if v.causality == "output"]
    res = simulate_fmu(str(fmu), stop_time=0.2, output_interval=0.01, output=outs)
    t, Y, YD = mbsfmu.simulate(scene, stop=0.2, step=0.01)
    assert np.allclose(res["time"], t, rtol=0, atol=1e-12)
    X = np.hstack([Y, YD])
    F = np.column_stack([res[n] for n in outs if n.startswith("y.")] + [res[n] for n in outs if n.startswith("yd.")])
    scale = np.maximum(np.max(np.abs(X), axis=0), 1.0)
    assert np.all(np.abs(F - X) <= 1e-12 * scale), np.max(np.abs(F - X) / scale)
    assert np.ptp(X, axis=0).max() > 1e-3  # the run moves
