"""FEModel as agreed with bodies/fe.py (issue 24), until that module lands: then fe_mesh imports it from there."""

from dataclasses import dataclass

import numpy as np
import scipy.sparse


@dataclass(frozen=True)
class FEModel:
    nodes: np.ndarray          # (N, 3) node coordinates in the body frame
    M: scipy.sparse.csr_matrix # (3N, 3N) consistent mass matrix, translational DOFs, node-major: [u1x u1y u1z u2x ...]
    K: scipy.sparse.csr_matrix # (3N, 3N) stiffness matrix, same DOF order
    node_sets: dict            # name -> node indices (0-based)
    source: str                # for messages: file name(s)
