"""FE reduction beyond plain modes (issue 24): static correction modes at load points, RBE3 (averaging)
interfaces and the rigid-body mode test.  References: the full tet10 model solved densely (the inertia-relief
deflection from the bordered system [[K, MR], [(MR)ᵀ, 0]], eigenvalues under constraints from a null space),
the closed-form weighted least-squares rigid fit (weighted centroid and inertia J) and its transpose, the
classic RBE3 load distribution, and Sylvester's law for eigenvalue counts."""

import numpy as np
import pytest
import scipy.linalg

pytest.importorskip("skfem")
from test_fe_reduce import MM, bar, dense_frequencies, scene, write_mm
from test_fe_reduce import part as part_body  # noqa: E402

from mbsfmu.bodies import cms, fe  # noqa: E402
from mbsfmu.bodies.ffrf import invariants  # noqa: E402
from mbsfmu.errors import ModelError  # noqa: E402

L, H = 1.0, 0.1


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("MBSFMU_CACHE", str(tmp_path / "cache"))


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
                             (", method: free, load_points: [99999]", "load_points", "does not exist")):
        fe_yaml = f"{{{base}, interface: {{nodes: {tip}}}{extra}}}" if "free" not in extra else f"{{{base}{extra}}}"
        with pytest.raises(ModelError, match=text) as err:
            scene(tmp_path, fe_yaml, joint="{type: revolute, axis: [0, 0, 1]}")
        assert err.value.key == f"bodies.part.elastic.fe.{key}", (extra, err.value.key)
