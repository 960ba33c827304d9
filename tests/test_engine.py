"""The C engine (mbsfmu.engine) against the numpy reference of the seed equations (equations/tree.py, which
Pinocchio checks independently in test_pinocchio.py and test_drives.py): every joint type, force element,
drive and input, parameter re-binding inside the engine; the instance's variables and checked state bytes."""

import glob
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.engine import EngineError
from mbsfmu.errors import IntegrationError
from mbsfmu.simulation import Simulation, simulate

REPO = Path(__file__).resolve().parent.parent
RIGID = [p for p in sorted(glob.glob(str(REPO / "models" / "*.yaml")) + glob.glob(str(REPO / "models" / "stress" / "*.yaml")))
         if "elastic" not in Path(p).read_text() and "flexible" not in p and "spinup" not in p]

# every joint type, both rotation parameterizations, every force element, a drive and force inputs
ALL_FEATURES = """
mbsfmu: 1
name: all_features
parameters: {k: 40.0, w: 2.0}
gravity: [0.2, -0.4, -9.81]
bodies:
  base:
    parent: world
    joint: {type: planar, axes: [[1, 0, 0], [0, 1, 0]], at: [0.1, 0, 0.2], rotation: {axis: [1, 2, 3], angle: 0.4}}
    mass: 2.0
    center_of_mass: [0.1, 0.05, 0]
    inertia: [[0.2, 0.01, 0], [0.01, 0.3, 0], [0, 0, 0.25]]
  cyl:
    parent: base
    joint: {type: cylindrical, axis: [0, 0.6, 0.8], at: [0.3, 0, 0]}
    mass: 1.0
    center_of_mass: [0, 0, 0.2]
    inertia: [[0.05, 0, 0], [0, 0.04, 0], [0, 0, 0.02]]
  uni:
    parent: cyl
    joint: {type: universal, axes: [[1, 0, 0], [0, 1, 0]], at: [0, 0, 0.4], drive: {uni.angle1: "0.3*sin(w*t)"}}
    mass: 0.7
    center_of_mass: [0.1, 0, 0]
    inertia: [[0.01, 0, 0], [0, 0.02, 0], [0, 0, 0.02]]
  ball:
    parent: uni
    joint: {type: spherical, parameterization: cardan, at: [0.2, 0, 0]}
    mass: 0.5
    center_of_mass: [0, 0.1, 0]
    inertia: [[0.01, 0, 0], [0, 0.012, 0], [0, 0, 0.015]]
  flyer:
    parent: world
    joint: {type: free, parameterization: cardan, at: [0, 1, 0]}
    mass: 1.5
    center_of_mass: [0.02, 0, 0.01]
    inertia: [[0.1, 0, 0.01], [0, 0.12, 0], [0.01, 0, 0.09]]
  puck:
    parent: flyer
    joint: {type: free, at: [0.2, 0, 0]}
    mass: 0.3
    inertia: [[0.002, 0, 0], [0, 0.003, 0], [0, 0, 0.004]]
  slider:
    parent: puck
    joint: {type: prismatic, axis: [1, 1, 0]}
    mass: 0.2
    inertia: [[0.001, 0, 0], [0, 0.001, 0], [0, 0, 0.001]]
  top:
    parent: slider
    joint: {type: spherical, at: [0, 0, 0.1]}
    mass: 0.4
    center_of_mass: [0, 0, 0.05]
    inertia: [[0.003, 0, 0], [0, 0.003, 0], [0, 0, 0.005]]
forces:
  - {type: joint_spring_damper, coordinate: slider.s, stiffness: k, damping: 0.3, offset: 0.05}
  - {type: spring_damper, bodies: [world, ball], at: [[0, 0, 1], [0.1, 0, 0]], stiffness: k, damping: 0.5, length: 0.4}
  - {type: spring_damper, bodies: [flyer, top], at: [[0, 0.1, 0], [0, 0, 0.1]], stiffness: 15, damping: 0.2, length: 0.1}
  - {type: force, body: cyl, at: [0, 0.1, 0], frame: body, value: ["sin(t)", 0, "2*cos(w*t)"]}
  - {type: torque, body: ball, frame: world, value: [0.1, -0.2, 0.3]}
  - {type: force, body: puck, at: [0.01, 0, 0], frame: body, input: F_puck}
  - {type: torque, body: flyer, frame: body, input: T_flyer}
"""




def _random_state(ev, rng):
    y = rng.normal(size=len(ev.coordinates)) * 0.5
    for qi in ev.model.quaternions:
        y[qi] /= np.linalg.norm(y[qi])
    return y, rng.normal(size=len(ev.velocity_coordinates))


def _compare(spec, rng, t=0.37, params=None):
    """M, k, q, ẋ and output points of the engine and of the numpy reference at a random state and inputs."""
    ev, sim = mbsfmu.compile(spec), Simulation(spec)
    for name, value in (params or {}).items():
        sim.set(name, value)
    ev.set_parameters(params or {})
    y, yd = _random_state(ev, rng)
    u = {n: rng.normal() for n in ev.inputs}
    for name, value in u.items():
        sim.set(name, value)
    M, k, q = ev.equations(y, yd, t, u)
    x = np.concatenate([y, yd])
    M2, k2, q2 = sim.engine.equations(t, x)
    scale = max(1.0, np.abs(M).max(), np.abs(k).max(), np.abs(q).max())
    for a, b in ((M, M2), (k, k2), (q, q2)):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * scale)
    ref = np.concatenate([ev.position_rates(y, yd), np.linalg.solve(M, q - k)])
    np.testing.assert_allclose(sim.f(t, x), ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    got, want = sim.output_values(x, t), ev.output_values(y, yd, t)
    assert set(got) == set(want)
    for name in want:
        assert abs(got[name] - want[name]) <= 1e-12 * max(1.0, abs(want[name]))


@pytest.mark.parametrize("path", RIGID, ids=lambda p: Path(p).stem)
def test_shipped_rigid_scenes_agree_with_numpy_reference(path):
    _compare(mbsfmu.load(path).spec, np.random.default_rng(3))


def test_every_joint_force_element_drive_and_input_agrees_with_numpy_reference():
    spec = mbsfmu.loads(ALL_FEATURES).spec
    rng = np.random.default_rng(11)
    for t in (0.0, 0.37, 1.9):
        _compare(spec, rng, t)


def test_parameters_rebind_inside_the_engine():
    """Parameters feed stiffnesses (k) and a drive's frequency (w): the engine's bind and time programs."""
    _compare(mbsfmu.loads(ALL_FEATURES).spec, np.random.default_rng(5), params={"k": 400.0, "w": 0.5})
    spec = mbsfmu.load(REPO / "models" / "double_pendulum.yaml").spec
    _compare(spec, np.random.default_rng(6), params={p["name"]: 1.7 * p["value"] for p in spec["parameters"]})


def test_initial_state_and_start_values():
    spec = mbsfmu.load(REPO / "models" / "double_pendulum.yaml").spec
    ev, sim = mbsfmu.compile(spec), Simulation(spec)
    y0, yd0 = ev.initial_state()
    assert [sim.get(f"y.{c}") for c in ev.coordinates] == list(y0)
    sim.set(f"y0.{ev.coordinates[0]}", 0.25)
    sim.set(f"yd0.{ev.velocity_coordinates[1]}", -1.5)
    sim.initialize(0.0)
    assert sim.get(f"y.{ev.coordinates[0]}") == 0.25 and sim.get(f"yd.{ev.velocity_coordinates[1]}") == -1.5


def test_singular_mass_matrix_is_a_clean_integration_error():
    scene = mbsfmu.loads("""
mbsfmu: 1
name: massless
bodies:
  arm: {parent: world, joint: {type: revolute, axis: [0, 0, 1]}, mass: 1, inertia: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}
""")
    arm = scene.spec["bodies"][0]   # load refuses a massless moving body; the engine must still fail cleanly on one
    arm["mass"], arm["inertia"] = 0.0, [[0.0] * 3 for _ in range(3)]
    sim = Simulation(scene.spec)
    sim.initialize(0.0)
    with pytest.raises(IntegrationError, match="singular"):
        sim.do_step(0.0, 0.1)
    assert sim.time == 0.0


def test_the_right_hand_side_from_python_takes_arrays_as_they_are_and_refuses_what_would_overrun():
    """Instance.rhs (fastcall.c where it is built, else ctypes): ẋ bit-identical to the ctypes call on every shipped
    model; lists and other dtypes converted; short or read-only arrays refused before the engine reads or writes
    them; a singular M raised with the engine's message, on both calls."""
    import mbsfmu.engine as E
    for path in sorted(glob.glob(str(REPO / "models" / "*.yaml"))):
        sim = Simulation(mbsfmu.load(path).spec)
        sim.initialize(0.0)
        x = np.array(sim.engine.state()) + 0.01
        a, b = np.empty(sim.engine.n), np.empty(sim.engine.n)
        assert sim.engine.rhs(0.3, x, a) is a
        sim.engine._rhs_slow(0.3, x, b)
        assert np.array_equal(a, b)
        assert np.array_equal(sim.engine.rhs(0.3, list(x)), b) and np.array_equal(sim.f(0.3, x.astype(np.float32)),
                                                                                   sim.engine.rhs(0.3, x.astype(np.float32), b))
    n, out = sim.engine.n, np.empty(sim.engine.n)
    for bad_x, bad_out in ((x[:-1], out), (x, out[:-1]), (x, np.empty((n, 2))[:, 0]), (x, np.empty(n, np.float32))):
        with pytest.raises(ValueError, match="float64"):
            sim.engine.rhs(0.0, bad_x, bad_out)
    frozen = np.empty(n)
    frozen.flags.writeable = False
    with pytest.raises(ValueError, match="writable"):
        sim.engine.rhs(0.0, x, frozen)
    import sysconfig
    if (Path(sysconfig.get_paths()["include"]) / "Python.h").exists():  # else Instance.rhs is the ctypes call
        assert E._fastcall(), "fastcall.c builds wherever there are the Python headers"
    scene = mbsfmu.loads("mbsfmu: 1\nname: massless\nbodies:\n  arm: {parent: world, joint: {type: revolute, axis: "
                         "[0, 0, 1]}, mass: 1, inertia: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}")
    scene.spec["bodies"][0].update(mass=0.0, inertia=[[0.0] * 3 for _ in range(3)])
    sim = Simulation(scene.spec)
    sim.initialize(0.0)
    for call in (sim.engine.rhs, sim.engine._rhs_slow):
        with pytest.raises(EngineError, match="singular"):
            call(0.0, np.zeros(2), np.empty(2))


# the shipped pendulum (models/pendulum.yaml): θ̈ = −g sin θ (m_rod L/2 + m_bob L) / I_O about the hinge
PENDULUM = dict(L=0.8, m_rod=0.3, m_bob=1.0, r_bob=0.031, g=9.81)


def _pendulum_acceleration(theta, L, m_rod, m_bob, r_bob, g):
    inertia = m_rod * L ** 2 / 12 + m_rod * (L / 2) ** 2 + 0.4 * m_bob * r_bob ** 2 + m_bob * L ** 2
    return -g * np.sin(theta) * (m_rod * L / 2 + m_bob * L) / inertia


def _pendulum():
    sim = Simulation(mbsfmu.load(REPO / "models" / "pendulum.yaml").spec)
    sim.initialize(0.0)
    return sim


def test_out_sharing_memory_with_x_gives_the_answer_of_a_separate_out():
    """rhs(t, x, out=x), a view of x as out, and an out shifted by one number inside x's buffer: the same ẋ as into
    a separate array (the closed form of the pendulum; the double pendulum's with out apart), on the fast and the
    ctypes call alike."""
    sim = _pendulum()
    for call in (sim.engine.rhs, sim.engine._rhs_slow):
        x = np.array([0.3, 2.0])
        assert call(0.0, x, x) is x
        assert x[0] == 2.0 and x[1] == pytest.approx(_pendulum_acceleration(0.3, **PENDULUM), rel=1e-12)
    sim = Simulation(mbsfmu.load(REPO / "models" / "double_pendulum.yaml").spec)
    sim.initialize(0.0)
    n, x0 = sim.engine.n, np.array(sim.engine.state()) + 0.1
    expected = sim.engine.rhs(0.0, x0.copy(), np.empty(n))
    for call in (sim.engine.rhs, sim.engine._rhs_slow):
        x = x0.copy()
        assert np.array_equal(call(0.0, x, x), expected)
        x = x0.copy()
        assert np.array_equal(call(0.0, x, x[:]), expected) and np.array_equal(x, expected)
        buf = np.concatenate([x0, [0.0]])
        assert np.array_equal(call(0.0, buf[:n], buf[1:]), expected) and np.array_equal(buf[1:], expected)


def test_a_bound_rhs_outlives_its_simulation():
    """Instance.rhs taken, the Simulation dropped and collected, its memory reused (and freed memory filled with
    junk by malloc: MALLOC_PERTURB_): the call still gives the pendulum's closed form, with and without out (it
    holds the engine's instance; before, it read freed memory and crashed). In a child process, so a crash fails
    the test. The Instance itself frees as soon as it is dropped, not at a collection (no cycle through its call)."""
    import json
    import os
    import subprocess
    import sys
    child = f"""
import gc, json, weakref, numpy as np, mbsfmu
from mbsfmu.simulation import Simulation
def bound():
    sim = Simulation(mbsfmu.load({str(REPO / "models" / "pendulum.yaml")!r}).spec)
    sim.initialize(0.0)
    return sim.engine.rhs, weakref.ref(sim.engine)
gc.disable()
_, engine = bound()
freed_at_once = engine() is None
f, engine = bound()
gc.collect()
junk = [np.full(1000, 7.0) for _ in range(1000)]
print(json.dumps([freed_at_once, engine() is None, list(f(0.0, np.array([0.3, 2.0]), np.empty(2))),
                  list(f(0.0, [0.3, 2.0]))]))
"""
    r = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, timeout=120,
                       env=dict(os.environ, MALLOC_PERTURB_="165"))
    assert r.returncode == 0, r.stderr[-2000:]
    freed_at_once, collected, into_out, new_array = json.loads(r.stdout)
    expected = [2.0, pytest.approx(_pendulum_acceleration(0.3, **PENDULUM), rel=1e-12)]
    assert collected and into_out == expected and new_array == expected
    assert freed_at_once  # (with the collector off)


def test_non_finite_derivatives_are_refused_with_a_message():
    """At a finite but extreme state (θ̇ = 1e200: θ̇² overflows inside) ẋ is not a number: rhs (both calls),
    Simulation.f, model exchange's derivatives and the directional and adjoint derivatives raise naming the entry,
    never return NaN; the same instance at an ordinary state gives the closed form after."""
    from mbsfmu.engine import Instance
    from mbsfmu.simulation import compiled
    sim = _pendulum()
    x = np.array([0.3, 1e200])
    for call in (sim.engine.rhs, sim.engine._rhs_slow, lambda t, x, out=None: sim.f(t, x)):
        with pytest.raises(IntegrationError, match=r"time derivative of yd\.theta is -?nan, not finite"):
            call(0.0, x, np.empty(2))
        out = x.copy()
        with pytest.raises(IntegrationError, match="not finite"):
            sim.engine.rhs(0.0, out, out)
        assert np.array_equal(out, x)  # out = x: refused before anything is written
    assert sim.f(0.0, [0.3, 2.0])[1] == pytest.approx(_pendulum_acceleration(0.3, **PENDULUM), rel=1e-12)
    blob, _, _ = compiled(sim.spec, derivatives=True)
    inst = Instance(blob)
    inst.initialize(0.0)
    names = inst.model.variable_names()
    der, states = [names.index("der(yd.theta)")], [names.index("y.theta"), names.index("yd.theta")]
    inst.set_state(x)
    with pytest.raises(IntegrationError, match=r"time derivative of yd\.theta .* not finite"):
        inst.derivatives()
    with pytest.raises(IntegrationError, match=r"directional derivative of der\(yd\.theta\) .* not finite"):
        inst.directional_derivative(der, states, [0.0, 1.0])
    with pytest.raises(IntegrationError, match=r"adjoint derivative's entry of y\.theta .* not finite"):
        inst.adjoint_derivative(der, states, [1.0])
    inst.set_state([0.3, 2.0])
    assert inst.derivatives()[1] == pytest.approx(_pendulum_acceleration(0.3, **PENDULUM), rel=1e-12)
    # ∂θ̈/∂θ = −g cos θ (m_rod L/2 + m_bob L) / I_O
    assert inst.directional_derivative(der, states, [1.0, 0.0])[0] == \
        pytest.approx(_pendulum_acceleration(0.3, **PENDULUM) / np.tan(0.3), rel=1e-10)


def test_wrong_calls_are_refused_with_a_message():
    sim = Simulation(mbsfmu.load(REPO / "models" / "pendulum.yaml").spec)
    with pytest.raises(KeyError):
        sim.set(f"y.{sim.coordinates[0]}", 1.0)
    with pytest.raises(EngineError, match="valid: rk4, dopri5"):
        sim.set("integrator.method", "euler")
    sim.initialize(0.0)
    with pytest.raises(EngineError, match="fixed"):
        sim.set("integrator.rtol", 1e-3)
    with pytest.raises(EngineError, match="simulation is at"):
        sim.do_step(1.0, 0.1)


def test_state_bytes_restore_bit_identical_and_refuse_foreign_or_corrupt_bytes():
    spec = mbsfmu.loads(ALL_FEATURES).spec
    a = Simulation(spec)
    a.set("F_puck.x", 0.3)
    a.initialize(0.0)
    for k in range(5):
        a.do_step(0.01 * k, 0.01)
    state = a.get_state()
    a.do_step(0.05, 0.01)
    expected = a.x
    b = Simulation(spec)  # a fresh instance continues bit for bit
    b.set_state(state)
    b.do_step(0.05, 0.01)
    assert np.array_equal(b.x, expected)
    before = b.x
    other = Simulation(mbsfmu.load(REPO / "models" / "pendulum.yaml").spec)
    other.initialize(0.0)
    rng = np.random.default_rng(0)
    flipped = bytearray(state)
    flipped[len(state) // 2] ^= 1
    bad = [state[:-1], state + b"x", b"", bytes(rng.integers(0, 256, len(state), dtype=np.uint8)),
           other.get_state(), bytes(flipped)]
    for data in bad:
        with pytest.raises(EngineError, match="state unchanged"):
            b.set_state(data)
        assert np.array_equal(b.x, before)


def test_simulate_input_function_is_held_between_points():
    """An input function is sampled at communication points: the same as setting it before each step."""
    spec = mbsfmu.load(REPO / "models" / "pendulum.yaml").spec
    name = "q." + Simulation(spec).velocity_coordinates[0]
    t, Y, _ = simulate(spec, stop=0.5, step=0.01, inputs=lambda t: {name: 1.0 if t < 0.2 else 0.0})
    sim = Simulation(spec)
    sim.initialize(0.0)
    for k in range(len(t) - 1):
        sim.set(name, 1.0 if t[k] < 0.2 else 0.0)
        sim.do_step(t[k], t[k + 1] - t[k])
    assert np.array_equal(sim.y, Y[-1])


SHIPPED_WITH_OUTPUTS = [p for p in sorted(glob.glob(str(REPO / "models" / "*.yaml")))
                        if mbsfmu.load(p).spec["outputs"]]


@pytest.mark.parametrize("method", ["rk4", "dopri5", "radau5", "gen_alpha"])
@pytest.mark.parametrize("path", SHIPPED_WITH_OUTPUTS, ids=lambda p: Path(p).stem)
def test_reading_output_points_between_steps_changes_nothing(path, method):
    """The output points read after a step share one kinematics pass with the next step's first stage (or an
    FSAL method's last stage): the trajectory with outputs read at every point equals, bit for bit, the one
    with none read, and every value read equals a fresh instance's (no kinematics kept) at that state."""
    spec = mbsfmu.load(path).spec
    runs = []
    for read in (False, True):
        sim = Simulation(spec)
        sim.set("integrator.method", method)
        sim.set("integrator.step", 1e-4)  # rk4 stable on the elastic arm
        names = [v.name for v in sim.variables if v.causality == "output" and not v.name.startswith(("y.", "yd."))]
        sim.initialize(0.0)
        fresh = Simulation(spec)
        X, read_values = [], []
        for k in range(25):
            sim.do_step(k * 0.01, 0.01)
            X.append(sim.x)
            if read:
                read_values.append([sim.get(n) for n in names])
                want = Simulation(spec).output_values(sim.x, sim.time)
                assert read_values[-1] == [want[n] for n in names]
        runs.append(np.array(X))
    assert np.array_equal(runs[0], runs[1])


def test_output_points_follow_a_parameter_set_at_the_same_state():
    """Outputs read, a length changed, outputs read again at the same (t, x): the new geometry, not the
    kinematics kept from before."""
    spec = mbsfmu.load(REPO / "models" / "pendulum.yaml").spec
    sim = Simulation(spec)
    sim.initialize(0.0)
    sim.do_step(0.0, 0.1)
    before = sim.get("bob.r.z")
    sim.set("L", 2.0)
    after = sim.get("bob.r.z")
    ref = Simulation(spec)
    ref.set("L", 2.0)
    assert after == ref.output_values(sim.x, sim.time)["bob.r.z"] and after != before


def test_an_unstable_step_that_breaks_the_mass_matrix_says_so():
    """rk4 at 0.25 ms on the elastic arm grows its stiff modes until M is indefinite (t ≈ 0.013 s): the message
    names the unstable step and the remedies, not massless bodies (M was regular at the start)."""
    sim = Simulation(mbsfmu.load(REPO / "models" / "robot_arm_elastic.yaml").spec)
    sim.set("integrator.method", "rk4")
    sim.set("integrator.step", 2.5e-4)
    with pytest.raises(IntegrationError, match="unstable step .*radau5") as e:
        sim.run(np.linspace(0.0, 0.1, 11))
    assert 0.0 < e.value.t < 0.1


@pytest.mark.parametrize("model,method", [("spinning_top", "dop853"), ("driven_crank", "auto"),
                                          ("driven_crank", "rk4")])
def test_step_observer_shows_each_internal_point_and_refuses_changes(model, method):
    """mbs_set_step_observer: inside mbs_do_step at each internal point and the end, the instance shows that
    point (time, state, output points as a fresh instance computes them there: not the step's end), refuses
    steps, settings and state changes with a message; afterwards it is at the end, bit for bit where an
    instance without an observer is."""
    from mbsfmu.engine.api import STEP_OBSERVER
    spec = mbsfmu.load(REPO / "models" / f"{model}.yaml").spec
    sims = [Simulation(spec), Simulation(spec)]
    names = [v.name for v in sims[0].variables if v.causality == "output" and not v.name.startswith(("y.", "yd."))]
    seen, refusals = [], []
    sim = sims[0]

    def observe(env, t, x):
        xs = np.ctypeslib.as_array(x, (sim.engine.n,)).copy()
        seen.append((t, sim.engine.time, xs, sim.x, [sim.get(n) for n in names]))
        for call in (lambda: sim.engine.do_step(t, 0.01), lambda: sim.engine.set_state(xs),
                     lambda: sim.set("integrator.rtol", 1e-3), lambda: sim.engine.reset()):
            with pytest.raises(EngineError) as e:
                call()
            refusals.append(str(e.value))

    cb = STEP_OBSERVER(observe)
    assert sim.engine.lib.mbs_set_step_observer(sim.engine.ptr, cb, None) == 0
    for s in sims:
        s.set("integrator.method", method)
        s.set("integrator.step", 0.002)
        s.initialize(0.0)
    fresh = Simulation(spec)
    for k in range(5):
        n0 = len(seen)
        for s in sims:
            s.do_step(k * 0.01, 0.01)
        assert np.array_equal(sims[0].x, sims[1].x) and sims[0].engine.time == sims[1].engine.time == (k + 1) * 0.01
        step = seen[n0:]
        assert step[-1][0] == sims[0].engine.time and all(k * 0.01 < t for t, *_ in step)
        assert np.array_equal(step[-1][2], sims[0].x)
        for t, time, x, shown, values in step:
            assert time == t and np.array_equal(x, shown)
            want = fresh.output_values(x, t)
            assert values == [want[n] for n in names], (t, values)
        assert len({tuple(v) for *_, v in step}) == len(step)  # each point's own outputs
    assert len(seen) > 5  # internal points besides the ends
    assert refusals and all("not allowed while the step observer runs" in m for m in refusals), refusals[:4]
