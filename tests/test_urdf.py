"""URDF import (issue 25): real robots against Pinocchio's model of the same file (an independent URDF parser
and dynamics), the URDF conventions against closed forms, hostile and broken URDFs refused in one line."""

import contextlib
import re
import sysconfig
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.errors import ModelError
from mbsfmu.scene.urdf import nearest_physical_inertia, rpy_matrix
from mbsfmu.simulation import Simulation

pin = pytest.importorskip("pinocchio")
ROBOTS = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"
if not ROBOTS.is_dir():
    pytest.skip("example-robot-data is not installed", allow_module_level=True)

# (file, base): fixed-base arms, quadrupeds on a floating base, humanoids of 32 and 43 dof, a 39-dof centaur
REAL = [("ur_description/urdf/ur5_robot.urdf", "fixed"), ("kinova_description/robots/kinova.urdf", "fixed"),
        ("xarm_description/urdf/xarm7.urdf", "fixed"), ("solo_description/robots/solo12.urdf", "free"),
        ("go2_description/urdf/go2.urdf", "free"), ("icub_description/robots/icub.urdf", "free"),
        ("g1_description/urdf/g1_29dof_with_hand_rev_1_0.urdf", "free"), ("centauro_description/urdf/centauro.urdf", "fixed")]


def _scene(file, base="fixed", extra=""):
    return mbsfmu.loads(f"mbsfmu: 1\nurdf: {{file: {file}, base: {base}}}\n{extra}", base=ROBOTS)


def _pinocchio(file, base):
    path = str(ROBOTS / file)
    return pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if base == "free" else pin.buildModelFromUrdf(path)


class _Twin:
    """Our state ↔ Pinocchio's. Pinocchio's free flyer takes the linear velocity in the body frame (ours: in
    the world) and its quaternion as (x, y, z, w) (ours: w first); a continuous joint is (cos, sin) there."""

    def __init__(self, ev, pm):
        self.ev, self.pm = ev, pm
        self.free = ev.model.bodies[0].kind == "free"
        index = {}
        for jid in range(1, pm.njoints):
            j = pm.joints[jid]
            name = "root" if pm.names[jid] == "root_joint" else pm.names[jid]
            index[name] = (j.idx_q, j.nq, j.idx_v)
        self.index = index
        vel = ev.velocity_coordinates
        self.P = np.array([self._v(c, k) for k, c in enumerate(vel)])  # our velocity i ↔ Pinocchio's v[P[i]]

    def _v(self, c, k):
        if self.free and k < 6:
            return k
        return self.index[c][2]

    def state(self, y, yd, ydd):
        pm, nv = self.pm, self.pm.nv
        q, v, a = np.zeros(pm.nq), np.zeros(nv), np.zeros(nv)
        v[self.P], a[self.P] = yd, ydd
        for k, c in enumerate(self.ev.coordinates):
            if self.free and k < 7:
                continue
            iq, nq, _ = self.index[c]
            q[iq:iq + nq] = [y[k]] if nq == 1 else [np.cos(y[k]), np.sin(y[k])]
        T = np.zeros((nv, nv))  # v = T ẏ
        T[self.P, np.arange(nv)] = 1.0
        if self.free:
            w, x, yy, z = y[3:7]
            q[:3], q[3:7] = y[:3], [x, yy, z, w]
            R = pin.Quaternion(w, x, yy, z).toRotationMatrix()
            T[:3, :3] = R.T
            v[:3] = R.T @ yd[:3]
            a[:3] = R.T @ ydd[:3] - np.cross(yd[3:6], v[:3])  # d/dt (Rᵀ ẋ) = Rᵀ ẍ − ω × (Rᵀ ẋ)
        return q, v, a, T


def _random_state(ev, rng):
    y = rng.uniform(-1, 1, len(ev.coordinates))
    if ev.model.bodies[0].kind == "free":
        y[3:7] /= np.linalg.norm(y[3:7])
    n = len(ev.velocity_coordinates)
    return y, rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)


@pytest.mark.parametrize("file,base", REAL, ids=[Path(f).stem for f, _ in REAL])
def test_real_robot_matches_pinocchio(file, base):
    """M, k, q and ÿ of a real robot against Pinocchio's model of the same URDF: RNEA (k − q = τ at ÿ = 0,
    gravity included), CRBA (M) and ABA (ÿ), with the URDF's joint damping added to Pinocchio's torques."""
    ev = mbsfmu.compile(_scene(file, base))
    pm = _pinocchio(file, base)
    pd = pm.createData()
    twin = _Twin(ev, pm)
    engine = Simulation(ev.model.spec).engine
    assert sorted(twin.P) == list(range(pm.nv))  # every Pinocchio velocity is one of ours
    rng = np.random.default_rng(len(file))
    for _ in range(2):
        y, yd, ydd = _random_state(ev, rng)
        q, v, a, T = twin.state(y, yd, ydd)
        damping = pm.damping * v  # Pinocchio's damping, read by its own parser; T = 1 on the 1-dof joints
        tau = T.T @ (pin.rnea(pm, pd, q, v, a) + damping)
        Mp = pin.crba(pm, pd, q)
        Mp = np.triu(Mp) + np.triu(Mp, 1).T
        a_free = pin.aba(pm, pd, q, v, -damping)
        ydd_p = a_free[twin.P]
        if twin.free:  # back to our world-frame linear acceleration: ẍ = R (a + ω × v)
            R = pin.Quaternion(y[3], *y[4:7]).toRotationMatrix()
            ydd_p[:3] = R @ (a_free[:3] + np.cross(v[3:6], v[:3]))
        for M, k, qf in (ev.equations(y, yd, 0.0), engine.equations(0.0, np.concatenate([y, yd]))):
            scale = max(1.0, np.abs(tau).max())
            np.testing.assert_allclose(M @ ydd + k - qf, tau, rtol=0, atol=1e-10 * scale)
            np.testing.assert_allclose(M, T.T @ Mp @ T, rtol=0, atol=1e-10 * max(1.0, np.abs(M).max()))
            # two backward-stable solves differ by up to ε·cond(M) relative (icub's tiny links: cond 1e7)
            rel = max(1e-10, 1e-15 * np.linalg.cond(M))
            np.testing.assert_allclose(np.linalg.solve(M, qf - k), ydd_p, rtol=0, atol=rel * max(1.0, np.abs(ydd_p).max()))


# ---- the URDF conventions against closed forms ------------------------------------------------------------
def _urdf(tmp_path, body, name="robot.urdf"):
    path = tmp_path / name
    path.write_text(f'<?xml version="1.0"?>\n<robot name="t">\n{body}\n</robot>\n')
    return path


_BOX = '<inertial><origin xyz="{c}" rpy="{rpy}"/><mass value="{m}"/><inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" ixy="0" ixz="0" iyz="0"/></inertial>'


def _link(name, m=2.0, c="0 0 0", rpy="0 0 0", ixx=0.1, iyy=0.2, izz=0.25):
    return f'<link name="{name}">{_BOX.format(c=c, rpy=rpy, m=m, ixx=ixx, iyy=iyy, izz=izz)}</link>'


def test_rpy_is_fixed_axis_roll_pitch_yaw():
    from scipy.spatial.transform import Rotation
    for rpy in ([0.3, -0.7, 1.9], [np.pi / 2, 0, 0], [0.1, 1.2, -2.5]):
        np.testing.assert_allclose(rpy_matrix(rpy), Rotation.from_euler("xyz", rpy).as_matrix(), atol=1e-15)  # extrinsic x, y, z


def test_prismatic_on_a_rotated_origin_falls_along_its_world_axis(tmp_path):
    """A slider whose joint frame is turned by rpy: M = m, and gravity drives it with m·g·(R·axis)."""
    rpy, m = [0.4, -0.3, 1.1], 2.0
    path = _urdf(tmp_path, _link("base") + _link("slider", m=m, c="0.1 0.2 0.3", rpy="0.5 0.2 0.1")
                 + f'<joint name="s" type="prismatic"><origin xyz="1 2 3" rpy="{" ".join(map(str, rpy))}"/>'
                   '<parent link="base"/><child link="slider"/><axis xyz="0 3 4"/></joint>')
    ev = mbsfmu.compile(mbsfmu.load(path))
    M, k, q = ev.equations(np.array([0.7]), np.array([1.3]))
    axis_world = rpy_matrix(rpy) @ np.array([0, 0.6, 0.8])
    np.testing.assert_allclose(M, [[m]], atol=1e-14)
    np.testing.assert_allclose(q - k, [m * np.array([0, 0, -9.81]) @ axis_world], atol=1e-13)


def test_inertial_rpy_rotates_the_tensor_into_the_link_frame(tmp_path):
    """A wheel about z whose inertial frame is rolled by 90°: its polar moment iyy becomes the link's zz."""
    path = _urdf(tmp_path, _link("base") + _link("wheel", m=1.0, rpy=f"{np.pi / 2} 0 0", ixx=0.4, iyy=0.7, izz=0.35)
                 + '<joint name="w" type="continuous"><parent link="base"/><child link="wheel"/><axis xyz="0 0 1"/></joint>')
    M, _, _ = mbsfmu.compile(mbsfmu.load(path)).equations(np.zeros(1), np.zeros(1))
    np.testing.assert_allclose(M, [[0.7]], atol=1e-14)


def test_planar_and_floating_joints_fall_freely(tmp_path):
    """In free fall a body on a floating joint accelerates with g; one on a vertical planar joint (normal y)
    with g inside the plane; neither turns. M: m for translations, the moment about the normal for the turn."""
    body = (_link("base") + _link("board", m=3.0) + _link("ball", m=1.5)
            + '<joint name="p" type="planar"><parent link="base"/><child link="board"/><axis xyz="0 1 0"/></joint>'
            + '<joint name="f" type="floating"><origin xyz="0 0 1"/><parent link="base"/><child link="ball"/></joint>')
    ev = mbsfmu.compile(mbsfmu.load(_urdf(tmp_path, body)))
    assert ev.velocity_coordinates[:3] == ["p.x", "p.y", "p.angle"]
    y, yd = np.zeros(len(ev.coordinates)), np.zeros(len(ev.velocity_coordinates))
    y[6] = 1.0  # the ball's quaternion (1, 0, 0, 0)
    M, k, q = ev.equations(y, yd)
    ydd = np.linalg.solve(M, q - k)
    np.testing.assert_allclose(np.diag(M)[:3], [3.0, 3.0, 0.2], atol=1e-14)  # iyy = 0.2 about the normal y
    np.testing.assert_allclose(np.linalg.norm(ydd[:2]), 9.81, atol=1e-13)  # g lies in the plane normal to y
    np.testing.assert_allclose(ydd[2], 0, atol=1e-14)
    np.testing.assert_allclose(ydd[3:6], [0, 0, -9.81], atol=1e-13)
    np.testing.assert_allclose(ydd[6:], 0, atol=1e-14)


# ---- imperfect robots: refused by default, repaired on request ---------------------------------------------
def test_nearest_physical_inertia_is_the_projection_of_the_moments():
    """diag(1, 1, 3) breaks I1 + I2 >= I3 by 1: its nearest physical moments are (4/3, 4/3, 8/3); no physical
    diagonal tensor of a random sample lies closer."""
    I = nearest_physical_inertia(np.diag([1.0, 1.0, 3.0]))
    np.testing.assert_allclose(I, np.diag([4 / 3, 4 / 3, 8 / 3]), atol=1e-15)
    rng = np.random.default_rng(0)
    lam = rng.uniform(0, 3, (20000, 3))
    ok = (lam[:, 0] + lam[:, 1] >= lam[:, 2]) & (lam[:, 0] + lam[:, 2] >= lam[:, 1]) & (lam[:, 1] + lam[:, 2] >= lam[:, 0])
    dist = np.linalg.norm(lam[ok] - [1.0, 1.0, 3.0], axis=1)
    assert dist.min() >= np.linalg.norm(np.diag(I) - [1.0, 1.0, 3.0]) - 1e-12


def test_unphysical_inertia_refused_naming_the_link_then_repaired(tmp_path):
    path = _urdf(tmp_path, _link("base") + _link("arm", ixx=0.1, iyy=0.1, izz=0.3)
                 + '<joint name="j" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/></joint>')
    with pytest.raises(ModelError, match=r"robot.urdf:3: <inertia>: link 'arm': .*triangle inequality.*repair"):
        mbsfmu.load(path)
    with pytest.warns(UserWarning, match="repaired link 'arm'"):
        scene = mbsfmu.load(path, repair=True)
    assert len(scene.repairs) == 1
    M, _, _ = mbsfmu.compile(scene).equations(np.zeros(1), np.zeros(1))
    np.testing.assert_allclose(M, [[0.3 - 0.1 / 3]], atol=1e-14)  # (0.1, 0.1, 0.3) → (0.1 + d, 0.1 + d, 0.3 − d), d = 0.1/3


def test_massless_moving_leaves_refused_then_merged(tmp_path):
    path = _urdf(tmp_path, _link("base") + _link("arm") + '<link name="finger"/><link name="tip"/>'
                 + '<joint name="j" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/></joint>'
                 + '<joint name="f" type="revolute"><parent link="arm"/><child link="finger"/><axis xyz="0 1 0"/></joint>'
                 + '<joint name="t" type="prismatic"><parent link="finger"/><child link="tip"/><axis xyz="1 0 0"/></joint>')
    with pytest.raises(ModelError, match=r":3: <joint>: joint 'f' moves link 'finger', which with the links it carries has no mass"):
        mbsfmu.load(path)
    with pytest.warns(UserWarning):
        scene = mbsfmu.load(path, repair=True)
    assert [r.split(":")[0] for r in scene.repairs] == ["joint 'f' fixed", "joint 't' fixed"]
    ev = mbsfmu.compile(scene)
    assert ev.coordinates == ["j"] and {"finger", "tip"} <= {b["name"] for b in scene.spec["bodies"]}  # still frames


def test_romeo_massless_fingers_and_romeo_small_inertias():
    """Pinocchio accepts both silently (romeo's M is singular); here they are refused, and repaired on request."""
    for file, what in (("romeo_description/urdf/romeo.urdf", "no mass or inertia"),
                       ("romeo_description/urdf/romeo_small.urdf", "triangle inequality")):
        with pytest.raises(ModelError, match=what):
            mbsfmu.load(ROBOTS / file)
        with pytest.warns(UserWarning):
            ev = mbsfmu.compile(mbsfmu.load(ROBOTS / file, repair=True))
        y, yd, _ = _random_state(ev, np.random.default_rng(3))
        assert np.linalg.eigvalsh(ev.equations(y, yd)[0]).min() > 0  # M positive definite


# ---- hostile and broken URDFs: one ModelError line each, quickly --------------------------------------------
LAUGHS = ('<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY a "aaaaaaaaaa">' +
          "".join(f'<!ENTITY {chr(98 + i)} "{("&" + chr(97 + i) + ";") * 10}">' for i in range(9)) + "]>\n<robot name=\"&j;\"/>\n")
HOSTILE = {
    "billion_laughs": (LAUGHS, r":2: .*EntitiesForbidden.*refused"),
    "external_entity": ('<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY x SYSTEM "file:///etc/passwd">]>\n<robot name="&x;"/>',
                        r":2: .*refused"),
    "parameter_entity": ('<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY % x SYSTEM "http://example.com/x.dtd"> %x;]>\n<robot/>',
                         r":2: .*refused"),
    "not_xml": ("<robot><link name='a'></robot>", r":1: not well-formed XML"),
    "not_a_robot": ('<?xml version="1.0"?>\n<sdf/>', r":2: <sdf>: .*a URDF's is <robot>"),
    "xacro": ('<robot xmlns:xacro="http://www.ros.org/wiki/xacro">\n<xacro:macro name="leg"/>\n</robot>', r":2: <xacro:macro>: .*run xacro first"),
    "missing_link": ('<robot name="r">\n<link name="a"/>\n<joint name="j" type="fixed"><parent link="a"/>\n<child link="b"/></joint>\n</robot>',
                     r":4: <child>: joint 'j' names the child link 'b'"),
    "cycle": ('<robot name="r">\n<link name="a"/><link name="b"/><link name="c"/>\n'
              '<joint name="j1" type="fixed"><parent link="a"/><child link="b"/></joint>\n'
              '<joint name="j2" type="fixed"><parent link="c"/><child link="c"/></joint>\n</robot>', r"cycle"),
    "two_parents": ('<robot name="r">\n<link name="a"/><link name="b"/>\n'
                    '<joint name="j1" type="fixed"><parent link="a"/><child link="b"/></joint>\n'
                    '<joint name="j2" type="fixed"><parent link="a"/><child link="b"/></joint>\n</robot>', r":4: <joint>: link 'b' is the child of two joints"),
    "unknown_joint_type": ('<robot name="r">\n<link name="a"/><link name="b"/>\n'
                           '<joint name="j" type="revolut"><parent link="a"/><child link="b"/></joint>\n</robot>',
                           r":3: <joint>: joint 'j' has the unknown type 'revolut' \(did you mean 'revolute'"),
    "mimic": ('<robot name="r">\n' + _link("a") + _link("b") + _link("c") +
              '\n<joint name="j" type="revolute"><parent link="a"/><child link="b"/></joint>\n'
              '<joint name="k" type="revolute"><parent link="b"/><child link="c"/>\n<mimic joint="j"/></joint>\n</robot>',
              r":5: <mimic>: joint 'k' mimics joint 'j'"),
    "nan_origin": ('<robot name="r">\n' + _link("a") + _link("b") + '\n<joint name="j" type="revolute"><parent link="a"/>'
                   '<child link="b"/>\n<origin xyz="0 nan 0"/></joint>\n</robot>', r":4: <origin>: xyz=\"0 nan 0\" is not 3 finite numbers"),
    "negative_mass": ('<robot name="r">\n<link name="a"><inertial>\n<mass value="-1"/></inertial></link>\n</robot>', r":3: <mass>: .*negative mass"),
    "huge_counts": ('<robot name="r">\n' + '<link name="l"/>' * (limits_entries := 10_001) + '\n</robot>', r"a second link named 'l'"),
    "many_links": ('<robot name="r">\n' + "".join(f'<link name="l{i}"/>' for i in range(limits_entries)) + '\n</robot>', r"more than 10,000 links"),
    "names_collide": ('<robot name="r">\n' + _link("a") + _link("b") + _link("c") + '\n<joint name="j-1" type="revolute"><parent link="a"/>'
                      '<child link="b"/></joint>\n<joint name="j_1" type="revolute"><parent link="b"/><child link="c"/></joint>\n</robot>',
                      r":4: <joint>: joint 'j_1' would name the coordinate 'j_1', which joint 'j-1' already names"),
    "links_collide": ('<robot name="r">\n' + _link("a") + '\n' + _link("b-1") + '\n' + _link("b_1") + '\n<joint name="j" type="fixed"><parent link="a"/>'
                      '<child link="b-1"/></joint><joint name="k" type="fixed"><parent link="a"/><child link="b_1"/></joint>\n</robot>',
                      r":4: <link>: link 'b_1' would be the scene body 'b_1', which another link"),
    "many_elements": ('<robot name="r">' + "<a/>" * 320_001 + "</robot>", r": more than 320,000 XML elements \(320,002 start tags\)"),
    "deep": ('<robot name="r">' + "<a>" * 100 + "</a>" * 100 + "</robot>", r"nested deeper than 64"),
}


@pytest.mark.parametrize("case", HOSTILE)
def test_hostile_urdf_is_one_model_error_line(tmp_path, case):
    text, pattern = HOSTILE[case]
    path = tmp_path / "robot.urdf"
    path.write_text(text)
    t0 = time.process_time()
    with pytest.raises(ModelError, match=pattern) as e:
        mbsfmu.load(path)
    assert time.process_time() - t0 < 1.0
    assert "\n" not in str(e.value) and str(e.value).startswith(str(path))


def test_xacro_suffix_and_urdf_outside_the_scene_folder_refused(tmp_path):
    (tmp_path / "arm.urdf.xacro").write_text("<robot/>")
    with pytest.raises(ModelError, match="run xacro first"):
        mbsfmu.load(tmp_path / "arm.urdf.xacro")
    inner = tmp_path / "scene"
    inner.mkdir()
    _urdf(tmp_path, _link("base"))
    with pytest.raises(ModelError, match=r"scene.yaml:2: urdf.file: the URDF file '../robot.urdf' lies outside the scene's folder"):
        (inner / "scene.yaml").write_text("mbsfmu: 1\nurdf: {file: ../robot.urdf}\n")
        mbsfmu.load(inner / "scene.yaml")
    assert mbsfmu.load(inner / "scene.yaml", allow_outside=True).spec["bodies"][0]["name"] == "base"


# ---- a YAML over a URDF: inputs, outputs, initial state; its native FMU ------------------------------------
UR5 = "ur_description/urdf/ur5_robot.urdf"
OVERLAY = """mbsfmu: 1
name: ur5_torques
urdf: {file: ur5.urdf, base: fixed}
bodies:
  upper_arm_link: {joint: {initial: {shoulder_lift_joint: -1.0}, initial_velocity: {shoulder_lift_joint: 0.5}}}
  forearm_link: {joint: {initial: {elbow_joint: 0.8}}}
outputs:
  - {body: ee_link, point: [0.1, 0, 0], quantities: [position], name: tool}
integrator: {method: dop853, rtol: 1e-11, atol: 1e-12}
experiment: {stop: 0.3, step: 0.01}
"""
TORQUES = {"q.shoulder_pan_joint": 3.0, "q.elbow_joint": -2.0, "q.wrist_2_joint": 0.5}


def _pinocchio_run(stop):
    """Pinocchio's forward dynamics (ABA) with the same torques, integrated by scipy at rtol 1e-12."""
    from scipy.integrate import solve_ivp
    pm = _pinocchio(UR5, "fixed")
    pd = pm.createData()
    names = [pm.names[j] for j in range(1, pm.njoints)]
    tau = np.array([TORQUES.get(f"q.{n}", 0.0) for n in names])
    q0, v0 = np.zeros(pm.nq), np.zeros(pm.nv)
    q0[names.index("shoulder_lift_joint")], q0[names.index("elbow_joint")] = -1.0, 0.8
    v0[names.index("shoulder_lift_joint")] = 0.5
    sol = solve_ivp(lambda t, x: np.concatenate([x[6:], pin.aba(pm, pd, x[:6], x[6:], tau)]), (0, stop),
                    np.concatenate([q0, v0]), method="DOP853", rtol=1e-12, atol=1e-12)
    q = sol.y[:6, -1]
    pin.framesForwardKinematics(pm, pd, q)
    frame = pd.oMf[pm.getFrameId("ee_link")]
    return names, q, frame.act(np.array([0.1, 0.0, 0.0]))


def test_overlay_arm_native_fmu_against_pinocchio(tmp_path):
    """The overlay's initial state, torque inputs and end-effector output point: the in-process run against
    Pinocchio's forward dynamics and frame placement; the native FMU (fmpy) validates and matches the run."""
    from fmpy import read_model_description, simulate_fmu
    from fmpy.validation import validate_fmu
    (tmp_path / "ur5.urdf").write_bytes((ROBOTS / UR5).read_bytes())
    (tmp_path / "ur5.yaml").write_text(OVERLAY)
    scene = mbsfmu.load(tmp_path / "ur5.yaml")
    t, Y, YD = mbsfmu.simulate(scene, inputs=TORQUES)
    names, q_ref, tool_ref = _pinocchio_run(t[-1])
    ev = mbsfmu.compile(scene)
    np.testing.assert_allclose(Y[-1], q_ref[[names.index(c) for c in ev.coordinates]], atol=1e-9)
    fmu = mbsfmu.build_fmu(scene, tmp_path / "native", kind="native")
    assert validate_fmu(str(fmu)) == []
    outs = [v.name for v in read_model_description(str(fmu)).modelVariables if v.causality == "output"]
    res = simulate_fmu(str(fmu), stop_time=0.3, output_interval=0.01, start_values=TORQUES, output=outs)
    F = np.column_stack([res[f"y.{c}"] for c in ev.coordinates])
    np.testing.assert_allclose(F, Y, rtol=0, atol=1e-12)
    np.testing.assert_allclose([res[f"tool.r.{x}"][-1] for x in "xyz"], tool_ref, atol=1e-9)


# ---- mbsfmu convert -------------------------------------------------------------------------------------
@pytest.mark.parametrize("file,base", [("kinova_description/robots/kinova.urdf", "fixed"), ("icub_description/robots/icub.urdf", "free")])
def test_convert_writes_the_equivalent_scene(tmp_path, file, base, capsys):
    """The written YAML loads to the very scene the URDF gives (floats written with every digit), dampers and
    rotated inertias included."""
    from mbsfmu.cli import main
    out = tmp_path / "robot.yaml"
    assert main(["convert", str(ROBOTS / file), "-o", str(out), "--base", base]) == 0
    direct = _scene(file, base).spec
    assert mbsfmu.load(out).spec == direct


def test_convert_and_check_fail_in_one_line(tmp_path, capsys):
    from mbsfmu.cli import main
    out = tmp_path / "robot.yaml"
    for argv in (["convert", str(ROBOTS / "panda_description/urdf/panda.urdf"), "-o", str(out)],
                 ["check", str(ROBOTS / "romeo_description/urdf/romeo_small.urdf")]):
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err and (".urdf:" in err)
    assert not out.exists()
    assert main(["check", "--repair", str(ROBOTS / "romeo_description/urdf/romeo_small.urdf")]) == 0
    assert "note: " in capsys.readouterr().err


# ---- visuals: drawn shapes, package:// confined --------------------------------------------------------------
def _stl(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n")


def test_visuals_become_shapes_and_package_uris_stay_in_their_folder(tmp_path):
    _stl(tmp_path / "pkgs/arm_description/meshes/link.stl")
    visual = ('<material name="blue"><color rgba="0 0 1 1"/></material>'
              '<link name="base">' + _BOX.format(c="0 0 0", rpy="0 0 0", m=1, ixx=0.1, iyy=0.1, izz=0.1) +
              '<visual><origin xyz="0 0 0.1" rpy="0 0 1.5"/><geometry><box size="0.2 0.3 0.4"/></geometry>'
              '<material name="blue"/></visual><visual><geometry><mesh filename="package://arm_description/meshes/link.stl" scale="0.001 0.001 0.001"/>'
              '</geometry></visual><visual><geometry><mesh filename="package://arm_description/meshes/link.dae"/></geometry></visual>'
              '<visual><geometry><cylinder radius="0.05" length="0.5"/></geometry><material name="m"><color rgba="1 0 0 0.5"/></material></visual></link>')
    (tmp_path / "robot").mkdir()
    _urdf(tmp_path / "robot", visual)
    (tmp_path / "scene.yaml").write_text("mbsfmu: 1\nurdf: {file: robot/robot.urdf, package_dirs: [pkgs], base: free}\n")
    with pytest.warns(UserWarning, match=r"visual meshes not drawn: 1 not found"):
        scene = mbsfmu.load(tmp_path / "scene.yaml")
    box, mesh, cyl = scene.spec["bodies"][0]["shape"]
    assert box["size"] == [0.2, 0.3, 0.4] and box["at"] == [0, 0, 0.1] and box["color"] == "#0000ff"
    np.testing.assert_allclose(box["rotation"]["matrix"], rpy_matrix([0, 0, 1.5]), atol=1e-15)
    assert mesh["file"] == "pkgs/arm_description/meshes/link.stl" and mesh["scale"] == [0.001] * 3
    assert cyl["type"] == "cylinder" and cyl["opacity"] == 0.5 and cyl["color"] == "#ff0000"
    page = mbsfmu.animate(scene, str(tmp_path / "anim.html"), stop=0.1)
    assert Path(page).stat().st_size > 0
    # a package:// name that climbs out of its package folder is not followed: that visual is not drawn, named
    # by its URDF line (a drawing never refuses the robot's dynamics)
    (tmp_path / "robot/robot.urdf").write_text('<robot name="r">\n<link name="a">' + _BOX.format(c="0 0 0", rpy="0 0 0", m=1, ixx=0.1, iyy=0.1, izz=0.1) +
                                               '<visual><geometry>\n<mesh filename="package://arm_description/../../../secret.stl"/>'
                                               '</geometry></visual></link>\n</robot>')
    _stl(tmp_path / "secret.stl")
    with pytest.warns(UserWarning, match=r"robot.urdf:3: <mesh>: the mesh file 'package://arm_description/../../../secret.stl' leaves its folder"):
        assert "shape" not in mbsfmu.load(tmp_path / "scene.yaml").spec["bodies"][0]
    # a mesh of 1 GB (sparse) is left out by its size before a byte is read
    (tmp_path / "robot/robot.urdf").write_text(visual.join(['<robot name="r">\n', '\n</robot>']))
    with open(tmp_path / "pkgs/arm_description/meshes/link.stl", "wb") as f:
        f.truncate(2**30)
    with pytest.warns(UserWarning, match=r"visual meshes not drawn: .*1 larger than 64 MB"):
        assert [s["type"] for s in mbsfmu.load(tmp_path / "scene.yaml").spec["bodies"][0]["shape"]] == ["box", "cylinder"]


@pytest.mark.parametrize("file,base", REAL, ids=[Path(f).stem for f, _ in REAL])
def test_real_robot_native_fmu_validates_and_matches_the_in_process_run(tmp_path, file, base):
    """Each real robot's native FMU: fmpy's validation is clean and its outputs equal the in-process run
    (the in-process engine is held to Pinocchio above), falling or swinging under gravity from rest, with the
    default method: some real robots are stiff from the first step (iCub's M has λ_min/λ_max ≈ 1e-18 at rest, with
    joint damping), where auto must hand over to radau5."""
    from fmpy import simulate_fmu
    from fmpy.validation import validate_fmu
    scene = _scene(file, base)
    fmu = mbsfmu.build_fmu(scene, tmp_path, kind="native")
    assert validate_fmu(str(fmu)) == []
    stop, h = 0.05, 0.01
    t, Y, YD = mbsfmu.simulate(scene, stop=stop, step=h)
    ev = mbsfmu.compile(scene)
    outs = [f"y.{c}" for c in ev.coordinates] + [f"yd.{c}" for c in ev.velocity_coordinates]
    res = simulate_fmu(str(fmu), stop_time=stop, output_interval=h, output=outs)
    F = np.column_stack([res[n] for n in outs])
    X = np.hstack([Y, YD])
    scale = np.maximum(np.abs(X).max(axis=0), 1.0)
    assert F.shape == X.shape and np.all(np.abs(F - X) <= 1e-12 * scale), np.abs(F - X).max()
    assert np.ptp(YD, axis=0).max() > 1e-3  # it moved


# ---- an elastic link through the overlay: UR5's forearm as a beam along its z axis ----------------------------
FOREARM_L, FOREARM_M, FOREARM_IZZ = 0.39225, 2.275, 0.004095   # the URDF's wrist_1_joint origin z, forearm mass, izz


def _elastic_ur5(EI, extra=""):
    """UR5 with its forearm a beam of the URDF forearm's mass along forearm z, the wrist at the beam's tip."""
    L = FOREARM_L
    return _scene(UR5, extra=f"""bodies:
  upper_arm_link: {{joint: {{initial: {{shoulder_lift_joint: -1.0}}, initial_velocity: {{shoulder_lift_joint: 0.5}}}}}}
  forearm_link:
    joint: {{initial: {{elbow_joint: 0.8}}}}
    elastic: {{beam: {{length: {L}, EI: {EI}, rhoA: {FOREARM_M / L!r}, rhoIp: {FOREARM_IZZ / L!r}, axis: [0, 0, 1], elements: 8, modes: 4}}}}
  wrist_1_link: {{joint: {{node: -1}}}}
outputs:
  - {{body: forearm_link, node: -1, quantities: [position], name: tip}}
integrator: {{method: dop853, rtol: 1e-10, atol: 1e-12}}
experiment: {{stop: 0.2, step: 0.01}}
{extra}""")


def _rigid_beam_ur5():
    """Pinocchio's UR5 with the forearm's inertia replaced by the rigid beam's: a rod of the forearm's mass
    along z from 0 to L (m L²/12 about its centre across; izz as rhoIp gives)."""
    pm = _pinocchio(UR5, "fixed")
    m, L = FOREARM_M, FOREARM_L
    pm.inertias[pm.getJointId("elbow_joint")] = pin.Inertia(m, np.array([0.0, 0.0, L / 2]), np.diag([m * L**2 / 12, m * L**2 / 12, FOREARM_IZZ]))
    return pm


def test_elastic_forearm_replaces_the_urdf_inertial_or_keeps_the_overlays():
    """Made elastic, the forearm's URDF inertial goes (the beam carries the mass); a mass the overlay gives stays."""
    forearm = lambda s: next(b for b in s.spec["bodies"] if b["name"] == "forearm_link")
    assert forearm(_elastic_ur5(1e3))["mass"] == 0.0
    text = "bodies: {forearm_link: {mass: 0.5, center_of_mass: [0, 0, 0.1], elastic: {beam: {length: 0.39, EI: 100, rhoA: 5, axis: [0, 0, 1]}}}}"
    body = forearm(_scene(UR5, extra=text))
    assert body["mass"] == 0.5 and body["center_of_mass"] == [0, 0, 0.1] and not np.any(body["inertia"])


def test_stiff_elastic_forearm_approaches_the_rigid_robot_of_the_beams_inertia():
    """As EI grows tenfold, the joint motion of the UR5 with an elastic forearm approaches Pinocchio's ABA run of
    the rigid robot whose forearm has the beam's mass and inertia about tenfold (the gravity sag ∝ 1/EI)."""
    from scipy.integrate import solve_ivp
    pm = _rigid_beam_ur5()
    pd = pm.createData()
    names = [pm.names[j] for j in range(1, pm.njoints)]
    q0, v0 = np.zeros(pm.nq), np.zeros(pm.nv)
    q0[names.index("shoulder_lift_joint")], q0[names.index("elbow_joint")] = -1.0, 0.8
    v0[names.index("shoulder_lift_joint")] = 0.5
    sol = solve_ivp(lambda t, x: np.concatenate([x[6:], pin.aba(pm, pd, x[:6], x[6:], np.zeros(6))]), (0, 0.2),
                    np.concatenate([q0, v0]), method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)
    errors = []
    for EI in (1e3, 1e4, 1e5):
        scene = _elastic_ur5(EI)
        t, Y, _ = mbsfmu.simulate(scene)
        coords = mbsfmu.compile(scene).coordinates
        joints = [coords.index(n) for n in names]
        errors.append(np.abs(Y[:, joints] - sol.sol(t)[:6].T).max())
    assert errors[0] > 1e-4                               # soft enough to differ visibly
    ratios = np.array(errors[:-1]) / errors[1:]
    assert np.all((ratios > 7) & (ratios < 13)) and errors[-1] < 5e-6, errors   # ∝ 1/EI: no plateau, so → 0


def _static_elastic_coordinates(scene):
    """The state at rest under gravity, the joints held at zero: Newton on the elastic rows of k − q."""
    sim = Simulation(scene.spec)
    e = [i for i, c in enumerate(sim.coordinates) if c.startswith("forearm_link.q")]
    y = np.zeros(sim.npos)
    residual = lambda y: (lambda M, k, q: (k - q)[e])(*sim.engine.equations(0.0, np.concatenate([y, np.zeros(sim.nvel)])))
    for _ in range(3):
        J = np.column_stack([(residual(y + 1e-7 * np.eye(len(y))[i]) - residual(y)) / 1e-7 for i in e])
        y[e] -= np.linalg.solve(J, residual(y))
    return sim, np.zeros(sim.npos), y


def test_soft_forearm_sags_as_a_cantilever_under_its_weight_and_the_wrists():
    """UR5 at its zero configuration (arm horizontal): the static tip deflection of the soft forearm is the
    cantilever's w L⁴/8EI (own weight) + P L³/3EI (the wrist subtree's weight, at the tip) + P d L²/2EI (its moment
    about the tip, d = the subtree's centre of mass beyond the tip), mass and centre of mass from Pinocchio."""
    EI, g = 2e3, 9.81
    scene = _elastic_ur5(EI)
    sim, y, ys = _static_elastic_coordinates(scene)
    tip0, tip = (np.array([sim.output_values(np.concatenate([v, np.zeros(sim.nvel)]))[f"tip.r.{a}"] for a in "xyz"]) for v in (y, ys))
    pm = _pinocchio(UR5, "fixed")
    pd = pm.createData()
    pin.centerOfMass(pm, pd, np.zeros(pm.nq))
    wrist, elbow = pm.getJointId("wrist_1_joint"), pm.getJointId("elbow_joint")
    np.testing.assert_allclose(tip0, pd.oMi[wrist].translation, atol=1e-12)   # undeformed, the tip is the wrist joint
    along = (tip0 - pd.oMi[elbow].translation) / FOREARM_L
    assert abs(along[2]) < 1e-9 and abs(np.linalg.norm(along) - 1) < 1e-12  # a horizontal forearm of length L (the URDF rounds π/2)
    P, d = pd.mass[wrist] * g, (pd.oMi[wrist].act(pd.com[wrist]) - tip0) @ along   # com[i]: in joint i's frame
    L, w = FOREARM_L, FOREARM_M / FOREARM_L * g
    sag = w * L**4 / (8 * EI) + P * L**3 / (3 * EI) + P * d * L**2 / (2 * EI)
    np.testing.assert_allclose(tip0[2] - tip[2], sag, rtol=0.01)   # 4 modes of 8 elements: 0.4 % here
    assert abs((tip - tip0) @ along) < 1e-3 * sag   # inextensible axis: the tip moves across it only


def test_elastic_ur5_native_fmu_builds_and_validates(tmp_path):
    from fmpy.validation import validate_fmu
    fmu = mbsfmu.build_fmu(_elastic_ur5(1e3), tmp_path, kind="native")
    assert validate_fmu(str(fmu)) == []


def test_fixed_and_massless_links_match_pinocchio(tmp_path):
    """A fixed-base arm whose moving links hang on fixed ones (massive, rotated, massless, in a chain, one on the
    world): the engine's ÿ (its recursive path, fixed links welded to their carriers) against pin.aba on
    Pinocchio's own model of the URDF, which merges the fixed links itself."""
    joint = '<joint name="{n}" type="{t}"><parent link="{p}"/><child link="{c}"/><origin xyz="{xyz}" rpy="{rpy}"/>' \
            '<axis xyz="{a}"/></joint>'
    links = [_link("base", m=4), _link("l1", c="0.1 0 0.05"), _link("f1", m=0.7, c="0 0.05 0", rpy="0.3 0 0.2"),
             '<link name="f2"/>', _link("l2", m=1.1, c="0.2 0 0"), _link("f3", m=0.2, c="0.01 0 0"),
             _link("l3", m=0.5, c="0 0 0.1", ixx=0.01, iyy=0.02, izz=0.015), '<link name="f4"/>']
    joints = [("j1", "revolute", "base", "l1", "0 0 0.2", "0 0 0", "0 0 1"),
              ("w1", "fixed", "l1", "f1", "0.3 0 0", "0.5 -0.2 1.0", "1 0 0"),
              ("w2", "fixed", "f1", "f2", "0 0.1 0", "0 0.7 0", "1 0 0"),
              ("j2", "revolute", "f2", "l2", "0.1 0 0", "0 0 0", "0 1 0"),
              ("w3", "fixed", "l2", "f3", "0.4 0 0", "0.2 0 0", "1 0 0"),
              ("j3", "revolute", "f3", "l3", "0.05 0 0", "0 0 0", "1 0 0"),
              ("w4", "fixed", "l3", "f4", "0 0 0.2", "0 0 0", "1 0 0")]
    body = "\n".join(links + [joint.format(n=n, t=t, p=p, c=c, xyz=x, rpy=r, a=a) for n, t, p, c, x, r, a in joints])
    path = _urdf(tmp_path, body.replace('<axis xyz="1 0 0"/></joint>', "</joint>").replace(
        'type="revolute"', 'type="continuous"'))
    scene = mbsfmu.loads(f"mbsfmu: 1\nurdf: {{file: {path.name}}}\n", base=tmp_path)
    ev, sim = mbsfmu.compile(scene), Simulation(scene.spec)
    pm = pin.buildModelFromUrdf(str(path))
    pd, twin = pm.createData(), _Twin(ev, pm)
    rng = np.random.default_rng(1)
    for _ in range(3):
        y, yd, _ = _random_state(ev, rng)
        q, v, _, _ = twin.state(y, yd, np.zeros(len(yd)))
        ydd_p = pin.aba(pm, pd, q, v, np.zeros(pm.nv))[twin.P]
        np.testing.assert_allclose(sim.f(0.0, np.concatenate([y, yd]))[len(y):], ydd_p, rtol=0,
                                   atol=1e-12 * max(1.0, np.abs(ydd_p).max()))


# ---- issue 34: whole robots load; drawing never refuses them; trusted package folders; base=; limits -----------
TINY_BASES = [("anymal_b_simple_description/robots/anymal.urdf", "free"), ("b1_description/urdf/b1.urdf", "free"),
              ("go1_description/urdf/go1.urdf", "free"), ("hyq_description/robots/hyq_no_sensors.urdf", "free"),
              ("ur_description/urdf/ur5_robot.urdf", "free")]  # ur5: its root link is `world`, the free base its child


@pytest.mark.parametrize("file,base", TINY_BASES, ids=[Path(f).stem for f, _ in TINY_BASES])
def test_tiny_base_links_and_world_roots_float_as_pinocchio(file, base):
    """anymal's, b1's, go1's and hyq's base link of 1e-6 kg has the tensor 1e-6·ones (moments −2e-22, 8.5e-23, 3e-6:
    no rigid body's); welded to its trunk, the rigid group is physical: loaded without repair, and M, k, ÿ are
    Pinocchio's (which merges the group itself). ur5 given base='free' directly: its `world` link stays the
    world, base_link floats (Pinocchio: the free flyer on the root, world_joint welded)."""
    with pytest.warns(UserWarning) as notes:
        scene = mbsfmu.load(ROBOTS / file, base=base)
    if "ur5" not in file:
        # the tiny negative moment is roundoff of the eigen solver (-2.5e-22 or -2.0e-22, by machine): its size only
        assert any(re.search(r"principal moments -[0-9.]+e-22, ", str(n.message)) and "rigid group" in str(n.message)
                   for n in notes)
    assert not scene.repairs and scene.spec["bodies"][0]["joint"]["type"] == "free"
    _matches_pinocchio(mbsfmu.compile(scene), file, base)


def _matches_pinocchio(ev, file, base):
    pm = _pinocchio(file, base)
    pd, twin = pm.createData(), _Twin(ev, pm)
    assert sorted(twin.P) == list(range(pm.nv))
    rng = np.random.default_rng(7)
    for _ in range(2):
        y, yd, ydd = _random_state(ev, rng)
        q, v, a, T = twin.state(y, yd, ydd)
        damping = pm.damping * v
        tau = T.T @ (pin.rnea(pm, pd, q, v, a) + damping)
        M, k, qf = ev.equations(y, yd, 0.0)
        np.testing.assert_allclose(M @ ydd + k - qf, tau, rtol=0, atol=1e-10 * max(1.0, np.abs(tau).max()))
        Mp = pin.crba(pm, pd, q)
        np.testing.assert_allclose(M, T.T @ (np.triu(Mp) + np.triu(Mp, 1).T) @ T, rtol=0, atol=1e-10 * max(1.0, np.abs(M).max()))


def test_inertia_tolerance_is_relative_to_the_links_own_scale(tmp_path):
    """A link's inertia is taken as physical within 1e-6 of its own scale (its largest moment, or m·ℓ²): icub's
    point mass of moments −5.4e-20 (0.526 kg, 3 cm: scale 4.7e-4) is zero; a 1e-9 link breaking I1 + I2 >= I3 by
    80 % is refused, however small (an absolute floor of 1e-9 let it pass); alone on its joint, the 1e-6·ones
    tensor is refused too (no rigid group to carry it)."""
    def load(ixx, iyy, izz, m=0.526, c="0 0 0.03045", ixy=0):
        inertial = (f'<inertial><origin xyz="{c}"/><mass value="{m}"/><inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" '
                    f'ixy="{ixy}" ixz="{ixy}" iyz="{ixy}"/></inertial>')
        return mbsfmu.load(_urdf(tmp_path, _link("base") + f'<link name="arm">{inertial}</link>'
                                 '<joint name="j" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/></joint>'))
    arm = load(-5.42101e-20, -5.42101e-20, 0).spec["bodies"][1]
    assert np.abs(np.array(arm["inertia"])).max() <= 1e-19
    for args, what in (((1e-10, 1e-10, 1e-9), "triangle inequality"), ((1e-6, 1e-6, 1e-6, 1e-6, "0 0 0", 1e-6), "triangle inequality"),
                       ((-1e-9, 1e-9, 1e-9, 1e-3, "0 0 0"), "not positive semi-definite")):
        with pytest.raises(ModelError, match=r"robot.urdf:3: <inertia>: link 'arm': .*" + what):
            load(*args)


def test_rigid_group_carries_its_total_inertia_on_its_top_link(tmp_path):
    """The anymal numbers by hand: a 1e-6 kg base of tensor 1e-6·ones welded 0.1 m above a 5 kg trunk of
    diag(0.1, 0.2, 0.25): one body of 5.000001 kg at the mass-weighted centre, the tensor summed with the
    parallel-axis shifts (Steiner); the base's own entry is left empty."""
    base = ('<link name="base"><inertial><mass value="1e-6"/><inertia ixx="1e-6" ixy="1e-6" ixz="1e-6" iyy="1e-6" '
            'iyz="1e-6" izz="1e-6"/></inertial></link>')
    path = _urdf(tmp_path, base + _link("trunk", m=5) + '<joint name="w" type="fixed"><parent link="base"/><child link="trunk"/>'
                 '<origin xyz="0 0 -0.1"/></joint>')
    with pytest.warns(UserWarning, match=r"robot.urdf:3: link 'base': .*alone; the rigid group of 2 links"):
        b = mbsfmu.load(path, base="free").spec["bodies"]
    m1, m2, z2 = 1e-6, 5.0, -0.1
    c = m2 * z2 / (m1 + m2)
    I = 1e-6 * np.ones((3, 3)) + np.diag([0.1, 0.2, 0.25])
    I += m1 * (c * c * np.eye(3) - np.outer([0, 0, c], [0, 0, c])) + m2 * ((z2 - c) ** 2 * np.eye(3) - np.outer([0, 0, z2 - c], [0, 0, z2 - c]))
    assert b[0]["mass"] == pytest.approx(m1 + m2, rel=1e-15) and b[0]["center_of_mass"] == pytest.approx([0, 0, c], abs=1e-15)
    np.testing.assert_allclose(b[0]["inertia"], I, rtol=1e-13, atol=1e-19)
    assert b[1]["mass"] == 0 and not np.any(b[1]["inertia"])


def _tetra_stl(path):
    """A closed tetrahedron, faces wound outwards (signed volume +1/6)."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("solid t\n" + "".join("facet normal 0 0 0\nouter loop\n" + "".join(f"vertex {x} {y} {z}\n" for x, y, z in V[list(f)])
                                         + "endloop\nendfacet\n" for f in faces) + "endsolid t\n")


def _ros_layout(tmp_path, scale="1 1 1", extra_visual=""):
    """example-robot-data's layout: robots/arm_description/{urdf/arm.urdf, meshes/tetra.stl}, package:// names."""
    pkg = tmp_path / "robots/arm_description"
    _tetra_stl(pkg / "meshes/tetra.stl")
    (pkg / "urdf").mkdir()
    visual = f'<visual><geometry><mesh filename="package://arm_description/meshes/tetra.stl" scale="{scale}"/></geometry></visual>'
    return _urdf(pkg / "urdf", f'<link name="base">{_BOX.format(c="0 0 0", rpy="0 0 0", m=1, ixx=0.1, iyy=0.1, izz=0.1)}'
                 f'{visual}\n{extra_visual}</link>', name="arm.urdf")


def _signed_volume(tris):
    t = np.asarray(tris, float)
    return np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6


def test_mirrored_mesh_is_drawn_and_bad_visuals_never_refuse_the_robot(tmp_path):
    """scale="0.001 -0.001 0.001" (centauro, talos_reduced, tiago_dual) mirrors the mesh: drawn with its corners'
    order turned, so the closed surface still winds outwards (signed volume > 0, |det S| × 1/6). A zero scale or a
    negative box leaves that visual out with a note at its URDF line, on a direct load and through an overlay."""
    from mbsfmu.animation.drawing import shapes
    from mbsfmu.compiler.model import Model
    bad = '<visual><geometry>\n<mesh filename="package://arm_description/meshes/tetra.stl" scale="0 1 1"/></geometry></visual>' \
          '<visual><geometry><box size="1 -1 1"/></geometry></visual>'
    path = _ros_layout(tmp_path, "0.001 -0.001 0.001", bad)
    with pytest.warns(UserWarning, match=r"arm.urdf:5: <mesh>: scale=\"0 1 1\" has a zero factor.*arm.urdf:5: <box>: .*not positive"):
        scene = mbsfmu.load(path, package_dirs=["../.."])
    (mesh,) = scene.spec["bodies"][0]["shape"]
    assert mesh["scale"] == [0.001, -0.001, 0.001]
    tris = shapes(Model(scene.spec), 0, path.parent, scene.package_dirs)[0]["triangles"]
    assert _signed_volume(tris) == pytest.approx(1e-9 / 6, rel=1e-6)
    (path.parent / "over.yaml").write_text("mbsfmu: 1\nurdf: {file: arm.urdf, package_dirs: [../..]}\n")
    with pytest.warns(UserWarning, match=r"arm.urdf:5: <mesh>: scale"):
        assert mbsfmu.load(path.parent / "over.yaml").spec["bodies"][0]["shape"][0]["scale"] == [0.001, -0.001, 0.001]


def test_package_folders_outside_the_scene_folder_are_trusted_and_still_confined(tmp_path, capsys):
    """urdf/ beside meshes/: package_dirs the user names are trusted wherever they are, on a direct load and an
    overlay; the mesh is drawn from there (no copy under the scene). A package:// name leaving its package is not
    followed. An FMU's drawing names the package; `animate X.fmu` says how to give it (--scene --package-dir)."""
    from mbsfmu.cli import main
    path = _ros_layout(tmp_path)
    scene = mbsfmu.load(path, package_dirs=["../.."], base="free")
    assert scene.spec["bodies"][0]["shape"][0]["file"] == "package://arm_description/meshes/tetra.stl"
    page = mbsfmu.animate(scene, str(tmp_path / "a.html"), stop=0.05)
    assert "tetra.stl" in Path(page).read_text()
    (path.parent / "over.yaml").write_text("mbsfmu: 1\nurdf: {file: arm.urdf, package_dirs: [../..], base: free}\n")
    over = mbsfmu.load(path.parent / "over.yaml")
    assert over.spec["bodies"][0]["shape"] == scene.spec["bodies"][0]["shape"] and over.package_dirs == [tmp_path / "robots"]
    # the same name without its package folder: refused as a drawing, with the way to give it
    with pytest.raises(ModelError, match=r"no package folder holds the mesh 'package://arm_description/meshes/tetra.stl'.*--package-dir"):
        mbsfmu.loads("mbsfmu: 1\nname: m\nbodies: {b: {parent: world, joint: {type: fixed}, shape: {type: mesh, "
                     "file: 'package://arm_description/meshes/tetra.stl'}}}\n", base=tmp_path)
    with pytest.raises(ModelError, match=r"package folder 'nowhere' is not a folder"):
        mbsfmu.load(path, package_dirs=["nowhere"])
    fmu = mbsfmu.build_fmu(scene, tmp_path)
    assert main(["animate", str(fmu), "-o", str(tmp_path / "b.html"), "--stop", "0.05"]) == 1
    assert "--package-dir" in capsys.readouterr().err
    assert main(["animate", str(fmu), "--scene", str(path), "--package-dir", "../..", "--base", "free", "-o", str(tmp_path / "b.html"), "--stop", "0.05"]) == 0


def test_base_free_on_a_direct_load_and_the_command_line(tmp_path, capsys):
    """load(urdf, base='free') is the overlay's base: free; `--base free` on check; a YAML scene given a base is
    told where it goes; a world root holding a robot on a moving joint cannot float it."""
    from mbsfmu.cli import main
    path = _urdf(tmp_path, _link("base") + _link("arm") + '<joint name="j" type="revolute"><parent link="base"/><child link="arm"/>'
                 '<axis xyz="0 0 1"/></joint>')
    (tmp_path / "over.yaml").write_text("mbsfmu: 1\nurdf: {file: robot.urdf, base: free}\n")
    assert mbsfmu.load(path, base="free").spec == mbsfmu.load(tmp_path / "over.yaml").spec
    assert main(["check", "--base", "free", str(path)]) == 0 and "7 degrees of freedom" in capsys.readouterr().out
    assert main(["check", "--base", "free", str(tmp_path / "over.yaml")]) == 1
    assert "base is given for a URDF loaded directly" in capsys.readouterr().err
    world = _urdf(tmp_path, '<link name="world"/>' + _link("arm") + '<joint name="j" type="revolute"><parent link="world"/>'
                  '<child link="arm"/><axis xyz="0 0 1"/></joint>', name="w.urdf")
    with pytest.raises(ModelError, match=r"w.urdf:3: <joint>: joint 'j' \(revolute\) holds link 'arm' on the URDF's world link"):
        mbsfmu.load(world, base="free")


def test_fmu_attributes_are_never_nan(tmp_path):
    """A point mass whose tensor rounds to moments −5.4e-20 (icub's r_hip_2) gave the nominal √(tr I / 2m) = NaN;
    every real attribute of its modelDescription parses now as a finite number, and the writer refuses NaN."""
    import xml.etree.ElementTree as ET
    from mbsfmu.fmu.common import _fmt, model_description
    from mbsfmu.compiler.variables import variables
    scene = mbsfmu.loads("mbsfmu: 1\nname: point\nbodies:\n  b: {parent: world, joint: {type: revolute, axis: [1, 0, 0]}, mass: 0.526,\n"
                         "      center_of_mass: [0, 0, 0.03], inertia: {xx: -5.42101e-20, yy: -5.42101e-20, zz: 0}}\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the NaN came with a RuntimeWarning (invalid value in sqrt)
        listed = variables(scene.spec)
        xml = model_description(scene.spec, "point", listed, "1")
    # ℓ = the centre of mass's 0.03 m (the point mass has no radius of gyration), T = √(ℓ/g), g the default 9.81
    assert [v.nominal for v in listed if v.nominal] == pytest.approx([1.0, 1 / np.sqrt(0.03 / 9.81)], rel=1e-14)
    numbers = [v for e in ET.fromstring(xml).iter() for k, v in e.attrib.items()
               if e.tag == "DefaultExperiment" or e.tag == "Real" and k in ("start", "nominal", "min", "max")]
    assert any(e.get("nominal") for e in ET.fromstring(xml).iter("Real"))
    assert numbers and all(np.isfinite(float(v)) for v in numbers)
    with pytest.raises(ValueError, match="non-finite"):
        _fmt(float("nan"))


@pytest.mark.slow
def test_a_chain_of_the_documented_10000_links_loads_and_one_more_is_refused(tmp_path):
    """docs: URDFs of up to 10,000 links. The element cap is derived from it (limits.URDF_ELEMENTS =
    ENTRIES × URDF_ELEMENTS_PER_LINK): a plain chain (12 elements a link with its <limit>) of 10,000 loads, in a
    child process whose CPU time and peak memory are bounded; 10,001 links are refused by their count."""
    import subprocess
    import sys
    from mbsfmu import limits
    link = ('<link name="l{i}"><inertial><origin xyz="0 0 0.05"/><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.001" '
            'ixy="0" ixz="0" iyz="0"/></inertial></link>')
    joint = ('<joint name="j{i}" type="revolute"><origin xyz="0 0 0.1"/><parent link="l{p}"/><child link="l{i}"/>'
             '<axis xyz="1 0 0"/><limit effort="1" velocity="1" lower="-1" upper="1"/></joint>')
    for n in (limits.ENTRIES, limits.ENTRIES + 1):
        (tmp_path / f"c{n}.urdf").write_text('<robot name="chain">' + "".join(link.format(i=i) + (joint.format(i=i, p=i - 1) if i else "")
                                                                            for i in range(n)) + "</robot>")
    assert 12 * limits.ENTRIES <= limits.URDF_ELEMENTS
    code = ("import resource, sys, time, mbsfmu\nt = time.process_time()\ns = mbsfmu.load(sys.argv[1])\n"
            "print(len(s.spec['bodies']), time.process_time() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / f"c{limits.ENTRIES}.urdf")], capture_output=True, text=True,
                         env={**__import__("os").environ, "PYTHONPATH": str(Path(mbsfmu.__file__).parents[1])}, timeout=300)
    n, cpu, rss_kb = out.stdout.split()
    assert int(n) == limits.ENTRIES and float(cpu) < 60 and int(rss_kb) < 1_000_000, out.stdout
    t0 = time.process_time()
    with pytest.raises(ModelError, match=r"more than 10,000 links"):
        mbsfmu.load(tmp_path / f"c{limits.ENTRIES + 1}.urdf")
    assert time.process_time() - t0 < 10


# every URDF of example-robot-data: loads as it is, meshes drawn from its package folder, or one documented refusal
REFUSED = {"alex_psyonic_hands": "mimics joint", "baxter": "mimics joint", "panda": "mimics joint", "panda_collision": "mimics joint",
           "pr2": "mimics joint", "talos_full_v2": "mimics joint", "talos_full_v2_box": "mimics joint", "tiago_pro": "mimics joint",
           "romeo": "no mass or inertia", "romeo_laas_small": "no mass or inertia",  # repair merges the fingers
           "romeo_small": "triangle inequality",  # repair projects it
           "ur3": r"no <link> in the robot"}  # ur3.urdf is an empty wrapper (ur3_robot.urdf is the robot)


def test_every_example_robot_loads_with_its_meshes_or_is_refused_as_documented():
    files = sorted(ROBOTS.rglob("*.urdf"))
    assert len(files) >= 69
    loaded = 0
    for f in files:
        with _notes() as notes:
            try:
                scene = mbsfmu.load(f, package_dirs=[ROBOTS.parent.parent])  # share/: package://example-robot-data/...
            except ModelError as e:
                assert f.stem in REFUSED and re.search(REFUSED[f.stem], str(e)) and str(e).startswith(f"{f}:"), str(e)
                continue
        assert f.stem not in REFUSED, f
        assert not [n for n in notes if "not drawn" in str(n.message)], f  # every visual mesh found, in its package
        assert scene.spec["bodies"] and not scene.repairs
        loaded += 1
    assert loaded == len(files) - len(REFUSED)


@contextlib.contextmanager
def _notes():
    """The warnings given inside, every one (not once per place)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield caught


def test_an_overlays_errors_in_the_urdf_name_the_urdf_and_its_line(tmp_path):
    """A problem the scene's checker finds in what the URDF gave (a mass of 1e-200 kg) names the URDF's file and
    the link's line, through an overlay too (it named the YAML's `urdf:` line); the overlay's own keys its own."""
    _urdf(tmp_path, _link("base") + "\n" + _link("arm", m="1e-200") +
          '<joint name="j" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/></joint>')
    (tmp_path / "s.yaml").write_text("mbsfmu: 1\nurdf: {file: robot.urdf}\n")
    with pytest.raises(ModelError, match=r"robot.urdf:4: bodies.arm.mass: 1e-200 is outside"):
        mbsfmu.load(tmp_path / "s.yaml")
    (tmp_path / "s.yaml").write_text("mbsfmu: 1\nurdf: {file: robot.urdf}\nbodies:\n  arm: {mass: -1}\n")
    with pytest.raises(ModelError, match=r"s.yaml:4: bodies.arm.mass: must not be negative"):
        mbsfmu.load(tmp_path / "s.yaml")
