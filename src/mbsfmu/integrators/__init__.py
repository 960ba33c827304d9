"""Time integrators run inside the FMU's do_step (pure numpy/scipy, no compiled extras).

Problem (duck-typed): n, npos, nvel; f(t, x) -> ẋ for x = [y; v]; optional jac(t, x) (else finite
differences), normalize(x) (applied after every accepted step; x may also be states as rows); for
gen_alpha also accel(t, y, v) -> v̇ and retract(y, dy) (y ⊕ dy; plain addition is assumed when absent
and npos == nvel).

Integrator (same API for every method in METHODS):
    integ = make_integrator(method, problem, rtol=1e-6, atol=1e-8, max_step=inf, h=None, max_steps=1e6)
    integ.reset(t0, x0); x = integ.advance(t_end)      # lands exactly on t_end, carries h to the next call
    X = advance_many(integ, ts)                          # rows x(ts[i]): same steps, points of one step at once
    integ.inputs_changed()                               # f jumped (new inputs/parameters): drop cached f
    integ.t, integ.x, integ.h, integ.stats
    s = integ.get_state(); integ.set_state(s)            # picklable; continuing is bit-identical
Failures raise mbsfmu.errors.IntegrationError with the integrator left at the last accepted point.

Methods: rk4 (fixed), dopri5, dop853, radau5, gen_alpha (fixed with h, else adaptive), auto
(dopri5 → radau5 on detected stiffness; integ.switched_at, stats["switched"]).
"""

from .base import advance_many
from .registry import METHODS, make_integrator
from .solve import solve

__all__ = ["METHODS", "advance_many", "make_integrator", "solve"]
