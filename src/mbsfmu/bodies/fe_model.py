"""The FEModel every FE reader produces (fe.py: matrix files, fe_mesh.py: a meshed solid) and cms.py reduces."""

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp


@dataclass(frozen=True)
class FEModel:
    """A solid FE model in the body frame: nodes (N×3), consistent M and K (3N×3N, node-major x y z)."""
    nodes: np.ndarray
    M: sp.csr_matrix
    K: sp.csr_matrix
    node_sets: dict = field(default_factory=dict)   # name -> node indices (0-based)
    source: str = ""                                # file name(s), for messages
    stress: object = None   # a mesh's σ at nodes: (U 3N×n, nodes) → (nodes, 6, n) (fe_mesh.nodal_stress); else None

    @property
    def n_nodes(self):
        return self.nodes.shape[0]
