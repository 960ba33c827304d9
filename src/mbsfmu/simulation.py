"""One simulated scene on the engine: the FMU's variables (compiler/variables.py), parameters and inputs held
over a step.

In-process runs, the pythonfmu FMU and the native FMU all run the same C engine (mbsfmu.engine), so all
three give the same numbers. Python compiles the scene once (compiler/scene_file.py); every step runs in C.
"""

import hashlib
import json
import math
import uuid

import numpy as np

from .engine import Instance
from .engine import layout as L
from .compiler.scene_file import compile_scene
from .compiler.model import Model
from .errors import IntegrationError
from .scene import domains
from .compiler.variables import Variable, variables


def compiled(spec, guid=None, derivatives=False):
    """(compiled scene bytes, variables, model) of a normalized spec; guid: the FMU's, else one derived from the
    scene (equal scenes accept each other's states); derivatives: with model exchange's derivative variables, as
    the native FMUs compile them."""
    model = Model(spec)
    var = variables(spec, model, derivatives=derivatives)
    if guid is None:
        digest = hashlib.sha256(json.dumps(spec, sort_keys=True, default=str).encode()).hexdigest()
        guid = "{" + str(uuid.UUID(digest[:32])) + "}"
    return compile_scene(spec, var, guid, model), var, model


class Simulation:
    """A scene ready to step: set parameters and inputs, initialize, do_step, read outputs."""

    def __init__(self, spec, _original=None):
        self.spec = spec
        self._original = spec if _original is None else _original  # reset() goes back to it
        self.blob, self.variables, model = compiled(spec)
        self.coordinates, self.velocity_coordinates = list(model.coordinates), list(model.velocity_coordinates)
        self.npos, self.nvel = model.npos, model.nvel
        self.engine = Instance(self.blob)
        self._vr = {v.name: i for i, v in enumerate(self.variables)}
        # structural parameters (they shape the elastic bodies' FE data) are compiled in: changing one before
        # initialize compiles the scene again and replays what was set so far
        self._structural = {p["name"] for p in spec["parameters"]} & {v.name for v in self.variables if v.variability == "fixed"}
        self._settings = {}
        self._start = {f"y0.{c}": i for i, c in enumerate(self.coordinates)}
        self._start.update({f"yd0.{c}": self.npos + i for i, c in enumerate(self.velocity_coordinates)})
        self.time = spec["experiment"]["start"]
        self.initialized = False

    # -- variables ----------------------------------------------------------------------------------
    def set(self, name, value):
        """Set an input or parameter by FMU name; `y0.<coordinate>` / `yd0.<coordinate>` replace an initial
        value (before initialize). A value outside the variable's domain (scene/domains.py), or one that makes a
        quantity of the scene invalid, raises ValueError naming it; nothing changes then."""
        vr = self._vr.get(name)
        if name not in self._start and (vr is None or self.variables[vr].causality == "output"):
            raise KeyError(f"'{name}' is not an input or parameter of {self.spec['name']}")
        string = vr is not None and self.variables[vr].type == "String"
        if not string:
            value = as_real(name, value)
        if name in self._structural and not self.initialized:
            self._recompile(name, value)
        elif name in self._start:
            self.engine.set_start(self._start[name], value)
        elif string:
            self.engine.set_string(vr, value)
        else:
            self.engine.set_real(vr, value)
        if not self.initialized:
            self._settings[name] = value

    def set_many(self, values):
        """Set {name: value} at once: the Real parameters, inputs and integrator settings together (values that
        must change together, such as the moments of an inertia, are checked together and none changes on a
        refusal), structural parameters, start values and integrator.method first, one by one as `set`."""
        together = {}
        for name, value in values.items():
            v = self.variables[self._vr[name]] if name in self._vr else None
            if v is not None and name not in self._structural and v.type == "Real" and v.causality != "output":
                together[name] = as_real(name, value)
            else:
                self.set(name, value)  # one by one (an unknown name or an output: refused naming it)
        if together:
            self.engine.set_reals([self._vr[n] for n in together], list(together.values()))
            if not self.initialized:
                self._settings.update(together)

    def _recompile(self, name, value):
        """A structural parameter: the scene compiled again with it, what was set so far replayed; on any
        refusal this simulation stays as it was."""
        domain = domains.variable_domain(name, self.spec)
        if not domain.contains(value):
            raise ValueError(f"{name} = {value:g} is {'outside its domain' if math.isfinite(value) else 'not finite'} "
                             f"(valid: {domain.text})")
        spec = json.loads(json.dumps(self.spec))
        for p in spec["parameters"]:
            if p["name"] == name:
                p["value"] = value
        try:
            other = Simulation(spec, self._original)
            other.time = self.time
            other.set_many({k: v for k, v in self._settings.items() if k != name})
        except (ValueError, ArithmeticError) as e:  # the generated elastic data refuses it
            raise ValueError(f"{name} = {value:g}: {e}") from None
        self.__dict__.update(other.__dict__)

    def get(self, name):
        vr = self._vr.get(name)
        if vr is None:
            raise KeyError(f"'{name}' is not a variable of {self.spec['name']}")
        if self.variables[vr].type == "String":
            return self.engine.get_string(vr)
        return self.engine.get_real(vr)

    # -- running ------------------------------------------------------------------------------------
    def initialize(self, t0=None):
        """Bind parameters, build the integrator and the initial state (exit of initialization mode)."""
        if t0 is not None:
            self.time = float(t0)
        self.engine.initialize(self.time)
        self.initialized = True

    def do_step(self, t, h):
        """Advance from t to t + h with the inputs held; raises IntegrationError (state stays at self.time)."""
        if not self.initialized:
            self.initialize(t)
        try:
            self.engine.do_step(t, h)
        finally:
            self.time = self.engine.time

    def run(self, ts):
        """States at the communication points ts (ts[0] = now) with the inputs held throughout: the same
        steps as one do_step per interval, but points inside one dense-output step are interpolated
        together (like solve_ivp's t_eval). Returns X with a row [y; ẏ] per point."""
        ts = np.asarray(ts, dtype=float)
        if not self.initialized:
            self.initialize(ts[0])
        try:
            return self.engine.run(ts)
        finally:
            self.time = self.engine.time

    @property
    def x(self):
        return np.array(self.engine.state())

    @property
    def y(self):
        return self.x[:self.npos]

    @property
    def yd(self):
        return self.x[self.npos:]

    @property
    def stats(self):
        """Integrator counters: steps, rejected, rhs_evaluations, jac_evaluations, lu_decompositions (auto:
        switched, switched_at)."""
        return self.engine.stats()

    def f(self, t, x):
        """ẋ = [Z(y)·ẏ; M⁻¹(q − k)] with the current inputs (for peers such as scipy's solve_ivp): a new array."""
        return self.engine.rhs(t, x, np.empty(self.engine.n))

    def output_values(self, x, t=None):
        """{FMU output name: value} of the `outputs:` points and the von Mises stresses at state x."""
        out, t = {}, self.time if t is None else t
        for o, spec_o in enumerate(self.spec["outputs"]):
            p = self.engine.output_point(o, t, x)
            for k, (qty, sym) in enumerate((("position", "r"), ("velocity", "v"))):
                if qty in spec_o["quantities"]:
                    for a, ax in enumerate("xyz"):
                        out[f"{spec_o['name']}.{sym}.{ax}"] = float(p[3 * k + a])
        for v in self.variables:
            if v.kind == L.MBS_V_VM:
                out[v.name] = self.engine.von_mises(v.index, x)
        return out

    # -- state ----------------------------------------------------------------------------------------
    def get_state(self):
        """Everything that determines the future, as the engine's checked bytes (the FMU state)."""
        return self.engine.save_state()

    def set_state(self, s):
        self.engine.load_state(s)
        self.time = self.engine.time
        self.initialized = True  # the engine knows; do_step refuses when the state was saved before initialization

    def reset(self):
        """Back to the state after instantiation (fmi2Reset): the scene's parameters, structural ones too."""
        if self.spec is not self._original:
            self.__init__(self._original)
            return
        self.engine.reset()
        self._settings = {}
        self.time = self.spec["experiment"]["start"]
        self.initialized = False


def as_real(name, value):
    """A value for a Real variable, taken exactly: a real number (not a bool, text or complex)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} = {value!r}: expected a real number")
    try:
        x = float(value)
    except OverflowError:
        x = math.inf
    if isinstance(value, (int, np.integer)) and x != value:  # rounded: not the value the caller named
        raise ValueError(f"{name} = {value}: not representable as a double (nearest {x:.17g})")
    return x


def simulate(scene, stop=None, step=None, inputs=None, method=None, inputs_interpolation="hold", **options):
    """In-process run: returns (t, Y, YD) at the communication points. `inputs`: {name: value} held for the
    whole run; an input table (a CSV path, read as inputs_interpolation says: "hold", each row's values
    held until the next row's time, or "linear", interpolated and sampled at every communication point; or
    an mbsfmu.inputs.InputTable); or a function `inputs(t) -> {name: value}`, sampled at every communication point and held over
    the following interval (as an FMU master does)."""
    import os
    from .inputs import InputTable, interpolation, step_through
    spec = scene if isinstance(scene, dict) else scene.spec
    sim = Simulation(spec)
    if method is not None:
        sim.set("integrator.method", method)
    for k, v in options.items():
        sim.set(f"integrator.{k}", v)
    e = spec["experiment"]
    t0, stop, step = e["start"], stop if stop is not None else e["stop"], step if step is not None else e["step"]
    if not step > 0 or not stop >= t0:
        raise ValueError(f"need step > 0 and stop >= start (got step={step}, start={t0}, stop={stop})")
    n = int(round((stop - t0) / step))
    ts = t0 + step * np.arange(n + 1)
    if isinstance(inputs, (str, os.PathLike)):
        inputs = InputTable.read(inputs, {v.name for v in sim.variables if v.causality == "input"}, spec["name"],
                                 interpolation(inputs_interpolation))
    sim.initialize(t0)
    if inputs is None or isinstance(inputs, dict):  # held for the whole run: points of one step together
        for name, val in (inputs or {}).items():
            sim.set(name, val)
        X = sim.run(ts)
    else:
        table = inputs if isinstance(inputs, InputTable) else _Sampled(inputs)
        X = np.empty((n + 1, sim.npos + sim.nvel))
        step_through(table, ts, sim.set_many, lambda a, b: sim.do_step(a, b - a), lambda k: X.__setitem__(k, sim.x))
    return ts, X[:, :sim.npos], X[:, sim.npos:]


class _Sampled:
    """A function of time as a table sampled at the communication points (inputs.step_through's table)."""

    def __init__(self, f):
        self.at = f

    @staticmethod
    def pieces(t0, t1):
        return [t0, t1]


__all__ = ["Simulation", "Variable", "simulate", "variables", "compiled", "IntegrationError", "as_real"]
