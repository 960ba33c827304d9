"""Mesh files for `shape: {type: mesh}` → triangle corner positions (T × 3 × 3, float32).

STL (binary or ASCII), OBJ (`v` and `f` lines; polygons split into fans) and COLLADA (.dae: screened by
defusedxml, then read by pycollada; see _dae). Read as data only; the work and
memory are bounded by counts (limits.MESH_TRIANGLES, MESH_VERTICES) checked as the file is read, before
anything is expanded: a polygon's triangles are counted before its fan is built, a binary STL's header count is
held against the file's size. Any problem is a ModelError naming the file.
"""

import io
import re
import struct
import warnings
from array import array
from pathlib import Path

import numpy as np

from ..errors import ModelError
from .. import limits

_SPACE = bytes.maketrans(b"\t\r\v\f", b"    ")  # OBJ and ASCII STL separate fields by any blank: a space
_CHUNK = 1 << 16                                # tokens converted to numbers at a time (bounded lists)
NUMBER_CHARS = 64                               # one coordinate or index


class _Limit(ValueError):
    """A count over its limit: the message names the limit."""


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
            tris = _obj(data)
        elif path.suffix.lower() == ".dae":
            tris = _dae(data)
        elif _is_binary_stl(data):
            tris = _binary_stl(data)
        else:
            tris = _ascii_stl(data)
    except _Limit as e:
        raise ModelError(f"the mesh has {e}", file=str(path), hint="simplify the mesh") from None
    except (ValueError, IndexError, OverflowError, struct.error) as e:
        raise ModelError(f"cannot read mesh: {e}", file=str(path)) from None
    if not len(tris):
        raise ModelError("the mesh has no triangles", file=str(path))
    if not np.isfinite(tris).all():
        raise ModelError("the mesh has non-finite coordinates", file=str(path))
    return tris.astype(np.float32)


def _dae(data):
    """Every geometry instanced in the COLLADA scene, node transforms applied (pycollada's bound primitives),
    in metres (<unit meter>) with z up (<up_axis>). Triangles and vertices are counted instance by instance
    before each is expanded: nested <instance_node>s can repeat one geometry exponentially often."""
    import collada
    from defusedxml import ElementTree as safe_xml
    try:  # no DTD at all: neither entity bombs nor external entities reach pycollada's parser (lxml)
        safe_xml.fromstring(data, forbid_dtd=True, forbid_entities=True, forbid_external=True)
    except safe_xml.ParseError as e:
        raise ValueError(f"not XML: {e}") from None
    except ValueError as e:  # defusedxml's DTDForbidden, EntitiesForbidden, ExternalReferenceForbidden
        raise ValueError(f"refused XML: {e}") from None
    try:
        doc = collada.Collada(io.BytesIO(data), aux_file_loader=_no_aux_files)
    except (collada.DaeError, KeyError, TypeError, AttributeError) as e:  # pycollada's own checks, and what it trips on
        raise ValueError(f"not COLLADA: {str(e)[:200]}") from None
    except RecursionError:
        raise ValueError("the COLLADA nodes are nested too deeply") from None
    if doc.scene is None:
        raise ValueError("the COLLADA file has no <scene>")
    with warnings.catch_warnings():  # pycollada's numpy.matrix warns once per instance
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        try:
            tris = _bound_triangles(collada, doc.scene)
        except RecursionError:
            raise ValueError("the COLLADA nodes are nested too deeply") from None
    return tris @ _UP_TO_Z[doc.assetInfo.upaxis].T * float(doc.assetInfo.unitmeter or 1.0)


def _bound_triangles(collada, scene):
    """The triangles (T × 3 × 3) of every geometry instance in the scene graph, counted before each is built."""
    parts, n_tri, n_vert = [], 0, 0
    for n_inst, geometry in enumerate(scene.objects("geometry"), 1):
        _count(n_inst, limits.MESH_INSTANCES, "geometry instances")  # empty ones too: binding each is work
        for prim in geometry.primitives():
            if isinstance(prim, collada.polylist.BoundPolylist):  # polylists and polygons: fans
                sizes = np.diff(np.asarray(prim.polyindex).reshape(-1, 2), axis=1).ravel()
                n_tri += int(np.maximum(sizes - 2, 0).sum())
            elif isinstance(prim, collada.triangleset.BoundTriangleSet):
                n_tri += len(prim.vertex_index) if prim.vertex_index is not None else 0
            else:
                continue  # lines: nothing to draw as a surface
            n_vert += 0 if prim.vertex is None else len(prim.vertex)
            _count(n_tri, limits.MESH_TRIANGLES, "triangles")
            _count(n_vert, limits.MESH_VERTICES, "vertices")
            if isinstance(prim, collada.polylist.BoundPolylist):
                prim = prim.triangleset()
            if prim.vertex is not None and prim.vertex_index is not None and len(prim.vertex_index):
                parts.append(np.asarray(prim.vertex, dtype=float)[np.asarray(prim.vertex_index)])
    return np.concatenate(parts) if parts else np.zeros((0, 3, 3))


_UP_TO_Z = {  # COLLADA <up_axis> → the rotation taking that axis to +z (right-handed)
    "Z_UP": np.eye(3),
    "Y_UP": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),   # (x, y, z) → (x, -z, y)
    "X_UP": np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]]),   # (x, y, z) → (-z, y, x)
}


def _no_aux_files(name):
    """pycollada asks for files a COLLADA document names (textures): a drawing needs none, none are opened."""
    return None


def _count(n, limit, what):
    if n > limit:
        raise _Limit(f"more than {limit:,} {what}, the limit for drawing")


def _is_binary_stl(data):
    """An ASCII STL starts with 'solid', but so do some binary headers: a binary file's size is its header's
    count × 50 + 84 bytes; any other file that does not start with 'solid' is a binary one too (a broken one)."""
    if len(data) >= 84 and len(data) == 84 + 50 * struct.unpack_from("<I", data, 80)[0]:
        return True
    return data.lstrip()[:5].lower() != b"solid"


def _binary_stl(data):
    if len(data) < 84:
        raise ValueError(f"{len(data)} bytes: shorter than a binary STL header (84 bytes)")
    n = struct.unpack_from("<I", data, 80)[0]
    _count(n, limits.MESH_TRIANGLES, "triangles")  # the header's word, before anything is allocated
    if len(data) != 84 + 50 * n:
        raise ValueError(f"the binary STL header counts {n} triangles ({84 + 50 * n} bytes), "
                         f"but the file has {len(data)} bytes")
    rec = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")]), count=n, offset=84)
    return rec["v"].astype(float)


def _ascii_stl(data):
    """The three numbers of every 'vertex' line, three lines a triangle."""
    text = data.translate(_SPACE)
    for counts in _keyword_counts(text, [b"vertex"]):
        _count(counts[b"vertex"][0] // 3, limits.MESH_TRIANGLES, "triangles")
    xyz = _Numbers(float)
    for line in io.BytesIO(text):
        parts = line.split(None, 4)
        if parts and parts[0] == b"vertex":
            if len(parts) < 4:
                raise ValueError(f"a 'vertex' line needs three numbers: {line.strip()[:80]!r}")
            xyz.add(parts[1:4])
    if len(xyz) % 9:
        raise ValueError("the number of 'vertex' lines is not a multiple of 3")
    return xyz.array().reshape(-1, 3, 3)


_SLASH = re.compile(rb"/\S*")  # 'f 1/4/7 2//8': the vertex index is the part before the first slash


def _obj(data):
    """'v x y z' and 'f i j k …' lines (1-based indices, negative ones count back); each polygon becomes the
    fan (i, j, k), (i, k, l), …; vertices and triangles are counted before any line is parsed."""
    text = data.translate(_SPACE)
    for counts in _keyword_counts(text, [b"v", b"f"]):
        _count(counts[b"v"][0], limits.MESH_VERTICES, "vertices")
        faces, corners = counts[b"f"]
        _count(corners - 2 * faces, limits.MESH_TRIANGLES, "triangles")  # a polygon of k corners: k - 2 triangles
    xyz, corners, sizes = _Numbers(float), _Numbers(int), array("q")
    for line in io.BytesIO(text):
        head = line.lstrip()[:2]
        if head == b"v ":
            parts = line.split(None, 4)
            if len(parts) < 4:
                raise ValueError(f"a 'v' line needs three numbers: {line.strip()[:80]!r}")
            xyz.add(parts[1:4])
        elif head == b"f ":
            parts = _SLASH.sub(b"", line).split()
            if len(parts) < 4:
                raise ValueError(f"a face needs three vertices: {line.strip()[:80]!r}")
            corners.add(parts[1:])
            sizes.append(len(parts) - 1)
    V = xyz.array().reshape(-1, 3)
    I = _fans(corners.array().astype(np.int64), np.frombuffer(sizes, dtype=np.int64) if sizes else np.zeros(0, np.int64))
    I = np.where(I < 0, len(V) + I, I - 1)  # OBJ indices start at 1; negative ones count back
    if I.size and (I.min() < 0 or I.max() >= len(V)):
        raise ValueError("a face refers to a vertex that does not exist")
    return V[I]


def _keyword_counts(text, keywords, chunk=1 << 22):
    """Yield {keyword: [lines whose first field it is, their fields after it in all]} so far, after each few MB
    (counted with numpy: no line is split, memory stays bounded, a line of millions of fields included), so that
    a count over its limit stops the reading there, before anything is parsed. Blanks are spaces (_SPACE)."""
    counts = {k: [0, 0] for k in keywords}
    start, n = 0, len(text)
    while start < n:
        end = text.find(b"\n", min(start + chunk, n))
        end = n if end < 0 else end + 1
        if end - start > 2 * chunk:  # a long line crosses start + chunk: the lines before it, then the line alone
            line_start = max(start, text.rfind(b"\n", start, start + chunk) + 1)
            _count_lines(text, start, line_start, counts)
            _count_long_line(text, line_start, end, counts, chunk)
        else:
            _count_lines(text, start, end, counts)
        start = end
        yield counts


def _field_starts(arr, blank_before=True):
    blank = (arr == ord(" ")) | (arr == ord("\n"))
    return blank, ~blank & np.concatenate([[blank_before], blank[:-1]])


def _count_lines(text, start, end, counts):
    """Add the keyword lines of text[start:end] (whole lines) to counts."""
    if end <= start:
        return
    arr = np.frombuffer(text, dtype=np.uint8, count=end - start, offset=start)
    blank, first = _field_starts(arr)
    at = np.flatnonzero(first)
    line = np.searchsorted(np.flatnonzero(arr == ord("\n")), at)  # the line of each field
    lead = np.concatenate([[True], line[1:] != line[:-1]])[:len(at)]  # a line's first field
    n_fields = np.diff(np.append(np.flatnonzero(lead), len(at)))  # fields per non-empty line
    for k, c in counts.items():
        hit = np.ones(len(n_fields), dtype=bool)
        for i, byte in enumerate(k):  # the first field is exactly the keyword
            pos = at[lead] + i
            hit &= (pos < len(arr)) & (arr[np.minimum(pos, len(arr) - 1)] == byte)
        after = at[lead] + len(k)
        hit &= (after >= len(arr)) | blank[np.minimum(after, len(arr) - 1)]
        c[0] += int(hit.sum())
        c[1] += int((n_fields[hit] - 1).sum())


def _count_long_line(text, start, end, counts, chunk):
    """Add one line text[start:end], too long for _count_lines' per-field arrays, to counts."""
    head = text[start:start + 64].split(None, 1)
    c = counts.get(head[0] if head else b"")
    if c is None:
        return
    fields, blank_before = 0, True
    for a in range(start, end, chunk):
        arr = np.frombuffer(text, dtype=np.uint8, count=min(chunk, end - a), offset=a)
        blank, first = _field_starts(arr, blank_before)
        fields += int(np.count_nonzero(first))
        blank_before = bool(blank[-1])
    c[0] += 1
    c[1] += fields - 1


def _fans(corners, sizes):
    """Polygons (their corner indices one after another, `sizes` corners each) → triangles (T × 3)."""
    n_tri = sizes - 2
    first = np.cumsum(sizes) - sizes                       # where each polygon's corners start
    face = np.repeat(np.arange(len(sizes)), n_tri)         # the polygon of each triangle
    k = np.arange(len(face)) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)  # its number within the polygon
    base = first[face]
    return np.stack([corners[base], corners[base + k + 1], corners[base + k + 2]], axis=1)


class _Numbers:
    """Number tokens (bytes) collected into a compact array, converted in chunks (bounded lists)."""

    def __init__(self, kind):
        self.kind, self.done, self.pending, self.n = kind, [], [], 0

    def add(self, tokens):
        self.pending += tokens
        self.n += len(tokens)
        if len(self.pending) >= _CHUNK:
            self._flush()

    def _flush(self):
        longest = max(map(len, self.pending), default=0)
        if longest > NUMBER_CHARS:  # numpy would size every entry like the longest one
            raise ValueError(f"a number of {longest} characters (at most {NUMBER_CHARS})")
        if self.pending:
            self.done.append(np.array(self.pending).astype(np.float64 if self.kind is float else np.int64))
            self.pending = []

    def __len__(self):
        return self.n

    def array(self):
        self._flush()
        return np.concatenate(self.done) if self.done else np.zeros(0)
