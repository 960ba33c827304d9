"""Beam generator: cantilever and free–free frequencies, static deflections, rotating beam (Wright et al. 1982)."""

import numpy as np
import pytest
from scipy.linalg import eigh

from mbsfmu.bodies import beam, elastic_forces, invariants, mass_matrix, quadratic_forces
from mbsfmu.bodies.beam import beam_from_spec, fe_model, retained_dofs

CANTILEVER = [3.5160, 22.0345, 61.6972]      # (β_n L)², clamped–free
FREE_FREE = [22.3733, 61.6728, 120.9034]     # (β_n L)², free–free

# Wright, Smith, Thompson, Worley, J. Appl. Mech. 49 (1982): flapwise rotating cantilever, no hub,
# dimensionless ω√(ρA L⁴/EI) for γ = Ω√(ρA L⁴/EI).  γ = 10, mode 2 is 33.6404 (our full FE gives
# 33.64037); the 32.0214 sometimes quoted does not satisfy the linearised equations.
WRIGHT = {0: (3.5160, 22.0345), 1: (3.6816, 22.1810), 2: (4.1373, 22.6149), 3: (4.7973, 23.3203),
          4: (5.5850, 24.2734), 5: (6.4495, 25.4461), 10: (11.2023, 33.6404)}


def dimensionless(omega, L, EI, rhoA):
    return omega * np.sqrt(rhoA * L**4 / EI)


def test_cantilever_frequencies_both_planes():
    L, EIy, EIz, rhoA = 2.0, 3.0, 5.0, 0.7
    b = beam(L, [EIy, EIz], rhoA, elements=16, modes=6)
    flap = [k for k in range(6) if np.abs(b.Phi[:, 2, k]).max() > 0.5]   # w (about y)
    chord = [k for k in range(6) if np.abs(b.Phi[:, 1, k]).max() > 0.5]  # v (about z)
    np.testing.assert_allclose(dimensionless(b.frequencies[flap], L, EIy, rhoA), CANTILEVER, rtol=5e-4)
    np.testing.assert_allclose(dimensionless(b.frequencies[chord], L, EIz, rhoA), CANTILEVER, rtol=5e-4)
    # the modal K and the invariants' M_ee give the same frequencies
    inv = invariants(b)
    lam = eigh(b.stiffness, inv.M_ee, eigvals_only=True)
    np.testing.assert_allclose(np.sqrt(lam), np.sort(b.frequencies), rtol=1e-8)


def test_free_free_frequencies_and_mean_axes():
    L, EI, rhoA = 1.5, 2.0, 0.4
    b = beam(L, EI, rhoA, elements=16, modes=6, EA=100.0, GJ=1.0, clamped="none")
    bending = [k for k in range(6) if np.abs(b.Phi[:, 1:, k]).max() > 0.5]
    fb = np.sort(dimensionless(b.frequencies[bending], L, EI, rhoA))
    np.testing.assert_allclose(fb, np.repeat(FREE_FREE[:len(fb) // 2], 2), rtol=5e-4)
    inv = invariants(b)
    scale = inv.m * L
    assert np.abs(inv.C_t).max() < 1e-10 * scale           # ∫Φ dm = 0
    assert np.abs(inv.C_r0).max() < 1e-10 * scale * L      # ∫(R̃Φ + JΨ) dm = 0
    np.testing.assert_allclose(inv.m, rhoA * L)
    np.testing.assert_allclose(inv.S0, [rhoA * L**2 / 2, 0, 0])


def test_static_tip_deflection_bending_axial_torsion():
    L, EI, EA, GJ, rhoA, P = 1.2, 4.0, 300.0, 2.0, 1.0, 0.5
    b = beam(L, EI, rhoA, elements=10, modes=60, EA=EA, GJ=GJ)   # all modes: exact FE statics
    K = b.stiffness
    tip_t, tip_r = b.Phi[-1], b.Psi[-1]
    for axis, expected in ((2, P * L**3 / (3 * EI)), (1, P * L**3 / (3 * EI)), (0, P * L / EA)):
        f = np.zeros(3)
        f[axis] = P
        q = np.linalg.solve(K, tip_t.T @ f)
        np.testing.assert_allclose((tip_t @ q)[axis], expected, rtol=1e-8)
    q = np.linalg.solve(K, tip_r.T @ np.array([P, 0, 0]))
    np.testing.assert_allclose((tip_r @ q)[0], P * L / GJ, rtol=1e-8)
    # few modes already give the tip deflection within 0.5 %: modal truncation of a static load
    b4 = beam(L, EI, rhoA, elements=10, modes=4)
    q = np.linalg.solve(b4.stiffness, b4.Phi[-1].T @ np.array([0, 0, P]))
    np.testing.assert_allclose((b4.Phi[-1] @ q)[2], P * L**3 / (3 * EI), rtol=5e-3)


@pytest.mark.parametrize("gamma", sorted(WRIGHT))
def test_published_wright_values_from_full_fe(gamma):
    """The published table satisfies K + γ² K_ω (full FE, 60 elements, flapwise)."""
    M, K, _, KGw, _ = fe_model(1.0, 1.0, 1.0, 1.0, 60, rhoIp=1e-6)
    free = retained_dofs(61, None, None, "start")
    flap = [i for i in free if i % 6 in (2, 4)]
    ix = np.ix_(flap, flap)
    lam = eigh(K[ix] + gamma**2 * KGw[ix], M[ix], eigvals_only=True, subset_by_index=[0, 1])
    np.testing.assert_allclose(np.sqrt(lam), WRIGHT[gamma], rtol=2e-5)


def linearised_spin(inv, Omega):
    """M_ee, K_t, G of the q rows of the FFRF equations about steady spin ω = Ω e_z (frame fixed at the hub)."""
    n = inv.n
    w = np.array([0.0, 0.0, Omega])
    z = np.zeros(n)

    def rhs(q, qd):   # q rows of h − f_e (a = α = 0)
        return (quadratic_forces(inv, q, qd, w) - elastic_forces(inv, q, qd))[6:]

    E = np.eye(n)
    Kt = np.column_stack([(rhs(E[k], z) - rhs(-E[k], z)) / 2 for k in range(n)])   # exact: linear in q
    G = np.column_stack([(rhs(z, E[k]) - rhs(z, -E[k])) / 2 for k in range(n)])
    return mass_matrix(inv, z)[6:, 6:], Kt, G


@pytest.mark.parametrize("gamma", sorted(WRIGHT))
def test_rotating_beam_flapwise_from_ffrf(gamma):
    L, EI, rhoA = 0.8, 2.5, 1.7
    b = beam(L, [EI, 10 * EI], rhoA, elements=24, modes=16)
    inv = invariants(b)
    Omega = gamma / np.sqrt(rhoA * L**4 / EI)
    M, Kt, G = linearised_spin(inv, Omega)
    flap = [k for k in range(inv.n) if np.abs(b.Phi[:, 2, k]).max() > 0.5]
    assert len(flap) >= 6
    ix = np.ix_(flap, flap)
    assert np.abs(G[ix]).max() < 1e-12          # flapwise modes see no Coriolis coupling
    lam = eigh(Kt[ix], M[ix], eigvals_only=True, subset_by_index=[0, 1])
    np.testing.assert_allclose(dimensionless(np.sqrt(lam), L, EI, rhoA), WRIGHT[gamma], rtol=1e-4)


@pytest.mark.parametrize("gamma", [0.0, 1.0, 2.0, 3.0])
def test_rotating_beam_chordwise_softening(gamma):
    """In-plane (inextensible): ω_c² = ω_f² − Ω², the centrifugal softening from the FFRF h term."""
    L, EI, rhoA = 1.0, 1.0, 1.0
    b = beam(L, [EI, EI], rhoA, elements=24, modes=16)
    M, Kt, _ = linearised_spin(invariants(b), gamma)
    flap = [k for k in range(b.n) if np.abs(b.Phi[:, 2, k]).max() > 0.5]
    chord = [k for k in range(b.n) if np.abs(b.Phi[:, 1, k]).max() > 0.5]
    f = eigh(Kt[np.ix_(flap, flap)], M[np.ix_(flap, flap)], eigvals_only=True)[:2]
    c = eigh(Kt[np.ix_(chord, chord)], M[np.ix_(chord, chord)], eigvals_only=True)[:2]
    np.testing.assert_allclose(c, f - gamma**2, rtol=1e-9, atol=1e-9)


def test_stiffening_switch():
    b = beam(1.0, 1.0, 1.0, elements=8, modes=4, dynamic_stiffening=False)
    assert b.stiffening is None
    b = beam(1.0, 1.0, 1.0, elements=8, modes=4)
    inv_off = invariants(b, dynamic_stiffening=False)
    M, Kt, _ = linearised_spin(inv_off, 3.0)
    flap = [k for k in range(b.n) if np.abs(b.Phi[:, 2, k]).max() > 0.5]
    lam = eigh(Kt[np.ix_(flap, flap)], M[np.ix_(flap, flap)], eigvals_only=True)
    np.testing.assert_allclose(np.sqrt(lam[0]), 3.5160, rtol=1e-3)   # no stiffening: no rise


# ---- `axis`: the beam generated along x, turned onto another body axis ------------------------------------
TURNED = """
mbsfmu: 1
name: turned_beam
gravity: [0, 0, -9.81]
bodies:
  hub:
    parent: world
    joint: {{type: revolute, axis: [0.3, 1, 0.2], initial_velocity: {{hub.angle: 1.5}}, coordinates: [hub.angle]}}
    mass: 1.0
    inertia: {{xx: 0.02, yy: 0.03, zz: 0.04}}
  beam:
    parent: hub
    joint: {{type: fixed, at: [0.05, 0.02, 0]{rotation}}}
    elastic:
      beam: {{length: 0.8, EI: [3.0, 7.0], rhoA: 0.5, elements: 8, modes: 4{axis}}}
      dynamic_stiffening: false
outputs:
  - {{body: beam, node: -1, quantities: [position, velocity], name: tip}}
integrator: {{method: dop853, rtol: 1e-11, atol: 1e-12}}
experiment: {{start: 0, stop: 0.6, step: 0.05}}
"""


def _tip_run(rotation="", axis=""):
    import mbsfmu
    from mbsfmu.simulation import Simulation
    scene = mbsfmu.loads(TURNED.format(rotation=rotation, axis=axis))
    t, Y, YD = mbsfmu.simulate(scene)
    sim = Simulation(scene.spec)
    tips = [list(sim.output_values(np.concatenate([y, yd])).values()) for y, yd in zip(Y, YD)]
    return Y, np.array(tips)


@pytest.mark.parametrize("axis, turn", [([0, 0, 1], "{axis: [0, -1, 0], angle: 1.5707963267948966}"),
                                        ([1, 2, -2], None),   # x × axis, by the angle between them
                                        ([-1, 0, 0], "{axis: [0, 0, 1], angle: 3.141592653589793}")])
def test_beam_axis_is_the_beam_along_x_in_a_frame_turned_onto_it(axis, turn):
    """A beam with `axis: a` moves exactly as the beam along x on a joint frame turned by the shortest rotation
    taking x onto a (the scene's own `rotation:`, an independent path): same hub angle and modal coordinates,
    same tip motion; its frequencies from the invariants are still the cantilever's closed form in both planes."""
    a = np.array(axis, float) / np.linalg.norm(axis)
    if turn is None:
        c = np.cross([1, 0, 0], a)
        turn = f"{{axis: {(c / np.linalg.norm(c)).tolist()}, angle: {float(np.arccos(a[0]))!r}}}"
    Y_x, tip_x = _tip_run(rotation=f", rotation: {turn}")
    Y_a, tip_a = _tip_run(axis=f", axis: {axis}")
    assert np.ptp(Y_x[:, 1:], axis=0).max() > 1e-3           # the beam does bend
    np.testing.assert_allclose(Y_a, Y_x, atol=1e-9)
    np.testing.assert_allclose(tip_a, tip_x, atol=1e-9)
    nodal = beam_from_spec({"length": 0.8, "EI": [3.0, 7.0], "rhoA": 0.5, "elements": 8, "modes": 4, "axis": axis},
                           dynamic_stiffening=False)
    inv = invariants(nodal)
    np.testing.assert_allclose(nodal.R_RP[-1], 0.8 * a, atol=1e-14)   # the nodes lie along the axis
    omega = np.sort(np.sqrt(eigh(nodal.stiffness, inv.M_ee, eigvals_only=True)))
    flap_chord = np.sort(np.outer(np.sqrt([3.0, 7.0]), CANTILEVER[:2]).ravel())[:4] / np.sqrt(0.5 * 0.8**4)
    np.testing.assert_allclose(omega, flap_chord, rtol=2e-3)


@pytest.mark.parametrize("axis, message", [("[0, 0, 0]", "not all zero"), ("[1, 0]", "not all zero"),
                                           ("[1, 0, x]", "three numbers"), ("5", "three numbers")])
def test_beam_axis_refused_in_one_line(axis, message):
    import mbsfmu
    from mbsfmu.errors import ModelError
    with pytest.raises(ModelError, match=message) as e:
        mbsfmu.loads(TURNED.format(rotation="", axis=f", axis: {axis}"))
    assert e.value.key == "bodies.beam.elastic.beam.axis" and e.value.line == 15   # the `beam:` line


def test_beam_axis_other_than_x_refuses_dynamic_stiffening():
    """Dynamic stiffening is written for a beam along x: asked for on another axis, refused; off by default there."""
    import mbsfmu
    from mbsfmu.errors import ModelError
    text = TURNED.format(rotation="", axis=", axis: [0, 0, 1]")
    assert mbsfmu.loads(text.replace("      dynamic_stiffening: false\n", "")).spec["bodies"][1]["elastic"]["dynamic_stiffening"] is False
    with pytest.raises(ModelError, match="along x") as e:
        mbsfmu.loads(text.replace("dynamic_stiffening: false", "dynamic_stiffening: true"))
    assert e.value.key == "bodies.beam.elastic.beam.axis"
