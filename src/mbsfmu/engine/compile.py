"""Compile a normalized scene into the engine's input: the compiled scene (bytes, read by model.c).

Structure (tree, coordinate indices, which numbers are constant) is fixed here; every number that depends on
the scene parameters becomes a bind program (bytecode of its parsed expression), every number that depends
on time a time program (drive values and their derivatives, force values), so the engine re-binds tunable
parameters and evaluates drives itself. Layout constants mirror mbs_model.h.
"""

import struct

import numpy as np

from ..equations.model import Model
from ..expr import CONSTANTS, parse
from ..scene import domains, limits
from .elastic_tables import elastic_sections

FORMAT_VERSION = 1
# sections (mbs_model.h: S_*) and their element kinds (0 int32, 1 double, 2 bytes)
(S_HEADER, S_BODY_I, S_FORCE_I, S_QUAT, S_PLAIN, S_VARS, S_OUT_I, S_PROG, S_CODE, S_ELASTIC_I, S_D, S_ELASTIC_D, S_NAMES,
 S_VDOM, S_RULES, S_RULE_NAMES, S_LIMITS) = range(17)
H_FIELDS = ("NB NPOS NVEL NFORCE NQUAT NPLAIN NDRV NVEC NINPUT NPARAM NVARS NOUT NPROG NCODE HAS_GRAVITY METHOD "
            "NCARDAN FEATURES MAXSTACK D_PARAM D_CONST D_BODY D_FORCE D_G D_X0 D_OUT D_INTEG ND").split()
F_EXPR, F_ELASTIC = 1, 2
JOINT_TYPES = {("fixed", None): 0, ("revolute", None): 1, ("prismatic", None): 2, ("cylindrical", None): 3,
               ("universal", None): 4, ("planar", None): 5, ("spherical", "quaternion"): 6,
               ("spherical", "cardan"): 7, ("free", "quaternion"): 8, ("free", "cardan"): 9}
FORCE_TYPES = {"joint_spring_damper": 0, "spring_damper": 1, "force": 2, "torque": 3}
IB_PARENT, IB_JTYPE, IB_NPOS, IB_NVEL, IB_MASSIVE, IB_POS, IB_VEL, IB_DRV = 0, 1, 2, 3, 4, 5, 12, 18
IB_ROT, IB_IROT, IB_IROT_MASK, IB_ELASTIC, IB_NODE, IB = 25, 26, 27, 28, 29, 30
DB_A1, DB_A2, DB_AT, DB_R0, DB_M, DB_C, DB_I = 0, 3, 6, 9, 18, 19, 22
DB_A1_RAW, DB_A2_RAW, DB_ROT_RAW, DB_IROT_RAW, DB = 31, 34, 37, 46, 55
IF_TYPE, IF_A, IF_B, IF_FRAME, IF_SRC, IF_NODE_A, IF_NODE_B, IF = range(8)
DF_K, DF_D, DF_L, DF_AT_A, DF_AT_B, DF_VEC, DF = 0, 1, 2, 3, 6, 9, 12
DI = 5
OP = {n: i for i, n in enumerate("CONST PARAM TIME NEG ADD SUB MUL DIV POW CALL1 CALL2 SEL_MIN SEL_MAX".split())}
FN1 = {n: i for i, n in enumerate("sin cos tan asin acos atan sinh cosh tanh exp log sqrt abs".split())}
FN2 = {"atan2": 0, "min": 1, "max": 2}
V_KINDS = {n: i for i, n in enumerate("PARAM METHOD RTOL ATOL MAX_STEP STEP QIN FIN Y YD OUT".split())}
METHODS = ("rk4", "dopri5", "dop853", "radau5", "gen_alpha", "auto")
MAXSTACK = 64
MAX_WORKSPACE = 2 ** 30  # bytes of per-instance workspace (mbs_model.h: MBS_MAX_WORKSPACE, the loader's limit)


class _Programs:
    """Bytecode of the parsed expressions: constants pooled, targets kept symbolic until the layout is known."""

    def __init__(self, params):
        self.params = {p: i for i, p in enumerate(params)}
        self.consts, self._const_index = [], {}
        self.code, self.rows = [], []  # rows: (stage, (region, offset), code offset, length)

    def _const(self, v):
        key = float(v).hex()
        if key not in self._const_index:
            self._const_index[key] = len(self.consts)
            self.consts.append(float(v))
        return self._const_index[key]

    def _emit(self, node, out, depth=1):
        if depth > MAXSTACK:
            raise ValueError("expression nested too deeply for the engine")
        k = node[0]
        if k == "num":
            out += [OP["CONST"], self._const(node[1])]
        elif k == "name":
            name = node[1]
            if name == "t":
                out += [OP["TIME"], 0]
            elif name in CONSTANTS:
                out += [OP["CONST"], self._const(CONSTANTS[name])]
            else:
                out += [OP["PARAM"], self.params[name]]
        elif k == "neg":
            self._emit(node[1], out, depth + 1)
            out += [OP["NEG"], 0]
        elif k == "sel":
            for a in node[2:]:
                self._emit(a, out, depth + 1)
            out += [OP["SEL_MIN" if node[1] == "min" else "SEL_MAX"], 0]
        elif k == "call":
            name, args = node[1], node[2]
            self._emit(args[0], out, depth + 1)
            if name in FN1:
                out += [OP["CALL1"], FN1[name]]
            else:
                for a in args[1:]:  # min/max of several arguments fold from the left
                    self._emit(a, out, depth + 2)
                    out += [OP["CALL2"], FN2[name]]
        else:
            self._emit(node[1], out, depth)
            self._emit(node[2], out, depth + 1)
            out += [OP[{"+": "ADD", "-": "SUB", "*": "MUL", "/": "DIV", "^": "POW"}[k]], 0]

    def add(self, stage, target, expr):
        out = []
        self._emit(expr.tree, out)
        self.rows.append((stage, target, len(self.code), len(out)))
        self.code += out

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

    def __init__(self):
        self.rows = []  # (rule, region, offset, path)

    def add(self, rule, region, offset, path):
        self.rows.append((rule, region, offset, path))

    def section(self, bound, offsets, carries):
        """int rows (rule, offset into D or body index, offset of the path in the names) and the names' bytes,
        for the rules of which an entry is bound by a parameter (a constant never changes)."""
        rows, names = [], b""
        for rule, region, off, path in self.rows:
            size = domains.RULE_SIZE[rule]
            keep = any((region, off + k) in bound for k in range(size)) if size else carries if rule == domains.CARRIES \
                else True  # TIMED: added only for expressions of parameters
            if not keep:
                continue
            rows.append((rule, offsets[region] + off if size else off, len(names)))
            names += path.encode() + b"\0"
        return np.array(rows, dtype=np.int32).reshape(-1, 3), np.frombuffer(names, np.uint8)


def compile_scene(spec, variables, guid=""):
    """The compiled scene of a normalized spec, with the FMU variables (list of simulation.Variable, in
    value-reference order). Returns bytes."""
    model = Model(spec)
    m, env = model, dict(model.env)
    # the engine keeps per body dense Jacobian rows (6 f doubles): refuse what it could not allocate
    need = 8 * len(m.bodies) * (26 + 6 * m.nvel) + 8 * m.nvel ** 2
    if need > MAX_WORKSPACE:
        raise ValueError(f"scene too large for the engine: {len(m.bodies)} bodies with {m.nvel} velocity coordinates "
                         f"need {need / 2**30:.1f} GiB of workspace (limit {MAX_WORKSPACE / 2**30:.0f} GiB); the "
                         "engine's dense per-body Jacobians suit tens to a few hundred coordinates")
    params = [p["name"] for p in spec["parameters"]]
    P = _Programs(params)
    R = _Rules()
    nb, f, npos = len(m.bodies), m.nvel, m.npos
    regions = {"body": np.zeros((nb, DB)), "force": np.zeros((max(len(m.bound_forces), 0), DF)), "g": np.zeros(3),
               "x0": np.zeros(npos + f), "out": np.zeros((len(m.outputs), 3)), "integ": np.zeros(DI)}
    ib = np.full((nb, IB), -1, dtype=np.int32)
    db = regions["body"]
    x0 = regions["x0"]
    drives = [(i, k, d) for i, b in enumerate(m.bodies) for k, *d in b.drives]
    ncardan = 0
    for r in range(3):  # rules in the loader's order (the first broken one is the one named): gravity, bodies, ...
        R.add(domains.MAGNITUDE, "g", r, f"gravity[{r}]")
    for i, b in enumerate(m.bodies):
        j, s = b.spec["joint"], b.spec
        ib[i, IB_PARENT] = b.parent
        ib[i, IB_JTYPE] = JOINT_TYPES[(b.kind, b.param if b.kind in ("spherical", "free") else None)]
        ncardan += ib[i, IB_JTYPE] in (7, 9)
        ib[i, IB_NPOS], ib[i, IB_NVEL] = b.joint.npos, b.joint.nvel
        ib[i, IB_MASSIVE] = int(i in m.massive)
        ib[i, IB_POS:IB_POS + b.joint.npos] = b.pos_idx
        ib[i, IB_VEL:IB_VEL + b.joint.nvel] = b.vel_idx
        ib[i, IB_ROT] = ib[i, IB_IROT] = ib[i, IB_IROT_MASK] = 0
        num = lambda v, off: P.number(v, env, "body", i * DB + off)  # noqa: E731
        rule = lambda kind, off, what: R.add(kind, "body", i * DB + off, f"bodies.{b.name}.{what}")  # noqa: E731
        db[i, DB_M] = num(s["mass"], DB_M)
        rule(domains.NONNEG, DB_M, "mass")
        rule(domains.MAGNITUDE, DB_M, "mass")
        for r in range(3):
            db[i, DB_C + r] = num(s["center_of_mass"][r], DB_C + r)
            rule(domains.MAGNITUDE, DB_C + r, f"center_of_mass[{r}]")
        for r in range(3):
            for c in range(3):
                db[i, DB_I + 3 * r + c] = num(s["inertia"][r][c], DB_I + 3 * r + c)
                rule(domains.MAGNITUDE, DB_I + 3 * r + c, f"inertia[{r}][{c}]")
        rule(domains.INERTIA, DB_I, "inertia")
        for r in range(3):
            db[i, DB_AT + r] = num(j["at"][r], DB_AT + r)
            rule(domains.MAGNITUDE, DB_AT + r, f"joint.at[{r}]")
        if any(c not in j["drive"] for c in j["coordinates"]):
            R.add(domains.CARRIES, "body", i, f"bodies.{b.name}.mass")
        ib[i, IB_ROT] = _rotation(j["rotation"], lambda v, off: num(v, DB_ROT_RAW + off), db[i, DB_ROT_RAW:])
        _rotation_rules(j["rotation"], lambda kind, off, what: rule(kind, DB_ROT_RAW + off, "joint.rotation" + what))
        for key, off in (("axis", DB_A1_RAW),):
            if key in j:
                for r in range(3):
                    db[i, off + r] = num(j[key][r], off + r)
                rule(domains.AXIS, off, "joint.axis")
        if "axes" in j:
            for k, (a, off) in enumerate(zip(j["axes"], (DB_A1_RAW, DB_A2_RAW))):
                for r in range(3):
                    db[i, off + r] = num(a[r], off + r)
                rule(domains.AXIS, off, f"joint.axes[{k}]")
            rule(domains.PERPENDICULAR if b.kind == "planar" else domains.NOT_PARALLEL, DB_A1_RAW, "joint.axes")
        if b.kind in ("spherical", "free"):
            ib[i, IB_IROT] = _rotation(j["initial_rotation"], lambda v, off: num(v, DB_IROT_RAW + off), db[i, DB_IROT_RAW:])
            _rotation_rules(j["initial_rotation"], lambda kind, off, what: rule(kind, DB_IROT_RAW + off, "joint.initial.rotation" + what))
            if b.param == "cardan":
                names = b.coordinates[-3:]
                ib[i, IB_IROT_MASK] = sum(1 << k for k, c in enumerate(names) if c not in j["initial"])
        for k, c in enumerate(b.coordinates):
            if b.pos_idx[k] >= 0 and c in j["initial"]:
                x0[b.pos_idx[k]] = P.number(j["initial"][c], env, "x0", b.pos_idx[k])
                R.add(domains.MAGNITUDE, "x0", b.pos_idx[k], f"bodies.{b.name}.joint.initial.{c}")
        for k, c in enumerate(b.velocities):
            if b.vel_idx[k] >= 0 and c in j["initial_velocity"]:
                x0[npos + b.vel_idx[k]] = P.number(j["initial_velocity"][c], env, "x0", npos + b.vel_idx[k])
                R.add(domains.MAGNITUDE, "x0", npos + b.vel_idx[k], f"bodies.{b.name}.joint.initial_velocity.{c}")
        ib[i, IB_ELASTIC] = -1
        ib[i, IB_NODE] = -1 if b.node is None else _node_index(m, b.parent, b.node)
        if b.elastic:  # initial elastic coordinates (tunable, like every initial value)
            for key, idx, base in (("initial", b.q_idx, 0), ("initial_velocity", b.qd_idx, npos)):
                for c, v in b.elastic[key].items():
                    k_ = base + idx[b.elastic["coordinates"].index(c)]
                    x0[k_] = P.number(v, env, "x0", k_)
                    R.add(domains.MAGNITUDE, "x0", k_, f"bodies.{b.name}.elastic.{key}.{c}")
    for s_, (i, k, (e, ed, edd)) in enumerate(drives):
        ib[i, IB_DRV + k] = s_
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
    iforce = np.full((len(m.bound_forces), IF), -1, dtype=np.int32)
    for n, fe in enumerate(m.bound_forces):
        src, kind = m.forces[n], fe["type"]
        iforce[n, IF_TYPE] = FORCE_TYPES[kind]
        iforce[n, IF_FRAME] = 0
        num = lambda v, off: P.number(v, env, "force", n * DF + off)  # noqa: E731
        rule = lambda kind, off, what: R.add(kind, "force", n * DF + off, f"forces[{n}].{what}")  # noqa: E731
        if kind == "joint_spring_damper":
            iforce[n, IF_A], iforce[n, IF_B] = fe["pos_index"], fe["vel_index"]
            for key, off in (("stiffness", DF_K), ("damping", DF_D), ("offset", DF_L)):
                forces[n, off] = num(src[key], off)
                rule(domains.MAGNITUDE, off, key)
                if key != "offset":
                    rule(domains.NONNEG, off, key)
        elif kind == "spring_damper":
            iforce[n, IF_A], iforce[n, IF_B] = fe["body_index"]
            for key, off in (("stiffness", DF_K), ("damping", DF_D), ("length", DF_L)):
                forces[n, off] = num(src[key], off)
                rule(domains.MAGNITUDE, off, key)
                rule(domains.NONNEG, off, key)
            for k, (at, off) in enumerate(zip(src["at"], (DF_AT_A, DF_AT_B))):
                for r in range(3):
                    forces[n, off + r] = num(at[r], off + r)
                    rule(domains.MAGNITUDE, off + r, f"at[{k}][{r}]")
            for end, node in enumerate(fe.get("node") or (None, None)):
                if node is not None:
                    iforce[n, IF_NODE_A + end] = _node_index(m, fe["body_index"][end], node)
        else:
            iforce[n, IF_A], iforce[n, IF_FRAME] = fe["body_index"], int(fe["frame"] == "body")
            if kind == "force":
                for r in range(3):
                    forces[n, DF_AT_A + r] = num(src["at"][r], DF_AT_A + r)
                    rule(domains.MAGNITUDE, DF_AT_A + r, f"at[{r}]")
            if fe.get("node") is not None:
                iforce[n, IF_NODE_A] = _node_index(m, fe["body_index"], fe["node"])
            if "input" in fe:
                iforce[n, IF_SRC] = nd3 + 3 * inputs.index(fe["input"])
            elif n in timed:
                slot = nd3 + 3 * (len(inputs) + timed.index(n))
                iforce[n, IF_SRC] = slot
                for r in range(3):
                    P.add(1, ("td", slot + r), parse(src["value"][r]))
                    if parse(src["value"][r]).names - {"t"} - set(CONSTANTS):
                        R.add(domains.TIMED, "td", slot + r, f"forces[{n}].value[{r}]")
            else:
                for r in range(3):
                    forces[n, DF_VEC + r] = num(src["value"][r], DF_VEC + r)
                    rule(domains.MAGNITUDE, DF_VEC + r, f"value[{r}]")
    for r in range(3):
        regions["g"][r] = P.number(spec["gravity"][r], env, "g", r)
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
    regions["integ"][:] = [integ["rtol"], integ["atol"], integ["max_step"], integ["step"], integ.get("rho_inf", 0.8)]
    # layout of D, then the symbolic targets resolved
    order = ("body", "force", "g", "x0", "out", "integ")
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
    vars_ = np.array([_variable(v, params, m, inputs) for v in variables], dtype=np.int32).reshape(-1, 2)
    # the domain of each settable kind, rows MBS_V_PARAM .. MBS_V_STEP (every parameter's is the same)
    kinds = ("", "integrator.method", "integrator.rtol", "integrator.atol", "integrator.max_step", "integrator.step")
    vdom = np.array([_domain_row(domains.variable_domain(name, spec)) for name in kinds])
    bound = {target for st, target, _, _ in P.rows if st == 0}
    masses = any(t[0] == "body" and t[1] % DB in (DB_M, DB_I, DB_I + 4, DB_I + 8) for t in bound)
    rules, rule_names = R.section(bound, offsets, carries=masses)  # what a body carries changes with a mass or moment only
    features = F_EXPR * bool(P.rows) | F_ELASTIC * m.has_elastic
    elastic_i, elastic_d = np.zeros(0, np.int32), np.zeros(0)
    if m.has_elastic:
        elastic_i, elastic_d, elastic_index = elastic_sections(m, spec)
        for i, e in elastic_index.items():
            ib[i, IB_ELASTIC] = e
    header = dict(NB=nb, NPOS=npos, NVEL=f, NFORCE=len(m.bound_forces), NQUAT=len(quat), NPLAIN=len(m.plain_pos),
                  NDRV=len(drives), NVEC=len(inputs) + len(timed), NINPUT=len(inputs), NPARAM=len(params),
                  NVARS=len(vars_), NOUT=len(m.outputs), NPROG=len(prog), NCODE=len(P.code),
                  HAS_GRAVITY=int(m.has_gravity), METHOD=METHODS.index(integ["method"]), NCARDAN=int(ncardan),
                  FEATURES=features, MAXSTACK=MAXSTACK, D_PARAM=0, D_CONST=len(params), D_BODY=offsets["body"],
                  D_FORCE=offsets["force"], D_G=offsets["g"], D_X0=offsets["x0"], D_OUT=offsets["out"],
                  D_INTEG=offsets["integ"], ND=nd)
    names = b"".join(n.encode() + b"\0" for n in list(m.coordinates) + [b.name for b in m.bodies] + [v.name for v in variables])
    sections = [(S_HEADER, 0, np.array([header[k] for k in H_FIELDS], dtype=np.int32)),
                (S_BODY_I, 0, ib), (S_FORCE_I, 0, iforce), (S_QUAT, 0, quat), (S_PLAIN, 0, plain),
                (S_VARS, 0, vars_), (S_OUT_I, 0, out_i), (S_PROG, 0, prog),
                (S_CODE, 0, np.array(P.code, dtype=np.int32)), (S_ELASTIC_I, 0, elastic_i), (S_D, 1, D),
                (S_ELASTIC_D, 1, elastic_d), (S_NAMES, 2, np.frombuffer(names, np.uint8)),
                (S_VDOM, 1, vdom), (S_RULES, 0, rules), (S_RULE_NAMES, 2, rule_names),
                (S_LIMITS, 1, np.array([spec["experiment"]["start"], spec["experiment"]["stop"], limits.DOMAIN_SAMPLES,
                                        *limits.MAGNITUDE, *limits.AXIS_LENGTH], float))]
    return _pack(sections, guid)


def _pack(sections, guid):
    """"MBSC", version, guid[64], nsec, section rows, then each section's data 8-byte aligned (little-endian)."""
    head = 76 + 24 * len(sections)
    rows, blobs, pos = [], [], (head + 7) // 8 * 8
    for sid, kind, arr in sections:
        data = np.ascontiguousarray(arr, dtype={0: "<i4", 1: "<f8", 2: "u1"}[kind]).tobytes()
        rows.append(struct.pack("<iiqq", sid, kind, pos, arr.size))
        pad = (-len(data)) % 8
        blobs.append(data + b"\0" * pad)
        pos += len(data) + pad
    g = guid.encode()[:63]
    out = b"MBSC" + struct.pack("<i", FORMAT_VERSION) + g + b"\0" * (64 - len(g)) + struct.pack("<i", len(sections))
    out += b"".join(rows)
    out += b"\0" * ((head + 7) // 8 * 8 - head)
    return out + b"".join(blobs)


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


def _domain_row(d):
    """lo, hi, flags (domains.Domain.flags): a domain as the compiled scene stores it."""
    return [d.lo, d.hi, float(d.flags())]


def _node_index(model, body, node):
    """Node P of an elastic body as a non-negative index (node: -1 is the last)."""
    N = model.bodies[body].nodal.nodes
    return node % N


def _variable(v, params, m, inputs):
    """(kind, index) of an FMU variable for the engine's variable table."""
    name = v.name
    if v.causality == "parameter":
        if name in params:
            return V_KINDS["PARAM"], params.index(name)
        return V_KINDS[name.split(".", 1)[1].upper()], 0
    if name.startswith("q.") and name[2:] in m.velocity_coordinates and v.causality == "input":
        return V_KINDS["QIN"], m.velocity_coordinates.index(name[2:])
    if v.causality == "input":
        base, _, ax = name.rpartition(".")
        return V_KINDS["FIN"], 3 * inputs.index(base) + "xyz".index(ax)
    if name.startswith("y.") and name[2:] in m.coordinates:
        return V_KINDS["Y"], m.coordinates.index(name[2:])
    if name.startswith("yd.") and name[3:] in m.velocity_coordinates:
        return V_KINDS["YD"], m.velocity_coordinates.index(name[3:])
    base, sym, ax = name.rsplit(".", 2)
    o = [x["name"] for x in m.outputs].index(base)
    return V_KINDS["OUT"], 6 * o + 3 * (sym == "v") + "xyz".index(ax)
