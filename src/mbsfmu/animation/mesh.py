"""Mesh files for `shape: {type: mesh}` → triangle corner positions (T × 3 × 3, float32).

STL (binary or ASCII) and OBJ (`v` and `f` lines; polygons split into fans). Read as data only, with the
number of triangles bounded; any problem is a ModelError naming the file.
"""

import struct
from pathlib import Path

import numpy as np

from ..errors import ModelError
from ..scene import limits

MAX_TRIANGLES = 2_000_000


def read_mesh(path):
    path = Path(path)
    try:
        with limits.open_regular(path) as f:  # not a FIFO or device: nothing waits or reads forever
            data = f.read(limits.MESH_BYTES + 1)  # the file may have grown since the scene was loaded
    except OSError as e:
        raise ModelError(f"cannot read mesh file: {e.strerror}", file=str(path)) from None
    if len(data) > limits.MESH_BYTES:
        raise ModelError(f"the mesh file is larger than {limits.MESH_BYTES // 2**20} MB", file=str(path))
    try:
        if path.suffix.lower() == ".obj":
            tris = _obj(data.decode("utf-8", errors="replace"))
        elif _is_binary_stl(data):
            tris = _binary_stl(data)
        else:
            tris = _ascii_stl(data.decode("utf-8", errors="replace"))
    except (ValueError, IndexError, struct.error) as e:
        raise ModelError(f"cannot read mesh: {e}", file=str(path)) from None
    if not len(tris):
        raise ModelError("the mesh has no triangles", file=str(path))
    if not np.isfinite(tris).all():
        raise ModelError("the mesh has non-finite coordinates", file=str(path))
    return tris.astype(np.float32)


def _is_binary_stl(data):
    # an ASCII STL starts with 'solid', but so do some binary headers: the size decides
    return len(data) >= 84 and len(data) == 84 + 50 * struct.unpack_from("<I", data, 80)[0]


def _binary_stl(data):
    n = struct.unpack_from("<I", data, 80)[0]
    if n > MAX_TRIANGLES:
        raise ValueError(f"{n} triangles (at most {MAX_TRIANGLES})")
    rec = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")]), count=n, offset=84)
    return rec["v"].astype(float)


def _ascii_stl(text):
    v = [line.split()[1:4] for line in text.splitlines() if line.lstrip().startswith("vertex")]
    if len(v) % 3:
        raise ValueError("the number of 'vertex' lines is not a multiple of 3")
    if len(v) > 3 * MAX_TRIANGLES:
        raise ValueError(f"more than {MAX_TRIANGLES} triangles")
    return np.array(v, dtype=float).reshape(-1, 3, 3)


def _obj(text):
    verts, faces = [], []
    for line in text.splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            verts.append(parts[1:4])
        elif parts[0] == "f":
            idx = [int(p.split("/")[0]) for p in parts[1:]]
            faces += [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]  # fan
            if len(faces) > MAX_TRIANGLES:
                raise ValueError(f"more than {MAX_TRIANGLES} triangles")
    V = np.array(verts, dtype=float).reshape(-1, 3)
    I = np.array(faces, dtype=int).reshape(-1, 3)
    I = np.where(I < 0, len(V) + I, I - 1)  # OBJ indices start at 1; negative ones count back
    if I.size and (I.min() < 0 or I.max() >= len(V)):
        raise ValueError("a face refers to a vertex that does not exist")
    return V[I]
