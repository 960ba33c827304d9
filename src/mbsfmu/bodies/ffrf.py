"""Floating frame of reference body (seed 004) with precomputed mass invariants.

Conventions (all vectors and matrices in components of the body reference frame R):
    z_II  = [v; ω; q̇]     v = v_IR, ω = ω_IR (absolute, R components), q̇ elastic velocities
    z_III = [a; α; q̈]     a = a_IR, α = α_IR (absolute accelerations, R components), so
                          a = d/dt(v) + ω̃ v  (d/dt of the R components), α = d/dt(ω)
Equations of the free body, applied forces on the right:

    mass_matrix(q) · z_III + quadratic_forces(q, q̇, ω) = gravity_forces(q, g) + elastic_forces(q, q̇) + Σ J_Pᵀ f_P

with J_P = [E, −r̃_RP, Φ_P] for a force f_P at node P and [0, E, Ψ_P] for a torque.  They are the
projected Newton–Euler equations Σ_g J_gᵀ m_g (a_g − f_g) + Γ_gᵀ (J_g α̃_g-part) over the mass
points g (nodes, or the beam's Gauss points), with a_g = J_g z_III + ω̃ω̃ u_g + 2 ω̃ Φ_g q̇,
u_g = R_g + Φ_g q.  Rotational mass-point inertias J_g are taken constant in R (their elastic
rotation changes them at second order only), with ω_g = ω + Ψ_g q̇.  For that model Lagrange's
equations give the rotary part Γ_gᵀ J_g (Γ_g z_III) + [0; ω̃ J_g ω_g; 0] (Γ_g = [E, Ψ_g]): the
gyroscopic moment acts on the frame rows only.  This keeps ½ z_IIᵀ M z_II + ½ qᵀKq exactly
conserved for a free undamped body; projecting ω̃_g J_g ω_g (or ω̃ J_g ω_g) with Ψ_gᵀ onto the
q rows, as a rigid node would, is inconsistent with a J_g that does not turn with the node.

Invariants (computed once; nothing loops over nodes at run time):
    m, S0 = Σ m R, C_t = Σ m Φ, A_ijk = Σ m R_i Φ_jk, B_ijkl = Σ m Φ_ik Φ_jl, S_RR = Σ m R Rᵀ,
    C_r0 = Σ m R̃ Φ + Σ J Ψ, G_ikl = Σ m ((Φ e_k)~ Φ)_il, M_ee = Σ m ΦᵀΦ + ΨᵀJΨ, J_sum = Σ J,
    JΨ = Σ J Ψ.

Dynamic stiffening (beam generator; see beam.py; Kane–Ryan–Banerjee): the axis foreshortens by
½ qᵀG(x)q under transverse deflection (G = ∫₀ˣ Φ'ᵀΦ' dξ), shifting the first moment by
δ(m·c) = −½ qᵀK_a q e_x (K_a = ∫ρA G dx, K_ω = ∫ρA x G dx: the unit-load geometric stiffnesses).
On the q rows this gives the geometric stiffness −K_geo q, K_geo = (g_x − a_x) K_a + (ω_y² + ω_z²) K_ω:
- first_moment (used by mass_matrix, quadratic_forces, gravity_forces) includes δ(m·c), so the
  frame rows carry the reactions of the a_x and g_x parts;
- mass_matrix: the a_x part as the symmetric v_x–q coupling −K_a q (axial momentum of the
  foreshortening), its velocity terms in the v rows of quadratic_forces;
- gravity_forces: −g_x K_a q (gradient of the potential ½ g_x qᵀK_a q);
- quadratic_forces: (ω_y² + ω_z²) K_ω q on the q rows only.  Its energy-consistent companion,
  δI = −(qᵀK_ω q) diag(0, 1, 1) in the ω–ω block, is left out on purpose: without the other
  second-order foreshortening terms of M it can make M indefinite for a clamped body whose
  frame rotates freely (I_yy − C_r M_ee⁻¹ C_rᵀ is small there).  So with stiffening on, a free
  body's energy is conserved only up to O(ω² q²) terms; prescribed-rotation results (Wright
  et al.) are unaffected, and without stiffening the equations are exactly conservative.
  Caveat: a `clamped: start` beam floating free with no other inertia on its frame has an almost
  singular frame rotation and these small errors then grow without bound; give its frame a hub
  (any rigid inertia), use `clamped: none`, or switch stiffening off.
"""

import numpy as np

from .nodal import skew

EPS = np.zeros((3, 3, 3))
EPS[0, 1, 2] = EPS[1, 2, 0] = EPS[2, 0, 1] = 1.0
EPS[0, 2, 1] = EPS[2, 1, 0] = EPS[1, 0, 2] = -1.0
E3 = np.eye(3)
P_AXIAL = np.diag([0.0, 1.0, 1.0])   # ω_y² + ω_z² = ωᵀ P ω: rotation rates that load the x axis


class Invariants:
    """Precomputed mass invariants of one elastic body (see the module docstring for the symbols)."""


def invariants(nodal, dynamic_stiffening=True):
    """The standard FFRF mass invariants from the mass moments of `nodal` (once per body)."""
    mo = nodal.points().moments()
    inv = Invariants()
    inv.n = np.shape(mo.C_t)[1]
    inv.m = float(mo.m)
    inv.S0, inv.S_RR, inv.C_t, inv.A, inv.B, inv.J_sum, inv.JPsi = (
        np.asarray(x, float) for x in (mo.S0, mo.S_RR, mo.C_t, mo.A, mo.B, mo.J_sum, mo.JPsi))
    inv.C_r0 = np.einsum("ijl,jlk->ik", EPS, inv.A) + inv.JPsi          # Σ m R̃Φ + Σ JΨ
    inv.G = np.einsum("ijm,jmkl->ikl", EPS, inv.B)                       # Σ m (Φe_k)~ Φ
    inv.M_ee = mo.M_ee
    inv.K = np.asarray(nodal.stiffness, float)
    inv.D = np.asarray(nodal.damping, float)
    st = nodal.stiffening if dynamic_stiffening else None
    inv.K_a = None if st is None else np.asarray(st["K_a"], float)
    inv.K_omega = None if st is None else np.asarray(st["K_omega"], float)
    return inv


def first_moment(inv, q):
    """m·c(q) = Σ m u = S0 + C_t q, minus the axial foreshortening ½ qᵀK_a q e_x with stiffening."""
    mc = inv.S0 + inv.C_t @ q
    if inv.K_a is not None:
        mc[0] -= 0.5 * (q @ inv.K_a @ q)
    return mc


def inertia(inv, q):
    """I(q) = Σ m ũᵀũ + Σ J = tr(S)E − S + J_sum with S = Σ m u uᵀ (q-free, q-linear, q-quadratic parts)."""
    Aq = inv.A @ q
    S = inv.S_RR + Aq + Aq.T + np.einsum("ijkl,k,l->ij", inv.B, q, q)
    return np.trace(S) * E3 - S + inv.J_sum


def C_r(inv, q):
    """C_r(q) = Σ m ũ Φ + Σ J Ψ (ω–q coupling)."""
    return inv.C_r0 + np.einsum("ikl,k->il", inv.G, q)


def mass_matrix(inv, q):
    """M_zz(q), (6+n)×(6+n), for z_III = [a; α; q̈] in R components."""
    n = inv.n
    q = np.asarray(q, float)
    mc = skew(first_moment(inv, q))
    Cr = C_r(inv, q)
    M = np.empty((6 + n, 6 + n))
    M[:3, :3] = inv.m * E3
    M[:3, 3:6] = -mc
    M[3:6, :3] = mc
    M[:3, 6:] = inv.C_t
    M[6:, :3] = inv.C_t.T
    M[3:6, 3:6] = inertia(inv, q)
    M[3:6, 6:] = Cr
    M[6:, 3:6] = Cr.T
    M[6:, 6:] = inv.M_ee
    if inv.K_a is not None:
        Kaq = inv.K_a @ q
        M[0, 6:] -= Kaq            # axial momentum of the foreshortened axis (a_x stiffening)
        M[6:, 0] -= Kaq
    return M


def quadratic_forces(inv, q, qd, omega):
    """h(q, q̇, ω): centrifugal, Coriolis and gyroscopic terms of M·z_III (left-hand side)."""
    q, qd, w = (np.asarray(x, float) for x in (q, qd, omega))
    wt = skew(w)
    w2 = wt @ wt
    Ctqd = inv.C_t @ qd
    W = inv.A @ qd + np.einsum("ijkl,k,l->ij", inv.B, q, qd)          # Σ m u (Φq̇)ᵀ
    I_m = inertia(inv, q) - inv.J_sum
    h = np.empty(6 + inv.n)
    h[:3] = w2 @ first_moment(inv, q) + 2.0 * wt @ Ctqd
    h[3:6] = wt @ (I_m @ w) + 2.0 * (w * np.trace(W) - W.T @ w)
    h[6:] = (np.einsum("ij,jik->k", w2, inv.A) + np.einsum("ij,ijkl,l->k", w2, inv.B, q)
             + 2.0 * np.einsum("ij,ijkl,l->k", wt, inv.B, qd))
    h[3:6] += wt @ (inv.J_sum @ w + inv.JPsi @ qd)       # ω̃ Σ J ω_g: frame rows only (see above)
    if inv.K_a is not None:
        h[:3] -= 2.0 * (q @ inv.K_a @ qd) * (wt @ E3[0])   # 2ω̃ and d²/dt² of the foreshortening
        h[0] -= qd @ inv.K_a @ qd
        h[6:] += (w @ P_AXIAL @ w) * (inv.K_omega @ q)       # centrifugal stiffening
    return h


def gravity_forces(inv, q, g_R):
    """f_g = Σ J_gᵀ m_g g_R (g_R gravity in R components), incl. the gravity part of stiffening."""
    q, g = np.asarray(q, float), np.asarray(g_R, float)
    f = np.empty(6 + inv.n)
    f[:3] = inv.m * g
    f[3:6] = np.cross(first_moment(inv, q), g)
    f[6:] = inv.C_t.T @ g
    if inv.K_a is not None:   # q-gradient of the potential ½ g_x qᵀK_a q; its frame torque is in m·c × g
        f[6:] -= g[0] * (inv.K_a @ q)
    return f


def elastic_forces(inv, q, qd):
    """f_e = [0; 0; −K q − D q̇]."""
    f = np.zeros(6 + inv.n)
    f[6:] = -inv.K @ np.asarray(q, float) - inv.D @ np.asarray(qd, float)
    return f


def K_geo(inv, omega, a_R, g_R):
    """Geometric stiffness (g_x − a_x) K_a + (ω_y² + ω_z²) K_ω (zero without stiffening); force −K_geo q."""
    if inv.K_a is None:
        return np.zeros((inv.n, inv.n))
    w = np.asarray(omega, float)
    return (g_R[0] - a_R[0]) * inv.K_a + (w @ P_AXIAL @ w) * inv.K_omega


def kinetic_energy(inv, q, z_II):
    """T = ½ z_IIᵀ M_zz(q) z_II."""
    return 0.5 * z_II @ mass_matrix(inv, q) @ z_II


def node_translation(nodal, P, q, qd, omega):
    """Seed 004 at node P: r_RP = R_RP + Φ_P q, J = [E, −r̃_RP, Φ_P], bias ω̃ω̃ r_RP + 2 ω̃ Φ_P q̇."""
    Phi = nodal.Phi[P]
    r = nodal.R_RP[P] + Phi @ q
    J = np.hstack([E3, -skew(r), Phi])
    wt = skew(omega)
    return r, J, wt @ (wt @ r) + 2.0 * wt @ (Phi @ qd)


def node_rotation(nodal, P, q, qd, omega):
    """Seed 004 at node P: S_RP = E + (Ψ_P q)~, J = [0, E, Ψ_P], bias ω̃ Ψ_P q̇."""
    Psi = nodal.Psi[P]
    S = E3 + skew(Psi @ q)
    J = np.hstack([np.zeros((3, 3)), E3, Psi])
    return S, J, np.cross(omega, Psi @ qd)
