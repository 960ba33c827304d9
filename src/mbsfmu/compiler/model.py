"""Compile a normalized scene into a Model (structure, fixed at compile time) whose numeric data are
bound from the parameters (`bind`), apart from the per-call workspace (Pinocchio's Model/Data split).

What is structurally zero for the scene is decided here, once: a joint offset or rotation written
as a literal zero, a body without mass, no gravity, no drives — the evaluator then skips that work.
"""

import numpy as np

from ..expr import parse
from ..kinematics.joints import joint_type
from ..kinematics.rotations import axis_angle


def _is_zero(values):
    return all(isinstance(v, (int, float)) and v == 0 for v in values)


def _vec(values, env):
    if all(type(v) is float for v in values):  # the loader writes numbers as floats, expressions as text
        return np.array(values)
    return np.array([parse(v)(env) for v in values], dtype=float)


def _number(value, env):
    return value if type(value) is float else parse(value)(env)


def _rotation(rot, env):
    if rot is None:
        return None
    if "matrix" in rot:
        return np.array([[parse(x)(env) for x in row] for row in rot["matrix"]], dtype=float)
    a = _vec(rot["axis"], env)
    return axis_angle(a / np.linalg.norm(a), parse(rot["angle"])(env))


class Body:
    """Compiled body: tree links, joint, index maps into y and ẏ, and bound inertial data."""

    def __init__(self, spec, parent):
        j = spec["joint"]
        self.name, self.spec, self.parent = spec["name"], spec, parent  # parent: index in topological order, -1 world
        self.kind = j["type"]
        self.param = j.get("parameterization", "quaternion")
        self.type = joint_type(self.kind, self.param)  # its row of the joint table
        self.quat = self.type.quaternion
        self.coordinates, self.velocities = j["coordinates"], j["velocities"]
        self.driven = [c in j["drive"] for c in self.coordinates]
        self.drives = [(k, parse(j["drive"][c])) for k, c in enumerate(self.coordinates) if c in j["drive"]]
        self.drives = [(k, e, e.diff("t"), e.diff("t").diff("t")) for k, e in self.drives]
        self.has_at = not _is_zero(j["at"])
        self.has_rotation = j["rotation"] is not None
        self.has_com = not _is_zero(spec["center_of_mass"])
        self.node = j.get("node")
        self.elastic = spec.get("elastic")

    def bind(self, env):
        """Evaluate the parameter-dependent data of this body."""
        j, s = self.spec["joint"], self.spec
        self.joint = self.type.make(axis=_vec(j["axis"], env) if "axis" in j else None,
                                    axes=[_vec(a, env) for a in j["axes"]] if "axes" in j else None)
        self.at = _vec(j["at"], env) if self.has_at else None
        self.R0 = _rotation(j["rotation"], env) if self.has_rotation else None
        self.m = _number(s["mass"], env)
        self.c = _vec(s["center_of_mass"], env) if self.has_com else None
        self.I = np.array([_vec(row, env) for row in s["inertia"]])
        lam, V = np.linalg.eigh(self.I)
        self.L_T = (V * np.sqrt(np.clip(lam, 0.0, None))).T  # I = L L^T; rows of L^T weight J_R
        self.has_inertia = bool(np.any(lam > 0))
        if self.elastic:
            from ..bodies.tree import bind_elastic  # elastic code is loaded only by elastic scenes
            bind_elastic(self, env)


def _parents_first(bodies):
    """The bodies parents first, otherwise in file order: the order of passes over the file that each place the
    bodies whose parent is placed (a parent later in the file waits for the next pass), found in linear time as
    (pass, file position), pass = the parent's, +1 if the parent comes later in the file (a 10,000-body chain
    written leaves first took 10,000 passes)."""
    pos = {b["name"]: k for k, b in enumerate(bodies)}
    passes = {"world": 1}
    for b in bodies:  # the pass of each body's line of ancestors, unknown ones from the top (no recursion)
        line, name = [], b["name"]
        while name not in passes:
            line.append(name)
            name = bodies[pos[name]]["parent"]
        for name in reversed(line):
            parent = bodies[pos[name]]["parent"]
            passes[name] = passes[parent] + (parent != "world" and pos[parent] > pos[name])
    return sorted(bodies, key=lambda b: (passes[b["name"]], pos[b["name"]]))


class Model:
    """Structure of a scene's equations of motion; `bind(params)` sets its numbers."""

    def __init__(self, spec, bind=True):
        """``bind=False``: the structure only (what the FMU variables are: their names, units and order), with
        only the elastic bodies bound (their modes set their coordinates' units)."""
        self.spec = spec
        self.name = spec["name"]
        self.parameters = {p["name"]: p["value"] for p in spec["parameters"]}
        order = _parents_first(spec["bodies"])
        placed = {"world": -1, **{b["name"]: i for i, b in enumerate(order)}}
        self.bodies = [Body(b, placed[b["parent"]]) for b in order]
        self.index = {b.name: i for i, b in enumerate(self.bodies)}
        # y and ẏ in file order of the bodies (contract), each joint's free coordinates then elastic ones
        self.coordinates, self.velocity_coordinates = [], []
        for b in spec["bodies"]:
            body = self.bodies[self.index[b["name"]]]
            body.pos_idx = np.full(len(body.coordinates), -1)
            body.vel_idx = np.full(len(body.velocities), -1)
            for k, c in enumerate(body.coordinates):
                if not body.driven[k]:
                    body.pos_idx[k] = len(self.coordinates)
                    self.coordinates.append(c)
            for k, c in enumerate(body.velocities):
                if body.quat is not None or not body.driven[k]:
                    body.vel_idx[k] = len(self.velocity_coordinates)
                    self.velocity_coordinates.append(c)
            body.free_cols = np.flatnonzero(body.vel_idx >= 0)
            body.J_cols = body.vel_idx[body.free_cols]
            body.drv_cols = np.flatnonzero(body.vel_idx < 0)
            body.ps = body.pos_idx[0] if len(body.pos_idx) and not body.drives else None
            body.vs = body.vel_idx[0] if len(body.vel_idx) and not body.drives else None
            if body.elastic:
                n = len(body.elastic["coordinates"])
                body.q_idx = np.arange(len(self.coordinates), len(self.coordinates) + n)
                body.qd_idx = np.arange(len(self.velocity_coordinates), len(self.velocity_coordinates) + n)
                self.coordinates += body.elastic["coordinates"]
                self.velocity_coordinates += body.elastic["coordinates"]
        self.npos, self.nvel = len(self.coordinates), len(self.velocity_coordinates)
        self.quaternions = [b.pos_idx[b.quat] for b in self.bodies if b.quat is not None]
        self.quat_vel = [b.vel_idx[-3:] for b in self.bodies if b.quat is not None]  # body-frame ω of each quaternion
        # coordinates whose rate is their velocity coordinate (everything but quaternions), in matching order
        quat_p = set(np.concatenate(self.quaternions).tolist()) if self.quaternions else set()
        quat_w = set(np.concatenate(self.quat_vel).tolist()) if self.quat_vel else set()
        self.plain_pos = np.array([i for i in range(self.npos) if i not in quat_p], dtype=int)
        self.plain_vel = np.array([i for i in range(self.nvel) if i not in quat_w], dtype=int)
        self.has_drives = any(b.drives for b in self.bodies)
        self.has_elastic = any(b.elastic for b in self.bodies)
        g = spec["gravity"]
        self.has_gravity = not _is_zero(g)
        self.forces = spec["forces"]
        self.outputs = spec["outputs"]
        self.inputs = [f["input"] for f in self.forces if "input" in f]
        if bind:
            self.bind(self.parameters)
        else:
            for b in self.bodies:
                if b.elastic:
                    b.bind(dict(self.parameters, t=0.0))

    def coordinate_units(self):
        """Units of y and ẏ entries (contract order): the joint table's, then the elastic coordinates': m for
        FE and beam modes (scaled so that the largest node translation is 1), rad for a beam's pure torsion
        mode (its largest rotation 1), 1 for nodal data as given."""
        pos, vel = [], []
        for b in (self.bodies[self.index[s["name"]]] for s in self.spec["bodies"]):
            pos += [u for u, dr in zip(b.type.units, b.driven) if not dr]
            vel += [u + "/s" for u, dr in zip(b.type.velocity_units, b.driven) if not dr or b.quat is not None]
            if b.elastic:
                units = [_mode_unit(b.elastic, b.nodal.Phi[:, :, k]) for k in range(b.nodal.Phi.shape[2])]
                pos += units
                vel += [u + "/s" for u in units]
        return pos, vel

    def bind(self, params):
        """(Re)evaluate every parameter-dependent number."""
        unknown = set(params) - set(self.parameters)
        if unknown:
            raise KeyError(f"unknown parameter(s): {', '.join(sorted(unknown))}; valid: {', '.join(self.parameters) or '(none)'}")
        self.parameters = dict(self.parameters, **params)
        env = dict(self.parameters, t=0.0)
        self.env = env
        self.g = _vec(self.spec["gravity"], env) if self.has_gravity else None
        for b in self.bodies:
            b.bind(env)
        self.massive = [i for i, b in enumerate(self.bodies) if (b.m > 0 or b.has_inertia) and not b.elastic]
        self.bound_forces = [self._resolve(_bind_force(f, env)) for f in self.forces]

    def _resolve(self, f):
        """Names in a bound force element → indices into y, ẏ and the bodies."""
        if f["type"] == "joint_spring_damper":
            f["pos_index"] = self.coordinates.index(f["coordinate"])
            f["vel_index"] = self.velocity_coordinates.index(f["coordinate"])
        elif f["type"] == "spring_damper":
            f["body_index"] = [self.index.get(n, -1) for n in f["bodies"]]
        else:
            f["body_index"] = self.index[f["body"]]
        return f


def _bind_force(f, env):
    """Numbers of a force element (time-dependent values stay expressions)."""
    out = dict(f)
    for k in ("stiffness", "damping", "length", "offset"):
        if k in f:
            out[k] = parse(f[k])(env)
    if "at" in f:
        out["at"] = [_vec(a, env) for a in f["at"]] if f["type"] == "spring_damper" else _vec(f["at"], env)
    if "value" in f:
        exprs = [parse(v) for v in f["value"]]
        out["value"] = exprs
        out["constant"] = _vec(f["value"], env) if all("t" not in e.names for e in exprs) else None
    return out


def initial_rotation(rot, env):
    """Initial rotation matrix of a spherical/free joint (identity when not given)."""
    return np.eye(3) if rot is None else _rotation(rot, env)


def _mode_unit(elastic, phi):
    """The unit of a modal coordinate (Model.coordinate_units): how its source scaled the mode."""
    if "fe" in elastic:
        return "m"
    if "beam" in elastic:
        return "m" if np.abs(phi).max(initial=0.0) > 1e-6 else "rad"  # a torsion mode: bodies/beam.py _mode_scale
    return "1"
