"""FMI 2.0 model exchange of the native FMU (issue 27, item 1): the host integrates the engine's x = [y; ẏ].

References: fmpy's validation and its model-exchange solvers (CVode, explicit Euler) against `mbsfmu.simulate`
(the engine's own dop853 at rtol 1e-12); explicit Euler's first-order convergence; a numpy Euler loop over the
in-process engine's right-hand side for the plain C host's Euler loop (bit for bit); the FMI 2.0 model-exchange
state machine for hostile hosts (in child processes: a crash fails the test instead of killing pytest).
"""
from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy import read_model_description, simulate_fmu  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

import mbsfmu  # noqa: E402
from mbsfmu.fmu import native  # noqa: E402
from mbsfmu.compiler.variables import continuous_states, variables  # noqa: E402
from mbsfmu.simulation import Simulation  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODELS = [p.stem for p in sorted((REPO / "models").glob("*.yaml"))]
# Euler at small steps: rigid and quick (free_body: quaternions; the spinning top's 150 rad/s needs far smaller steps)
LIGHT = ["pendulum", "double_pendulum", "free_body", "driven_crank"]
STOP = 0.5  # seconds of each model's experiment the comparisons run

pytestmark = pytest.mark.skipif(native.compiler() is None, reason="no C compiler (cc, gcc, clang or $CC)")


def _scene(m):
    return mbsfmu.load(REPO / "models" / f"{m}.yaml")


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("me")
    with warnings.catch_warnings(), pytest.MonkeyPatch.context() as mp:
        warnings.simplefilter("ignore")
        mp.setattr(native, "MINGW", "no-mingw-in-this-test")  # linux64 only: model exchange is the same C
        return {m: mbsfmu.build_fmu(REPO / "models" / f"{m}.yaml", out, kind="native") for m in MODELS}


def _reference(m, stop=STOP, step=None, inputs=None):
    """The engine's own run at tight tolerance: {name: values} of y.* and yd.* at the communication points."""
    scene = _scene(m)
    t, Y, YD = mbsfmu.simulate(scene, stop=stop, step=step, inputs=inputs, method="dop853", rtol=1e-12, atol=1e-12)
    sim = Simulation(scene.spec)
    names = [f"y.{c}" for c in sim.coordinates] + [f"yd.{c}" for c in sim.velocity_coordinates]
    return t, dict(zip(names, np.hstack([Y, YD]).T))


def _states_of(result, ref):
    return {n: result[n] for n in ref}


# ---- the modelDescription -------------------------------------------------------------------------------
@pytest.mark.parametrize("m", MODELS)
def test_fmpy_validates_and_states_are_the_engines(built, m):
    """fmpy's validation passes; the continuous states are y.* then yd.* in the engine's order (the derivative
    attribute of each der(·) names its state), as many as the engine's x has."""
    assert validate_fmu(str(built[m])) == []
    md = read_model_description(str(built[m]), validate=True)
    assert md.modelExchange is not None and md.coSimulation is not None
    sim = Simulation(_scene(m).spec)
    expected = [f"y.{c}" for c in sim.coordinates] + [f"yd.{c}" for c in sim.velocity_coordinates]
    assert md.numberOfContinuousStates == sim.npos + sim.nvel == len(expected)
    assert [u.variable.derivative.name for u in md.derivatives] == expected
    assert [u.variable.name for u in md.derivatives] == [f"der({n})" for n in expected]
    assert md.numberOfEventIndicators == 0


def test_continuous_states_pair_each_state_with_its_derivative():
    """The list both FMI versions take (variables.continuous_states): units per second, value references after
    every other variable, nothing without derivatives."""
    spec = _scene("spinning_top").spec
    plain, with_der = variables(spec), variables(spec, derivatives=True)
    assert [v.name for v in with_der[:len(plain)]] == [v.name for v in plain] and not continuous_states(plain)
    pairs = continuous_states(with_der)
    assert [d.vr for _, d in pairs] == list(range(len(plain), len(with_der)))
    per_second = {"1": "1/s", "m": "m/s", "rad": "rad/s", "1/s": "1/s2", "m/s": "m/s2", "rad/s": "rad/s2"}
    assert all(d.unit == per_second[s.unit] and d.name == f"der({s.name})" for s, d in pairs)
    assert {s.unit for s, _ in pairs} >= {"1", "rad/s"}  # quaternion components and body rates


@pytest.mark.parametrize("m", ["spinning_top", "robot_arm_elastic", "free_body"])
def test_declared_derivative_dependencies_hold(built, m):
    """ModelStructure/Derivatives against the FMU's own numbers at a random state: a derivative with declared
    dependencies changes when one of them is perturbed and not when any other state is; "constant" ones equal
    their state."""
    from fmpy import extract
    from fmpy.fmi2 import FMU2Model
    import ctypes
    md = read_model_description(str(built[m]))
    s = FMU2Model(guid=md.guid, unzipDirectory=extract(str(built[m])), instanceName="deps",
                  modelIdentifier=md.modelExchange.modelIdentifier)
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    s.newDiscreteStates()
    s.enterContinuousTimeMode()
    nx, A = md.numberOfContinuousStates, ctypes.c_double * md.numberOfContinuousStates
    state_vr = [u.variable.derivative.valueReference for u in md.derivatives]
    x = np.random.default_rng(1).uniform(0.2, 0.9, nx)

    def der(xx):
        s.setContinuousStates(A(*xx), nx)
        dx = A()
        s.getDerivatives(dx, nx)
        return np.array(dx)

    base, declared = der(x), 0
    for k, u in enumerate(md.derivatives):
        if not u.dependencies:
            continue
        declared += 1
        on = {state_vr.index(d.valueReference) for d in u.dependencies}
        for j in range(nx):
            moved = der(x + np.eye(nx)[j] * 0.1)[k] != base[k]
            assert moved == (j in on), (u.variable.name, md.derivatives[j].variable.derivative.name)
        if set(u.dependenciesKind) == {"constant"}:
            assert base[k] == x[state_vr.index(u.dependencies[0].valueReference)]
    assert declared == sum(1 for v in md.modelVariables if v.name.startswith("y."))  # every der(y.*)
    s.terminate()
    s.freeInstance()


@pytest.mark.parametrize("m", MODELS)
def test_directional_derivatives_equal_central_differences(built, m):
    """fmi2GetDirectionalDerivative (the engine's complex step, engine/deriv.c) through fmpy: the Jacobian of the
    derivatives and outputs with respect to the states and inputs, one unit seed at a time, against 4th-order
    central differences of the FMU's own fmi2GetDerivatives / fmi2GetReal at a state off the trajectory (steps and
    agreement as tests/test_directional.py's); a seed over every known at once is the sum of the columns."""
    from fmpy import extract
    from fmpy.fmi2 import FMU2Model
    import ctypes
    from test_directional import POSITION_STEPS, STENCIL, assert_jacobians_agree
    md = read_model_description(str(built[m]))
    s = FMU2Model(guid=md.guid, unzipDirectory=extract(str(built[m])), instanceName="dd",
                  modelIdentifier=md.modelExchange.modelIdentifier)
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    s.newDiscreteStates()
    s.enterContinuousTimeMode()
    nx, A = md.numberOfContinuousStates, ctypes.c_double * md.numberOfContinuousStates
    rng = np.random.default_rng(4)
    x0, nominal = A(), A()
    s.getContinuousStates(x0, nx)
    s.getNominalsOfContinuousStates(nominal, nx)
    nominal = np.array(nominal)
    x = np.array(x0) + 0.1 * nominal * rng.standard_normal(nx)
    states = [u.variable.derivative for u in md.derivatives]
    inputs = [v for v in md.modelVariables if v.causality == "input"]
    outputs = [v for v in md.modelVariables if v.causality == "output" and v not in states]
    s.setReal([v.valueReference for v in inputs], list(rng.standard_normal(len(inputs))))
    s.setTime(0.2)
    s.setContinuousStates(A(*x), nx)
    knowns = [v.valueReference for v in states + inputs]
    unknowns = [u.variable.valueReference for u in md.derivatives] + [v.valueReference for v in outputs]

    def values():
        dx = A()
        s.getDerivatives(dx, nx)
        return np.r_[np.array(dx), s.getReal([v.valueReference for v in outputs])]

    def central_differences(step):
        ref = np.empty((len(unknowns), len(knowns)))
        for j, vr in enumerate(knowns):
            cols = []
            if j < nx:
                h = nominal[j] * (step if md.derivatives[j].variable.name.startswith("der(y.") else 1.0)
                for c, _ in STENCIL:
                    s.setContinuousStates(A(*(x + c * h * np.eye(nx)[j])), nx)
                    cols.append(values())
                s.setContinuousStates(A(*x), nx)
            else:
                h, (v0,) = 1.0, s.getReal([vr])
                for c, _ in STENCIL:
                    s.setReal([vr], [v0 + c * h])
                    cols.append(values())
                s.setReal([vr], [v0])
            ref[:, j] = sum(w * col for (_, w), col in zip(STENCIL, cols)) / h
        return ref

    J = np.array([s.getDirectionalDerivative(unknowns, knowns, list(e)) for e in np.eye(len(knowns))]).T
    assert_jacobians_agree(J, [central_differences(step) for step in POSITION_STEPS])
    ones = s.getDirectionalDerivative(unknowns, knowns, [1.0] * len(knowns))
    np.testing.assert_allclose(ones, J.sum(axis=1), rtol=1e-12, atol=1e-12 * np.abs(J).max())
    s.terminate()
    s.freeInstance()


def test_directional_derivative_refusals(built):
    """Before initialization, a parameter as a known, an input as an unknown, an unknown reference, a NaN seed:
    fmi2Error (the engine's messages: tests/test_directional.py), and the next good call answers."""
    from fmpy import extract
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Model
    md = read_model_description(str(built["pendulum"]))
    s = FMU2Model(guid=md.guid, unzipDirectory=extract(str(built["pendulum"])), instanceName="refusals",
                  modelIdentifier=md.modelExchange.modelIdentifier)
    s.instantiate()
    vr = {v.name: v.valueReference for v in md.modelVariables}
    der, y, param = vr["der(yd.theta)"], vr["y.theta"], next(v.valueReference for v in md.modelVariables
                                                              if v.causality == "parameter")
    with pytest.raises(FMICallException):  # instantiated: not yet
        s.getDirectionalDerivative([der], [y], [1.0])
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    for unknowns, knowns, seed in (([der], [param], [1.0]), ([vr["q.theta"]], [y], [1.0]), ([der], [10 ** 6], [1.0]),
                                   ([der], [y], [float("nan")])):
        with pytest.raises(FMICallException):
            s.getDirectionalDerivative(unknowns, knowns, seed)
    (d,) = s.getDirectionalDerivative([der], [y], [1.0])
    assert np.isfinite(d) and d < 0  # the pendulum's restoring stiffness, -g/L cos θ near rest
    s.terminate()
    s.freeInstance()


# ---- numbers: fmpy's solvers against the engine's run ----------------------------------------------------
@pytest.mark.parametrize("m", MODELS)
def test_cvode_equals_the_engine(built, m):
    """fmpy's CVode at rtol 1e-10 through model exchange = mbsfmu.simulate to 1e-6 of each signal's range
    (ranges below 1e-3 of the signal's size, or below 1e-3, count as that: CVode's tolerance is rtol × (|x| +
    nominal) per step, and a nearly constant signal has next to no range), elastic scenes too now that each state
    carries its nominal (variables.state_nominals; with nominals 1 their modal coordinates were off by up to 5e-6).
    spinup_beam to 1e-5: measured 4e-6 on its third mode's rate, which CVode's BDF carries less well than the
    others at this rtol (the same to 1e-7 at rtol 1e-12; its nominals are within 6x of its ranges over the whole
    experiment)."""
    fe_part = any("fe" in (b.get("elastic") or {}) for b in _scene(m).spec["bodies"])
    stop, step = (0.02, 1e-4) if fe_part else (STOP, None)  # FE parts: stiff, ≤ 500 CVode steps per point
    t, ref = _reference(m, stop=stop, step=step)
    r = simulate_fmu(str(built[m]), fmi_type="ModelExchange", solver="CVode", relative_tolerance=1e-10,
                     stop_time=stop, output_interval=t[1] - t[0])
    assert np.allclose(r["time"], t, rtol=0, atol=1e-12)
    for name, want in ref.items():
        scale = max(np.ptp(want), 1e-3 * np.abs(want).max(), 1e-3)
        err = np.abs(r[name] - want).max()
        assert err <= (1e-5 if m == "spinup_beam" else 1e-6) * scale, (name, err, scale)


@pytest.mark.parametrize("m", MODELS)
def test_nominals_reach_the_host(built, m):
    """fmi2GetNominalsOfContinuousStates answers the modelDescription's nominal of each state (what fmpy's CVode
    takes as atol / rtol), all positive; the derivative variables carry none (FMI asks for no consistency)."""
    from fmpy import extract
    from fmpy.fmi2 import FMU2Model
    import ctypes
    md = read_model_description(str(built[m]))
    declared = [u.variable.derivative.nominal for u in md.derivatives]
    assert all(v.nominal is None for v in (u.variable for u in md.derivatives))
    s = FMU2Model(guid=md.guid, unzipDirectory=extract(str(built[m])), instanceName="nominals",
                  modelIdentifier=md.modelExchange.modelIdentifier)
    s.instantiate()
    got = (ctypes.c_double * len(declared))()
    s.getNominalsOfContinuousStates(got, len(declared))  # fmpy raises on a status other than fmi2OK
    assert [float(x) for x in got] == [float(x) for x in declared] and min(got) > 0, m
    s.freeInstance()


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf")])
def test_compiled_nominals_and_corrupt_ones_refused(value):
    """The engine answers the variables' nominals (the compiled scene's D region at H_D_NOMINAL); a scene.bin
    whose nominal is not a positive finite number is refused when loaded (a host would divide by it)."""
    import struct
    from test_domains import _corrupt
    from mbsfmu.engine import EngineError, Instance, layout as L
    sim = Simulation(_scene("robot_arm_elastic").spec)
    states = {v.name: v.nominal for v in variables(sim.spec) if v.kind in (L.MBS_V_Y, L.MBS_V_YD)}
    assert Instance(sim.blob).nominals() == list(states.values())
    nsec = struct.unpack_from("<i", sim.blob, 72)[0]
    head = next(off for sid, _, off, _ in (struct.unpack_from("<iiqq", sim.blob, 76 + 24 * n) for n in range(nsec))
                if sid == L.S_HEADER)
    d_nominal = struct.unpack_from("<i", sim.blob, head + 4 * L.H_D_NOMINAL)[0]
    with pytest.raises(EngineError, match="corrupt nominal of continuous state 3"):
        Instance(_corrupt(sim.blob, L.S_D, d_nominal + 3, value))


def test_modal_nominal_is_the_static_deflection_under_gravity():
    """The flapwise bending mode of flexible_pendulum's clamped beam (tip-normalized) gets the nominal of its
    static deflection under the beam's own weight: Euler-Bernoulli's tip deflection ρA g L⁴ / (8 EI) (the first
    mode carries 97% of it, the rest the higher modes); angles 1, a length the scene's characteristic length."""
    from mbsfmu.compiler.model import Model
    from mbsfmu.compiler.variables import state_nominals
    model = Model(_scene("flexible_pendulum").spec)
    p = model.parameters
    pos, vel = state_nominals(model)
    tip = p["rhoA"] * 9.81 * p["L"] ** 4 / (8 * p["EI"])
    assert model.coordinates[1] == "beam.q1" and pos[0] == 1.0
    assert 0.97 < tip / pos[1] < 1.03, (pos[1], tip)
    T = np.sqrt(1.0 / 9.81)  # ℓ = 1 m: the beam's length
    np.testing.assert_allclose(vel, pos / T, rtol=1e-12)
    cart = Model(_scene("cart_pole").spec)
    assert state_nominals(cart)[0][0] == 0.5  # the cart's position: ℓ = the pole's center of mass at l/2


@pytest.mark.parametrize("m", LIGHT)
def test_euler_converges_at_first_order(built, m):
    """fmpy's explicit Euler through model exchange: the error at the end against the engine's run halves
    with the step (first order), and is small at the smallest step."""
    stop = 0.2
    t, ref = _reference(m, stop=stop, step=stop)
    errors = []
    for h in (4e-4, 2e-4, 1e-4):
        r = simulate_fmu(str(built[m]), fmi_type="ModelExchange", solver="Euler", step_size=h, stop_time=stop,
                         output_interval=h)
        assert abs(r["time"][-1] - stop) < 1e-9
        errors.append(max(abs(r[n][-1] - v[-1]) for n, v in ref.items()))
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(1.8 < q < 2.2 for q in ratios), (errors, ratios)
    assert errors[-1] < 1e-2


def test_cosimulation_of_the_same_fmu_is_the_engines_run(built):
    """The co-simulation interface of an FMU that also offers model exchange: fmpy's run equals the in-process
    run bit for bit (the same engine, the same steps)."""
    for m in ("double_pendulum", "spinning_top"):
        scene = _scene(m)
        t, Y, YD = mbsfmu.simulate(scene, stop=0.2)
        r = simulate_fmu(str(built[m]), fmi_type="CoSimulation", stop_time=0.2, output_interval=t[1] - t[0])
        sim = Simulation(scene.spec)
        got = np.array([r[f"y.{c}"] for c in sim.coordinates]).T
        assert got.shape == Y.shape and np.array_equal(got, Y), m


def test_inputs_and_drives_under_model_exchange(built):
    """A generalized-force input held by the host, through CVode (drives and time expressions: driven_crank in
    test_cvode_equals_the_engine)."""
    md = read_model_description(str(built["cart_pole"]))
    name = next(v.name for v in md.modelVariables if v.causality == "input" and v.name.startswith("q."))
    t, ref = _reference("cart_pole", inputs={name: 2.5})
    u = np.array([(0.0, 2.5), (STOP, 2.5)], dtype=[("time", float), (name, float)])
    r = simulate_fmu(str(built["cart_pole"]), fmi_type="ModelExchange", solver="CVode", relative_tolerance=1e-10,
                     stop_time=STOP, output_interval=t[1] - t[0], input=u)
    free = simulate_fmu(str(built["cart_pole"]), fmi_type="ModelExchange", solver="CVode",
                        relative_tolerance=1e-10, stop_time=STOP, output_interval=t[1] - t[0])
    for n, want in ref.items():
        assert np.abs(r[n] - want).max() <= 1e-6 * max(np.ptp(want), 1e-12), n
    assert max(np.abs(r[n][-1] - free[n][-1]) for n in ref) > 1e-2  # the input acts


# ---- the plain C host's model-exchange loop ---------------------------------------------------------------
def test_plain_c_host_euler_equals_a_numpy_euler_over_the_engine(built, tmp_path):
    """tests/c/fmu_host.c -E on every shipped model, in a mount namespace where every Python installation is
    hidden (no libpython mapped): x += h·ẋ over fmi2GetDerivatives, bit for bit the same numbers as the same loop
    in numpy over the in-process engine's right-hand side (mbs_rhs)."""
    from test_fmu_native import _unpack, run_without_python
    exe = tmp_path / "fmu_host"
    subprocess.run([native.compiler(), "-O2", "-o", str(exe), str(REPO / "tests/c/fmu_host.c"), "-ldl"], check=True)
    n, h = 40, 1e-4
    runs = {}
    for m in MODELS:
        d, md, _ = _unpack(built[m], tmp_path / m)
        states = [s.valueReference for s in (u.variable.derivative for u in md.derivatives)]
        lib = d / "binaries" / "linux64" / f"{md.modelExchange.modelIdentifier}.so"
        runs[m] = [str(exe), str(lib), (d / "resources").as_uri(), md.guid, "-E", "-x", str(len(states)),
                   "-n", str(n), "-h", str(h), "-o", ",".join(map(str, states)), "-p", "-m"]
    chunks = run_without_python(runs, tmp_path)
    for m, out in chunks.items():
        assert "LIBPYTHON no" in out and "DONE" in out, m
        rows = np.array([list(map(float, ln.split()[1:])) for ln in out.splitlines() if ln.startswith("OUT ")])
        sim = Simulation(_scene(m).spec)
        sim.initialize(0.0)
        x, t, want = sim.x.copy(), 0.0, [np.r_[0.0, sim.x]]
        for _ in range(n):
            x = x + h * sim.f(t, x)
            t += h
            want.append(np.r_[t, x])
        assert np.array_equal(rows, np.array(want)), (m, np.abs(rows - np.array(want)).max())


# ---- hostile hosts ----------------------------------------------------------------------------------------
HOSTILE = r'''
from fmpy.fmi2 import FMU2Model
import ctypes
fmu, work, pyfmu = sys.argv[1:4]
md = read_model_description(fmu)
d = fmpy.extract(fmu, os.path.join(work, "u"))
nx = md.numberOfContinuousStates
Arr = ctypes.c_double * nx
vr = {v.name: v.valueReference for v in md.modelVariables}


def model(tag):
    s = FMU2Model(guid=md.guid, unzipDirectory=d, modelIdentifier=md.modelExchange.modelIdentifier, instanceName=tag)
    s.instantiate(callbacks=cb)
    return s


def running(s):
    init(s)
    s.newDiscreteStates()
    s.enterContinuousTimeMode()


def states(s):
    x = Arr()
    s.getContinuousStates(x, nx)
    return list(x)


def derivatives(s):
    dx = Arr()
    s.getDerivatives(dx, nx)
    return list(dx)


out = {}
# calls out of the model-exchange order, each refused with fmi2Error and a message
s = model("order")
x = Arr()
out["states before init"] = [status(s.getContinuousStates, x, nx), logged("order", 0)]
out["time before init"] = [status(s.setTime, 0.1), logged("order", 0)[-1:]]
init(s)
k = len(LOG)
out["set states in event mode"] = [status(s.setContinuousStates, x, nx), logged("order", k)]
k = len(LOG)
out["do step"] = [status(s.dll.fmi2DoStep, ctypes.c_void_p(s.component), ctypes.c_double(0.0), ctypes.c_double(0.01), 1),
                  logged("order", k)]
s.newDiscreteStates()
s.enterContinuousTimeMode()
k = len(LOG)
out["discrete states in continuous mode"] = [status(s.newDiscreteStates), logged("order", k)]
k = len(LOG)
out["continuous twice"] = [status(s.enterContinuousTimeMode), logged("order", k)]
param = next(v for v in md.modelVariables if v.causality == "parameter" and v.variability == "tunable")
k = len(LOG)
out["parameter in continuous mode"] = [status(s.setReal, [param.valueReference], [1.0]), logged("order", k)]
k = len(LOG)
out["wrong nx"] = [status(s.getDerivatives, Arr(), nx - 1), logged("order", k)]
k = len(LOG)
out["NULL states"] = [status(s.fmi2SetContinuousStates, s.component, None, nx), logged("order", k)]
k = len(LOG)
out["NULL event flags"] = [status(s.fmi2CompletedIntegratorStep, s.component, 1, None, None), logged("order", k)]
k = len(LOG)
out["event indicators"] = [status(s.getEventIndicators, Arr(), 1), logged("order", k)]

# NaN states and time: refused, the instance unchanged against an untouched twin
twin = model("twin")
running(twin)  # s is in continuous-time mode since the refusals above
before = states(s)
bad = Arr(*before)
bad[nx - 1] = float("nan")
k = len(LOG)
out["NaN state"] = [status(s.setContinuousStates, bad, nx), logged("order", k)]
k = len(LOG)
out["NaN time"] = [status(s.setTime, float("nan")), logged("order", k)]
out["unchanged"] = states(s) == states(twin) and derivatives(s) == derivatives(twin) == derivatives(twin)
# a NaN input: the derivatives are refused, not computed from it; a finite value again and they come back
inp = [v.valueReference for v in md.modelVariables if v.causality == "input"][:1]
if inp:
    s.setReal(inp, [float("nan")])
    k = len(LOG)
    out["NaN input"] = [status(s.getDerivatives, Arr(), nx), logged("order", k)]
    s.setReal(inp, [0.0])
    out["input back"] = derivatives(s) == derivatives(twin)
# a model-exchange step moves it: the state set is the state read, derivatives follow
x1 = [a + 1e-3 * b for a, b in zip(states(s), derivatives(s))]
s.setTime(1e-3)
s.setContinuousStates(Arr(*x1), nx)
out["set is read"] = states(s) == x1 and s.getReal([vr[md.derivatives[0].variable.derivative.name]]) == x1[:1]
out["der variable"] = s.getReal([md.derivatives[-1].variable.valueReference]) == derivatives(s)[-1:]
# an FMU state taken while integrating restores the states, and the instance goes on integrating
saved, x2 = s.getFMUstate(), states(s)
s.setTime(2e-3)
s.setContinuousStates(Arr(*[a + 0.1 for a in x2]), nx)
s.setFMUstate(saved)
out["state restored"] = states(s) == x2 and status(s.setContinuousStates, Arr(*x2), nx) == 0
s.freeFMUstate(saved)
s.terminate(), twin.terminate()
s.freeInstance(), twin.freeInstance()

# the pythonfmu kind offers co-simulation only: model exchange is refused with a message, no instance
pmd = read_model_description(pyfmu)
pd = fmpy.extract(pyfmu, os.path.join(work, "p"))
lib = ctypes.CDLL(os.path.join(pd, "binaries", "linux64", pmd.coSimulation.modelIdentifier + ".so"))
lib.fmi2Instantiate.restype = ctypes.c_void_p
k = len(LOG)
c = lib.fmi2Instantiate(b"py", 0, pmd.guid.encode(), ("file://" + os.path.join(pd, "resources")).encode(),
                        ctypes.byref(cb), 0, 0)
out["pythonfmu ME"] = [c is None, [m[3] for m in LOG[k:]]]
print(json.dumps(out))
'''


def test_hostile_model_exchange_calls(built, tmp_path):
    """Out-of-order calls, wrong sizes, NULL pointers, NaN states, time and inputs: fmi2Error with a message
    naming the call, never a crash, the instance bit-identical to an untouched twin; the pythonfmu FMU refuses
    model exchange at fmi2Instantiate."""
    from test_fmu_hostile import FMPY_CHILD
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pyfmu = mbsfmu.build_fmu(REPO / "models" / "cart_pole.yaml", tmp_path / "py")
    r = subprocess.run([sys.executable, "-c", FMPY_CHILD + HOSTILE, str(built["cart_pole"]), str(tmp_path),
                        str(pyfmu)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.splitlines()[-1])
    calls = {"states before init": "fmi2GetContinuousStates", "time before init": "fmi2SetTime",
             "set states in event mode": "fmi2SetContinuousStates", "do step": "fmi2DoStep",
             "discrete states in continuous mode": "fmi2NewDiscreteStates",
             "continuous twice": "fmi2EnterContinuousTimeMode", "parameter in continuous mode": "fmi2SetReal",
             "wrong nx": "fmi2GetDerivatives", "NULL states": "fmi2SetContinuousStates",
             "NULL event flags": "fmi2CompletedIntegratorStep", "event indicators": "fmi2GetEventIndicators",
             "NaN state": "fmi2SetContinuousStates", "NaN time": "fmi2SetTime", "NaN input": "fmi2GetDerivatives"}
    for case, fn in calls.items():
        st, messages = out[case]
        assert st == 3, (case, st, messages)  # fmi2Error
        assert messages and all(m[0] == 3 for m in messages), (case, messages)
        assert fn in messages[-1][2] or case.startswith("NaN"), (case, messages)  # NaN: the engine's message
    assert "model exchange" in out["do step"][1][-1][2]
    assert "not finite" in out["NaN state"][1][-1][2] and "not finite" in out["NaN input"][1][-1][2]
    assert out["unchanged"] and out["input back"] and out["set is read"] and out["der variable"]
    assert out["state restored"]
    refused, messages = out["pythonfmu ME"]
    assert refused and any("co-simulation only" in m for m in messages), messages
