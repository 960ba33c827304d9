"""Writes the FE model of models/fe_link.yaml: a steel link 0.5 × 0.04 × 0.01 m (x along the link), tet10
(scikit-fem P2 on a tensor tet mesh), as Matrix Market mass and stiffness matrices (node-major x y z) and a node
file; and the same link's tet4 mesh with node sets (link.inp) for models/fe_stress.yaml, which assembles it as
tet10 itself.  Run once from the repository: python models/fe/make_link.py  (needs the `fe` extra)."""

from pathlib import Path

import numpy as np
import scipy.io
import scipy.sparse as sp
import skfem
from skfem.helpers import dot
from skfem.models.elasticity import lame_parameters, linear_elasticity

L, W, T = 0.5, 0.04, 0.01            # m
E, NU, RHO = 210e9, 0.3, 7850.0      # Pa, -, kg/m³


@skfem.BilinearForm
def mass(u, v, w):
    return RHO * dot(u, v)


def tensor_mesh(nx=8, ny=1, nz=1):
    return skfem.MeshTet.init_tensor(np.linspace(0, L, nx + 1), np.linspace(-W / 2, W / 2, ny + 1),
                                     np.linspace(-T / 2, T / 2, nz + 1))


def link(nx=8, ny=1, nz=1):
    """(nodes N×3, M, K) of the link, DOFs node-major x y z (skfem numbers vertex DOFs first, then edge DOFs)."""
    mesh = tensor_mesh(nx, ny, nz)
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP2()))
    dofs = np.vstack([basis.nodal_dofs.T, basis.edge_dofs.T])        # (nodes, 3): x, y, z DOF of each node
    order = dofs.ravel()
    K = linear_elasticity(*lame_parameters(E, NU)).assemble(basis)[order][:, order]
    M = mass.assemble(basis)[order][:, order]
    return basis.doflocs[:, dofs[:, 0]].T, sp.csr_matrix(M), sp.csr_matrix(K)


def write_mesh(path):
    """The link's tet4 cells (positively oriented, VTK order) as an Abaqus .inp with point sets: the end faces
    root (x = 0) and tip (x = L), and the stress gauges at x = L/8 on the edge y = -W/2 of the top and bottom
    faces (the swing bends the link about y: its largest stresses are there, next to the hinge)."""
    import meshio
    m = tensor_mesh()
    p, t = m.p.T, m.t.T.copy()
    a = p[t[:, 0]]
    flip = np.einsum("ij,ij->i", p[t[:, 1]] - a, np.cross(p[t[:, 2]] - a, p[t[:, 3]] - a)) < 0
    t[flip] = t[flip][:, [1, 0, 2, 3]]

    def at(x, y, z):
        return np.flatnonzero(np.all(np.isclose(p, [x, y, z]), axis=1))
    sets = {"root": np.flatnonzero(p[:, 0] == 0), "tip": np.flatnonzero(np.isclose(p[:, 0], L)),
            "gauge_top": at(L / 8, -W / 2, T / 2), "gauge_bottom": at(L / 8, -W / 2, -T / 2)}
    meshio.Mesh(p, [("tetra", t)], point_sets=sets).write(path)


if __name__ == "__main__":
    here = Path(__file__).parent
    X, M, K = link()
    scipy.io.mmwrite(here / "link_mass.mtx", M, symmetry="symmetric", precision=17)
    scipy.io.mmwrite(here / "link_stiffness.mtx", K, symmetry="symmetric", precision=17)
    np.savetxt(here / "link_nodes.csv", X, delimiter=",", fmt="%.17g", header="x, y, z (m), one node per line")
    write_mesh(here / "link.inp")
    print(f"{len(X)} nodes, {3 * len(X)} DOFs; the end x = 0 is the interface: nodes "
          f"{np.flatnonzero(X[:, 0] == 0).tolist()}; tip node {int(np.argmax(X[:, 0] + X[:, 1] + X[:, 2]))}")
