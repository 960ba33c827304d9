"""Broken scenes: ModelError naming the file, the line, the key path and a hint; nothing is ever executed."""

import os

import numpy as np
import pytest

import mbsfmu
from mbsfmu.expr import ExprError, parse

BASE = """mbsfmu: 1
name: demo
parameters:
  L: 1.0
bodies:
  link1:
    parent: world
    joint:
      type: revolute
      axis: [0, 1, 0]
      coordinates: [phi1]
      initial: {phi1: 0.5}
    mass: 1.0
    center_of_mass: [0, 0, -L/2]
    inertia: {xx: 0.1, yy: 0.1, zz: 0.01}
  link2:
    parent: link1
    joint: {type: revolute, axis: [0, 1, 0], at: [0, 0, -L], coordinates: [phi2]}
    mass: 1.0
    inertia: {xx: 0.1, yy: 0.1, zz: 0.01}
"""
INERTIA1 = "    inertia: {xx: 0.1, yy: 0.1, zz: 0.01}\n  link2"
COM1 = "center_of_mass: [0, 0, -L/2]"

# case: (replace this, by that, line, key path, words the message must contain)
CASES = {
    "unknown_joint_type": ("      type: revolute", "      type: revolut", 9, "bodies.link1.joint.type",
                           ["unknown joint type 'revolut'", "did you mean 'revolute'"]),
    "negative_mass": ("    mass: 1.0\n    center", "    mass: -2\n    center", 13, "bodies.link1.mass", ["negative", "-2"]),
    "inertia_not_psd": (INERTIA1, INERTIA1.replace("yy: 0.1", "yy: -0.1"), 15, "bodies.link1.inertia",
                        ["not positive semi-definite", "moments"]),
    "inertia_triangle": (INERTIA1, INERTIA1.replace("zz: 0.01", "zz: 0.5"), 15, "bodies.link1.inertia",
                         ["triangle inequality", "no rigid body"]),
    "inertia_products_not_psd": (INERTIA1, INERTIA1.replace("zz: 0.01}", "zz: 0.01, xy: 0.2}"), 15, "bodies.link1.inertia",
                                 ["not positive semi-definite"]),
    "zero_axis": ("      axis: [0, 1, 0]", "      axis: [0, 0, 0]", 10, "bodies.link1.joint.axis", ["zero vector", "direction"]),
    "unknown_parent": ("    parent: link1", "    parent: lnk1", 17, "bodies.link2.parent",
                       ["unknown parent 'lnk1'", "did you mean 'link1'"]),
    "parent_cycle": ("    parent: world", "    parent: link2", 7, "bodies.link1.parent", ["cycle", "link1 -> link2 -> link1", "world"]),
    "own_parent": ("    parent: link1", "    parent: link2", 17, "bodies.link2.parent", ["own parent"]),
    "unknown_parameter": (COM1, "center_of_mass: [0, 0, -Len/2]", 14, "bodies.link1.center_of_mass[2]",
                          ["unknown name 'Len'", "L"]),
    "unknown_initial_coordinate": ("initial: {phi1: 0.5}", "initial: {phi: 0.5}", 12, "bodies.link1.joint.initial.phi",
                                   ["unknown coordinate 'phi'", "did you mean 'phi1'"]),
    "duplicate_body": ("  link2:\n", "  link1:\n", 16, "bodies.link1", ["duplicate key 'link1'", "line 6", "unique"]),
    "duplicate_coordinate": ("coordinates: [phi2]", "coordinates: [phi1]", 18, "bodies.link2.joint.coordinates",
                             ["'phi1'", "link1", "unique"]),
    "missing_version": ("mbsfmu: 1\n", "", 1, None, ["missing required key 'mbsfmu'", "mbsfmu: 1"]),
    "bad_name": ("name: demo", "name: 2demo-x", 2, "name", ["'2demo-x'", "letters, digits, underscore"]),
    "bad_version": ("mbsfmu: 1", "mbsfmu: 7", 1, "mbsfmu", ["version 7", "version 1"]),
    "unknown_body_key": ("    mass: 1.0\n    center", "    mas: 1.0\n    center", 13, "bodies.link1.mas",
                         ["unknown key 'mas'", "did you mean 'mass'"]),
    "t_outside_drive": (COM1, "center_of_mass: [0, 0, -L/2*t]", 14, "bodies.link1.center_of_mass[2]", ["'t'", "drives"]),
    "drive_unknown_coordinate": ("      initial: {phi1: 0.5}", "      drive: {ph1: sin(t)}", 12, "bodies.link1.joint.drive.ph1",
                                 ["unknown coordinate 'ph1'", "phi1"]),
    "unknown_force_type": ("    inertia: {xx: 0.1, yy: 0.1, zz: 0.01}\n", "    inertia: {xx: 0.1, yy: 0.1, zz: 0.01}\n"
                           "forces:\n  - {type: sprng_damper, bodies: [world, link2], stiffness: 1}\n", 22, "forces[0].type",
                           ["sprng_damper", "did you mean 'spring_damper'"]),
    "tab_indentation": ("    mass: 1.0\n    center", "\tmass: 1.0\n    center", 13, None, ["invalid YAML"]),
}


def _write(tmp_path, text, name="scene.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _error(path):
    with pytest.raises(mbsfmu.ModelError) as info:
        mbsfmu.load(path)
    return info.value


@pytest.mark.parametrize("case", sorted(CASES))
def test_broken_scene_names_file_line_key_and_hint(case, tmp_path):
    old, new, line, key, words = CASES[case]
    assert old in BASE
    if case == "unknown_force_type":
        text = BASE + new[len(old):]
    else:
        text = BASE.replace(old, new, 1)
    path = _write(tmp_path, text, f"{case}.yaml")
    e = _error(path)
    msg = str(e)
    assert msg.startswith(f"{path}:{line}: "), msg
    assert e.file == str(path) and e.line == line
    if key is not None:
        assert e.key == key, msg
        assert f": {key}: " in msg
    for w in words:
        assert w in msg, (w, msg)
    # the line the message points at really is about that key
    if key is not None:
        last = key.split(".")[-1].split("[")[0]
        assert last in text.splitlines()[line - 1], (text.splitlines()[line - 1], key)


def test_the_base_scene_is_valid():
    ev = mbsfmu.compile(mbsfmu.loads(BASE))
    assert ev.coordinates == ["phi1", "phi2"]


def test_point_mass_is_valid():
    """A mass without inertia (a point mass) is a valid body."""
    text = BASE.replace("    mass: 1.0\n    inertia: {xx: 0.1, yy: 0.1, zz: 0.01}\n", "    mass: 1.0\n    center_of_mass: [0, 0, -L]\n")
    assert text != BASE
    ev = mbsfmu.compile(mbsfmu.loads(text))
    M, _, _ = ev.equations([0.3, 0.2], [0, 0])
    assert np.linalg.eigvalsh(M).min() > 0
    assert not ev.model.bodies[1].has_inertia and ev.model.bodies[1].m == 1.0


def test_python_yaml_tag_is_refused_and_not_run(tmp_path):
    target = tmp_path / "pwned"
    text = BASE.replace("name: demo", f'name: !!python/object/apply:os.system ["touch {target}"]')
    path = _write(tmp_path, text)
    e = _error(path)
    assert not target.exists()
    assert e.line == 2 and str(path) in str(e) and "tags" in str(e)
    for tag in ("!!python/object/new:os.system", "!!python/name:os.system", "!!python/module:os"):
        text = BASE.replace("name: demo", f'name: {tag} ["touch {target}"]')
        with pytest.raises(mbsfmu.ModelError):
            mbsfmu.loads(text)
    assert not target.exists()


INJECTIONS = [
    "__import__('os').system('touch {target}')",
    "__import__(os)",
    "().__class__",
    "().__class__.__bases__[0].__subclasses__()",
    "1 if 1 else 2",
    "lambda: 1",
    "[x for x in (1,)]",
    "L.__class__",
    "sin.__globals__",
    "open('{target}', 'w')",
    "exec('1')",
    "1; import os",
    "`1`",
    "x := 1",
    "(" * 3000 + "1" + ")" * 3000,
    "-" * 5000 + "1",
]


@pytest.mark.parametrize("expr", INJECTIONS, ids=range(len(INJECTIONS)))
def test_expression_injection_is_refused(expr, tmp_path):
    target = tmp_path / "x"
    e = expr.format(target=target)
    text = BASE.replace(COM1, "center_of_mass: [0, 0, " + repr(e).replace("\\\\", "\\") + "]")
    path = _write(tmp_path, text)
    err = _error(path)
    assert err.line == 14 and err.key == "bodies.link1.center_of_mass[2]", str(err)
    assert not target.exists()


def test_expression_parser_never_evaluates_python():
    for s in ("__import__('os')", "().__class__", "1 if 1 else 2"):
        with pytest.raises(ExprError):
            parse(s)
    assert parse("2*pi*L^2 + sqrt(4)")({"L": 1.0}) == pytest.approx(2 * np.pi + 2)


def test_unreadable_file_is_a_model_error(tmp_path):
    e = _error(tmp_path / "missing.yaml")
    assert "missing.yaml" in str(e)


@pytest.mark.parametrize("text, value", [("2.1e11", 2.1e11), ("1e-3", 1e-3), ("5E+2", 500.0), ("-1.5e3", -1.5e3),
                                         (".5e1", 5.0), ('"2.5e-2"', 2.5e-2)])
def test_numbers_with_an_exponent_are_numbers_in_every_field(text, value):
    """PyYAML (YAML 1.1) reads a float only with a dot and a signed exponent (2.1e+11): 2.1e11, 1e-3, 5E+2 stay text.
    Every numeric field takes them as the numbers they are (YAML 1.2), read once: parameters, scalars, vectors,
    tensors, mappings of values, and the fields read as plain numbers (beam axis)."""
    mag = abs(value)
    text_abs = text.lstrip("-")
    scene = (BASE.replace("L: 1.0", f"L: {text}")
                 .replace("    mass: 1.0\n    center", f"    mass: {text_abs}\n    center")
                 .replace("center_of_mass: [0, 0, -L/2]", f"center_of_mass: [0, 0, {text}]")
                 .replace("inertia: {xx: 0.1, yy: 0.1, zz: 0.01}\n  link2", f"inertia: {{xx: {text_abs}, yy: {text_abs}, zz: {text_abs}}}\n  link2")
                 .replace("at: [0, 0, -L]", f"at: [{text}, 0, 0]"))
    spec = mbsfmu.loads(scene).spec
    body = spec["bodies"][0]
    assert spec["parameters"][0]["value"] == value
    got = [body["mass"], body["center_of_mass"][2], body["inertia"][0][0], body["inertia"][2][2], spec["bodies"][1]["joint"]["at"][0]]
    assert got == [mag, value, mag, mag, value] and all(type(v) is float for v in got), got


def test_a_number_with_an_exponent_that_overflows_is_refused():
    with pytest.raises(mbsfmu.ModelError, match="not finite"):
        mbsfmu.loads(BASE.replace("    mass: 1.0\n    center", "    mass: 1e400\n    center"))
