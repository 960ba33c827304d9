"""Built-in `elastic: beam:` generator: Euler–Bernoulli beam along body x, FE + modal reduction → NodalData.

Finite elements on x ∈ [0, L], node dofs [u_x, u_y, u_z, θ_x, θ_y, θ_z] (R components):
- bending: cubic Hermite in both planes, v = u_y with v' = θ_z (stiffness EIz, about z) and
  w = u_z with w' = −θ_y (stiffness EIy, about y);
- axial bar (linear) when EA is given, otherwise u_x ≡ 0 (inextensible axis);
- torsion (linear) when GJ is given, otherwise θ_x ≡ 0 (torsionally rigid).
Consistent mass: ρA on the axis plus torsional inertia ρIp (rhoIp) about x; Euler–Bernoulli, so no
rotary inertia of the cross-section in bending.  Default ρIp (needed even without GJ: it is the
beam's only inertia about its own axis): a solid section, Ip/A = (EIy + EIz)/EA when EA is given;
without EA we assume E/ρ = 2.6e7 m²/s² (steel, aluminium, titanium all lie within a few %), so
Ip/A = (EIy + EIz)/(rhoA · 2.6e7).

Reference conditions: `clamped: start` – the frame R is the tangent frame at x = 0 (all six dofs
of node 0 fixed).  `clamped: none` – free–free; the rigid-body modes (4 bending, +1 axial with EA,
+1 torsion with GJ) are dropped, so the kept modes are M-orthogonal to them: ∫Φ dm = 0 and
∫(R̃Φ + JΨ) dm = 0, i.e. linearised mean axes (Buckens/Tisserand) – R is the mean-axis frame.

Orientation: `axis` (default [1, 0, 0]) turns the beam generated along x by the shortest rotation taking x
onto the axis (about x × axis; half a turn about z for −x): node positions, Φ, Ψ, node inertias and the mass
points are turned before the invariants are computed, so EI's y and z are the images of body y and z.
Dynamic stiffening below is written for a beam along x; another axis needs it off.

Modes are scaled so that the largest nodal translation component is +1 (q in metres of
deflection; pure torsion modes: largest rotation +1 rad).

Dynamic stiffening (Kane, Ryan, Banerjee 1987): the axial force N(x) from inertial axial loads,
reacted at x = 0, p(x) = ρA [(g_x − a_x) + (ω_y² + ω_z²) x] (axis points: α × R and ω_x have no
axial component).  Unit-load geometric stiffness K_G = ∫ N (v'ᵀv' + w'ᵀw') dx for
N_a = ρA (L − x) (per unit g_x − a_x) and N_ω = ρA (L² − x²)/2 (per unit ω_y² + ω_z²), reduced to
modal space: stiffening = {"K_a": …, "K_omega": …}; ffrf.py adds K_geo = (g_x − a_x) K_a +
(ω_y² + ω_z²) K_omega.  Reaction at the start is exact for `clamped: start`; for a free–free beam
it is exact as long as no applied force acts on the beam axially (inertial loads balance).
Not included: axial loads from applied forces, children attached to nodes, or EA stretching.
"""

import numpy as np
from scipy.linalg import eigh

from ..errors import ModelError
from .. import limits
from .nodal import MassPoints, NodalData, damping_from_ratio, skew

GAUSS_XI, GAUSS_W = np.polynomial.legendre.leggauss(4)   # exact for the degree-6 mass integrands
GAUSS_XI, GAUSS_W = 0.5 * (GAUSS_XI + 1.0), 0.5 * GAUSS_W  # on [0, 1]
E_OVER_RHO = 2.6e7  # m²/s², specific modulus of common structural metals (default ρIp only)


def hermite(xi, h):
    """Cubic Hermite shape functions H1..H4 and their first and second x-derivatives on an element of length h."""
    H = np.array([1 - 3 * xi**2 + 2 * xi**3, h * (xi - 2 * xi**2 + xi**3),
                  3 * xi**2 - 2 * xi**3, h * (-xi**2 + xi**3)])
    dH = np.array([-6 * xi + 6 * xi**2, h * (1 - 4 * xi + 3 * xi**2),
                   6 * xi - 6 * xi**2, h * (-2 * xi + 3 * xi**2)]) / h
    ddH = np.array([-6 + 12 * xi, h * (-4 + 6 * xi), 6 - 12 * xi, h * (-2 + 6 * xi)]) / h**2
    return H, dH, ddH


def interpolation(xi, h):
    """Element rows at ξ over the 12 element dofs: Nt (3, translation), Nr (3, rotation), and strain rows."""
    H, dH, ddH = hermite(xi, h)
    L = np.array([1 - xi, xi])
    dL = np.array([-1.0, 1.0]) / h
    v_cols, w_cols = [1, 5, 7, 11], [2, 4, 8, 10]
    w_sign = np.array([1.0, -1.0, 1.0, -1.0])        # w' = −θ_y: the w "slope dofs" are −θ_y
    Nt, Nr = np.zeros((3, 12)), np.zeros((3, 12))
    Nt[0, [0, 6]] = L
    Nt[1, v_cols] = H
    Nt[2, w_cols] = H * w_sign
    Nr[0, [3, 9]] = L
    Nr[1, w_cols] = -dH * w_sign                      # θ_y = −w'
    Nr[2, v_cols] = dH                                # θ_z = v'
    strain = {"ux'": np.zeros(12), "v''": np.zeros(12), "w''": np.zeros(12), "tx'": np.zeros(12),
              "v'": np.zeros(12), "w'": np.zeros(12)}
    strain["ux'"][[0, 6]] = dL
    strain["tx'"][[3, 9]] = dL
    strain["v''"][v_cols] = ddH
    strain["w''"][w_cols] = ddH * w_sign
    strain["v'"][v_cols] = dH
    strain["w'"][w_cols] = dH * w_sign
    return Nt, Nr, strain


def _positive(spec, name, key, required=True):
    if spec.get(name) is None:
        if required:
            raise ModelError(f"missing `{name}`", key=key)
        return None
    try:
        value = float(spec[name])
    except (TypeError, ValueError):
        raise ModelError(f"`{name}` must be a number, got {spec[name]!r}", key=f"{key}.{name}") from None
    if not np.isfinite(value) or value <= 0:
        raise ModelError(f"`{name}` must be > 0, got {spec[name]!r}", key=f"{key}.{name}")
    return value


def _EI(spec, key):
    EI = spec.get("EI")
    if EI is None:
        raise ModelError("missing `EI`", key=key, hint="bending stiffness: one value or [EIy, EIz]")
    if np.ndim(EI) == 0:
        EI = [EI, EI]
    if len(EI) != 2:
        raise ModelError(f"`EI` must be one value or [EIy, EIz], got {EI!r}", key=f"{key}.EI")
    return [_positive({"EI": e}, "EI", key) for e in EI]


def fe_model(L, EIy, EIz, rhoA, elements, EA=None, GJ=None, rhoIp=None):
    """Assembled FE matrices over 6(N) dofs: M, K, K_Ga, K_Gω and the Gauss mass points (each a 6N-column map)."""
    N = elements + 1
    h = L / elements
    M, K = np.zeros((6 * N, 6 * N)), np.zeros((6 * N, 6 * N))
    KGa, KGw = np.zeros_like(K), np.zeros_like(K)
    Jp = np.diag([rhoIp, 0.0, 0.0])
    pts = {"m": [], "R": [], "J": [], "Nt": [], "Nr": []}
    for e in range(elements):
        dofs = np.arange(6 * e, 6 * e + 12)
        ix = np.ix_(dofs, dofs)
        for xi, w in zip(GAUSS_XI, GAUSS_W):
            Nt, Nr, s = interpolation(xi, h)
            x, dx = (e + xi) * h, w * h
            M[ix] += dx * (rhoA * Nt.T @ Nt + Nr.T @ Jp @ Nr)
            K[ix] += dx * (EIz * np.outer(s["v''"], s["v''"]) + EIy * np.outer(s["w''"], s["w''"])
                           + (EA or 0.0) * np.outer(s["ux'"], s["ux'"])
                           + (GJ or 0.0) * np.outer(s["tx'"], s["tx'"]))
            G = np.outer(s["v'"], s["v'"]) + np.outer(s["w'"], s["w'"])
            KGa[ix] += dx * rhoA * (L - x) * G               # N_a = ∫_x^L ρA dξ
            KGw[ix] += dx * rhoA * 0.5 * (L**2 - x**2) * G   # N_ω = ∫_x^L ρA ξ dξ
            full_t, full_r = np.zeros((3, 6 * N)), np.zeros((3, 6 * N))
            full_t[:, dofs], full_r[:, dofs] = Nt, Nr
            pts["m"].append(rhoA * dx)
            pts["R"].append([x, 0.0, 0.0])
            pts["J"].append(Jp * dx)
            pts["Nt"].append(full_t)
            pts["Nr"].append(full_r)
    pts = {k: np.array(v) for k, v in pts.items()}
    return M, K, KGa, KGw, pts


def retained_dofs(N, EA, GJ, clamped):
    """Indices of the free dofs: no u_x without EA, no θ_x without GJ, none of node 0 when clamped."""
    keep = np.ones((N, 6), bool)
    if EA is None:
        keep[:, 0] = False
    if GJ is None:
        keep[:, 3] = False
    if clamped == "start":
        keep[0, :] = False
    return np.flatnonzero(keep.ravel())


def beam(length, EI, rhoA, elements=10, modes=4, EA=None, GJ=None, rhoIp=None, clamped="start",
         damping_ratio=0.0, dynamic_stiffening=True, key="elastic.beam"):
    """FE beam reduced to `modes` modes → NodalData (nodes at the element ends, Gauss mass points)."""
    spec = dict(length=length, EI=EI, rhoA=rhoA, elements=elements, modes=modes, EA=EA, GJ=GJ,
                rhoIp=rhoIp, clamped=clamped)
    return beam_from_spec(spec, key=key, damping_ratio=damping_ratio,
                          dynamic_stiffening=dynamic_stiffening)


def beam_from_spec(spec, key="elastic.beam", damping_ratio=0.0, dynamic_stiffening=True):
    """The `beam:` mapping of the contract (numbers already evaluated) → NodalData."""
    known = {"length", "EI", "EA", "GJ", "rhoA", "rhoIp", "elements", "modes", "clamped", "axis"}
    for name in spec:
        if name not in known:
            raise ModelError(f"unknown key `{name}`", key=f"{key}.{name}",
                             hint="valid: " + ", ".join(sorted(known)))
    L = _positive(spec, "length", key)
    EIy, EIz = _EI(spec, key)
    rhoA = _positive(spec, "rhoA", key)
    EA, GJ = _positive(spec, "EA", key, False), _positive(spec, "GJ", key, False)
    rhoIp = _positive(spec, "rhoIp", key, False)
    if rhoIp is None:   # solid section: Ip/A = (Iy + Iz)/A = (EIy + EIz)/EA (see module docstring)
        EA_est = EA if EA is not None else rhoA * E_OVER_RHO
        rhoIp = rhoA * (EIy + EIz) / EA_est
    elements, modes = spec.get("elements", 10), spec.get("modes", 4)
    for name, value in (("elements", elements), ("modes", modes)):
        if isinstance(value, bool) or not float(value).is_integer() or value < 1:
            raise ModelError(f"`{name}` must be a positive integer, got {value!r}", key=f"{key}.{name}")
    elements, modes = int(elements), int(modes)
    if elements > limits.BEAM_ELEMENTS:  # here too: specs also come from FMUs (`mbsfmu animate`), not only from `load`
        raise ModelError(f"`elements` must be at most {limits.BEAM_ELEMENTS}, got {elements}", key=f"{key}.elements")
    clamped = spec.get("clamped", "start")
    if clamped not in ("start", "none"):
        raise ModelError(f"`clamped` must be `start` or `none`, got {clamped!r}", key=f"{key}.clamped")

    turn = axis_rotation(spec.get("axis", X_AXIS), f"{key}.axis")
    if dynamic_stiffening and not np.allclose(turn, np.eye(3)):
        raise ModelError("dynamic stiffening is written for a beam along x", key=f"{key}.axis",
                         hint="leave `axis` out, or set `dynamic_stiffening: false`")

    N = elements + 1
    M, K, KGa, KGw, pts = fe_model(L, EIy, EIz, rhoA, elements, EA, GJ, rhoIp)
    free = retained_dofs(N, EA, GJ, clamped)
    rigid = 0 if clamped == "start" else 4 + (EA is not None) + (GJ is not None)
    available = len(free) - rigid
    if modes > available:
        raise ModelError(f"`modes` = {modes} but this mesh has only {available} elastic modes",
                         key=f"{key}.modes", hint="raise `elements` or lower `modes`")
    lam, X = modes_by_plane(M, K, free, N, clamped, modes)
    X /= _mode_scale(X.reshape(N, 6, modes))
    nodes = X.reshape(N, 6, modes)

    Mm = X.T @ M @ X
    Km = X.T @ K @ X
    Km = 0.5 * (Km + Km.T)
    h = L / elements
    lumped = np.full(N, rhoA * h)
    lumped[[0, -1]] *= 0.5
    inertia = np.zeros((N, 3, 3))
    inertia[:, 0, 0] = rhoIp * lumped / rhoA
    points = MassPoints(pts["m"], pts["R"], pts["J"], pts["Nt"] @ X, pts["Nr"] @ X)
    stiffening = None
    if dynamic_stiffening:
        stiffening = {"K_a": _sym(X.T @ KGa @ X), "K_omega": _sym(X.T @ KGw @ X)}
    D = damping_from_ratio(Mm, Km, damping_ratio) if damping_ratio else None
    R_RP = np.column_stack([np.linspace(0.0, L, N), np.zeros(N), np.zeros(N)])
    return _turned(NodalData(R_RP, lumped, nodes[:, :3, :], Km, Psi=nodes[:, 3:, :], inertia=inertia,
                             damping=D, mass_points=points, stiffening=stiffening,
                             frequencies=np.sqrt(np.clip(lam, 0.0, None))), turn)


X_AXIS = (1.0, 0.0, 0.0)


def axis_rotation(axis, key):
    """The shortest rotation taking body x onto `axis` (three finite numbers, not all zero)."""
    try:
        a = np.array(axis, float)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (3,) or not (np.all(np.isfinite(a)) and np.linalg.norm(a) > 0):
        raise ModelError(f"`axis` must be three numbers, not all zero, got {axis!r}", key=key, hint="e.g. [0, 0, 1]: the beam along body z")
    a /= np.linalg.norm(a)
    if a[0] < -1.0 + 1e-12:   # x × axis vanishes: half a turn about z
        return np.diag([-1.0, -1.0, 1.0])
    V = skew(np.cross(X_AXIS, a))
    return np.eye(3) + V + V @ V / (1.0 + a[0])   # Rodrigues with cos = a_x, sin = |v|


def _turned(nodal, T):
    """Nodal data of a beam turned by T: every body-frame vector (positions, Φ, Ψ) and inertia."""
    if np.allclose(T, np.eye(3)):
        return nodal
    p = nodal.mass_points
    nodal.R_RP = nodal.R_RP @ T.T
    nodal.Phi, nodal.Psi = T @ nodal.Phi, T @ nodal.Psi
    nodal.inertia = T @ nodal.inertia @ T.T
    nodal.mass_points = MassPoints(p.m, p.R @ T.T, T @ p.J @ T.T, T @ p.Phi, T @ p.Psi)
    return nodal


PLANES = ((1, 5), (2, 4), (0,), (3,))   # v–θ_z, w–θ_y, axial, torsion: uncoupled for a straight beam


def modes_by_plane(M, K, free, N, clamped, modes):
    """Lowest `modes` elastic modes (λ, 6N×modes); each solved within its uncoupled dof group.

    Solving per group keeps every mode pure (flapwise, chordwise, axial or torsional) even when
    EIy = EIz makes the bending frequencies coincide.  Free–free: each group's rigid-body modes
    (2 per bending plane, 1 axial, 1 torsion) are its zero eigenvalues and are dropped.
    """
    found = []
    for rank, group in enumerate(PLANES):
        dofs = free[np.isin(free % 6, group)]
        if len(dofs) == 0:
            continue
        rigid = 0 if clamped == "start" else (2 if len(group) == 2 else 1)
        lam, V = eigh(K[np.ix_(dofs, dofs)], M[np.ix_(dofs, dofs)])
        for j in range(rigid, len(lam)):
            found.append((lam[j], rank, dofs, V[:, j]))
    found.sort(key=lambda f: (float(f"{f[0]:.9e}"), f[1]))
    X = np.zeros((6 * N, modes))
    for k, (_, _, dofs, v) in enumerate(found[:modes]):
        X[dofs, k] = v
    return np.array([f[0] for f in found[:modes]]), X


def _mode_scale(nodes):
    """Per mode: the largest |translation| (signed, so it becomes +1), or rotation for pure torsion."""
    scale = np.empty(nodes.shape[2])
    for k in range(nodes.shape[2]):
        t = nodes[:, :3, k].ravel()
        if np.abs(t).max() < 1e-8 * np.abs(nodes[:, :, k]).max():
            t = nodes[:, 3:, k].ravel()
        scale[k] = t[np.argmax(np.abs(t))]
    return scale


def _sym(A):
    return 0.5 * (A + A.T)
