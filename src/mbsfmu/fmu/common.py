"""What both FMU kinds share (build.py: pythonfmu kind, native.py: native kind): one modelDescription writer per
FMI version (2.0: both kinds; 3.0: the native kind) over the one list of variables (variables.py), the drawing
description, the archive writer and the version they carry."""

from __future__ import annotations

import datetime
import json
import math
import uuid
import warnings
import zipfile
from xml.dom.minidom import parseString
from xml.etree.ElementTree import Element, SubElement, tostring

from ..engine import layout as L
from ..compiler.variables import continuous_states, fmi3_variables

DRAWING_FILE = "mbsfmu_drawing.json"  # in resources/: what `mbsfmu animate FMU` draws from (animation/trajectory.py)

LOG_CATEGORIES = {
    "logStatusWarning": "Log messages with fmi2Warning status.",  # fmi3... in FMI 3.0 (_log_categories)
    "logStatusDiscard": "Log messages with fmi2Discard status.",
    "logStatusError": "Log messages with fmi2Error status.",
    "logStatusFatal": "Log messages with fmi2Fatal status.",
    "logAll": "Log all messages.",
}

# SI base-unit exponents of the units mbsfmu uses (FMI 2.0 BaseUnit attributes).
UNITS = {
    "1": {},
    "m": {"m": 1},
    "rad": {"rad": 1},
    "kg": {"kg": 1},
    "s": {"s": 1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "m/s": {"m": 1, "s": -1},
    "1/s": {"s": -1},
    "1/s2": {"s": -2},
    "rad/s": {"rad": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "rad/s2": {"rad": 1, "s": -2},
    "kg.m2": {"kg": 1, "m": 2},
    "N/m": {"kg": 1, "s": -2},
    "N.s/m": {"kg": 1, "s": -1},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "kg/m": {"kg": 1, "m": -1},
    "N.m2": {"kg": 1, "m": 3, "s": -2},
    "Pa": {"kg": 1, "m": -1, "s": -2},
}


def mbsfmu_version() -> str:
    try:
        from importlib.metadata import version
        return version("mbsfmu")
    except Exception:  # not installed (source checkout)
        return "0.1"


def write_zip(path, members: dict[str, bytes]) -> None:
    """An FMU archive at ``path`` (a temporary file of files.replacing) with the members (name → bytes)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for member, data in members.items():
            z.writestr(member, data)


def drawing_resource(spec: dict) -> dict[str, bytes]:
    """{member: bytes} of the drawing description: the normalized scene (the kinematics and shapes the page
    draws), read back bounded and checked against the compiled scene by `mbsfmu animate`. Nothing when it is
    larger than limits.DRAWING_BYTES (large nodal data): such FMUs are animated with --scene."""
    from ..limits import DRAWING_BYTES
    data = json.dumps(spec, separators=(",", ":")).encode("utf-8")
    if len(data) > DRAWING_BYTES:
        warnings.warn(f"{spec['name']}: no drawing description in the FMU ({len(data)} bytes, at most "
                      f"{DRAWING_BYTES}); animate it with --scene", RuntimeWarning, stacklevel=3)
        return {}
    return {f"resources/{DRAWING_FILE}": data}


def _fmt(x) -> str:
    """Every real attribute of a modelDescription (start, nominal, experiment): the shortest text that reads back
    to the same double (0.4, not 0.40000000000000002); NaN or inf is a bug upstream, never an FMU's attribute."""
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"a non-finite number ({x}) for a modelDescription attribute")
    return repr(x)


# <ModelExchange> of an FMU that offers it (native kind): the same capabilities as its co-simulation
MODEL_EXCHANGE = {
    "needsExecutionTool": "false",
    "completedIntegratorStepNotNeeded": "true",  # fmi2CompletedIntegratorStep does nothing (docs/fmu.md)
    "canBeInstantiatedOnlyOncePerProcess": "false",
    "canNotUseMemoryManagementFunctions": "true",
    "canGetAndSetFMUstate": "true",
    "canSerializeFMUstate": "true",
    "providesDirectionalDerivative": "true",  # the engine's, exact to rounding (engine/deriv.c)
}


def _guid(spec: dict, version: str) -> str:
    return "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, "mbsfmu:" + json.dumps(spec, sort_keys=True) + ":" + version)) + "}"


def _root(fmi: str, spec: dict, name: str, version: str, token: dict) -> Element:
    """<fmiModelDescription> with the attributes every version has (``token``: the FMI 2 guid or the FMI 3
    instantiationToken)."""
    return Element("fmiModelDescription", {
        "fmiVersion": fmi,
        "modelName": name,
        **token,
        "description": spec.get("description") or name,
        "generationTool": f"mbsfmu {version}",
        "generationDateAndTime": datetime.datetime.now(datetime.timezone.utc)
        .replace(microsecond=0).isoformat().replace("+00:00", "Z"),
        "variableNamingConvention": "structured",
    })


def _units(root: Element, variables, used_units=()) -> None:
    """<UnitDefinitions> of ``used_units`` and the units the Real variables use (the same elements in FMI 2.0
    and 3.0)."""
    used_units = list(used_units)
    for v in variables:
        u = v.unit
        if getattr(v, "type", "Real") == "Real" and u and u not in used_units:
            used_units.append(u)
    if used_units:
        ud = SubElement(root, "UnitDefinitions")
        for u in used_units:
            unit = SubElement(ud, "Unit", {"name": u})
            exps = UNITS.get(u)
            if exps is not None:
                SubElement(unit, "BaseUnit", {k: str(e) for k, e in exps.items()})


def _log_categories(root: Element, fmi: str) -> None:
    cats = SubElement(root, "LogCategories")
    for cat, desc in LOG_CATEGORIES.items():
        SubElement(cats, "Category", {"name": cat, "description": desc.replace("fmi2", f"fmi{fmi[0]}")})


def _default_experiment(root: Element, spec: dict) -> None:
    exp = spec.get("experiment") or {}
    de = {}
    for key, attr in (("start", "startTime"), ("stop", "stopTime"), ("step", "stepSize")):
        if exp.get(key) is not None:
            de[attr] = _fmt(exp[key])
    rtol = (spec.get("integrator") or {}).get("rtol")
    if rtol is not None:
        de["tolerance"] = _fmt(rtol)
    if de:
        SubElement(root, "DefaultExperiment", de)


def _variability(v) -> str:
    return "fixed" if getattr(v, "type", "Real") == "String" and v.causality == "parameter" else v.variability


def _initial(v) -> str | None:
    return {"parameter": "exact", "output": "calculated"}.get(v.causality)


def _xml(root: Element) -> bytes:
    return parseString(tostring(root, "UTF-8")).toprettyxml(indent="  ", encoding="UTF-8")


def model_description(spec: dict, name: str, variables, version: str, guid: str | None = None,
                      cosimulation: dict | None = None, source_files=(), model_exchange: bool = False) -> bytes:
    """The complete FMI 2.0 modelDescription.xml for the given variables (variables.py; value reference = index).

    ``cosimulation`` overrides ``<CoSimulation>`` attributes, ``source_files`` fills its ``<SourceFiles>``
    (native FMUs), ``model_exchange`` adds ``<ModelExchange>`` (the variables then carry their derivatives:
    ``variables(spec, derivatives=True)``); everything else is the same for both kinds."""
    states = continuous_states(variables)
    root = _root("2.0", spec, name, version, {"guid": guid or _guid(spec, version)})
    root.set("numberOfEventIndicators", "0")
    interfaces = []
    if model_exchange:
        interfaces.append(SubElement(root, "ModelExchange", {"modelIdentifier": name, **MODEL_EXCHANGE}))
    interfaces.append(SubElement(root, "CoSimulation", {
        "modelIdentifier": name,
        "needsExecutionTool": "true",
        "canHandleVariableCommunicationStepSize": "true",
        "canInterpolateInputs": "false",
        "maxOutputDerivativeOrder": "0",
        "canRunAsynchronuously": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false",
        "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "true",
        "canSerializeFMUstate": "true",
        "providesDirectionalDerivative": "false",
        **(cosimulation or {}),
    }))
    for interface in interfaces if source_files else ():
        sf = SubElement(interface, "SourceFiles")
        for f in source_files:
            SubElement(sf, "File", {"name": f})
    _units(root, variables)
    _log_categories(root, "2.0")
    _default_experiment(root, spec)

    mv = SubElement(root, "ModelVariables")
    outputs, calculated = [], []  # indices (1-based) of the outputs, and of what initialization calculates
    for i, v in enumerate(variables):
        sv = {"name": v.name, "valueReference": str(i)}
        if getattr(v, "description", None):
            sv["description"] = str(v.description)
        sv["causality"] = v.causality
        is_string = getattr(v, "type", "Real") == "String"
        sv["variability"] = _variability(v)
        if _initial(v):
            sv["initial"] = _initial(v)
        if v.causality == "output":
            outputs.append(i + 1)
        if v.causality == "output" or v.derivative_of is not None:  # a local's initial is "calculated" by default
            calculated.append(i + 1)
        node = SubElement(mv, "ScalarVariable", sv)
        tattr = {}
        if is_string:
            if v.causality != "output":
                tattr["start"] = "" if v.start is None else str(v.start)
            SubElement(node, "String", tattr)
        else:
            if v.unit:
                tattr["unit"] = v.unit
            if v.derivative_of is not None:
                tattr["derivative"] = str(v.derivative_of.vr + 1)
            if v.nominal is not None:
                tattr["nominal"] = _fmt(v.nominal)
            if v.causality in ("parameter", "input"):
                tattr["start"] = _fmt(0.0 if v.start is None else v.start)
            SubElement(node, "Real", tattr)

    ms = SubElement(root, "ModelStructure")
    if outputs:
        o = SubElement(ms, "Outputs")
        for idx in outputs:  # no direct feedthrough from inputs; under model exchange outputs follow the states
            deps = _output_dependencies(variables[idx - 1], states)
            SubElement(o, "Unknown", {"index": str(idx), "dependencies": " ".join(str(v.vr + 1) for v in deps)})
    if states:  # der(y.*): their states (variables.py); der(yd.*): every state and input (no attribute says that)
        d = SubElement(ms, "Derivatives")
        for _, der in states:
            SubElement(d, "Unknown", {"index": str(der.vr + 1), **_derivative_dependencies(der, 1)})
    if calculated:
        iu = SubElement(ms, "InitialUnknowns")
        for idx in calculated:
            SubElement(iu, "Unknown", {"index": str(idx)} if variables[idx - 1].derivative_of is not None
                       else {"index": str(idx), "dependencies": ""})

    return _xml(root)


def _output_dependencies(output, states) -> list:
    """The knowns an output depends on: none without continuous states (co-simulation: no input reaches an
    output within a step); with them, the state itself for y.*/yd.*, every state for a point's r and v."""
    if not states:
        return []
    return [output] if output.kind in (L.MBS_V_Y, L.MBS_V_YD) else [s for s, _ in states]


def _derivative_dependencies(der, base: int) -> dict:
    """The dependencies attributes of a derivative (value reference + base: FMI 2.0 indices count from 1); none
    (every state and input) when variables.py lists none."""
    if der.depends_on is None:
        return {}
    kind, on = der.depends_on
    return {"dependencies": " ".join(str(v.vr + base) for v in sorted(on, key=lambda v: v.vr)),
            "dependenciesKind": " ".join([kind] * len(on))}


# FMI 3.0: what an FMU offers beyond the defaults (all false), per interface
FMI3_DERIVATIVES = {"providesDirectionalDerivatives": "true", "providesAdjointDerivatives": "true"}
FMI3_COSIMULATION = {"canHandleVariableCommunicationStepSize": "true", "canGetAndSetFMUState": "true",
                     "canSerializeFMUState": "true", "providesIntermediateUpdate": "true", "hasEventMode": "false",
                     **FMI3_DERIVATIVES}
FMI3_MODEL_EXCHANGE = {"needsCompletedIntegratorStep": "false", "canGetAndSetFMUState": "true",
                       "canSerializeFMUState": "true", **FMI3_DERIVATIVES}


def model_description3(spec: dict, name: str, variables, version: str, token: str) -> bytes:
    """The complete FMI 3.0 modelDescription.xml for the same variables (variables.py), grouped as FMI 3.0 sees
    them (``fmi3_variables``: arrays where they help, value reference = index), plus the independent variable
    ``time`` after them (fmi/fmi3.c answers it). ``<ModelExchange>`` when the list carries the derivative
    variables (``variables(spec, derivatives=True)``). An array's attributes are its elements' (a nominal: the
    smallest of theirs; the host asks fmi3GetNominalsOfContinuousStates for each state's own)."""
    states = continuous_states(variables)
    groups = fmi3_variables(variables)
    vr3 = {id(v): k for k, (_, vs, _) in enumerate(groups) for v in vs}  # a scalar's FMI 3.0 variable
    root = _root("3.0", spec, name, version, {"instantiationToken": token})
    if states:
        SubElement(root, "ModelExchange", {"modelIdentifier": name, **FMI3_MODEL_EXCHANGE})
    SubElement(root, "CoSimulation", {"modelIdentifier": name, **FMI3_COSIMULATION})
    _units(root, variables, ["s"])  # the independent variable's
    _log_categories(root, "3.0")
    _default_experiment(root, spec)

    mv = SubElement(root, "ModelVariables")
    SubElement(mv, "Float64", {"name": "time", "valueReference": str(len(groups)), "causality": "independent",
                               "variability": "continuous", "unit": "s", "description": "simulation time"})
    for k, (vname, vs, description) in enumerate(groups):
        v, array = vs[0], vname != vs[0].name
        attr = {"name": vname, "valueReference": str(k)}
        if description:
            attr["description"] = str(description)
        attr.update(causality=v.causality, variability=_variability(v))
        if _initial(v):
            attr["initial"] = _initial(v)
        if getattr(v, "type", "Real") == "String":
            SubElement(SubElement(mv, "String", attr), "Start", {"value": "" if v.start is None else str(v.start)})
            continue
        if v.unit:
            attr["unit"] = v.unit
        if v.causality in ("parameter", "input"):
            attr["start"] = " ".join(_fmt(0.0 if e.start is None else e.start) for e in vs)
        if v.causality == "output":  # readable in the intermediateUpdate callback (fmi/fmi3.c: intermediate)
            attr["intermediateUpdate"] = "true"
        if v.nominal is not None:
            attr["nominal"] = _fmt(min(e.nominal for e in vs))
        if v.derivative_of is not None:
            attr["derivative"] = str(vr3[id(v.derivative_of)])
        node = SubElement(mv, "Float64", attr)
        if array:
            SubElement(node, "Dimension", {"start": str(len(vs))})

    def ref(vs):  # the FMI 3.0 variables of these scalars, each once, in order
        return " ".join(str(k) for k in sorted({vr3[id(v)] for v in vs}))

    ms = SubElement(root, "ModelStructure")
    outputs = [vs for _, vs, _ in groups if vs[0].causality == "output"]
    for vs in outputs:
        deps = [d for v in vs for d in _output_dependencies(v, states)]
        SubElement(ms, "Output", {"valueReference": str(vr3[id(vs[0])]), "dependencies": ref(deps)})
    ders = [vs for _, vs, _ in groups if vs[0].derivative_of is not None]
    for vs in ders:
        attr = {}
        if all(v.depends_on is not None for v in vs):  # else on every state and input: no attribute
            on = sorted({vr3[id(d)] for v in vs for d in v.depends_on[1]})
            kinds = {v.depends_on[0] for v in vs}
            attr = {"dependencies": " ".join(map(str, on)),
                    "dependenciesKind": " ".join([kinds.pop() if len(kinds) == 1 else "dependent"] * len(on))}
        SubElement(ms, "ContinuousStateDerivative", {"valueReference": str(vr3[id(vs[0])]), **attr})
    for vs in outputs + ders:  # no dependencies attribute: on every known
        SubElement(ms, "InitialUnknown", {"valueReference": str(vr3[id(vs[0])])})
    return _xml(root)
