"""compiler/variables.py owns the FMU variables: listed from the normalized scene without the engine, they are what
both kinds of built FMU declare (read back with fmpy), they address every engine slot once, and the fmu
package's modules import each other without a cycle."""

import ast
import json
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from mbsfmu import load
from mbsfmu.engine import layout as L
from mbsfmu.fmu.build import build_fmu
from mbsfmu.compiler.variables import variables

ROOT = Path(__file__).resolve().parent.parent
MODELS = sorted((ROOT / "models").glob("*.yaml"))
FMU_PACKAGE = ROOT / "src" / "mbsfmu" / "fmu"

LIST_WITHOUT_ENGINE = r"""
import json, sys
import mbsfmu
from mbsfmu.compiler.variables import variables
listed = {p: [v.name for v in variables(mbsfmu.load(p).spec)] for p in sys.argv[1:]}
import mbsfmu.engine
maps = open("/proc/self/maps").read()
print(json.dumps({"listed": listed, "library": mbsfmu.engine._lib is not None,
                  "mapped": [line.split()[-1] for line in maps.splitlines() if "mbs" in line.split()[-1]],
                  "modules": sorted(m for m in sys.modules if m.startswith("mbsfmu"))}))
"""


def test_listing_every_shipped_model_loads_no_engine():
    out = subprocess.run([sys.executable, "-c", LIST_WITHOUT_ENGINE, *map(str, MODELS)], capture_output=True,
                         text=True, check=True, timeout=120)
    seen = json.loads(out.stdout)
    assert all(seen["listed"][str(p)] for p in MODELS)
    assert not seen["library"] and not seen["mapped"]  # no engine library loaded or mapped
    engine_side = {"mbsfmu.simulation", "mbsfmu.engine.api", "mbsfmu.engine.build", "mbsfmu.compiler.scene_file",
                   "mbsfmu.fmu.native"}
    assert not engine_side & set(seen["modules"])


def _declared(fmu):
    from fmpy import read_model_description
    return read_model_description(str(fmu)).modelVariables


def _assert_declares(fmu, listed):
    declared = _declared(fmu)
    assert [d.name for d in declared] == [v.name for v in listed]
    for d, v in zip(declared, listed):
        assert (d.valueReference, d.causality, d.variability, d.type) == (v.vr, v.causality, v.variability, v.type)
        assert (d.unit, d.description) == (v.unit, v.description)
        assert (d.derivative.name if d.derivative else None) == (v.derivative_of.name if v.derivative_of else None)
        if v.causality in ("output", "local"):
            assert d.start is None
        elif v.type == "String":
            assert d.start == v.start
        else:
            assert float(d.start) == float(v.start)


@pytest.mark.parametrize("path", MODELS, ids=[p.stem for p in MODELS])
def test_listing_is_what_the_pythonfmu_fmu_declares(path, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fmu = build_fmu(str(path), tmp_path, shim=False)
    _assert_declares(fmu, variables(load(path).spec))


def test_listing_is_what_the_native_fmu_declares(tmp_path, monkeypatch):
    from mbsfmu.fmu import native
    monkeypatch.setattr(native, "MINGW", "no-mingw-in-this-test")  # linux64 only: the declaration is the same
    path = ROOT / "models" / "robot_arm_elastic.yaml"  # force inputs, output points, structural parameters
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fmu = build_fmu(str(path), tmp_path, kind="native")
    _assert_declares(fmu, variables(load(path).spec, derivatives=True))  # model exchange: der(·) after the rest


def _slots(spec):
    """{engine variable kind: number of its slots}, counted from the scene (mbs_layout.h MBS_V_*)."""
    from mbsfmu.compiler.model import Model
    m = Model(spec)
    n_points = {o["name"]: len(o["quantities"]) for o in spec["outputs"]}
    return {L.MBS_V_PARAM: len(spec["parameters"]), L.MBS_V_QIN: m.nvel, L.MBS_V_Y: m.npos, L.MBS_V_YD: m.nvel,
            L.MBS_V_FIN: 3 * sum("input" in f for f in spec["forces"]),
            L.MBS_V_OUT: 3 * sum(n_points.values()), L.MBS_V_DER: m.npos + m.nvel,
            L.MBS_V_VM: sum(len((b["elastic"] or {}).get("fe", {}).get("stress_nodes", [])) for b in spec["bodies"])}


@pytest.mark.parametrize("path", MODELS, ids=[p.stem for p in MODELS])
def test_every_engine_slot_has_one_variable(path):
    spec = load(path).spec
    rows = [(v.kind, v.index) for v in variables(spec, derivatives=True)]
    assert len(set(rows)) == len(rows)
    for kind, count in _slots(spec).items():
        indices = sorted(i for k, i in rows if k == kind)
        assert len(indices) == count
        if kind == L.MBS_V_OUT:  # 6 per point: r.x r.y r.z v.x v.y v.z, present when the quantity is asked for
            assert all(i < 6 * len(spec["outputs"]) for i in indices)
        else:
            assert indices == list(range(count))
    settings = {k for k, _ in rows} - set(_slots(spec))
    assert settings == {L.MBS_V_METHOD, L.MBS_V_RTOL, L.MBS_V_ATOL, L.MBS_V_MAX_STEP, L.MBS_V_STEP}


def _imports(path: Path, package: str) -> set[str]:
    """Modules of ``package`` that the file imports, at the top or inside functions."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1:  # from .x import y / from . import x
                if node.module:
                    found.add(f"{package}.{node.module}")
                else:
                    found.update(f"{package}.{a.name}" for a in node.names)
            elif node.level == 0 and node.module and node.module.startswith(package + "."):
                found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith(package + "."))
    return found


def _cycle(graph: dict[str, set[str]]):
    """A list of modules that import each other in a ring, or None."""
    state, stack = {}, []

    def visit(n):
        state[n] = "open"
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == "open":
                return stack[stack.index(m):] + [m]
            if m not in state and (ring := visit(m)):
                return ring
        state[n] = "done"
        stack.pop()
        return None

    for n in sorted(graph):
        if n not in state and (ring := visit(n)):
            return ring
    return None


def test_the_cycle_finder_finds_a_ring():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_import_cycle_between_fmu_modules():
    package = "mbsfmu.fmu"
    modules = {f"{package}.{p.stem}" if p.stem != "__init__" else package: p for p in FMU_PACKAGE.glob("*.py")}
    graph = {name: (_imports(path, package) & set(modules)) - {name} for name, path in modules.items()}
    assert graph[f"{package}.native"], "the walk sees native.py's imports"
    assert _cycle(graph) is None
