"""mbsfmu: multibody scenes (YAML) → equations of motion → FMI 2.0 co-simulation FMUs.

Build-time parts (YAML, FMU packaging) are imported lazily. Inside an FMU only the C engine runs: a native FMU
has no Python, a pythonfmu FMU imports the engine's ctypes seam (standard library only, no numpy or scipy).
"""

from .errors import IntegrationError, ModelError
from .version import __version__
__all__ = ["load", "loads", "compile", "simulate", "animate", "build_fmu", "sweep", "ModelError", "IntegrationError", "__version__"]


def load(path, allow_outside=False, repair=False, package_dirs=(), base=None):
    """Read and validate a scene file or a URDF (`.urdf`); raises ModelError (only) with file:line, key and a
    hint. Data files must lie in the scene's folder unless allow_outside=True. repair=True fixes a URDF's
    massless moving links and unphysical inertias instead of refusing them (listed in `scene.repairs`).
    package_dirs: for a URDF, the folders of its `package://NAME/...` meshes, relative to the URDF's folder
    (trusted wherever they are). base: for a URDF, 'fixed' (default) or 'free' (a floating base)."""
    from .scene import load as _load
    return _load(path, allow_outside=allow_outside, repair=repair, package_dirs=package_dirs, base=base)


def loads(text, file="<string>", base=None, allow_outside=False, repair=False):
    """Validate a scene given as YAML text (data files relative to `base`, default the current folder)."""
    from .scene import loads as _loads
    return _loads(text, file=file, base=base, allow_outside=allow_outside, repair=repair)


def compile(scene):
    """Scene (or path, or normalized spec dict) → the compiled model (compiler/model.py) with its numpy reference
    Evaluator of M, k, q (equations/): the readable twin of what the engine runs from the compiled scene."""
    from .equations import Evaluator
    if isinstance(scene, dict):
        return Evaluator(scene)
    if not hasattr(scene, "spec"):
        scene = load(scene)
    return Evaluator(scene.spec)


def simulate(scene, stop=None, step=None, inputs=None, method=None, inputs_interpolation="hold",
             **integrator_options):
    """In-process run with the FMU's integrators → (t, Y, YD) at the communication points. scene: path, loaded
    scene or spec; inputs: {name: value} held throughout, an input CSV (each row held until the next row's
    time; inputs_interpolation="linear": interpolated), or a function t → {name: value}; integrator_options:
    rtol, atol, max_step, step."""
    from .simulation import simulate as _simulate
    if not isinstance(scene, dict) and not hasattr(scene, "spec"):
        scene = load(scene)
    return _simulate(scene, stop=stop, step=step, inputs=inputs, method=method,
                     inputs_interpolation=inputs_interpolation, **integrator_options)


def animate(source, output="animation.html", **options):
    """Write one self-contained HTML page that plays the motion of a scene or mbsfmu FMU in 3-D; returns its
    path. options: stop, input_csv, result_csv, fps (see mbsfmu.animation.animate)."""
    from .animation import animate as _animate
    return _animate(source, output, **options)


def build_fmu(scene, outdir=".", **options):
    """Build `<outdir>/<name>.fmu` from a scene file or loaded scene; returns its path."""
    from .fmu.build import build_fmu as _build
    return _build(scene, outdir, **options)


# Imported here, not wrapped lazily: importing the submodule on first call would rebind `mbsfmu.sweep` from
# the function to the package. mbsfmu/sweep/__init__.py imports nothing heavy at the top.
from .sweep import sweep  # noqa: E402
