"""What a directional derivative costs beside the right-hand side it differentiates (issue 27's target: a column
within 3× of a right-hand side).

    python -m benchmarks.directional_cost --out reports

A column is what a host's fmi2GetDirectionalDerivative / fmi3GetDirectionalDerivative costs the engine: set the
state, then J·seed of every der(·) along a seed over all states (mbs_set_state + mbs_directional_derivative: the
complex step through the evaluation, engine/deriv.c). A right-hand side is mbs_rhs at a state. Both in one C loop
over the engine library (benchmarks/rhs_loop.c) on the same 64 states in turn (distinct states: the engine keeps its
kinematics while the state's bits stay the same), batches of the two alternating, the best batch of each. Cases:
every shipped model and random revolute chains (benchmarks/tree_speed.py: chain_scene) of growing length, which take
the recursive path: the column follows the right-hand side's linear cost.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from mbsfmu.reports import output
from .tree_speed import c_loop, chain_scene

REPO = Path(__file__).resolve().parents[1]
CHAINS = (10, 30, 100, 300)
COLUMNS = ["case", "n", "rhs_us", "column_us", "ratio"]


class _Case:
    """What c_loop reads: the compiled scene (with the derivative variables) and the states."""

    def __init__(self, spec, states=64, seed=0):
        from mbsfmu.engine import Instance
        from mbsfmu.simulation import compiled
        blob, _, _ = compiled(spec, derivatives=True)
        self.sim = type("Compiled", (), {"blob": blob})
        inst = Instance(blob)
        x0, nominal = np.array(inst.state()), np.array(inst.nominals())
        self.X = x0 + 0.1 * nominal * np.random.default_rng(seed).standard_normal((states, len(x0)))
        t0, out = time.perf_counter(), np.empty(len(x0))
        for x in self.X:
            inst.rhs(0.0, x, out)
        self.us = (time.perf_counter() - t0) / states * 1e6  # from Python: sizes c_loop's batches


def cases(models, chains):
    import mbsfmu
    for name in models:
        yield name, mbsfmu.load(REPO / "models" / f"{name}.yaml").spec
    for n in chains:
        yield f"chain{n}", chain_scene(n).spec


def run(models, chains, seconds, progress=True):
    rows = []
    for name, spec in output.progress(list(cases(models, chains)), "directional", lambda c: c[0], progress):
        case = _Case(spec)
        rhs, col = c_loop(case, python_us=case.us, seconds=seconds, column=True)
        rows.append({"case": name, "n": case.X.shape[1], "rhs_us": rhs, "column_us": col, "ratio": col / rhs})
    return rows


def plot(rows, path):
    output.paired_bars([r["case"] for r in rows], (("right-hand side (mbs_rhs)", [r["rhs_us"] for r in rows]),
                                                   ("directional derivative column", [r["column_us"] for r in rows])),
                       "µs per call (best batch, C loop)", path)


def markdown(rows, command):
    lines = ["# Directional derivatives: a column against a right-hand side", "", f"`{command}`", "",
             __doc__.split("\n\n", 2)[2].strip(), "",
             "| case | states | rhs µs | column µs | column / rhs |", "|---|---|---|---|---|"]
    lines += [f"| {r['case']} | {r['n']} | {r['rhs_us']:.2f} | {r['column_us']:.2f} | {r['ratio']:.2f} |" for r in rows]
    ratios = [r["ratio"] for r in rows]
    lines += ["", f"Column / right-hand side: {min(ratios):.2f}–{max(ratios):.2f} (median {np.median(ratios):.2f}); "
              f"{sum(q <= 3 for q in ratios)} of {len(ratios)} cases within the target 3.", "",
              "![column vs rhs](directional.png)", ""]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks.directional_cost", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="reports", help="folder for directional.md, .csv and .png")
    ap.add_argument("--models", nargs="*", default=[p.stem for p in sorted((REPO / "models").glob("*.yaml"))])
    ap.add_argument("--chains", nargs="*", type=int, default=list(CHAINS))
    ap.add_argument("--seconds", type=float, default=0.5, help="timed seconds per case and call")
    a = ap.parse_args(argv)
    rows = run(a.models, a.chains, a.seconds)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    output.write_csv(rows, out / "directional.csv", COLUMNS, 4)
    plot(rows, out / "directional.png")
    from mbsfmu import files
    files.write_text(out / "directional.md", markdown(rows, "python -m benchmarks.directional_cost " + " ".join(argv or sys.argv[1:])))
    print(markdown(rows, ""))


if __name__ == "__main__":
    main()
