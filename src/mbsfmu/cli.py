"""Command line: `mbsfmu build|check|simulate|info|validate|bench|stress`.

Errors users can fix (bad scene, bad FMU path) print one line and exit 1 — no traceback.
"""

import argparse
import sys

from .errors import IntegrationError, ModelError

EPILOG = """examples:
  mbsfmu build models/double_pendulum.yaml -o out/        # writes out/double_pendulum.fmu
  mbsfmu check models/robot_arm_6dof.yaml                 # validate a scene, list its coordinates
  mbsfmu simulate models/pendulum.yaml --stop 2 --plot pendulum.png
  mbsfmu simulate out/double_pendulum.fmu --csv result.csv
  mbsfmu simulate out/double_pendulum.fmu --input torque.csv --plot out.png   # CSV: time,<input names>
  mbsfmu crosscheck models/double_pendulum.yaml --out xc/double_pendulum      # FMI cross-check files
  mbsfmu info out/double_pendulum.fmu
  mbsfmu validate out/double_pendulum.fmu
  mbsfmu bench models/pendulum.yaml --out reports/pendulum
  mbsfmu stress --out reports
"""


def _build(args):
    import time
    from . import build_fmu
    n = len(args.scene)
    for i, scene in enumerate(args.scene, 1):
        t0 = time.perf_counter()
        if n > 1:
            print(f"[{i}/{n}] {scene} ...", end=" ", flush=True)
        path = build_fmu(scene, args.output)
        print(f"{path}" + (f" ({time.perf_counter() - t0:.1f} s)" if n > 1 else ""), flush=True)


def _read_input_csv(path, fmu):
    """A structured array for fmpy's ``input=``: a ``time`` column plus FMU input names."""
    import numpy as np
    from fmpy import read_model_description
    data = np.genfromtxt(path, delimiter=",", names=True, deletechars="", dtype=float)
    names = data.dtype.names or ()
    if not names or names[0] != "time":
        raise ValueError(f"{path}: the first column must be 'time' (got {names[:1]})")
    md = read_model_description(fmu)
    inputs = {v.name for v in md.modelVariables if v.causality == "input"}
    unknown = [n for n in names[1:] if n not in inputs]
    if unknown:
        raise ValueError(f"{path}: not inputs of {md.modelName}: {', '.join(unknown)} "
                         f"(inputs: {', '.join(sorted(inputs)) or 'none'})")
    return np.atleast_1d(data)


def _crosscheck(args):
    from .fmu.crosscheck import write_crosscheck
    out = write_crosscheck(args.scene, args.out)
    for f in sorted(out.iterdir()):
        print(f)


def _check(args):
    from . import compile, load
    scene = load(args.scene)
    ev = compile(scene)
    print(f"{scene.name}: {len(scene.spec['bodies'])} bodies, {len(ev.velocity_coordinates)} degrees of freedom")
    print("  y  = " + ", ".join(ev.coordinates))
    print("  ẏ  = " + ", ".join(ev.velocity_coordinates))
    print("  inputs: " + ", ".join(ev.inputs))


def _simulate(args):
    import numpy as np
    from pathlib import Path
    if not Path(args.model).is_file():
        raise FileNotFoundError(f"no such file: {args.model}")
    if args.input and not args.model.endswith(".fmu"):
        from . import build_fmu
        import tempfile
        tmp = tempfile.mkdtemp(prefix="mbsfmu_sim_")
        args.model = str(build_fmu(args.model, tmp))
    if args.model.endswith(".fmu"):
        from fmpy import read_model_description, simulate_fmu
        inp = _read_input_csv(args.input, args.model) if args.input else None
        outputs = [v.name for v in read_model_description(args.model).modelVariables if v.causality == "output"]
        res = simulate_fmu(args.model, stop_time=args.stop, output_interval=args.step, input=inp,
                           output=outputs)
        names = [n for n in res.dtype.names if n != "time"]
        t = res["time"]
        cols = np.column_stack([res[n] for n in names]) if names else np.zeros((len(t), 0))
    else:
        from . import load
        from .simulation import simulate
        scene = load(args.model)
        t, Y, YD = simulate(scene, stop=args.stop, step=args.step, method=args.method)
        from .equations import Evaluator
        ev = Evaluator(scene.spec)
        names = [f"y.{c}" for c in ev.coordinates] + [f"yd.{c}" for c in ev.velocity_coordinates]
        cols = np.hstack([Y, YD])
    if args.csv:
        np.savetxt(args.csv, np.column_stack([t, cols]), delimiter=",", header=",".join(["time"] + names), comments="")
        print(f"wrote {args.csv}")
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(8, 4.5))
        for k, n in enumerate(names):
            ax.plot(t, cols[:, k], label=n)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("outputs")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")
    if not args.csv and not args.plot:
        print(",".join(["time"] + names))
        for row in np.column_stack([t, cols])[:: max(1, len(t) // 20)]:
            print(",".join(f"{v:.6g}" for v in row))


def _need_fmu(path):
    import zipfile
    from pathlib import Path
    if not Path(path).is_file():
        raise FileNotFoundError(f"no such file: {path}")
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path} is not an FMU (not a zip archive)")


def _info(args):
    _need_fmu(args.fmu)
    from fmpy import read_model_description
    md = read_model_description(args.fmu)
    print(f"{md.modelName} — {md.description or ''}\n  FMI {md.fmiVersion}, generated by {md.generationTool}")
    if md.defaultExperiment:
        e = md.defaultExperiment
        print(f"  default experiment: start {e.startTime}, stop {e.stopTime}, step {e.stepSize}")
    for causality in ("parameter", "input", "output"):
        vs = [v for v in md.modelVariables if v.causality == causality]
        print(f"  {causality}s ({len(vs)}):")
        for v in vs:
            unit = f" [{v.unit}]" if getattr(v, "unit", None) else ""
            print(f"    {v.name}{unit} = {v.start}  {v.description or ''}")


def _validate(args):
    _need_fmu(args.fmu)
    from fmpy.validation import validate_fmu
    problems = validate_fmu(args.fmu)
    for p in problems:
        print(p)
    if problems:
        raise SystemExit(1)
    print(f"{args.fmu}: valid")


def main(argv=None):
    parser = argparse.ArgumentParser(prog="mbsfmu", description="Multibody scenes (YAML) → FMI 2.0 co-simulation FMUs.",
                                     epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("build", help="build FMUs from scene files")
    p.add_argument("scene", nargs="+")
    p.add_argument("-o", "--output", default=".", help="output directory (default: .)")
    p.set_defaults(run=_build)
    p = sub.add_parser("check", help="validate a scene and list its coordinates and inputs")
    p.add_argument("scene")
    p.set_defaults(run=_check)
    p = sub.add_parser("simulate", help="simulate a scene (in-process) or an FMU (fmpy)")
    p.add_argument("model", help="scene .yaml or .fmu")
    p.add_argument("--stop", type=float, default=None)
    p.add_argument("--step", type=float, default=None)
    p.add_argument("--method", default=None, help="integrator (scenes only)")
    p.add_argument("--csv", help="write the result as CSV")
    p.add_argument("--input", help="input CSV: a 'time' column, then FMU input names (scenes are built first)")
    p.add_argument("--plot", help="write a PNG plot of all outputs")
    p.set_defaults(run=_simulate)
    p = sub.add_parser("crosscheck", help="write the FMI cross-check files (<model>.fmu, _ref.csv, _ref.opt, _in.csv)")
    p.add_argument("scene")
    p.add_argument("--out", required=True, help="directory for the files")
    p.set_defaults(run=_crosscheck)
    p = sub.add_parser("info", help="show an FMU's variables")
    p.add_argument("fmu")
    p.set_defaults(run=_info)
    p = sub.add_parser("validate", help="validate an FMU with fmpy")
    p.add_argument("fmu")
    p.set_defaults(run=_validate)
    for name, fn in (("bench", "bench_main"), ("stress", "stress_main")):
        p = sub.add_parser(name, help="work-precision benchmark" if name == "bench" else "stability suite", add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(run=lambda a, fn=fn, name=name: _bench(name, fn, a.rest))
    args, extra = parser.parse_known_args(argv)
    if args.command in ("bench", "stress"):  # their own parsers read options, --help included
        args.rest = extra + list(args.rest)
    elif extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        args.run(args)
    except ModelError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except IntegrationError as e:
        print(f"simulation failed: {e}", file=sys.stderr)
        return 1
    except (FileNotFoundError, KeyError, ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    except Exception as e:  # anything else: still one line, no traceback
        print(f"error: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    return 0


def _bench(name, fn, rest):
    import importlib
    mod = importlib.import_module(f".bench.{'work_precision' if name == 'bench' else 'stress'}", __package__)
    return getattr(mod, fn)(rest)


if __name__ == "__main__":
    sys.exit(main())
