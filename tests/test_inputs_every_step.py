"""Inputs that change at every communication point (what a co-simulation master does), for every method of the
engine, against closed forms of the held-input solution (docs/python-api.md: sampled at t_k, held to t_k+1).

The integrator restarts at each point with the new input; a dense-output step computed past the point used to
stand in for it (the point interpolated in a step far longer than the interval) and lost accuracy, on a free mass
all of it: dopri5 2e-3 off at rtol 1e-10."""

import numpy as np
import pytest

import mbsfmu
from mbsfmu.engine import layout

METHODS = list(layout.METHODS)
M, K = 2.0, 50.0  # mass (kg), spring stiffness (N/m) of the spring case


def slider(stiffness=None):
    """One body on a prismatic joint along x (gravity along −z, across it): coordinate x.s, input q.x.s."""
    spring = (f"forces:\n  - {{type: spring_damper, bodies: [world, x], at: [[0, 0, 0], [0, 0, 0]], "
              f"stiffness: {stiffness}, damping: 0, length: 0}}\n" if stiffness else "")
    return mbsfmu.loads(f"""mbsfmu: 1
name: slider
gravity: [0, 0, -9.81]
bodies:
  x:
    parent: world
    joint: {{type: prismatic, axis: [1, 0, 0]}}
    mass: {M}
    inertia: {{xx: 0.01, yy: 0.01, zz: 0.01}}
{spring}experiment: {{start: 0, stop: 3, step: 0.1}}
""")


def ramp(t):
    return min(5 * t, max(0.0, 5 * (2 - t)))  # up to 5 N at t = 1, back to 0 at t = 2, then 0


def free_mass_exact(force, h, n):
    """x_k of a free mass from rest under a force held over each interval: piecewise quadratic."""
    x = v = 0.0
    xs = [x]
    for k in range(n):
        f = force(k * h)
        x, v = x + v * h + f * h * h / (2 * M), v + f * h / M
        xs.append(x)
    return np.array(xs)


def spring_exact(force, h, n):
    """x_k of the mass on a spring (ω² = K/M) under a held force: a harmonic motion about F/K in each interval.
    Also the phasors d_k = (x − F/K) + i·v/ω at the start of each interval (for rk4's truncation bound)."""
    w = np.sqrt(K / M)
    c, s = np.cos(w * h), np.sin(w * h)
    x = v = 0.0
    xs, ds = [x], []
    for k in range(n):
        xe = force(k * h) / K
        ds.append(complex(x - xe, v / w))
        x, v = xe + (x - xe) * c + v / w * s, -(x - xe) * w * s + v * c
        xs.append(x)
    return np.array(xs), np.array(ds), w


def run(scene, method, rtol, h, stop, force):
    t, Y, _ = mbsfmu.simulate(scene, stop=stop, step=h, method=method, rtol=rtol, atol=1e-2 * rtol,
                              inputs=lambda t: {"q.x.s": force(t)})
    return Y[:, 0]


@pytest.mark.parametrize("method", METHODS)
def test_free_mass_pushed_by_a_ramp_is_exact(method):
    """The held force makes x quadratic in t over each interval, which every method (order >= 2) integrates
    exactly: the restarts at the 30 points may cost rounding only. Before: dopri5/auto 2e-3, radau5 9e-7,
    dop853 2e-9 off at rtol 1e-10 (at rtol 1e-6: 0.38, 2e-4, 9e-5)."""
    exact = free_mass_exact(ramp, 0.1, 30)
    for rtol in (1e-6, 1e-10):
        x = run(slider(), method, rtol, 0.1, 3.0, ramp)
        assert np.max(np.abs(x - exact)) <= 1e-12 * np.max(np.abs(exact)), (rtol, np.max(np.abs(x - exact)))


def wavy(t):
    return 10 * np.sin(4 * t) + 5 * (t > 1)


@pytest.mark.parametrize("method", METHODS)
def test_mass_on_a_spring_with_a_new_force_every_step_meets_the_tolerance(method):
    """300 points of 0.01 s, the force resampled at each. The adaptive methods must stay within a few times
    the tolerance asked for (before: dopri5 15×, radau5 2700× at rtol 1e-10); gen_alpha (order 2, step
    doubling) takes 10³–10⁴ steps whose local errors add up, so 100×. rk4 takes one step per interval (its
    `integrator.step` 0): its error is its truncation, |R(iωh) − e^(iωh)| per step times the phasor of the
    motion, summed (R: RK4's stability polynomial)."""
    h, n = 0.01, 300
    exact, phasors, w = spring_exact(wavy, h, n)
    scale = np.max(np.abs(exact))
    for rtol in (1e-6, 1e-9):
        err = np.max(np.abs(run(slider(K), method, rtol, h, n * h, wavy) - exact))
        if method == "rk4":
            z = 1j * w * h
            bound = 1.5 * abs(1 + z + z ** 2 / 2 + z ** 3 / 6 + z ** 4 / 24 - np.exp(z)) * np.sum(np.abs(phasors))
        else:
            bound = (100 if method == "gen_alpha" else 10) * (rtol * scale + 1e-2 * rtol)
        assert err <= bound, (rtol, err, bound)
