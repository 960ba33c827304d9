"""Which scene key gives each FMU variable, so that two scene names that would give one FMU variable are refused
at load, naming both. The variables themselves (names, order, kinds) are compiler/variables.py's: this module only
traces each one back to the key it comes from, through the engine's variable kind and index."""

from ..engine import layout as L
from ..compiler.elastic_tables import stress_points
from ..compiler.model import Model
from ..compiler.variables import variables


def fmu_variables(spec):
    """[(FMU variable name, what gives it, key path of its source in the scene)] in value-reference order."""
    model = Model(spec, bind=False)
    coordinate = {}  # coordinate name → (what, path); the loader already refused a name two bodies give
    for b in spec["bodies"]:
        for c in b["joint"]["coordinates"] + b["joint"]["velocities"]:
            coordinate.setdefault(c, (f"coordinate '{c}'", f"bodies.{b['name']}.joint.coordinates"))
        for c in b["elastic"]["coordinates"] if b["elastic"] else ():
            coordinate.setdefault(c, (f"elastic coordinate '{c}'", f"bodies.{b['name']}.elastic.coordinates"))
    inputs = [i for i, f in enumerate(spec["forces"]) if "input" in f]  # FIN index // 3 → force

    def parameter(i):
        name = spec["parameters"][i]["name"]
        return f"parameter '{name}'", f"parameters.{name}"

    def force_input(i):
        k = inputs[i // 3]
        return f"input '{spec['forces'][k]['input']}'", f"forces[{k}].input"

    def output(i):
        return f"output '{spec['outputs'][i // 6]['name']}'", f"outputs[{i // 6}]"

    points = stress_points(spec)

    def stress(i):
        body, node = points[i]
        return f"stress node '{node}' of '{body}'", f"bodies.{body}.elastic.fe.stress"

    def setting(i):  # integrator.method, .rtol, ...
        return "the integrator settings", "integrator"

    source = {L.MBS_V_PARAM: parameter, L.MBS_V_FIN: force_input, L.MBS_V_OUT: output, L.MBS_V_VM: stress,
              L.MBS_V_Y: lambda i: coordinate[model.coordinates[i]],
              L.MBS_V_QIN: lambda i: coordinate[model.velocity_coordinates[i]],
              L.MBS_V_YD: lambda i: coordinate[model.velocity_coordinates[i]]}
    return [(v.name, *source.get(v.kind, setting)(v.index)) for v in variables(spec, model, nominals=False)]


def first_collision(spec):
    """None, or ((variable, source, path) given first, (variable, source, path) that repeats it)."""
    seen = {}
    for v in fmu_variables(spec):
        if v[0] in seen:
            return seen[v[0]], v
        seen[v[0]] = v
    return None
