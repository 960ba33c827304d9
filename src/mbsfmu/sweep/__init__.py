"""Parameter sweeps and ensembles: many runs of one model (scene or FMU), one table back (issue 14).

`mbsfmu.sweep(...)` is this package's `sweep` (imported by `import mbsfmu`, so this module imports nothing
heavy at the top); numpy, pandas and dask are imported when a sweep runs.
"""

import hashlib
import json
import math
from pathlib import Path

RESERVED = ("case", "status", "wall_time")  # result columns besides the varied names and the outputs


def sweep(model, vary=None, samples=None, seed=None, stop=None, step=None, outputs=None, inputs=None,
          scheduler=None, workers=None, series=False, progress=None, input_table=None, inputs_interpolation="hold"):
    """Run `model` (scene file, loaded scene, or built .fmu) once per case; returns a pandas DataFrame with a
    row per case: `case`, the varied names, each output at the stop time (named as the FMU variable),
    `status` ("ok" or the case's failure message) and `wall_time` [s]. With `series=True` returns
    (table, series): the outputs at every communication point, a row per case and time.

    vary: {name: spec}; spec "start:stop:count", "a,b,c" or a sequence of values (a grid over all names), or
      with `samples=N` a range "lo:hi" / (lo, hi) (N Latin-hypercube samples, reproducible with `seed`); or a
      DataFrame with a row per case. Names: tunable parameters, inputs (held), `integrator.*`,
      initial values `y0.<coordinate>` / `yd0.<coordinate>`.
    input_table: an input CSV for every case, read as mbsfmu.simulate reads it (each row held until the next
      row's time; inputs_interpolation="linear": interpolated, sampled at every communication point).
    scheduler: None (embedded LocalCluster, `workers` processes, default one per core), "tcp://host:port" of a
      running Dask scheduler (waits for `workers` workers, default 1), a dask.distributed.Client, or
      "inprocess" (no Dask). progress: a bar with the time left on stderr (default: when stderr is a terminal).
    """
    from .cases import make_cases
    from .dispatch import run_cases
    from .runner import Cases, Setup
    np, pd = _require(scheduler)
    columns = make_cases(vary, samples, seed)
    names, n = list(columns), len(next(iter(columns.values())))
    clash = [c for c in names if c in RESERVED]
    if clash:
        raise ValueError(f"cannot vary {clash[0]!r}: the name is a result column ({', '.join(RESERVED)})")
    data, info = _model(model)
    _words_only_for_strings(columns, info)
    inputs = {str(k): v for k, v in (inputs or {}).items()}
    info.check({**inputs, **{k: columns[k][0] for k in names}})
    outputs = info.outputs if outputs is None else _chosen_outputs(info, outputs)
    table = None
    if input_table is not None:
        from ..inputs import InputTable, interpolation
        table = InputTable.read(input_table, info.inputs, info.name, interpolation(inputs_interpolation))
        both = [n for n in table.names if n in names or n in inputs]
        if both:
            raise ValueError(f"{both[0]!r} is a column of the input table {input_table} and set otherwise too "
                             "(--vary or --input NAME=VALUE): give it one way")
    setup = Setup(_times(info, stop, step), tuple(outputs), inputs, bool(series), table)
    rows = run_cases(data, Cases.from_columns(columns), setup, scheduler, workers, progress)
    table = pd.DataFrame({"case": np.arange(n), **columns, **{o: rows.final[:, k] for k, o in enumerate(outputs)},
                          "status": rows.status, "wall_time": rows.wall})
    if not series:
        return table
    ok = [(i, s) for i, s in zip(rows.index, rows.series) if s is not None]
    ts = setup.ts
    S = np.vstack([s for _, s in ok]) if ok else np.empty((0, len(outputs)))
    long = pd.DataFrame({"case": np.repeat([i for i, _ in ok], len(ts)).astype(int), "time": np.tile(ts, len(ok)),
                         **{o: S[:, k] for k, o in enumerate(outputs)}})
    return table, long


def _words_only_for_strings(columns, info):
    """A value that is not a number is refused before any case runs, unless its name takes text
    (integrator.method): `0.5-1.5` would otherwise fail every case."""
    from .cases import not_a_number
    for name, values in columns.items():
        word = next((v for v in values if isinstance(v, str)), None)
        if word is not None and name not in info.strings:
            raise ValueError(not_a_number(name, word))


def _require(scheduler):
    try:
        import numpy
        import pandas
        if scheduler != "inprocess":
            import dask.distributed  # noqa: F401
    except ImportError as e:
        raise ImportError(f"mbsfmu sweep needs pandas and dask[distributed] ({e.name} is missing): "
                          "pip install 'mbsfmu[sweep]'") from None
    return numpy, pandas


class _Info:
    """What the client knows about the model: settable names, outputs, default experiment, a name check."""

    def __init__(self, name, outputs, experiment, check, strings, inputs):
        self.name, self.outputs, self.experiment, self.check = name, outputs, experiment, check
        self.strings = strings  # names that take text (integrator.method)
        self.inputs = inputs    # the model's input names (an input table's columns)


def _model(model):
    """→ (ModelData for the workers, _Info) from a path (.fmu or scene), a loaded scene or a spec dict."""
    if isinstance(model, (str, Path)) and str(model).lower().endswith(".fmu"):
        return _fmu(Path(model))
    if isinstance(model, (str, Path)):
        from ..scene import load
        model = load(model)
    spec = model if isinstance(model, dict) else model.spec
    return _scene(spec)


_SCENES = {}  # content hash → (ModelData, _Info): repeated sweeps of one scene compile its probe once


def _scene(spec):
    text = json.dumps(spec, sort_keys=True)
    key = _digest(text.encode())
    hit = _SCENES.get(key)
    if hit is None:
        while len(_SCENES) >= 8:
            _SCENES.pop(next(iter(_SCENES)))
        hit = _SCENES[key] = _new_scene(json.loads(text), text, key)
    return hit


def _new_scene(spec, text, key):
    from ..simulation import Simulation
    from .runner import ModelData
    probe = Simulation(json.loads(text))  # what the workers will build; compiles the kernel once, here
    outs = [v.name for v in probe.variables if v.causality == "output"]
    settable = [v.name for v in probe.variables if v.causality in ("parameter", "input")]
    initial = [f"{n.split('.', 1)[0]}0.{n.split('.', 1)[1]}" for n in outs if n.startswith(("y.", "yd."))]

    def check(values):
        """Unknown names stop the sweep; a value the model refuses fails only its case (runner.run_batch)."""
        for name, v in values.items():
            try:
                probe.set(name, v)
            except KeyError:
                raise ValueError(f"cannot vary {name!r} in {spec['name']}: not a parameter, input, integrator "
                                 f"setting or initial value; choose from {', '.join(settable + initial)}") from None
            except (TypeError, ValueError):
                pass

    e = spec["experiment"]
    data = ModelData("scene", key, text, spec["name"])
    strings = {v.name for v in probe.variables if v.type == "String"}
    inputs = {v.name for v in probe.variables if v.causality == "input"}
    return data, _Info(spec["name"], outs, (e["start"], e["stop"], e["step"]), check, strings, inputs)


def _fmu(path):
    from fmpy import read_model_description
    from .runner import ModelData
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    blob = path.read_bytes()
    md = read_model_description(str(path))
    outs = [v.name for v in md.modelVariables if v.causality == "output"]
    settable = [v.name for v in md.modelVariables if v.causality in ("parameter", "input")]

    def check(values):
        bad = [k for k in values if k not in settable]
        if bad:
            raise ValueError(f"cannot vary {bad[0]!r} in {md.modelName}: not a parameter or input of the FMU; "
                             f"choose from {', '.join(settable)}")

    d = md.defaultExperiment
    t0 = d.startTime if d and d.startTime is not None else 0.0
    t1 = d.stopTime if d and d.stopTime is not None else None
    h = d.stepSize if d and d.stepSize is not None else None
    exp = tuple(None if x is None else float(x) for x in (t0, t1, h))
    strings = {v.name for v in md.modelVariables if v.type == "String"}
    inputs = {v.name for v in md.modelVariables if v.causality == "input"}
    return ModelData("fmu", _digest(blob), blob, md.modelName), _Info(md.modelName, outs, exp, check, strings, inputs)


def _digest(b):
    return hashlib.sha256(b).hexdigest()[:20]


def _chosen_outputs(info, outputs):
    chosen = [o.strip() for o in (outputs.split(",") if isinstance(outputs, str) else outputs) if o.strip()]
    bad = [o for o in chosen if o not in info.outputs]
    if bad or not chosen:
        raise ValueError(f"{bad[0] if bad else 'no output'!r} is not an output of {info.name}; "
                         f"outputs: {', '.join(info.outputs)}")
    return chosen


def _times(info, stop, step):
    """Communication points from the start time to `stop` (exactly) in steps of at most `step`."""
    t0, default_stop, default_step = info.experiment
    stop = default_stop if stop is None else float(stop)
    if stop is None:
        raise ValueError(f"{info.name} has no default stop time: give stop")
    step = default_step if step is None else float(step)
    step = (stop - t0) / 100 if step is None else step
    if not (math.isfinite(stop) and stop > t0):
        raise ValueError(f"stop must be a finite time after the start {t0}, got {stop}")
    if not (math.isfinite(step) and step > 0):
        raise ValueError(f"step must be positive, got {step}")
    import numpy as np
    n = math.ceil((stop - t0) / step - 1e-9)
    from ..limits import RESULT_POINTS  # bounded work and memory per case
    if n > RESULT_POINTS:
        raise ValueError(f"{n} communication points per case (stop {stop}, step {step}); at most {RESULT_POINTS:,}")
    return np.linspace(t0, stop, n + 1)
