"""Rheonomic drives: M, k, q of the free coordinates vs Pinocchio's RNEA of the FULL tree, with the driven
joints' position, velocity and acceleration taken from the drive expressions (derivatives by hand)."""

import math

import numpy as np
import pytest

import mbsfmu
from mbsfmu.simulation import Simulation
from mbsfmu.simulation import simulate

pin = pytest.importorskip("pinocchio")
from pinocchio_twin import pinocchio_model, to_pin  # noqa: E402

W = 2 * math.pi
DRIVES = {  # coordinate → (expression, exact position, velocity, acceleration as functions of t)
    "d_rot": ("0.5*sin(2*pi*t)", lambda t: 0.5 * math.sin(W * t), lambda t: 0.5 * W * math.cos(W * t),
              lambda t: -0.5 * W * W * math.sin(W * t)),
    "d_lin": ("0.1*t^2 + 0.2*t - 0.05", lambda t: 0.1 * t * t + 0.2 * t - 0.05, lambda t: 0.2 * t + 0.2, lambda t: 0.2),
    "d_exp": ("0.3*exp(-t)*cos(3*t)", lambda t: 0.3 * math.exp(-t) * math.cos(3 * t),
              lambda t: 0.3 * math.exp(-t) * (-math.cos(3 * t) - 3 * math.sin(3 * t)),
              lambda t: 0.3 * math.exp(-t) * (-8 * math.cos(3 * t) + 6 * math.sin(3 * t))),
}

SCENE = """
mbsfmu: 1
name: driven_tree
gravity: [0.4, -1.1, -9.81]
parameters: {L: 0.7}
bodies:
  base:
    parent: world
    joint: {type: revolute, axis: [0.2, 0.1, 1], coordinates: [d_rot], drive: {d_rot: "0.5*sin(2*pi*t)"},
            at: [0.1, 0, 0.2], rotation: {axis: [1, 2, 0.5], angle: 0.4}}
    mass: 2.0
    center_of_mass: [0.1, 0.05, -0.1]
    inertia: [[0.05, 0.002, -0.001], [0.002, 0.04, 0.003], [-0.001, 0.003, 0.03]]
  arm:
    parent: base
    joint: {type: revolute, axis: [0, 1, 0.3], at: [0.3, 0.1, 0], rotation: {axis: [0, 0, 1], angle: 0.7}, coordinates: [a1]}
    mass: 1.3
    center_of_mass: [0, 0, -L/2]
    inertia: {xx: 0.06, yy: 0.055, zz: 0.01, xy: 0.001}
  slider:
    parent: arm
    joint: {type: prismatic, axis: [1, 0, 0.2], at: [0, 0, -L], coordinates: [d_lin], drive: {d_lin: "0.1*t^2 + 0.2*t - 0.05"}}
    mass: 0.8
    center_of_mass: [0.05, 0, 0.02]
    inertia: {xx: 0.004, yy: 0.005, zz: 0.006}
  tip:
    parent: slider
    joint: {type: universal, axes: [[1, 0, 0], [0, 1, 0]], at: [0.1, 0, 0], coordinates: [u1, u2]}
    mass: 0.5
    center_of_mass: [0, 0.1, -0.2]
    inertia: {xx: 0.003, yy: 0.002, zz: 0.0025}
  side:
    parent: base
    joint: {type: revolute, axis: [1, 0, 0], at: [-0.2, 0, 0.1], coordinates: [d_exp], drive: {d_exp: "0.3*exp(-t)*cos(3*t)"}}
    mass: 0.6
    center_of_mass: [0, 0.2, 0]
    inertia: {xx: 0.01, yy: 0.002, zz: 0.01}
  ball:
    parent: side
    joint: {type: spherical, at: [0, 0.4, 0]}
    mass: 0.9
    center_of_mass: [0, 0, -0.15]
    inertia: {xx: 0.004, yy: 0.005, zz: 0.003, yz: 0.0005}
"""


def _drive(c, t):
    _, p, v, a = DRIVES[c]
    return p(t), v(t), a(t)


def _check(ev, y, yd, ydd, t):
    pm = pinocchio_model(ev)
    pd = pm.createData()
    M, k, q = ev.equations(y, yd, t)
    qp, vp, ap, free = to_pin(ev, y, yd, ydd, drive=lambda c: _drive(c, t))
    tau = pin.rnea(pm, pd, qp, vp, ap)
    np.testing.assert_allclose(M @ ydd + k - q, tau[free], rtol=1e-10, atol=1e-10)
    # the engine evaluates the drives (bytecode of the expressions and their derivatives) the same way
    M2, k2, q2 = Simulation(ev.model.spec).engine.equations(t, np.concatenate([y, yd]))
    np.testing.assert_allclose(M2 @ ydd + k2 - q2, tau[free], rtol=1e-10, atol=1e-10)
    # mass matrix of the free coordinates: columns of RNEA differences
    base = ev.equations(y, yd, t)
    for i in range(len(ydd)):
        e = np.zeros_like(ydd)
        e[i] = 1.0
        _, _, a1, _ = to_pin(ev, y, yd, ydd + e, drive=lambda c: _drive(c, t))
        col = pin.rnea(pm, pd, qp, vp, a1) - tau
        np.testing.assert_allclose(base[0][:, i], col[free], rtol=1e-10, atol=1e-10)
    return M


@pytest.mark.parametrize("t", [0.0, 0.13, 0.37, 0.5, 1.21])
def test_driven_tree_matches_pinocchio_rnea_of_full_tree(t):
    ev = mbsfmu.compile(mbsfmu.loads(SCENE))
    assert ev.coordinates == ["a1", "u1", "u2", "ball.q0", "ball.q1", "ball.q2", "ball.q3"]
    assert ev.velocity_coordinates == ["a1", "u1", "u2", "ball.wx", "ball.wy", "ball.wz"]
    rng = np.random.default_rng(int(t * 100))
    y = rng.normal(size=7)
    y[3:] /= np.linalg.norm(y[3:])
    yd, ydd = rng.normal(size=6), rng.normal(size=6)
    M = _check(ev, y, yd, ydd, t)
    np.testing.assert_allclose(M, M.T, atol=1e-13)
    assert np.linalg.eigvalsh(M).min() > 0


def test_rheonomic_terms_vanish_only_when_drive_is_at_rest():
    """The drive's velocity shows up as v̄ (bodies moved by the drive) and its acceleration in ā."""
    ev = mbsfmu.compile(mbsfmu.loads(SCENE))
    y = np.array([0.3, 0.1, -0.2, 1, 0, 0, 0.0])
    yd = np.zeros(6)
    J = ev.jacobians(y, yd, 0.0)
    # at t = 0: d_rot velocity = 0.5*2*pi ≠ 0 → the arm's COM moves although ẏ = 0
    assert np.linalg.norm(J["arm"]["v_bar"]) > 0.1
    om = J["base"]["omega"]
    axis = J["base"]["S"] @ np.array([0.2, 0.1, 1]) / np.linalg.norm([0.2, 0.1, 1])
    np.testing.assert_allclose(om, 0.5 * W * axis, atol=1e-12)


def test_driven_crank_model_matches_pinocchio():
    ev = mbsfmu.compile(mbsfmu.load("models/driven_crank.yaml"))
    omega = ev.parameters["omega"]
    for t in (0.0, 0.21, 0.8):
        y, yd, ydd = np.array([0.4 + t]), np.array([-1.3]), np.array([0.7])
        pm = pinocchio_model(ev)
        pd = pm.createData()
        M, k, q = ev.equations(y, yd, t)
        qp, vp, ap, free = to_pin(ev, y, yd, ydd, drive=lambda c: (omega * t, omega, 0.0))
        np.testing.assert_allclose(M @ ydd + k - q, pin.rnea(pm, pd, qp, vp, ap)[free], rtol=1e-10, atol=1e-12)


def test_driven_crank_power_balance():
    """Along a simulated run the mechanical energy (from the body velocities, v̄ included) changes exactly
    by the work of the motor: dE/dt = tau_motor · omega, tau_motor from Pinocchio's RNEA of the full tree."""
    scene = mbsfmu.load("models/driven_crank.yaml")
    ev = mbsfmu.compile(scene)
    omega = ev.parameters["omega"]
    t, Y, YD = simulate(scene, stop=1.0, step=0.005, method="dop853", rtol=1e-10, atol=1e-12)
    pm = pinocchio_model(ev)
    pd = pm.createData()
    g = ev.model.g
    E, P = [], []
    for tt, y, yd in zip(t, Y, YD):
        J = ev.jacobians(y, yd, tt)
        e = 0.0
        for b in ev.model.bodies:
            jb = J[b.name]
            S, w = jb["S"], jb["omega"]
            e += 0.5 * b.m * jb["v"] @ jb["v"] + 0.5 * w @ S @ b.I @ S.T @ w - b.m * g @ jb["r"]
        E.append(e)
        ydd = ev.accelerations(y, yd, tt)
        qp, vp, ap, free = to_pin(ev, y, yd, ydd, drive=lambda c: (omega * tt, omega, 0.0))
        tau = pin.rnea(pm, pd, qp, vp, ap)
        np.testing.assert_allclose(tau[free], 0.0, atol=1e-9)  # the free joint needs no torque
        P.append(tau[0] * omega)
        assert ev.energy(y, yd, tt) == pytest.approx(e, rel=1e-12, abs=1e-12)  # v̄, ω̄ of the drive included
    E, P = np.array(E), np.array(P)
    work = np.concatenate([[0.0], np.cumsum(0.5 * (P[1:] + P[:-1]) * np.diff(t))])
    assert np.ptp(E) > 0.1  # the motor does work ...
    np.testing.assert_allclose(E - E[0], work, atol=2e-4 * np.ptp(E))  # ... and all of it goes into E
