"""Command line: `mbsfmu build|check|simulate|crosscheck|info|validate|sweep|bench|stress`.

Every failure prints one line on stderr and exits non-zero (1; 2 for a bad command line) — never a
traceback. A closed pipe (`mbsfmu simulate … | head`) ends the command quietly with 141, as other Unix
tools do. The scene format, the FMU interface and every command are described in docs/.
"""

import argparse
import contextlib
import math
import os
import re
import sys

from . import __version__, files
from .engine.layout import METHODS
from .errors import IntegrationError, ModelError, printable
from .inputs import INTERPOLATIONS
from .limits import RESULT_POINTS, TABLE_ROWS
from .scene.urdf import BASES

EPILOG = """examples:
  mbsfmu build models/double_pendulum.yaml -o out/        # writes out/double_pendulum.fmu
  mbsfmu check models/robot_arm_6dof.yaml                 # validate a scene, list its coordinates
  mbsfmu simulate models/pendulum.yaml --stop 2 --plot pendulum.png
  mbsfmu simulate models/pendulum.yaml --signals 'y.*,bob.r.z' --csv result.csv
  mbsfmu simulate out/double_pendulum.fmu --input torque.csv --plot out.png   # CSV: time,<input names>
  mbsfmu animate models/double_pendulum.yaml -o anim.html                # open anim.html#t=1.5 in a browser
  mbsfmu crosscheck models/double_pendulum.yaml --out xc/double_pendulum      # FMI cross-check files
  mbsfmu info out/double_pendulum.fmu
  mbsfmu validate out/double_pendulum.fmu
  mbsfmu sweep models/pendulum.yaml --vary L=0.5:1.5:11 --vary m_bob=0.5,1,2 --out grid.csv
  mbsfmu bench models/pendulum.yaml --quick                # writes a fresh bench-pendulum-<time>/ folder
  mbsfmu stress --quick                                    # writes a fresh stress-<time>/ folder

documentation: docs/README.md (scene format, FMU interface, Python API, integrators, this command line)
"""


class CommandParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line, naming the (sub)command's own help, with the closest option
    for an unknown one. Every command's parser is one of these (subcommands, bench and stress too)."""

    def error(self, message):
        if message.startswith(_UNKNOWN):
            message += self.suggestions(w.split("=")[0] for w in message[len(_UNKNOWN):].split() if w.startswith("-"))
        choice = re.match(r"argument .*: invalid choice: '(.*)' \(choose from (.*)\)$", message)
        if choice:  # a mistyped command or --kind/--method value
            message += self.suggestions([choice.group(1)], re.findall(r"'([^']*)'", choice.group(2)))
        self.exit(2, printable(f"{self.prog}: error: {message} (see {self.prog} --help)") + "\n")

    def suggestions(self, words, valid=None):
        """' (did you mean --stop?)' for the mistyped `words` among `valid` (default: this parser's options)."""
        import difflib
        valid = list(valid if valid is not None else (o for o in self._option_string_actions if o.startswith("--")))
        close = [m[0] for w in words for m in [difflib.get_close_matches(w, valid, n=1, cutoff=0.6)] if m]
        return f" (did you mean {', '.join(close)}?)" if close else ""

    def refuse_unknown(self, words):
        """Refuse the options among `words` that this parser does not know (argparse's unambiguous prefixes are
        known), before argparse would report a missing argument instead of the typo behind it."""
        unknown = [w for w in words if _is_option(w)
                   and not any(o.startswith(w.split("=")[0]) for o in self._option_string_actions)]
        if unknown:
            self.error(_UNKNOWN + " ".join(unknown))


def _is_option(word):
    """'--stp' or '-x', not '-' or a negative number (a value)."""
    try:
        float(word)
        return False
    except ValueError:
        return word.startswith("-") and word != "-"


_UNKNOWN = "unrecognized arguments: "


def _seconds(text):
    """A positive, finite number of seconds (--stop, --step)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got '{text}'") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return v


# -- files -------------------------------------------------------------------------------------------
def _is_fmu(path):
    """True for an FMU (a zip archive), False for anything else; the file must exist."""
    import zipfile
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{'not a regular file' if os.path.exists(path) else 'no such file'}: {path}")
    return zipfile.is_zipfile(path)


def _need_scene(path):
    if _is_fmu(path):
        raise ValueError(f"{path} is an FMU, not a scene file (for FMUs: mbsfmu info, validate, simulate)")


def _animate(args):
    from .animation import animate
    model = args.model if _is_fmu(args.model) else _load(args.model, args)
    scene = _load(args.scene, args) if args.scene and _is_fmu(args.model) else args.scene  # its meshes' package folders
    out = animate(model, args.output, stop=args.stop, input_csv=args.input, result_csv=args.result, fps=args.fps,
                  scene=scene)
    print(f"wrote {out}")


def _need_fmu(path):
    if not _is_fmu(path):
        raise ValueError(f"{path} is not an FMU (not a zip archive); for scene files use: mbsfmu check, build, simulate")


# -- commands ----------------------------------------------------------------------------------------
def _load(path, args):
    """A scene file or URDF as the options of _allow_outside say (every command that loads one)."""
    from . import load
    return load(path, allow_outside=args.allow_outside, repair=args.repair, package_dirs=args.package_dir, base=args.base)


def _build(args):
    """Every scene is loaded and every FMU's path checked against the scenes and the other FMUs before the
    first build: two scenes with one model name would write one FMU."""
    import time
    from . import build_fmu
    from .fmu.build import fmu_path
    scenes = []
    for path in args.scene:
        _need_scene(path)
        scenes.append(_load(path, args))
    files.check({f"the FMU of {path}": fmu_path(s, args.output) for path, s in zip(args.scene, scenes)},
                {f"the scene {path}": path for path in args.scene},
                hint="give the models different names (name:) or build them into different folders")
    n = len(scenes)
    for i, (path, scene) in enumerate(zip(args.scene, scenes), 1):
        t0 = time.perf_counter()
        if n > 1:
            print(f"[{i}/{n}] {path} ...", end=" ", flush=True)
        elif args.kind == "native":
            status(f"building {path}: compiling the engine's C sources (10–60 s) …")
        out = build_fmu(scene, args.output, kind=args.kind, fmi=args.fmi)
        print(f"{out}" + (f" ({time.perf_counter() - t0:.1f} s)" if n > 1 else ""), flush=True)


def _check(args):
    from . import compile
    from .simulation import Simulation
    _need_scene(args.scene)
    scene = _load(args.scene, args)
    ev = compile(scene)
    nb, nf = len(scene.spec["bodies"]), len(ev.velocity_coordinates)
    print(f"{scene.name}: {nb} bod{'y' if nb == 1 else 'ies'}, {nf} degree{'' if nf == 1 else 's'} of freedom")
    print("  y  = " + ", ".join(ev.coordinates))
    print("  ẏ  = " + ", ".join(ev.velocity_coordinates))
    print("  inputs: " + (", ".join(ev.inputs) or "none"))
    variables = Simulation(scene.spec).variables
    print("  outputs: " + ", ".join(v.name for v in variables if v.causality == "output"))
    params = [v for v in variables if v.causality == "parameter" and not v.name.startswith("integrator.")]
    print("  parameters: " + (", ".join(f"{v.name} = {v.start:g}" for v in params) or "none"))
    for b in ev.model.bodies:
        if b.elastic:
            print("  " + _elastic_summary(b))
            if "fe" in b.elastic:
                _reduction_check(b.name, b.elastic["fe"])


def _reduction_check(name, fe):
    """The reduced body's frequencies against the full FE model's (same boundary condition); a note when any
    retained one is off by more than the scene's check_tolerance (the scene is still valid: status 0)."""
    import warnings
    from .bodies.cms import frequency_deviation
    full, off = fe["full_frequencies"], frequency_deviation(fe)
    print(f"    full model, same boundary condition: {_hz(full)} Hz (the reduction's off by at most {100 * off.max():.3g} %)")
    bad = [i + 1 for i in range(len(off)) if off[i] > fe["check_tolerance"]]
    if bad:
        warnings.warn(f"{name}: mode{'s' if len(bad) > 1 else ''} {', '.join(map(str, bad[:8]))}"
                      f"{', …' if len(bad) > 8 else ''} of the reduction {'differ' if len(bad) > 1 else 'differs'} from the full model's by more than "
                      f"{fe['check_tolerance']:.3g} (up to {100 * off.max():.3g} %): retain more modes (modes, cutoff_hz)",
                      stacklevel=2)


def _hz(values):
    return ", ".join(f"{f:.4g}" for f in values[:8]) + (", …" if len(values) > 8 else "")


def _elastic_summary(body):
    """One line on an elastic body: its modes' frequencies (from its modal stiffness and mass), mass, nodes."""
    import numpy as np
    from scipy.linalg import eigvalsh
    inv = body.inv
    hz = np.sqrt(np.clip(eigvalsh(inv.K, inv.M_ee), 0, None)) / (2 * np.pi)
    return (f"elastic {body.name}: {inv.n} mode{'s' if inv.n != 1 else ''} at {_hz(hz)} Hz (undamped, frame held), "
            f"mass {inv.m:.6g} kg, {body.nodal.nodes} node{'s' if body.nodal.nodes != 1 else ''}")


def _convert(args):
    from pathlib import Path

    from .scene.urdf import to_yaml
    files.check({"--output": args.output}, {"the URDF": args.urdf})
    text = to_yaml(args.urdf, base=args.base, repair=args.repair, scene_dir=Path(args.output).parent, package_dirs=args.package_dir)
    print(files.write_text(args.output, text))


def _crosscheck(args):
    from .fmu.crosscheck import write_crosscheck
    _need_scene(args.scene)
    out = write_crosscheck(args.scene, args.out)
    for f in sorted(out.iterdir()):
        print(f)


def _simulate(args):
    files.check({"--csv": args.csv, "--plot": args.plot}, {"the model": args.model, "--input": args.input})
    result = _run_fmu(args.model, args) if _is_fmu(args.model) else _run_scene(args.model, args)
    title, t, cols, names, units = result
    keep = _select(names, args.signals)
    cols, names, units = cols[:, keep], [names[k] for k in keep], [units[k] for k in keep]
    if args.csv:
        import numpy as np
        with files.replacing(args.csv) as tmp:
            np.savetxt(tmp, np.column_stack([t, cols]), delimiter=",", header=",".join(["time"] + names),
                       comments="", fmt="%.17g")
        print(f"wrote {args.csv}")
    if args.plot:
        from .plot import plot_result
        plot_result(args.plot, t, cols, names, units, title)
        print(f"wrote {args.plot}")
    if not args.csv and not args.plot:
        _print_table(t, cols, names)


def _check_times(start, stop, step):
    if stop <= start:
        raise ValueError(f"--stop {stop:g} must come after the start time {start:g}")
    if step > stop - start:
        raise ValueError(f"--step {step:g} is longer than the run ({start:g} to {stop:g} s)")
    if (stop - start) / step > RESULT_POINTS:
        raise ValueError(f"{(stop - start) / step:.3g} communication points: use a larger --step (at most {RESULT_POINTS:,} points)")


def _run_scene(path, args):
    """In-process run of a scene → (title, t, columns, names, units): the FMU's outputs, `outputs:` points included."""
    import numpy as np
    from . import simulate
    from .simulation import Simulation
    scene = _load(path, args)
    spec, e = scene.spec, scene.spec["experiment"]
    stop, step = args.stop or e["stop"], args.step or e["step"]
    _check_times(e["start"], stop, step)
    t, Y, YD = simulate(scene, stop=stop, step=step, method=args.method, inputs=args.input,
                        inputs_interpolation=args.interpolate)
    sim = Simulation(spec)
    sim.initialize(e["start"])  # binds the parameters the output points depend on
    outputs = [v for v in sim.variables if v.causality == "output"]  # y.*, yd.*, then the points
    cols = np.hstack([Y, YD, np.zeros((len(t), len(outputs) - Y.shape[1] - YD.shape[1]))])
    if len(outputs) > Y.shape[1] + YD.shape[1]:   # `outputs:` points or von Mises stresses
        names = [v.name for v in outputs]
        for k, (ti, y, yd) in enumerate(zip(t, Y, YD)):
            if hasattr(sim, "output_values"):
                p = sim.output_values(np.concatenate([y, yd]), ti)
            else:  # the Python reference path (elastic scenes, until the engine has them: issue 10)
                p = sim.ev.output_values(y, yd, ti)
            for n, v in p.items():
                cols[k, names.index(n)] = v
    method = args.method or spec["integrator"]["method"]
    title = f"{spec['name']} (scene): {method}, rtol {spec['integrator']['rtol']:g}"
    return title, t, cols, [v.name for v in outputs], [v.unit for v in outputs]


def _run_fmu(path, args):
    """fmpy run of an FMU → (title, t, columns, names, units) of all its outputs."""
    import numpy as np
    from fmpy import read_model_description, simulate_fmu
    md = read_model_description(path)
    e = md.defaultExperiment
    start = float(e.startTime) if e is not None and e.startTime is not None else 0.0
    stop = args.stop or (float(e.stopTime) if e is not None and e.stopTime is not None else start + 1.0)
    step = args.step or (float(e.stepSize) if e is not None and e.stepSize is not None else (stop - start) / 500)
    _check_times(start, stop, step)
    byname = {v.name: v for v in md.modelVariables}
    start_values = {}
    if args.method:
        if "integrator.method" not in byname:
            raise ValueError(f"{path}: --method needs an mbsfmu FMU (no parameter integrator.method)")
        start_values["integrator.method"] = args.method
    outputs = [v for v in md.modelVariables if v.causality == "output"]
    inp = None
    if args.input:
        from .inputs import InputTable
        inp = InputTable.for_fmu(args.input, md, args.interpolate).fmpy_signals()
    with _stdout_to_stderr():  # fmpy's notes ("missing input for variable ...") are not rows of the table
        res = simulate_fmu(path, stop_time=stop, output_interval=step, input=inp, start_values=start_values,
                           output=[v.name for v in outputs])
    k = (res["time"] - start) / step  # fmpy also stops where an input jumps: the rows asked for only
    res = res[(np.abs(k - np.round(k)) < 1e-6) | (np.arange(len(k)) == len(k) - 1)]
    t = res["time"]
    if t[-1] < stop - 1e-9 * max(1.0, abs(stop)):
        print(f"warning: the FMU stopped at t = {t[-1]:g} s, before {stop:g} s (it refused a step; "
              "the scene run `mbsfmu simulate <scene>.yaml` names the reason)", file=sys.stderr)
    setting = [args.method or getattr(byname.get("integrator.method"), "start", None)]
    if "integrator.rtol" in byname:
        setting.append(f"rtol {float(byname['integrator.rtol'].start):g}")
    title = f"{md.modelName} (FMU): " + ", ".join(filter(None, setting))
    cols = np.column_stack([res[v.name] for v in outputs]) if outputs else np.zeros((len(t), 0))
    return title, t, cols, [v.name for v in outputs], [v.unit for v in outputs]


@contextlib.contextmanager
def _stdout_to_stderr():
    """What is printed meanwhile (Python's print or an FMU's C code) goes to stderr: stdout carries results."""
    sys.stdout.flush()
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # not a real file (captured): Python's prints only
        fd = None
    saved = os.dup(fd) if fd is not None else None
    try:
        if saved is not None:
            os.dup2(sys.stderr.fileno(), fd)
        with contextlib.redirect_stdout(sys.stderr):
            yield
    finally:
        if saved is not None:
            sys.stdout.flush()
            os.dup2(saved, fd)
            os.close(saved)


def _select(names, patterns):
    """Column indices of the signals matching --signals (comma-separated names or shell patterns), in order."""
    if not patterns:
        return list(range(len(names)))
    import fnmatch
    keep = set()
    for p in (p.strip() for p in patterns.split(",") if p.strip()):
        hits = {k for k, n in enumerate(names) if fnmatch.fnmatchcase(n, p)}
        if not hits:
            raise ValueError(f"--signals: no output matches '{p}' (outputs: {', '.join(names)})")
        keep |= hits
    return sorted(keep)


def _print_table(t, cols, names):
    import numpy as np
    n = len(t)
    every = max(1, math.ceil((n - 1) / (TABLE_ROWS - 1)))  # with the last row: at most TABLE_ROWS
    rows = sorted(set(range(0, n, every)) | {n - 1})
    if every > 1:
        last = " and the last" if (n - 1) % every else ""
        print(f"# showing {len(rows)} of {n} rows, one every {every}{last} (all rows: --csv FILE)")
    _say(",".join(["time"] + names))  # an FMU's output names
    for row in np.column_stack([t, cols])[rows]:
        print(",".join(f"{v:.6g}" for v in row))


def _info(args):
    _need_fmu(args.fmu)
    from fmpy import read_model_description
    md = read_model_description(args.fmu)
    # everything below quotes the FMU's modelDescription: foreign text
    _say(f"{md.modelName} — {md.description or ''}")
    _say(f"  FMI {md.fmiVersion}, generated by {md.generationTool}")
    if md.defaultExperiment:
        e = md.defaultExperiment
        _say(f"  default experiment: start {e.startTime}, stop {e.stopTime}, step {e.stepSize}")
    for causality in ("parameter", "input", "output"):
        vs = [v for v in md.modelVariables if v.causality == causality]
        _say(f"  {causality}s ({len(vs)}):")
        for v in vs:
            unit = f" [{v.unit}]" if getattr(v, "unit", None) else ""
            name, description, elements = _fmi_names(v)
            start = f" = {v.start}" if v.start is not None else ""  # outputs and inputs may have none
            _say(f"    {name}{unit}{start}  {description or ''}")
            if elements:
                _say("      FMI 2.0: " + ", ".join(f"{v.name}[{k}] = {e}" for k, e in enumerate(elements, 1)))


def _fmi_names(v):
    """(name, description, FMI 2.0 names of its elements or None) of an FMU variable as info shows it: an FMI
    3.0 array with its size, its elements' FMI 2.0 names from its description (compiler/variables.py writes them
    there; an FMI 2.0 element's description names its FMI 3.0 element)."""
    from .compiler.variables import fmi2_elements
    dims = [str(d.start) for d in getattr(v, "dimensions", None) or ()]
    if not dims:
        return v.name, v.description, None
    description, elements = fmi2_elements(v.description)
    return f"{v.name}[{','.join(dims)}]", description, elements


def _say(line):
    """Print a line that quotes foreign text (an FMU's names and descriptions) with control characters escaped."""
    print(printable(line))


def _validate(args):
    _need_fmu(args.fmu)
    from fmpy.validation import validate_fmu
    problems = validate_fmu(args.fmu)
    for p in problems:
        _say(p)
    if problems:
        raise SystemExit(1)
    print(f"{args.fmu}: valid")


def _bench(name, rest):
    """`bench` and `stress` parse their own options; without --out they write to a fresh folder."""
    import importlib
    scene = rest[0] if name == "bench" and rest and not rest[0].startswith("-") else None  # as documented: first
    if scene is not None:
        _need_scene(scene)
    mod = importlib.import_module(f".reports.{'work_precision' if name == 'bench' else 'stress'}", __package__)
    return getattr(mod, f"{name}_main")(rest)


def fresh_folder(name, scene=None):
    """`<name>[-<scene>]-<YYYYmmdd-HHMMSS>` in the current folder (not the tracked reports/): where `bench` and
    `stress` write without --out."""
    import time
    from pathlib import Path
    base = "-".join(filter(None, [name, scene and Path(scene).stem, time.strftime("%Y%m%d-%H%M%S")]))
    path, k = Path(base), 1
    while path.exists():
        k += 1
        path = Path(f"{base}-{k}")
    print(f"output folder: {path}/", flush=True)
    return str(path)


# -- the parser ----------------------------------------------------------------------------------------
def _allow_outside(p):
    p.add_argument("--repair", action="store_true",
                   help="a URDF's massless moving links and unphysical inertias: repair them, each reported "
                        "(default: refused)")
    p.add_argument("--allow-outside", action="store_true",
                   help="read data files (nodal .npz) outside the scene's folder too (default: refused)")
    p.add_argument("--package-dir", action="append", default=[], metavar="DIR",
                   help="a URDF given directly: a folder its package://NAME/... meshes are looked up in, relative "
                        "to the URDF's folder, trusted wherever it is (repeatable; a YAML scene names them in urdf: package_dirs)")
    p.add_argument("--base", choices=BASES, default=None,
                   help="a URDF given directly: its root link fixed in the world (default) or on a free joint (a "
                        "floating base; a root link named world stays the world and the links it holds float)")


def parser():
    top = CommandParser(prog="mbsfmu", description="Multibody scenes (YAML, URDF) → FMI 2.0 and 3.0 FMUs "
                                                            "(co-simulation, model exchange).",
                        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    top.add_argument("--version", action="version", version=f"mbsfmu {__version__}")
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    top.commands = sub.choices  # name → the command's parser: its errors name its help
    p = sub.add_parser("build", help="build FMUs from scene files")
    p.add_argument("scene", nargs="+", help="scene files (.yaml) or URDFs (.urdf)")
    p.add_argument("-o", "--output", default=".", help="output directory (default: .)")
    p.add_argument("--kind", choices=("pythonfmu", "native"), default="pythonfmu",
                   help="pythonfmu (default; runs the engine through Python) or native (C only, no Python "
                        "needed where the FMU runs; needs a C compiler here)")
    p.add_argument("--fmi", choices=("2", "3"), default="2",
                   help="FMI version: 2 (default) or 3 (co-simulation and model exchange; --kind native only)")
    _allow_outside(p)
    p.set_defaults(run=_build)
    p = sub.add_parser("check", help="validate a scene and list its coordinates, inputs, outputs and parameters")
    p.add_argument("scene", help="scene file (.yaml) or URDF (.urdf)")
    _allow_outside(p)
    p.set_defaults(run=_check)
    p = sub.add_parser("simulate", help="simulate a scene (in-process) or an FMU (fmpy)",
                       description="Simulate a scene in-process, or an FMU with fmpy. Without --csv or --plot "
                                   f"a table of at most {TABLE_ROWS} rows goes to stdout. A run keeps at most "
                                   f"{RESULT_POINTS:,} communication points ((stop - start) / step).")
    p.add_argument("model", help="scene file (.yaml), URDF (.urdf) or FMU (.fmu)")
    p.add_argument("--stop", type=_seconds, default=None, help="end time in s (default: the experiment's stop)")
    p.add_argument("--step", type=_seconds, default=None,
                   help="communication step in s (default: the experiment's step)")
    p.add_argument("--method", default=None,
                   help=f"integrator: {', '.join(METHODS)} (default: the scene's)")
    p.add_argument("--signals", default=None, metavar="NAMES",
                   help="comma-separated outputs or shell patterns to keep, e.g. 'y.*,bob.r.z' (default: all)")
    p.add_argument("--csv", metavar="FILE", help="write every row of the result as CSV")
    p.add_argument("--input", metavar="FILE",
                   help="input CSV: a 'time' column, then FMU input names; each row's values hold until the next "
                        "row's time")
    p.add_argument("--interpolate", choices=INTERPOLATIONS, default="hold",
                   help="the input CSV between rows: hold (default) or linear (interpolated, sampled at every "
                        "communication point)")
    p.add_argument("--plot", metavar="FILE", help="write a PNG plot, one panel per unit")
    _allow_outside(p)
    p.set_defaults(run=_simulate)
    p = sub.add_parser("convert", help="write the scene YAML equivalent to a URDF robot description")
    p.add_argument("urdf", help="URDF file (.urdf)")
    p.add_argument("-o", "--output", required=True, help="scene file to write (.yaml)")
    p.add_argument("--base", choices=BASES, default="fixed",
                   help="the root link fixed in the world (default) or on a free joint (a floating base)")
    p.add_argument("--repair", action="store_true", help="repair massless moving links and unphysical inertias")
    p.add_argument("--package-dir", action="append", default=[], metavar="DIR",
                   help="a folder the URDF's package://NAME/... meshes are looked up in, relative to the URDF's folder (repeatable)")
    p.set_defaults(run=_convert)
    p = sub.add_parser("animate", help="write a self-contained HTML page that plays the motion in 3-D")
    p.add_argument("model", help="scene .yaml or mbsfmu .fmu")
    p.add_argument("-o", "--output", default="animation.html", help="HTML file to write (default: animation.html)")
    p.add_argument("--stop", type=_seconds, default=None, help="simulate until (default: the scene's experiment)")
    p.add_argument("--input", help="input CSV: a 'time' column, then input names")
    p.add_argument("--result", help="draw this result CSV (from 'mbsfmu simulate --csv') instead of simulating")
    p.add_argument("--fps", type=float, default=60, help="frames kept per simulated second (default: 60)")
    p.add_argument("--scene", help="for an FMU: draw from this scene (default: the drawing description the FMU carries)")
    _allow_outside(p)
    p.set_defaults(run=_animate)
    p = sub.add_parser("crosscheck", help="write the FMI cross-check files (<model>.fmu, _ref.csv, _ref.opt, _in.csv)")
    p.add_argument("scene", help="scene file (.yaml)")
    p.add_argument("--out", required=True, help="directory for the files")
    p.set_defaults(run=_crosscheck)
    p = sub.add_parser("info", help="show an FMU's variables")
    p.add_argument("fmu", help="FMU file (.fmu)")
    p.set_defaults(run=_info)
    p = sub.add_parser("validate", help="validate an FMU with fmpy")
    p.add_argument("fmu", help="FMU file (.fmu)")
    p.set_defaults(run=_validate)
    from .sweep.cli import HELP as SWEEP_HELP, configure as configure_sweep
    configure_sweep(sub.add_parser("sweep", help="parameter sweep or ensemble on Dask (docs/sweeps.md)",
                                   epilog=SWEEP_HELP, formatter_class=argparse.RawDescriptionHelpFormatter))
    for name, text in (("bench", "work-precision benchmark of a scene (options: mbsfmu bench --help)"),
                       ("stress", "numerical stability suite (options: mbsfmu stress --help)")):
        p = sub.add_parser(name, help=text, add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER, help=f"scene and options, see mbsfmu {name} --help")
        p.set_defaults(run=lambda a, name=name: _bench(name, a.rest))
    return top


def parse(argv=None):
    """Command line → argparse namespace (`bench` and `stress` keep their arguments for their own parsers)."""
    top = parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    at = next((i for i, w in enumerate(argv) if not w.startswith("-")), len(argv))  # the command
    top.refuse_unknown(argv[:at])
    if at < len(argv) and argv[at] in top.commands and argv[at] not in ("bench", "stress"):
        words = argv[at + 1:]
        top.commands[argv[at]].refuse_unknown(words[:words.index("--")] if "--" in words else words)
    args, extra = top.parse_known_args(argv)
    if args.command in ("bench", "stress"):  # their own parsers read options, --help included
        args.rest = extra + list(args.rest)
    elif extra:  # told by the command's parser: its help, its options
        top.commands[args.command].error(_UNKNOWN + " ".join(extra))
    return args


def main(argv=None):
    import warnings
    args = parse(argv)
    with warnings.catch_warnings():
        warnings.showwarning = _note  # restored on return
        for category in (UserWarning, RuntimeWarning):  # notes to the user, whatever filters the caller set
            warnings.filterwarnings("default", category=category)
        return _run(args)


def _note(message, category, filename, lineno, file=None, line=None):
    """A warning (no MinGW for win64 binaries, Dask's port note, ...) is a note to the user: one plain line, no
    source line (the lines of a message of several joined)."""
    print(printable("note: " + " ".join(str(message).split())), file=sys.stderr)


def status(line):
    """A progress line on stderr while something slow runs (a native build, a cluster starting), for a person
    watching: only when stderr is a terminal (as the sweep's progress bar)."""
    if sys.stderr.isatty():
        print(printable(line), file=sys.stderr, flush=True)


def _run(args):
    try:
        status = args.run(args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's exit
        return status if isinstance(status, int) else 0
    except BrokenPipeError:  # the reader (e.g. head) has gone: stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except IntegrationError as e:
        return _fail(f"simulation failed: {e}")
    except (ModelError, FileNotFoundError, KeyError, ValueError, OSError) as e:
        return _fail(f"error: {e}")
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # anything else: still one line, no traceback
        return _fail(f"error: {type(e).__name__}: {e}")


def _fail(line):
    """The one line a failure prints: what it quotes (file names, keys, values) is escaped, never obeyed."""
    print(printable(line), file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
