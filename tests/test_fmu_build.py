"""FMU build: modelDescription validity, simulation through fmpy, isolation of several FMUs.

Most tests use a stand-in runtime (a damped oscillator with the same `Simulation` interface as
mbsfmu.simulation) so that they do not depend on the multibody code; the tests at the end use the
real runtime with a scene when it is available.
"""
from __future__ import annotations

import math
import re
import shutil
import textwrap
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from mbsfmu.fmu import build_fmu  # noqa: E402
from mbsfmu.fmu.build import forbidden_imports  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
PKG = REPO / "src" / "mbsfmu"

OSC_SCENE = textwrap.dedent("""\
    mbsfmu: 1
    name: {name}
    description: damped oscillator m x'' + c x' + k x = q.x + F_ext.x
    gravity: [0, 0, 0]
    parameters:
      k: {{value: 4.0, description: stiffness}}
      c: {{value: 0.1, description: damping}}
      m: {{value: 1.0, description: mass}}
      x0: {{value: {x0}, description: initial position}}
    bodies:
      mass:
        parent: world
        joint: {{type: prismatic, axis: [1, 0, 0], coordinates: [x], initial: {{x: x0}}}}
        mass: m
        inertia: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    forces:
      - {{type: joint_spring_damper, coordinate: x, stiffness: k, damping: c}}
      - {{type: force, body: mass, input: F_ext}}
    integrator: {{method: dopri5, rtol: 1e-10, atol: 1e-12}}
    experiment: {{start: 0, stop: 2, step: 0.01}}
    """)


def osc_scene(name="osc", x0=1.0):
    import mbsfmu
    return mbsfmu.loads(OSC_SCENE.format(name=name, x0=x0))


@pytest.fixture(scope="module")
def osc_fmu(tmp_path_factory):
    out = tmp_path_factory.mktemp("fmu")
    return build_fmu(osc_scene("osc"), out)


def test_validates_clean(osc_fmu):
    assert osc_fmu.name == "osc.fmu"
    assert validate_fmu(str(osc_fmu)) == []


def test_model_description(osc_fmu):
    md = read_model_description(str(osc_fmu))
    assert md.fmiVersion == "2.0"
    assert md.modelName == "osc"
    assert md.generationTool.startswith("mbsfmu ")
    cs = md.coSimulation
    assert cs.modelIdentifier == "osc"
    assert cs.canHandleVariableCommunicationStepSize
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    de = md.defaultExperiment
    assert (float(de.startTime), float(de.stopTime), float(de.stepSize)) == (0.0, 2.0, 0.01)
    assert float(de.tolerance) == 1e-10
    names = [v.name for v in md.modelVariables]
    assert names == ["k", "c", "m", "x0", "integrator.method", "integrator.rtol", "integrator.atol",
                     "integrator.max_step", "integrator.step", "q.x", "F_ext.x", "F_ext.y", "F_ext.z", "y.x", "yd.x"]
    assert [v.valueReference for v in md.modelVariables] == list(range(len(names)))  # = the engine's table
    byname = {v.name: v for v in md.modelVariables}
    assert byname["y.x"].unit == "m" and byname["y.x"].causality == "output"
    assert byname["y.x"].initial == "calculated" and byname["y.x"].start is None
    assert byname["q.x"].causality == "input" and float(byname["q.x"].start) == 0.0
    assert byname["k"].variability == "tunable" and float(byname["k"].start) == 4.0
    s = byname["integrator.method"]
    assert (s.type, s.variability, s.start) == ("String", "fixed", "dopri5")
    assert all(v.description for v in md.modelVariables)
    assert {"N", "m", "m/s"} <= {u.name for u in md.unitDefinitions}
    assert [u.variable.name for u in md.outputs] == ["y.x", "yd.x"]
    assert [u.variable.name for u in md.initialUnknowns] == ["y.x", "yd.x"]
    assert all(u.dependencies == [] for u in md.outputs + md.initialUnknowns)
    # dependencies="" is written explicitly (no feedthrough), not left out
    xml = zipfile.ZipFile(osc_fmu).read("modelDescription.xml").decode()
    root = ET.fromstring(xml)
    for u in root.find("ModelStructure").iter("Unknown"):
        assert u.get("dependencies") == ""


def test_runtime_copy(osc_fmu):
    names = zipfile.ZipFile(osc_fmu).namelist()
    rt = [n for n in names if re.match(r"resources/mbsfmu_rt_[0-9a-f]+/", n)]
    assert rt, names
    pkg = rt[0].split("/")[1]
    # the engine's seam, its library and sources: no multibody Python, no numpy-based reference
    for part in ("errors.py", "engine/__init__.py", "engine/api.py", "engine/build.py", "engine/tree.c", "engine/instance.c", "engine/ode.c"):
        assert f"resources/{pkg}/{part}" in names
    assert [n for n in names if re.fullmatch(rf"resources/{pkg}/engine/libmbsfmu_engine_\w+\.so\.1", n)]
    assert not [n for n in names if re.search(r"/(bodies|scene|equations|integrators)/|cli\.py|simulation\.py", n)]
    assert "resources/mbsfmu_scene.bin" in names
    assert not [n for n in names if n.startswith("resources/pythonfmu/")]  # only pythonfmu's binary is needed
    scripts = [n for n in names if re.fullmatch(r"resources/mbsfmu_osc_[0-9a-f]+\.py", n)]
    assert len(scripts) == 1
    slavemodule = zipfile.ZipFile(osc_fmu).read("resources/slavemodule.txt").decode().strip()
    assert f"resources/{slavemodule}.py" == scripts[0]
    z = zipfile.ZipFile(osc_fmu)
    sources = {n: z.read(n) for n in names if n.startswith(f"resources/{pkg}/") and n.endswith(".py")}
    assert forbidden_imports(sources) == []
    for n, src in sources.items():
        assert not re.search(rb"^(from|import)\s+(mbsfmu|numpy|scipy)\b", src, re.M), n  # numpy only lazily (tests)
    assert b"pickle" not in z.read(scripts[0])


def test_build_leaves_interpreter_clean(tmp_path):
    import sys
    path_before = list(sys.path)
    mods_before = set(sys.modules)
    fmu = build_fmu(osc_scene("clean"), tmp_path)
    assert sys.path == path_before
    new = {m for m in set(sys.modules) - mods_before if m.startswith(("mbsfmu_rt_", "mbsfmu_clean"))}
    assert new == set()
    assert fmu.exists()


def _signal(t, name, value):
    return np.array([(ti, value(ti)) for ti in t], dtype=[("time", np.float64), (name, np.float64)])


def test_simulate_with_input(osc_fmu):
    t = np.linspace(0, 2, 11)
    res = simulate_fmu(str(osc_fmu), stop_time=2.0, step_size=0.01,
                       input=_signal(t, "q.x", lambda ti: 4.0), output=["y.x", "yd.x"])
    # constant force 4 N on k=4: oscillation about x=1 from x0=1 -> stays at 1
    assert res["time"][-1] == pytest.approx(2.0)
    assert np.allclose(res["y.x"], 1.0, atol=1e-9)
    res0 = simulate_fmu(str(osc_fmu), stop_time=2.0, step_size=0.01, output=["y.x"],
                        start_values={"k": 9.0, "c": 0.0})
    tt = res0["time"]
    assert np.allclose(res0["y.x"], np.cos(3.0 * tt), atol=1e-6)


def test_nan_input_discards_and_host_survives(osc_fmu, tmp_path):
    sig = np.array([(0.0, 0.0), (0.5, 0.0), (0.5, math.nan), (2.0, math.nan)],
                   dtype=[("time", np.float64), ("q.x", np.float64)])
    # The FMU answers fmi2Discard and reports fmi2Terminated; fmpy then ends the run at the last
    # successful time (t = 0.5) instead of raising.
    res = simulate_fmu(str(osc_fmu), stop_time=2.0, step_size=0.01, input=sig, output=["y.x"])
    assert res["time"][-1] == pytest.approx(0.5)
    assert np.isfinite(res["y.x"]).all()
    # the host (this process) and the FMU are still usable
    res = simulate_fmu(str(osc_fmu), stop_time=0.1, step_size=0.01, output=["y.x"])
    assert np.isfinite(res["y.x"]).all()
    # the reason is logged (category logStatusDiscard)
    from fmpy.fmi1 import FMICallException
    f, vr = _instantiate(osc_fmu, tmp_path, "nanlog")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    f.setReal([vr["q.x"]], [math.inf])
    with pytest.raises(FMICallException):
        f.doStep(0.0, 0.01)
    assert [m for m in _messages("nanlog") if m[1:3] == (2, "logStatusDiscard") and "q.x is not finite" in m[3]]
    f.freeInstance()


MESSAGES = []   # (instance, status, category, message) from every FMU instantiated by _instantiate


def _log_message(component, instance, status, category, message):
    MESSAGES.append((instance.decode(), status, category.decode(), message.decode()))


def _callbacks():
    # One set of callbacks for the whole session: fmpy's C logger proxy keeps a single global
    # pointer to the last registered Python logger, so that logger must stay alive.
    global _CALLBACKS
    if _CALLBACKS is None:
        from ctypes import byref

        from fmpy import calloc, free
        from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        from fmpy.logging import addLoggerProxy
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(_log_message)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(byref(cb))
        _CALLBACKS = cb
    return _CALLBACKS


_CALLBACKS = None


def _instantiate(fmu_path, tmp_path, tag):
    md = read_model_description(str(fmu_path))
    unzipdir = fmpy.extract(str(fmu_path), str(tmp_path / tag))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=tag)
    fmu.instantiate(loggingOn=True, callbacks=_callbacks())
    vrs = {v.name: v.valueReference for v in md.modelVariables}
    return fmu, vrs


def _messages(tag):
    return [m for m in MESSAGES if m[0] == tag]


def test_two_fmus_in_one_process(tmp_path):
    a = build_fmu(osc_scene("osc_a"), tmp_path / "a")
    b = build_fmu(osc_scene("osc_b", x0=2.0), tmp_path / "b")
    fa, va = _instantiate(a, tmp_path, "a")
    fb, vb = _instantiate(b, tmp_path, "b")
    fb.setReal([vb["k"]], [9.0])
    fa.setReal([va["c"]], [0.0])
    fb.setReal([vb["c"]], [0.0])
    for f in (fa, fb):
        f.setupExperiment(startTime=0.0)
        f.enterInitializationMode()
        f.exitInitializationMode()
    t, h = 0.0, 0.01
    for _ in range(100):
        fa.doStep(t, h)
        fb.doStep(t, h)
        t += h
    ya = fa.getReal([va["y.x"]])[0]
    yb = fb.getReal([vb["y.x"]])[0]
    assert ya == pytest.approx(math.cos(2.0 * t), abs=1e-8)
    assert yb == pytest.approx(2.0 * math.cos(3.0 * t), abs=1e-8)
    assert fa.getString([va["integrator.method"]]) == [b"dopri5"]
    for f in (fa, fb):
        f.terminate()
        f.freeInstance()


def test_fmu_state_roundtrip(osc_fmu, tmp_path):
    f, vr = _instantiate(osc_fmu, tmp_path, "st")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    t, h = 0.0, 0.05
    for _ in range(5):
        f.doStep(t, h)
        t += h
    state = f.getFMUstate()
    blob = f.serializeFMUstate(state)
    y_mid = f.getReal([vr["y.x"]])[0]
    for _ in range(5):
        f.doStep(t, h)
        t += h
    y_end = f.getReal([vr["y.x"]])[0]
    f.setFMUstate(state)
    assert f.getReal([vr["y.x"]])[0] == y_mid
    t = 0.25
    for _ in range(5):
        f.doStep(t, h)
        t += h
    assert f.getReal([vr["y.x"]])[0] == y_end
    state2 = f.deSerializeFMUstate(blob)
    f.setFMUstate(state2)
    assert f.getReal([vr["y.x"]])[0] == y_mid
    f.freeFMUstate(state)
    f.freeFMUstate(state2)
    f.terminate()
    f.freeInstance()


def test_integration_error_is_discard(tmp_path):
    from fmpy.fmi2 import fmi2LastSuccessfulTime
    from fmpy.fmi1 import FMICallException
    # a push exp(300 t), finite over the experiment [0, 2] (the loader's check), overflows at t = 709.78/300 =
    # 2.366 s, inside the step from 2.3 s, where a host that runs on past the experiment gets there
    pushed = OSC_SCENE.format(name="pushed", x0=1.0).replace(
        "forces:\n", "forces:\n  - {type: force, body: mass, value: [exp(300*t), 0, 0]}\n")
    import mbsfmu
    f, vr = _instantiate(build_fmu(mbsfmu.loads(pushed), tmp_path / "fmu"), tmp_path, "div")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    t = 0.0
    with pytest.raises(FMICallException) as err:
        for _ in range(100):
            f.doStep(t, 0.1)
            t += 0.1
    assert err.value.status == 2  # fmi2Discard
    assert t > 0  # some steps succeeded first
    # FMI 2.0: the slave computed a subinterval of the step; it goes on from the time it reached (as the native FMU)
    last = f.getRealStatus(fmi2LastSuccessfulTime)
    assert t < last < t + 0.1
    with pytest.raises(FMICallException) as err:   # not refused (fmi2Error): the instance is at `last`
        f.doStep(last, 0.1)
    assert err.value.status == 2
    # the instance is still alive: state can be read, parameters changed, and it terminates cleanly
    assert isinstance(f.getReal([vr["y.x"]])[0], float)
    f.terminate()
    f.freeInstance()


def test_bad_parameter_and_fixed_parameter(osc_fmu, tmp_path):
    from fmpy.fmi1 import FMICallException
    f, vr = _instantiate(osc_fmu, tmp_path, "bad")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    with pytest.raises(FMICallException) as err:  # outside its domain: refused when set (issue 22)
        f.setReal([vr["m"]], [math.inf])
    assert err.value.status == 3 and f.getReal([vr["m"]]) == [1.0]
    with pytest.raises(FMICallException) as err:  # fmi2Error with the reason (issue 12; the loader shim)
        f.exitInitializationMode()
    assert err.value.status == 3
    assert [m for m in _messages("bad") if m[1:3] == (3, "logStatusError") and "m = inf is not finite" in m[3]]
    f.freeInstance()

    f, vr = _instantiate(osc_fmu, tmp_path, "fixed")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    with pytest.raises(FMICallException):       # fixed: refused (fmi2Error, logged) after initialization
        f.setReal([vr["integrator.rtol"]], [1e-3])
    assert f.getReal([vr["integrator.rtol"]]) == [1e-10]
    assert _messages("fixed")[-1][1:3] == (3, "logStatusError") and "fixed" in _messages("fixed")[-1][3]
    f.setReal([vr["k"]], [9.0])                 # tunable: takes effect
    assert f.getReal([vr["k"]]) == [9.0]
    f.doStep(0.0, 0.01)
    f.terminate()
    f.freeInstance()


def test_generated_script_is_template_free(osc_fmu):
    z = zipfile.ZipFile(osc_fmu)
    mod = z.read("resources/slavemodule.txt").decode().strip()
    entry, src = (z.read(f"resources/{name}.py").decode() for name in (mod, f"{mod}_slave"))
    assert "@" not in entry and "@" not in src.replace("@staticmethod", "")
    assert re.search(r"^class (\w+)\(\s*Fmi2Slave\s*\)\s*:", src, re.M)
    assert f"from {mod}_slave import MbsfmuSlave" in entry


# --- with the real runtime -------------------------------------------------------------------

def _real_runtime_available():
    return (PKG / "simulation.py").exists() and (PKG / "scene" / "__init__.py").exists()


needs_real = pytest.mark.skipif(not _real_runtime_available(), reason="mbsfmu.simulation not available")

REAL_SCENE = textwrap.dedent("""\
    mbsfmu: 1
    name: fmu_pendulum
    description: Pendulum for the FMU tests
    parameters:
      L: 1.0
      m: {value: 1.0, description: mass}
    bodies:
      link:
        parent: world
        joint: {type: revolute, axis: [0, 1, 0], coordinates: [phi], initial: {phi: 0.5}}
        mass: m
        center_of_mass: [0, 0, -L]
        inertia: {xx: 1e-3, yy: 1e-3, zz: 1e-3}
    forces:
      - {type: force, body: link, at: [0, 0, -1], input: F_tip, frame: world}
    integrator: {method: dopri5, rtol: 1e-8, atol: 1e-10}
    experiment: {start: 0, stop: 1, step: 0.01}
    """)

ELASTIC_SCENE = textwrap.dedent("""\
    mbsfmu: 1
    name: fmu_flex
    bodies:
      hub:
        parent: world
        joint: {type: revolute, axis: [0, 0, 1], coordinates: [theta]}
        mass: 1.0
        inertia: {xx: 0.01, yy: 0.01, zz: 0.01}
      beam:
        parent: hub
        joint: {type: fixed, at: [0.1, 0, 0]}
        elastic:
          beam: {length: 1.0, EI: [10.0, 10.0], rhoA: 0.5, elements: 4, modes: 2, clamped: start}
          damping_ratio: 0.01
    experiment: {start: 0, stop: 0.1, step: 0.01}
    """)


@pytest.fixture(scope="module")
def real_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("real")


@pytest.fixture(scope="module")
def real_fmu(real_dir):
    if not _real_runtime_available():
        pytest.skip("mbsfmu.simulation / mbsfmu.scene not available yet")
    path = real_dir / "fmu_pendulum.yaml"
    path.write_text(REAL_SCENE)
    return build_fmu(path, real_dir / "out")


@pytest.fixture(scope="module")
def pendulum2_fmu(real_dir):
    if not _real_runtime_available():
        pytest.skip("mbsfmu.simulation / mbsfmu.scene not available yet")
    import mbsfmu
    scene = mbsfmu.load(REPO / "models" / "double_pendulum.yaml")
    return build_fmu(scene, real_dir / "out2")     # a loaded scene object works too


def _real_sim(yaml_path_or_text):
    import json

    import mbsfmu
    from mbsfmu.simulation import Simulation
    scene = mbsfmu.load(yaml_path_or_text) if isinstance(yaml_path_or_text, Path) else mbsfmu.loads(yaml_path_or_text)
    return Simulation(json.loads(json.dumps(scene.spec)))


def test_real_validates_and_has_only_scene_variables(real_fmu, pendulum2_fmu):
    for fmu, sim in ((real_fmu, _real_sim(REAL_SCENE)),
                     (pendulum2_fmu, _real_sim(REPO / "models" / "double_pendulum.yaml"))):
        assert validate_fmu(str(fmu)) == []
        md = read_model_description(str(fmu))
        assert [(v.name, v.causality, v.variability) for v in md.modelVariables] == \
            [(v.name, v.causality, "fixed" if v.type == "String" else v.variability) for v in sim.variables]
        assert [v.valueReference for v in md.modelVariables] == list(range(len(sim.variables)))
        assert {u.variable.name for u in md.outputs} == {v.name for v in sim.variables if v.causality == "output"}
    md = read_model_description(str(real_fmu))
    names = [v.name for v in md.modelVariables]
    assert {"q.phi", "F_tip.x", "F_tip.y", "F_tip.z", "y.phi", "yd.phi", "L", "m",
            "integrator.method", "integrator.rtol", "integrator.atol", "integrator.max_step"} <= set(names)
    assert not [n for n in names if n.startswith(("q.phi1", "y.phi1", "y.x"))]  # nothing from other scenes
    byname = {v.name: v for v in md.modelVariables}
    assert byname["y.phi"].unit == "rad" and byname["yd.phi"].unit == "rad/s"
    assert byname["q.phi"].unit == "N.m" and byname["F_tip.x"].unit == "N"
    assert md.defaultExperiment.tolerance == "1e-08" or float(md.defaultExperiment.tolerance) == 1e-8


def test_real_runtime_is_clean(real_fmu):
    z = zipfile.ZipFile(real_fmu)
    names = z.namelist()
    pkg = next(n.split("/")[1] for n in names if n.startswith("resources/mbsfmu_rt_"))
    rt = [n for n in names if n.startswith(f"resources/{pkg}/")]
    assert not [n for n in rt if "/bodies/" in n or "/scene/" in n or "/fmu/" in n or "/bench/" in n
                or n.endswith("cli.py")]
    # the compiled engine travels with the FMU (no compiler needed on the target), its sources too
    assert [n for n in rt if re.search(r"/engine/libmbsfmu_engine_[0-9a-f]+\.so\.1$", n)]
    sources = {n: z.read(n) for n in rt if n.endswith(".py")}
    assert forbidden_imports(sources) == []
    for n, src in sources.items():
        assert not re.search(rb"^\s*(from|import)\s+mbsfmu\b", src, re.M), n
        assert not re.search(rb"\b(yaml|sympy|matplotlib)\b", src), n


@needs_real
def test_real_elastic_scene_packs_bodies(real_dir):
    path = real_dir / "fmu_flex.yaml"
    path.write_text(ELASTIC_SCENE)
    fmu = build_fmu(path, real_dir / "flex")
    names = zipfile.ZipFile(fmu).namelist()
    # the engine carries the elastic terms, or (until it does) the FMU carries the Python reference
    assert [n for n in names if re.search(r"/mbsfmu_rt_[0-9a-f]+/(engine/elastic\.c|bodies/__init__\.py)$", n)]
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    assert {"y.beam.q1", "y.beam.q2", "yd.beam.q1"} <= {v.name for v in md.modelVariables}
    res = simulate_fmu(str(fmu), stop_time=0.05, step_size=0.01, output=["y.theta", "y.beam.q1"])
    assert res["time"][-1] == pytest.approx(0.05)
    assert np.isfinite(res["y.beam.q1"]).all()


def test_real_simulates_like_in_process(real_fmu):
    t = np.array([0.0, 0.5, 0.5, 1.0])
    sig = np.array([(0.0, 0.0), (0.5, 0.0), (0.5, 2.0), (1.0, 2.0)],
                   dtype=[("time", np.float64), ("F_tip.x", np.float64)])
    res = simulate_fmu(str(real_fmu), stop_time=1.0, step_size=0.01, input=sig, output=["y.phi", "yd.phi"])
    assert res["time"][-1] == pytest.approx(1.0)
    assert res["y.phi"][0] == pytest.approx(0.5)
    # the same run in-process (communication points 0.01, input switched at 0.5)
    sim = _real_sim(REAL_SCENE)
    sim.initialize(0.0)
    tt, ys = 0.0, [sim.get("y.phi")]
    for i in range(100):
        sim.set("F_tip.x", 2.0 if i >= 50 else 0.0)
        sim.do_step(tt, 0.01)
        tt = (i + 1) * 0.01
        ys.append(sim.get("y.phi"))
    assert len(res) == len(ys)
    assert np.allclose(res["y.phi"], ys, rtol=0, atol=1e-9)
    del t


def test_two_real_fmus_interleaved(real_fmu, pendulum2_fmu, tmp_path):
    fa, va = _instantiate(real_fmu, tmp_path, "p1")
    fb, vb = _instantiate(pendulum2_fmu, tmp_path, "p2")
    sa, sb = _real_sim(REAL_SCENE), _real_sim(REPO / "models" / "double_pendulum.yaml")
    for f in (fa, fb):
        f.setupExperiment(startTime=0.0)
        f.enterInitializationMode()
        f.exitInitializationMode()
    assert _messages("p1") == [] and _messages("p2") == []
    sa.initialize(0.0)
    sb.initialize(0.0)
    t, h = 0.0, 0.01
    for i in range(30):
        fa.setReal([va["q.phi"], va["F_tip.z"]], [0.3, 1.0])
        sa.set("q.phi", 0.3)
        sa.set("F_tip.z", 1.0)
        fb.setReal([vb["q.phi2"]], [-0.2])
        sb.set("q.phi2", -0.2)
        try:
            fa.doStep(t, h)
            fb.doStep(t, h)
        except Exception:
            pytest.fail(f"{_messages('p1')} {_messages('p2')}")
        sa.do_step(t, h)
        sb.do_step(t, h)
        t = (i + 1) * h
    assert fa.getReal([va["y.phi"]])[0] == pytest.approx(sa.get("y.phi"), abs=1e-12)
    assert fb.getReal([vb["y.phi1"], vb["y.phi2"]]) == pytest.approx([sb.get("y.phi1"), sb.get("y.phi2")], abs=1e-12)
    for f in (fa, fb):
        f.terminate()
        f.freeInstance()


def test_real_nan_input_and_state(real_fmu, tmp_path):
    from fmpy.fmi1 import FMICallException
    f, vr = _instantiate(real_fmu, tmp_path, "nan")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    t, h = 0.0, 0.01
    for i in range(10):
        f.doStep(t, h)
        t = (i + 1) * h
    state = f.getFMUstate()
    blob = f.serializeFMUstate(state)
    y10 = f.getReal([vr["y.phi"], vr["yd.phi"]])
    f.setReal([vr["q.phi"]], [math.nan])
    with pytest.raises(FMICallException) as err:
        f.doStep(t, h)
    assert err.value.status == 2
    assert f.getReal([vr["y.phi"], vr["yd.phi"]]) == y10       # state untouched by the refused step
    f.setReal([vr["q.phi"]], [0.0])
    for i in range(10, 20):
        f.doStep(t, h)
        t = (i + 1) * h
    y20 = f.getReal([vr["y.phi"], vr["yd.phi"]])
    f.setFMUstate(f.deSerializeFMUstate(blob))               # back to t = 0.1, replay
    assert f.getReal([vr["y.phi"], vr["yd.phi"]]) == y10
    t = 0.1
    for i in range(10, 20):
        f.doStep(t, h)
        t = (i + 1) * h
    assert f.getReal([vr["y.phi"], vr["yd.phi"]]) == pytest.approx(y20, abs=1e-12)
    f.freeFMUstate(state)
    f.terminate()
    f.freeInstance()


MODELS = sorted((REPO / "models").glob("*.yaml"))


@needs_real
@pytest.mark.parametrize("model", MODELS, ids=[m.stem for m in MODELS])
def test_every_model_builds_validates_and_steps(model, tmp_path):
    fmu = build_fmu(model, tmp_path)
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    step = float(md.defaultExperiment.stepSize)
    f, vr = _instantiate(fmu, tmp_path, f"m_{model.stem}")
    f.setupExperiment(startTime=float(md.defaultExperiment.startTime))
    f.enterInitializationMode()
    f.exitInitializationMode()
    t = float(md.defaultExperiment.startTime)
    outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    for i in range(5):
        f.doStep(t, step)
        t += step
    assert np.isfinite(f.getReal(outs)).all()
    assert _messages(f"m_{model.stem}") == []
    f.terminate()
    f.freeInstance()


@needs_real
def test_real_q_input_alone_with_declared_force_input(real_fmu, tmp_path):
    f, vr = _instantiate(real_fmu, tmp_path, "qonly")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    f.setReal([vr["q.phi"]], [0.3])
    try:
        f.doStep(0.0, 0.01)
    except Exception:
        pytest.fail(str(_messages("qonly")))
    finally:
        f.freeInstance()
