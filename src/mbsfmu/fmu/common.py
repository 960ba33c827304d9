"""What both FMU kinds share (build.py: pythonfmu kind, native.py: native kind): the one FMI 2.0
modelDescription writer, the drawing description, the archive writer and the version they carry."""

from __future__ import annotations

import datetime
import json
import uuid
import warnings
import zipfile
from xml.dom.minidom import parseString
from xml.etree.ElementTree import Element, SubElement, tostring

from ..engine import layout as L
from .variables import continuous_states

DRAWING_FILE = "mbsfmu_drawing.json"  # in resources/: what `mbsfmu animate FMU` draws from (animation/trajectory.py)

LOG_CATEGORIES = {
    "logStatusWarning": "Log messages with fmi2Warning status.",
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
    from ..scene.limits import DRAWING_BYTES
    data = json.dumps(spec, separators=(",", ":")).encode("utf-8")
    if len(data) > DRAWING_BYTES:
        warnings.warn(f"{spec['name']}: no drawing description in the FMU ({len(data)} bytes, at most "
                      f"{DRAWING_BYTES}); animate it with --scene", RuntimeWarning, stacklevel=3)
        return {}
    return {f"resources/{DRAWING_FILE}": data}


def _fmt(x) -> str:
    return repr(float(x))  # the shortest text that reads back to the same double (0.4, not 0.40000000000000002)


# <ModelExchange> of an FMU that offers it (native kind): the same capabilities as its co-simulation
MODEL_EXCHANGE = {
    "needsExecutionTool": "false",
    "completedIntegratorStepNotNeeded": "true",  # fmi2CompletedIntegratorStep does nothing (docs/fmu.md)
    "canBeInstantiatedOnlyOncePerProcess": "false",
    "canNotUseMemoryManagementFunctions": "true",
    "canGetAndSetFMUstate": "true",
    "canSerializeFMUstate": "true",
    "providesDirectionalDerivative": "false",
}


def model_description(spec: dict, name: str, variables, version: str, guid: str | None = None,
                      cosimulation: dict | None = None, source_files=(), model_exchange: bool = False) -> bytes:
    """The complete FMI 2.0 modelDescription.xml for the given variables (variables.py; value reference = index).

    ``cosimulation`` overrides ``<CoSimulation>`` attributes, ``source_files`` fills its ``<SourceFiles>``
    (native FMUs), ``model_exchange`` adds ``<ModelExchange>`` (the variables then carry their derivatives:
    ``variables(spec, derivatives=True)``); everything else is the same for both kinds."""
    states = continuous_states(variables)
    guid = guid or "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, "mbsfmu:" + json.dumps(spec, sort_keys=True)
                                        + ":" + version)) + "}"
    attrib = {
        "fmiVersion": "2.0",
        "modelName": name,
        "guid": guid,
        "description": spec.get("description") or name,
        "generationTool": f"mbsfmu {version}",
        "generationDateAndTime": datetime.datetime.now(datetime.timezone.utc)
        .replace(microsecond=0).isoformat().replace("+00:00", "Z"),
        "variableNamingConvention": "structured",
        "numberOfEventIndicators": "0",
    }
    root = Element("fmiModelDescription", attrib)
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

    used_units = []
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

    cats = SubElement(root, "LogCategories")
    for cat, desc in LOG_CATEGORIES.items():
        SubElement(cats, "Category", {"name": cat, "description": desc})

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

    mv = SubElement(root, "ModelVariables")
    outputs, calculated = [], []  # indices (1-based) of the outputs, and of what initialization calculates
    for i, v in enumerate(variables):
        sv = {"name": v.name, "valueReference": str(i)}
        if getattr(v, "description", None):
            sv["description"] = str(v.description)
        sv["causality"] = v.causality
        is_string = getattr(v, "type", "Real") == "String"
        variability = v.variability
        if is_string and v.causality == "parameter":
            variability = "fixed"
        sv["variability"] = variability
        if v.causality == "parameter":
            sv["initial"] = "exact"
        elif v.causality == "output":
            sv["initial"] = "calculated"
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
            if v.causality in ("parameter", "input"):
                tattr["start"] = _fmt(0.0 if v.start is None else v.start)
            SubElement(node, "Real", tattr)

    ms = SubElement(root, "ModelStructure")
    state_indices = " ".join(str(s.vr + 1) for s, _ in states)
    if outputs:
        o = SubElement(ms, "Outputs")
        for idx in outputs:  # no direct feedthrough from inputs; under model exchange outputs follow the states
            SubElement(o, "Unknown", {"index": str(idx), "dependencies": _state_dependencies(variables[idx - 1],
                                                                                           state_indices)})
    if states:  # der(y.*): their states (variables.py); der(yd.*): every state and input (no attribute says that)
        d = SubElement(ms, "Derivatives")
        for _, der in states:
            deps = {}
            if der.depends_on is not None:
                kind, on = der.depends_on
                deps = {"dependencies": " ".join(str(v.vr + 1) for v in sorted(on, key=lambda v: v.vr)),
                        "dependenciesKind": " ".join([kind] * len(on))}
            SubElement(d, "Unknown", {"index": str(der.vr + 1), **deps})
    if calculated:
        iu = SubElement(ms, "InitialUnknowns")
        for idx in calculated:
            SubElement(iu, "Unknown", {"index": str(idx)} if variables[idx - 1].derivative_of is not None
                       else {"index": str(idx), "dependencies": ""})

    return parseString(tostring(root, "UTF-8")).toprettyxml(indent="  ", encoding="UTF-8")


def _state_dependencies(output, state_indices: str) -> str:
    """An output's dependencies on the knowns: none without continuous states (co-simulation: no input reaches an
    output within a step); with them, the state itself for y.*/yd.*, every state for a point's r and v."""
    if not state_indices:
        return ""
    return str(output.vr + 1) if output.kind in (L.MBS_V_Y, L.MBS_V_YD) else state_indices
