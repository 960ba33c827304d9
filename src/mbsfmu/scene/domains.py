"""Expressions in t over the experiment's time span: drives (with the velocity and acceleration the equations
use) and force values must stay finite and real at every sampled time, so that no run fails on a domain error.

Sampling alone misses a pole or a domain edge between two samples (1/(t - 0.3333), tan(t) at pi/2,
sqrt(cos(t) + 0.99999) near pi). So every place where an expression can fail is also watched between the
samples: denominators (and cos of tan's argument) must not change sign or dip to zero, arguments of log, sqrt,
asin, acos and bases of fractional powers must not dip below their domain; local minima are refined by a
golden-section search.
"""

import math

import numpy as np

from ..expr import Expr, parse
from . import limits

_GOLDEN = (math.sqrt(5) - 1) / 2


def first_failure(expression, env, start, stop, derivatives=0):
    """None if `expression` and its first `derivatives` time derivatives are finite at DOMAIN_SAMPLES times in
    [start, stop] (both ends included) and between them, else a short text: which derivative failed, where and why."""
    e = parse(expression)
    if "t" not in e.names:
        return None
    funcs = [e]
    for _ in range(derivatives):
        funcs.append(funcs[-1].diff("t"))
    env = dict(env)
    times = np.linspace(start, stop, limits.DOMAIN_SAMPLES)
    for t in times:
        env["t"] = float(t)
        for k, f in enumerate(funcs):
            try:
                v = f(env)
            except ZeroDivisionError:
                return f"{_WHAT[k]} divides by zero at t = {t:g}"
            except (ValueError, OverflowError, TypeError) as err:  # math domain, overflow, a complex power
                return f"{_WHAT[k]} cannot be evaluated at t = {t:g} ({err})"
            if not math.isfinite(v):
                return f"{_WHAT[k]} is {v} at t = {t:g}"
    for k, f in enumerate(funcs):
        for kind, tree in _guards(f.tree):
            problem = _between_samples(kind, Expr("guard", tree), env, times)
            if problem:
                return f"{_WHAT[k]} {problem}"
    return None


_WHAT = ("the value", "the first time derivative", "the second time derivative")


def _guards(node):
    """(kind, subtree) for every place where `node` can fail: 'nonzero' (a denominator) or 'nonneg' (a domain
    argument that must stay >= 0; 'positive' both)."""
    kind = node[0]
    if kind in ("num", "name"):
        return
    if kind == "sel":  # min/max branch selection: the compared values are evaluated, the branches are derivatives of them
        for a in node[2:4]:
            yield from _guards(a)
        return
    children = node[2] if kind == "call" else node[1:]
    for a in children:
        yield from _guards(a)
    if kind == "/":
        yield "nonzero", node[2]
    elif kind == "^":
        base, exponent = node[1], node[2]
        c = exponent[1] if exponent[0] == "num" else None
        if c is None or c != int(c):
            yield ("positive" if c is None or c < 0 else "nonneg"), base
        elif c < 0:
            yield "nonzero", base
    elif kind == "call":
        name, a = node[1], node[2][0]
        if name == "tan":
            yield "nonzero", ("call", "cos", (a,))
        elif name == "log":
            yield "positive", a
        elif name == "sqrt":
            yield "nonneg", a
        elif name in ("asin", "acos"):
            yield "nonneg", ("-", ("num", 1.0), ("^", a, ("num", 2.0)))


def _between_samples(kind, g, env, times):
    """A text if guard g breaks its rule between two sample times, else None."""
    def at(t):
        env["t"] = float(t)
        try:
            v = g(env)
        except (ArithmeticError, ValueError, TypeError):
            return math.nan
        return v if math.isfinite(v) else math.nan

    values = np.array([at(t) for t in times])
    if np.isnan(values).any():
        return None  # evaluating the expression itself reports such times
    if kind == "nonzero":
        for i in np.flatnonzero(values[:-1] * values[1:] < 0):
            return f"divides by zero near t = {_zero(at, times[i], times[i + 1]):.6g} (a denominator changes sign)"
    scale = max(np.abs(values).max(), 1e-300)
    signed = kind != "nonzero"
    dips = np.abs(values) if not signed else values
    for i in range(len(times)):
        lo, hi = max(i - 1, 0), min(i + 1, len(times) - 1)
        if dips[i] > min(dips[lo], dips[hi]) or dips[i] > 0.05 * scale:
            continue  # not a local minimum, or far from the edge
        t, v = _minimize(lambda t: abs(at(t)) if not signed else at(t), times[lo], times[hi])
        if signed and v < 0:
            return f"leaves its domain near t = {t:.6g} (an argument falls to {v:.3g})"
        if kind != "nonneg" and abs(v) <= 1e-9 * max(abs(values[lo]), abs(values[hi])):  # zero to rounding, locally
            return f"divides by zero near t = {t:.6g} (a denominator or logarithm's argument touches 0)"
    return None


def _zero(f, a, b):
    """A sign change of f in [a, b], by bisection."""
    fa = f(a)
    for _ in range(60):
        m = 0.5 * (a + b)
        fm = f(m)
        if (fm < 0) == (fa < 0):
            a, fa = m, fm
        else:
            b = m
    return 0.5 * (a + b)


def _minimize(f, a, b, iterations=60):
    """(t, f(t)) at a minimum of f in [a, b] (golden-section search; NaN counts as no minimum)."""
    c, d = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(iterations):
        if not fc > fd:  # NaN-safe: keep the left part unless fd is clearly smaller
            b, d, fd = d, c, fc
            c = b - _GOLDEN * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + _GOLDEN * (b - a)
            fd = f(d)
    return (c, fc) if not fc > fd else (d, fd)
