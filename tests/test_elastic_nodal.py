"""Validation of `elastic:` data: user nodal arrays and the beam generator's keys raise ModelError naming the key."""

import numpy as np
import pytest

from mbsfmu.bodies import elastic_body, invariants, node_index
from mbsfmu.errors import ModelError


def good(N=3, n=2):
    rng = np.random.default_rng(0)
    return {"R_RP": [[i, 0, 0] for i in range(N)], "mass": [1.0] * N,
            "Phi": rng.normal(size=(N, 3, n)).tolist(), "stiffness": np.diag([4.0, 9.0]).tolist()}


def test_good_nodal_inline_and_file(tmp_path):
    nodal = elastic_body({"nodal": good(), "damping_ratio": 0.05})
    assert nodal.n == 2 and nodal.Psi.shape == (3, 3, 2) and np.all(nodal.inertia == 0)
    inv = invariants(nodal)
    # modal damping of the (here non-diagonal M_ee) modes: D = M V diag(2ζω) Vᵀ M
    lam, V = np.linalg.eig(np.linalg.solve(inv.M_ee, nodal.stiffness))
    W = np.linalg.inv(V)
    d = np.diag(W @ np.linalg.solve(inv.M_ee, nodal.damping) @ V).real
    np.testing.assert_allclose(np.sort(d), np.sort(2 * 0.05 * np.sqrt(lam.real)), rtol=1e-10)
    np.savez(tmp_path / "b.npz", **{k: np.asarray(v) for k, v in good().items()})
    nodal = elastic_body({"nodal": {"file": "b.npz"}}, base_dir=str(tmp_path))
    np.testing.assert_allclose(nodal.stiffness, np.diag([4.0, 9.0]))


def bad(**change):
    data = good()
    for k, v in change.items():
        if v is None:
            del data[k]
        else:
            data[k] = v
    return data


@pytest.mark.parametrize("data, key, text", [
    (bad(mass=None), "elastic.nodal", "missing `mass`"),
    (bad(R_RP=[[0, 0], [1, 0], [2, 0]]), "elastic.nodal.R_RP", "N×3"),
    (bad(mass=[1.0, 1.0]), "elastic.nodal.mass", "shape"),
    (bad(mass=[1.0, 0.0, 1.0]), "elastic.nodal.mass", "> 0"),
    (bad(mass=[1.0, float("nan"), 1.0]), "elastic.nodal.mass", "non-finite"),
    (bad(mass=["a", 1, 1]), "elastic.nodal.mass", "numeric"),
    (bad(Phi=np.zeros((3, 2, 2)).tolist()), "elastic.nodal.Phi", "N×3×n"),
    (bad(Psi=np.zeros((3, 3, 1)).tolist()), "elastic.nodal.Psi", "shape"),
    (bad(inertia=np.zeros((3, 3))), "elastic.nodal.inertia", "shape"),
    (bad(inertia=np.tile(-np.eye(3), (3, 1, 1))), "elastic.nodal.inertia", "positive semi-definite"),
    (bad(stiffness=[[1.0, 2.0], [0.0, 1.0]]), "elastic.nodal.stiffness", "symmetric"),
    (bad(stiffness=[[1.0, 0.0], [0.0, -1.0]]), "elastic.nodal.stiffness", "positive semi-definite"),
    (bad(stiffness=np.eye(3)), "elastic.nodal.stiffness", "shape"),
    (bad(damping=np.eye(3)), "elastic.nodal.damping", "shape"),
])
def test_bad_nodal_data(data, key, text):
    with pytest.raises(ModelError) as e:
        elastic_body({"nodal": data})
    assert e.value.key == key
    assert text in e.value.message


@pytest.mark.parametrize("spec, key, text", [
    ({"beam": {"length": 1, "EI": 1, "rhoA": 1}, "nodal": good()}, "elastic", "exactly one"),
    ({"nodal": good(), "damping": np.eye(2), "damping_ratio": 0.1}, "elastic.damping", "not both"),
    ({"nodal": good(), "damping_ratio": -0.1}, "elastic.nodal.damping_ratio", "≥ 0"),
    ({"nodal": good(), "wobble": 1}, "elastic.wobble", "unknown"),
    ({"nodal": good(), "coordinates": ["a"]}, "elastic.coordinates", "2 names"),
    ({"nodal": {"file": "/nonexistent/x.npz"}}, "elastic.nodal.file", "cannot read"),
    ({"beam": {"length": 1, "rhoA": 1}}, "elastic.beam", "missing `EI`"),
    ({"beam": {"length": -1, "EI": 1, "rhoA": 1}}, "elastic.beam.length", "> 0"),
    ({"beam": {"length": 1, "EI": [1, 2, 3], "rhoA": 1}}, "elastic.beam.EI", "[EIy, EIz]"),
    ({"beam": {"length": 1, "EI": 1, "rhoA": 1, "clamped": "end"}}, "elastic.beam.clamped", "start"),
    ({"beam": {"length": 1, "EI": 1, "rhoA": 1, "elements": 2, "modes": 9}}, "elastic.beam.modes", "only 8"),
    ({"beam": {"length": 1, "EI": 1, "rhoA": 1, "modes": 1.5}}, "elastic.beam.modes", "integer"),
    ({"beam": {"length": 1, "EI": 1, "rhoA": 1, "E": 3}}, "elastic.beam.E", "unknown"),
    ({"beam": {"length": 1, "EI": 1, "rhoA": 1}, "dynamic_stiffening": "yes"},
     "elastic.dynamic_stiffening", "true or false"),
])
def test_bad_elastic_spec(spec, key, text):
    with pytest.raises(ModelError) as e:
        elastic_body(spec)
    assert e.value.key == key
    assert text in e.value.message


def test_beam_spec_and_node_index():
    nodal = elastic_body({"beam": {"length": 2, "EI": [1, 2], "rhoA": 1, "elements": 4, "modes": 3},
                          "damping_ratio": 0.01, "dynamic_stiffening": False, "coordinates": ["a", "b", "c"]})
    assert nodal.stiffening is None and nodal.n == 3 and nodal.nodes == 5
    assert node_index(nodal, -1) == 4 and node_index(nodal, 0) == 0
    np.testing.assert_allclose(nodal.R_RP[node_index(nodal, -1)], [2, 0, 0])
    for P in (5, -6, 1.0, True):
        with pytest.raises(ModelError, match="node"):
            node_index(nodal, P, key="bodies.tip.joint.node")
