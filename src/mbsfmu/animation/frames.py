"""Trajectory → what the page draws: per frame each body's pose, elastic nodes and spring end points.

Poses come from the numpy reference kinematics (`equations.tree.kinematics`, build time): body i's frame
is at o_i with rotation S_i (body → world); elastic nodes at r_IR + S (R_RP + Φ_P q) (`bodies.tree.node_point`).
The page only interpolates between these frames; it does no physics.
"""

import numpy as np

from ..equations.tree import kinematics, point
from ..kinematics.rotations import matrix_to_quat


class Layout:
    """Which numbers one frame holds, in order: for each body position (3) and quaternion x, y, z, w (4),
    then each elastic body's node positions (3 per node), then each spring's two end points (6)."""

    def __init__(self, model):
        self.model = model
        self.elastic = [i for i, b in enumerate(model.bodies) if b.elastic]
        self.nodes = [model.bodies[i].nodal.nodes for i in self.elastic]
        self.springs = [f for f in model.bound_forces if f["type"] == "spring_damper"]
        self.stride = 7 * len(model.bodies) + 3 * sum(self.nodes) + 6 * len(self.springs)


def frame(layout, y, yd, t):
    """One frame's numbers (see Layout) at state y, ẏ and time t."""
    model = layout.model
    d = kinematics(model, y, yd, t)
    out = []
    for S, o in zip(d.S, d.o):
        p = matrix_to_quat(S)  # scalar first
        out += [*o, p[1], p[2], p[3], p[0]]
    if layout.elastic:
        from ..bodies.tree import node_point
        for i, n in zip(layout.elastic, layout.nodes):
            for P in range(n):
                out += list(node_point(model, d, i, P)[0])
    for f in layout.springs:
        for i, at, node in zip(f["body_index"], f["at"], f["node"]):
            if node is not None:
                from ..bodies.tree import node_point
                out += list(node_point(model, d, i, node)[0])
            else:
                out += list(point(d, i, at)[0])
    return out


def frames(model, t, Y, YD=None):
    """(Layout, F): F[k] holds frame k of the trajectory (t[k], Y[k], YD[k]); quaternion signs kept
    continuous from frame to frame so the page can interpolate between neighbours."""
    layout = Layout(model)
    Y = np.asarray(Y, dtype=float)
    YD = np.zeros((len(Y), model.nvel)) if YD is None else np.asarray(YD, dtype=float)
    F = np.array([frame(layout, y, yd, tk) for tk, y, yd in zip(t, Y, YD)]).reshape(len(t), layout.stride)
    for i in range(len(model.bodies)):
        Q = F[:, 7 * i + 3:7 * i + 7]  # a view: flips land in F
        for k in range(1, len(t)):
            if Q[k] @ Q[k - 1] < 0:
                Q[k] *= -1
    return layout, F
