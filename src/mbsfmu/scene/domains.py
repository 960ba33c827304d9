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

from ..engine import layout as _layout
from ..expr import Expr, parse
from .. import limits

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


# -- domains of the numbers a host may change -------------------------------------------------------------
# One table, declared here: the loader checks a scene's nominal numbers with these rules; compiler/scene_file.py writes
# the same rules into the compiled scene (variable domains, and the derived-quantity rules of every number
# that depends on a parameter), and the engine applies them when a host sets a value (rules.c: mbs_check_rules and
# in_domain mirror check() and Domain.contains, kind by kind; tests/test_domains.py holds the two equal).

NONNEG, MAGNITUDE, INERTIA, AXIS, ROTATION, CARRIES, TIMED, PERPENDICULAR, NOT_PARALLEL = (  # codes: mbs_layout.h
    _layout.R_NONNEG, _layout.R_MAGNITUDE, _layout.R_INERTIA, _layout.R_AXIS, _layout.R_ROTATION, _layout.R_CARRIES,
    _layout.R_TIMED, _layout.R_PERPENDICULAR, _layout.R_NOT_PARALLEL)
RULE_SIZE = {_layout.CONSTANTS[name]: size for name, size in _layout.LISTS["MBS_RULES"]}  # numbers each rule reads
# CARRIES: the loader's `massless` check of a body; TIMED: a drive (or its derivatives) or force value of t that
# a parameter feeds, finite at the DOMAIN_SAMPLES times of first_failure (the checks between samples stay the
# loader's: they need the expression tree, which the engine holds as bytecode)


def check(rule, values):
    """None if `values` (the rule's numbers, RULE_SIZE of them) satisfy the rule, else what is wrong."""
    if rule == NONNEG:
        return None if values[0] >= 0 else f"must not be negative, got {values[0]:g}"
    if rule == MAGNITUDE:
        v, (lo, hi) = values[0], limits.MAGNITUDE
        return None if v == 0 or lo <= abs(v) <= hi else \
            f"{v:g} is outside the magnitudes a model can compute with ({lo:g} to {hi:g}, or 0)"
    if rule == AXIS:
        length, (lo, hi) = math.hypot(*values), limits.AXIS_LENGTH
        if length == 0:
            return "must not be the zero vector"
        return None if lo <= length <= hi else f"a direction of length {length:.3g} (allowed: {lo:g} to {hi:g})"
    if rule in (PERPENDICULAR, NOT_PARALLEL):  # two axes (planar, universal joints), each of a valid length
        a1, a2 = np.array(values[:3]), np.array(values[3:])
        c = abs(a1 @ a2) / np.linalg.norm(a1) / np.linalg.norm(a2)
        if rule == PERPENDICULAR:
            return None if c <= 1e-9 else "the two in-plane axes must be perpendicular"
        return None if c <= 1 - 1e-9 else "the two axes of a universal joint must not be parallel"
    if rule == ROTATION:
        R = np.reshape(values, (3, 3))
        return None if np.allclose(R.T @ R, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0 else \
            "is not a proper rotation (orthonormal columns, determinant +1)"
    if rule == INERTIA:
        I = np.reshape(values, (3, 3))
        if not np.allclose(I, I.T, rtol=1e-9, atol=1e-12):
            return "the inertia tensor must be symmetric"
        lam = np.linalg.eigvalsh(I)
        tol = 1e-9 * max(1.0, abs(lam).max())
        if lam[0] < -tol:
            return f"the inertia tensor is not positive semi-definite (principal moments {lam[0]:.4g}, {lam[1]:.4g}, {lam[2]:.4g})"
        if lam[0] + lam[1] < lam[2] - tol:
            return f"principal moments {lam[0]:.4g}, {lam[1]:.4g}, {lam[2]:.4g} break the triangle inequality (I1 + I2 >= I3)"
        return None
    raise ValueError(f"unknown rule {rule}")


CARRIES_TEXT = "the bodies it carries have no mass or inertia, so its joint's motion is undetermined (singular mass matrix)"


class Domain:
    """The values a settable variable takes: lo..hi (each end open or closed), and 0 besides when `zero`; always
    finite. `text` says it for messages ("[1e-14, 1]")."""

    __slots__ = ("lo", "hi", "lo_open", "hi_open", "zero")

    def __init__(self, lo=-math.inf, hi=math.inf, lo_open=True, hi_open=True, zero=False):
        self.lo, self.hi, self.lo_open, self.hi_open, self.zero = lo, hi, lo_open, hi_open, zero

    def contains(self, v):
        if not math.isfinite(v):
            return False
        if self.zero and v == 0:
            return True
        return (v > self.lo if self.lo_open else v >= self.lo) and (v < self.hi if self.hi_open else v <= self.hi)

    @property
    def text(self):
        if self.lo == -math.inf and self.hi == math.inf:
            return "a finite number"
        lo = "(" if self.lo_open else "["
        hi = ")" if self.hi_open else "]"
        return ("0 or " if self.zero else "") + f"{lo}{self.lo:g}, {self.hi:g}{hi}"

    def flags(self):
        """The flags the compiled scene stores (mbs_layout.h: VD_*)."""
        return _layout.VD_LO_OPEN * self.lo_open | _layout.VD_HI_OPEN * self.hi_open | _layout.VD_ZERO * self.zero


ANY = Domain()  # a parameter: its derived numbers have the rules above; a start value y0.*/yd0.* has MAGNITUDE's


def integrator_domains(experiment):
    """{setting: Domain} of the integrator settings; fixed and largest steps must let the experiment end, and
    atol's weights 1/atol must square without overflow (below 1e-100 radau5 and gen_alpha get NaN errors)."""
    h_min = (experiment["stop"] - experiment["start"]) / (100 * limits.COMMUNICATION_POINTS)
    steps = Domain(h_min, limits.MAGNITUDE[1], False, False, zero=True)
    return {"rtol": Domain(*limits.RTOL, False, False), "atol": Domain(*limits.MAGNITUDE, False, False),
            "max_step": steps, "step": steps}


def variable_domain(name, spec):
    """Domain of an FMU variable (a parameter, an integrator setting; inputs: finite, else the next step's
    Discard)."""
    if name.startswith("integrator."):
        return integrator_domains(spec["experiment"]).get(name.split(".", 1)[1], ANY)
    return ANY
