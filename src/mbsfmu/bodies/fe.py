"""Finite-element models of elastic bodies (issue 24): the FEModel every reader produces and cms.py reduces.

A solid FE model has translational node DOFs only, ordered node-major: [u1x u1y u1z u2x ...].  Readers:
- Matrix Market (`scipy.io.mmwrite`, Ansys, Code_Aster): a mass and a stiffness file, a node file (x y z per
  line, commas or blanks) and a DOF map (node-major by default, or a file of `node direction` rows);
- Abaqus `*MATRIX OUTPUT` `.mtx` files, either layout (told apart by their columns): FORMAT=MATRIX INPUT lines
  `row_node, row_dof, col_node, col_dof, value`, or FORMAT=COORDINATE lines `row col value` with global
  equation numbers (node-major over the `.inp`'s *NODE order by default, or the DOF map); with the nodes and
  node sets (`*NODE`, `*NSET`) of the `.inp` file.
A matrix given as one triangle (the other empty) is mirrored; given whole, it must be symmetric.  Every file
is bounded (limits.py) before it is parsed: sizes and counts in headers are checked before any entry is
read.  The consistent mass of a solid is the same scalar mass matrix for x, y and z (M = M_s ⊗ E); check()
requires that, since the floating-frame invariants (cms.py) are quadratic forms of M_s.
"""

import os
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ..errors import ModelError
from .. import limits
from .fe_model import FEModel

DIRECTIONS = {"x": 0, "y": 1, "z": 2, "1": 0, "2": 1, "3": 2}
SYMMETRY_TOL = 1e-9   # of the matrix's largest entry: symmetry and the x/y/z mass blocks


# -- bounded files ---------------------------------------------------------------------------------
def open_bounded(path):
    """A regular file of at most FE_BYTES, opened in binary."""
    name = Path(path).name
    try:
        f = limits.open_regular(path)
    except OSError as e:
        raise ModelError(f"{name}: cannot read it: {e.strerror or e}", hint="a regular file next to the scene") from None
    size = os.fstat(f.fileno()).st_size
    if size > limits.FE_BYTES:
        f.close()
        raise ModelError(f"{name}: {size:,} bytes, more than the {limits.FE_BYTES // 2**20} MiB an FE file may have",
                         hint=f"at most {limits.FE_DOFS:,} DOFs; reduce the model in the FE program first")
    return f


def _text_lines(f, name, max_lines):
    """The file's lines as text (UTF-8 or Latin-1), at most max_lines of them."""
    lines = []
    for i, raw in enumerate(f):
        if i >= max_lines:
            raise ModelError(f"{name}: more than {max_lines:,} lines", hint=f"at most {limits.FE_DOFS:,} DOFs")
        lines.append(raw.decode("utf-8", errors="replace"))
    return lines


# -- Matrix Market ---------------------------------------------------------------------------------
def _mm_header(f, name):
    """(rows, cols, entries) of a Matrix Market file from its banner and size line, checked against the limits."""
    banner = f.readline(1024).decode("ascii", errors="replace").lower().split()
    if len(banner) != 5 or banner[0] != "%%matrixmarket" or banner[1] != "matrix":
        raise ModelError(f"{name}: not a Matrix Market file (first line '%%MatrixMarket matrix coordinate real symmetric')")
    fmt, fld, sym = banner[2:]
    if fmt not in ("coordinate", "array") or fld not in ("real", "double", "integer") or sym not in ("general", "symmetric"):
        raise ModelError(f"{name}: a {fmt} {fld} {sym} matrix", hint="a real coordinate or array matrix, general or symmetric")
    for _ in range(10_000):
        line = f.readline(1024).decode("ascii", errors="replace").strip()
        if line and not line.startswith("%"):
            break
    else:
        raise ModelError(f"{name}: no size line after 10,000 comment lines")
    try:
        size = [int(x) for x in line.split()]
    except ValueError:
        raise ModelError(f"{name}: bad size line {line[:60]!r}", hint="'rows cols entries'") from None
    if len(size) != (3 if fmt == "coordinate" else 2) or min(size) < 0:
        raise ModelError(f"{name}: bad size line {line[:60]!r}", hint="'rows cols entries' (coordinate) or 'rows cols' (array)")
    rows, cols = size[:2]
    entries = size[2] if fmt == "coordinate" else rows * cols
    if rows != cols:
        raise ModelError(f"{name}: a {rows}×{cols} matrix; mass and stiffness matrices are square")
    if rows > limits.FE_DOFS or entries > limits.FE_ENTRIES:
        raise ModelError(f"{name}: {rows:,} DOFs and {entries:,} entries claimed, at most {limits.FE_DOFS:,} DOFs "
                         f"and {limits.FE_ENTRIES:,} entries", hint="reduce the model in the FE program first")
    return rows, entries


def read_matrix_market(path):
    """A square sparse matrix (CSR) from a Matrix Market file, bounded before it is parsed."""
    import scipy.io
    name = Path(path).name
    with open_bounded(path) as f:
        _mm_header(f, name)
        f.seek(0)
        try:
            A = scipy.io.mmread(f)
        except (ValueError, OverflowError, IndexError, OSError, RuntimeError) as e:
            raise ModelError(f"{name}: cannot read the matrix: {str(e)[:120]}",
                             hint="write it with scipy.io.mmwrite (Matrix Market coordinate format)") from None
    return _finite(sp.csr_matrix(A, dtype=float), name)


def _finite(A, name):
    if not np.all(np.isfinite(A.data)):
        raise ModelError(f"{name}: the matrix holds nan or inf")
    A.eliminate_zeros()
    A.sum_duplicates()
    return A


def read_nodes(path):
    """Node coordinates (N×3) from a text file: one node per line, x y z separated by commas or blanks."""
    name = Path(path).name
    with open_bounded(path) as f:
        lines = _text_lines(f, name, limits.FE_DOFS // 3 + 10_000)
    rows = []
    for i, line in enumerate(lines, 1):
        text = line.split("#")[0].replace(",", " ").replace(";", " ").strip()
        if not text or text.startswith("%"):
            continue
        try:
            xyz = [float(v) for v in text.split()]
        except ValueError:
            xyz = []
        if len(xyz) != 3 or not np.all(np.isfinite(xyz)):
            raise ModelError(f"{name}:{i}: expected three finite numbers x y z, got {text[:60]!r}")
        rows.append(xyz)
    if not rows:
        raise ModelError(f"{name}: no nodes", hint="one node per line: x y z")
    if len(rows) > limits.FE_DOFS // 3:
        raise ModelError(f"{name}: {len(rows):,} nodes, at most {limits.FE_DOFS // 3:,}")
    return np.array(rows)


def read_dof_map(path, n_nodes):
    """Row → node-major DOF index from a file of `node direction` lines (node 0-based, direction x|y|z or 1|2|3)."""
    name = Path(path).name
    with open_bounded(path) as f:
        lines = _text_lines(f, name, limits.FE_DOFS + 10_000)
    dofs = []
    for i, line in enumerate(lines, 1):
        parts = line.split("#")[0].replace(",", " ").split()
        if not parts:
            continue
        if len(parts) != 2 or not parts[0].isdigit() or parts[1].lower() not in DIRECTIONS:
            hint = "rotational DOFs (4-6) cannot be read: solid models only" if parts[-1:] in (["4"], ["5"], ["6"]) else None
            raise ModelError(f"{name}:{i}: expected 'node direction' (node 0-based, direction x, y, z or 1, 2, 3)",
                             hint=hint)
        node = int(parts[0])
        if node >= n_nodes:
            raise ModelError(f"{name}:{i}: node {node} does not exist (the node file has {n_nodes})")
        dofs.append(3 * node + DIRECTIONS[parts[1].lower()])
    return np.array(dofs, dtype=np.int64)


def _permute(A, dof_map, name):
    """A with row/column r moved to dof_map[r] (a bijection onto 0 … 3N-1)."""
    if A.shape[0] != len(dof_map):
        raise ModelError(f"{name}: {A.shape[0]} rows, but the DOF map lists {len(dof_map)} DOFs")
    coo = A.tocoo()
    return sp.csr_matrix((coo.data, (dof_map[coo.row], dof_map[coo.col])), shape=A.shape)


def _check_dof_map(dof_map, n_nodes, name):
    counts = np.bincount(dof_map, minlength=3 * n_nodes)
    if len(counts) != 3 * n_nodes or counts.max(initial=0) > 1 or counts.min(initial=1) < 1:
        missing = np.flatnonzero(counts == 0)
        twice = np.flatnonzero(counts > 1)
        what = (f"DOF {'xyz'[missing[0] % 3]} of node {missing[0] // 3} is missing" if len(missing)
                else f"DOF {'xyz'[twice[0] % 3]} of node {twice[0] // 3} appears twice")
        raise ModelError(f"{name}: the DOF map does not match the {n_nodes} nodes: {what}",
                         hint="every node needs exactly its x, y and z DOF")


def from_matrix_market(mass, stiffness, nodes, dof_map="node-major", node_sets=None):
    """FEModel from Matrix Market M and K, a node file and a DOF map ('node-major', 'direction-major' or a file)."""
    X = read_nodes(nodes)
    N = len(X)
    M, K = read_matrix_market(mass), read_matrix_market(stiffness)
    if dof_map == "node-major":
        perm = None
    elif dof_map == "direction-major":   # [all x, all y, all z]
        perm = (3 * np.arange(N)[None, :] + np.arange(3)[:, None]).ravel()
    else:
        perm = read_dof_map(dof_map, N)
        _check_dof_map(perm, N, Path(dof_map).name)
    for A, path in ((M, mass), (K, stiffness)):
        if A.shape[0] != 3 * N:
            raise ModelError(f"{Path(path).name}: {A.shape[0]} rows, but the {N} nodes of {Path(nodes).name} "
                             f"need {3 * N} (x, y, z per node)", hint="matrix and node file must be of the same model")
    if perm is not None:
        M, K = _permute(M, perm, Path(mass).name), _permute(K, perm, Path(stiffness).name)
    source = ", ".join(Path(p).name for p in (mass, stiffness, nodes))
    return check(FEModel(X, symmetric(M, Path(mass).name), symmetric(K, Path(stiffness).name),
                         dict(node_sets or {}), source))


# -- Abaqus ------------------------------------------------------------------------------------------
def read_inp_nodes(path):
    """(labels, coordinates N×3, {set name: labels}) from the *NODE and *NSET blocks of an Abaqus .inp file."""
    name = Path(path).name
    with open_bounded(path) as f:
        lines = _text_lines(f, name, 10 * limits.FE_DOFS)
    labels, coords, sets = [], [], {}
    block, current = None, None
    for i, line in enumerate(lines, 1):
        text = line.strip()
        if not text or text.startswith("**"):
            continue
        if text.startswith("*"):
            words = [w.strip().lower() for w in text[1:].split(",")]
            block = words[0]
            opts = dict((w.split("=", 1) + [""])[:2] for w in words[1:])
            if block == "nset":
                current = sets.setdefault(opts.get("nset", "").strip(), [])
                block = "nset-generate" if "generate" in opts else "nset"
            continue
        values = [v.strip() for v in text.split(",") if v.strip()]
        try:
            if block == "node":
                if len(values) < 3:
                    raise ValueError
                labels.append(int(values[0]))
                coords.append([float(v) for v in values[1:4]] + [0.0] * (4 - len(values)))
            elif block == "nset":
                current.extend(int(v) for v in values)
            elif block == "nset-generate":
                a, b, step = (int(v) for v in (values + ["1"])[:3])
                if step < 1 or (b - a) // step > limits.FE_DOFS:
                    raise ValueError
                current.extend(range(a, b + 1, step))
        except ValueError:
            raise ModelError(f"{name}:{i}: cannot read this *{block.upper()} line: {text[:60]!r}") from None
    if not labels:
        raise ModelError(f"{name}: no *NODE block", hint="the .inp of the part whose matrices were written")
    return np.array(labels), np.array(coords, float), sets


ABAQUS_LAYOUTS = {   # columns of an Abaqus *MATRIX OUTPUT file → the FORMAT= that writes them
    5: "MATRIX INPUT",   # row_node, row_dof, col_node, col_dof, value (node labels, DOFs 1-6)
    3: "COORDINATE",     # row col value: global equation numbers, 1-based
}
_ABAQUS_HINT = ("*MATRIX OUTPUT, FORMAT=MATRIX INPUT lines 'row_node, row_dof, col_node, col_dof, value' or "
                "FORMAT=COORDINATE lines 'row col value'")


def read_abaqus_matrix(path, index, dof_map="node-major"):
    """A sparse matrix from an Abaqus .mtx file in either layout (ABAQUS_LAYOUTS, told apart by their columns;
    commas or blanks): `index` maps node labels to 0-based node indices; `dof_map` ("node-major",
    "direction-major" or an array: equation → node-major DOF) numbers a COORDINATE file's equations."""
    name = Path(path).name
    with open_bounded(path) as f:
        lines = (raw.replace(b",", b" ").decode("latin-1") for raw in f)
        try:
            rows = np.loadtxt(lines, comments="*", ndmin=2, max_rows=limits.FE_ENTRIES + 1)
        except ValueError as e:
            raise ModelError(f"{name}: cannot read it: {str(e)[:120]}", hint=_ABAQUS_HINT) from None
    if len(rows) == 0 or rows.shape[1] not in ABAQUS_LAYOUTS:
        raise ModelError(f"{name}: {rows.shape[1] if len(rows) else 'no'} columns: not an Abaqus matrix file",
                         hint=_ABAQUS_HINT)
    if len(rows) > limits.FE_ENTRIES:
        raise ModelError(f"{name}: more than {limits.FE_ENTRIES:,} entries", hint="reduce the model in the FE program first")
    ints = rows[:, :-1]
    if not np.all(np.isfinite(rows)) or np.any(ints != np.round(ints)):
        raise ModelError(f"{name}: node labels, DOFs and equation numbers must be integers and values finite")
    lab, idx = index
    N = len(lab)
    if rows.shape[1] == 3:
        dofs = _equation_dofs(ints.astype(np.int64), dof_map, N, name)
    else:
        if not isinstance(dof_map, str) or dof_map != "node-major":
            raise ModelError(f"{name}: a FORMAT=MATRIX INPUT file names its nodes and DOFs; a dof_map numbers "
                             "the equations of FORMAT=COORDINATE files only", key="dof_map", hint="leave dof_map out")
        dof = ints[:, [1, 3]].astype(np.int64)
        if np.any((dof < 1) | (dof > 3)):
            bad = int(dof[(dof < 1) | (dof > 3)][0])
            raise ModelError(f"{name}: DOF {bad} found; only translations 1, 2, 3 can be read",
                             hint="solid models only: condense rotational DOFs (beams, shells) in the FE program")
        labels = ints[:, [0, 2]].astype(np.int64)
        pos = np.minimum(np.searchsorted(lab, labels), N - 1)
        known = lab[pos] == labels
        if not known.all():
            raise ModelError(f"{name}: node label {int(labels[~known][0])} is not in the *NODE block")
        dofs = 3 * idx[pos] + dof - 1
    return _finite(sp.csr_matrix((rows[:, -1], (dofs[:, 0], dofs[:, 1])), shape=(3 * N, 3 * N)), name)


def _equation_dofs(eqs, dof_map, N, name):
    """Node-major DOF indices of a COORDINATE file's 1-based equation numbers (eqs: entries × 2)."""
    if eqs.min(initial=1) < 1 or eqs.max(initial=1) > 3 * N:
        bad = int(eqs[(eqs < 1) | (eqs > 3 * N)][0])
        raise ModelError(f"{name}: equation {bad}, but the {N} nodes of the .inp have equations 1 … {3 * N} "
                         "(x, y, z per node)", hint="a solid model's matrices and the .inp of the same part")
    e = eqs - 1
    if isinstance(dof_map, str) and dof_map == "direction-major":   # [all x, all y, all z]
        return 3 * (e % N) + e // N
    if isinstance(dof_map, str):                                     # node-major
        return e
    return dof_map[e]


def from_abaqus(mass, stiffness, inp, node_sets=None, dof_map="node-major"):
    """FEModel from Abaqus *MATRIX OUTPUT files (FORMAT=MATRIX INPUT or COORDINATE, read_abaqus_matrix) and the
    .inp with their nodes (node sets: *NSET and YAML); `dof_map` as from_matrix_market's, for COORDINATE files."""
    labels, X, inp_sets = read_inp_nodes(inp)
    if len(np.unique(labels)) != len(labels):
        raise ModelError(f"{Path(inp).name}: a node label appears twice in *NODE")
    if len(X) > limits.FE_DOFS // 3:
        raise ModelError(f"{Path(inp).name}: {len(X):,} nodes, at most {limits.FE_DOFS // 3:,}")
    order = np.argsort(labels)
    index = (labels[order], order)
    sets = {}
    for set_name, members in inp_sets.items():
        members = np.asarray(members, dtype=np.int64)
        pos = np.minimum(np.searchsorted(index[0], members), len(labels) - 1)
        if not np.all(index[0][pos] == members):
            raise ModelError(f"{Path(inp).name}: *NSET {set_name} names a node that is not in *NODE")
        sets[set_name] = np.unique(index[1][pos])
    sets.update(node_sets or {})
    if dof_map not in ("node-major", "direction-major"):
        dof_map, path = read_dof_map(dof_map, len(X)), dof_map
        _check_dof_map(dof_map, len(X), Path(path).name)
    M, K = read_abaqus_matrix(mass, index, dof_map), read_abaqus_matrix(stiffness, index, dof_map)
    source = ", ".join(Path(p).name for p in (mass, stiffness, inp))
    return check(FEModel(X, symmetric(M, Path(mass).name), symmetric(K, Path(stiffness).name), sets, source))


def read(files, source, node_sets=None):
    """FEModel from `files` as `source` says: {format: matrix-market, dof_map}, {format: abaqus} (files mass,
    stiffness, nodes: the .inp) or {format: mesh, material: {E, nu, rho}, element} (file mesh, fe_mesh.py)."""
    if source["format"] == "mesh":
        from dataclasses import replace

        from .fe_mesh import assemble_solid  # scikit-fem is imported only by scenes that mesh a solid
        mat = source["material"]
        model = assemble_solid(files["mesh"], mat["E"], mat["nu"], mat["rho"], source.get("element"),
                               base=Path(files["mesh"]).parent)
        return check(replace(model, node_sets={**model.node_sets, **(node_sets or {})}))
    dof_map = files.get("dof_map", source.get("dof_map", "node-major"))
    if source["format"] == "abaqus":
        return from_abaqus(files["mass"], files["stiffness"], files["nodes"], node_sets, dof_map)
    return from_matrix_market(files["mass"], files["stiffness"], files["nodes"], dof_map, node_sets)


def node_set(model, name):
    """The node indices of a named node set (Abaqus names match in any case)."""
    found = name if name in model.node_sets else name.lower()
    if found not in model.node_sets:
        known = ", ".join(sorted(model.node_sets)[:20]) or "none: define node_sets"
        raise ModelError(f"no node set '{name}' in {model.source}", hint=f"known: {known}")
    return model.node_sets[found]


# -- checks ------------------------------------------------------------------------------------------
def symmetric(A, name):
    """A mirrored if only one triangle was given; otherwise A, which must be symmetric."""
    A = sp.csr_matrix(A)
    lower, upper = sp.tril(A, -1), sp.triu(A, 1)
    if lower.nnz == 0 or upper.nnz == 0:
        return sp.csr_matrix(A + (lower + upper).T)
    scale = max(abs(A).max(), 1e-300)
    diff = abs(A - A.T).tocoo()
    worst = np.argmax(diff.data) if diff.nnz else None
    if worst is not None and diff.data[worst] > SYMMETRY_TOL * scale:
        i, j = int(diff.row[worst]), int(diff.col[worst])
        raise ModelError(f"{name}: the matrix is not symmetric: entries ({i}, {j}) and ({j}, {i}) differ by "
                         f"{diff.data[worst]:.3g}", hint="mass and stiffness matrices of a solid are symmetric")
    return A


def check(model):
    """The model's sizes, and a solid's consistent mass: the same positive scalar mass matrix for x, y, z."""
    X, M, K = model.nodes, model.M, model.K
    N = len(X)
    if X.ndim != 2 or X.shape[1] != 3 or N < 1 or not np.all(np.isfinite(X)):
        raise ModelError(f"{model.source}: nodes must be a finite N×3 array, got shape {X.shape}")
    for A, what in ((M, "mass"), (K, "stiffness")):
        if A.shape != (3 * N, 3 * N):
            raise ModelError(f"{model.source}: the {what} matrix is {A.shape[0]}×{A.shape[1]}, the {N} nodes need "
                             f"{3 * N}×{3 * N} (x, y, z per node)")
    scale = max(abs(M).max(), 1e-300)
    blocks = [[M[a::3, b::3] for b in range(3)] for a in range(3)]
    coupled = max(abs(blocks[a][b]).max() for a in range(3) for b in range(3) if a != b)
    differ = max(abs(blocks[a][a] - blocks[0][0]).max() for a in (1, 2))
    if coupled > SYMMETRY_TOL * scale or differ > SYMMETRY_TOL * scale:
        raise ModelError(f"{model.source}: the mass matrix is not a solid's consistent mass (the same scalar mass "
                         "matrix for x, y and z)", hint="translational DOFs of solid elements, node-major x y z; "
                         "check the DOF map")
    diag = M.diagonal()
    if np.any(diag <= 0):
        i = int(np.argmin(diag))
        raise ModelError(f"{model.source}: DOF {'xyz'[i % 3]} of node {i // 3} has no mass (diagonal {diag[i]:g})",
                         hint="the mass matrix must be positive definite")
    for set_name, members in model.node_sets.items():
        members = np.asarray(members)
        if members.size == 0 or members.min() < 0 or members.max() >= N:
            raise ModelError(f"{model.source}: node set '{set_name}' must list node indices in 0 … {N - 1}")
    return model
