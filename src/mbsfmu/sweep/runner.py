"""Worker side of a sweep: each process builds a model once and runs many cases on it (reset between cases).

A case's failure (IntegrationError, an FMU's Discard, non-finite results, a value the model refuses) becomes
its status message; the batch goes on.
"""

import json
import math
import threading
import time
from typing import NamedTuple

import numpy as np

from ..inputs import InputTable, step_through

_NO_TABLE = InputTable([], [0.0], np.zeros((1, 0)), "linear")  # no input table: a piece per communication step

_MODELS = {}          # (model key, thread) → runner: a worker process builds each model once
_MAX_MODELS = 8       # long-lived cluster workers see many sweeps: keep only the latest models

# The FMU's messages. fmpy formats an FMI 2.0 FMU's variadic messages in a C proxy (fmpy.logging.addLoggerProxy)
# that keeps ONE pointer per process to the Python logger it was given last, and calls it for every FMI 2.0
# message of every FMU of the process. A logger made per instance (instantiate_fmu(logger=f) wraps f in a new
# ctypes thunk) leaves that pointer dangling once the instance is freed: the thunk's memory goes to the next
# ctypes callback made in the process, which the next FMI 2.0 message anywhere then calls with a logger's
# arguments (a segfault of the test suite: an FMI 3.0 intermediateUpdate callback of a freed FMU called by a
# pythonfmu FMU's discard message). So one thunk for the process, never freed, handed to fmpy by its address
# (no new thunk), and the messages go to the runner whose case this thread runs.
_SINK = threading.local()  # .log: the messages list of the FmuRunner running a case in this thread
_LOGGER = []               # [the process's one fmi2CallbackLoggerTYPE thunk], made at the first FMU instance
_LOGGER_LOCK = threading.Lock()


def _log_message(component, instance, status, category, message):
    log = getattr(_SINK, "log", None)
    if log is not None and status >= 2 and message:  # Discard, Error, Fatal: the reason a call failed
        log.append(message.decode("utf-8", "replace"))


def _log_message3(env, status, category, message):  # FMI 3.0: no proxy, fmpy keeps the thunk with the instance
    _log_message(None, None, status, category, message)


def _fmu_logger(fmi_version):
    """The address of the process's logger thunk (an int: fmpy's fmi2CallbackLoggerTYPE(address) makes no thunk);
    FMI 3.0's logger (another signature, not through the proxy) as a function."""
    import ctypes
    if fmi_version.startswith("3"):
        return _log_message3
    with _LOGGER_LOCK:
        if not _LOGGER:
            from fmpy.fmi2 import fmi2CallbackLoggerTYPE
            _LOGGER.append(fmi2CallbackLoggerTYPE(_log_message))
        return ctypes.cast(_LOGGER[0], ctypes.c_void_p).value


class ModelData(NamedTuple):
    """What travels to the workers: a scene as normalized JSON ("scene") or the bytes of an FMU ("fmu")."""
    kind: str
    key: str    # content hash: the per-process cache key
    data: object
    name: str


class Setup(NamedTuple):
    """What every case shares: communication points, outputs read, inputs held, whether to keep series, and
    an input table (mbsfmu.inputs.InputTable) or None."""
    ts: np.ndarray
    outputs: tuple
    inputs: dict
    series: bool
    table: object = None


class Cases:
    """Cases by column: case numbers and {name: values}. A plain object on purpose: Dask walks the lists, tuples
    and dicts in a task's arguments looking for references to other tasks (200 cases as tuples of dicts cost
    ~3 ms to submit); a class instance and numpy arrays it leaves alone, and they pickle compactly."""

    __slots__ = ("index", "columns")

    def __init__(self, index, columns):
        self.index = np.asarray(index, dtype=np.int64)
        self.columns = columns  # {name: numpy array (numbers) or list (words such as integrator methods)}

    @classmethod
    def from_columns(cls, columns):
        n = len(next(iter(columns.values()))) if columns else 0
        return cls(np.arange(n), {k: _column(v) for k, v in columns.items()})

    def take(self, positions):
        """The cases at these positions (a numpy index array)."""
        positions = np.asarray(positions, dtype=np.int64)
        return Cases(self.index[positions], {k: v[positions] if isinstance(v, np.ndarray) else [v[p] for p in positions]
                                             for k, v in self.columns.items()})

    def __len__(self):
        return len(self.index)

    def values(self, k):
        """{name: value} of the k-th case here (Python scalars, as a user's loop would pass them)."""
        return {name: col[k].item() if isinstance(col, np.ndarray) else col[k] for name, col in self.columns.items()}

    def __getstate__(self):
        return self.index, self.columns

    def __setstate__(self, state):
        self.index, self.columns = state


def _column(values):
    """Floats as a float64 array (the same numbers back, bit for bit), anything else (words, ints) as a list."""
    values = list(values)
    if values and all(isinstance(v, float) for v in values):
        return np.asarray(values, dtype=np.float64)
    return values


class Rows(NamedTuple):
    """Results of some cases, by column: case numbers, status ("ok" or the failure message), wall time per case
    [s], the outputs at the stop time (a row per case), and with series a (points × outputs) array per case
    (None for a failed case)."""
    index: np.ndarray
    status: list
    wall: np.ndarray
    final: np.ndarray
    series: list

    @staticmethod
    def join(parts, n_outputs):
        parts = [p for p in parts if len(p.index)]
        if not parts:
            return Rows(np.empty(0, np.int64), [], np.empty(0), np.empty((0, n_outputs)), [])
        index = np.concatenate([p.index for p in parts])
        order = np.argsort(index, kind="stable")
        status = [s for p in parts for s in p.status]
        series = [s for p in parts for s in p.series]
        return Rows(index[order], [status[k] for k in order], np.concatenate([p.wall for p in parts])[order],
                    np.concatenate([p.final for p in parts])[order], [series[k] for k in order])


def run_batch(model, cases, setup):
    """Run `cases` (a Cases) on this process's build of `model` → Rows."""
    runner = _runner(model)
    n, m = len(cases), len(setup.outputs)
    final, wall = np.empty((n, m)), np.empty(n)
    status, series = ["ok"] * n, [None] * n
    for k in range(n):
        t0 = time.perf_counter()
        try:
            final[k], series[k] = runner.run(cases.values(k), setup)
            bad = [o for o, v in zip(setup.outputs, final[k]) if not math.isfinite(v)]
            if bad:
                status[k] = f"non-finite output {', '.join(bad)} at t={setup.ts[-1]:g}"
        except Exception as e:  # one case's failure never stops the sweep
            final[k], series[k], status[k] = np.nan, None, runner.failed(e)
        wall[k] = time.perf_counter() - t0
    return Rows(cases.index, status, wall, final, series)


def _runner(model):
    key = (model.key, threading.get_ident())  # an instance is not shared between a worker's threads
    r = _MODELS.get(key)
    if r is None:
        while len(_MODELS) >= _MAX_MODELS:
            _MODELS.pop(next(iter(_MODELS))).close()
        r = _MODELS[key] = (SceneRunner if model.kind == "scene" else FmuRunner)(model.data)
    return r


def _message(e):
    from ..errors import IntegrationError, ModelError
    if isinstance(e, (IntegrationError, ModelError, ValueError)):  # a refused value: its message names it
        return str(e)
    if isinstance(e, KeyError) and e.args:
        return str(e.args[0])
    return f"{type(e).__name__}: {e}"


class SceneRunner:
    """A scene run in this process through mbsfmu.simulation.Simulation."""

    def __init__(self, spec_json):
        from ..simulation import Simulation
        self.sim = Simulation(json.loads(spec_json))
        outs = [v.name for v in self.sim.variables if v.causality == "output"]
        ys = [n for n in outs if n.startswith("y.")]
        # rows of run() are [y; ẏ] in the order of the y.* and yd.* outputs
        self.column = {n: k for k, n in enumerate(ys)}
        self.column.update({n: len(ys) + k for k, n in enumerate(n for n in outs if n.startswith("yd."))})

    def run(self, values, setup):
        sim, ts = self.sim, setup.ts
        sim.reset()
        sim.set_many({**setup.inputs, **values})  # together: parameters that only make sense together
        sim.initialize(ts[0])
        if setup.table is not None:  # the rows held as mbsfmu.simulate holds them
            S = np.empty((len(ts), len(setup.outputs))) if setup.series else None

            def sample(k):
                if S is not None:
                    S[k] = [sim.get(n) for n in setup.outputs]
            step_through(setup.table, ts, sim.set_many, lambda a, b: sim.do_step(a, b - a), sample)
            return [sim.get(n) for n in setup.outputs], S
        if not setup.series:
            sim.run(ts)
            return [sim.get(n) for n in setup.outputs], None
        if all(n in self.column for n in setup.outputs):  # states only: one run, columns of X
            X = sim.run(ts)
            S = X[:, [self.column[n] for n in setup.outputs]]
            return S[-1], S
        S = np.empty((len(ts), len(setup.outputs)))  # point outputs: read at each communication point
        S[0] = [sim.get(n) for n in setup.outputs]
        for k in range(len(ts) - 1):
            sim.run(ts[k:k + 2])
            S[k + 1] = [sim.get(n) for n in setup.outputs]
        return S[-1], S

    def failed(self, e):
        return _message(e)

    def close(self):
        pass


class FmuRunner:
    """A built FMU run through fmpy: extracted and instantiated once, fmi2Reset between cases."""

    def __init__(self, fmu_bytes):
        import tempfile
        from pathlib import Path
        from fmpy import extract, read_model_description
        self.dir = tempfile.mkdtemp(prefix="mbsfmu_sweep_")
        path = Path(self.dir, "model.fmu")
        path.write_bytes(fmu_bytes)
        self.unzipdir = extract(str(path), unzipdir=str(Path(self.dir, "x")))
        self.md = read_model_description(self.unzipdir)
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.fmu, self.fresh, self.log = None, True, []

    def _instance(self):
        from fmpy import instantiate_fmu
        if self.fmu is None:
            self.fmu = instantiate_fmu(self.unzipdir, self.md, "CoSimulation", logger=_fmu_logger(self.md.fmiVersion),
                                       debug_logging=True)  # pythonfmu forwards messages only with logging on
            self.fresh = True
        elif not self.fresh:
            self.fmu.reset()
        self.fresh = False
        return self.fmu

    def run(self, values, setup):
        from ..simulation import as_real
        ts = setup.ts
        self.log.clear()
        _SINK.log = self.log  # this thread's FMU messages, from here to the next case (failed() reads them)
        fmu = self._instance()
        reals = {}  # set in one fmi2SetReal: parameters that only make sense together are checked together
        for name, v in {**setup.inputs, **values}.items():
            var = self.vars.get(name)
            if var is None or var.causality not in ("parameter", "input"):
                raise KeyError(f"'{name}' is not an input or parameter of {self.md.modelName}")
            if var.type == "String":
                fmu.setString([var.valueReference], [str(v)])
            elif var.type in ("Integer", "Enumeration", "Boolean"):  # the value exactly, or the case fails naming it
                x = float(v) if var.type == "Boolean" and isinstance(v, (bool, np.bool_)) else as_real(name, v)
                if x != int(x) or (var.type == "Boolean" and x not in (0, 1)):
                    raise ValueError(f"{name} = {v!r}: expected {'0 or 1' if var.type == 'Boolean' else 'an integer'}")
                setter = fmu.setBoolean if var.type == "Boolean" else fmu.setInteger
                setter([var.valueReference], [bool(x) if var.type == "Boolean" else int(x)])
            else:
                reals[var.valueReference] = as_real(name, v)
        if reals:
            fmu.setReal(list(reals), list(reals.values()))
        fmu.setupExperiment(startTime=ts[0], stopTime=ts[-1])
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        vrs = [self.vars[n].valueReference for n in setup.outputs]
        S = np.empty((len(ts), len(vrs))) if setup.series else None
        table = setup.table if setup.table is not None else _NO_TABLE
        table_vrs = [self.vars[n].valueReference for n in table.names]

        def sample(k):
            if S is not None:
                S[k] = fmu.getReal(vrs)
        step_through(table, ts, lambda u: table_vrs and fmu.setReal(table_vrs, list(u.values())),
                     lambda a, b: fmu.doStep(currentCommunicationPoint=a, communicationStepSize=b - a), sample)
        final = fmu.getReal(vrs)
        fmu.terminate()
        return final, S

    def failed(self, e):
        """After an error the instance may be unusable: free it, the next case instantiates afresh."""
        logged = list(dict.fromkeys(self.log))  # a message and the shim's copy of it ("fmi2SetReal: ..."): once
        msg = "; ".join(m for m in logged if not any(m != o and m in o for o in logged)) or _message(e)
        self._free()
        return msg

    def _free(self):
        if self.fmu is not None:
            try:
                self.fmu.freeInstance()
            except Exception:
                pass
            self.fmu = None

    def close(self):
        import shutil
        self._free()
        shutil.rmtree(self.dir, ignore_errors=True)
