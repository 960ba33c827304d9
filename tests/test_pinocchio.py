"""M, k, q against Pinocchio (independent implementation): rnea(q, v, a) = M·a + k − q_gravity."""

import numpy as np
import pytest

import mbsfmu
from mbsfmu.kinematics.rotations import axis_angle

pin = pytest.importorskip("pinocchio")

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


def _pinocchio_model(ev):
    """The same tree in Pinocchio (joint placement = parent body frame → joint frame)."""
    model = pin.Model()
    ids = {}
    for b in ev.model.bodies:
        parent = 0 if b.parent < 0 else ids[ev.model.bodies[b.parent].name]
        R0 = b.R0 if b.R0 is not None else np.eye(3)
        at = b.at if b.at is not None else np.zeros(3)
        placement = pin.SE3(R0, at)
        j = b.joint
        if b.kind == "revolute":
            jm = pin.JointModelRevoluteUnaligned(*j.a)
        elif b.kind == "prismatic":
            jm = pin.JointModelPrismaticUnaligned(*j.a)
        elif b.kind == "cylindrical":
            jm = pin.JointModelComposite(pin.JointModelPrismaticUnaligned(*j.a))
            jm.addJoint(pin.JointModelRevoluteUnaligned(*j.a))
        elif b.kind == "universal":
            jm = pin.JointModelComposite(pin.JointModelRevoluteUnaligned(*j.a1))
            jm.addJoint(pin.JointModelRevoluteUnaligned(*j.a2))
        elif b.kind == "spherical":
            jm = pin.JointModelSpherical()
        jid = model.addJoint(parent, jm, placement, b.name)
        c = b.c if b.c is not None else np.zeros(3)
        model.appendBodyToJoint(jid, pin.Inertia(b.m, c, b.I), pin.SE3.Identity())
        ids[b.name] = jid
    model.gravity = pin.Motion(ev.model.g, np.zeros(3))
    return model


def _to_pin(ev, y, yd):
    """Our coordinates → Pinocchio's (joint order = topological order; quaternion (w,x,y,z) → (x,y,z,w))."""
    q, v = [], []
    for b in ev.model.bodies:
        p = y[b.pos_idx]
        if b.kind == "spherical":
            p = np.array([p[1], p[2], p[3], p[0]])
        q.extend(p)
        v.extend(yd[b.vel_idx])
    return np.array(q), np.array(v)


def _perm(ev):
    return np.concatenate([b.vel_idx for b in ev.model.bodies])


@pytest.mark.parametrize("seed", range(6))
def test_rnea_and_crba_match_pinocchio(seed):
    rng = np.random.default_rng(seed)
    ev = mbsfmu.compile(mbsfmu.loads(_random_scene(rng, 7, JOINTS[seed % 5:] + JOINTS[:seed % 5])))
    pm = _pinocchio_model(ev)
    pd = pm.createData()
    for _ in range(3):
        y = rng.normal(size=len(ev.coordinates))
        for b in ev.model.bodies:
            if b.quat is not None:
                y[b.pos_idx[b.quat]] /= np.linalg.norm(y[b.pos_idx[b.quat]])
        yd, ydd = rng.normal(size=len(ev.velocity_coordinates)), rng.normal(size=len(ev.velocity_coordinates))
        M, k, q = ev.equations(y, yd, 0.0)
        qp, vp = _to_pin(ev, y, yd)
        P = _perm(ev)
        tau = pin.rnea(pm, pd, qp, vp, ydd[P])
        np.testing.assert_allclose((M @ ydd + k - q)[P], tau, rtol=1e-10, atol=1e-10)
        # Pinocchio's mass matrix, column by column from its RNEA (its crba leaves branch blocks unfilled)
        zero = np.zeros_like(vp)
        Mp = np.array([pin.rnea(pm, pd, qp, zero, e) - pin.rnea(pm, pd, qp, zero, zero) for e in np.eye(len(vp))]).T
        np.testing.assert_allclose(M[np.ix_(P, P)], Mp, rtol=1e-10, atol=1e-10)


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
