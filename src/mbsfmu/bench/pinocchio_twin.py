"""Pinocchio twin of a compiled scene (the independent reference of the tests and the equations benchmark).

Handles revolute, prismatic, cylindrical, universal, spherical (quaternion) and fixed joints; driven
coordinates stay ordinary Pinocchio joints, so the full tree can be compared with the free part.
"""

import numpy as np
import pinocchio as pin


def pinocchio_model(ev):
    """The same tree in Pinocchio: joint placement = parent body frame → joint frame; fixed bodies are
    appended to their parent's joint with the composed placement."""
    model = pin.Model()
    frames = {}  # body name → (Pinocchio joint id, SE3 from that joint's frame to the body frame)
    for b in ev.model.bodies:
        pj, pX = (0, pin.SE3.Identity()) if b.parent < 0 else frames[ev.model.bodies[b.parent].name]
        R0 = b.R0 if b.R0 is not None else np.eye(3)
        at = b.at if b.at is not None else np.zeros(3)
        placement = pX * pin.SE3(R0, at)
        j = b.joint
        c = b.c if b.c is not None else np.zeros(3)
        if b.kind == "fixed":
            model.appendBodyToJoint(pj, pin.Inertia(b.m, c, b.I), placement)
            frames[b.name] = (pj, placement)
            continue
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
        else:
            raise NotImplementedError(b.kind)
        jid = model.addJoint(pj, jm, placement, b.name)
        model.appendBodyToJoint(jid, pin.Inertia(b.m, c, b.I), pin.SE3.Identity())
        frames[b.name] = (jid, pin.SE3.Identity())
    model.gravity = pin.Motion(ev.model.g if ev.model.g is not None else np.zeros(3), np.zeros(3))
    return model


def to_pin(ev, y, yd, ydd=None, drive=None):
    """Our state → Pinocchio's (q, v, a) in its joint order, plus the index of every free velocity
    coordinate of ours in Pinocchio's v. `drive(coordinate name) -> (pos, vel, acc)` fills driven ones."""
    q, v, a, free = [], [], [], []
    for b in ev.model.bodies:
        if b.kind == "fixed":
            continue
        if b.kind == "spherical":
            p = y[b.pos_idx]
            q.extend([p[1], p[2], p[3], p[0]])
        else:
            for k, c in enumerate(b.coordinates):
                q.append(y[b.pos_idx[k]] if b.pos_idx[k] >= 0 else drive(c)[0])
        for k, c in enumerate(b.velocities):
            i = b.vel_idx[k]
            if i >= 0:
                free.append((i, len(v)))
                v.append(yd[i])
                a.append(0.0 if ydd is None else ydd[i])
            else:
                _, vel, acc = drive(c)
                v.append(vel)
                a.append(acc)
    free = sorted(free)
    return np.array(q), np.array(v), np.array(a), np.array([p for _, p in free])
