"""Elastic bodies inside the tree (seed 004 joined to seed 000).

An elastic body's reference frame R is its body frame; its elastic coordinates q join y. With
z_II = [v_R; ω_R; q̇] = J_z·ẏ (R components) and J_z = [Sᵀ J_T; Sᵀ J_R; E_q], the FFRF equations
M_zz·z_III + h = f_g + f_e add J_zᵀ M_zz J_z to M, J_zᵀ (M_zz z̄_III + h) to k and J_zᵀ (f_g + f_e) to q.
Children and forces at node P move with r_IP = r_IR + S(R_RP + Φ_P q), S_IP = S (E + (Ψ_P q)~).
"""

import numpy as np

from ..expr import parse
from ..kinematics.rotations import cross, skew
from .beam import beam_from_spec
from .ffrf import elastic_forces, gravity_forces, invariants, mass_matrix, quadratic_forces
from .cms import nodal_data
from .nodal import check_damping, modal_mass, validate_nodal


def bind_elastic(body, env):
    """Nodal data and mass invariants of an elastic body (once per parameter set)."""
    e = body.elastic
    key = f"bodies.{body.name}.elastic"
    ratio = parse(e["damping_ratio"])(env)
    if "beam" in e:
        spec = {k: v for k, v in e["beam"].items() if v is not None}
        for k in ("length", "rhoA", "EA", "GJ", "rhoIp"):
            if k in spec:
                spec[k] = parse(spec[k])(env)
        spec["EI"] = [parse(x)(env) for x in spec["EI"]]
        nodal = beam_from_spec(spec, key=key + ".beam", damping_ratio=ratio, dynamic_stiffening=e["dynamic_stiffening"])
    elif "fe" in e:   # reduced when the scene was loaded (cms.py); the normalized scene holds the reduced body
        nodal = nodal_data(e["fe"], damping_ratio=ratio, key=key + ".fe")
        if "damping" in e:
            nodal.damping = check_damping(e["damping"], nodal.n, key)
    else:
        data = dict(e["nodal"])
        if "damping" in e:
            data["damping"] = e["damping"]
        nodal = validate_nodal(data, key=key + ".nodal", damping_ratio=ratio if ratio and "damping" not in e else None)
        if not e["dynamic_stiffening"]:
            nodal.stiffening = None
    if e.get("rayleigh"):   # D = α M_ee + β K (proportional damping of the retained modes)
        alpha, beta = (parse(x)(env) for x in e["rayleigh"])
        nodal.damping = alpha * modal_mass(nodal) + beta * nodal.stiffness
    body.nodal = nodal
    body.inv = invariants(nodal, dynamic_stiffening=e["dynamic_stiffening"] and nodal.stiffening is not None)


def elastic_kinematics(model, d, i, y, yd):
    """Store q, q̇ and J_z of elastic body i in the workspace."""
    b = model.bodies[i]
    q, qd = y[b.q_idx], yd[b.qd_idx]
    S = d.S[i]
    J_z = np.zeros((6 + len(q), model.nvel))
    J_z[:3] = S.T @ d.J_T[i]
    J_z[3:6] = S.T @ d.J_R[i]
    J_z[6 + np.arange(len(q)), b.qd_idx] = 1.0
    d.extra[i] = (q, qd, J_z)


def _node(b, node):
    N = b.nodal.nodes
    if not -N <= node < N:
        raise IndexError(f"node {node} of body '{b.name}' does not exist (it has {N} nodes)")
    return node % N


def _node_motion(model, d, i, node):
    """World position, velocity, bias acceleration, J_T and the rotation part at node P of body i."""
    b = model.bodies[i]
    P = _node(b, node)
    q, qd, _ = d.extra[i]
    S, w = d.S[i], d.w[i]
    rho = S @ (b.nodal.R_RP[P] + b.nodal.Phi[P] @ q)
    u = S @ (b.nodal.Phi[P] @ qd)                # elastic velocity of the node
    wxr = cross(w, rho)
    r = d.o[i] + rho
    v = d.v[i] + wxr + u
    a = d.a[i] + cross(d.al[i], rho) + cross(w, wxr) + 2.0 * cross(w, u)
    J_T = d.J_T[i] - skew(rho) @ d.J_R[i]
    J_T = J_T.copy()
    J_T[:, b.qd_idx] += S @ b.nodal.Phi[P]
    return P, r, v, a, J_T


def node_point(model, d, i, node):
    """World position, velocity and J_T of node P of elastic body i (seed 004)."""
    _, r, v, _, J_T = _node_motion(model, d, i, node)
    return r, v, J_T


def node_rotation_jacobian(model, d, i, node):
    """J_R at node P: J_R + S Ψ_P on the elastic columns."""
    b = model.bodies[i]
    P = _node(b, node)
    J_R = d.J_R[i].copy()
    J_R[:, b.qd_idx] += d.S[i] @ b.nodal.Psi[P]
    return J_R


def node_frame(model, d, child):
    """Attachment frame of a child joint at a node of its elastic parent (for tree.attachment)."""
    i = child.parent
    b = model.bodies[i]
    P, r, v, a, J_T = _node_motion(model, d, i, child.node)
    q, qd, _ = d.extra[i]
    S = d.S[i]
    w_rel = S @ (b.nodal.Psi[P] @ qd)
    S_P = S @ (np.eye(3) + skew(b.nodal.Psi[P] @ q))
    w = d.w[i] + w_rel
    al = d.al[i] + cross(d.w[i], w_rel)
    J_R = node_rotation_jacobian(model, d, i, child.node)
    S_J = S_P @ child.R0 if child.R0 is not None else S_P
    return S_P, r, w, v, a, al, J_R, J_T, None, S_J


def elastic_equations(model, d, M, k, q):
    """Add every elastic body's J_zᵀ M_zz J_z, J_zᵀ (M_zz z̄_III + h) and J_zᵀ (f_g + f_e)."""
    for i, b in enumerate(model.bodies):
        if not b.elastic:
            continue
        qe, qd, J_z = d.extra[i]
        S = d.S[i]
        w_R = S.T @ d.w[i]
        M_zz = mass_matrix(b.inv, qe)
        z_bar = np.concatenate([S.T @ d.a[i], S.T @ d.al[i], np.zeros(len(qe))])
        MJ = M_zz @ J_z
        M = M + J_z.T @ MJ
        k = k + J_z.T @ (M_zz @ z_bar + quadratic_forces(b.inv, qe, qd, w_R))
        f = elastic_forces(b.inv, qe, qd)
        if model.g is not None:
            f += gravity_forces(b.inv, qe, S.T @ model.g)
        q = q + J_z.T @ f
    return M, k, q


def elastic_energy(model, d, y, yd):
    """Strain energy ½ qᵀKq and gravity potential of the elastic bodies (kinetic energy is in ½ ẏᵀMẏ)."""
    from .ffrf import first_moment
    E = 0.0
    for i, b in enumerate(model.bodies):
        if not b.elastic:
            continue
        qe = d.extra[i][0]
        E += 0.5 * qe @ b.inv.K @ qe
        if model.g is not None:
            # first_moment includes the stiffening foreshortening, i.e. the potential ½ g_x qᵀK_a q
            E -= model.g @ (b.inv.m * d.o[i] + d.S[i] @ first_moment(b.inv, qe))
    return E
