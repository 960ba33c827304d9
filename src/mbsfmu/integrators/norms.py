"""Hairer's weighted RMS error norm and finiteness checks (scalar-returning, few numpy calls)."""

import math

import numpy as np


def error_norm(err, x_old, x_new, atol, rtol):
    """Hairer's RMS norm of err / (atol + rtol * max(|x_old|, |x_new|))."""
    # one fused expression: each numpy call costs ~1 µs on tiny arrays, so keep the count low
    e = err / (atol + rtol * np.maximum(np.abs(x_old), np.abs(x_new)))
    return math.sqrt(e.dot(e) / e.size)


def rms(v):
    """Plain RMS norm sqrt(sum(v²)/n) of an already scaled vector."""
    return math.sqrt(v.dot(v) / v.size)


def all_finite(v):
    """True when every entry of v is finite (one reduction: a NaN/Inf makes the sum non-finite)."""
    s = v.dot(v) if v.ndim == 1 else float(np.sum(v * v))
    # v·v overflows to inf for huge-but-finite entries too; fall back to the exact test then
    return math.isfinite(s) or bool(np.isfinite(v).all())
