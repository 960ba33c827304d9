"""Time integrators run inside the FMU's do_step (pure numpy/scipy).

All methods share one API: make_integrator(method, problem, ...), reset(t0, x0), advance(t_end),
t, x, stats, get_state()/set_state(), inputs_changed(). See registry.METHODS for the names.
"""

from .registry import METHODS, make_integrator
from .solve import solve

__all__ = ["METHODS", "make_integrator", "solve"]
