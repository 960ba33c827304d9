"""Input tables: a `time` column, then input names (`simulate --input`, `animate --input`, `mbsfmu.simulate`,
`mbsfmu.sweep`). One reader and one meaning for all of them:

- "hold" (the default, a zero-order hold): each row's values hold from its time until the next row's time,
  exactly: a step that crosses a row's time is split there. Before the first row its values hold, after
  the last row too; two rows at one time are a jump (the later row holds from that time).
- "linear": the table interpolated linearly in time, sampled at every communication point and held over the
  step (what fmpy and most FMU masters do with a table).
"""

import numpy as np

from .csvfile import check_fmu_inputs, check_inputs, read_csv

INTERPOLATIONS = ("hold", "linear")


def interpolation(value):
    if value not in INTERPOLATIONS:
        raise ValueError(f"input interpolation {value!r}: choose {' or '.join(INTERPOLATIONS)}")
    return value


class InputTable:
    """names, row times `t` (non-decreasing) and `values` (a row per time, a column per name)."""

    def __init__(self, names, t, values, how="hold"):
        self.names, self.t = list(names), np.asarray(t, dtype=float)
        self.values = np.asarray(values, dtype=float).reshape(len(self.t), len(self.names))
        self.how = interpolation(how)

    @classmethod
    def read(cls, path, valid, model_name, how="hold"):
        """A CSV (csvfile.read_csv: every cell a finite number) whose columns after `time` are inputs in `valid`."""
        return cls._read(path, lambda names: check_inputs(path, names, valid, model_name), how)

    @classmethod
    def for_fmu(cls, path, md, how="hold"):
        """read, its columns checked against an FMU's modelDescription (csvfile.check_fmu_inputs: an FMI 3.0
        array's elements named)."""
        return cls._read(path, lambda names: check_fmu_inputs(path, names, md), how)

    @classmethod
    def _read(cls, path, check, how):
        names, t, data = read_csv(path, "input")
        check(names)
        return cls(names, t, np.column_stack([data[n] for n in names]) if names else np.zeros((len(t), 0)), how)

    def at(self, t):
        """{name: value} applied from time t on (for "linear": over the step that starts at t)."""
        if self.how == "linear":
            return {n: float(np.interp(t, self.t, self.values[:, k])) for k, n in enumerate(self.names)}
        row = max(0, int(np.searchsorted(self.t, t, side="right")) - 1)
        return dict(zip(self.names, self.values[row].tolist()))

    def pieces(self, t0, t1):
        """[t0, …, t1]: the step from t0 to t1 cut where a held value changes (rows' times inside it)."""
        if self.how == "linear":
            return [t0, t1]
        eps = 1e-12 * max(1.0, abs(t0), abs(t1))  # a row on a communication point is not a piece of its own
        inside = self.t[(self.t > t0 + eps) & (self.t < t1 - eps)]
        return [t0, *np.unique(inside).tolist(), t1]

    def fmpy_signals(self):
        """The table as fmpy's `input=` (a structured array that fmpy interpolates linearly, a repeated time
        being a jump): "hold" as steps, every row's value repeated at the next row's time."""
        t, v = self.t, self.values
        if self.how == "hold" and len(t) > 1:
            t = np.repeat(t, 2)[1:]                  # t0, t1, t1, t2, t2, …
            v = np.repeat(v, 2, axis=0)[:-1]         # v0, v0, v1, v1, v2, …
        out = np.zeros(len(t), dtype=[("time", float)] + [(n, float) for n in self.names])
        out["time"] = t
        for k, n in enumerate(self.names):
            out[n] = v[:, k]
        return out


def step_through(table, ts, set_values, advance, sample):
    """The master loop over the communication points ts: inputs from `table` set (`set_values({name: value})`)
    at every piece of every step, `advance(t0, t1)` over each piece, `sample(k)` after reaching ts[k]."""
    sample(0)
    for k in range(len(ts) - 1):
        cuts = table.pieces(ts[k], ts[k + 1])
        for a, b in zip(cuts[:-1], cuts[1:]):
            set_values(table.at(a))
            advance(a, b)
        sample(k + 1)
