"""Plot a sweep's table: outputs against one varied name, or a heat map over two (one panel per output)."""

import math

import numpy as np

from .. import files

MAX_PANELS = 12


def plot(table, against, outputs, path):
    """against: one or two varied names. A full grid over two names is drawn as cells, samples as dots."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    if not 1 <= len(against) <= 2:
        raise ValueError(f"plot against one or two varied names, got {len(against)}: {', '.join(against)}")
    outputs = list(outputs)[:MAX_PANELS]
    ok = table[table["status"] == "ok"]
    cols = min(3, len(outputs))
    rows = math.ceil(len(outputs) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    for ax, out in zip(axes.flat, outputs):
        if len(against) == 1:
            _lines(ax, ok, against[0], out)
        else:
            _heat(fig, ax, ok, against[0], against[1], out)
    for ax in axes.flat[len(outputs):]:
        ax.set_visible(False)
    failed = len(table) - len(ok)
    fig.suptitle(f"{len(ok)} cases" + (f", {failed} failed (not shown)" if failed else ""), fontsize="medium")
    fig.tight_layout()
    with files.replacing(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


def _lines(ax, ok, x, out):
    d = ok.sort_values(x)
    ax.plot(d[x], d[out], "o-", ms=3, lw=1)
    ax.set_xlabel(x)
    ax.set_ylabel(out)
    ax.grid(True, alpha=0.3)


def _heat(fig, ax, ok, x, y, out):
    xs, ys = np.unique(ok[x]), np.unique(ok[y])
    numeric = ok[x].dtype.kind in "fiu" and ok[y].dtype.kind in "fiu"
    if numeric and len(xs) * len(ys) == len(ok) and len(xs) > 1 and len(ys) > 1:  # a full grid: cells
        Z = ok.pivot_table(index=y, columns=x, values=out).to_numpy()
        m = ax.pcolormesh(xs, ys, Z, shading="nearest")
    else:  # samples (or a grid with failed cases): dots coloured by the output
        m = ax.scatter(ok[x], ok[y], c=ok[out], s=14)
    fig.colorbar(m, ax=ax, label=out)
    ax.set_xlabel(x)
    ax.set_ylabel(y)
