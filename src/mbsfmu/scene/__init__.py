"""Scene files: YAML reading with line numbers, validation, normalization (build time only)."""

from .load import Scene, load, loads

__all__ = ["Scene", "load", "loads"]
