"""Numerical stability suite: stiff and extreme scenes × integration methods.

Every run either completes or fails with an `IntegrationError` (a clean failure, message recorded); any
other exception is a bug and is reported as CRASH. Each run has a CPU-time budget (exceeding it is
recorded as "budget"). The built-in cases' scenes live in `models/stress/*.yaml` (the repository's); scenes
given on the command line are run instead, each as a case over every method (`scene_cases`).

Columns: case, method, status (completed | failed | budget | CRASH), expected (as the case expects?),
error (max |y − y_ref| over communication points, y_ref = radau5/dop853 at rtol 1e-11 where sensible),
energy_drift (max |E(t) − E(0)| / max(|E(0)|, kinetic-energy scale), conservative cases only),
wall_seconds, steps, rhs_evaluations, message.
"""

import argparse
import os
import time
from pathlib import Path

import numpy as np

from .. import files
from ..engine import layout as L
from . import output

METHODS = L.METHODS  # every integrator of the engine (mbs_layout.h: MBS_METHODS)
COLUMNS = ["case", "method", "status", "expected", "error", "energy_drift", "wall_seconds", "steps",
           "rhs_evaluations", "message"]


def scene_dir():
    """models/stress of the repository (the package is installed editable from it)."""
    here = Path(__file__).resolve()
    for p in here.parents:
        d = p / "models" / "stress"
        if d.is_dir():
            return d
    raise FileNotFoundError("models/stress not found next to the mbsfmu sources")


class Case:
    """One stress scenario: scene, experiment, methods, what is expected, how to judge it."""

    def __init__(self, name, scene, description, stop=None, step=None, methods=METHODS, expect="complete",
                 expect_message=None, reference="dop853", conservative=False, inputs=None, params=None,
                 rtol=1e-6, atol=1e-8, quick_stop=None, budget=30.0, quick_methods=None, tol_error=None, spec=None):
        self.name, self.scene, self.description, self.spec = name, scene, description, spec
        self.stop, self.step, self.methods, self.expect = stop, step, methods, expect
        self.expect_message, self.reference, self.conservative = expect_message, reference, conservative
        self.inputs, self.params, self.rtol, self.atol = inputs or {}, params or {}, rtol, atol
        self.quick_stop, self.budget, self.tol_error = quick_stop, budget, tol_error
        self.quick_methods = quick_methods or methods


def cases():
    """The suite. NaN/Inf inputs and parameters must be refused with IntegrationError."""
    nan, inf = float("nan"), float("inf")
    return [
        Case("stiff_spring", "stiff_spring", "1e8 N/m spring between two 10 g sliders (fast modes ~-6e4, -3.4e5 1/s)",
             reference="radau5", budget=40.0, tol_error=1e-4),
        Case("heavy_damping", "heavy_damping", "double pendulum with 1000 N m s/rad hinge dampers",
             reference="radau5", budget=40.0, quick_stop=0.2, tol_error=1e-4),
        Case("mass_ratio_1e6", "mass_ratio", "double pendulum, link masses 1000 kg and 1 g", conservative=True,
             quick_stop=0.5, tol_error=1e-3),
        Case("tiny_inertia_1e-9", "tiny_inertia", "spherical pendulum (quaternion), 1 mg, inertias 1e-9 kg m^2",
             conservative=True, quick_stop=0.3, tol_error=1e-3),
        Case("top_150rad_s", "top_150", "heavy top spinning at 150 rad/s (quaternion)", conservative=True,
             quick_stop=0.2, tol_error=1e-3),
        Case("gimbal_lock", "gimbal_lock", "Cardan angles driven through b = 90 deg", expect="fail",
             expect_message="quaternion", reference=None),
        Case("gimbal_lock_coarse_step", "gimbal_lock",
             "same, 0.05 s communication step (no communication point within 1e-3 rad of b = 90 deg)",
             step=0.05, expect="fail", expect_message="quaternion", reference=None,
             methods=("auto", "dopri5", "radau5", "rk4")),
        Case("long_run_1e5_steps", "long_run", "pendulum, 1e5 communication steps of 1 ms, energy drift",
             conservative=True, methods=("dopri5", "rk4", "gen_alpha"), quick_stop=5.0, budget=150.0,
             reference=None, quick_methods=("dopri5", "rk4")),
        Case("comm_step_1e6_x_tau", "heavy_damping",
             "heavy damping with a 0.5 s communication step (fastest time constant ~1e-4 s)", stop=2.0, step=0.5,
             reference="radau5", budget=20.0, quick_stop=1.0, tol_error=1e-4),
        Case("stiff_elastic_beam", "stiff_beam", "flexible pendulum with a 1e4 times stiffer beam (4 modes, bending "
             "frequencies 100 times higher): elastic and stiff", reference="radau5", budget=40.0, quick_stop=0.2, tol_error=1e-4,
             stop=1.0),
        Case("spinup_beam_stiffening", "spinup_beam", "driven spin-up of a beam with dynamic stiffening (rheonomic, "
             "elastic)", reference="radau5", budget=40.0, quick_stop=0.5, tol_error=1e-4),
        Case("fe_link", "fe_link", "FE link (459-DOF tet10 part, Craig–Bampton, 4 modes, 34–629 Hz, consistent-mass "
             "invariants, 1 % modal damping) swinging from horizontal with a 50 g end mass", reference="radau5",
             budget=40.0, quick_stop=0.2, tol_error=1e-4),
        Case("nan_input", "double_pendulum", "input q.phi1 = NaN", expect="fail", expect_message="not finite",
             inputs={"q.phi1": nan}, reference=None, stop=0.1),
        Case("inf_input", "double_pendulum", "input q.phi2 = +Inf", expect="fail", expect_message="not finite",
             inputs={"q.phi2": inf}, reference=None, stop=0.1),
        Case("nan_parameter", "double_pendulum", "parameter m set to NaN after initialization", expect="fail",
             expect_message="not finite", params={"m": nan}, reference=None, stop=0.1),
    ]


QUICK_METHODS = ("dopri5", "radau5", "rk4")  # a scene of the user's with --quick: explicit, implicit, fixed step


def scene_cases(paths):
    """A case per scene file (a user's): its experiment, every method, reference dop853 at rtol 1e-11 (radau5
    where dop853 fails); --quick runs a tenth of the experiment (at least 10 communication steps)."""
    import mbsfmu
    out, names = [], set()
    for path in paths:
        spec = mbsfmu.load(str(path)).spec
        e = spec["experiment"]
        name = spec["name"] if spec["name"] not in names else f"{spec['name']} ({path})"
        names.add(name)
        quick = e["start"] + max(10 * e["step"], (e["stop"] - e["start"]) / 10)
        out.append(Case(name, str(path), (spec.get("description") or f"the scene {path}").strip(), spec=spec,
                        quick_stop=min(e["stop"], quick), quick_methods=QUICK_METHODS))
    return out


def _load_spec(scene):
    import mbsfmu
    p = scene_dir() / f"{scene}.yaml"
    if not p.exists():
        p = scene_dir().parent / f"{scene}.yaml"
    return mbsfmu.load(str(p)).spec


def _ts(spec, case, quick):
    from .work_precision import comm_points
    stop = case.stop
    if quick and case.quick_stop is not None:
        stop = case.quick_stop if stop is None else min(stop, case.quick_stop)
    return comm_points(spec, stop=stop, step=case.step)


def run_one(spec, case, method, ts, rtol=None, atol=None, budget=None):
    """One run through Simulation.do_step → dict with status, message, Y, YD, wall, stats."""
    from mbsfmu.engine import EngineError
    from mbsfmu.errors import IntegrationError
    from mbsfmu.simulation import Simulation
    from .work_precision import Budget, _check_budget
    rtol = case.rtol if rtol is None else rtol
    atol = case.atol if atol is None else atol
    budget = case.budget if budget is None else budget
    out = {"status": "completed", "message": "", "Y": None, "YD": None, "stats": {}}
    w0 = time.perf_counter()
    sim = None
    try:
        sim = Simulation(spec)
        sim.set("integrator.method", method)
        sim.set("integrator.rtol", rtol)
        sim.set("integrator.atol", atol)
        c0 = time.process_time()
        sim.initialize(ts[0])
        for k, v in case.inputs.items():
            sim.set(k, v)
        Y = np.empty((len(ts), sim.npos))
        YD = np.empty((len(ts), sim.nvel))
        Y[0], YD[0] = sim.y, sim.yd
        for k in range(len(ts) - 1):
            if k == 1:
                for p, v in case.params.items():
                    sim.set(p, v)
            sim.do_step(ts[k], ts[k + 1] - ts[k])
            Y[k + 1], YD[k + 1] = sim.y, sim.yd
            _check_budget(c0, budget)
        out["Y"], out["YD"] = Y, YD
    except (IntegrationError, EngineError) as e:  # a failed step, or a value the engine refused when set
        out["status"], out["message"] = "failed", str(e)
    except Budget as e:
        out["status"], out["message"] = "budget", f"stopped {e} at t={sim.time:.4g}" if sim else str(e)
    except Exception as e:  # noqa: BLE001 - anything else is a bug we want in the table, not a crash of the suite
        out["status"], out["message"] = "CRASH", f"{type(e).__name__}: {e}"
    out["wall"] = time.perf_counter() - w0
    if sim is not None and sim.initialized:
        out["stats"] = dict(sim.stats)
    out["sim"] = sim
    return out


def energy_drift(spec, Y, YD, ts):
    """max |E(t_k) − E(0)| relative to max(|E(0)|, max kinetic energy)."""
    from mbsfmu.equations import Evaluator
    ev = Evaluator(spec)
    E = np.array([ev.energy(y, yd, t) for y, yd, t in zip(Y, YD, ts)])
    zero = np.zeros_like(Y[0])
    T = np.array([ev.energy(y, yd, t) - ev.energy(y, np.zeros_like(yd), t) for y, yd, t in zip(Y[::max(1, len(Y) // 50)], YD[::max(1, len(Y) // 50)], ts)])
    del zero
    scale = max(abs(E[0]), float(np.max(np.abs(T))), 1e-300)
    return float(np.max(np.abs(E - E[0])) / scale)


def run(out_dir=None, quick=False, progress=True, only=None, methods=None, scenes=None):
    """Run the suite (or a case per scene file of `scenes`); write stress.csv, stress.md and stress.png in
    out_dir; return the rows."""
    rows = []
    todo = scene_cases(scenes) if scenes else [c for c in cases() if only is None or c.name in only]
    jobs = [(c, m) for c in todo for m in (c.quick_methods if quick else c.methods) if methods is None or m in methods]
    refs = {}
    for case, method in output.progress(jobs, "stress", lambda j: f"{j[0].name} {j[1]}", progress):
        spec = case.spec or _load_spec(case.scene)
        ts = _ts(spec, case, quick)
        if case.reference and case.name not in refs:
            refs[case.name] = None
            for ref_method in dict.fromkeys((case.reference, "radau5")):  # the stiff fall-back
                ref = run_one(spec, case, ref_method, ts, rtol=1e-11, atol=1e-13, budget=120.0)
                if ref["status"] == "completed":
                    refs[case.name] = ref["Y"]
                    break
        r = run_one(spec, case, method, ts)
        err = ""
        Yref = refs.get(case.name)
        if r["status"] == "completed" and Yref is not None:
            err = float(np.max(np.abs(r["Y"] - Yref)))
        drift = ""
        if r["status"] == "completed" and case.conservative:
            drift = energy_drift(spec, r["Y"], r["YD"], ts)
        if case.expect == "complete":
            expected = r["status"] == "completed" and (case.tol_error is None or err == "" or err <= case.tol_error)
            if r["status"] in ("failed", "budget"):
                expected = "clean failure"
        else:
            expected = r["status"] == "failed" and (case.expect_message or "") in r["message"]
        st = r["stats"]
        rows.append({"case": case.name, "method": method, "status": r["status"],
                     "expected": expected if isinstance(expected, str) else ("yes" if expected else "NO"),
                     "error": err, "energy_drift": drift, "wall_seconds": r["wall"],
                     "steps": st.get("steps", ""), "rhs_evaluations": st.get("rhs_evaluations", ""),
                     "message": r["message"], "switched": st.get("switched", ""),
                     "description": case.description, "n_comm": len(ts) - 1, "stop": ts[-1], "step": ts[1] - ts[0]})
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
        output.write_csv(rows, os.path.join(out_dir, "stress.csv"), COLUMNS, 4)
        files.write_text(os.path.join(out_dir, "stress.md"), markdown(rows, quick))
        plot(rows, os.path.join(out_dir, "stress.png"))
    return rows


OUTCOMES = {  # (status, as expected?) → (colour, word) of the plot's cells
    "completed": ("#4caf50", "ok"), "failed": ("#ffb74d", "failed"), "budget": ("#bdbdbd", "budget"),
    "CRASH": ("#e53935", "CRASH"), "NO": ("#e53935", "NO")}


def _cell(r):
    """(colour, text) of one run: not as expected shows NO whatever the status; a completed run its error."""
    if r["status"] == "failed" and r["expected"] == "yes":  # a refusal the case asks for
        return "#a5d6a7", "failed, ok"
    colour, word = OUTCOMES["NO" if r["expected"] == "NO" else r["status"]]
    if r["status"] == "completed" and isinstance(r["error"], float):
        word = f"{r['error']:.0e}" if r["expected"] != "NO" else f"NO {r['error']:.0e}"
    return colour, word


def plot(rows, path):
    """The case × method summary as a grid: a cell's colour says how the run ended (green completed, light green
    a failure the case expects, orange a clean failure, grey the budget, red a crash or not as expected), its text
    the error against the reference."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import to_rgb
    case_names = list(dict.fromkeys(r["case"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    grid = np.ones((len(case_names), len(methods), 3))
    fig, ax = plt.subplots(figsize=(1.3 + 1.1 * len(methods), 1.2 + 0.4 * len(case_names)))
    for r in rows:
        i, j = case_names.index(r["case"]), methods.index(r["method"])
        colour, word = _cell(r)
        grid[i, j] = to_rgb(colour)
        ax.text(j, i, word, ha="center", va="center", fontsize=7)
    ax.imshow(grid, aspect="auto")
    ax.set_xticks(range(len(methods)), methods)
    ax.set_yticks(range(len(case_names)), case_names)
    ax.xaxis.tick_top()
    ax.set_xticks(np.arange(len(methods) + 1) - 0.5, minor=True)
    ax.set_yticks(np.arange(len(case_names) + 1) - 0.5, minor=True)
    ax.grid(which="minor", color="white", linewidth=2)
    ax.tick_params(which="minor", length=0)
    ax.set_title("max |y − y_ref| per case and method\ngreen: completed (light: failed as the case expects), "
                 "orange: failed cleanly, grey: budget, red: crash or not as expected", fontsize=8, pad=22)
    fig.tight_layout()
    output.save_figure(fig, path, dpi=110, bbox_inches="tight")


def _fmt(v, spec=".2e"):
    return format(v, spec) if isinstance(v, float) else str(v)


def markdown(rows, quick):
    lines = ["# Stress suite" + (" (quick)" if quick else ""), "",
             "Each run goes through `Simulation.do_step` (the FMU path) with rtol 1e-6, atol 1e-8 (rk4: one step "
             "per communication interval, gen_alpha adaptive). status: completed | failed (IntegrationError, "
             "message shown) | budget (CPU budget exceeded, stopped cleanly) | CRASH (any other exception: a bug). "
             "error = max |y − y_ref| over the communication points (y_ref: radau5 or dop853 at rtol 1e-11). "
             "energy drift = max |E − E(0)| / max(|E(0)|, kinetic energy), conservative cases only. "
             "expected: yes / NO / clean failure (an explicit method giving up on a stiff case).", ""]
    crashes = [r for r in rows if r["status"] == "CRASH"]
    lines.append(f"**{len(rows)} runs, {sum(r['status'] == 'completed' for r in rows)} completed, "
                 f"{sum(r['status'] == 'failed' for r in rows)} failed cleanly, "
                 f"{sum(r['status'] == 'budget' for r in rows)} stopped at the budget, {len(crashes)} crashes, "
                 f"{sum(r['expected'] == 'NO' for r in rows)} not as expected.**")
    lines.append("")
    methods = list(dict.fromkeys(r["method"] for r in rows))
    lines += ["## Summary", "", "Error against the reference, or how the run ended (![stress.png](stress.png)).", "",
              "| case | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for case in dict.fromkeys(r["case"] for r in rows):
        cells = {r["method"]: _cell(r)[1] for r in rows if r["case"] == case}
        lines.append(f"| {case} | " + " | ".join(cells.get(m, "") for m in methods) + " |")
    lines.append("")
    for case in dict.fromkeys(r["case"] for r in rows):
        rr = [r for r in rows if r["case"] == case]
        lines += [f"## {case}", "", f"{rr[0]['description']} — {rr[0]['n_comm']} communication steps of "
                  f"{rr[0]['step']:g} s to t = {rr[0]['stop']:g} s.", "",
                  "| method | status | expected | error | energy drift | wall s | steps | rhs evals | message |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for r in rr:
            msg = r["message"].replace("|", "/")
            if r["switched"] is True:
                msg = (msg + " " if msg else "") + "(auto switched to radau5)"
            lines.append(f"| {r['method']} | {r['status']} | {r['expected']} | {_fmt(r['error'])} | "
                         f"{_fmt(r['energy_drift'])} | {r['wall_seconds']:.3f} | {r['steps']} | {r['rhs_evaluations']} | {msg} |")
        lines.append("")
    return "\n".join(lines)


def stress_main(argv=None):
    from ..cli import CommandParser, _need_scene, fresh_folder
    p = CommandParser(prog="mbsfmu stress", description="Numerical stability suite: the built-in stiff and "
                      "extreme cases, or your scenes, × every integration method")
    p.add_argument("scenes", nargs="*", metavar="SCENE",
                   help="scene files (.yaml) or URDFs to stress instead of the built-in cases, each over every method")
    p.add_argument("--out", help="output directory (default: a fresh stress-<time>/ folder here)")
    p.add_argument("--quick", action="store_true", help="shorter runs and fewer methods")
    p.add_argument("--cases", nargs="+", default=None, help="subset of: " + " ".join(c.name for c in cases()))
    p.add_argument("--methods", nargs="+", default=None, help="subset of: " + " ".join(METHODS))
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    if a.scenes and a.cases:
        p.error("--cases chooses among the built-in cases; with scenes, give the scenes only")
    for scene in a.scenes:
        _need_scene(scene)
    a.out = a.out or fresh_folder("stress", a.scenes[0] if len(a.scenes) == 1 else None)
    rows = run(a.out, quick=a.quick, progress=not a.no_progress, only=a.cases, methods=a.methods, scenes=a.scenes)
    bad = [r for r in rows if r["status"] == "CRASH"]
    print(f"{len(rows)} runs → {os.path.join(a.out, 'stress.md')}, stress.csv, stress.png; {len(bad)} crashes")
    return 1 if bad else 0
