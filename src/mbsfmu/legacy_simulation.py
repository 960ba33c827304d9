"""Transition only (elastic scenes until their terms are in the engine) — one simulated scene: evaluator + integrator + the FMU's variables (inputs held over a step).

This is what the FMU wraps and what in-process runs use, so both give the same numbers.
"""

import math

import numpy as np

from .equations import Evaluator
from .simulation import variables
from .errors import IntegrationError
from .integrators import advance_many, make_integrator
from .kinematics.rotations import quat_exp_step


class Problem:
    """First-order form x = [y; ẏ] for the integrators: ẋ = [Z(y)·ẏ; M⁻¹(q − k)]."""

    def __init__(self, ev):
        self.ev = ev
        m = ev.model
        self.npos, self.nvel = m.npos, m.nvel
        self.n = m.npos + m.nvel
        self.q_in, self.F_in = None, None
        self.quats = m.quaternions
        self.quat_vel = m.quat_vel
        # a joint's 4 quaternion entries are consecutive: a slice is a view (in-place update, no fancy indexing)
        self._quat_slices = [slice(int(q[0]), int(q[0]) + 4) for q in self.quats]
        assert all((q == np.arange(q[0], q[0] + 4)).all() for q in self.quats)
        if not self.quats:
            self.normalize = None  # integrators skip the projection entirely
        self.rhs_calls = 0
        self.cardan = any(b.kind in ("spherical", "free") and b.param == "cardan" for b in m.bodies)

    def accel(self, t, y, v):
        """ÿ = M⁻¹ (q − k)."""
        self._check_gimbal(t, y)
        M, k, q = self.ev._equations(y, v, t, self.q_in, self.F_in)
        try:
            return np.linalg.solve(M, q - k)
        except np.linalg.LinAlgError:
            raise self._singular(t, y) from None

    def f(self, t, x):
        self.rhs_calls += 1
        y, v = x[:self.npos], x[self.npos:]
        return np.concatenate([self.ev.position_rates(y, v), self.accel(t, y, v)])

    def _singular(self, t, y):
        """M is not positive definite at y: gimbal lock of Cardan angles, or a mass-less chain."""
        return IntegrationError(self.ev.singularity_message(y) or "the mass matrix is singular", t)

    def _check_gimbal(self, t, y):
        if self.cardan:  # only scenes with Cardan joints pay for the gimbal-lock check
            msg = self.ev.singularity_message(y)
            if msg:
                raise IntegrationError(msg, t)

    def normalize(self, x):
        """Project quaternions back to unit length after each step (None for scenes without quaternions);
        x is one state or states as rows."""
        x = x.copy()
        for qi in self._quat_slices:
            p = x[..., qi]
            if x.ndim == 1:
                p /= math.sqrt(p.dot(p))
            else:
                p /= np.sqrt(np.einsum("ij,ij->i", p, p))[:, None]
        return x

    def retract(self, y, dy):
        """y ⊕ dy: plain coordinates add, quaternions rotate by the body-frame rotation vector."""
        if not self.quats:
            return y + dy
        m = self.ev.model
        out = np.empty_like(y)
        for qi, wi in zip(self.quats, self.quat_vel):
            out[qi] = quat_exp_step(y[qi], dy[wi])
        out[m.plain_pos] = y[m.plain_pos] + dy[m.plain_vel]
        return out


class Simulation:
    """A scene ready to step: set parameters and inputs, initialize, do_step, read outputs."""

    def __init__(self, spec):
        self.spec = spec
        self.ev = Evaluator(spec)
        self.problem = Problem(self.ev)
        self.variables = variables(spec, self.ev.model)
        self._by_name = {v.name: v for v in self.variables}
        npos = self.problem.npos
        self._state_index = {f"y.{c}": i for i, c in enumerate(self.ev.coordinates)}
        self._state_index.update({f"yd.{c}": npos + i for i, c in enumerate(self.ev.velocity_coordinates)})
        self._outputs = None
        self._initial = None  # (x0, point outputs) read before initialization
        self.values = {v.name: v.start for v in self.variables if v.causality in ("input", "parameter")}
        self.integrator = None
        self.time = spec["experiment"]["start"]
        self.x = None

    def set(self, name, value):
        v = self._by_name.get(name)
        if v is None or v.causality == "output":
            raise KeyError(f"'{name}' is not an input or parameter of {self.spec['name']}")
        self._initial = None
        if v.type == "String":
            self.values[name] = str(value)
        else:
            self.values[name] = float(value)
            if v.causality == "parameter" and v.variability == "tunable" and self.x is not None:
                self._params_dirty = True
        if v.causality == "input":
            self._inputs_dirty = True

    def get(self, name):
        if name in self.values:
            return self.values[name]
        if self.x is None:  # before initialization: the initial state at the parameters set so far
            if self._initial is None:
                self._bind_parameters()
                x = np.concatenate(self.ev.initial_state())
                self._initial = x, self._compute_outputs(x[:self.problem.npos], x[self.problem.npos:])
            return self._output(name, self._initial[0], self.time, self._initial[1])
        if self._outputs is None:  # computed on demand: a master may never read the point outputs
            self._outputs = self._compute_outputs(self.y, self.yd)
        return self._output(name, self.x, self.time, self._outputs)

    def _output(self, name, x, t, points):
        i = self._state_index.get(name)
        if i is not None:
            return float(x[i])
        return points[name]

    # -- running ------------------------------------------------------------------------------------
    def initialize(self, t0=None):
        """Bind parameters, build the integrator and the initial state (exit of initialization mode)."""
        if t0 is not None:
            self.time = float(t0)
        self._bind_parameters()
        y0, yd0 = self.ev.initial_state()
        self.x = np.concatenate([y0, yd0])
        v = self.values
        step = v["integrator.step"] or None
        self.integrator = make_integrator(v["integrator.method"], self.problem, rtol=v["integrator.rtol"],
                                          atol=v["integrator.atol"], max_step=v["integrator.max_step"] or math.inf,
                                          h=step, **({"rho_inf": self.spec["integrator"]["rho_inf"]} if v["integrator.method"] == "gen_alpha" else {}))
        self.integrator.reset(self.time, self.x)
        self._applied = None
        self._inputs_dirty = True
        self._params_dirty = False
        self._outputs = None

    def _bind_parameters(self):
        """Hand the scene parameters' current values to the evaluator."""
        self.ev.set_parameters({p["name"]: self.values[p["name"]] for p in self.spec["parameters"]})

    def _apply_inputs(self):
        """Copy FMU inputs into the problem (held constant over the step); refuse NaN/Inf."""
        u = {n: self.values[n] for n in self.ev.inputs}
        bad = [n for n, x in u.items() if not math.isfinite(x)]
        if bad:
            raise IntegrationError(f"input {', '.join(bad)} is not finite ({u[bad[0]]}); step refused", self.time)
        self._inputs_dirty = False
        if u == getattr(self, "_applied", None):
            return False
        self.problem.q_in, self.problem.F_in = self.ev._split_inputs({n: x for n, x in u.items() if x != 0.0})
        self._applied = u
        return True

    def do_step(self, t, h):
        """Advance from t to t + h with the inputs held; raises IntegrationError (state stays at self.time)."""
        self._prepare(t)
        x_before = self.x
        try:
            x = self.integrator.advance(t + h)
        except IntegrationError as e:
            raise self._failed(e) from None
        self.time, self.x = self.integrator.t, x
        if self.problem.cardan:  # a coarse step may jump across b = ±90° without landing near it
            npos = self.problem.npos
            msg = self.ev.singularity_message(x[:npos], x_before[:npos])
            if msg:
                raise IntegrationError(msg, self.time)
        self._outputs = None

    def run(self, ts):
        """States at the communication points ts (ts[0] = now) with the inputs held throughout: the same
        steps as one do_step per interval, but points inside one dense-output step are interpolated
        together (like solve_ivp's t_eval). Returns X with a row [y; ẏ] per point."""
        ts = np.asarray(ts, dtype=float)
        self._prepare(ts[0])
        X = np.empty((len(ts), self.problem.n))
        X[0] = self.x
        if self.problem.cardan:  # the gimbal check looks at every consecutive pair of points
            for k in range(len(ts) - 1):
                self.do_step(ts[k], ts[k + 1] - ts[k])
                X[k + 1] = self.x
            return X
        try:
            X[1:] = advance_many(self.integrator, ts[1:])
        except IntegrationError as e:
            raise self._failed(e) from None
        self.time, self.x = self.integrator.t, X[-1].copy()
        self._outputs = None
        return X

    def _prepare(self, t):
        """Before a step at t: initialize on first use, bind changed parameters and inputs."""
        if self.integrator is None:
            self.initialize(t)
        if self._params_dirty:
            bad = [p["name"] for p in self.spec["parameters"] if not math.isfinite(self.values[p["name"]])]
            if bad:
                raise IntegrationError(f"parameter {bad[0]} is not finite; step refused", self.time)
            self._bind_parameters()
            self._params_dirty = False
            self.integrator.inputs_changed()
        if self._inputs_dirty:
            if self._apply_inputs():  # masters set every input each step: restart only on a real change
                self.integrator.inputs_changed()
        if abs(t - self.time) > 1e-9 * max(1.0, abs(t)):
            raise IntegrationError(f"do_step called at t={t} but the simulation is at t={self.time}", self.time)

    def _failed(self, e):
        """The integrator stopped at its last good point: move there, name a singularity if there is one."""
        self.time, self.x = self.integrator.t, self.integrator.x.copy()
        self._outputs = None
        msg = self.ev.singularity_message(self.x[:self.ev.model.npos])
        return IntegrationError(e.message + (f"; {msg}" if msg and msg not in e.message else ""), self.time)

    def _compute_outputs(self, y, yd):
        """Values of the `outputs:` points (y and ẏ are read straight from the state)."""
        return self.ev.output_values(y, yd, self.time)

    npos = property(lambda self: self.problem.npos)
    nvel = property(lambda self: self.problem.nvel)
    stats = property(lambda self: dict(self.integrator.stats) if self.integrator else {})
    initialized = property(lambda self: self.integrator is not None)

    def f(self, t, x):
        return self.problem.f(t, x)

    @property
    def y(self):
        return self.x[:self.ev.model.npos]

    @property
    def yd(self):
        return self.x[self.ev.model.npos:]

    # -- state ----------------------------------------------------------------------------------------
    def get_state(self):
        """Everything that determines the future: time, state, inputs, parameters, integrator history."""
        return {"time": self.time, "x": None if self.x is None else self.x.copy(), "values": dict(self.values),
                "integrator": None if self.integrator is None else self.integrator.get_state(),
                "outputs": None if self._outputs is None else dict(self._outputs)}

    def set_state(self, s):
        self.values = dict(s["values"])
        self._initial = None
        if s["integrator"] is None:
            self.integrator, self.x, self.time = None, None, s["time"]
            return
        if self.integrator is None or self.integrator.method != s["integrator"]["method"]:
            self.initialize(s["time"])
        self._bind_parameters()
        self.integrator.set_state(s["integrator"])
        self.time, self.x = s["time"], s["x"].copy()
        self._outputs = None if s.get("outputs") is None else dict(s["outputs"])
        self._applied = None
        self._apply_inputs()
        self._params_dirty = False

    def reset(self):
        """Back to the state after instantiation (fmi2Reset)."""
        self.__init__(self.spec)

