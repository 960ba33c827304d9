"""FE reduction beyond plain modes (issue 24): static correction modes at load points, RBE3 (averaging)
interfaces and the rigid-body mode test.  References: the full tet10 model solved densely (the inertia-relief
deflection from the bordered system [[K, MR], [(MR)ᵀ, 0]], eigenvalues under constraints from a null space),
the closed-form weighted least-squares rigid fit (weighted centroid and inertia J) and its transpose, the
classic RBE3 load distribution, and Sylvester's law for eigenvalue counts."""

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse

pytest.importorskip("skfem")
from test_fe_reduce import MM, bar, dense_frequencies, scene, write_mm
from test_fe_reduce import part as part_body  # noqa: E402

from mbsfmu.bodies import cms, fe  # noqa: E402
from mbsfmu.bodies.ffrf import invariants  # noqa: E402
from mbsfmu.errors import ModelError  # noqa: E402

L, H = 1.0, 0.1
E, RHO = 2.1e11, 7850.0


pytestmark = pytest.mark.usefixtures("private_fe_cache")  # conftest.py: each test's own FE cache


def dofs(nodes):
    return (3 * np.asarray(nodes)[:, None] + np.arange(3)).ravel()


def closed_fit(X, u, w, P):
    """(u_P, θ) of the weighted least-squares rigid motion of nodes X (n×3) moving by u (n×3) about point P:
    weighted centroid c, mean ū, θ = J⁻¹ Σ w r × (u − ū) with J = Σ w (|r|² I − r rᵀ), u_P = ū + θ × (P − c)."""
    W = w.sum()
    c, ub = w @ X / W, w @ u / W
    r = X - c
    J = sum(wi * (ri @ ri * np.eye(3) - np.outer(ri, ri)) for wi, ri in zip(w, r))
    th = np.linalg.solve(J, sum(wi * np.cross(ri, ui - ub) for wi, ri, ui in zip(w, r, u)))
    return ub + np.cross(th, P - c), th


def rbe3_loads(X, w, P, F, Mo):
    """Nodal forces (n×3) of a force F and moment Mo at P spread as RBE3 does: f_i = w_i F / W + w_i (J⁻¹M_c) × r_i,
    M_c the moment about the weighted centroid (the transpose of closed_fit, by virtual work)."""
    W = w.sum()
    c = w @ X / W
    r = X - c
    J = sum(wi * (ri @ ri * np.eye(3) - np.outer(ri, ri)) for wi, ri in zip(w, r))
    a = np.linalg.solve(J, Mo + np.cross(P - c, F))
    return w[:, None] * F / W + w[:, None] * np.cross(a, r)


def relieved_deflection(X, M, K, f):
    """The free body's static deflection under f balanced by its rigid-body inertia, in mean axes: the bordered
    system K u + M R a = f, (MR)ᵀ u = 0 (dense LAPACK; Rᵀ K = 0 makes a the rigid acceleration)."""
    R = cms.rigid_fields(X)
    MR = M @ R
    A = np.block([[K.toarray(), MR], [MR.T, np.zeros((6, 6))]])
    return np.linalg.solve(A, np.concatenate([f, np.zeros(6)]))[:-6]


def reduced_deflection(r, loads):
    """Static deflection of the reduced body at its kept nodes (k×3 translations, k×3 rotations) for generalized
    loads: q = K_ee⁻¹ (Φᵀ F + Ψᵀ M) over the kept nodes' forces F and moments M (k×3 each)."""
    Phi, Psi = np.asarray(r["Phi"]), np.asarray(r["Psi"])
    F, Mo = loads
    q = np.linalg.solve(r["stiffness"], np.einsum("kin,ki->n", Phi, F) + np.einsum("kin,ki->n", Psi, Mo))
    return Phi @ q, Psi @ q


# -- static correction modes ------------------------------------------------------------------------------

def test_static_correction_gives_the_full_models_inertia_relief_deflection():
    """Free tet10 bar, 4 free modes, load points: a tip corner node (3 forces) and the tip face (6 force and moment
    components, spread as the kept set averages).  For each unit load the reduced body's static deflection at
    the kept nodes equals the full model's inertia-relief deflection (bordered dense solve) to 1e-8 with the
    correction modes; without them the truncated modal sum misses it by more than 1 %.  The normal frequencies
    stay the full model's and every reduced frequency bounds the full one of its index from above (Ritz)."""
    X, M, K = bar(nx=6)
    model = fe.FEModel(X, M, K, {}, "bar")
    tip = np.flatnonzero(X[:, 0] == L)
    corner = int(tip[np.argmax(X[tip].sum(1))])
    other = int(np.flatnonzero(X[:, 0] == 0)[0])
    keep = [corner, other, tip]
    with_c = cms.reduce(model, "free", keep=keep, modes=4, load_points=[corner, tip])
    without = cms.reduce(model, "free", keep=keep, modes=4)
    assert len(with_c["frequencies"]) == 4 + 3 + 6
    w = np.ones(len(tip))
    c = X[tip].mean(0)
    cases = []
    for i in range(3):                                        # unit forces at the corner node
        f = np.zeros(K.shape[0])
        f[3 * corner + i] = 1
        F = np.zeros((3, 3))
        F[0, i] = 1
        cases.append((f, (F, np.zeros((3, 3)))))
    for i in range(6):                                        # unit force / moment on the tip face's centroid
        e = np.eye(6)[i]
        f = np.zeros(K.shape[0])
        f[dofs(tip)] = rbe3_loads(X[tip], w, c, e[:3], e[3:]).ravel()
        F, Mo = np.zeros((3, 3)), np.zeros((3, 3))
        F[2], Mo[2] = e[:3], e[3:]
        cases.append((f, (F, Mo)))
    worst_without = 0
    for f, loads in cases:
        u = relieved_deflection(X, M, K, f).reshape(-1, 3)
        ref_t = np.vstack([u[corner], u[other], closed_fit(X[tip], u[tip], w, c)[0]])
        ref_r = closed_fit(X[tip], u[tip], w, c)[1]
        size = np.abs(ref_t).max()
        t, rot = reduced_deflection(with_c, loads)
        assert np.abs(t - ref_t).max() < 1e-8 * size and np.abs(rot[2] - ref_r).max() < 1e-8 * size / H
        t0, _ = reduced_deflection(without, loads)
        worst_without = max(worst_without, np.abs(t0 - ref_t).max() / size)
    assert worst_without > 0.01, worst_without
    full = dense_frequencies(K, M, skip=6, count=13)
    assert np.allclose(with_c["frequencies"][:4], full[:4], rtol=1e-8)
    assert np.all(with_c["frequencies"] >= full * (1 - 1e-9))
    inv = invariants(cms.nodal_data(with_c))                    # the correction modes keep the mean axes
    assert np.abs(inv.C_t).max() < 1e-12 * inv.m and np.abs(inv.C_r0).max() < 1e-12 * inv.m * L


def test_static_correction_with_an_rbe2_reference():
    """Free modes with the root face tied to a reference point: a unit force at a tip node gives the full
    RBE2-constrained model's inertia-relief deflection (bordered solve on the tied DOFs) at the kept tip node."""
    X, M, K = bar(nx=6)
    model = fe.FEModel(X, M, K, {}, "bar")
    root, tip = np.flatnonzero(X[:, 0] == 0), int(np.argmax(X.sum(1)))
    P = np.array([-0.05, 0.05, 0.05])
    r = cms.reduce(model, "free", interface=root, reference=P, keep=[tip], modes=3, load_points=[tip])
    others = np.setdiff1d(np.arange(len(X)), root)
    T = np.zeros((K.shape[0], 3 * len(others) + 6))      # u_i = u_R + θ_R × (X_i − P) on the face, others free
    T[dofs(others), np.arange(3 * len(others))] = 1
    for i in root:
        for a in range(3):
            T[3 * i + a, -6 + a] = 1
            T[3 * i:3 * i + 3, -3 + a] = np.cross(np.eye(3)[a], X[i] - P)
    Kt, Mt = T.T @ K @ T, T.T @ M @ T
    R = np.vstack([cms.rigid_fields(X[others]), cms.rigid_fields(P[None]), np.hstack([np.zeros((3, 3)), np.eye(3)])])
    A = np.block([[Kt, Mt @ R], [(Mt @ R).T, np.zeros((6, 6))]])
    for i in range(3):
        f = np.zeros(K.shape[0])
        f[3 * tip + i] = 1
        u = T @ np.linalg.solve(A, np.concatenate([T.T @ f, np.zeros(6)]))[:-6]
        F = np.zeros((2, 3))
        F[1, i] = 1
        t, _ = reduced_deflection(r, (F, np.zeros((2, 3))))
        assert np.abs(t[1] - u[dofs([tip])]).max() < 1e-8 * np.abs(u).max()


def test_load_points_through_the_scene_and_their_refusals(tmp_path):
    X, M, K = bar(p2=False, nx=4)
    write_mm(tmp_path, X, M, K)
    tip = np.flatnonzero(X[:, 0] == L).tolist()
    base = f"{MM}, node_sets: {{tip: {tip}}}, keep: [tip], modes: 3"
    spec = scene(tmp_path, f"{{{base}, method: free, load_points: [tip, 0]}}", joint="{type: revolute, axis: [0, 0, 1]}")
    assert len(part_body(spec).nodal.stiffness) == 3 + 6 + 3
    for extra, key, text in ((", load_points: [tip]", "load_points", "free-interface"),           # craig-bampton
                             (", method: free, load_points: [0, 0]", "load_points", "dependent"),
                             (", method: free, load_points: [tap]", "load_points", "no node set 'tap'"),
                             (", method: free, load_points: [-1]", "load_points", "node indices"),
                             (", method: free, load_points: [99999]", "load_points", "does not exist"),
                             (f", method: free, load_points: {[0] * 34}", "load_points", "102 static correction modes asked"),
                             (f", method: free, load_points: {[0] * 33}", "load_points", "3 modes \\+ 99")):
        fe_yaml = f"{{{base}, interface: {{nodes: {tip}}}{extra}}}" if "free" not in extra else f"{{{base}{extra}}}"
        with pytest.raises(ModelError, match=text) as err:
            scene(tmp_path, fe_yaml, joint="{type: revolute, axis: [0, 0, 1]}")
        assert err.value.key == f"bodies.part.elastic.fe.{key}", (extra, err.value.key)


# -- RBE3 (averaging) interfaces ----------------------------------------------------------------------------

def fit_rows(X, w, P):
    """The 6 × 3n matrix of closed_fit (it is linear in u): its columns are the fits of unit displacements."""
    cols = []
    for k in range(3 * len(X)):
        u = np.zeros(3 * len(X))
        u[k] = 1
        cols.append(np.concatenate(closed_fit(X, u.reshape(-1, 3), w, P)))
    return np.array(cols).T


def face_weights(X, face):
    """Weights symmetric about the face's midlines: 3 at its corners, 1 elsewhere."""
    Y = X[face][:, 1:]
    corner = np.all((Y == Y.min(0)) | (Y == Y.max(0)), axis=1)
    return np.where(corner, 3.0, 1.0)


def test_rbe3_craig_bampton_holds_the_weighted_fit_and_matches_the_full_model():
    """Craig–Bampton with the root face averaged (RBE3, corner weights 3) onto a point off the face: the normal
    modes are the full model's with the six weighted-fit constraints (dense LAPACK on their null space, first
    six to 1e-7); the reference point is the frame (Φ = Ψ = 0); the face nodes move, but their closed-form
    weighted rigid fit about the reference is zero in every mode."""
    X, M, K = bar(nx=6)
    root = np.flatnonzero(X[:, 0] == 0)
    w = face_weights(X, root)
    P = np.array([-0.1, 0.05, 0.05])
    r = cms.reduce(fe.FEModel(X, M, K, {}, "bar"), interface=root, reference=P, coupling="rbe3", weights=w,
                   keep=root.tolist(), modes=8)
    C = np.zeros((6, K.shape[0]))
    C[:, dofs(root)] = fit_rows(X[root], w, P)
    Z = scipy.linalg.null_space(C)
    lam = scipy.linalg.eigh(Z.T @ (K @ Z), Z.T @ (M @ Z), eigvals_only=True)[:6]
    assert np.allclose(r["frequencies"][:6], np.sqrt(lam) / (2 * np.pi), rtol=1e-7)
    assert np.allclose(r["full_frequencies"][:6], np.sqrt(lam) / (2 * np.pi), rtol=1e-7)
    Phi = np.asarray(r["Phi"])
    assert np.all(Phi[0] == 0) and np.all(np.asarray(r["Psi"])[0] == 0)
    face = Phi[1:]                                                       # (n_I, 3, modes)
    assert np.abs(face).max() > 0.01                                     # not clamped
    for k in range(face.shape[2]):
        assert np.abs(np.concatenate(closed_fit(X[root], face[:, :, k], w, P))).max() < 1e-10


def test_rbe3_free_reference_is_the_weighted_fit_and_a_symmetric_load_gives_the_mean():
    """Free modes with an RBE3 reference: the modes are the plain free modes (RBE3 adds no stiffness or mass:
    dense full-model frequencies to 1e-8), the reference's Φ, Ψ are the closed-form weighted fit of the face
    nodes' motion about it.  An axial tip load (static correction at the tip face): the reference at the
    weighted centroid of the root face moves by the weighted mean of the full model's face displacements
    (bordered inertia-relief solve), to 1e-8."""
    X, M, K = bar(nx=6)
    root, tip = np.flatnonzero(X[:, 0] == 0), np.flatnonzero(X[:, 0] == L)
    w = face_weights(X, root)
    full = dense_frequencies(K, M, skip=6, count=5)
    for P in (np.array([0.0, 0.02, 0.07]), w @ X[root] / w.sum()):
        r = cms.reduce(fe.FEModel(X, M, K, {}, "bar"), "free", interface=root, reference=P, coupling="rbe3",
                       weights=w, keep=root.tolist() + [tip], modes=5, load_points=[tip])
        assert np.allclose(r["frequencies"][:5], full, rtol=1e-8)
        Phi, Psi = np.asarray(r["Phi"]), np.asarray(r["Psi"])
        for k in range(Phi.shape[2]):
            u_R, th = closed_fit(X[root], Phi[1:1 + len(root), :, k], w, P)
            assert np.allclose(Phi[0, :, k], u_R, atol=1e-12) and np.allclose(Psi[0, :, k], th, atol=1e-12)
    f = np.zeros(K.shape[0])
    f[dofs(tip)] = rbe3_loads(X[tip], np.ones(len(tip)), X[tip].mean(0), np.array([1.0, 0, 0]), np.zeros(3)).ravel()
    u = relieved_deflection(X, M, K, f).reshape(-1, 3)
    F = np.zeros((len(Phi), 3))
    F[-1, 0] = 1
    t, rot = reduced_deflection(r, (F, np.zeros_like(F)))
    mean = w @ u[root] / w.sum()
    assert np.abs(t[0] - mean).max() < 1e-8 * np.abs(u).max() and abs(mean[0]) > 0.1 * np.abs(u).max()


def test_rbe2_and_rbe3_agree_on_a_rigidly_moving_interface():
    """Where the interface moves rigidly (free modes with the face tied by RBE2), any weighted fit of the face
    nodes' motion is that rigid motion: the RBE3 closed form gives the RBE2 reference's Φ, Ψ (1e-12)."""
    X, M, K = bar(p2=False, nx=6)
    root = np.flatnonzero(X[:, 0] == 0)
    P = np.array([-0.05, 0.03, 0.06])
    r = cms.reduce(fe.FEModel(X, M, K, {}, "bar"), "free", interface=root, reference=P, keep=root.tolist(), modes=4)
    Phi, Psi = np.asarray(r["Phi"]), np.asarray(r["Psi"])
    w = np.linspace(1, 4, len(root))
    for k in range(4):
        u_R, th = closed_fit(X[root], Phi[1:, :, k], w, P)
        assert np.allclose(u_R, Phi[0, :, k], atol=1e-12) and np.allclose(th, Psi[0, :, k], atol=1e-12)


def test_rbe3_through_the_scene_and_its_refusals(tmp_path):
    X, M, K = bar(p2=False, nx=4)
    write_mm(tmp_path, X, M, K)
    root = np.flatnonzero(X[:, 0] == 0).tolist()
    base = f"{MM}, node_sets: {{root: {root}}}, modes: 3"
    iface = f"node_set: root, reference: [0, 0.05, 0.05], coupling: rbe3, weights: {[1.0] * len(root)}"
    spec = scene(tmp_path, f"{{{base}, interface: {{{iface}}}}}", extra="outputs:\n  - {body: part, node: root, quantities: [position]}\n")
    body = part_body(spec)
    assert body.nodal.nodes == 1 and np.allclose(body.nodal.R_RP[0], [0, 0.05, 0.05])
    for extra, key, text in (("coupling: rbe4", "interface.coupling", "did you mean 'rbe3'"),
                             ("coupling: rbe2, weights: [1, 1, 1, 1]", "interface.weights", "RBE3"),
                             ("coupling: rbe3, weights: [1, 2]", "interface.weights", "one positive weight per node"),
                             ("coupling: rbe3, weights: [1, 0, 1, 1]", "interface.weights[1]", "positive"),
                             ("coupling: rbe3, weights: 3", "interface.weights", "list of positive numbers")):
        fe_yaml = f"{{{base}, interface: {{nodes: {root}, reference: [0, 0, 0], {extra}}}}}"
        with pytest.raises(ModelError, match=text) as err:
            scene(tmp_path, fe_yaml)
        assert err.value.key == f"bodies.part.elastic.fe.{key}", (extra, err.value.key)
    with pytest.raises(ModelError, match="do not fix a frame"):            # two nodes: a turn about their line
        scene(tmp_path, f"{{{base}, method: free, keep: [0], interface: {{nodes: {root[:2]}, reference: [0, 0, 0], coupling: rbe3}}}}")
    with pytest.raises(ModelError, match="averages the interface onto a reference point") as err:
        scene(tmp_path, f"{{{base}, keep: [0], interface: {{nodes: {root}, coupling: rbe3}}}}")
    assert err.value.key == "bodies.part.elastic.fe.interface.coupling"


# -- rigid-body modes decided against roundoff --------------------------------------------------------------

def rounded(A, digits=8):
    """A's entries printed with `digits` significant digits, as an FE program may write them."""
    A = A.tocoo()
    A.data[A.data == 0] = 0.0
    unit = 10.0 ** (np.floor(np.log10(np.abs(A.data) + (A.data == 0))) - digits + 1)
    return scipy.sparse.csr_matrix((np.round(A.data / unit) * unit, (A.row, A.col)), shape=A.shape)


@pytest.mark.parametrize("part, size, n, meshes", [("strip", (4.0, 0.04, 0.002), 1, (8, 12, 16)),
                                                   ("block", (0.1, 0.1, 0.1), 2, (2, 3, 4))])
def test_rigid_modes_are_found_at_every_mesh_size_and_in_every_unit(part, size, n, meshes):
    """A 4 m × 40 mm × 2 mm strip (its first free eigenvalue 5e-14 of max K_ii/M_ii, below the old fixed bound
    1e-13) and a 0.1 m cube at three mesh sizes: free modes find the six rigid ones; K in other units (× 1e6)
    gives eigenvalues × 1e6 (to 1e-9, or ε·λ_scale/λ₁ where roundoff allows no better: 4e-3 for the strip); the strip's first frequency within 3 % of Euler–Bernoulli's free-free
    (4.7300)² √(EI/ρA)/L², the cube's within 1e-8 of dense LAPACK.  Matrices printed with 8 digits (rigid
    eigenvalues ~1e-9·λ_scale) give the same body to 1e-5."""
    prev = None
    for nx in meshes:
        X, M, K = bar(nx=nx, n=n, size=size)
        R = cms.rigid_fields(X)
        lam = cms.free_modes(K, M, R, part, modes=2)[1]
        resolved = max(1e-9, np.finfo(float).eps * cms._lam_scale(K, M) / lam[0])   # roundoff's relative share
        assert np.allclose(cms.free_modes(1e6 * K, M, R, part, modes=2)[1], 1e6 * lam, rtol=resolved)
        if part == "strip":
            assert lam[0] < 1e-13 * cms._lam_scale(K, M)
            b, t = size[1:]
            eb = 4.7300407**2 * np.sqrt(E * b * t**3 / 12 / (RHO * b * t)) / size[0]**2
            assert abs(np.sqrt(lam[0]) / eb - 1) < 0.03, (nx, np.sqrt(lam[0]) / eb)
        else:
            full = scipy.linalg.eigh(K.toarray(), M.toarray(), eigvals_only=True, subset_by_index=[6, 7])
            assert np.allclose(lam, full, rtol=1e-8)
        prev = lam
    if part == "block":
        assert np.allclose(cms.free_modes(rounded(K), rounded(M), R, part, modes=2)[1], prev, rtol=1e-5)
    else:                # 8 digits cannot hold the strip's bending (its roundoff λ_R is 4e4 × its first λ)
        with pytest.raises(ModelError):
            cms.free_modes(rounded(K), rounded(M), R, part, modes=2)


def test_supports_mechanisms_and_loose_interfaces_are_refused_in_every_unit():
    """A spring to ground at one node (the rigid fields carry energy: supported), two disconnected bars (a
    seventh zero mode), a Craig–Bampton interface of two nodes (an edge: the part turns about it): each one
    ModelError naming it, in SI and with K × 1e6."""
    X, M, K = bar(p2=False, nx=4)
    spring = scipy.sparse.csr_matrix(([1e-3 * K.diagonal().max()] * 3, (range(3), range(3))), shape=K.shape)
    X2 = np.vstack([X, X + [2 * L, 0, 0]])
    two = scipy.sparse.block_diag([K, K]).tocsr(), scipy.sparse.block_diag([M, M]).tocsr()
    for f in (1, 1e6):
        with pytest.raises(ModelError, match="rigid-body motions carry energy"):
            cms.free_modes(f * (K + spring), M, cms.rigid_fields(X), "bar")
        with pytest.raises(ModelError, match="more than six zero-frequency modes"):
            cms.free_modes(f * two[0], two[1], cms.rigid_fields(X2), "bars")
        with pytest.raises(ModelError, match="does not hold the body"):
            cms.reduce(fe.FEModel(X, M, f * K, {}, "bar"), interface=[0, 1], reference=[0, 0, 0], modes=2)
