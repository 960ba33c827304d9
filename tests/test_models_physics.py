"""Shipped models and physics against independent references (closed forms, conservation laws, Pinocchio)."""

import glob
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.special import ellipk

import mbsfmu
from mbsfmu.simulation import simulate

ROOT = Path(__file__).resolve().parents[1]
MODELS = sorted(glob.glob(str(ROOT / "models" / "*.yaml")))
G = 9.81


def _model(name):
    return mbsfmu.load(ROOT / "models" / name)


# -- every shipped model ------------------------------------------------------------------------------
def test_the_required_models_ship():
    names = {Path(m).name for m in MODELS}
    for n in ("double_pendulum", "pendulum", "cart_pole", "robot_arm_6dof", "spinning_top", "driven_crank",
              "spring_damper", "free_body"):
        assert f"{n}.yaml" in names


@pytest.mark.parametrize("path", MODELS, ids=lambda p: Path(p).stem)
def test_model_loads_compiles_and_runs(path):
    scene = mbsfmu.load(path)
    assert len(scene.spec["description"]) > 40
    ev = mbsfmu.compile(scene)
    y, yd = ev.initial_state()
    assert len(y) == len(ev.coordinates) and len(yd) == len(ev.velocity_coordinates)
    M, k, q = ev.equations(y, yd, 0.0)
    assert M.shape == (len(yd), len(yd))
    np.testing.assert_allclose(M, M.T, rtol=0, atol=1e-12 * np.abs(M).max())
    assert np.linalg.eigvalsh(M).min() > 0
    assert np.all(np.isfinite(k)) and np.all(np.isfinite(q))
    e = scene.spec["experiment"]
    t, Y, YD = simulate(scene, stop=e["start"] + min(0.1, e["stop"] - e["start"]), step=min(e["step"], 0.01))
    assert np.all(np.isfinite(Y)) and np.all(np.isfinite(YD))
    assert Y.shape[1] == len(ev.coordinates)


# -- simple pendulum: periods ----------------------------------------------------------------------------
def _pendulum(mass, inertia, d, theta0):
    return mbsfmu.loads(f"""
mbsfmu: 1
name: p
gravity: [0, 0, -{G}]
bodies:
  bob:
    parent: world
    joint: {{type: revolute, axis: [0, 1, 0], coordinates: [th], initial: {{th: {theta0!r}}}}}
    mass: {mass}
    center_of_mass: [0, 0, -{d}]
    inertia: {{xx: {inertia}, yy: {inertia}, zz: {inertia}}}
""")


def _period(t, th, thd):
    """Period from the upward zero crossings of th, each located on the cubic Hermite interpolant."""
    cross = []
    for i in np.flatnonzero((th[:-1] < 0) & (th[1:] >= 0)):
        h = t[i + 1] - t[i]
        p0, p1, m0, m1 = th[i], th[i + 1], thd[i] * h, thd[i + 1] * h
        s = -p0 / (p1 - p0)
        for _ in range(30):  # Newton on the Hermite cubic
            h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
            f = h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1
            df = (6 * s**2 - 6 * s) * p0 + (3 * s**2 - 4 * s + 1) * m0 + (-6 * s**2 + 6 * s) * p1 + (3 * s**2 - 2 * s) * m1
            s -= f / df
        cross.append(t[i] + s * h)
    assert len(cross) >= 2
    return (cross[-1] - cross[0]) / (len(cross) - 1)


def test_small_angle_period_of_a_physical_pendulum():
    m, d, Ic = 1.3, 0.6, 0.05
    T_ref = 2 * math.pi * math.sqrt((Ic + m * d * d) / (m * G * d))
    theta0 = 1e-3  # amplitude correction theta0^2/16 ~ 6e-8
    t, Y, YD = simulate(_pendulum(m, Ic, d, theta0), stop=2.2 * T_ref, step=0.01, method="dop853", rtol=1e-12, atol=1e-15)
    T = _period(t, Y[:, 0], YD[:, 0])
    assert abs(T / T_ref - 1) < 1e-6, (T, T_ref)


@pytest.mark.parametrize("theta0", [2.0, 3.0])
def test_large_amplitude_period_of_a_point_mass_pendulum(theta0):
    L = 1.0  # point mass: zero inertia is valid
    T_ref = 4 * math.sqrt(L / G) * ellipk(math.sin(theta0 / 2) ** 2)
    t, Y, YD = simulate(_pendulum(0.7, 0, L, theta0), stop=2.1 * T_ref, step=0.01, method="dop853", rtol=1e-12, atol=1e-14)
    T = _period(t, Y[:, 0], YD[:, 0])
    assert abs(T / T_ref - 1) < 1e-6, (T, T_ref)


def test_shipped_pendulum_period():
    """models/pendulum.yaml (rod + bob, 30°): period vs the exact physical-pendulum formula."""
    scene = _model("pendulum.yaml")
    ev = mbsfmu.compile(scene)
    p = ev.parameters
    m = p["m_rod"] + p["m_bob"]
    d = (p["m_rod"] * p["L"] / 2 + p["m_bob"] * p["L"]) / m
    I_O = p["m_rod"] * p["L"] ** 2 / 3 + p["m_bob"] * (p["L"] ** 2 + 0.4 * p["r_bob"] ** 2)
    theta0 = math.pi / 6
    T_ref = 4 * math.sqrt(I_O / (m * G * d)) * ellipk(math.sin(theta0 / 2) ** 2)
    t, Y, YD = simulate(scene, stop=2.1 * T_ref, step=0.01, method="dop853", rtol=1e-11, atol=1e-13)
    T = _period(t, Y[:, 0], YD[:, 0])
    assert abs(T / T_ref - 1) < 1e-6, (T, T_ref)


# -- conservation laws ----------------------------------------------------------------------------------
def test_double_pendulum_energy_conserved():
    scene = _model("double_pendulum.yaml")
    ev = mbsfmu.compile(scene)
    t, Y, YD = simulate(scene, stop=3.0, step=0.01, method="dop853", rtol=1e-10, atol=1e-12)
    E = np.array([ev.energy(y, yd) for y, yd in zip(Y, YD)])
    scale = ev.parameters["m"] * G * ev.parameters["L"]
    assert np.ptp(YD[:, 1]) > 1.0  # it really moves (chaotic regime)
    assert np.abs(E - E[0]).max() / scale < 1e-8


def _angular_momentum(ev, y, yd, origin=np.zeros(3)):
    """World angular momentum about `origin`: Σ S I Sᵀ ω + m (r − origin) × v, from `jacobians`."""
    J = ev.jacobians(y, yd)
    L = np.zeros(3)
    for b in ev.model.bodies:
        jb = J[b.name]
        S = jb["S"]
        L += S @ b.I @ S.T @ jb["omega"] + b.m * np.cross(jb["r"] - origin, jb["v"])
    return L


def test_free_body_invariants():
    scene = _model("free_body.yaml")
    ev = mbsfmu.compile(scene)
    t, Y, YD = simulate(scene, stop=5.0, step=0.05, method="dop853", rtol=1e-10, atol=1e-12)
    E = np.array([ev.energy(y, yd) for y, yd in zip(Y, YD)])
    L = np.array([_angular_momentum(ev, y, yd) for y, yd in zip(Y, YD)])
    assert np.abs(E - E[0]).max() / E[0] < 1e-8
    assert np.abs(L - L[0]).max() / np.linalg.norm(L[0]) < 1e-8
    qn = np.linalg.norm(Y[:, 3:7], axis=1)
    assert np.abs(qn - 1).max() < 1e-12
    # the body flips: ω_y changes sign (intermediate-axis instability) within 5 s
    assert YD[:, 4].min() < 0 < YD[:, 4].max()
    # the centre of mass drifts uniformly
    np.testing.assert_allclose(Y[:, 0], 0.1 * t, atol=1e-9)


def test_free_body_tumbling_with_general_initial_state():
    """Random asymmetric inertia, random ω and v: E and world L about the origin conserved."""
    scene = mbsfmu.loads("""
mbsfmu: 1
name: tumbler
gravity: [0, 0, 0]
bodies:
  b:
    parent: world
    joint: {type: free, initial: {b.x: 0.3, b.y: -0.2, rotation: {axis: [1, 1, 0], angle: 0.8}},
            initial_velocity: {velocity: [0.5, -0.3, 0.2], omega: [1.5, -2.0, 3.0]}}
    mass: 3.0
    center_of_mass: [0.05, -0.02, 0.1]
    inertia: [[0.30, 0.02, -0.01], [0.02, 0.20, 0.03], [-0.01, 0.03, 0.15]]
""")
    ev = mbsfmu.compile(scene)
    t, Y, YD = simulate(scene, stop=2.0, step=0.02, method="dop853", rtol=1e-10, atol=1e-12)
    E = np.array([ev.energy(y, yd) for y, yd in zip(Y, YD)])
    L = np.array([_angular_momentum(ev, y, yd) for y, yd in zip(Y, YD)])
    assert np.abs(E - E[0]).max() / E[0] < 1e-8
    assert np.abs(L - L[0]).max() / np.linalg.norm(L[0]) < 1e-8
    assert np.abs(np.linalg.norm(Y[:, 3:7], axis=1) - 1).max() < 1e-12


def test_heavy_symmetric_top_integrals():
    scene = _model("spinning_top.yaml")
    ev = mbsfmu.compile(scene)
    t, Y, YD = simulate(scene, stop=0.5, step=0.005, method="dop853", rtol=1e-10, atol=1e-12)
    E, Lz, L3 = [], [], []
    for y, yd in zip(Y, YD):
        L = _angular_momentum(ev, y, yd)
        S = ev.jacobians(y, yd)["top"]["S"]
        E.append(ev.energy(y, yd))
        Lz.append(L[2])
        L3.append(L @ S[:, 2])
    E, Lz, L3 = map(np.array, (E, Lz, L3))
    p = ev.parameters
    C = p["m"] * p["r"] ** 2 / 2
    np.testing.assert_allclose(L3[0], C * p["spin"], rtol=1e-12)
    assert np.abs(E - E[0]).max() / abs(E[0]) < 1e-8
    assert np.abs(Lz - Lz[0]).max() / abs(L3[0]) < 1e-8
    assert np.abs(L3 - L3[0]).max() / abs(L3[0]) < 1e-8
    # it precesses: the symmetry axis turns about the vertical
    axis = [ev.jacobians(y, yd)["top"]["S"][:, 2] for y, yd in zip(Y, YD)]
    az = np.unwrap([math.atan2(a[1], a[0]) for a in axis])
    assert abs(az[-1] - az[0]) > 0.1
    assert np.abs(np.linalg.norm(Y[:, :4], axis=1) - 1).max() < 1e-12


def test_quarter_car_settles_to_static_equilibrium():
    scene = _model("spring_damper.yaml")
    ev = mbsfmu.compile(scene)
    p = ev.parameters
    t, Y, YD = simulate(scene, stop=3.0, step=0.01)
    zw = -(p["m_s"] + p["m_u"]) * G / p["k_t"]
    zb = zw - p["m_s"] * G / p["k_s"]
    np.testing.assert_allclose(Y[-1], [zw, zb], atol=1e-3)  # 5 cm drop, decays as exp(-2 t)
    E = np.array([ev.energy(y, yd) for y, yd in zip(Y, YD)])
    assert np.all(np.diff(E) < 1e-6 * abs(E).max())  # dampers only take energy out


# -- force inputs -------------------------------------------------------------------------------------
def test_cart_pole_force_input_enters_q():
    ev = mbsfmu.compile(_model("cart_pole.yaml"))
    y, yd = np.array([0.2, 0.4]), np.array([0.0, 0.0])
    F = np.array([3.0, -1.5, 2.0])
    _, _, q0 = ev.equations(y, yd)
    _, _, q1 = ev.equations(y, yd, u={"F_cart.x": F[0], "F_cart.y": F[1], "F_cart.z": F[2]})
    J_T = ev.jacobians(y, yd)["cart"]["J_T"]  # the force acts at the cart's centre of mass
    np.testing.assert_allclose(q1 - q0, J_T.T @ F, atol=1e-12)
    np.testing.assert_allclose(q1 - q0, [3.0, 0.0], atol=1e-12)
    assert "F_cart.x" in ev.inputs and "q.x" in ev.inputs


def test_cart_pole_pushed_cart_accelerates():
    scene = _model("cart_pole.yaml")
    t, Y, YD = simulate(scene, stop=0.2, step=0.01, inputs=lambda t: {"F_cart.x": 5.0})
    assert Y[-1, 0] > 0.05  # ~ F/(m_c+m_p) t²/2 ≈ 0.09 m
    assert Y[-1, 1] < 0.05  # pushing the cart tips the pole backwards (phi < initial)


def test_force_at_a_point_in_body_frame_matches_jacobian():
    """A body-frame force at a point off the centre of mass: q = J_Pᵀ S F, J_P from J_T, J_R by hand."""
    scene = mbsfmu.loads("""
mbsfmu: 1
name: fp
gravity: [0, 0, 0]
bodies:
  a:
    parent: world
    joint: {type: revolute, axis: [0, 0, 1], coordinates: [q1]}
    mass: 1
    center_of_mass: [0.5, 0, 0]
    inertia: {xx: 0.01, yy: 0.1, zz: 0.1}
  b:
    parent: a
    joint: {type: revolute, axis: [0, 1, 0], at: [1, 0, 0], coordinates: [q2]}
    mass: 1
    center_of_mass: [0.2, 0.1, 0]
    inertia: {xx: 0.01, yy: 0.1, zz: 0.1}
forces:
  - {type: force, body: b, at: [0.5, 0.05, -0.1], input: Fb, frame: body}
""")
    ev = mbsfmu.compile(scene)
    y, yd = np.array([0.3, -0.7]), np.zeros(2)
    F = np.array([1.0, 2.0, -0.5])
    _, _, q = ev.equations(y, yd, u={"Fb.x": F[0], "Fb.y": F[1], "Fb.z": F[2]})
    jb = ev.jacobians(y, yd)["b"]
    S = jb["S"]
    r_cp = S @ (np.array([0.5, 0.05, -0.1]) - np.array([0.2, 0.1, 0]))
    J_P = jb["J_T"] - np.cross(r_cp, jb["J_R"].T).T  # v_P = v_c + ω × r_cp
    np.testing.assert_allclose(q, J_P.T @ (S @ F), atol=1e-12)


# -- PUMA 560 ---------------------------------------------------------------------------------------
DH = [(0, 0, math.pi / 2), (0, 0.4318, 0), (0.15005, 0.0203, -math.pi / 2), (0.4318, 0, math.pi / 2),
      (0, 0, -math.pi / 2), (0, 0, 0)]  # (d, a, alpha), Corke's mdl_puma560
COM = [[0, 0, 0], [-0.3638, 0.006, 0.2275], [-0.0203, -0.0141, 0.070], [0, 0.019, 0], [0, 0, 0], [0, 0, 0.032]]


def _dh_frames(qs):
    T, out = np.eye(4), []
    for (d, a, al), th in zip(DH, qs):
        ct, st, ca, sa = math.cos(th), math.sin(th), math.cos(al), math.sin(al)
        T = T @ np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])
        out.append(T)
    return out


def test_puma560_matches_dh_forward_kinematics():
    ev = mbsfmu.compile(_model("robot_arm_6dof.yaml"))
    rng = np.random.default_rng(3)
    for _ in range(4):
        qs = rng.uniform(-math.pi, math.pi, 6)
        J = ev.jacobians(qs, np.zeros(6))
        for i, T in enumerate(_dh_frames(qs)[1:], start=2):  # link 1 has no mass
            np.testing.assert_allclose(J[f"link{i}"]["r"], T[:3, :3] @ COM[i - 1] + T[:3, 3], atol=1e-12)
            # z axis of DH frame i is the axis of joint i+1; x axis of frame i = body x axis
            np.testing.assert_allclose(J[f"link{i}"]["S"][:, 0], T[:3, 0], atol=1e-12)


def test_puma560_matches_pinocchio():
    pytest.importorskip("pinocchio")
    import pinocchio as pin
    from pinocchio_twin import pinocchio_model, to_pin
    scene = _model("robot_arm_6dof.yaml")
    ev = mbsfmu.compile(scene)
    ev.set_parameters({"m_load": 2.5})  # the payload (a fixed child body) takes part
    pm = pinocchio_model(ev)
    pd = pm.createData()
    rng = np.random.default_rng(11)
    for _ in range(4):
        y, yd, ydd = rng.uniform(-3, 3, 6), rng.normal(size=6), rng.normal(size=6)
        M, k, q = ev.equations(y, yd, 0.0)
        qp, vp, ap, free = to_pin(ev, y, yd, ydd)
        np.testing.assert_allclose(M @ ydd + k - q, pin.rnea(pm, pd, qp, vp, ap)[free], rtol=1e-10, atol=1e-10)
        Mp = np.array([pin.rnea(pm, pd, qp, 0 * vp, e) - pin.rnea(pm, pd, qp, 0 * vp, 0 * vp) for e in np.eye(6)]).T
        np.testing.assert_allclose(M, Mp, rtol=1e-10, atol=1e-12)
    # gravity torques at the 'ready' pose (q3 = -90°): shoulder holds the upper arm
    y0, _ = ev.initial_state()
    _, k, q = ev.equations(y0, np.zeros(6))
    assert abs(q[1]) > 10  # N m


# -- gantry crane -------------------------------------------------------------------------------------
def test_crane_inputs_and_horizontal_momentum():
    scene = _model("crane.yaml")
    ev = mbsfmu.compile(scene)
    y, yd = np.array([0.5, -0.3, 0.1, -0.2]), np.zeros(4)
    _, _, q0 = ev.equations(y, yd)
    Fb, Ft = np.array([100.0, 20.0, -5.0]), np.array([-3.0, 50.0, 7.0])
    u = {f"F_bridge.{a}": v for a, v in zip("xyz", Fb)} | {f"F_trolley.{a}": v for a, v in zip("xyz", Ft)}
    _, _, q1 = ev.equations(y, yd, u=u)
    J = ev.jacobians(y, yd)
    np.testing.assert_allclose(q1 - q0, J["bridge"]["J_T"].T @ Fb + J["trolley"]["J_T"].T @ Ft, atol=1e-12)
    np.testing.assert_allclose(q1 - q0, [97.0, 50.0, 0, 0], atol=1e-12)
    # without rail friction and inputs no horizontal force acts: Σ m v_x and Σ m v_y stay constant
    ev.set_parameters({"c_rail": 0.0})
    sim_scene = dict(scene.spec, parameters=[dict(p, value=0.0) if p["name"] == "c_rail" else p for p in scene.spec["parameters"]])
    t, Y, YD = simulate(sim_scene, stop=3.0, step=0.05)
    P = np.array([sum(b.m * ev.jacobians(y, yd)[b.name]["v"] for b in ev.model.bodies) for y, yd in zip(Y, YD)])
    assert np.ptp(YD[:, 0]) > 0.01  # the bridge does move, pushed by the swinging load
    np.testing.assert_allclose(P[:, :2], 0.0, atol=1e-6)


def test_heavy_top_nutation_and_precession_follow_lagrange_top_solution():
    """Lagrange top: precession rate φ̇ = (L_z − L_3 cos θ)/(A_O sin²θ) at every instant, and the largest tilt
    is the root of the effective-energy equation (θ̇ = 0) — from the three integrals, not from the simulator."""
    from scipy.optimize import brentq
    scene = _model("spinning_top.yaml")
    ev = mbsfmu.compile(scene)
    p = ev.parameters
    m, l, C = p["m"], p["l"], p["m"] * p["r"] ** 2 / 2
    A_O = m * p["r"] ** 2 / 4 + m * p["h"] ** 2 / 12 + m * l * l
    t, Y, YD = simulate(scene, stop=0.2, step=0.001, method="dop853", rtol=1e-10, atol=1e-12)
    y0, yd0 = Y[0], YD[0]
    L = _angular_momentum(ev, y0, yd0)
    e3 = ev.jacobians(y0, yd0)["top"]["S"][:, 2]
    Lz, L3, E = L[2], L @ e3, ev.energy(y0, yd0)

    def phidot(th):
        return (Lz - L3 * math.cos(th)) / (A_O * math.sin(th) ** 2)

    tilt, rate = [], []
    for y, yd in zip(Y, YD):
        jb = ev.jacobians(y, yd)["top"]
        a = jb["S"][:, 2]
        ad = np.cross(jb["omega"], a)
        tilt.append(math.acos(a[2]))
        rate.append((a[0] * ad[1] - a[1] * ad[0]) / (a[0] ** 2 + a[1] ** 2))
        # outputs between internal steps are dense-output values: their error is ~rtol·|ω| = 1e-10·150 rad/s
        np.testing.assert_allclose(rate[-1], phidot(tilt[-1]), rtol=1e-7, atol=3e-8)

    def f(th):  # E − T_spin − V − T_precession = ½ A_O θ̇²
        return E - L3 ** 2 / (2 * C) - m * G * l * math.cos(th) - 0.5 * A_O * phidot(th) ** 2 * math.sin(th) ** 2

    th1 = p["tilt"]
    th2 = brentq(f, th1 + 1e-6, 1.5)
    assert abs(max(tilt) - th2) < 1e-4, (max(tilt), th2)
    assert abs(min(tilt) - th1) < 1e-9


def test_top_with_cardan_angles_follows_the_quaternion_top():
    """The same top in x-y-z Cardan angles (away from gimbal lock) traces the same centre-of-mass path."""
    text = (ROOT / "models" / "spinning_top.yaml").read_text().replace("parameterization: quaternion", "parameterization: cardan")
    runs = []
    for scene in (_model("spinning_top.yaml"), mbsfmu.loads(text)):
        ev = mbsfmu.compile(scene)
        t, Y, YD = simulate(scene, stop=0.2, step=0.01, method="dop853", rtol=1e-11, atol=1e-13)
        runs.append(np.array([ev.jacobians(y, yd)["top"]["r"] for y, yd in zip(Y, YD)]))
    assert "top.b" in ev.coordinates
    np.testing.assert_allclose(runs[1], runs[0], atol=1e-8)


def test_robot_arm_description_cites_its_data_source():
    d = _model("robot_arm_6dof.yaml").spec["description"]
    assert "Armstrong" in d and "Corke" in d
