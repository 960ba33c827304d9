"""The scene-specific evaluator of M(y,t)·ÿ + k(y,ẏ,t) = q(y,ẏ,t) — the public `mbsfmu.compile` result.

This is the readable numpy reference of the seed equations (tree.py, bodies/); runs use the C engine
(mbsfmu.engine), and the tests hold the engine against this evaluator."""

import math

import numpy as np

from ..expr import parse
from ..kinematics.rotations import cross, matrix_to_quat, quat_rate_matrix
from ..compiler.model import Model, initial_rotation
from .tree import applied_forces, kinematics, mass_matrix_and_bias, point


class Evaluator:
    """Equations of motion of one scene. `y` are position coordinates, `yd` velocity coordinates."""

    def __init__(self, spec):
        self.model = Model(spec)
        m = self.model
        self.name = m.name
        self.coordinates = list(m.coordinates)
        self.velocity_coordinates = list(m.velocity_coordinates)
        self.force_inputs = list(m.inputs)
        self.inputs = [f"q.{c}" for c in self.velocity_coordinates] + [f"{n}.{x}" for n in m.inputs for x in "xyz"]
        self._q_index = {f"q.{c}": i for i, c in enumerate(self.velocity_coordinates)}
        self._bind_outputs()

    def _bind_outputs(self):
        """The `outputs:` points with their parameter-dependent body-frame offsets evaluated once."""
        m = self.model
        self._out_points = []
        for o in m.outputs:
            syms = [s for q, s in (("position", "r"), ("velocity", "v")) if q in o["quantities"]]
            r_b = None if o.get("node") is not None else np.array([parse(x)(m.env) for x in o["point"]], dtype=float)
            self._out_points.append((o, m.index[o["body"]], r_b, syms))
        self._stress = []   # (variable name, the body's elastic coordinates, the node's stress modes 6 × n)
        for b in m.spec["bodies"]:
            fe = (b.get("elastic") or {}).get("fe") or {}
            if "stress_names" in fe:
                from ..bodies.cms import stress_table   # here: bodies imports scene, which imports this package
                q_idx = m.bodies[m.index[b["name"]]].q_idx
                self._stress += [(f"vm.{b['name']}.{name}", q_idx, S)
                                 for name, S in zip(fe["stress_names"], stress_table(fe))]

    # -- parameters and initial state ---------------------------------------------------------------
    @property
    def parameters(self):
        return dict(self.model.parameters)

    def set_parameters(self, params):
        """Change parameters without recompiling (re-binds the numbers only)."""
        self.model.bind({k: float(v) for k, v in params.items()})
        self._bind_outputs()

    def initial_state(self):
        """y(0), ẏ(0) from the scene's `initial`, `initial_velocity` and initial rotations."""
        m = self.model
        env = dict(m.env, t=0.0)
        y, yd = np.zeros(m.npos), np.zeros(m.nvel)
        for b in m.bodies:
            j = b.spec["joint"]
            for k, c in enumerate(b.coordinates):
                if b.pos_idx[k] >= 0 and c in j["initial"]:
                    y[b.pos_idx[k]] = parse(j["initial"][c])(env)
            for k, c in enumerate(b.velocities):
                if b.vel_idx[k] >= 0 and c in j["initial_velocity"]:
                    yd[b.vel_idx[k]] = parse(j["initial_velocity"][c])(env)
            if b.quat is not None:
                y[b.pos_idx[b.quat]] = matrix_to_quat(initial_rotation(j["initial_rotation"], env))
            elif b.type.orientation and j["initial_rotation"] is not None:
                S = initial_rotation(j["initial_rotation"], env)  # Cardan x-y-z angles of S
                angles = _cardan_angles(S)
                for k, c in enumerate(b.coordinates[-3:]):
                    idx = b.pos_idx[len(b.coordinates) - 3 + k]
                    if idx >= 0 and c not in j["initial"]:
                        y[idx] = angles[k]
            if b.elastic:
                for key, vec in (("initial", y), ("initial_velocity", yd)):
                    for c, v in b.elastic[key].items():
                        idx = (b.q_idx if key == "initial" else b.qd_idx)[b.elastic["coordinates"].index(c)]
                        vec[idx] = parse(v)(env)
        return y, yd

    # -- equations ----------------------------------------------------------------------------------
    def _split_inputs(self, u):
        """FMU-named inputs → (q_in vector or None, {force input: 3-vector})."""
        if not u:
            return None, None
        q_in, F_in = None, {}
        for name, value in u.items():
            if name in self._q_index:
                if q_in is None:
                    q_in = np.zeros(self.model.nvel)
                q_in[self._q_index[name]] = value
                continue
            base, _, comp = name.rpartition(".")
            if base not in self.force_inputs or comp not in ("x", "y", "z"):
                raise KeyError(f"unknown input '{name}'; valid: {', '.join(self.inputs)}")
            F_in.setdefault(base, np.zeros(3))["xyz".index(comp)] = value
        return q_in, F_in

    def equations(self, y, yd, t=0.0, u=None):
        """M (f×f), k (f), q (f) at (y, ẏ, t) with inputs u = {FMU input name: value}."""
        q_in, F_in = self._split_inputs(u)
        return self._equations(np.asarray(y, float), np.asarray(yd, float), t, q_in, F_in)

    def _equations(self, y, yd, t, q_in, F_in):
        d = kinematics(self.model, y, yd, t)
        M, k, q = mass_matrix_and_bias(self.model, d)
        q += applied_forces(self.model, d, y, yd, t, q_in, F_in)
        return M, k, q

    def accelerations(self, y, yd, t=0.0, q_in=None, F_in=None):
        """ÿ = M⁻¹ (q − k)."""
        M, k, q = self._equations(y, yd, t, q_in, F_in)
        return np.linalg.solve(M, q - k)

    def position_rates(self, y, yd):
        """ẏ_pos from the velocity coordinates (identity except ṗ = G(p) ω for quaternions)."""
        m = self.model
        if not m.quaternions:
            return yd
        out = np.empty(m.npos)
        for qi, wi in zip(m.quaternions, m.quat_vel):
            out[qi] = quat_rate_matrix(y[qi]) @ yd[wi]
        out[m.plain_pos] = yd[m.plain_vel]
        return out

    # -- body quantities ----------------------------------------------------------------------------
    def kinematics(self, y, yd, t=0.0):
        """Per-body workspace (body origins, world frame), see equations/tree.py."""
        return kinematics(self.model, np.asarray(y, float), np.asarray(yd, float), t)

    def jacobians(self, y, yd, t=0.0):
        """Per body at its centre of mass: r, S, v, ω, J_T, J_R, v̄, ω̄, ā, ᾱ (seed 000)."""
        y, yd = np.asarray(y, float), np.asarray(yd, float)
        d = kinematics(self.model, y, yd, t)
        out = {}
        for i, b in enumerate(self.model.bodies):
            c = d.S[i] @ b.c if b.c is not None else np.zeros(3)
            r, v, J_T = point(d, i, b.c if b.c is not None else np.zeros(3))
            a = d.a[i] + cross(d.al[i], c) + cross(d.w[i], cross(d.w[i], c))
            out[b.name] = {"r": r, "S": d.S[i], "v": v, "omega": d.w[i], "J_T": J_T, "J_R": d.J_R[i],
                           "v_bar": v - J_T @ yd, "omega_bar": d.w[i] - d.J_R[i] @ yd, "a_bar": a, "alpha_bar": d.al[i]}
        return out

    def point_state(self, y, yd, body, r_body, t=0.0):
        """World position and velocity of a point fixed on a body."""
        d = kinematics(self.model, np.asarray(y, float), np.asarray(yd, float), t)
        r, v, _ = point(d, self.model.index[body], np.asarray(r_body, float))
        return r, v

    def output_values(self, y, yd, t):
        """{FMU output name: value} of the scene's `outputs:` points (world position r, velocity v) and von Mises
        stresses (σ = Σ_k σ_k q_k at an FE body's stress node)."""
        out = {}
        d = kinematics(self.model, np.asarray(y, float), np.asarray(yd, float), t) if self._out_points else None
        for o, i, r_b, syms in self._out_points:
            if r_b is None:
                r, v, _ = _node_pt(self.model, d, i, o["node"])
            else:
                r, v, _ = point(d, i, r_b)
            for sym in syms:
                vec = r if sym == "r" else v
                for k, ax in enumerate("xyz"):
                    out[f"{o['name']}.{sym}.{ax}"] = float(vec[k])
        for name, q_idx, S in self._stress:
            sxx, syy, szz, sxy, syz, szx = S @ np.asarray(y, float)[q_idx]
            out[name] = math.sqrt(0.5 * ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2)
                                  + 3.0 * (sxy ** 2 + syz ** 2 + szx ** 2))
        return out

    def singularity_message(self, y, y_before=None):
        """Why M is (or was, between y_before and y) singular: Cardan angles at gimbal lock (b = ±90°), else None."""
        for b in self.model.bodies:
            if b.type.cardan is not None:
                k = len(b.coordinates) - 2  # the middle angle b
                idx = b.pos_idx[k]
                if idx < 0:
                    continue
                angle = y[idx]
                crossed = y_before is not None and math.cos(y_before[idx]) * math.cos(angle) < 0
                if crossed or abs(math.cos(angle)) < 1e-3:
                    return (f"gimbal lock: Cardan angle {b.coordinates[k]} = {angle:.6g} rad reached ±90°, where the "
                            f"x-y-z angles of body '{b.name}' are singular; use parameterization: quaternion")
        return None

    def energy(self, y, yd, t=0.0):
        """Kinetic + potential energy (gravity, springs, elastic strain): conserved without damping and inputs."""
        y, yd = np.asarray(y, float), np.asarray(yd, float)
        m = self.model
        d = kinematics(m, y, yd, t)
        if m.has_drives and not m.has_elastic:  # ½ẏᵀMẏ misses the drives' v̄, ω̄: sum over the bodies
            E = 0.0
            for i in m.massive:
                b = m.bodies[i]
                _, v, _ = point(d, i, b.c if b.c is not None else np.zeros(3))
                Iw = d.S[i] @ (b.I @ (d.S[i].T @ d.w[i]))
                E += 0.5 * b.m * (v @ v) + 0.5 * (d.w[i] @ Iw)
        else:
            M, _, _ = mass_matrix_and_bias(m, d)
            E = 0.5 * yd @ M @ yd
        if m.g is not None:
            for i in m.massive:
                b = m.bodies[i]
                r, _, _ = point(d, i, b.c if b.c is not None else np.zeros(3))
                E -= b.m * (m.g @ r)
        for f in m.bound_forces:
            if f["type"] == "joint_spring_damper":
                E += 0.5 * f["stiffness"] * (y[f["pos_index"]] - f["offset"]) ** 2
            elif f["type"] == "spring_damper":
                (xa, _, _), (xb, _, _) = (point(d, i, at) if node is None else _node_pt(m, d, i, node) for i, at, node in zip(f["body_index"], f["at"], f["node"]))
                E += 0.5 * f["stiffness"] * (math.sqrt((xb - xa) @ (xb - xa)) - f["length"]) ** 2
        if m.has_elastic:
            from ..bodies.tree import elastic_energy
            E += elastic_energy(m, d, y, yd)
        return E


def _node_pt(m, d, i, node):
    from ..bodies.tree import node_point
    return node_point(m, d, i, node)


def _cardan_angles(S):
    """x-y-z Cardan angles (a, b, c) with S = Sx(a) Sy(b) Sz(c)."""
    b = math.asin(max(-1.0, min(1.0, S[0, 2])))
    a = math.atan2(-S[1, 2], S[2, 2])
    c = math.atan2(-S[0, 1], S[0, 0])
    return a, b, c
