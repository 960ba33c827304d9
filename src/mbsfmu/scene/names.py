"""The FMU variable names a scene generates (contract: docs/fmu.md, "Variables"), each with the scene
key it comes from, so that two scene names that would give one FMU variable are refused at load, naming both."""

from ..engine.layout import LISTS

INTEGRATOR = tuple(e[1] for e in LISTS["MBS_VAR_KINDS"] if e[1])  # the settable integrator settings


def fmu_variables(spec):
    """[(FMU variable name, what gives it, key path of its source in the scene)] in the FMU's order."""
    out = [(p["name"], f"parameter '{p['name']}'", f"parameters.{p['name']}") for p in spec["parameters"]]
    out += [(v, "the integrator settings", "integrator") for v in INTEGRATOR]
    for b in spec["bodies"]:
        j, path = b["joint"], f"bodies.{b['name']}.joint.coordinates"
        driven = set(j["drive"])
        quat = j["type"] in ("spherical", "free") and j.get("parameterization") == "quaternion"
        for c in j["coordinates"]:
            if c not in driven:
                out.append((f"y.{c}", f"coordinate '{c}'", path))
        for c in j["velocities"]:
            if quat or c not in driven:
                out += [(f"q.{c}", f"coordinate '{c}'", path), (f"yd.{c}", f"coordinate '{c}'", path)]
        if b["elastic"]:
            for c in b["elastic"]["coordinates"]:
                epath = f"bodies.{b['name']}.elastic.coordinates"
                out += [(f"{v}.{c}", f"elastic coordinate '{c}'", epath) for v in ("y", "q", "yd")]
    for i, f in enumerate(spec["forces"]):
        if "input" in f:
            out += [(f"{f['input']}.{x}", f"input '{f['input']}'", f"forces[{i}].input") for x in "xyz"]
    for i, o in enumerate(spec["outputs"]):
        for quantity, sym in (("position", "r"), ("velocity", "v")):
            if quantity in o["quantities"]:
                out += [(f"{o['name']}.{sym}.{x}", f"output '{o['name']}'", f"outputs[{i}]") for x in "xyz"]
    return out


def first_collision(spec):
    """None, or ((variable, source, path) given first, (variable, source, path) that repeats it)."""
    seen = {}
    for v in fmu_variables(spec):
        if v[0] in seen:
            return seen[v[0]], v
        seen[v[0]] = v
    return None
