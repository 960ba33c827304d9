"""The FMU variables of a scene: their one owner.

Listed from the normalized scene alone (no engine library, no Simulation), in value-reference order, the same
for both FMU kinds and in-process runs. Each variable also carries the row of the engine's variable table it
becomes (``kind``: an ``MBS_V_*`` code of mbs_layout.h, ``index`` within that kind), so the compiler writes the
table from here and never reads a name back. Contract: docs/fmu.md, "Variables".

Model exchange (the native kind) adds one derivative variable per continuous state after all others
(``variables(spec, derivatives=True)``); ``continuous_states`` pairs them up for any FMI version's writer.
Every y.* and yd.* (the continuous states) carries its ``nominal`` (``state_nominals``): a host's absolute
tolerance is rtol × nominal, so each is the size the state physically has in this scene.

FMI 3.0 groups runs of these scalars into arrays (``fmi3_variables``): a force input's three components, an
output point's position and its velocity, an elastic body's modal coordinates (y, ẏ, their generalized forces and
derivatives). Each Variable names the array it belongs to (``array``), so the grouping is written here once.
A host that knows only the other version's names silently ignores a start value under them, so each side's
descriptions name the other's (``_name_both_versions``): an element's ends in ``(FMI 3.0: F_a[2])``, an array's
in ``(FMI 2.0: F_a.x, F_a.y, F_a.z)`` (``fmi2_elements`` reads it back: ``mbsfmu info``, input CSVs).
"""



import numpy as np

from ..engine import layout as L
from .elastic_tables import stress_points, structural_parameters
from .model import Model

INTEGRATOR_DESCRIPTIONS = {
    "integrator.rtol": ("1", "relative tolerance of the adaptive integrators"),
    "integrator.atol": ("1", "absolute tolerance of the adaptive integrators"),
    "integrator.max_step": ("s", "largest internal step (0: no limit)"),
    "integrator.step": ("s", "fixed step of rk4 and gen_alpha (0: one step per communication interval for rk4, "
                             "adaptive for gen_alpha)"),
}
INPUT_UNITS = {"m/s": "N", "rad/s": "N.m"}  # the generalized force that does work on a velocity of this unit


class Variable:
    """An FMU variable: name, causality, variability, type, unit, description, start; value reference ``vr``;
    the engine's variable-table row (``kind``, ``index``)."""

    __slots__ = ("name", "causality", "variability", "type", "unit", "description", "start", "vr", "kind", "index",
                 "derivative_of", "depends_on", "nominal", "array")

    def __init__(self, name, causality, variability, type="Real", unit=None, description="", start=0.0,
                 kind=None, index=0, derivative_of=None):
        self.name, self.causality, self.variability, self.type = name, causality, variability, type
        self.unit, self.description, self.start = unit, description, start
        self.kind, self.index, self.vr = kind, index, None
        self.derivative_of = derivative_of  # the state Variable this is the time derivative of (model exchange)
        self.depends_on = None  # a derivative's states (kind "constant": ẏ_pos = ẏ) or None: every state and input
        self.nominal = None  # a continuous state's (y.*, yd.*) nominal value: state_nominals
        self.array = None  # (name, description) of the FMI 3.0 array it is an element of (fmi3_variables), or None

    def __repr__(self):
        return f"Variable({self.name!r}, {self.causality}, {self.unit})"


def variables(spec, model=None, derivatives=False, nominals=True):
    """The FMU variables of a normalized spec, in value-reference order (``model``: its equations.Model, if
    already built; ``derivatives``: with the derivative variables of model exchange, after all others, so that
    every other value reference is the same with or without them; ``nominals=False``: the states without their
    nominal values, which need the model's numbers: names and order need only its structure)."""
    model = Model(spec, bind=nominals) if model is None else model
    out = _parameters(spec) + _settings(spec["integrator"]) + _inputs(spec, model) + _outputs(spec, model, nominals)
    if derivatives:
        out += _derivatives(out, model)
    for vr, v in enumerate(out):
        v.vr = vr
    _name_both_versions(out)
    return out


FMI3_ELEMENT = " (FMI 3.0: {}[{}])"  # 1-based, as FMI's structured names count
FMI2_NAMES = " (FMI 2.0: {})"


def _name_both_versions(variables):
    """Each element of an FMI 3.0 array says which one it is, each array which FMI 2.0 scalars it holds."""
    for name, vs, description in fmi3_variables(variables):
        if name != vs[0].name:
            for k, v in enumerate(vs, 1):
                v.description += FMI3_ELEMENT.format(name, k)
                v.array = (name, description + FMI2_NAMES.format(", ".join(e.name for e in vs)))


def fmi2_elements(description):
    """(description without the names, [FMI 2.0 names of the elements]) of an FMI 3.0 array's description as
    ``_name_both_versions`` writes it; (description, None) for any other text."""
    text, mark, names = (description or "").rpartition(FMI2_NAMES.split("{")[0])
    return (text, names[:-1].split(", ")) if mark and names.endswith(")") else (description, None)


def _parameters(spec):
    fixed = set(structural_parameters(spec))  # they feed generated elastic data, which the engine cannot redo
    return [Variable(p["name"], "parameter", "fixed" if p["name"] in fixed else "tunable", unit=p.get("unit"),
                     description=(p["description"] or f"scene parameter {p['name']}")
                     + (" (structural: feeds an elastic body's generated data; fixed)" if p["name"] in fixed else ""),
                     start=p["value"], kind=L.MBS_V_PARAM, index=i)
            for i, p in enumerate(spec["parameters"])]


def _settings(integrator):
    kinds = L.names("MBS_VAR_KINDS")  # the integrator.* settings by name
    out = [Variable("integrator.method", "parameter", "fixed", "String", None,
                    "integration method: " + ", ".join(L.METHODS), integrator["method"],
                    kind=L.MBS_V_METHOD)]
    for name, (unit, description) in INTEGRATOR_DESCRIPTIONS.items():
        out.append(Variable(name, "parameter", "fixed", unit=unit, description=description,
                            start=integrator[name.split(".")[1]], kind=kinds[name]))
    return out


def _modal(model):
    """{elastic coordinate: its body's array of modal coordinates (``<body>.q``)}"""
    return {c: f"{b.name}.q" for b in model.bodies if b.elastic for c in b.elastic["coordinates"]}


def _in_array(v, name, description=None):
    v.array = (name, description) if name else None
    return v


def _inputs(spec, model):
    _, units_vel = model.coordinate_units()
    modal = _modal(model)
    out = [_in_array(Variable(f"q.{c}", "input", "continuous", unit=INPUT_UNITS.get(u, "1"),
                              description=f"generalized force on velocity coordinate {c}", kind=L.MBS_V_QIN, index=i),
                     f"q.{modal[c]}" if c in modal else None, f"generalized forces on the modal coordinates of {c.split('.')[0]}")
           for i, (c, u) in enumerate(zip(model.velocity_coordinates, units_vel))]
    inputs = [f for f in spec["forces"] if "input" in f]  # the engine's force inputs, in scene order
    for i, f in enumerate(inputs):
        unit = "N" if f["type"] == "force" else "N.m"
        out += [_in_array(Variable(f"{f['input']}.{ax}", "input", "continuous", unit=unit,
                                   description=f"{f['type']} on {f['body']}, {f['frame']} frame, {ax} component",
                                   kind=L.MBS_V_FIN, index=3 * i + k), f["input"],
                          f"{f['type']} on {f['body']}, {f['frame']} frame")
                for k, ax in enumerate("xyz")]
    return out


def _outputs(spec, model, nominals=True):
    units_pos, units_vel = model.coordinate_units()
    modal = _modal(model)
    out = [_in_array(Variable(f"y.{c}", "output", "continuous", unit=u, description=f"position coordinate {c}",
                              kind=L.MBS_V_Y, index=i), f"y.{modal[c]}" if c in modal else None,
                    f"modal coordinates of {c.split('.')[0]}")
           for i, (c, u) in enumerate(zip(model.coordinates, units_pos))]
    out += [_in_array(Variable(f"yd.{c}", "output", "continuous", unit=u, description=f"velocity coordinate {c}",
                               kind=L.MBS_V_YD, index=i), f"yd.{modal[c]}" if c in modal else None,
                     f"modal velocities of {c.split('.')[0]}")
            for i, (c, u) in enumerate(zip(model.velocity_coordinates, units_vel))]
    for v, nominal in zip(out, np.concatenate(state_nominals(model)) if nominals else ()):
        v.nominal = float(nominal)
    for i, o in enumerate(spec["outputs"]):  # each output point: 6 engine values, r then v
        for s, (qty, sym, unit) in enumerate((("position", "r", "m"), ("velocity", "v", "m/s"))):
            if qty in o["quantities"]:
                out += [_in_array(Variable(f"{o['name']}.{sym}.{ax}", "output", "continuous", unit=unit,
                                           description=f"world-frame {qty} of a point on {o['body']}, {ax} component",
                                           kind=L.MBS_V_OUT, index=6 * i + 3 * s + k), f"{o['name']}.{sym}",
                                 f"world-frame {qty} of a point on {o['body']}")
                        for k, ax in enumerate("xyz")]
    out += [Variable(f"vm.{body}.{node}", "output", "continuous", unit="Pa",
                     description=f"von Mises stress at FE node {node} of {body}", kind=L.MBS_V_VM, index=k)
            for k, (body, node) in enumerate(stress_points(spec))]
    return out


STANDARD_GRAVITY = 9.80665  # m/s²: the reference load of a scene without gravity


def characteristic_length(model):
    """ℓ (m): the largest length the scene's bodies set out — joint offsets, centers of mass, radii of gyration
    √(tr I / 2m), elastic nodes' positions; 1 m if there is none."""
    lengths = [1e-300]
    for b in model.bodies:
        lengths += [np.linalg.norm(b.at) if b.at is not None else 0.0, np.linalg.norm(b.c) if b.c is not None else 0.0]
        if b.m > 0:
            lengths.append(np.sqrt(max(np.trace(b.I), 0.0) / (2 * b.m)))  # a point mass's rotated zero: -1e-19
        if b.elastic:
            lengths.append(np.linalg.norm(b.nodal.R_RP, axis=1).max())
    ell = max(lengths)
    return ell if ell > 1e-300 else 1.0


def state_nominals(model):
    """Nominal values of y and ẏ (docs/fmu.md, "Nominal values"), from the scene's bound data: with ℓ the
    characteristic length, g the gravity's magnitude (standard gravity if none) and T = √(ℓ/g),
      angles, quaternion components: 1;   lengths: ℓ;
      modal coordinate k of an elastic body: its static deflection under the body's own inertia loaded by g,
        q_k = max(g |C_t[:, k]|, g |C_r0[:, k]| / ℓ) / K_kk  (translational, rotational coupling: an acceleration
        g or an angular one g/ℓ), 1 where neither reaches the mode;
      every rate: its coordinate's nominal / T (the scene's motion, not the mode's own period, sets how fast
        an elastic coordinate moves: most of it follows the loads quasi-statically)."""
    ell = characteristic_length(model)
    g = np.linalg.norm(model.g) if model.has_gravity else STANDARD_GRAVITY
    T = np.sqrt(ell / g)
    units_pos, units_vel = model.coordinate_units()
    pos = np.array([ell if u == "m" else 1.0 for u in units_pos])
    vel = np.array([(ell if u == "m/s" else 1.0) / T for u in units_vel])
    for b in (b for b in model.bodies if b.elastic):
        load = g * np.maximum(np.linalg.norm(b.inv.C_t, axis=0), np.linalg.norm(b.inv.C_r0, axis=0) / ell)
        with np.errstate(divide="ignore", invalid="ignore"):
            q = load / np.diag(b.inv.K)
        pos[b.q_idx] = np.where(np.isfinite(q) & (q > 0), q, 1.0)
        vel[b.qd_idx] = pos[b.q_idx] / T
    return pos, vel


def continuous_states(variables):
    """(state, derivative) Variable pairs in the engine's state order x = [y; ẏ]: what a model-exchange host
    integrates (empty for a list made without ``derivatives``)."""
    return [(v.derivative_of, v) for v in variables if v.derivative_of is not None]


def _per_second(unit):
    return unit + "2" if unit.endswith("/s") else unit + "/s"  # m → m/s → m/s2, 1 → 1/s → 1/s2


def _derivatives(out, model):
    """der(y.*) then der(yd.*): the engine's state x = [y; ẏ] with quaternions as it keeps them (ṗ = ½ p ⊗ ω:
    the derivative keeps |p| = 1 only as well as the host integrates it; docs/fmu.md, "Model exchange")."""
    y = [v for v in out if v.kind == L.MBS_V_Y]
    yd = [v for v in out if v.kind == L.MBS_V_YD]
    der = [_in_array(Variable(f"der({v.name})", "local", "continuous", unit=_per_second(v.unit),
                              description=f"time derivative of {v.name}", start=None, kind=L.MBS_V_DER, index=i,
                              derivative_of=v), v.array and f"der({v.array[0]})",
                    v.array and f"time derivative of {v.array[0]}")
           for i, v in enumerate(y + yd)]
    for i, j in zip(model.plain_pos, model.plain_vel):  # ẏ_pos = ẏ (the engine's plain coordinates)
        der[i].depends_on = ("constant", [yd[j]])
    for p, w in zip(model.quaternions, model.quat_vel):  # ṗ = ½ p ⊗ (0, ω): ṗ_k on the other three p and ω
        for i in p:
            der[i].depends_on = ("dependent", [y[k] for k in p if k != i] + [yd[k] for k in w])
    return der


def fmi3_variables(variables):
    """The FMI 3.0 variables: (name, [Variable, ...], description) in value-reference order, runs of consecutive
    variables of one ``array`` as one array variable (shape: its length), every other variable a scalar as in FMI
    2.0 (so are the elements of an array whose name another variable has). FMI 3.0 value reference = index."""
    taken = {v.name for v in variables}
    out = []
    for v in variables:
        array = v.array if v.array and v.array[0] not in taken else None
        if array and out and out[-1][0] == array[0] and out[-1][1][-1].vr == v.vr - 1:
            out[-1][1].append(v)
        else:
            out.append((array[0], [v], array[1]) if array else (v.name, [v], v.description))
    return out
