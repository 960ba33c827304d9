"""Simulation.run (what simulate uses) against the FMU master's path, one do_step per communication step."""

import math
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.errors import IntegrationError
from mbsfmu.simulation import Simulation, simulate

ROOT = Path(__file__).resolve().parents[1]


def _spec(name, text_replace=None):
    path = ROOT / "models" / name
    if text_replace:
        return mbsfmu.loads(path.read_text().replace(*text_replace)).spec
    return mbsfmu.load(path).spec


def _do_step_loop(spec, ts, method, inputs=None):
    sim = Simulation(spec)
    sim.set("integrator.method", method)
    sim.initialize(ts[0])
    for k, v in (inputs or {}).items():
        sim.set(k, v)
    X = [sim.x.copy()]
    for k in range(len(ts) - 1):
        sim.do_step(ts[k], ts[k + 1] - ts[k])
        X.append(sim.x.copy())
    return sim, np.array(X)


@pytest.mark.parametrize("scene,method,inputs", [
    ("free_body.yaml", "dopri5", None),          # quaternions: interpolated rows are normalized together
    ("spring_damper.yaml", "dop853", None),
    ("crane.yaml", "auto", {"F_bridge.x": 40.0, "F_trolley.y": -15.0}),
    ("pendulum.yaml", "radau5", None),           # no dense output: lands on every point
])
def test_run_takes_the_steps_of_the_do_step_loop(scene, method, inputs):
    spec = _spec(scene)
    ts = np.linspace(0.0, 0.5, 501)
    loop, X1 = _do_step_loop(spec, ts, method, inputs)
    sim = Simulation(spec)
    sim.set("integrator.method", method)
    sim.initialize(ts[0])
    for k, v in (inputs or {}).items():
        sim.set(k, v)
    X2 = sim.run(ts)
    assert sim.stats == loop.stats
    assert np.max(np.abs(X1 - X2)) < 1e-12
    assert sim.time == loop.time == ts[-1]
    assert sim.get("y." + sim.coordinates[0]) == X2[-1, 0]
    assert sim.get("yd." + sim.velocity_coordinates[-1]) == X2[-1, -1]
    for q in mbsfmu.compile(spec).model.quaternions:
        assert np.max(np.abs(np.linalg.norm(X2[:, q], axis=1) - 1.0)) < 1e-14


def test_simulate_with_held_inputs_equals_an_input_function():
    spec = _spec("cart_pole.yaml")
    held = mbsfmu.simulate(ROOT / "models" / "cart_pole.yaml", stop=0.3, step=0.01, inputs={"F_cart.x": 5.0})
    called = simulate(spec, stop=0.3, step=0.01, inputs=lambda t: {"F_cart.x": 5.0})
    for a, b in zip(held, called):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-13)
    assert held[1][-1, 0] > 0.05  # the push acts: ~ F/(m_c+m_p)·t²/2


def test_run_refuses_a_nan_input_and_stays_put():
    sim = Simulation(_spec("cart_pole.yaml"))
    sim.initialize(0.0)
    sim.set("F_cart.x", math.nan)
    with pytest.raises(IntegrationError, match="F_cart.x is not finite"):
        sim.run([0.0, 0.1, 0.2])
    assert sim.time == 0.0


def test_run_with_cardan_angles_reports_gimbal_lock():
    """The pairwise gimbal check of do_step also guards run (a coarse step may jump across b = ±90°)."""
    spec = _spec("spinning_top.yaml", ("parameterization: quaternion", "parameterization: cardan"))
    sim = Simulation(spec)
    sim.set("y0.top.b", 0.5 * math.pi - 1e-3)  # next to the singular pitch
    sim.initialize(0.0)
    with pytest.raises(IntegrationError, match="quaternion"):
        sim.run(np.linspace(0.0, 2.0, 21))
    assert 0.0 <= sim.time < 2.0


def test_outputs_before_initialization_follow_the_parameters_set():
    """An FMU master may read outputs in initialization mode, after setting parameters: bob at L·(−sin θ0, 0, −cos θ0)."""
    sim = Simulation(_spec("pendulum.yaml"))
    th = math.pi / 6  # the scene's initial angle
    for L in (0.8, 1.6):
        sim.set("L", L)
        assert sim.get("bob.r.x") == pytest.approx(-L * math.sin(th), abs=1e-14)
        assert sim.get("bob.r.z") == pytest.approx(-L * math.cos(th), abs=1e-14)
    assert sim.get("y.theta") == pytest.approx(th, abs=1e-15)
