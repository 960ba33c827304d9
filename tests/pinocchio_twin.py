"""Pinocchio twin of a compiled scene (the independent reference of the tests and the benchmarks).

Every joint type: revolute, prismatic, cylindrical, universal, planar, spherical and free (quaternion or
Cardan angles) and fixed. Joints Pinocchio has no single model for are composites of its elementary joints
with the same coordinates: planar = two prismatic + a revolute about their normal, Cardan = revolutes about
x, y, z, free = three prismatic along x, y, z + spherical (our free joint's linear velocity is in the parent
frame). With `free_flyer`, free quaternion joints are Pinocchio's own `JointModelFreeFlyer` (what a floating
base is there: the fastest), whose linear velocity is in the body frame; to_pin and from_pin_acceleration map
it. Driven coordinates stay ordinary Pinocchio joints, so the full tree can be compared with the free part.
"""

import numpy as np
import pinocchio as pin

_AXES = np.eye(3)


def _composite(*joints):
    jm = pin.JointModelComposite(joints[0])
    for j in joints[1:]:
        jm.addJoint(j)
    return jm


def _cardan():
    return [pin.JointModelRevoluteUnaligned(*a) for a in _AXES]


def _joint_model(b, free_flyer):
    """Pinocchio's joint model of body b's joint (same coordinates, same order)."""
    j, kind = b.joint, b.kind
    if kind == "revolute":
        return pin.JointModelRevoluteUnaligned(*j.a)
    if kind == "prismatic":
        return pin.JointModelPrismaticUnaligned(*j.a)
    if kind == "cylindrical":
        return _composite(pin.JointModelPrismaticUnaligned(*j.a), pin.JointModelRevoluteUnaligned(*j.a))
    if kind == "universal":
        return _composite(pin.JointModelRevoluteUnaligned(*j.a1), pin.JointModelRevoluteUnaligned(*j.a2))
    if kind == "planar":
        return _composite(pin.JointModelPrismaticUnaligned(*j.ax), pin.JointModelPrismaticUnaligned(*j.ay),
                          pin.JointModelRevoluteUnaligned(*j.n))
    if kind == "spherical":
        return pin.JointModelSpherical() if b.quat is not None else _composite(*_cardan())
    if kind == "free":
        if b.quat is None:
            return _composite(*[pin.JointModelPrismaticUnaligned(*a) for a in _AXES], *_cardan())
        if free_flyer:
            return pin.JointModelFreeFlyer()
        return _composite(*[pin.JointModelPrismaticUnaligned(*a) for a in _AXES], pin.JointModelSpherical())
    raise NotImplementedError(kind)


def _inertia(b):
    """Pinocchio's inertia of body b, set field by field: its constructor refuses moments a rounding below zero
    (iCub's r_hip_2: -5e-20), which the scene's loader accepts within its tolerance."""
    inertia = pin.Inertia.Zero()
    inertia.mass, inertia.inertia = b.m, b.I
    inertia.lever = b.c if b.c is not None else np.zeros(3)
    return inertia


def pinocchio_model(ev, free_flyer=False):
    """The same tree in Pinocchio: joint placement = parent body frame → joint frame; fixed bodies are
    appended to their parent's joint with the composed placement."""
    model = pin.Model()
    frames = {}  # body name → (Pinocchio joint id, SE3 from that joint's frame to the body frame)
    for b in ev.model.bodies:
        if b.elastic:
            raise NotImplementedError(f"elastic body '{b.name}'")
        pj, pX = (0, pin.SE3.Identity()) if b.parent < 0 else frames[ev.model.bodies[b.parent].name]
        R0 = b.R0 if b.R0 is not None else np.eye(3)
        at = b.at if b.at is not None else np.zeros(3)
        placement = pX * pin.SE3(R0, at)
        if b.kind == "fixed":
            model.appendBodyToJoint(pj, _inertia(b), placement)
            frames[b.name] = (pj, placement)
            continue
        jid = model.addJoint(pj, _joint_model(b, free_flyer), placement, b.name)
        model.appendBodyToJoint(jid, _inertia(b), pin.SE3.Identity())
        frames[b.name] = (jid, pin.SE3.Identity())
    model.gravity = pin.Motion(ev.model.g if ev.model.g is not None else np.zeros(3), np.zeros(3))
    return model


def _flyer(b, free_flyer):
    return free_flyer and b.kind == "free" and b.quat is not None


def _rotation(y, b):
    w, x, yy, z = y[b.pos_idx[3:7]]
    return pin.Quaternion(w, x, yy, z).normalized().toRotationMatrix()


def to_pin(ev, y, yd, ydd=None, drive=None, free_flyer=False):
    """Our state → Pinocchio's (q, v, a) in its joint order, plus the index of every free velocity
    coordinate of ours in Pinocchio's v. `drive(coordinate name) -> (pos, vel, acc)` fills driven ones.
    free_flyer: as pinocchio_model(ev, free_flyer=True) (a free joint's linear velocity in the body frame)."""
    q, v, a, free = [], [], [], []
    ydd = np.zeros(len(yd)) if ydd is None else ydd
    for b in ev.model.bodies:
        if b.kind == "fixed":
            continue
        if b.quat is not None:
            p = y[b.pos_idx]
            k = b.quat.start
            q.extend([*p[:k], p[k + 1], p[k + 2], p[k + 3], p[k]])  # Pinocchio: (x, y, z, w)
        else:
            for k, c in enumerate(b.coordinates):
                q.append(y[b.pos_idx[k]] if b.pos_idx[k] >= 0 else drive(c)[0])
        start = len(v)
        for k, c in enumerate(b.velocities):
            i = b.vel_idx[k]
            if i >= 0:
                free.append((i, len(v)))
                v.append(yd[i])
                a.append(ydd[i])
            else:
                _, vel, acc = drive(c)
                v.append(vel)
                a.append(acc)
        if _flyer(b, free_flyer):  # Rᵀ ẋ; its rate Rᵀ ẍ − ω × (Rᵀ ẋ)
            R, lin, w = _rotation(y, b), slice(start, start + 3), slice(start + 3, start + 6)
            v[lin] = R.T @ np.array(v[lin])
            a[lin] = R.T @ np.array(a[lin]) - np.cross(v[w], v[lin])
    free = sorted(free)
    return np.array(q), np.array(v), np.array(a), np.array([p for _, p in free])


def from_pin_acceleration(ev, y, v, a, P, free_flyer=False):
    """Pinocchio's acceleration a (at its velocity v, from to_pin) → our ÿ of the free velocity coordinates
    (P from to_pin); with free_flyer, ẍ = R (a_lin + ω × v_lin) on free joints."""
    a = np.array(a, dtype=float)
    if free_flyer:
        start = 0
        for b in ev.model.bodies:
            if _flyer(b, free_flyer):
                lin, w = slice(start, start + 3), slice(start + 3, start + 6)
                a[lin] = _rotation(y, b) @ (a[lin] + np.cross(v[w], v[lin]))
            start += len(b.velocities)
    return a[P]
