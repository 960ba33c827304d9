"""Writes the FE model of models/fe_plate.yaml as Abaqus writes it: an aluminium plate 0.4 × 0.1 × 0.005 m (x along
the plate, z through its thickness), tet10 (scikit-fem P2 on a tensor tet mesh); the part's nodes and node sets in
plate.inp (*NODE, *NSET HUB for the edge x = 0, *NSET TIP for the edge x = L), mass and stiffness as
`*MATRIX OUTPUT, FORMAT=MATRIX INPUT` files (lower triangle, lines `row_node, row_dof, col_node, col_dof, value`).
Node labels are 101, 103, 105, … as a part meshed among others gets them.
Run once from the repository: python models/fe/make_plate.py  (needs the `fe` extra)."""

from pathlib import Path

import numpy as np
import scipy.sparse as sp
import skfem
from skfem.helpers import dot
from skfem.models.elasticity import lame_parameters, linear_elasticity

L, W, T = 0.4, 0.1, 0.005            # m
E, NU, RHO = 70e9, 0.33, 2700.0      # Pa, -, kg/m³


@skfem.BilinearForm
def mass(u, v, w):
    return RHO * dot(u, v)


def plate(nx=8, ny=2, nz=1):
    """(nodes N×3, M, K) of the plate, DOFs node-major x y z."""
    mesh = skfem.MeshTet.init_tensor(np.linspace(0, L, nx + 1), np.linspace(-W / 2, W / 2, ny + 1),
                                     np.linspace(-T / 2, T / 2, nz + 1))
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementTetP2()))
    dofs = np.vstack([basis.nodal_dofs.T, basis.edge_dofs.T])
    order = dofs.ravel()
    K = linear_elasticity(*lame_parameters(E, NU)).assemble(basis)[order][:, order]
    M = mass.assemble(basis)[order][:, order]
    return basis.doflocs[:, dofs[:, 0]].T, sp.csr_matrix(M), sp.csr_matrix(K)


def nset(name, labels):
    return [f"*NSET, NSET={name}"] + [", ".join(map(str, labels[i:i + 8])) for i in range(0, len(labels), 8)]


if __name__ == "__main__":
    here = Path(__file__).parent
    X, M, K = plate()
    labels = 101 + 2 * np.arange(len(X))
    inp = ["*HEADING", "plate of models/fe_plate.yaml (models/fe/make_plate.py)", "*NODE"]
    inp += [f"{n}, {x:.17g}, {y:.17g}, {z:.17g}" for n, (x, y, z) in zip(labels, X)]
    inp += nset("HUB", labels[np.isclose(X[:, 0], 0)]) + nset("TIP", labels[np.isclose(X[:, 0], L)])
    (here / "plate.inp").write_text("\n".join(inp) + "\n")
    for A, name in ((M, "plate_mass.mtx"), (K, "plate_stiffness.mtx")):
        low = sp.tril(A).tocoo()
        (here / name).write_text("".join(f"{labels[i // 3]}, {i % 3 + 1}, {labels[j // 3]}, {j % 3 + 1}, {v:.17g}\n"
                                         for i, j, v in zip(low.row, low.col, low.data)))
    print(f"{len(X)} nodes, {3 * len(X)} DOFs; hub edge {np.isclose(X[:, 0], 0).sum()} nodes, "
          f"tip edge {np.isclose(X[:, 0], L).sum()} nodes")
