"""FMI 2.0 co-simulation FMUs (pythonfmu based) from mbsfmu scenes."""
from .build import build_fmu
from .common import model_description

__all__ = ["build_fmu", "model_description"]
