"""Which cases a sweep runs: a grid of `start:stop:count` ranges and comma lists, or Latin-hypercube samples.

Cases are columns, {name: list of values}, one entry per case; a pandas DataFrame of cases is taken as is.
"""

import itertools
import math

import numpy as np

MAX_CASES = 10_000_000  # a grid's size is checked before it is built: bounded memory, clear message


def parse_values(name, spec):
    """`start:stop:count` → count evenly spaced values; `a,b,c` → those values (numbers, or words such as
    integrator methods); a sequence → its values."""
    if not isinstance(spec, str):
        values = list(spec) if isinstance(spec, (list, tuple)) else np.atleast_1d(spec).tolist()
        if not values:
            raise ValueError(f"--vary {name}: no values")
        return values
    text = spec.strip()
    if ":" in text:
        parts = text.split(":")
        if len(parts) != 3:
            raise ValueError(f"--vary {name}={spec}: a range is start:stop:count (or give a comma list)")
        lo, hi = _number(name, spec, parts[0]), _number(name, spec, parts[1])
        count = _count(name, spec, parts[2])
        return np.linspace(lo, hi, count).tolist()
    values = [_word_or_number(name, spec, v.strip()) for v in text.split(",") if v.strip()]
    if not values:
        raise ValueError(f"--vary {name}={spec}: no values")
    return values


def parse_range(name, spec):
    """`lo:hi` (or a pair) → (lo, hi): the interval Latin-hypercube samples are drawn from."""
    if isinstance(spec, str):
        parts = spec.strip().split(":")
        if len(parts) != 2:
            raise ValueError(f"--vary {name}={spec}: with --samples give a range lo:hi")
        lo, hi = (_number(name, spec, p) for p in parts)
    else:
        try:
            lo, hi = (float(v) for v in spec)
        except (TypeError, ValueError):
            raise ValueError(f"vary {name}: with samples give a range (lo, hi), got {spec!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        raise ValueError(f"--vary {name}: range {lo}:{hi} must be finite with lo <= hi")
    return lo, hi


def grid(vary):
    """Every combination of the values (the first name varies slowest)."""
    values = {name: parse_values(name, spec) for name, spec in vary.items()}
    n = math.prod(len(v) for v in values.values())
    if n > MAX_CASES:
        sizes = " × ".join(str(len(v)) for v in values.values())
        raise ValueError(f"the grid has {n} cases ({sizes}), more than {MAX_CASES}; use --samples")
    combos = list(itertools.product(*values.values()))
    return {name: [c[k] for c in combos] for k, name in enumerate(values)}


def latin_hypercube(ranges, n, seed=None):
    """n samples in the box `ranges` = {name: (lo, hi)}: each name's range cut into n equal strata holds
    exactly one sample (strata paired at random, position within a stratum uniform)."""
    rng = np.random.default_rng(seed)
    d = len(ranges)
    strata = rng.permuted(np.tile(np.arange(n), (d, 1)), axis=1).T  # n × d, each column a permutation
    u = (strata + rng.random((n, d))) / n
    lo, hi = np.array(list(ranges.values()), dtype=float).reshape(d, 2).T
    x = lo + u * (hi - lo)
    return {name: x[:, k].tolist() for k, name in enumerate(ranges)}


def make_cases(vary, samples=None, seed=None):
    """vary ({name: spec}, or a DataFrame with a row per case) → {name: values}."""
    if hasattr(vary, "to_dict") and hasattr(vary, "columns"):  # a DataFrame of explicit cases
        return {str(c): vary[c].tolist() for c in vary.columns}
    if not vary:
        raise ValueError("nothing to vary: give --vary NAME=SPEC")
    if samples is None:
        if seed is not None:
            raise ValueError("--seed applies to --samples (Latin-hypercube sampling)")
        return grid(vary)
    n = int(samples)
    if not 1 <= n <= MAX_CASES:
        raise ValueError(f"--samples must be between 1 and {MAX_CASES}, got {samples}")
    return latin_hypercube({name: parse_range(name, spec) for name, spec in vary.items()}, n, seed)


def finite_number(text, where):
    """A number from the command line; 'abc', 'nan' and 'inf' are refused, naming `where` (never a NaN case)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise ValueError(f"{where}: '{text}' is not a finite number")
    return value


def not_a_number(name, text):
    """The message for a value that is neither a number nor a range; `a-b` is taken for a range meant."""
    import re
    num = r"\s*[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?\s*"
    dash = re.fullmatch(f"({num})-({num})", str(text))
    hint = (f": a range is start:stop:count, e.g. {dash.group(1).strip()}:{dash.group(4).strip()}:11"
            if dash else ": give a number, a comma list or a range start:stop:count")
    return f"--vary {name}: '{text}' is not a number{hint}"


def _number(name, spec, text):
    return finite_number(text, f"--vary {name}={spec}")


def _count(name, spec, text):
    try:
        count = int(text)
    except ValueError:
        raise ValueError(f"--vary {name}={spec}: count '{text}' is not an integer") from None
    if not 1 <= count <= MAX_CASES:
        raise ValueError(f"--vary {name}={spec}: count must be between 1 and {MAX_CASES}")
    return count


def _word_or_number(name, spec, text):
    try:
        float(text)
    except ValueError:
        return text  # a word, such as an integrator method
    return _number(name, spec, text)
