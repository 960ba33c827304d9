"""Hostile hosts against the pythonfmu FMU (issue 12, items 2-3): the loader shim (fmu/shim.c) refuses bad calls
with fmi2Error and a logged message before pythonfmu 0.7.0 sees them (pythonfmu would answer fmi2Fatal, release the
instance's Python objects and crash the host a few calls later).

Every hostile sequence runs in a child process (fmpy's FMU2Slave, or a C host): a crash fails the test instead of
killing pytest. The children print one JSON line; the checks are against the FMI 2.0 rules (status codes, calling
sequence) and against an untouched twin instance (bit-identical outputs after the hostile calls).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import mbsfmu
from mbsfmu.fmu import build

REPO = Path(__file__).resolve().parents[1]
CC = shutil.which("cc") or shutil.which("gcc")
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux") or CC is None,
                                reason="the loader shim is built for linux64 with a C compiler")

# ---- the child processes (here and tests/test_hostile_extra.py): fmpy's low-level API, a logger that keeps every
# message, the FMI call helpers; each driver script appends its own part ----------------------------------------
FMPY_CHILD = r'''
import ctypes, json, math, os, pickle, random, struct, sys
import fmpy
from fmpy import read_model_description, calloc, free
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2CallbackAllocateMemoryTYPE,
                       fmi2CallbackFreeMemoryTYPE, fmi2FMUstate)
from fmpy.fmi1 import FMICallException
from fmpy.logging import addLoggerProxy

LOG = []
cb = fmi2CallbackFunctions()
cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, st, cat, msg: LOG.append((name.decode(errors="replace"), st,
                                                                              (cat or b"").decode(),
                                                                              msg.decode(errors="replace"))))
cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
addLoggerProxy(ctypes.byref(cb))   # fmpy's proxy formats the messages like a C host does


def init(s):
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()


def status(call, *args):
    try:
        r = call(*args)
        return 0 if r is None or not isinstance(r, int) else r
    except FMICallException as e:
        return e.status


def logged(tag, since):
    return [m[1:] for m in LOG[since:] if m[0] == tag]


def steps(s, t, n, h=0.01):
    for _ in range(n):
        s.doStep(t, h)
        t += h
    return t
'''

DRIVER = FMPY_CHILD + r'''
scenario, fmu, other, work = sys.argv[1:5]


def open_fmu(path, tag):
    md = read_model_description(path)
    d = fmpy.extract(path, os.path.join(work, tag))
    s = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier, instanceName=tag)
    s.instantiate(callbacks=cb)
    return s, {v.name: v.valueReference for v in md.modelVariables}, md, d


def outputs(s, md):
    return s.getReal([v.valueReference for v in md.modelVariables if v.causality == "output"])


def calls_with_messages(tag, calls):
    """[(status, [(status, category, message) logged by this call])] for calls = [(fn, args)]"""
    out = []
    for fn, args in calls:
        n = len(LOG)
        out.append((status(fn, *args), logged(tag, n)))
    return out


def scenario_refs():
    a, vr, md, _ = open_fmu(fmu, "a")
    b, _, _, _ = open_fmu(fmu, "b")
    init(a), init(b)
    t = steps(a, 0.0, 5)
    steps(b, 0.0, 5)
    nv = len(md.modelVariables)
    real = [v.valueReference for v in md.modelVariables if v.type == "Real"]
    string = [v.valueReference for v in md.modelVariables if v.type == "String"]
    outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    fixed = [v.valueReference for v in md.modelVariables if v.variability == "fixed" and v.type == "Real"]
    rng = random.Random(12)
    unknown = lambda: rng.choice([nv, nv + 1, rng.randrange(nv, 2**32), 2**32 - 1])
    makers = [
        lambda: (a.getReal, ([unknown()],)),
        lambda: (a.setReal, ([unknown()], [1.0])),
        lambda: (a.setReal, ([real[0], unknown()], [123.0, 1.0])),   # one bad reference: nothing is set
        lambda: (a.getInteger, ([rng.choice(real)],)),
        lambda: (a.getBoolean, ([rng.choice(real)],)),
        lambda: (a.setInteger, ([rng.choice(real)], [1])),
        lambda: (a.setBoolean, ([rng.choice(real)], [True])),
        lambda: (a.setReal, ([rng.choice(string)], [1.0])),
        lambda: (a.getString, ([rng.choice(real)],)),
        lambda: (a.getString, ([nv],)),   # the slave's hidden variable is not the host's
        lambda: (a.setString, ([rng.choice(real)], ["x"])),
        lambda: (a.setReal, ([rng.choice(outs)], [0.5])),
        lambda: (a.setReal, ([rng.choice(fixed)], [1e-3])),   # fixed parameter after initialization
        lambda: (a.setString, ([rng.choice(string)], ["rk4"])),
        lambda: (a.fmi2GetReal, (a.component, None, 3, None)),
        lambda: (a.fmi2SetReal, (a.component, None, 2, None)),
    ]
    calls = [makers[i % len(makers)]() for i in range(100)]
    result = calls_with_messages("a", calls)
    param0 = a.getReal([real[0]])[0] == b.getReal([real[0]])[0]
    steps(a, t, 20), steps(b, t, 20)
    return {"calls": result, "param_unchanged": param0, "a": outputs(a, md), "b": outputs(b, md)}


def scenario_order():
    a, vr, md, _ = open_fmu(fmu, "a")
    b, _, _, _ = open_fmu(fmu, "b")
    inp = [v.valueReference for v in md.modelVariables if v.causality == "input"]
    out = [v.valueReference for v in md.modelVariables if v.causality == "output"][:1]
    rs = ctypes.c_double()
    seq = [
        ("doStep before initialization", a.doStep, (0.0, 0.01)),
        ("exit before enter", a.exitInitializationMode, ()),
        ("terminate before initialization", a.terminate, ()),
        ("status before initialization", a.fmi2GetRealStatus, (a.component, 2, ctypes.byref(rs))),
        ("enter", a.enterInitializationMode, ()),
        ("setupExperiment in initialization mode", a.setupExperiment, ()),
        ("enter twice", a.enterInitializationMode, ()),
        ("doStep in initialization mode", a.doStep, (0.0, 0.01)),
        ("exit", a.exitInitializationMode, ()),
        ("enter after initialization", a.enterInitializationMode, ()),
        ("cancelStep", a.fmi2CancelStep, (a.component,)),
        ("doStep", a.doStep, (0.0, 0.01)),
        ("terminate", a.terminate, ()),
        ("terminate twice", a.terminate, ()),
        ("doStep after terminate", a.doStep, (0.01, 0.01)),
        ("set input after terminate", a.setReal, (inp, [0.0] * len(inp))),
        ("getReal after terminate", a.getReal, (out,)),
        ("reset", a.reset, ()),
        ("doStep after reset", a.doStep, (0.0, 0.01)),
        ("setupExperiment after reset", a.setupExperiment, ()),
        ("enter after reset", a.enterInitializationMode, ()),
        ("exit after reset", a.exitInitializationMode, ()),
        ("doStep after re-initialization", a.doStep, (0.0, 0.01)),
    ]
    result = [(what,) + r for (what, fn, args), r in zip(seq, calls_with_messages("a", [(f, x) for _, f, x in seq]))]
    init(b)
    b.doStep(0.0, 0.01)
    same = a.getReal(out) == b.getReal(out)
    old = a.component
    a.fmi2FreeInstance(old)   # the raw call: fmpy's freeInstance would also dlclose
    foreign = ctypes.create_string_buffer(256)
    after = [status(a.fmi2DoStep, old, 0.0, 0.01, 1),
             status(a.fmi2GetReal, old, (ctypes.c_uint * 1)(0), 1, (ctypes.c_double * 1)()),
             status(a.fmi2Reset, old), status(a.fmi2DoStep, None, 0.0, 0.01, 1),
             status(a.fmi2EnterInitializationMode, None),
             status(a.fmi2DoStep, ctypes.addressof(foreign), 0.0, 0.01, 1),
             status(a.fmi2SetupExperiment, None, 0, 0.0, 0.0, 0, 0.0)]
    a.fmi2FreeInstance(old)   # twice: ignored
    a.fmi2FreeInstance(None)
    b.doStep(0.01, 0.01)
    return {"sequence": result, "reset_equals_fresh": same, "after_free": after, "b_alive": outputs(b, md)}


def header(guid, payload, version=1):
    h = 1469598103934665603
    for x in payload:
        h = ((h ^ x) * 1099511628211) % 2**64
    g = guid.encode().ljust(64, b"\0")
    return b"MBSS" + struct.pack("<I", version) + g + struct.pack("<QQ", len(payload), h) + payload


class Marker:
    def __reduce__(self):
        return (open, (os.path.join(work, "PWNED"), "w"))


def serialized(s):
    st = s.getFMUstate()
    data = bytes(s.serializeFMUstate(st))
    s.freeFMUstate(st)
    return data


def scenario_states():
    a, vr, md, _ = open_fmu(fmu, "a")
    b, _, _, _ = open_fmu(fmu, "b")
    c, _, _, _ = open_fmu(other, "c")
    for s in (a, b, c):
        init(s)
    t = steps(a, 0.0, 10)
    steps(b, 0.0, 10)
    steps(c, 0.0, 3)
    good = serialized(a)
    payload = good[88:]
    rng = random.Random(5)
    flip = bytearray(good)
    flip[100] ^= 1
    bad_method = bytearray(payload)
    bad_method[44:48] = struct.pack("<i", 99)   # Head.method out of range, checksum made to fit
    crafted = {
        "empty": b"", "random10": rng.randbytes(10), "random87": rng.randbytes(87), "random88": rng.randbytes(88),
        "random": rng.randbytes(len(good)), "truncated": good[:-1], "truncated_header": good[:60],
        "trailing": good + b"\0", "flipped": bytes(flip), "version": good[:4] + b"\2" + good[5:],
        "foreign": serialized(c), "guid": header("{00000000-0000-0000-0000-000000000000}", payload),
        "pickle": pickle.dumps(Marker()), "pickle_with_header": header(md.guid, pickle.dumps(Marker())),
        "bad_method": header(md.guid, bytes(bad_method)),
    }
    result = {}
    for name, data in crafted.items():
        n = len(LOG)
        handle = fmi2FMUstate()
        buf = ctypes.create_string_buffer(data, len(data))
        st = status(a.fmi2DeSerializeFMUstate, a.component, buf, len(data), ctypes.byref(handle))
        st_set = status(a.fmi2SetFMUstate, a.component, handle) if st == 0 else None
        if st == 0:
            a.fmi2FreeFMUstate(a.component, ctypes.byref(handle))
        result[name] = (st, st_set, logged("a", n))
    theirs, mine = b.getFMUstate(), a.getFMUstate()
    n = len(LOG)
    handles = {
        "made-up handle": status(a.fmi2SetFMUstate, a.component, fmi2FMUstate(0x1234560)),
        "another instance's handle": status(a.fmi2SetFMUstate, a.component, theirs),
        "free unknown handle": status(a.fmi2FreeFMUstate, a.component, ctypes.byref(fmi2FMUstate(0x1234560))),
        "serialize into a short buffer": status(a.fmi2SerializeFMUstate, a.component, mine,
                                                ctypes.create_string_buffer(8), 8),
    }
    handle_logs = logged("a", n)
    b.freeFMUstate(theirs)
    a.freeFMUstate(mine)
    # the checks do not refuse everything: a good state restores (a and b are both at t)
    ok = a.deSerializeFMUstate(good)
    a.setFMUstate(ok)
    a.freeFMUstate(ok)
    steps(a, t, 20), steps(b, t, 20)
    return {"crafted": result, "handles": handles, "handle_logs": handle_logs, "a": outputs(a, md),
            "b": outputs(b, md), "marker": os.path.exists(os.path.join(work, "PWNED"))}


def scenario_init():
    a, vr, md, _ = open_fmu(fmu, "a")
    bad_utf8 = (a.component, (ctypes.c_uint * 1)(vr["integrator.method"]), 1, (ctypes.c_char_p * 1)(b"rk\xff"))
    seq = [("not UTF-8", a.fmi2SetString, bad_utf8),
           ("bad method", a.setString, ([vr["integrator.method"]], ["bogus"])),
           ("setup", a.setupExperiment, ()),
           ("enter", a.enterInitializationMode, ()),
           ("exit", a.exitInitializationMode, ()),
           ("doStep after failed initialization", a.doStep, (0.0, 0.01)),
           ("getReal", a.getReal, ([vr["integrator.rtol"]],)),
           ("reset", a.reset, ()),
           ("setup", a.setupExperiment, ()),
           ("enter", a.enterInitializationMode, ()),
           ("exit", a.exitInitializationMode, ()),
           ("doStep", a.doStep, (0.0, 0.01))]
    first = [(what,) + r for (what, fn, args), r in zip(seq, calls_with_messages("a", [(f, x) for _, f, x in seq]))]
    b, vrb, _, _ = open_fmu(fmu, "b")
    p = [v.name for v in md.modelVariables if v.causality == "parameter" and v.variability == "tunable"][0]
    seq = [("setup", b.setupExperiment, ()), ("enter", b.enterInitializationMode, ()),
           ("infinite parameter", b.setReal, ([vrb[p]], [float("inf")])), ("exit", b.exitInitializationMode, ())]
    second = [(what,) + r for (what, fn, args), r in zip(seq, calls_with_messages("b", [(f, x) for _, f, x in seq]))]
    try:
        res = fmpy.simulate_fmu(fmu, stop_time=0.1, start_values={"integrator.method": "bogus"})
        simulate = f"returned {len(res)} rows"
    except Exception as exc:
        simulate = f"raised {exc}"
    return {"method": first, "parameter": second, "parameter_name": p, "simulate": simulate}


def scenario_fatal():
    a, vr, md, d = open_fmu(fmu, "a")
    init(a)
    a.doStep(0.0, 0.01)
    slave = next(m for k, m in sys.modules.items() if k.endswith("_slave") and hasattr(m, "MbsfmuSlave"))
    do_step = slave.MbsfmuSlave.do_step
    slave.MbsfmuSlave.do_step = lambda self, t, h: 1 / 0   # a slave that raises anyway: pythonfmu's fmi2Fatal
    n = len(LOG)
    first = status(a.doStep, 0.01, 0.01)
    first_logs = logged("a", n)
    slave.MbsfmuSlave.do_step = do_step
    out = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    calls = [(a.doStep, (0.01, 0.01)), (a.getReal, (out,)), (a.reset, ()), (a.getFMUstate, ()), (a.terminate, ()),
             (a.setReal, ([0], [1.0])), (a.setupExperiment, ()), (a.enterInitializationMode, ())] * 4
    later = calls_with_messages("a", calls)
    a.fmi2FreeInstance(a.component)
    b, _, _, _ = open_fmu(fmu, "b")   # another instance of the same FMU still works
    init(b)
    b.doStep(0.0, 0.01)
    return {"first": first, "first_logs": first_logs, "later": later, "b": outputs(b, md)}


def scenario_steps():
    a, vr, md, _ = open_fmu(fmu, "a")
    b, _, _, _ = open_fmu(fmu, "b")
    init(a), init(b)
    t = steps(a, 0.0, 3)
    steps(b, 0.0, 3)
    seq = [("negative h", (t, -0.01)), ("NaN t", (float("nan"), 0.01)), ("infinite h", (t, float("inf"))),
           ("t ahead", (t + 5.0, 0.01)), ("t behind", (0.0, 0.01))]
    res = calls_with_messages("a", [(a.doStep, args) for _, args in seq])
    steps(a, t, 3)   # the instance goes on from where it was, like its untouched twin
    steps(b, t, 3)
    return {"sequence": [[what, st, logs] for (what, _), (st, logs) in zip(seq, res)],
            "same": outputs(a, md) == outputs(b, md)}


print("RESULT " + json.dumps(globals()["scenario_" + scenario]()), flush=True)
'''


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    out = tmp_path_factory.mktemp("hostile")
    return {m: mbsfmu.build_fmu(REPO / "models" / f"{m}.yaml", out) for m in ("pendulum", "spring_damper")}


def drive(scenario, fmus, tmp_path):
    work = tmp_path / scenario
    work.mkdir()
    r = subprocess.run([sys.executable, "-c", DRIVER, scenario, str(fmus["pendulum"]), str(fmus["spring_damper"]),
                        str(work)], capture_output=True, text=True, timeout=120)
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")]
    assert r.returncode == 0 and lines, (r.returncode, r.stdout[-3000:], r.stderr[-3000:])
    return json.loads(lines[-1][7:]), r.stderr


def refused(status, logs):
    """fmi2Error, and the call logged one message with status error."""
    return status == 3 and [m for m in logs if m[0] == 3 and m[1] == "logStatusError" and m[2]]


def test_shim_compiles_warning_free(fmus, tmp_path):
    md = zipfile.ZipFile(fmus["pendulum"]).read("modelDescription.xml")
    assert build.compile_shim(tmp_path / "shim.so", "real.so", md) is not None
    r = subprocess.run([CC, "-Wall", "-Wextra", "-Werror", "-fsyntax-only", *(f"-I{f.parent}" for f in build.SHIM_SHARED),
                        str(tmp_path / "shim.c"), *map(str, build.SHIM_SHARED)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_variable_table_is_the_model_description(fmus):
    from fmpy import read_model_description
    md = zipfile.ZipFile(fmus["pendulum"]).read("modelDescription.xml")
    defines = build.shim_model_defines(md)
    rows = [ln.strip().rstrip(", \\") for ln in defines.splitlines() if ln.startswith("    {")]
    variables = read_model_description(str(fmus["pendulum"])).modelVariables
    assert [v.valueReference for v in variables] == list(range(len(rows)))
    for v, row in zip(variables, rows):
        assert row == '{"%s", \'%s\', \'%s\', \'%s\'}' % (v.name, v.type[0], v.causality[0], v.variability[0])
    assert build._c_string('a"b\\c?é\n') == r'"a\042b\134c\077\303\251\012"'


def test_100_bad_value_references_and_types(fmus, tmp_path):
    res, _ = drive("refs", fmus, tmp_path)
    assert len(res["calls"]) == 100
    bad = [(i, c) for i, c in enumerate(res["calls"]) if not refused(*c)]
    assert not bad, bad[:5]
    texts = " | ".join(c[1][0][2] for c in res["calls"][:16])
    for expected in ("unknown value reference", "is a Real variable, not Integer", "not Boolean",
                     "is a String variable, not Real", "cannot be set", "fixed parameter", "NULL value reference"):
        assert expected in texts, expected
    assert res["param_unchanged"]            # a call with one bad reference sets nothing
    assert res["a"] == res["b"]              # 100 refused calls changed nothing: bit-identical to the twin


@pytest.mark.parametrize("kind", ["pythonfmu", "native"])
def test_wrong_call_order(fmus, tmp_path, kind):
    """Calls out of the FMI 2.0 order (status queries before initialization among them): fmi2Error with a
    message from both kinds, the same answers; freed, NULL and foreign components refused untouched."""
    if kind == "native":
        fmus = {m: mbsfmu.build_fmu(REPO / "models" / f"{m}.yaml", tmp_path / "native", kind="native")
                for m in ("pendulum", "spring_damper")}
    res, stderr = drive("order", fmus, tmp_path)
    expected_ok = {"enter", "exit", "doStep", "terminate", "getReal after terminate", "reset",
                   "setupExperiment after reset", "enter after reset", "exit after reset",
                   "doStep after re-initialization"}
    for what, st, logs in res["sequence"]:
        if what in expected_ok:
            assert st == 0, (what, logs)
        else:
            assert refused(st, logs), (what, st, logs)
            assert "not allowed" in logs[0][2] or "not supported" in logs[0][2], (what, logs)
    assert res["reset_equals_fresh"]
    assert res["after_free"] == [3] * 7       # freed, NULL and foreign components: fmi2Error, nothing dereferenced
    assert "not a live instance" in stderr and "NULL component" in stderr
    assert len(res["b_alive"]) > 0


@pytest.mark.parametrize("kind", ["pythonfmu", "native"])
def test_bad_step_arguments_are_errors_and_change_nothing(fmus, tmp_path, kind):
    """doStep with h < 0, a non-finite t or h, or t other than the current time: fmi2Error with a message
    from both kinds, and the instance steps on exactly like an untouched twin."""
    if kind == "native":
        fmus = {m: mbsfmu.build_fmu(REPO / "models" / f"{m}.yaml", tmp_path / "native", kind="native")
                for m in ("pendulum", "spring_damper")}
    res, _ = drive("steps", fmus, tmp_path)
    for what, st, logs in res["sequence"]:
        assert refused(st, logs), (kind, what, st, logs)
    assert res["same"]


def test_hostile_state_bytes(fmus, tmp_path):
    res, _ = drive("states", fmus, tmp_path)
    assert not res["marker"]                  # nothing from a state executed
    for name, (st, st_set, logs) in res["crafted"].items():
        if name in ("pickle_with_header", "bad_method"):
            # header, GUID, length and checksum made to fit: the engine refuses the payload, all or nothing
            assert st == 0 and st_set == 3, (name, st, st_set, logs)
            assert "set FMU state" in logs[-1][2], (name, logs)
        else:
            assert refused(st, logs) and st_set is None, (name, st, logs)
    texts = {name: logs[0][2] for name, (st, _, logs) in res["crafted"].items() if st}
    assert "GUID" in texts["foreign"] and "GUID" in texts["guid"] and "bad magic" in texts["random"]
    assert "checksum" in texts["flipped"] and "length" in texts["truncated"] and "version" in texts["version"]
    assert res["handles"] == {k: 3 for k in res["handles"]} and len(res["handle_logs"]) == 4
    assert res["a"] == res["b"]               # the instance continued unchanged: bit-identical to the twin


def test_failed_initialization_is_an_error(fmus, tmp_path):
    res, _ = drive("init", fmus, tmp_path)
    calls = {what: (st, logs) for what, st, logs in res["method"][:7]}
    assert refused(*calls["not UTF-8"]) and "not UTF-8" in calls["not UTF-8"][1][0][2]
    assert refused(*calls["bad method"]) and "bogus" in calls["bad method"][1][-1][2]
    assert refused(*calls["exit"]) and "bogus" in calls["exit"][1][-1][2]
    assert "initialization failed" in calls["exit"][1][-1][2]
    assert refused(*calls["doStep after failed initialization"])
    assert calls["getReal"][0] == 0
    assert [st for _, st, _ in res["method"][7:]] == [0] * 5   # fmi2Reset recovers the instance
    exit_b = res["parameter"][-1]
    assert refused(*exit_b[1:]) and "not finite" in exit_b[2][-1][2], exit_b
    assert res["simulate"].startswith("raised"), res["simulate"]


def test_fatal_from_pythonfmu_is_never_forwarded_again(fmus, tmp_path):
    res, _ = drive("fatal", fmus, tmp_path)
    assert res["first"] == 4 and any("fatal" in m[2] for m in res["first_logs"])
    assert all(st == 3 and logs and "unusable" in logs[0][2] for st, logs in res["later"]), res["later"][:3]
    assert len(res["b"]) > 0                  # the process lives on and other instances work


# ---- C hosts: a failed instantiation ends cleanly, with the message on the logger ----------------------------
HOST_C = r"""
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
typedef struct {
    void (*logger)(void*, const char*, int, const char*, const char*, ...);
    void* (*alloc)(size_t, size_t); void (*free)(void*); void* step_finished; void* env;
} cb_t;
static void logger(void* env, const char* inst, int st, const char* cat, const char* msg, ...) {
    va_list ap;
    (void)env;
    printf("LOG %d %s %s: ", st, cat ? cat : "", inst ? inst : "");
    va_start(ap, msg); vprintf(msg, ap); va_end(ap);
    printf("\n"); fflush(stdout);
}
/* like ecos: use whatever fmi2Instantiate returned, NULL included */
int main(int argc, char** argv) {  /* lib resources_uri guid */
    void* h = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (argc < 4 || !h) return 2;
    void* (*inst)(const char*, int, const char*, const char*, const cb_t*, int, int) = dlsym(h, "fmi2Instantiate");
    int (*setup)(void*, int, double, double, int, double) = dlsym(h, "fmi2SetupExperiment");
    int (*enter)(void*) = dlsym(h, "fmi2EnterInitializationMode");
    int (*exit_init)(void*) = dlsym(h, "fmi2ExitInitializationMode");
    int (*step)(void*, double, double, int) = dlsym(h, "fmi2DoStep");
    int (*term)(void*) = dlsym(h, "fmi2Terminate");
    void (*free_instance)(void*) = dlsym(h, "fmi2FreeInstance");
    cb_t cb = {logger, calloc, free, NULL, NULL};
    void* c = inst("host", 1, argv[3], argv[2], &cb, 0, 0);
    printf("INSTANCE %s\n", c ? "yes" : "NULL");
    printf("STATUS %d %d %d %d %d\n", setup(c, 0, 0.0, 0.0, 0, 0.0), enter(c), exit_init(c), step(c, 0.0, 0.01, 1),
           term(c));
    free_instance(c);
    printf("DONE\n");
    return 0;
}
"""


@pytest.fixture(scope="module")
def c_host(tmp_path_factory):
    d = tmp_path_factory.mktemp("chost")
    (d / "host.c").write_text(HOST_C)
    subprocess.run([CC, "-O1", "-Wall", "-o", str(d / "host"), str(d / "host.c"), "-ldl"], check=True)
    return d / "host"


def _unpacked(fmu, where):
    zipfile.ZipFile(fmu).extractall(where)
    from fmpy import read_model_description
    md = read_model_description(str(fmu))
    return where / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so", md.guid


def _host_env():
    return {k: v for k, v in os.environ.items() if not k.startswith("PYTHON") and k != "LD_PRELOAD"}


FAILED_INSTANTIATION = {"guid": "GUID differs", "empty": "is not this FMU's resources folder",
                        "broken": "fmi2Instantiate: cannot load the compiled scene"}


@pytest.mark.parametrize("case", FAILED_INSTANTIATION)
def test_failed_instantiation_in_a_c_host(fmus, c_host, tmp_path, case):
    lib, guid = _unpacked(fmus["pendulum"], tmp_path / "fmu")
    resources = (tmp_path / "fmu" / "resources").as_uri()
    if case == "guid":
        guid = "{00000000-0000-0000-0000-000000000000}"
    elif case == "empty":   # pythonfmu 0.7.0 itself segfaults here
        (tmp_path / "empty").mkdir()
        resources = (tmp_path / "empty").as_uri()
    else:                   # the engine refuses the scene: the slave cannot start
        (tmp_path / "fmu" / "resources" / "mbsfmu_scene.bin").write_bytes(b"not a compiled scene")
    r = subprocess.run([str(c_host), str(lib), resources, guid], capture_output=True, text=True, timeout=60,
                       env=_host_env())
    assert r.returncode == 0 and "DONE" in r.stdout, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    assert "INSTANCE NULL" in r.stdout and "STATUS 3 3 3 3 3" in r.stdout
    errors = [ln for ln in r.stdout.splitlines() if ln.startswith("LOG 3 logStatusError host: fmi2Instantiate")]
    assert errors and FAILED_INSTANTIATION[case] in errors[0], r.stdout
    assert "NULL component" in r.stderr


def test_failed_instantiation_in_ecos(fmus, tmp_path):
    """ecos used to call fmi2SetupExperiment on the NULL instance and abort; now it ends with an error."""
    from test_fmu_hosts import _clean_env, _ecos_binary
    exe, why = _ecos_binary(tmp_path, "ecos")
    if exe is None:
        pytest.skip(why)
    broken = tmp_path / "pendulum.fmu"
    with zipfile.ZipFile(fmus["pendulum"]) as zin, zipfile.ZipFile(broken, "w") as zout:
        for item in zin.infolist():
            broken_scene = item.filename.endswith("mbsfmu_scene.bin")   # the slave cannot start with it
            zout.writestr(item, b"not a compiled scene" if broken_scene else zin.read(item.filename))
    work = tmp_path / "run"
    work.mkdir()
    r = subprocess.run([str(exe), "simulate", "--path", str(broken), "--stopTime", "0.1", "--stepSize", "0.01",
                        "--noParallel", "--logLevel", "debug"],   # ecos shows FMU messages at debug level
                       cwd=work, env=_clean_env(), capture_output=True, text=True, timeout=120)
    assert r.returncode in (0, 1), (r.returncode, r.stdout[-2000:], r.stderr[-2000:])  # no signal, no abort
    assert "fmi2Instantiate: cannot load the compiled scene" in r.stdout + r.stderr, r.stdout[-3000:]
    assert "NULL component" in r.stderr   # what ecos then called on the NULL instance was refused
