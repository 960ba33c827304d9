"""'auto': DOPRI5 until its stiffness test fires (Hairer's h·|λ| > 3.25, 15 times), then RADAU5 for good."""

import math

from mbsfmu.errors import IntegrationError

from .base import deep_copy, new_stats
from .dopri5 import Dopri5
from .radau5 import Radau5


class Auto:
    """Same API as the other integrators; t, x, h and stats come from the active method."""

    method = "auto"

    def __init__(self, problem, rtol=1e-6, atol=1e-8, max_step=math.inf, h=None, max_steps=1_000_000,
                 dense=True):
        kw = dict(rtol=rtol, atol=atol, max_step=max_step, max_steps=max_steps)
        self.problem = problem
        self.nonstiff = Dopri5(problem, stop_when_stiff=True, dense=dense, **kw)
        self.stiff = Radau5(problem, dense=dense, **kw)
        self.phase = "dopri5"
        self.switched_at = None

    @property
    def _active(self):
        """The integrator currently in charge."""
        return self.nonstiff if self.phase == "dopri5" else self.stiff

    t = property(lambda self: self._active.t, doc="current time")
    x = property(lambda self: self._active.x, doc="current state")
    h = property(lambda self: self._active.h, doc="proposed next step size")

    @property
    def stats(self):
        """Counters summed over both phases, plus the switch flag and time."""
        s = new_stats()
        for integ in (self.nonstiff, self.stiff) if self.phase == "radau5" else (self.nonstiff,):
            for k, v in integ.stats.items():
                s[k] = s.get(k, 0) + v
        s["switched"] = self.phase == "radau5"
        s["switched_at"] = self.switched_at
        return s

    def reset(self, t0, x0):
        """Start non-stiff again at (t0, x0)."""
        self.phase = "dopri5"
        self.switched_at = None
        self.nonstiff.reset(t0, x0)

    @property
    def dense(self):
        """Whether the integrators step past communication points and interpolate."""
        return self.nonstiff.dense

    def inputs_changed(self):
        """Forward to the active method (cached derivatives are stale)."""
        self._active.inputs_changed()

    def advance(self, t_end):
        """Advance with DOPRI5; on detected stiffness continue from that point with RADAU5."""
        if self.phase == "dopri5":
            if self.nonstiff.x is None:
                raise IntegrationError("reset(t0, x0) must be called before advance()")
            self.nonstiff.advance(t_end)
            # stiffness may be detected in a dense-output step that went past t_end: switch at the
            # visible point (the ahead point of DOPRI5 is dropped with it)
            if self.nonstiff.t < t_end or self.nonstiff.stiff_detected:
                self._switch()
        if self.phase == "radau5":
            self.stiff.advance(t_end)
        return self.x.copy()

    def _switch(self):
        """Hand (t, x) and the current step size to RADAU5, which grows h as stability allows."""
        ns = self.nonstiff
        self.stiff.reset(ns.t, ns.x)
        self.stiff.h = ns.h
        self.phase = "radau5"
        self.switched_at = ns.t

    def get_state(self):
        """Snapshot of both sub-integrators and the phase."""
        s = {"method": self.method, "phase": self.phase, "switched_at": self.switched_at,
             "nonstiff": self.nonstiff.get_state()}
        if self.phase == "radau5":
            s["stiff"] = self.stiff.get_state()
        return s

    def set_state(self, s):
        """Restore a get_state() snapshot."""
        if s.get("method") != self.method:
            raise ValueError(f"state of method {s.get('method')!r} given to an 'auto' integrator")
        s = deep_copy(s)
        self.phase, self.switched_at = s["phase"], s["switched_at"]
        self.nonstiff.set_state(s["nonstiff"])
        if self.phase == "radau5":
            self.stiff.set_state(s["stiff"])
