"""`mbsfmu sweep`: the command-line face of mbsfmu.sweep (table to .parquet/.csv, optional series and plot)."""

import sys
from pathlib import Path

from .. import files
from ..errors import printable
from ..inputs import INTERPOLATIONS

HELP = """examples:
  mbsfmu sweep models/pendulum.yaml --vary L=0.5:1.5:11 --vary m_bob=0.5,1,2 --stop 5 --out grid.csv
  mbsfmu sweep models/double_pendulum.yaml --vary L=0.5:1.5 --vary m=0.5:2 --samples 200 --seed 1 \\
      --stop 2 --out lhs.parquet --plot lhs.png
  mbsfmu sweep out/double_pendulum.fmu --vary L=0.8,1,1.2 --scheduler tcp://10.0.0.5:8786 --out r.csv

SPEC is start:stop:count (evenly spaced) or a comma list; several --vary form a grid. With --samples N,
each SPEC is a range lo:hi and N Latin-hypercube samples are drawn (reproducible with --seed).
NAME: a tunable parameter, an input (held), integrator.method/rtol/atol/max_step/step, y0.<coordinate>,
yd0.<coordinate>."""


def configure(p):
    p.add_argument("model", help="scene .yaml or built .fmu")
    p.add_argument("--vary", action="append", default=[], metavar="NAME=SPEC", help="a varied name (repeatable)")
    p.add_argument("--samples", type=int, help="N Latin-hypercube samples within the --vary ranges")
    p.add_argument("--seed", type=int, help="seed of the sampling")
    p.add_argument("--stop", type=float, help="stop time (default: the model's experiment)")
    p.add_argument("--step", type=float, help="communication step (default: the model's experiment)")
    p.add_argument("--outputs", help="comma list of outputs (default: every output)")
    p.add_argument("--input", action="append", default=[], metavar="NAME=VALUE|FILE",
                   help="an input held constant (repeatable), or an input CSV for every case: a 'time' column, "
                        "then input names, each row's values held until the next row's time")
    p.add_argument("--interpolate", choices=INTERPOLATIONS, default="hold",
                   help="an input CSV between rows: hold (default) or linear (interpolated, sampled at every "
                        "communication point)")
    p.add_argument("--out", help="results table: .parquet or .csv (default: print it)")
    p.add_argument("--series", metavar="FILE", help="also write every output at every communication point "
                                                   "(.parquet or .csv, a row per case and time)")
    p.add_argument("--scheduler", help="address of a running Dask scheduler (tcp://host:port), or 'inprocess'; "
                                       "default: an embedded local cluster")
    p.add_argument("--workers", type=int, help="local cluster: worker processes (default: one per core); "
                                               "existing cluster: workers to wait for")
    p.add_argument("--plot", metavar="FILE.png", help="plot the outputs against the varied name(s)")
    p.add_argument("--plot-vs", metavar="NAME[,NAME]", help="varied name(s) for the plot's axes (default: the first two)")
    p.add_argument("--allow-failures", action="store_true",
                   help="exit 0 even when cases failed (default: exit 1, after writing the results)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


def run(args):
    from . import sweep
    from .cases import finite_number
    vary = dict(_pair(v, "--vary") for v in args.vary)
    tables = [i for i in args.input if "=" not in i]
    if len(tables) > 1:
        raise ValueError(f"--input: one input CSV per sweep (got {', '.join(tables)})")
    inputs = {k: finite_number(v, f"--input {k}={v}")
              for k, v in (_pair(i, "--input") for i in args.input if "=" in i)}
    for path in (args.out, args.series):
        if path:
            _format(path)
    files.check({"--out": args.out, "--series": args.series, "--plot": args.plot},
                {"the model": args.model, "--input": tables[0] if tables else None})
    res = sweep(args.model, vary=vary, samples=args.samples, seed=args.seed, stop=args.stop, step=args.step,
                outputs=args.outputs, inputs=inputs, scheduler=args.scheduler, workers=args.workers,
                series=bool(args.series), progress=not args.quiet, input_table=tables[0] if tables else None,
                inputs_interpolation=args.interpolate)
    table, series = res if args.series else (res, None)
    failed = int((table["status"] != "ok").sum())
    print(f"{len(table)} cases, {failed} failed, {table['wall_time'].sum():.3g} s of run time")
    if args.out:
        _write(table, args.out)
    else:
        print(table.to_string(index=False))
    if series is not None:
        _write(series, args.series)
    if args.plot:
        from .plot import plot
        varied = [c for c in table.columns if c in vary] if not args.plot_vs else args.plot_vs.split(",")
        unknown = [v for v in varied if v not in vary]
        if unknown:
            raise ValueError(f"--plot-vs {unknown[0]} is not a varied name ({', '.join(vary)})")
        outputs = [c for c in table.columns if c not in vary and c not in ("case", "status", "wall_time")]
        plot(table, varied[:2], outputs, args.plot)
        print(f"wrote {args.plot}")
    if failed and not args.allow_failures:
        first = table.loc[table["status"] != "ok", "status"].iloc[0]
        print(printable(f"error: {failed} of {len(table)} cases failed (the first: {first}); "
                        "--allow-failures to exit 0 all the same"), file=sys.stderr)
        return 1


def _pair(text, option):
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise ValueError(f"{option} {text}: expected NAME=VALUE")
    return name.strip(), value.strip()


def _format(path):
    suffix = Path(path).suffix.lower()
    if suffix not in (".parquet", ".csv"):
        raise ValueError(f"{path}: write .parquet or .csv")
    if suffix == ".parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise ImportError("writing .parquet needs pyarrow: pip install 'mbsfmu[sweep]' (or use .csv)") from None
    return suffix


def _write(df, path):
    with files.replacing(path) as tmp:
        if _format(path) == ".parquet":
            df.to_parquet(tmp, index=False)
        else:
            df.to_csv(tmp, index=False)
    print(f"wrote {path}")
