"""Von Mises outputs of FE bodies from stress modes (`fe: stress:`; fe_mesh.nodal_stress, cms.stress_modes,
the engine's MBS_V_VM) against closed forms and the full FE model: Hooke's law for uniform strain, F/A in a bar
pulled at its ends, M·c/I and scikit-fem's full static solution in a tet10 cantilever; the FMUs' outputs against
the in-process run; a scene without `stress:` unchanged; hostile input refused with one ModelError line."""

import sys
from pathlib import Path

import numpy as np
import pytest

meshio = pytest.importorskip("meshio")
skfem = pytest.importorskip("skfem")

import scipy.sparse.linalg  # noqa: E402

import mbsfmu  # noqa: E402
from mbsfmu.bodies import cms  # noqa: E402
from mbsfmu.bodies.fe_mesh import assemble_solid  # noqa: E402
from mbsfmu.engine import build  # noqa: E402
from mbsfmu.engine import layout as L  # noqa: E402
from mbsfmu.errors import ModelError  # noqa: E402
from mbsfmu import limits  # noqa: E402
from mbsfmu.simulation import Simulation, compiled, simulate  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from test_fe_mesh import box_hexes, box_tets  # noqa: E402

E, NU, RHO = 2.1e11, 0.3, 7850.0
MATERIAL = "{E: 2.1e+11, nu: 0.3, rho: 7850}"


pytestmark = pytest.mark.usefixtures("private_fe_cache")  # conftest.py: each test's own FE cache


def von_mises(s):
    """σ_vm of Voigt stresses (…, 6: xx yy zz xy yz zx), written out from the deviatoric invariant J2."""
    dev = s[..., :3] - s[..., :3].mean(axis=-1, keepdims=True)
    return np.sqrt(1.5 * (np.sum(dev ** 2, axis=-1) + 2 * np.sum(s[..., 3:] ** 2, axis=-1)))


def write_mesh(path, p, t, cell, **sets):
    meshio.Mesh(p, [(cell, t)], point_sets={k: np.atleast_1d(v) for k, v in sets.items()}).write(path)


def scene(tmp_path, fe, extra="", joint="{type: prismatic, axis: [1, 0, 0], coordinates: [s]}", gravity="[0, 0, 0]",
          stop=0.01):
    return mbsfmu.loads(f"""
mbsfmu: 1
name: part
gravity: {gravity}
bodies:
  part:
    parent: world
    joint: {joint}
    elastic:
      fe: {fe}
{extra}
integrator: {{method: dopri5, rtol: 1e-10, atol: 1e-14}}
experiment: {{start: 0, stop: {stop}, step: {stop / 2}}}
""", base=tmp_path)


def static_q(spec, loads):
    """The reduced body's static coordinates K_ee q = Σ Φ_Pᵀ F_P + Ψ_Pᵀ M_P under (kept node, F, M) loads."""
    fe = spec["bodies"][0]["elastic"]["fe"]
    n = len(fe["stiffness"])
    Phi, Psi = np.reshape(fe["Phi"], (-1, 3, n)), np.reshape(fe["Psi"], (-1, 3, n))
    Q = sum(Phi[P].T @ F + Psi[P].T @ Mo for P, F, Mo in loads)
    return np.linalg.solve(np.asarray(fe["stiffness"]), Q)


def at_state(spec, q):
    """A Simulation with the elastic coordinates set to q, initialized at rest."""
    sim = Simulation(spec)
    for k, v in enumerate(q):
        sim.set(f"y0.part.q{k + 1}", float(v))
    sim.initialize(0.0)
    return sim


@pytest.mark.parametrize("element", ["tet4", "tet10", "hex8"])
def test_stress_of_a_uniform_strain_is_hookes_law(element):
    """u = A x (strain ε = sym A, with a rotation part) gives σ = λ tr ε + 2μ ε at every node, in Voigt order."""
    p, t = box_hexes(0.3, 0.1, 0.05, 3, 2, 1) if element == "hex8" else box_tets(0.3, 0.1, 0.05, 3, 2, 1)
    fe = assemble_solid(meshio.Mesh(p, [("hexahedron" if element == "hex8" else "tetra", t)]), E, NU, RHO, element)
    A = np.array([[1.0, 0.3, -0.2], [0.3, -0.5, 0.7], [-0.2, 0.7, 0.4]]) * 1e-3 + np.array(
        [[0, 1, 2], [-1, 0, 3], [-2, -3, 0]]) * 1e-3
    eps = 0.5 * (A + A.T)
    lam, mu = E * NU / ((1 + NU) * (1 - 2 * NU)), E / (2 * (1 + NU))
    sigma = lam * np.trace(eps) * np.eye(3) + 2 * mu * eps
    voigt = np.array([sigma[0, 0], sigma[1, 1], sigma[2, 2], sigma[0, 1], sigma[1, 2], sigma[2, 0]])
    U = (fe.nodes @ A.T).reshape(-1, 1)
    s = fe.stress(np.hstack([U, -2 * U]), np.arange(fe.n_nodes))
    assert np.abs(s[:, :, 0] - voigt).max() < 1e-9 * np.abs(voigt).max()
    assert np.abs(s[:, :, 1] + 2 * voigt).max() < 1e-9 * np.abs(voigt).max()


def test_a_bar_pulled_at_its_ends_has_von_mises_F_over_A(tmp_path):
    """A hex8 bar one element across, free, pulled by ±F at its end faces (equal node forces: on a one-element
    face the consistent load of a uniform traction), is in uniaxial tension σ = F/A everywhere: the FE solution
    is exact (linear displacements), and the static correction modes of the two end faces hold it. From the
    reduced static state the engine's σ_vm is F/A to 1e-6; held by the scene's forces, it stays there."""
    Lx, a, F = 0.4, 0.02, 1000.0
    p, t = box_hexes(Lx, a, a, 4, 1, 1)
    write_mesh(tmp_path / "bar.inp", p, t, "hexahedron", end0=np.flatnonzero(p[:, 0] == 0),
               end1=np.flatnonzero(p[:, 0] == Lx), mid=np.flatnonzero(np.isclose(p[:, 0], Lx / 2)))
    fe = (f"{{mesh: bar.inp, material: {MATERIAL}, method: free, modes: 2, load_points: [end0, end1], "
          "keep: [end0, end1], stress: [mid, 0]}")
    forces = (f"forces:\n  - {{type: force, body: part, node: end0, value: [{-F}, 0, 0], frame: world}}\n"
              f"  - {{type: force, body: part, node: end1, value: [{F}, 0, 0], frame: world}}")
    spec = scene(tmp_path, fe, forces).spec
    names = [f"vm.part.mid.{k}" for k in np.flatnonzero(np.isclose(p[:, 0], Lx / 2))] + ["vm.part.0"]
    assert spec["bodies"][0]["elastic"]["fe"]["stress_names"] == [n[len("vm.part."):] for n in names]
    q = static_q(spec, [(0, [-F, 0, 0], np.zeros(3)), (1, [F, 0, 0], np.zeros(3))])
    sim = at_state(spec, q)
    assert [sim.get(n) for n in names] == pytest.approx([F / a ** 2] * len(names), rel=1e-6)
    ts = [0.0, 0.0005, 0.001]   # (the axial modes of a 0.4 m steel bar: kHz, small steps)
    X = sim.run(ts)
    for x, t_ in zip(X, ts):
        assert list(sim.output_values(x, t_).values()) == pytest.approx([F / a ** 2] * len(names), rel=1e-6)


def cantilever(tmp_path):
    """A tet10 steel bar 0.5 × 0.04 × 0.02 m as a .inp (tet4 cells, element: tet10), its end faces as node sets
    and the gauge node at x = L/4 on the top face's centre line; (points, the assembled full model)."""
    Lx, b, h = 0.5, 0.04, 0.02
    p, t = box_tets(Lx, b, h, 12, 2, 2)
    p -= [0, b / 2, h / 2]
    gauge = np.flatnonzero(np.isclose(p[:, 0], Lx / 4) & np.isclose(p[:, 1], 0) & np.isclose(p[:, 2], h / 2))
    sets = {"root": np.flatnonzero(p[:, 0] == 0), "tip": np.flatnonzero(np.isclose(p[:, 0], Lx)), "gauge": gauge}
    write_mesh(tmp_path / "bar.inp", p, t, "tetra", **sets)
    return (Lx, b, h), assemble_solid(meshio.Mesh(p, [("tetra", t)], point_sets=sets), E, NU, RHO, "tet10"), gauge[0]


def test_cantilever_bending_stress_against_beam_theory_and_the_full_static_solution(tmp_path):
    """Tip force F down, held at the root face by the clamp's reactions (F up, moment F·L): the free body's
    static correction modes of the two faces hold the full model's static deflection, so σ_vm at the gauge
    node (x = L/4 on the top face, where σ_xx dominates and the other components vanish) is scikit-fem's full
    static solution's to 1e-6, and beam theory's M·c/I = F (L − x)(h/2)/I to 3 % (two quadratic elements
    across the height: their strain is linear within an element, while σ_xx varies with x and z; L/4 is six
    heights from the root face, where the reactions' spread differs from a clamp's)."""
    (Lx, b, h), full, gauge = cantilever(tmp_path)
    F = 200.0
    fe = (f"{{mesh: bar.inp, material: {MATERIAL}, element: tet10, method: free, modes: 4, "
          "load_points: [root, tip], keep: [root, tip], stress: [gauge]}")
    spec = scene(tmp_path, fe).spec
    q = static_q(spec, [(0, [0, 0, F], [0, -F * Lx, 0]), (1, [0, 0, -F], np.zeros(3))])
    vm = at_state(spec, q).get("vm.part.gauge")
    I = b * h ** 3 / 12
    assert vm == pytest.approx(F * (Lx - Lx / 4) * (h / 2) / I, rel=0.03)
    # the full model: the same loads (cms.load_patterns spreads them as the kept sets do), held at six DOFs
    # that fix the rigid motions only (the loads are balanced: no reaction), solved by sparse LU
    root, tip = full.node_sets["root"], full.node_sets["tip"]
    f = cms.load_patterns(full, [root, tip]) @ np.r_[0, 0, F, 0, -F * Lx, 0, 0, 0, -F, 0, 0, 0]
    a, c = root[np.argmin(full.nodes[root, 1] + full.nodes[root, 2])], tip[0]
    d = next(n for n in root if abs(full.nodes[n, 1] - full.nodes[a, 1]) > 1e-9 and abs(full.nodes[n, 2] - full.nodes[a, 2]) < 1e-9)
    held = [3 * a, 3 * a + 1, 3 * a + 2, 3 * c + 1, 3 * c + 2, 3 * d + 2]
    free = np.setdiff1d(np.arange(3 * full.n_nodes), held)
    u = np.zeros(3 * full.n_nodes)
    u[free] = scipy.sparse.linalg.spsolve(full.K[free][:, free].tocsc(), f[free])
    node = int(np.flatnonzero(np.all(np.isclose(full.nodes, full.nodes[gauge]), axis=1))[0])
    assert vm == pytest.approx(von_mises(full.stress(u[:, None], [node])[0, :, 0]), rel=1e-6)


def test_fmu_outputs_equal_the_in_process_run_and_other_scenes_are_unchanged(tmp_path):
    """A hinged tet10 link swinging under gravity with two stress nodes: the native and the pythonfmu FMU give
    the in-process von Mises outputs (FMI 3 = FMI 2 on every output: test_fmu3 on models/fe_stress.yaml), and
    the scene without `stress:` has the same trajectory bit for bit, no stress section nor variable, and the
    same native engine sources and switches."""
    fmpy = pytest.importorskip("fmpy")
    cantilever(tmp_path)
    base = (f"mesh: bar.inp, material: {MATERIAL}, element: tet10, interface: {{node_set: root, reference: "
            "[0, 0, 0]}, modes: 3, keep: [tip]")
    joint, g = "{type: revolute, axis: [0, 1, 0], coordinates: [theta]}", "[0, 0, -9.81]"
    with_stress = scene(tmp_path, f"{{{base}, stress: [gauge, 5]}}", joint=joint, gravity=g, stop=0.04)
    plain = scene(tmp_path, f"{{{base}}}", joint=joint, gravity=g, stop=0.04)
    t, Y, YD = simulate(with_stress, inputs=lambda t: {})   # one do_step per interval, as an FMU master
    _, Y0, YD0 = simulate(plain, inputs=lambda t: {})
    assert np.array_equal(Y, Y0) and np.array_equal(YD, YD0)
    blob, var, _ = compiled(plain.spec)
    blob_s, var_s, _ = compiled(with_stress.spec)
    assert [v.name for v in var_s if v.kind == L.MBS_V_VM] == ["vm.part.gauge", "vm.part.5"]
    assert all(v.unit == "Pa" and v.causality == "output" for v in var_s if v.kind == L.MBS_V_VM)
    assert not any(v.kind == L.MBS_V_VM for v in var)
    sections = [int.from_bytes(blob[76 + 24 * s:80 + 24 * s], "little") for s in range(int.from_bytes(blob[72:76], "little"))]
    assert L.S_STRESS_I not in sections and L.S_STRESS_D not in sections   # none added without stress
    assert build.sources(build.features(blob)) == build.sources(build.features(blob_s))
    sim = Simulation(with_stress.spec)
    sim.initialize(0.0)
    ref = np.array([[sim.output_values(np.r_[y, yd], ti)[n] for n in ("vm.part.gauge", "vm.part.5")]
                    for ti, y, yd in zip(t, Y, YD)])
    assert ref[-1].min() > 1e4   # bending under gravity: tens of kPa and more
    for kind in ("native", "pythonfmu"):
        fmu = mbsfmu.build_fmu(with_stress, tmp_path / kind, kind=kind)
        res = fmpy.simulate_fmu(str(fmu), stop_time=0.04, output_interval=0.02,
                                output=["vm.part.gauge", "vm.part.5"])
        got = np.column_stack([res["vm.part.gauge"], res["vm.part.5"]])
        assert np.allclose(got, ref, rtol=1e-12, atol=0), kind


def test_engine_outputs_are_the_numpy_references_at_random_states():
    """models/fe_stress.yaml: the engine's von Mises (and point) outputs = the numpy evaluator's σ = Σ σ_k q_k
    at random states, to 1e-12."""
    spec = mbsfmu.load(Path(__file__).resolve().parents[1] / "models" / "fe_stress.yaml").spec
    ev, sim = mbsfmu.compile(spec), Simulation(spec)
    rng = np.random.default_rng(7)
    for _ in range(3):
        y, yd = rng.normal(size=len(ev.coordinates)) * 1e-4, rng.normal(size=len(ev.velocity_coordinates))
        got, want = sim.output_values(np.r_[y, yd], 0.1), ev.output_values(y, yd, 0.1)
        assert list(got) == list(want) and {"vm.link.gauge_top", "vm.link.gauge_bottom"} <= set(want)
        for name in want:
            assert got[name] == pytest.approx(want[name], rel=1e-12, abs=1e-15)


def test_hostile_stress_keys_are_refused_with_one_line(tmp_path, monkeypatch):
    (Lx, b, h), full, gauge = cantilever(tmp_path)
    base = f"mesh: bar.inp, material: {MATERIAL}, interface: {{node_set: root, reference: [0, 0, 0]}}, modes: 2"
    cases = [("stress: [gage]", "no node set 'gage'"), ("stress: [99999]", "does not exist"),
             ("stress: [gauge, gauge]", "named twice"), ("stress: []", "a list of node indices"),
             ("stress: [1.5]", "a list of node indices"), ("stress: ['a b']", "not valid as a stress node set name")]
    for extra, words in cases:
        with pytest.raises(ModelError, match=words) as err:
            scene(tmp_path, f"{{{base}, {extra}}}")
        assert "\n" not in str(err.value) and err.value.key.startswith("bodies.part.elastic.fe.stress"), extra
    monkeypatch.setattr(limits, "FE_STRESS_NODES", 3)        # the root face has 9 nodes
    with pytest.raises(ModelError, match="9 stress nodes asked, at most 3") as err:
        scene(tmp_path, f"{{{base}, stress: [root]}}")
    assert "\n" not in str(err.value) and err.value.key == "bodies.part.elastic.fe.stress"
    with pytest.raises(ModelError, match="4 stress nodes, at most 3"):
        scene(tmp_path, f"{{{base}, stress: [0, 1, 2, 3]}}")
    # matrices: no elements to take stresses from
    scipy_io = pytest.importorskip("scipy.io")
    scipy_io.mmwrite(tmp_path / "m.mtx", full.M)
    scipy_io.mmwrite(tmp_path / "k.mtx", full.K)
    np.savetxt(tmp_path / "n.csv", full.nodes, delimiter=",")
    with pytest.raises(ModelError, match="stress outputs need a solid mesh") as err:
        scene(tmp_path, "{mass: m.mtx, stiffness: k.mtx, nodes: n.csv, interface: {nodes: [0, 1, 2], reference: "
                        "[0, 0, 0]}, modes: 2, stress: [5]}")
    assert "\n" not in str(err.value) and err.value.key == "bodies.part.elastic.fe.stress"
    with pytest.raises(ModelError, match="need a solid mesh"):   # the Python API refuses it as well
        cms.reduce(cms.fe.FEModel(full.nodes, full.M, full.K), interface=[0, 1, 2], reference=[0, 0, 0],
                   modes=2, stress=[5])
