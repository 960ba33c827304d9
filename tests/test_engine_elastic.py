"""Elastic bodies in the C engine (engine/elastic.c) against the numpy reference of seed 004
(equations/tree.py + bodies/tree.py + bodies/ffrf.py): M, k, q and node kinematics at random states, on the
shipped elastic scenes (the dense path) and on random nodal data that exercise every part (Ψ, node inertias,
damping, a child joint at a node, an elastic body at a node of another, springs/forces/torques/outputs at nodes,
drives, gravity) on the recursive path (elastic bodies as nodes of the articulated-body algorithm); the compiled
data refused when corrupt; structural parameters fixed."""

import json
import struct
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.bodies.tree import node_point
from mbsfmu.engine import EngineError, Instance
from mbsfmu.compiler.scene_file import carriers, dense_path
from mbsfmu.compiler.model import Model
from mbsfmu.engine.layout import S_ELASTIC_D, S_ELASTIC_I
from mbsfmu.simulation import Simulation, compiled

MODELS = Path(__file__).resolve().parents[1] / "models"
SHIPPED = ["flexible_pendulum", "spinup_beam", "robot_arm_elastic"]
RTOL = 1e-12


def engine(spec, dense=None):
    """The engine instance of a scene on the path the compiler picks (dense None) or on the one asked for."""
    from mbsfmu.compiler.scene_file import compile_scene
    from mbsfmu.compiler.variables import variables
    if dense is None:
        blob, _, model = compiled(spec)
        return Instance(blob), model
    model = Model(spec)
    return Instance(compile_scene(spec, variables(spec, model), model=model, dense=dense)), model


def random_state(ev, rng, scale=1.0):
    """A random state: joint coordinates O(1), elastic coordinates of size `scale` (quaternions normalized)."""
    m = ev.model
    y, yd = ev.initial_state()
    y = y + scale * rng.normal(size=y.shape)
    yd = yd + rng.normal(size=yd.shape)
    for qi in m.quaternions:
        y[qi] /= np.linalg.norm(y[qi])
    return y, yd


def on_dense_path(spec):
    """The compiler's choice of evaluation path for the scene (compiler/scene_file.py: dense_path)."""
    model = Model(spec)
    return dense_path(model, carriers(model))


def assert_close(ours, ref, what):
    scale = max(np.abs(ref).max(), 1e-300)
    err = np.abs(ours - ref).max() / scale
    assert err < RTOL, f"{what}: relative difference {err:.2e}"


def compare(spec, seed, states=4, scale=0.3, dense=None):
    """Engine against the reference for M, k, q and every output point (nodes included)."""
    inst, model = engine(spec, dense)
    ev = mbsfmu.compile(spec)
    rng = np.random.default_rng(seed)
    for _ in range(states):
        y, yd = random_state(ev, rng, scale)
        t = rng.uniform(0.0, 3.0)
        M0, k0, q0 = ev.equations(y, yd, t)
        M1, k1, q1 = inst.equations(t, np.r_[y, yd])
        assert_close(M1, M0, "M")
        assert_close(k1, k0, "k")
        assert_close(q1, q0, "q")
        d = ev.kinematics(y, yd, t)
        for o, spec_o in enumerate(spec["outputs"]):
            i = model.index[spec_o["body"]]
            if spec_o.get("node") is not None:
                r, v, _ = node_point(model, d, i, spec_o["node"])
            else:
                S = d.S[i]
                rb = S @ np.asarray(spec_o["point"], float)
                r, v = d.o[i] + rb, d.v[i] + np.cross(d.w[i], rb)
            p = inst.output_point(o, t, np.r_[y, yd])
            assert_close(p, np.r_[r, v], f"output {spec_o['name']}")


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scene_equations_and_nodes(name):
    spec = mbsfmu.load(MODELS / f"{name}.yaml").spec
    flex = next(b["name"] for b in spec["bodies"] if b["elastic"])
    spec["outputs"].append({"body": flex, "node": 0, "point": [0.0] * 3,
                            "quantities": ["position", "velocity"], "name": "root"})
    compare(spec, seed=SHIPPED.index(name))


# -- random nodal data ------------------------------------------------------------------------------

def nodal(rng, N, n, psi=True, inertia=True):
    A = rng.normal(size=(n, n))
    Dm = rng.normal(size=(n, n))
    d = {"R_RP": rng.normal(size=(N, 3)), "mass": rng.uniform(0.2, 2.0, N), "Phi": rng.normal(size=(N, 3, n)),
         "stiffness": A @ A.T + n * np.eye(n), "damping": 0.1 * Dm @ Dm.T}
    if psi:
        d["Psi"] = rng.normal(size=(N, 3, n))
    if inertia:
        d["inertia"] = np.array([0.1 * np.array(inertia_of(rng)) for _ in range(N)])
    return {k: v.tolist() for k, v in d.items()}


def inertia_of(rng):
    """A physical inertia tensor: that of a few random point masses, Σ m (|r|² E − r rᵀ)."""
    r, m = rng.normal(size=(4, 3)), rng.uniform(0.5, 1.0, 4)
    return sum(mi * (ri @ ri * np.eye(3) - np.outer(ri, ri)) for mi, ri in zip(m, r)).tolist()


def random_scene(seed, arm_joint=None):
    """A free base, an elastic body on a revolute joint, a hinged child at one of its nodes (arm_joint: another
    joint there), a second elastic body at another node (stacked node frames), and forces, torques, springs and
    outputs at nodes."""
    rng = np.random.default_rng(seed)
    v = lambda: rng.normal(size=3).tolist()  # noqa: E731
    n1, n2, N1, N2 = int(rng.integers(1, 6)), int(rng.integers(1, 4)), int(rng.integers(2, 6)), int(rng.integers(2, 5))
    scene = {
        "mbsfmu": 1, "name": f"random_nodal_{seed}", "gravity": v(),
        "parameters": {"w": {"value": 1.3}},
        "bodies": {
            "base": {"parent": "world", "joint": {"type": "free"},
                     "mass": 2.0, "center_of_mass": v(), "inertia": inertia_of(rng)},
            "flex": {"parent": "base", "joint": {"type": "revolute", "axis": v(), "at": v(), "coordinates": ["a"],
                                                 "rotation": {"axis": v(), "angle": 0.4}},
                     "elastic": {"nodal": nodal(rng, N1, n1)}},
            "arm": {"parent": "flex", "joint": {"type": "revolute", "axis": v(), "node": int(rng.integers(0, N1)),
                                                "coordinates": ["b"]} if arm_joint is None else
                           {**arm_joint, "node": int(rng.integers(0, N1)), "rotation": {"axis": v(), "angle": 0.7}},
                    "mass": 0.7, "center_of_mass": v(), "inertia": inertia_of(rng)},
            "flex2": {"parent": "flex", "joint": {"type": "fixed", "node": -1, "rotation": {"axis": v(), "angle": -0.8}},
                      "elastic": {"nodal": nodal(rng, N2, n2, psi=bool(seed % 2), inertia=not seed % 3)}},
            "spun": {"parent": "flex2", "joint": {"type": "revolute", "axis": [0, 0, 1], "node": 0, "coordinates": ["c"],
                                                  "drive": {"c": "w*t + 0.3*sin(2*t)"}},
                     "mass": 0.3, "inertia": inertia_of(rng)},
        },
        "forces": [
            {"type": "spring_damper", "bodies": ["world", "flex"], "node": [None, N1 - 1], "at": [v(), [0, 0, 0]],
             "stiffness": 50.0, "damping": 2.0, "length": 0.5},
            {"type": "spring_damper", "bodies": ["flex", "flex2"], "node": [0, 1], "stiffness": 30.0, "damping": 1.0},
            {"type": "force", "body": "flex2", "node": 0, "value": v(), "frame": "body"},
            {"type": "force", "body": "flex", "node": 1, "value": [0, "sin(t)", 1.0], "frame": "world"},
            {"type": "torque", "body": "flex", "node": 0, "value": v(), "frame": "world"},
            {"type": "torque", "body": "flex2", "node": N2 - 1, "value": v(), "frame": "body"},
            {"type": "force", "body": "flex", "at": v(), "value": v()},
        ],
        "outputs": [{"body": "flex", "node": N1 - 1, "name": "tip"}, {"body": "flex2", "node": 1, "name": "tip2"},
                    {"body": "arm", "point": v(), "name": "hand"}, {"body": "flex", "point": v(), "name": "frame"}],
    }
    return mbsfmu.loads(json.dumps(scene)).spec


@pytest.mark.parametrize("dense", (False, True), ids=("recursive", "dense"))
@pytest.mark.parametrize("seed", range(6))
def test_random_nodal_scene(seed, dense):
    """On either evaluation path (the compiler picks the recursive one for these scenes)."""
    compare(random_scene(seed), seed, dense=dense)


@pytest.mark.parametrize("seed", range(8))
def test_accelerations_on_the_recursive_path(seed):
    """ÿ of the engine's right-hand side, where the elastic bodies are nodes of the articulated-body algorithm
    (dynamics.c with elastic.c's recursive path), against M⁻¹ (q − k) of the reference, at large and small
    deflections (the random scenes have more coordinates than the dense path takes)."""
    spec = random_scene(seed)
    ev, sim = mbsfmu.compile(spec), Simulation(spec)
    assert not on_dense_path(spec)
    rng = np.random.default_rng(seed)
    for scale in (0.3, 1e-3):
        y, yd = random_state(ev, rng, scale)
        t = rng.uniform(0.0, 3.0)
        M, k, q = ev.equations(y, yd, t)
        ydd = np.linalg.solve(M, q - k)
        got = sim.f(t, np.r_[y, yd])[len(y):]
        assert np.abs(got - ydd).max() < 1e-12 * np.linalg.cond(M) * np.abs(ydd).max()


ARM_JOINTS = [{"type": "prismatic", "axis": [0.3, -1, 0.5]}, {"type": "cylindrical", "axis": [1, 0.2, -0.4]},
              {"type": "universal", "axes": [[1, 0, 0.3], [0.2, 1, 0]]}, {"type": "planar", "axes": [[0, 0.6, 0.8], [0, -0.8, 0.6]]},
              {"type": "spherical", "parameterization": "quaternion"}, {"type": "spherical", "parameterization": "cardan"},
              {"type": "free", "parameterization": "quaternion"}, {"type": "free", "parameterization": "cardan"},
              {"type": "fixed"}]


@pytest.mark.parametrize("joint", ARM_JOINTS, ids=lambda j: j["type"] + j.get("parameterization", ""))
def test_every_joint_type_at_a_node_on_the_recursive_path(joint):
    """The child at a node of the elastic body on every joint type (the free joint's own articulated-body step
    passes its parent only a force): M, k, q, the nodes and ÿ equal the reference's."""
    spec = random_scene(3, arm_joint=joint)
    assert not on_dense_path(spec)
    compare(spec, 3, states=2)
    ev, sim = mbsfmu.compile(spec), Simulation(spec)
    y, yd = random_state(ev, np.random.default_rng(0), 0.3)
    M, k, q = ev.equations(y, yd, 0.4)
    ydd = np.linalg.solve(M, q - k)
    got = sim.f(0.4, np.r_[y, yd])[len(y):]
    assert np.abs(got - ydd).max() < 1e-12 * np.linalg.cond(M) * np.abs(ydd).max()


def test_realistic_deflections():
    """At small elastic coordinates (the regime of the linear theory) as well as at large ones."""
    compare(random_scene(7), 7, scale=1e-3)


def test_rhs_and_short_run_match_reference():
    """ẍ from the engine's Cholesky solve equals numpy's, and a short run follows scipy on the reference."""
    from scipy.integrate import solve_ivp
    spec = mbsfmu.load(MODELS / "flexible_pendulum.yaml").spec
    sim = Simulation(spec)
    ev = mbsfmu.compile(spec)
    y0, yd0 = ev.initial_state()
    x0 = np.r_[y0, yd0]
    np.testing.assert_allclose(sim.f(0.0, x0)[len(y0):], ev.accelerations(y0, yd0, 0.0), rtol=1e-11, atol=1e-11)
    n = len(y0)
    ref = solve_ivp(lambda t, x: np.r_[x[n:], ev.accelerations(x[:n], x[n:], t)], (0, 0.2), x0,
                    method="DOP853", rtol=1e-11, atol=1e-13, t_eval=[0.2]).y[:, -1]
    sim.set("integrator.rtol", 1e-11)
    sim.set("integrator.atol", 1e-13)
    sim.set("integrator.method", "dop853")
    X = sim.run([0.0, 0.2])
    np.testing.assert_allclose(X[-1], ref, rtol=1e-7, atol=1e-9)


# -- what the engine refuses --------------------------------------------------------------------------

def test_structural_parameter_recompiles_before_initialize_and_is_refused_after():
    """L feeds the beam generator: the engine cannot recompute the FE data, so it refuses a new value (the FMU
    declares it fixed); in-process, Simulation.set compiles the scene again before initialize. m_tip stays
    tunable and takes effect."""
    spec = mbsfmu.load(MODELS / "flexible_pendulum.yaml").spec
    sim = Simulation(spec)
    var = {v.name: v for v in sim.variables}
    assert var["L"].variability == "fixed" and var["EI"].variability == "fixed"
    assert var["m_tip"].variability == "tunable"
    engine = Simulation(spec).engine
    with pytest.raises(EngineError, match="L = 1.5: parameter L is structural"):  # refused when set
        engine.set_real(list(var).index("L"), 1.5)
    assert engine.get_real(list(var).index("L")) == 1.0
    sim.set("m_tip", 0.5)
    sim.set("L", 1.5)           # recompiled; m_tip set before is kept
    sim.initialize(0.0)
    assert sim.get("L") == 1.5 and sim.get("m_tip") == 0.5
    assert sim.get("tip.r.x") == pytest.approx(0.05 + 1.5, abs=1e-12)  # hub at the origin, beam along x
    with pytest.raises(EngineError, match="L is structural"):
        sim.set("L", 1.0)
    sim.do_step(0.0, 0.01)
    assert np.all(np.isfinite(sim.x))


def _sections(blob):
    nsec = struct.unpack_from("<i", blob, 72)[0]
    return {sid: (kind, off, cnt) for sid, kind, off, cnt in
            (struct.unpack_from("<iiqq", blob, 76 + 24 * s) for s in range(nsec))}


def _patch(blob, sid, index, value):
    kind, off, cnt = _sections(blob)[sid]
    b = bytearray(blob)
    struct.pack_into("<d" if kind == 1 else "<i", b, off + (8 if kind == 1 else 4) * index, value)
    return bytes(b)


@pytest.mark.parametrize("index, value", [(0, 5), (0, -1), (1, 1000), (2, 99), (3, 0), (3, 5000),
                                          (4, 0), (4, 1 << 30), (5, 100), (6, 100), (7, 2), (8, 1),
                                          (9, 100), (9, -1)])
def test_corrupt_elastic_section_refused(index, value):
    """Counts, the body link, modes, nodes, coordinate ranges, flags and data offsets are checked at load."""
    blob, _, model = compiled(mbsfmu.load(MODELS / "robot_arm_elastic.yaml").spec)
    bad = _patch(blob, S_ELASTIC_I, index, value)
    with pytest.raises(EngineError, match="corrupt"):
        Instance(bad)


def test_truncated_elastic_data_and_bad_node_refused():
    from mbsfmu.engine.layout import IB, IB_NODE, S_BODY_I, S_OUT_I
    blob, _, model = compiled(mbsfmu.load(MODELS / "robot_arm_elastic.yaml").spec)
    kind, off, cnt = _sections(blob)[S_ELASTIC_D]
    short = bytearray(blob)
    rows = 76 + 24 * [sid for sid in _sections(blob)].index(S_ELASTIC_D)
    struct.pack_into("<q", short, rows + 16, cnt - 1)
    with pytest.raises(EngineError, match="corrupt"):
        Instance(bytes(short))
    payload = model.index["payload"]
    with pytest.raises(EngineError, match="corrupt"):
        Instance(_patch(blob, S_BODY_I, payload * IB + IB_NODE, 9))
    with pytest.raises(EngineError, match="corrupt"):
        Instance(_patch(blob, S_OUT_I, 3 * 1 + 1, 9))


def test_the_paths_benchmark_writes_its_report(tmp_path):
    """benchmarks/elastic_paths.py (reports/elastic_paths.md): each case on both paths in the C loop, the report written."""
    from benchmarks import elastic_paths
    from mbsfmu.fmu.native import compiler
    if compiler() is None:
        pytest.skip("no C compiler")
    elastic_paths.main(["--out", str(tmp_path), "--quick", "--rounds", "2", "--seconds", "0.02"])
    text = (tmp_path / "elastic_paths.md").read_text()
    assert "| flexible_pendulum | 4 | dense |" in text and "| arm 1×8 | 9 | dense |" in text
    assert (tmp_path / "elastic_paths.png").stat().st_size
