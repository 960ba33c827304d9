"""A solid mesh plus material (E, ν, ρ) → FEModel: consistent mass and stiffness from scikit-fem (issue 24).

Build time only (the `fe` extra: meshio reads the file, scikit-fem assembles); nothing of this reaches an FMU.

Elements, from the mesh's solid cell type unless `element=` says otherwise:
- tet4 (meshio 'tetra'): linear tetrahedra; `element="tet10"` on such a mesh adds a node at every edge midpoint;
- tet10 ('tetra10'): quadratic tetrahedra; with midside nodes off their edges' midpoints (curved edges) the
  elements are isoparametric (scikit-fem's MeshTet2), else straight; `element="tet4"` drops the midside nodes;
- hex8 ('hexahedron'): trilinear hexahedra.
hex20/hex27, wedges, pyramids and mixed solid cell types are refused with the supported list.

Nodes (FEModel.nodes, the DOF-carrying nodes, scikit-fem's `basis.doflocs`): first the vertices of the solid
cells in the order of the file (points no solid cell uses are dropped), then for tet10 one node per edge in
scikit-fem's edge order. DOFs are node-major, x y z per node; scikit-fem numbers vector DOFs its own way, so
`_node_major` maps them explicitly. Node sets: the file's point sets, and the points of its named cell sets
(Abaqus *ELSET, gmsh physical groups), mapped to these nodes; a file's midside point maps to its edge's node.

Stresses: the FEModel carries `stress` (nodal_stress on this mesh and material), from which cms.py takes each
mode's stress at the nodes a scene's `stress:` names.

Bounded: the file is read whole (at most limits.FE_MESH_BYTES), meshio parses a private copy of it in a child
process under limits.FE_PARSE_BYTES and FE_PARSE_SECONDS, the assembled size is checked against limits.FE_DOFS
before any assembly, which goes CHUNK_CELLS elements at a time, and nothing outside the one file is read
(Abaqus *INCLUDE is refused).
"""

import os
import tempfile
from pathlib import Path

import numpy as np

from ..errors import ModelError
from .. import datafile, limits
from .fe_model import FEModel

ELEMENTS = ("tet4", "tet10", "hex8")
CELL_ELEMENT = {"tetra": "tet4", "tetra10": "tet10", "hexahedron": "hex8"}
CELL_NODES = {"tetra": 4, "tetra10": 10, "hexahedron": 8}
SOLID_CELLS = ("tetra", "tetra10", "hexahedron", "hexahedron20", "hexahedron24", "hexahedron27", "wedge",
               "wedge12", "wedge15", "pyramid", "pyramid13", "pyramid14")
FORMATS = {".msh": "gmsh", ".inp": "abaqus", ".vtk": "vtk", ".vtu": "vtu"}   # self-contained: read no other file
TET10_EDGES = ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))                 # meshio/VTK midside node order
MIDSIDE_TOL = 1e-6                                                             # of the edge's length
CHUNK_CELLS = 2048    # elements assembled at once: scikit-fem keeps ~30 kB of basis values per tet10 element


def assemble_solid(mesh, E, nu, rho, element=None, *, base=".", allow_outside=False):
    """FEModel of the solid `mesh` (a file name relative to `base`, confined to it unless `allow_outside`, or a
    meshio.Mesh) with Young's modulus E, Poisson's ratio nu and density rho; `element` one of ELEMENTS or None."""
    _require_extra()
    E, nu, rho = _material(E, nu, rho)
    path, source = None, "<meshio.Mesh>"
    if isinstance(mesh, (str, os.PathLike)):
        path = datafile.resolve(base, str(mesh), allow_outside)
        try:
            source = path.relative_to(Path(base).resolve()).as_posix()
        except ValueError:
            source = str(path)
    try:   # the file named in the message: a scene's error keeps its line and key, not a `file`
        if path is not None:
            mesh = read_mesh(path)
        name_cell = (lambda k: _file_element(path, mesh, k)) if path else (lambda k: f"solid cell {k} (0-based)")
        return _assemble(mesh, E, nu, rho, element, source, name_cell)
    except ModelError as err:
        raise ModelError(f"{source}: {err.message}", key=err.key, hint=err.hint) from None


def _require_extra():
    """scikit-fem and meshio (the `fe` extra) are there, or one ModelError that says how to get them."""
    try:
        import meshio  # noqa: F401
        import skfem  # noqa: F401
    except ImportError as e:
        raise ModelError(f"elastic bodies from solid meshes need scikit-fem and meshio ({e.name} is missing)",
                         hint="pip install 'mbsfmu[fe]'") from None


def _material(E, nu, rho):
    """E > 0, -1 < ν < 0.5, ρ > 0, all finite: the range in which the elasticity form is positive definite."""
    checks = (("E", E, lambda v: v > 0, "a positive Young's modulus in Pa"),
              ("nu", nu, lambda v: -1 < v < 0.5, "a Poisson's ratio in (-1, 0.5)"),
              ("rho", rho, lambda v: v > 0, "a positive density in kg/m³"))
    out = []
    for key, v, ok, what in checks:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or not ok(v):
            raise ModelError(f"expected {what}, got {v!r}", key=f"material.{key}")
        out.append(float(v))
    return out


def read_mesh(path):
    """The meshio.Mesh in the regular file `path`, read whole into memory first (size bounded)."""
    path = Path(path)
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ModelError(f"unknown mesh format '{path.suffix}'", file=str(path),
                         hint="give a gmsh .msh, Abaqus .inp, VTK .vtk or .vtu file")
    try:
        with limits.open_regular(path) as f:
            data = f.read(limits.FE_MESH_BYTES + 1)  # not fstat alone: the file may grow while it is read
    except OSError as e:
        raise ModelError(f"cannot read the mesh file: {e.strerror or e}", file=str(path),
                         hint="give a regular mesh file next to the scene") from None
    if len(data) > limits.FE_MESH_BYTES:
        raise ModelError(f"the mesh file is larger than {limits.FE_MESH_BYTES // 2**20} MiB", file=str(path),
                         hint=f"a mesh of at most {limits.FE_DOFS:,} DOFs fits well below that")
    if fmt == "abaqus" and any(line.lstrip().lower().startswith(b"*include") for line in data.splitlines()):
        raise ModelError("the Abaqus file includes other files (*INCLUDE), which are not followed", file=str(path),
                         hint="write the mesh into one .inp file")
    return _parse(data, fmt, path)


# meshio's readers allocate what a file's header declares (10¹² nodes in a 200-byte file): they run in a child
# process under an address-space and CPU limit, and hand back plain arrays only (npz read without pickle).
_PARSER = r"""
import json, os, resource, sys
import numpy as np
resource.setrlimit(resource.RLIMIT_AS, ({memory}, {memory}))
resource.setrlimit(resource.RLIMIT_CPU, ({seconds}, {seconds}))
try:
    import meshio
    m = meshio._helpers.reader_map[sys.argv[2]](sys.argv[1])  # not meshio.read: it exits on a bad file
    arrays, meta = [np.asarray(m.points, float)], {{"cells": [], "point_sets": [], "cell_sets": [], "physical": [],
                                                   "field_data": []}}
    def put(a):
        arrays.append(np.asarray(a))
        return len(arrays) - 1
    meta["cells"] = [(c.type, put(c.data)) for c in m.cells]
    meta["point_sets"] = [(str(k), put(v)) for k, v in m.point_sets.items()]
    meta["cell_sets"] = [(str(k), [None if v is None else put(v) for v in vs]) for k, vs in m.cell_sets.items()]
    meta["physical"] = [put(v) for v in m.cell_data.get("gmsh:physical", [])]
    meta["field_data"] = [(str(k), put(v)) for k, v in m.field_data.items()]
    np.savez(sys.argv[3], *arrays)
    print(json.dumps(meta))
except BaseException as e:
    text = str(e).strip().splitlines()[0][:200] if str(e).strip() else ""
    print(json.dumps({{"error": type(e).__name__, "message": text}}))
"""


def _parse(data, fmt, path):
    """meshio's reader for `fmt` on the bytes, from a private temporary copy (the readers want a file name; the
    copy cannot change or grow), in a bounded child process; any failure of it becomes one ModelError."""
    import json
    import subprocess
    import sys
    with tempfile.TemporaryDirectory() as tmp:
        copy, out = Path(tmp) / ("mesh" + path.suffix.lower()), Path(tmp) / "arrays.npz"
        copy.write_bytes(data)
        code = _PARSER.format(memory=limits.FE_PARSE_BYTES, seconds=limits.FE_PARSE_SECONDS)
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
        try:
            r = subprocess.run([sys.executable, "-c", code, str(copy), fmt, str(out)], cwd=tmp, env=env,
                               capture_output=True, text=True, timeout=2 * limits.FE_PARSE_SECONDS)
            meta = json.loads(r.stdout.strip().splitlines()[-1]) if r.stdout.strip() else {
                "error": "crash", "message": f"the reader ended with status {r.returncode}"}
        except subprocess.TimeoutExpired:
            meta = {"error": "timeout", "message": f"reading took longer than {2 * limits.FE_PARSE_SECONDS} s"}
        if "error" in meta:
            what = meta["message"] or f"not a {fmt} file"
            raise ModelError(f"cannot read the {fmt} mesh: {meta['error']}: {what}", file=str(path),
                             hint="write the mesh again from the mesher (gmsh, Abaqus, meshio)")
        if out.stat().st_size > limits.FE_PARSE_BYTES // 2:   # what the child may hold, the parent holds twice
            raise ModelError(f"the mesh unpacks to {out.stat().st_size:,} bytes of arrays", file=str(path),
                             hint=f"a compressed file expands to more than {limits.FE_PARSE_BYTES // 2**21} MiB")
        return _mesh(meta, out, fmt, path)


def _mesh(meta, npz, fmt, path):
    """The meshio.Mesh the child described: arrays from its npz (numbers only, never unpickled)."""
    import meshio
    try:
        with np.load(npz, allow_pickle=False) as z:
            a = [z[f"arr_{i}"] for i in range(len(z.files))]
        return meshio.Mesh(a[0], [(t, a[i]) for t, i in meta["cells"]],
                           point_sets={k: a[i] for k, i in meta["point_sets"]},
                           cell_sets={k: [None if i is None else a[i] for i in v] for k, v in meta["cell_sets"]},
                           cell_data={"gmsh:physical": [a[i] for i in meta["physical"]]} if meta["physical"] else None,
                           field_data={k: a[i] for k, i in meta["field_data"]})
    except (ValueError, KeyError, IndexError, TypeError, OSError) as e:
        raise ModelError(f"cannot read the {fmt} mesh: {type(e).__name__}: {str(e)[:200]}", file=str(path),
                         hint="write the mesh again from the mesher (gmsh, Abaqus, meshio)") from None


def _assemble(mesh, E, nu, rho, element, source, name_cell):
    """FEModel of a meshio.Mesh; name_cell(k) names solid cell k (0-based) as its file does, for messages."""
    kind, cells = _solid_cells(mesh)
    element = _element(kind, element)
    try:
        points = np.asarray(mesh.points, float)
    except (TypeError, ValueError):
        points = np.zeros((0, 0))
    if points.ndim != 2 or points.shape[1] != 3 or not np.all(np.isfinite(points)):
        raise ModelError(f"the mesh's points are not finite 3-D coordinates (shape {points.shape})")
    if cells.size and (cells.min() < 0 or cells.max() >= len(points)):
        raise ModelError("a cell refers to a point the mesh does not have", hint="the file is corrupt")
    corners = cells[:, :8 if kind == "hexahedron" else 4]
    used = np.unique(corners)
    _check_size(element, len(used), len(cells))
    vertex = np.full(len(points), -1)
    vertex[used] = np.arange(len(used))
    p, t = points[used], vertex[corners]
    _check_orientation(p, t, kind, name_cell)
    grid, elem = _mesh_element(p, t, element)
    edges = None
    if kind == "tetra10" and element == "tet10":                # with tet4 its midside points are dropped
        edges = _cell_edges(grid.edges, vertex, cells)
        if _curved(points, cells):
            grid = _curved_mesh(grid, points, cells, edges, name_cell)
    basis, M, K = _matrices(grid, elem, E, nu, rho)
    order, nodes = _node_major(basis, element)
    point_node = _point_nodes(vertex, basis, cells, edges)

    def stress(U, at):
        return nodal_stress(basis, order, E, nu, U, at)
    return FEModel(nodes=nodes, M=M[order][:, order].tocsr(), K=K[order][:, order].tocsr(),
                   node_sets=_node_sets(mesh, point_node), source=source, stress=stress)


def _solid_cells(mesh):
    """(meshio cell type, connectivity) of the mesh's solid cells, all blocks of the one supported type."""
    types = sorted({c.type for c in mesh.cells if len(c.data)})
    if not types:
        raise ModelError("the mesh has no cells", hint="mesh the volume of the part (gmsh: Mesh 3D)")
    solid = [t for t in types if t in SOLID_CELLS]
    supported = ", ".join(f"{c} ({e})" for c, e in CELL_ELEMENT.items())
    if not solid:
        raise ModelError(f"the mesh has no solid cells, only {', '.join(types)}", hint=f"mesh the volume: {supported}")
    if len(solid) > 1:
        raise ModelError(f"the mesh mixes solid cell types {', '.join(solid)}", hint=f"use one of {supported}")
    if solid[0] not in CELL_ELEMENT:
        raise ModelError(f"solid cells of type '{solid[0]}' are not supported", hint=f"use {supported}")
    data = [np.asarray(c.data) for c in mesh.cells if c.type == solid[0]]
    per_cell = CELL_NODES[solid[0]]
    if any(d.dtype.kind not in "iu" or d.ndim != 2 or d.shape[1] != per_cell for d in data):
        raise ModelError(f"the '{solid[0]}' cells are not rows of {per_cell} point indices", hint="the file is corrupt")
    return solid[0], np.concatenate(data).astype(np.int64)


def _element(kind, element):
    """The element to assemble: the cell type's own, or `element` where the cells carry it."""
    own = CELL_ELEMENT[kind]
    if element is None:
        return own
    if element not in ELEMENTS:
        raise ModelError(f"unknown element {element!r}", key="element", hint=f"use one of {', '.join(ELEMENTS)}")
    if (element == "hex8") != (own == "hex8"):
        raise ModelError(f"element {element} does not fit the mesh's '{kind}' cells", key="element",
                         hint="tet4 or tet10 on tetrahedra, hex8 on hexahedra")
    return element


def _check_size(element, vertices, cells):
    """Refuse before assembling: DOFs counted from vertices and edges (Euler: edges ≈ vertices + cells, a little
    more with the boundary; 1.2 cells measured on box meshes)."""
    nodes = vertices + (int(1.2 * cells) + vertices if element == "tet10" else 0)
    if 3 * nodes > limits.FE_DOFS:
        raise ModelError(f"the mesh has about {3 * nodes:,} DOFs as {element}, more than {limits.FE_DOFS:,}",
                         hint="coarsen the mesh: a few thousand quadratic elements resolve the lowest modes")


NODE_ORDER = {   # the corner order every supported file (gmsh, VTK, Abaqus; meshio keeps it) gives a positive volume
    "tetra": "corners 1, 2, 3 counter-clockwise seen from corner 4",
    "tetra10": "corners 1, 2, 3 counter-clockwise seen from corner 4, then the midside nodes",
    "hexahedron": "bottom face 1, 2, 3, 4 counter-clockwise seen from the top face 5, 6, 7, 8 (5 above 1)",
}


def _check_orientation(p, t, kind, name_cell):
    """Every element's corner Jacobians positive (VTK/meshio node order): an inverted or flat element is refused.
    Measured as the sine-like ratio det / (product of the three edge lengths), so that small elements pass."""
    if kind == "hexahedron":
        # at corner i, the three edges to its neighbours in the VTK hexahedron (bottom 0-3, top 4-7)
        nb = [(1, 3, 4), (2, 0, 5), (3, 1, 6), (0, 2, 7), (7, 5, 0), (4, 6, 1), (5, 7, 2), (6, 4, 3)]
        shape = np.column_stack([_corner_shape(p, t, i, *n) for i, n in enumerate(nb)])
    else:
        shape = _corner_shape(p, t, 0, 1, 2, 3)[:, None]
    bad = np.nonzero(~(shape > 1e-9).all(axis=1))[0]     # NaN (coincident corners) counts as flat
    if len(bad):
        raise ModelError(f"{len(bad)} element(s) are inverted or flat (non-positive Jacobian), "
                         f"the first is {name_cell(int(bad[0]))}",
                         hint=f"the node order for a positive volume: {NODE_ORDER[kind]}; fix it or the mesh in the mesher")


def _file_element(path, mesh, k):
    """How the mesh file names solid cell k: its element tag (gmsh, Abaqus label), else its VTK cell index."""
    solid = _solid_cells(mesh)[0]
    position = 0   # of the cell among all the file's cells: meshio keeps their order, block by block
    for block in mesh.cells:
        if block.type == solid and k < len(block.data):
            position += k
            break
        position += len(block.data)
        k -= len(block.data) if block.type == solid else 0
    fmt = FORMATS[path.suffix.lower()]
    if fmt in ("vtk", "vtu"):
        return f"cell {position} (0-based, as VTK and ParaView number cells)"
    try:
        with limits.open_regular(path) as f:
            tags = (_gmsh_tags if fmt == "gmsh" else _abaqus_labels)(f.read(limits.FE_MESH_BYTES).decode("latin-1"))
    except (OSError, ValueError, IndexError, KeyError, OverflowError):   # a file meshio read but we cannot
        tags = []
    if position < len(tags):
        return f"element {tags[position]}"
    return f"element number {position + 1} in the file's order"   # (binary gmsh 2.2: tags not read)


def _gmsh_tags(text):
    """The element tags of a gmsh file (2.2 or 4.1; binary only 4.1, else []), in the file's order."""
    head = text.split("$MeshFormat", 1)[1].split()
    if head[1] != "0":
        return _gmsh41_binary_tags(text, head) if head[0].startswith("4") else []
    lines = text.split("$Elements", 1)[1].split("$EndElements", 1)[0].strip().splitlines()
    if head[0].startswith("2"):              # count, then: tag type ntags tags… nodes…
        return [int(line.split()[0]) for line in lines[1:] if line.strip()]
    tags, i = [], 1                          # blocks: dim entity type count, then count lines: tag nodes…
    while i < len(lines):
        count = int(lines[i].split()[3])
        tags += [int(line.split()[0]) for line in lines[i + 1:i + 1 + count]]
        i += 1 + count
    return tags


def _gmsh41_binary_tags(text, head):
    """Binary gmsh 4.1 $Elements: counts (4 size_t), then blocks of entity dim, tag, element type (3 int), count
    (size_t) and count rows of the element tag and its nodes (size_t)."""
    from meshio._common import num_nodes_per_cell
    from meshio.gmsh.common import _gmsh_to_meshio_type
    size = np.dtype(f"u{int(head[2])}")
    data = text.split("$Elements\n", 1)[1].encode("latin-1")
    blocks = int(np.frombuffer(data, size, 1)[0])
    at, tags = 4 * size.itemsize, []
    for _ in range(blocks):
        kind = int(np.frombuffer(data, np.int32, 1, at + 8)[0])
        count = int(np.frombuffer(data, size, 1, at + 12)[0])
        width = 1 + num_nodes_per_cell[_gmsh_to_meshio_type[kind]]
        rows = np.frombuffer(data, size, count * width, at + 12 + size.itemsize).reshape(count, width)
        tags += rows[:, 0].tolist()
        at += 12 + size.itemsize * (1 + count * width)
    return tags


def _abaqus_labels(text):
    """The element labels of an Abaqus .inp, in the file's order: the first number of each *ELEMENT data line that
    does not continue the one before (a line ending in a comma continues on the next)."""
    labels, inside, continued = [], False, False
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("**"):
            continue
        if line.startswith("*"):
            inside, continued = line[1:].split(",")[0].strip().lower() == "element", False
            continue
        if inside and not continued:
            labels.append(int(line.split(",")[0]))
        continued = line.endswith(",")
    return labels


def _corner_shape(p, t, i, a, b, c):
    """(e_a · (e_b × e_c)) / (|e_a| |e_b| |e_c|) with e_k = p_k - p_i, for every element: 1 for a right corner."""
    o = p[t[:, i]]
    ea, eb, ec = p[t[:, a]] - o, p[t[:, b]] - o, p[t[:, c]] - o
    norms = np.linalg.norm(ea, axis=1) * np.linalg.norm(eb, axis=1) * np.linalg.norm(ec, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.einsum("ij,ij->i", ea, np.cross(eb, ec)) / norms


def _curved(points, cells):
    """Whether a midside node of the tet10 cells lies off its edge's midpoint (by MIDSIDE_TOL edge lengths)."""
    a = points[cells[:, [e[0] for e in TET10_EDGES]]]
    b = points[cells[:, [e[1] for e in TET10_EDGES]]]
    off = np.linalg.norm(points[cells[:, 4:10]] - 0.5 * (a + b), axis=2) / np.linalg.norm(b - a, axis=2)
    return bool(off.max() > MIDSIDE_TOL)


def _curved_mesh(mesh, points, cells, edges, name_cell):
    """The isoparametric (MeshTet2) mesh with the file's midside nodes; its Jacobian must stay positive at the
    corners and the quadrature points of every element (a midside node pushed too far inverts a corner)."""
    from skfem import MeshTet2
    from skfem.quadrature import get_quadrature
    from skfem.refdom import RefTet
    xyz = np.empty((3, mesh.edges.shape[1]))
    xyz[:, edges.ravel()] = points[cells[:, 4:10]].reshape(-1, 3).T
    curved = MeshTet2(np.ascontiguousarray(np.hstack([mesh.p, xyz])), mesh.t)
    X = np.hstack([np.eye(3, 4, 1), get_quadrature(RefTet, 4)[0]])     # corners (0, e1, e2, e3), then Gauss
    bad = np.nonzero(~(curved.mapping().detDF(X) > 0).all(axis=1))[0]
    if len(bad):
        raise ModelError(f"{len(bad)} curved element(s) are inverted somewhere (non-positive Jacobian), the first "
                         f"is {name_cell(int(bad[0]))}", hint="move the midside nodes back towards their edges' midpoints")
    return curved


def _mesh_element(p, t, element):
    """scikit-fem's mesh (its own hexahedron corner order) and vector element."""
    from skfem import ElementHex1, ElementTetP1, ElementTetP2, ElementVector, MeshHex1, MeshTet1
    from skfem.io.meshio import INV_HEX_MAPPING
    p, t = np.ascontiguousarray(p.T), np.ascontiguousarray(t.T)   # scikit-fem's layout (it says so, copying)
    if element == "hex8":
        return MeshHex1(p, np.ascontiguousarray(t[INV_HEX_MAPPING[:8]])), ElementVector(ElementHex1())
    return MeshTet1(p, t), ElementVector(ElementTetP2() if element == "tet10" else ElementTetP1())


def _matrices(mesh, elem, E, nu, rho):
    """(basis, M, K): consistent mass ∫ρ u·v and stiffness ∫σ(u):ε(v) in scikit-fem's DOF order (quadrature
    exact for both on straight elements), assembled CHUNK_CELLS elements at a time; `basis` (of the first
    chunk) numbers and locates the DOFs of the whole mesh."""
    from skfem import Basis, BilinearForm, asm
    from skfem.helpers import ddot, div, dot, sym_grad
    from skfem.models.elasticity import lame_parameters
    lam, mu = lame_parameters(E, nu)

    @BilinearForm
    def stiffness(u, v, w):
        # σ:ε(v) of skfem.models.elasticity.linear_elasticity, written out: 3× faster (no identity tensor per pair)
        return lam * div(u) * div(v) + 2.0 * mu * ddot(sym_grad(u), sym_grad(v))

    @BilinearForm
    def mass(u, v, w):
        return rho * dot(u, v)

    cells = mesh.t.shape[1]
    basis = Basis(mesh, elem, elements=np.arange(min(CHUNK_CELLS, cells)))
    M, K = asm(mass, basis).tocsr(), asm(stiffness, basis).tocsr()
    for start in range(CHUNK_CELLS, cells, CHUNK_CELLS):
        chunk = Basis(mesh, elem, elements=np.arange(start, min(start + CHUNK_CELLS, cells)), dofs=basis.dofs,
                      disable_doflocs=True)
        M, K = M + asm(mass, chunk).tocsr(), K + asm(stiffness, chunk).tocsr()
    return basis, M, K


VOIGT = ((0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (2, 0))   # σ components in this order: xx yy zz xy yz zx


def nodal_stress(basis, order, E, nu, U, at):
    """σ (len(at), 6, n) at the nodes `at` of the displacement fields U (3N × n, node-major), Voigt order VOIGT:
    the unweighted mean over the elements around each node of that element's stress σ = λ tr(ε) E + 2μ ε,
    ε = sym(∇u), evaluated at the node itself (its reference coordinates in the element: scikit-fem's doflocs).
    Only the elements around the requested nodes are visited, grouped by the node's local position (≤ 10)."""
    from skfem import Basis
    from skfem.models.elasticity import lame_parameters
    lam, mu = lame_parameters(E, nu)
    at, back = np.unique(np.asarray(at, dtype=np.int64), return_inverse=True)   # a node asked twice: once
    n = U.shape[1]
    u = np.empty_like(U)
    u[order] = U                                          # node-major → scikit-fem's DOF order
    element_dofs = basis.dofs.element_dofs                # (local DOFs, elements) of the whole mesh
    row = np.full(basis.N, -1)
    row[order[3 * at]] = np.arange(len(at))               # the x DOF of each requested node → its row
    local, elements = np.nonzero(row[element_dofs] >= 0)
    grad = np.zeros((len(at), 3, 3, n))
    count = np.bincount(row[element_dofs[local, elements]], minlength=len(at))
    for l in np.unique(local):
        els = elements[local == l]
        X = basis.elem.doflocs[l][:, None]                # the node's reference coordinates in these elements
        at_node = Basis(basis.mesh, basis.elem, elements=els, quadrature=(X, np.ones(1)))
        g = sum(f[0].grad[:, :, :, 0, None] * u[element_dofs[i, els]][None, None]
                for i, f in enumerate(at_node.basis))      # ∇u (3, 3, elements, n): [component, derivative]
        np.add.at(grad, row[element_dofs[l, els]], np.moveaxis(g, 2, 0))
    grad /= count[:, None, None, None]
    eps = 0.5 * (grad + np.swapaxes(grad, 1, 2))
    sigma = 2 * mu * eps + lam * np.einsum("pkkn->pn", eps)[:, None, None, :] * np.eye(3)[None, :, :, None]
    return np.stack([sigma[:, a, b] for a, b in VOIGT], axis=1)[back]


def _node_major(basis, element):
    """(order, nodes): order[3k + c] is scikit-fem's DOF of component c at node k; nodes are the vertices, then the
    edge midpoints for tet10 (their coordinates from basis.doflocs)."""
    dofs = basis.nodal_dofs if element != "tet10" else np.hstack([basis.nodal_dofs, basis.edge_dofs])
    order = dofs.T.reshape(-1)                       # node-major: (node, component)
    return order, np.ascontiguousarray(basis.doflocs[:, dofs[0]].T)


def _cell_edges(edges, vertex, cells):
    """(cells, 6): scikit-fem's edge index (of `edges`, 2 × E vertex pairs) of each midside point of the file's
    tet10 cells, in meshio's midside order."""
    n = int(vertex.max()) + 1
    pairs = np.sort(edges, axis=0)
    keys = pairs[0].astype(np.int64) * n + pairs[1]
    order = np.argsort(keys)
    ends = np.sort(vertex[cells[:, np.array(TET10_EDGES)]], axis=2)        # (cells, 6, 2) vertex pairs
    return order[np.searchsorted(keys, ends[..., 0] * n + ends[..., 1], sorter=order)]


def _point_nodes(vertex, basis, cells, edges):
    """FE node of each point of the file (-1: carries no DOF); a tet10 file's midside points map to the nodes of
    their edges (`edges` from _cell_edges, None when the midside points are dropped)."""
    node = vertex.copy()
    if edges is not None:
        node[cells[:, 4:10]] = basis.nodal_dofs.shape[1] + edges
    return node


def _node_sets(mesh, point_node):
    """name → FE node indices: the file's point sets, the points of its named cell sets and gmsh physical groups."""
    sets = {name: _indices(idx, len(point_node), f"point set '{name}'")
            for name, idx in (mesh.point_sets or {}).items()}
    for name, per_block in (mesh.cell_sets or {}).items():
        if not name.startswith("gmsh:"):          # gmsh:bounding_entities are entity tags, not cells
            sets.setdefault(name, np.concatenate([np.zeros(0, np.int64)] + [
                np.asarray(block.data)[_indices(sel, len(block.data), f"cell set '{name}'")].ravel()
                for block, sel in zip(mesh.cells, per_block) if sel is not None]))
    physical = (mesh.cell_data or {}).get("gmsh:physical")     # gmsh 2.2 files: tags, named in field_data
    for name, value in (mesh.field_data or {}).items() if physical else ():
        tag = np.asarray(value).ravel()[:1]
        sets.setdefault(name, np.concatenate([np.zeros(0, np.int64)] + [
            np.asarray(block.data)[np.asarray(tags).ravel() == tag].ravel()
            for block, tags in zip(mesh.cells, physical) if len(tags) == len(block.data)]))
    out = {}
    for name, idx in sets.items():
        nodes = np.unique(point_node[idx])
        nodes = nodes[nodes >= 0]                 # points no solid cell uses carry no DOF
        if len(nodes):
            out[str(name)] = nodes
    return out


def _indices(idx, n, what):
    """Integer indices in [0, n) of a set, or one ModelError (a forged file may point anywhere)."""
    idx = np.asarray(idx).ravel()
    if idx.size and (idx.dtype.kind not in "iu" or idx.min() < 0 or idx.max() >= n):
        raise ModelError(f"the {what} refers to entries the mesh does not have (of {n})", hint="the file is corrupt")
    return idx.astype(np.int64)
