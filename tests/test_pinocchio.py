"""M, k, q against Pinocchio (independent implementation): rnea(q, v, a) = M·a + k − q_gravity."""


import numpy as np
import pytest

import mbsfmu
from mbsfmu.kinematics.rotations import axis_angle
from mbsfmu.simulation import Simulation

pin = pytest.importorskip("pinocchio")
from pinocchio_twin import pinocchio_model, to_pin  # noqa: E402

JOINTS = ["revolute", "prismatic", "cylindrical", "spherical", "universal"]


def _random_scene(rng, n_bodies, kinds):
    """YAML text of a random tree: branching, rotated joint frames, offsets, full inertia tensors."""
    lines = ["mbsfmu: 1", "name: random_tree", "gravity: [0.3, -1.2, -9.81]", "bodies:"]
    for i in range(n_bodies):
        parent = "world" if i == 0 else f"b{rng.integers(0, i)}"
        kind = kinds[i % len(kinds)]
        axis = rng.normal(size=3)
        rot_axis = rng.normal(size=3)
        at = rng.normal(size=3) * 0.5
        com = rng.normal(size=3) * 0.3
        pts = rng.normal(size=(4, 3)) * 0.3  # inertia of point masses about their centre: physical by construction
        pts -= pts.mean(axis=0)
        I = sum(np.dot(r, r) * np.eye(3) - np.outer(r, r) for r in pts) + 0.01 * np.eye(3)
        j = f"{{type: {kind}"
        if kind in ("revolute", "prismatic", "cylindrical"):
            j += f", axis: {axis.round(4).tolist()}"
        if kind == "universal":
            j += f", axes: [{axis.round(4).tolist()}, {rng.normal(size=3).round(4).tolist()}]"
        j += f", at: {at.round(4).tolist()}, rotation: {{axis: {rot_axis.round(4).tolist()}, angle: {rng.uniform(-3, 3):.4f}}}}}"
        lines += [f"  b{i}:", f"    parent: {parent}", f"    joint: {j}", f"    mass: {rng.uniform(0.5, 3):.4f}",
                  f"    center_of_mass: {com.round(4).tolist()}",
                  f"    inertia: {I.round(5).tolist()}"]
    return "\n".join(lines)


@pytest.mark.parametrize("seed", range(6))
def test_rnea_and_crba_match_pinocchio(seed):
    rng = np.random.default_rng(seed)
    ev = mbsfmu.compile(mbsfmu.loads(_random_scene(rng, 7, JOINTS[seed % 5:] + JOINTS[:seed % 5])))
    engine = Simulation(ev.model.spec).engine
    pm = pinocchio_model(ev)
    pd = pm.createData()
    for _ in range(3):
        y = rng.normal(size=len(ev.coordinates))
        for b in ev.model.bodies:
            if b.quat is not None:
                y[b.pos_idx[b.quat]] /= np.linalg.norm(y[b.pos_idx[b.quat]])
        yd, ydd = rng.normal(size=len(ev.velocity_coordinates)), rng.normal(size=len(ev.velocity_coordinates))
        qp, vp, ap, P = to_pin(ev, y, yd, ydd)  # P[i]: Pinocchio's index of our velocity coordinate i
        tau = pin.rnea(pm, pd, qp, vp, ap)
        # Pinocchio's mass matrix, column by column from its RNEA (its crba leaves branch blocks unfilled)
        zero = np.zeros_like(vp)
        Mp = np.array([pin.rnea(pm, pd, qp, zero, e) - pin.rnea(pm, pd, qp, zero, zero) for e in np.eye(len(vp))]).T
        paths = {"numpy": ev.equations(y, yd, 0.0), "engine": engine.equations(0.0, np.concatenate([y, yd]))}
        for M, k, q in paths.values():
            np.testing.assert_allclose(M @ ydd + k - q, tau[P], rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(M, Mp[np.ix_(P, P)], rtol=1e-10, atol=1e-10)


def test_generalized_force_input_enters_q():
    rng = np.random.default_rng(7)
    ev = mbsfmu.compile(mbsfmu.loads(_random_scene(rng, 3, ["revolute"])))
    y = rng.normal(size=3)
    _, _, q0 = ev.equations(y, np.zeros(3))
    _, _, q1 = ev.equations(y, np.zeros(3), u={"q.b1.angle": 2.5})
    np.testing.assert_allclose(q1 - q0, [0, 2.5, 0])


def test_rotation_matrix_helper_is_proper():
    S = axis_angle(np.array([0, 0.6, 0.8]), 0.7)
    np.testing.assert_allclose(S.T @ S, np.eye(3), atol=1e-14)
