"""Joint motion in the joint frame: relative rotation and displacement, and the maps from the joint's
velocity coordinates to relative angular velocity (H_R) and to the origin's relative velocity (H_T).

`motion(p, v)` → (R_rel, d_rel, H_R, H_T, b_R, b_T) with ω_rel = H_R·v, ḋ_rel = H_T·v,
ω̇_rel = H_R·v̇ + b_R, d̈_rel = H_T·v̇ + b_T (all in the joint frame). `None` marks a zero part,
so that the tree recursion skips it.
"""

import numpy as np

from ..engine import layout as L
from .rotations import axis_angle, cross, quat_to_matrix, rot_x, rot_y, rot_z

_E = np.eye(3)


def _unit(a):
    a = np.asarray(a, dtype=float)
    return a / np.linalg.norm(a)


class Fixed:
    npos = nvel = 0

    def motion(self, p, v):
        return None, None, None, None, None, None


class Revolute:
    """Rotation by y about a fixed axis: H_R = [a]."""
    npos = nvel = 1

    def __init__(self, axis):
        self.a = _unit(axis)
        self.H_R = self.a.reshape(3, 1)

    def motion(self, p, v):
        return axis_angle(self.a, p[0]), None, self.H_R, None, None, None


class Prismatic:
    """Translation by s along a fixed axis: H_T = [a]."""
    npos = nvel = 1

    def __init__(self, axis):
        self.a = _unit(axis)
        self.H_T = self.a.reshape(3, 1)

    def motion(self, p, v):
        return None, self.a * p[0], None, self.H_T, None, None


class Cylindrical:
    """Translation s along and rotation about one axis: y = (s, angle)."""
    npos = nvel = 2

    def __init__(self, axis):
        self.a = _unit(axis)
        self.H_R = np.column_stack([np.zeros(3), self.a])
        self.H_T = np.column_stack([self.a, np.zeros(3)])

    def motion(self, p, v):
        return axis_angle(self.a, p[1]), self.a * p[0], self.H_R, self.H_T, None, None


class Universal:
    """Rotation about a1, then about the rotated a2: ω_rel = a1 θ̇1 + S1 a2 θ̇2."""
    npos = nvel = 2

    def __init__(self, axes):
        self.a1, self.a2 = _unit(axes[0]), _unit(axes[1])

    def motion(self, p, v):
        S1 = axis_angle(self.a1, p[0])
        h2 = S1 @ self.a2
        H_R = np.column_stack([self.a1, h2])
        b_R = cross(self.a1, h2) * (v[0] * v[1])  # ḣ2 θ̇2 with ḣ2 = (a1 θ̇1) × h2
        return S1 @ axis_angle(self.a2, p[1]), None, H_R, None, b_R, None


class Planar:
    """Translation x·ax + y·ay in the plane, rotation about n = ax × ay."""
    npos = nvel = 3

    def __init__(self, axes):
        self.ax, self.ay = _unit(axes[0]), _unit(axes[1])
        self.n = np.cross(self.ax, self.ay)
        self.H_R = np.column_stack([np.zeros(3), np.zeros(3), self.n])
        self.H_T = np.column_stack([self.ax, self.ay, np.zeros(3)])

    def motion(self, p, v):
        return axis_angle(self.n, p[2]), self.ax * p[0] + self.ay * p[1], self.H_R, self.H_T, None, None


def _cardan(p, v):
    """x-y-z Cardan angles: S = Sx(a) Sy(b) Sz(c), ω_rel = [ex, Sx ey, Sx Sy ez]·(ȧ, ḃ, ċ)."""
    Sx, Sy = rot_x(p[0]), rot_y(p[1])
    Sxy = Sx @ Sy
    h1, h2, h3 = _E[:, 0], Sx[:, 1], Sxy[:, 2]
    w1 = h1 * v[0]
    w2 = w1 + h2 * v[1]
    b_R = cross(w1, h2) * v[1] + cross(w2, h3) * v[2]
    return Sxy @ rot_z(p[2]), np.column_stack([h1, h2, h3]), b_R


class SphericalQuaternion:
    """Unit quaternion positions, body-frame angular velocity: ω_rel = S·ω_body (no bias term)."""
    npos, nvel = 4, 3

    def motion(self, p, v):
        S = quat_to_matrix(p)
        return S, None, S, None, None, None


class SphericalCardan:
    npos = nvel = 3

    def motion(self, p, v):
        S, H_R, b_R = _cardan(p, v)
        return S, None, H_R, None, b_R, None


_H_T_FREE = np.hstack([_E, np.zeros((3, 3))])


class FreeQuaternion:
    """Translation in the joint (parent) frame, then a quaternion rotation."""
    npos, nvel = 7, 6

    def motion(self, p, v):
        S = quat_to_matrix(p[3:7])
        return S, p[0:3], np.hstack([np.zeros((3, 3)), S]), _H_T_FREE, None, None


class FreeCardan:
    npos = nvel = 6

    def motion(self, p, v):
        S, H, b_R = _cardan(p[3:6], v[3:6])
        return S, p[0:3], np.hstack([np.zeros((3, 3)), H]), _H_T_FREE, b_R, None


_XYZ, _QUAT, _CARDAN, _OMEGA = ("x", "y", "z"), ("q0", "q1", "q2", "q3"), ("a", "b", "c"), ("wx", "wy", "wz")
_P = ("parameterization",)


def _slice(names, part):
    k = names.index(part[0]) if part[0] in names else -1
    return slice(k, k + len(part)) if k >= 0 and tuple(names[k:k + len(part)]) == part else None


class JointType:
    """A row of the joint table: the scene's joint type (and parameterization), its numpy joint class, the scene
    fields it takes, its default coordinate names (suffixes of `<body>.`) and their units, its engine code; the
    rule its two axes obey (an R_* code of mbs_layout.h), whether it has a free orientation (`initial.rotation`,
    `initial_velocity.omega`) and a free translation (`initial_velocity.velocity`)."""

    def __init__(self, cls, fields, positions, units, velocities=None, velocity_units=None, axes_rule=None,
                 translation=False):
        self.cls, self.fields, self.positions, self.units = cls, fields, positions, units
        self.velocities = positions if velocities is None else velocities
        self.velocity_units = units if velocity_units is None else velocity_units
        self.npos, self.nvel = len(self.positions), len(self.velocities)
        self.axes_rule, self.translation = axes_rule, translation
        self.quaternion = _slice(positions, _QUAT)  # where the unit quaternion sits in y, or None
        self.cardan = _slice(positions, _CARDAN)    # where the x-y-z Cardan angles sit, or None
        self.orientation = self.quaternion is not None or self.cardan is not None

    def make(self, axis=None, axes=None):
        return self.cls(axis) if "axis" in self.fields else self.cls(axes) if "axes" in self.fields else self.cls()


# The joint table (contract: docs/scene-format.md, "Joints"), keyed by (type, parameterization or None) as
# mbs_layout.h's MBS_JOINTS, whose codes and coordinate counts tests/test_layout.py holds it against.
JOINTS = {
    ("fixed", None): JointType(Fixed, (), (), ()),
    ("revolute", None): JointType(Revolute, ("axis",), ("angle",), ("rad",)),
    ("prismatic", None): JointType(Prismatic, ("axis",), ("s",), ("m",)),
    ("cylindrical", None): JointType(Cylindrical, ("axis",), ("s", "angle"), ("m", "rad")),
    ("universal", None): JointType(Universal, ("axes",), ("angle1", "angle2"), ("rad", "rad"),
                                   axes_rule=L.R_NOT_PARALLEL),
    ("planar", None): JointType(Planar, ("axes",), ("x", "y", "angle"), ("m", "m", "rad"),
                                axes_rule=L.R_PERPENDICULAR),
    ("spherical", "quaternion"): JointType(SphericalQuaternion, _P, _QUAT, ("1",) * 4, _OMEGA, ("rad",) * 3),
    ("spherical", "cardan"): JointType(SphericalCardan, _P, _CARDAN, ("rad",) * 3),
    ("free", "quaternion"): JointType(FreeQuaternion, _P, _XYZ + _QUAT, ("m",) * 3 + ("1",) * 4, _XYZ + _OMEGA,
                                      ("m",) * 3 + ("rad",) * 3, translation=True),
    ("free", "cardan"): JointType(FreeCardan, _P, _XYZ + _CARDAN, ("m",) * 3 + ("rad",) * 3, translation=True),
}
_CODES = {(e[1], e[2] or None): L.CONSTANTS[e[0]] for e in L.LISTS["MBS_JOINTS"]}
for (_kind, _param), _row in JOINTS.items():
    _row.kind, _row.param, _row.code = _kind, _param, _CODES.get((_kind, _param))
TYPES = tuple(dict.fromkeys(kind for kind, _ in JOINTS))  # the scene's joint types, in table order
PARAMETERIZATIONS = {kind: tuple(p for k, p in JOINTS if k == kind and p) for kind in TYPES}  # first: the default


def joint_type(kind, parameterization="quaternion"):
    """The table's row of a scene joint (the parameterization matters only to the types that have one)."""
    return JOINTS[(kind, parameterization if PARAMETERIZATIONS[kind] else None)]


def make_joint(kind, axis=None, axes=None, parameterization="quaternion"):
    """The joint object for a scene joint type."""
    return joint_type(kind, parameterization).make(axis, axes)


def quaternion_slice(kind, parameterization):
    """Positions of the quaternion inside a joint's position coordinates (or None)."""
    return joint_type(kind, parameterization).quaternion
