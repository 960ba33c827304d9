"""The engine seam: one compiled scene and its running instances, through ctypes (mbs_engine.h).

Python compiles (compiler/scene_file.py: scene → compiled scene bytes), C runs (everything per step). This module is
the only place where Python talks to the engine; it imports no numpy, so that an FMU's run time stays lean.
"""

import ctypes
import functools
import os

from ..errors import EngineUnavailable, IntegrationError

__all__ = ["Instance", "model_file", "EngineError", "EngineUnavailable", "library", "OK", "WARNING", "DISCARD",
           "ERROR", "V_METHOD"]
OK, WARNING, DISCARD, ERROR = 0, 1, 2, 3
V_METHOD = 1  # mbs_engine.h MBS_V_*: the kind of the one String variable, integrator.method


_lib = None


def library():
    """The loaded engine (ctypes.CDLL with argument types declared): the copy a pythonfmu FMU carries next to
    this file, else the one compiled into the cache (build.py, imported only then: an FMU starts without it)."""
    global _lib
    if _lib is None:
        from .api import declare
        here = os.path.dirname(os.path.abspath(__file__))
        shipped = [f for f in os.listdir(here) if f.startswith("libmbsfmu_engine_")]
        if len(shipped) == 1:
            path = os.path.join(here, shipped[0])
        else:
            from .build import library_path
            path = str(library_path())
        _lib = declare(ctypes.CDLL(path))
    return _lib


_fast = None  # fastcall.c's module, False where it cannot be built


def _fastcall():
    """The extension of Instance.rhs (build.py: fastcall_path), loaded on first use; False without it (an FMU's
    run time never asks: it steps in C)."""
    global _fast
    if _fast is None:
        _fast = False
        try:
            import importlib.util
            from .build import fastcall_path
            path = fastcall_path()
            if path is not None:
                spec = importlib.util.spec_from_file_location("_mbsfmu_fastcall", path)
                module = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(module)
                _fast = module
        except (ImportError, OSError, EngineUnavailable):
            pass
    return _fast


class EngineError(ValueError):
    """A call the engine refused (wrong variable, bad setting, corrupt state bytes)."""


class _Model:
    """A loaded compiled scene (immutable, shared by instances): from bytes, or from a file (path given)."""

    def __init__(self, blob, path=None):
        self.lib = lib = library()
        err = ctypes.create_string_buffer(1024)
        self.ptr = lib.mbs_model_load(blob, len(blob), err, len(err)) if path is None else \
            lib.mbs_model_load_file(os.fsencode(path), err, len(err))
        if not self.ptr:
            raise EngineError(err.value.decode(errors="replace"))
        self.guid = lib.mbs_model_guid(self.ptr).decode()
        self.npos, self.nvel = lib.mbs_model_npos(self.ptr), lib.mbs_model_nvel(self.ptr)

    def variable_names(self):
        """FMU variable names by value reference."""
        return [self.lib.mbs_model_var_name(self.ptr, vr).decode() for vr in range(self.lib.mbs_model_nvars(self.ptr))]

    def variable_kinds(self):
        """mbs_engine.h MBS_V_* kind of each variable, by value reference."""
        return [self.lib.mbs_model_var_kind(self.ptr, vr) for vr in range(self.lib.mbs_model_nvars(self.ptr))]

    def __del__(self):
        if getattr(self, "ptr", None):
            self.lib.mbs_model_free(self.ptr)
            self.ptr = None


def model_file(path):
    """The compiled scene in the file path, read by the engine (fmu_files.c: a regular file of bounded size only,
    so a FIFO or device in its place is refused, not waited on); EngineError if it cannot be read or loaded."""
    return _Model(None, path)


class _Engine:
    """The engine's instance and what it needs while it lives (the compiled scene, the logger's callback): held
    by its Instance and by every call bound to it (Instance.rhs), freed with the last of them, so that a bound call
    never reaches a freed instance. It refers to neither (no reference cycle: it frees as soon as they drop it)."""

    __slots__ = ("lib", "model", "logger", "ptr", "n", "address")

    def __init__(self, model, logger):
        self.lib, self.model, self.n, self.address = model.lib, model, model.npos + model.nvel, None
        LOGGER = self.lib.mbs_instance_new.argtypes[1]
        self.logger = LOGGER() if logger is None else \
            LOGGER(lambda env, status, msg: logger(status, msg.decode(errors="replace")))
        self.ptr = self.lib.mbs_instance_new(model.ptr, self.logger, None)
        if not self.ptr:
            raise MemoryError("engine instance")

    def __del__(self):
        if getattr(self, "ptr", None):
            self.lib.mbs_instance_free(self.ptr)
            self.ptr = None

    def check(self, status, t=None):
        """status, or the engine's message raised: EngineError, IntegrationError (at t, default the instance's)."""
        if status >= ERROR:
            raise EngineError(self.lib.mbs_message(self.ptr).decode(errors="replace"))
        if status == DISCARD:
            message = self.lib.mbs_message(self.ptr).decode(errors="replace")
            raise IntegrationError(message.split(": ", 1)[-1] if message.startswith("t = ") else message,
                                   self.lib.mbs_time(self.ptr) if t is None else t)
        return status


def _rhs_bound(engine):
    """rhs(t, x, out=None) of the engine: fastcall.c's call where it is built (0.07 µs from Python to the engine and
    back), which hands anything else to _rhs_slow (ctypes: 0.5 µs and more); either holds the engine."""
    fast = _fastcall()
    slow = functools.partial(_rhs_slow, engine)
    if not fast:
        return slow
    if engine.address is None:  # mbs_rhs in the engine ctypes loaded, taken once per instance
        engine.address = ctypes.cast(engine.lib.mbs_rhs, ctypes.c_void_p).value
    return functools.partial(fast.rhs, engine.address, engine.ptr, engine.n, slow)


def _rhs_slow(engine, t, x, out=None):
    import numpy as np
    x = np.ascontiguousarray(x, dtype=float)
    if out is None:  # a new array, then the fast call again (which comes back here only with an out)
        out = np.empty(engine.n)
        if _fastcall():
            return _rhs_bound(engine)(t, x, out)
    if x.size < engine.n or not isinstance(out, np.ndarray) or out.dtype != np.float64 or out.size < engine.n \
            or not out.flags.c_contiguous or not out.flags.writeable:
        raise ValueError(f"x and out: {engine.n} float64 numbers each, out a writable contiguous array")
    engine.check(engine.lib.mbs_rhs(engine.ptr, t, x.ctypes.data, out.ctypes.data), t)  # (out may be x: mbs_rhs)
    return out


class Instance:
    """One running instance: variables by value reference, initialize, steps, state bytes, evaluation."""

    def __init__(self, blob, logger=None):
        self.model = blob if isinstance(blob, _Model) else _Model(blob)
        self.lib = self.model.lib
        self.npos, self.nvel = self.model.npos, self.model.nvel
        self.n = self.npos + self.nvel
        self._engine = _Engine(self.model, logger)
        self.ptr = self._engine.ptr
        self._value = ctypes.c_double()
        self._str = ctypes.c_char_p()

    # -- status → exceptions
    @property
    def message(self):
        return self.lib.mbs_message(self.ptr).decode(errors="replace")

    @property
    def time(self):
        return self.lib.mbs_time(self.ptr)

    def _check(self, status):
        return self._engine.check(status)

    # -- variables
    def set_real(self, vr, value):
        self._check(self.lib.mbs_set_real(self.ptr, vr, value))

    def set_reals(self, vrs, values):
        """Set together (parameters that must change together: one call); nothing changes on a refusal."""
        n = len(vrs)
        vr, v = (ctypes.c_uint * n)(*vrs), (ctypes.c_double * n)(*values)
        self._check(self.lib.mbs_set_reals(self.ptr, vr, n, v, None))

    def get_real(self, vr):
        self._check(self.lib.mbs_get_real(self.ptr, vr, ctypes.byref(self._value)))
        return self._value.value

    def set_string(self, vr, value):
        self._check(self.lib.mbs_set_string(self.ptr, vr, str(value).encode()))

    def get_string(self, vr):
        self._check(self.lib.mbs_get_string(self.ptr, vr, ctypes.byref(self._str)))
        return self._str.value.decode()

    def set_start(self, index, value):
        self._check(self.lib.mbs_set_start(self.ptr, index, value))

    # -- running
    def reset(self):
        self._check(self.lib.mbs_reset(self.ptr))

    def initialize(self, t0):
        self._check(self.lib.mbs_initialize(self.ptr, t0))

    def do_step(self, t, h):
        self._check(self.lib.mbs_do_step(self.ptr, t, h))

    def state(self):
        """Current [y; ẏ] as a list (copy)."""
        p = self.lib.mbs_state(self.ptr)
        return p[:self.n]

    def nominals(self):
        """Nominal values of [y; ẏ] as the compiled scene carries them (a list)."""
        return self.lib.mbs_nominals(self.ptr)[:self.n]

    def run(self, ts):
        """numpy array of rows [y; ẏ] at the times ts (ts[0] = now)."""
        import numpy as np
        ts = np.ascontiguousarray(ts, dtype=float)
        X = np.empty((len(ts), self.n))
        self._check(self.lib.mbs_run(self.ptr, ts.ctypes.data, len(ts), X.ctypes.data))
        return X

    def stats(self):
        out, sw = (ctypes.c_long * 6)(), ctypes.c_double()
        self.lib.mbs_stats(self.ptr, out, ctypes.byref(sw))
        keys = ("steps", "rejected", "rhs_evaluations", "jac_evaluations", "lu_decompositions")
        return dict(zip(keys, out[:5]), switched=bool(out[5]), switched_at=sw.value if out[5] else None)

    # -- state bytes (fixed layout: version, GUID, length, checksum)
    def save_state(self):
        n = self.lib.mbs_state_size(self.ptr)
        buf = ctypes.create_string_buffer(n)
        self._check(self.lib.mbs_state_save(self.ptr, buf, n))
        return buf.raw

    def load_state(self, data):
        data = bytes(data)
        self._check(self.lib.mbs_state_load(self.ptr, data, len(data)))

    # -- evaluation (numpy; tests and benchmarks)
    def equations(self, t, x):
        import numpy as np
        x = np.ascontiguousarray(x, dtype=float)
        M, k, q = np.empty((self.nvel, self.nvel)), np.empty(self.nvel), np.empty(self.nvel)
        self._check(self.lib.mbs_equations(self.ptr, t, x.ctypes.data, M.ctypes.data, k.ctypes.data, q.ctypes.data))
        return M, k, q

    @functools.cached_property
    def rhs(self):
        """rhs(t, x, out=None): ẋ = f(t, x) into `out` (float64 arrays of n numbers; a new array if None; out may
        be x). Bound on first use (_rhs_bound); the bound call keeps the engine's instance alive, whatever becomes
        of this object."""
        return _rhs_bound(self._engine)

    def _rhs_slow(self, t, x, out=None):
        return _rhs_slow(self._engine, t, x, out)

    def output_point(self, o, t, x):
        import numpy as np
        x = np.ascontiguousarray(x, dtype=float)
        out = np.empty(6)
        self._check(self.lib.mbs_output_point(self.ptr, o, x.ctypes.data, t, out.ctypes.data))
        return out

    # -- model exchange: the host's time and states, ẋ and its directional derivatives there
    def set_time(self, t):
        self._check(self.lib.mbs_set_time(self.ptr, t))

    def set_state(self, x):
        import numpy as np
        x = np.ascontiguousarray(x, dtype=float)
        self._check(self.lib.mbs_set_state(self.ptr, x.ctypes.data, len(x)))

    def derivatives(self):
        import numpy as np
        out = np.empty(self.n)
        self._check(self.lib.mbs_derivatives(self.ptr, out.ctypes.data, self.n))
        return out

    def directional_derivative(self, unknowns, knowns, seed):
        """J·seed, J = ∂(unknowns)/∂(knowns) by value reference (knowns: states and inputs; unknowns: derivatives,
        outputs, states), at the time and state set, exact to rounding (complex step in the engine)."""
        return self._derivative(self.lib.mbs_directional_derivative, unknowns, knowns, seed, forward=True)

    def adjoint_derivative(self, unknowns, knowns, seed):
        """seedᵀ·J (seed per unknown), as directional_derivative's J."""
        return self._derivative(self.lib.mbs_adjoint_derivative, unknowns, knowns, seed, forward=False)

    def _derivative(self, fn, unknowns, knowns, seed, forward):
        import numpy as np
        u, k = np.ascontiguousarray(unknowns, dtype=np.uintc), np.ascontiguousarray(knowns, dtype=np.uintc)
        seeded, out = (k, np.empty(len(u))) if forward else (u, np.empty(len(k)))
        seed = np.ascontiguousarray(seed, dtype=float)
        if len(seed) != len(seeded):
            raise ValueError(f"{len(seeded)} {'knowns' if forward else 'unknowns'} but {len(seed)} seeds")
        self._check(fn(self.ptr, u.ctypes.data, len(u), k.ctypes.data, len(k), seed.ctypes.data, out.ctypes.data))
        return out

    def von_mises(self, k, x):
        """Von Mises stress (Pa) of stress node k at state x."""
        import numpy as np
        x = np.ascontiguousarray(x, dtype=float)
        out = ctypes.c_double()
        self._check(self.lib.mbs_von_mises(self.ptr, k, x.ctypes.data, ctypes.byref(out)))
        return out.value
