"""Nodal data files (`nodal: {file: data.npz}`): only inside the scene's folder, only the arrays a scene uses,
sizes checked in the zip directory and the .npy headers before a byte is decompressed; never unpickled."""

import os
import zipfile
from pathlib import Path

import numpy as np
from numpy.lib import format as npy

from ..errors import ModelError
from . import limits

NODAL_ARRAYS = ("R_RP", "mass", "Phi", "Psi", "inertia", "stiffness", "damping")


def resolve(base, name, allow_outside=False):
    """The data file `name` relative to the scene's folder `base`, symlinks resolved; outside it only if allowed."""
    if not isinstance(name, str) or not name:
        raise ModelError("expected a file name (a path relative to the scene's folder)")
    base = Path(base).resolve()
    path = (base / name).resolve()
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
                raise ModelError(f"the data file is larger than {limits.NPZ_BYTES // 2**20} MiB")
            z = zipfile.ZipFile(f)
            infos = z.infolist()
            if len(infos) > limits.NPZ_ENTRIES:
                raise ModelError(f"the data file has {len(infos)} members (at most {limits.NPZ_ENTRIES})")
            members = {i.filename[:-4]: i for i in infos if i.filename.endswith(".npy")}
            wanted = [members[n] for n in names if n in members]
            total = sum(i.file_size for i in wanted)
            if total > limits.NPZ_BYTES:
                raise ModelError(f"the arrays unpack to {total:,} bytes (at most {limits.NPZ_BYTES:,})")
            return {i.filename[:-4]: _array(z, i) for i in wanted}
    except ModelError:
        raise
    except zipfile.BadZipFile:
        raise ModelError("not an .npz file (a zip archive of .npy arrays, as numpy.savez writes)") from None
    except (OSError, ValueError, EOFError, NotImplementedError, RuntimeError) as e:  # unreadable, corrupt, encrypted
        raise ModelError(f"cannot read the data file: {type(e).__name__}: {e}") from None


def _array(z, info):
    """One .npy member: plain numbers only; its header's size must match the zip directory's."""
    name = info.filename[:-4]
    with z.open(info) as f:
        version = npy.read_magic(f)
        header = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
        shape, fortran, dtype = header(f, max_header_size=10_000)
        if dtype.kind not in "fiu" or dtype.fields is not None or dtype.subdtype is not None:
            raise ModelError(f"array '{name}' holds {dtype} values; nodal data are plain numbers")
        nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
        if nbytes > info.file_size:
            raise ModelError(f"array '{name}' claims {nbytes:,} bytes in a member of {info.file_size:,}")
        data = f.read(nbytes)
    if len(data) != nbytes:
        raise ModelError(f"array '{name}' is truncated")
    return np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C").astype(float)
