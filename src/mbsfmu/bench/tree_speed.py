"""Cost of one right-hand side against the size of the tree (issue 26): mbsfmu's engine beside Pinocchio's `aba`.

(a) Every robot of example-robot-data that is a tree: each URDF loaded as a scene (a floating base for the ones
    that stand, walk or fly, `FLOATING`; `repair` where the plain load refuses an unphysical or massless link,
    as `--repair` would); the ones the scene format refuses by design (`<mimic>`: a closed constraint) are
    listed with their reason. Pinocchio gets the same tree (bench/pinocchio_twin.py, its own free flyer for a
    floating base) and its ÿ is checked against ours at the timed state.
(b) Random revolute chains of N = 10 … 10,000 bodies (random axes, offsets, masses, inertias; gravity), each
    size in a fresh process, so that its peak resident set (RSS) is the size's: the engine's after compiling the
    scene, creating the instance and calling the right-hand side, before Pinocchio is imported. Sizes the
    engine refuses (its workspace) are listed as refused.

Timing: the right-hand side ẋ = f(t, x) through ctypes (`mbs_rhs`) into a preallocated array, against
`pin.aba(model, data, q, v, tau)` on preallocated arrays: both called the same way from Python, in alternating
batches; best and median batch, µs per call; the ratio of the bests. The empty ctypes call (`mbs_time`) is
listed: the part of a small robot's time that is the call from Python. (c) The same right-hand side in a C
loop (bench/rhs_loop.c over the engine library): the engine without Python.

Targets (issue 26): ratio ≤ 1.0 on every robot; chains N = 100 ≤ 1.5, N = 1000 ≤ 2; time at most linear in N
from 100 to 10,000.

    python -m mbsfmu.bench.tree_speed --out reports                 (about 5 minutes)
    python -m mbsfmu.bench.tree_speed --out /tmp/x --sizes 10,30 --robots ur5_robot,solo12 --seconds 0.05
"""

import argparse
import ctypes
import json
import math
import resource
import statistics
import subprocess
import sys
import sysconfig
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from .. import files
from . import output

SIZES = (10, 30, 100, 300, 1000, 3000, 10000)
ROBOTS = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"
# robots that stand, walk or fly get a floating base (the rest are arms, hands, pendulums and wheeled bases)
FLOATING = ("a1_", "alexander_", "anymal_", "b1_", "bolt_", "borinot_", "centauro_", "g1_", "go1_", "go2_", "hector_",
            "hextilt_", "human_", "hyq_", "icub_", "iris_", "laikago_", "quadruped_", "romeo_", "simple_humanoid_",
            "solo_", "talos_data/robots/talos_reduced", "talos_data/robots/talos_full")
RC_SOURCE = Path(__file__).resolve().parent / "rhs_loop.c"
TARGETS = {"robot": 1.0, 100: 1.5, 1000: 2.0}


# ------------------------------------------------------------------------------------------------ scenes
def robot_files():
    """Every URDF of example-robot-data, relative to its robots folder (none when it is not installed)."""
    return sorted(str(p.relative_to(ROBOTS)) for p in ROBOTS.rglob("*.urdf")) if ROBOTS.is_dir() else []


def base_of(file):
    return "free" if file.startswith(FLOATING) else "fixed"


def load_robot(file):
    """(scene, repaired) of a URDF of example-robot-data; repaired (as --repair) only when the plain load refuses.
    ModelError when the scene format refuses it even so (a <mimic> joint: by design)."""
    import mbsfmu
    from ..errors import ModelError

    def load(repair):
        text = f"mbsfmu: 1\nurdf: {{file: {file}, base: {base_of(file)}, repair: {str(repair).lower()}}}\n"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the repairs are reported by the caller
            return mbsfmu.loads(text, base=ROBOTS)
    try:
        return load(False), False
    except ModelError:
        return load(True), True


def chain_scene(n, seed=0):
    """A random revolute chain of n bodies under gravity: random axes, 0.1 m links, masses 0.5–2 kg, physical
    inertias; it starts from random angles and rates (in ±0.5)."""
    import mbsfmu
    rng = np.random.default_rng(seed)
    lines = ["mbsfmu: 1", f"name: chain{n}", "gravity: [0, 0, -9.81]", "bodies:"]
    for i in range(n):
        axis = rng.normal(size=3).round(4).tolist()
        d = rng.uniform(0.01, 0.05, 3).round(4)
        inertia = np.diag([d[1] + d[2], d[0] + d[2], d[0] + d[1]]).tolist()  # a box's: physical
        a, w = rng.uniform(-0.5, 0.5, 2).round(4)
        lines.append(f"  b{i}: {{parent: {'world' if i == 0 else f'b{i - 1}'}, joint: {{type: revolute, axis: {axis}, "
                     f"at: [0, 0, -0.1], initial: {{b{i}.angle: {a}}}, initial_velocity: {{b{i}.angle: {w}}}}}, "
                     f"mass: {rng.uniform(0.5, 2):.4f}, center_of_mass: [0, 0, -0.05], inertia: {inertia}}}")
    return mbsfmu.loads("\n".join(lines))


# ------------------------------------------------------------------------------------------------ calls
class Pair:
    """One scene's right-hand side (mbsfmu, through ctypes into a preallocated array) and Pinocchio's aba on
    the same tree at the same random state, both as no-argument calls; `deviation`: max |ÿ − ÿ_pin| relative."""

    def __init__(self, scene, seed=0):
        import pinocchio as pin

        import mbsfmu
        from ..simulation import Simulation
        from .pinocchio_twin import from_pin_acceleration, pinocchio_model, to_pin
        self.sim = sim = Simulation(scene.spec)
        sim.initialize(0.0)
        ev = mbsfmu.compile(scene)
        rng = np.random.default_rng(seed)
        y, yd = random_state(ev, rng)
        self.x, self.out = np.r_[y, yd], np.empty(sim.engine.n)
        lib, ptr, xp, op = sim.engine.lib, sim.engine.ptr, self.x.ctypes.data, self.out.ctypes.data
        sim.engine.rhs(0.0, self.x, self.out)  # once through the checked path: a failing state raises here
        self.ours = lambda: lib.mbs_rhs(ptr, 0.0, xp, op)
        self.empty = lambda: lib.mbs_time(ptr)
        self.nv = sim.nvel
        model = pinocchio_model(ev, free_flyer=True)
        data = model.createData()
        q, v, _, P = to_pin(ev, y, yd, free_flyer=True)
        tau = joint_dampers(ev, yd, P, model.nv)
        self.theirs = lambda: pin.aba(model, data, q, v, tau)
        ydd = from_pin_acceleration(ev, y, v, self.theirs(), P, free_flyer=True)
        ours = self.out[sim.npos:]
        self.deviation = float(np.max(np.abs(ours - ydd)) / max(1.0, np.max(np.abs(ydd))))


def random_state(ev, rng):
    """Coordinates and velocities uniform in ±1 (quaternions normalized)."""
    y = rng.uniform(-1, 1, len(ev.coordinates))
    for qi in ev.model.quaternions:
        y[qi] /= np.linalg.norm(y[qi])
    return y, rng.uniform(-1, 1, len(ev.velocity_coordinates))


def joint_dampers(ev, yd, P, nv):
    """Pinocchio's τ of the scene's joint spring-dampers at zero deflection (a URDF's joint damping: −d q̇) in
    its velocity order (P from to_pin); other force elements have no twin there."""
    tau = np.zeros(nv)
    vel = ev.velocity_coordinates
    for f in ev.model.spec["forces"]:
        if f["type"] != "joint_spring_damper" or f["stiffness"] or f["offset"]:
            raise NotImplementedError(f"force element {f['type']} in a Pinocchio comparison")
        i = vel.index(f["coordinate"])
        tau[P[i]] -= float(f["damping"]) * yd[i]
    return tau


def batch(fn, calls):
    """Seconds per call of one batch of `calls` calls."""
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - t0) / calls


def alternate(fns, rounds=7, seconds=0.5):
    """{name: (best, median)} µs per call: batches of each function in turn, `rounds` times; each batch about
    seconds / rounds / len(fns) long (at least one call)."""
    calls = {k: max(1, int(seconds / rounds / len(fns) / max(batch(f, 1), 1e-7))) for k, f in fns.items()}
    samples = {k: [] for k in fns}
    for _ in range(rounds):
        for k, f in fns.items():
            samples[k].append(batch(f, calls[k]))
    return {k: (min(s) * 1e6, statistics.median(s) * 1e6) for k, s in samples.items()}


def time_pair(pair, rounds, seconds):
    t = alternate({"mbsfmu": pair.ours, "pinocchio": pair.theirs}, rounds, seconds)
    empty = alternate({"ctypes": pair.empty}, 3, 0.05)["ctypes"][0]
    return {"nv": pair.nv, "mbsfmu_us": t["mbsfmu"][0], "mbsfmu_median_us": t["mbsfmu"][1],
            "pin_us": t["pinocchio"][0], "pin_median_us": t["pinocchio"][1], "ratio": t["mbsfmu"][0] / t["pinocchio"][0],
            "ctypes_us": empty, "deviation": pair.deviation}


# ------------------------------------------------------------------------------------------------ (a) robots
def robots(names=None, rounds=7, seconds=0.5, progress=True):
    """(rows of the timed robots, rows of the refused ones)."""
    from ..errors import ModelError
    todo = [f for f in robot_files() if names is None or Path(f).stem in names]
    rows, refused = [], []
    for file in output.progress(todo, "robots", lambda f: Path(f).stem, progress):
        try:
            scene, repaired = load_robot(file)
        except ModelError as e:
            refused.append({"robot": file, "reason": str(e).split(": ", 1)[-1].split(" (")[0]})
            continue
        pair = Pair(scene)
        row = {"robot": file, "base": base_of(file), "repaired": repaired, **time_pair(pair, rounds, seconds)}
        row["c_us"] = c_loop(pair, row["mbsfmu_us"])
        rows.append(row)
    return rows, refused


# ------------------------------------------------------------------------------------------------ (b) chains
def chain_child(n, rounds, seconds):
    """One chain size, in this (fresh) process: RSS before and after the engine's part, then the timing."""
    rss0 = peak_rss_mb()
    scene = chain_scene(n)
    from ..simulation import Simulation
    try:
        sim = Simulation(scene.spec)
        sim.initialize(0.0)
        x = np.zeros(sim.engine.n)
        sim.engine.rhs(0.0, x)
    except ValueError as e:
        return {"n": n, "refused": str(e)}
    rss = peak_rss_mb()
    del sim
    pair = Pair(scene)
    row = {"n": n, "rss_mb": rss, "rss_python_mb": rss0, **time_pair(pair, rounds, seconds)}
    row["c_us"] = c_loop(pair, row["mbsfmu_us"])
    return row


def peak_rss_mb():
    """Peak resident set of this process in MB: VmHWM (Linux; ru_maxrss would keep the parent's across exec)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def chains(sizes, rounds=7, seconds=0.5, progress=True):
    rows = []
    for n in output.progress(list(sizes), "chains", lambda n: f"N = {n}", progress):
        r = subprocess.run([sys.executable, "-m", "mbsfmu.bench.tree_speed", "--chain", str(n), "--rounds", str(rounds),
                            "--seconds", str(seconds)], capture_output=True, text=True, timeout=3600)
        if r.returncode != 0:
            raise RuntimeError(f"chain of {n}: exit {r.returncode}: {r.stderr[-2000:]}")
        rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
    return rows


# ------------------------------------------------------------------------------------------------ (c) C loop
_C_LOOP = {}


def c_loop(pair, python_us, seconds=0.3):
    """µs per mbs_rhs of the pair's scene and state called in a C loop (rhs_loop.c), best of 5 batches; None
    without a C compiler."""
    from ..engine.build import library_path
    from ..fmu.native import compiler
    if "exe" not in _C_LOOP:
        cc = compiler()
        if cc is None:
            _C_LOOP["exe"] = None
        else:
            _C_LOOP["tmp"] = tmp = tempfile.TemporaryDirectory(prefix="mbsfmu_rhs_loop_")
            exe = Path(tmp.name) / "rhs_loop"
            subprocess.run([cc, "-O2", "-o", str(exe), str(RC_SOURCE), "-ldl"], check=True, capture_output=True, text=True)
            _C_LOOP["exe"] = exe
    if _C_LOOP["exe"] is None:
        return None
    calls = max(1, int(seconds / 5 / max(python_us * 1e-6, 1e-7)))
    with tempfile.TemporaryDirectory(prefix="mbsfmu_rhs_loop_") as d:
        (Path(d) / "scene.bin").write_bytes(pair.sim.blob)
        pair.x.astype("<f8").tofile(Path(d) / "x.bin")
        r = subprocess.run([str(_C_LOOP["exe"]), str(library_path()), str(Path(d) / "scene.bin"), str(Path(d) / "x.bin"),
                            str(calls)], capture_output=True, text=True, timeout=3600)
    if r.returncode != 0:
        raise RuntimeError(f"rhs_loop: exit {r.returncode}: {r.stdout[-500:]} {r.stderr[-500:]}")
    return float(r.stdout.split()[-1])


# ------------------------------------------------------------------------------------------------ report
def slope(rows, lo=100, hi=10000):
    """Growth exponent of the mbsfmu and Pinocchio times between the sizes lo and the largest timed ≤ hi."""
    timed = [r for r in rows if "mbsfmu_us" in r and lo <= r["n"] <= hi]
    if len(timed) < 2:
        return None
    a, b = timed[0], timed[-1]
    k = math.log(b["n"] / a["n"])
    return {"from": a["n"], "to": b["n"], "mbsfmu": math.log(b["mbsfmu_us"] / a["mbsfmu_us"]) / k,
            "pinocchio": math.log(b["pin_us"] / a["pin_us"]) / k}


def plot(robot_rows, chain_rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.5))
    timed = [r for r in chain_rows if "mbsfmu_us" in r]
    if timed:
        n = np.array([r["n"] for r in timed], float)
        for key, label, style in (("mbsfmu_us", "mbsfmu mbs_rhs (from Python)", "o-"), ("c_us", "mbsfmu mbs_rhs (C loop)", "o:"),
                                  ("pin_us", "Pinocchio aba (from Python)", "s-")):
            vals = [r.get(key) for r in timed]
            if all(v is not None for v in vals):
                ax.loglog(n, vals, style, label=label)
        t0 = timed[0]["pin_us"]
        grid = np.geomspace(n[0], max(n[-1], 10000), 20)
        for p, ls in ((1, "--"), (2, "-."), (3, ":")):
            ax.loglog(grid, t0 * (grid / n[0]) ** p, "k" + ls, lw=0.8, alpha=0.5, label=f"∝ N^{p}")
        for r in chain_rows:
            if "refused" in r:
                ax.axvline(r["n"], color="r", lw=0.8, alpha=0.5)
                ax.text(r["n"], ax.get_ylim()[0] * 2, f" N = {r['n']} refused", color="r", rotation=90, fontsize=7, va="bottom")
        ax.set_ylim(top=max(max(r["mbsfmu_us"] for r in timed), t0) * 3)
    ax.set_xlabel("bodies in the chain (N)")
    ax.set_ylabel("µs per right-hand side")
    ax.set_title("Random revolute chains")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    if robot_rows:
        nv = [r["nv"] for r in robot_rows]
        bx.loglog(nv, [r["mbsfmu_us"] for r in robot_rows], "o", label="mbsfmu mbs_rhs (from Python)")
        bx.loglog(nv, [r["pin_us"] for r in robot_rows], "s", mfc="none", label="Pinocchio aba (from Python)")
        bx.set_xlabel("degrees of freedom")
        bx.set_title("example-robot-data robots")
        bx.grid(True, which="both", alpha=0.3)
        bx.legend(fontsize=7)
    fig.tight_layout()
    output.save_figure(fig, path, dpi=120)


def markdown(robot_rows, refused, chain_rows, cmd):
    def met(ok):
        return "met" if ok else "NOT met"
    lines = ["# Right-hand side against the size of the tree: mbsfmu and Pinocchio's aba", "",
             f"Generated by `{cmd}` (Pinocchio {_pin_version()}). One right-hand side of the engine (`mbs_rhs` through "
             "ctypes into a preallocated array: ẏ and ÿ) against `pin.aba(model, data, q, v, tau)` on preallocated "
             "arrays, both from Python, alternating batches; best and median batch. C loop: the same `mbs_rhs` "
             "called from C (bench/rhs_loop.c), best of 5 batches. Empty ctypes call: `mbs_time`, the floor of a "
             "call from Python. Deviation: max |ÿ − ÿ_Pinocchio| / max(1, |ÿ_Pinocchio|) at the timed state "
             "(the same tree, bench/pinocchio_twin.py).", "", "![time against size](tree_speed.png)", ""]
    if chain_rows:
        lines += ["## Random revolute chains", "",
                  "Each size in a fresh process. RSS: peak resident set after compiling the scene, creating the "
                  "instance and one right-hand side (Pinocchio not yet imported); the Python process with numpy "
                  "and mbsfmu loaded is the first number.", "",
                  "| N | mbsfmu µs (median) | Pinocchio aba µs (median) | ratio | mbsfmu C loop µs | empty ctypes call µs | "
                  "RSS MB (Python alone) | deviation |", "|---|---|---|---|---|---|---|---|"]
        for r in chain_rows:
            if "refused" in r:
                lines.append(f"| {r['n']} | refused by the engine: {r['refused']} | | | | | | |")
                continue
            lines.append(f"| {r['n']} | {r['mbsfmu_us']:.4g} ({r['mbsfmu_median_us']:.4g}) | {r['pin_us']:.4g} "
                         f"({r['pin_median_us']:.4g}) | {r['ratio']:.2f} | {_num(r.get('c_us'))} | {r['ctypes_us']:.2f} | "
                         f"{r['rss_mb']:.0f} ({r['rss_python_mb']:.0f}) | {r['deviation']:.1e} |")
        by_n = {r["n"]: r for r in chain_rows if "ratio" in r}
        s = slope(chain_rows)
        lines += [""] + [f"Target N = {n}: ratio ≤ {TARGETS[n]} → " + (f"{by_n[n]['ratio']:.2f} ({met(by_n[n]['ratio'] <= TARGETS[n])})"
                                                                      if n in by_n else "not timed") + "." for n in (100, 1000)]
        if s:
            lines.append(f"Growth from N = {s['from']} to {s['to']}: mbsfmu ∝ N^{s['mbsfmu']:.2f}, Pinocchio ∝ "
                         f"N^{s['pinocchio']:.2f} (target: at most linear up to N = 10,000"
                         + (", which the engine refuses today" if any("refused" in r for r in chain_rows) else "") + ").")
    if robot_rows:
        worst = max(robot_rows, key=lambda r: r["ratio"])
        lines += ["", "## example-robot-data robots", "",
                  "Floating base: the ones that stand, walk or fly (their free joint is Pinocchio's free flyer). "
                  "Repaired: loaded with `repair` (`--repair`) because the plain load refuses an unphysical or "
                  "massless link.", "",
                  "| robot | base | dof | mbsfmu µs (median) | Pinocchio aba µs (median) | ratio | mbsfmu C loop µs | "
                  "empty ctypes call µs | deviation |", "|---|---|---|---|---|---|---|---|---|"]
        for r in sorted(robot_rows, key=lambda r: (r["nv"], r["robot"])):
            lines.append(f"| {r['robot']}{' (repaired)' if r['repaired'] else ''} | {r['base']} | {r['nv']} | "
                         f"{r['mbsfmu_us']:.3g} ({r['mbsfmu_median_us']:.3g}) | {r['pin_us']:.3g} ({r['pin_median_us']:.3g}) | "
                         f"{r['ratio']:.2f} | {_num(r.get('c_us'))} | {r['ctypes_us']:.2f} | {r['deviation']:.1e} |")
        met_all = sum(r["ratio"] <= TARGETS["robot"] for r in robot_rows)
        lines += ["", f"Target: ratio ≤ {TARGETS['robot']} on every robot → met on {met_all} of {len(robot_rows)}; "
                  f"worst {worst['robot']} ({worst['nv']} dof) {worst['ratio']:.2f}."]
    if refused:
        lines += ["", "Refused by the scene format (not trees of independent joints, or not robots):", ""]
        lines += [f"- {r['robot']}: {r['reason']}" for r in refused]
    return "\n".join(lines) + "\n"


def _num(x):
    return "–" if x is None else f"{x:.4g}"


def _pin_version():
    import pinocchio as pin
    return pin.__version__


def main(argv=None):
    ap = argparse.ArgumentParser(prog="mbsfmu.bench.tree_speed", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="reports", help="folder for tree_speed.md, tree_speed_*.csv and tree_speed.png")
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)), help="chain sizes (comma list; empty: none)")
    ap.add_argument("--robots", default=None, help="URDF stems to time (comma list; default: all; 'none': none)")
    ap.add_argument("--rounds", type=int, default=7, help="alternating batches per function")
    ap.add_argument("--seconds", type=float, default=0.5, help="timed seconds per case, all batches together")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    ap.add_argument("--chain", type=int, help=argparse.SUPPRESS)  # one chain size in this process: JSON on stdout
    a = ap.parse_args(argv)
    if a.chain is not None:
        print(json.dumps(chain_child(a.chain, a.rounds, a.seconds)))
        return None
    names = None if a.robots is None else ([] if a.robots == "none" else a.robots.split(","))
    sizes = [int(n) for n in a.sizes.split(",") if n]
    robot_rows, refused = robots(names, a.rounds, a.seconds, not a.quiet) if names != [] else ([], [])
    chain_rows = chains(sizes, a.rounds, a.seconds, not a.quiet)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    cmd = "python -m mbsfmu.bench.tree_speed " + " ".join(argv if argv is not None else sys.argv[1:])
    if robot_rows:
        output.write_csv(robot_rows, out / "tree_speed_robots.csv", list(robot_rows[0]), 4)
    timed = [r for r in chain_rows if "mbsfmu_us" in r]
    if timed:
        output.write_csv(timed, out / "tree_speed_chains.csv", list(timed[0]), 4)
    plot(robot_rows, chain_rows, out / "tree_speed.png")
    md = out / "tree_speed.md"
    files.write_text(md, markdown(robot_rows, refused, chain_rows, cmd.strip()))
    print(md)
    return robot_rows, refused, chain_rows


if __name__ == "__main__":
    main()
