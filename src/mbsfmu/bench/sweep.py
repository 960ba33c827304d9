"""Sweep benchmark (issue 14): N double-pendulum cases over 2 s (Latin-hypercube samples of L and m).

Measures, in alternation so that every configuration sees the same machine load:
- a plain in-process loop over the cases (one Simulation: reset, set, initialize, run, get) — the baseline;
- mbsfmu.sweep in this process without Dask (the sweep's own bookkeeping);
- mbsfmu.sweep on an embedded LocalCluster with 1 … cores worker processes, started and warmed up (imports)
  beforehand; each timed sweep ships the model and builds it on the workers.
Writes <out>/sweep.md, sweep.csv and sweep.png.

    python -m mbsfmu.bench.sweep [--cases 200] [--stop 2] [--repeats 5] [--max-workers N] [--out reports]
"""

import argparse
import os
import statistics
import time
from pathlib import Path

MODEL = Path(__file__).resolve().parents[3] / "models" / "double_pendulum.yaml"
VARY = {"L": "0.5:1.5", "m": "0.5:2.0"}


def _warm():
    """Run on every worker before timing: the imports a worker pays once in its life."""
    import mbsfmu.simulation  # noqa: F401
    import mbsfmu.sweep.runner  # noqa: F401
    return os.getpid()


def plain_loop(spec, cases, ts, outputs):
    """What a user writes by hand: one Simulation, one run per case, outputs at the stop time."""
    from ..simulation import Simulation
    sim = Simulation(spec)
    finals = []
    for values in cases:
        sim.reset()
        for name, v in values.items():
            sim.set(name, v)
        sim.initialize(ts[0])
        sim.run(ts)
        finals.append([sim.get(o) for o in outputs])
    return finals


def measure(n_cases=200, stop=2.0, repeats=5, max_workers=None):
    import numpy as np
    from dask.distributed import Client
    import mbsfmu
    from ..sweep.cases import make_cases
    from ..sweep.dispatch import local_cluster
    scene = mbsfmu.load(MODEL)
    cols = make_cases(VARY, samples=n_cases, seed=1)
    cases = [{k: cols[k][i] for k in cols} for i in range(n_cases)]
    e = scene.spec["experiment"]
    ts = np.linspace(e["start"], stop, int(round((stop - e["start"]) / e["step"])) + 1)
    outputs = ["y.phi1", "y.phi2", "yd.phi1", "yd.phi2"]
    kw = dict(vary=VARY, samples=n_cases, seed=1, stop=stop, outputs=outputs, progress=False)

    t = time.perf_counter()  # a cold sweep: cluster start, worker imports, model shipped and built, 2 workers
    cold = mbsfmu.sweep(scene, workers=2, **kw)
    cold_wall = time.perf_counter() - t
    assert (cold["status"] == "ok").all()
    ref = np.array(plain_loop(scene.spec, cases, ts, outputs))
    assert np.array_equal(ref, cold[outputs].to_numpy()), "the sweep and the plain loop disagree"

    counts = list(range(1, (max_workers or os.cpu_count() or 1) + 1))
    clusters = {}
    for k in counts:
        cluster = local_cluster(k)
        client = Client(cluster)
        client.run(_warm)
        clusters[k] = (cluster, client)
    runs = {"plain loop": lambda: plain_loop(scene.spec, cases, ts, outputs),
            "sweep, in process": lambda: mbsfmu.sweep(scene, scheduler="inprocess", **kw)}
    runs.update({f"sweep, {k} worker{'s' if k > 1 else ''}": (lambda c=c: mbsfmu.sweep(scene, scheduler=c, **kw))
                 for k, (_, c) in clusters.items()})
    walls = {name: [] for name in runs}
    try:
        for _ in range(repeats):
            for name, fn in runs.items():
                t = time.perf_counter()
                fn()
                walls[name].append(time.perf_counter() - t)
    finally:
        for cluster, client in clusters.values():
            client.close()
            cluster.close()
    return walls, cold_wall, counts


def write_report(walls, cold_wall, counts, n_cases, stop, out, load_before, load_after, command):
    out.mkdir(parents=True, exist_ok=True)
    best = {name: min(w) for name, w in walls.items()}
    with open(out / "sweep.csv", "w") as fh:
        fh.write("configuration,workers,repeat,wall_s,cases_per_s\n")
        for name, ws in walls.items():
            k = next((c for c in counts if name.startswith(f"sweep, {c} worker")), 0)
            for r, w in enumerate(ws):
                fh.write(f"{name},{k},{r},{w:.6f},{n_cases / w:.2f}\n")
    one = best["sweep, 1 worker"]
    speedup = {k: one / best[f"sweep, {k} worker{'s' if k > 1 else ''}"] for k in counts}
    ratio = one / best["plain loop"]
    ratio_inproc = best["sweep, in process"] / best["plain loop"]
    lines = [
        "# Sweep benchmark (issue 14)",
        "",
        f"{n_cases} cases of `models/double_pendulum.yaml` over {stop:g} s (dopri5, rtol 1e-8; Latin-hypercube "
        f"samples of L ∈ [0.5, 1.5], m ∈ [0.5, 2]), {len(walls['plain loop'])} repeats in alternation, best "
        f"shown. Machine: {os.cpu_count()} cores; load average {load_before[0]:.2f} before, {load_after[0]:.2f} "
        "after (shared with other engineers' work).",
        "",
        f"Reproduce: `{command}`",
        "",
        "| configuration | best wall [s] | median [s] | cases/s | cost per case [ms] | vs plain loop | speed-up vs 1 worker |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, ws in walls.items():
        k = next((c for c in counts if name.startswith(f"sweep, {c} worker")), None)
        cost = best[name] * 1e3 / n_cases
        lines.append(f"| {name} | {best[name]:.3f} | {statistics.median(ws):.3f} | {n_cases / best[name]:.0f} | "
                     f"{cost:.2f} | {best[name] / best['plain loop']:.2f}× | "
                     f"{'' if k is None else f'{speedup[k]:.2f}×'} |")
    two = speedup.get(2)
    lines += [
        "",
        "Targets:",
        "",
        (f"- 2 workers vs 1: **{two:.2f}×** the throughput (target ≥ 1.7×)." if two is not None else
         "- 2 workers vs 1: not measured (fewer than 2 cores)."),
        f"- cost per case of the sweep on 1 worker vs the plain in-process loop: **{ratio:.2f}×** (target ≤ 1.1×); "
        f"the sweep's bookkeeping in this process without Dask: {ratio_inproc:.2f}×.",
        f"- one-time cost, not in the table: a cold `mbsfmu.sweep(..., workers=2)` (start a LocalCluster, "
        f"import mbsfmu in 2 fresh processes, ship and build the model, run) took {cold_wall:.2f} s in all.",
        "",
        "The plain loop is what a user writes by hand: one `Simulation`, then per case `reset`, `set`, `initialize`,"
        " `run`, `get` of the four outputs. A sweep on a cluster adds: the model sent to each worker and built there"
        " once, the cases split into batches (8 per worker), a task per batch, results back as arrays and one"
        " DataFrame. Results of the sweep equal the plain loop's bit for bit (checked before timing).",
        "",
        "![throughput](sweep.png)",
        "",
    ]
    (out / "sweep.md").write_text("\n".join(lines))
    _plot(walls, counts, n_cases, out / "sweep.png")
    return speedup, ratio


def _plot(walls, counts, n_cases, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    thr = [n_cases / min(walls[f"sweep, {k} worker{'s' if k > 1 else ''}"]) for k in counts]
    loop = n_cases / min(walls["plain loop"])
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(counts, thr, "o-", label="sweep on a LocalCluster")
    ax.plot(counts, [loop * k for k in counts], "k:", label="ideal: k × plain loop")
    ax.axhline(loop, color="gray", lw=0.8, ls="--", label="plain in-process loop")
    ax.set_xlabel("worker processes")
    ax.set_ylabel("cases per second")
    ax.set_xticks(counts)
    ax.set_ylim(0, None)
    ax.grid(True, alpha=0.3)
    ax.legend()
    ax.set_title(f"{n_cases} double-pendulum cases, 2 s each")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m mbsfmu.bench.sweep", description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=200)
    p.add_argument("--stop", type=float, default=2.0)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--max-workers", type=int, default=None, help="largest cluster measured (default: the cores)")
    p.add_argument("--out", default="reports")
    a = p.parse_args(argv)
    load_before = os.getloadavg()
    walls, cold, counts = measure(a.cases, a.stop, a.repeats, a.max_workers)
    command = "python -m mbsfmu.bench.sweep" + (f" --cases {a.cases}" if a.cases != 200 else "") + \
        (f" --stop {a.stop:g}" if a.stop != 2.0 else "") + (f" --repeats {a.repeats}" if a.repeats != 5 else "")
    speedup, ratio = write_report(walls, cold, counts, a.cases, a.stop, Path(a.out), load_before, os.getloadavg(),
                                  command)
    print((Path(a.out) / "sweep.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
