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

STUB_SIMULATION = '''
"""Stand-in for mbsfmu.simulation: damped oscillator m*x'' + c*x' + k*x = q.x (+ F_ext.x)."""
import copy
import math
from dataclasses import dataclass

import numpy as np

from .errors import IntegrationError


@dataclass
class Variable:
    name: str
    causality: str
    variability: str
    type: str = "Real"
    unit: object = None
    description: str = ""
    start: object = 0.0


class Simulation:
    def __init__(self, spec):
        self.spec = spec
        p = spec.get("parameters", {})
        integ = spec.get("integrator", {})
        self.variables = [
            Variable("q.x", "input", "continuous", unit="N", description="generalized force on x"),
            Variable("F_ext.x", "input", "continuous", unit="N", description="force input, x"),
            Variable("y.x", "output", "continuous", unit="m", description="position"),
            Variable("yd.x", "output", "continuous", unit="m/s", description="velocity"),
            Variable("k", "parameter", "tunable", unit="N/m", description="stiffness", start=p.get("k", 4.0)),
            Variable("c", "parameter", "tunable", unit="N.s/m", description="damping", start=p.get("c", 0.1)),
            Variable("m", "parameter", "tunable", unit="kg", description="mass", start=p.get("m", 1.0)),
            Variable("integrator.method", "parameter", "fixed", type="String",
                     description="integration method", start=integ.get("method", "rk4")),
            Variable("integrator.rtol", "parameter", "fixed", unit=None,
                     description="relative tolerance", start=integ.get("rtol", 1e-6)),
        ]
        self._byname = {v.name: v for v in self.variables}
        self.reset()

    def reset(self):
        self.values = {v.name: v.start for v in self.variables if v.causality != "output"}
        self.time = 0.0
        self.x = np.array([float(self.spec.get("x0", 1.0)), 0.0])

    def set(self, name, value):
        if name not in self.values:
            raise KeyError(name)
        self.values[name] = value

    def get(self, name):
        if name == "y.x":
            return float(self.x[0])
        if name == "yd.x":
            return float(self.x[1])
        return self.values[name]

    def initialize(self, t0):
        self.time = t0
        self.x = np.array([float(self.spec.get("x0", 1.0)), 0.0])

    def _f(self, x):
        v = self.values
        return np.array([x[1], (v["q.x"] + v["F_ext.x"] - v["c"] * x[1] - v["k"] * x[0]) / v["m"]])

    def do_step(self, t, h):
        n = max(1, int(math.ceil(h / 1e-3)))
        dt = h / n
        x = self.x.copy()
        for i in range(n):
            k1 = self._f(x); k2 = self._f(x + dt / 2 * k1); k3 = self._f(x + dt / 2 * k2); k4 = self._f(x + dt * k3)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            if not np.all(np.isfinite(x)) or abs(x[0]) > 1e6:
                raise IntegrationError("state diverged", t + i * dt)
        self.x = x
        self.time = t + h

    def get_state(self):
        return copy.deepcopy({"x": self.x, "time": self.time, "values": self.values})

    def set_state(self, s):
        s = copy.deepcopy(s)
        self.x, self.time, self.values = s["x"], s["time"], s["values"]
'''


def stub_spec(name="osc", **extra):
    spec = {
        "name": name,
        "description": f"stub oscillator {name}",
        "parameters": {"k": 4.0, "c": 0.1, "m": 1.0},
        "bodies": {"mass": {"parent": "world"}},
        "integrator": {"method": "rk4", "rtol": 1e-6},
        "experiment": {"start": 0.0, "stop": 2.0, "step": 0.01},
    }
    spec.update(extra)
    return spec


@pytest.fixture(scope="module")
def stub_root(tmp_path_factory):
    """A fake package root: real errors.py, stub simulation.py, plus parts that must not be copied."""
    root = tmp_path_factory.mktemp("stubpkg")
    shutil.copy(PKG / "errors.py", root / "errors.py")
    (root / "simulation.py").write_text(STUB_SIMULATION)
    (root / "equations").mkdir()
    (root / "equations" / "__init__.py").write_text("from ..errors import ModelError  # noqa\n")
    (root / "integrators").mkdir()
    (root / "integrators" / "__init__.py").write_text("from mbsfmu.errors import IntegrationError  # noqa\n")
    (root / "bodies").mkdir()
    (root / "bodies" / "__init__.py").write_text('"""elastic bodies"""\nimport numpy  # noqa\n')
    (root / "scene").mkdir()
    (root / "scene" / "__init__.py").write_text("import yaml  # noqa\n")
    (root / "cli.py").write_text("import matplotlib  # noqa\n")
    return root


@pytest.fixture(scope="module")
def osc_fmu(stub_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("fmu")
    return build_fmu(stub_spec("osc"), out, runtime_root=stub_root)


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
    assert float(de.tolerance) == 1e-6
    names = [v.name for v in md.modelVariables]
    assert names == ["q.x", "F_ext.x", "y.x", "yd.x", "k", "c", "m", "integrator.method", "integrator.rtol"]
    byname = {v.name: v for v in md.modelVariables}
    assert byname["y.x"].unit == "m" and byname["y.x"].causality == "output"
    assert byname["y.x"].initial == "calculated" and byname["y.x"].start is None
    assert byname["q.x"].causality == "input" and float(byname["q.x"].start) == 0.0
    assert byname["k"].variability == "tunable" and float(byname["k"].start) == 4.0
    s = byname["integrator.method"]
    assert (s.type, s.variability, s.start) == ("String", "fixed", "rk4")
    assert all(v.description for v in md.modelVariables)
    assert [u.name for u in md.unitDefinitions] == ["N", "m", "m/s", "N/m", "N.s/m", "kg"]
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
    assert f"resources/{pkg}/simulation.py" in names
    assert f"resources/{pkg}/errors.py" in names
    assert f"resources/{pkg}/equations/__init__.py" in names
    assert not [n for n in names if "/bodies/" in n or "/scene/" in n or n.endswith("cli.py")]
    assert "resources/mbsfmu_spec.json" in names
    scripts = [n for n in names if re.fullmatch(r"resources/mbsfmu_osc_[0-9a-f]+\.py", n)]
    assert len(scripts) == 1
    slavemodule = zipfile.ZipFile(osc_fmu).read("resources/slavemodule.txt").decode().strip()
    assert f"resources/{slavemodule}.py" == scripts[0]
    z = zipfile.ZipFile(osc_fmu)
    sources = {n: z.read(n) for n in names if n.startswith(f"resources/{pkg}/")}
    assert forbidden_imports(sources) == []
    # absolute imports of the package are redirected to the renamed copy
    text = z.read(f"resources/{pkg}/integrators/__init__.py").decode()
    assert text.startswith(f"from {pkg}.errors import IntegrationError")
    for n, src in sources.items():
        assert not re.search(rb"^\s*(from|import)\s+mbsfmu\b", src, re.M), n


def test_build_leaves_interpreter_clean(stub_root, tmp_path):
    import sys
    path_before = list(sys.path)
    mods_before = set(sys.modules)
    fmu = build_fmu(stub_spec("clean"), tmp_path, runtime_root=stub_root)
    assert sys.path == path_before
    new = {m for m in set(sys.modules) - mods_before if m.startswith(("mbsfmu_rt_", "mbsfmu_clean"))}
    assert new == set()
    assert fmu.exists()


def test_elastic_scene_gets_bodies(stub_root, tmp_path):
    spec = stub_spec("flex", bodies={"beam": {"parent": "world", "elastic": {"beam": {"length": 1}}}})
    fmu = build_fmu(spec, tmp_path, runtime_root=stub_root)
    names = zipfile.ZipFile(fmu).namelist()
    assert [n for n in names if n.endswith("/bodies/__init__.py")]


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
    assert ("nanlog", 2, "logStatusDiscard", "t=0: refusing to step: non-finite input q.x") in MESSAGES
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


def test_two_fmus_in_one_process(stub_root, tmp_path):
    a = build_fmu(stub_spec("osc_a"), tmp_path / "a", runtime_root=stub_root)
    b = build_fmu(stub_spec("osc_b", x0=2.0), tmp_path / "b", runtime_root=stub_root)
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
    assert fa.getString([va["integrator.method"]]) == [b"rk4"]
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


def test_integration_error_is_discard(osc_fmu, tmp_path):
    from fmpy.fmi2 import fmi2LastSuccessfulTime
    from fmpy.fmi1 import FMICallException
    f, vr = _instantiate(osc_fmu, tmp_path, "div")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.setReal([vr["k"]], [-400.0])   # unstable: |x| > 1e6 after about 0.7 s
    f.exitInitializationMode()
    t = 0.0
    with pytest.raises(FMICallException) as err:
        for _ in range(100):
            f.doStep(t, 0.1)
            t += 0.1
    assert err.value.status == 2  # fmi2Discard
    assert t > 0  # some steps succeeded first
    assert f.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(t)
    # the instance is still alive: state can be read, parameters changed, and it terminates cleanly
    assert isinstance(f.getReal([vr["y.x"]])[0], float)
    f.terminate()
    f.freeInstance()


def test_bad_parameter_and_fixed_parameter(osc_fmu, tmp_path):
    from fmpy.fmi1 import FMICallException
    f, vr = _instantiate(osc_fmu, tmp_path, "bad")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.setReal([vr["m"]], [math.inf])
    f.exitInitializationMode()       # reported through the logger, the step is then discarded
    with pytest.raises(FMICallException) as err:
        f.doStep(0.0, 0.01)
    assert err.value.status == 2
    assert ("bad", 3, "logStatusError", "non-finite value for m") in MESSAGES
    f.terminate()
    f.freeInstance()

    f, vr = _instantiate(osc_fmu, tmp_path, "fixed")
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    f.setReal([vr["integrator.rtol"]], [1e-3])  # fixed: ignored (warning) after initialization
    assert f.getReal([vr["integrator.rtol"]]) == [1e-6]
    assert _messages("fixed")[-1][1:3] == (1, "logStatusWarning")
    f.setReal([vr["k"]], [9.0])                 # tunable: takes effect
    assert f.getReal([vr["k"]]) == [9.0]
    f.doStep(0.0, 0.01)
    f.terminate()
    f.freeInstance()


def test_generated_script_is_template_free(osc_fmu):
    z = zipfile.ZipFile(osc_fmu)
    mod = z.read("resources/slavemodule.txt").decode().strip()
    src = z.read(f"resources/{mod}.py").decode()
    assert "@" not in src.replace("@staticmethod", "")
    assert re.search(r"^class (\w+)\(\s*Fmi2Slave\s*\)\s*:", src, re.M)


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
    assert f"resources/{pkg}/simulation.py" in rt and f"resources/{pkg}/integrators/__init__.py" in rt
    assert not [n for n in rt if "/bodies/" in n or "/scene/" in n or "/fmu/" in n or "/bench/" in n
                or n.endswith("cli.py")]
    # the compiled right-hand side travels with a rigid scene (the FMU needs no compiler on the target)
    assert [n for n in rt if re.search(r"/equations/libmbsfmu_native_[0-9a-f]+\.so\.1$", n)]
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
    assert [n for n in names if re.search(r"/mbsfmu_rt_[0-9a-f]+/bodies/__init__\.py$", n)]
    assert not [n for n in names if "native" in n and not n.endswith(".py")]  # elastic: numpy path only
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
