"""The `elastic:` section of a body (contract: model-format.md) → NodalData, with ModelError on bad data."""

import os

import numpy as np

from ..errors import ModelError
from .beam import beam_from_spec
from .nodal import validate_nodal

KEYS = {"beam", "nodal", "damping_ratio", "damping", "coordinates", "dynamic_stiffening"}


def elastic_body(spec, key="elastic", base_dir=None):
    """NodalData for one `elastic:` mapping (numbers already evaluated); `nodal: {file: x.npz}` is read relative to base_dir."""
    if not isinstance(spec, dict):
        raise ModelError("`elastic` must be a mapping with `beam:` or `nodal:`", key=key)
    for name in spec:
        if name not in KEYS:
            raise ModelError(f"unknown key `{name}`", key=f"{key}.{name}", hint="valid: " + ", ".join(sorted(KEYS)))
    if ("beam" in spec) == ("nodal" in spec):
        raise ModelError("give exactly one of `beam:` or `nodal:`", key=key)
    ratio = spec.get("damping_ratio")
    if ratio is not None and spec.get("damping") is not None:
        raise ModelError("give either `damping` or `damping_ratio`, not both", key=f"{key}.damping")
    stiffening = spec.get("dynamic_stiffening", True)
    if not isinstance(stiffening, bool):
        raise ModelError(f"`dynamic_stiffening` must be true or false, got {stiffening!r}",
                         key=f"{key}.dynamic_stiffening")
    if "beam" in spec:
        if not isinstance(spec["beam"], dict):
            raise ModelError("`beam` must be a mapping (length, EI, rhoA, …)", key=f"{key}.beam")
        nodal = beam_from_spec(spec["beam"], key=f"{key}.beam", damping_ratio=_ratio(ratio, key),
                               dynamic_stiffening=stiffening)
        if spec.get("damping") is not None:
            nodal.damping = _damping(spec["damping"], nodal.n, key)
    else:
        data = _nodal_data(spec["nodal"], f"{key}.nodal", base_dir)
        if spec.get("damping") is not None:
            if data.get("damping") is not None:
                raise ModelError("`damping` given twice (in `nodal` and next to it)", key=f"{key}.damping")
            data = dict(data, damping=spec["damping"])
        nodal = validate_nodal(data, key=f"{key}.nodal", damping_ratio=ratio)
    names = spec.get("coordinates")
    if names is not None and (not isinstance(names, (list, tuple)) or len(names) != nodal.n):
        raise ModelError(f"`coordinates` must list {nodal.n} names (one per elastic coordinate)",
                         key=f"{key}.coordinates")
    return nodal


def _ratio(ratio, key):
    if ratio is None:
        return 0.0
    try:
        r = float(ratio)
    except (TypeError, ValueError):
        raise ModelError(f"`damping_ratio` must be a number, got {ratio!r}", key=f"{key}.damping_ratio") from None
    if not np.isfinite(r) or r < 0:
        raise ModelError(f"`damping_ratio` must be ≥ 0, got {ratio!r}", key=f"{key}.damping_ratio")
    return r


def _damping(D, n, key):
    try:
        D = np.asarray(D, float)
    except (TypeError, ValueError):
        raise ModelError("`damping` must be an n×n matrix of numbers", key=f"{key}.damping") from None
    if D.shape != (n, n) or not np.all(np.isfinite(D)):
        raise ModelError(f"`damping` must be a finite {n}×{n} matrix, got shape {D.shape}", key=f"{key}.damping")
    return D


def _nodal_data(nodal, key, base_dir):
    if isinstance(nodal, dict) and set(nodal) == {"file"}:
        path = nodal["file"]
        if base_dir is not None and not os.path.isabs(path):
            path = os.path.join(base_dir, path)
        try:
            with np.load(path) as f:
                return {name: f[name] for name in f.files}
        except (OSError, ValueError) as e:
            raise ModelError(f"cannot read nodal data file {path!r}: {e}", key=f"{key}.file",
                             hint="an .npz with R_RP, mass, Phi, stiffness and optional Psi, inertia, damping") from None
    if not isinstance(nodal, dict):
        raise ModelError("`nodal` must be a mapping of arrays or {file: path.npz}", key=key)
    return nodal


def node_index(nodal, node, key="node"):
    """Index of node `node` (negative counts from the end, as in Python) with a range check."""
    N = nodal.nodes
    if isinstance(node, bool) or not isinstance(node, (int, np.integer)) or not -N <= node < N:
        raise ModelError(f"`node` must be an integer in [{-N}, {N - 1}], got {node!r}", key=key,
                         hint=f"the elastic body has {N} nodes")
    return int(node) % N
