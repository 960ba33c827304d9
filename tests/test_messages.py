"""What a new user reads: every message that quotes a file (its name, keys, values, data file names) shows
control, format and bidi characters as escapes, so nothing from a file acts on the terminal; the CLI prints
one plain line."""

import contextlib
import io
import math
import re

import pytest

import mbsfmu
from mbsfmu.cli import main
from mbsfmu.errors import ModelError

SCENE = """mbsfmu: 1
name: demo
bodies:
  NAME:
    parent: world
    joint: {type: TYPE, axis: [0, 1, 0], coordinates: [phi]}
    mass: MASS
    inertia: {xx: 0.1, yy: 0.1, zz: 0.1}
    KEY: [0, 0, 0]
"""
GOOD = {"NAME": "link", "TYPE": "revolute", "MASS": "1.0", "KEY": "center_of_mass"}

# every class: C0 controls, DEL, C1 controls (U+009B is a one-character CSI), a terminal command,
# bidi overrides and isolates, zero widths, the BOM, line and paragraph separators
HOSTILE = ([chr(c) for c in range(0x20)] + ["\x7f"] + [chr(c) for c in range(0x80, 0xA0)]
           + ["\x1b[2J", "\x1b]0;owned\x07", "\u202e", "\u202a", "\u2066", "\u2069", "\u200e", "\u061c",
              "\u200b", "\ufeff", "\u2028", "\u2029"])


def _yaml(s):
    """s as a double-quoted YAML scalar (YAML escapes: the file itself stays plain text)."""
    return '"' + "".join(ch if ch.isprintable() and ch not in '"\\' else f"\\u{ord(ch):04x}" for ch in s) + '"'


def _refusal(tmp_path, file="scene.yaml", **place):
    text = SCENE
    for k, v in {**GOOD, **place}.items():
        text = text.replace(k, v)
    path = tmp_path / file
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ModelError) as e:
        mbsfmu.load(path)
    return str(e.value), e.value.key, path


def test_the_template_scene_loads(tmp_path):
    path = tmp_path / "ok.yaml"
    text = SCENE
    for k, v in GOOD.items():
        text = text.replace(k, v)
    path.write_text(text, encoding="utf-8")
    assert mbsfmu.load(path).name == "demo"


def _shown_safely(line, raw):
    # Python's own notion of printable (Unicode categories) is the reference: nothing else may reach a terminal
    assert line.isprintable(), repr(line)
    assert raw not in line


@pytest.mark.parametrize("ch", HOSTILE, ids=[f"U+{ord(c[0]):04X}{'…' if len(c) > 1 else ''}" for c in HOSTILE])
def test_names_keys_and_values_are_escaped(tmp_path, ch):
    for place, key in (({"NAME": _yaml(f"hook{ch}")}, "bodies"), ({"KEY": _yaml(f"key{ch}")}, "bodies.link"),
                       ({"TYPE": _yaml(f"revolute{ch}")}, "bodies.link.joint"), ({"MASS": _yaml(f"m{ch}")}, "bodies.link.mass"),
                       ({"MASS": _yaml(f"1.0 + m{ch}")}, "bodies.link.mass")):
        line, where, _ = _refusal(tmp_path, **place)
        _shown_safely(line, ch)
        assert where.startswith(key), (where, line)  # refused where the character is


@pytest.mark.parametrize("ch", ["\r", "\n", "\x1b[2J", "\x9b", "\u202e", "\x7f", "\t"])
def test_file_and_data_file_names_are_escaped(tmp_path, ch):
    line, _, path = _refusal(tmp_path, file=f"scene{ch}.yaml", MASS="-1")  # a refusal that names the file
    _shown_safely(line, ch)
    assert "scene" in line and ":7: bodies.link.mass" in line
    for key, expected in ((f"elastic: {{nodal: {{file: {_yaml('data' + ch + '.npz')}}}}}", "data"),
                          (f"shape: {{type: mesh, file: {_yaml('mesh' + ch + '.stl')}}}", "bodies.link.shape.file")):
        text = SCENE.replace("    KEY: [0, 0, 0]\n", f"    {key}\n")
        for k, v in GOOD.items():
            text = text.replace(k, v)
        path.write_text(text, encoding="utf-8")
        with pytest.raises(ModelError) as e:
            mbsfmu.load(path)
        _shown_safely(str(e.value), ch)
        assert expected in str(e.value)


def test_the_cli_line_is_escaped(tmp_path):
    """Through `mbsfmu check`: one line on stderr, exit 1, the terminal command shown as text."""
    path = tmp_path / "scene\x1b[2J.yaml"
    text = SCENE
    for k, v in {**GOOD, "NAME": _yaml("hook\r\u202e\x85")}.items():
        text = text.replace(k, v)
    path.write_text(text, encoding="utf-8")
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        status = main(["check", str(path)])
    assert status == 1
    line = err.getvalue()
    assert line.endswith("\n") and line.count("\n") == 1
    _shown_safely(line[:-1], "\x1b")
    assert all(e in line for e in ("\\x1b[2J", "hook\\r\\u202e\\x85"))  # shown as the escapes one would type


def test_plain_text_is_unchanged():
    e = ModelError("unknown key 'ä → ü 😀'", file="C:\\scenes\\x.yaml", line=3, key="bodies.Übung", hint="valid: a")
    assert str(e) == "C:\\scenes\\x.yaml:3: bodies.Übung: unknown key 'ä → ü 😀' (valid: a)"


# -- numeric fields: what was expected, in plain words ------------------------------------------------------

def _numeric_leaves(node, path=()):
    """Paths of every number in a scene document (each sits in a numeric field)."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _numeric_leaves(v, path + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _numeric_leaves(v, path + (i,))
    elif isinstance(node, (int, float)) and not isinstance(node, bool) and path != ("mbsfmu",):
        yield path


def _key(path):
    return "".join(f"[{k}]" if isinstance(k, int) else f".{k}" for k in path).lstrip(".")


NOT_NUMBERS = {"[1.0]": [1.0], "empty": None, "yes": True, "{a: 1}": {"a": 1}}


@pytest.mark.parametrize("model", ["spring_damper", "flexible_pendulum", "pendulum_with_shape"])
def test_every_numeric_field_says_what_was_expected(model):
    """Each number of a shipped scene replaced by a list, nothing, `yes` or a mapping: the message names that
    field and says in words what was expected (never a reader's type name such as Seq, NoneType or True)."""
    import yaml
    from pathlib import Path
    models = Path(__file__).resolve().parent.parent / "models"
    text = (models / f"{model.replace('_with_shape', '')}.yaml").read_text()
    if model.endswith("_with_shape"):
        text = text.replace("    mass: m_bob\n", "    mass: m_bob\n    shape: {type: box, size: [0.1, 0.1, 0.1], at: [0, 0, 0.1],"
                            " rotation: {axis: [0, 0, 1], angle: 0.5}, opacity: 0.5}\n")
    doc = yaml.safe_load(text)
    paths = list(_numeric_leaves(doc))
    assert len(paths) > 20
    for path in paths:
        for shown, bad in NOT_NUMBERS.items():
            broken = yaml.safe_load(text)
            parent = broken
            for k in path[:-1]:
                parent = parent[k]
            parent[path[-1]] = bad
            if bad is None and path[-1] == "node":
                continue  # null: no node (a rigid point), a valid value
            with pytest.raises(ModelError) as e:
                mbsfmu.loads(yaml.safe_dump(broken))
            msg = str(e.value)
            assert e.value.key == _key(path) or _key(path).startswith((e.value.key + "[", e.value.key + ".")), (path, msg)
            assert re.search(r"a number or an expression was expected|must be a finite number|integer", msg), (path, shown, msg)
            assert not re.search(r"\b(Seq|Map|NoneType|None|True|False|bool|dict)\b", e.value.message), (path, shown, msg)


# -- angles: radians, and no silent degrees -----------------------------------------------------------------

JOINT = """mbsfmu: 1
name: j
parameters: {a45: 45, L: 0.5}
gravity: [0, 0, -9.81]
bodies:
  b:
    parent: world
    joint: {type: KIND, EXTRA, initial: {INITIAL}}
    mass: 1
    inertia: {xx: 1, yy: 1, zz: 1}
"""
# the contract's table (docs/scene-format.md): position coordinates in order, True for an angle
COORDINATES = {
    "revolute": ("axis: [0, 0, 1]", {"b.angle": True}),
    "prismatic": ("axis: [0, 0, 1]", {"b.s": False}),
    "cylindrical": ("axis: [0, 0, 1]", {"b.s": False, "b.angle": True}),
    "universal": ("axes: [[1, 0, 0], [0, 1, 0]]", {"b.angle1": True, "b.angle2": True}),
    "planar": ("axes: [[1, 0, 0], [0, 1, 0]]", {"b.x": False, "b.y": False, "b.angle": True}),
    "spherical": ("parameterization: cardan", {"b.a": True, "b.b": True, "b.c": True}),
    "free": ("parameterization: cardan", {"b.x": False, "b.y": False, "b.z": False, "b.a": True, "b.b": True, "b.c": True}),
}


def _joint(kind, initial, extra=None):
    return (JOINT.replace("KIND", kind).replace("EXTRA", extra or COORDINATES[kind][0])
            .replace("INITIAL", initial))


@pytest.mark.parametrize("kind", COORDINATES)
def test_angle_coordinates_refuse_degrees_and_take_radians(kind):
    """Every angle coordinate (its initial value, a joint spring's offset on it): 90 (degrees, surely) is refused
    with the radians to write; pi/2, 4*pi and 6 are taken as radians (the initial state holds them); a length
    coordinate takes 90 (metres)."""
    for coord, is_angle in COORDINATES[kind][1].items():
        for value in ("90", "-180", "a45"):
            spring = f"forces:\n  - {{type: joint_spring_damper, coordinate: {coord}, stiffness: 1, offset: {value}}}\n"
            for text, key in ((_joint(kind, f"{coord}: {value}"), f"bodies.b.joint.initial.{coord}"),
                              (_joint(kind, "") + spring, "forces[0].offset")):
                if not is_angle:
                    mbsfmu.loads(text)
                    continue
                with pytest.raises(ModelError) as e:
                    mbsfmu.loads(text)
                assert e.value.key == key and "radians" in str(e.value), str(e.value)
                assert re.search(r"write -?\d+\*pi/180", str(e.value)), str(e.value)
        if is_angle:
            for value, radians in (("pi/2", math.pi / 2), ("4*pi", 4 * math.pi), ("6", 6.0)):
                ev = mbsfmu.compile(mbsfmu.loads(_joint(kind, f"{coord}: {value}")))
                assert ev.initial_state()[0][ev.coordinates.index(coord)] == pytest.approx(radians, rel=1e-15)


@pytest.mark.parametrize("where", ["joint", "shape", "initial"])
def test_rotation_angles_refuse_degrees(where):
    """Every {axis, angle} rotation (joint frames, shapes, initial rotations) reads radians; 90 is refused."""
    def scene(angle):
        rot = f"{{axis: [0, 0, 1], angle: {angle}}}"
        if where == "joint":
            return _joint("revolute", "", f"axis: [0, 0, 1], rotation: {rot}"), "bodies.b.joint.rotation.angle"
        if where == "initial":
            return _joint("spherical", f"rotation: {rot}", "parameterization: quaternion"), "bodies.b.joint.initial.rotation.angle"
        return (_joint("revolute", "") + f"    shape: {{type: sphere, radius: L, rotation: {rot}}}\n",
                "bodies.b.shape.rotation.angle")
    for bad in ("90", "a45", "-7"):
        text, key = scene(bad)
        with pytest.raises(ModelError) as e:
            mbsfmu.loads(text)
        assert e.value.key == key and "radians" in str(e.value)
    for good in ("pi/2", "6.2", "-2*pi"):
        mbsfmu.loads(scene(good)[0])
