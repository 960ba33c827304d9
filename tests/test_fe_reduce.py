"""Elastic bodies from FE models (issue 24): readers, Craig–Bampton and free-interface reduction, consistent-mass
invariants, the `elastic: fe:` scene key and its cache.  References: the full FE model solved densely by LAPACK
(scipy.linalg.eigh) with the same boundary condition, closed-form box moments, the lumped-mass sums of the
nodal path, conservation laws of a free body, the Matrix Market and Abaqus (MATRIX INPUT, COORDINATE) file formats,
and Exudyn's reader of Abaqus COORDINATE files."""

import os
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.io
import scipy.linalg
import scipy.sparse as sp

skfem = pytest.importorskip("skfem")
from skfem.helpers import dot  # noqa: E402
from skfem.models.elasticity import lame_parameters, linear_elasticity  # noqa: E402

import mbsfmu  # noqa: E402
from mbsfmu.bodies import cms, fe  # noqa: E402
from mbsfmu.bodies.ffrf import invariants  # noqa: E402
from mbsfmu.bodies.nodal import MassPoints  # noqa: E402
from mbsfmu.errors import ModelError  # noqa: E402

MODELS = Path(__file__).resolve().parents[1] / "models"
L, H = 1.0, 0.1
E, NU, RHO = 2.1e11, 0.3, 7850.0


pytestmark = pytest.mark.usefixtures("private_fe_cache")  # conftest.py: each test's own FE cache


def bar(p2=True, nx=6, n=1, size=(L, H, H)):
    """(nodes, M, K) of a steel bar meshed with tets by scikit-fem, DOFs node-major x y z."""
    mesh = skfem.MeshTet.init_tensor(*(np.linspace(0, s, k + 1) for s, k in zip(size, (nx, n, n))))
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP2() if p2 else skfem.ElementTetP1()))

    @skfem.BilinearForm
    def mass(u, v, w):
        return RHO * dot(u, v)

    dofs = np.vstack([basis.nodal_dofs.T] + ([basis.edge_dofs.T] if p2 else []))
    order = dofs.ravel()
    K = linear_elasticity(*lame_parameters(E, NU)).assemble(basis)[order][:, order]
    M = mass.assemble(basis)[order][:, order]
    return basis.doflocs[:, dofs[:, 0]].T, sp.csr_matrix(M), sp.csr_matrix(K)


def write_mm(folder, X, M, K):
    scipy.io.mmwrite(folder / "M.mtx", M, symmetry="symmetric", precision=17)
    scipy.io.mmwrite(folder / "K.mtx", K, symmetry="general", precision=17)
    np.savetxt(folder / "nodes.csv", X, delimiter=",", fmt="%.17g")


def scene(folder, fe_yaml, joint="{type: fixed}", extra=""):
    text = f"""mbsfmu: 1
name: fe_test
gravity: [0, 0, 0]
bodies:
  part:
    parent: world
    joint: {joint}
    elastic:
      fe: {fe_yaml}
{extra}"""
    (folder / "s.yaml").write_text(text)
    return mbsfmu.load(folder / "s.yaml")


MM = "mass: M.mtx, stiffness: K.mtx, nodes: nodes.csv"


def dense_frequencies(K, M, fixed_nodes=(), skip=0, count=6):
    """Lowest eigenfrequencies (Hz) of the full model with fixed_nodes clamped (LAPACK, dense)."""
    fixed = (3 * np.asarray(fixed_nodes, int)[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(K.shape[0]), fixed)
    lam = scipy.linalg.eigh(K[free][:, free].toarray(), M[free][:, free].toarray(), eigvals_only=True)
    return np.sqrt(np.clip(lam[skip:skip + count], 0, None)) / (2 * np.pi)


def body_frequencies(nodal):
    """Eigenfrequencies (Hz) of the reduced body from its modal stiffness and the invariants' modal mass."""
    inv = invariants(nodal)
    return np.sqrt(scipy.linalg.eigh(inv.K, inv.M_ee, eigvals_only=True)) / (2 * np.pi)


def part(spec):
    return next(b for b in mbsfmu.compile(spec).model.bodies if b.elastic)


# -- reduction against the full model ----------------------------------------------------------------------

def test_craig_bampton_from_files_matches_the_full_clamped_model(tmp_path):
    """tet10 bar, end face tied (RBE2) to a reference point: 12 CB modes through the scene; the reduced body's
    K_ee, M_ee (from the consistent-mass invariants) give the full clamped model's first six within 0.5 %."""
    X, M, K = bar()
    write_mm(tmp_path, X, M, K)
    root = np.flatnonzero(X[:, 0] == 0).tolist()
    spec = scene(tmp_path, f"{{{MM}, node_sets: {{root: {root}}}, interface: {{node_set: root, reference: [0, 0.05, 0.05]}}, modes: 12, keep: [{int(np.argmax(X.sum(1)))}]}}")
    got = body_frequencies(part(spec).nodal)[:6]
    ref = dense_frequencies(K, M, root)
    assert np.abs(got / ref - 1).max() < 0.005
    assert np.abs(got / ref - 1).max() < 1e-7          # fixed-interface modes of this interface are exact
    nodal = part(spec).nodal
    assert nodal.nodes == 2 and np.all(nodal.Phi[0] == 0)   # the reference (clamped), then the kept node


def test_craig_bampton_node_set_interface_converges_to_the_full_model():
    """Interface without a reference point: the frame follows the interface's mean rigid motion (T_rᵀ u_I = 0)
    and its deformation is kept by static constraint modes.  Reference: the full tet10 model under the same six
    constraints (dense LAPACK on their null space).  10 fixed-interface modes: first six within 0.5 %."""
    X, M, K = bar()
    root = np.flatnonzero(X[:, 0] == 0)
    r = cms.reduce(fe.FEModel(X, M, K, {}, "bar"), interface=root, keep=[0], modes=10)
    idofs = (3 * root[:, None] + np.arange(3)).ravel()
    C = np.zeros((6, K.shape[0]))
    C[:, idofs] = cms.rigid_fields(X[root]).T
    Z = scipy.linalg.null_space(C)
    lam = scipy.linalg.eigh(Z.T @ (K @ Z), Z.T @ (M @ Z), eigvals_only=True)[:6]
    ref = np.sqrt(lam) / (2 * np.pi)
    assert len(r["frequencies"]) == 10 + 3 * len(root) - 6
    assert np.abs(r["frequencies"][:6] / ref - 1).max() < 0.005, (r["frequencies"][:6], ref)
    assert np.allclose(body_frequencies(cms.nodal_data(r))[:6], r["frequencies"][:6], rtol=1e-9)


def test_free_modes_match_the_full_model_and_satisfy_mean_axes():
    X, M, K = bar(p2=False, nx=8)
    model = fe.FEModel(X, M, K, {}, "bar")
    r = cms.reduce(model, "free", keep=[0, len(X) - 1], modes=8)
    ref = dense_frequencies(K, M, skip=6, count=8)
    assert np.allclose(r["frequencies"], ref, rtol=1e-8)
    inv = invariants(cms.nodal_data(r))
    assert np.abs(inv.C_t).max() < 1e-12 * inv.m                      # ∫Φ dm = 0
    assert np.abs(inv.C_r0).max() < 1e-12 * inv.m * L                 # ∫R̃Φ dm = 0 (mean axes)
    assert np.allclose(body_frequencies(cms.nodal_data(r)), ref, rtol=1e-8)


def test_free_modes_with_an_rbe2_reference():
    """Free modes with the end face tied rigidly to a reference point.  Reference: the full model constrained
    to a rigid end face (dense LAPACK on the null space of the face's 3n − 6 deformation components); the
    reference node's Φ, Ψ move the face nodes rigidly (u = Φ_R q + Ψ_R q × (X − X_R)); mean axes."""
    X, M, K = bar(p2=False, nx=8)
    root = np.flatnonzero(X[:, 0] == 0)
    ref_point = np.array([-0.1, 0.05, 0.05])                   # off the body: where a joint would sit
    r = cms.reduce(fe.FEModel(X, M, K, {}, "bar"), "free", interface=root, reference=ref_point, keep=root.tolist(), modes=6)
    U = np.linalg.svd(cms.rigid_fields(X[root]))[0]
    C = np.zeros((3 * len(root) - 6, K.shape[0]))
    C[:, (3 * root[:, None] + np.arange(3)).ravel()] = U[:, 6:].T
    Z = scipy.linalg.null_space(C)
    lam = scipy.linalg.eigh(Z.T @ (K @ Z), Z.T @ (M @ Z), eigvals_only=True)[6:12]
    assert np.allclose(r["frequencies"], np.sqrt(lam) / (2 * np.pi), rtol=1e-8)
    Phi_R, Psi_R = r["Phi"][0], r["Psi"][0]
    for P, X_P in zip(r["Phi"][1:], X[root]):
        assert np.allclose(P, Phi_R + np.cross(Psi_R.T, X_P - ref_point).T, atol=1e-12)
    inv = invariants(cms.nodal_data(r))
    assert np.abs(inv.C_t).max() < 1e-12 * inv.m and np.abs(inv.C_r0).max() < 1e-12 * inv.m * L


def eigenvalues_below(K, M, lam):
    """Number of eigenvalues of the full K x = λ M x below lam: Sylvester's inertia of K − lam·M (dense LDLᵀ)."""
    _, D, _ = scipy.linalg.ldl((K - lam * M).toarray())    # D: 1×1 and 2×2 blocks, so tridiagonal
    return int(np.count_nonzero(scipy.linalg.eigvalsh_tridiagonal(np.diag(D), np.diag(D, 1)) < 0))


def test_a_slender_parts_low_modes_are_not_taken_for_rigid_ones():
    """A 2 m × 40 mm × 5 mm strip in 8 tet10 cells: its first free and clamped eigenvalues lie below 1e-9 of the
    scale max K_ii/M_ii (which grows with mesh refinement) yet are elastic: free modes find exactly the six rigid
    ones, Craig–Bampton accepts the clamped face, and the reduced eigenvalues bracket the full model's within
    1e-4 by Sylvester's law (any dense factorization's roundoff here is ~ε·max(K_ii/M_ii)/λ ≈ 1e-5)."""
    X, M, K = bar(nx=8, n=1, size=(2.0, 0.04, 0.005))
    model = fe.FEModel(X, M, K, {}, "strip")
    root = np.flatnonzero(X[:, 0] == 0)
    keep = np.setdiff1d(np.arange(K.shape[0]), (3 * root[:, None] + np.arange(3)).ravel())
    scale = float(np.max(K.diagonal() / M.diagonal()))
    for Phi, rigid, dofs in ((cms.free_modes(K, M, cms.rigid_fields(X), "strip", modes=3)[0], 6, slice(None)),
                             (cms.craig_bampton(model, root, modes=3)[0], 0, keep)):
        Kf, Mf, V = K[dofs][:, dofs], M[dofs][:, dofs], Phi[dofs]
        lam = scipy.linalg.eigvalsh(V.T @ (Kf @ V), V.T @ (Mf @ V))
        assert lam[0] < 1e-9 * scale                                     # the premise: below the old bound
        for k, lk in enumerate(lam):     # the k-th elastic eigenvalue of the full model lies within 1e-4 of lk
            assert [eigenvalues_below(Kf, Mf, lk * f) for f in (1 - 1e-4, 1 + 1e-4)] == [rigid + k, rigid + k + 1]


def test_cutoff_gives_exactly_the_modes_below_it():
    X, M, K = bar(p2=False)
    root = np.flatnonzero(X[:, 0] == 0)
    ref = dense_frequencies(K, M, root, count=8)
    cutoff = 0.5 * (ref[4] + ref[5])
    r = cms.reduce(fe.FEModel(X, M, K, {}, "bar"), interface=root, reference=[0, 0, 0], cutoff_hz=cutoff)
    assert len(r["frequencies"]) == 5 and np.allclose(r["frequencies"], ref[:5], rtol=1e-8)


# -- the factorizations: CHOLMOD's Cholesky (cvxopt, the fe extra) and SuperLU's LU without it ------------

def _factorization(monkeypatch, cvxopt):
    """cms's factorizations as with cvxopt installed (the Cholesky, and AMD orders the LU) or without it; the
    list of the Cholesky's calls: (order of the matrix, factored: else not positive definite)."""
    calls = []
    if not cvxopt:
        monkeypatch.setattr(cms, "_cholesky", lambda A: None)
        monkeypatch.setattr(cms, "_amd", lambda A: None)
        return calls
    pytest.importorskip("cvxopt")
    cholesky = cms._cholesky

    def spy(A):
        solve = cholesky(A)
        calls.append((A.shape[0], solve is not None))
        return solve
    monkeypatch.setattr(cms, "_cholesky", spy)
    return calls


def _rectangular_bar():
    """A tet10 bar of 1275 DOFs with a 100 × 60 mm section (no two bending modes alike), its x = 0 face."""
    X, M, K = bar(nx=8, n=2, size=(L, H, 0.6 * H))
    return X, M, K, np.flatnonzero(X[:, 0] == 0)


@pytest.mark.parametrize("cvxopt", [True, False], ids=["cholmod", "superlu"])
def test_either_factorization_gives_the_full_models_modes_and_cutoff_count(monkeypatch, cvxopt):
    """Craig–Bampton of a clamped bar with a cut-off between the full model's 6th and 7th frequencies (dense
    LAPACK): exactly six modes (the LU's inertia count) at the full model's frequencies (eigsh on the Cholesky
    or on the LU) to 1e-8 (the dense solve's own roundoff at the first: 1e-9)."""
    calls = _factorization(monkeypatch, cvxopt)
    X, M, K, root = _rectangular_bar()
    ref = dense_frequencies(K, M, root, count=8)
    r = cms.reduce(fe.FEModel(X, M, K, {}, "bar"), interface=root, reference=[0, 0, 0],
                   cutoff_hz=0.5 * (ref[5] + ref[6]))
    assert len(r["frequencies"]) == 6 and np.allclose(r["frequencies"], ref[:6], rtol=1e-8, atol=0)
    assert [ok for _, ok in calls] == ([True, True] if cvxopt else [])   # the mass check, then K − σM


@pytest.mark.parametrize("cvxopt", [True, False], ids=["cholmod", "superlu"])
def test_an_indefinite_stiffness_is_one_line_naming_its_negative_eigenvalues(monkeypatch, cvxopt):
    """K − cM, c between the full clamped model's 3rd and 4th eigenvalues (dense LAPACK): three negative
    eigenvalues.  The Cholesky of K − σM fails (with cvxopt, even where the caller set cvxopt to LDLᵀ, which
    would not fail), the LU's negative pivots count them (Sylvester): one ModelError line that says three."""
    calls = _factorization(monkeypatch, cvxopt)
    if cvxopt:
        from cvxopt import cholmod
        monkeypatch.setitem(cholmod.options, "supernodal", 0)
    X, M, K, root = _rectangular_bar()
    f = dense_frequencies(K, M, root, count=4)
    c = (np.pi * (f[2] + f[3])) ** 2            # (2π · their mean)²
    with pytest.raises(ModelError) as err:
        cms.reduce(fe.FEModel(X, M, sp.csr_matrix(K - c * M), {}, "bar"), interface=root, reference=[0, 0, 0],
                   modes=4)
    text = str(err.value)
    assert "\n" not in text and "not positive semi-definite (3 eigenvalue(s) below" in text, text
    assert calls == ([(K.shape[0] // 3, True), (K.shape[0] - 3 * len(root), False)] if cvxopt else [])
    assert not cvxopt or cholmod.options == {"supernodal": 0}


# -- invariants from the consistent mass ----------------------------------------------------------------

def test_box_moments_are_the_closed_form_integrals():
    """m = ρabc, S0 = m c, S_RR = ∫ρ x xᵀ dV of a box [0,a]×[0,b]×[0,c] (exact for P1 and P2 interpolation)."""
    a, b, c = 0.3, 0.2, 0.1
    for p2 in (False, True):
        X, M, K = bar(p2=p2, nx=3, n=2, size=(a, b, c))
        mo = cms.moments(fe.FEModel(X, M, K, {}, "box"), np.zeros((len(X), 3, 1)))
        m = RHO * a * b * c
        half = np.array([a, b, c]) / 2
        second = m * (np.outer(half, half) + np.diag(np.array([a, b, c]) ** 2 / 12))
        assert np.isclose(mo.m, m, rtol=1e-13)
        assert np.allclose(mo.S0, m * half, rtol=1e-13)
        assert np.allclose(mo.S_RR, second, rtol=1e-12)


def test_lumped_mass_model_equals_the_nodal_path():
    """A diagonal (lumped) consistent mass: the FE quadratic forms equal the sums over mass points to 1e-12."""
    rng = np.random.default_rng(3)
    N, n = 7, 3
    X, masses, Phi = rng.normal(size=(N, 3)), rng.uniform(0.5, 2, N), rng.normal(size=(N, 3, n))
    model = fe.FEModel(X, sp.csr_matrix(sp.kron(sp.diags(masses), sp.eye(3))), sp.csr_matrix((3 * N, 3 * N)), {}, "lumped")
    got = cms.moments(model, Phi)
    ref = MassPoints(masses, X, np.zeros((N, 3, 3)), Phi, np.zeros((N, 3, n))).moments()
    for name in ("m", "S0", "S_RR", "C_t", "A", "B", "M_ee"):
        assert np.allclose(getattr(got, name), getattr(ref, name), rtol=1e-12, atol=1e-12), name


# -- readers -----------------------------------------------------------------------------------------------

def write_abaqus(folder, X, M, K, labels):
    """The model as Abaqus writes it: *NODE/*NSET in an .inp, lower triangles as FORMAT=MATRIX INPUT .mtx lines."""
    lines = ["*HEADING", "** written by the test", "*NODE"]
    lines += [f"{lab}, {float(x)!r}, {float(y)!r}, {float(z)!r}" for lab, (x, y, z) in zip(labels, X)]
    root = labels[X[:, 0] == 0]
    lines += ["*NSET, NSET=ROOT"] + [", ".join(map(str, root[i:i + 8])) for i in range(0, len(root), 8)]
    (folder / "part.inp").write_text("\n".join(lines) + "\n")
    for A, name in ((M, "M.mtx"), (K, "K.mtx")):
        low = sp.tril(A).tocoo()
        rows = [f"{labels[i // 3]}, {i % 3 + 1}, {labels[j // 3]}, {j % 3 + 1}, {float(v)!r}" for i, j, v in zip(low.row, low.col, low.data)]
        (folder / name).write_text("\n".join(rows) + "\n")


def write_abaqus_coordinate(folder, M, K, perm=None):
    """M and K as *MATRIX OUTPUT, FORMAT=COORDINATE writes them (as Exudyn's Abaqus-written test data): blank-
    separated `row col value`, 1-based global equation numbers, both triangles; equation e is DOF perm[e - 1]."""
    for A, name in ((M, "M3.mtx"), (K, "K3.mtx")):
        coo = sp.coo_matrix(A)
        eq = np.argsort(perm) if perm is not None else np.arange(A.shape[0])   # DOF → its equation
        lines = [f"{eq[i] + 1} {eq[j] + 1} {v: .15e}" for i, j, v in zip(coo.row, coo.col, coo.data)]
        (folder / name).write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("dof_map", ["node-major", "direction-major", "file"])
def test_abaqus_coordinate_files_read_as_exudyn_reads_them(tmp_path, dof_map):
    """FORMAT=COORDINATE files (row col value) against Exudyn's FEMinterface.Read…MatrixFromAbaqus (its reader of
    them) and against the matrices written; the FORMAT=MATRIX INPUT files of the same model give the same model."""
    exudyn_fem = pytest.importorskip("exudyn.FEM")
    X, M, K = bar(p2=False, nx=3)
    N = len(X)
    labels = np.arange(1, N + 1)
    write_abaqus(tmp_path, X, M, K, labels)
    perm = {"node-major": None, "direction-major": (3 * np.arange(N)[None, :] + np.arange(3)[:, None]).ravel(),
            "file": np.random.default_rng(1).permutation(3 * N)}[dof_map]
    write_abaqus_coordinate(tmp_path, M, K, perm)
    arg = dof_map
    if dof_map == "file":
        (tmp_path / "dofs.txt").write_text("".join(f"{p // 3} {'xyz'[p % 3]}\n" for p in perm))
        arg = tmp_path / "dofs.txt"
    coordinate = fe.from_abaqus(tmp_path / "M3.mtx", tmp_path / "K3.mtx", tmp_path / "part.inp", dof_map=arg)
    matrix_input = fe.from_abaqus(tmp_path / "M.mtx", tmp_path / "K.mtx", tmp_path / "part.inp")
    fem = exudyn_fem.FEMinterface()
    fem.ReadMassMatrixFromAbaqus(str(tmp_path / "M3.mtx"))
    fem.ReadStiffnessMatrixFromAbaqus(str(tmp_path / "K3.mtx"))
    order = np.arange(3 * N) if perm is None else np.argsort(perm)   # Exudyn keeps the file's equation order
    for ours, theirs, written in ((coordinate.M, fem.massMatrix, M), (coordinate.K, fem.stiffnessMatrix, K)):
        theirs = sp.csr_matrix(theirs)[order][:, order]
        scale = abs(written).max()
        assert abs(ours - theirs).max() <= 1e-15 * scale and abs(ours - written).max() <= 1e-15 * scale
    assert abs(matrix_input.M - coordinate.M).max() <= 1e-15 * abs(M).max()
    assert abs(matrix_input.K - coordinate.K).max() <= 1e-15 * abs(K).max()
    assert np.array_equal(coordinate.nodes, X) and sorted(coordinate.node_sets) == ["root"]


def test_abaqus_coordinate_files_in_a_scene_and_their_errors(tmp_path):
    """`format: abaqus` takes either layout (by its columns); equations beyond the .inp's nodes and a dof_map
    beside MATRIX INPUT files are refused with the file's name."""
    X, M, K = bar(p2=False, nx=3)
    write_abaqus(tmp_path, X, M, K, np.arange(1, len(X) + 1))
    write_abaqus_coordinate(tmp_path, M, K)
    iface = "interface: {node_set: root, reference: [0, 0, 0]}, modes: 2"
    a = scene(tmp_path, f"{{mass: M3.mtx, stiffness: K3.mtx, nodes: part.inp, format: abaqus, {iface}}}")
    b = scene(tmp_path, f"{{mass: M.mtx, stiffness: K.mtx, nodes: part.inp, format: abaqus, {iface}}}")
    fa, fb = (s.spec["bodies"][0]["elastic"]["fe"] for s in (a, b))
    assert np.allclose(fa["frequencies"], fb["frequencies"], rtol=1e-10)
    assert np.allclose(fa["frequencies"], dense_frequencies(K, M, np.flatnonzero(X[:, 0] == 0), count=2), rtol=1e-8)
    (tmp_path / "K3.mtx").write_text((tmp_path / "K3.mtx").read_text() + f"{3 * len(X) + 1} 1 1.0\n")
    with pytest.raises(ModelError, match=r"K3.mtx: equation %d, but the %d nodes" % (3 * len(X) + 1, len(X))):
        scene(tmp_path, f"{{mass: M3.mtx, stiffness: K3.mtx, nodes: part.inp, format: abaqus, {iface}}}")
    with pytest.raises(ModelError, match="M.mtx: a FORMAT=MATRIX INPUT file names its nodes"):
        scene(tmp_path, f"{{mass: M.mtx, stiffness: K.mtx, nodes: part.inp, format: abaqus, dof_map: direction-major, {iface}}}")


def test_abaqus_matrix_input_files_give_the_same_body(tmp_path):
    X, M, K = bar(p2=False)
    labels = 1000 + 7 * np.arange(len(X))[::-1]           # labels neither 1-based nor in order
    write_abaqus(tmp_path, X, M, K, labels)
    spec = scene(tmp_path, "{mass: M.mtx, stiffness: K.mtx, nodes: part.inp, format: abaqus, interface: {node_set: root, reference: [0, 0, 0]}, modes: 6}")
    ref = dense_frequencies(K, M, np.flatnonzero(X[:, 0] == 0))
    assert np.allclose(body_frequencies(part(spec).nodal), ref, rtol=1e-8)


@pytest.mark.parametrize("layout", ["direction-major", "file"])
def test_dof_maps_reorder_the_matrices(tmp_path, layout):
    X, M, K = bar(p2=False)
    N = len(X)
    rng = np.random.default_rng(0)
    perm = (3 * np.arange(N)[None, :] + np.arange(3)[:, None]).ravel() if layout == "direction-major" else rng.permutation(3 * N)
    write_mm(tmp_path, X, M[perm][:, perm], K[perm][:, perm])          # row r of the files is DOF perm[r]
    dof_map = layout
    if layout == "file":
        (tmp_path / "dofs.txt").write_text("".join(f"{p // 3} {'xyz'[p % 3]}\n" for p in perm))
        dof_map = "dofs.txt"
    model = fe.from_matrix_market(tmp_path / "M.mtx", tmp_path / "K.mtx", tmp_path / "nodes.csv", dof_map if layout == "direction-major" else tmp_path / dof_map)
    assert abs(model.M - M).max() == 0 and abs(model.K - K).max() == 0


# -- a free-floating FE body -------------------------------------------------------------------------------

def test_free_floating_fe_body_conserves_energy_and_momentum(tmp_path):
    X, M, K = bar(p2=False, nx=6)
    write_mm(tmp_path, X, M, K)
    spec = scene(tmp_path, f"{{{MM}, method: free, modes: 4, keep: [0]}}",
                 joint="{type: free, initial_velocity: {velocity: [0.3, -0.2, 0.1], omega: [2, 5, -3]}}",
                 extra="      coordinates: [part.e1, part.e2, part.e3, part.e4]\n      initial_velocity: {part.e1: 0.5, part.e3: -0.2}\n")
    ev = mbsfmu.compile(spec)
    t, Y, YD = mbsfmu.simulate(spec, stop=0.02, step=0.002, method="dopri5", rtol=1e-11, atol=1e-13)
    energy = np.array([ev.energy(y, yd) for y, yd in zip(Y, YD)])
    momentum = np.array([(ev.equations(y, yd, 0.0)[0] @ yd)[:3] for y, yd in zip(Y, YD)])  # ∂T/∂ẋ, x cyclic
    elastic = np.ptp([0.5 * y[-4:] @ part(spec).nodal.stiffness @ y[-4:] for y in Y])
    assert elastic > 1e-4 * energy[0]                                 # the modes really exchange energy
    assert np.abs(energy / energy[0] - 1).max() < 1e-8
    assert np.abs(momentum - momentum[0]).max() < 1e-8 * np.abs(momentum[0]).max()


# -- cache -------------------------------------------------------------------------------------------------

def test_reduction_is_cached_by_its_inputs(tmp_path, monkeypatch):
    X, M, K = bar(p2=False)
    write_mm(tmp_path, X, M, K)
    yaml = f"{{{MM}, interface: {{nodes: {np.flatnonzero(X[:, 0] == 0).tolist()}, reference: [0, 0, 0]}}, modes: 3}}"
    first = part(scene(tmp_path, yaml)).nodal
    entries = list((tmp_path / "cache" / "fe").glob("*.npz"))
    assert len(entries) == 1
    monkeypatch.setattr(cms, "reduce", lambda *a, **k: pytest.fail("reduced again"))
    assert np.array_equal(part(scene(tmp_path, yaml)).nodal.stiffness, first.stiffness)
    entries[0].write_bytes(b"not an npz")                               # a damaged entry is computed again
    monkeypatch.undo()
    monkeypatch.setenv("MBSFMU_CACHE", str(tmp_path / "cache"))
    assert np.array_equal(part(scene(tmp_path, yaml)).nodal.stiffness, first.stiffness)
    K2 = K.copy()
    K2[3, 3] *= 1.01                                                    # other bytes, another entry
    write_mm(tmp_path, X, M, K2)
    part(scene(tmp_path, yaml))
    assert len(list((tmp_path / "cache" / "fe").glob("*.npz"))) == 2
    root = np.flatnonzero(X[:, 0] == 0).tolist()
    for members in (root, root[:3]):                                    # a node set's members are inputs too
        part(scene(tmp_path, f"{{{MM}, node_sets: {{root: {members}}}, interface: {{node_set: root, reference: [0, 0, 0]}}, modes: 3}}"))
    assert len(list((tmp_path / "cache" / "fe").glob("*.npz"))) == 4


@pytest.mark.parametrize("damage", ["truncated", "empty", "bit flip", "tampered", "other key", "wrong shape", "folder"])
def test_a_damaged_or_tampered_cache_entry_is_computed_again(tmp_path, monkeypatch, damage):
    """A cache entry is never trusted: a truncated, empty or bit-flipped file, one whose content was changed and
    written again as a valid .npz (stiffness × 4), one made for another key, or of other shapes:
    each is reduced again (results equal the fresh reduction, not the entry) and rewritten, then used."""
    X, M, K = bar(p2=False, nx=3)
    write_mm(tmp_path, X, M, K)
    yaml = f"{{{MM}, interface: {{nodes: {np.flatnonzero(X[:, 0] == 0).tolist()}, reference: [0, 0, 0]}}, modes: 2}}"
    fresh = scene(tmp_path, yaml).spec["bodies"][0]["elastic"]["fe"]
    (entry,) = (tmp_path / "cache" / "fe").glob("*.npz")
    data = entry.read_bytes()
    with np.load(entry) as z:
        arrays = {k: z[k] for k in z.files}
    if damage == "truncated":
        entry.write_bytes(data[: len(data) // 2])
    elif damage == "empty":
        entry.write_bytes(b"")
    elif damage == "bit flip":   # in the stiffness values: the zip's CRC or the digest catches it
        at = data.index(arrays["stiffness"].tobytes()) + 3
        entry.write_bytes(data[:at] + bytes([data[at] ^ 0x10]) + data[at + 1:])
    elif damage in ("tampered", "other key"):
        if damage == "tampered":
            arrays["stiffness"] = 4 * arrays["stiffness"]
        else:   # a valid entry of another reduction (other modes) copied under this key
            other = scene(tmp_path, yaml.replace("modes: 2", "modes: 1")).spec["bodies"][0]["elastic"]["fe"]
            (other_entry,) = set((tmp_path / "cache" / "fe").glob("*.npz")) - {entry}
            with np.load(other_entry) as z:
                arrays = {k: z[k] for k in z.files}
            assert len(other["frequencies"]) == 1
        np.savez(entry, **arrays)
    elif damage == "wrong shape":
        np.savez(entry, **dict(arrays, stiffness=arrays["stiffness"][:1]))
    else:
        entry.unlink()
        entry.mkdir()
    again = scene(tmp_path, yaml).spec["bodies"][0]["elastic"]["fe"]
    assert again == fresh
    if damage != "folder":   # rewritten: the next load takes it from the cache
        monkeypatch.setattr(cms, "reduce", lambda *a, **k: pytest.fail("reduced again"))
        assert scene(tmp_path, yaml).spec["bodies"][0]["elastic"]["fe"] == fresh


def test_a_cache_entry_gives_back_the_arrays_as_built(tmp_path):
    """Every array of a reduced body comes back from the cache as built: values, shapes and dtypes (the integer
    stress_nodes and stress_counts stay integers)."""
    X, M, K = bar(p2=False, nx=3)
    write_mm(tmp_path, X, M, K)
    model = fe.FEModel(X, M, K, {}, "bar", stress=lambda U, at: np.ones((len(at), 6, U.shape[1])))
    stress = [[1, 2], 5]

    def build():
        return cms.reduce(model, interface=np.flatnonzero(X[:, 0] == 0), reference=[0, 0, 0], modes=2, stress=stress)
    fresh = cms.reduce_cached([tmp_path / "K.mtx"], {"stress": stress}, build)
    cached = cms.reduce_cached([tmp_path / "K.mtx"], {"stress": stress}, lambda: pytest.fail("reduced again"))
    assert sorted(cached) == sorted(fresh)
    for k, v in fresh.items():
        assert cached[k].dtype == v.dtype and cached[k].shape == v.shape and np.array_equal(cached[k], v), k


# -- hostile input -----------------------------------------------------------------------------------------

def _break(kind, folder, X, M, K):
    """Write a broken model of the given kind; return the fe: mapping of the scene."""
    root = np.flatnonzero(X[:, 0] == 0).tolist()
    base = f"{MM}, interface: {{nodes: {root}, reference: [0, 0, 0]}}"
    if kind == "non-symmetric":
        K = K.tolil()
        K[0, 5] += 1e3 * abs(K).max()
        write_mm(folder, X, M, K.tocsr())
    elif kind == "indefinite":
        write_mm(folder, X, M, K - 1e-3 * abs(K).max() * sp.eye(K.shape[0]))
    elif kind == "dof-map-mismatch":
        write_mm(folder, X[:-1], M, K)
    elif kind == "mass-couples-directions":
        M = M.tolil()
        M[0, 1] = M[1, 0] = 0.1 * M[0, 0]
        write_mm(folder, X, M.tocsr(), K)
    elif kind == "indefinite-mass":                               # positive diagonal, one negative eigenvalue
        Ms = M[0::3, 0::3].tolil()
        Ms[0, 1] = Ms[1, 0] = 3 * max(Ms[0, 0], Ms[1, 1])
        write_mm(folder, X, sp.csr_matrix(sp.kron(Ms.tocsr(), sp.eye(3))), K)
    elif kind == "missing-node-set":
        write_mm(folder, X, M, K)
        base = f"{MM}, interface: {{node_set: flange, reference: [0, 0, 0]}}"
    elif kind == "huge-header":
        write_mm(folder, X, M, K)
        (folder / "K.mtx").write_text("%%MatrixMarket matrix coordinate real general\n1000000 1000000 1000000000000\n1 1 1.0\n")
    elif kind == "2-GB-file":
        write_mm(folder, X, M, K)
        with open(folder / "K.mtx", "r+b") as f:
            f.truncate(2 * 2**30)
    elif kind == "no-rigid-modes":                                   # free modes of a supported model
        write_mm(folder, X, M, K + 1e-2 * abs(K).max() * sp.eye(K.shape[0]))
        base = f"{MM}, method: free, keep: [0]"
    elif kind == "rotational-dofs":
        write_abaqus(folder, X, M, K, np.arange(1, len(X) + 1))
        text = (folder / "K.mtx").read_text().replace(", 3, ", ", 5, ", 1)
        (folder / "K.mtx").write_text(text)
        base = "mass: M.mtx, stiffness: K.mtx, nodes: part.inp, format: abaqus, interface: {node_set: root, reference: [0, 0, 0]}"
    elif kind == "outside-the-folder":
        write_mm(folder, X, M, K)
        base = base.replace("M.mtx", "../M.mtx")
    elif kind == "collinear-interface":
        write_mm(folder, X, M, K)
        base = f"{MM}, interface: {{nodes: [{root[0]}], reference: [0, 0, 0]}}"
    elif kind == "fifo":
        write_mm(folder, X, M, K)
        (folder / "K.mtx").unlink()
        os.mkfifo(folder / "K.mtx")
    elif kind == "garbage-entries":
        write_mm(folder, X, M, K)
        with open(folder / "K.mtx", "ab") as f:
            f.write(b"17 x 0.5\n\xff\xfe 3\n")
    elif kind == "entry-out-of-range":
        write_mm(folder, X, M, K)
        text = (folder / "K.mtx").read_text().splitlines()
        text[3] = f"{K.shape[0] + 5} 1 1.0"
        (folder / "K.mtx").write_text("\n".join(text) + "\n")
    elif kind == "unknown-node-label":
        write_abaqus(folder, X, M, K, np.arange(1, len(X) + 1))
        (folder / "M.mtx").write_text((folder / "M.mtx").read_text() + "99999, 1, 99999, 1, 1.0\n")
        base = "mass: M.mtx, stiffness: K.mtx, nodes: part.inp, format: abaqus, interface: {node_set: root, reference: [0, 0, 0]}"
    elif kind == "no-kept-node":
        write_mm(folder, X, M, K)
        base = f"{MM}, method: free"
    elif kind == "one-node-interface":
        write_mm(folder, X, M, K)
        base = f"{MM}, interface: {{nodes: [{root[0]}]}}, keep: [0]"
    return "{" + base + "}"


HOSTILE = {"non-symmetric": "not symmetric", "indefinite": "not positive semi-definite",
           "dof-map-mismatch": "need", "mass-couples-directions": "consistent mass",
           "missing-node-set": "no node set 'flange'", "huge-header": "1,000,000,000,000 entries",
           "2-GB-file": "MiB", "no-rigid-modes": "rigid-body modes", "rotational-dofs": "DOF 5",
           "outside-the-folder": "outside", "collinear-interface": "does not hold the body",
           "one-node-interface": "do not fix a frame", "fifo": "not a regular file",
           "garbage-entries": "cannot read the matrix", "entry-out-of-range": "cannot read the matrix",
           "unknown-node-label": "node label 99999", "no-kept-node": "no node is kept",
           "indefinite-mass": "mass matrix is not positive definite"}


@pytest.mark.parametrize("kind", sorted(HOSTILE))
def test_hostile_fe_input_is_one_model_error_line(tmp_path, kind):
    X, M, K = bar(p2=False, nx=4)
    folder = tmp_path / "scene"
    folder.mkdir()
    fe_yaml = _break(kind, folder, X, M, K)
    start = time.process_time()
    with pytest.raises(ModelError) as err:
        scene(folder, fe_yaml)
    assert time.process_time() - start < 5
    text = str(err.value)
    assert "\n" not in text and "s.yaml:" in text and "bodies.part.elastic.fe" in text, text
    assert HOSTILE[kind] in text, text


# -- the shipped example -----------------------------------------------------------------------------------

def test_check_prints_the_shipped_links_frequencies_of_the_full_model(capsys):
    """`mbsfmu check models/fe_link.yaml`: the reduced body's frequencies are those of the full link (read with
    scipy's own Matrix Market reader) clamped at its root face, to the 4 digits printed; one line, no traceback."""
    from pathlib import Path

    from mbsfmu.cli import main
    models = Path(__file__).resolve().parents[1] / "models"
    M, K = (sp.csr_matrix(scipy.io.mmread(models / "fe" / f"link_{w}.mtx")) for w in ("mass", "stiffness"))
    X = np.loadtxt(models / "fe" / "link_nodes.csv", delimiter=",")
    ref = dense_frequencies(K, M, np.flatnonzero(X[:, 0] == 0), count=4)
    main(["check", str(models / "fe_link.yaml")])
    line = next(x for x in capsys.readouterr().out.splitlines() if "elastic link" in x)
    shown = [float(f) for f in line.split(" at ")[1].split(" Hz")[0].split(", ")]
    assert np.allclose(shown, ref, rtol=5e-4), (shown, ref)
    assert f"mass {RHO * 0.5 * 0.04 * 0.01:g} kg" in line


def test_compiled_scene_size_does_not_depend_on_the_fe_model(tmp_path):
    """Only the reduced body reaches the compiled scene (what both FMU kinds carry): a tet4 and a tet10 mesh of
    the bar (4× the DOFs) with the same modes and kept nodes compile to the same number of bytes."""
    from mbsfmu.simulation import compiled
    sizes = []
    for p2 in (False, True):
        folder = tmp_path / f"p2_{p2}"
        folder.mkdir()
        X, M, K = bar(p2=p2)
        write_mm(folder, X, M, K)
        tip = int(np.argmax(X.sum(1)))
        spec = scene(folder, f"{{{MM}, interface: {{nodes: {np.flatnonzero(X[:, 0] == 0).tolist()}, reference: [0, 0, 0]}}, modes: 5, keep: [{tip}]}}")
        sizes.append((K.shape[0], len(compiled(spec.spec)[0])))
    assert sizes[1][0] > 4 * sizes[0][0] and sizes[0][1] == sizes[1][1], sizes


def test_exudyn_computes_the_same_accelerations_from_the_full_fe_matrices():
    """Exudyn's ObjectFFRFreducedOrder, given the full consistent M, K, the nodes and the same Craig–Bampton
    basis, builds its own invariants from M: its accelerations of the free body at a rotated state with ω, q,
    q̇ equal ours from the quadratic-form moments (cms.moments) through ffrf's equations."""
    exu = pytest.importorskip("exudyn")
    from exudyn.FEM import FEMinterface, ObjectFFRFreducedOrderInterface

    from mbsfmu.bodies.ffrf import elastic_forces, mass_matrix, quadratic_forces
    from mbsfmu.bodies.nodal import NodalData
    from mbsfmu.kinematics.rotations import axis_angle
    from test_exudyn_flexible import exudyn_accelerations
    X, M, K = bar(p2=True, nx=3)
    model = fe.FEModel(X, M, K, {}, "bar")
    Phi = cms.craig_bampton(model, np.flatnonzero(X[:, 0] == 0), modes=3)[0]
    n = Phi.shape[1]
    K_ee = Phi.T @ (K @ Phi)
    inv = invariants(NodalData(X[:1], [0.0], Phi[:3, None, :].reshape(1, 3, n), K_ee,
                               mass_points=cms.moments(model, Phi.reshape(len(X), 3, n))))
    S = axis_angle(np.array([1.0, 2.0, 2.0]) / 3.0, 0.7)
    v, w = np.array([0.3, -0.1, -0.2]), np.array([0.4, 1.3, -0.5])          # R components
    q, qd = np.array([1e-4, -4e-5, 2e-5]), np.array([0.02, 0.01, -0.03])
    z = np.linalg.solve(mass_matrix(inv, q), elastic_forces(inv, q, qd) - quadratic_forces(inv, q, qd, w))

    fem = FEMinterface()
    fem.nodes = {"Position": X}
    fem.massMatrix, fem.stiffnessMatrix = sp.csr_matrix(M), sp.csr_matrix(K)
    fem.modeBasis = {"matrix": Phi, "type": "NormalModes"}
    reduced = ObjectFFRFreducedOrderInterface(fem, rigidBodyNodeType="NodeType.RotationRotationVector")
    mbs = exu.SystemContainer().AddSystem()
    obj = reduced.AddObjectFFRFreducedOrder(mbs, initialVelocity=list(S @ v), initialAngularVelocity=list(S @ w),
                                            rotationMatrixRef=S)
    mbs.SetNodeParameter(obj["nGenericODE2"], "initialCoordinates", list(q))
    mbs.SetNodeParameter(obj["nGenericODE2"], "initialCoordinates_t", list(qd))
    ydd = exudyn_accelerations(mbs, 6 + n)
    np.testing.assert_allclose(ydd[:3], S @ z[:3], atol=1e-9 * np.abs(z[:3]).max())       # a_IR (world)
    np.testing.assert_allclose(ydd[6:], z[6:], atol=1e-9 * np.abs(z[6:]).max())          # q̈


def test_cli_prints_one_line_for_a_broken_fe_model(tmp_path):
    import subprocess
    import sys
    X, M, K = bar(p2=False, nx=4)
    write_mm(tmp_path, X, M, K - 1e-3 * abs(K).max() * sp.eye(K.shape[0]))
    (tmp_path / "s.yaml").write_text(f"mbsfmu: 1\nname: t\nbodies:\n  part:\n    parent: world\n    joint: {{type: fixed}}\n"
                                     f"    elastic:\n      fe: {{{MM}, interface: {{nodes: [0, 1, 2], reference: [0, 0, 0]}}}}\n")
    r = subprocess.run([sys.executable, "-m", "mbsfmu.cli", "check", str(tmp_path / "s.yaml")], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 1 and r.stdout == "" and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "not positive semi-definite" in r.stderr, r.stderr


FE_KEYS = ("mass", "stiffness", "nodes", "format", "dof_map", "node_sets", "interface", "method", "modes", "cutoff_hz", "keep",
           "check_tolerance")


VALID = {("node_sets", "null"), ("keep", "[1, 2]"), ("cutoff_hz", "99999"), ("check_tolerance", "99999")}   # no node sets; two nodes; ≤ 100 modes


def test_every_fe_key_with_a_wrong_value_is_a_model_error_at_that_key(tmp_path):
    X, M, K = bar(p2=False, nx=3)
    write_mm(tmp_path, X, M, K)
    for key in FE_KEYS + ("interface.node_set", "interface.nodes", "interface.reference"):
        for value in ("[1, 2]", "{a: 1}", "-1", "1e400", "null", "true", "x", "[[1]]", "99999"):
            base = {"mass": "M.mtx", "stiffness": "K.mtx", "nodes": "nodes.csv", "keep": "[0]",
                    "interface": "{nodes: [0, 1, 2], reference: [0, 0, 0]}"}
            if (key, value) in VALID:
                continue
            if key.startswith("interface."):
                base["interface"] = f"{{{key.split('.')[1]}: {value}}}"
            else:
                base[key] = value
            with pytest.raises(ModelError) as err:
                scene(tmp_path, "{" + ", ".join(f"{k}: {v}" for k, v in base.items()) + "}")
            assert (err.value.key or "").startswith("bodies.part.elastic.fe") and "\n" not in str(err.value), (key, value, str(err.value))


def test_a_kept_node_set_turns_as_the_euler_bernoulli_slope(tmp_path):
    """`keep: [tip]` keeps the end face as one node: its centroid, mean translation Φ and least-squares rotation
    Ψ.  For the first bending mode of the slender tet10 cantilever, the end rotation over the end deflection
    is the Euler–Bernoulli mode's slope ratio φ'(L)/φ(L) (βL = 1.8751) within 0.5 % (measured 0.01 %, 0.15 %); `node:
    tip` and `node: root` (the interface, its reference point) resolve to the kept nodes in outputs."""
    X, M, K = bar(nx=10)
    write_mm(tmp_path, X, M, K)
    root, tip = (np.flatnonzero(X[:, 0] == x).tolist() for x in (0, L))
    spec = scene(tmp_path, f"{{{MM}, node_sets: {{root: {root}, tip: {tip}}}, interface: {{node_set: root, reference: [0, 0.05, 0.05]}}, modes: 2, keep: [tip]}}",
                 extra="outputs:\n  - {body: part, node: tip, quantities: [position]}\n  - {body: part, node: root, quantities: [position], name: hub}\n")
    nodal = part(spec).nodal
    assert np.allclose(nodal.R_RP[1], [L, H / 2, H / 2])
    bl = 1.875104069
    sigma = (np.cosh(bl) + np.cos(bl)) / (np.sinh(bl) + np.sin(bl))
    ratio = bl * (np.sinh(bl) + np.sin(bl) - sigma * (np.cosh(bl) - np.cos(bl))) / (np.cosh(bl) - np.cos(bl) - sigma * (np.sinh(bl) - np.sin(bl)))
    for k in range(2):                                     # the two first bending modes (about y and about z)
        u, th = nodal.Phi[1][:, k], nodal.Psi[1][:, k]
        lateral = 1 + np.argmax(np.abs(u[1:]))             # y or z deflection
        slope = th[2] if lateral == 1 else -th[1]          # v' = θ_z, w' = −θ_y
        assert abs(slope / u[lateral] * L / ratio - 1) < 0.005, (slope / u[lateral] * L, ratio)
    assert [o["node"] for o in spec.spec["outputs"]] == [1, 0]


def test_node_names_that_are_not_kept_sets_are_refused(tmp_path):
    X, M, K = bar(p2=False, nx=3)
    write_mm(tmp_path, X, M, K)
    fe_yaml = f"{{{MM}, node_sets: {{tip: {np.flatnonzero(X[:, 0] == L).tolist()}}}, interface: {{nodes: [0, 1, 2], reference: [0, 0, 0]}}, keep: [tip]}}"
    with pytest.raises(ModelError, match="keeps no node set 'tp'.*tip") as err:
        scene(tmp_path, fe_yaml, extra="outputs:\n  - {body: part, node: tp}\n")
    assert err.value.key == "outputs[0].node" and err.value.line == 11


def test_slender_solid_bar_has_the_beam_generators_invariants():
    """A tet10 cantilever 1 × 0.1 × 0.05 m (L/h = 20, 16 × 2 × 2 cells) clamped at x = 0 against the built-in Euler–Bernoulli
    beam generator with the same EI, ρA: mass and ∫x² dm exactly, and for the first (flapwise) mode — both
    scaled to a unit largest translation — its frequency, modal mass M_ee, C_t = ∫Φ dm and A = ∫x Φ dm within
    1 % (shear and 3-D effects of the solid)."""
    from mbsfmu.bodies import beam
    b, h = 0.1, 0.05
    X, M, K = bar(nx=16, n=2, size=(L, b, h))
    root = np.flatnonzero(X[:, 0] == 0)
    r = cms.reduce(fe.FEModel(X, M, K, {}, "bar"), interface=root, reference=[0, b / 2, h / 2], keep=[0], modes=1)
    solid = invariants(cms.nodal_data(r))
    generated = beam(L, [E * b * h**3 / 12, E * h * b**3 / 12], RHO * b * h, elements=20, modes=1)
    ref = invariants(generated, dynamic_stiffening=False)
    assert np.isclose(solid.m, ref.m, rtol=1e-12) and np.isclose(solid.S_RR[0, 0], ref.S_RR[0, 0], rtol=1e-12)
    assert np.isclose(r["frequencies"][0], generated.frequencies[0] / (2 * np.pi), rtol=0.01)
    assert np.isclose(solid.M_ee[0, 0], ref.M_ee[0, 0], rtol=0.01), (solid.M_ee, ref.M_ee)
    assert np.isclose(solid.C_t[2, 0], ref.C_t[2, 0], rtol=0.01) and abs(solid.C_t[1, 0]) < 1e-3 * abs(ref.C_t[2, 0])
    assert np.isclose(solid.A[0, 2, 0], ref.A[0, 2, 0], rtol=0.01)


@pytest.mark.parametrize("damage", ["B shape", "nan", "no mass", "indefinite stiffness", "missing", "200 modes"])
def test_damaged_reduced_body_data_are_a_model_error(damage):
    """The reduced body crosses trust boundaries (the cache, an FMU's drawing description): checked on the way in."""
    X, M, K = bar(p2=False, nx=3)
    r = cms.reduce(fe.FEModel(X, M, K, {}, "bar"), interface=np.flatnonzero(X[:, 0] == 0), reference=[0, 0, 0], modes=2)
    r = {k: np.asarray(v).tolist() for k, v in r.items()}
    if damage == "B shape":
        r["B"] = r["B"][:2]
    elif damage == "nan":
        r["A"][0][0][0] = float("nan")
    elif damage == "no mass":
        r["m"] = 0.0
    elif damage == "indefinite stiffness":
        r["stiffness"][0][0] = -1.0
    elif damage == "missing":
        del r["S0"]
    else:
        r["stiffness"] = np.eye(200).tolist()
    with pytest.raises(ModelError, match="bodies.x.elastic.fe"):
        cms.nodal_data(r, key="bodies.x.elastic.fe")


def test_rayleigh_damping_decays_as_the_damped_oscillator(tmp_path):
    """`rayleigh: [α, β]` (D = α M_ee + β K): a one-mode FE body on a fixed joint follows the damped oscillator
    q = e^(−ζωt) (q0 cos ω_d t + ζω q0/ω_d sin ω_d t), ζ = α/2ω + βω/2, ω from the reduced K and M_ee."""
    X, M, K = bar(p2=False, nx=4)
    write_mm(tmp_path, X, M, K)
    alpha, beta = 20.0, 2e-5
    spec = scene(tmp_path, f"{{{MM}, interface: {{nodes: {np.flatnonzero(X[:, 0] == 0).tolist()}, reference: [0, 0, 0]}}, modes: 1}}",
                 extra=f"      rayleigh: [{alpha}, {beta}]\n      initial: {{part.q1: 1.0e-3}}\n")
    inv = part(spec).inv
    omega = np.sqrt(inv.K[0, 0] / inv.M_ee[0, 0])
    zeta = alpha / (2 * omega) + beta * omega / 2
    assert np.isclose(inv.D[0, 0], 2 * zeta * omega * inv.M_ee[0, 0], rtol=1e-12)
    t, Y, _ = mbsfmu.simulate(spec, stop=10 * 2 * np.pi / omega, step=1e-4, method="dop853", rtol=1e-10, atol=1e-14)
    wd = omega * np.sqrt(1 - zeta**2)
    exact = np.exp(-zeta * omega * t) * 1e-3 * (np.cos(wd * t) + zeta * omega / wd * np.sin(wd * t))
    assert 0.01 < zeta < 0.05 and Y[-1, 0] < 0.5e-3
    assert np.abs(Y[:, 0] - exact).max() < 1e-7 * 1e-3


def test_a_solid_mesh_is_assembled_and_reduced_like_matrix_files(tmp_path):
    """`fe: {mesh, material}` (fe_mesh.py assembles it): the reduced tet4 bar has the frequencies of the full
    model assembled here (dense LAPACK, clamped end face) — mesh reading, assembly and reduction in one scene."""
    meshio = pytest.importorskip("meshio")
    X, M, K = bar(p2=False)
    mesh = skfem.MeshTet.init_tensor(*(np.linspace(0, s, k + 1) for s, k in zip((L, H, H), (6, 1, 1))))
    P, T = mesh.p.T, mesh.t.T.copy()
    flip = np.linalg.det(P[T[:, 1:]] - P[T[:, :1]]) < 0                  # VTK order: positive volume
    T[flip, 1], T[flip, 2] = T[flip, 2], T[flip, 1].copy()
    meshio.write(tmp_path / "bar.vtu", meshio.Mesh(P, [("tetra", T)]))
    root = np.flatnonzero(X[:, 0] == 0).tolist()
    spec = scene(tmp_path, f"{{mesh: bar.vtu, material: {{E: {E}, nu: {NU}, rho: {RHO}}}, interface: {{nodes: {root}, reference: [0, 0, 0]}}, modes: 6}}")
    assert np.allclose(body_frequencies(part(spec).nodal), dense_frequencies(K, M, root), rtol=1e-8)
    with pytest.raises(ModelError, match="material"):
        scene(tmp_path, f"{{mesh: bar.vtu, interface: {{nodes: {root}, reference: [0, 0, 0]}}}}")
    with pytest.raises(ModelError, match="not 'mass' beside 'mesh'"):
        scene(tmp_path, f"{{mesh: bar.vtu, mass: M.mtx, material: {{E: 1, nu: 0.3, rho: 1}}}}")


def test_explicit_method_recovers_from_an_unstable_first_trial_step(tmp_path):
    """A free FE body's stiff modes: HINIT's first step for dop853 (rtol 1e-8) lies outside its stability region,
    the trial stages grow until M is indefinite there; the first step is tried again shorter instead of the run
    failing at t = 0, and the run agrees with radau5 at tight tolerance."""
    X, M, K = bar(p2=False, nx=6)
    write_mm(tmp_path, X, M, K)
    spec = scene(tmp_path, f"{{{MM}, method: free, modes: 4, keep: [0]}}",
                 joint="{type: free, initial_velocity: {velocity: [0.3, -0.2, 0.1], omega: [2, 5, -3]}}",
                 extra="      coordinates: [part.e1, part.e2, part.e3, part.e4]\n      initial_velocity: {part.e1: 0.5, part.e3: -0.2}\n")
    _, Y, _ = mbsfmu.simulate(spec, stop=0.02, step=0.002, method="dop853", rtol=1e-8, atol=1e-10)
    _, R, _ = mbsfmu.simulate(spec, stop=0.02, step=0.002, method="radau5", rtol=1e-12, atol=1e-14)
    assert np.abs(Y - R).max() < 1e-9, np.abs(Y - R).max()


# -- how good a reduction is: the full model's frequencies under the same boundary condition ----------------

def _null_space_frequencies(K, M, C, skip, count):
    """Lowest frequencies (Hz) of the full model constrained by C u = 0 (dense LAPACK on C's null space)."""
    Z = scipy.linalg.null_space(C)
    lam = scipy.linalg.eigh(Z.T @ (K @ Z), Z.T @ (M @ Z), eigvals_only=True)[skip:skip + count]
    return np.sqrt(lam) / (2 * np.pi)


def _interface_rows(X, root, fields):
    """Constraint rows acting on the interface DOFs only: fields (3n_I × r) → C (r × 3N)."""
    C = np.zeros((fields.shape[1], 3 * len(X)))
    C[:, (3 * root[:, None] + np.arange(3)).ravel()] = fields.T
    return C


@pytest.mark.parametrize("method, reference", [("craig-bampton", [0, 0.05, 0.05]), ("craig-bampton", None),
                                               ("free", None), ("free", [-0.1, 0.05, 0.05])])
def test_full_model_frequencies_are_the_dense_eigenvalues_under_the_bases_condition(method, reference):
    """The full model's frequencies a reduction is judged by equal dense eigh of the constrained full matrices:
    CB + reference: interface clamped; CB + node set: only its six rigid motions held (T_rᵀ u_I = 0); free:
    nothing held, six rigid modes skipped; free + reference (RBE2): the interface moves rigidly (its 3n_I − 6
    deformation components zero), six rigid modes skipped."""
    X, M, K = bar()
    root = np.flatnonzero(X[:, 0] == 0)
    got = cms.full_frequencies(fe.FEModel(X, M, K, {}, "bar"), method, root, reference, 8)
    rigid = cms.rigid_fields(X[root] - X[root].mean(axis=0))
    U = np.linalg.svd(rigid)[0]
    if method == "craig-bampton":
        ref = (dense_frequencies(K, M, root, count=8) if reference else
               _null_space_frequencies(K, M, _interface_rows(X, root, rigid), 0, 8))
    else:
        ref = (dense_frequencies(K, M, skip=6, count=8) if reference is None else
               _null_space_frequencies(K, M, _interface_rows(X, root, U[:, 6:]), 6, 8))
    assert np.allclose(got, ref, rtol=1e-8, atol=0), (got, ref)


def _check(folder, fe_yaml):
    import subprocess
    import sys
    (folder / "s.yaml").write_text(f"mbsfmu: 1\nname: t\nbodies:\n  part:\n    parent: world\n    joint: {{type: fixed}}\n"
                                   f"    elastic:\n      fe: {{{MM}, keep: [0], {fe_yaml}}}\n")
    return subprocess.run([sys.executable, "-m", "mbsfmu.cli", "check", str(folder / "s.yaml")], capture_output=True,
                          text=True, timeout=120)


def test_check_notes_a_reduction_that_misses_a_mode_of_its_band(tmp_path):
    """CB on the bar's 9-node end face without a reference point, 1 fixed-interface mode: it claims the band up
    to the clamped first frequency, but the full model under the node set's condition (only the face's rigid
    motion held) has two modes there (dense LAPACK), and the reduced body's second is far above: one note line,
    exit status 0.  2 modes reproduce both: no note; check_tolerance above the miss silences it."""
    X, M, K = bar()
    write_mm(tmp_path, X, M, K)
    root = np.flatnonzero(X[:, 0] == 0)
    clamped = dense_frequencies(K, M, root, count=1)[0]
    held = _null_space_frequencies(K, M, _interface_rows(X, root, cms.rigid_fields(X[root])), 0, 3)
    assert np.count_nonzero(held <= clamped) == 2            # the band of 1 fixed-interface mode holds two modes
    iface = f"interface: {{nodes: {root.tolist()}}}"
    r = _check(tmp_path, f"{iface}, modes: 1")
    notes = [x for x in r.stderr.splitlines() if x.startswith("note:")]
    assert r.returncode == 0 and len(notes) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "mode 2 " in notes[0] and "0.01" in notes[0], notes
    shown = next(x for x in r.stdout.splitlines() if "full model" in x).split(": ")[1].split(" Hz")[0]
    assert np.allclose([float(f) for f in shown.split(", ")], held[:2], rtol=5e-4), (shown, held)
    for adequate in ("modes: 2", "modes: 1, check_tolerance: 5"):   # the miss: 4.7 times the full model's
        r = _check(tmp_path, f"{iface}, {adequate}")
        assert r.returncode == 0 and r.stderr == "" and "full model" in r.stdout, (adequate, r.stderr)


def test_shipped_abaqus_plate_matches_its_files_and_plate_theory():
    """models/fe_plate.yaml (Abaqus COORDINATE files): the reduced body's frequencies equal the full model's
    read here from the files' lines and solved densely with the hub edge clamped (RBE2 to a point on it is a
    clamp), and the first is the clamped plate strip's 1.875²/(2πL²)·√(D/ρt), D = Et³/12(1−ν²), within 1 %
    (the strip's width is 1/4 of its length: not quite cylindrical bending)."""
    folder = MODELS / "fe"
    text = (folder / "plate.inp").read_text().split("*NODE\n")[1]
    labels = [int(line.split(",")[0]) for line in text.split("*NSET")[0].splitlines()]
    X = np.array([[float(v) for v in line.split(",")[1:]] for line in text.split("*NSET")[0].splitlines()])
    index = {lab: i for i, lab in enumerate(labels)}

    def matrix(name):
        rows = np.loadtxt(folder / name, delimiter=",")
        i = np.array([3 * index[int(a)] + int(b) - 1 for a, b in rows[:, :2]])
        j = np.array([3 * index[int(a)] + int(b) - 1 for a, b in rows[:, 2:4]])
        A = sp.coo_matrix((rows[:, 4], (i, j)), shape=(3 * len(X),) * 2).tocsr()
        return A + sp.triu(A.T, 1)                       # lower triangle → whole
    M, K = matrix("plate_mass.mtx"), matrix("plate_stiffness.mtx")
    ref = dense_frequencies(K, M, np.flatnonzero(X[:, 0] == 0))
    reduced = body_frequencies(part(mbsfmu.load(MODELS / "fe_plate.yaml").spec).nodal)
    assert np.allclose(reduced, ref[:len(reduced)], rtol=1e-6)
    L, t, E, nu, rho = 0.4, 0.005, 70e9, 0.33, 2700.0
    strip = 1.875 ** 2 / (2 * np.pi * L ** 2) * np.sqrt(E * t ** 3 / (12 * (1 - nu ** 2)) / (rho * t))
    assert abs(reduced[0] / strip - 1) < 0.01
