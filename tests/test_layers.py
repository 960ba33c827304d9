"""The package's floors, written once (LAYERS), lowest first: a module imports from its own floor or below. An
import that runs back up a floor is refused unless UP names it with the reason; no two modules import each other,
directly or round a circle, whether the import sits at the top of the file or inside a function."""
from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = SRC / "mbsfmu"

# (floor, module prefixes): a module belongs to the floor of its longest matching prefix
LAYERS = [
    ("base", ["mbsfmu.errors", "mbsfmu.expr", "mbsfmu.files", "mbsfmu.version", "mbsfmu.limits", "mbsfmu.datafile",
              "mbsfmu.engine.layout"]),  # the C engine's tables (mbs_layout.h), which C and Python share
    ("kinematics", ["mbsfmu.kinematics"]),
    ("scene", ["mbsfmu.scene", "mbsfmu.bodies"]),  # reading and checking a scene; reducing its elastic bodies
    ("compile", ["mbsfmu.compiler"]),
    ("run", ["mbsfmu.engine", "mbsfmu.equations"]),  # the C engine and its seam; the numpy reference
    ("simulate", ["mbsfmu.csvfile", "mbsfmu.inputs", "mbsfmu.simulation"]),
    ("deliver", ["mbsfmu.fmu", "mbsfmu.animation", "mbsfmu.plot", "mbsfmu.sweep"]),
    ("commands", ["mbsfmu.reports", "mbsfmu.cli", "mbsfmu.__main__", "mbsfmu"]),
]

UP = {  # (importer, imported): why it may run up
    ("mbsfmu.scene.names", "mbsfmu.compiler.model"):
        "a scene whose two names make one FMU variable is refused at load, naming both lines; the names are the compiler's",
    ("mbsfmu.scene.names", "mbsfmu.compiler.variables"): "as above",
    ("mbsfmu.scene.names", "mbsfmu.compiler.elastic_tables"): "as above (the stress outputs' nodes)",
}


def _module(path):
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _exists(name):
    p = SRC.joinpath(*name.split("."))
    return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()


def imports():
    """{module: {imported mbsfmu module: line}} of every import statement, anywhere in the file."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        mod = _module(path)
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        found = out.setdefault(mod, {})
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[:len(package.split(".")) - node.level + 1]
                    base = ".".join(up + ([node.module] if node.module else []))
                targets = [f"{base}.{a.name}" if _exists(f"{base}.{a.name}") else base for a in node.names]
            else:
                continue
            for t in targets:
                if t.startswith("mbsfmu") and t != mod:
                    found.setdefault(t, node.lineno)
    return out


def floor(mod):
    best = max(((len(p), i) for i, (_, prefixes) in enumerate(LAYERS) for p in prefixes
                if mod == p or mod.startswith(p + ".")), default=None)
    assert best is not None, f"{mod} is on no floor: add it to LAYERS"
    return best[1]


def test_every_module_is_on_a_floor_and_imports_only_down_or_level():
    up = [f"{m}:{line} imports {t} ({LAYERS[floor(t)][0]} above {LAYERS[floor(m)][0]})"
          for m, ts in imports().items() for t, line in ts.items()
          if floor(t) > floor(m) and (m, t) not in UP]
    assert not up, "imports that run back up a floor:\n" + "\n".join(up)


def test_the_exceptions_are_still_needed():
    graph = imports()
    stale = [pair for pair in UP if pair[1] not in graph.get(pair[0], {})]
    assert not stale, f"UP names imports that no longer exist: {stale}"


def test_no_circle_of_imports():
    graph = {m: set(ts) for m, ts in imports().items()}
    state, circles = {}, []

    def visit(m, path):  # depth first; a grey node met again closes a circle
        state[m] = "grey"
        for t in sorted(graph.get(m, ())):
            if state.get(t) == "grey":
                circles.append(" → ".join(path[path.index(t):] + [t]))
            elif t not in state:
                visit(t, path + [t])
        state[m] = "black"

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert not circles, "import circles:\n" + "\n".join(circles)
