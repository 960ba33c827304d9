"""URDF robot descriptions → the scene document a YAML scene gives (issue 25), so that validation, compilation
and the FMUs are the existing path; `include` merges one into a YAML scene (`urdf: {file: ...}`).

XML from outside is hostile until proven otherwise: defusedxml's expat reader refuses entity declarations and
external references, the file and its element counts are bounded (limits.py), and every problem is one
ModelError with the file, the line and the element. Links on fixed joints stay bodies on fixed joints (the
engine adds no coordinates for them: the dynamics are those of Pinocchio's merged links, and their names stay
usable for outputs, forces and drawing).
"""

import io
import math
import os
import re
import xml.sax
from pathlib import Path

import numpy as np
from defusedxml import DefusedXmlException
from defusedxml.expatreader import DefusedExpatParser

from ..errors import ModelError
from .. import datafile, limits
from . import domains
from .shapes import MESH_SUFFIXES, PACKAGE, package_path
from .wording import suggest
from .yaml_lines import Map, Seq

JOINT_KINDS = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
BASES = ("fixed", "free")
INCLUDE_KEYS = ("file", "package_dirs", "base", "repair")
ROUNDOFF = 1e-6  # an inertia this close (relative to its link's scale) to a physical one is that one: the file's rounding
_XACRO_HINT = "run xacro first (xacro robot.urdf.xacro > robot.urdf) and load the URDF it writes"


class _Element:
    """An XML element with the line it starts on (ElementTree keeps no line numbers)."""

    __slots__ = ("tag", "attrs", "line", "children")

    def __init__(self, tag, attrs, line):
        self.tag, self.attrs, self.line, self.children = tag, attrs, line, []

    def find(self, tag):
        return next((c for c in self.children if c.tag == tag), None)


class _Builder(xml.sax.ContentHandler):
    """SAX events → _Element tree, counting elements as they come (bounded work for any file)."""

    def __init__(self, fail):
        super().__init__()
        self.fail, self.stack, self.root, self.count = fail, [], None, 0

    def startElement(self, tag, attrs):
        line = self._locator.getLineNumber() if self._locator else None
        if tag.startswith("xacro:"):
            self.fail(line, tag, "a xacro macro file, not a URDF", _XACRO_HINT)
        self.count += 1
        if self.count > limits.URDF_ELEMENTS:
            self.fail(line, tag, f"more than {limits.URDF_ELEMENTS:,} XML elements", "a robot description needs far fewer")
        if len(self.stack) >= limits.DEPTH:
            self.fail(line, tag, f"elements nested deeper than {limits.DEPTH}", "URDF elements nest 3-4 deep")
        e = _Element(tag, dict(attrs), line)
        if self.stack:
            self.stack[-1].children.append(e)
        else:
            self.root = e
        self.stack.append(e)

    def endElement(self, tag):
        self.stack.pop()


def read(path, package_dirs=(), base="fixed", repair=False, included=False, scene_dir=None, packages_kept=True):
    """The URDF file `path` → (scene document of Map/Seq as a YAML scene gives it, [repair reports]).

    base: 'fixed' (the root link fixed to the world) or 'free' (a free joint, a floating base). repair: merge
    massless moving subtrees into their parents and project unphysical inertias instead of refusing them.
    package_dirs: folders (resolved) that `package://NAME/...` mesh files are looked up in, each mesh confined
    to the folder it is found in. scene_dir: the folder mesh shapes are named relative to (default the URDF's);
    packages_kept: a package mesh outside it keeps its package:// name (else it is not drawn).
    Every body and damper reports its URDF line; included (in a YAML scene): each line names the URDF too."""
    path = Path(path)
    fail = _failer(str(path))
    if path.suffix.lower() == ".xacro":
        fail(None, None, "a xacro file, not a URDF", _XACRO_HINT)
    root = _parse(path, fail)
    if root.tag != "robot":
        fail(root.line, root.tag, f"the document's element is <{root.tag}>, a URDF's is <robot>", "give a URDF file")
    robot = _Robot(root, fail, repair)
    robot.file = str(path)
    robot.meshes = _Meshes(path.parent, package_dirs, scene_dir or path.parent, fail, packages_kept)
    doc = robot.document(base)
    tree = _with_urdf_lines(doc, robot.lines, robot.damper_lines, str(path) if included else None)
    return tree, robot.repairs


def _failer(file):
    def fail(line, element, message, hint=None):
        raise ModelError(message, file=file, line=line, key=f"<{element}>" if element else None, hint=hint)
    return fail


def _parse(path, fail):
    try:
        with limits.open_regular(path) as f:
            data = f.read(limits.DOCUMENT_BYTES + 1)  # bounded
    except OSError as e:
        fail(None, None, f"cannot read the URDF file: {e.strerror or e}", "give the path of a regular URDF file")
    if len(data) > limits.DOCUMENT_BYTES:
        fail(None, None, f"the file is larger than {limits.DOCUMENT_BYTES // 2**20} MiB", "a robot description is far smaller")
    starts = data.count(b"<") - data.count(b"</") - data.count(b"<!") - data.count(b"<?")  # ≥ its elements: C-fast
    if starts > limits.URDF_ELEMENTS:
        fail(None, None, f"more than {limits.URDF_ELEMENTS:,} XML elements ({starts:,} start tags)", "a robot description needs far fewer")
    builder = _Builder(fail)
    parser = DefusedExpatParser()  # entity declarations and external references are refused where they stand
    parser.setContentHandler(builder)
    parser.setFeature(xml.sax.handler.feature_external_ges, False)
    try:
        parser.parse(io.BytesIO(data))  # parse, not feed: it gives the handler the locator of line numbers
    except DefusedXmlException as e:
        line = parser.getLineNumber() if parser._parser else None
        fail(line, None, f"{type(e).__name__}: {e}: entity declarations and external references are refused",
             "a URDF needs neither; expand them before loading")
    except xml.sax.SAXParseException as e:
        fail(e.getLineNumber(), None, f"not well-formed XML: {e.getMessage()}", "fix the XML (an editor that checks XML helps)")
    if builder.root is None:
        fail(None, None, "an empty document", "give a URDF file (<robot name=...> with links and joints)")
    return builder.root


class _Robot:
    """Links and joints of one URDF, checked; `document` writes the scene."""

    def __init__(self, root, fail, repair):
        self.fail, self.repair, self.repairs, self.notes = fail, repair, [], []  # notes: "line: what", warned once
        self.coordinates = {}  # coordinate name → the URDF joint that gives it
        self.lines, self.damper_lines = {}, []  # URDF lines of the bodies (by name) and of the joint dampers
        self.name = _identifier(root.attrs.get("name") or "robot", "model")
        self.links, self.joints = {}, {}
        self.materials = {e.attrs.get("name"): e for e in root.children if e.tag == "material"}
        for e in root.children:
            if e.tag in ("link", "joint"):
                table = self.links if e.tag == "link" else self.joints
                name = self.attr(e, "name")
                if name in table:
                    fail(e.line, e.tag, f"a second {e.tag} named '{name}' (first at line {table[name].line})", f"give every {e.tag} its own name")
                if len(table) >= limits.ENTRIES:
                    fail(e.line, e.tag, f"more than {limits.ENTRIES:,} {e.tag}s", "a robot description needs far fewer")
                table[name] = e
        if not self.links:
            fail(root.line, "robot", "no <link> in the robot", "a URDF describes links and the joints between them")
        self.parent_joint = {}  # child link → joint element
        for name, j in self.joints.items():
            for end in ("parent", "child"):
                link = self.attr(self.child(j, end), "link")
                if link not in self.links:
                    fail(self.child(j, end).line, end, f"joint '{name}' names the {end} link '{link}', which the robot does not have",
                         "links: " + ", ".join(list(self.links)[:20]))
            child = self.child(j, "child").attrs["link"]
            if child in self.parent_joint:
                fail(j.line, "joint", f"link '{child}' is the child of two joints ('{self.parent_joint[child].attrs['name']}' and '{name}')",
                     "a URDF is a tree: closed loops are not supported")
            self.parent_joint[child] = j
            if self.attr(j, "type") not in JOINT_KINDS:
                fail(j.line, "joint", f"joint '{name}' has the unknown type '{j.attrs['type']}'", suggest(j.attrs["type"], JOINT_KINDS))
        roots = [n for n in self.links if n not in self.parent_joint]
        if len(roots) != 1:
            where = self.links[roots[1]] if len(roots) > 1 else root
            fail(where.line, "link", f"the links form {'no tree (a cycle: every link is a child)' if not roots else f'{len(roots)} trees (roots {roots[:5]})'}",
                 "a URDF is one tree: exactly one link (the base) is no joint's child")
        self.root = roots[0]
        self.order = self._depth_first()
        if len(self.order) != len(self.links):
            cyc = next(n for n in self.links if n not in set(self.order))
            fail(self.links[cyc].line, "link", f"link '{cyc}' lies on a cycle of joints", "a URDF is a tree: closed loops are not supported")

    def attr(self, e, key):
        v = e.attrs.get(key)
        if v is None:
            self.fail(e.line, e.tag, f"<{e.tag}> needs the attribute '{key}'")
        return v

    def child(self, e, tag):
        c = e.find(tag)
        if c is None:
            self.fail(e.line, e.tag, f"<{e.tag} name=\"{e.attrs.get('name', '')}\"> needs a <{tag}> element")
        return c

    def numbers(self, e, key, n, default):
        text = e.attrs.get(key) if e is not None else None
        if text is None:
            return list(default)
        try:
            v = [float(x) for x in text.split()]
        except ValueError:
            v = []
        if len(v) != n or not all(math.isfinite(x) for x in v):
            self.fail(e.line, e.tag, f"{key}=\"{text[:60]}\" is not {n} finite number{'s' if n > 1 else ''}")
        return v

    def _depth_first(self):
        self.child_joints = children = {}
        for j in self.joints.values():
            children.setdefault(j.find("parent").attrs["link"], []).append(j)
        order, stack = [], [self.root]
        while stack and len(order) <= len(self.links):
            link = stack.pop()
            order.append(link)
            stack.extend(j.find("child").attrs["link"] for j in reversed(children.get(link, [])))
        return order

    def origin(self, j):
        """A joint's <origin> → (R, p): the child link's frame in the parent link's."""
        o = j.find("origin")
        return rpy_matrix(self.numbers(o, "rpy", 3, [0.0] * 3)), np.array(self.numbers(o, "xyz", 3, [0.0] * 3))

    def floating_links(self, base):
        """The links on a free joint that `base` adds: the root, or with the URDF's own `world` link as root (the
        fixed frame, as in ur*, xarm7, z1) its children on fixed joints: the robot it holds floats instead."""
        if base != "free":
            return set()
        if self.root != "world":
            return {self.root}
        out = set()
        for j in self.child_joints.get("world", []):
            if self.attr(j, "type") == "fixed":
                out.add(j.find("child").attrs["link"])
            elif j.attrs["type"] != "floating":
                self.fail(j.line, "joint", f"joint '{j.attrs['name']}' ({j.attrs['type']}) holds link '{j.find('child').attrs['link']}' "
                          "on the URDF's world link: a free base cannot float a robot that moves on the world's joint",
                          "load with base fixed, or make the URDF's root the robot's base link")
        return out

    # -- the scene document -----------------------------------------------------------------------
    def document(self, base):
        if base not in BASES:
            self.fail(None, None, f"unknown base '{base}'", "base: fixed (the root link held in the world) or free (a floating base)")
        floating = self.floating_links(base)
        inertial = {n: self.inertial(n) for n in self.order}
        moving = self.moving_links(inertial, floating)
        self.rigid_groups(inertial, moving | floating)
        bodies, forces, self.body_of = {}, [], {}
        for link in self.order:
            self.body_of[link] = _identifier(link, "body")
        for link in self.order:
            e = self.links[link]
            name = self.body_of[link]
            if link == self.root and link == "world":
                self.body_of[link] = "world"  # the URDF's own world link: the scene's world (with a free base too)
                continue
            if name in bodies or name == "world":
                self.fail(e.line, "link", f"link '{link}' would be the scene body '{name}', which another link or the world already is",
                          "rename one of the links (scene body names are letters, digits and '_')")
            if link == self.root:
                joint = {"type": base}
            else:
                joint = self.joint(self.parent_joint[link], link in moving, forces)  # floating ones: free
            body = {"parent": "world" if link == self.root else self.body_of[self.parent_joint[link].find("parent").attrs["link"]],
                    "joint": joint}
            m, com, inertia, _ = inertial[link]
            if m > 0 or np.any(inertia):
                body.update(mass=m, center_of_mass=com, inertia=_entries(inertia))
            shapes = self.visuals(e)
            if shapes:
                body["shape"] = shapes
            bodies[name] = body
            self.lines[name] = e.line
        self.meshes.report()
        self.report()
        doc = {"mbsfmu": 1, "name": self.name, "bodies": bodies}
        if forces:
            doc["forces"] = forces
        return doc

    def report(self):
        if self.notes:
            import warnings
            more = f"; and {len(self.notes) - 5} more" if len(self.notes) > 5 else ""
            warnings.warn("; ".join(f"{self.file}:{n}" for n in self.notes[:5]) + more, stacklevel=4)

    def visuals(self, link):
        """The link's <visual> geometry as `shape:` entries (drawing only): boxes, cylinders (along z in both),
        spheres, STL/OBJ/DAE meshes; the colour of an inline or named material. A visual the drawing cannot
        show (a zero size or scale, unreadable numbers) is left out with a note: drawing never refuses a robot."""
        out = []
        for v in link.children:
            g = v.find("geometry") if v.tag == "visual" else None
            if g is None or not g.children:
                continue
            try:
                shape = self.visual(v, g.children[0])
            except ModelError as e:
                self.notes.append(f"{e.line}: {e.key or '<visual>'}: {e.message} (not drawn)")
                continue
            if shape is not None:
                out.append(shape)
        return out

    def visual(self, v, geom):
        """One <visual> as a `shape:` entry, None if it is not drawn (a mesh not found); ModelError if unreadable."""
        if geom.tag == "box":
            shape = {"type": "box", "size": self.numbers(geom, "size", 3, [0.0] * 3)}
        elif geom.tag == "cylinder":
            shape = {"type": "cylinder", "radius": self.numbers(geom, "radius", 1, [0.0])[0], "length": self.numbers(geom, "length", 1, [0.0])[0]}
        elif geom.tag == "sphere":
            shape = {"type": "sphere", "radius": self.numbers(geom, "radius", 1, [0.0])[0]}
        elif geom.tag == "mesh":
            scale = self.numbers(geom, "scale", 3, [1.0] * 3)
            if not all(scale):  # a negative factor mirrors the mesh (drawn so); a zero one flattens it away
                self.fail(geom.line, "mesh", f"scale=\"{geom.attrs['scale']}\" has a zero factor")
            name = self.meshes.find(geom, self.attr(geom, "filename"))
            if name is None:
                return None
            shape = {"type": "mesh", "file": name, "scale": scale}
        else:
            return None
        sizes = [shape[k] for k in ("radius", "length") if k in shape] + shape.get("size", [])
        if not all(x > 0 for x in sizes):
            self.fail(geom.line, geom.tag, f"<{geom.tag}> has a size that is not positive ({', '.join(f'{x:g}' for x in sizes)})")
        origin = v.find("origin")
        shape["at"] = self.numbers(origin, "xyz", 3, [0.0] * 3)
        rpy = self.numbers(origin, "rpy", 3, [0.0] * 3)
        if any(rpy):
            shape["rotation"] = {"matrix": rpy_matrix(rpy).tolist()}
        rgba = self.color(v.find("material"))
        if rgba:
            shape["color"], shape["opacity"] = [min(max(c, 0.0), 1.0) for c in rgba[:3]], min(max(rgba[3], 1e-3), 1.0)
        return shape

    def color(self, material):
        if material is None:
            return None
        c = material.find("color")
        if c is None and material.attrs.get("name") in self.materials:
            c = self.materials[material.attrs["name"]].find("color")
        return self.numbers(c, "rgba", 4, [0.5, 0.5, 0.5, 1.0]) if c is not None else None

    def inertial(self, link):
        """(mass, centre of mass, inertia about it in the link frame, None or (line, what is unphysical about it))."""
        e = self.links[link].find("inertial")
        if e is None:
            return 0.0, [0.0] * 3, np.zeros((3, 3)), None
        origin = e.find("origin")
        com = self.numbers(origin, "xyz", 3, [0.0] * 3)
        R = rpy_matrix(self.numbers(origin, "rpy", 3, [0.0] * 3))
        m = self.numbers(e.find("mass"), "value", 1, [0.0])[0]
        if m < 0:
            self.fail(e.find("mass").line, "mass", f"link '{link}' has the negative mass {m:g}")
        i = e.find("inertia")
        I = np.zeros((3, 3))
        if i is not None:
            xx, xy, xz, yy, yz, zz = (self.numbers(i, k, 1, [0.0])[0] for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"))
            I = R @ np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]) @ R.T  # the inertial frame's tensor in the link frame
        lam = np.linalg.eigvalsh(I)
        if lam[0] >= 0 and lam[0] + lam[1] >= lam[2]:
            return m, com, I, None  # physical (most links: no scale needed)
        defect, I = unphysical(I, self.inertia_scale(link, m, com, I))
        return m, com, I, ((i or e).line, defect) if defect else None

    def inertia_scale(self, link, m, com, I):
        """The size of inertia a link has: its largest moment, or m·ℓ² with ℓ its extent (centre of mass, the
        origins of its child joints), whichever is larger."""
        ell = max([np.linalg.norm(com)] + [np.linalg.norm(self.origin(j)[1]) for j in self.child_joints.get(link, [])])
        return max(float(np.abs(np.linalg.eigvalsh(I)).max()), m * ell * ell)

    def rigid_groups(self, inertial, moving):
        """Links with an inertia that no rigid body has. A link on fixed joints is one rigid body with the links
        fixed to it (Pinocchio merges them): if that group's total inertia is physical (anymal's, b1's, go1's, hyq's
        1e-6 base on its trunk), the total goes on the group's top link and the others carry none (the same
        dynamics exactly); else refused, or (repair) projected onto the nearest physical inertia."""
        top = {}
        for link in self.order:
            top[link] = link if link == self.root or link in moving else top[self.parent_joint[link].find("parent").attrs["link"]]
        for link in self.order:
            if inertial[link][3] is None:
                continue
            line, defect = inertial[link][3]
            group = [n for n in self.order if top[n] == top[link]]
            total = self.composite(group, inertial) if len(group) > 1 else None
            if total is not None:
                m, com, I, _ = total
                problem, I = unphysical(I, max(self.inertia_scale(n, *inertial[n][:3]) for n in group))
                total = None if problem else (m, com, I, None)
            if total is not None:
                for n in group:
                    inertial[n] = (0.0, [0.0] * 3, np.zeros((3, 3)), None)
                inertial[group[0]] = total
                self.notes.append(f"{line}: link '{link}': {defect} alone; the rigid group of {len(group)} links on "
                                  f"fixed joints is physical and goes on '{group[0]}' as one body")
                continue
            if not self.repair:
                self.fail(line, "inertia", f"link '{link}': {defect}", "no rigid body has such an inertia; load with repair "
                          "(repair: true, --repair) to project it onto the nearest physical inertia")
            m, com, I, _ = inertial[link]
            inertial[link] = (m, com, nearest_physical_inertia(I), None)
            self.repairs.append(f"link '{link}': principal moments {_moments(np.linalg.eigvalsh(I))} projected onto the nearest "
                                f"physical ones {_moments(np.linalg.eigvalsh(inertial[link][2]))}")

    def composite(self, group, inertial):
        """(mass, centre of mass, inertia about it) of the links `group` (the first is the top, the others fixed
        below it, in tree order) in the top link's frame."""
        frame = {group[0]: (np.eye(3), np.zeros(3))}
        parts = []
        for n in group:
            if n != group[0]:
                j = self.parent_joint[n]
                Rp, pp = frame[j.find("parent").attrs["link"]]
                R, p = self.origin(j)
                frame[n] = (Rp @ R, pp + Rp @ p)
            R, p = frame[n]
            m, com, I, _ = inertial[n]
            parts.append((m, p + R @ np.asarray(com, dtype=float), R @ I @ R.T))
        M = sum(m for m, _, _ in parts)
        c = sum(m * x for m, x, _ in parts) / M if M > 0 else np.zeros(3)
        I = sum(J + m * ((x - c) @ (x - c) * np.eye(3) - np.outer(x - c, x - c)) for m, x, J in parts)
        return M, c.tolist(), I, None

    def moving_links(self, inertial, floating):
        """Links on non-fixed joints. A moving subtree without mass or inertia makes M singular: refused, or
        (repair) its joint is fixed, merging the massless links into their parent."""
        loaded = {n: inertial[n][0] > 0 or bool(np.trace(inertial[n][2]) > 0) for n in self.order}
        for link in reversed(self.order):  # children first
            j = self.parent_joint.get(link)
            if j is not None and loaded[link]:
                loaded[j.find("parent").attrs["link"]] = True
        moving = set()
        for link in self.order:
            j = self.parent_joint.get(link)
            if j is None or (self.attr(j, "type") == "fixed" and link not in floating):
                continue
            if loaded[link]:
                moving.add(link)
            elif not self.repair:
                self.fail(j.line, "joint", f"joint '{j.attrs['name']}' moves link '{link}', which with the links it carries has no mass "
                          "or inertia: its motion is undetermined (singular mass matrix)",
                          "give the links <inertial> data, or load with repair (repair: true, --repair) to merge them into their parent")
            else:
                self.repairs.append(f"joint '{j.attrs['name']}' fixed: link '{link}' and the links it carries have no mass or inertia")
        return moving

    def joint(self, j, moving, forces):
        name, kind = j.attrs["name"], j.attrs["type"]
        origin = j.find("origin")
        out = {"type": kind if moving else "fixed", "at": self.numbers(origin, "xyz", 3, [0.0] * 3)}
        rpy = self.numbers(origin, "rpy", 3, [0.0] * 3)
        if any(rpy):
            out["rotation"] = {"matrix": rpy_matrix(rpy).tolist()}
        if not moving:
            return out
        if j.find("mimic") is not None:  # (a repaired massless joint drops its mimic with its motion)
            self.fail(j.find("mimic").line, "mimic", f"joint '{name}' mimics joint '{j.find('mimic').attrs.get('joint', '?')}': "
                      "a coupled coordinate (a closed constraint), which the scene format cannot state",
                      "remove the <mimic> element to make the joint independent")
        coordinate = _identifier(name, "coordinate", dots=True)
        if coordinate in self.coordinates:
            self.fail(j.line, "joint", f"joint '{name}' would name the coordinate '{coordinate}', which joint '{self.coordinates[coordinate]}' already names",
                      "rename one of the joints (coordinate names are letters, digits, '_' and '.')")
        self.coordinates[coordinate] = name
        axis = self.numbers(j.find("axis"), "xyz", 3, [1.0, 0.0, 0.0])
        norm = math.sqrt(sum(a * a for a in axis))
        if kind in ("revolute", "continuous", "prismatic", "planar") and not norm > 0:
            self.fail(j.find("axis").line, "axis", f"joint '{name}' has the zero axis")
        axis = [a / norm for a in axis] if norm else axis
        if kind in ("revolute", "continuous", "prismatic"):
            out.update(type="prismatic" if kind == "prismatic" else "revolute", axis=axis, coordinates=[coordinate])
        elif kind == "planar":  # URDF gives the plane's normal
            ax = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
            ax /= np.linalg.norm(ax)
            out.update(axes=[ax.tolist(), np.cross(axis, ax).tolist()],
                       coordinates=[f"{coordinate}.x", f"{coordinate}.y", f"{coordinate}.angle"])
        else:
            out["type"] = "free"
        d = j.find("dynamics")
        damping = self.numbers(d, "damping", 1, [0.0])[0] if d is not None else 0.0
        if damping < 0:
            self.fail(d.line, "dynamics", f"joint '{name}' has the negative damping {damping:g}")
        if damping > 0 and len(out.get("coordinates", ())) == 1:
            forces.append({"type": "joint_spring_damper", "coordinate": coordinate, "stiffness": 0, "damping": damping})
            self.damper_lines.append(d.line)
        return out


def _entries(I):
    """An inertia tensor as the scene's {xx, yy, zz, xy, xz, yz} (zero products left out)."""
    I = (I + I.T) / 2  # the rotated tensor, symmetric to the last bit
    out = {k: float(I[i, j]) for k, (i, j) in zip(("xx", "yy", "zz", "xy", "xz", "yz"), ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)))}
    return {k: v for k, v in out.items() if v != 0 or k in ("xx", "yy", "zz")}


class _Meshes:
    """Mesh file names of <mesh filename=...> → the names shapes give: `package://NAME/rest` is looked up in the
    named package folders and kept as it is (the scene's package_dirs are trusted folders, wherever they lie),
    or named relative to the scene's folder if it lies in it; other names are relative to the URDF's folder and
    must lie in the scene's. A name that leaves its folder is refused (its visual is not drawn). Meshes the
    drawing cannot show (other formats, outside the scene's folder, not found) are counted and reported in one note.
    packages_kept: False where the shapes must name files in the scene's folder (convert writes a YAML)."""

    def __init__(self, urdf_dir, package_dirs, scene_dir, fail, packages_kept=True):
        self.urdf_dir, self.package_dirs, self.scene_dir, self.fail = urdf_dir.resolve(), list(package_dirs), scene_dir.resolve(), fail
        self.packages_kept, self.skipped = packages_kept, {}

    def find(self, e, uri):
        if uri.startswith(PACKAGE):
            found = package_path(self.package_dirs, uri)
            if found is None:
                return self.skip("in no named package folder (package_dirs)")
            folder, path = found
        elif "://" in uri:
            return self.skip(f"{uri.split('://')[0]}:// names")
        else:
            folder = self.urdf_dir
            path = (folder / uri).resolve()
        if not path.is_relative_to(folder):
            self.fail(e.line, "mesh", f"the mesh file '{uri[:200]}' leaves its folder {folder}", "mesh files must lie inside their package folder")
        if path.suffix.lower() not in MESH_SUFFIXES:
            return self.skip(f"{path.suffix or 'no suffix'} files")
        if not path.is_file():
            return self.skip("not found")
        if path.stat().st_size > limits.MESH_BYTES:
            return self.skip(f"larger than {limits.MESH_BYTES // 2**20} MB")
        if path.is_relative_to(self.scene_dir):
            return path.relative_to(self.scene_dir).as_posix()
        if uri.startswith(PACKAGE) and self.packages_kept:
            return uri
        return self.skip("outside the scene's folder")

    def skip(self, why):
        self.skipped[why] = self.skipped.get(why, 0) + 1
        return None

    def report(self):
        if self.skipped:
            import warnings
            warnings.warn("visual meshes not drawn: " + ", ".join(f"{n} {why}" for why, n in self.skipped.items()), stacklevel=4)


def rpy_matrix(rpy):
    """URDF's fixed-axis roll, pitch, yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def unphysical(I, scale):
    """(None or what is wrong, I): an inertia within ROUNDOFF·scale of a physical one is taken as that one (its
    file's digits rounded it: icub's point masses of moments -5.4e-20); farther, it is unphysical (not positive
    semi-definite, or breaking I1 + I2 >= I3), whatever its own size (domains.check's floor is absolute)."""
    lam = np.linalg.eigvalsh(I)
    if max(-lam[0], lam[2] - lam[0] - lam[1]) <= ROUNDOFF * scale:
        return None, I if domains.check(domains.INERTIA, I.ravel()) is None else nearest_physical_inertia(I)
    moments = f"principal moments {lam[0]:.4g}, {lam[1]:.4g}, {lam[2]:.4g}"
    if lam[0] < -ROUNDOFF * scale:
        return f"the inertia tensor is not positive semi-definite ({moments})", I
    return f"{moments} break the triangle inequality (I1 + I2 >= I3)", I


def nearest_physical_inertia(I):
    """The physical inertia nearest to I in its principal moments (same principal axes): negative moments
    raised to 0, then the moments projected onto the plane I1 + I2 = I3 when the triangle inequality fails."""
    lam, V = np.linalg.eigh(I)
    lam = np.maximum(lam, 0.0)
    excess = lam[2] - lam[0] - lam[1]
    if excess > 0:  # orthogonal projection onto I1 + I2 - I3 = 0 along its normal (1, 1, -1)
        lam = lam + excess / 3 * np.array([1.0, 1.0, -1.0])
    return V @ np.diag(lam) @ V.T


def _moments(lam):
    return "(" + ", ".join(f"{x:.4g}" for x in lam) + ")"


def _identifier(name, what, dots=False):
    """A URDF name as a scene name: characters other than letters, digits, '_' (and '.' for coordinates)
    become '_'; a name that does not start with a letter gets the prefix 'l_'."""
    out = re.sub(r"[^A-Za-z0-9_.]" if dots else r"[^A-Za-z0-9_]", "_", name)[:limits.NAME_CHARS]
    return out if re.match(r"[A-Za-z]", out) else "l_" + out


def _tree(value, line):
    """Plain data → Map/Seq as read_yaml gives them, every node reporting `line`."""
    if isinstance(value, dict):
        out = Map({k: _tree(v, line) for k, v in value.items()})
        out.lines = dict.fromkeys(value, line)
    elif isinstance(value, list):
        out = Seq(_tree(v, line) for v in value)
        out.lines = dict.fromkeys(range(len(value)), line)
    else:
        return value
    out.line = line
    return out


class FileLine(int):
    """A line of another file than the scene's: the URDF a YAML scene includes (the checker names that file)."""


def _line(n, file):
    if file is None:
        return n
    out = FileLine(n)
    out.file = file
    return out


def _with_urdf_lines(doc, lines, damper_lines, file=None):
    """The document with each body and joint damper reporting the line of its URDF element (as a FileLine of
    `file` if given: the URDF merged into a YAML scene)."""
    tree = _tree(doc, _line(1, file))
    for name, body in doc["bodies"].items():
        line = _line(lines[name], file)
        tree["bodies"][name] = _tree(body, line)
        tree["bodies"].lines[name] = line
    for i, force in enumerate(doc.get("forces", ())):
        line = _line(damper_lines[i], file)
        tree["forces"][i] = _tree(force, line)
        tree["forces"].lines[i] = line
    return tree


def include(root, file, base, allow_outside=False, repair=False):
    """A YAML scene with `urdf: {file, package_dirs, base, repair}` → the merged document, the repairs and the
    package folders (which its mesh shapes may name).

    The URDF gives bodies (and joint dampers); the YAML adds or overrides the rest. Its `bodies:` entries are
    merged key by key into the URDF's (joint initial values, drives, shapes) or add bodies; its `forces` and
    `outputs` follow the URDF's."""
    spec = root["urdf"]
    line = root.lines.get("urdf", root.line)
    if isinstance(spec, str):
        spec = Map({"file": spec})
    if not isinstance(spec, Map) or "file" not in spec:
        raise ModelError("expected {file: robot.urdf} (optionally package_dirs, base, repair)", file=file, line=line, key="urdf")
    for k in spec:
        if k not in INCLUDE_KEYS:
            raise ModelError(f"unknown key '{k}'", file=file, line=spec.lines.get(k, line), key=f"urdf.{k}", hint=suggest(k, INCLUDE_KEYS))
    try:
        path = datafile.resolve(base, spec["file"], allow_outside)
    except ModelError as e:
        raise ModelError(e.message.replace("data file", "URDF file"), file=file, line=line, key="urdf.file", hint=e.hint) from None
    kind = spec.get("base", "fixed")
    if kind not in BASES:
        raise ModelError(f"unknown base {kind!r}", file=file, line=spec.lines.get("base", line), key="urdf.base",
                         hint="fixed (the root link held in the world) or free (a floating base)")
    repair = spec.get("repair", repair)
    if not isinstance(repair, bool):
        raise ModelError("expected true or false", file=file, line=spec.lines.get("repair", line), key="urdf.repair")
    package_dirs = package_folders(spec.get("package_dirs", []), base, file, spec.lines.get("package_dirs", line), "urdf.package_dirs")
    doc, repairs = read(path, package_dirs, kind, repair, included=True, scene_dir=base)
    merged = _merge(doc, Map({k: v for k, v in root.items() if k != "urdf"}), ("forces", "outputs"))
    if isinstance(root.get("bodies"), Map) and isinstance(merged.get("bodies"), Map):
        _overlay_replaces(merged["bodies"], root["bodies"], doc["bodies"])
    merged.lines = {**doc.lines, **{k: v for k, v in root.lines.items() if k != "urdf"}}
    merged.line = root.line
    return merged, repairs, package_dirs


INERTIAL = ("mass", "center_of_mass", "inertia")


def _overlay_replaces(bodies, overlay, urdf_bodies):
    """What an overlay replaces rather than merges key by key: a link it makes elastic loses the URDF's
    inertial (the elastic body has its own mass; the overlay's own mass, center_of_mass, inertia stay, as
    extra rigid mass on the frame), and a joint it attaches at a `node` loses the URDF origin's `at`."""
    for name, body in overlay.items():
        if name not in urdf_bodies or not isinstance(body, Map):
            continue
        if "elastic" in body:
            _drop(bodies[name], [k for k in INERTIAL if k not in body])
        joint = body.get("joint")
        if isinstance(joint, Map) and "node" in joint and "at" not in joint:
            _drop(bodies[name]["joint"], ["at"])


def _drop(node, keys):
    for k in keys:
        node.pop(k, None)
        node.lines.pop(k, None)


def package_folders(dirs, base, file, line=None, key="package_dirs"):
    """Package folders (`package://NAME/...`) relative to `base` → resolved paths. Folders the user names are
    trusted wherever they lie (a ROS layout keeps meshes/ beside urdf/); each mesh stays confined to its package."""
    if isinstance(dirs, (str, Path)) or not isinstance(dirs, (list, tuple)) or len(dirs) > 64:
        raise ModelError("expected a list of at most 64 folders", file=file, line=line, key=key)
    out = []
    for i, d in enumerate(dirs):
        try:
            folder = datafile.resolve(base, os.fspath(d) if isinstance(d, os.PathLike) else d, allow_outside=True)
        except ModelError as e:
            raise ModelError(e.message.replace("data file", "package folder"), file=file, line=line,
                             key=f"{key}[{i}]", hint="give the folder that holds the packages (NAME/ of package://NAME/...)") from None
        if not folder.is_dir():
            raise ModelError(f"the package folder '{d}' is not a folder ({folder})", file=file, line=line, key=f"{key}[{i}]",
                             hint="give the folder that holds the packages (NAME/ of package://NAME/...)")
        out.append(folder)
    return out


def _merge(a, b, appended=()):
    """b over a: mappings merged key by key, the `appended` lists concatenated, anything else replaced."""
    if not (isinstance(a, Map) and isinstance(b, Map)):
        return b
    out = Map(a)
    out.line, out.lines = a.line, dict(a.lines)
    for k, v in b.items():
        if k in appended and isinstance(a.get(k), Seq) and isinstance(v, Seq):
            s = Seq(list(a[k]) + list(v))
            s.line, s.lines = v.line, {**{i: a[k].line for i in range(len(a[k]))}, **{len(a[k]) + i: l for i, l in v.lines.items()}}
            out[k] = s
        else:
            out[k] = _merge(a[k], v) if k in a else v
        out.lines[k] = b.lines.get(k, b.line)
    return out


def to_yaml(path, base="fixed", repair=False, scene_dir=None, package_dirs=()):
    """The URDF at `path` as the text of an equivalent scene YAML to be written into `scene_dir` (default the
    URDF's folder: mesh files are named relative to it), what `mbsfmu convert` writes. package_dirs: as for
    mbsfmu.load of a URDF (relative to its folder); meshes outside `scene_dir` are not drawn (a YAML names
    files in its folder)."""
    import json

    import yaml
    doc, repairs = read(path, package_folders(package_dirs, Path(path).parent, str(path)), base, repair, scene_dir=scene_dir,
                        packages_kept=False)
    plain = json.loads(json.dumps(doc))  # Map/Seq → plain data; floats keep every digit (repr)
    head = [f"# {Path(path).name} converted by mbsfmu convert (base: {base}); joint limits and friction are not modelled"]
    head += [f"# repaired: {r}" for r in repairs]
    return "\n".join(head) + "\n" + yaml.safe_dump(plain, sort_keys=False, default_flow_style=None, width=120)

