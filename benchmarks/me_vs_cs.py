"""fmpy's model exchange against co-simulation at equal error: one native FMU, the host's solver or the engine's.

Cases (benchmarks/fmu_peers.CASES): the heavy top (`models/spinning_top.yaml`, spin 150 rad/s, 2 s, 1000 points) and
the double pendulum (`models/double_pendulum.yaml`, 10 s, 1000 points). One native FMI 2.0 FMU per case, offering
both interfaces, run through `fmpy.simulate_fmu` from its extracted folder (no validation, the modelDescription
read once), with the same outputs (the position coordinates) at the same communication points:
* ``ME:CVode``: model exchange under fmpy's CVode (BDF; absolute tolerance rtol × each state's nominal,
  docs/fmu.md "Nominal values") at rtol 1e-4 … 1e-12;
* ``ME:Euler``: model exchange under fmpy's explicit Euler at the communication step divided by 1 … 4096 (fmpy
  takes one Euler step per output interval: those runs record every step, and the communication points are
  every k-th row);
* ``CS:<method>``: co-simulation, the engine integrating inside `fmi2DoStep`: dop853, dopri5, radau5 and auto at
  rtol 1e-4 … 1e-12 (atol = rtol·1e-2), rk4 at the communication step divided by 1 … 64.

error = max over communication points of |y − y_ref| over the position coordinates (the top's quaternion
sign-aligned with the reference), y_ref: the engine's dop853 in-process at rtol 1e-13, atol 1e-15
(work_precision.reference; scipy's DOP853 on the same right-hand side at that tolerance differs by the floor
reported). CPU = time.process_time of the whole `simulate_fmu` call (instantiation, fmpy's loop and recorder), the
same host code for both interfaces. Each sweep runs loose to tight and stops after a run below 1e-10 or over the CPU
budget; the runs kept (but that one over the budget) are then timed again in rounds, every run once per round, the
order rotating (alternating runs); medians are reported. Equal error: for each error level, the cheapest median among a family's runs at or
below it.

    python -m benchmarks.me_vs_cs --out reports
"""
from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from pathlib import Path

import numpy as np

from mbsfmu.engine import layout as L
from mbsfmu.reports import output
from .fmu_peers import CASES, MODELS, case, error
from mbsfmu.reports.work_precision import reference

RTOLS = tuple(10.0 ** -k for k in range(4, 13))
EULER_DIVISORS = tuple(4 ** k for k in range(7))  # 1 … 4096
RK4_DIVISORS = (1, 2, 4, 8, 16, 32, 64)
LEVELS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)  # the error levels of the ratio table
FLOOR = 1e-10  # a sweep stops after a run below this error (tighter is the reference's business)
COLUMNS = ["model", "interface", "method", "setting", "cpu_ms", "cpu_ms_min", "error", "rounds"]


def plan(dt, quick=False):
    """(interface, method, setting label, kwargs of FMU.run) of every sweep, each loose to tight."""
    rtols = RTOLS[::4] if quick else RTOLS
    out = [("ME", "CVode", f"rtol={r:.0e}", {"rtol": r}) for r in rtols]
    out += [("ME", "Euler", f"h={dt / k:.4g}", {"h": dt / k}) for k in (EULER_DIVISORS[:4:3] if quick else EULER_DIVISORS)]
    for m in ("dop853",) if quick else L.ADAPTIVE:   # every adaptive integrator of the engine's table
        out += [("CS", m, f"rtol={r:.0e}", {"rtol": r, "atol": r * 1e-2}) for r in rtols]
    out += [("CS", "rk4", f"h={dt / k:.4g}", {"h": dt / k}) for k in (RK4_DIVISORS[::3] if quick else RK4_DIVISORS)]
    return out


class FMU:
    """A scene's native FMI 2.0 FMU (both interfaces), built and extracted once; `run` is one simulate_fmu."""

    def __init__(self, scene_file, workdir):
        from fmpy import extract, read_model_description
        import mbsfmu
        path = mbsfmu.build_fmu(scene_file, Path(workdir) / "fmu", kind="native")
        self.md = read_model_description(str(path))
        self.root = extract(str(path), str(Path(workdir) / "unzipped"))
        self.positions = [v.name for v in self.md.modelVariables if v.causality == "output" and v.name.startswith("y.")]

    def run(self, interface, method, ts, parameters, rtol=None, atol=None, h=None):
        """fmpy's simulate_fmu over ts → (Y at ts, cpu seconds). ME: fmpy's solver `method` (CVode at rtol,
        Euler at step h); CS: the engine's integrator `method` (rtol and atol, or the step h) set as start values."""
        from fmpy import simulate_fmu
        start, dt = dict(parameters), float(ts[1] - ts[0])
        every = 1 if h is None or interface == "CS" else round(dt / h)  # fmpy's Euler: one step per output interval
        kw = dict(fmi_type="ModelExchange" if interface == "ME" else "CoSimulation", output_interval=dt / every)
        if interface == "ME":
            kw.update(solver=method, relative_tolerance=rtol, step_size=h)
        else:
            start["integrator.method"] = method
            start.update({k: v for k, v in (("integrator.rtol", rtol), ("integrator.atol", atol),
                                            ("integrator.step", h)) if v is not None})
        c0 = time.process_time()
        r = simulate_fmu(self.root, validate=False, model_description=self.md, start_time=float(ts[0]),
                         stop_time=float(ts[-1]), output=self.positions, start_values=start, **kw)
        cpu = time.process_time() - c0
        r = r[::every]
        if len(r) != len(ts) or not np.allclose(r["time"], ts, rtol=0, atol=1e-9 * dt):
            raise RuntimeError(f"{interface}:{method}: {len(r)} points, not the {len(ts)} asked for")
        return np.column_stack([r[n] for n in self.positions]), cpu


def run_case(name, workdir, quick=False, budget=2.0, rounds=5, stop=None, log=print):
    """Sweeps, then `rounds` alternating rounds over the runs kept → dict for the report."""
    from .fmu_peers import _model
    spec, ts, params = case(name, stop)
    model, _ = _model(spec)
    quats = [np.asarray(q) for q in model.quaternions]
    Yref, ref_cpu, floor = reference(spec, ts)
    fmu = FMU(MODELS / CASES[name][0], workdir)
    load = [os.getloadavg()[0]]
    kept, stopped, notes = [], set(), []
    for interface, method, label, kw in plan(ts[1] - ts[0], quick):
        if (interface, method) in stopped:
            continue
        try:
            Y, cpu = fmu.run(interface, method, ts, params, **kw)
        except Exception as e:  # noqa: BLE001 - a failed setting is a result (noted), not the end of the sweep
            notes.append(f"{interface}:{method} {label} did not run: {type(e).__name__}: {str(e).strip()[:120]}")
            continue
        err = error(Y, Yref, quats)
        log(f"{name} {interface}:{method} {label}: {cpu * 1e3:.1f} ms, error {err:.1e}")
        kept.append(dict(interface=interface, method=method, setting=label, kw=kw, error=err, samples=[cpu * 1e3]))
        if err < FLOOR or cpu > budget:
            stopped.add((interface, method))
    load.append(os.getloadavg()[0])
    timed = [row for row in kept if row["samples"][0] <= budget * 1e3]  # a run over the budget is timed once
    for r in range(rounds - 1):  # alternating: every timed run once per round, the order rotating
        k = r % len(timed)
        for row in timed[k:] + timed[:k]:
            row["samples"].append(fmu.run(row["interface"], row["method"], ts, params, **row["kw"])[1] * 1e3)
    load.append(os.getloadavg()[0])
    for row in kept:
        row["cpu_ms"], row["cpu_ms_min"] = statistics.median(row["samples"]), min(row["samples"])
    return dict(name=name, ts=ts, params=params, rows=kept, notes=notes, ref_cpu=ref_cpu, floor=floor, load=load,
                rounds=rounds)


def cheapest(rows, level, family):
    """The row of `family` ("ME:CVode", "ME:Euler" or "CS": any engine method) with the least median CPU among
    those at error ≤ level, or None."""
    ok = [r for r in rows if r["error"] <= level and (f"{r['interface']}:{r['method']}" == family
                                                      or r["interface"] == family)]
    return min(ok, key=lambda r: r["cpu_ms"]) if ok else None


def ratio_table(res):
    """Markdown rows: per error level the cheapest ME:CVode, ME:Euler and CS run, and ME / CS time ratios."""
    lines = ["| error ≤ | ME:CVode | ME:Euler | CS (cheapest engine method) | CVode / CS | Euler / CS |",
             "|---|---|---|---|---|---|"]
    for level in LEVELS:
        best = {f: cheapest(res["rows"], level, f) for f in ("ME:CVode", "ME:Euler", "CS")}
        cell = {f: (f"{b['cpu_ms']:.1f} ms ({(b['method'] + ' ') if f == 'CS' else ''}{b['setting']})" if b else "—")
                for f, b in best.items()}
        cs = best["CS"]
        rat = {f: (f"**{best[f]['cpu_ms'] / cs['cpu_ms']:.1f}**" if best[f] and cs else "—") for f in ("ME:CVode", "ME:Euler")}
        lines.append(f"| {level:.0e} | {cell['ME:CVode']} | {cell['ME:Euler']} | {cell['CS']} | {rat['ME:CVode']} | "
                     f"{rat['ME:Euler']} |")
    return lines


def plot(res, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(9, 6.5))
    for interface, method in dict.fromkeys((r["interface"], r["method"]) for r in res["rows"]):
        rr = [r for r in res["rows"] if (r["interface"], r["method"]) == (interface, method) and math.isfinite(r["error"])]
        ax.loglog([r["cpu_ms"] for r in rr], [max(r["error"], 1e-16) for r in rr], marker="o" if interface == "ME" else ".",
                  ls="-" if interface == "ME" else "--", lw=1.8 if interface == "ME" else 1.0, ms=4,
                  label=f"{interface}:{method}")
    ts = res["ts"]
    ax.set_xlabel("CPU time [ms] (median of alternating rounds; fmpy.simulate_fmu, instantiation included)")
    ax.set_ylabel("max |y − y_ref| over communication points")
    ax.set_title(f"{res['name']}: t = 0…{ts[-1]:g} s, {len(ts) - 1} points; ME = fmpy's solver, CS = the engine's")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    output.save_figure(fig, path, dpi=100)


def csv_rows(res):
    return [dict(r, model=res["name"], rounds=len(r["samples"])) for r in res["rows"]]


def markdown(results, command):
    lines = ["# fmpy's model exchange against co-simulation at equal error", "", f"`{command}`", "",
             __doc__.split("\n\n", 1)[1].split("\n    python")[0].strip(), ""]
    for res in results:
        ts = res["ts"]
        params = ", ".join(f"{k} = {v:g}" for k, v in res["params"].items())
        lines += [f"## {res['name']}" + (f" ({params})" if params else ""), "",
                  f"t = 0…{ts[-1]:g} s, {len(ts) - 1} communication points of {ts[1] - ts[0]:g} s. Reference: the "
                  f"engine's dop853 at rtol 1e-13 ({res['ref_cpu'] * 1e3:.0f} ms); scipy DOP853 at the same tolerance "
                  f"differs by {res['floor']:.1e}. {res['rounds']} rounds. Load average (1 min) at the start / after "
                  "the sweeps / at the end: " + " / ".join(f"{x:.2f}" for x in res["load"]) + " on 2 cores.", "",
                  "Time ratios at equal error (> 1: model exchange is slower):", ""] + ratio_table(res)
        lowest = {}
        for r in res["rows"]:
            key = f"{r['interface']}:{r['method'] if r['interface'] == 'ME' else 'engine'}"
            if math.isfinite(r["error"]) and r["error"] < lowest.get(key, {"error": math.inf})["error"]:
                lowest[key] = r
        lines += ["", "Lowest error each reached within the sweep: " + "; ".join(
            f"{k} {r['error']:.1e} ({'' if k.startswith('ME') else r['method'] + ' '}{r['setting']}, {r['cpu_ms']:.0f} ms)"
            for k, r in lowest.items()) + "."]
        if res["notes"]:
            lines += ["", "Notes:", ""] + [f"- {n}" for n in res["notes"]]
        lines += ["", f"![work-precision {res['name']}](me_vs_cs.{res['name']}.png)", ""]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks.me_vs_cs", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="reports", help="folder for me_vs_cs.md, .csv and the plots")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--rounds", type=int, default=5, help="alternating rounds (>= 5 for the report)")
    ap.add_argument("--budget", type=float, default=2.0, help="CPU seconds of one run after which a sweep stops")
    ap.add_argument("--stop", type=float, default=None, help="shorter experiments (the cases' own by default)")
    ap.add_argument("--quick", action="store_true", help="coarse sweeps, one round (a smoke run, not for the report)")
    a = ap.parse_args(argv)
    return output.case_reports("me_vs_cs", "benchmarks.me_vs_cs", argv, a.out, a.cases,
                               lambda name, tmp: run_case(name, tmp, quick=a.quick, budget=a.budget, stop=a.stop,
                                                          rounds=1 if a.quick else a.rounds),
                               plot, csv_rows, COLUMNS, markdown)


if __name__ == "__main__":
    main()
