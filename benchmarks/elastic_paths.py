"""Elastic bodies on the engine's two evaluation paths (issue 26): the dense equations (per-body Jacobian rows, M
assembled and factored: cubic in the coordinates) against the articulated-body algorithm, where an elastic body is
a node with its modal coordinates (linear in the bodies), and the path the compiler picks (compiler/scene_file.py: dense_path).

    python -m benchmarks.elastic_paths --out reports          (about 2 minutes)

Cases: the shipped elastic models; arms of L beams (n modes each, every beam on a revolute joint at the tip node
of the one before); rigid chains ending in a beam; and arms of growing length (2 modes a link), where the dense
path's cubic cost shows. Every case compiled for each path, µs per right-hand side (`mbs_rhs`) in a C loop over the
engine library (benchmarks/rhs_loop.c) on the same 64 distinct states in turn (the engine keeps its kinematics while the
state's bits stay the same), batches of the two paths alternating (rounds), the best batch of each. Target: the
chosen path is the faster within the noise (its time ≤ 1.1 × the other's), the shipped elastic models no slower than
on the dense path they had.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from mbsfmu.reports import output
from .tree_speed import c_loop

REPO = Path(__file__).resolve().parents[1]
SHIPPED = ("flexible_pendulum", "spinup_beam", "robot_arm_elastic", "fe_link", "fe_plate", "fe_stress")
ARMS = ((1, 8), (1, 20), (2, 4), (3, 2), (3, 4), (2, 8), (4, 4), (3, 8), (6, 6))
RIGID_THEN_BEAM = ((6, 12), (12, 4))
LONG_ARMS = (10, 30, 100)
COLUMNS = ["case", "nvel", "chosen", "dense_us", "recursive_us", "chosen_over_faster"]


def arm(links, modes):
    """L beams of `modes` modes on revolute joints about y, each at the tip node of the one before."""
    import mbsfmu
    beam = f"elastic: {{beam: {{length: 1, EI: [40, 700], rhoA: 0.8, elements: 8, modes: {modes}, clamped: start}}}}"
    bodies = [f"  l{i}: {{parent: {'world' if i == 0 else f'l{i - 1}'}, joint: {{type: revolute, axis: [0, 1, 0]"
              f"{'' if i == 0 else ', node: -1'}}}, {beam}}}" for i in range(links)]
    return mbsfmu.loads("mbsfmu: 1\nname: arm\ngravity: [0, 0, -9.81]\nbodies:\n" + "\n".join(bodies)).spec


def rigid_then_beam(links, modes):
    """A chain of rigid links on revolute joints about y, a beam welded to the last."""
    import mbsfmu
    bodies = [f"  r{i}: {{parent: {'world' if i == 0 else f'r{i - 1}'}, joint: {{type: revolute, axis: [0, 1, 0], "
              "at: [0, 0, -0.3]}, mass: 1, inertia: [[0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]]}" for i in range(links)]
    bodies.append(f"  beam: {{parent: r{links - 1}, joint: {{type: fixed}}, elastic: {{beam: {{length: 1, "
                  f"EI: [40, 700], rhoA: 0.8, elements: 8, modes: {modes}, clamped: start}}}}}}")
    return mbsfmu.loads("mbsfmu: 1\nname: chain_beam\ngravity: [0, 0, -9.81]\nbodies:\n" + "\n".join(bodies)).spec


class _Compiled:
    """What c_loop reads (the compiled scene, the states) for one path; `dense`: the compiler's own choice."""

    def __init__(self, spec, dense, states=64, seed=0):
        from mbsfmu.engine import Instance
        from mbsfmu.compiler.scene_file import compile_scene
        from mbsfmu.compiler.variables import variables
        blob = compile_scene(spec, variables(spec), dense=dense)
        self.sim = type("Compiled", (), {"blob": blob})
        inst = Instance(blob)
        x0, nominal = np.array(inst.state()), np.array(inst.nominals())
        self.X = x0 + 0.1 * nominal * np.random.default_rng(seed).standard_normal((states, len(x0)))
        self.nvel = inst.nvel
        t0, out = time.perf_counter(), np.empty(len(x0))
        for x in self.X:
            inst.rhs(0.0, x, out)
        self.us = (time.perf_counter() - t0) / states * 1e6  # from Python: sizes c_loop's batches


def cases(shipped=SHIPPED, arms=ARMS, rigid_then_beam_=RIGID_THEN_BEAM, long_arms=LONG_ARMS):
    import mbsfmu
    for name in shipped:
        yield name, mbsfmu.load(REPO / "models" / f"{name}.yaml").spec
    for L, n in arms:
        yield f"arm {L}×{n}", arm(L, n)
    for L, n in rigid_then_beam_:
        yield f"{L} rigid + beam {n}", rigid_then_beam(L, n)
    for L in long_arms:
        yield f"arm {L}×2", arm(L, 2)


def run(case_list, rounds=5, seconds=0.2, progress=True):
    from mbsfmu.compiler.scene_file import carriers, dense_path
    from mbsfmu.compiler.model import Model
    rows = []
    for name, spec in output.progress(case_list, "elastic paths", lambda c: c[0], progress):
        model = Model(spec)
        paths = {p: _Compiled(spec, p == "dense") for p in ("dense", "recursive")}
        best = {p: np.inf for p in paths}
        for _ in range(rounds):  # alternating: the machine's noise falls on both alike
            for p, c in paths.items():
                best[p] = min(best[p], c_loop(c, python_us=c.us, seconds=seconds / rounds))
        chosen = "dense" if dense_path(model, carriers(model)) else "recursive"
        rows.append({"case": name, "nvel": paths["dense"].nvel, "chosen": chosen, "dense_us": best["dense"],
                     "recursive_us": best["recursive"], "chosen_over_faster": best[chosen] / min(best.values())})
    return rows


def plot(rows, path):
    output.paired_bars([r["case"] for r in rows], (("dense path", [r["dense_us"] for r in rows]),
                                                   ("recursive path (articulated bodies)", [r["recursive_us"] for r in rows])),
                       "µs per right-hand side (best batch, C loop)", path,
                       [(k, r["chosen"] == "recursive", "chosen") for k, r in enumerate(rows)])


def markdown(rows, command):
    lines = ["# Elastic bodies on the two evaluation paths", "", f"`{command}`", "", __doc__.split("\n\n", 2)[2].strip(),
             "", "| case | coordinates | chosen | dense µs | recursive µs | recursive / dense | chosen / faster |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['case']} | {r['nvel']} | {r['chosen']} | {r['dense_us']:.3g} | {r['recursive_us']:.3g} | "
              f"{r['recursive_us'] / r['dense_us']:.2f} | {r['chosen_over_faster']:.2f} |" for r in rows]
    worst = max(rows, key=lambda r: r["chosen_over_faster"])
    shipped = [r for r in rows if r["case"] in SHIPPED]
    lines += ["", f"The chosen path within 1.1 × the faster: {sum(r['chosen_over_faster'] <= 1.1 for r in rows)} of "
              f"{len(rows)} cases (worst: {worst['case']}, {worst['chosen_over_faster']:.2f})."]
    if shipped:
        lines += [f"Shipped elastic models, chosen / dense: "
                  + ", ".join(f"{r['case']} {r[r['chosen'] + '_us'] / r['dense_us']:.2f}" for r in shipped) + "."]
    lines += ["", "![the two paths](elastic_paths.png)", ""]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks.elastic_paths", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="reports", help="folder for elastic_paths.md, .csv and .png")
    ap.add_argument("--rounds", type=int, default=5, help="alternating batches per path")
    ap.add_argument("--seconds", type=float, default=0.2, help="timed seconds per case and path")
    ap.add_argument("--quick", action="store_true", help="a few small cases (the tests)")
    a = ap.parse_args(argv)
    case_list = list(cases(SHIPPED[:1], ARMS[:1], (), ())) if a.quick else list(cases())
    rows = run(case_list, a.rounds, a.seconds)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    output.write_csv(rows, out / "elastic_paths.csv", COLUMNS, 4)
    plot(rows, out / "elastic_paths.png")
    from mbsfmu import files
    command = "python -m benchmarks.elastic_paths " + " ".join(argv if argv is not None else sys.argv[1:])
    files.write_text(out / "elastic_paths.md", markdown(rows, command.strip()))
    print(markdown(rows, ""))


if __name__ == "__main__":
    main()
