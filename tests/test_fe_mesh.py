"""Solid meshes → consistent M, K (bodies/fe_mesh.py) against closed forms: Euler–Bernoulli frequencies and
deflection of a slender tet10 cantilever, ρV, rigid-body modes, the energy of uniform strain (which pins the
node-major DOF map), file points against node coordinates; hostile meshes refused with one ModelError line."""

import os
import time

import numpy as np
import pytest

meshio = pytest.importorskip("meshio")
skfem = pytest.importorskip("skfem")

from scipy.sparse.linalg import eigsh, factorized  # noqa: E402

from mbsfmu.bodies.fe_mesh import assemble_solid  # noqa: E402
from mbsfmu.errors import ModelError  # noqa: E402

E, NU, RHO = 2.1e11, 0.3, 7850.0
BETA_L = (1.875104068711961, 4.694091132974175)   # cantilever roots: (βL)² = 3.5160, 22.0345


def box_tets(L, b, h, nx, ny, nz):
    """Positively oriented tetrahedra of the box [0, L]×[0, b]×[0, h] (scikit-fem's tensor mesh, reoriented)."""
    m = skfem.MeshTet.init_tensor(np.linspace(0, L, nx + 1), np.linspace(0, b, ny + 1), np.linspace(0, h, nz + 1))
    p, t = m.p.T.copy(), m.t.T.copy()
    flip = _volumes(p, t) < 0
    t[flip] = t[flip][:, [1, 0, 2, 3]]
    return p, t


def box_hexes(L, b, h, nx, ny, nz):
    """Hexahedra of the box in VTK node order (bottom face counter-clockwise, then the top face)."""
    x, y, z = np.linspace(0, L, nx + 1), np.linspace(0, b, ny + 1), np.linspace(0, h, nz + 1)
    idx = np.arange(len(x) * len(y) * len(z)).reshape(len(x), len(y), len(z))
    p = np.array(np.meshgrid(x, y, z, indexing="ij")).reshape(3, -1).T
    i, j, k = (a.ravel() for a in np.meshgrid(range(nx), range(ny), range(nz), indexing="ij"))
    t = np.column_stack([idx[i, j, k], idx[i + 1, j, k], idx[i + 1, j + 1, k], idx[i, j + 1, k],
                         idx[i, j, k + 1], idx[i + 1, j, k + 1], idx[i + 1, j + 1, k + 1], idx[i, j + 1, k + 1]])
    return p, t


def _volumes(p, t):
    a = p[t[:, 0]]
    return np.einsum("ij,ij->i", p[t[:, 1]] - a, np.cross(p[t[:, 2]] - a, p[t[:, 3]] - a)) / 6


def tet10_cells(p, t):
    """A 'tetra10' mesh of the tet4 mesh: one point per edge at its midpoint, in meshio's midside order."""
    edges, points, cells = {}, list(p), []
    for tet in t:
        mid = []
        for a, b in ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)):
            key = tuple(sorted((tet[a], tet[b])))
            if key not in edges:
                edges[key] = len(points)
                points.append(0.5 * (p[tet[a]] + p[tet[b]]))
            mid.append(edges[key])
        cells.append(list(tet) + mid)
    return np.array(points), np.array(cells)


def same_points(a, b):
    """The same set of points (rows), in any order."""
    a, b = np.round(a, 12), np.round(b, 12)
    return a.shape == b.shape and np.array_equal(a[np.lexsort(a.T)], b[np.lexsort(b.T)])


def clamped(fe, x0=0.0):
    """DOFs left free when every node at x = x0 is fixed."""
    fixed = np.nonzero(np.abs(fe.nodes[:, 0] - x0) < 1e-12)[0]
    keep = np.ones(fe.M.shape[0], bool)
    keep[(3 * fixed[:, None] + np.arange(3)).ravel()] = False
    return np.nonzero(keep)[0]


@pytest.fixture(scope="module")
def cantilever():
    """Slender steel bar 1 m × 20 mm × 20 mm (L/h = 50: shear and rotary inertia < 0.15 % on mode 2), tet10;
    ν = 0 so that the clamped face does not stiffen the root by blocking the Poisson contraction."""
    L, h = 1.0, 0.02
    p, t = box_tets(L, h, h, 40, 2, 2)
    fe = assemble_solid(meshio.Mesh(p, [("tetra", t)]), E, 0.0, RHO, element="tet10")
    return L, h, fe


def test_tet10_cantilever_bending_frequencies(cantilever):
    """Full clamped model (shift-invert eigsh) against Euler–Bernoulli and against the beam generator."""
    L, h, fe = cantilever
    free = clamped(fe)
    K, M = fe.K[free][:, free], fe.M[free][:, free]
    lam = eigsh(K, k=6, M=M, sigma=0.0, which="LM", return_eigenvectors=False)
    f = np.sort(np.sqrt(lam))
    EI, rhoA = E * h**4 / 12, RHO * h * h
    eb = np.array(BETA_L) ** 2 * np.sqrt(EI / (rhoA * L**4))
    # square section: each bending frequency twice (in y and in z)
    assert f[:2] == pytest.approx([eb[0]] * 2, rel=5e-3)
    assert f[2:4] == pytest.approx([eb[1]] * 2, rel=5e-3)
    from mbsfmu.bodies import beam                  # the beam generator's modes of the same bar
    generated = np.sort(beam(L, [EI, EI], rhoA, elements=20, modes=4).frequencies)
    assert f[:4] == pytest.approx(generated, rel=5e-3)


def test_tet10_cantilever_static_deflection(cantilever):
    """The consistent body load f = M·g (exactly ρg over the volume) against w_tip = qL⁴/8EI, and a tip force P
    shared equally by the tip face's nodes (statically equivalent: Saint-Venant at L/h = 50) against PL³/3EI."""
    L, h, fe = cantilever
    free = clamped(fe)
    solve = factorized(fe.K[free][:, free].tocsc())
    tip = np.abs(fe.nodes[:, 0] - L) < 1e-12
    EI = E * h**4 / 12
    g = np.zeros(fe.M.shape[0])
    g[2::3] = -9.81
    u = np.zeros_like(g)
    u[free] = solve((fe.M @ g)[free])
    assert u[2::3][tip].mean() == pytest.approx(-RHO * h * h * 9.81 * L**4 / (8 * EI), rel=5e-3)
    P, f = 10.0, np.zeros_like(g)
    f[2::3][tip] = P / tip.sum()
    u[free] = solve(f[free])
    assert u[2::3][tip].mean() == pytest.approx(P * L**3 / (3 * EI), rel=5e-3)


def test_exudyn_craig_bampton_peer():
    """The same M, K and nodes in Exudyn's FEMinterface: its fixed-interface modes (clamped face as the one
    interface, node-major xyz as Exudyn numbers DOFs) give scipy's clamped eigenvalues of the full model, and its
    Craig–Bampton basis with the tip face as a second (RBE2) interface, 10 normal modes, gives the first six
    full-model frequencies within 0.5 %."""
    exu_fem = pytest.importorskip("exudyn.FEM")
    from scipy.linalg import eigh
    L, h = 1.0, 0.05
    p, t = box_tets(L, h, h, 16, 1, 1)
    fe = assemble_solid(meshio.Mesh(p, [("tetra", t)]), E, NU, RHO, element="tet10")
    free = clamped(fe)
    full = np.sort(eigsh(fe.K[free][:, free], k=10, M=fe.M[free][:, free], sigma=0.0, return_eigenvectors=False))
    root, tip = (np.nonzero(np.abs(fe.nodes[:, 0] - x) < 1e-12)[0] for x in (0.0, L))
    for interfaces in ([root], [root, tip]):
        fem = exu_fem.FEMinterface()
        fem.nodes, fem.massMatrix, fem.stiffnessMatrix = {"Position": fe.nodes}, fe.M, fe.K
        fem.ComputeHurtyCraigBamptonModes(boundaryNodesList=interfaces, nEigenModes=10,
                                          computationMode=exu_fem.HCBstaticModeSelection.RBE2)
        V = fem.modeBasis["matrix"]
        reduced = eigh(V.T @ (fe.K @ V), V.T @ (fe.M @ V), eigvals_only=True)
        if len(interfaces) == 1:
            assert reduced == pytest.approx(full, rel=1e-8)
        else:
            assert np.sqrt(reduced[:6] / full[:6]) == pytest.approx(np.ones(6), rel=5e-3)


@pytest.mark.parametrize("element", ["tet4", "tet10", "hex8"])
def test_mass_rigid_modes_and_uniform_strain(element):
    """Free body: Σ M over each direction = ρV exactly, K has exactly six zero eigenvalues, and a uniform strain
    field u = εx (set from the node coordinates, node-major) stores ½ V ε:C:ε: a wrong DOF map fails all."""
    L, b, h = 0.3, 0.1, 0.05
    p, t = box_hexes(L, b, h, 3, 2, 1) if element == "hex8" else box_tets(L, b, h, 3, 2, 1)
    fe = assemble_solid(meshio.Mesh(p, [("hexahedron" if element == "hex8" else "tetra", t)]), E, NU, RHO,
                        element=element)
    n = fe.M.shape[0]
    assert fe.M.shape == fe.K.shape == (3 * len(fe.nodes),) * 2
    for c in range(3):
        one = np.zeros(n)
        one[c::3] = 1.0
        assert one @ fe.M @ one == pytest.approx(RHO * L * b * h, rel=1e-12)
        assert np.abs((fe.M @ one)[np.arange(n) % 3 != c]).max() < 1e-12 * RHO * L * b * h   # no cross-coupling
    w = np.linalg.eigvalsh(fe.K.toarray())
    assert np.sum(np.abs(w) < 1e-9 * w.max()) == 6 and w[6] > 1e-6 * w.max()
    eps = np.array([[1.0, 0.3, -0.2], [0.3, -0.5, 0.7], [-0.2, 0.7, 0.4]]) * 1e-3
    lam, mu = E * NU / ((1 + NU) * (1 - 2 * NU)), E / (2 * (1 + NU))
    sigma = lam * np.trace(eps) * np.eye(3) + 2 * mu * eps
    u = (fe.nodes @ (eps + np.array([[0, 1, 2], [-1, 0, 3], [-2, -3, 0]]) * 1e-3).T).ravel()  # + a small rotation
    assert 0.5 * u @ fe.K @ u == pytest.approx(0.5 * L * b * h * np.sum(sigma * eps), rel=1e-9)


def test_chunked_assembly_is_scikit_fems_whole_mesh_assembly(monkeypatch):
    """fe_mesh writes σ:ε out (for speed) and assembles a few elements at a time (for memory): scikit-fem's own
    linear_elasticity model and a ρ u·v form on the whole mesh at once give the same K and M."""
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    from mbsfmu.bodies import fe_mesh
    monkeypatch.setattr(fe_mesh, "CHUNK_CELLS", 5)
    p, t = box_tets(0.2, 0.1, 0.1, 2, 1, 1)
    fe = assemble_solid(meshio.Mesh(p, [("tetra", t)]), E, NU, RHO, element="tet10")
    basis = skfem.Basis(skfem.MeshTet1(p.T, t.T), skfem.ElementVector(skfem.ElementTetP2()))
    K = skfem.asm(linear_elasticity(*lame_parameters(E, NU)), basis)
    M = skfem.asm(skfem.BilinearForm(lambda u, v, w: RHO * dot(u, v)), basis)
    order = np.hstack([basis.nodal_dofs, basis.edge_dofs]).T.ravel()
    assert abs(fe.K - K[order][:, order]).max() < 1e-9 * abs(K).max()
    assert abs(fe.M - M[order][:, order]).max() < 1e-12 * abs(M).max()


def test_tet10_file_points_map_to_their_nodes(tmp_path):
    """A 'tetra10' Abaqus file (C3D10) against element: tet10 on its corners: the same matrices, and every point
    of a node set (midside points included) maps to the FE node at the same coordinates."""
    p4, t4 = box_tets(0.2, 0.1, 0.1, 2, 1, 1)
    p, t = tet10_cells(p4, t4)
    end = np.nonzero(np.abs(p[:, 0] - 0.2) < 1e-12)[0]
    meshio.Mesh(p, [("tetra10", t)], point_sets={"end": end}).write(tmp_path / "part.inp")
    fe = assemble_solid("part.inp", E, NU, RHO, base=tmp_path)
    ref = assemble_solid(meshio.Mesh(p4, [("tetra", t4)]), E, NU, RHO, element="tet10")
    assert len(fe.node_sets["end"]) == len(end)
    assert same_points(fe.nodes[fe.node_sets["end"]], p[end])
    assert np.array_equal(fe.nodes, ref.nodes)
    assert abs(fe.K - ref.K).max() < 1e-9 * abs(ref.K).max() and abs(fe.M - ref.M).max() < 1e-12 * abs(ref.M).max()


GMSH41 = """$MeshFormat
4.1 0 8
$EndMeshFormat
$PhysicalNames
2
2 8 "clamp"
3 7 "body"
$EndPhysicalNames
$Entities
0 0 1 1
1 0 0 0 0 1 1 1 8 0
1 0 0 0 1 1 1 1 7 1 1
$EndEntities
$Nodes
1 4 1 4
3 1 0 4
1
2
3
4
0 0 0
1 0 0
0 1 0
0 0 1
$EndNodes
$Elements
2 2 1 2
2 1 2 1
1 1 3 4
3 1 4 1
2 1 2 3 4
$EndElements
"""


@pytest.mark.parametrize("version", ["4.1", "2.2"])
def test_gmsh_physical_groups_become_node_sets(tmp_path, version):
    """gmsh physical groups name node sets: a 4.1 file as gmsh writes it (one tet, the face x = 0 as the surface
    group 'clamp') and a 2.2 file (physical tags named in field_data) written by meshio."""
    if version == "4.1":
        (tmp_path / "part.msh").write_text(GMSH41)
        p, root, n = np.eye(4, 3, -1), [0, 2, 3], 4
    else:
        p, t = box_tets(0.2, 0.1, 0.1, 2, 1, 1)
        root, n = np.nonzero(p[:, 0] < 1e-12)[0], len(p)
        tri = np.array([[root[0], root[1], root[3]], [root[0], root[3], root[2]]])
        assert set(tri.ravel()) == set(root)
        tags = [np.full(len(t), 7), np.full(2, 8)]
        meshio.Mesh(p, [("tetra", t), ("triangle", tri)], cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
                    field_data={"body": np.array([7, 3]), "clamp": np.array([8, 2])}).write(tmp_path / "part.msh",
                                                                                          file_format="gmsh22")
    fe = assemble_solid("part.msh", E, NU, RHO, base=tmp_path)
    assert same_points(fe.nodes[fe.node_sets["clamp"]], p[root])
    assert len(fe.node_sets["clamp"]) == len(root) and len(fe.node_sets["body"]) == n


# -- hostile meshes: one ModelError line each, quickly -------------------------------------------------------------

def _refused(call, *words):
    t0 = time.process_time()
    with pytest.raises(ModelError) as err:
        call()
    assert time.process_time() - t0 < 2.0
    text = str(err.value)
    assert "\n" not in text and all(w in text for w in words), text
    return text


def _write(path, cells, points=None):
    p, t = box_tets(0.2, 0.1, 0.1, 2, 1, 1)
    meshio.Mesh(p if points is None else points, cells(t)).write(path, file_format="gmsh")  # .msh alone: ANSYS


def test_inverted_element_refused(tmp_path):
    def swap_first(t):
        t = t.copy()
        t[3, [0, 1]] = t[3, [1, 0]]
        return [("tetra", t)]
    _write(tmp_path / "bad.msh", swap_first)   # binary gmsh 4.1, tags 1, 2, … in the cells' order
    _refused(lambda: assemble_solid("bad.msh", E, NU, RHO, base=tmp_path), "bad.msh", "inverted",
             "the first is element 4 ", "counter-clockwise")
    p, t = box_hexes(0.2, 0.1, 0.1, 2, 1, 1)
    _refused(lambda: assemble_solid(meshio.Mesh(p, [("hexahedron", t[:, [4, 5, 6, 7, 0, 1, 2, 3]])]), E, NU, RHO),
             "inverted")
    flat = p.copy()
    flat[t[1, 6], 2] = 0.0                           # a top corner of cell 1 (its last) on the bottom plane
    _refused(lambda: assemble_solid(meshio.Mesh(flat, [("hexahedron", t)]), E, NU, RHO), "flat", "1 element", "cell 1")
    tiny, tt = box_tets(1e-5, 1e-5, 1e-5, 1, 1, 1)   # a 10 µm cube beside a 1 m one: small, not flat
    big, bt = box_tets(1.0, 1.0, 1.0, 1, 1, 1)
    both = meshio.Mesh(np.vstack([big, tiny + 2]), [("tetra", np.vstack([bt, tt + len(big)]))])
    fe = assemble_solid(both, E, NU, RHO)
    assert np.ones(fe.M.shape[0])[0::3] @ fe.M[0::3, 0::3] @ np.ones(len(fe.nodes)) == pytest.approx(RHO * (1 + 1e-15))


def _tet_volume(p, nodes):
    a, b, c, d = p[np.asarray(nodes)]
    return np.dot(b - a, np.cross(c - a, d - a)) / 6


@pytest.mark.parametrize("fmt", ["gmsh22", "gmsh41", "gmsh41-binary", "abaqus", "vtu"])
def test_inverted_element_named_as_its_file_names_it(tmp_path, fmt):
    """A scene's inverted element: the message names the mesh file (as fe.py names matrix files), the element's tag as the
    file writes it (gmsh element tag, Abaqus label; VTK: the cell index), and the node order that is expected.
    The file holds surface cells before the solid ones and tags that are not the cells' indices; the test finds
    the tag of the one element with a negative volume in the file's own text."""
    import mbsfmu
    (tmp_path / "meshes").mkdir()
    p, t = box_tets(0.2, 0.1, 0.1, 2, 1, 1)
    t[4, [1, 2]] = t[4, [2, 1]]
    tris = t[:3, :3]
    name = {"abaqus": "inverted.inp", "vtu": "inverted.vtu"}.get(fmt, "inverted.msh")
    path = tmp_path / "meshes" / name
    if fmt == "gmsh22":   # written by hand: tags 500, 510, … (gmsh keeps whatever tags the mesher gave)
        rows = [f"{500 + 10 * i} 2 2 0 1 " + " ".join(map(str, c + 1)) for i, c in enumerate(tris)]
        rows += [f"{500 + 10 * (i + 3)} 4 2 0 1 " + " ".join(map(str, c + 1)) for i, c in enumerate(t)]
        path.write_text("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n%d\n%s\n$EndNodes\n$Elements\n%d\n%s\n$EndElements\n" % (
            len(p), "\n".join(f"{i + 1} {x} {y} {z}" for i, (x, y, z) in enumerate(p.tolist())), len(rows), "\n".join(rows)))
    elif fmt.startswith("gmsh41"):   # (meshio writes one cell type without entity data; its tags count from 1)
        meshio.Mesh(p, [("tetra", t)]).write(path, file_format="gmsh", binary=False)
    elif fmt == "abaqus":  # labels 1000, 1007, … as a part meshed among others has them
        lines = ["*NODE"] + [f"{i + 1}, {x}, {y}, {z}" for i, (x, y, z) in enumerate(p.tolist())]
        lines += ["*ELEMENT, TYPE=C3D4"] + [f"{1000 + 7 * i}, " + ", ".join(map(str, c + 1)) for i, c in enumerate(t)]
        path.write_text("\n".join(lines) + "\n")
    else:
        meshio.Mesh(p, [("triangle", tris), ("tetra", t)]).write(path)
    if fmt == "vtu":
        expected = f"cell {3 + 4}"
    else:   # the tag of the line whose nodes have a negative volume, read from the text
        text = path.read_text()
        body = text.split("$Elements")[1].split("$EndElements")[0] if fmt.startswith("gmsh") else text.split("*ELEMENT")[1]
        cells = [[int(v) for v in line.replace(",", " ").split()] for line in body.strip().splitlines()[1:]]
        negative = [c[0] for c in cells if len(c) >= 5 and (c[1] == 4 or fmt == "abaqus" or len(c) == 5)
                    and len(c[-4:]) == 4 and _tet_volume(p, np.array(c[-4:]) - 1) < 0]
        assert len(negative) == 1, negative
        expected = f"element {negative[0]}"
    if fmt == "gmsh41-binary":   # the same mesh and tags, binary
        meshio.Mesh(p, [("tetra", t)]).write(path, file_format="gmsh", binary=True)
        assert b"\0" in path.read_bytes()
    (tmp_path / "s.yaml").write_text(f"""mbsfmu: 1
name: inverted
bodies:
  part:
    parent: world
    joint: {{type: fixed}}
    elastic:
      fe: {{mesh: meshes/{name}, material: {{E: 2.1e+11, nu: 0.3, rho: 7850}}, method: free, modes: 1, keep: [0]}}
""")
    msg = _refused(lambda: mbsfmu.load(tmp_path / "s.yaml"), f"s.yaml:8: bodies.part.elastic.fe: {name}: 1 element(s) are inverted",
                   "corners 1, 2, 3 counter-clockwise seen from corner 4")
    assert msg.split("the first is ")[1].startswith(expected + " "), msg


def test_empty_and_unknown_cells_refused(tmp_path):
    p, t = box_tets(0.2, 0.1, 0.1, 2, 1, 1)
    _refused(lambda: assemble_solid(meshio.Mesh(p, []), E, NU, RHO), "no cells")
    _refused(lambda: assemble_solid(meshio.Mesh(p, [("triangle", t[:, :3])]), E, NU, RHO), "no solid cells", "triangle")
    wedges = meshio.Mesh(p, [("wedge", np.hstack([t, t[:, :2]]))])
    hex27 = meshio.Mesh(p, [("hexahedron27", np.tile(t, 7)[:, :27])])
    _refused(lambda: assemble_solid(wedges, E, NU, RHO), "wedge", "tetra")
    _refused(lambda: assemble_solid(hex27, E, NU, RHO), "hexahedron27")
    _refused(lambda: assemble_solid(meshio.Mesh(p, [("tetra", t)]), E, NU, RHO, element="hex8"), "element", "tet4")
    _refused(lambda: assemble_solid(meshio.Mesh(p, [("tetra", t + len(p))]), E, NU, RHO), "point the mesh does not")
    _refused(lambda: assemble_solid(meshio.Mesh(p, [("tetra", t + 0.5)]), E, NU, RHO), "rows of 4 point indices")
    _refused(lambda: assemble_solid(meshio.Mesh(p[:, :2], [("tetra", t)]), E, NU, RHO), "finite 3-D coordinates")
    nan = p.copy()
    nan[3, 1] = np.nan
    _refused(lambda: assemble_solid(meshio.Mesh(nan, [("tetra", t)]), E, NU, RHO), "finite 3-D coordinates")
    (tmp_path / "x.stl").write_text("solid x\nendsolid x\n")
    _refused(lambda: assemble_solid("x.stl", E, NU, RHO, base=tmp_path), "unknown mesh format", ".msh")
    for name in ("empty.msh", "empty.inp", "empty.vtk", "empty.vtu"):
        (tmp_path / name).write_bytes(b"")
        _refused(lambda: assemble_solid(name, E, NU, RHO, base=tmp_path), name)
    (tmp_path / "nodes_only.inp").write_text("*NODE\n1, 0, 0, 0\n2, 1, 0, 0\n")
    _refused(lambda: assemble_solid("nodes_only.inp", E, NU, RHO, base=tmp_path), "no cells")
    (tmp_path / "junk.msh").write_bytes(os.urandom(5000))
    _refused(lambda: assemble_solid("junk.msh", E, NU, RHO, base=tmp_path), "junk.msh", "cannot read")


def test_missing_extra_named(monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "skfem", None)     # as if scikit-fem were not installed
    _refused(lambda: assemble_solid("part.msh", E, NU, RHO), "skfem is missing", "mbsfmu[fe]")


def test_material_refused():
    p, t = box_tets(0.2, 0.1, 0.1, 1, 1, 1)
    m = meshio.Mesh(p, [("tetra", t)])
    for E_, nu, rho, key in ((0.0, NU, RHO, "material.E"), (E, 0.5, RHO, "material.nu"),
                             (E, NU, float("nan"), "material.rho"), ("1e9", NU, RHO, "material.E")):
        _refused(lambda: assemble_solid(m, E_, nu, rho), key)


def test_big_outside_and_special_files_refused(tmp_path):
    big = tmp_path / "big.msh"
    with open(big, "wb") as f:
        f.truncate(2 * 2**30)                     # 2 GB, sparse: nothing of it may be read
    _refused(lambda: assemble_solid("big.msh", E, NU, RHO, base=tmp_path), "larger than")
    inner = tmp_path / "scene"
    inner.mkdir()
    _write(tmp_path / "part.msh", lambda t: [("tetra", t)])
    _refused(lambda: assemble_solid("../part.msh", E, NU, RHO, base=inner), "outside the scene's folder")
    (inner / "link.msh").symlink_to(tmp_path / "part.msh")
    _refused(lambda: assemble_solid("link.msh", E, NU, RHO, base=inner), "outside the scene's folder")
    os.mkfifo(inner / "fifo.msh")
    _refused(lambda: assemble_solid("fifo.msh", E, NU, RHO, base=inner), "not a regular file")
    (inner / "inc.inp").write_text(f"*Heading\n*INCLUDE, INPUT={tmp_path / 'part.inp'}\n")
    _refused(lambda: assemble_solid("inc.inp", E, NU, RHO, base=inner), "*INCLUDE")


def _vtu_bomb(blocks):
    """A .vtu whose points are zlib blocks of 64 MiB of zeros each (about 64 kB compressed, one block reused)."""
    import base64
    import zlib
    size = 64 * 2**20
    block = zlib.compress(bytes(size), 9)
    header = np.array([blocks, size, size] + [len(block)] * blocks, np.uint64).tobytes()
    data = base64.b64encode(header).decode() + base64.b64encode(block * blocks).decode()
    return f"""<?xml version="1.0"?>
<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64"
compressor="vtkZLibDataCompressor"><UnstructuredGrid><Piece NumberOfPoints="{blocks * size // 24}" NumberOfCells="1">
<Points><DataArray type="Float64" NumberOfComponents="3" format="binary">{data}</DataArray></Points>
<Cells><DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3</DataArray>
<DataArray type="Int64" Name="offsets" format="ascii">4</DataArray>
<DataArray type="UInt8" Name="types" format="ascii">10</DataArray></Cells></Piece></UnstructuredGrid></VTKFile>"""


FORGED = {   # file: a few hundred bytes whose headers declare 10⁹..10¹² entries (meshio allocates them)
    "nodes41.msh": "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 1000000000000 1 1000000000000\n"
                   "3 1 0 1000000000000\n1\n$EndNodes\n",
    "nodes22.msh": "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n1000000000000\n1 0 0 0\n$EndNodes\n",
    "points.vtk": "# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\n"
                  "POINTS 1000000000000 double\n0 0 0\n",
    "cells.vtk": "# vtk DataFile Version 4.2\nx\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 double\n"
                 "0 0 0 1 0 0 0 1 0 0 0 1\nCELLS 1000000000 5000000000\n4 0 1 2 3\nCELL_TYPES 1000000000\n10\n",
}


@pytest.mark.parametrize("name", [*FORGED, "bomb.vtu"])
def test_forged_counts_and_bombs_bounded(tmp_path, monkeypatch, name):
    """The foreign parser runs in a child under limits.FE_PARSE_BYTES (here lowered to 512 MiB, so that the 1 GiB
    zlib bomb fails fast): a declared 10¹² nodes or a decompression bomb is one ModelError line, within seconds."""
    from mbsfmu import limits
    monkeypatch.setattr(limits, "FE_PARSE_BYTES", 512 * 2**20)
    (tmp_path / name).write_text(_vtu_bomb(16) if name == "bomb.vtu" else FORGED[name])
    t0 = time.perf_counter()
    with pytest.raises(ModelError) as err:
        assemble_solid(name, E, NU, RHO, base=tmp_path)
    assert time.perf_counter() - t0 < 10.0
    assert "\n" not in str(err.value) and "cannot read" in str(err.value) and name in str(err.value)


def test_too_many_dofs_refused(monkeypatch):
    from mbsfmu import limits
    monkeypatch.setattr(limits, "FE_DOFS", 100)
    p, t = box_tets(0.2, 0.1, 0.1, 2, 1, 1)
    _refused(lambda: assemble_solid(meshio.Mesh(p, [("tetra", t)]), E, NU, RHO, element="tet10"), "DOFs", "100")


def quarter_tube(curved, R1=0.5, R2=1.0, L=0.3, n=(1, 3, 1)):
    """tet10 mesh of the quarter tube R1 ≤ r ≤ R2, 0 ≤ θ ≤ π/2, 0 ≤ z ≤ L: a box in (r, θ, z) mapped to
    x, y, z (orientation kept: the map's Jacobian is r > 0); midside nodes mapped too (`curved`: on the arcs) or at the
    mapped edges' midpoints (straight)."""
    def to_xyz(q):
        return np.column_stack([q[:, 0] * np.cos(q[:, 1]), q[:, 0] * np.sin(q[:, 1]), q[:, 2]])
    q4, t4 = box_tets(R2 - R1, np.pi / 2, L, *n)
    q4[:, 0] += R1
    if curved:
        q, t = tet10_cells(q4, t4)
        return to_xyz(q), t
    return tet10_cells(to_xyz(q4), t4)


def test_curved_tet10_is_isoparametric():
    """Midside nodes on the arcs make the elements isoparametric: the mass of a coarse quarter tube (3 elements
    around) comes within 0.1 % of ρ·π/4·(R2² − R1²)·L, 30× closer than with the same nodes on the chords; the
    midside nodes are FE nodes at their own coordinates, and the free body keeps its six rigid-body modes."""
    exact = RHO * np.pi / 4 * (1.0**2 - 0.5**2) * 0.3
    mass = {}
    for curved in (True, False):
        p, t = quarter_tube(curved)
        fe = assemble_solid(meshio.Mesh(p, [("tetra10", t)], point_sets={"all": np.arange(len(p))}), E, NU, RHO)
        one = np.zeros(fe.M.shape[0])
        one[0::3] = 1.0
        mass[curved] = one @ fe.M @ one
        assert same_points(fe.nodes, p) and same_points(fe.nodes[fe.node_sets["all"]], p)
    assert abs(mass[True] / exact - 1) < 1e-3 and abs(mass[True] - exact) < abs(mass[False] - exact) / 30
    w = np.linalg.eigvalsh(fe.K.toarray())
    assert np.sum(np.abs(w) < 1e-9 * w.max()) == 6


def test_overcurved_tet10_refused():
    """A midside node moved along its edge to a quarter of the edge from a corner (0.3 of the edge off the midpoint)
    makes the isoparametric Jacobian negative at that corner."""
    p4, t4 = box_tets(0.2, 0.1, 0.1, 2, 1, 1)
    p, t = tet10_cells(p4, t4)
    a, b = p[t[2, 0]], p[t[2, 1]]
    p[t[2, 4]] = 0.8 * a + 0.2 * b
    _refused(lambda: assemble_solid(meshio.Mesh(p, [("tetra10", t)]), E, NU, RHO), "inverted", "curved")


def test_docs_quote_the_limits():
    """docs/scene-format.md states the mesh limits of limits.py (the one source)."""
    from pathlib import Path

    from mbsfmu import limits
    text = (Path(__file__).resolve().parents[1] / "docs" / "scene-format.md").read_text(encoding="utf-8")
    for quoted in (f"`FE_MESH_BYTES` ({limits.FE_MESH_BYTES // 2**20} MiB)",
                   f"`FE_PARSE_BYTES` ({limits.FE_PARSE_BYTES // 2**30} GiB)",
                   f"`FE_PARSE_SECONDS` ({limits.FE_PARSE_SECONDS} s", "`FE_DOFS`"):
        assert quoted in text, quoted


def _mutant(rng, data):
    """`data` with a few random byte edits, deletions, duplications, big numbers or a truncation."""
    d = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        i, k = rng.randrange(len(d)), rng.random()
        if k < 0.3:
            d[i] = rng.randrange(256)
        elif k < 0.5:
            del d[i:i + rng.randint(1, 50)]
        elif k < 0.7:
            j = rng.randrange(len(d))
            d[i:i] = d[j:j + rng.randint(1, 80)]
        elif k < 0.85:
            d[i:i] = str(rng.choice([0, -1, 10**12, 2**31, 2**63])).encode()
        else:
            del d[i:]
    return bytes(d)


def test_fuzzed_mesh_files_raise_model_error_only(tmp_path):
    """Mutants of valid gmsh 2.2, Abaqus, VTK and VTU files: each assembles or is one ModelError line, within
    seconds (400 mutants of this kind passed when written; 16 here, for the suite's time)."""
    import random
    p, t = box_tets(0.2, 0.1, 0.1, 2, 1, 1)
    m = meshio.Mesh(p, [("tetra", t)], point_sets={"a": np.arange(3)})
    seeds = {}
    for suffix, fmt in ((".msh", "gmsh22"), (".inp", "abaqus"), (".vtk", "vtk"), (".vtu", "vtu")):
        m.write(tmp_path / f"seed{suffix}", file_format=fmt, **({"binary": False} if fmt in ("gmsh22", "vtk") else {}))
        seeds[suffix] = (tmp_path / f"seed{suffix}").read_bytes()
    rng = random.Random(24)
    for n in range(16):
        suffix = list(seeds)[n % 4]
        (tmp_path / f"m{n}{suffix}").write_bytes(_mutant(rng, seeds[suffix]))
        t0 = time.perf_counter()
        try:
            assemble_solid(f"m{n}{suffix}", E, NU, RHO, base=tmp_path, element=rng.choice([None, "tet10"]))
        except ModelError as err:
            assert "\n" not in str(err)
        assert time.perf_counter() - t0 < 10.0


def test_material_as_the_docs_write_it(tmp_path, monkeypatch):
    """`material: {E: 2.1e11, ...}` (docs/scene-format.md): PyYAML reads 2.1e11 as text; the scene takes it as the
    number, the same body as `E: 2.1e+11` (which YAML 1.1 reads as a float)."""
    import mbsfmu
    monkeypatch.setenv("MBSFMU_CACHE", str(tmp_path / "cache"))
    p, t = box_tets(0.2, 0.1, 0.1, 2, 1, 1)
    meshio.Mesh(p, [("tetra", t)]).write(tmp_path / "box.vtu")
    bodies = []
    for material in ("{E: 2.1e11, nu: 3e-1, rho: 7.85E3}", "{E: 2.1e+11, nu: 0.3, rho: 7850.0}"):
        (tmp_path / "s.yaml").write_text(f"""mbsfmu: 1
name: fe_material
bodies:
  part:
    parent: world
    joint: {{type: fixed}}
    elastic:
      fe: {{mesh: box.vtu, material: {material}, method: free, modes: 1, keep: [0]}}
""")
        bodies.append(mbsfmu.load(tmp_path / "s.yaml").spec["bodies"][0]["elastic"]["fe"])
    assert bodies[0]["stiffness"] == bodies[1]["stiffness"] and bodies[0]["m"] == pytest.approx(RHO * 0.2 * 0.1 * 0.1)
