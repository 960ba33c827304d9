"""`mbsfmu animate`: watch a scene or a result move in 3-D, in one self-contained HTML page (three.js).

Build-time only (never packed into FMUs): poses come from the numpy reference kinematics, the page only
interpolates between frames.
"""

from pathlib import Path

import numpy as np

MAX_FRAMES = 20_000  # bounds the page size (a frame is a few dozen float32 numbers)


def decimate(t, fps, max_frames=MAX_FRAMES):
    """Indices of the samples to keep: about `fps` per simulated second, never more than `max_frames`,
    always the first and the last."""
    t = np.asarray(t, dtype=float)
    n = len(t)
    span = t[-1] - t[0] if n > 1 else 0.0
    want = min(max_frames, max(2, int(np.ceil(span * fps)) + 1))
    if n <= want:
        return np.arange(n)
    idx = np.unique(np.searchsorted(t, np.linspace(t[0], t[-1], want)))
    return np.union1d(np.minimum(idx, n - 1), [0, n - 1])


def animate(source, output="animation.html", stop=None, input_csv=None, result_csv=None, fps=60, scene=None):
    """Write an HTML page that plays the motion of `source` (a scene file or loaded scene, or an mbsfmu FMU)
    and return its path. The motion is simulated (a scene in process, an FMU with fmpy) until `stop` (default:
    the scene's experiment), with inputs from `input_csv` (a 'time' column, then input names); or read from
    `result_csv` (written by `mbsfmu simulate --csv`: 'time' and 'y.<coordinate>' columns). `scene`: the scene
    an FMU was built from (without it, the drawing description the FMU carries; shape files are read next to
    the scene, else next to the FMU)."""
    from .. import files
    from ..compiler.model import Model
    from ..scene.shapes import mesh_path
    from . import drawing, frames, page, trajectory
    spec, base, fmu, package_dirs = trajectory.load_source(source, scene)
    inputs = {"the model": getattr(source, "path", source), "the input CSV": input_csv, "the result CSV": result_csv,
              "the scene": getattr(scene, "path", scene),
              **{f"the mesh file {f}": mesh_path(base, f, package_dirs) for f in drawing.mesh_files(spec)}}
    files.check({"the page": output}, inputs)
    model = Model(spec)
    if result_csv:
        t, Y, YD = trajectory.from_result(result_csv, model.coordinates)
    elif fmu is None:
        t, Y, YD = trajectory.from_scene(spec, stop=stop, input_csv=input_csv)
    else:
        t, Y, YD = trajectory.from_fmu(fmu, model.coordinates, stop=stop, input_csv=input_csv)
    keep = decimate(t, fps)
    t, Y = np.asarray(t, dtype=float)[keep], np.asarray(Y)[keep]
    YD = None if YD is None else np.asarray(YD)[keep]
    layout, F = frames.frames(model, t, Y, YD)
    if not np.all(np.isfinite(F)):
        raise ValueError("the motion has non-finite positions (did the simulation fail?)")
    scene_data = drawing.describe(model, layout, F, base, package_dirs)
    html = page.render(spec["name"], spec.get("description", ""), t, F, scene_data)
    return Path(files.write_text(output, html))
