"""Mesh files of `shape: {type: mesh}` (issue 22): work and memory bounded by counts of triangles and vertices
checked as the file is read, before anything is expanded. Hostile files (a polygon fanning into 3e7
triangles, millions of faces or vertices, a binary STL header that lies) are refused with one message naming
the limit, within two seconds of CPU (0.6 s measured on a developer machine, 1.0 s on CI; expanding the fan
would take minutes and gigabytes) under a 1 GiB address-space limit; below the limits the counts are exact
(a polygon of k corners is k - 2 triangles, whatever the blanks)."""
from __future__ import annotations

import json
import random
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import mbsfmu
from mbsfmu.animation import mesh
from mbsfmu import limits

REPO = Path(__file__).resolve().parents[1]
GiB = 2**30

CHILD = """
import json, resource, sys, time
resource.setrlimit(resource.RLIMIT_AS, ({memory}, {memory}))
from mbsfmu.animation.mesh import read_mesh
out = {{}}
for path in sys.argv[1:]:
    t = time.process_time()
    try:
        out[path] = {{"triangles": len(read_mesh(path))}}
    except BaseException as e:
        out[path] = {{"error": type(e).__name__, "message": str(e)}}
    out[path]["cpu"] = time.process_time() - t
print(json.dumps(out))
"""


def hostile(tmp_path):
    """{name: (file, what the refusal names)}: each far over a limit, within the 64 MB a mesh file may have."""
    T, V = limits.MESH_TRIANGLES, limits.MESH_VERTICES
    tri = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"
    files = {
        "fan.obj": (tri + b"f " + b"1 " * 30_000_000 + b"\n", f"more than {T:,} triangles"),  # the file
        "fan_after_vertices.obj": (b"v 0.5 0.25 0.125\n" * (V - 1) + b"f " + b"1\t" * 10_000_000,
                                   f"more than {T:,} triangles"),
        "faces.obj": (tri + b"f 1 2 3\r\n" * (T + 1), f"more than {T:,} triangles"),
        "quads.obj": (tri + b"  f  1 2  3 1\n" * (T // 2 + 1), f"more than {T:,} triangles"),
        "vertices.obj": (b"v 0 0 0\n" * (V + 1), f"more than {V:,} vertices"),
        "header.stl": (b"\0" * 80 + struct.pack("<I", 30_000_000) + b"\0" * 500, f"more than {T:,} triangles"),
        "long_number.obj": (b"v " + b"1" * 50_000_000 + b" 0 0\nf 1 1 1\n", "a number of 50000000 characters"),
    }
    for name, (data, _) in files.items():
        (tmp_path / name).write_bytes(data)
    return {name: (tmp_path / name, words) for name, (_, words) in files.items()}


def test_hostile_meshes_are_refused_within_seconds_and_1_gib(tmp_path):
    cases = hostile(tmp_path)
    r = subprocess.run([sys.executable, "-c", CHILD.format(memory=GiB), *map(str, (p for p, _ in cases.values()))],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout)
    for name, (path, words) in cases.items():
        res = out[str(path)]
        assert res.get("error") == "ModelError" and words in res["message"] and name in res["message"], (name, res)
        assert res["cpu"] < 2.0, (name, res)


def test_animate_of_a_fan_of_3e7_triangles_is_one_line(tmp_path):
    scene = tmp_path / "pendulum.yaml"
    text = (REPO / "models" / "pendulum.yaml").read_text()
    scene.write_text(text.replace("\n  bob:\n", "\n  bob:\n    shape: {type: mesh, file: fan.obj}\n", 1))
    (tmp_path / "fan.obj").write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf " + b"1 " * 30_000_000 + b"\n")
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "mbsfmu.cli", "animate", str(scene), "-o", str(tmp_path / "a.html")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"more than {limits.MESH_TRIANGLES:,} triangles" in r.stderr and "fan.obj" in r.stderr, r.stderr
    assert time.perf_counter() - t < 30 and not (tmp_path / "a.html").exists()


def _fan(corners):
    """The reference: polygon (c0, c1, …) → triangles (c0, c1, c2), (c0, c2, c3), …"""
    return [(corners[0], corners[k], corners[k + 1]) for k in range(1, len(corners) - 1)]


BLANKS = [" ", "  ", "\t", " \t ", "\v"]


def _obj_text(rng, n_vertices, polygons):
    """An OBJ file with the given polygons (0-based corner lists), random blanks, leading blanks, CRLF, vt/vn/
    comment lines and 'i/j/k' corners."""
    b = lambda: rng.choice(BLANKS)  # noqa: E731
    lines = ["# made by the test", "o thing"]
    for i in range(n_vertices):
        lines.append(f"{rng.choice(['', ' ', chr(9)])}v{b()}{i}{b()}{i / 2}{b()}{-i}{rng.choice(['', ' 1.0'])}")
        lines.append(f"vt{b()}0.5{b()}0.5")
    for p in polygons:
        corners = [f"{c + 1}" if rng.random() < 0.5 else f"{c + 1}/{c + 1}/{c + 1}" for c in p]
        lines.append(f"{rng.choice(['', ' '])}f{b()}" + b().join(corners) + rng.choice(["", " ", "\t"]))
    return rng.choice(["\n", "\r\n"]).join(lines) + rng.choice(["", "\n"])


@pytest.mark.parametrize("seed", range(8))
def test_counts_are_exact_at_the_limits(tmp_path, monkeypatch, seed):
    """Random OBJ text: the triangles read are the fans of the polygons (reference _fan), and the limits hold
    exactly: a mesh of exactly the limit's triangles and vertices is read, one more of either is refused."""
    rng = random.Random(seed)
    n = rng.randint(3, 40)
    polygons = [[rng.randrange(n) for _ in range(rng.randint(3, 30))] for _ in range(rng.randint(1, 20))]
    want = np.array([[(c, c / 2, -c) for c in t] for p in polygons for t in _fan(p)], dtype=np.float32)
    path = tmp_path / "m.obj"
    path.write_text(_obj_text(rng, n, polygons))
    monkeypatch.setattr(limits, "MESH_TRIANGLES", len(want))
    monkeypatch.setattr(limits, "MESH_VERTICES", n)
    assert np.array_equal(mesh.read_mesh(path), want)
    for name, value in (("MESH_TRIANGLES", len(want) - 1), ("MESH_VERTICES", n - 1)):
        with monkeypatch.context() as m:
            m.setattr(limits, name, value)
            what = "triangles" if name == "MESH_TRIANGLES" else "vertices"
            with pytest.raises(mbsfmu.ModelError, match=f"more than {value:,} {what}"):
                mesh.read_mesh(path)


def test_stl_triangle_counts(tmp_path, monkeypatch):
    """ASCII STL: three 'vertex' lines a triangle, refused above the limit; binary STL: the header's count
    must match the file's size."""
    tri = "facet normal 0 0 1\n outer loop\n  vertex 0 0 0\n\tvertex 1 0 0\n   vertex 0 1 0\n endloop\nendfacet\n"
    ascii_ = tmp_path / "a.stl"
    ascii_.write_text("solid a\n" + tri * 5 + "endsolid a\n")
    monkeypatch.setattr(limits, "MESH_TRIANGLES", 5)
    assert mesh.read_mesh(ascii_).shape == (5, 3, 3)
    monkeypatch.setattr(limits, "MESH_TRIANGLES", 4)
    with pytest.raises(mbsfmu.ModelError, match="more than 4 triangles"):
        mesh.read_mesh(ascii_)
    monkeypatch.undo()
    body = b"".join(struct.pack("<12fH", *[0.0] * 12, 0) for _ in range(4))
    short = tmp_path / "b.stl"
    short.write_bytes(b"binary".ljust(80, b"\0") + struct.pack("<I", 5) + body)
    with pytest.raises(mbsfmu.ModelError, match=r"header counts 5 triangles \(334 bytes\).* 284 bytes"):
        mesh.read_mesh(short)


@pytest.mark.parametrize("text, words", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", "cannot read mesh"),  # past int64
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -99999999999999999\n", "vertex that does not exist"),
    ("v 1e400 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "non-finite"),
    ("v 0 0 0\nf 1 2\n", "three vertices"),
    ("v 0 0\n", "three numbers"),
])
def test_malformed_obj_is_a_model_error(tmp_path, text, words):
    path = tmp_path / "w.obj"
    path.write_text(text)
    with pytest.raises(mbsfmu.ModelError, match=words):
        mesh.read_mesh(path)
