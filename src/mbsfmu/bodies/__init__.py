"""Elastic bodies: nodal data, the built-in beam generator and the floating-frame-of-reference equations."""

from .beam import beam, beam_from_spec
from .elastic import elastic_body, node_index
from .ffrf import (K_geo, elastic_forces, gravity_forces, invariants, kinetic_energy, mass_matrix,
                   node_rotation, node_translation, quadratic_forces)
from .nodal import MassPoints, NodalData, damping_from_ratio, validate_nodal

__all__ = ["elastic_body", "node_index", "beam", "beam_from_spec", "invariants", "mass_matrix", "quadratic_forces", "gravity_forces",
           "elastic_forces", "K_geo", "kinetic_energy", "node_translation", "node_rotation",
           "NodalData", "MassPoints", "validate_nodal", "damping_from_ratio"]
