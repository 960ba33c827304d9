"""Seed 000 on a tree: per body r_i, S_i, J_Ti, J_Ri, ā_i, ᾱ_i by one pass from the root, then
M = Σ J_Tᵀ m J_T + J_Rᵀ I J_R,  k = Σ J_Tᵀ m ā + J_Rᵀ (I ᾱ + ω̃ I ω),  q = Σ J_Tᵀ f + J_Rᵀ l.

World-frame quantities; J_T and ā are first those of the body-frame origin o_i (the centre of mass
follows with one shift), ā and ᾱ hold everything that does not multiply ÿ, rheonomic drive terms included.
"""

import math

import numpy as np

from ..kinematics.rotations import cross, skew

_E = np.eye(3)
_Z = np.zeros(3)


class Data:
    """Per-evaluation workspace: lists over the bodies in topological order."""

    __slots__ = ("S", "o", "w", "v", "a", "al", "J_R", "J_T", "t", "extra")

    def __init__(self, n):
        self.S, self.o, self.w, self.v = [None] * n, [None] * n, [None] * n, [None] * n
        self.a, self.al, self.J_R, self.J_T = [None] * n, [None] * n, [None] * n, [None] * n
        self.extra = {}


def joint_state(b, y, yd, env):
    """The joint's positions, velocities and the accelerations of its driven coordinates."""
    if b.ps is not None:
        return y[b.ps:b.ps + b.joint.npos], yd[b.vs:b.vs + b.joint.nvel], None
    p = np.empty(b.joint.npos)
    v = np.empty(b.joint.nvel)
    free = b.pos_idx >= 0
    p[free] = y[b.pos_idx[free]]
    v[b.free_cols] = yd[b.J_cols]
    a = np.empty(len(b.drives))
    for n, (k, f, fd, fdd) in enumerate(b.drives):
        p[k], v[k], a[n] = f(env), fd(env), fdd(env)
    return p, v, a


def attachment(model, d, b):
    """Joint frame of body b in the world: origin offset ρ_at, S_J, and the parent's motion.
    Returns (S_p, o_p, ω_p, v_p, a_p, α_p, J_Rp, J_Tp, at_w, S_J)."""
    if b.parent < 0:
        f = model.nvel
        S_p, o_p, w_p, v_p, a_p, al_p = _E, _Z, _Z, _Z, _Z, _Z
        J_Rp = J_Tp = np.zeros((3, f))
        at_w = b.at if b.at is not None else None
        S_J = b.R0 if b.R0 is not None else _E
        return S_p, o_p, w_p, v_p, a_p, al_p, J_Rp, J_Tp, at_w, S_J
    i = b.parent
    S_p = d.S[i]
    if model.bodies[i].elastic and b.node is not None:
        from ..bodies.tree import node_frame  # elastic code only for scenes that have elastic bodies
        return node_frame(model, d, b)
    at_w = S_p @ b.at if b.at is not None else None
    S_J = S_p @ b.R0 if b.R0 is not None else S_p
    return S_p, d.o[i], d.w[i], d.v[i], d.a[i], d.al[i], d.J_R[i], d.J_T[i], at_w, S_J


def kinematics(model, y, yd, t):
    """Recursive kinematics (seed 000): S_i, r_i, ω_i, v_i, ᾱ_i, ā_i, J_Ri, J_Ti of every body origin."""
    d = Data(len(model.bodies))
    d.t = t
    env = model.env
    if model.has_drives:
        env["t"] = t
    for i, b in enumerate(model.bodies):
        S_p, o_p, w_p, v_p, a_p, al_p, J_Rp, J_Tp, rho, S_J = attachment(model, d, b)
        if b.joint.nvel:
            p, v, a_drv = joint_state(b, y, yd, env)
            R, dd, H_R, H_T, b_R, b_T = b.joint.motion(p, v)
        else:
            R = dd = H_R = H_T = b_R = b_T = a_drv = None
        if dd is not None:
            dd_w = S_J @ dd
            rho = dd_w if rho is None else rho + dd_w
        w_rel = S_J @ (H_R @ v) if H_R is not None else None
        v_rel = S_J @ (H_T @ v) if H_T is not None else None
        if a_drv is not None:  # prescribed accelerations are known: they join the bias terms
            dc = b.drv_cols
            if H_R is not None:
                b_R = H_R[:, dc] @ a_drv + (b_R if b_R is not None else 0.0)
            if H_T is not None:
                b_T = H_T[:, dc] @ a_drv + (b_T if b_T is not None else 0.0)
        # ω_i = ω_p + ω_rel ;  ᾱ_i = ᾱ_p + ω_p × ω_rel + S_J b_R
        w = w_p if w_rel is None else w_p + w_rel
        al = al_p
        if w_rel is not None:
            al = al + cross(w_p, w_rel)
        if b_R is not None:
            al = al + S_J @ b_R
        # v_i = v_p + ω_p × ρ + v_rel ;  ā_i = ā_p + ᾱ_p × ρ + ω_p × (ω_p × ρ) + 2 ω_p × v_rel + S_J b_T
        v, a = v_p, a_p
        J_T = J_Tp
        o = o_p
        if rho is not None:
            wxr = cross(w_p, rho)
            o = o_p + rho
            v = v + wxr
            a = a + cross(al_p, rho) + cross(w_p, wxr)
            J_T = J_Tp - skew(rho) @ J_Rp
        if v_rel is not None:
            v = v + v_rel
            a = a + 2.0 * cross(w_p, v_rel)
        if b_T is not None:
            a = a + S_J @ b_T
        J_R = J_Rp
        cols = b.J_cols
        if len(cols):
            if H_R is not None:
                J_R = J_R.copy()
                J_R[:, cols] += S_J @ H_R[:, b.free_cols]
            if H_T is not None:
                J_T = J_T.copy()
                J_T[:, cols] += S_J @ H_T[:, b.free_cols]
        d.S[i] = S_J @ R if R is not None else S_J
        d.o[i], d.w[i], d.v[i], d.a[i], d.al[i], d.J_R[i], d.J_T[i] = o, w, v, a, al, J_R, J_T
        if b.elastic:
            from ..bodies.tree import elastic_kinematics
            elastic_kinematics(model, d, i, y, yd)
    return d


def point(d, i, r_body):
    """World position, velocity and J_T of a point fixed on body i (r_body in the body frame)."""
    if i < 0:
        return r_body, _Z, None
    r = d.S[i] @ r_body
    return d.o[i] + r, d.v[i] + cross(d.w[i], r), d.J_T[i] - skew(r) @ d.J_R[i]


def mass_matrix_and_bias(model, d):
    """M and k from the d'Alembert sums, as M = Aᵀ A, k = Aᵀ b + Σ J_Rᵀ (ω̃ I ω), with the rows of A
    √m J_Tc and Lᵀ Sᵀ J_R (I = L Lᵀ), the rows of b √m ā_c and Lᵀ Sᵀ ᾱ. Also the gravity part of q."""
    f = model.nvel
    rows = len(model.massive)
    A = np.empty((6 * rows, f))
    bvec = np.empty(6 * rows)
    k = np.zeros(f)
    q = np.zeros(f)
    g = model.g
    for r, i in enumerate(model.massive):
        b = model.bodies[i]
        S, w, J_R = d.S[i], d.w[i], d.J_R[i]
        J_T, a = d.J_T[i], d.a[i]
        if b.c is not None:
            c = S @ b.c
            wxc = cross(w, c)
            J_T = J_T - skew(c) @ J_R
            a = a + cross(d.al[i], c) + cross(w, wxc)
        sm = math.sqrt(b.m)
        A[6 * r:6 * r + 3] = sm * J_T
        bvec[6 * r:6 * r + 3] = sm * a
        if b.has_inertia:
            LS = b.L_T @ S.T
            A[6 * r + 3:6 * r + 6] = LS @ J_R
            bvec[6 * r + 3:6 * r + 6] = LS @ d.al[i]
            if w.any():
                w_b = S.T @ w
                k += J_R.T @ (S @ cross(w_b, b.I @ w_b))
        else:
            A[6 * r + 3:6 * r + 6] = 0.0
            bvec[6 * r + 3:6 * r + 6] = 0.0
        if g is not None and b.m:
            q += J_T.T @ (b.m * g)
    M = A.T @ A
    k += A.T @ bvec
    if model.has_elastic:
        from ..bodies.tree import elastic_equations
        M, k, q = elastic_equations(model, d, M, k, q)
    return M, k, q


def applied_forces(model, d, y, yd, t, q_in=None, F_in=None):
    """q from the force elements (seed 000: q = Σ J_Tᵀ f + J_Rᵀ l) and the generalized-force inputs."""
    q = np.zeros(model.nvel) if q_in is None else np.array(q_in, dtype=float)
    env = model.env
    for f in model.bound_forces:
        kind = f["type"]
        if kind == "joint_spring_damper":
            i = f["vel_index"]
            q[i] -= f["stiffness"] * (y[f["pos_index"]] - f["offset"]) + f["damping"] * yd[i]
            continue
        if kind == "spring_damper":
            (xa, va, Ja), (xb, vb, Jb) = (_force_point(model, d, name, at, node) for name, at, node in zip(f["body_index"], f["at"], f["node"]))
            dx = xb - xa
            l = math.sqrt(dx @ dx)
            if l < 1e-12:  # direction undefined at zero length: no force rather than NaN
                continue
            e = dx / l
            F = (f["stiffness"] * (l - f["length"]) + f["damping"] * (e @ (vb - va))) * e  # pulls B toward A
            if Ja is not None:
                q += Ja.T @ F
            if Jb is not None:
                q -= Jb.T @ F
            continue
        i = f["body_index"]
        if "input" in f:
            vec = F_in.get(f["input"]) if F_in else None
            if vec is None or not vec.any():
                continue
        elif f["constant"] is not None:
            vec = f["constant"]
        else:
            env["t"] = t
            vec = np.array([e(env) for e in f["value"]])
        if f["frame"] == "body":
            vec = d.S[i] @ vec
        if kind == "torque":
            J_R = d.J_R[i] if f.get("node") is None else _node_J_R(model, d, i, f["node"])
            q += J_R.T @ vec
        else:
            _, _, J = _force_point(model, d, i, f["at"], f.get("node"))
            q += J.T @ vec
    return q


def _force_point(model, d, i, at, node):
    if node is not None and i >= 0:
        from ..bodies.tree import node_point
        return node_point(model, d, i, node)
    return point(d, i, at)


def _node_J_R(model, d, i, node):
    from ..bodies.tree import node_rotation_jacobian
    return node_rotation_jacobian(model, d, i, node)

