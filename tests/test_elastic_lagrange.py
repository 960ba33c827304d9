"""Elastic bodies in the tree against Lagrange's equations of the mass points (independent reference).

The reference knows only the mass points of the beam (m_g, R_g, J_g, Φ_g, Ψ_g: the same discretisation
the invariants integrate) and the rigid bodies, and writes the position-level kinematics by hand:
    T(y, ẏ) = Σ ½ m_g v_g·v_g + ½ ω_gᵀ J_g ω_g,   V = −Σ m_g g·r_g + ½ qᵀKq,
with v_g = ∂r_g/∂y ẏ.  Then M = ∂²T/∂ẏ² and  k − q = (∂p/∂y) ẏ − ∂T/∂y + ∂V/∂y  (p = ∂T/∂ẏ).
First derivatives by complex step (exact to rounding), (∂p/∂y) ẏ by a 4th-order central difference.
Compared with the evaluator's M, k, q (M ÿ + k = q) at random states, no stiffening (the reference is
the plain linear FFRF model: u_g = R_g + Φ_g q, J_g constant in R, ω_g = ω + Ψ_g q̇).
Scope: only what projects onto θ (hub axis e_y) and q; e.g. the (C_t q) × g frame torque is seen
(replacing it by S0 × g, Exudyn's LoadMassProportional, fails by 3.5 %), frame-torque terms about x
or z are constraint reactions here.  The full 6+n frame rows are checked by test_elastic_ffrf (node
loop, energy) and test_exudyn_flexible.test_exudyn_one_state_accelerations (rotated 3-D state).
"""

import numpy as np
import pytest

import mbsfmu

PENDULUM = """
mbsfmu: 1
name: lagrange_pendulum
gravity: [0, 0, -9.81]
bodies:
  beam:
    parent: world
    joint: {type: revolute, axis: [0, 1, 0], coordinates: [theta]}
    elastic:
      beam: {length: 1.0, EI: [43.75, 700.0], rhoA: 0.785, elements: 6, modes: 3, GJ: 20.0, rhoIp: 0.01, clamped: start}
      dynamic_stiffening: false
  tip:
    parent: beam
    joint: {type: fixed, node: -1}
    mass: 0.2
"""


def rot(axis, a):
    """Rodrigues, complex-safe."""
    x, y, z = axis
    c, s = np.cos(a), np.sin(a)
    C = 1.0 - c
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


class Reference:
    """Pendulum: y = [θ, q]; beam frame S = rot(e_y, θ) at the origin; tip point mass at the last node."""

    def __init__(self, nodal, m_tip, g):
        p = nodal.points()
        self.m, self.R, self.J, self.Phi, self.Psi = (np.asarray(x, float) for x in (p.m, p.R, p.J, p.Phi, p.Psi))
        self.m_tip, self.R_tip, self.Phi_tip = m_tip, nodal.R_RP[-1], nodal.Phi[-1]
        self.K, self.g = np.asarray(nodal.stiffness, float), np.asarray(g, float)
        self.axis = np.array([0.0, 1.0, 0.0])

    def positions(self, y):
        S, q = rot(self.axis, y[0]), y[1:]
        r = (self.R + self.Phi @ q) @ S.T
        r_tip = S @ (self.R_tip + self.Phi_tip @ q)
        return r, r_tip

    def T(self, y, yd):
        """T(y, ẏ), complex-safe in y and ẏ: v_g = (∂r_g/∂θ) θ̇ + S Φ_g q̇ (∂S/∂θ = S ẽ_y by hand)."""
        S, q = rot(self.axis, y[0]), y[1:]
        dS = rot(self.axis, y[0]) @ _skew(self.axis)                    # dS/dθ = S ẽ_y
        u = self.R + self.Phi @ q
        v = (u @ dS.T) * yd[0] + (self.Phi @ yd[1:]) @ S.T
        u_t = self.R_tip + self.Phi_tip @ q
        v_tip = dS @ u_t * yd[0] + S @ (self.Phi_tip @ yd[1:])
        Om = self.axis * yd[0] + self.Psi @ yd[1:]
        return (0.5 * np.einsum("g,gi,gi->", self.m, v, v) + 0.5 * self.m_tip * v_tip @ v_tip
                + 0.5 * np.einsum("gi,gij,gj->", Om, self.J, Om))

    def V(self, y):
        r, r_tip = self.positions(y)
        q = y[1:]
        return -(self.m @ r) @ self.g - self.m_tip * (self.g @ r_tip) + 0.5 * q @ self.K @ q

    def equations(self, y, yd):
        """M and k − q of Lagrange's equations at (y, ẏ)."""
        f = len(y)
        E = np.eye(f)
        h = 1e-30
        p = lambda y_, yd_: np.array([self.T(y_.astype(complex), yd_ + 1j * h * E[i]).imag / h for i in range(f)])
        M = np.column_stack([p(y, E[j]) for j in range(f)])
        d = 1e-4   # (∂p/∂y) ẏ = d/ds p(y + s ẏ, ẏ): 4th-order central difference
        dp = (8 * (p(y + d * yd, yd) - p(y - d * yd, yd)) - (p(y + 2 * d * yd, yd) - p(y - 2 * d * yd, yd))) / (12 * d)
        dT = np.array([self.T(y + 1j * h * E[i], yd.astype(complex)).imag / h for i in range(f)])
        dV = np.array([self.V(y + 1j * h * E[i]).imag / h for i in range(f)])
        return M, dp - dT + dV


def _skew(x):
    return np.array([[0.0, -x[2], x[1]], [x[2], 0.0, -x[0]], [-x[1], x[0], 0.0]])


@pytest.fixture(scope="module")
def pendulum():
    ev = mbsfmu.compile(mbsfmu.loads(PENDULUM))
    nodal = next(b for b in ev.model.bodies if b.elastic).nodal
    return ev, Reference(nodal, 0.2, ev.model.g)


def test_reference_kinematics_match_the_tree(pendulum):
    """The hand-written positions are the evaluator's (so the comparison below is about dynamics)."""
    ev, ref = pendulum
    rng = np.random.default_rng(3)
    y = rng.normal(size=ev.model.npos) * np.r_[1.0, 0.05 * np.ones(ev.model.npos - 1)]
    d = ev.kinematics(y, np.zeros(ev.model.nvel))
    np.testing.assert_allclose(d.S[0], rot(ref.axis, y[0]), atol=1e-14)
    _, r_tip = ref.positions(y)
    np.testing.assert_allclose(d.o[1], r_tip, atol=1e-14)


def test_pendulum_equations_equal_lagrange(pendulum):
    ev, ref = pendulum
    rng = np.random.default_rng(11)
    for _ in range(4):
        f = ev.model.npos
        y = np.r_[rng.uniform(-np.pi, np.pi), rng.normal(size=f - 1) * 0.05]
        yd = np.r_[rng.normal() * 3.0, rng.normal(size=f - 1) * 0.5]
        M, k, q = ev.equations(y, yd)
        M_ref, b_ref = ref.equations(y, yd)
        np.testing.assert_allclose(M, M_ref, rtol=0, atol=1e-12 * np.abs(M_ref).max())
        np.testing.assert_allclose(k - q, b_ref, rtol=0, atol=1e-9 * np.abs(b_ref).max())
