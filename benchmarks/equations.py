"""Cost of one evaluation of the equations: mbsfmu (C engine and numpy reference) vs Pinocchio crba + nonLinearEffects,
plus a full fmpy run of the built FMU versus the same run in process (when build_fmu works).
"""

import math
import os
import tempfile
import time

import numpy as np

from mbsfmu import files


def _time_per_call(fn, args_list, min_time=0.5):
    """Best-of-3 mean µs per call over the argument list (repeated until ≥ min_time/3 per trial)."""
    best = math.inf
    for _ in range(3):
        n, t0 = 0, time.perf_counter()
        while True:
            for a in args_list:
                fn(*a)
            n += len(args_list)
            el = time.perf_counter() - t0
            if el > min_time / 3:
                break
        best = min(best, el / n)
    return best * 1e6


def benchmark_equations(scene_path, out_dir=None, n_states=20, fmu=True, stop=None):
    """Time Evaluator.equations, the engine (equations, Simulation.f) and Pinocchio crba+nonLinearEffects on random states; fmpy run."""
    import mbsfmu
    from mbsfmu.simulation import Simulation
    scene = mbsfmu.load(scene_path)
    spec = scene.spec
    ev = mbsfmu.compile(scene)
    rng = np.random.default_rng(0)
    y0, yd0 = ev.initial_state()
    states = []
    for _ in range(n_states):
        y = y0 + rng.normal(size=y0.size) * 0.5
        if ev.model.quaternions:
            for qi in ev.model.quaternions:
                y[qi] /= np.linalg.norm(y[qi])
        states.append((y, rng.normal(size=yd0.size), 0.0))
    res = {"scene": spec["name"], "n": int(yd0.size), "notes": []}
    res["mbsfmu_equations_us"] = _time_per_call(ev.equations, states)  # numpy reference path (tree.py)
    sim = Simulation(spec)
    sim.initialize(0.0)
    eng = sim.engine
    res["mbsfmu_native_us"] = _time_per_call(lambda y, yd, t: eng.equations(t, np.concatenate([y, yd])), states)
    xs = [(0.0, np.concatenate([y, yd])) for y, yd, _ in states]
    res["mbsfmu_rhs_us"] = _time_per_call(sim.f, xs)
    try:
        import pinocchio as pin

        from pinocchio_twin import pinocchio_model, to_pin
        model = pinocchio_model(ev)
        data = model.createData()
        pstates = [to_pin(ev, y, yd)[:2] for y, yd, _ in states]

        def pin_eq(q, v):
            pin.crba(model, data, q)
            pin.nonLinearEffects(model, data, q, v)

        def pin_aba(q, v):
            pin.aba(model, data, q, v, np.zeros(model.nv))

        res["pinocchio_us"] = _time_per_call(pin_eq, pstates)
        res["pinocchio_aba_us"] = _time_per_call(pin_aba, pstates)
        # same model? compare M and k − q (no inputs, no force elements assumed)
        dev = 0.0
        for (y, yd, t), (q, v) in zip(states, pstates):
            M, k, qq = ev.equations(y, yd, t)
            Mp = pin.crba(model, data, q)
            Mp = np.triu(Mp) + np.triu(Mp, 1).T
            nle = pin.nonLinearEffects(model, data, q, v)
            dev = max(dev, float(np.max(np.abs(M - Mp))), float(np.max(np.abs((k - qq) - nle))))
        res["pinocchio_max_deviation"] = dev
    except Exception as e:  # noqa: BLE001
        res["notes"].append(f"Pinocchio skipped: {type(e).__name__}: {e}")
    if fmu:
        res.update(_fmu_run(scene_path, spec, stop, res["notes"]))
    if out_dir is not None:
        os.makedirs(out_dir, exist_ok=True)
        files.write_text(os.path.join(out_dir, "equations.md"), markdown(res))
    return res


def _fmu_run(scene_path, spec, stop, notes):
    """Build the FMU, run it with fmpy and in process with the same settings; CPU seconds of both."""
    out = {}
    try:
        import fmpy
        import mbsfmu
        from mbsfmu.simulation import simulate
    except Exception as e:  # noqa: BLE001
        notes.append(f"fmpy run skipped: {e}")
        return out
    e = spec["experiment"]
    stop = e["stop"] if stop is None else stop
    try:
        with tempfile.TemporaryDirectory() as d:
            path = mbsfmu.build_fmu(scene_path, d)
            c0 = time.process_time()
            w0 = time.perf_counter()
            r = fmpy.simulate_fmu(path, start_time=e["start"], stop_time=stop, output_interval=e["step"],
                                  step_size=e["step"], fmi_type="CoSimulation")
            out["fmpy_wall_s"] = time.perf_counter() - w0
            out["fmpy_cpu_s"] = time.process_time() - c0
            c0 = time.process_time()
            ts, Y, _ = simulate(spec, stop=stop)
            out["inprocess_cpu_s"] = time.process_time() - c0
            name = f"y.{mbsfmu.compile(spec).coordinates[0]}"
            out["fmpy_vs_inprocess_max_diff"] = float(np.max(np.abs(np.interp(ts, r["time"], r[name]) - Y[:, 0])))
            out["fmu_steps"] = len(ts) - 1
            out["fmu_stop"] = stop
    except Exception as ex:  # noqa: BLE001
        notes.append(f"fmpy run skipped: {type(ex).__name__}: {ex}")
    return out


def markdown(r):
    L = [f"# Cost of the equations: {r['scene']} ({r['n']} degrees of freedom)", "",
         "µs per call, best of 3 trials over 20 random states, same process (`time.perf_counter`).", "",
         "| what | µs per call | ratio to Pinocchio crba+nle |", "|---|---|---|"]
    p = r.get("pinocchio_us")

    def ratio(x):
        return f"{x / p:.1f}" if p else "—"
    if "mbsfmu_native_us" in r:
        L.append(f"| mbsfmu engine `mbs_equations` (M, k, q; from Python: ctypes call and three numpy arrays per call included) | {r['mbsfmu_native_us']:.1f} | {ratio(r['mbsfmu_native_us'])} |")
    L.append(f"| mbsfmu engine right-hand side `Simulation.f` (equations + Cholesky solve of M ÿ = q − k; from Python) | {r['mbsfmu_rhs_us']:.1f} | {ratio(r['mbsfmu_rhs_us'])} |")
    L.append(f"| mbsfmu numpy reference path `Evaluator.equations` (tree.py) | {r['mbsfmu_equations_us']:.1f} | {ratio(r['mbsfmu_equations_us'])} |")
    if p:
        L.append(f"| Pinocchio `crba` + `nonLinearEffects` (Python bindings, C++) | {p:.1f} | 1.0 |")
        L.append(f"| Pinocchio `aba` (forward dynamics) | {r['pinocchio_aba_us']:.1f} | {ratio(r['pinocchio_aba_us'])} |")
        L += ["", f"Same model check: max |M − M_pin|, |(k − q) − nle_pin| over the states = "
              f"{r['pinocchio_max_deviation']:.2e}."]
    if "fmpy_cpu_s" in r:
        L += ["", f"## Full FMU run ({r['fmu_steps']} communication steps to t = {r['fmu_stop']:g} s, scene integrator)", "",
              "| run | CPU s |", "|---|---|",
              f"| fmpy `simulate_fmu` of the built FMU | {r['fmpy_cpu_s']:.3f} (wall {r['fmpy_wall_s']:.3f}) |",
              f"| in process `mbsfmu.simulation.simulate` | {r['inprocess_cpu_s']:.3f} |", "",
              f"Max difference of the first coordinate, FMU vs in process: {r['fmpy_vs_inprocess_max_diff']:.2e}."]
    if r["notes"]:
        L += ["", "## Notes", ""] + [f"- {n}" for n in r["notes"]]
    return "\n".join(L) + "\n"
