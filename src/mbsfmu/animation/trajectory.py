"""Where a motion comes from: an in-process run of a scene, an FMU run through fmpy, or a result CSV
(`mbsfmu simulate --csv`). Each gives the scene spec, the folder shape files are read from, and t, Y, ẏ."""

import json
import zipfile
from pathlib import Path

import numpy as np

from ..csvfile import read_csv
from ..inputs import InputTable


def from_scene(spec, stop=None, input_csv=None):
    """Run a scene in process; each row of the input CSV held until the next (mbsfmu.inputs)."""
    from ..simulation import simulate
    return simulate(spec, stop=stop, inputs=input_csv)


def fmu_spec(path):
    """The normalized scene an mbsfmu FMU carries for drawing (fmu/build.py: drawing_resource). Foreign data:
    read bounded, parsed as JSON (never unpickled or executed) and accepted only if it compiles to the very
    scene the FMU runs (its compiled scene, GUID included) and its shapes (drawing only, not compiled) pass
    the scene file's shape rules."""
    from fmpy import read_model_description
    from ..fmu.build import SCENE_FILE
    from ..fmu.common import DRAWING_FILE
    from ..fmu.native import SCENE_FILE as NATIVE_SCENE_FILE
    from ..scene.load import check_shapes_again
    from ..simulation import compiled
    member, spec, problem = f"resources/{DRAWING_FILE}", None, None
    try:
        with zipfile.ZipFile(path) as z:
            names = set(z.namelist())
            text = _read_member(z, member) if member in names else None
            # the native kind's scene (resources/scene.bin) carries model exchange's derivative variables
            found = next(((n == NATIVE_SCENE_FILE, _read_member(z, f"resources/{n}")) for n in
                          (SCENE_FILE, NATIVE_SCENE_FILE) if f"resources/{n}" in names), (False, None))
            native, blob = found
        if text is None:
            problem = f"carries no drawing description ({member})"
        else:
            spec = json.loads(text)
            if blob is None or compiled(spec, read_model_description(path).guid, native)[0] != blob:
                problem = "its drawing description is not the scene it runs (altered, or built by another mbsfmu version)"
            else:
                check_shapes_again(spec, Path(path).parent, f"{path}:{member}")
    except Exception as e:  # noqa: BLE001 - whatever the bytes hold, the answer is one message
        problem = f"cannot read its drawing description ({type(e).__name__}: {e})"
    if problem:
        raise ValueError(f"{path}: {problem}; give the scene it was built from as well (--scene SCENE.yaml)")
    return spec


def _read_member(z, name):
    """A zip member's bytes, at most limits.DRAWING_BYTES whatever its header claims (no zip bomb unpacks)."""
    from ..limits import DRAWING_BYTES
    with z.open(name) as f:
        data = f.read(DRAWING_BYTES + 1)
    if len(data) > DRAWING_BYTES:
        raise ValueError(f"{name} is larger than {DRAWING_BYTES} bytes")
    return data


def from_fmu(path, coordinates, stop=None, input_csv=None):
    """Run the FMU with fmpy and read its `y.*` outputs (the position coordinates)."""
    from fmpy import read_model_description, simulate_fmu
    md = read_model_description(path)
    inp = None
    if input_csv:
        inp = InputTable.for_fmu(input_csv, md).fmpy_signals()
    outputs = [f"y.{c}" for c in coordinates]
    missing = set(outputs) - {v.name for v in md.modelVariables if v.causality == "output"}
    if missing:
        raise ValueError(f"{path} has no output(s) {', '.join(sorted(missing))}: it was not built from this scene")
    res = simulate_fmu(str(path), stop_time=stop, input=inp, output=outputs)
    return res["time"], np.column_stack([res[n] for n in outputs]), None


def from_result(path, coordinates):
    """t and Y from a result CSV: its `y.<coordinate>` columns (velocities are not needed for drawing)."""
    names, t, data = read_csv(path, "result")
    missing = [c for c in coordinates if f"y.{c}" not in names]
    if missing:
        raise ValueError(f"{path}: no column for coordinate(s) {', '.join('y.' + c for c in missing)} "
                         "(write the result with 'mbsfmu simulate --csv' from the same scene)")
    return t, np.column_stack([data[f"y.{c}"] for c in coordinates]), None


def load_scene(scene):
    """A scene file or loaded Scene → (Scene, base folder for shape files); its package folders are
    scene.package_dirs."""
    from ..scene import load
    if hasattr(scene, "spec"):
        return scene, Path(scene.path).parent if scene.path and Path(scene.path).is_file() else Path.cwd()
    if not Path(scene).is_file():
        raise FileNotFoundError(f"no such file: {scene}")
    return load(scene), Path(scene).parent


def load_source(source, scene=None):
    """SCENE or FMU (with the scene it was built from, or the one it carries) → (spec, base folder for shape
    files, FMU path or None, package folders of its package:// meshes: a loaded scene's, never an FMU's)."""
    if not hasattr(source, "spec") and Path(source).is_file() and zipfile.is_zipfile(source):
        if scene is not None:
            s, base = load_scene(scene)
            return s.spec, base, Path(source), s.package_dirs
        return fmu_spec(source), Path(source).parent, Path(source), ()
    s, base = load_scene(source)
    return s.spec, base, None, s.package_dirs
