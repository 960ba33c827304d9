"""Result plots for people: one panel per unit, a title with the model and the method (build time only).

Curves of one panel cycle through 10 colours with a solid line, then the same colours dashed, dotted,
dash-dotted: 40 curves per panel before a style repeats.
"""

from . import files

QUANTITY = {"rad": "angle", "rad/s": "angular velocity", "m": "position", "m/s": "velocity",
            "1": "dimensionless", "1/s": "rate", "N": "force", "N.m": "torque",
            "Pa": "von Mises stress"}
LINESTYLES = ("-", "--", ":", "-.")


def panels(units):
    """{unit: [column indices]} in the order the units first appear (a missing unit counts as '1')."""
    groups = {}
    for k, u in enumerate(units):
        groups.setdefault(u or "1", []).append(k)
    return groups


def styles():
    """The line styles of one panel, in order: 10 colours solid, then dashed, dotted, dash-dotted."""
    import matplotlib.pyplot as plt
    from cycler import cycler
    return cycler(linestyle=LINESTYLES) * cycler(color=plt.get_cmap("tab10").colors)


def plot_result(path, t, cols, names, units, title):
    """Write a PNG: time on x, one panel per unit; cols[:, k] is signal names[k] in units[k]."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    groups = panels(units)
    height = 1.2 + 2.3 * len(groups)  # inches
    fig, axes = plt.subplots(len(groups), 1, sharex=True, squeeze=False, figsize=(9, height))
    for ax, (unit, idx) in zip(axes[:, 0], groups.items()):
        ax.set_prop_cycle(styles())
        for k in idx:
            ax.plot(t, cols[:, k], label=names[k])
        ax.set_ylabel(f"{QUANTITY.get(unit, unit)} [{unit}]")
        ax.grid(True, alpha=0.3)
        # beside the panel, so no legend hides a curve; a second column once it would grow taller than the panel
        ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False,
                  ncol=1 + (len(idx) - 1) // 10)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / height))  # 0.35 in for the title
    with files.replacing(path) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight")
    plt.close(fig)
