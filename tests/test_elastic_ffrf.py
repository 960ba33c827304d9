"""FFRF equations: invariants vs the slow node loop, energy conservation of a free body, node kinematics."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mbsfmu.bodies import (K_geo, NodalData, beam, elastic_forces, gravity_forces, invariants, kinetic_energy,
                           mass_matrix, node_rotation, node_translation, quadratic_forces)
from mbsfmu.bodies.ffrf import first_moment
from mbsfmu.bodies.nodal import skew

E3 = np.eye(3)


def slow(nodal, q, qd, w, g=np.zeros(3)):
    """M, h, f_g by looping over the mass points with the seed-004 Jacobians (the independent check)."""
    p = nodal.points()
    n = nodal.n
    M, h, f = np.zeros((6 + n, 6 + n)), np.zeros(6 + n), np.zeros(6 + n)
    wt = skew(w)
    for m, R, J, Phi, Psi in zip(p.m, p.R, p.J, p.Phi, p.Psi):
        u = R + Phi @ q
        Jt = np.hstack([E3, -skew(u), Phi])
        Jr = np.hstack([np.zeros((3, 3)), E3, Psi])
        M += m * Jt.T @ Jt + Jr.T @ J @ Jr
        h += Jt.T @ (m * (wt @ wt @ u + 2 * wt @ Phi @ qd))
        h[3:6] += wt @ J @ (w + Psi @ qd)     # node gyroscopic moment: frame rows (ffrf docstring)
        f += Jt.T @ (m * g)
    return M, h, f


def random_nodal(rng, N=5, n=3):
    """User-style nodal data with node inertias and rotational shape functions."""
    A = rng.normal(size=(N, 3, 3))
    inertia = np.einsum("pij,pkj->pik", A, A) * 0.01
    K = rng.normal(size=(n, n))
    return NodalData(rng.normal(size=(N, 3)), rng.uniform(0.5, 2, N), rng.normal(size=(N, 3, n)) * 0.3,
                     K @ K.T + n * np.eye(n), Psi=rng.normal(size=(N, 3, n)), inertia=inertia)


BODIES = {
    "nodal": lambda: random_nodal(np.random.default_rng(0)),
    "beam_free": lambda: beam(1.3, [2.0, 3.0], 0.8, elements=6, modes=6, EA=50.0, GJ=4.0, rhoIp=0.05,
                              clamped="none"),
    "beam_clamped": lambda: beam(0.9, 1.0, 1.2, elements=5, modes=5, GJ=1.0, rhoIp=0.02),
}


@pytest.mark.parametrize("name", sorted(BODIES))
def test_invariants_equal_node_loop(name):
    body = BODIES[name]()
    inv = invariants(body, dynamic_stiffening=False)
    rng = np.random.default_rng(7)
    for _ in range(3):
        q, qd, w, g = rng.normal(size=body.n) * 0.3, rng.normal(size=body.n), rng.normal(size=3), rng.normal(size=3)
        Ms, hs, fs = slow(body, q, qd, w, g)
        M = mass_matrix(inv, q)
        np.testing.assert_allclose(M, M.T, atol=1e-14)
        assert np.linalg.eigvalsh(M).min() > 0
        np.testing.assert_allclose(M, Ms, atol=1e-12 * np.abs(Ms).max())
        np.testing.assert_allclose(quadratic_forces(inv, q, qd, w), hs, atol=1e-12 * np.abs(hs).max())
        np.testing.assert_allclose(gravity_forces(inv, q, g), fs, atol=1e-12 * np.abs(fs).max())
        # ½ zᵀMz is the kinetic energy Σ ½ m |v_g|² + ½ ω_gᵀ J ω_g
        z = rng.normal(size=6 + body.n)
        p = body.points()
        T = 0.0
        for m, R, J, Phi, Psi in zip(p.m, p.R, p.J, p.Phi, p.Psi):
            vg = z[:3] + np.cross(z[3:6], R + Phi @ q) + Phi @ z[6:]
            wg = z[3:6] + Psi @ z[6:]
            T += 0.5 * m * vg @ vg + 0.5 * wg @ J @ wg
        np.testing.assert_allclose(kinetic_energy(inv, q, z), T, rtol=1e-12)


def test_elastic_forces():
    body = beam(1.0, 1.0, 1.0, elements=4, modes=3, damping_ratio=0.02)
    inv = invariants(body)
    q, qd = np.array([0.1, -0.2, 0.3]), np.array([1.0, 2.0, -1.0])
    f = elastic_forces(inv, q, qd)
    assert np.all(f[:6] == 0)
    np.testing.assert_allclose(f[6:], -body.stiffness @ q - body.damping @ qd)
    # modal damping: D = 2ζω m per (diagonal) mode
    m = np.diag(inv.M_ee)
    np.testing.assert_allclose(np.diag(body.damping), 2 * 0.02 * body.frequencies * m, rtol=1e-10)


def quat_matrix(p):
    p0, p1, p2, p3 = p / np.linalg.norm(p)
    return np.array([[1 - 2 * (p2**2 + p3**2), 2 * (p1 * p2 - p0 * p3), 2 * (p1 * p3 + p0 * p2)],
                     [2 * (p1 * p2 + p0 * p3), 1 - 2 * (p1**2 + p3**2), 2 * (p2 * p3 - p0 * p1)],
                     [2 * (p1 * p3 - p0 * p2), 2 * (p2 * p3 + p0 * p1), 1 - 2 * (p1**2 + p2**2)]])


def free_flight(inv, g_I):
    """ODE of the free elastic body: x = [r_IR (I), quaternion, q, v (R), ω (R), q̇]."""
    n = inv.n

    def rhs(t, x):
        p, q = x[3:7], x[7:7 + n]
        v, w, qd = x[7 + n:10 + n], x[10 + n:13 + n], x[13 + n:]
        S = quat_matrix(p)
        f = gravity_forces(inv, q, S.T @ g_I) + elastic_forces(inv, q, qd) - quadratic_forces(inv, q, qd, w)
        acc = np.linalg.solve(mass_matrix(inv, q), f)
        pdot = 0.5 * np.array([-p[1:] @ w, *(p[0] * w + np.cross(p[1:], w))])
        return np.concatenate([S @ v, pdot, qd, acc[:3] - np.cross(w, v), acc[3:6], acc[6:]])

    def energy(x):
        q, z = x[7:7 + n], x[7 + n:]
        S = quat_matrix(x[3:7])
        V = 0.5 * q @ inv.K @ q - g_I @ (inv.m * x[:3] + S @ first_moment(inv, q))
        return kinetic_energy(inv, q, z) + V

    return rhs, energy


@pytest.mark.parametrize("name", ["nodal", "beam_free", "beam_clamped"])
def test_energy_conserved_in_free_flight(name):
    body = BODIES[name]()
    inv = invariants(body, dynamic_stiffening=False)
    n = inv.n
    rng = np.random.default_rng(3)
    x0 = np.concatenate([[0.1, 0.2, 0.3], [1, 0, 0, 0], 0.05 * rng.normal(size=n),
                         rng.normal(size=3), 2 * rng.normal(size=3), rng.normal(size=n)])
    rhs, energy = free_flight(inv, np.array([0.0, 0.0, -9.81]))
    sol = solve_ivp(rhs, (0, 0.5), x0, method="DOP853", rtol=1e-11, atol=1e-11)
    assert sol.success
    e = np.array([energy(x) for x in sol.y.T])
    scale = kinetic_energy(inv, x0[7:7 + n], x0[7 + n:]) + 0.5 * x0[7:7 + n] @ inv.K @ x0[7:7 + n]
    assert np.abs(e - e[0]).max() < 1e-8 * scale
    assert np.abs(sol.y[7:7 + n]).max() > 1e-3    # it did deform


@pytest.mark.parametrize("name", ["beam_free", "beam_clamped"])
def test_free_flight_with_dynamic_stiffening(name):
    """Stiffening on: M stays positive definite and the energy error is second order in q (ffrf docstring)."""
    body = BODIES[name]()
    inv = invariants(body)
    assert inv.K_a is not None
    # a hub of inertia 0.1 E fixed to R: a clamped-frame beam alone has a nearly singular frame
    # rotation (its modes almost span the rigid rotation), where the O(ω²q²) energy error of the
    # stiffening terms is amplified without bound (see the ffrf docstring)
    inv.J_sum = inv.J_sum + 0.1 * np.eye(3)
    n = inv.n
    rng = np.random.default_rng(5)
    x0 = np.concatenate([[0, 0, 0], [0.9, 0.1, -0.3, 0.2], 0.01 * rng.normal(size=n),
                         rng.normal(size=3), [1.0, 3.0, -2.0], 0.1 * rng.normal(size=n)])
    x0[3:7] /= np.linalg.norm(x0[3:7])
    rhs, energy = free_flight(inv, np.array([0.1, -0.2, -0.5]))
    sol = solve_ivp(rhs, (0, 0.5), x0, method="DOP853", rtol=1e-10, atol=1e-10)
    assert sol.success
    q = sol.y[7:7 + n]
    assert min(np.linalg.eigvalsh(mass_matrix(inv, qk)).min() for qk in q.T) > 0
    e = np.array([energy(x) for x in sol.y.T])
    drift = np.abs(e - e[0]).max()
    q2 = np.abs(q).max() ** 2
    assert drift < 13 * q2 * np.abs(inv.K_omega).max()    # ≲ (ω_y² + ω_z²) qᵀK_ω q


def test_frame_acceleration_equals_reversed_gravity():
    """Equivalence principle, incl. the a_x and g_x stiffening: M[:, :3] a − f_g(g) = −f_g(g − a)."""
    body = BODIES["beam_clamped"]()
    inv = invariants(body)
    rng = np.random.default_rng(4)
    q, a, g = 0.1 * rng.normal(size=body.n), rng.normal(size=3), rng.normal(size=3)
    lhs = mass_matrix(inv, q)[:, :3] @ a - gravity_forces(inv, q, g)
    np.testing.assert_allclose(lhs, -gravity_forces(inv, q, g - a), atol=1e-12)
    Kg = K_geo(inv, np.zeros(3), a, g)
    np.testing.assert_allclose(lhs[6:], -inv.C_t.T @ (g - a) + Kg @ q, atol=1e-12)


def test_node_kinematics_match_differentiated_motion():
    """a_P = J z_III + bias and α_P likewise, against finite differences of r_IP(t), S_IP(t)."""
    body = random_nodal(np.random.default_rng(1))
    n, P = body.n, 2
    c = np.random.default_rng(2).normal(size=(5, 3 + 3 + n))

    def motion(t):   # r_IR(t), rotation vector of S_IR(t), q(t): smooth polynomials
        return c[0] + c[1] * t + c[2] * t**2 + c[3] * t**3 + c[4] * t**4

    def rot(phi):
        a = np.linalg.norm(phi)
        K = skew(phi / a)
        return E3 + np.sin(a) * K + (1 - np.cos(a)) * K @ K

    def state(t):
        m = motion(t)
        S = rot(m[3:6])
        r_P = m[:3] + S @ (body.R_RP[P] + body.Phi[P] @ m[6:])
        S_P = S @ (E3 + skew(body.Psi[P] @ m[6:]))
        return m, S, r_P, S_P

    t, dt = 0.3, 1e-4
    m, S, r_P, S_P = state(t)
    st = [state(t + k * dt) for k in (-2, -1, 1, 2)]
    d1 = lambda i: (st[0][i] - 8 * st[1][i] + 8 * st[2][i] - st[3][i]) / (12 * dt)
    d2 = lambda i: (-st[0][i] + 16 * st[1][i] - 30 * state(t)[i] + 16 * st[2][i] - st[3][i]) / (12 * dt**2)
    Sd, Sdd = d1(1), d2(1)
    w = S.T @ Sd                               # ω̃ in R components
    omega = np.array([w[2, 1], w[0, 2], w[1, 0]])
    alpha_t = S.T @ Sdd - w @ w                # α̃ = Sᵀ S̈ − ω̃ω̃
    alpha = np.array([alpha_t[2, 1], alpha_t[0, 2], alpha_t[1, 0]])
    q, qd, qdd = m[6:], d1(0)[6:], d2(0)[6:]
    a = S.T @ d2(0)[:3]
    v = S.T @ d1(0)[:3]
    z2, z3 = np.concatenate([v, omega, qd]), np.concatenate([a, alpha, qdd])

    r, J, bias = node_translation(body, P, q, qd, omega)
    np.testing.assert_allclose(r, body.R_RP[P] + body.Phi[P] @ q)
    np.testing.assert_allclose(J @ z2, S.T @ d1(2), rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(J @ z3 + bias, S.T @ d2(2), rtol=1e-5, atol=1e-5)

    S_RP, Jr, bias_r = node_rotation(body, P, q, qd, omega)
    np.testing.assert_allclose(S @ S_RP, S_P)
    # ω_P = ω + Ψ_P q̇ (R components) is Ṡ_IP to first order in the elastic rotation θ = Ψ_P q
    Wp = S.T @ d1(3) @ np.linalg.inv(S_RP)
    wP = np.array([Wp[2, 1] - Wp[1, 2], Wp[0, 2] - Wp[2, 0], Wp[1, 0] - Wp[0, 1]]) / 2
    theta, thetad = body.Psi[P] @ q, body.Psi[P] @ qd
    np.testing.assert_allclose(Jr @ z2, wP, atol=2 * np.linalg.norm(theta) * np.linalg.norm(thetad) + 1e-6)
    # α_P = d/dt ω_P (absolute) = [0, E, Ψ_P] z_III + ω̃ Ψ_P q̇, exactly for that ω_P
    def w_world(tt):
        mm = motion(tt)
        return rot(mm[3:6]) @ (omega_at(tt) + body.Psi[P] @ qdot_at(tt))

    def omega_at(tt):
        Sd = (rot(motion(tt + dt)[3:6]) - rot(motion(tt - dt)[3:6])) / (2 * dt)
        W = rot(motion(tt)[3:6]).T @ Sd
        return np.array([W[2, 1], W[0, 2], W[1, 0]])

    def qdot_at(tt):
        return (motion(tt + dt)[6:] - motion(tt - dt)[6:]) / (2 * dt)

    h = 1e-3
    aP = S.T @ (w_world(t + h) - w_world(t - h)) / (2 * h)
    np.testing.assert_allclose(Jr @ z3 + bias_r, aP, rtol=1e-4, atol=1e-4)
