"""Cost of one right-hand side against the size of the tree (issue 26): mbsfmu's engine beside Pinocchio's `aba`.

(a) Every robot of example-robot-data that is a tree: each URDF loaded as a scene (a floating base for the ones
    that stand, walk or fly, `FLOATING`; `repair` where the plain load refuses an unphysical or massless link,
    as `--repair` would); the ones the scene format refuses by design (`<mimic>`: a closed constraint) are
    listed with their reason. Pinocchio gets the same tree (tests/pinocchio_twin.py, its own free flyer for a
    floating base) and its ÿ is checked against ours at the timed states.
(b) Random revolute chains of N = 10 … 10,000 bodies (random axes, offsets, masses, inertias; gravity), each
    size in a fresh process, so that its peak resident set (RSS) is the size's: the engine's while compiling the
    loaded scene, creating the instance and calling the right-hand side, before any peer is loaded. Sizes the
    engine refuses (its workspace) are listed as refused. Peers: Pinocchio up to PIN_MAX_CHAIN bodies (its Data
    grows as N³) and MuJoCo's mj_forward (`mujoco_model`) up to MUJOCO_MAX_CHAIN.

Timing: the right-hand side ẋ = f(t, x) by the public call `Instance.rhs(t, x, out)` into a preallocated array
(engine/fastcall.c, else ctypes), against `pin.aba(model, data, q, v, tau)` on preallocated arrays: both called the
same way from Python, each with its arrays, in alternating
batches; best and median batch, µs per call; the ratio of the bests. Every call is at the next of STATES distinct
random states, the same for every peer (Pair): the engine keeps its kinematics while the state's bits stay the
same, so one state would time that cache against Pinocchio's full aba. The empty ctypes call (`mbs_time`) is
listed: the part of a small robot's time that is the call from Python. (c) The same right-hand side in a C
loop (benchmarks/rhs_loop.c over the engine library): the engine without Python.

Targets (issue 26): ratio ≤ 1.0 on every robot; chains N = 100 ≤ 1.5, N = 1000 ≤ 2; time at most linear in N
from 100 to 10,000.

    python -m benchmarks.tree_speed --out reports                 (about 20 minutes: N = 3000 takes most)
    python -m benchmarks.tree_speed --out /tmp/x --sizes 10,30 --robots ur5_robot,solo12 --seconds 0.05
"""

import argparse
import itertools
import json
import math
import statistics
import subprocess
import sys
import sysconfig
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from mbsfmu import files
from mbsfmu.reports import output

SIZES = (10, 30, 100, 300, 1000, 3000, 10000)
ROBOTS = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"
# robots that stand, walk or fly get a floating base (the rest are arms, hands, pendulums and wheeled bases)
FLOATING = ("a1_", "alexander_", "anymal_", "b1_", "bolt_", "borinot_", "centauro_", "g1_", "go1_", "go2_", "hector_",
            "hextilt_", "human_", "hyq_", "icub_", "iris_", "laikago_", "quadruped_", "romeo_", "simple_humanoid_",
            "solo_", "talos_data/robots/talos_reduced", "talos_data/robots/talos_full")
RC_SOURCE = Path(__file__).resolve().parent / "rhs_loop.c"
TARGETS = {"robot": 1.0, 100: 1.5, 1000: 2.0}
# Pinocchio 4.1's Data of an N-body chain grows as N³ (measured: 0.07, 0.5, 4 GB at N = 100, 200, 400): no
# Pinocchio beyond this size (1000 bodies would take about 60 GB)
PIN_MAX_CHAIN = 300
# distinct random states every timed call cycles through, the same for every peer (Pair)
STATES = 64
# MuJoCo's share of them: one MjData each (28 MB at N = 1000)
MUJOCO_STATES = 4
# MuJoCo's compiled chain grows as N² (its dense M): no MuJoCo beyond this size (10,000 bodies: 5 GB, minutes)
MUJOCO_MAX_CHAIN = 3000


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
    from mbsfmu.errors import ModelError

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
    inertias; it starts at rest from random angles (in ±0.5). Few numbers per body: a scene holds at most
    400,000 (limits.py), and 10,000 bodies must fit."""
    import mbsfmu
    rng = np.random.default_rng(seed)
    lines = ["mbsfmu: 1", f"name: chain{n}", "gravity: [0, 0, -9.81]", "bodies:"]
    for i in range(n):
        axis = rng.normal(size=3).round(4).tolist()
        d = rng.uniform(0.01, 0.05, 3).round(4)  # a box's moments: physical
        inertia = f"{{xx: {d[1] + d[2]:.4f}, yy: {d[0] + d[2]:.4f}, zz: {d[0] + d[1]:.4f}}}"
        lines.append(f"  b{i}: {{parent: {'world' if i == 0 else f'b{i - 1}'}, joint: {{type: revolute, axis: {axis}, "
                     f"at: [0, 0, -0.1], initial: {{b{i}.angle: {rng.uniform(-0.5, 0.5):.4f}}}}}, "
                     f"mass: {rng.uniform(0.5, 2):.4f}, center_of_mass: [0, 0, -0.05], inertia: {inertia}}}")
    return mbsfmu.loads("\n".join(lines))


# ------------------------------------------------------------------------------------------------ calls
class Pair:
    """One scene's right-hand side (mbsfmu: `Instance.rhs` into a preallocated array) as a no-argument call that
    cycles through `states` distinct random states, and its peers on the same tree cycling through the same
    states (add_pinocchio, add_mujoco): `calls` {name: call}, `deviations` {peer: max over the states of
    max |ÿ − ÿ_peer| / max(1, |ÿ_peer|)}. Distinct states because the engine keeps its kinematics while t and
    x's bits stay the same (sim.c: kinematics): at one state every timed call after the first would skip them,
    while pin.aba recomputes everything."""

    def __init__(self, scene, seed=0, states=STATES):
        import mbsfmu
        self.sim = sim = engine_of(scene)
        self.ev = mbsfmu.compile(scene)
        rng = np.random.default_rng(seed)
        self.states = [random_state(self.ev, rng) for _ in range(states)]
        self.X = np.array([np.r_[y, yd] for y, yd in self.states])  # one state [y; ẏ] a row
        self.out = np.empty(sim.engine.n)
        self.ydd = []
        for x in self.X:  # through the checked path: a failing state raises here
            sim.engine.rhs(0.0, x, self.out)
            self.ydd.append(self.out[sim.npos:].copy())
        lib, ptr = sim.engine.lib, sim.engine.ptr
        self.calls = {"mbsfmu": cycling(sim.engine.rhs, [(0.0, x, self.out) for x in self.X])}
        self.empty = lambda: lib.mbs_time(ptr)
        self.nv = sim.nvel
        self.deviations = {}

    def add_pinocchio(self):
        """pin.aba(model, data, q, v, tau) on preallocated arrays, one (q, v, tau) a state (a floating base as
        Pinocchio's free flyer, the URDF's joint damping as tau); the MB its model and data add to the peak
        resident set."""
        import pinocchio as pin

        from pinocchio_twin import from_pin_acceleration, pinocchio_model, to_pin
        ev, before = self.ev, rss_mb()
        reset_peak_rss()
        model = pinocchio_model(ev, free_flyer=True)
        data = model.createData()
        mb = peak_rss_mb() - before
        args, dev = [], 0.0
        for (y, yd), ydd in zip(self.states, self.ydd):
            q, v, _, P = to_pin(ev, y, yd, free_flyer=True)
            tau = joint_dampers(ev, yd, P, model.nv)
            args.append((model, data, q, v, tau))
            a = pin.aba(model, data, q, v, tau)
            dev = max(dev, _deviation(ydd, from_pin_acceleration(ev, y, v, a, P, free_flyer=True)))
        self.calls["pinocchio"] = cycling(pin.aba, args)
        self.deviations["pinocchio"] = dev
        return mb

    def add_mujoco(self):
        """MuJoCo's mj_forward (contacts and constraints off: forward dynamics only) on the same tree, cycling
        through the first MUJOCO_STATES states, each in its own MjData (mj_forward reads the state from its
        data: copying it in from Python would cost more than a small tree's forward dynamics); else the reason:
        not installed, not mapped (mujoco_model), refused by MuJoCo's compiler (trees deeper than 1024 bodies)."""
        try:
            import mujoco
            M = mujoco_model(self.ev)
        except (ImportError, NotImplementedError, ValueError) as e:
            return f"{type(e).__name__}: {e}".splitlines()[0]
        datas, dev = [], 0.0
        for (y, yd), ydd in list(zip(self.states, self.ydd))[:MUJOCO_STATES]:
            D = mujoco.MjData(M)
            D.qpos[:], D.qvel[:] = y, yd
            mujoco.mj_forward(M, D)
            dev = max(dev, _deviation(ydd, D.qacc))
            datas.append((M, D))
        self.calls["mujoco"] = cycling(mujoco.mj_forward, datas)
        self.deviations["mujoco"] = dev
        return None


def cycling(fn, args):
    """A no-argument call of fn on each of the argument tuples in turn: the same cycling cost for every peer."""
    it = itertools.cycle(args)
    return lambda: fn(*next(it))


_MUJOCO_OFF = ("CONTACT", "CONSTRAINT", "LIMIT", "EQUALITY", "FRICTIONLOSS", "SPRING", "DAMPER", "ACTUATION",
               "WARMSTART", "SENSOR")


def mujoco_model(ev):
    """MuJoCo's model of a tree of hinges without joint rotations, drives or force elements (the chains),
    built through MjSpec, not MJCF text: MuJoCo's XML reader refuses bodies nested deeper than about 500. The
    same masses, centres of mass, inertias and gravity; contacts, constraints and the rest off, as the MJCF of
    benchmarks/fmu_peers.py has them."""
    import mujoco
    if ev.model.spec["forces"]:
        raise NotImplementedError("force elements")
    spec = mujoco.MjSpec()
    spec.option.gravity = ev.model.g if ev.model.g is not None else np.zeros(3)
    for flag in _MUJOCO_OFF:
        spec.option.disableflags |= getattr(mujoco.mjtDisableBit, f"mjDSBL_{flag}")
    bodies = {-1: spec.worldbody}
    for i, b in enumerate(ev.model.bodies):
        if b.kind != "revolute" or b.R0 is not None or b.elastic or any(b.driven):
            raise NotImplementedError(f"body '{b.name}' ({b.kind})")
        I = np.asarray(b.I, float)
        bodies[i] = body = bodies[b.parent].add_body(
            pos=b.at if b.at is not None else np.zeros(3), mass=b.m, explicitinertial=True,
            ipos=b.c if b.c is not None else np.zeros(3), fullinertia=[I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])
        body.add_joint(type=mujoco.mjtJoint.mjJNT_HINGE, axis=b.joint.a)
    return spec.compile()


def engine_of(scene):
    """The scene's engine instance, initialized with an explicit integrator (the right-hand side does not
    depend on it; auto's radau5 workspace is refused for thousands of states)."""
    from mbsfmu.simulation import Simulation
    sim = Simulation(scene.spec)
    sim.set("integrator.method", "dopri5")
    sim.initialize(0.0)
    return sim


def _deviation(ours, theirs):
    return float(np.max(np.abs(ours - theirs)) / max(1.0, np.max(np.abs(theirs))))


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
    """Row of µs per call: `<name>_us` (best batch) and `<name>_median_us` of every call of the pair, alternating;
    `ratio_<peer>` = mbsfmu's best / the peer's; deviations; the empty ctypes call."""
    t = alternate(pair.calls, rounds, seconds * len(pair.calls) / 2)
    row = {"nv": pair.nv, "ctypes_us": alternate({"ctypes": pair.empty}, 3, 0.05)["ctypes"][0]}
    for name, (best, median) in t.items():
        row[f"{name}_us"], row[f"{name}_median_us"] = best, median
    for peer, dev in pair.deviations.items():
        row[f"ratio_{peer}"], row[f"deviation_{peer}"] = t["mbsfmu"][0] / t[peer][0], dev
    return row


# ------------------------------------------------------------------------------------------------ (a) robots
def robots(names=None, rounds=7, seconds=0.5, progress=True):
    """(rows of the timed robots, rows of the refused ones)."""
    from mbsfmu.errors import ModelError
    todo = [f for f in robot_files() if names is None or Path(f).stem in names]
    rows, refused = [], []
    for file in output.progress(todo, "robots", lambda f: Path(f).stem, progress):
        try:
            scene, repaired = load_robot(file)
        except ModelError as e:
            refused.append({"robot": file, "reason": str(e).split(": ", 1)[-1].split(" (")[0]})
            continue
        pair = Pair(scene)
        pair.add_pinocchio()
        row = {"robot": file, "base": base_of(file), "repaired": repaired, **time_pair(pair, rounds, seconds)}
        row["c_us"] = c_loop(pair, row["mbsfmu_us"])
        rows.append(row)
    return rows, refused


# ------------------------------------------------------------------------------------------------ (b) chains
def chain_child(n, rounds, seconds):
    """One chain size, in this (fresh) process: the engine's peak resident set (compiling the loaded scene,
    creating the instance, one right-hand side) over the process before, then the timing."""
    scene = chain_scene(n)
    rss0 = rss_mb()
    reset_peak_rss()  # the loader's own peak (Python objects of the scene) is not the engine's
    try:
        sim = engine_of(scene)
        sim.engine.rhs(0.0, np.zeros(sim.engine.n))
    except ValueError as e:
        return {"n": n, "refused": str(e)}
    row = {"n": n, "rss_mb": peak_rss_mb(), "rss_python_mb": rss0}
    del sim
    pair = Pair(scene)
    if n <= PIN_MAX_CHAIN:
        row["pin_data_mb"] = pair.add_pinocchio()
    why = pair.add_mujoco() if n <= MUJOCO_MAX_CHAIN else f"more than MUJOCO_MAX_CHAIN = {MUJOCO_MAX_CHAIN} bodies"
    if why:
        row["mujoco_refused"] = why
    row.update(time_pair(pair, rounds, seconds))
    row["c_us"] = c_loop(pair, row["mbsfmu_us"])
    return row


def peak_rss_mb():
    """Peak resident set of this process in MB since it started or since reset_peak_rss: VmHWM (Linux;
    ru_maxrss would keep the parent's across exec)."""
    return _status_mb("VmHWM")


def rss_mb():
    return _status_mb("VmRSS")


def reset_peak_rss():
    """Start the peak resident set afresh from the current one (Linux ≥ 4.0: /proc/self/clear_refs)."""
    Path("/proc/self/clear_refs").write_text("5")


def _status_mb(key):
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    raise OSError(f"no {key} in /proc/self/status")


def chains(sizes, rounds=7, seconds=0.5, progress=True):
    rows = []
    for n in output.progress(list(sizes), "chains", lambda n: f"N = {n}", progress):
        r = subprocess.run([sys.executable, "-m", "benchmarks.tree_speed", "--chain", str(n), "--rounds", str(rounds),
                            "--seconds", str(seconds)], capture_output=True, text=True, timeout=3600,
                           cwd=Path(__file__).resolve().parents[1])  # benchmarks/ is the repository's, not installed
        if r.returncode != 0:  # reported in its row: the other sizes still count
            last = (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1]
            rows.append({"n": n, "failed": last})
            continue
        rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
    return rows


# ------------------------------------------------------------------------------------------------ (c) C loop
_C_LOOP = {}


def c_loop(pair, python_us, seconds=0.3, batch=2e-3, column=False):
    """µs per mbs_rhs of the pair's scene called in a C loop (rhs_loop.c) on its states in turn: the best of batches
    of about `batch` seconds (at least one call) over `seconds`; None without a C compiler. column: (µs per rhs,
    µs per directional derivative column), batches alternating (benchmarks/directional_cost.py)."""
    from mbsfmu.engine.build import library_path
    from mbsfmu.fmu.native import compiler
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
    calls = max(1, int(batch / (python_us * 1e-6)))
    batches = max(5, int(seconds / (calls * python_us * 1e-6)))
    with tempfile.TemporaryDirectory(prefix="mbsfmu_rhs_loop_") as d:
        (Path(d) / "scene.bin").write_bytes(pair.sim.blob)
        pair.X.astype("<f8").tofile(Path(d) / "x.bin")
        r = subprocess.run([str(_C_LOOP["exe"]), str(library_path()), str(Path(d) / "scene.bin"), str(Path(d) / "x.bin"),
                            str(calls), str(batches), *(["column"] if column else [])], capture_output=True, text=True,
                           timeout=3600)
    if r.returncode != 0:
        raise RuntimeError(f"rhs_loop: exit {r.returncode}: {r.stdout[-500:]} {r.stderr[-500:]}")
    words = r.stdout.split()
    return (float(words[1]), float(words[3])) if column else float(words[-1])


# ------------------------------------------------------------------------------------------------ report
PEERS = {"pinocchio": "Pinocchio aba", "mujoco": "MuJoCo mj_forward"}


def slope(rows, lo=100, hi=10000):
    """{name: growth exponent of its time from size lo to the largest size ≤ hi it was timed at, (lo, that)}."""
    out = {}
    for name in ("mbsfmu", *PEERS):
        timed = [r for r in rows if f"{name}_us" in r and lo <= r["n"] <= hi]
        if len(timed) >= 2:
            a, b = timed[0], timed[-1]
            out[name] = (math.log(b[f"{name}_us"] / a[f"{name}_us"]) / math.log(b["n"] / a["n"]), (a["n"], b["n"]))
    return out


def plot(robot_rows, chain_rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.5))
    timed = [r for r in chain_rows if "mbsfmu_us" in r]
    curves = (("mbsfmu_us", "mbsfmu mbs_rhs (from Python)", "o-"), ("c_us", "mbsfmu mbs_rhs (C loop)", "o:"),
              ("pinocchio_us", "Pinocchio aba (from Python)", "s-"), ("mujoco_us", "MuJoCo mj_forward (from Python)", "^-"))
    for key, label, style in curves:
        pts = [(r["n"], r[key]) for r in timed if r.get(key) is not None]
        if pts:
            ax.loglog(*zip(*pts), style, label=label)
    if timed:
        n0, t0 = timed[0]["n"], timed[0]["mbsfmu_us"]
        grid = np.geomspace(n0, 10000, 20)
        for p, ls in ((1, "--"), (2, "-."), (3, ":")):
            ax.loglog(grid, t0 * (grid / n0) ** p, "k" + ls, lw=0.8, alpha=0.4, label=f"∝ N^{p}")
        ax.set_ylim(min(r["ctypes_us"] for r in timed), max(r["mbsfmu_us"] for r in timed) * 5)
    for r in chain_rows:
        if "refused" in r:
            ax.axvline(r["n"], color="r", lw=0.8, alpha=0.5)
            ax.annotate(f"N = {r['n']}: refused", (r["n"], 0.05), xycoords=("data", "axes fraction"), color="r",
                        rotation=90, fontsize=7, ha="right")
    ax.set_xlabel("bodies in the chain (N)")
    ax.set_ylabel("µs per right-hand side")
    ax.set_title("Random revolute chains")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    if robot_rows:
        nv = [r["nv"] for r in robot_rows]
        bx.loglog(nv, [r["mbsfmu_us"] for r in robot_rows], "o", label="mbsfmu mbs_rhs (from Python)")
        bx.loglog(nv, [r["pinocchio_us"] for r in robot_rows], "s", mfc="none", label="Pinocchio aba (from Python)")
        bx.set_xlabel("degrees of freedom")
        bx.set_title("example-robot-data robots")
        bx.grid(True, which="both", alpha=0.3)
        bx.legend(fontsize=7)
    fig.tight_layout()
    output.save_figure(fig, path, dpi=120)


def _peer(r, name, digits=4):
    """'best (median) | ratio | deviation' of a peer in a row, or dashes."""
    if f"{name}_us" not in r:
        return "– | – | –"
    return (f"{r[f'{name}_us']:.{digits}g} ({r[f'{name}_median_us']:.{digits}g}) | {r[f'ratio_{name}']:.2f} | "
            f"{r[f'deviation_{name}']:.0e}")


def markdown(robot_rows, refused, chain_rows, cmd):
    def met(ok):
        return "met" if ok else "NOT met"
    lines = ["# Right-hand side against the size of the tree: mbsfmu, Pinocchio's aba, MuJoCo", "",
             f"Generated by `{cmd}` (Pinocchio {_version('pinocchio')}, MuJoCo {_version('mujoco')}). One right-hand "
             "side of the engine (`Instance.rhs(t, x, out)` into a preallocated array: ẏ and ÿ) against "
             "`pin.aba(model, data, q, v, tau)` on preallocated arrays and MuJoCo's `mj_forward` (contacts and "
             "constraints off), all from Python, alternating batches; best and median batch; ratio = mbsfmu's best / "
             f"the peer's best. The states vary per call: each call is at the next of {STATES} distinct random "
             f"states, the same for every peer (MuJoCo: the first {MUJOCO_STATES}, one `MjData` each), so the "
             "engine's kinematics, kept while the state's bits stay the same, run on every call. C loop: the same "
             "`mbs_rhs` on the same states called from C (benchmarks/rhs_loop.c), best of batches of about 2 ms. Empty "
             "ctypes call: `mbs_time`, the floor of a call from Python. Deviation: max |ÿ − ÿ_peer| / max(1, |ÿ_peer|) "
             "over the timed states (the same tree: tests/pinocchio_twin.py, `mujoco_model`). Timed on a "
             "shared 2-core machine: the best batch is the cost, the medians show the load.", "",
             "![time against size](tree_speed.png)", ""]
    if chain_rows:
        lines += ["## Random revolute chains", "",
                  "Each size in a fresh process. RSS: peak resident set while compiling the loaded scene, creating "
                  "the instance and calling the right-hand side once (no peer loaded yet), beside the process "
                  f"before that (Python, numpy, mbsfmu and the loaded scene). Pinocchio's data: what its model and `Data` add to the peak; "
                  f"its `Data` grows as N³ (Pinocchio 4.1), so it is left out beyond N = {PIN_MAX_CHAIN}. MuJoCo's "
                  "model is built through `MjSpec` (its XML reader refuses bodies nested deeper than about 500); its "
                  "compiler refuses trees deeper than 1024 bodies.", "",
                  "| N | mbsfmu µs (median) | mbsfmu C loop µs | empty ctypes call µs | RSS MB (before) | "
                  "Pinocchio aba µs (median) | ratio | deviation | Pinocchio's data MB | "
                  "MuJoCo mj_forward µs (median) | ratio | deviation |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in chain_rows:
            if "refused" in r or "failed" in r:
                why = f"refused by the engine: {r['refused']}" if "refused" in r else f"the run failed: {r['failed']}"
                lines.append(f"| {r['n']} | {why} |" + " |" * 10)
                continue
            lines.append(f"| {r['n']} | {r['mbsfmu_us']:.4g} ({r['mbsfmu_median_us']:.4g}) | {_num(r.get('c_us'))} | "
                         f"{r['ctypes_us']:.2f} | {r['rss_mb']:.0f} ({r['rss_python_mb']:.0f}) | {_peer(r, 'pinocchio')} | "
                         f"{_num(r.get('pin_data_mb'))} | {_peer(r, 'mujoco')} |")
        by_n = {r["n"]: r for r in chain_rows}
        lines.append("")
        for n in (100, 1000):
            r = by_n.get(n, {})
            got = (f"{r['ratio_pinocchio']:.2f} ({met(r['ratio_pinocchio'] <= TARGETS[n])})" if "ratio_pinocchio" in r
                   else "not measured" + (f" (MuJoCo: {r['ratio_mujoco']:.2f})" if "ratio_mujoco" in r else ""))
            lines.append(f"Target N = {n}: ratio to Pinocchio ≤ {TARGETS[n]} → {got}.")
        grow = slope(chain_rows)
        if grow:
            lines.append("Growth of the time (target: mbsfmu at most linear from N = 100 to 10,000): " + "; ".join(
                f"{'mbsfmu' if k == 'mbsfmu' else PEERS[k]} ∝ N^{e:.2f} (N = {a}…{b})" for k, (e, (a, b)) in grow.items()) + ".")
    if robot_rows:
        worst = max(robot_rows, key=lambda r: r["ratio_pinocchio"])
        lines += ["", "## example-robot-data robots", "",
                  "Floating base: the ones that stand, walk or fly (their free joint is Pinocchio's free flyer). "
                  "Repaired: loaded with `repair` (`--repair`) because the plain load refuses an unphysical or "
                  "massless link.", "",
                  "| robot | base | dof | mbsfmu µs (median) | mbsfmu C loop µs | empty ctypes call µs | "
                  "Pinocchio aba µs (median) | ratio | deviation |", "|---|---|---|---|---|---|---|---|---|"]
        for r in sorted(robot_rows, key=lambda r: (r["nv"], r["robot"])):
            lines.append(f"| {r['robot']}{' (repaired)' if r['repaired'] else ''} | {r['base']} | {r['nv']} | "
                         f"{r['mbsfmu_us']:.3g} ({r['mbsfmu_median_us']:.3g}) | {_num(r.get('c_us'))} | "
                         f"{r['ctypes_us']:.2f} | {_peer(r, 'pinocchio', 3)} |")
        met_all = sum(r["ratio_pinocchio"] <= TARGETS["robot"] for r in robot_rows)
        lines += ["", f"Target: ratio ≤ {TARGETS['robot']} on every robot → met on {met_all} of {len(robot_rows)}; "
                  f"worst {worst['robot']} ({worst['nv']} dof) {worst['ratio_pinocchio']:.2f}."]
    if refused:
        lines += ["", "Refused by the scene format:", ""] + [f"- {r['robot']}: {r['reason']}" for r in refused]
    return "\n".join(lines) + "\n"


def _num(x):
    return "–" if x is None else f"{x:.4g}"


def _version(module):
    try:
        return __import__(module).__version__
    except ImportError:
        return "not installed"


def main(argv=None):
    ap = argparse.ArgumentParser(prog="benchmarks.tree_speed", description=__doc__.split("\n\n")[0])
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
    cmd = "python -m benchmarks.tree_speed " + " ".join(argv if argv is not None else sys.argv[1:])
    for rows, name in ((robot_rows, "robots"), ([r for r in chain_rows if "mbsfmu_us" in r], "chains")):
        if rows:
            columns = list(dict.fromkeys(k for r in rows for k in r))  # peers missing at some sizes: empty cells
            output.write_csv([{k: r.get(k, "") for k in columns} for r in rows], out / f"tree_speed_{name}.csv", columns, 4)
    plot(robot_rows, chain_rows, out / "tree_speed.png")
    md = out / "tree_speed.md"
    files.write_text(md, markdown(robot_rows, refused, chain_rows, cmd.strip()))
    print(md)
    return robot_rows, refused, chain_rows


if __name__ == "__main__":
    main()
