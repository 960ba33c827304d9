"""The engine's recursive path for rigid scenes (engine/dynamics.c, issue 26): ÿ by the articulated-body algorithm,
M by the composite-rigid-body algorithm, k and q by the recursive Newton–Euler pass, held against the numpy
reference of the seed equations (equations/tree.py: dense M, k, q, solved by LAPACK) on random trees of every
joint type with branching, drives, every force element and input; and a 10,000-body chain in bounded memory."""

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.compiler.scene_file import carriers, dense_path
from mbsfmu.engine import layout as L
from mbsfmu.simulation import Simulation

REPO = Path(__file__).resolve().parent.parent

# (type, parameterization, coordinate a drive may prescribe, a plain coordinate a joint spring may act on)
JOINTS = [("revolute", None, "angle", "angle"), ("prismatic", None, "s", "s"), ("cylindrical", None, "s", "angle"),
          ("universal", None, "angle1", "angle2"), ("planar", None, "x", "angle"), ("spherical", "quaternion", None, None),
          ("spherical", "cardan", "b", "a"), ("free", "quaternion", None, "x"), ("free", "cardan", "z", "c"),
          ("fixed", None, None, None)]


def _vec(v):
    return "[" + ", ".join(f"{x:.5f}" for x in v) + "]"


def random_tree(rng, n, gravity=True, origin=(0, 0, 0), light_from=None):
    """YAML of a random tree of n bodies cycling through every joint type (both parameterizations), branching,
    rotated joint frames, full inertias; drives on some joints, joint springs, springs between bodies and to the
    world, forces and torques constant, of time and as inputs, in both frames. The root's joint is at `origin`
    (plus a little); bodies from `light_from` on have 1e-4 of the mass, 1e-8 of the inertia."""
    lines = ["mbsfmu: 1", "name: random_tree", f"gravity: {_vec([0.3, -1.2, -9.81] if gravity else [0, 0, 0])}",
             "bodies:"]
    springs = []
    for i in range(n):
        kind, param, driven, plain = JOINTS[(i + int(rng.integers(len(JOINTS)))) % len(JOINTS)]
        parent = "world" if i == 0 else f"b{rng.integers(max(0, i - 3), i)}"  # branching
        pts = rng.normal(size=(4, 3)) * 0.3  # the inertia of point masses about their centre: physical by construction
        pts -= pts.mean(axis=0)
        inertia = sum(np.dot(r, r) * np.eye(3) - np.outer(r, r) for r in pts) + 0.01 * np.eye(3)
        j = f"type: {kind}, at: {_vec(rng.normal(size=3) * 0.3 + (origin if i == 0 else 0))}, " \
            f"rotation: {{axis: {_vec(rng.normal(size=3))}, angle: {rng.uniform(-3, 3):.4f}}}"
        if kind in ("revolute", "prismatic", "cylindrical"):
            j += f", axis: {_vec(rng.normal(size=3))}"
        elif kind == "universal":
            j += f", axes: [{_vec(rng.normal(size=3))}, {_vec(rng.normal(size=3))}]"
        elif kind == "planar":  # perpendicular in-plane axes; the rotated joint frame turns the plane
            j += ", axes: [[0, 0.6, 0.8], [0, -0.8, 0.6]]"
        if param:
            j += f", parameterization: {param}"
        if driven and rng.uniform() < 0.4:
            j += f", drive: {{b{i}.{driven}: \"0.3*sin(2*t) + 0.1*t\"}}"
        elif plain and rng.uniform() < 0.5:
            springs.append(f"  - {{type: joint_spring_damper, coordinate: b{i}.{plain}, stiffness: 30, damping: 0.4, "
                           f"offset: 0.1}}")
        light = light_from is not None and i >= light_from
        lines += [f"  b{i}:", f"    parent: {parent}", f"    joint: {{{j}}}",
                  f"    mass: {rng.uniform(0.5, 3) * (1e-4 if light else 1):.6g}",
                  f"    center_of_mass: {_vec(rng.normal(size=3) * (1e-4 if light else 0.3))}",
                  f"    inertia: {(inertia * (1e-8 if light else 1)).round(14 if light else 6).tolist()}"]
    a, b = rng.choice(n, 2, replace=False)
    lines += ["forces:", *springs,
              f"  - {{type: spring_damper, bodies: [world, b{a}], at: [[0, 0, 1], [0.1, 0, 0]], stiffness: 20, "
              "damping: 0.5, length: 0.4}",
              f"  - {{type: spring_damper, bodies: [b{a}, b{b}], at: [[0, 0.1, 0], [0, 0, 0.1]], stiffness: 15, "
              "damping: 0.2, length: 0.1}",
              f"  - {{type: force, body: b{b}, at: [0, 0.1, 0], frame: body, value: [\"sin(t)\", 0, 2]}}",
              f"  - {{type: force, body: b{a}, at: [0.2, 0, 0.1], frame: world, input: F_a}}",
              f"  - {{type: torque, body: b{b}, frame: world, value: [0.1, -0.2, 0.3]}}",
              f"  - {{type: torque, body: b{a}, frame: body, input: T_a}}"]
    return "\n".join(lines)


def _state(ev, rng):
    y = rng.normal(size=len(ev.coordinates)) * 0.5
    for qi in ev.model.quaternions:
        y[qi] /= np.linalg.norm(y[qi])
    return y, rng.normal(size=len(ev.velocity_coordinates))


@pytest.mark.parametrize("seed", range(8))
def test_accelerations_equal_the_reference_on_random_trees_of_every_joint_type(seed):
    """ÿ of the engine's right-hand side (ABA) against M⁻¹(q − k) of the numpy reference, and M, k, q of the
    engine (CRBA, RNEA) against the reference's, at random states, times and inputs, with gravity and without."""
    rng = np.random.default_rng(seed)
    spec = mbsfmu.loads(random_tree(rng, int(rng.integers(8, 16)), gravity=seed % 2 == 0)).spec
    ev, sim = mbsfmu.compile(spec), Simulation(spec)
    assert not dense_path(ev.model, carriers(ev.model))  # the scene is on the recursive path
    for t in (0.0, 0.37, 1.9):
        y, yd = _state(ev, rng)
        u = {n: rng.normal() for n in ev.inputs}
        for name, value in u.items():
            sim.set(name, value)
        M, k, q = ev.equations(y, yd, t, u)
        x = np.concatenate([y, yd])
        M2, k2, q2 = sim.engine.equations(t, x)
        scale = max(1.0, np.abs(M).max(), np.abs(k).max(), np.abs(q).max())
        for want, got in ((M, M2), (k, k2), (q, q2)):
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * scale)
        ydd = np.linalg.solve(M, q - k)
        got = sim.f(t, x)
        np.testing.assert_allclose(got[len(y):], ydd, rtol=0, atol=1e-12 * np.linalg.cond(M) * np.abs(ydd).max())
        np.testing.assert_allclose(got[:len(y)], ev.position_rates(y, yd), rtol=1e-15, atol=1e-15)


@pytest.mark.parametrize("seed", (5, 6, 7))
def test_small_links_far_from_the_world_origin_keep_their_digits(seed):
    """A random tree 1 km from the world origin whose last bodies are 10⁴ times lighter and 10⁸ times less inert,
    their centres of mass on their joints (cond(M) ≈ 1e10): the engine's ÿ solves the reference's M ÿ = q − k
    with a small componentwise backward error (Oettli–Prager: each row against its own terms), since the recursive
    path takes inertias about each body's origin. About the world origin the 10⁶ m² lever arms swamp the small
    links' pivots: 4e-6 here (and iCub, 0.6 m from it, got a negative pivot)."""
    rng = np.random.default_rng(seed)
    spec = mbsfmu.loads(random_tree(rng, 12, origin=[1000, -700, 300], light_from=6)).spec
    ev, sim = mbsfmu.compile(spec), Simulation(spec)
    for _ in range(3):
        y, yd = _state(ev, rng)
        M, k, q = ev.equations(y, yd, 0.3)
        got = sim.f(0.3, np.concatenate([y, yd]))[len(y):]
        backward = np.abs(M @ got - (q - k)) / (np.abs(M) @ np.abs(got) + np.abs(q - k))
        assert backward.max() < 1e-11


def test_random_trees_cover_every_joint_type_drives_and_forces():
    """The generator above reaches every joint type and parameterization, drives and every force element."""
    seen, forces, drives = set(), set(), 0
    for seed in range(8):
        rng = np.random.default_rng(seed)
        spec = mbsfmu.loads(random_tree(rng, int(rng.integers(8, 16)), gravity=seed % 2 == 0)).spec
        for b in spec["bodies"]:
            seen.add((b["joint"]["type"], b["joint"].get("parameterization")))
            drives += bool(b["joint"]["drive"])
        forces |= {f["type"] for f in spec["forces"]}
    assert {(k, p) for k, p, _, _ in JOINTS} <= {(k, p if k in ("spherical", "free") else None) for k, p in seen}
    assert forces == {"joint_spring_damper", "spring_damper", "force", "torque"} and drives >= 5


def _chain(n):
    """A hanging chain of n pendulums about y, the first 0.5 rad out."""
    body = lambda i: (f"  b{i}: {{parent: {'world' if i == 0 else f'b{i - 1}'}, joint: {{type: revolute, "  # noqa: E731
                      f"axis: [0, 1, 0], at: [0, 0, -0.1]{', initial: {b0.angle: 0.5}' if i == 0 else ''}}}, mass: 1, "
                      "inertia: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}")
    return "mbsfmu: 1\nname: chain\ngravity: [0, 0, -9.81]\nbodies:\n" + "\n".join(body(i) for i in range(n))


@pytest.mark.slow  # about 7 s of loading and compiling 250,000 YAML values
def test_a_10000_body_chain_compiles_and_steps_within_200_MB(tmp_path):
    """The recursive path's workspace grows with the bodies (the dense path's would be 4.5 GiB for this chain):
    loaded, compiled and stepped (rk4) in a fresh process, its peak resident set measured there beyond the interpreter
    with its imports (numpy and the rest: 38–42 MB, varying between installs of the same versions): the scene's
    share, within 170 MB (measured 157–160: the engine's workspace 16 MB of it, the rest the loader's and the
    compiler's Python objects); the whole process stays within 200 MB give or take those few MB. The import, load and
    compile marks are in the message."""
    if not Path("/proc/self/status").exists():
        pytest.skip("the peak resident set is read from /proc (Linux)")
    (tmp_path / "chain.yaml").write_text(_chain(10000))
    code = textwrap.dedent(f"""
        import json, sys, time
        import mbsfmu
        from mbsfmu.simulation import Simulation
        def rss():  # the peak resident set of this image: VmHWM (ru_maxrss keeps the forking parent's across exec)
            line = next(x for x in open("/proc/self/status") if x.startswith("VmHWM:"))
            return int(line.split()[1]) / 1024
        t0, r0 = time.process_time(), rss()
        scene = mbsfmu.load({str(tmp_path / "chain.yaml")!r})
        r1 = rss()
        sim = Simulation(scene.spec)
        t1, r2 = time.process_time(), rss()
        sim.set("integrator.method", "rk4")
        sim.initialize(0.0)
        for k in range(3):
            sim.do_step(k * 1e-3, 1e-3)
        t2 = time.process_time()
        print(json.dumps({{"rss_mb": rss(), "imported": r0, "loaded": r1, "compiled": r2, "compile": t1 - t0,
                          "steps": t2 - t1, "y": [sim.get("y.b0.angle"), sim.get("yd.b0.angle")]}}))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={"PYTHONPATH": str(REPO / "src"), "OPENBLAS_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"})
    assert out.returncode == 0, out.stderr[-2000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["rss_mb"] - r["imported"] < 170, r
    print(r)
    assert abs(r["y"][0] - 0.5) < 1e-3 and r["y"][1] < 0, r  # swinging back under gravity


def test_bodies_are_ordered_parents_first_in_linear_time():
    """compiler.model's body order is the passes over the file that each place every body whose parent is placed
    (the definition, run literally here on shuffled random trees), and a 10,000-body chain written leaves first is
    ordered in well under a second (the passes took 10,000 sweeps of the file)."""
    import time
    from mbsfmu.compiler.model import _parents_first

    def by_passes(bodies):
        order, placed = [], {"world"}
        while len(order) < len(bodies):
            for b in bodies:
                if b["name"] not in placed and b["parent"] in placed:
                    placed.add(b["name"])
                    order.append(b)
        return order
    rng = np.random.default_rng(0)
    for n in (1, 5, 40):
        for _ in range(20):
            parents = ["world"] + [f"b{rng.integers(0, i)}" if rng.uniform() < 0.9 else "world" for i in range(1, n)]
            bodies = [{"name": f"b{i}", "parent": p} for i, p in enumerate(parents)]
            bodies = [bodies[k] for k in rng.permutation(n)]
            assert [b["name"] for b in _parents_first(bodies)] == [b["name"] for b in by_passes(bodies)]
    chain = [{"name": f"b{i}", "parent": f"b{i - 1}" if i else "world"} for i in reversed(range(10000))]
    t0 = time.process_time()
    order = _parents_first(chain)
    assert time.process_time() - t0 < 1.0 and [b["name"] for b in order] == [f"b{i}" for i in range(10000)]


WELDED = """mbsfmu: 1
name: welded
gravity: [0.2, -0.5, -9.81]
parameters: {m_w: 1.5}
bodies:
  stand: {parent: world, joint: {type: fixed, at: [0.1, 0, 0.3]}, mass: 5, inertia: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}
  hub: {parent: world, joint: {type: free, at: [0, 0.2, 1]}, mass: 3, center_of_mass: [0.05, 0, 0.02],
        inertia: [[0.1, 0.01, 0], [0.01, 0.2, 0], [0, 0, 0.15]]}
  w1: {parent: hub, joint: {type: fixed, at: [0.3, 0.1, 0], rotation: {axis: [1, 2, 3], angle: 0.7}}, mass: m_w,
       center_of_mass: [0.1, -0.05, 0.2], inertia: [[0.02, 0.001, 0], [0.001, 0.03, 0.002], [0, 0.002, 0.04]]}
  w2: {parent: w1, joint: {type: fixed, at: [0, 0.2, 0.1], rotation: {axis: [0, 1, 0], angle: -1.1}}, mass: 0}
  arm: {parent: w2, joint: {type: revolute, axis: [0, 0, 1], at: [0.1, 0, 0]}, mass: 1.2,
        center_of_mass: [0.2, 0, 0], inertia: [[0.01, 0, 0], [0, 0.05, 0], [0, 0, 0.05]]}
  tip: {parent: arm, joint: {type: fixed, at: [0.4, 0, 0], rotation: {axis: [1, 0, 0], angle: 0.4}}, mass: 0.3,
        center_of_mass: [0.02, 0.01, 0], inertia: [[0.001, 0, 0], [0, 0.002, 0], [0, 0, 0.002]]}
  finger: {parent: tip, joint: {type: universal, axes: [[1, 0, 0], [0, 1, 0]], at: [0.05, 0, 0]}, mass: 0.2,
           center_of_mass: [0, 0, 0.05], inertia: [[0.001, 0, 0], [0, 0.001, 0], [0, 0, 0.0005]]}
  pad: {parent: finger, joint: {type: fixed, at: [0, 0, 0.1]}, mass: 0}
forces:
  - {type: spring_damper, bodies: [stand, pad], at: [[0, 0, 0.1], [0.01, 0, 0]], stiffness: 20, damping: 0.5, length: 0.3}
  - {type: force, body: w2, at: [0.1, 0.2, 0], frame: body, value: ["sin(t)", 1, 0.5]}
  - {type: torque, body: tip, frame: body, value: [0.1, -0.3, 0.2]}
  - {type: force, body: pad, at: [0, 0.02, 0], frame: world, value: [0, 0, -2]}
outputs:
  - {body: w2, point: [0.1, -0.2, 0.3], quantities: [position, velocity], name: on_w2}
  - {body: pad, point: [0.02, 0, 0.01], quantities: [position, velocity], name: on_pad}
  - {body: stand, point: [0, 0.1, 0], quantities: [position, velocity], name: on_stand}
"""


def test_welded_and_massless_links_join_their_carriers():
    """Bodies on fixed joints (massive and massless, in chains, one on the world, moving bodies on them, forces
    and torques on them in both frames) are welded to their carriers (compile.carriers): the recursive path's M,
    k, q and ÿ equal the numpy reference's, which keeps every body, to 1e-12, also after the parameter that sets a
    welded body's mass changes (the composites are derived at bind time); output points on welded bodies (whose
    frames the recursive kinematics derive from their carriers') equal the reference's."""
    from mbsfmu.compiler.scene_file import carriers
    spec = mbsfmu.loads(WELDED).spec
    ev, sim = mbsfmu.compile(spec), Simulation(spec)
    names = [b.name for b in ev.model.bodies]
    c = carriers(ev.model)
    assert {n: names[k] if k >= 0 else None for n, k in zip(names, c)} == {
        "stand": None, "hub": "hub", "w1": "hub", "w2": "hub", "arm": "arm", "tip": "arm", "finger": "finger",
        "pad": "finger"}
    rng = np.random.default_rng(3)
    for m_w in (1.5, 4.0):
        sim.set("m_w", m_w)  # the engine's parameter; the reference's scene with it as its value
        ev = mbsfmu.compile(mbsfmu.loads(WELDED.replace("m_w: 1.5", f"m_w: {m_w}")).spec)
        for t in (0.0, 0.8):
            y, yd = _state(ev, rng)
            x = np.concatenate([y, yd])
            M, k, q = ev.equations(y, yd, t)
            scale = max(1.0, np.abs(M).max(), np.abs(k).max(), np.abs(q).max())
            for want, got in zip((M, k, q), sim.engine.equations(t, x)):
                np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * scale)
            ydd = np.linalg.solve(M, q - k)
            np.testing.assert_allclose(sim.f(t, x)[len(y):], ydd, rtol=0, atol=1e-12 * np.linalg.cond(M) * np.abs(ydd).max())
            want, got = ev.output_values(y, yd, t), sim.output_values(x, t)
            assert want.keys() == got.keys()
            np.testing.assert_allclose([got[k] for k in want], list(want.values()), rtol=0, atol=1e-12)


@pytest.mark.parametrize("model", sorted(p.stem for p in (REPO / "models").glob("*.yaml")))
def test_either_path_evaluates_every_shipped_model(model):
    """The compiler picks the faster path per scene (compiler/scene_file.py: dense_path); either evaluates every scene: each
    shipped model compiled for each path (elastic ones too: their bodies are nodes of the articulated-body
    algorithm) gives M, k, q of the reference (1e-12) and the same ÿ."""
    from mbsfmu.engine import Instance
    from mbsfmu.compiler.scene_file import compile_scene
    from mbsfmu.compiler.variables import variables
    spec = mbsfmu.load(REPO / "models" / f"{model}.yaml").spec
    ev = mbsfmu.compile(spec)
    rng = np.random.default_rng(0)
    var = variables(spec)
    paths = [Instance(compile_scene(spec, var, dense=dense)) for dense in (True, False)]
    for p in paths:
        p.initialize(0.0)
    for t in (0.0, 0.7):
        y, yd = ev.initial_state()
        y, yd = y + 0.1 * rng.normal(size=y.shape), yd + rng.normal(size=yd.shape)
        for qi in ev.model.quaternions:
            y[qi] /= np.linalg.norm(y[qi])
        M, k, q = ev.equations(y, yd, t)
        x = np.r_[y, yd]
        scale = max(1.0, np.abs(M).max(), np.abs(k).max(), np.abs(q).max())
        ydd = []
        for p in paths:
            for want, got in zip((M, k, q), p.equations(t, x)):
                np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * scale)
            ydd.append(p.rhs(t, x)[len(y):])
        np.testing.assert_allclose(ydd[1], ydd[0], rtol=0, atol=1e-12 * np.linalg.cond(M) * np.abs(ydd[0]).max())
