"""Start-up and per-communication-point cost of FMUs, timed in a plain C host (tests/c/fmu_host.c).

(a) start-up: from fmi2Instantiate to the end of the first fmi2DoStep, each run in a fresh host process (so
    the pythonfmu FMU pays its interpreter and imports as a simulator would), the FMUs alternating run by run;
    best and median. dlopen is reported beside it.
(b) cost per communication point beyond the integration, at h = 1 ms: a chunk of n steps of h with outputs
    read after each (fmi2DoStep + fmi2GetReal), minus one fmi2DoStep over n·h (+ one read) on a second instance,
    which makes the same fixed rk4 steps of 1 ms (integrator.method = rk4, integrator.step = 1 ms); divided by
    n. Chunks alternate between the two instances, the best chunk of each counts (this machine is shared: the
    minimum is the cost, the rest is other processes); repeated in fresh processes. The same two runs are also
    counted in instructions by valgrind's callgrind when it is installed (exact, whatever the load).
    Each scene reads one output, its states (y.*, yd.*) and, if it has output points, all outputs.

Peers: the native FMU of the scene, its pythonfmu FMU (start-up only) and trivial native FMUs built here:
fmi/fmi2.c over benchmarks/fmu_trivial.c (k states x_i' = -a x_i + u, rk4 at 1 ms), the same FMI layer over the
smallest engine, with as many outputs as the case beside it reads.
Targets (issue 10): native start-up <= 20 ms, pythonfmu <= 60 ms; native per-point overhead <= 1.5x the trivial
FMU's (output points aside: they are model work).

    python -m benchmarks.fmu_speed models/pendulum.yaml models/double_pendulum.yaml --out reports
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import tempfile
import uuid
from typing import NamedTuple
from pathlib import Path

from mbsfmu import files

HERE = Path(__file__).resolve().parent
HOST_SOURCE = HERE.parent / "tests" / "c" / "fmu_host.c"  # benchmarks run from a source checkout
TRIVIAL_SOURCE = HERE / "fmu_trivial.c"
H = 1e-3


def compile_host(dest: Path) -> Path:
    from mbsfmu.fmu.native import compiler
    if not HOST_SOURCE.is_file():
        raise FileNotFoundError(f"{HOST_SOURCE} not found: run the benchmark from an mbsfmu source checkout")
    exe = Path(dest) / "fmu_host"
    subprocess.run([compiler(), "-O2", "-o", str(exe), str(HOST_SOURCE), "-ldl"], check=True,
                   capture_output=True, text=True)
    return exe


def build_trivial_fmu(outdir: Path, n: int = 1) -> Path:
    """A native FMU of n states x_i' = -a x_i + u: fmi2.c over fmu_trivial.c, packaged like a scene's native FMU."""
    from mbsfmu.fmu.common import mbsfmu_version, model_description
    from mbsfmu.engine.build import linked_sources
    from mbsfmu.fmu.native import FMI_LAYER, COSIMULATION, c_names, collect_sources, package
    from mbsfmu.compiler.variables import Variable
    # the FMI layer's calls that fmu_trivial.c does not answer (resource locations) reach the engine's files
    sources = collect_sources(linked_sources([FMI_LAYER, TRIVIAL_SOURCE], []))
    guid = "{" + str(uuid.uuid4()) + "}"
    variables = [Variable("a", "parameter", "tunable", unit="1", description="decay rate", start=1.0),
                 Variable("u", "input", "continuous", unit="1", description="input")]
    variables += [Variable(f"y.x{i + 1}", "output", "continuous", unit="1", description="state") for i in range(n)]
    spec = {"name": f"trivial{n}", "description": f"x_i' = -a x_i + u, i = 1..{n} (rk4, 1 ms)",
            "experiment": {"start": 0.0}, "integrator": {}, "parameters": []}
    xml = model_description(spec, f"trivial{n}", variables, mbsfmu_version(), guid=guid, cosimulation=COSIMULATION,
                            source_files=c_names(sources))
    dest = Path(outdir) / f"trivial{n}.fmu"
    package(dest, f"trivial{n}", sources, f"{guid}\n{n}".encode(), xml)
    return dest


class Unpacked:
    """An FMU extracted for the C host: library, resource URI, GUID, value references by name."""

    def __init__(self, fmu: Path, where: Path):
        from fmpy import extract, read_model_description
        md = read_model_description(str(fmu))
        root = Path(extract(str(fmu), str(where))).resolve()
        self.name = md.modelName
        self.lib = root / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
        self.uri = (root / "resources").as_uri()
        self.guid = md.guid
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
        self.states = [v.valueReference for v in md.modelVariables  # y.*, yd.*: the rest are output points
                       if v.causality == "output" and v.name.startswith(("y.", "yd."))]

    def args(self, *options, settings=(), outputs=None):  # outputs: value references read, None: all
        out = ["-o", ",".join(map(str, self.outputs if outputs is None else outputs))]
        for name, value in settings:
            out += ["-S" if isinstance(value, str) else "-s", f"{self.vr[name]}={value}"]
        return [str(self.lib), self.uri, self.guid, *out, *options]


def run_host(host: Path, fmu: Unpacked, *options, settings=(), outputs=None) -> dict:
    r = subprocess.run([str(host), *fmu.args(*options, settings=settings, outputs=outputs)], capture_output=True, text=True,
                       timeout=300)
    if r.returncode != 0:
        raise RuntimeError(f"{fmu.name}: host exit {r.returncode}: {r.stdout[-2000:]} {r.stderr[-2000:]}")
    return {ln.split()[0]: ln.split()[1:] for ln in r.stdout.splitlines() if ln[:4] in ("TIME", "LOOP")}


def startup(host, fmus: dict, runs: int) -> list[dict]:
    """Fresh process per run, FMUs alternating; milliseconds."""
    samples = {k: ([], []) for k in fmus}
    for _ in range(runs):
        for kind, fmu in fmus.items():
            load, first = run_host(host, fmu, "-T", "-n", "1", "-h", str(H))["TIME"]
            samples[kind][0].append(float(load) / 1e6)
            samples[kind][1].append(float(first) / 1e6)
    return [{"kind": k, "runs": runs, "load_ms_median": statistics.median(lo), "first_step_ms_best": min(fs),
             "first_step_ms_median": statistics.median(fs)} for k, (lo, fs) in samples.items()]


class Case(NamedTuple):
    """One per-point measurement: an FMU, its settings and the outputs read after every step."""
    label: str
    fmu: Unpacked
    settings: tuple
    outputs: list
    points: int = 0  # how many of the outputs are output-point values (computed by kinematics when read)
    trivial: str = ""  # label of the trivial FMU that reads as many outputs


def loop_cost(host, cases: list, n: int, runs: int, chunks: int = 300) -> dict:
    """{label: (per point, integration, overhead best, overhead median)} in µs, cases alternating."""
    samples = {c.label: [] for c in cases}
    for _ in range(runs):
        for c in cases:
            _, points, one = run_host(host, c.fmu, "-L", "-n", str(n), "-r", str(chunks), "-h", str(H),
                                      settings=c.settings, outputs=c.outputs)["LOOP"]
            samples[c.label].append((float(points) / n / 1e3, float(one) / n / 1e3))
    out = {}
    for label, s in samples.items():
        over = [p - o for p, o in s]
        out[label] = (statistics.median(p for p, _ in s), statistics.median(o for _, o in s), min(over),
                      statistics.median(over))
    return out


def instructions(host, cases: list, n: int = 2000) -> dict:
    """{label: instructions per point beyond the integration}: the same two runs as loop_cost (n steps of h
    with a read after each; one step of n·h and one read), counted by valgrind's callgrind: exact, whatever
    the load on the machine. {} without valgrind."""
    import re
    import shutil
    if not shutil.which("valgrind"):
        return {}
    out = {}
    with tempfile.TemporaryDirectory(prefix="mbsfmu_callgrind_") as tmp:
        def count(c, *options):
            log = Path(tmp) / "cg.log"
            subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={Path(tmp) / 'cg.out'}",
                            f"--log-file={log}", str(host), *c.fmu.args(*options, settings=c.settings,
                                                                          outputs=c.outputs)],
                           check=True, capture_output=True, timeout=600)
            return int(re.search(r"Collected : (\d+)", log.read_text()).group(1))
        for c in cases:
            many = count(c, "-n", str(n), "-h", str(H))
            out[c.label] = (many - count(c, "-n", "1", "-h", str(n * H))) / (n - 1)
    return out


def cases_of(native: dict, settings: tuple, build_trivial) -> list:
    """For each scene's native FMU: one output, the states (y.*, yd.*), and all outputs when it has output
    points; each beside a trivial FMU that reads as many outputs (build_trivial(n) → Unpacked)."""
    trivial, cases = {}, []

    def beside(k):
        if k not in trivial:
            trivial[k] = Case(f"trivial, {k} state{'s' * (k > 1)}", build_trivial(k), (), None)
        return trivial[k].label
    for name, fmu in native.items():
        reads = [("one output", fmu.outputs[:1]), ("y, ẏ outputs", fmu.states)]
        if len(fmu.outputs) > len(fmu.states):
            reads.append(("all outputs", fmu.outputs))
        for what, outputs in reads:
            cases.append(Case(f"{name}: {what}", fmu, settings, outputs,
                              len(outputs) - len(set(outputs) & set(fmu.states)), beside(len(outputs))))
    return cases + sorted(trivial.values(), key=lambda c: len(c.fmu.outputs))


def report(scenes, outdir: Path, runs: int, n: int) -> Path:
    """Both measurements for the native and pythonfmu FMUs of each scene and trivial FMUs; writes
    fmu_speed.md and two CSV files into outdir."""
    from mbsfmu import build_fmu
    from mbsfmu.reports.output import write_csv
    outdir.mkdir(parents=True, exist_ok=True)
    rk4 = (("integrator.method", "rk4"), ("integrator.step", H))
    with tempfile.TemporaryDirectory(prefix="mbsfmu_fmu_speed_") as tmp:
        tmp = Path(tmp)
        host = compile_host(tmp)
        built = {}
        for scene in scenes:
            fmu = build_fmu(scene, tmp / f"n{len(built)}", kind="native")
            built[f"native {fmu.stem}"] = fmu
            built[f"pythonfmu {fmu.stem}"] = build_fmu(scene, tmp / f"p{len(built)}")
        built["trivial"] = build_trivial_fmu(tmp / "trivial")
        fmus = {k: Unpacked(p, tmp / f"x{i}") for i, (k, p) in enumerate(built.items())}
        start_rows = startup(host, fmus, runs)
        cases = cases_of({k[len("native "):]: f for k, f in fmus.items() if k.startswith("native")}, rk4,
                         lambda k: fmus["trivial"] if k == 1 else Unpacked(build_trivial_fmu(tmp / f"t{k}", k),
                                                                           tmp / f"tx{k}"))
        times = loop_cost(host, cases, n, runs)
        instr = instructions(host, cases)
    loop_rows = []
    for c in cases:
        per_point, integration, best, median = times[c.label]
        row = {"case": c.label, "outputs": len(c.outputs if c.outputs is not None else c.fmu.outputs),
               "point_outputs": c.points, "runs": runs, "points": n, "per_point_us_median": per_point,
               "integration_us_median": integration, "overhead_us_best": best, "overhead_us_median": median,
               "trivial": c.trivial}
        if instr:
            row["instructions"] = instr[c.label]
            row["instructions_ratio"] = instr[c.label] / instr[c.trivial] if c.trivial else 1.0
        loop_rows.append(row)
    write_csv(start_rows, outdir / "fmu_speed_startup.csv", list(start_rows[0]), 4)
    write_csv(loop_rows, outdir / "fmu_speed_loop.csv", list(loop_rows[0]), 4)
    slowest = max(r["first_step_ms_median"] for r in start_rows if r["kind"].startswith("native"))
    slowest_py = max(r["first_step_ms_median"] for r in start_rows if r["kind"].startswith("pythonfmu"))
    lines = ["# FMU start-up and per-communication-point cost", "",
             "Timed in the plain C host `tests/c/fmu_host.c` (`python -m benchmarks.fmu_speed "
             f"{' '.join(map(str, scenes))} --out {outdir} --runs {runs} --points {n}`). The trivial FMUs are "
             "fmi/fmi2.c over benchmarks/fmu_trivial.c: k independent states x_i' = -a x_i + u, rk4 at 1 ms, "
             "the same FMI layer as the scenes' FMUs over the smallest engine.", "",
             f"## Start-up: fmi2Instantiate → end of the first fmi2DoStep (h = 1 ms), a fresh process per run, "
             f"{runs} runs, FMUs alternating", "",
             "| FMU | best [ms] | median [ms] | dlopen, median [ms] |", "|---|---|---|---|"]
    lines += [f"| {r['kind']} | {r['first_step_ms_best']:.3f} | {r['first_step_ms_median']:.3f} | "
              f"{r['load_ms_median']:.3f} |" for r in start_rows]
    lines += ["", f"Target: native ≤ 20 ms → slowest median {slowest:.3f} ms ({'met' if slowest <= 20 else 'NOT met'}); "
              f"pythonfmu ≤ 60 ms → slowest median {slowest_py:.1f} ms ({'met' if slowest_py <= 60 else 'NOT met'}).",
              "", f"## Per communication point beyond the integration, h = 1 ms", "",
              "Per point: fmi2DoStep(h) + fmi2GetReal(the outputs read). Integration: one fmi2DoStep(n·h) + one "
              "fmi2GetReal on a second instance (the same rk4 steps of 1 ms). Overhead = difference / n. Each "
              "case is compared with the trivial FMU that reads as many outputs, so that both pay the same "
              "number of reads. Output points (world position and velocity of a body point) are computed from "
              "the kinematics when first read after a step: model work a trivial FMU does not have, shown in "
              "rows of their own.", "",
              f"Time: chunks of {n} points, the best of 300 alternating chunks per run (short chunks: most run "
              f"without an interrupt), best and median over {runs} runs. The overheads are a few hundredths of a "
              "microsecond against a microsecond of integration, within this machine's noise (a negative best "
              "is noise), so their ratios say nothing; the instruction counts below are the measure.", "",
              "| case | outputs read (output-point values) | per point [µs] | integration [µs] | overhead best [µs] | "
              "overhead median [µs] |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['case']} | {r['outputs']} ({r['point_outputs']}) | {r['per_point_us_median']:.3f} | "
              f"{r['integration_us_median']:.3f} | {r['overhead_us_best']:.4f} | {r['overhead_us_median']:.4f} |"
              for r in loop_rows]
    if instr:
        lines += ["", "Instructions (valgrind callgrind: exact and load-independent; 2000 points of 1 ms against one "
                  "step of 2 s):", "",
                  "| case | outputs read (output-point values) | instructions per point beyond the integration | "
                  "× trivial |", "|---|---|---|---|"]
        lines += [f"| {r['case']} | {r['outputs']} ({r['point_outputs']}) | {r['instructions']:.0f} | "
                  f"{r['instructions_ratio']:.2f} |" for r in loop_rows]
        judged = [r for r in loop_rows if r["trivial"] and not r["point_outputs"]]
        worst = max(r["instructions_ratio"] for r in judged)
        lines += ["", f"Target: native overhead ≤ 1.5 × the trivial FMU's (instructions, as many outputs read, "
                  f"output points aside) → up to {worst:.2f} × ({'met' if worst <= 1.5 else 'NOT met'})."]
        for r in loop_rows:
            if r["point_outputs"]:
                states = next(q for q in loop_rows if q["case"] == r["case"].replace("all outputs", "y, ẏ outputs"))
                lines += [f"{r['case']}: its {r['point_outputs']} output-point values cost "
                          f"{r['instructions'] - states['instructions']:.0f} instructions per point beyond reading "
                          f"the states."]
    lines += [""]
    md = outdir / "fmu_speed.md"
    files.write_text(md, "\n".join(lines))
    return md


def main(argv=None):
    ap = argparse.ArgumentParser(prog="benchmarks.fmu_speed", description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", default=["models/pendulum.yaml", "models/double_pendulum.yaml"])
    ap.add_argument("--out", default="reports", help="folder for fmu_speed.md and the CSV files")
    ap.add_argument("--runs", type=int, default=15)
    ap.add_argument("--points", type=int, default=200, help="communication points per timed chunk")
    a = ap.parse_args(argv)
    print(report(a.scenes, Path(a.out), a.runs, a.points))


if __name__ == "__main__":
    main()
