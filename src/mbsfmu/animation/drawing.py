"""What each body looks like (in its own frame), the scene's size and the initial camera, for the page.

Without `shape:` a body is drawn as links from its joint frame (the body origin) to the points that matter
on it (its children's joint frames, output points, spring ends; else its centre of mass) and a marker at
its centre of mass whose volume grows with the mass. Elastic bodies are drawn through their nodes.
"""

import math

import numpy as np

from ..expr import parse
from ..compiler.model import initial_rotation
from ..kinematics.rotations import matrix_to_quat
from ..scene.shapes import mesh_path
from .mesh import read_mesh

PALETTE = ("#4878cf", "#d65f5f", "#6acc65", "#b47cc7", "#c4ad66", "#77bedb", "#e08a3c", "#8c8c8c")
FOV = 40.0  # vertical field of view of the initial camera, degrees
MARKER = 0.04  # radius of the heaviest body's centre-of-mass marker, relative to the scene size


def _vec(v, env):
    return [parse(x)(env) for x in v]


def link_points(model, i):
    """Points in body i's frame that its links run to (from the origin, the joint frame)."""
    b = model.bodies[i]
    pts = [c.at if c.at is not None else np.zeros(3) for c in model.bodies if c.parent == i and c.node is None]
    pts += [_vec(o["point"], model.env) for o in model.outputs if o["body"] == b.name and o.get("node") is None]
    for f in model.bound_forces:
        if f["type"] == "spring_damper":
            pts += [at for k, at, node in zip(f["body_index"], f["at"], f["node"]) if k == i and node is None]
    pts = [np.asarray(p, dtype=float) for p in pts]
    if not any(np.any(p) for p in pts) and b.c is not None:
        pts.append(b.c)
    out = []
    for p in pts:
        if np.any(p) and not any(np.allclose(p, q) for q in out):
            out.append(p)
    return out


def mesh_files(spec):
    """The mesh files the shapes of a scene name (relative to its folder)."""
    return [s["file"] for b in spec["bodies"] for s in b.get("shape") or () if s.get("type") == "mesh"]


def shapes(model, i, base, package_dirs=()):
    """Body i's `shape:` entries with numbers evaluated, rotations as quaternions (x, y, z, w), meshes read
    (relative to `base`, or package:// ones in package_dirs)."""
    env, out = model.env, []
    for s in model.bodies[i].spec.get("shape") or ():
        g = {"type": s["type"], "at": _vec(s["at"], env), "color": s["color"], "opacity": s["opacity"]}
        p = matrix_to_quat(initial_rotation(s["rotation"], env))  # the joints' rotation format (identity if None)
        g["quaternion"] = [p[1], p[2], p[3], p[0]]
        for k in ("size", "radius", "length"):
            if k in s:
                g[k] = _vec(s[k], env) if k == "size" else parse(s[k])(env)
        if s["type"] == "mesh":
            f = mesh_path(base, s["file"], package_dirs)  # confined again: specs from FMUs are foreign data
            scale = np.array(_vec(s["scale"], env), dtype=np.float32)
            g["triangles"] = read_mesh(f) * scale
            if np.prod(np.sign(scale)) < 0:  # a mirror image: the corners' order turned, so faces still face out
                g["triangles"] = g["triangles"][:, ::-1].copy()
            g["file"] = s["file"]
        out.append(g)
    return out


def _extent(g):
    """Radius of a sphere around a shape's placement point that holds the shape."""
    if g["type"] == "box":
        return 0.5 * float(np.linalg.norm(g["size"]))
    if g["type"] == "mesh":
        return float(np.abs(g["triangles"]).max())
    return g["radius"] + 0.5 * g.get("length", 0.0)


def describe(model, layout, F, base, package_dirs=()):
    """Static description of the scene for the page (JSON-able apart from mesh arrays), with sizes
    from the bounding box of everything drawn over all frames."""
    nb = len(model.bodies)
    bodies, pts, pad = [], [], 0.0
    for i, b in enumerate(model.bodies):
        o, q = F[:, 7 * i:7 * i + 3], F[:, 7 * i + 3:7 * i + 7]
        links = [] if b.elastic else link_points(model, i)
        sh = shapes(model, i, base, package_dirs)
        local = links + [np.asarray(g["at"]) for g in sh] + ([b.c] if b.c is not None else [])
        pts.append(o)
        for p in local:
            pts.append(o + _rotate(q, p))
        pad = max([pad] + [_extent(g) for g in sh])
        bodies.append({"name": b.name, "parent": b.parent, "mass": 0.0 if b.elastic else float(b.m),
                       "com": list(b.c) if b.c is not None else [0.0] * 3, "links": [list(p) for p in links],
                       "shapes": sh, "color": PALETTE[i % len(PALETTE)]})
    pts += [F[:, 7 * nb:].reshape(-1, 3), np.zeros((1, 3))]  # nodes, spring ends and the world frame
    P = np.concatenate(pts)
    lo, hi = P.min(axis=0) - pad, P.max(axis=0) + pad
    size = max(float(np.linalg.norm(hi - lo)), 0.2)  # a lone point still gets a visible scene
    m_max = max([b["mass"] for b in bodies] + [1e-300])
    for b in bodies:
        b["marker"] = MARKER * size * (b["mass"] / m_max) ** (1 / 3) if b["mass"] > 0 else 0.0
    lo, hi = lo - MARKER * size, hi + MARKER * size
    g = model.g if model.g is not None else np.zeros(3)
    return {"bodies": bodies, "size": size, "gravity": list(g), "camera": camera(0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo)), g),
            "elastic": [{"body": i, "nodes": n} for i, n in zip(layout.elastic, layout.nodes)],
            "springs": len(layout.springs)}


def _rotate(q, p):
    """Rotate body-frame point p by quaternions q (rows x, y, z, w) → world offsets."""
    v, w = q[:, :3], q[:, 3:]
    t = 2.0 * np.cross(v, p)
    return p + w * t + np.cross(v, t)


def camera(target, radius, g):
    """Initial camera: up against gravity (z without gravity), looking from the −y side, slightly from +x
    and above, far enough for a sphere of `radius` around `target` to fit the vertical field of view."""
    up = -g / np.linalg.norm(g) if np.any(g) else np.array([0.0, 0.0, 1.0])
    e1 = np.array([1.0, 0.0, 0.0]) - up[0] * up
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.array([0.0, 1.0, 0.0]) - up[1] * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    view = 0.35 * e1 - e2 + 0.3 * up
    dist = 1.25 * radius / math.sin(math.radians(FOV / 2))
    pos = target + dist * view / np.linalg.norm(view)
    return {"position": list(pos), "target": list(target), "up": list(up), "fov": FOV, "near": dist / 100, "far": dist * 100}
