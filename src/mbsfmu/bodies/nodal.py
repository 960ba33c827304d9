"""Nodal data of an elastic body (seed 004): nodes P with R_RP, masses, Φ_P, Ψ_P, modal K and D.

Everything is expressed in the body reference frame R.  `Phi[P]` (3×n) maps the elastic
coordinates q to the displacement of node P, `Psi[P]` (3×n) to its small rotation (rotation
vector, R components), so r_RP = R_RP + Φ_P q and S_RP = E + (Ψ_P q)~ (Ŝ_RP = E).

`mass_points` is the mass distribution the FFRF invariants integrate over.  For user `nodal:`
data it is the nodes themselves (lumped masses and node inertias).  The beam generator sets it
to the Gauss points of its elements, so that the invariants equal the integrals over the
consistent FE mass matrix exactly (e.g. Σ m ΦᵀΦ + ΨᵀJΨ = Φᵀ M_FE Φ).  A body reduced from a solid FE model
(cms.py) gives the moments themselves (MassMoments), computed as quadratic forms of its consistent mass matrix.
"""

import numpy as np

from ..errors import ModelError


class MassMoments:
    """The mass moments the FFRF invariants are made of (ffrf.py names the symbols):
    m, S0 = Σ m R, S_RR = Σ m R Rᵀ, C_t = Σ m Φ, A_ijk = Σ m R_i Φ_jk, B_ijkl = Σ m Φ_ik Φ_jl,
    J_sum = Σ J, JPsi = Σ J Ψ, PsiJPsi = Σ ΨᵀJΨ."""

    def __init__(self, m, S0, S_RR, C_t, A, B, J_sum, JPsi, PsiJPsi):
        self.m, self.S0, self.S_RR, self.C_t, self.A, self.B = m, S0, S_RR, C_t, A, B
        self.J_sum, self.JPsi, self.PsiJPsi = J_sum, JPsi, PsiJPsi

    def moments(self):
        return self

    @property
    def M_ee(self):
        """Modal mass Σ m ΦᵀΦ + ΨᵀJΨ (symmetrized)."""
        M = np.einsum("iikl->kl", self.B) + self.PsiJPsi
        return 0.5 * (M + M.T)


class MassPoints:
    """Mass distribution for the invariants: masses m (N), positions R (N×3), inertias J (N×3×3), Φ, Ψ (N×3×n)."""

    def __init__(self, m, R, J, Phi, Psi):
        self.m, self.R, self.J, self.Phi, self.Psi = m, R, J, Phi, Psi

    def moments(self):
        """MassMoments as sums over the points."""
        m, R, J, Phi, Psi = (np.asarray(x, float) for x in (self.m, self.R, self.J, self.Phi, self.Psi))
        return MassMoments(m.sum(), m @ R, np.einsum("g,gi,gj->ij", m, R, R), np.einsum("g,gik->ik", m, Phi),
                           np.einsum("g,gi,gjk->ijk", m, R, Phi), np.einsum("g,gik,gjl->ijkl", m, Phi, Phi),
                           J.sum(axis=0), np.einsum("gij,gjk->ik", J, Psi), np.einsum("gik,gij,gjl->kl", Psi, J, Psi))


class NodalData:
    """Nodes of an elastic body and its modal stiffness/damping (the `nodal:` form of the contract).

    R_RP (N×3), mass (N), inertia (N×3×3, about the node, R components), Phi, Psi (N×3×n),
    stiffness, damping (n×n).  Optional: mass_points (MassPoints or MassMoments used by the invariants
    instead of the nodes), stiffening (dict of unit-load modal geometric stiffness matrices, see beam.py),
    frequencies (rad/s of the retained modes, informative).
    """

    def __init__(self, R_RP, mass, Phi, stiffness, Psi=None, inertia=None, damping=None,
                 mass_points=None, stiffening=None, frequencies=None):
        self.R_RP = np.asarray(R_RP, float)
        self.mass = np.asarray(mass, float)
        self.Phi = np.asarray(Phi, float)
        N, _, n = self.Phi.shape
        self.Psi = np.zeros((N, 3, n)) if Psi is None else np.asarray(Psi, float)
        self.inertia = np.zeros((N, 3, 3)) if inertia is None else np.asarray(inertia, float)
        self.stiffness = np.asarray(stiffness, float)
        self.damping = np.zeros((n, n)) if damping is None else np.asarray(damping, float)
        self.mass_points = mass_points
        self.stiffening = stiffening
        self.frequencies = frequencies

    @property
    def n(self):
        """Number of elastic coordinates."""
        return self.Phi.shape[2]

    @property
    def nodes(self):
        """Number of nodes N."""
        return self.R_RP.shape[0]

    def points(self):
        """The mass distribution for the invariants: mass_points if given, else the nodes."""
        if self.mass_points is not None:
            return self.mass_points
        return MassPoints(self.mass, self.R_RP, self.inertia, self.Phi, self.Psi)


def skew(x):
    """x̃, the cross-product matrix: x̃ y = x × y."""
    return np.array([[0.0, -x[2], x[1]], [x[2], 0.0, -x[0]], [-x[1], x[0], 0.0]])


def damping_from_ratio(M_ee, K, ratio):
    """Modal damping D = M V diag(2ζω) Vᵀ M with K V = M V Λ, Vᵀ M V = E (zero for ω = 0 modes)."""
    lam, V = _eigh(K, M_ee)
    omega = np.sqrt(np.clip(lam, 0.0, None))
    MV = M_ee @ V
    D = MV @ np.diag(2.0 * ratio * omega) @ MV.T
    return 0.5 * (D + D.T)


def _eigh(K, M):
    from scipy.linalg import eigh
    return eigh(K, M)


def _array(data, name, key, shape_text):
    try:
        a = np.asarray(data, dtype=float)
    except (TypeError, ValueError):
        raise ModelError(f"`{name}` must be a numeric array {shape_text}", key=f"{key}.{name}") from None
    if not np.all(np.isfinite(a)):
        raise ModelError(f"`{name}` contains non-finite values (nan or inf)", key=f"{key}.{name}")
    return a


def _shape(a, shape, name, key, shape_text):
    if a.shape != shape:
        raise ModelError(f"`{name}` has shape {a.shape}, expected {shape_text} = {shape}",
                         key=f"{key}.{name}")


def _symmetric_psd(a, name, key, what):
    """a (n×n, or a stack of them) symmetric and positive semi-definite, to 1e-9 of its largest entry."""
    aT = np.swapaxes(a, -1, -2)
    scale = np.maximum(np.abs(a).max(axis=(-2, -1)), 1e-300)
    bad = np.abs(a - aT).max(axis=(-2, -1)) > 1e-9 * scale
    if np.any(bad):
        raise ModelError(f"`{name}` must be symmetric", key=f"{key}.{name}", hint=_which(bad, what))
    bad = np.linalg.eigvalsh(0.5 * (a + aT)).min(axis=-1) < -1e-9 * scale
    if np.any(bad):
        raise ModelError(f"`{name}` must be positive semi-definite", key=f"{key}.{name}", hint=_which(bad, what))


def _which(bad, what):
    return what if np.ndim(bad) == 0 else f"node {int(np.argmax(bad))}: {what}"


def check_damping(D, n, key):
    """A modal damping matrix: finite n×n, symmetric positive semi-definite (it may only take energy out)."""
    D = _array(D, "damping", key, "n×n")
    _shape(D, (n, n), "damping", key, "n×n")
    _symmetric_psd(D, "damping", key, "a damping matrix (negative damping feeds energy in)")
    return D


def validate_nodal(data, key="elastic.nodal", damping_ratio=None):
    """Check user `nodal:` data (a mapping or NpzFile) and return NodalData; raises ModelError naming the key."""
    required = ("R_RP", "mass", "Phi", "stiffness")
    for name in required:
        if name not in data:
            raise ModelError(f"missing `{name}`", key=key,
                             hint="nodal data needs R_RP (N×3), mass (N), Phi (N×3×n), stiffness (n×n)")
    R = _array(data["R_RP"], "R_RP", key, "N×3")
    if R.ndim != 2 or R.shape[1] != 3 or R.shape[0] < 1:
        raise ModelError(f"`R_RP` has shape {R.shape}, expected N×3 with N ≥ 1", key=f"{key}.R_RP")
    N = R.shape[0]
    mass = _array(data["mass"], "mass", key, "(N)")
    _shape(mass, (N,), "mass", key, "(N)")
    if np.any(mass <= 0):
        i = int(np.argmin(mass))
        raise ModelError(f"nodal masses must be > 0 (node {i} has {mass[i]:g})", key=f"{key}.mass")
    Phi = _array(data["Phi"], "Phi", key, "N×3×n")
    if Phi.ndim != 3 or Phi.shape[:2] != (N, 3) or Phi.shape[2] < 1:
        raise ModelError(f"`Phi` has shape {Phi.shape}, expected N×3×n = ({N}, 3, n) with n ≥ 1",
                         key=f"{key}.Phi")
    n = Phi.shape[2]
    Psi = None
    if data.get("Psi") is not None:
        Psi = _array(data["Psi"], "Psi", key, "N×3×n")
        _shape(Psi, (N, 3, n), "Psi", key, "N×3×n")
    inertia = None
    if data.get("inertia") is not None:
        inertia = _array(data["inertia"], "inertia", key, "N×3×3")
        _shape(inertia, (N, 3, 3), "inertia", key, "N×3×3")
        _symmetric_psd(inertia, "inertia", key, "an inertia tensor")
    K = _array(data["stiffness"], "stiffness", key, "n×n")
    _shape(K, (n, n), "stiffness", key, "n×n")
    _symmetric_psd(K, "stiffness", key, "a stiffness matrix")
    D = None
    if data.get("damping") is not None:
        if damping_ratio is not None:
            raise ModelError("give either `damping` or `damping_ratio`, not both", key=f"{key}.damping")
        D = check_damping(data["damping"], n, key)
    nodal = NodalData(R, mass, Phi, K, Psi=Psi, inertia=inertia, damping=D)
    M_ee = modal_mass(nodal)
    if np.linalg.eigvalsh(M_ee).min() <= 1e-12 * max(np.abs(M_ee).max(), 1e-300):
        raise ModelError("the modal mass Σ m ΦᵀΦ + ΨᵀJΨ is singular: some combination of modes moves no mass",
                         key=f"{key}.Phi", hint="every mode (column of Phi, Psi) must move a node that has mass")
    if damping_ratio is not None:
        nodal.damping = damping_from_ratio(M_ee, K, _ratio(damping_ratio, key))
    return nodal


def _ratio(value, key):
    try:
        r = float(value)
    except (TypeError, ValueError):
        raise ModelError("`damping_ratio` must be a number", key=f"{key}.damping_ratio") from None
    if not np.isfinite(r) or r < 0:
        raise ModelError(f"`damping_ratio` must be ≥ 0, got {value}", key=f"{key}.damping_ratio")
    return r


def modal_mass(nodal):
    """M_ee = Σ m ΦᵀΦ + ΨᵀJΨ over the mass points."""
    return nodal.points().moments().M_ee
