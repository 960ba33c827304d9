"""Elastic bodies from solid meshes (issue 24): time and peak memory against DOFs for tet10 cantilevers.

Each size runs in a fresh process (its peak resident set is its own): a tet4 box mesh 1 m × 0.1 m × 0.1 m
(nx = 5 n cells along, n × n across, six tets per cell) written as a gmsh .msh, then
- read + assemble: `assemble_solid(file, element="tet10")` (meshio's parse in its bounded child, scikit-fem's
  consistent M and K, the node-major map);
- reduce: `bodies.cms.reduce`, what a scene's `fe:` key runs: Craig–Bampton to 20 modes, the x = 0 face tied
  (RBE2) to its centre, the tip node kept (mass check, the shift-invert factorization and eigensolve, the
  consistent-mass invariants, the kept nodes); `f1_hz` is its first frequency, for convergence against size.
Sizes grow until one run passes 60 s or limits.FE_DOFS. Writes fe_reduce.csv and fe_reduce.png into --out;
`load` is the machine's 1-minute load average as the row finished (2 cores, shared).
--compare n: peers at one size, alternating runs (fe_factor.csv): as installed with the `fe` extra (CHOLMOD's
Cholesky from cvxopt, BLAS held to one thread in the eigensolver by threadpoolctl), without threadpoolctl, and
without cvxopt (SuperLU's LU); a worker runs without a module by making its import fail.

    python -m benchmarks.fe_reduce --out reports                  (a few minutes)
    python -m benchmarks.fe_reduce --out reports --compare 7      (47,925 DOFs, 3 runs of each: ~4 minutes)
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mbsfmu.reports import output

MODES, BUDGET_S = 20, 60.0
COLUMNS = ["n", "dofs", "assemble_s", "reduce_s", "f1_hz", "peak_mib", "parser_peak_mib", "load"]
PEERS = {"cholmod": (), "cholmod-blas-threads": ("--without", "threadpoolctl"),   # worker flags
         "superlu": ("--without", "cvxopt")}


def box_mesh(n):
    """meshio.Mesh of the 1 × 0.1 × 0.1 m box, positively oriented tetrahedra (scikit-fem's tensor mesh)."""
    import meshio
    from skfem import MeshTet
    m = MeshTet.init_tensor(np.linspace(0, 1, 5 * n + 1), np.linspace(0, 0.1, n + 1), np.linspace(0, 0.1, n + 1))
    p, t = m.p.T, m.t.T.copy()
    a = p[t[:, 0]]
    flip = np.einsum("ij,ij->i", p[t[:, 1]] - a, np.cross(p[t[:, 2]] - a, p[t[:, 3]] - a)) < 0
    t[flip] = t[flip][:, [1, 0, 2, 3]]
    return meshio.Mesh(p, [("tetra", t)])


def reduce_clamped(model):
    """(seconds, first frequency in Hz) of cms.reduce: Craig–Bampton, MODES modes, the x = 0 face tied to its
    centre, the tip node kept."""
    from mbsfmu.bodies import cms
    root = np.flatnonzero(model.nodes[:, 0] < 1e-12)
    t0 = time.perf_counter()
    r = cms.reduce(model, "craig-bampton", interface=root, reference=[0, 0.05, 0.05],
                   keep=[int(np.argmax(model.nodes[:, 0]))], modes=MODES)
    return time.perf_counter() - t0, float(r["frequencies"][0])


def one(n):
    """One size, in this process: the row of the table."""
    from mbsfmu.bodies.fe_mesh import assemble_solid
    with tempfile.TemporaryDirectory() as tmp:
        box_mesh(n).write(Path(tmp) / "bar.msh", file_format="gmsh")
        t0 = time.perf_counter()
        fe = assemble_solid("bar.msh", 2.1e11, 0.3, 7850.0, element="tet10", base=tmp)
        assemble = time.perf_counter() - t0
    reduce_s, f1 = reduce_clamped(fe)
    return {"n": n, "dofs": fe.M.shape[0], "assemble_s": assemble, "reduce_s": reduce_s, "f1_hz": f1,
            "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "parser_peak_mib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
            "load": os.getloadavg()[0]}


def worker(n, *flags):
    """one(n) in a fresh process (its peak resident set its own): the row, or None and why it stopped."""
    r = subprocess.run([sys.executable, "-m", "benchmarks.fe_reduce", "--one", str(n), *flags],
                       capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])  # the repository's
    if r.returncode:
        return None, r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode
    row = json.loads(r.stdout.strip().splitlines()[-1])
    print(f"{row['dofs']:8,d} DOFs: read + assemble {row['assemble_s']:6.2f} s, reduce {row['reduce_s']:6.2f} s, "
          f"peak {row['peak_mib']:6.0f} MiB (parser {row['parser_peak_mib']:.0f} MiB), load {row['load']:.1f}"
          + (f" [{' '.join(flags)}]" if flags else ""))
    return row, None


def sweep(sizes, budget=BUDGET_S):
    """Rows for the sizes in order, each in a fresh process, until one run passes the budget or fails."""
    rows = []
    for n in sizes:
        row, why = worker(n)
        if row is None:
            print(f"n = {n}: stopped ({why})")
            break
        rows.append(row)
        if row["assemble_s"] + row["reduce_s"] > budget:
            break
    return rows


def compare(n, repeat):
    """The PEERS at size n, alternating runs: rows with `peer` and `run`; printed, each one's median reduce time
    and the median over runs of its ratio to the first peer's (the `fe` extra's) in the same run."""
    rows = []
    for run in range(repeat):
        for name, flags in PEERS.items():
            row, why = worker(n, *flags)
            if row is None:
                raise SystemExit(f"n = {n} ({name}): {why}")
            rows.append({"peer": name, "run": run, **row})
    seconds = {name: np.array([r["reduce_s"] for r in rows if r["peer"] == name]) for name in PEERS}
    first = seconds["cholmod"]
    for name, t in seconds.items():
        print(f"{name}: reduce {np.median(t):.2f} s (median of {repeat}), {np.median(t / first):.2f}× cholmod's "
              f"(median of the runs' ratios, {np.min(t / first):.2f}…{np.max(t / first):.2f})")
    return rows


def plot(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    dofs = [r["dofs"] for r in rows]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.loglog(dofs, [r["assemble_s"] for r in rows], "o-", label="read + assemble (tet10)")
    a.loglog(dofs, [r["reduce_s"] for r in rows], "s-", label=f"cms.reduce: Craig–Bampton, {MODES} modes")
    a.loglog(dofs, [r["assemble_s"] + r["reduce_s"] for r in rows], "k^-", label="both")
    a.axhline(BUDGET_S, color="gray", ls=":", label="60 s target")
    a.set_xlabel("DOFs")
    a.set_ylabel("wall time (s)")
    a.legend(loc="upper left", fontsize="small")
    b.loglog(dofs, [r["peak_mib"] for r in rows], "o-", label="peak resident set")
    b.loglog(dofs, [r["parser_peak_mib"] for r in rows], "s-", label="meshio parser process")
    b.axhline(4096, color="gray", ls=":", label="4 GB target")
    b.set_xlabel("DOFs")
    b.set_ylabel("MiB")
    b.legend(loc="upper left", fontsize="small")
    fig.suptitle("tet10 cantilever: assembly and reduction against size")
    fig.tight_layout()
    output.save_figure(fig, path, dpi=110)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="reports", help="folder for fe_reduce.csv and fe_reduce.png")
    ap.add_argument("--sizes", default="1,2,3,4,5,6,7,8,9,10,11,12,13",
                    help="cross-section divisions n (5n × n × n cells), in increasing order")
    ap.add_argument("--compare", type=int, metavar="N", help="time the factorizations as peers at size N instead")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each factorization with --compare")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)   # the worker: one size, a JSON row on stdout
    ap.add_argument("--without", action="append", default=[], help=argparse.SUPPRESS)   # a module, hidden
    a = ap.parse_args(argv)
    if a.one is not None:
        for module in a.without:
            sys.modules[module] = None   # its import fails: cms runs as an install without it
        print(json.dumps(one(a.one)))
        return None
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.compare is not None:
        rows = compare(a.compare, a.repeat)
        output.write_csv(rows, out / "fe_factor.csv", ["peer", "run"] + COLUMNS, 4)
        return rows
    rows = sweep([int(s) for s in a.sizes.split(",")])
    output.write_csv(rows, out / "fe_reduce.csv", COLUMNS, 4)
    if rows:
        plot(rows, out / "fe_reduce.png")
    return rows


if __name__ == "__main__":
    main()
