"""Dynamics of whole trees (issue 26), whatever algorithm the engine runs for them: its ÿ (the right-hand side
in process) and its M, k, q against the numpy reference of the seed equations (ÿ = M⁻¹(q − k)) on random trees
of every joint type with branching, drives, every force element, inputs and elastic bodies (beam and nodal, in
the middle of chains and at leaves); rigid random trees against Pinocchio's aba and rnea; every URDF of
example-robot-data against Pinocchio's aba, rnea and crba; a long chain stepped within a memory bound, its ÿ
held by an O(N) Newton–Euler residual."""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import mbsfmu
from mbsfmu.engine import layout as L
from mbsfmu.kinematics.joints import JOINTS as TABLE, joint_type
from mbsfmu.simulation import Simulation

JOINTS = list(TABLE)  # (joint type, parameterization or None): every row of the joint table
DRIVE = "{a}*sin({w}*t + {p})"  # a rheonomic drive: position, velocity and acceleration all vary with t


def _vec(rng, scale=1.0):
    return (rng.normal(size=3) * scale).round(4).tolist()


def _inertia(rng):
    """A physical inertia tensor: that of a few point masses about their centre, plus a little on the diagonal."""
    pts = rng.normal(size=(4, 3)) * 0.3
    pts -= pts.mean(axis=0)
    return (sum(r @ r * np.eye(3) - np.outer(r, r) for r in pts) + 0.02 * np.eye(3)).round(5).tolist()


def _joint(rng, kind, param):
    """A joint of the table's row (kind, param) with random axes (as its axes rule asks), offset and rotation."""
    row = TABLE[(kind, param)]
    j = {"type": kind, "at": _vec(rng, 0.3), "rotation": {"axis": _vec(rng), "angle": round(float(rng.uniform(-3, 3)), 4)}}
    if "axis" in row.fields:
        j["axis"] = _vec(rng)
    elif row.axes_rule == L.R_PERPENDICULAR:
        a, b = np.linalg.qr(rng.normal(size=(3, 2)))[0].T.round(6)
        j["axes"] = [a.tolist(), np.cross(np.cross(a, b), a).tolist()]  # perpendicular once rounded
    elif "axes" in row.fields:
        j["axes"] = [_vec(rng), _vec(rng)]
    if param:
        j["parameterization"] = param
    return j


def _nodal(rng, N, n):
    """Random elastic data of N nodes and n modes (positive stiffness, node inertias, rotational shapes)."""
    A, D = rng.normal(size=(n, n)), rng.normal(size=(n, n))
    return {"R_RP": (rng.normal(size=(N, 3)) * 0.3).tolist(), "mass": rng.uniform(0.2, 1.0, N).tolist(),
            "Phi": (0.1 * rng.normal(size=(N, 3, n))).tolist(), "Psi": (0.1 * rng.normal(size=(N, 3, n))).tolist(),
            "inertia": [(0.1 * np.array(_inertia(rng))).tolist() for _ in range(N)],
            "stiffness": (A @ A.T + n * np.eye(n)).tolist(), "damping": (0.1 * D @ D.T).tolist()}


BEAM = {"beam": {"length": 0.6, "EI": 40.0, "rhoA": 0.5, "elements": 3, "modes": 2, "clamped": "start"}}


def _modal(body, n):
    """Names of elastic coordinates (the default b.q1 … would meet a quaternion joint's b.q1 … on the same body)."""
    return [f"{body}.e{k + 1}" for k in range(n)]


def _suffixes(kind, param):
    """Suffixes of a joint's coordinates that joint springs may name (not quaternion ones)."""
    row = TABLE[(kind, param)]
    quat = range(len(row.positions))[row.quaternion] if row.quaternion else ()
    return [c for i, c in enumerate(row.positions) if i not in quat]


def random_tree(seed, n=12, rigid=False, forces=True, drives=True, gravity=True):
    """A scene (dict) of a random tree of n bodies: every joint type (shuffled, cycling); each body hangs from
    the previous one (a chain) or, one time in three, from an earlier one (a branch); joint frames turned and
    offset; full inertia tensors. Unless rigid: a nodal elastic body in the middle of the chain (the next body
    hangs from one of its nodes) and an elastic beam as the last body (a leaf). Drives on about a third of the
    joints that can have one, force elements of every kind (at nodes on elastic bodies), a force and a torque
    input; gravity a random vector or none."""
    rng = np.random.default_rng(seed)
    kinds = [JOINTS[k] for k in rng.permutation(len(JOINTS))]
    mid = -1 if rigid else n // 2
    bodies, nodes = {}, {}  # nodes: elastic body → its number of nodes
    for i in range(n):
        name = f"b{i}"
        if i == 0:
            parent = "world"
        elif i - 1 == mid or rng.uniform() < 0.67:
            parent = f"b{i - 1}"
        else:
            parent = f"b{rng.integers(0, i)}"
        kind, param = kinds[i % len(kinds)]
        if i == 0 and not TABLE[(kind, param)].nvel:
            kind, param = kinds[(i + 1) % len(kinds)]  # the root must move
        body = {"parent": parent, "joint": _joint(rng, kind, param)}
        if parent in nodes:  # on an elastic body: at one of its nodes
            del body["joint"]["at"]
            body["joint"]["node"] = int(rng.integers(0, nodes[parent]))
        if i == mid:
            N, modes = int(rng.integers(3, 6)), int(rng.integers(1, 4))
            body["elastic"] = {"nodal": _nodal(rng, N, modes), "coordinates": _modal(name, modes)}
            nodes[name] = N
        elif i == n - 1 and not rigid:
            body["elastic"] = {**BEAM, "coordinates": _modal(name, BEAM["beam"]["modes"])}
            nodes[name] = BEAM["beam"]["elements"] + 1
        else:
            body.update(mass=round(float(rng.uniform(0.5, 3)), 4), center_of_mass=_vec(rng, 0.3), inertia=_inertia(rng))
        drivable = [] if TABLE[(kind, param)].quaternion else _suffixes(kind, param)  # the loader refuses drives there
        if drives and drivable and rng.uniform() < 0.35:
            c = f"{name}.{drivable[rng.integers(0, len(drivable))]}"
            body["joint"]["drive"] = {c: DRIVE.format(a=round(float(rng.uniform(0.2, 0.8)), 3),
                                                      w=round(float(rng.uniform(0.5, 3)), 3), p=round(float(rng.uniform(0, 3)), 3))}
        bodies[name] = body
    scene = {"mbsfmu": 1, "name": f"random_tree_{seed}", "gravity": _vec(rng, 5) if gravity else [0, 0, 0],
             "bodies": bodies}
    if forces:
        scene["forces"] = _forces(rng, bodies, nodes)
    return scene


def _forces(rng, bodies, nodes):
    """Every force element kind, with constant values, expressions in t and inputs; at nodes of elastic bodies."""
    names = list(bodies)

    def point(b):  # where a force acts: a node of an elastic body, else a point of the body
        return {"node": int(rng.integers(0, nodes[b]))} if b in nodes else {"at": _vec(rng, 0.2)}

    def node0(*bs):  # springs: node 0 on elastic ends (null on rigid ones)
        return {"node": [0 if b in nodes else None for b in bs]} if any(b in nodes for b in bs) else {}
    a, b = (str(x) for x in rng.choice(names, 2, replace=False))
    out = [{"type": "spring_damper", "bodies": ["world", a], "at": [_vec(rng), [0, 0, 0]], "stiffness": 30.0,
            "damping": 0.8, "length": 0.4, **node0("world", a)},
           {"type": "spring_damper", "bodies": [a, b], "stiffness": 12.0, "damping": 0.3, "length": 0.1, **node0(a, b)}]
    springy = [f"{name}.{c}" for name, body in bodies.items()
               for c in _suffixes(body["joint"]["type"], body["joint"].get("parameterization"))
               if f"{name}.{c}" not in body["joint"].get("drive", {})]
    for c in rng.choice(springy, min(3, len(springy)), replace=False):
        out.append({"type": "joint_spring_damper", "coordinate": str(c), "stiffness": round(float(rng.uniform(1, 50)), 3),
                    "damping": round(float(rng.uniform(0, 2)), 3), "offset": round(float(rng.uniform(-0.5, 0.5)), 3)})
    f, g, h, k = (str(x) for x in rng.choice(names, 4))
    out += [{"type": "force", "body": f, "frame": "world", "value": ["sin(t)", 0.5, "2*cos(3*t)"], **point(f)},
            {"type": "force", "body": g, "frame": "body", "input": "F_in", **point(g)},
            {"type": "torque", "body": h, "frame": "body", "value": _vec(rng), **({"node": 0} if h in nodes else {})},
            {"type": "torque", "body": k, "frame": "world", "input": "T_in", **({"node": 0} if k in nodes else {})}]
    return out


def random_state(ev, rng, elastic=0.1):
    """Joint coordinates uniform in ±1 (quaternions normalized), elastic ones in ±`elastic`, velocities in ±1."""
    modal = {c for b in ev.model.spec["bodies"] if b["elastic"] for c in b["elastic"]["coordinates"]}
    y = np.array([rng.uniform(-elastic, elastic) if c in modal else rng.uniform(-1, 1) for c in ev.coordinates])
    for qi in ev.model.quaternions:
        y[qi] /= np.linalg.norm(y[qi])
    return y, rng.uniform(-1, 1, len(ev.velocity_coordinates))


def solve_tolerance(M, rtol):
    """Two backward-stable solves of M ÿ = r differ by up to about ε·cond(M) relative: rtol, or that when larger."""
    return max(rtol, 4e-16 * np.linalg.cond(M))


def assert_close(ours, ref, rtol, what):
    err = np.max(np.abs(ours - ref)) / max(np.max(np.abs(ref)), 1e-300)
    assert err <= rtol, f"{what}: relative difference {err:.2e} > {rtol:.1e}"


# ---- the engine against the numpy reference --------------------------------------------------------------
def compare_with_reference(scene, seed, states=3):
    """At random states, times and inputs: the engine's M, k, q (mbs_equations) and its ÿ (the right-hand side,
    mbs_rhs) against the reference's M, k, q and ÿ = M⁻¹(q − k)."""
    spec = mbsfmu.loads(json.dumps(scene)).spec
    ev, sim = mbsfmu.compile(spec), Simulation(spec)
    rng = np.random.default_rng(seed)
    for _ in range(states):
        y, yd = random_state(ev, rng)
        t = float(rng.uniform(0, 3))
        u = {name: float(rng.normal()) for name in ev.inputs}
        for name, value in u.items():
            sim.set(name, value)
        x = np.r_[y, yd]
        M, k, q = ev.equations(y, yd, t, u)
        for ours, ref, what in zip(sim.engine.equations(t, x), (M, k, q), "Mkq"):
            assert_close(ours, ref, 1e-12, what)
        ydd = sim.f(t, x)[len(y):]
        assert_close(ydd, np.linalg.solve(M, q - k), solve_tolerance(M, 1e-12), "ÿ")
    return ev


@pytest.mark.parametrize("seed", range(8))
def test_random_tree_with_elastic_bodies_matches_the_reference(seed):
    scene = random_tree(seed, n=8 + seed, gravity=seed % 3 != 2)
    ev = compare_with_reference(scene, seed)
    kinds = {joint_type(b.kind, b.param) for b in ev.model.bodies}
    assert sum(1 for b in ev.model.bodies if b.elastic) == 2 and len(kinds) >= min(8 + seed, len(JOINTS)) - 1


@pytest.mark.parametrize("seed", range(4))
def test_random_rigid_tree_matches_the_reference(seed):
    compare_with_reference(random_tree(100 + seed, n=10 + 4 * seed, rigid=True, gravity=seed % 2 == 0), seed)


# ---- against Pinocchio -----------------------------------------------------------------------------------
pin = pytest.importorskip("pinocchio")
from benchmarks import tree_speed  # noqa: E402
from pinocchio_twin import from_pin_acceleration, pinocchio_model, to_pin  # noqa: E402


def engine_ydd(sim, y, yd, t=0.0):
    return sim.f(t, np.r_[y, yd])[len(y):]


@pytest.mark.parametrize("seed", range(6))
def test_random_rigid_tree_matches_pinocchio(seed):
    """Rigid random trees of every joint type (no drives, no force elements: Pinocchio has neither): the engine's
    ÿ against pin.aba (free joints as composites with our coordinates, and as Pinocchio's free flyer), its M
    and k − q against pin.rnea (M column by column: Pinocchio 4.1's crba is wrong on composite joints, whose
    aba and rnea are right; the robots' test below holds M against crba)."""
    scene = random_tree(200 + seed, n=10 + 3 * seed, rigid=True, forces=False, drives=False, gravity=seed % 3 != 2)
    spec = mbsfmu.loads(json.dumps(scene)).spec
    ev, sim = mbsfmu.compile(spec), Simulation(spec)
    rng = np.random.default_rng(seed)
    models = {flyer: pinocchio_model(ev, free_flyer=flyer) for flyer in (False, True)}
    for _ in range(3):
        y, yd = random_state(ev, rng)
        ydd = engine_ydd(sim, y, yd)
        M, k, q = sim.engine.equations(0.0, np.r_[y, yd])
        for flyer, pm in models.items():
            pd = pm.createData()
            qp, vp, _, P = to_pin(ev, y, yd, free_flyer=flyer)
            a = from_pin_acceleration(ev, y, vp, pin.aba(pm, pd, qp, vp, np.zeros(pm.nv)), P, free_flyer=flyer)
            assert_close(ydd, a, solve_tolerance(M, 1e-10), f"ÿ (free flyer: {flyer})")
        qp, vp, _, P = to_pin(ev, y, yd)
        pm, pd = models[False], models[False].createData()
        zero = np.zeros(pm.nv)
        bias = pin.rnea(pm, pd, qp, zero, zero)
        Mp = np.array([pin.rnea(pm, pd, qp, zero, e) - bias for e in np.eye(pm.nv)]).T
        assert_close(M, Mp[np.ix_(P, P)], 1e-10, "M")
        assert_close(k - q, pin.rnea(pm, pd, qp, vp, zero)[P], 1e-10, "k − q")


ROBOT_FILES = tree_speed.robot_files()


@pytest.mark.skipif(not ROBOT_FILES, reason="example-robot-data is not installed")
@pytest.mark.parametrize("file", ROBOT_FILES, ids=[f.split("/")[-1][:-5] for f in ROBOT_FILES])
def test_example_robot_matches_pinocchio_aba(file):
    """Every URDF of example-robot-data as the benchmark loads it (floating base for the ones that stand, walk or
    fly; repaired where the plain load refuses): the engine's ÿ against pin.aba of the same tree with the URDF's
    joint damping as τ = −d q̇, the residual rnea(q, v, ÿ) − τ = 0 (backward error, whatever cond(M)), and M
    against pin.crba (fixed bases: on a floating base Pinocchio's linear velocity is in the body frame).
    The scene format refuses only robots with <mimic> joints (closed constraints) and a file without links."""
    from mbsfmu.errors import ModelError
    try:
        scene, _ = tree_speed.load_robot(file)
    except ModelError as e:
        assert "<mimic>" in str(e) or "no <link>" in str(e), str(e)
        return
    ev, sim = mbsfmu.compile(scene), Simulation(scene.spec)
    pm = pinocchio_model(ev, free_flyer=True)
    pd = pm.createData()
    rng = np.random.default_rng(len(file))
    for _ in range(2):
        y, yd = random_state(ev, rng)
        ydd = engine_ydd(sim, y, yd)
        qp, vp, _, P = to_pin(ev, y, yd, free_flyer=True)
        tau = tree_speed.joint_dampers(ev, yd, P, pm.nv)
        a = pin.aba(pm, pd, qp, vp, tau)
        M, _, _ = sim.engine.equations(0.0, np.r_[y, yd])
        assert_close(ydd, from_pin_acceleration(ev, y, vp, a, P, free_flyer=True), solve_tolerance(M, 1e-10), "ÿ")
        _, _, a_ours, _ = to_pin(ev, y, yd, ydd, free_flyer=True)
        residual = pin.rnea(pm, pd, qp, vp, a_ours) - tau
        assert np.max(np.abs(residual)) <= 1e-10 * max(1.0, np.max(np.abs(M)) * np.max(np.abs(ydd))), "rnea residual"
        if tree_speed.base_of(file) == "fixed":
            Mp = pin.crba(pm, pd, qp)
            assert_close(M, (np.triu(Mp) + np.triu(Mp, 1).T)[np.ix_(P, P)], 1e-10, "M")


# ---- a long chain ----------------------------------------------------------------------------------------
# Issue 26: a 10,000-body chain compiles and steps within 200 MB: the recursive path (engine/dynamics.c, linear
# in the bodies) steps it. (Not Pinocchio as the reference here: its Data of an N-chain takes O(N³) memory,
# 0.5 GB at N = 200.)
LONG_CHAIN = 10_000
MEMORY_MB = 200
STEPS, H = 10, 1e-3
_CHILD = """
import json, sys
import numpy as np
from benchmarks.tree_speed import chain_scene, peak_rss_mb, reset_peak_rss, rss_mb
from mbsfmu.simulation import Simulation
n, steps, h = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
spec = chain_scene(n).spec
before = rss_mb()
reset_peak_rss()
sim = Simulation(spec)
sim.set("integrator.method", "rk4")
sim.set("integrator.step", h)
sim.initialize(0.0)
states = [sim.x.copy()]
for k in range(steps):
    sim.do_step(k * h, h)
states.append(sim.x.copy())
print(json.dumps({"grown_mb": peak_rss_mb() - before, "x": [x.tolist() for x in states],
                  "xdot": [sim.f(t, x).tolist() for t, x in zip((0.0, steps * h), states)]}))
"""


def chain_rnea(ev, y, yd, ydd):
    """τ = M ÿ + k − q of a chain of revolute joints without joint rotations, under gravity alone: the
    recursive Newton–Euler equations in world coordinates, O(N) (Luh, Walker & Paul 1980)."""
    from scipy.spatial.transform import Rotation
    R, o, w, dw, ao = np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    g, links = ev.model.g, []
    for i, b in enumerate(ev.model.bodies):
        p = o + R @ b.at  # the joint point: this body's origin
        ao = ao + np.cross(dw, p - o) + np.cross(w, np.cross(w, p - o))
        z = R @ b.joint.a
        dw = dw + z * ydd[i] + np.cross(w, z) * yd[i]  # ż = ω_parent × z
        w = w + z * yd[i]
        R, o = R @ Rotation.from_rotvec(b.joint.a * y[i]).as_matrix(), p
        r, I = R @ b.c, R @ b.I @ R.T
        ac = ao + np.cross(dw, r) + np.cross(w, np.cross(w, r))
        links.append((o, z, r, b.m * (ac - g), I @ dw + np.cross(w, I @ w)))
    tau, F, M, p_child = np.zeros(len(links)), np.zeros(3), np.zeros(3), np.zeros(3)
    for i in reversed(range(len(links))):  # force and moment about the joint point that body i passes inwards
        o, z, r, f, n = links[i]
        F, M = f + F, n + np.cross(r, f) + M + np.cross(p_child - o, F)
        tau[i], p_child = z @ M, o
    return tau


def test_chain_rnea_is_pinocchios():
    ev = mbsfmu.compile(tree_speed.chain_scene(15))
    pm = pinocchio_model(ev)
    rng = np.random.default_rng(5)
    y, yd, ydd = (rng.uniform(-1, 1, 15) for _ in range(3))
    assert_close(chain_rnea(ev, y, yd, ydd), pin.rnea(pm, pm.createData(), y, yd, ydd), 1e-12, "τ")


def test_long_chain_steps_within_its_memory_bound():
    """A random revolute chain compiled and stepped (rk4) in a fresh process: the peak resident set grows by at
    most MEMORY_MB over the process with the scene loaded (the loader's Python objects are not the engine's:
    about 300 MB for 10,000 bodies); the engine's ÿ at the first and the last state
    satisfies the equations of motion, τ = rnea(y, ẏ, ÿ) = 0 (backward error: whatever cond(M)), and the
    steps moved the chain."""
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(_CHILD), str(LONG_CHAIN), str(STEPS), str(H)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    got = json.loads(r.stdout)
    assert got["grown_mb"] <= MEMORY_MB, f"{LONG_CHAIN} bodies: the resident set grew by {got['grown_mb']:.0f} MB"
    ev = mbsfmu.compile(tree_speed.chain_scene(LONG_CHAIN))
    n = len(ev.coordinates)
    for x, xdot in zip(got["x"], got["xdot"]):
        y, yd, ydd = np.array(x[:n]), np.array(x[n:]), np.array(xdot[n:])
        scale = max(m.m for m in ev.model.bodies) * 9.81 * 0.1 * n * n  # the size of the gravity torques at the root
        assert np.max(np.abs(chain_rnea(ev, y, yd, ydd))) <= 1e-11 * scale  # ÿ off by 1e-10 relative leaves 7e-11
    assert np.max(np.abs(np.subtract(got["x"][1], got["x"][0]))) > 1e-3
