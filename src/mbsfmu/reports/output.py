"""What the benchmark commands share: a progress bar over their runs and the report writers (atomic, through
mbsfmu.files: a run that fails or is killed leaves the previous report)."""

import csv
import sys
import tempfile
from pathlib import Path

from .. import files


def progress(jobs, desc, label, enabled=True):
    """Yield the jobs; with `enabled`, under a tqdm bar whose postfix is label(job)."""
    if not enabled:
        yield from jobs
        return
    from tqdm import tqdm
    with tqdm(total=len(jobs), desc=desc, unit="run") as bar:
        for job in jobs:
            bar.set_postfix_str(label(job))
            yield job
            bar.update(1)


def write_csv(rows, path, columns, digits):
    """rows (dicts) → CSV with the given columns, floats to `digits` significant digits."""
    with files.replacing(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{r[k]:.{digits}g}" if isinstance(r[k], float) else r[k]) for k in columns})


def save_figure(fig, path, **kw):
    """Save the matplotlib figure `fig` as `path` (savefig's keywords), then close it. A PNG is kept small: the
    reports' figures are tracked in git (reports/), and line plots need no more than a 64-colour palette."""
    import matplotlib.pyplot as plt
    with files.replacing(path) as tmp:
        fig.savefig(tmp, **kw)
        if Path(path).suffix == ".png" and Path(tmp).is_file():  # (not a device such as /dev/null)
            small_png(tmp)
    plt.close(fig)


def small_png(path):
    """Rewrite a PNG with a 64-colour palette (Pillow: matplotlib's own dependency); 3–4× smaller for plots."""
    from PIL import Image
    with Image.open(path) as im:
        small = im.convert("RGB").quantize(colors=64, method=Image.Quantize.MEDIANCUT)
    small.save(path, format="PNG", optimize=True)


def paired_bars(names, pair, ylabel, path, marks=()):
    """Two series of µs per case side by side on a log axis (pair: ((label, values), (label, values))), the
    cases' names below, `marks` ((case index, which of the two, text), ...) over their bars; saved as path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    fig, ax = plt.subplots(figsize=(max(9, 0.5 * len(names)), 4))
    x = np.arange(len(names))
    for side, (label, values) in zip((-0.2, 0.2), pair):
        ax.bar(x + side, values, 0.4, label=label)
    for k, which, text in marks:
        ax.annotate(text, (k + (0.2 if which else -0.2), pair[which][1][k]), ha="center", va="bottom", fontsize=6,
                    rotation=90)
    ax.set_yscale("log")
    ax.set_xticks(x, names, rotation=45, ha="right")
    ax.set_ylabel(ylabel)
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path, dpi=100)


def case_reports(stem, prog, argv, out, cases, run_case, plot, csv_rows, columns, markdown):
    """The report of a benchmark over named cases: run_case(name, workdir) for each (in a temporary folder), its
    figure plot(result, <out>/<stem>.<name>.png), then <stem>.csv (csv_rows(result) with `columns`) and <stem>.md
    (markdown(results, the command line)). Returns the results."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    command = f"python -m {prog} " + " ".join(sys.argv[1:] if argv is None else argv)
    results = []
    with tempfile.TemporaryDirectory(prefix=f"mbsfmu_{stem}_") as tmp:
        for name in cases:
            results.append(run_case(name, Path(tmp) / name))
            plot(results[-1], out / f"{stem}.{name}.png")
    write_csv([r for res in results for r in csv_rows(res)], out / f"{stem}.csv", columns, 5)
    files.write_text(out / f"{stem}.md", markdown(results, command.strip()))
    print(out / f"{stem}.md")
    return results
