"""Component mode synthesis: an FEModel (fe.py) reduced to a floating-frame body (seed 004) → NodalData.

Methods and their reference frame condition (the body frame R is the FE model's coordinate frame):
- `craig-bampton` with a reference point coupled rigidly (RBE2) to the interface node set: the frame moves with
  the reference point, so the interface nodes do not move in R.  Clamping them leaves the fixed-interface
  normal modes; the static constraint modes of the reference's six DOFs are the frame's rigid motion itself, so
  the elastic basis is the fixed-interface modes alone ("clamped at the reference").
- `craig-bampton` with a node set alone: the frame follows the interface's mean rigid motion (the interface
  displacements are orthogonal to its six rigid-body fields, equal node weights).  The basis is the
  fixed-interface modes plus the static constraint modes of the interface's 3·n_I − 6 deformation DOFs.
- `craig-bampton` with a reference point averaging the node set (RBE3: its motion is the set's weighted
  least-squares rigid motion): the frame moves with the reference, so that fit is zero; the interface nodes
  keep their deformation and the normal modes are the full model's under those six conditions (rbe3_modes).
  Its six constraint modes are the frame's rigid motion: none is added.
- `free`: free-interface normal modes; the six rigid-body modes are found (their count is checked) and removed,
  and the elastic modes are made exactly M-orthogonal to the rigid fields: ∫Φ dm = 0 and ∫R̃Φ dm = 0, the
  linearised mean axes (Buckens/Tisserand).  With a reference point the interface is tied to it rigidly (RBE2:
  the reference gains six DOFs u_R, θ_R, the interface nodes follow them) before the modes are found, and the
  reference is a kept node whose Φ, Ψ are u_R, θ_R of each mode.  An RBE3 reference adds nothing to K or M:
  the modes are the plain free ones and the reference's Φ, Ψ their interface's weighted rigid fit.  Optional
  static correction modes for named load points follow the normal modes (correction_modes: inertia-relief
  residual attachment modes).
Modes come from a sparse shift-invert Lanczos (eigsh) on the factor of K − σM (σ < 0, so K positive
semi-definite makes it positive definite): CHOLMOD's supernodal Cholesky (cvxopt, the `fe` extra), else
SuperLU's LU.  A Cholesky exists exactly when the matrix is positive definite; where it fails, and for a
frequency cut-off, an LU with diagonal pivots (an LDLᵀ) counts by Sylvester's law the eigenvalues below the
shift as its negative pivots: an indefinite K is refused with that count, a cut-off becomes an exact number of
modes.  Modes are scaled so that the largest node translation is +1.

Invariants: for a solid's consistent mass M = M_s ⊗ E (fe.check), every FFRF moment is a quadratic form of the
scalar mass matrix M_s over node fields — 1 (rigid translation), the coordinates X_i and the mode components
Φ_ik: m = 1ᵀM_s1, S0_i = 1ᵀM_sX_i, S_RR_ij = X_iᵀM_sX_j, C_t_ik = 1ᵀM_sΦ_ik, A_ijk = X_iᵀM_sΦ_jk,
B_ijkl = Φ_ikᵀM_sΦ_jl (so M_ee = ΦᵀMΦ); no node inertias (solid nodes have no rotational DOFs, Ψ = 0).  These
are the integrals ∫ρ … dV of the FE interpolation exactly (partition of unity; isoparametric geometry).
Only the kept nodes (the reference point, then the `keep` nodes) reach the compiled scene.
"""

import contextlib
import hashlib
import json
import os
import tempfile
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, eigsh, splu

from ..errors import ModelError
from .. import datafile, limits
from . import fe
from .nodal import MassMoments, NodalData, _symmetric_psd, damping_from_ratio

METHODS = ("craig-bampton", "free")
SHIFT = 1e-8      # σ = −SHIFT·λ_scale: below every eigenvalue of a positive semi-definite K, by far more than roundoff
# Zero energy is decided against the model's own roundoff, not a fixed fraction of λ_scale (which grows as
# 1/element size² while a slender part's first mode falls as (thickness/length²)²: a 4 m strip 1 mm thick has it
# at 3e-15·λ_scale).  λ_R, the largest eigenvalue of the exact rigid-body fields' pencil (RᵀKR, RᵀMR), measures
# that roundoff: 2e-17…6e-17·λ_scale for double-precision matrices, 1e-9·λ_scale for 8 printed digits; a
# support makes it its stiffness.  Rigid modes are then projected out exactly (no threshold picks them).
EPS = np.finfo(float).eps
ZERO_GAP = 10      # an eigenvalue within ZERO_GAP·max(λ_R, ε λ_scale / 100) is zero (mechanisms come out ≲ λ_R)
RIGID_GAP = 1e-4   # the rigid fields are free when λ_R ≤ 100 ε λ_scale or ≤ RIGID_GAP × the first elastic λ
CACHE_VERSION = "cms-4"
DEFAULT_MODES = 10
CHECK_TOLERANCE = 0.01   # `mbsfmu check` notes a frequency of the claimed band off the full model's by more


def _lam_scale(K, M):
    """A scale of the eigenvalues: max over DOFs of K_ii/M_ii (a Rayleigh quotient, so ≤ λ_max)."""
    return float(np.max(K.diagonal() / M.diagonal()))


def _factor(A, source, what, inertia=False):
    """(solve, number of negative pivots) of a sparse symmetric A.  Unless the inertia is asked: CHOLMOD's
    supernodal Cholesky (from cvxopt, the `fe` extra; for K − σM of a 47,250-DOF tet10 part 1.6 s and 0.47 GiB
    against SuperLU's 26 s and 1.6 GiB); it fails exactly where A is not positive definite, and the LU below
    then says by how much."""
    if not inertia:
        solve = _cholesky(A)
        if solve is not None:
            return solve, 0
    return _ldl(A, source, what)


def _cholesky(A):
    """solve() of the Cholesky factor P A Pᵀ = L Lᵀ (CHOLMOD's AMD order), or None: no cvxopt, or A not positive
    definite."""
    try:
        from cvxopt import cholmod, matrix
    except ImportError:
        return None
    C = _cvxopt_lower(A)
    options = dict(cholmod.options)   # cvxopt's settings are global: its defaults here, the caller's put back
    cholmod.options.clear()           # (supernodal LLᵀ, which fails on an indefinite A where an LDLᵀ would not)
    try:
        F = cholmod.symbolic(C, uplo="L")
        cholmod.numeric(C, F)
    except ArithmeticError:
        return None
    finally:
        cholmod.options.clear()
        cholmod.options.update(options)

    def solve(b):
        x = matrix(np.asarray(b, dtype=float).reshape(len(b), -1))   # a copy, which CHOLMOD overwrites
        cholmod.solve(F, x)
        return np.asarray(x).reshape(np.shape(b))
    return solve


def _cvxopt_lower(A):
    """A's lower triangle as cvxopt's sparse matrix (CHOLMOD and AMD read only that half)."""
    from cvxopt import matrix, spmatrix
    L = sp.tril(A).tocoo()
    return spmatrix(matrix(L.data), matrix(L.row.astype(np.int64)), matrix(L.col.astype(np.int64)), L.shape)


def _ldl(A, source, what):
    """SuperLU's LU of a symmetric A with diagonal pivots (an LDLᵀ: U = D Lᵀ) in a fill-reducing symmetric order
    (AMD with cvxopt, else SuperLU's MMD), and the number of negative pivots: by Sylvester's law A's number of
    negative eigenvalues."""
    A = sp.csc_matrix(A)
    p = _amd(A)
    try:
        lu = splu(A if p is None else A[p][:, p], permc_spec="MMD_AT_PLUS_A" if p is None else "NATURAL",
                  diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError as e:
        raise ModelError(f"{source}: {what} is singular ({e})",
                         hint="a mechanism or a part without stiffness; check the model's elements") from None
    if not np.array_equal(lu.perm_r, lu.perm_c):
        raise ModelError(f"{source}: {what} needed off-diagonal pivots (it is not positive definite)",
                         hint="the stiffness matrix must be positive semi-definite")
    negative = int(np.count_nonzero(lu.U.diagonal() < 0))
    if p is None:
        return lu.solve, negative
    inverse = np.argsort(p)
    return (lambda b: lu.solve(np.asarray(b)[p])[inverse]), negative


def _amd(A):
    """AMD's fill-reducing order of a symmetric A (cvxopt), or None without cvxopt."""
    try:
        from cvxopt import amd
    except ImportError:
        return None
    return np.asarray(amd.order(_cvxopt_lower(A))).ravel()


def _check_mass(model):
    """M = M_s ⊗ E positive definite: no negative (or zero) pivot in the factor of the scalar M_s."""
    if _factor(model.M[0::3, 0::3], model.source, "the mass matrix")[1]:
        raise ModelError(f"{model.source}: the mass matrix is not positive definite",
                         hint="a consistent or lumped mass of positive density; check the elements and the DOF map")


def _lowest(K, M, k, source, scale, R=None):
    """The k lowest eigenpairs of K x = λ M x (shift-invert about σ < 0); refuses an indefinite K.  With the
    rigid-body fields R: the k lowest in their M-orthogonal complement (no threshold decides which are rigid)."""
    sigma = -SHIFT * scale
    factor, negative = _factor(K - sigma * M, source, "the stiffness matrix")
    if negative:
        raise ModelError(f"{source}: the stiffness matrix is not positive semi-definite ({negative} eigenvalue(s) "
                         f"below {sigma:.3g})", hint="a negative stiffness: check the material and the elements")
    n = K.shape[0]
    if k >= n:
        raise ModelError(f"{source}: {k} modes asked, the model has {n} free DOFs", hint="ask for fewer modes")
    solve, v0 = factor, np.random.default_rng(0).standard_normal(n)   # a fixed start: same files, same body
    if R is not None:
        MR = M @ R
        G = R.T @ MR

        def solve(b):
            x = factor(b)
            return x - R @ np.linalg.solve(G, MR.T @ x)
        v0 = solve(M @ v0)
    op = LinearOperator((n, n), matvec=solve, dtype=float)
    with _one_blas_thread():
        lam, V = eigsh(K, k=k, M=M, sigma=sigma, OPinv=op, which="LM", tol=1e-12, v0=v0)
    order = np.argsort(lam)
    return lam[order], V[:, order]


def _one_blas_thread():
    """The BLAS libraries held to one thread (threadpoolctl, the `fe` extra; without it as they are): the Lanczos
    loop alternates small calls into numpy's, scipy's and CHOLMOD's BLAS, whose idle threads spin and take the
    cores from the one working (47,925 DOFs on 2 cores: the reduction 9.5 s with two threads, 3.3 s with one)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(1, user_api="blas")


def _count_below(K, M, lam, source):
    """Number of eigenvalues below lam (Sylvester: negative pivots of K − lam·M)."""
    return _factor(K - lam * M, source, "K − λM", inertia=True)[1]


def _mode_count(K, M, modes, cutoff_hz, rigid, source, scale):
    if cutoff_hz is None and modes is None:
        modes = DEFAULT_MODES
    if cutoff_hz is not None:
        modes = _count_below(K, M, (2 * np.pi * cutoff_hz) ** 2, source) - rigid
        if modes < 1:
            raise ModelError(f"{source}: no elastic mode below {cutoff_hz:g} Hz", hint="raise cutoff_hz")
    if modes > limits.FE_MODES:
        raise ModelError(f"{source}: {modes} modes, at most {limits.FE_MODES}", hint="lower modes or cutoff_hz")
    return modes


def rigid_fields(X):
    """The six rigid-body displacement fields (3N×6): translations x, y, z and small rotations about x, y, z."""
    N = len(X)
    T = np.zeros((N, 3, 6))
    T[:, :, :3] = np.eye(3)
    T[:, 0, 4], T[:, 0, 5] = X[:, 2], -X[:, 1]      # θ × X
    T[:, 1, 3], T[:, 1, 5] = -X[:, 2], X[:, 0]
    T[:, 2, 3], T[:, 2, 4] = X[:, 1], -X[:, 0]
    return T.reshape(3 * N, 6)


def _dofs(nodes):
    return (3 * np.asarray(nodes, dtype=np.int64)[:, None] + np.arange(3)).ravel()


def craig_bampton(model, interface, modes=None, cutoff_hz=None):
    """(Φ 3N×n, λ): fixed-interface modes (zero at the interface nodes) and their eigenvalues."""
    fixed = np.zeros(3 * model.n_nodes, bool)
    fixed[_dofs(interface)] = True
    free = np.flatnonzero(~fixed)
    K, M = model.K[free][:, free], model.M[free][:, free]
    scale = _lam_scale(K, M)
    modes = _mode_count(K, M, modes, cutoff_hz, 0, model.source, scale)
    lam, V = _lowest(K, M, modes, model.source, scale)
    _held(lam, model)
    Phi = np.zeros((3 * model.n_nodes, modes))
    Phi[free] = V
    return Phi, lam


def constraint_modes(model, interface, budget):
    """Static constraint modes of the interface's deformation: unit interface displacements orthogonal to its
    six rigid motions (those are the frame's), the inner nodes following statically (K_ii u_i = −K_iI u_I)."""
    idofs = _dofs(interface)
    basis = _interface_frame(model, interface)[:, 6:]
    if basis.shape[1] > budget:
        raise ModelError(f"{model.source}: {len(interface)} interface nodes give {basis.shape[1]} constraint modes, "
                         f"at most {budget} fit", hint="tie a large interface to a reference point (reference: [x, y, z])")
    inner = np.setdiff1d(np.arange(3 * model.n_nodes), idofs)
    solve = _factor(model.K[inner][:, inner], model.source, "the stiffness of the inner nodes")[0]
    Psi = np.zeros((3 * model.n_nodes, basis.shape[1]))
    Psi[idofs] = basis
    Psi[inner] = -solve(np.asarray(model.K[inner][:, idofs] @ basis))
    return Psi


def rigid_fit(X, point, weights=None):
    """G (6 × 3n): the weighted least-squares rigid motion (u_P, θ_P) about `point` of nodes at X moving by u
    (3n, node-major), G u = argmin Σ w_i |u_i − u_P − θ_P × (X_i − point)|²; equal weights by default.
    Gᵀ distributes a force and moment at the point over the nodes (the same averaging, transposed).  Nodes on
    one line leave the turn about it undetermined: the least-norm fit does not turn about it."""
    A = rigid_fields(np.asarray(X, float) - np.asarray(point, float))
    sw = np.sqrt(np.repeat(np.ones(len(X)) if weights is None else np.asarray(weights, float), 3))
    return np.linalg.pinv(sw[:, None] * A, rcond=1e-9) * sw


def load_patterns(model, points):
    """Unit load patterns (3N × k) at load points: a node index gives its x, y, z forces; a node set (array of
    indices) the six force and moment components at its centroid spread over its nodes as a kept set averages
    (rigid_fit, transposed)."""
    cols = []
    for p in points:
        nodes = np.atleast_1d(np.asarray(p, dtype=np.int64))
        F = np.zeros((3 * model.n_nodes, 3 if np.ndim(p) == 0 else 6))
        if np.ndim(p) == 0:
            F[_dofs(nodes), np.arange(3)] = 1.0
        else:
            X = model.nodes[nodes]
            _interface_frame(model, nodes)   # three nodes not on one line: else no moment can be spread
            F[_dofs(nodes)] = rigid_fit(X, X.mean(axis=0)).T
        cols.append(F)
    return np.hstack(cols) if cols else np.zeros((3 * model.n_nodes, 0))


def _load_count(points):
    """The static correction modes the load points ask for: three per node, six per node set."""
    return sum(3 if np.ndim(p) == 0 else 6 for p in points)


def correction_modes(K, M, R, normal, loads, source):
    """Residual attachment modes (static correction, inertia relief) of a free body for load patterns (columns
    of `loads`): the static deflection under each load balanced by the rigid-body inertia it causes,
    f − M R a with a = (RᵀMR)⁻¹Rᵀf, made M-orthogonal to the rigid fields R (mean axes) and to the kept normal
    modes (whose share of the deflection the basis holds already).  With them the reduced body's static
    deflection under these loads is the full model's."""
    MR = M @ R
    relieved = loads - MR @ np.linalg.solve(R.T @ MR, R.T @ loads)
    # a self-equilibrated load needs no reaction: hold six DOFs that fix the rigid motions (statically
    # determinate, chosen by pivoted QR of the rigid fields), solve, then remove the rigid part below
    support = scipy.linalg.qr(R.T, pivoting=True, mode="r")[1][:6]
    free = np.setdiff1d(np.arange(K.shape[0]), support)
    solve = _factor(K[free][:, free], source, "the stiffness held at six DOFs")[0]
    U = np.zeros(loads.shape)
    U[free] = solve(np.ascontiguousarray(relieved[free]))
    B = np.hstack([R, normal])
    MB = M @ B
    U -= B @ np.linalg.solve(B.T @ MB, MB.T @ U)
    gram = U.T @ (M @ U)
    d = np.sqrt(np.clip(np.diag(gram), 1e-300, None))
    if np.linalg.eigvalsh(gram / np.outer(d, d)).min() < 1e-10:
        raise ModelError(f"{source}: the load points give dependent static correction modes", key="load_points",
                         hint="name each load point once; a node set and a node of it, or two sets that "
                              "share their rigid motion, repeat a load")
    return U


def free_modes(K, M, R, source, modes=None, cutoff_hz=None):
    """(Φ, λ): free-interface elastic modes of K, M, M-orthogonal to the rigid-body fields R (n×6): mean axes."""
    scale = _lam_scale(K, M)
    modes = _mode_count(K, M, modes, cutoff_hz, 6, source, scale)
    lam, V = _lowest(K, M, modes, source, scale, R)
    _rigid_check(K, M, R, lam[0], scale, source)
    MR = M @ R
    return V - R @ np.linalg.solve(R.T @ MR, MR.T @ V), lam   # exact mean axes, not only to eigsh's tolerance


def _rigid_energy(K, M, R):
    """λ_R: the largest eigenvalue of the rigid-body fields' pencil (RᵀKR, RᵀMR), zero but for roundoff."""
    KR = R.T @ (K @ R)
    return float(np.abs(scipy.linalg.eigvalsh(0.5 * (KR + KR.T), R.T @ (M @ R))).max())


def _rigid_check(K, M, R, lam1, scale, source):
    """A free body: its six rigid fields free of energy (to roundoff, or far below its first elastic mode),
    and no seventh zero-energy motion (the first elastic eigenvalue above roundoff)."""
    lam_R = _rigid_energy(K, M, R)
    if lam_R > max(100 * EPS * scale, RIGID_GAP * lam1):
        raise ModelError(f"{source}: the rigid-body motions carry energy (λ = {lam_R:.3g} against the first elastic "
                         f"{lam1:.3g}): a free body has six free rigid-body modes",
                         hint="the model is supported (remove the supports, or use craig-bampton), or its matrices "
                              "were written with too few digits for its lowest modes")
    if lam1 <= ZERO_GAP * max(lam_R, EPS * scale / 100):
        raise ModelError(f"{source}: more than six zero-frequency modes (λ = {lam1:.3g}, roundoff ≈ {lam_R:.3g})",
                         hint="a mechanism or disconnected parts")


def rbe2(model, interface, reference):
    """T (3N × 3(N − n_I) + 6): the interface nodes follow the reference point rigidly, u = u_R + θ_R × (X − X_R);
    the new DOFs are the other nodes' x y z, then the reference's u_R, θ_R (its last six)."""
    _interface_frame(model, interface)
    N = model.n_nodes
    others = np.setdiff1d(np.arange(N), interface)
    k = 3 * len(others)
    rows, cols, vals = list(_dofs(others)), list(range(k)), [1.0] * k
    arm = rigid_fields(model.nodes[interface] - np.asarray(reference, float)).reshape(len(interface), 3, 6)
    for n, node in enumerate(interface):
        for i in range(3):
            for j in np.flatnonzero(arm[n, i]):
                rows.append(3 * node + i)
                cols.append(k + j)
                vals.append(arm[n, i, j])
    return sp.csr_matrix((vals, (rows, cols)), shape=(3 * N, k + 6))


def _free_space(model, interface, reference):
    """(T, R) of a free body: its DOFs (T = None: the model's own; else the RBE2 tie of the interface to the
    reference point) and its six rigid-body fields in those DOFs."""
    if reference is None:
        return None, rigid_fields(model.nodes)
    T = rbe2(model, interface, reference)
    others = np.setdiff1d(np.arange(model.n_nodes), interface)
    R = np.vstack([rigid_fields(model.nodes[others]), rigid_fields(np.asarray(reference, float)[None, :]),
                   np.hstack([np.zeros((3, 3)), np.eye(3)])])
    return T, R


def free_basis(model, interface=None, reference=None, modes=None, cutoff_hz=None, load_points=()):
    """Free-interface modes (3N × n), then the static correction modes of the load points (3N × k), with a
    reference point its own motion u_R, θ_R in all of them (6 × (n + k)), and the modes' eigenvalues."""
    T, R = _free_space(model, interface, reference)
    K, M = (model.K, model.M) if T is None else (T.T @ model.K @ T, T.T @ model.M @ T)
    normal, lam = free_modes(K, M, R, model.source, modes, cutoff_hz)
    basis = normal
    if len(load_points):
        count = _load_count(load_points)   # before any 3N-long column is made
        if normal.shape[1] + count > limits.FE_MODES:
            raise ModelError(f"{model.source}: {normal.shape[1]} modes + {count} static correction modes, "
                             f"at most {limits.FE_MODES}", key="load_points",
                             hint="fewer modes or load points (a node gives three, a node set six)")
        loads = load_patterns(model, load_points)
        corr = correction_modes(K, M, R, normal, loads if T is None else np.asarray(T.T @ loads), model.source)
        basis = np.hstack([normal, corr])
    if T is None:
        return normal, basis[:, normal.shape[1]:], None, lam
    return T @ normal, T @ basis[:, normal.shape[1]:], basis[-6:], lam


def _craig_bampton_space(model, interface, clamped, weights=None):
    """T (3N × m): the displacements a Craig–Bampton basis spans, the interface held by the frame: inner DOFs
    free; interface DOFs zero (clamped: an RBE2 reference point) or its deformation alone, the motions whose
    weighted rigid fit is zero (a node set, or an RBE3 reference point; see the docstring)."""
    idofs = _dofs(interface)
    inner = np.setdiff1d(np.arange(3 * model.n_nodes), idofs)
    T = sp.csr_matrix((np.ones(len(inner)), (inner, np.arange(len(inner)))), shape=(3 * model.n_nodes, len(inner)))
    if clamped:
        return T
    _interface_bound(model, interface)
    basis = np.zeros((3 * model.n_nodes, 3 * len(interface) - 6))
    basis[idofs] = _interface_frame(model, interface, weights)[:, 6:]
    return sp.hstack([T, sp.csr_matrix(basis)]).tocsr()


def _interface_bound(model, interface):
    """An interface that keeps its deformation couples all its DOFs: a dense block of (3 n_I)² in the problem."""
    if len(interface) > limits.FE_AVERAGED_NODES:
        raise ModelError(f"{model.source}: {len(interface):,} interface nodes keep their deformation, at most "
                         f"{limits.FE_AVERAGED_NODES:,}", key="interface",
                         hint="tie the interface rigidly (coupling: rbe2) or choose fewer nodes")


def rbe3_modes(model, interface, weights=None, modes=None, cutoff_hz=None):
    """(Φ 3N×n, λ): Craig–Bampton normal modes of an RBE3 interface, the full model's lowest modes with the
    interface's weighted rigid fit held (its nodes otherwise free).  Its constraint modes are the six rigid
    motions of the reference point: the frame's own, so none is added."""
    T = _craig_bampton_space(model, interface, False, weights)
    K, M = T.T @ model.K @ T, T.T @ model.M @ T
    scale = _lam_scale(K, M)
    modes = _mode_count(K, M, modes, cutoff_hz, 0, model.source, scale)
    lam, V = _lowest(K, M, modes, model.source, scale)
    _held(lam, model)
    return np.asarray(T @ V), lam


def _held(lam, model):
    """The interface holds the body: its first eigenvalue is above the model's roundoff (see ZERO_GAP; λ_R at most
    100 ε λ_scale: the matrices may hold a support of their own)."""
    scale = _lam_scale(model.K, model.M)
    zero = np.clip(_rigid_energy(model.K, model.M, rigid_fields(model.nodes)), EPS * scale / 100, 100 * EPS * scale)
    if lam[0] <= ZERO_GAP * zero:
        raise ModelError(f"{model.source}: the interface does not hold the body: a zero-frequency mode remains",
                         hint="an interface of at least three nodes not on one line, one connected part")


def full_frequencies(model, method, interface, reference, n, coupling="rbe2", weights=None):
    """The full model's n lowest elastic frequencies (Hz) under the reduced basis's boundary condition: what
    the retained modes approximate (Rayleigh–Ritz: each reduced frequency is an upper bound of its own)."""
    rigid_tie = reference is not None and coupling == "rbe2"
    if method == "free":
        T, R = _free_space(model, interface, reference if rigid_tie else None)
    else:
        T, R = _craig_bampton_space(model, interface, rigid_tie, weights), None
    K, M = (model.K, model.M) if T is None else (T.T @ model.K @ T, T.T @ model.M @ T)
    lam = _lowest(K, M, n, model.source, _lam_scale(K, M), R)[0]
    return np.sqrt(np.clip(lam, 0, None)) / (2 * np.pi)


def _band_top(model, normal):
    """The band a reduction claims: up to its highest normal mode's frequency (Hz).  Those modes are
    eigenvectors, so their Rayleigh quotients are their eigenvalues; static constraint modes claim none."""
    lam = np.sum(normal * (model.K @ normal), axis=0) / np.sum(normal * (model.M @ normal), axis=0)
    return np.sqrt(max(lam.max(), 0)) / (2 * np.pi)


def frequency_deviation(fe):
    """|f_reduced / f_full − 1| of a reduced body (as the normalized scene holds it) for each full-model mode in
    the band it claims: a mode the reduction misses shows as its next frequency far above the full model's."""
    full = np.asarray(fe["full_frequencies"], float)
    return np.abs(np.asarray(fe["frequencies"], float)[:len(full)] / full - 1)


def _interface_frame(model, interface, weights=None):
    """An orthonormal basis (U, 3n_I × 3n_I) whose first six columns span W·(the interface's rigid motions), W
    the node weights (equal by default): the others span the motions whose weighted rigid fit is zero."""
    A = rigid_fields(model.nodes[interface] - model.nodes[interface].mean(axis=0))
    if weights is not None:
        A = np.repeat(np.asarray(weights, float), 3)[:, None] * A
    U, sv, _ = np.linalg.svd(A)
    if len(sv) < 6 or sv[5] < 1e-9 * sv[0]:
        raise ModelError(f"{model.source}: the interface nodes do not fix a frame (fewer than three, or on one line)",
                         hint="give at least three interface nodes not on one line, or a reference point")
    return U


def moments(model, Phi):
    """MassMoments of the consistent mass for mode fields Phi (N×3×n) (see the module docstring)."""
    Ms = model.M[0::3, 0::3]
    X = model.nodes
    N, _, n = Phi.shape
    one = np.ones(N)
    MsX = Ms @ X
    MsPhi = (Ms @ Phi.reshape(N, 3 * n)).reshape(N, 3, n)
    return MassMoments(one @ Ms @ one, one @ MsX, X.T @ MsX, np.einsum("g,gik->ik", one, MsPhi),
                       np.einsum("gi,gjk->ijk", X, MsPhi), np.einsum("gik,gjl->ijkl", Phi, MsPhi),
                       np.zeros((3, 3)), np.zeros((3, n)), np.zeros((n, n)))


def reduce(model, method="craig-bampton", interface=None, reference=None, keep=(), modes=None, cutoff_hz=None,
           load_points=(), coupling="rbe2", weights=None, stress=()):
    """The reduced body as plain arrays (what the normalized scene and the cache hold): kept nodes R_RP, Phi,
    Psi, modal stiffness, the mass moments, the frequencies (Hz) and the full model's in the band the reduction
    claims (full_frequencies: `mbsfmu check` compares them).  `stress`: node indices (one array, or one index,
    per entry) whose stress modes the body keeps (stress_modes)."""
    _check_stress(model, stress)
    _check_mass(model)
    if interface is not None:
        interface, weights = _interface_nodes(interface, reference, coupling, weights)
        if coupling == "rbe3":   # the weighted fit must fix all six motions of the reference
            _interface_frame(model, interface, weights)
    rigid_tie = reference is not None and coupling == "rbe2"
    if reference is None and not len(keep):
        raise ModelError("no node is kept: a reduced body needs at least one (the engine's nodes carry joints, "
                         "forces and outputs)", hint="keep: [node indices], or an interface reference point")
    if len(load_points) and method != "free":
        raise ModelError("static correction modes (load_points) complete free-interface modes",
                         key="load_points", hint="method: free; Craig–Bampton's constraint modes already carry "
                                                 "the interface loads (keep the load point as an interface)")
    if _load_count(load_points) > limits.FE_MODES:   # refused before the modes are computed
        raise ModelError(f"{_load_count(load_points)} static correction modes asked, at most {limits.FE_MODES}",
                         key="load_points", hint="fewer load points (a node gives three, a node set six)")
    if method == "craig-bampton":
        if interface is None:
            raise ModelError("craig-bampton needs an interface: a node set, optionally tied to a reference point",
                             hint="interface: {node_set: name, reference: [x, y, z]}")
        statics = np.zeros((3 * model.n_nodes, 0))
        if reference is None:   # the interface moves with the frame on average: its deformation is kept
            statics = constraint_modes(model, interface, limits.FE_MODES - (modes or 1))
        if rigid_tie or reference is None:
            normal, lam_normal = craig_bampton(model, interface, modes, cutoff_hz)
        else:                   # RBE3: the interface's weighted fit is the frame, its deformation is free
            normal, lam_normal = rbe3_modes(model, interface, weights, modes, cutoff_hz)
        Phi = normal
        if Phi.shape[1] + statics.shape[1] > limits.FE_MODES:
            raise ModelError(f"{model.source}: {Phi.shape[1]} + {statics.shape[1]} constraint modes, at most "
                             f"{limits.FE_MODES}", hint="lower cutoff_hz, or tie the interface to a reference point")
        Phi = np.hstack([Phi, statics])
    elif method == "free":
        if reference is not None and interface is None:
            raise ModelError("a reference point needs its interface node set",
                             hint="interface: {node_set: name, reference: [x, y, z]}")
        normal, corr, at_reference, lam_normal = free_basis(model, interface, reference if rigid_tie else None,
                                                            modes, cutoff_hz, load_points)
        Phi = np.hstack([normal, corr])
    else:
        raise ModelError(f"unknown method {method!r}", hint="craig-bampton or free")
    N, n = model.n_nodes, Phi.shape[1]
    Phi = Phi.reshape(N, 3, n)
    scale = _largest(Phi)
    Phi = Phi / scale
    mo = moments(model, Phi)
    K_ee = np.einsum("gik,gil->kl", Phi, (model.K @ Phi.reshape(3 * N, n)).reshape(N, 3, n))
    K_ee = 0.5 * (K_ee + K_ee.T)
    lam = scipy.linalg.eigvalsh(K_ee, mo.M_ee)   # the reduced body's own frequencies
    if method == "craig-bampton" and reference is None:   # the basis spans more than the clamped modes
        full = full_frequencies(model, method, interface, reference, n, coupling, weights)
        full = full[full <= _band_top(model, normal) * (1 + 1e-6)]   # (the slack: eigsh's tolerance, not a mode)
    else:   # the normal modes are the full model's own under the basis's condition: no second solve
        full = np.sqrt(np.clip(lam_normal, 0, None)) / (2 * np.pi)
    R_RP, Phi_kept, Psi_kept = kept_nodes(model, Phi, keep)
    if reference is not None:   # craig-bampton: the frame (Φ = Ψ = 0); free: its u_R, θ_R
        if method == "craig-bampton":
            ref = np.zeros((2, 3, n))
        elif rigid_tie:
            ref = at_reference.reshape(2, 3, n) / scale
        else:                   # RBE3: the weighted least-squares rigid motion of the interface nodes
            fit = rigid_fit(model.nodes[interface], reference, weights)
            ref = (fit @ Phi[interface].reshape(-1, n)).reshape(2, 3, n)
        R_RP = np.vstack([np.asarray(reference, float)[None, :], R_RP])
        Phi_kept = np.concatenate([ref[:1], Phi_kept])
        Psi_kept = np.concatenate([ref[1:], Psi_kept])
    return {"R_RP": R_RP, "Phi": Phi_kept, "Psi": Psi_kept, "stiffness": K_ee,
            "frequencies": np.sqrt(np.clip(lam, 0, None)) / (2 * np.pi), "full_frequencies": full,
            "m": np.array(mo.m), "S0": mo.S0,
            "S_RR": mo.S_RR, "C_t": mo.C_t, "A": mo.A, "B": mo.B, **stress_modes(model, Phi, stress)}


def _check_stress(model, stress):
    """Stress modes need the elements (a mesh), and at most limits.FE_STRESS_NODES nodes: refused before any
    mode is computed."""
    if not len(stress):
        return
    if model.stress is None:
        raise ModelError("stress outputs need a solid mesh (mesh: and material:): mass and stiffness matrices "
                         "carry no elements to take stresses from", key="stress",
                         hint="give the part as a mesh, or leave stress out")
    count = sum(np.size(s) for s in stress)
    if count > limits.FE_STRESS_NODES:
        raise ModelError(f"{count} stress nodes asked, at most {limits.FE_STRESS_NODES}", key="stress",
                         hint="name fewer nodes or smaller node sets")


def stress_modes(model, Phi, stress):
    """{} without stress nodes; else stress (rows, 6, n): each mode's stress at the nodes (fe_mesh.nodal_stress,
    Voigt xx yy zz xy yz zx, Pa per unit q), stress_nodes (rows: FE node indices, the entries' nodes in order)
    and stress_counts (rows per entry)."""
    if not len(stress):
        return {}
    nodes = [np.atleast_1d(np.asarray(s, dtype=np.int64)) for s in stress]
    at = np.concatenate(nodes)
    N, _, n = Phi.shape
    return {"stress": model.stress(Phi.reshape(3 * N, n), at), "stress_nodes": at,
            "stress_counts": np.array([len(s) for s in nodes])}


COUPLINGS = ("rbe2", "rbe3")


def _interface_nodes(interface, reference, coupling, weights):
    """The interface's nodes sorted, and their weights in that order (RBE3 only: positive, one per node)."""
    interface = np.asarray(interface, dtype=np.int64)
    nodes, first = np.unique(interface, return_index=True)
    if coupling not in COUPLINGS:
        raise ModelError(f"unknown coupling {coupling!r}", key="interface.coupling", hint="rbe2 or rbe3")
    if coupling == "rbe3" and reference is None:
        raise ModelError("an RBE3 coupling averages the interface onto a reference point",
                         key="interface.coupling",
                         hint="interface: {node_set: name, reference: [x, y, z], coupling: rbe3}")
    if weights is None:
        return nodes, None
    w = np.asarray(weights, float)
    if coupling != "rbe3":
        raise ModelError("weights belong to an RBE3 (averaging) coupling", key="interface.weights",
                         hint="coupling: rbe3, or leave weights out")
    if w.shape != interface.shape or len(nodes) != len(interface) or not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise ModelError(f"{len(w)} weights for {len(interface)} interface nodes: one positive weight per node, "
                         "no node twice", key="interface.weights")
    return nodes, w[first]


def kept_nodes(model, Phi, keep):
    """R_RP, Φ, Ψ of the kept nodes: an FE node index as it is (Ψ = 0: solid nodes carry no rotation), a node
    set (array of indices) as one node at its centroid moving with the set's least-squares rigid motion
    (equal weights, RBE3-like): Φ its mean translation, Ψ its rotation."""
    R, Phi_k, Psi_k = [], [], []
    for k in keep:
        if np.ndim(k) == 0:
            R.append(model.nodes[k])
            Phi_k.append(Phi[k])
            Psi_k.append(np.zeros_like(Phi[k]))
            continue
        X = model.nodes[np.asarray(k)]
        c = X.mean(axis=0)
        fit = rigid_fit(X, c) @ Phi[np.asarray(k)].reshape(-1, Phi.shape[2])
        R.append(c)
        Phi_k.append(fit[:3])
        Psi_k.append(fit[3:])
    n = Phi.shape[2]
    return np.reshape(R, (-1, 3)), np.reshape(Phi_k, (-1, 3, n)), np.reshape(Psi_k, (-1, 3, n))


def _largest(Phi):
    """Per mode: its largest node translation component (signed, so that it becomes +1)."""
    flat = Phi.reshape(-1, Phi.shape[2])
    return flat[np.argmax(np.abs(flat), axis=0), np.arange(flat.shape[1])]


REDUCED = ("R_RP", "Phi", "Psi", "stiffness", "frequencies", "m", "S0", "S_RR", "C_t", "A", "B")
CACHED = REDUCED + ("full_frequencies",)   # the full model's frequencies: for `mbsfmu check`, not the body
STRESS = ("stress", "stress_nodes", "stress_counts")   # only for a body with stress nodes (stress_modes)
INTEGER = ("stress_nodes", "stress_counts")              # node indices and counts: integers in and out of the cache


def nodal_data(reduced, damping_ratio=0.0, key="elastic.fe"):
    """NodalData of a reduced body (arrays or lists, as the normalized scene, an FMU's drawing description or the
    cache hold them): shapes, finiteness, mass and the modal matrices checked, ModelError otherwise."""
    try:
        r = {k: np.asarray(reduced[k], float) for k in REDUCED}
        n = r["stiffness"].shape[0]
        r["R_RP"] = r["R_RP"].reshape(-1, 3)             # no kept nodes: JSON holds [] for (0, 3)
        r["Phi"], r["Psi"] = r["Phi"].reshape(-1, 3, n), r["Psi"].reshape(-1, 3, n)
        shapes = {"m": (), "S0": (3,), "S_RR": (3, 3), "C_t": (3, n), "A": (3, 3, n), "B": (3, 3, n, n),
                  "stiffness": (n, n), "frequencies": (n,), "Psi": r["Phi"].shape}
        bad = next((k for k, shape in shapes.items() if r[k].shape != shape), None)
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise ModelError(f"the reduced body's data are damaged ({e})", key=key) from None
    if bad or not all(np.all(np.isfinite(a)) for a in r.values()) or not 1 <= n <= limits.FE_MODES or r["m"] <= 0:
        raise ModelError(f"the reduced body's data are damaged ({bad or 'values'})", key=key,
                         hint=f"{n} modes, a positive mass and finite numbers expected")
    mo = MassMoments(float(r["m"]), r["S0"], r["S_RR"], r["C_t"], r["A"], r["B"],
                     np.zeros((3, 3)), np.zeros((3, n)), np.zeros((n, n)))
    _symmetric_psd(r["stiffness"], "stiffness", key, "a stiffness matrix")
    if np.linalg.eigvalsh(mo.M_ee).min() <= 1e-12 * np.abs(mo.M_ee).max():
        raise ModelError("the reduced body's modal mass is not positive definite", key=key)
    D = damping_from_ratio(mo.M_ee, r["stiffness"], damping_ratio) if damping_ratio else None
    return NodalData(r["R_RP"], np.zeros(len(r["R_RP"])), r["Phi"], r["stiffness"], Psi=r["Psi"], damping=D,
                     mass_points=mo, frequencies=2 * np.pi * r["frequencies"])


def stress_table(reduced, key="elastic.fe"):
    """The stress modes (rows, 6, n) of a reduced body with stress nodes (as reduce, the cache or the normalized
    scene hold them): shapes, counts and finiteness checked, ModelError otherwise."""
    try:
        n = np.asarray(reduced["stiffness"], float).shape[0]
        S = np.asarray(reduced["stress"], float).reshape(-1, 6, n)
        rows, counts = np.asarray(reduced["stress_nodes"]), np.asarray(reduced["stress_counts"])
        ok = len(S) == len(rows) == counts.sum() and 1 <= len(S) <= limits.FE_STRESS_NODES and np.all(np.isfinite(S))
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise ModelError(f"the reduced body's stress modes are damaged ({e})", key=key) from None
    if not ok:
        raise ModelError("the reduced body's stress modes are damaged (counts or values)", key=key)
    return S


# -- cache ---------------------------------------------------------------------------------------------
def cache_key(files, params):
    """Hash of the input files' bytes and the reduction's parameters (files bounded as the readers bound them)."""
    h = hashlib.sha256(CACHE_VERSION.encode())
    for path in files:
        with fe.open_bounded(path) as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        h.update(b"\0")
    h.update(json.dumps(params, sort_keys=True, default=_plain).encode())
    return h.hexdigest()[:32]


def _plain(x):
    return np.asarray(x).tolist()


def cache_dir():
    return Path(os.environ.get("MBSFMU_CACHE") or Path.home() / ".cache" / "mbsfmu") / "fe"


def reduce_files(files, source, node_sets, **params):
    """reduce() of the FE model in `files` read as `source` says (fe.read) with node set names in `interface`
    and `keep` resolved; cached by the files' bytes and every input.  ModelError keys are relative to the
    scene's `fe:` mapping."""
    def build():
        model = fe.read(files, source, node_sets)
        return reduce(model, **dict(params, **_resolve(model, params)))
    inputs = dict(params, source=source, node_sets=node_sets)
    return reduce_cached(list(files.values()), inputs, build)


def _resolve(model, params):
    """interface and keep with node set names replaced by node indices, indices checked against the model."""
    def nodes(value, key):
        try:
            idx = fe.node_set(model, value) if isinstance(value, str) else value
        except ModelError as err:
            raise ModelError(err.message, key=key, hint=err.hint) from None
        if np.any(np.asarray(idx) >= model.n_nodes):   # (negative indices never pass the scene's checks)
            raise ModelError(f"node {np.max(idx)} does not exist: the model has {model.n_nodes} nodes", key=key)
        return idx
    iface = params["interface"]
    return {"interface": None if iface is None else nodes(iface, "interface.node_set" if isinstance(iface, str) else "interface.nodes"),
            "keep": [nodes(k, "keep") for k in params["keep"]],
            "load_points": [nodes(k, "load_points") for k in params.get("load_points", ())],
            "stress": [nodes(k, "stress") for k in params.get("stress", ())]}


def reduce_cached(files, inputs, build):
    """build() (a reduced body), or its result from the cache: an .npz named by cache_key(files, inputs).  An entry
    is used only if it reads back (bounded, no pickle: datafile.read_npz) with every member, the digest of its
    content under this key (_digest) and the shapes of a reduced body; any other is built and written again."""
    key = cache_key(files, inputs)
    path = cache_dir() / f"{key}.npz"
    names = CACHED + (STRESS if inputs.get("stress") else ())
    reduced = _cached_entry(path, key, names)
    if reduced is not None:
        return reduced
    reduced = build()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{key}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **reduced, digest=_digest(key, reduced))
            os.replace(tmp, path)   # readers see the old entry or the whole new one, never a part
        except BaseException:
            os.unlink(tmp)
            raise
    except OSError:
        pass   # no writable cache: reduce again next time
    return reduced


def _digest(key, arrays):
    """SHA-256 of the cache key and every array (name, shape, float64 values; integers are exact in them), as 32
    bytes: an entry changed in any way, or stored under another key, no longer matches.  (Integrity, not a
    signature: the cache is the user's own.)"""
    h = hashlib.sha256(key.encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name], dtype=np.float64)
        h.update(f"\0{name}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    return np.frombuffer(h.digest(), dtype=np.uint8)


def _cached_entry(path, key, names):
    """The reduced body of the cache entry at `path`, or None where it is not exactly what reduce_cached wrote."""
    try:
        z = datafile.read_npz(path, names + ("digest",))   # float arrays, bounded, never unpickled
        digest = z.pop("digest")
        if set(z) != set(names) or not np.array_equal(digest, _digest(key, z)):
            return None
        reduced = {k: z[k].astype(np.int64) if k in INTEGER else z[k] for k in names}
        nodal_data(reduced)
        if not 1 <= len(reduced["full_frequencies"]) <= len(reduced["frequencies"]):
            return None
        if "stress" in names:
            stress_table(reduced)
        return reduced
    except Exception:   # noqa: BLE001 -- unreadable (truncated, empty, not a zip, a folder) or damaged: built again
        return None
