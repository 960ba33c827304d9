"""The compiled scene's layout is declared once (mbs_layout.h, issue 23): Python's reading of it (engine/layout.py)
is held against what a C compiler makes of the same header, and no Python source keeps a copy of its own."""

import ctypes
import random
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from mbsfmu.engine import layout
from mbsfmu.engine.layout import LayoutError, parse

ENGINE = Path(layout.__file__).parent
SRC = ENGINE.parent

needs_cc = pytest.mark.skipif(not (shutil.which("cc") or shutil.which("gcc")), reason="no C compiler")


def _c_values(tmp_path, includes, names, texts=()):
    """{name: value} as a C compiler evaluates each name (and each text constant of `texts`) after `includes`
    (compiled with -Wall -Werror)."""
    prog = "".join(f'#include "{h}"\n' for h in includes) + "#include <stdio.h>\nint main(void) {\n"
    prog += "".join(f'    printf("%s %lld\\n", "{n}", (long long)({n}));\n' for n in names)
    prog += "".join(f'    printf("%s %s\\n", "{n}", {n});\n' for n in texts) + "    return 0;\n}\n"
    (tmp_path / "layout_print.c").write_text(prog)
    exe = tmp_path / "layout_print"
    cc = shutil.which("cc") or shutil.which("gcc")
    subprocess.run([cc, "-std=c99", "-pedantic", "-Wall", "-Werror", f"-I{ENGINE}", f"-I{tmp_path}", "-o", str(exe),
                    str(tmp_path / "layout_print.c")], check=True, capture_output=True)
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout
    return {n: v if n in texts else int(v) for n, v in (line.split() for line in out.splitlines())}


@needs_cc
def test_every_constant_is_what_the_c_compiler_makes_of_the_header(tmp_path):
    """All ~200 names, included the way the engine includes them (mbs_model.h, mbs_integrator.h): a name the
    parser reads differently from C (offsets of wide fields, totals, flag values) fails here; a copy left in
    another header would not compile (redeclared enumerator)."""
    assert len(layout.CONSTANTS) > 190
    texts = sorted(n for n, v in layout.CONSTANTS.items() if isinstance(v, str))
    c = _c_values(tmp_path, ["mbs_model.h", "mbs_integrator.h"], sorted(set(layout.CONSTANTS) - set(texts)), texts)
    assert c == layout.CONSTANTS


@needs_cc
def test_parser_agrees_with_c_on_random_layouts(tmp_path):
    """Random lists of each kind (codes, fields of random widths, flag values) in the header's grammar: the
    parser's numbers are the compiler's, so its reading holds for lists not yet written too."""
    rng = random.Random(23)
    head = (ENGINE / "mbs_layout.h").read_text()
    generators = head[head.index("#define MBS_CODE("):head.index("#define MBS_FORMAT_VERSION")]
    lines = ["#ifndef MBS_LAYOUT_H", "#define MBS_LAYOUT_H", generators]
    for k in range(12):
        kind = ("MBS_CODE", "MBS_FIELD", "MBS_VALUE")[k % 3]
        entries = []
        for j in range(rng.randint(1, 9)):
            args = [f"T{k}_E{j}"]
            if kind != "MBS_CODE":
                args.append(str(rng.randint(1, 12) if kind == "MBS_FIELD" else 1 << j))
            if kind != "MBS_FIELD" and rng.random() < 0.5:
                args.append(f'"name_{j}"')
            entries.append(f"X({', '.join(args)})")
        lines.append(f"#define MBS_T{k}(X) \\\n    " + " \\\n    ".join(entries) + f"  /* list {k} */")
        lines.append(f"enum {{ MBS_T{k}({kind}){'' if kind == 'MBS_VALUE' else f' T{k}_N'} }};")
    lines += ["#define T_LIMIT 1073741824", "#endif"]
    text = "\n".join(lines) + "\n"
    (tmp_path / "mbs_layout.h").write_text(text)
    consts, _ = parse(text)
    assert _c_values(tmp_path, ["mbs_layout.h"], sorted(consts)) == consts


def test_engine_method_names_are_the_layouts():
    """The names the engine accepts for integrator.method (mbs_method_names, generated from MBS_METHODS) are
    Python's, in code order."""
    from mbsfmu.engine.build import library_path
    lib = ctypes.CDLL(str(library_path()))
    names = (ctypes.c_char_p * layout.MBS_NMETHODS).in_dll(lib, "mbs_method_names")
    assert tuple(n.decode() for n in names) == layout.METHODS


def test_joint_table_has_exactly_the_layouts_joints():
    """The joint table (kinematics/joints.py: loader, compiler, units, docs) and mbs_layout.h's MBS_JOINTS list the
    same (type, parameterization) pairs: a joint added on one side only fails here."""
    from mbsfmu.kinematics.joints import JOINTS
    assert set(JOINTS) == {(e[1], e[2] or None) for e in layout.LISTS["MBS_JOINTS"]}


@pytest.mark.parametrize("entry", layout.LISTS["MBS_JOINTS"], ids=lambda e: e[0])
def test_joint_table_row_is_the_layouts_and_the_kinematics(entry):
    """Each row's engine code is the header's, and its coordinate counts are the header's (which model.c checks a
    compiled body against), its default names' and units', and those of the numpy reference's joint object."""
    from mbsfmu.kinematics.joints import JOINTS
    name, kind, param, npos, nvel, naxes, rot, gimbal = entry
    row = JOINTS[(kind, param or None)]
    joint = row.make(axis=[0, 0, 1], axes=[[1, 0, 0], [0, 1, 0]])
    assert row.code == layout.CONSTANTS[name]
    assert (joint.npos, joint.nvel) == (row.npos, row.nvel) == (npos, nvel)
    assert (len(row.units), len(row.velocity_units)) == (npos, nvel)
    # the engine's columns (mbs_derive, mbs_initial_state, the gimbal check) are the scene's fields and names
    assert naxes == (1 if "axis" in row.fields else 2 if "axes" in row.fields else 0)
    orientation = row.quaternion or row.cardan
    assert rot == (orientation.start if orientation else -1)
    assert gimbal == (row.cardan.start + 1 if row.cardan else -1)


ROOT = Path(__file__).resolve().parents[1]


def joint_code_missing(entry, tree_c=None, docs=None):
    """What a row of MBS_JOINTS lacks, one place for all: the numpy reference's row (kinematics/joints.py), the
    engine's motion (a `case` of tree.c's joint_motion; the fixed joint has none), the scene format's row
    (docs/scene-format.md) and an example scene (docs/examples/<type>.yaml or <type>_<parameterization>.yaml)."""
    from mbsfmu.kinematics.joints import JOINTS
    name, kind, param = entry[:3]
    tree_c = (ENGINE / "tree.c").read_text() if tree_c is None else tree_c
    docs = (ROOT / "docs" / "scene-format.md").read_text() if docs is None else docs
    motion = tree_c[tree_c.index("static void joint_motion("):]
    motion = motion[:motion.index("\n}\n")]
    missing = []
    if (kind, param or None) not in JOINTS:
        missing.append("a row in kinematics/joints.py's JOINTS")
    if name != "J_FIXED" and f"case {name}:" not in motion:
        missing.append(f"its motion in tree.c's joint_motion (case {name}:)")
    if f"\n| {kind} |" not in docs:
        missing.append(f"its row in docs/scene-format.md's joint table (| {kind} |)")
    if not any((ROOT / "docs" / "examples" / f).exists() for f in (f"{kind}.yaml", f"{kind}_{param}.yaml")) \
            and kind != "fixed":
        missing.append(f"an example scene docs/examples/{kind}.yaml")
    return missing


@pytest.mark.parametrize("entry", layout.LISTS["MBS_JOINTS"], ids=lambda e: e[0])
def test_every_joint_row_has_its_code(entry):
    assert joint_code_missing(entry) == []


def test_a_joint_row_without_its_code_fails_loudly():
    """A joint type added to mbs_layout.h alone: the one check names every piece it lacks."""
    entry = ("J_HELICAL", "helical", "", 1, 1, 1, -1, -1)
    assert joint_code_missing(entry) == [
        "a row in kinematics/joints.py's JOINTS", "its motion in tree.c's joint_motion (case J_HELICAL:)",
        "its row in docs/scene-format.md's joint table (| helical |)", "an example scene docs/examples/helical.yaml"]


@pytest.mark.parametrize("text, words", [
    ("#define MBS_A(X) X(A0) X(A1)\nenum { MBS_A(MBS_CODE) A_N };\nint x;\n", ["not a line of the layout"]),
    ("#define MBS_A(X) X(A0, 1.5)\n", ["1.5", "not a NAME, an integer"]),
    ("#define MBS_A(X) X(A0) X(A0)\nenum { MBS_A(MBS_CODE) };\n", ["A0 declared twice"]),
    ("enum { MBS_B(MBS_CODE) B_N };\n", ["MBS_B", "not declared"]),
    ("#define MBS_A(X) X(A0) junk\n", ["expected X(...)"]),
    ("#define MBS_A(X) X(A0)\nenum { MBS_A(MBS_FIELD) A_N };\n", ["A0", "integer second argument"]),
    ("#define MBS_A(X) X(A0, 1)\nenum { MBS_A(MBS_VALUE) A_N };\n", ["no total"]),
    ("#define A 1 + 2\n", ["not a line of the layout"]),
])
def test_a_line_outside_the_grammar_is_refused_with_its_line(text, words):
    """A line the parser does not know would be a constant C has and Python not: refused, naming the line."""
    with pytest.raises(LayoutError) as e:
        parse("/* a\n comment */\n" + text, "t.h")
    for w in words + ["t.h:"]:
        assert w in str(e.value)


def test_no_python_source_keeps_its_own_copy_of_a_layout_name():
    """The class of defect the header removes: a module assigning a name of the layout (an offset, a size, a
    code) a number by hand, which nothing keeps equal to C's. (The scan finds every copy compile.py and
    elastic_tables.py held before.)"""
    names = "|".join(sorted(layout.CONSTANTS, key=len, reverse=True))
    assign = re.compile(rf"^\s*(?:[A-Z0-9_]+\s*,\s*)*(?:{names})\b(?:\s*,\s*[A-Z0-9_]+)*\s*=\s*(?:-?\d|range\()", re.M)
    bad = [f"{p.relative_to(SRC)}: {m.group(0).strip()}" for p in sorted(SRC.rglob("*.py")) if p.name != "layout.py"
           for m in assign.finditer(p.read_text())]
    assert not bad, bad


@pytest.mark.parametrize("entry", layout.LISTS["MBS_METHODS"], ids=lambda e: e[1])
def test_method_accuracy_column_is_what_the_engine_does(entry):
    """MBS_METHODS says what sets each integrator's accuracy (the benchmarks sweep rtol or the step from it): a
    "tolerance" method ignores integrator.step (bit for bit) and follows rtol; a "step" method follows the step."""
    import numpy as np
    from mbsfmu import load
    from mbsfmu.simulation import Simulation
    spec = load(SRC.parents[1] / "models" / "double_pendulum.yaml").spec
    _, method, _, control = entry

    def run(rtol, step):
        sim = Simulation(spec)
        for k, v in (("method", method), ("rtol", rtol), ("atol", rtol * 1e-2), ("step", step)):
            sim.set(f"integrator.{k}", v)
        sim.initialize(0.0)
        return sim.run(np.linspace(0.0, 0.5, 26))
    base = run(1e-3, 1e-3)
    step_changes = np.abs(run(1e-3, 5e-4) - base).max()
    rtol_changes = np.abs(run(1e-8, 1e-3) - base).max()
    assert control in ("tolerance", "step")
    if control == "tolerance":
        assert step_changes == 0.0 and rtol_changes > 1e-6
    else:
        assert step_changes > 1e-12


def _joint_rows():
    from mbsfmu.kinematics.joints import JOINTS
    return list(JOINTS.values())


@pytest.mark.parametrize("row", _joint_rows(), ids=lambda r: f"{r.kind}-{r.param}")
def test_joint_table_units_and_flags_are_the_kinematics(row):
    """What the table says of each coordinate (its unit, hence the loader's angle reading and the FMU's units) and
    of the joint (free orientation, free translation) is what the numpy joint does: moving an "m" coordinate by δ
    translates the joint frame by δ without turning it, a "rad" one turns it by δ without translating, "1" is the
    unit quaternion; a "m/s" velocity's H_T column is a unit vector (H_R's zero), a "rad/s" one the other way."""
    import numpy as np
    joint = row.make(axis=[0, 0, 1], axes=[[1, 0, 0], [0, 1, 0]])
    p0, v0 = np.zeros(row.npos), np.zeros(row.nvel)
    if row.quaternion is not None:
        p0[row.quaternion.start] = 1.0

    def frame(p):
        R, d = joint.motion(p, v0)[:2]
        return (np.eye(3) if R is None else R), (np.zeros(3) if d is None else d)
    R0, d0 = frame(p0)
    for k, unit in enumerate(row.units):
        if unit == "1":
            assert row.quaternion is not None and row.quaternion.start <= k < row.quaternion.stop
            continue
        p = p0.copy()
        p[k] += 0.3
        R, d = frame(p)
        angle = np.arccos(np.clip((np.trace(R0.T @ R) - 1) / 2, -1, 1))
        moved = np.linalg.norm(d - d0)
        assert (moved, angle) == pytest.approx((0.3, 0.0) if unit == "m" else (0.0, 0.3), abs=1e-12), (k, unit)
    H_R, H_T = joint.motion(p0, v0)[2:4]
    H_R = np.zeros((3, row.nvel)) if H_R is None else H_R
    H_T = np.zeros((3, row.nvel)) if H_T is None else H_T
    for k, unit in enumerate(row.velocity_units):
        norms = (np.linalg.norm(H_T[:, k]), np.linalg.norm(H_R[:, k]))
        assert norms == pytest.approx((1.0, 0.0) if unit == "m" else (0.0, 1.0), abs=1e-12), (k, unit)
    assert row.orientation == (np.linalg.matrix_rank(H_R) == 3)
    assert row.translation == (np.linalg.matrix_rank(H_T) == 3)


def test_no_source_writes_the_integrator_lists_by_hand():
    """The class of defect the integrator table removes: a tuple, list or set literal naming every method, or every
    adaptive or fixed-step one (layout.METHODS, ADAPTIVE, FIXED_STEP are those lists), which a new integrator would
    have to be added to by hand. A subset chosen for a purpose (the methods a stress case runs) is not a copy."""
    import ast
    views = {frozenset(layout.METHODS), frozenset(layout.ADAPTIVE), frozenset(layout.FIXED_STEP)}
    bad = []
    for p in sorted(SRC.rglob("*.py")) + sorted((SRC.parents[1] / "tests").rglob("*.py")):
        for n in ast.walk(ast.parse(p.read_text())):
            names = [e.value for e in getattr(n, "elts", ()) if isinstance(e, ast.Constant)]
            if isinstance(n, (ast.Tuple, ast.List, ast.Set)) and len(names) == len(n.elts) > 1 \
                    and frozenset(names) in views:
                bad.append(f"{p.name}:{n.lineno}: {names}")
    assert not bad, bad


def test_no_source_branches_on_joint_types_by_hand():
    """The class of defect the joint table removes: a module naming two or more scene joint types in a literal
    (`kind in ("spherical", "free")`, a dict of per-type defaults) or comparing a kind with one, which a new joint
    type would have to be added to by hand. Only the table says what a type is; URDF's own joint kinds (urdf.py)
    and the peers' twins (what Exudyn or Pinocchio can model: reports/work_precision.py, benchmarks/) are other vocabularies."""
    import ast
    from mbsfmu.kinematics.joints import TYPES
    own = {"kinematics/joints.py", "scene/urdf.py", "reports/work_precision.py"}  # the last: its Exudyn twin's joints
    words = set(TYPES) - {"fixed", "free"}  # compared alone, these two are also variabilities and CMS mode kinds
    bad = []
    for p in sorted(SRC.rglob("*.py")):
        rel = p.relative_to(SRC).as_posix()
        if rel in own:
            continue
        for n in ast.walk(ast.parse(p.read_text())):
            items = getattr(n, "elts", None) or (n.keys if isinstance(n, ast.Dict) else [])
            named = [e.value for e in items if isinstance(e, ast.Constant) and e.value in TYPES]
            compared = isinstance(n, ast.Compare) and any(isinstance(c, ast.Constant) and c.value in words
                                                          for c in n.comparators)
            if len(named) > 1 or compared:
                bad.append(f"{rel}:{n.lineno}")
    assert not bad, bad


def test_variable_kinds_columns_are_the_fmu_variables():
    """MBS_VAR_KINDS' columns (how a host sets a kind, whether it follows from the state, its role in directional
    derivatives: what the engine and its FMI layers read) agree with the FMU variables the compiler declares, for
    a scene with every kind (parameters, settings, inputs, states, outputs, derivatives, stresses)."""
    import mbsfmu
    from mbsfmu.compiler.model import Model
    from mbsfmu.compiler.variables import variables
    vs = []
    for scene in ("fe_stress.yaml", "crane.yaml"):
        spec = mbsfmu.load(ROOT / "models" / scene).spec
        vs += variables(spec, Model(spec), derivatives=True)
    rows = {layout.CONSTANTS[e[0]]: e for e in layout.LISTS["MBS_VAR_KINDS"]}
    assert {v.kind for v in vs} == set(rows)  # the two scenes have every kind
    for v in vs:
        name, _, set_, state, role = rows[v.kind]
        want = {0: {"output", "local"}, 1: {"parameter"}, 2: {"parameter"}, 3: {"input"}}[set_]
        assert v.causality in want, (v.name, name)
        if set_ == 2:
            assert v.variability == "fixed", v.name
        # follows from the state: exactly the states and what the ODE computes from them
        assert state == (v.causality in {"output", "local"}), v.name
        assert (role & 1) == (name in ("MBS_V_Y", "MBS_V_YD") or set_ == 3), v.name   # knowns: states, inputs
        assert bool(role & 2) == (set_ == 0), v.name                                   # unknowns: what it computes
