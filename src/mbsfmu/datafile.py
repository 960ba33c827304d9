"""Nodal data files (`nodal: {file: data.npz}`): only inside the scene's folder, only the arrays a scene uses,
sizes checked in the zip directory and the .npy headers before a byte is decompressed; never unpickled."""

import os
import tokenize
import zipfile
from pathlib import Path

import numpy as np
from numpy.lib import format as npy

from .errors import ModelError
from . import limits

NODAL_ARRAYS = ("R_RP", "mass", "Phi", "Psi", "inertia", "stiffness", "damping")


def resolve(base, name, allow_outside=False):
    """The data file `name` relative to the scene's folder `base`, symlinks resolved; outside it only if allowed."""
    if not isinstance(name, str) or not name:
        raise ModelError("expected a file name (a path relative to the scene's folder)", hint="e.g. file: plate.npz")
    try:
        base = Path(base).resolve()
        path = (base / name).resolve()
    except (OSError, RuntimeError) as e:  # a symlink loop (RuntimeError before Python 3.13), a name too long
        raise ModelError(f"cannot resolve the data file '{name}': {getattr(e, 'strerror', None) or e}",
                         hint="give the path of a regular .npz file next to the scene") from None
    if not allow_outside and not path.is_relative_to(base):
        raise ModelError(f"the data file '{name}' lies outside the scene's folder {base}",
                         hint="move it next to the scene, or allow other folders explicitly "
                              "(mbsfmu.load(..., allow_outside=True), command line --allow-outside)")
    return path


def read_npz(path, names=NODAL_ARRAYS):
    """{name: array} for the members of `names` present in the .npz; other members are never read."""
    try:
        with limits.open_regular(path) as f:
            if os.fstat(f.fileno()).st_size > limits.NPZ_BYTES:
                raise ModelError(f"the data file is larger than {limits.NPZ_BYTES // 2**20} MiB", hint="keep only the modes and nodes the model needs")
            z = zipfile.ZipFile(f)
            infos = z.infolist()
            if len(infos) > limits.NPZ_ENTRIES:
                raise ModelError(f"the data file has {len(infos)} members (at most {limits.NPZ_ENTRIES})", hint="an .npz of nodal data holds R_RP, mass, Phi, stiffness (and Psi, inertia, damping)")
            members = {i.filename[:-4]: i for i in infos if i.filename.endswith(".npy")}
            if len(members) != sum(i.filename.endswith(".npy") for i in infos):  # which of two 'mass.npy' is meant?
                raise ModelError("the data file holds two members of the same name", hint="write it again with numpy.savez")
            wanted = [members[n] for n in names if n in members]
            total = sum(i.file_size for i in wanted)
            if total > limits.NPZ_BYTES:
                raise ModelError(f"the arrays unpack to {total:,} bytes (at most {limits.NPZ_BYTES:,})", hint="a zip bomb? keep only the modes and nodes the model needs")
            return {i.filename[:-4]: _array(z, i) for i in wanted}
    except ModelError:
        raise
    except zipfile.BadZipFile:
        raise ModelError("not an .npz file (a zip archive of .npy arrays, as numpy.savez writes)", hint="write it with numpy.savez") from None
    except (OSError, ValueError, EOFError, NotImplementedError, RuntimeError, SyntaxError, tokenize.TokenError) as e:
        # unreadable, corrupt, encrypted; a header numpy's literal parser cannot read (it is parsed, never executed)
        raise ModelError(f"cannot read the data file: {type(e).__name__}: {e}",
                         hint="write the file with numpy.savez (plain float arrays, no pickled objects)") from None


def _array(z, info):
    """One .npy member: plain numbers only; its header's size must match the zip directory's."""
    name = info.filename[:-4]
    with z.open(info) as f:
        version = npy.read_magic(f)
        header = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
        shape, fortran, dtype = header(f, max_header_size=10_000)
        if dtype.kind not in "fiu" or dtype.fields is not None or dtype.subdtype is not None:
            raise ModelError(f"array '{name}' holds {dtype} values; nodal data are plain numbers", hint="save float64 arrays")
        if any(d < 0 for d in shape):
            raise ModelError(f"array '{name}' has the shape {shape}", hint="write the file with numpy.savez")
        nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
        if nbytes > info.file_size:
            raise ModelError(f"array '{name}' claims {nbytes:,} bytes in a member of {info.file_size:,}", hint="the file is corrupt or forged; write it again with numpy.savez")
        data = f.read(nbytes)
    if len(data) != nbytes:
        raise ModelError(f"array '{name}' is truncated", hint="write the file again with numpy.savez")
    return np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C").astype(float)
