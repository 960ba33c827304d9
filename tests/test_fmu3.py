"""FMI 3.0 native FMUs (`build_fmu(..., kind="native", fmi="3")`, fmi/fmi3.c): co-simulation and model exchange.

References: fmpy's validation (the FMI 3.0 schema and rules); the FMI 2.0 native FMU of the same scene (the same
engine: co-simulation equal to 1e-12); the in-process engine (`mbsfmu.simulate`, dop853 at rtol 1e-13, atol 1e-16,
which radau5 there matches to 6e-8 of each signal's range) for model exchange under fmpy's CVode; the FMI 3.0
standard for the state machines; an explicit Euler step in numpy over the in-process right-hand side for the C
host's model exchange path. Skipped without a C compiler.
"""
from __future__ import annotations

import ctypes
import json
import os
import re
import subprocess
import sys
import warnings
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.fmi3 import FMU3Model, FMU3Slave  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

import mbsfmu  # noqa: E402
from mbsfmu.fmu import native  # noqa: E402
from mbsfmu.compiler.variables import fmi3_variables, variables  # noqa: E402
from mbsfmu.simulation import Simulation  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODELS = [p.stem for p in sorted((REPO / "models").glob("*.yaml"))]
SCENES = {m: mbsfmu.load(REPO / "models" / f"{m}.yaml") for m in MODELS}
ELASTIC = {m for m, s in SCENES.items() if any(b.get("elastic") for b in s.spec["bodies"])}
HOST = REPO / "tests" / "c" / "fmu3_host.c"

pytestmark = pytest.mark.skipif(native.compiler() is None, reason="no C compiler (cc, gcc, clang or $CC)")


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """{model: (FMI 3 FMU, FMI 2 FMU)}: every shipped model in both versions, linux only (no MinGW: the
    numbers are the linux binaries'), built on two threads."""
    out3, out2 = tmp_path_factory.mktemp("fmi3"), tmp_path_factory.mktemp("fmi2")
    with pytest.MonkeyPatch.context() as mp, warnings.catch_warnings():
        mp.setattr(native, "MINGW", "no-mingw-for-these-tests")
        warnings.simplefilter("ignore", RuntimeWarning)  # "no binaries/win64"
        with ThreadPoolExecutor(2) as pool:
            jobs = {m: (pool.submit(mbsfmu.build_fmu, SCENES[m], out3, kind="native", fmi="3"),
                        pool.submit(mbsfmu.build_fmu, SCENES[m], out2, kind="native", fmi="2")) for m in MODELS}
            return {m: (a.result(), b.result()) for m, (a, b) in jobs.items()}


def _outputs(fmu):
    md = read_model_description(str(fmu))
    return md, [v for v in md.modelVariables if v.causality == "output"]


def _elements(model):
    """{FMI 3.0 variable name: the FMI 2.0 scalars it holds} (compiler/variables.py: fmi3_variables)"""
    return {name: [v.name for v in vs] for name, vs, _ in fmi3_variables(variables(SCENES[model].spec, derivatives=True))}


def _size(v):
    return int(np.prod(v.shape)) if v.shape else 1


def _columns(result, names):
    """The columns of fmpy's result for these variables, arrays flat (their elements in order)."""
    return np.hstack([np.asarray(result[n]).reshape(len(result), -1) for n in names])


# ---- what the archive holds -------------------------------------------------------------------------------
def test_every_model_validates_with_both_interfaces(built):
    shapes = set()
    for m in MODELS:
        fmu3 = built[m][0]
        assert validate_fmu(str(fmu3)) == [], m
        md = read_model_description(str(fmu3))
        assert md.fmiVersion == "3.0" and md.coSimulation and md.modelExchange, m
        names = zipfile.ZipFile(fmu3).namelist()
        assert f"binaries/x86_64-linux/{md.coSimulation.modelIdentifier}.so" in names, m
        # sources/buildDescription.xml lists exactly the C files shipped in sources/
        from xml.etree import ElementTree as ET
        listed = {e.get("name") for e in ET.fromstring(zipfile.ZipFile(fmu3).read("sources/buildDescription.xml"))
                  .iter("SourceFile")}
        assert listed == {n[8:] for n in names if n.startswith("sources/") and n.endswith(".c")}, m
        assert "fmi3.c" in listed and "fmi2.c" not in listed, m
        assert (m in ELASTIC) == ("elastic.c" in listed), m  # the layer's closure (engine.build.linked_sources)
        # one table of variables: the FMI 2 FMU's scalars, runs of them as FMI 3 arrays (fmi3_variables): a force
        # input's components, a point's r and v, an elastic body's modal coordinates; the same causality,
        # variability, unit and starts, an array's nominal its elements' smallest
        md2 = {v.name: v for v in read_model_description(str(built[m][1])).modelVariables}
        v3 = [v for v in md.modelVariables if v.name != "time"]
        groups = _elements(m)
        assert [(v.name, v.valueReference) for v in v3] == [(n, k) for k, n in enumerate(groups)], m
        for w in v3:
            els = [md2[e] for e in groups[w.name]]
            assert w.shape == (() if [w.name] == groups[w.name] else (len(els),)), (m, w.name)
            assert {(e.causality, e.variability, e.unit) for e in els} == {(w.causality, w.variability, w.unit)}, w.name
            starts = [e.start for e in els]  # an output has none
            assert (w.start.split() if w.start is not None and w.type != "String" else [w.start] * len(els)) == \
                   starts, (m, w.name)
            nominals = [float(e.nominal) for e in els if e.nominal is not None]
            assert (float(w.nominal) if w.nominal is not None else None) == (min(nominals) if nominals else None)
        shapes |= {w.shape for w in v3}
        (time,) = [v for v in md.modelVariables if v.causality == "independent"]
        assert time.valueReference == len(md.modelVariables) - 1 and time.unit == "s"
        der = [v for v in md.modelVariables if v.derivative is not None]
        assert [d.derivative.name for d in der] == [v.name for v in md.modelVariables
                                                    if v.name.startswith(("y.", "yd."))], m
    assert {(2,), (3,), (4,)} <= shapes  # arrays of modal coordinates and 3-vectors among the shipped models


# ---- co-simulation: the FMI 2 FMU's numbers ---------------------------------------------------------------
@pytest.mark.parametrize("model", MODELS)
def test_cosimulation_equals_the_fmi2_fmu(built, model):
    fmu3, fmu2 = built[model]
    _, outs = _outputs(fmu3)
    elements = _elements(model)
    kw = dict(stop_time=0.3, output_interval=0.01)
    r3 = simulate_fmu(str(fmu3), fmi_type="CoSimulation", output=[v.name for v in outs], **kw)
    r2 = simulate_fmu(str(fmu2), fmi_type="CoSimulation", output=[e for v in outs for e in elements[v.name]], **kw)
    assert len(r3) == len(r2) == 31
    for v in outs:
        got, want = _columns(r3, [v.name]), _columns(r2, elements[v.name])
        scale = max(1.0, np.abs(want).max())
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * scale, err_msg=f"{model} {v.name}")
    assert np.ptp(_columns(r3, [v.name for v in outs]), axis=0).max() > 1e-4, model  # it moved


# ---- model exchange: fmpy's CVode against the in-process engine -------------------------------------------
def _scale(ref):
    """Each signal's range; a constant signal (range below 1e-9 of its size) its size."""
    rng, size = np.ptp(ref, axis=0), np.abs(ref).max(axis=0)
    return np.where(rng > 1e-9 * size, rng, size)


@pytest.mark.parametrize("model", MODELS)
def test_model_exchange_under_cvode_matches_simulate(built, model):
    """Rigid models over 0.3 s, elastic ones over 0.1 s, all at rtol 1e-10: fmpy's CVode takes atol = rtol ·
    nominal, and each state's nominal is its size in the scene (fmi3GetNominalsOfContinuousStates; with nominals
    1 the modal coordinates of 1e-7 were off by up to 2e-4 of their range at this rtol). spinup_beam at rtol
    1e-12: its spin-up starts smoothly from rest, so in 0.1 s its modes move a millionth of their size over the
    experiment, which its nominals are."""
    fmu3 = built[model][0]
    stop, h = (0.1, 5e-4) if model in ELASTIC else (0.3, 0.01)
    rtol = 1e-12 if model == "spinup_beam" else 1e-10
    md, _ = _outputs(fmu3)
    states = [v.derivative.name for v in md.modelVariables if v.derivative is not None]
    r = simulate_fmu(str(fmu3), fmi_type="ModelExchange", solver="CVode", relative_tolerance=rtol, stop_time=stop,
                     output_interval=h, output=states)
    t, Y, YD = mbsfmu.simulate(SCENES[model], stop=stop, step=h, method="dop853", rtol=1e-13, atol=1e-16)
    ref = np.hstack([Y, YD])
    got = _columns(r, states)
    assert got.shape == ref.shape and np.allclose(r["time"], t, rtol=0, atol=1e-12)
    scale = _scale(ref)
    err = np.abs(got - ref).max(axis=0)
    zero = scale == 0  # identically zero in the reference (an unexcited mode): zero here too, to 1e-9
    names = np.array([e for n in states for e in _elements(model)[n]])
    worst = dict(zip(names[~zero], err[~zero] / scale[~zero]))
    assert (err[~zero] <= 1e-6 * scale[~zero]).all(), (model, worst)
    assert (err[zero] <= 1e-9).all(), model


def _ptr(a):
    return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))


def _fmu3(fmu, cls, name):
    md = read_model_description(str(fmu))
    d = extract(str(fmu))
    iface = md.modelExchange if cls is FMU3Model else md.coSimulation
    return cls(guid=md.guid, unzipDirectory=d, modelIdentifier=iface.modelIdentifier, instanceName=name), md


def test_derivatives_are_the_engines_right_hand_side(built):
    """fmi3GetContinuousStateDerivatives at states the host sets (off the trajectory, quaternions not of unit
    norm, inputs set) equals the in-process engine's f(t, x) there bit for bit, and der(·) variables read it;
    fmi3GetNominalsOfContinuousStates answers the declared nominals."""
    rng = np.random.default_rng(3)
    for m in ("spinning_top", "driven_crank", "robot_arm_elastic"):
        fmu = built[m][0]
        me, md = _fmu3(fmu, FMU3Model, "me")
        vr = {v.name: v.valueReference for v in md.modelVariables}
        sim = Simulation(json.loads(json.dumps(SCENES[m].spec)))
        inputs = [v.name for v in md.modelVariables if v.causality == "input"]
        scalars = [e for i in inputs for e in _elements(m)[i]]  # the inputs' values, arrays flat
        me.instantiate()
        me.enterInitializationMode()
        me.exitInitializationMode()
        me.updateDiscreteStates()
        me.enterContinuousTimeMode()
        n = len(sim.x)
        for k in range(3):
            t = 0.1 + 0.37 * k
            x = np.array(sim.x) + (0.1 * rng.standard_normal(n) if k else 0.0)
            u = rng.standard_normal(len(scalars))
            me.setFloat64([vr[i] for i in inputs], list(u))
            me.setTime(t)
            me.setContinuousStates(_ptr(x), n)
            dx = np.zeros(n)
            me.getContinuousStateDerivatives(_ptr(dx), n)
            for name, val in zip(scalars, u):
                sim.set(name, float(val))
            ref = np.array(sim.f(t, x))
            assert dx.tolist() == ref.tolist(), m
            ders = [v for v in md.modelVariables if v.derivative is not None]
            assert me.getFloat64([v.valueReference for v in ders], sum(map(_size, ders))) == ref.tolist(), m
        nominals = np.zeros(n)  # what a host's error weights take: the states' nominals, of arrays the smallest
        me.getNominalsOfContinuousStates(_ptr(nominals), n)
        declared = [float(v.derivative.nominal) for v in md.modelVariables if v.derivative for _ in range(_size(v))]
        assert nominals.tolist() == [v.nominal for v in variables(SCENES[m].spec) if v.nominal is not None], m
        assert all(a >= b for a, b in zip(nominals, declared)), m
        me.terminate()
        me.freeInstance()


@pytest.mark.parametrize("m", ["robot_arm_elastic", "free_body", "fe_stress"])
def test_directional_and_adjoint_derivatives_are_the_engines(built, m):
    """fmi3GetDirectionalDerivative and fmi3GetAdjointDerivative over arrays (seeds and sensitivities flat, an
    array's elements in order) at a state the host set: equal to the in-process engine's columns of the same
    Jacobian (tests/test_directional.py holds those against central differences), and the adjoint seedᵀJ; a seed
    or sensitivity count that is not the variables' size is fmi3Error with a message."""
    from mbsfmu.engine import Instance
    from mbsfmu.simulation import compiled
    me, md = _fmu3(built[m][0], FMU3Model, "dd")
    me.instantiate()
    me.enterInitializationMode()
    me.exitInitializationMode()
    me.updateDiscreteStates()
    me.enterContinuousTimeMode()
    blob, var, _ = compiled(SCENES[m].spec, derivatives=True)
    inst = Instance(blob)
    inst.initialize(0.0)
    rng = np.random.default_rng(5)
    n = inst.n
    x = np.array(inst.state()) + 0.1 * np.array(inst.nominals()) * rng.standard_normal(n)
    inputs = [v for v in md.modelVariables if v.causality == "input"]
    u = rng.standard_normal(sum(map(_size, inputs)))
    me.setFloat64([v.valueReference for v in inputs], list(u))
    me.setTime(0.2)
    me.setContinuousStates(_ptr(x), n)
    index = {v.name: v.vr for v in var}  # the engine's rows, by FMI 2.0 name
    for name, value in zip([e for v in inputs for e in _elements(m)[v.name]], u):
        inst.set_real(index[name], float(value))
    inst.set_time(0.2)
    inst.set_state(x)
    states = [v.derivative for v in md.modelVariables if v.derivative is not None]
    unknowns = [v for v in md.modelVariables if v.derivative is not None or v.causality == "output"]
    knowns = states + inputs
    rows = lambda vs: [index[e] for v in vs for e in _elements(m)[v.name]]  # noqa: E731
    nk, nu = len(rows(knowns)), len(rows(unknowns))
    seed = rng.standard_normal(nk)
    got = me.getDirectionalDerivative([v.valueReference for v in unknowns], [v.valueReference for v in knowns],
                                      list(seed), nu)
    want = inst.directional_derivative(rows(unknowns), rows(knowns), seed)
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-14 * np.abs(want).max())
    wseed = rng.standard_normal(nu)
    got = me.getAdjointDerivative([v.valueReference for v in unknowns], [v.valueReference for v in knowns],
                                  list(wseed), nk)
    want = inst.adjoint_derivative(rows(unknowns), rows(knowns), wseed)
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-14 * np.abs(want).max())
    J = np.array([inst.directional_derivative(rows(unknowns), rows(knowns), e) for e in np.eye(nk)]).T
    np.testing.assert_allclose(got, wseed @ J, rtol=1e-12, atol=1e-12 * np.abs(wseed @ J).max())
    from fmpy.fmi1 import FMICallException
    with pytest.raises(FMICallException):  # one seed short
        me.getDirectionalDerivative([unknowns[0].valueReference], [v.valueReference for v in knowns], list(seed[1:]),
                                    _size(unknowns[0]))
    me.terminate()
    me.freeInstance()


def test_non_finite_derivatives_are_discard_with_a_message(built):
    """The pendulum at θ̇ = 1e200 (finite; θ̇² overflows inside): fmi3GetContinuousStateDerivatives,
    fmi3GetDirectionalDerivative, fmi2GetDerivatives and fmi2GetDirectionalDerivative answer Discard with a logged
    message naming the entry (before: OK with NaN); the derivatives' buffer keeps what it held; at θ̇ = 2 again,
    the closed form."""
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Model, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, calloc, free
    from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE
    from fmpy.logging import addLoggerProxy
    from test_engine import PENDULUM, _pendulum_acceleration
    log = []
    fmu3, fmu2 = built["pendulum"]
    me, md = _fmu3(fmu3, FMU3Model, "extreme3")
    me.instantiate(logMessage=lambda env, status, cat, msg: log.append((3, status, msg.decode())))
    me.enterInitializationMode()
    me.exitInitializationMode()
    me.updateDiscreteStates()
    me.enterContinuousTimeMode()
    md2 = read_model_description(str(fmu2))
    me2 = FMU2Model(guid=md2.guid, unzipDirectory=extract(str(fmu2)), modelIdentifier=md2.modelExchange.modelIdentifier,
                    instanceName="extreme2")
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg: log.append((2, status, msg.decode())))
    cb.allocateMemory, cb.freeMemory = fmi2CallbackAllocateMemoryTYPE(calloc), fmi2CallbackFreeMemoryTYPE(free)
    addLoggerProxy(ctypes.byref(cb))
    me2.instantiate(callbacks=cb)
    me2.setupExperiment(startTime=0.0)
    me2.enterInitializationMode()
    me2.exitInitializationMode()
    me2.newDiscreteStates()
    me2.enterContinuousTimeMode()
    vr3, vr2 = ({v.name: v.valueReference for v in m.modelVariables} for m in (md, md2))
    calls = {3: (lambda dx: me.getContinuousStateDerivatives(_ptr(dx), 2), me.setContinuousStates,
                 lambda: me.getDirectionalDerivative([vr3["der(yd.theta)"]], [vr3["y.theta"], vr3["yd.theta"]],
                                                     [0.0, 1.0], 1)),
             2: (lambda dx: me2.getDerivatives(_ptr(dx), 2), me2.setContinuousStates,
                 lambda: me2.getDirectionalDerivative([vr2["der(yd.theta)"]], [vr2["y.theta"], vr2["yd.theta"]],
                                                      [0.0, 1.0]))}
    for version, (derivatives, set_states, directional) in calls.items():
        set_states(_ptr(np.array([0.3, 1e200])), 2)
        dx = np.full(2, 7.0)
        for call in (lambda: derivatives(dx), directional):
            k = len(log)
            with pytest.raises(FMICallException) as e:
                call()
            assert e.value.status == 2, (version, e.value)  # fmi2Discard, fmi3Discard
            assert [m for v, st, m in log[k:] if v == version and st == 2 and "yd.theta" in m and "not finite" in m]
        assert dx.tolist() == [7.0, 7.0]
        set_states(_ptr(np.array([0.3, 2.0])), 2)
        derivatives(dx)
        assert dx[0] == 2.0 and dx[1] == pytest.approx(_pendulum_acceleration(0.3, **PENDULUM), rel=1e-12)
    for m in (me, me2):
        m.terminate()
        m.freeInstance()


# ---- FMU state: get/set/serialize, bit for bit ------------------------------------------------------------
def _cs_run(s, outs, t, n, h=0.01, nvalues=None):
    rows = []
    for _ in range(n):
        s.doStep(t, h)
        t += h
        rows.append(s.getFloat64(outs, nvalues))
    return t, rows


@pytest.mark.parametrize("model", ["spinning_top", "robot_arm_elastic"])
def test_state_round_trip_is_bit_identical_and_fmi2_reads_the_bytes(built, model):
    fmu3, fmu2 = built[model]
    s, md = _fmu3(fmu3, FMU3Slave, "a")
    outputs = [v for v in md.modelVariables if v.causality == "output"]
    outs, nvalues = [v.valueReference for v in outputs], sum(map(_size, outputs))
    s.instantiate()
    s.enterInitializationMode()
    s.exitInitializationMode()
    t, _ = _cs_run(s, outs, 0.0, 7, nvalues=nvalues)
    state = s.getFMUState()
    data = s.serializeFMUState(state)
    s.freeFMUState(state)
    _, first = _cs_run(s, outs, t, 20, nvalues=nvalues)
    restored = s.deserializeFMUState(data)
    s.setFMUState(restored)
    _, again = _cs_run(s, outs, t, 20, nvalues=nvalues)
    assert again == first  # bit for bit
    assert bytes(s.serializeFMUState(s.getFMUState())) != bytes(data)  # it did move on
    s.freeInstance()
    # the same byte layout as FMI 2: the FMI 2 FMU of the scene continues from the FMI 3 FMU's bytes
    md2 = read_model_description(str(fmu2))
    vr2 = {v.name: v.valueReference for v in md2.modelVariables}
    outs = [vr2[e] for v in outputs for e in _elements(model)[v.name]]
    s2 = FMU2Slave(guid=md2.guid, unzipDirectory=extract(str(fmu2)), modelIdentifier=md2.coSimulation.modelIdentifier,
                   instanceName="b")
    s2.instantiate()
    s2.setupExperiment(startTime=0.0)
    s2.enterInitializationMode()
    s2.exitInitializationMode()
    s2.setFMUstate(s2.deSerializeFMUstate(data))
    rows = []
    for _ in range(20):  # the same communication points as _cs_run's
        s2.doStep(t, 0.01)
        t += 0.01
        rows.append(s2.getReal(outs))
    assert rows == first
    s2.terminate()
    s2.freeInstance()


def test_model_exchange_state_round_trip(built):
    me, md = _fmu3(built["spinning_top"][0], FMU3Model, "me")
    me.instantiate()
    me.enterInitializationMode()
    me.exitInitializationMode()
    me.updateDiscreteStates()
    me.enterContinuousTimeMode()
    n = sum(1 for v in md.modelVariables if v.derivative is not None)
    x, dx = np.zeros(n), np.zeros(n)

    def euler(t, steps, h=1e-3):
        rows = []
        me.getContinuousStates(_ptr(x), n)
        for _ in range(steps):
            me.getContinuousStateDerivatives(_ptr(dx), n)
            x[:] += h * dx
            t += h
            me.setTime(t)
            me.setContinuousStates(_ptr(x), n)
            rows.append(x.tolist())
        return t, rows

    t, _ = euler(0.0, 5)
    data = me.serializeFMUState(me.getFMUState())
    _, first = euler(t, 30)
    me.setFMUState(me.deserializeFMUState(data))
    _, again = euler(t, 30)
    assert again == first
    me.terminate()
    me.freeInstance()


# ---- hostile host: every refusal is fmi3Error (fmi3Discard for a failed step) with a message, no crash -----
CHILD = r'''
import ctypes, json, math, sys
lib = ctypes.CDLL(sys.argv[1]); RES, TOKEN, NOUT = sys.argv[2].encode(), sys.argv[3].encode(), int(sys.argv[4])
B, D, P, U, S, C = ctypes.c_bool, ctypes.c_double, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_size_t, ctypes.c_char_p
LOG = ctypes.CFUNCTYPE(None, P, ctypes.c_int, C, C)
messages = []
logger = LOG(lambda env, st, cat, msg: messages.append([st, cat.decode(), msg.decode()]))
def sig(name, res, *args):
    f = getattr(lib, name); f.restype = res; f.argtypes = list(args); return f
cs_new = sig("fmi3InstantiateCoSimulation", P, C, C, C, B, B, B, B, P, S, P, LOG, P)
me_new = sig("fmi3InstantiateModelExchange", P, C, C, C, B, B, P, LOG)
se_new = sig("fmi3InstantiateScheduledExecution", P, C, C, C, B, B, P, LOG, P, P, P)
enter = sig("fmi3EnterInitializationMode", int, P, B, D, D, B, D)
exit_ = sig("fmi3ExitInitializationMode", int, P)
step = sig("fmi3DoStep", int, P, D, D, B, ctypes.POINTER(B), ctypes.POINTER(B), ctypes.POINTER(B), ctypes.POINTER(D))
getf = sig("fmi3GetFloat64", int, P, ctypes.POINTER(U), S, ctypes.POINTER(D), S)
setf = sig("fmi3SetFloat64", int, P, ctypes.POINTER(U), S, ctypes.POINTER(D), S)
geti = sig("fmi3GetInt32", int, P, ctypes.POINTER(U), S, ctypes.POINTER(ctypes.c_int32), S)
term = sig("fmi3Terminate", int, P)
free = sig("fmi3FreeInstance", None, P)
getst = sig("fmi3GetFMUState", int, P, ctypes.POINTER(P))
setst = sig("fmi3SetFMUState", int, P, P)
size = sig("fmi3SerializedFMUStateSize", int, P, P, ctypes.POINTER(S))
ser = sig("fmi3SerializeFMUState", int, P, P, ctypes.c_char_p, S)
deser = sig("fmi3DeserializeFMUState", int, P, ctypes.c_char_p, S, ctypes.POINTER(P))
settime = sig("fmi3SetTime", int, P, D)
setx = sig("fmi3SetContinuousStates", int, P, ctypes.POINTER(D), S)
getdx = sig("fmi3GetContinuousStateDerivatives", int, P, ctypes.POINTER(D), S)
nx_ = sig("fmi3GetNumberOfContinuousStates", int, P, ctypes.POINTER(S))
upd = sig("fmi3UpdateDiscreteStates", int, P, *[ctypes.POINTER(B)] * 5, ctypes.POINTER(D))
cont = sig("fmi3EnterContinuousTimeMode", int, P)
event = sig("fmi3EnterEventMode", int, P)
dirder = sig("fmi3GetDirectionalDerivative", int, P, P, S, P, S, P, S, P, S)
stepmode = sig("fmi3EnterStepMode", int, P)
gets = sig("fmi3GetString", int, P, ctypes.POINTER(U), S, ctypes.POINTER(C), S)
sets = sig("fmi3SetString", int, P, ctypes.POINTER(U), S, ctypes.POINTER(C), S)
debug = sig("fmi3SetDebugLogging", int, P, B, S, ctypes.POINTER(C))

def cs(name): return cs_new(name.encode(), TOKEN, RES, False, False, False, False, None, 0, None, logger, None)
def me(name): return me_new(name.encode(), TOKEN, RES, False, False, None, logger)
def vrs(*v): return (U * len(v))(*v)
def dbl(*v): return (D * len(v))(*v)
bools = [B() for _ in range(5)]
last = D()
def do_step(c, t, h):
    return step(c, t, h, True, *[ctypes.byref(b) for b in bools[:3]], ctypes.byref(last))
def init(c): return enter(c, False, 0.0, 0.0, False, 0.0) or exit_(c)
def outputs(c):
    v = (D * NOUT)(); getf(c, vrs(*range(FIRST_OUT, FIRST_OUT + NOUT)), NOUT, v, NOUT); return list(v)
out = {}
def case(name, call):
    n0 = len(messages); st = call(); out[name] = [st, messages[n0:]]

NVAR, INPUT, PARAM, FIRST_OUT, METHOD = map(int, sys.argv[5:10])
a, twin = cs("a"), cs("twin")
# wrong order
case("DoStep before initialization", lambda: do_step(a, 0.0, 0.01))
case("ExitInitializationMode before Enter", lambda: exit_(a))
case("Terminate before initialization", lambda: term(a))
case("SetTime on co-simulation", lambda: settime(a, 1.0))
case("EnterEventMode on co-simulation", lambda: event(a))
case("EnterStepMode (no event mode)", lambda: stepmode(a))
case("NaN start time", lambda: enter(a, False, 0.0, math.nan, False, 0.0))
case("scalar count mismatch", lambda: setf(a, vrs(PARAM), 1, dbl(1.0, 2.0), 2))
case("set the independent variable", lambda: setf(a, vrs(NVAR), 1, dbl(1.0), 1))
case("unknown value reference", lambda: getf(a, vrs(NVAR + 7), 1, dbl(0.0), 1))
case("no Int32 variables", lambda: geti(a, vrs(0), 1, (ctypes.c_int32 * 1)(), 1))
case("directional derivative", lambda: dirder(a, None, 0, None, 0, None, 0, None, 0))
case("GetString of a Float64", lambda: gets(a, vrs(PARAM), 1, (C * 1)(), 1))
method = (C * 1)(); assert gets(a, vrs(METHOD), 1, method, 1) == 0
case("unknown integrator method", lambda: sets(a, vrs(METHOD), 1, (C * 1)(b"euler"), 1))
assert sets(a, vrs(METHOD), 1, (C * 1)(method[0]), 1) == 0  # set again: the refusal no longer fails initialization
case("unknown log category", lambda: debug(a, True, 1, (C * 1)(b"logEverything")))
case("number of states into NULL", lambda: nx_(a, None))
assert debug(a, False, 1, (C * 1)(b"logStatusError")) == 0  # the host switches error messages off ...
n0 = len(messages); out["silenced"] = [do_step(a, 0.0, 0.01), messages[n0:]]
assert debug(a, True, 1, (C * 1)(b"logStatusError")) == 0  # ... and on again
assert init(a) == 0 and init(twin) == 0, messages
case("EnterInitializationMode twice", lambda: enter(a, False, 0.0, 0.0, False, 0.0))
case("NaN parameter", lambda: setf(a, vrs(PARAM), 1, dbl(math.nan), 1))
case("DoStep NaN step", lambda: do_step(a, 0.0, math.nan))
case("DoStep at the wrong time", lambda: do_step(a, 5.0, 0.01))
case("DoStep NULL outputs", lambda: step(a, 0.0, 0.01, True, None, None, None, None))
case("SetContinuousStates on co-simulation", lambda: setx(a, dbl(0.0), 1))
# bad state bytes
sp = P(); assert getst(a, ctypes.byref(sp)) == 0
n = S(); size(a, sp, ctypes.byref(n)); good = ctypes.create_string_buffer(n.value); ser(a, sp, good, n.value)
raw = bytearray(good.raw)
flipped = bytearray(raw); flipped[-1] ^= 1
guid = bytearray(raw); guid[9] ^= 1
fresh = P()
for label, data in [("random bytes", bytes(range(256)) * 3), ("truncated", bytes(raw[:-8])),
                    ("checksum", bytes(flipped)), ("other model's GUID", bytes(guid)), ("too short", b"MBSS")]:
    case("deserialize " + label, lambda: deser(a, data, len(data), ctypes.byref(fresh)))
case("SetFMUState with a made-up handle", lambda: setst(a, P(0x1234)))
# NaN input: the step is discarded, the instance stays at its last good point
setf(a, vrs(INPUT), 1, dbl(math.nan), 1)
case("DoStep with a NaN input", lambda: do_step(a, 0.0, 0.01))
out["lastSuccessfulTime after the NaN input"] = last.value
setf(a, vrs(INPUT), 1, dbl(0.0), 1)
# after all that, `a` runs on exactly like its untouched twin
rows_a, rows_b = [], []
for k in range(10):
    assert do_step(a, 0.01 * k, 0.01) == 0 and do_step(twin, 0.01 * k, 0.01) == 0, messages[-3:]
    rows_a.append(outputs(a)); rows_b.append(outputs(twin))
out["same as twin"] = rows_a == rows_b
# model exchange
m = me("m")
case("SetContinuousStates before initialization", lambda: setx(m, dbl(0.0), 1))
case("DoStep on model exchange", lambda: do_step(m, 0.0, 0.01))
assert init(m) == 0
case("SetContinuousStates in event mode", lambda: setx(m, dbl(0.0), 1))
case("EnterEventMode in event mode", lambda: event(m))
assert upd(m, *[ctypes.byref(b) for b in bools], ctypes.byref(last)) == 0 and cont(m) == 0
case("UpdateDiscreteStates in continuous-time mode",
     lambda: upd(m, *[ctypes.byref(b) for b in bools], ctypes.byref(last)))
nx = S(); nx_(m, ctypes.byref(nx)); N = nx.value
case("SetTime NaN", lambda: settime(m, math.nan))
case("SetContinuousStates NaN", lambda: setx(m, dbl(*([math.nan] * N)), N))
case("SetContinuousStates wrong length", lambda: setx(m, dbl(*([0.0] * (N + 1))), N + 1))
case("derivatives wrong length", lambda: getdx(m, dbl(*([0.0] * (N + 1))), N + 1))
setf(m, vrs(INPUT), 1, dbl(math.inf), 1)
case("derivatives with an infinite input", lambda: getdx(m, dbl(*([0.0] * N)), N))
# wrong instance pointers: refused before anything is read from them (no logger known: stderr)
free(m); free(twin)
case("DoStep on a freed instance", lambda: do_step(twin, 0.0, 0.01))
case("GetFloat64 on a made-up pointer", lambda: getf(P(0xdeadbeef), vrs(0), 1, dbl(0.0), 1))
case("SetContinuousStates on NULL", lambda: setx(None, dbl(0.0), 1))
free(m); free(P(0xdeadbeef))
out["scheduled execution"] = se_new(b"s", TOKEN, RES, False, False, None, logger, None, None, None) is None
def refused(token, res):
    return cs_new(b"t", token, res, False, False, False, False, None, 0, None, logger, None) is None
out["wrong token"] = refused(b"{not-the-token}", RES)
out["relative resources"] = refused(TOKEN, b"resources/")
out["no resources"] = refused(TOKEN, None)
out["instantiation messages"] = messages[-4:]
free(a)
print("RESULT " + json.dumps(out))
'''


def _asan_library(sources, out):
    """The FMU's sources/ compiled with AddressSanitizer and UBSan (every finding fatal), and the runtime to
    preload into Python; None without gcc's libasan."""
    cc = native.compiler()
    runtime = subprocess.run([cc, "-print-file-name=libasan.so"], capture_output=True, text=True).stdout.strip()
    if not os.path.isabs(runtime) or not os.path.exists(runtime):
        return None
    r = subprocess.run([cc, "-O1", "-g", "-std=c99", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                        "-shared", "-fPIC", "-I", str(sources), "-o", str(out), *map(str, sorted(sources.glob("*.c"))),
                        "-lm"], capture_output=True, text=True)
    return (out, runtime) if r.returncode == 0 else None


def fmu_library(d, md, tmp_path, build):
    """The library of the FMU unpacked in d and the environment to load it in: as shipped, or ("sanitized") its
    sources/ built with AddressSanitizer and UBSan (skipped without gcc's libasan)."""
    lib, env = d / "binaries" / "x86_64-linux" / f"{md.coSimulation.modelIdentifier}.so", dict(os.environ)
    if build == "sanitized":
        asan = _asan_library(d / "sources", tmp_path / "asan.so")
        if asan is None:
            pytest.skip("no AddressSanitizer runtime (gcc's libasan)")
        lib = asan[0]
        env.update(LD_PRELOAD=asan[1], ASAN_OPTIONS="detect_leaks=0:abort_on_error=1")
    return lib, env


@pytest.mark.parametrize("build", ["shipped", "sanitized"])
def test_hostile_calls_are_errors_with_messages(built, tmp_path, build):
    """Each hostile call in a child process: fmi3Error (fmi3Discard for a step with a NaN input) with a message
    through the logger (stderr where no logger is known), and the instance runs on like an untouched twin; the
    same calls on the FMU's sources/ built with AddressSanitizer and UBSan report nothing."""
    fmu = built["driven_crank"][0]
    d = tmp_path / "fmu"
    zipfile.ZipFile(fmu).extractall(d)
    md = read_model_description(str(fmu))
    engine_vars = [v for v in md.modelVariables if v.name != "time"]
    out_vrs = sorted(v.valueReference for v in engine_vars if v.causality == "output")
    first_out, nout = out_vrs[0], len(out_vrs)
    assert out_vrs == list(range(first_out, first_out + nout))
    inp = next(v.valueReference for v in engine_vars if v.causality == "input")
    par = next(v.valueReference for v in engine_vars if v.causality == "parameter" and v.type == "Float64"
               and v.variability == "tunable")
    method = next(v.valueReference for v in engine_vars if v.name == "integrator.method")
    lib, env = fmu_library(d, md, tmp_path, build)
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    r = subprocess.run([sys.executable, str(script), str(lib), str(d / "resources") + os.sep, md.guid, str(nout),
                        str(len(engine_vars)), str(inp), str(par), str(first_out), str(method)], capture_output=True,
                       text=True, timeout=120, env=env)
    assert r.returncode == 0, (r.returncode, r.stdout[-3000:], r.stderr[-3000:])
    assert "runtime error" not in r.stderr and "AddressSanitizer" not in r.stderr, r.stderr[-3000:]
    out = json.loads(r.stdout.split("RESULT ", 1)[1])
    discarded = out.pop("DoStep with a NaN input")
    assert discarded[0] == 2 and any("not finite" in msg for _, _, msg in discarded[1]), discarded
    assert out.pop("lastSuccessfulTime after the NaN input") == 0.0
    assert out.pop("same as twin") is True
    assert out.pop("silenced") == [3, []]  # refused, and not logged: the host switched logStatusError off
    for key in ("scheduled execution", "wrong token", "relative resources", "no resources"):
        assert out.pop(key) is True, key
    said = [msg for _, _, msg in out.pop("instantiation messages")]
    assert any("does not match" in s for s in said) and any("not absolute" in s for s in said), said
    no_logger = {"DoStep on a freed instance", "GetFloat64 on a made-up pointer", "SetContinuousStates on NULL"}
    for name, (status, logged) in out.items():
        assert status == 3, (name, status, logged)  # fmi3Error
        if name in no_logger:
            continue
        assert logged and logged[-1][0] == 3 and logged[-1][1] == "logStatusError" and logged[-1][2], (name, logged)
    assert r.stderr.count("not a live instance of this FMU") >= 3 and "NULL instance" in r.stderr, r.stderr


# ---- the command line -------------------------------------------------------------------------------------
def test_fmi3_is_native_only(tmp_path):
    with pytest.raises(ValueError, match="native kind only"):
        mbsfmu.build_fmu(REPO / "models" / "pendulum.yaml", tmp_path, fmi="3")
    with pytest.raises(ValueError, match="unknown FMI version"):
        mbsfmu.build_fmu(REPO / "models" / "pendulum.yaml", tmp_path, kind="native", fmi="4")
    r = subprocess.run([sys.executable, "-m", "mbsfmu.cli", "build", "--fmi", "3",
                        str(REPO / "models" / "pendulum.yaml"), "-o", str(tmp_path)], capture_output=True, text=True,
                       timeout=120, env=os.environ)
    assert r.returncode != 0 and len(r.stderr.strip().splitlines()) == 1 and "--kind native" in r.stderr, r.stderr
    assert not list(tmp_path.iterdir())


def _info_elements(fmu, capsys):
    """{FMI 3.0 array: [FMI 2.0 name of element 1, 2, ...]} as `mbsfmu info` prints them."""
    from mbsfmu.cli import main
    capsys.readouterr()
    assert main(["info", str(fmu)]) == 0
    out = {}
    for line in capsys.readouterr().out.splitlines():
        if line.strip().startswith("FMI 2.0: "):
            pairs = [p.split(" = ") for p in line.strip()[len("FMI 2.0: "):].split(", ")]
            out[pairs[0][0].rsplit("[", 1)[0]] = [e for _, e in pairs]
    return out


@pytest.mark.parametrize("model", ["crane", "robot_arm_elastic"])
def test_info_names_both_versions_and_a_host_reaches_the_same_variable_under_either(built, model, capsys):
    """A start value under the FMI 2.0 name of an array element (F_bridge.y) is unknown to an FMI 3.0 host:
    `mbsfmu info` of the FMI 3.0 FMU prints each array's FMI 2.0 names, that of the FMI 2.0 FMU each scalar's
    FMI 3.0 element. Held against the two FMUs themselves: input element k set to 1 in the FMI 3.0 FMU and the
    scalar info names set to 1 in the FMI 2.0 FMU give the same outputs, element for element under those names."""
    fmu3, fmu2 = built[model]
    arrays = _info_elements(fmu3, capsys)
    md3 = {v.name: v for v in read_model_description(str(fmu3)).modelVariables}
    assert arrays and set(arrays) == {n for n, v in md3.items() if v.dimensions and v.causality != "local"}
    capsys.readouterr()
    from mbsfmu.cli import main
    main(["info", str(fmu2)])
    text = capsys.readouterr().out
    for a, names in arrays.items():
        for k, n in enumerate(names, 1):
            if not n.startswith("der("):  # the derivatives are local: info lists its parameters, inputs, outputs
                assert re.search(rf"^    {re.escape(n)} .*\(FMI 3\.0: {re.escape(a)}\[{k}\]\)$", text, re.M), (a, k, n)
    for a in (a for a, v in md3.items() if v.causality == "input" and v.dimensions):
        for k, n in enumerate(arrays[a]):
            start = np.zeros(len(arrays[a]))
            start[k] = 1.0
            r3 = simulate_fmu(str(fmu3), stop_time=0.05, output_interval=0.05, start_values={a: list(start)})
            r2 = simulate_fmu(str(fmu2), stop_time=0.05, output_interval=0.05, start_values={n: 1.0})
            for b, elements in arrays.items():
                if b in r3.dtype.names:
                    got = np.asarray(r3[b]).reshape(len(r3), -1)
                    want = np.column_stack([r2[e] for e in elements])
                    assert np.array_equal(got, want), (a, n, b)
            moved = [c for c in r2.dtype.names if c != "time" and r2[c][-1] != 0.0]
            assert moved, f"setting {n} moves nothing: the check would pass with any mapping"


def test_input_csv_under_an_fmi2_element_name_is_refused_naming_the_element(built, tmp_path, capsys):
    """`mbsfmu simulate FMI3.fmu --input` with a column F_bridge.y (FMI 2.0's name) or F_bridge (an array, one
    number per cell) stops before running, naming the FMI 3.0 element; q.* columns (scalars) still run."""
    from mbsfmu.cli import main
    fmu3, _ = built["crane"]
    for column, says in (("F_bridge.y", "F_bridge.y' is FMI 2.0's name of F_bridge[2], an element of the array input F_bridge"),
                         ("F_bridge", "F_bridge' is the array input F_bridge")):
        csv = tmp_path / "in.csv"
        csv.write_text(f"time,{column}\n0,1\n")
        capsys.readouterr()
        assert main(["simulate", str(fmu3), "--input", str(csv), "--stop", "0.1"]) == 1
        err = capsys.readouterr().err
        assert says in err and ("F_bridge.x, F_bridge.y, F_bridge.z" in err or "where it is F_bridge.y" in err), err
    q = next(v.name for v in read_model_description(str(fmu3)).modelVariables if v.name.startswith("q."))
    csv.write_text(f"time,{q}\n0,1\n")
    assert main(["simulate", str(fmu3), "--input", str(csv), "--stop", "0.1"]) == 0


# ---- a plain C host, where no Python can be found ---------------------------------------------------------
@pytest.fixture(scope="module")
def host(tmp_path_factory):
    exe = tmp_path_factory.mktemp("host3") / "fmu3_host"
    subprocess.run([native.compiler(), "-O2", "-std=c99", "-Wall", "-Werror", "-o", str(exe), str(HOST), "-ldl"],
                   check=True)
    return exe


def _rows(stdout):
    return np.array([[float(x) for x in ln.split()[1:]] for ln in stdout.splitlines() if ln.startswith("OUT ")])


def test_plain_c_host_cs_and_me_without_python(built, host, tmp_path):
    """The C importer in a mount namespace where every Python installation is hidden: co-simulation equal to
    fmpy's run of the same FMU bit for bit; model exchange by explicit Euler equal to the same Euler steps in
    numpy over the in-process right-hand side."""
    from test_fmu_native import run_without_python
    models = ["double_pendulum", "spinning_top", "flexible_pendulum"]
    runs, n, h = {}, 30, 1e-3
    for m in models:
        fmu = built[m][0]
        d = tmp_path / m
        zipfile.ZipFile(fmu).extractall(d)
        md = read_model_description(str(fmu))
        outs = [f"{v.valueReference}:{_size(v)}" for v in md.modelVariables if v.causality == "output"]
        lib = d / "binaries" / "x86_64-linux" / f"{md.coSimulation.modelIdentifier}.so"
        base = [str(host), str(lib), str(d / "resources") + "/", md.guid, "-o", ",".join(outs),
                "-n", str(n), "-h", str(h), "-m"]
        runs[m] = (base, base + ["-E"])
    chunks = run_without_python({(m, k): args for m, both in runs.items() for k, args in zip(("cs", "me"), both)},
                                tmp_path)
    for m in models:
        cs, me = _rows(chunks[m, "cs"]), _rows(chunks[m, "me"])
        assert "LIBPYTHON no" in chunks[m, "cs"] and "DONE" in chunks[m, "cs"] and "DONE" in chunks[m, "me"], m
        fmu = built[m][0]
        md = read_model_description(str(fmu))
        names = [v.name for v in md.modelVariables if v.causality == "output"]
        ref = simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=n * h, output_interval=h, output=names)
        assert cs.tolist() == np.column_stack([ref["time"], _columns(ref, names)]).tolist(), m
        # model exchange: x += h·f(t, x) in numpy over the engine in-process, y.* and yd.* compared
        sim = Simulation(json.loads(json.dumps(SCENES[m].spec)))
        sim.initialize(0.0)
        x = np.array(sim.x)
        euler = [x.copy()]
        for k in range(n):
            x = x + h * np.array(sim.f(k * h, x))
            euler.append(x.copy())
        flat = [e for k in names for e in _elements(m)[k]]  # the printed columns after t
        cols = [flat.index(e) + 1 for v in md.modelVariables if v.derivative is not None for e in _elements(m)[v.derivative.name]]
        np.testing.assert_allclose(me[:, cols], np.array(euler), rtol=0, atol=1e-12, err_msg=m)


def test_sources_rebuild_the_fmi3_library(built, host, tmp_path):
    """sources/ alone, compiled with the README's command, gives a library that runs like the shipped one."""
    fmu = built["pendulum"][0]
    d = tmp_path / "fmu"
    zipfile.ZipFile(fmu).extractall(d)
    md = read_model_description(str(fmu))
    readme = (d / "sources" / "README").read_text()
    assert "FMI 3.0" in readme and "x86_64-linux" in readme
    cmd = next(ln.strip() for ln in readme.splitlines() if ln.strip().startswith("cc "))
    subprocess.run(cmd, shell=True, cwd=d / "sources", check=True, capture_output=True)
    rebuilt = d / "sources" / f"{md.coSimulation.modelIdentifier}.so"
    outs = ",".join(f"{v.valueReference}:{_size(v)}" for v in md.modelVariables if v.causality == "output")
    runs = [subprocess.run([str(host), str(lib), str(d / "resources") + "/", md.guid, "-o", outs, "-n", "20"],
                           capture_output=True, text=True, timeout=60).stdout
            for lib in (rebuilt, d / "binaries" / "x86_64-linux" / rebuilt.name)]
    assert "DONE" in runs[0] and _rows(runs[0]).tolist() == _rows(runs[1]).tolist()
    cmake = (d / "sources" / "CMakeLists.txt").read_text()
    assert "fmi3.c" in cmake and "fmi2.c" not in cmake
