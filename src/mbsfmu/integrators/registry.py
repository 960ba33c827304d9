"""Method name → integrator class, and the factory used by the FMU."""

import math

from .auto import Auto
from .dop853 import Dop853
from .dopri5 import Dopri5
from .radau5 import Radau5
from .rk4 import RK4

_CLASSES = {"rk4": RK4, "dopri5": Dopri5, "dop853": Dop853, "radau5": Radau5, "auto": Auto}


def _register_gen_alpha():
    """gen_alpha lives in its own module; imported lazily to keep this table the single source."""
    from .gen_alpha import GenAlpha
    _CLASSES["gen_alpha"] = GenAlpha


try:
    _register_gen_alpha()
except ImportError:  # pragma: no cover - only while the module is being written
    pass

METHODS = tuple(_CLASSES)


def make_integrator(method, problem, rtol=1e-6, atol=1e-8, max_step=math.inf, h=None, **options):
    """Build the integrator named `method` (one of METHODS) for `problem`."""
    key = str(method).strip().lower()
    if key not in _CLASSES:
        raise ValueError(f"unknown integrator method {method!r}; valid: {', '.join(METHODS)}")
    return _CLASSES[key](problem, rtol=rtol, atol=atol, max_step=max_step, h=h, **options)
