"""Directional and adjoint derivatives of the engine (issue 27, item 3: what the native FMUs' fmi2/fmi3
GetDirectionalDerivative and fmi3GetAdjointDerivative answer): ∂(ẋ, outputs)/∂(states, inputs) by complex step
through the evaluation (engine/deriv.c).

Reference: 4th-order central differences of the engine's own double-precision evaluation (ẋ of mbs_derivatives,
outputs of mbs_get_real), a path that shares no arithmetic with the complex step's. Steps: positions 1e-3 and 1e-4
of their nominal (POSITION_STEPS: the larger keeps rounding out of stiff elastic rows, the smaller truncation out
of a stress near zero, where √ bends sharply; an entry agrees with either); velocities and inputs their nominal and
1 (ẋ is exactly quadratic in the velocities and linear in the inputs: the stencil is exact there). Agreement to
1e-7 of the larger of the entry's row and column maxima, on every shipped model and on random trees of every joint
type (the recursive path), at states away from the initial one.
"""
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.engine import EngineError, Instance
from mbsfmu.engine import layout as L
from mbsfmu.simulation import compiled
from test_engine_aba import random_tree
from test_engine_elastic import on_dense_path, random_scene

REPO = Path(__file__).resolve().parent.parent
MODELS = [p.stem for p in sorted((REPO / "models").glob("*.yaml"))]
STENCIL = ((-2, 1 / 12), (-1, -8 / 12), (1, 8 / 12), (2, -1 / 12))
POSITION_STEPS = (1e-3, 1e-4)  # of the nominal


class Case:
    """An initialized instance at a random state (nominal-scaled) and random inputs, its knowns (states, inputs)
    and unknowns (derivatives, outputs other than the states) by value reference."""

    def __init__(self, spec, seed=0):
        blob, self.var, model = compiled(spec, derivatives=True)
        self.npos = model.npos
        self.inst = inst = Instance(blob)
        inst.initialize(0.0)
        rng = np.random.default_rng(seed)
        self.nominal = np.array(inst.nominals())
        self.x = np.array(inst.state()) + 0.1 * self.nominal * rng.standard_normal(inst.n)
        for qi in model.quaternions:  # a rotation, as a host's integrator keeps it (near unit)
            self.x[qi] /= np.linalg.norm(self.x[qi])
        inst.set_time(0.3)
        inst.set_state(self.x)
        names = [v.name for v in self.var]
        self.states = [names.index(f"y.{c}") for c in model.coordinates] + \
                      [names.index(f"yd.{c}") for c in model.velocity_coordinates]
        self.inputs = [i for i, v in enumerate(self.var) if v.causality == "input"]
        for vr in self.inputs:
            inst.set_real(vr, rng.normal())
        self.ders = [i for i, v in enumerate(self.var) if v.name.startswith("der(")]
        self.outputs = [i for i, v in enumerate(self.var) if v.causality == "output" and i not in self.states + self.ders]
        self.knowns, self.unknowns = self.states + self.inputs, self.ders + self.outputs

    def values(self):
        return np.r_[self.inst.derivatives(), [self.inst.get_real(vr) for vr in self.outputs]]

    def jacobian(self):
        eye = np.eye(len(self.knowns))
        return np.array([self.inst.directional_derivative(self.unknowns, self.knowns, e) for e in eye]).T

    def central_differences(self, step):
        J = np.empty((len(self.unknowns), len(self.knowns)))
        for j, vr in enumerate(self.knowns):
            if j < len(self.states):
                h = self.nominal[j] * (step if j < self.npos else 1.0)
                def at(d, j=j):
                    x = self.x.copy()
                    x[j] += d
                    self.inst.set_state(x)
                    return self.values()
            else:
                h, v0 = 1.0, self.inst.get_real(vr)
                def at(d, vr=vr, v0=v0):
                    self.inst.set_real(vr, v0 + d)
                    return self.values()
            J[:, j] = sum(w * at(c * h) for c, w in STENCIL) / h
            self.inst.set_state(self.x)
            if j >= len(self.states):
                self.inst.set_real(vr, v0)
        return J


def assert_jacobians_agree(J, refs, rtol=1e-7):
    """Each entry of J within rtol of the larger of its row's and column's maxima from one of the references."""
    scale = np.maximum(np.abs(refs[0]).max(axis=1, keepdims=True), np.abs(refs[0]).max(axis=0, keepdims=True))
    err = np.min([np.abs(J - ref) for ref in refs], axis=0) / np.maximum(scale, 1e-300)
    assert not (err > rtol).any(), f"{(err > rtol).sum()} entries differ, worst {err.max():.2e}"


@pytest.mark.parametrize("model", MODELS)
def test_every_shipped_model_equals_central_differences(model):
    case = Case(mbsfmu.load(REPO / "models" / f"{model}.yaml").spec)
    J = case.jacobian()
    assert_jacobians_agree(J, [case.central_differences(step) for step in POSITION_STEPS])
    # the states as unknowns: the identity on their own seeds, zero on the inputs'
    S = np.array([case.inst.directional_derivative(case.states, case.knowns, e) for e in np.eye(len(case.knowns))]).T
    np.testing.assert_array_equal(S, np.eye(len(case.states), len(case.knowns)))
    # the adjoint: seedᵀ J, one known at a time
    seed = np.random.default_rng(1).standard_normal(len(case.unknowns))
    np.testing.assert_allclose(case.inst.adjoint_derivative(case.unknowns, case.knowns, seed), seed @ J,
                               rtol=1e-13, atol=1e-13 * np.abs(seed @ J).max())


@pytest.mark.parametrize("seed", range(3))
def test_random_trees_of_every_joint_type_on_the_recursive_path(seed):
    """Branching, drives of time, joint springs, springs, forces and torques as inputs, both quaternion and
    Cardan joints: the articulated-body path (dynamics.c), differentiated as it runs."""
    rng = np.random.default_rng(seed)
    spec = mbsfmu.loads(random_tree(rng, 12)).spec
    case = Case(spec, seed)
    assert not on_dense_path(spec) and case.inputs
    assert_jacobians_agree(case.jacobian(), [case.central_differences(step) for step in POSITION_STEPS])


@pytest.mark.parametrize("seed", (0, 1))
def test_elastic_bodies_on_the_recursive_path(seed):
    """Elastic bodies as nodes of the articulated-body algorithm (a joint at a node, an elastic body at a node of
    another, forces, torques, springs and outputs at nodes), differentiated as it runs."""
    spec = random_scene(seed)
    assert not on_dense_path(spec)
    case = Case(spec, seed)
    assert_jacobians_agree(case.jacobian(), [case.central_differences(step) for step in POSITION_STEPS])


def test_a_seed_is_one_direction():
    """J·(a e_i + b e_j) = a J e_i + b J e_j: the seeds of one call act together (FMI's dvKnown)."""
    case = Case(mbsfmu.load(REPO / "models" / "crane.yaml").spec)
    J, seed = case.jacobian(), np.random.default_rng(2).standard_normal(len(case.knowns))
    np.testing.assert_allclose(case.inst.directional_derivative(case.unknowns, case.knowns, seed), J @ seed,
                               rtol=1e-12, atol=1e-12 * np.abs(J).max() * np.abs(seed).max())


def test_wrong_references_and_seeds_are_refused_with_a_message():
    case = Case(mbsfmu.load(REPO / "models" / "pendulum.yaml").spec)
    inst, param = case.inst, next(i for i, v in enumerate(case.var) if v.causality == "parameter")
    for unknowns, knowns, seed, says in (
            ([case.ders[0]], [param], [1.0], "is not a continuous state or an input"),
            ([case.inputs[0]], [case.states[0]], [1.0], "is not a derivative, an output or a state"),
            ([case.ders[0]], [10 ** 6], [1.0], "unknown"),
            ([case.ders[0]], [case.states[0]], [np.nan], "not finite")):
        with pytest.raises(EngineError, match=says):
            inst.directional_derivative(unknowns, knowns, seed)
    with pytest.raises(EngineError, match="not finite"):
        inst.adjoint_derivative([case.ders[0]], [case.states[0]], [np.inf])
    # nothing changed: the next call answers
    assert np.isfinite(inst.directional_derivative(case.ders, case.states, np.ones(len(case.states)))).all()


def test_the_cost_benchmark_writes_its_report(tmp_path):
    """benchmarks/directional_cost.py (reports/directional.md): both calls timed in the C loop, the report written."""
    from benchmarks import directional_cost
    from mbsfmu.fmu.native import compiler
    if compiler() is None:
        pytest.skip("no C compiler")
    directional_cost.main(["--out", str(tmp_path), "--models", "pendulum", "--chains", "10", "--seconds", "0.02"])
    text = (tmp_path / "directional.md").read_text()
    assert "| pendulum | 2 |" in text and "| chain10 | 20 |" in text and (tmp_path / "directional.png").stat().st_size
