"""The compiled right-hand side (equations/native.c) against the numpy recursion of tree.py, which
Pinocchio checks independently (test_pinocchio.py, test_drives.py run both paths)."""

import glob
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.errors import IntegrationError
from mbsfmu.simulation import Simulation

REPO = Path(__file__).resolve().parent.parent
# without a C compiler everything runs on the numpy path (checked by test_numpy_fallback_when_disabled)
pytestmark = pytest.mark.skipif(shutil.which(os.environ.get("CC") or "cc") is None, reason="no C compiler (cc)")
RIGID = [p for p in sorted(glob.glob(str(REPO / "models" / "*.yaml")) + glob.glob(str(REPO / "models" / "stress" / "*.yaml")))
         if "elastic" not in Path(p).read_text() and "flexible" not in p and "spinup" not in p]

# every joint type, both rotation parameterizations, every force element, a drive and force inputs
ALL_FEATURES = """
mbsfmu: 1
name: all_features
parameters: {k: 40.0, w: 2.0}
gravity: [0.2, -0.4, -9.81]
bodies:
  base:
    parent: world
    joint: {type: planar, axes: [[1, 0, 0], [0, 1, 0]], at: [0.1, 0, 0.2], rotation: {axis: [1, 2, 3], angle: 0.4}}
    mass: 2.0
    center_of_mass: [0.1, 0.05, 0]
    inertia: [[0.2, 0.01, 0], [0.01, 0.3, 0], [0, 0, 0.25]]
  cyl:
    parent: base
    joint: {type: cylindrical, axis: [0, 0.6, 0.8], at: [0.3, 0, 0]}
    mass: 1.0
    center_of_mass: [0, 0, 0.2]
    inertia: [[0.05, 0, 0], [0, 0.04, 0], [0, 0, 0.02]]
  uni:
    parent: cyl
    joint: {type: universal, axes: [[1, 0, 0], [0, 1, 0]], at: [0, 0, 0.4], drive: {uni.angle1: "0.3*sin(w*t)"}}
    mass: 0.7
    center_of_mass: [0.1, 0, 0]
    inertia: [[0.01, 0, 0], [0, 0.02, 0], [0, 0, 0.02]]
  ball:
    parent: uni
    joint: {type: spherical, parameterization: cardan, at: [0.2, 0, 0]}
    mass: 0.5
    center_of_mass: [0, 0.1, 0]
    inertia: [[0.01, 0, 0], [0, 0.012, 0], [0, 0, 0.015]]
  flyer:
    parent: world
    joint: {type: free, parameterization: cardan, at: [0, 1, 0]}
    mass: 1.5
    center_of_mass: [0.02, 0, 0.01]
    inertia: [[0.1, 0, 0.01], [0, 0.12, 0], [0.01, 0, 0.09]]
  puck:
    parent: flyer
    joint: {type: free, at: [0.2, 0, 0]}
    mass: 0.3
    inertia: [[0.002, 0, 0], [0, 0.003, 0], [0, 0, 0.004]]
  slider:
    parent: puck
    joint: {type: prismatic, axis: [1, 1, 0]}
    mass: 0.2
    inertia: [[0.001, 0, 0], [0, 0.001, 0], [0, 0, 0.001]]
  top:
    parent: slider
    joint: {type: spherical, at: [0, 0, 0.1]}
    mass: 0.4
    center_of_mass: [0, 0, 0.05]
    inertia: [[0.003, 0, 0], [0, 0.003, 0], [0, 0, 0.005]]
forces:
  - {type: joint_spring_damper, coordinate: slider.s, stiffness: k, damping: 0.3, offset: 0.05}
  - {type: spring_damper, bodies: [world, ball], at: [[0, 0, 1], [0.1, 0, 0]], stiffness: k, damping: 0.5, length: 0.4}
  - {type: spring_damper, bodies: [flyer, top], at: [[0, 0.1, 0], [0, 0, 0.1]], stiffness: 15, damping: 0.2, length: 0.1}
  - {type: force, body: cyl, at: [0, 0.1, 0], frame: body, value: ["sin(t)", 0, "2*cos(w*t)"]}
  - {type: torque, body: ball, frame: world, value: [0.1, -0.2, 0.3]}
  - {type: force, body: puck, at: [0.01, 0, 0], frame: body, input: F_puck}
  - {type: torque, body: flyer, frame: body, input: T_flyer}
"""


def _random_state(ev, rng):
    y = rng.normal(size=len(ev.coordinates)) * 0.5
    for qi in ev.model.quaternions:
        y[qi] /= np.linalg.norm(y[qi])
    return y, rng.normal(size=len(ev.velocity_coordinates))


def _compare(ev, rng, t=0.37):
    assert ev.native is not None, "compiled kernel not available"
    y, yd = _random_state(ev, rng)
    u = {n: rng.normal() for n in ev.inputs}
    q_in, F_in = ev._split_inputs(u)
    M, k, q = ev._equations(y, yd, t, q_in, F_in)
    M2, k2, q2 = ev.native.equations(y, yd, t, q_in, F_in)
    scale = max(1.0, np.abs(M).max(), np.abs(k).max(), np.abs(q).max())
    for a, b in ((M, M2), (k, k2), (q, q2)):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * scale)
    x = np.concatenate([y, yd])
    ref = np.concatenate([ev.position_rates(y, yd), np.linalg.solve(M, q - k)])
    np.testing.assert_allclose(ev.native.rhs(t, x, q_in, F_in), ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


@pytest.mark.parametrize("path", RIGID, ids=lambda p: Path(p).stem)
def test_shipped_rigid_scenes_agree_with_numpy_path(path):
    ev = mbsfmu.compile(mbsfmu.load(path))
    _compare(ev, np.random.default_rng(3))


def test_every_joint_and_force_element_agrees_with_numpy_path():
    ev = mbsfmu.compile(mbsfmu.loads(ALL_FEATURES))
    rng = np.random.default_rng(11)
    for t in (0.0, 0.37, 1.9):
        _compare(ev, rng, t)


def test_parameter_change_rebinds_the_kernel():
    ev = mbsfmu.compile(mbsfmu.loads(ALL_FEATURES))
    ev.set_parameters({"k": 400.0, "w": 0.5})
    _compare(ev, np.random.default_rng(5))


def test_elastic_scenes_stay_on_the_numpy_path():
    ev = mbsfmu.compile(mbsfmu.load(REPO / "models" / "flexible_pendulum.yaml"))
    assert ev.native is None


def test_singular_mass_matrix_is_a_clean_integration_error():
    scene = mbsfmu.loads("""
mbsfmu: 1
name: massless
bodies:
  arm: {parent: world, joint: {type: revolute, axis: [0, 0, 1]}, mass: 0, inertia: [[0, 0, 0], [0, 0, 0], [0, 0, 0]]}
""")
    sim = Simulation(scene.spec)
    assert sim.ev.native is not None
    with pytest.raises(IntegrationError, match="singular"):
        sim.problem.f(0.0, np.zeros(2))


def test_numpy_fallback_when_disabled():
    code = ("import mbsfmu, numpy as np; ev = mbsfmu.compile(mbsfmu.load('models/pendulum.yaml')); "
            "assert ev.native is None; from mbsfmu.simulation import Simulation; s = Simulation(ev.model.spec); "
            "print(s.problem.f(0.0, np.array([0.5, 0.0]))[1])")
    env = dict(os.environ, MBSFMU_NATIVE="0", PYTHONPATH=str(REPO / "src"))
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    ev = mbsfmu.compile(mbsfmu.load(REPO / "models" / "pendulum.yaml"))
    expected = Simulation(ev.model.spec).problem.f(0.0, np.array([0.5, 0.0]))[1]
    assert abs(float(out.stdout) - expected) < 1e-12 * abs(expected)


@pytest.mark.parametrize("method", ["dopri5", "dop853"])
def test_compiled_stage_loop_matches_stage_by_stage(method, monkeypatch):
    """One compiled call for all Runge–Kutta stages (drive values and time-dependent forces tabulated at the
    stage times beforehand) gives the trajectory of the stage-by-stage loop."""
    scene = mbsfmu.loads(ALL_FEATURES.replace("gravity: [0.2, -0.4, -9.81]", "gravity: [0.2, -0.4, -9.81]\n"
                                              "integrator: {rtol: 1e-9, atol: 1e-11}"))

    def run():
        sim = Simulation(scene.spec)
        sim.set("integrator.method", method)
        sim.set("F_puck.x", 0.3)
        sim.set("T_flyer.z", -0.2)
        sim.initialize(0.0)
        for k in range(20):
            sim.do_step(0.01 * k, 0.01)
        return sim.x.copy(), sim.problem.rhs_calls

    from mbsfmu.equations.native import NativeTree
    used = []
    original = NativeTree.stages
    monkeypatch.setattr(NativeTree, "stages", lambda self, *a: used.append(1) or original(self, *a))
    x_fast, calls = run()
    assert used, "compiled stage loop not used"
    monkeypatch.setattr(Simulation, "__init__", _without_stage_loop(Simulation.__init__))
    x_slow, calls_slow = run()
    assert calls == calls_slow
    np.testing.assert_allclose(x_fast, x_slow, rtol=1e-10, atol=1e-12)


def _without_stage_loop(init):
    def wrapped(self, spec):
        init(self, spec)
        self.problem.stages = lambda *a: None  # erk_stages then calls problem.f stage by stage
    return wrapped
