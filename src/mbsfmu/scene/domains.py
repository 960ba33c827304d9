"""Expressions in t over the experiment's time span: drives (with the velocity and acceleration the equations
use) and force values must stay finite and real at every sampled time, so that no run fails on a domain error."""

import math

import numpy as np

from ..expr import parse
from . import limits


def first_failure(expression, env, start, stop, derivatives=0):
    """None if `expression` and its first `derivatives` time derivatives are finite at DOMAIN_SAMPLES times in
    [start, stop] (both ends included), else a short text: which derivative failed, at what t and why."""
    e = parse(expression)
    if "t" not in e.names:
        return None
    funcs = [e]
    for _ in range(derivatives):
        funcs.append(funcs[-1].diff("t"))
    env = dict(env)
    for t in np.linspace(start, stop, limits.DOMAIN_SAMPLES):
        env["t"] = float(t)
        for k, f in enumerate(funcs):
            what = ("the value", "the first time derivative", "the second time derivative")[k]
            try:
                v = f(env)
            except ZeroDivisionError:
                return f"{what} divides by zero at t = {t:g}"
            except (ValueError, OverflowError, TypeError) as err:  # math domain, overflow, a complex power
                return f"{what} cannot be evaluated at t = {t:g} ({err})"
            if not math.isfinite(v):
                return f"{what} is {v} at t = {t:g}"
    return None
