"""Scene files → validated, normalized scene (`Scene.spec`, plain JSON data that the run time compiles).

Every check raises ModelError with the file, the line, the key path and what would be valid.
"""

import gc
import json
import math
import re
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..engine.layout import LISTS, METHODS  # the engine's integrators (mbs_layout.h: MBS_METHODS)
from ..errors import ModelError
from ..expr import FUNCTIONS, ExprError, parse
from ..kinematics.joints import PARAMETERIZATIONS, TYPES as JOINT_TYPES, joint_type  # the joint table
from .. import datafile, limits
from . import domains, names, urdf
from .shapes import check_shapes
from .wording import brief, shown, suggest
from .yaml_lines import FLOAT_LITERAL, Date, Map, Seq, read_yaml

FORCE_TYPES = tuple(e[1] for e in LISTS["MBS_FORCES"])  # the engine's force elements (mbs_layout.h: MBS_FORCES)
TOP_KEYS = ("mbsfmu", "name", "description", "gravity", "parameters", "bodies", "forces", "integrator",
            "experiment", "outputs")
RESERVED = {"t", "pi", "world", "q", "y", "yd", "integrator"}
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")        # matched with fullmatch: nothing may follow (no newline)
_COORD = re.compile(r"[A-Za-z][A-Za-z0-9_.]*")


class Scene:
    """A validated scene: `spec` (normalized, JSON-able), `name`, `path`."""

    def __init__(self, spec, path=None, repairs=(), package_dirs=()):
        self.spec, self.path, self.name = spec, path, spec["name"]
        self.repairs = list(repairs)  # what `repair` changed in an imported URDF, one line each
        self.package_dirs = list(package_dirs)  # where its shapes' package://NAME/... meshes are (a URDF's, trusted)

    def __repr__(self):
        return f"<Scene {self.name} ({len(self.spec['bodies'])} bodies)>"


def load(path, allow_outside=False, repair=False, package_dirs=(), base=None):
    """Read and validate a scene file or a URDF (format: docs/scene-format.md); raises ModelError and nothing else.

    Data files (`nodal: {file: ...}`, `urdf: {file: ...}`) must lie inside the scene's folder unless
    `allow_outside` is true. `repair`: fix a URDF's massless moving links and unphysical inertias (reported
    in `Scene.repairs`) instead of refusing them. `package_dirs`: for a URDF, the folders its `package://NAME/...`
    meshes are looked up in, relative to the URDF's folder (trusted folders: they may lie anywhere; a YAML scene
    names them in its `urdf:` entry). `base`: for a URDF, 'fixed' (default: the root link held in the world) or
    'free' (a floating base), as the `urdf:` entry's `base` key.
    """
    path = Path(path)
    if path.suffix.lower() in (".urdf", ".xacro"):
        def document():
            dirs = urdf.package_folders(package_dirs, path.parent, str(path))
            return (*urdf.read(path, dirs, base=base or "fixed", repair=repair), dirs)
        return _checked(document, str(path), path.parent, allow_outside)
    for given, key in ((package_dirs, "package_dirs"), (base, "base")):
        if given:
            raise ModelError(f"{key} is given for a URDF loaded directly, and this is a YAML scene", file=str(path), key=key,
                             hint=f"a YAML scene names it in its urdf: entry (urdf: {{file: robot.urdf, {key}: ...}})")
    try:
        with limits.open_regular(path) as f:
            raw = f.read(limits.DOCUMENT_BYTES + 1)  # bounded
    except OSError as e:
        raise ModelError(f"cannot read scene file: {e.strerror or e}", file=str(path),
                         hint="give the path of a regular YAML file (not a folder, FIFO or device)") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ModelError(f"byte 0x{raw[e.start]:02x} is not UTF-8", file=str(path), line=raw.count(b"\n", 0, e.start) + 1,
                         hint="save the scene as UTF-8 text") from None
    return loads(text, file=str(path), base=path.parent, allow_outside=allow_outside, repair=repair)


def loads(text, file="<string>", base=None, allow_outside=False, repair=False):
    """Validate a scene given as YAML text; data files are looked up relative to `base` (default: the current folder)."""
    base = Path(base) if base else Path.cwd()

    def document():
        root = read_yaml(text, file)
        if isinstance(root, Map) and "urdf" in root:  # a URDF with this YAML over it (scene/urdf.py)
            return urdf.include(root, file, base, allow_outside, repair)
        return root, (), ()
    return _checked(document, file, base, allow_outside)


def _checked(document, file, base, allow_outside):
    """Scene of the document that `document()` gives (a Map/Seq tree, the repairs made while reading it and the
    package folders its meshes may be in)."""
    try:
        with _collector_paused():
            root, repairs, package_dirs = document()
            spec = _Checker(file, base, allow_outside, package_dirs).scene(root)
            json.dumps(spec)  # the run time gets the spec as JSON: it must stay plain data
    except ModelError as e:
        raise _short(e) from None
    except Exception as e:  # noqa: BLE001
        # a check this file slipped past: still a ModelError (the promise of `load`), naming what happened
        raise _short(ModelError(f"cannot read this scene ({type(e).__name__}: {e})", file=file)) from None
    for r in repairs:  # the CLI shows each as a note
        warnings.warn(f"{file}: repaired {r}", stacklevel=3)
    return Scene(spec, file, repairs, package_dirs)


@contextmanager
def _collector_paused():
    """Reading a scene creates many objects that all stay alive; Python's cyclic collector would scan them again
    and again while they are made (10,000 bodies: 4.8 s with it, 1.7 s without). Bounded input: bounded memory."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _short(e):
    """The same error with quoted input shortened: messages stay readable whatever the file holds; every error
    gets a hint (at least where the format of that part of the file is described)."""
    def cut(text, n=limits.MESSAGE_CHARS):
        return text if text is None or len(text) <= n else text[:n - 60] + " … " + text[-50:]
    hint = e.hint
    if not hint:
        section = re.match(r"[A-Za-z_]+", e.key or "")
        hint = "see docs/scene-format.md" + (f", section '{section.group()}'" if section else "")
    return ModelError(cut(e.message), file=e.file, line=e.line, key=cut(e.key, 120), hint=cut(hint))


_EXPR_HINT = ("an expression may use numbers, parameters, pi, + - * / ^ ** and parentheses, and the functions "
              + ", ".join(FUNCTIONS) + "; it is parsed, never executed")


_NUMBER_HINT = "write a number (1.5, 2e-3) or an expression over parameters (m_rod/2, pi/6)"


def _literal(value):
    """A number written as text (quoted, "2.5e-3") as the float it is; anything else as it is.  The one reading of
    numbers beside YAML's own (yaml_lines.FLOAT_LITERAL: plain 2.1e11 is already a float)."""
    if isinstance(value, str) and not isinstance(value, Date) and FLOAT_LITERAL.fullmatch(value):
        return float(value)
    return value


def _known(name, names):
    """`name` is one of `names` (a dict or set); a list or mapping given as a name is not."""
    return isinstance(name, str) and name in names


class _Checker:
    """Walks the YAML tree; `self.fail(node, key, ...)` reports the key's own line."""

    def __init__(self, file, base, allow_outside=False, package_dirs=()):
        self.file, self.base, self.allow_outside, self.package_dirs = file, base, allow_outside, package_dirs
        self.params = {}
        self.root = None
        self.node_count = {}  # elastic body → number of nodes
        self.node_names = {}  # elastic body → {node set name: node index} (FE bodies)

    # -- reporting ---------------------------------------------------------------------------------
    def fail(self, parent, key, path, message, hint=None):
        line = None
        if isinstance(parent, (Map, Seq)):
            line = parent.lines.get(key, parent.line)
        raise ModelError(message, file=self.file_of(line), line=line, key=path, hint=hint)

    def file_of(self, line):
        """The file a line is in: the scene's, or (urdf.FileLine) the URDF a YAML scene includes."""
        return getattr(line, "file", self.file)

    def fail_at(self, path, message, hint=None):
        """Fail at the line of a key path such as `bodies.arm.elastic.nodal.stiffness` (the deepest key given)."""
        line = self.line_of(path)
        raise ModelError(message, file=self.file_of(line), line=line, key=path, hint=hint)

    def line_of(self, path):
        node, line = self.root, self.root.line
        tokens = re.findall(r"\[\d+\]|[^.\[\]]+", path)
        i = 0
        while i < len(tokens):
            if tokens[i][0] == "[" and isinstance(node, Seq) and int(tokens[i][1:-1]) < len(node):
                k, i = int(tokens[i][1:-1]), i + 1
            elif isinstance(node, Map):  # keys may hold dots (coordinate names): the longest one that is there
                j = next((j for j in range(len(tokens), i, -1) if ".".join(tokens[i:j]) in node), None)
                if j is None:
                    break
                k, i = ".".join(tokens[i:j]), j
            else:
                break
            line, node = node.lines.get(k, line), node[k]
        return line

    def keys(self, node, path, allowed, required=()):
        if not isinstance(node, Map):
            line = getattr(node, "line", None) or (self.line_of(path) if path and self.root is not None else None)
            raise ModelError("expected a mapping", file=self.file, line=line, key=path, hint="key: value pairs, one per line or {key: value, ...}")
        for k in node:
            if k not in allowed:
                self.fail(node, k, f"{path}.{k}" if path else k, f"unknown key '{k}'", suggest(k, allowed))
        for k in required:
            if k not in node:
                hint = "a scene starts with 'mbsfmu: 1' (the format version)" if not path and k == "mbsfmu" else "required: " + ", ".join(required)
                raise ModelError(f"missing required key '{k}'", file=self.file, line=node.line, key=path or None, hint=hint)

    # -- values ------------------------------------------------------------------------------------
    def number(self, parent, key, path, allow_t=False, positive=False, nonneg=False, magnitude=True):
        """A numeric field: number or expression over parameters (and `t` where allowed) → JSON value."""
        value = _literal(parent[key])
        if type(value) is float or type(value) is int:  # most fields: a plain number (bool is not of type int)
            v = value = float(value)
        else:
            value, v = self._expression(parent, key, path, value, allow_t)
            if v is None:  # a function of time: checked over the whole experiment by time_domains
                return value
        if not math.isfinite(v):
            self.fail(parent, key, path, f"'{value if isinstance(value, str) else repr(v)}' is not finite",
                      "give a finite number (.inf, .nan and overflowing expressions are refused)")
        if positive and not v > 0:
            self.fail(parent, key, path, f"must be positive, got {v:g}", "give a value > 0")
        if nonneg and domains.check(domains.NONNEG, [v]):
            self.fail(parent, key, path, domains.check(domains.NONNEG, [v]), "use 0 or a positive value")
        if magnitude and domains.check(domains.MAGNITUDE, [v]):
            self.fail(parent, key, path, domains.check(domains.MAGNITUDE, [v]),
                      "products of such numbers over- or underflow in double precision; check the units")
        return value

    def _expression(self, parent, key, path, value, allow_t):
        """(the expression text, its value; None if it depends on t) of a numeric field that is not a number."""
        if isinstance(value, Date):
            self.fail(parent, key, path, f"'{value}' reads as a date, not a number", "write the number; quote an expression that looks like a date")
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            self.fail(parent, key, path, f"a number or an expression was expected, got {shown(value)}", _NUMBER_HINT)
        if isinstance(value, str) and len(value) > limits.EXPRESSION_CHARS:
            self.fail(parent, key, path, f"an expression of {len(value):,} characters (at most {limits.EXPRESSION_CHARS})")
        if isinstance(value, str) and not value.isascii():
            self.fail(parent, key, path, f"the expression '{value}' holds characters other than ASCII", _EXPR_HINT)
        try:
            e = parse(value)
        except ExprError as err:
            self.fail(parent, key, path, str(err), _EXPR_HINT)
        for name in e.names:
            if name not in self.params and not (allow_t and name == "t"):
                hint = "'t' is only allowed in drives and force values" if name == "t" else suggest(name, sorted(self.params) or ["(no parameters defined)"])
                self.fail(parent, key, path, f"unknown name '{name}'", hint)
        if "t" in e.names:
            return value, None
        try:
            return value, e(self.params)  # t is not among its names here
        except (ValueError, ZeroDivisionError, OverflowError, TypeError) as err:
            self.fail(parent, key, path, f"cannot evaluate '{e.text}': {err}")

    def value(self, spec_value):
        """Nominal numeric value of a normalized field."""
        return parse(spec_value)(dict(self.params, t=0.0))

    def vector(self, parent, key, path, n=3, nonzero=False, allow_t=False):
        v = parent[key]
        if not isinstance(v, list) or len(v) != n:
            self.fail(parent, key, path, f"a list of {n} numbers or expressions was expected, got {shown(v)}", _NUMBER_HINT)
        out = [self.number(v, i, f"{path}[{i}]", allow_t=allow_t, magnitude=not nonzero) for i in range(n)]
        if nonzero:  # a direction: normalized by the run time, so its length must square without under- or overflow
            problem = domains.check(domains.AXIS, [self.value(x) for x in out])
            if problem:
                self.fail(parent, key, path, problem, "give a direction such as [0, 0, 1]; its length does not matter")
        return out

    def matrix(self, parent, key, path):
        m = parent[key]
        if not isinstance(m, list) or len(m) != 3 or not all(isinstance(r, list) and len(r) == 3 for r in m):
            self.fail(parent, key, path, "expected a 3x3 list of lists")
        return [[self.number(m[i], j, f"{path}[{i}][{j}]") for j in range(3)] for i in range(3)]

    def rotation(self, parent, key, path):
        """`{axis, angle}` or `{matrix}` (a proper rotation) → normalized dict."""
        node = parent[key]
        self.keys(node, path, ("axis", "angle", "matrix"))
        if "matrix" in node:
            if len(node) != 1:
                self.fail(parent, key, path, "give either 'matrix' or 'axis' and 'angle'")
            m = self.matrix(node, "matrix", path + ".matrix")
            problem = domains.check(domains.ROTATION, [self.value(x) for row in m for x in row])
            if problem:
                self.fail(node, "matrix", path + ".matrix", problem)
            return {"matrix": m}
        if "axis" not in node or "angle" not in node:
            self.fail(parent, key, path, "a rotation needs 'axis' and 'angle' (radians), or 'matrix'")
        return {"axis": self.vector(node, "axis", path + ".axis", nonzero=True), "angle": self.angle(node, "angle", path + ".angle")}

    def angle(self, parent, key, path):
        """An angle, in radians. A value beyond a full turn not written in terms of pi (90, a parameter of 45)
        is most likely meant in degrees: refused, with the radians to write."""
        value = self.number(parent, key, path)
        v = self.value(value)
        if abs(v) > 2 * math.pi and "pi" not in re.findall(r"[A-Za-z_]\w*", str(value)):
            self.fail(parent, key, path, f"{v:g} is more than a full turn: angles are in radians",
                      f"for {v:g} degrees write {v:g}*pi/180; several turns in radians: write them with pi (e.g. 4*pi)")
        return value

    def name(self, parent, key, path, pattern=_NAME, what="a name"):
        v = parent[key]
        if not isinstance(v, str) or not pattern.fullmatch(v):
            self.fail(parent, key, path, f"{shown(v)} is not valid as {what}", "letters, digits, underscore; starts with a letter")
        if len(v) > limits.NAME_CHARS:
            self.fail(parent, key, path, f"{what} of {len(v):,} characters (at most {limits.NAME_CHARS})", "use a shorter name")
        return v

    def key_name(self, node, name, path, what, exclude=()):
        """A name given as a key of `node` (a parameter, a body): the rule `name` applies to values."""
        if not isinstance(name, str) or not _NAME.fullmatch(name) or len(name) > limits.NAME_CHARS or name in exclude:
            self.fail(node, name, path, f"{shown(name)} is not valid as {what}",
                      f"letters, digits, underscore; starts with a letter; at most {limits.NAME_CHARS} characters"
                      + "".join(f"; not '{x}'" for x in exclude))

    def text(self, parent, key, path):
        """A description: text (numbers allowed and kept as written)."""
        v = parent.get(key)
        if v is None:
            return ""
        if isinstance(v, bool) or not isinstance(v, (str, int, float)):
            self.fail(parent, key, path, "expected text", "quote it if it looks like a list or mapping")
        return str(v)

    # -- the scene ---------------------------------------------------------------------------------
    def scene(self, root):
        if not isinstance(root, Map):
            raise ModelError("a scene file is a YAML mapping with at least 'mbsfmu', 'name' and 'bodies'", file=self.file, line=1)
        self.root = root
        self.keys(root, "", TOP_KEYS, required=("mbsfmu", "name", "bodies"))
        if type(root["mbsfmu"]) is not int or root["mbsfmu"] != 1:  # `true` is not the version 1
            self.fail(root, "mbsfmu", "mbsfmu", f"unsupported format version {shown(root['mbsfmu'])}", "this mbsfmu reads version 1: write 'mbsfmu: 1'")
        spec = {"mbsfmu": 1, "name": self.name(root, "name", "name", what="a model name")}
        spec["description"] = self.text(root, "description", "description")
        spec["parameters"] = self.parameters(root)
        spec["gravity"] = self.vector(root, "gravity", "gravity") if "gravity" in root else [0.0, 0.0, -9.81]
        spec["bodies"] = self.bodies(root)
        self.coords = {}
        for b in spec["bodies"]:
            for c in b["joint"]["coordinates"] + b["joint"]["velocities"] + (b["elastic"]["coordinates"] if b["elastic"] else []):
                self.coords.setdefault(c, b)
        spec["forces"] = self.forces(root, spec)
        spec["outputs"] = self.outputs(root, spec)
        spec["integrator"] = self.integrator(root)
        spec["experiment"] = self.experiment(root)
        self.integrator_steps(root, spec)
        self.time_domains(spec)
        self.variable_names(spec)
        return spec

    def parameters(self, root):
        out = []
        node = root.get("parameters") or Map()
        if not isinstance(node, Map):
            self.fail(root, "parameters", "parameters", "expected a mapping of name: value")
        for name, v in node.items():
            path = f"parameters.{name}"
            self.key_name(node, name, path, "a parameter name")
            if name in RESERVED or name in FUNCTIONS:
                self.fail(node, name, path, f"'{name}' is reserved", "choose another parameter name")
            desc, unit = "", None
            if isinstance(v, Map):
                self.keys(v, path, ("value", "description", "unit"), required=("value",))
                if "unit" in v:
                    unit = v["unit"]
                    if not isinstance(unit, str) or not re.fullmatch(r"[A-Za-z0-9_.*/^()+-]{1,32}", unit):
                        self.fail(v, "unit", path + ".unit", f"a unit is a short name such as N/m, kg.m2 or rad/s, got {shown(unit)}")
                desc, v = self.text(v, "description", path + ".description"), v["value"]
            v = _literal(v)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                self.fail(node, name, path, f"a parameter value must be a finite number, got {shown(v)}",
                          "a parameter is a plain number such as 1.5 or 2e-3; expressions belong in the fields that use it")
            self.params[name] = float(v)
            out.append({"name": name, "value": float(v), "description": desc, **({"unit": unit} if unit else {})})
        return out

    def bodies(self, root):
        node = root["bodies"]
        if not isinstance(node, Map) or not node:
            self.fail(root, "bodies", "bodies", "expected a non-empty mapping of body name: body")
        names = list(node)
        for n in names:
            self.key_name(node, n, f"bodies.{n}", "a body name", exclude=("world",))
        out = [self.body(node, n) for n in names]
        self.acyclic(node, {b["name"]: b["parent"] for b in out})
        self.massless(node, out)
        for b in out:  # `node:` of a child joint, now that every elastic body knows its nodes
            if b["joint"]["node"] is not None:
                b["joint"]["node"] = self.node_index(node[b["name"]]["joint"], "node", f"bodies.{b['name']}.joint.node", b["parent"], b["joint"]["node"])
        coords = {}
        for b in out:
            for c in b["joint"]["coordinates"] + b["joint"]["velocities"] + (b["elastic"]["coordinates"] if b["elastic"] else []):
                if c in coords and coords[c] != b["name"]:
                    jn = node[b["name"]]["joint"]
                    where, key = (jn, "coordinates") if isinstance(jn, Map) and "coordinates" in jn else (node[b["name"]], "joint")
                    self.fail(where, key, f"bodies.{b['name']}.joint.coordinates", f"coordinate name '{c}' is used by body '{coords[c]}' too", "coordinate names must be unique")
                coords[c] = b["name"]
        return out

    def acyclic(self, node, parent):
        """Every chain of parents ends at world: one walk up per body, stopping at bodies already known to
        hang from world (linear in the number of bodies)."""
        grounded = {"world"}
        for n in parent:
            chain, on_chain, p = [n], {n}, parent[n]
            while p not in grounded:
                if p in on_chain:
                    cycle = chain[chain.index(p):] + [p]
                    listed = cycle if len(cycle) <= 8 else cycle[:4] + ["…"] + cycle[-3:]
                    self.fail(node[p], "parent", f"bodies.{p}.parent", "the parents form a cycle: " + " -> ".join(listed), "every body must hang from world through a chain of parents")
                chain.append(p)
                on_chain.add(p)
                p = parent[p]
            grounded.update(chain)

    def massless(self, node, bodies):
        """A joint that moves nothing with mass or inertia gives a singular mass matrix: every body whose joint has a
        free (undriven) coordinate needs mass, inertia or an elastic body in its subtree. Linear: each loaded body
        marks its chain of ancestors up to the first one already marked."""
        parent = {b["name"]: b["parent"] for b in bodies}
        loaded = set()
        for b in bodies:
            if b["elastic"] or self.value(b["mass"]) > 0 or any(self.value(b["inertia"][i][i]) > 0 for i in range(3)):
                n = b["name"]
                while n != "world" and n not in loaded:
                    loaded.add(n)
                    n = parent[n]
        for b in bodies:
            j = b["joint"]
            if b["name"] not in loaded and any(c not in j["drive"] for c in j["coordinates"]):
                where = node[b["name"]]
                self.fail(where, "mass" if "mass" in where else "joint", f"bodies.{b['name']}.mass",
                          f"body '{b['name']}' and {domains.CARRIES_TEXT}",
                          "give the body (or one it carries) a mass and inertia, make the joint fixed, or drive its coordinates")

    def body(self, bodies, name):
        node, path = bodies[name], f"bodies.{name}"
        if not isinstance(node, Map):
            self.fail(bodies, name, path, "expected a mapping with at least 'parent' and 'joint'")
        self.keys(node, path, ("parent", "joint", "mass", "center_of_mass", "inertia", "elastic", "description", "shape"), required=("parent", "joint"))
        parent = node["parent"]
        if not isinstance(parent, str):
            self.fail(node, "parent", path + ".parent", f"expected a body name, got {shown(parent)}")
        if parent != "world" and parent not in bodies:
            self.fail(node, "parent", path + ".parent", f"unknown parent '{parent}'", suggest(parent, ["world"] + list(bodies)))
        if parent == name:
            self.fail(node, "parent", path + ".parent", "a body cannot be its own parent")
        b = {"name": name, "parent": parent, "description": self.text(node, "description", path + ".description")}
        b["mass"] = self.number(node, "mass", path + ".mass", nonneg=True) if "mass" in node else 0.0
        b["center_of_mass"] = self.vector(node, "center_of_mass", path + ".center_of_mass") if "center_of_mass" in node else [0.0] * 3
        b["inertia"] = self.inertia(node, path) if "inertia" in node else [[0.0] * 3 for _ in range(3)]
        b["joint"] = self.joint(node, path, name, bodies)
        b["elastic"] = self.elastic(node, path, name) if "elastic" in node else None
        if "shape" in node:  # drawing only (mbsfmu animate)
            b["shape"] = check_shapes(self, node, path)
        return b

    def inertia(self, node, path):
        key, path = "inertia", path + ".inertia"
        v = node[key]
        if isinstance(v, Map):
            self.keys(v, path, ("xx", "yy", "zz", "xy", "xz", "yz"))
            g = {k: (self.number(v, k, f"{path}.{k}") if k in v else 0.0) for k in ("xx", "yy", "zz", "xy", "xz", "yz")}
            m = [[g["xx"], g["xy"], g["xz"]], [g["xy"], g["yy"], g["yz"]], [g["xz"], g["yz"], g["zz"]]]
        else:
            m = self.matrix(node, key, path)
        problem = domains.check(domains.INERTIA, [self.value(x) for row in m for x in row])
        if problem:
            self.fail(node, key, path, problem, "moments of inertia (about the centre of mass) are >= 0 and no one exceeds "
                      "the sum of the other two (no rigid body has such an inertia); check signs and the products xy, xz, yz")
        return m

    # -- joints ------------------------------------------------------------------------------------
    def joint(self, node, path, name, bodies):
        j, path = node["joint"], path + ".joint"
        if not isinstance(j, Map):
            self.fail(node, "joint", path, "expected a mapping with at least 'type'")
        if "type" not in j:
            self.fail(node, "joint", path, "missing 'type'", "valid: " + ", ".join(JOINT_TYPES))
        kind = j["type"]
        if kind not in JOINT_TYPES:
            self.fail(j, "type", path + ".type", f"unknown joint type '{kind}'", suggest(kind, JOINT_TYPES))
        fields = joint_type(kind, PARAMETERIZATIONS[kind][0] if PARAMETERIZATIONS[kind] else None).fields
        common = ("type", "at", "node", "rotation", "coordinates", "initial", "initial_velocity", "drive")
        self.keys(j, path, common + fields, required=tuple(f for f in fields if f != "parameterization"))
        out = {"type": kind}
        if "at" in j and "node" in j:
            self.fail(j, "node", path + ".node", "give either 'at' or 'node'")
        out["at"] = self.vector(j, "at", path + ".at") if "at" in j else [0.0] * 3
        out["node"] = None
        if "node" in j:
            if not isinstance(j["node"], (int, str)) or isinstance(j["node"], bool):
                self.fail(j, "node", path + ".node", "a node index must be an integer (negative counts from the end) or a kept node set's name")
            parent = node["parent"]
            if parent == "world" or "elastic" not in bodies[parent]:
                self.fail(j, "node", path + ".node", "'node' needs an elastic parent body", "use 'at' on rigid parents")
            out["node"] = j["node"]
        out["rotation"] = self.rotation(j, "rotation", path + ".rotation") if "rotation" in j else None
        if "axis" in fields:
            out["axis"] = self.vector(j, "axis", path + ".axis", nonzero=True)
        if "axes" in fields:
            axes = j["axes"]
            if not isinstance(axes, list) or len(axes) != 2:
                self.fail(j, "axes", path + ".axes", "expected two axes [a1, a2]")
            out["axes"] = [self.vector(axes, i, f"{path}.axes[{i}]", nonzero=True) for i in range(2)]
            rule = joint_type(kind).axes_rule
            problem = domains.check(rule, [self.value(x) for a in out["axes"] for x in a])
            if problem:
                self.fail(j, "axes", path + ".axes", problem)
        param = j.get("parameterization", PARAMETERIZATIONS[kind][0] if PARAMETERIZATIONS[kind] else None)
        if PARAMETERIZATIONS[kind]:
            if param not in PARAMETERIZATIONS[kind]:
                self.fail(j, "parameterization", path + ".parameterization", f"unknown parameterization '{param}'", suggest(param, PARAMETERIZATIONS[kind]))
            out["parameterization"] = param
        row = joint_type(kind, param)
        pos, vel = [f"{name}.{s}" for s in row.positions], [f"{name}.{s}" for s in row.velocities]
        quat = row.quaternion is not None
        if "coordinates" in j:
            given = j["coordinates"]
            if quat:
                self.fail(j, "coordinates", path + ".coordinates", "quaternion joints use fixed coordinate names", "names are " + ", ".join(pos) + "; or use parameterization: cardan")
            if not isinstance(given, list) or len(given) != len(pos):
                self.fail(j, "coordinates", path + ".coordinates", f"a {kind} joint has {len(pos)} coordinate(s), got {shown(given)}", "e.g. " + str(pos))
            for i, c in enumerate(given):
                self.name(given, i, f"{path}.coordinates[{i}]", pattern=_COORD, what="a coordinate name")
            if len(set(given)) != len(given):
                self.fail(j, "coordinates", path + ".coordinates", "coordinate names repeat")
            pos = vel = list(given)
        out["coordinates"], out["velocities"] = pos, vel
        out["initial"], out["initial_velocity"], out["initial_rotation"] = {}, {}, None
        if "initial" in j:
            ini = j["initial"]
            if not isinstance(ini, Map):
                self.fail(j, "initial", path + ".initial", "expected a mapping coordinate: value")
            for c in ini:
                if c == "rotation" and row.orientation:
                    out["initial_rotation"] = self.rotation(ini, "rotation", path + ".initial.rotation")
                elif c in pos and not (quat and c in pos[row.quaternion]):
                    read = self.angle if row.units[pos.index(c)] == "rad" else self.number
                    out["initial"][c] = read(ini, c, f"{path}.initial.{c}")
                else:
                    valid = [p for p in pos if not (quat and p in pos[row.quaternion])] + (["rotation"] if row.orientation else [])
                    self.fail(ini, c, f"{path}.initial.{c}", f"unknown coordinate '{c}'", suggest(c, valid or ["(none)"]))
        if "initial_velocity" in j:
            ini = j["initial_velocity"]
            if not isinstance(ini, Map):
                self.fail(j, "initial_velocity", path + ".initial_velocity", "expected a mapping coordinate: value")
            for c in ini:
                if c == "omega" and row.orientation:
                    for i, v in enumerate(self.vector(ini, "omega", path + ".initial_velocity.omega")):
                        out["initial_velocity"][vel[-3 + i]] = v
                elif c == "velocity" and row.translation:
                    for i, v in enumerate(self.vector(ini, "velocity", path + ".initial_velocity.velocity")):
                        out["initial_velocity"][vel[i]] = v
                elif c in vel:
                    out["initial_velocity"][c] = self.number(ini, c, f"{path}.initial_velocity.{c}")
                else:
                    valid = list(vel) + (["omega"] if row.orientation else []) + (["velocity"] if row.translation else [])
                    self.fail(ini, c, f"{path}.initial_velocity.{c}", f"unknown coordinate '{c}'", suggest(c, valid or ["(none)"]))
        out["drive"] = {}
        if "drive" in j:
            d = j["drive"]
            if not isinstance(d, Map):
                self.fail(j, "drive", path + ".drive", "expected a mapping coordinate: expression in t")
            for c in d:
                if quat:
                    drivable = [k for k in JOINT_TYPES if joint_type(k).npos and joint_type(k).quaternion is None]
                    self.fail(d, c, f"{path}.drive.{c}", "quaternion joints cannot be driven", f"drive {', '.join(drivable)} or cardan coordinates")
                if c not in pos:
                    self.fail(d, c, f"{path}.drive.{c}", f"unknown coordinate '{c}'", suggest(c, pos or ["(none)"]))
                out["drive"][c] = self.number(d, c, f"{path}.drive.{c}", allow_t=True)
                try:
                    parse(out["drive"][c]).diff("t").diff("t")
                except ExprError as err:
                    self.fail(d, c, f"{path}.drive.{c}", str(err))
        return out

    # -- elastic bodies ----------------------------------------------------------------------------
    def elastic(self, node, path, name):
        e, path = node["elastic"], path + ".elastic"
        self.keys(e, path, ("beam", "nodal", "fe", "damping_ratio", "damping", "rayleigh", "coordinates", "dynamic_stiffening", "initial", "initial_velocity"))
        if sum(k in e for k in ("beam", "nodal", "fe")) != 1:
            self.fail(node, "elastic", path, "give exactly one of 'beam', 'nodal' or 'fe'")
        given = [k for k in ("damping", "damping_ratio", "rayleigh") if k in e]
        if len(given) > 1:
            self.fail(e, given[0], f"{path}.{given[0]}", f"give one of 'damping' (a matrix), 'damping_ratio' or 'rayleigh', not both '{given[0]}' and '{given[1]}'")
        along_x = "beam" in e and self.beam_along_x(e["beam"], path + ".beam")
        out = {"damping_ratio": self.number(e, "damping_ratio", path + ".damping_ratio", nonneg=True) if "damping_ratio" in e else 0.0,
               "dynamic_stiffening": bool(e.get("dynamic_stiffening", along_x))}
        if "damping" in e:
            out["damping"] = _plain(e["damping"])
        if "rayleigh" in e:   # D = α M_ee + β K
            if not isinstance(e["rayleigh"], list) or len(e["rayleigh"]) != 2:
                self.fail(e, "rayleigh", path + ".rayleigh", f"[alpha, beta] was expected, got {shown(e['rayleigh'])}", "D = alpha·M + beta·K (1/s and s)")
            out["rayleigh"] = [self.number(e["rayleigh"], i, f"{path}.rayleigh[{i}]", nonneg=True) for i in range(2)]
        if "beam" in e:
            b, bp = e["beam"], path + ".beam"
            self.keys(b, bp, ("length", "EI", "EA", "GJ", "rhoA", "rhoIp", "elements", "modes", "clamped", "axis"), required=("length", "EI", "rhoA"))
            beam = {"length": self.number(b, "length", bp + ".length", positive=True), "rhoA": self.number(b, "rhoA", bp + ".rhoA", positive=True)}
            EI = b["EI"]
            if not isinstance(EI, list):  # one value for both planes, reported at its own line
                EI = Seq([EI, EI])
                EI.line = b.lines["EI"]
                EI.lines = {0: EI.line, 1: EI.line}
            if len(EI) != 2:
                self.fail(b, "EI", bp + ".EI", "give one value or [EI_y, EI_z]")
            beam["EI"] = [self.number(EI, i, f"{bp}.EI[{i}]", positive=True) for i in range(2)]
            for k in ("EA", "GJ", "rhoIp"):
                beam[k] = self.number(b, k, f"{bp}.{k}", positive=True) if k in b else None
            for k, default, most in (("elements", 10, limits.BEAM_ELEMENTS), ("modes", 4, None)):
                v = b.get(k, default)
                if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                    self.fail(b, k, f"{bp}.{k}", f"must be a positive integer, got {shown(v)}")
                if most and v > most:
                    self.fail(b, k, f"{bp}.{k}", f"at most {most} elements (the generator's FE matrices are dense)",
                              "a few dozen elements resolve the lowest modes; or give nodal data from an FE program")
                beam[k] = v
            beam["clamped"] = b.get("clamped", "start")
            if beam["clamped"] not in ("start", "none"):
                self.fail(b, "clamped", bp + ".clamped", f"unknown boundary condition {shown(beam['clamped'])}", suggest(beam["clamped"], ("start", "none")))
            if "axis" in b:
                beam["axis"] = [float(x) for x in b["axis"]]
            out["beam"] = beam
        elif "fe" in e:
            if e.get("dynamic_stiffening"):
                self.fail(e, "dynamic_stiffening", path + ".dynamic_stiffening", "dynamic stiffening is not available for FE bodies yet",
                          "leave it out (false); the beam generator has it")
            out["fe"] = self.fe(e, path, name)
        else:
            out["nodal"] = self.nodal(e, path)
        nodal = self.elastic_data(name, out, path)
        n = nodal.n
        coords = [f"{name}.q{i + 1}" for i in range(n)]
        if "coordinates" in e:
            if not isinstance(e["coordinates"], list) or len(e["coordinates"]) != n:
                self.fail(e, "coordinates", path + ".coordinates", f"expected {n} names (one per mode)")
            coords = [self.name(e["coordinates"], i, f"{path}.coordinates[{i}]", pattern=_COORD, what="a coordinate name") for i in range(n)]
        out["coordinates"] = coords
        for key in ("initial", "initial_velocity"):
            out[key] = {}
            if e.get(key) is not None and not isinstance(e[key], Map):
                self.fail(e, key, f"{path}.{key}", "expected a mapping coordinate: value")
            for c in e.get(key) or {}:
                if c not in coords:
                    self.fail(e[key], c, f"{path}.{key}.{c}", f"unknown elastic coordinate '{c}'", suggest(c, coords))
                out[key][c] = self.number(e[key], c, f"{path}.{key}.{c}")
        return out

    def nodal(self, e, path):
        """`nodal:` inline (the arrays as lists) or `{file: data.npz}` → the arrays the equations use, as lists."""
        node, path = e["nodal"], path + ".nodal"
        if isinstance(node, Map) and "file" in node:
            self.keys(node, path, ("file",))
            try:
                data = datafile.read_npz(datafile.resolve(self.base, node["file"], self.allow_outside))
            except ModelError as err:
                self.fail(node, "file", path + ".file", err.message, err.hint)
        elif isinstance(node, Map):
            self.keys(node, path, datafile.NODAL_ARRAYS, required=("R_RP", "mass", "Phi", "stiffness"))
            data = node
        else:
            self.fail(e, "nodal", path, "expected a mapping with R_RP, mass, Phi, Psi, stiffness (or file: data.npz)")
        return _plain(data)

    def fe(self, e, path, body):
        """`fe:` (an FE model's files and how to reduce it) → the reduced body's arrays as lists (bodies/cms.py)."""
        from ..bodies import cms
        node, path = e["fe"], path + ".fe"
        self.keys(node, path, _FE_KEYS)
        method = node.get("method", "craig-bampton")
        if method not in cms.METHODS:
            self.fail(node, "method", path + ".method", f"unknown method {shown(method)}", suggest(method, cms.METHODS))
        if "modes" in node and "cutoff_hz" in node:
            self.fail(node, "cutoff_hz", path + ".cutoff_hz", "give either 'modes' or 'cutoff_hz', not both")
        source, files = self.fe_mesh(node, path) if "mesh" in node else self.fe_matrices(node, path)
        sets = {}
        if not isinstance(node.get("node_sets") or Map(), Map):
            self.fail(node, "node_sets", path + ".node_sets", "expected a mapping name: [node indices]")
        for name in node.get("node_sets") or {}:
            sets[name] = self.fe_nodes(node["node_sets"], name, f"{path}.node_sets.{name}")
        params = {"method": method, "modes": None,
                  **{k: self.fe_points(node, k, f"{path}.{k}") if k in node else [] for k in ("keep", "load_points")}, "cutoff_hz": None, "interface": None, "reference": None}
        if "stress" in node:
            params["stress"] = self.fe_stress(node, path + ".stress")
        if "cutoff_hz" in node:
            params["cutoff_hz"] = self.plain_number(node, "cutoff_hz", path + ".cutoff_hz", positive=True)
        else:
            params["modes"] = node.get("modes", cms.DEFAULT_MODES)
            if not isinstance(params["modes"], int) or isinstance(params["modes"], bool) or not 1 <= params["modes"] <= limits.FE_MODES:
                self.fail(node, "modes", path + ".modes", f"must be an integer in 1 … {limits.FE_MODES}, got {shown(params['modes'])}")
        if "interface" in node:
            i, ip = node["interface"], path + ".interface"
            self.keys(i, ip, ("node_set", "nodes", "reference", "coupling", "weights"))
            if ("node_set" in i) == ("nodes" in i):
                self.fail(node, "interface", ip, "give exactly one of 'node_set' or 'nodes'")
            if "nodes" in i:
                params["interface"] = self.fe_nodes(i, "nodes", ip + ".nodes")
            else:
                params["interface"] = str(i["node_set"])
            if "reference" in i:
                if not isinstance(i["reference"], list) or len(i["reference"]) != 3:
                    self.fail(i, "reference", ip + ".reference", f"a point [x, y, z] was expected, got {shown(i['reference'])}")
                params["reference"] = [self.plain_number(i["reference"], k, f"{ip}.reference[{k}]", magnitude=False) for k in range(3)]
            if "coupling" in i:
                if i["coupling"] not in cms.COUPLINGS:
                    self.fail(i, "coupling", ip + ".coupling", f"unknown coupling {shown(i['coupling'])}", suggest(i["coupling"], cms.COUPLINGS))
                params["coupling"] = i["coupling"]
            if "weights" in i:
                if not isinstance(i["weights"], list) or not 1 <= len(i["weights"]) <= limits.FE_DOFS // 3:
                    self.fail(i, "weights", ip + ".weights", f"a list of positive numbers (one per interface node) was expected, got {shown(i['weights'])}")
                params["weights"] = [self.plain_number(i["weights"], k, f"{ip}.weights[{k}]", positive=True) for k in range(len(i["weights"]))]
        # judges the reduction (mbsfmu check), does not change it: not an input of reduce_files
        tolerance = (self.plain_number(node, "check_tolerance", path + ".check_tolerance", positive=True)
                     if "check_tolerance" in node else cms.CHECK_TOLERANCE)
        try:
            reduced = cms.reduce_files(files, source, sets, **params)
        except ModelError as err:
            self.fail_at(f"{path}.{err.key}" if err.key else path, err.message, err.hint)
        names = {params["interface"]: 0} if isinstance(params["interface"], str) and params["reference"] else {}
        first = 1 if params["reference"] else 0
        names.update({k: first + i for i, k in enumerate(params["keep"]) if isinstance(k, str)})
        self.node_names[body] = names
        out = dict(_plain(reduced), check_tolerance=tolerance)
        if "stress" in params:
            out["stress_names"] = self.stress_names(node, path + ".stress", params["stress"], reduced)
        return out

    def fe_stress(self, node, path):
        """`stress:` FE node indices and node set names (scene names: they name FMU variables), of a mesh only."""
        if "mesh" not in node:
            self.fail(node, "stress", path, "stress outputs need a solid mesh (mesh: and material:): mass and "
                      "stiffness matrices carry no elements to take stresses from", "give the part as a mesh, or leave stress out")
        entries = self.fe_points(node, "stress", path)
        if len(entries) > limits.FE_STRESS_NODES:
            self.fail(node, "stress", path, f"{len(entries)} stress nodes, at most {limits.FE_STRESS_NODES}", "name fewer nodes")
        for i, x in enumerate(entries):
            if isinstance(x, str):
                self.name(node["stress"], i, f"{path}[{i}]", what="a stress node set name (it names FMU outputs)")
        return entries

    def stress_names(self, node, path, entries, reduced):
        """The name of each stress node (a row of the reduced body's stress modes): its index, a one-node set's
        name, else set.index; each name once."""
        names, rows = [], iter(np.asarray(reduced["stress_nodes"]).tolist())
        for entry, count in zip(entries, np.asarray(reduced["stress_counts"]).tolist()):
            nodes = [next(rows) for _ in range(count)]
            names += [str(entry)] if isinstance(entry, int) or count == 1 else [f"{entry}.{k}" for k in nodes]
        twice = next((n for i, n in enumerate(names) if n in names[:i]), None)
        if twice is not None:
            self.fail(node, "stress", path, f"stress node '{twice}' is named twice", "name each node once")
        return names

    def fe_matrices(self, node, path):
        """(source, files) of an FE model given as mass and stiffness matrices (fe.read)."""
        for k in ("mass", "stiffness", "nodes"):
            if k not in node:
                raise ModelError(f"missing required key '{k}'", file=self.file, line=node.line, key=path,
                                 hint="mass, stiffness and nodes files, or a solid mesh: mesh and material")
        for k in _FE_MESH_KEYS:
            if k in node:
                self.fail(node, k, f"{path}.{k}", f"'{k}' belongs to a solid mesh (mesh:), not to matrix files")
        fmt = node.get("format", "matrix-market")
        if fmt not in _FE_FORMATS:
            self.fail(node, "format", path + ".format", f"unknown format {shown(fmt)}", suggest(fmt, _FE_FORMATS))
        files = {k: self.fe_file(node, k, path) for k in ("mass", "stiffness", "nodes")}
        dof_map = node.get("dof_map", "node-major")
        if dof_map not in ("node-major", "direction-major"):   # (Abaqus: for FORMAT=COORDINATE files, fe.py)
            files["dof_map"] = self.fe_file(node, "dof_map", path)
            dof_map = "file"
        return {"format": fmt, "dof_map": dof_map}, files

    def fe_mesh(self, node, path):
        """(source, files) of an FE model given as a solid mesh and its material (fe_mesh.py assembles it)."""
        for k in ("mass", "stiffness", "nodes", "format", "dof_map"):
            if k in node:
                self.fail(node, k, f"{path}.{k}", f"give either a solid mesh (mesh:) or matrix files, not '{k}' beside 'mesh'")
        if "material" not in node:
            self.fail(node, "mesh", path + ".material", "a solid mesh needs its material", "material: {E: 2.1e11, nu: 0.3, rho: 7850}")
        m, mp = node["material"], path + ".material"
        self.keys(m, mp, ("E", "nu", "rho"), required=("E", "nu", "rho"))
        material = {k: self.plain_number(m, k, f"{mp}.{k}", positive=k != "nu", magnitude=k != "nu") for k in ("E", "nu", "rho")}
        from ..bodies.fe_mesh import ELEMENTS
        element = node.get("element")
        if element is not None and element not in ELEMENTS:
            self.fail(node, "element", path + ".element", f"unknown element {shown(element)}", suggest(element, ELEMENTS))
        return {"format": "mesh", "material": material, "element": element}, {"mesh": self.fe_file(node, "mesh", path)}

    def fe_file(self, node, key, path):
        try:
            return datafile.resolve(self.base, node[key], self.allow_outside)
        except ModelError as err:
            self.fail(node, key, f"{path}.{key}", err.message, err.hint)

    def fe_points(self, parent, key, path):
        """`keep:` or `load_points:` FE node indices and node set names (a set is one point: its average motion)."""
        v = parent[key]
        if not isinstance(v, list) or not v or any(isinstance(x, bool) or not isinstance(x, (int, str)) or (isinstance(x, int) and x < 0) for x in v):
            self.fail(parent, key, path, f"a list of node indices (integers ≥ 0) and node set names was expected, got {shown(v)}")
        return [x if isinstance(x, str) else int(x) for x in v]

    def fe_nodes(self, parent, key, path):
        """A list of node indices (0-based) of an FE model."""
        v = parent[key]
        if not isinstance(v, list) or not v or any(isinstance(x, bool) or not isinstance(x, int) or x < 0 for x in v):
            self.fail(parent, key, path, f"a list of node indices (integers ≥ 0) was expected, got {shown(v)}")
        return [int(x) for x in v]

    def plain_number(self, parent, key, path, **kw):
        """A number that feeds build-time work (an FE reduction): no parameters."""
        v = self.number(parent, key, path, **kw)
        if isinstance(v, str):
            self.fail(parent, key, path, f"a plain number was expected, got '{v}'", "the reduction runs once, when the scene is loaded")
        return v

    def beam_along_x(self, b, path):
        """Whether a `beam:` lies along body x (its `axis`, checked here: plain numbers, since dynamic
        stiffening, on by default, exists only along x)."""
        from ..bodies.beam import axis_rotation
        if not isinstance(b, Map) or "axis" not in b:
            return True
        axis = b["axis"]
        if not (isinstance(axis, list) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in axis)):
            self.fail(b, "axis", path + ".axis", f"three numbers were expected, got {shown(axis)}", "e.g. [0, 0, 1]: the beam along body z")
        try:
            return bool(np.allclose(axis_rotation(axis, path + ".axis"), np.eye(3)))
        except ModelError as err:
            self.fail(b, "axis", path + ".axis", err.message, err.hint)

    def elastic_data(self, name, elastic, path):
        """The body's nodal data built as compile builds it, at the parameters' values: bad shapes, stiffness or
        damping that is not symmetric positive semi-definite, non-positive masses fail here with their line."""
        from types import SimpleNamespace

        from ..bodies.nodal import check_damping
        from ..bodies.tree import bind_elastic
        body = SimpleNamespace(name=name, elastic=elastic)
        try:
            bind_elastic(body, dict(self.params, t=0.0))
            if "beam" in elastic and "damping" in elastic:
                check_damping(elastic["damping"], body.nodal.n, path)
        except ModelError as err:
            key = err.key or path
            if key == path + ".nodal.damping" and "damping" in elastic:  # given beside `nodal:`, not in it
                key = path + ".damping"
            self.fail_at(key, err.message, err.hint)
        except (ValueError, ArithmeticError) as err:  # e.g. a singular modal mass in a linear-algebra routine
            self.fail_at(path, f"cannot build the elastic body: {err}")
        self.node_count[name] = body.nodal.nodes
        return body.nodal

    def node_index(self, parent, key, path, body, node):
        """A `node:` index on elastic body `body`: in [-N, N - 1] (negative counts from the end)."""
        N = self.node_count.get(body)
        if N is None:
            self.fail(parent, key, path, f"'{body}' has no nodes: nodes exist only on elastic bodies")
        names = self.node_names.get(body, {})
        if isinstance(node, str) and node in names:   # a node set an FE body keeps
            return names[node]
        if isinstance(node, str):
            self.fail(parent, key, path, f"'{body}' keeps no node set '{node}'",
                      suggest(node, sorted(names)) if names else "name node sets in the body's fe: keep list")
        if isinstance(node, bool) or not isinstance(node, int):
            self.fail(parent, key, path, f"a node index (an integer) was expected, got {shown(node)}", f"use 0 … {N - 1}, or -1 … {-N} from the end")
        if not -N <= node < N:
            self.fail(parent, key, path, f"node {node} does not exist: '{body}' has {N} nodes", f"use 0 … {N - 1}, or -1 … {-N} from the end")
        return node

    # -- force elements ----------------------------------------------------------------------------
    def forces(self, root, spec):
        node = root.get("forces") or Seq()
        if not isinstance(node, list):
            self.fail(root, "forces", "forces", "expected a list of force elements")
        bodies = {b["name"]: b for b in spec["bodies"]}
        inputs, out = set(), []
        for i, f in enumerate(node):
            path = f"forces[{i}]"
            if not isinstance(f, Map) or "type" not in f:
                self.fail(node, i, path, "expected a mapping with 'type'", "valid: " + ", ".join(FORCE_TYPES))
            kind = f["type"]
            if kind not in FORCE_TYPES:
                self.fail(f, "type", path + ".type", f"unknown force type '{kind}'", suggest(kind, FORCE_TYPES))
            g = {"type": kind}
            if kind == "spring_damper":
                self.keys(f, path, ("type", "bodies", "at", "node", "stiffness", "damping", "length"), required=("bodies", "stiffness"))
                bs = f["bodies"]
                if not isinstance(bs, list) or len(bs) != 2:
                    self.fail(f, "bodies", path + ".bodies", "expected two body names [A, B] (world allowed)")
                for j, b in enumerate(bs):
                    if b != "world" and not _known(b, bodies):
                        self.fail(bs, j, f"{path}.bodies[{j}]", f"unknown body '{b}'", suggest(b, ["world"] + list(bodies)))
                if bs[0] == bs[1]:
                    self.fail(f, "bodies", path + ".bodies", "a spring needs two different bodies")
                g["bodies"] = list(bs)
                g["at"] = [[0.0] * 3, [0.0] * 3]
                if "at" in f:
                    if not isinstance(f["at"], list) or len(f["at"]) != 2:
                        self.fail(f, "at", path + ".at", "expected two points [[x, y, z], [x, y, z]] in the bodies' frames")
                    g["at"] = [self.vector(f["at"], j, f"{path}.at[{j}]") for j in range(2)]
                g["node"] = self.nodes(f, path, bs)
                g["stiffness"] = self.number(f, "stiffness", path + ".stiffness", nonneg=True)
                g["damping"] = self.number(f, "damping", path + ".damping", nonneg=True) if "damping" in f else 0.0
                g["length"] = self.number(f, "length", path + ".length", nonneg=True) if "length" in f else 0.0
            elif kind == "joint_spring_damper":
                self.keys(f, path, ("type", "coordinate", "stiffness", "damping", "offset"), required=("coordinate",))
                c = f["coordinate"]
                b = self.coords.get(c) if _known(c, self.coords) else None
                if b is None:
                    self.fail(f, "coordinate", path + ".coordinate", f"unknown coordinate '{c}'", suggest(c, sorted(self.coords)))
                j = b["joint"]
                if c in j["drive"]:
                    self.fail(f, "coordinate", path + ".coordinate", f"coordinate '{c}' is driven, so a spring on it does nothing")
                row = joint_type(j["type"], j.get("parameterization"))
                if row.quaternion and c not in j["coordinates"][:row.quaternion.start]:
                    self.fail(f, "coordinate", path + ".coordinate", f"'{c}' is a quaternion coordinate", "use parameterization: cardan, or a spring_damper between points")
                if b["elastic"] and c in b["elastic"]["coordinates"]:
                    self.fail(f, "coordinate", path + ".coordinate", f"'{c}' is an elastic coordinate (its stiffness comes from the body)")
                g["coordinate"] = c
                g["stiffness"] = self.number(f, "stiffness", path + ".stiffness", nonneg=True) if "stiffness" in f else 0.0
                g["damping"] = self.number(f, "damping", path + ".damping", nonneg=True) if "damping" in f else 0.0
                angle = row.units[j["coordinates"].index(c)] == "rad"
                g["offset"] = (self.angle if angle else self.number)(f, "offset", path + ".offset") if "offset" in f else 0.0
            else:
                self.keys(f, path, ("type", "body", "at", "node", "value", "input", "frame"), required=("body",))
                b = f["body"]
                if not _known(b, bodies):
                    self.fail(f, "body", path + ".body", f"unknown body '{b}'", suggest(b, list(bodies)))
                g["body"] = b
                if kind == "torque" and ("at" in f or "node" in f) and not bodies[b]["elastic"]:
                    self.fail(f, "at", path, "a torque acts on the whole rigid body: drop 'at'")
                g["at"] = self.vector(f, "at", path + ".at") if "at" in f else [0.0] * 3
                g["node"] = self.nodes(f, path, [b])[0] if "node" in f else None
                if ("value" in f) == ("input" in f):
                    self.fail(f, "type", path, "give exactly one of 'value' (three numbers or expressions in t) or 'input' (an FMU input name)")
                if "value" in f:
                    g["value"] = self.vector(f, "value", path + ".value", allow_t=True)
                else:
                    name = self.name(f, "input", path + ".input", what="an input name")
                    if name in inputs or name in self.params:
                        self.fail(f, "input", path + ".input", f"the name '{name}' is used twice")
                    inputs.add(name)
                    g["input"] = name
                frame = f.get("frame", "world")
                if frame not in ("world", "body"):
                    self.fail(f, "frame", path + ".frame", f"unknown frame '{frame}'", suggest(frame, ("world", "body")))
                g["frame"] = frame
            out.append(g)
        return out

    def nodes(self, f, path, names):
        """`node:` on force elements (one index per body) → list (None for 'at' points)."""
        if "node" not in f:
            return [None] * len(names)
        nodes = f["node"] if isinstance(f["node"], list) else [f["node"]]
        if len(nodes) != len(names):
            self.fail(f, "node", path + ".node", f"expected {len(names)} node index(es), null for a rigid body")
        return [None if n is None else self.node_index(f, "node", path + ".node", b, n) for n, b in zip(nodes, names)]

    # -- outputs, integrator, experiment -----------------------------------------------------------
    def outputs(self, root, spec):
        node = root.get("outputs") or Seq()
        if not isinstance(node, list):
            self.fail(root, "outputs", "outputs", "expected a list of {body, point, quantities, name}")
        bodies = {b["name"]: b for b in spec["bodies"]}
        out, names = [], set()
        for i, o in enumerate(node):
            path = f"outputs[{i}]"
            self.keys(o, path, ("body", "point", "node", "quantities", "name"), required=("body",))
            if not _known(o["body"], bodies):
                self.fail(o, "body", path + ".body", f"unknown body '{o['body']}'", suggest(o["body"], list(bodies)))
            g = {"body": o["body"], "point": self.vector(o, "point", path + ".point") if "point" in o else [0.0] * 3}
            g["node"] = self.nodes(o, path, [o["body"]])[0] if "node" in o else None
            qs = o.get("quantities", ["position", "velocity"])
            if not isinstance(qs, list) or not qs:
                self.fail(o, "quantities", path + ".quantities", "expected a list", "valid: position, velocity")
            for j, q in enumerate(qs):
                if q not in ("position", "velocity"):
                    self.fail(qs, j, f"{path}.quantities[{j}]", f"unknown quantity '{q}'", suggest(q, ("position", "velocity")))
            g["quantities"] = list(qs)
            g["name"] = self.name(o, "name", path + ".name", pattern=_COORD, what="an output name") if "name" in o else o["body"]
            if g["name"] in names:
                self.fail(o, "name" if "name" in o else "body", path, f"output name '{g['name']}' is used twice", "give each output its own 'name'")
            names.add(g["name"])
            out.append(g)
        return out

    def integrator(self, root):
        node = root.get("integrator") or Map()
        self.keys(node, "integrator", ("method", "rtol", "atol", "max_step", "step", "rho_inf"))
        method = node.get("method", "auto")
        if method not in METHODS:
            self.fail(node, "method", "integrator.method", f"unknown method '{method}'", suggest(method, METHODS))
        out = {"method": method}
        for k, default in (("rtol", 1e-6), ("atol", 1e-8), ("max_step", 0.0), ("step", 0.0), ("rho_inf", 0.8)):
            out[k] = self.value(self.number(node, k, f"integrator.{k}", positive=k in ("rtol", "atol"), nonneg=True, magnitude=False)) if k in node else default
        if not 0 <= out["rho_inf"] <= 1:
            self.fail(node, "rho_inf", "integrator.rho_inf", "must lie in [0, 1]")
        return out

    def integrator_steps(self, root, spec):
        """The settings' domains (scene/domains.py, which the engine applies to a host's values too): tolerances a
        step can meet, fixed and largest steps that the experiment's span can afford (a run must end)."""
        node, ex = root.get("integrator") or Map(), spec["experiment"]
        span = ex["stop"] - ex["start"]
        for k, domain in domains.integrator_domains(ex).items():
            v = spec["integrator"][k]
            if k not in node or domain.contains(v):
                continue
            if k == "rtol":
                self.fail(node, k, f"integrator.{k}", f"{v:g} is outside {domain.text}",
                          "double precision cannot meet a relative tolerance below 1e-14")
            elif k == "atol":
                self.fail(node, k, f"integrator.{k}", f"{v:g} is outside {domain.text}",
                          "an absolute tolerance below 1e-100 overflows the error weights")
            else:
                self.fail(node, k, f"integrator.{k}", f"{v:g} s would take {span / v:.3g} steps over the experiment's {span:g} s",
                          f"at most {100 * limits.COMMUNICATION_POINTS:.0e} steps (valid: {domain.text}); 0 lets the method choose")

    def experiment(self, root):
        node = root.get("experiment") or Map()
        self.keys(node, "experiment", ("start", "stop", "step"))
        out = {"start": 0.0, "stop": 10.0, "step": 0.01}
        for k in out:
            if k in node:
                out[k] = self.value(self.number(node, k, f"experiment.{k}", positive=k == "step"))
        if out["stop"] <= out["start"]:
            self.fail(node, "stop" if "stop" in node else "start", "experiment.stop", f"stop ({out['stop']:g}) must come after start ({out['start']:g})")
        key = "step" if "step" in node else "stop"
        points = (out["stop"] - out["start"]) / out["step"]
        if not points <= limits.COMMUNICATION_POINTS:
            self.fail(node, key, f"experiment.{key}", f"{points:.3g} communication points (at most {limits.COMMUNICATION_POINTS:.0e})",
                      "raise the step or shorten the experiment")
        if out["step"] < 100 * np.spacing(max(abs(out["start"]), abs(out["stop"]))):
            self.fail(node, key, f"experiment.{key}", f"a step of {out['step']:g} s is below the resolution of times near {out['stop']:g} s",
                      "raise the step or start nearer 0")
        return out

    def time_domains(self, spec):
        """Drives (with their first two time derivatives) and force values stay finite over [start, stop]."""
        ex, env = spec["experiment"], dict(self.params)
        fields = [(f"bodies.{b['name']}.joint.drive.{c}", v, 2) for b in spec["bodies"] for c, v in b["joint"]["drive"].items()]
        fields += [(f"forces[{i}].value[{k}]", v, 0) for i, f in enumerate(spec["forces"]) for k, v in enumerate(f.get("value", ()))]
        for path, value, derivatives in fields:
            problem = domains.first_failure(value, env, ex["start"], ex["stop"], derivatives)
            if problem:
                self.fail_at(path, f"'{value}': {problem}", f"the expression must be defined over the experiment [{ex['start']:g}, {ex['stop']:g}] s"
                             + (", with its velocity and acceleration" if derivatives else ""))

    def variable_names(self, spec):
        """Two scene names that make one FMU variable (an input `q` beside a coordinate `x`: both `q.x`)."""
        clash = names.first_collision(spec)
        if clash:  # the one written later in the file is the one to rename
            (var, first, first_path), (_, second, second_path) = sorted(clash, key=lambda v: self.line_of(v[2]))
            self.fail_at(second_path, f"{second} and {first} both make the FMU variable '{var}' (line {self.line_of(first_path)})",
                         "rename one of them")


_FE_MESH_KEYS = ("mesh", "material", "element")
_FE_KEYS = ("mass", "stiffness", "nodes", "format", "dof_map", "node_sets", "interface", "method", "modes", "cutoff_hz", "keep", "load_points", "check_tolerance", "stress") + _FE_MESH_KEYS
_FE_FORMATS = ("matrix-market", "abaqus")


def _plain(v):
    """Map/Seq trees → plain dicts/lists (JSON-able)."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


def check_shapes_again(spec, base, file):
    """The bodies' `shape` entries of a normalized scene that comes from elsewhere (an FMU's drawing description),
    checked by the rules of a scene file: each is read back as `shape:` input (mesh files next to `base`) and
    must normalize to itself. Raises ModelError."""
    ck = _Checker(file, Path(base))
    ck.params = {p["name"]: float(p["value"]) for p in spec["parameters"]}
    for b in spec["bodies"]:
        if "shape" in b and check_shapes(ck, Map(shape=_as_input(b["shape"])), f"bodies.{b['name']}") != b["shape"]:
            raise ModelError("is not a shape list as mbsfmu writes it", file=file, key=f"bodies.{b['name']}.shape")


def _as_input(v):
    """Plain JSON data → the reader's Map/Seq nodes; keys a normalized scene sets to null are left out."""
    if isinstance(v, dict):
        return Map({k: _as_input(x) for k, x in v.items() if x is not None})
    if isinstance(v, list):
        return Seq(_as_input(x) for x in v)
    return v
