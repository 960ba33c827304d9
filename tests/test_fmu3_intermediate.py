"""FMI 3.0 co-simulation intermediate update (fmi/fmi3.c over the engine's step observer, mbs_set_step_observer).

References: scipy's DOP853 at rtol 1e-12 over the in-process right-hand side (the values read in the callback are
the integrator's internal points); the FMI 2.0 native FMU of the same scene, which never observes (outputs bit for
bit); the FMI 3.0 standard's intermediate update mode (times inside the step, reading only the variables marked
intermediateUpdate="true", every other call refused), also under AddressSanitizer and UBSan. Skipped without a C
compiler.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.fmi3 import FMU3Slave  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

import mbsfmu  # noqa: E402
from mbsfmu.fmu import native  # noqa: E402
from mbsfmu.simulation import Simulation  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODEL = "double_pendulum"
SCENE = mbsfmu.load(REPO / "models" / f"{MODEL}.yaml")

pytestmark = pytest.mark.skipif(native.compiler() is None, reason="no C compiler (cc, gcc, clang or $CC)")


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """(FMI 3 FMU, FMI 2 FMU) of the double pendulum, linux only."""
    out = tmp_path_factory.mktemp("iu")
    with pytest.MonkeyPatch.context() as mp, warnings.catch_warnings():
        mp.setattr(native, "MINGW", "no-mingw-for-these-tests")
        warnings.simplefilter("ignore", RuntimeWarning)  # "no binaries/win64"
        with ThreadPoolExecutor(2) as pool:
            jobs = [pool.submit(mbsfmu.build_fmu, SCENE, out / v, kind="native", fmi=v) for v in ("3", "2")]
            return tuple(j.result() for j in jobs)


def _slave(fmu, cls, name):
    md = read_model_description(str(fmu))
    return cls(guid=md.guid, unzipDirectory=extract(str(fmu)), modelIdentifier=md.coSimulation.modelIdentifier,
               instanceName=name), md


def _marked(fmu):
    """{name: intermediateUpdate attribute} of the modelDescription's variables (fmpy does not read it)."""
    root = ET.fromstring(zipfile.ZipFile(fmu).read("modelDescription.xml"))
    return {v.get("name"): v.get("intermediateUpdate") == "true" for v in root.find("ModelVariables")}


def _size(v):
    return int(np.prod(v.shape)) if v.shape else 1


def _observed(fmu, method, options, h, n):
    """Run n steps of h with the method; per step the callback's (t, flags, states, outputs) and the outputs read
    after the step."""
    s, md = _slave(fmu, FMU3Slave, "observed")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    outs = [v for v in md.modelVariables if v.causality == "output"]
    states = [v.valueReference for v in outs if v.name.startswith(("y.", "yd."))]
    ovr, nout = [v.valueReference for v in outs], sum(map(_size, outs))
    seen = []

    def update(env, t, set_requested, get_allowed, finished, can_return_early, early, early_time):
        seen[-1].append((t, (set_requested, get_allowed, finished, can_return_early),
                         s.getFloat64(states, len(states)), s.getFloat64(ovr, nout), s.getFloat64([vr["time"]])[0]))

    s.instantiate(intermediateUpdate=update)
    s.setString([vr["integrator.method"]], [method])
    for k, v in options.items():
        s.setFloat64([vr[f"integrator.{k}"]], [v])
    s.enterInitializationMode()
    s.exitInitializationMode()
    x0 = s.getFloat64(states, len(states))
    after = []
    for k in range(n):
        seen.append([])
        s.doStep(k * h, h)
        after.append(s.getFloat64(ovr, nout))
    s.terminate()
    s.freeInstance()
    return seen, after, x0


def _reference(x0, ts):
    """[y; ẏ] at the times ts from x0 at 0: scipy's DOP853 at rtol 1e-12 over the in-process right-hand side."""
    sim = Simulation(json.loads(json.dumps(SCENE.spec)))
    sol = solve_ivp(sim.f, (0.0, ts[-1]), np.array(x0, float), method="DOP853", rtol=1e-12, atol=1e-14,
                    dense_output=True)
    return sol.sol(ts).T


METHODS = [("dopri5", {"rtol": 1e-8}, None), ("dop853", {"rtol": 1e-9}, None), ("radau5", {"rtol": 1e-8}, None),
           ("auto", {"rtol": 1e-8}, None), ("rk4", {"step": 0.002}, 50), ("gen_alpha", {"step": 0.0005}, 200)]


@pytest.mark.parametrize("method,options,per_step", METHODS, ids=[m for m, _, _ in METHODS])
def test_callback_reports_each_internal_step_and_the_end(built, method, options, per_step):
    """After every accepted internal step strictly inside fmi3DoStep and at its end, at increasing times, with the
    flags of a finished step that allows reading only; the states read there are the trajectory's at that time
    (to the method's accuracy), the end's outputs are what the host reads after the step."""
    h, n = 0.1, 4
    seen, after, x0 = _observed(built[0], method, options, h, n)
    times = [t for step in seen for t, *_ in step]
    assert np.all(np.diff(times) > 0), method
    for k, step in enumerate(seen):
        t0, t1 = k * h, (k + 1) * h
        ts = [t for t, *_ in step]
        assert ts[-1] == t1 and all(t0 < t < t1 for t in ts[:-1]), (method, k, ts)
        assert len(ts) >= 3 and (per_step is None or len(ts) == per_step), (method, k, len(ts))
        assert step[-1][3] == after[k], method  # the end: what the host reads after the step
        for t, flags, _, _, time in step:
            assert flags == (False, True, True, False) and time == t, (method, flags)
    t = np.array(times)
    got = np.array([x for step in seen for _, _, x, _, _ in step])
    ref = _reference(x0, t)
    scale = np.ptp(ref, axis=0)
    err = np.abs(got - ref).max(axis=0) / scale
    assert err.max() < 1e-5, (method, err)
    # an internal point's outputs are its own, not the step's end: they move within a step
    assert all(len({tuple(o) for _, _, _, o, _ in step}) == len(step) for step in seen), method


def test_without_callback_nothing_changes(built):
    """The outputs after each step are bit for bit the FMI 2.0 FMU's (same engine, no observer), with no callback
    and with one that reads every output at every internal point."""
    fmu3, fmu2 = built
    h, n = 0.05, 20
    _, observed, _ = _observed(fmu3, "dopri5", {}, h, n)
    rows = {}
    for label in ("fmi3", "fmi2"):
        s, md = _slave(fmu3 if label == "fmi3" else fmu2, FMU3Slave if label == "fmi3" else FMU2Slave, label)
        outs = [v for v in md.modelVariables if v.causality == "output"]
        s.instantiate()
        if label == "fmi3":
            s.setString([next(v.valueReference for v in md.modelVariables if v.name == "integrator.method")],
                        ["dopri5"])
            s.enterInitializationMode()
            s.exitInitializationMode()
            get = lambda: s.getFloat64([v.valueReference for v in outs], sum(map(_size, outs)))  # noqa: E731
        else:
            s.setupExperiment(startTime=0.0)
            s.enterInitializationMode()
            s.exitInitializationMode()
            get = lambda: s.getReal([v.valueReference for v in outs])  # noqa: E731
        rows[label] = []
        for k in range(n):
            s.doStep(k * h, h)
            rows[label].append(list(get()))
        s.terminate()
        s.freeInstance()
    assert rows["fmi3"] == observed == rows["fmi2"]


def test_only_outputs_are_marked(built):
    md = read_model_description(str(built[0]))
    marked = _marked(built[0])
    assert {n for n, m in marked.items() if m} == {v.name for v in md.modelVariables if v.causality == "output"}
    assert md.coSimulation.providesIntermediateUpdate and not md.coSimulation.canReturnEarlyAfterIntermediateUpdate


CHILD = r'''
import ctypes, json, sys
lib = ctypes.CDLL(sys.argv[1]); RES, TOKEN = sys.argv[2].encode(), sys.argv[3].encode()
OUT, NOUT, INPUT, PARAM, DER, NVAR = map(int, sys.argv[4:10])
B, D, P, U, S, C = ctypes.c_bool, ctypes.c_double, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_size_t, ctypes.c_char_p
LOG = ctypes.CFUNCTYPE(None, P, ctypes.c_int, C, C)
UPDATE = ctypes.CFUNCTYPE(None, P, D, B, B, B, B, ctypes.POINTER(B), ctypes.POINTER(D))
messages = []
logger = LOG(lambda env, st, cat, msg: messages.append([st, msg.decode()]))
def sig(name, res, *args):
    f = getattr(lib, name); f.restype = res; f.argtypes = list(args); return f
new = sig("fmi3InstantiateCoSimulation", P, C, C, C, B, B, B, B, P, S, P, LOG, UPDATE)
enter = sig("fmi3EnterInitializationMode", int, P, B, D, D, B, D)
exit_ = sig("fmi3ExitInitializationMode", int, P)
step = sig("fmi3DoStep", int, P, D, D, B, ctypes.POINTER(B), ctypes.POINTER(B), ctypes.POINTER(B), ctypes.POINTER(D))
getf = sig("fmi3GetFloat64", int, P, ctypes.POINTER(U), S, ctypes.POINTER(D), S)
setf = sig("fmi3SetFloat64", int, P, ctypes.POINTER(U), S, ctypes.POINTER(D), S)
getst = sig("fmi3GetFMUState", int, P, ctypes.POINTER(P))
term = sig("fmi3Terminate", int, P)
reset = sig("fmi3Reset", int, P)
free = sig("fmi3FreeInstance", None, P)
dirder = sig("fmi3GetDirectionalDerivative", int, P, ctypes.POINTER(U), S, ctypes.POINTER(U), S, ctypes.POINTER(D), S,
             ctypes.POINTER(D), S)
def vrs(*v): return (U * len(v))(*v)
def dbl(n): return (D * n)()
flags = [B() for _ in range(3)]; last = D()
def do_step(c, t, h): return step(c, t, h, True, *[ctypes.byref(b) for b in flags], ctypes.byref(last))
calls = {"DoStep": lambda c: do_step(c, 0.0, 0.01),
         "SetFloat64 of an input": lambda c: setf(c, vrs(INPUT), 1, dbl(1), 1),
         "GetFloat64 of a parameter": lambda c: getf(c, vrs(PARAM), 1, dbl(1), 1),
         "GetFloat64 of a derivative": lambda c: getf(c, vrs(DER), 1, dbl(1), 1),
         "GetFMUState": lambda c: getst(c, ctypes.byref(P())),
         "GetDirectionalDerivative": lambda c: dirder(c, vrs(OUT), 1, vrs(OUT), 1, dbl(1), 1, dbl(1), 1),
         "Terminate": lambda c: term(c), "Reset": lambda c: reset(c),
         "EnterInitializationMode": lambda c: enter(c, False, 0.0, 0.0, False, 0.0),
         "FreeInstance": lambda c: free(c)}
out, box = {}, {}
def hostile(env, t, *rest):
    c = box["a"]
    if out: return
    for name, call in calls.items():
        n0 = len(messages); out[name] = [call(c), messages[n0:]]
    ok = dbl(NOUT); out["outputs readable"] = getf(c, vrs(*range(OUT, OUT + NOUT)), NOUT, ok, NOUT)
cb = UPDATE(hostile)
box["a"] = a = new(b"a", TOKEN, RES, False, False, False, False, None, 0, None, logger, cb)
twin = new(b"twin", TOKEN, RES, False, False, False, False, None, 0, None, logger, UPDATE())
for c in (a, twin): assert enter(c, False, 0.0, 0.0, False, 0.0) == 0 and exit_(c) == 0
rows = []
for k in range(10):
    assert do_step(a, 0.01 * k, 0.01) == 0 and do_step(twin, 0.01 * k, 0.01) == 0, messages[-3:]
    r = [dbl(NOUT), dbl(NOUT)]
    for c, v in zip((a, twin), r): getf(c, vrs(*range(OUT, OUT + NOUT)), NOUT, v, NOUT)
    rows.append(list(r[0]) == list(r[1]))
out["same as twin"] = all(rows)
free(a); free(twin)
print("RESULT " + json.dumps(out))
'''


@pytest.mark.parametrize("build", ["shipped", "sanitized"])
def test_hostile_calls_in_the_callback_are_errors(built, tmp_path, build):
    """Inside the callback every call but reading an intermediate variable (and logging switches) is fmi3Error
    with a message naming intermediate update mode, nothing changes (FreeInstance: refused, logged), and the
    instance steps on exactly like an untouched twin without a callback (a NULL one); the same on the FMU's
    sources/ built with AddressSanitizer and UBSan, which report nothing."""
    fmu = built[0]
    d = tmp_path / "fmu"
    zipfile.ZipFile(fmu).extractall(d)
    md = read_model_description(str(fmu))
    vs = [v for v in md.modelVariables if v.name != "time"]
    out_vrs = sorted(v.valueReference for v in vs if v.causality == "output")
    first = lambda pred: next(v.valueReference for v in vs if pred(v))  # noqa: E731
    args = [out_vrs[0], sum(_size(v) for v in vs if v.causality == "output"), first(lambda v: v.causality == "input"),
            first(lambda v: v.causality == "parameter" and v.type == "Float64"),
            first(lambda v: v.derivative is not None), len(vs)]
    assert out_vrs == list(range(out_vrs[0], out_vrs[0] + len(out_vrs)))
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    from test_fmu3 import fmu_library  # as shipped, or sources/ with ASan + UBSan
    lib, env = fmu_library(d, md, tmp_path, build)
    r = subprocess.run([sys.executable, str(script), str(lib), str(d / "resources") + os.sep, md.guid,
                        *map(str, args)], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, (r.returncode, r.stdout[-3000:], r.stderr[-3000:])
    assert "runtime error" not in r.stderr and "AddressSanitizer" not in r.stderr, r.stderr[-3000:]
    out = json.loads(r.stdout.split("RESULT ", 1)[1])
    assert out.pop("same as twin") is True
    assert out.pop("outputs readable") == 0
    free = out.pop("FreeInstance")
    assert free[0] is None and "intermediate update mode" in free[1][-1][1], free
    for name, (status, logged) in out.items():
        assert status == 3, (name, status, logged)  # fmi3Error
        assert logged and logged[-1][0] == 3 and "intermediate" in logged[-1][1], (name, logged)
