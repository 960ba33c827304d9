"""The compiled scene's elastic sections (seed 004): the mass invariants of every elastic body, computed once
here (bodies/ffrf.invariants), and its node data, laid out for engine/elastic.c.

S_ELASTIC_I (int32):  the EH header (NE, NFIX), then NE rows of EI fields, then NFIX parameter indices
                      (mbs_layout.h declares both).
S_ELASTIC_D (double): per elastic body, at its EI_D offset, the arrays of mbs_layout.h's MBS_ELASTIC_D in its
                      order and sizes (m, S0, S_RR, J_sum, C_t, A, C_r0, JPsi, G, B, M_ee, K, D, with stiffening
                      K_a, K_omega), then per node R_RP 3, Φ_P 3×n, Ψ_P 3×n; after the bodies the NFIX parameter
                      values the data were computed with. The inner index of G and B is the one contracted
                      with q, so that G·q and B·q run along memory.

S_STRESS_I (int32):   per stress node (an FE body's `stress:`), its elastic data index (the EI row) and the
                      offset of its stress modes in S_STRESS_D; both sections only in scenes with stress nodes.
S_STRESS_D (double):  per stress node its 6 × n stress modes σ_ck (row-major, Voigt xx yy zz xy yz zx): the
                      engine's σ_c = Σ_k σ_ck q_k and von Mises value (elastic.c, mbs_elastic_von_mises).

The finite-element data depend on the parameters that feed the beam generator (and a damping_ratio): those
are structural. The engine cannot recompute them, so it refuses a different value (elastic.c); the FMU
declares them fixed (`structural_parameters`).
"""

import numpy as np

from ..errors import ModelError
from ..expr import parse
from ..engine import layout as L


def structural_parameters(spec):
    """Names of the parameters that feed an elastic body's generated data (beam fields, damping_ratio, rayleigh)."""
    params = [p["name"] for p in spec["parameters"]]
    used = set()
    for b in spec["bodies"]:
        e = b.get("elastic")
        if not e:
            continue
        exprs = [e.get("damping_ratio")] + list(e.get("rayleigh") or [])
        for v in (e.get("beam") or {}).values():
            exprs += v if isinstance(v, list) else [v]
        for x in exprs:
            if isinstance(x, str):
                used |= parse(x).names
    return [p for p in params if p in used]


def body_block(inv, nodal):
    """One elastic body's doubles in the S_ELASTIC_D order (mbs_layout.h: MBS_ELASTIC_D, with the arrays' sizes)."""
    n = inv.n
    arrays = {"ED_M": [inv.m], "ED_S0": inv.S0, "ED_S_RR": inv.S_RR, "ED_J_SUM": inv.J_sum, "ED_C_T": inv.C_t,
              "ED_A": inv.A, "ED_C_R0": inv.C_r0, "ED_JPSI": inv.JPsi,
              "ED_G": np.transpose(inv.G, (0, 2, 1)),          # [i][l][k]
              "ED_B": np.transpose(inv.B, (0, 1, 3, 2)),       # [i][j][l][k]
              "ED_M_EE": inv.M_ee, "ED_K": inv.K, "ED_D": inv.D, "ED_K_A": inv.K_a, "ED_K_W": inv.K_omega}
    parts = []
    for name, size in L.elastic_array_sizes(n, inv.K_a is not None).items():
        a = np.ravel(np.asarray(arrays[name], float))
        assert a.size == size, (name, a.size, size)  # the layout's size of this array
        parts.append(a)
    nodes = np.concatenate([nodal.R_RP, nodal.Phi.reshape(-1, 3 * n), nodal.Psi.reshape(-1, 3 * n)], axis=1)
    return np.concatenate(parts + [nodes.ravel()])


def elastic_sections(model, spec):
    """(S_ELASTIC_I, S_ELASTIC_D, {body index: elastic index}) of a compiled Model."""
    rows, blocks, index, off = [], [], {}, 0
    for i, b in enumerate(model.bodies):
        if not b.elastic:
            continue
        block = body_block(b.inv, b.nodal)
        index[i] = len(rows)
        row = np.zeros(L.EI, np.int64)
        row[[L.EI_BODY, L.EI_N, L.EI_NODES, L.EI_Q, L.EI_QD, L.EI_STIFF, L.EI_D]] = \
            i, b.inv.n, b.nodal.nodes, b.q_idx[0], b.qd_idx[0], int(b.inv.K_a is not None), off
        rows.append(row)
        blocks.append(block)
        off += block.size
    params = [p["name"] for p in spec["parameters"]]
    fixed = structural_parameters(spec)
    head = np.zeros(L.EH, np.int64)
    head[[L.EH_NE, L.EH_NFIX]] = len(rows), len(fixed)
    I = np.concatenate([head, np.ravel(rows), [params.index(p) for p in fixed]])
    D = np.concatenate(blocks + [[float(model.parameters[p]) for p in fixed]])
    return I.astype(np.int32), D.astype(float), index


def stress_points(spec):
    """[(body name, node name)] of the scene's stress nodes: the order of the von Mises variables and of the
    S_STRESS_I rows."""
    return [(b["name"], name) for b in spec["bodies"] if (b.get("elastic") or {}).get("fe")
            for name in b["elastic"]["fe"].get("stress_names", ())]


def stress_sections(model, spec, elastic_index):
    """(S_STRESS_I, S_STRESS_D) of a compiled Model ({body index: elastic index} from elastic_sections), rows in
    stress_points' order."""
    from ..bodies.cms import stress_table
    rows, blocks, off = [], [], 0
    for b in spec["bodies"]:
        fe = (b.get("elastic") or {}).get("fe") or {}
        if "stress_names" not in fe:
            continue
        S = stress_table(fe, key=f"bodies.{b['name']}.elastic.fe")
        if len(S) != len(fe["stress_names"]):
            raise ModelError(f"{len(fe['stress_names'])} stress node names for {len(S)} stress nodes",
                             key=f"bodies.{b['name']}.elastic.fe.stress_names")
        for sigma in S:
            rows.append((elastic_index[model.index[b["name"]]], off))
            blocks.append(sigma.ravel())
            off += sigma.size
    return np.array(rows, np.int32).reshape(-1, 2), np.concatenate(blocks)
