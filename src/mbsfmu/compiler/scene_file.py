"""Compile a normalized scene into the engine's input: the compiled scene (bytes, read by model.c).

Structure (tree, coordinate indices, which numbers are constant) is fixed here; every number that depends on
the scene parameters becomes a bind program (bytecode of its parsed expression), every number that depends
on time a time program (drive values and their derivatives, force values), so the engine re-binds tunable
parameters and evaluates drives itself. The layout is mbs_layout.h's (engine/layout.py reads it).
"""

import struct

import numpy as np

from .model import Model
from ..expr import CONSTANTS, parse
from .. import limits
from ..scene import domains
from ..engine import layout as L
from .variables import fmi3_variables
from .elastic_tables import elastic_sections, stress_sections

# every section id, field, type code and size comes from mbs_layout.h (layout.py); these are views of it
FORCE_TYPES, FN1, FN2 = L.names("MBS_FORCES"), L.names("MBS_FN1"), L.names("MBS_FN2")
# the names of a body's vector and matrix entries in rule paths, made once (not once per body)
_ENTRY = {"center_of_mass": [f"center_of_mass[{r}]" for r in range(3)], "joint.at": [f"joint.at[{r}]" for r in range(3)],
          "inertia": [f"inertia[{r}][{c}]" for r in range(3) for c in range(3)]}
BINARY = {"+": L.OP_ADD, "-": L.OP_SUB, "*": L.OP_MUL, "/": L.OP_DIV, "^": L.OP_POW}


class _Programs:
    """Bytecode of the parsed expressions: constants pooled, targets kept symbolic until the layout is known."""

    def __init__(self, params):
        self.params = {p: i for i, p in enumerate(params)}
        self.consts, self._const_index = [], {}
        self.code, self.rows = [], []  # rows: (stage, (region, offset), code offset, length)
        self.bound = set()  # the targets of bind programs so far: numbers that depend on parameters

    def _const(self, v):
        key = float(v).hex()
        if key not in self._const_index:
            self._const_index[key] = len(self.consts)
            self.consts.append(float(v))
        return self._const_index[key]

    def _emit(self, node, out, depth=1):
        if depth > L.MBS_MAXSTACK:
            raise ValueError("expression nested too deeply for the engine")
        k = node[0]
        if k == "num":
            out += [L.OP_CONST, self._const(node[1])]
        elif k == "name":
            name = node[1]
            if name == "t":
                out += [L.OP_TIME, 0]
            elif name in CONSTANTS:
                out += [L.OP_CONST, self._const(CONSTANTS[name])]
            else:
                out += [L.OP_PARAM, self.params[name]]
        elif k == "neg":
            self._emit(node[1], out, depth + 1)
            out += [L.OP_NEG, 0]
        elif k == "sel":
            for a in node[2:]:
                self._emit(a, out, depth + 1)
            out += [L.OP_SEL_MIN if node[1] == "min" else L.OP_SEL_MAX, 0]
        elif k == "call":
            name, args = node[1], node[2]
            self._emit(args[0], out, depth + 1)
            if name in FN1:
                out += [L.OP_CALL1, FN1[name]]
            else:
                for a in args[1:]:  # min/max of several arguments fold from the left
                    self._emit(a, out, depth + 2)
                    out += [L.OP_CALL2, FN2[name]]
        else:
            self._emit(node[1], out, depth)
            self._emit(node[2], out, depth + 1)
            out += [BINARY[k], 0]

    def add(self, stage, target, expr):
        out = []
        self._emit(expr.tree, out)
        self.rows.append((stage, target, len(self.code), len(out)))
        self.code += out
        if stage == 0:
            self.bound.add(target)

    def number(self, value, env, region, offset):
        """A number of the scene at D[region][offset]: its value now, plus a bind program if it depends on
        parameters. Returns the value."""
        e = parse(value)
        if e.names - set(CONSTANTS):
            self.add(0, (region, offset), e)
        return e(env)


class _Rules:
    """The derived-quantity rules (scene/domains.py) of the numbers that depend on parameters: what the engine
    checks when a host changes a parameter, with the scene path each rule names."""

    def __init__(self, bound):
        self.bound = bound  # _Programs.bound: a rule is added after the numbers it reads
        self.rows = []  # (rule, region, offset, *parts of the path)

    def add(self, rule, region, offset, *path):
        """path: the scene path, or its parts, joined with dots only for the rules kept. A rule of constants is
        dropped at once (a 10,000-body chain's 200,000 of them were a third of its compile's memory)."""
        size = domains.RULE_SIZE[rule]
        if size and not any((region, offset + k) in self.bound for k in range(size)):
            return
        self.rows.append((rule, region, offset) + path)

    def section(self, bound, offsets, carries):
        """int rows (rule, offset into D or body index, offset of the path in the names) and the names' bytes,
        for the rules of which an entry is bound by a parameter (a constant never changes)."""
        rows, names, nbytes = [], [], 0
        for rule, region, off, *path in self.rows:
            size = domains.RULE_SIZE[rule]
            keep = any((region, off + k) in bound for k in range(size)) if size else carries if rule == domains.CARRIES \
                else True  # TIMED: added only for expressions of parameters
            if not keep:
                continue
            rows.append((rule, offsets[region] + off if size else off, nbytes))
            names.append(".".join(path).encode() + b"\0")
            nbytes += len(names[-1])
        return np.array(rows, dtype=np.int32).reshape(-1, 3), np.frombuffer(b"".join(names), np.uint8)


def compile_scene(spec, variables, guid="", model=None, dense=None):
    """The compiled scene of a normalized spec, with the FMU variables (fmu.variables.variables(spec): in
    value-reference order, each with its engine table row) and its Model if the caller has it; dense: the
    evaluation path (None: dense_path's choice; tests and benchmarks hold the two paths against each other).
    Returns bytes."""
    model = Model(spec) if model is None else model
    m, env = model, dict(model.env)
    carrier = carriers(m)
    ncarrier = sum(c == i for i, c in enumerate(carrier))
    dense = dense_path(m, carrier) if dense is None else dense
    params = [p["name"] for p in spec["parameters"]]
    P = _Programs(params)
    R = _Rules(P.bound)
    nb, f, npos = len(m.bodies), m.nvel, m.npos
    regions = {"body": np.zeros((nb, L.DB)), "force": np.zeros((max(len(m.bound_forces), 0), L.DF)), "g": np.zeros(3),
               "x0": np.zeros(npos + f), "nominal": np.zeros(npos + f), "out": np.zeros((len(m.outputs), 3)), "integ": np.zeros(L.DI)}
    ib = np.full((nb, L.IB), -1, dtype=np.int32)
    db = regions["body"]
    x0 = regions["x0"]
    drives = [(i, k, d) for i, b in enumerate(m.bodies) for k, *d in b.drives]
    ncardan = 0
    ib[:, L.IB_CARRIER] = carrier
    for r in range(3):  # rules in the loader's order (the first broken one is the one named): gravity, bodies, ...
        regions["g"][r] = P.number(spec["gravity"][r], env, "g", r)
        R.add(domains.MAGNITUDE, "g", r, f"gravity[{r}]")
    for i, b in enumerate(m.bodies):
        j, s = b.spec["joint"], b.spec
        ib[i, L.IB_PARENT] = b.parent
        ib[i, L.IB_JTYPE] = b.type.code
        ncardan += b.type.cardan is not None
        ib[i, L.IB_NPOS], ib[i, L.IB_NVEL] = b.joint.npos, b.joint.nvel
        ib[i, L.IB_MASSIVE] = int(i in m.massive)
        ib[i, L.IB_POS:L.IB_POS + b.joint.npos] = b.pos_idx
        ib[i, L.IB_VEL:L.IB_VEL + b.joint.nvel] = b.vel_idx
        ib[i, L.IB_ROT] = ib[i, L.IB_IROT] = ib[i, L.IB_IROT_MASK] = 0
        num = lambda v, off: P.number(v, env, "body", i * L.DB + off)  # noqa: E731
        rule = lambda kind, off, what: R.add(kind, "body", i * L.DB + off, "bodies", b.name, what)  # noqa: E731
        db[i, L.DB_M] = num(s["mass"], L.DB_M)
        rule(domains.NONNEG, L.DB_M, "mass")
        rule(domains.MAGNITUDE, L.DB_M, "mass")
        for r in range(3):
            db[i, L.DB_C + r] = num(s["center_of_mass"][r], L.DB_C + r)
            rule(domains.MAGNITUDE, L.DB_C + r, _ENTRY["center_of_mass"][r])
        for r in range(3):
            for c in range(3):
                db[i, L.DB_I + 3 * r + c] = num(s["inertia"][r][c], L.DB_I + 3 * r + c)
                rule(domains.MAGNITUDE, L.DB_I + 3 * r + c, _ENTRY["inertia"][3 * r + c])
        rule(domains.INERTIA, L.DB_I, "inertia")
        for r in range(3):
            db[i, L.DB_AT + r] = num(j["at"][r], L.DB_AT + r)
            rule(domains.MAGNITUDE, L.DB_AT + r, _ENTRY["joint.at"][r])
        if any(c not in j["drive"] for c in j["coordinates"]):
            R.add(domains.CARRIES, "body", i, f"bodies.{b.name}.mass")
        ib[i, L.IB_ROT] = _rotation(j["rotation"], lambda v, off: num(v, L.DB_ROT_RAW + off), db[i, L.DB_ROT_RAW:])
        _rotation_rules(j["rotation"], lambda kind, off, what: rule(kind, L.DB_ROT_RAW + off, "joint.rotation" + what))
        for key, off in (("axis", L.DB_A1_RAW),):
            if key in j:
                for r in range(3):
                    db[i, off + r] = num(j[key][r], off + r)
                rule(domains.AXIS, off, "joint.axis")
        if "axes" in j:
            for k, (a, off) in enumerate(zip(j["axes"], (L.DB_A1_RAW, L.DB_A2_RAW))):
                for r in range(3):
                    db[i, off + r] = num(a[r], off + r)
                rule(domains.AXIS, off, f"joint.axes[{k}]")
            rule(b.type.axes_rule, L.DB_A1_RAW, "joint.axes")
        if b.type.orientation:
            ib[i, L.IB_IROT] = _rotation(j["initial_rotation"], lambda v, off: num(v, L.DB_IROT_RAW + off), db[i, L.DB_IROT_RAW:])
            _rotation_rules(j["initial_rotation"], lambda kind, off, what: rule(kind, L.DB_IROT_RAW + off, "joint.initial.rotation" + what))
            if b.type.cardan is not None:
                names = b.coordinates[b.type.cardan]
                ib[i, L.IB_IROT_MASK] = sum(1 << k for k, c in enumerate(names) if c not in j["initial"])
        for k, c in enumerate(b.coordinates):
            if b.pos_idx[k] >= 0 and c in j["initial"]:
                x0[b.pos_idx[k]] = P.number(j["initial"][c], env, "x0", b.pos_idx[k])
                R.add(domains.MAGNITUDE, "x0", b.pos_idx[k], f"bodies.{b.name}.joint.initial.{c}")
        for k, c in enumerate(b.velocities):
            if b.vel_idx[k] >= 0 and c in j["initial_velocity"]:
                x0[npos + b.vel_idx[k]] = P.number(j["initial_velocity"][c], env, "x0", npos + b.vel_idx[k])
                R.add(domains.MAGNITUDE, "x0", npos + b.vel_idx[k], f"bodies.{b.name}.joint.initial_velocity.{c}")
        ib[i, L.IB_ELASTIC] = -1
        ib[i, L.IB_NODE] = -1 if b.node is None else _node_index(m, b.parent, b.node)
        if b.elastic:  # initial elastic coordinates (tunable, like every initial value)
            for key, idx, base in (("initial", b.q_idx, 0), ("initial_velocity", b.qd_idx, npos)):
                for c, v in b.elastic[key].items():
                    k_ = base + idx[b.elastic["coordinates"].index(c)]
                    x0[k_] = P.number(v, env, "x0", k_)
                    R.add(domains.MAGNITUDE, "x0", k_, f"bodies.{b.name}.elastic.{key}.{c}")
    for s_, (i, k, (e, ed, edd)) in enumerate(drives):
        ib[i, L.IB_DRV + k] = s_
        for c, ex in enumerate((e, ed, edd)):
            P.add(1, ("td", 3 * s_ + c), ex)
            if ex.names - {"t"} - set(CONSTANTS):
                what = ("", " (its velocity)", " (its acceleration)")[c]
                R.add(domains.TIMED, "td", 3 * s_ + c, f"bodies.{m.bodies[i].name}.joint.drive.{m.bodies[i].coordinates[k]}{what}")
    # force elements; vector slots in td: the inputs first (FMU input order), then time-dependent values
    nd3 = 3 * len(drives)
    inputs = list(m.inputs)
    timed = [n for n, fe in enumerate(m.bound_forces) if fe["type"] in ("force", "torque") and "input" not in fe
             and fe["constant"] is None]
    forces = regions["force"]
    iforce = np.full((len(m.bound_forces), L.IF), -1, dtype=np.int32)
    for n, fe in enumerate(m.bound_forces):
        src, kind = m.forces[n], fe["type"]
        iforce[n, L.IF_TYPE] = FORCE_TYPES[kind]
        iforce[n, L.IF_FRAME] = 0
        num = lambda v, off: P.number(v, env, "force", n * L.DF + off)  # noqa: E731
        rule = lambda kind, off, what: R.add(kind, "force", n * L.DF + off, f"forces[{n}].{what}")  # noqa: E731
        if kind == "joint_spring_damper":
            iforce[n, L.IF_A], iforce[n, L.IF_B] = fe["pos_index"], fe["vel_index"]
            for key, off in (("stiffness", L.DF_K), ("damping", L.DF_D), ("offset", L.DF_L)):
                forces[n, off] = num(src[key], off)
                rule(domains.MAGNITUDE, off, key)
                if key != "offset":
                    rule(domains.NONNEG, off, key)
        elif kind == "spring_damper":
            iforce[n, L.IF_A], iforce[n, L.IF_B] = fe["body_index"]
            for key, off in (("stiffness", L.DF_K), ("damping", L.DF_D), ("length", L.DF_L)):
                forces[n, off] = num(src[key], off)
                rule(domains.MAGNITUDE, off, key)
                rule(domains.NONNEG, off, key)
            for k, (at, off) in enumerate(zip(src["at"], (L.DF_AT_A, L.DF_AT_B))):
                for r in range(3):
                    forces[n, off + r] = num(at[r], off + r)
                    rule(domains.MAGNITUDE, off + r, f"at[{k}][{r}]")
            for end, node in enumerate(fe.get("node") or (None, None)):
                if node is not None:
                    iforce[n, L.IF_NODE_A + end] = _node_index(m, fe["body_index"][end], node)
        else:
            iforce[n, L.IF_A], iforce[n, L.IF_FRAME] = fe["body_index"], int(fe["frame"] == "body")
            if kind == "force":
                for r in range(3):
                    forces[n, L.DF_AT_A + r] = num(src["at"][r], L.DF_AT_A + r)
                    rule(domains.MAGNITUDE, L.DF_AT_A + r, f"at[{r}]")
            if fe.get("node") is not None:
                iforce[n, L.IF_NODE_A] = _node_index(m, fe["body_index"], fe["node"])
            if "input" in fe:
                iforce[n, L.IF_SRC] = nd3 + 3 * inputs.index(fe["input"])
            elif n in timed:
                slot = nd3 + 3 * (len(inputs) + timed.index(n))
                iforce[n, L.IF_SRC] = slot
                for r in range(3):
                    P.add(1, ("td", slot + r), parse(src["value"][r]))
                    if parse(src["value"][r]).names - {"t"} - set(CONSTANTS):
                        R.add(domains.TIMED, "td", slot + r, f"forces[{n}].value[{r}]")
            else:
                for r in range(3):
                    forces[n, L.DF_VEC + r] = num(src["value"][r], L.DF_VEC + r)
                    rule(domains.MAGNITUDE, L.DF_VEC + r, f"value[{r}]")
    out_i = np.zeros((len(m.outputs), 3), dtype=np.int32)
    for o, spec_o in enumerate(m.outputs):
        out_i[o, 0] = m.index[spec_o["body"]]
        out_i[o, 2] = ("position" in spec_o["quantities"]) | 2 * ("velocity" in spec_o["quantities"])
        if spec_o.get("node") is not None:
            out_i[o, 1] = _node_index(m, out_i[o, 0], spec_o["node"])
        else:
            out_i[o, 1] = -1
            for r in range(3):
                regions["out"][o, r] = P.number(spec_o["point"][r], env, "out", 3 * o + r)
                R.add(domains.MAGNITUDE, "out", 3 * o + r, f"outputs[{o}].point[{r}]")
    integ = spec["integrator"]
    ri = regions["integ"]
    ri[L.DI_RTOL], ri[L.DI_ATOL], ri[L.DI_MAX_STEP], ri[L.DI_STEP] = (integ[k] for k in ("rtol", "atol", "max_step", "step"))
    ri[L.DI_RHO_INF] = integ.get("rho_inf", 0.8)
    # layout of D, then the symbolic targets resolved
    nominal = regions["nominal"]  # the continuous states' nominals, as the variables carry them (fmi*GetNominals...)
    for v in variables:
        if v.kind in (L.MBS_V_Y, L.MBS_V_YD):
            nominal[v.index + npos * (v.kind == L.MBS_V_YD)] = v.nominal
    order = ("body", "force", "g", "x0", "nominal", "out", "integ")
    offsets, pos = {}, len(params) + len(P.consts)
    for name in order:
        offsets[name] = pos
        pos += regions[name].size
    nd = pos
    D = np.concatenate([np.array([p["value"] for p in spec["parameters"]], dtype=float), np.array(P.consts, dtype=float)]
                       + [regions[n].ravel() for n in order])
    prog = np.array([(st, (offsets[reg] if st == 0 else 0) + off, co, ln) for st, (reg, off), co, ln in P.rows],
                    dtype=np.int32).reshape(-1, 4)
    quat = np.array([np.r_[p, w] for p, w in zip(m.quaternions, m.quat_vel)], dtype=np.int32).reshape(-1, 7)
    plain = np.concatenate([m.plain_pos, m.plain_vel]).astype(np.int32)
    vars_ = np.array([(v.kind, v.index) for v in variables], dtype=np.int32).reshape(-1, 2)
    # the domain of each settable kind, rows MBS_V_PARAM .. MBS_V_STEP (every parameter's is the same)
    kinds = [e[1] for e in L.LISTS["MBS_VAR_KINDS"][L.MBS_V_PARAM:L.MBS_V_STEP + 1]]
    vdom = np.array([_domain_row(domains.variable_domain(name, spec)) for name in kinds])
    bound = {target for st, target, _, _ in P.rows if st == 0}
    masses = any(t[0] == "body" and t[1] % L.DB in (L.DB_M, L.DB_I, L.DB_I + 4, L.DB_I + 8) for t in bound)
    rules, rule_names = R.section(bound, offsets, carries=masses)  # what a body carries changes with a mass or moment only
    features = L.F_EXPR * bool(P.rows) | L.F_ELASTIC * m.has_elastic
    elastic_i, elastic_d, stress = np.zeros(0, np.int32), np.zeros(0), []
    if m.has_elastic:
        elastic_i, elastic_d, elastic_index = elastic_sections(m, spec)
        for i, e in elastic_index.items():
            ib[i, L.IB_ELASTIC] = e
        if any(v.kind == L.MBS_V_VM for v in variables):   # only then: other scenes compile as before
            stress = list(zip((L.S_STRESS_I, L.S_STRESS_D), stress_sections(m, spec, elastic_index)))
    header = dict(NB=nb, NPOS=npos, NVEL=f, NFORCE=len(m.bound_forces), NQUAT=len(quat), NPLAIN=len(m.plain_pos),
                  NDRV=len(drives), NVEC=len(inputs) + len(timed), NINPUT=len(inputs), NPARAM=len(params),
                  NVARS=len(vars_), NOUT=len(m.outputs), NPROG=len(prog), NCODE=len(P.code),
                  HAS_GRAVITY=int(m.has_gravity), METHOD=L.METHODS.index(integ["method"]), NCARDAN=int(ncardan),
                  NCARRIER=ncarrier, DENSE=int(dense),
                  FEATURES=features, MAXSTACK=L.MBS_MAXSTACK, D_PARAM=0, D_CONST=len(params), D_BODY=offsets["body"],
                  D_FORCE=offsets["force"], D_G=offsets["g"], D_X0=offsets["x0"], D_NOMINAL=offsets["nominal"], D_OUT=offsets["out"],
                  D_INTEG=offsets["integ"], ND=nd)
    names = b"".join(n.encode() + b"\0" for n in list(m.coordinates) + [b.name for b in m.bodies] + [v.name for v in variables])
    sections = [(L.S_HEADER, np.array([header[e[0][2:]] for e in L.LISTS["MBS_HEADER"]], dtype=np.int32)),
                (L.S_BODY_I, ib), (L.S_FORCE_I, iforce), (L.S_QUAT, quat), (L.S_PLAIN, plain),
                (L.S_VARS, vars_), (L.S_OUT_I, out_i), (L.S_PROG, prog),
                (L.S_CODE, np.array(P.code, dtype=np.int32)), (L.S_ELASTIC_I, elastic_i), (L.S_D, D),
                (L.S_ELASTIC_D, elastic_d), (L.S_NAMES, np.frombuffer(names, np.uint8)),
                (L.S_VDOM, vdom), (L.S_RULES, rules), (L.S_RULE_NAMES, rule_names),
                (L.S_LIMITS, _limits(spec))] + stress
    arrays = [(vs[0].vr, len(vs)) for name, vs, _ in fmi3_variables(variables) if name != vs[0].name]
    if arrays:  # only then: a scene without arrays compiles as before
        sections.append((L.S_ARRAYS, np.array(arrays, dtype=np.int32)))
    return _pack(sections, guid)


# the dense path: scenes of at most DENSE_MAX_NVEL velocity coordinates besides their largest elastic body's, or
# elastic ones of at most DENSE_MAX_ELASTIC in all with at most DENSE_MAX_NVEL moved by joints (dense_path)
DENSE_MAX_NVEL = 6
DENSE_MAX_ELASTIC = 20


def dense_path(model, carrier):
    """The evaluation path (H_DENSE), whichever is the faster: the dense equations (per-body Jacobian rows, M
    assembled and factored: cubic in the coordinates) for the smallest scenes (DENSE_MAX_NVEL, DENSE_MAX_ELASTIC)
    with no more welded bodies than carriers; else the articulated-body algorithm (linear in the bodies).
    Measured, rigid, in instructions per right-hand side with its kinematics (callgrind, recursive/dense):
    revolute chains of 1, 2, 4 bodies 3.0k/2.8k, 6.2k/5.6k, 12.6k/12.1k, of 6 and 16 bodies 19.0k/20.3k,
    51.0k/92.7k; the free body 8.1k/6.6k; the 6-dof arm (7 bodies, 1 welded) 25.4k/22.6k; of example-robot-data:
    UR arms (10 bodies, 4 welded) 27.9k/26.4k, kinova (6 dof, 7 welded) 30.7k/39.4k, iris_simple (a free body with
    5 welded) 12.7k/24.4k. Elastic, in time (reports/elastic_paths.md, recursive/dense): the shipped models
    (4–5 coordinates) 1.5–1.7; beams of n modes on L revolute joints (L × n) 1 × 20 1.17, 3 × 4 1.24, 2 × 8 1.14,
    4 × 4 1.04, 3 × 8 0.92, 6 × 6 0.55, 10 × 2 0.68; 6 rigid links and a beam of 12 modes 1.07, 12 and 4
    modes 0.83; the random nodal trees of tests/test_engine_elastic.py (13–15 coordinates, 8–9 of joints) 0.8 in
    instructions."""
    modes = [len(b.elastic["coordinates"]) for b in model.bodies if b.elastic]
    f, ncarrier = model.nvel, sum(c == i for i, c in enumerate(carrier))
    few = f - max(modes, default=0) <= DENSE_MAX_NVEL or (f <= DENSE_MAX_ELASTIC and f - sum(modes) <= DENSE_MAX_NVEL)
    return few and len(model.bodies) - ncarrier <= ncarrier


def carriers(model):
    """The body that carries each body on the recursive path (IB_CARRIER): a body welded to its parent (a fixed
    joint with no elastic body on its path to the root) moves with it and joins its carrier (-1: the world), the rest
    carry themselves. The engine derives each carrier's composite mass and inertia at bind time (mbs_derive: the
    numbers may depend on parameters), so its recursion runs over the moving bodies only, as Pinocchio merges a
    URDF's fixed links; its kinematics skip them too, and find points on them through their carrier's frame."""
    out, flexed = [], []  # flexed: an elastic body on the path to the root
    for i, b in enumerate(model.bodies):
        p = b.parent
        flexed.append(bool(b.elastic) or (p >= 0 and flexed[p]))
        # below an elastic body S is orthogonal only to first order (seed 004): a composite's parallel-axis terms,
        # taken in its carrier's axes, would differ from the reference's in second order, so nothing there welds
        welded = b.type.code == L.J_FIXED and not flexed[i] and b.node is None
        out.append((out[p] if p >= 0 else -1) if welded else i)
    return out


def _pack(sections, guid):
    """The file head (mbs_layout.h: MBS_FILE_HEAD), the section rows, then each section's data 8-byte aligned (little-endian),
    written once into one buffer (a 10,000-body scene is 7 MB: no copies of it per section)."""
    head = L.FH_SIZE + L.SR_SIZE * len(sections)
    rows, parts, pos = [], [], (head + 7) // 8 * 8
    for sid, arr in sections:
        kind = L.LISTS["MBS_SECTIONS"][sid][1]
        data = np.ascontiguousarray(arr, dtype={0: "<i4", 1: "<f8", 2: "u1"}[kind])
        rows.append(struct.pack(L.SECTION_ROW, sid, kind, pos, data.size))
        parts.append((pos, data))
        pos += (data.nbytes + 7) // 8 * 8
    top = bytearray(L.FH_SIZE)
    top[:4] = L.MBS_SCENE_MAGIC.encode()
    struct.pack_into("<i", top, L.FH_VERSION, L.MBS_FORMAT_VERSION)
    g = guid.encode()[:L.FH_NSEC - L.FH_GUID - 1]  # NUL-padded, at least one NUL
    top[L.FH_GUID:L.FH_GUID + len(g)] = g
    struct.pack_into("<i", top, L.FH_NSEC, len(sections))
    out = bytearray(pos)
    out[:head] = bytes(top) + b"".join(rows)
    for at, data in parts:
        out[at:at + data.nbytes] = memoryview(data.reshape(-1)).cast("B")
    return bytes(out)


def _rotation(rot, num, raw):
    """Raw numbers of a rotation spec into raw (9 slots); returns the code: 0 none, 1 axis-angle, 2 matrix."""
    if rot is None:
        return 0
    if "matrix" in rot:
        for r in range(3):
            for c in range(3):
                raw[3 * r + c] = num(rot["matrix"][r][c], 3 * r + c)
        return 2
    for r in range(3):
        raw[r] = num(rot["axis"][r], r)
    raw[3] = num(rot["angle"], 3)
    return 1


def _rotation_rules(rot, rule):
    """The rules of a rotation spec's raw numbers (slots as _rotation writes them)."""
    if rot is None:
        return
    if "matrix" in rot:
        rule(domains.ROTATION, 0, ".matrix")
        return
    rule(domains.AXIS, 0, ".axis")
    rule(domains.MAGNITUDE, 3, ".angle")


def _limits(spec):
    """The S_LIMITS numbers of a scene (LIM_*)."""
    lim = np.zeros(L.LIM_N)
    lim[L.LIM_START], lim[L.LIM_STOP] = spec["experiment"]["start"], spec["experiment"]["stop"]
    lim[L.LIM_SAMPLES] = limits.DOMAIN_SAMPLES
    lim[L.LIM_MAGNITUDE_LO], lim[L.LIM_MAGNITUDE_HI] = limits.MAGNITUDE
    lim[L.LIM_AXIS_LO], lim[L.LIM_AXIS_HI] = limits.AXIS_LENGTH
    return lim


def _domain_row(d):
    """lo, hi, flags (domains.Domain.flags): a domain as the compiled scene stores it."""
    return [d.lo, d.hi, float(d.flags())]


def _node_index(model, body, node):
    """Node P of an elastic body as a non-negative index (node: -1 is the last)."""
    N = model.bodies[body].nodal.nodes
    return node % N
