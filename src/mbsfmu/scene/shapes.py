"""`shape:` of a body (drawing only, see docs/animation.md): one shape or a list, each placed in the body frame.

    shape: {type: box, size: [a, b, c], at: [x, y, z], rotation: {axis: [..], angle: ..}, color: "#c03030"}
    shape: [{type: cylinder, radius: r, length: L, at: [0, 0, -L/2]}, {type: sphere, radius: r_bob, at: [0, 0, -L]}]

Cylinders and capsules lie along the body z axis; a mesh file (STL, OBJ or COLLADA .dae) must sit in the scene's folder,
or (`package://NAME/...`, from a URDF) in a package folder the user named.
Numbers may be expressions over parameters. Nothing here is used by the equations of motion.
"""

import re
from pathlib import Path

from ..errors import ModelError
from .. import datafile, limits
from .wording import shown, suggest
from .yaml_lines import Map, Seq

SHAPE_TYPES = ("box", "sphere", "cylinder", "capsule", "mesh")
MESH_SUFFIXES = (".stl", ".obj", ".dae")
_SIZE_KEYS = {"box": ("size",), "sphere": ("radius",), "cylinder": ("radius", "length"),
              "capsule": ("radius", "length"), "mesh": ("file",)}
_COMMON = ("type", "at", "rotation", "color", "opacity")
_HEX = re.compile(r"#(?:[0-9a-fA-F]{3}|[0-9a-fA-F]{6})")   # fullmatch: no trailing newline
COLORS = {"red": "#d03030", "green": "#30a040", "blue": "#3060d0", "yellow": "#e0c020", "orange": "#e08020",
          "purple": "#8040b0", "cyan": "#20b0c0", "magenta": "#c030a0", "white": "#f0f0f0", "grey": "#808080",
          "gray": "#808080", "black": "#202020", "brown": "#8b5a2b", "steel": "#8c9aa8"}


def check_shapes(ck, node, path):
    """`node["shape"]` (one mapping or a list) → list of normalized shapes; `ck` is the scene's checker."""
    path = path + ".shape"
    if "elastic" in node:
        ck.fail(node, "shape", path, "elastic bodies are drawn deformed through their nodes; a rigid shape would hide that",
                "put the shape on a rigid body attached to a node (joint: {type: fixed, node: ...})")
    value = node["shape"]
    if isinstance(value, Map):
        return [_shape(ck, node, "shape", path)]
    if not isinstance(value, Seq) or not value:
        ck.fail(node, "shape", path, "expected a mapping with 'type', or a list of them", "types: " + ", ".join(SHAPE_TYPES))
    return [_shape(ck, value, i, f"{path}[{i}]") for i in range(len(value))]


def _shape(ck, parent, key, path):
    s = parent[key]
    if not isinstance(s, Map) or "type" not in s:
        ck.fail(parent, key, path, "expected a mapping with 'type'", "types: " + ", ".join(SHAPE_TYPES))
    kind = s["type"]
    if kind not in SHAPE_TYPES:
        ck.fail(s, "type", path + ".type", f"unknown shape type '{kind}'", suggest(kind, SHAPE_TYPES))
    extra = ("scale",) if kind == "mesh" else ()
    ck.keys(s, path, _COMMON + _SIZE_KEYS[kind] + extra, required=_SIZE_KEYS[kind])
    out = {"type": kind}
    if kind == "box":
        out["size"] = ck.vector(s, "size", path + ".size")
        for i in range(3):
            if not ck.value(out["size"][i]) > 0:
                ck.fail(s["size"], i, f"{path}.size[{i}]", "box edges must be positive")
    elif kind == "mesh":
        out["file"] = _mesh_file(ck, s, path)
        out["scale"] = _scale(ck, s, path)
    else:
        for k in _SIZE_KEYS[kind]:
            out[k] = ck.number(s, k, f"{path}.{k}", positive=True)
    out["at"] = ck.vector(s, "at", path + ".at") if "at" in s else [0.0] * 3
    out["rotation"] = ck.rotation(s, "rotation", path + ".rotation") if "rotation" in s else None
    out["color"] = _color(ck, s, path) if "color" in s else None
    out["opacity"] = 1.0
    if "opacity" in s:
        out["opacity"] = ck.value(ck.number(s, "opacity", path + ".opacity", positive=True))
        if out["opacity"] > 1:
            ck.fail(s, "opacity", path + ".opacity", f"must lie in (0, 1], got {out['opacity']:g}")
    return out


def _scale(ck, s, path):
    if "scale" not in s:
        return [1.0] * 3
    if isinstance(s["scale"], list):
        v = ck.vector(s, "scale", path + ".scale")
    else:
        v = [ck.number(s, "scale", path + ".scale")] * 3
    if not all(ck.value(x) != 0 for x in v):  # a negative factor mirrors the mesh (drawing.py turns its triangles)
        ck.fail(s, "scale", path + ".scale", "scale factors must not be zero",
                "e.g. scale: 0.001 for a mesh drawn in mm, [0.001, -0.001, 0.001] for its mirror image")
    return v


PACKAGE = "package://"
_PACKAGE_NAME = re.compile(r"[^/\\]+")


def package_path(package_dirs, uri):
    """`package://NAME/rest` → (the folder NAME in the first of `package_dirs` that has one, the file in it), or
    None if none has; the file may still lie outside the folder (a '..' in rest): the caller refuses that."""
    package, _, rest = uri[len(PACKAGE):].partition("/")
    if not _PACKAGE_NAME.fullmatch(package) or package in (".", ".."):
        return None
    folder = next(((Path(d) / package).resolve() for d in package_dirs if (Path(d) / package).is_dir()), None)
    return None if folder is None else (folder, (folder / rest).resolve())


def mesh_path(base, name, package_dirs=()):
    """The mesh file a shape names: relative to the scene's folder `base` and inside it, or `package://NAME/...`
    inside a package folder the user named (package_dirs: trusted, wherever they are). Raises ModelError."""
    if not (isinstance(name, str) and name.startswith(PACKAGE)):
        try:  # always confined, even when nodal data may come from elsewhere: the drawing never needs more
            return datafile.resolve(base, name)
        except ModelError as e:
            raise ModelError(e.message.replace("data file", "mesh file"), hint="mesh files must sit in the scene's folder or below it") from None
    found = package_path(package_dirs, name)
    if found is None:
        raise ModelError(f"no package folder holds the mesh '{name}'" + ("" if package_dirs else " (none was named)"),
                         hint="name the folder that holds the package: package_dirs (urdf: package_dirs, load(..., package_dirs=...), "
                              "--package-dir DIR; for an FMU's drawing: --scene ROBOT.urdf --package-dir DIR)")
    folder, f = found
    if not f.is_relative_to(folder):
        raise ModelError(f"the mesh file '{name}' leaves its package folder {folder}", hint="mesh files must lie inside their package folder")
    return f


def _mesh_file(ck, s, path):
    """A mesh file inside the scene's folder (no absolute paths, no '..' out of it) or a named package folder,
    STL, OBJ or DAE, bounded size."""
    name = s["file"]
    try:
        f = mesh_path(ck.base, name, ck.package_dirs)
    except ModelError as e:
        ck.fail(s, "file", path + ".file", e.message, e.hint)
    base = ck.base.resolve()
    if f.suffix.lower() not in MESH_SUFFIXES:
        ck.fail(s, "file", path + ".file", f"'{name}' is not a supported mesh file", "formats: STL (binary or ASCII), OBJ, COLLADA (.dae)")
    if not f.is_file():
        ck.fail(s, "file", path + ".file", f"no such mesh file '{name}' (looked in {base})")
    if f.stat().st_size > limits.MESH_BYTES:
        ck.fail(s, "file", path + ".file", f"'{name}' is larger than {limits.MESH_BYTES // 2**20} MB", "simplify the mesh for drawing")
    return name if name.startswith(PACKAGE) else Path(name).as_posix()


def _color(ck, s, path):
    c = s["color"]
    if isinstance(c, str) and _HEX.fullmatch(c):
        return "#" + "".join(ch * 2 for ch in c[1:]).lower() if len(c) == 4 else c.lower()
    if isinstance(c, str) and c.lower() in COLORS:
        return COLORS[c.lower()]
    if isinstance(c, list) and len(c) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool) and 0 <= x <= 1 for x in c):
        return "#" + "".join(f"{round(255 * x):02x}" for x in c)
    ck.fail(s, "color", path + ".color", f"not a colour: {shown(c)}",
            "give '#rrggbb', [r, g, b] in 0..1, or a name: " + ", ".join(sorted(COLORS)))
