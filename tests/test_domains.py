"""Values a host sets go through the checks the loader applies to a scene (issue 22, items 8 and 4).

Every settable variable has one domain and every number a parameter derives the loader's rules
(scene/domains.py); the engine applies the same table, written into the compiled scene, when a host sets a
value: fmi2SetReal of both FMU kinds, Simulation.set and sweeps. The references are the loader's verdicts on the
same numbers written into a scene (numpy's eigvalsh for the inertia), closed forms, and an untouched twin.
"""
from __future__ import annotations

import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest

import mbsfmu
from mbsfmu.errors import ModelError
from mbsfmu.scene import loads
from mbsfmu.simulation import Simulation

from test_fmu_hostile import CC, FMPY_CHILD, REPO

RULES = """mbsfmu: 1
name: rules
parameters: {{Ixx: {Ixx!r}, Iyy: {Iyy!r}, Izz: {Izz!r}, Ixy: {Ixy!r}, Ixz: {Ixz!r}, Iyz: {Iyz!r}, ax: {ax!r},
              ay: {ay!r}, az: {az!r}, m: {m!r}, k: {k!r}, c: {c!r}}}
bodies:
  arm:
    parent: world
    joint: {{type: revolute, axis: [ax, ay, az]}}
    mass: m
    center_of_mass: [c, 0, 0]
    inertia: {{xx: Ixx, yy: Iyy, zz: Izz, xy: Ixy, xz: Ixz, yz: Iyz}}
  tip:
    parent: arm
    joint: {{type: revolute, axis: [0, 1, 0], at: [0.5, 0, 0]}}
    mass: m
    inertia: {{xx: Ixx, yy: Iyy, zz: Izz}}
forces:
  - {{type: joint_spring_damper, coordinate: arm.angle, stiffness: k}}
integrator: {{method: dopri5}}
"""
NOMINAL = dict(Ixx=1.0, Iyy=1.0, Izz=1.0, Ixy=0.0, Ixz=0.0, Iyz=0.0, ax=0.0, ay=0.0, az=1.0, m=1.0, k=1.0, c=0.1)


def loader_verdict(values):
    """None if the loader takes a scene with these parameter values, else its message."""
    try:
        loads(RULES.format(**values))
        return None
    except ModelError as e:
        return e.message


def engine_verdict(sim, values):
    """None if the engine takes these values set together on a compiled scene, else its message."""
    names = list(values)
    try:
        sim.engine.set_reals([sim._vr[n] for n in names], [values[n] for n in names])
        return None
    except ValueError as e:
        return str(e)


def _draws(rng, n):
    """Parameter sets around the rules' edges: inertias from principal moments (some breaking the triangle
    inequality or negative) in a random frame, axes from zero length through the allowed lengths, signed masses."""
    for _ in range(n):
        lam = rng.uniform(0, 1, 3) * 10.0 ** rng.integers(-3, 4)
        if rng.random() < 0.3:
            lam[2] = lam[0] + lam[1] + rng.choice([-1, 1]) * rng.uniform(0, 0.02) * lam.max()
        if rng.random() < 0.1:
            lam[0] = -rng.uniform(0, 0.01) * lam.max()
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        I = Q @ np.diag(lam) @ Q.T
        axis = rng.normal(size=3) * 10.0 ** rng.choice([-12, -9.5, -8, 0, 50, 101], p=[.05, .05, .1, .65, .1, .05])
        yield dict(Ixx=I[0, 0], Iyy=I[1, 1], Izz=I[2, 2], Ixy=I[0, 1], Ixz=I[0, 2], Iyz=I[1, 2], ax=axis[0],
                   ay=axis[1], az=axis[2], m=float(rng.choice([1.0, 0.0, -1e-3, 2e-101, 1e-99], p=[.8, .05, .05, .05, .05])),
                   k=float(rng.choice([1.0, -1.0, 0.0], p=[.9, .05, .05])),
                   c=float(rng.choice([0.1, 1e101, -1e-101], p=[.9, .05, .05])))


def _without_numbers(text):
    return re.sub(r"-?\d[\d.e+-]*", "#", text)


def test_engine_applies_the_loaders_rules_to_a_hosts_parameters():
    """400 parameter sets at the rules' edges (inertia: symmetric, positive semi-definite, triangle inequality;
    axis lengths; mass and stiffness >= 0; magnitudes): the engine refuses exactly the sets the loader refuses in
    a scene file, with the same reason, names the parameters and the quantity, and keeps its values."""
    sim = Simulation(loads(RULES.format(**NOMINAL)).spec)
    refused = 0
    for values in _draws(np.random.default_rng(22), 400):
        values = {k: float(v) for k, v in values.items()}
        want, got = loader_verdict(values), engine_verdict(sim, values)
        assert (want is None) == (got is None), (values, want, got)
        if got is None:
            sim.engine.set_reals([sim._vr[n] for n in NOMINAL], list(NOMINAL.values()))
            continue
        refused += 1
        problem = re.search(r"makes? (\S+?)(?: = \S+)?: (.*); the parameters keep their values", got)
        assert problem and got.startswith("Ixx = "), got
        assert _without_numbers(problem.group(2)) == _without_numbers(want), (got, want)
        assert all(sim.get(n) == v for n, v in NOMINAL.items())  # nothing changed
    assert 100 < refused < 350  # both verdicts were exercised


def test_massless_subtree_is_refused_as_the_loader_refuses_it():
    """m = 0 leaves the arm's hinge carrying no mass or inertia (a singular mass matrix): the loader refuses the
    scene, the engine refuses the host's value naming the same body, before any step."""
    values = dict(NOMINAL, m=0.0, Ixx=0.0, Iyy=0.0, Izz=0.0)
    want = loader_verdict(values)
    assert "body 'arm' and the bodies it carries have no mass or inertia" in want, want
    sim = Simulation(loads(RULES.format(**NOMINAL)).spec)
    got = engine_verdict(sim, values)
    assert got and "bodies.arm.mass: body 'arm' and the bodies it carries have no mass or inertia" in got, got


@pytest.mark.parametrize("name, value, valid", [
    ("integrator.rtol", 1e9, "[1e-14, 1]"), ("integrator.rtol", 1e-15, "[1e-14, 1]"),
    ("integrator.atol", 0.0, "[1e-100, 1e+100]"), ("integrator.atol", -1e-9, "[1e-100, 1e+100]"),
    ("integrator.atol", 1e-200, "[1e-100, 1e+100]"),
    ("integrator.step", -0.01, "0 or [1e-09, 1e+100]"), ("integrator.max_step", 1e-12, "0 or [1e-09, 1e+100]"),
    ("integrator.rtol", math.nan, "[1e-14, 1]"), ("m_bob", math.inf, "a finite number")])
def test_integrator_settings_and_parameters_have_one_domain(name, value, valid):
    """A scene file with the value is refused by the loader; Simulation.set refuses it with the same range
    (experiment 0..10 s: at most 1e10 steps, so steps of at least 1e-9 s) and keeps the old value."""
    key = name.split(".")[-1]
    text = (REPO / "models" / "pendulum.yaml").read_text()
    if name.startswith("integrator."):
        with pytest.raises(ModelError) as err:
            loads(re.sub(r"integrator: .*", f"integrator: {{method: dopri5, {key}: {value!r}}}", text))
        assert f"integrator.{key}" in str(err.value)
    sim = Simulation(mbsfmu.load(REPO / "models" / "pendulum.yaml").spec)
    before = sim.get(name)
    with pytest.raises(ValueError) as err:
        sim.set(name, value)
    assert f"{name} = {value:g}" in str(err.value) and f"(valid: {valid})" in str(err.value), str(err.value)
    assert sim.get(name) == before


def test_simulation_set_refuses_and_runs_on_unchanged():
    """m_bob = -0.05, NaN start values, a bool and an integer beyond double precision are refused naming the
    variable; the simulation then runs exactly as an untouched one, and a valid m_bob gives the closed-form
    small-angle period's pendulum."""
    spec = mbsfmu.load(REPO / "models" / "pendulum.yaml").spec
    a, b = Simulation(spec), Simulation(spec)
    for name, value, words in [("m_bob", -0.05, ["m_bob = -0.05 makes bodies.bob.mass = -0.05", "must not be negative"]),
                               ("y0.theta", math.nan, ["y0.theta = nan", "not finite"]),
                               ("yd0.theta", -math.inf, ["yd0.theta = -inf", "not finite"]),
                               ("m_bob", True, ["m_bob = True", "real number"]),
                               ("L", 2**60 + 1, ["L = 1152921504606846977", "not representable"])]:
        with pytest.raises(ValueError) as err:
            a.set(name, value)
        assert all(w in str(err.value) for w in words), str(err.value)
    ts = np.linspace(0, 1, 11)
    assert np.array_equal(a.run(ts), b.run(ts))


def test_structural_parameter_refused_before_recompiling(tmp_path):
    """A structural parameter (it feeds an elastic body's generated data) outside its domain: refused naming it,
    the simulation unchanged; reset() returns to the scene's value after an accepted change."""
    spec = mbsfmu.load(REPO / "models" / "flexible_pendulum.yaml").spec
    sim = Simulation(spec)
    structural = sorted(sim._structural)
    assert structural
    name = structural[0]
    before = sim.get(name)
    with pytest.raises(ValueError, match=f"{name} = nan is not finite"):
        sim.set(name, math.nan)
    assert sim.get(name) == before and sim.spec is spec
    sim.set(name, before * 1.1)
    assert sim.get(name) == pytest.approx(before * 1.1)
    sim.reset()
    assert sim.get(name) == before and sim.spec is spec


def test_sweep_case_fails_naming_the_value_it_could_not_use():
    """Item 4: NaN initial values, a negative mass and an rtol out of range fail their case naming the value; the
    valid cases start exactly at the values they name. Text for a number is refused before any case runs."""
    import pandas as pd
    nan = math.nan
    cases = pd.DataFrame({"y0.phi1": [nan, 0.3, 0.3, 0.3, 0.3, 0.3], "yd0.phi2": [0.0, nan, 0.0, 0.0, 0.0, -0.25],
                          "m": [1.0, 1.0, -1.0, 1.0, 1.0, 2.0], "integrator.rtol": [1e-8, 1e-8, 1e-8, 1e9, 1e-8, 1e-8],
                          "L": [1.0, 1.0, 1.0, 1.0, 1.0, 0.7]})
    with pytest.raises(ValueError, match="L: 'long' is not a number"):
        mbsfmu.sweep(REPO / "models" / "double_pendulum.yaml", vary=cases.assign(L=[1.0, 1.0, 1.0, 1.0, "long", 0.7]),
                     stop=0.1, step=0.05, scheduler="inprocess")
    table, series = mbsfmu.sweep(REPO / "models" / "double_pendulum.yaml", vary=cases, stop=0.1, step=0.05,
                                 scheduler="inprocess", series=True)
    status = table["status"].tolist()
    for k, words in enumerate([["y0.phi1 = nan", "not finite"], ["yd0.phi2 = nan", "not finite"],
                               ["m = -1 makes bodies.link1.mass = -1", "must not be negative"],
                               ["integrator.rtol = 1e+09", "[1e-14, 1]"]]):
        assert all(w in status[k] for w in words), (k, status[k])
    assert status[4] == status[5] == "ok"
    first = series[(series["case"] == 5) & (series["time"] == 0.0)].iloc[0]
    assert first["y.phi1"] == 0.3 and first["yd.phi2"] == -0.25 and first["y.phi2"] == 0.0


# ---- both FMU kinds through fmpy, in a child process (a crash fails the test, not pytest) ----------------------
HOST = FMPY_CHILD + r'''
fmu, work = sys.argv[1:3]
md = read_model_description(fmu)
d = fmpy.extract(fmu, os.path.join(work, "x"))
vr = {v.name: v.valueReference for v in md.modelVariables}
outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]


def open_fmu(tag):
    s = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier, instanceName=tag)
    s.instantiate(callbacks=cb)
    return s


def set_(s, tag, names, values):
    n = len(LOG)
    st = status(s.setReal, [vr[x] for x in names], values)
    return [st, [m[2] for m in logged(tag, n) if m[0] >= 2]]


a, b = open_fmu("a"), open_fmu("b")
res = {"before": [set_(a, "a", ["m_bob"], [-0.05]), set_(a, "a", ["integrator.rtol"], [1e9]),
                  set_(a, "a", ["integrator.atol"], [0.0]), set_(a, "a", ["integrator.step"], [-1.0])]}
res["kept"] = a.getReal([vr["m_bob"], vr["integrator.rtol"], vr["integrator.atol"], vr["integrator.step"]])
res["exit_after_refusal"] = status(lambda: (a.setupExperiment(startTime=0.0), a.enterInitializationMode(),
                                            a.exitInitializationMode())[-1])
a.reset()
init(a), init(b)
t = steps(a, 0.0, 10)
steps(b, 0.0, 10)
res["after"] = [set_(a, "a", ["m_bob"], [-0.05]), set_(a, "a", ["L"], [float("nan")]),
                set_(a, "a", ["L", "m_bob"], [0.9, -1.0]), set_(a, "a", ["m_rod"], [0.0])]
res["kept_after"] = a.getReal([vr["L"], vr["m_bob"], vr["m_rod"]])
steps(a, t, 20), steps(b, t, 20)
res["same"] = a.getReal(outs) == b.getReal(outs)
res["valid_pair"] = set_(a, "a", ["L", "m_bob"], [0.9, 0.5])
res["pair_kept"] = a.getReal([vr["L"], vr["m_bob"]])
print("RESULT " + json.dumps(res), flush=True)
'''


@pytest.mark.skipif(not sys.platform.startswith("linux") or CC is None, reason="FMU binaries for linux64")
@pytest.mark.parametrize("kind", ["pythonfmu", "native"])
def test_fmu_refuses_values_outside_their_domain(tmp_path, kind):
    """fmi2SetReal of m_bob = -0.05, rtol = 1e9, atol = 0, step < 0, NaN, a pair that makes a mass negative and a
    massless rod: fmi2Error with a message naming the variable, its value and the valid range or the quantity it
    made invalid; the values kept; initialization refused after a refused start value (no silent default);
    after initialization the instance steps on bit-identical to an untouched twin."""
    fmu = mbsfmu.build_fmu(REPO / "models" / "pendulum.yaml", tmp_path, **({"kind": "native"} if kind == "native" else {}))
    r = subprocess.run([sys.executable, "-c", HOST, str(fmu), str(tmp_path)], capture_output=True, text=True, timeout=120)
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")]
    assert r.returncode == 0 and lines, (r.stdout[-2000:], r.stderr[-2000:])
    res = json.loads(lines[-1][7:])
    expected = [["m_bob = -0.05 makes bodies.bob.mass = -0.05", "must not be negative"],
                ["integrator.rtol = 1e+09", "valid: [1e-14, 1]"], ["integrator.atol = 0", "valid: [1e-100, 1e+100]"],
                ["integrator.step = -1", "valid: 0 or [1e-09, 1e+100]"]]
    for (st, logs), words in zip(res["before"], expected):
        assert st == 3 and any(all(w in m for w in words) for m in logs), (kind, st, logs, words)
    assert res["kept"] == [1.0, 1e-8, 1e-10, 0.0]
    assert res["exit_after_refusal"] == 3
    expected = [["m_bob = -0.05 makes bodies.bob.mass"], ["L = nan is not finite", "valid: a finite number"],
                ["L = 0.9, m_bob = -1 make bodies.bob.mass = -1"], ["m_rod = 0 makes bodies.rod.inertia", "triangle"]]
    for (st, logs), words in zip(res["after"], expected):
        assert st == 3 and any(all(w in m for w in words) for m in logs), (kind, st, logs, words)
    assert res["kept_after"] == [0.8, 1.0, 0.3]
    assert res["same"]
    assert res["valid_pair"][0] == 0 and res["pair_kept"] == [0.9, 0.5]


DRIVEN = """mbsfmu: 1
name: driven
parameters: {{T: {T!r}, F: {F!r}}}
bodies:
  crank:
    parent: world
    joint: {{type: revolute, axis: [0, 1, 0], drive: {{crank.angle: asin(t/T)}}}}
    mass: 1
    inertia: {{xx: 1, yy: 1, zz: 1}}
  slider:
    parent: crank
    joint: {{type: prismatic, axis: [1, 0, 0], at: [0.5, 0, 0]}}
    mass: 1
    inertia: {{xx: 1, yy: 1, zz: 1}}
forces:
  - {{type: force, body: slider, value: [sqrt(F - t), 0, 0]}}
experiment: {{start: 0, stop: 1, step: 0.01}}
"""


@pytest.mark.parametrize("name, value, path, t", [
    ("T", 0.5, "bodies.crank.joint.drive.crank.angle (its velocity)", "0.5"),   # asin(t/T)' = 1/sqrt(T² - t²)
    ("T", -0.75, "bodies.crank.joint.drive.crank.angle (its velocity)", "0.75"),
    ("F", 0.5, "forces[0].value[0]", "0.503906"),                               # sqrt(F - t), first sample past F
    ("T", 1.5, None, None), ("F", 1.5, None, None)])
def test_drives_and_force_values_of_a_parameter_stay_defined(name, value, path, t):
    """A parameter that takes a drive (or its velocity, acceleration) or a force value of t out of its domain
    within the experiment is refused as the loader refuses the same number in the scene (at the same sample
    time); values that keep them defined run."""
    values = {"T": 2.0, "F": 2.0, name: value}
    try:
        loads(DRIVEN.format(**values))
        want = None
    except ModelError as e:
        want = e.message
    sim = Simulation(loads(DRIVEN.format(T=2.0, F=2.0)).spec)
    if path is None:
        assert want is None
        sim.set(name, value)
        sim.initialize(0.0)
        assert np.all(np.isfinite(sim.run(np.linspace(0, 1, 5))))
        return
    assert want and f"t = {t}" in want and ("first time derivative" in want) == ("velocity" in path), want
    with pytest.raises(ValueError) as err:
        sim.set(name, value)
    assert f"{name} = {value:g} makes {path} = " in str(err.value) and f"at t = {t}:" in str(err.value), str(err.value)
    assert sim.get(name) == 2.0


AXES = """mbsfmu: 1
name: axes
parameters: {{p: {p!r}}}
bodies:
  b:
    parent: world
    joint: {{type: {kind}, axes: {axes}}}
    mass: 1
    inertia: {{xx: 1, yy: 1, zz: 1}}
"""


@pytest.mark.parametrize("kind, axes, nominal, values", [
    ("universal", "[[0, 0, 1], [p, 0, 1]]", 1.0, [0.0, 1e-7, -1e-2, 2.0]),      # parallel to 1e-9 near p = 0
    ("planar", "[[1, 0, 0], [p, 1, 0]]", 0.0, [0.5, 1e-10, -2e-9, 0.0])])       # perpendicular to 1e-9 only at p = 0
def test_joint_axes_relations_follow_the_loader(kind, axes, nominal, values):
    """Two axes that a parameter turns parallel (universal) or out of perpendicular (planar): the engine's verdict
    and reason are the loader's on the same numbers."""
    sim = Simulation(loads(AXES.format(p=nominal, kind=kind, axes=axes)).spec)
    verdicts = []
    for v in values:
        try:
            loads(AXES.format(p=v, kind=kind, axes=axes))
            want = None
        except ModelError as e:
            want = e.message
        try:
            sim.set("p", v)
            got = None
        except ValueError as e:
            got = str(e)
        assert (want is None) == (got is None), (v, want, got)
        assert got is None or f"makes bodies.b.joint.axes: {want}" in got, (got, want)
        verdicts.append(got is None)
    assert any(verdicts) and not all(verdicts)


def test_engine_domains_are_the_declared_ones():
    """At and around every end of every setting's domain (scene/domains.py), the engine accepts exactly what
    Domain.contains accepts."""
    from mbsfmu.scene.domains import variable_domain
    spec = mbsfmu.load(REPO / "models" / "pendulum.yaml").spec
    sim = Simulation(spec)
    for name in ("integrator.rtol", "integrator.atol", "integrator.step", "integrator.max_step"):
        d = variable_domain(name, spec)
        ends = [x for x in (d.lo, d.hi) if math.isfinite(x)]
        probes = [0.0, -0.0, 1.0, -1.0, math.nan, math.inf, 5e-324, 1e308]
        probes += [np.nextafter(x, s) for x in ends for s in (-math.inf, math.inf)] + ends
        for v in probes:
            try:
                sim.set(name, float(v))
                got = True
            except ValueError:
                got = False
            assert got == d.contains(float(v)), (name, v, d.text)


def test_quaternion_start_values_must_be_a_rotation():
    """y0 of one quaternion component alone would start the body with a scaled 'rotation' (then normalized
    after the first step: not the value named); a unit quaternion given in full is used exactly."""
    spec = mbsfmu.load(REPO / "models" / "free_body.yaml").spec
    sim = Simulation(spec)
    scene_q = np.array([sim.get(f"y.block.q{k}") for k in range(4)])  # before initialize: the scene's start
    sim.set("y0.block.q0", 0.5)
    norm = np.linalg.norm(np.r_[0.5, scene_q[1:]])
    with pytest.raises(ValueError, match=r"quaternion \(y0.block.q0, y0.block.q1, y0.block.q2, y0.block.q3\) = "
                                         rf"\(0.5, .*\) of norm {norm:.6g}, not a rotation"):
        sim.initialize(0.0)
    sim.reset()
    q = np.array([0.5, 0.5, -0.5, 0.5])  # a 120° turn about (1, -1, 1)/√3
    for c, v in zip(("q0", "q1", "q2", "q3"), q):
        sim.set(f"y0.block.{c}", float(v))
    sim.initialize(0.0)
    assert list(sim.y[3:7]) == list(q)


@pytest.mark.skipif(not sys.platform.startswith("linux") or CC is None, reason="FMU binaries for linux64")
def test_fmu_sweep_case_fails_naming_the_value(tmp_path):
    """Through a built FMU (fmpy): a negative mass, a bool for a Real, an rtol out of range fail their case naming
    the value, once; the valid case runs as the same case in-process. Text for a Real is refused before any case."""
    import pandas as pd
    fmu = mbsfmu.build_fmu(REPO / "models" / "pendulum.yaml", tmp_path)
    cases = pd.DataFrame({"m_bob": [-0.05, True, 1.0, 1.0, 0.5], "L": [0.8, 0.8, 0.8, 0.8, 0.7],
                          "integrator.rtol": [1e-8, 1e-8, 1e-8, 1e9, 1e-10]})
    with pytest.raises(ValueError, match="L: 'long' is not a number"):
        mbsfmu.sweep(str(fmu), vary=cases.assign(L=[0.8, 0.8, "long", 0.8, 0.7]), stop=0.2, step=0.05,
                     scheduler="inprocess")
    table = mbsfmu.sweep(str(fmu), vary=cases, stop=0.2, step=0.05, scheduler="inprocess", outputs=["y.theta"])
    status = table["status"].tolist()
    for k, words in {0: ["m_bob = -0.05 makes bodies.bob.mass"], 1: ["m_bob = True", "real number"],
                     3: ["integrator.rtol = 1e+09", "[1e-14, 1]"]}.items():
        assert all(w in status[k] for w in words) and status[k].count(words[0]) == 1, (k, status[k])
    assert status[2] == "ok"
    assert status[4] == "ok"
    same = mbsfmu.sweep(REPO / "models" / "pendulum.yaml", vary=cases.iloc[4:], stop=0.2, step=0.05,
                        scheduler="inprocess", outputs=["y.theta"])
    assert table["y.theta"][4] == same["y.theta"][0]


def _corrupt(blob, sid, index, value):
    """The compiled scene with entry `index` of section `sid` replaced (the layout of compiler/scene_file.py: _pack)."""
    import struct
    nsec = struct.unpack_from("<i", blob, 72)[0]
    table = {s: (k, off) for s, k, off, _ in (struct.unpack_from("<iiqq", blob, 76 + 24 * n) for n in range(nsec))}
    kind, off = table[sid]
    b = bytearray(blob)
    struct.pack_into("<d" if kind == 1 else "<i", b, off + (8 if kind == 1 else 4) * index, value)
    return bytes(b)


@pytest.mark.parametrize("section, index, value", [
    ("S_RULES", 0, 99), ("S_RULES", 0, -1), ("S_RULES", 1, -5), ("S_RULES", 1, 10**9), ("S_RULES", 2, 10**6),
    ("S_RULES", 2, -1), ("S_VDOM", 2, 8.0), ("S_VDOM", 2, 0.5), ("S_VDOM", 0, math.nan), ("S_LIMITS", 2, 0.0),
    ("S_LIMITS", 2, 1e9), ("S_LIMITS", 1, -1.0), ("S_LIMITS", 3, 0.0), ("S_LIMITS", 6, math.inf)])
def test_corrupt_domain_tables_are_refused_at_load(section, index, value):
    """A compiled scene whose rule, domain or limit tables point outside the scene or make no sense is refused
    when loaded, with a message (a host reading a damaged scene.bin is not crashed by the checks)."""
    from mbsfmu.engine import EngineError, Instance, layout
    sim = Simulation(loads(RULES.format(**NOMINAL)).spec)
    blob = _corrupt(sim.blob, getattr(layout, section), index, value)
    with pytest.raises(EngineError, match="corrupt"):
        Instance(blob)


def test_moments_that_only_make_sense_together_are_set_together():
    """From moments (1, 1, 1) to (10, 10, 10): one at a time, (10, 1, 1) on the way breaks the triangle
    inequality; set together (Simulation.set_many, a sweep's case, one fmi2SetReal) they are taken exactly."""
    import pandas as pd
    spec = loads(RULES.format(**NOMINAL)).spec
    sim = Simulation(spec)
    with pytest.raises(ValueError, match="triangle"):
        sim.set("Ixx", 10.0)
    sim.set_many({"Ixx": 10.0, "Iyy": 10.0, "Izz": 10.0})
    assert [sim.get(n) for n in ("Ixx", "Iyy", "Izz")] == [10.0, 10.0, 10.0]
    table = mbsfmu.sweep(spec, vary=pd.DataFrame({"Ixx": [10.0], "Iyy": [10.0], "Izz": [10.0]}), stop=0.1,
                         scheduler="inprocess")
    assert table["status"].tolist() == ["ok"]
