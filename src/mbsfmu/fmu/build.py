"""Build an FMI 2.0 co-simulation FMU from a scene.

The default kind is a pythonfmu FMU: pythonfmu's prebuilt FMI binary (behind mbsfmu's loader shim on linux64,
``shim.c``) and resources holding

* ``mbsfmu_scene.bin`` - the compiled scene the engine reads (variables and their names included),
* ``mbsfmu_rt_<hash>/`` - a renamed copy of the run-time part of mbsfmu: the ctypes seam of the C engine
  (``engine/*.py``), the compiled engine library for this platform and its C sources (compiled on the
  target with ``cc`` if the library does not load there); no numpy, scipy, YAML or plotting,
* ``mbsfmu_<name>_<hash>.py`` - the generated slave script (from ``slave.py.in``), which implements the
  slave protocol pythonfmu's binary calls (pythonfmu's Python package is not needed at run time),
* ``mbsfmu_drawing.json`` - the normalized scene as JSON, for ``mbsfmu animate`` only (both kinds carry it;
  the FMU never reads it),

and the ``modelDescription.xml`` (common.py: one writer for both kinds).
"""
from __future__ import annotations

import hashlib
import importlib
import importlib.util
import io
import json
import re
import sys
import tempfile
import uuid
import warnings
import zipfile
from pathlib import Path

from .. import files
from .common import drawing_resource, mbsfmu_version, model_description, write_zip

KINDS = ("pythonfmu", "native")
FMI_VERSIONS = ("2", "3")
SCENE_FILE = "mbsfmu_scene.bin"
TEMPLATE = Path(__file__).with_name("slave.py.in")
SHIM_SOURCE = Path(__file__).with_name("shim.c")
# engine sources the shim shares with native FMUs: the resource-location parser and file reader, the FMI 2.0 guard
PACKAGE_ROOT = Path(__file__).resolve().parent.parent  # src/mbsfmu
SHIM_SHARED = (PACKAGE_ROOT / "engine" / "fmu_files.c", PACKAGE_ROOT / "engine" / "state_header.c",
               PACKAGE_ROOT / "fmi" / "call_guard.c")

# The module pythonfmu imports (named in slavemodule.txt). pythonfmu 0.7.0 also compiles and runs this file's text
# again in every fmi2Instantiate, in a fresh namespace, to find the slave class, and never releases what that
# creates (the classes a full slave script defines there: ~36 kB per instance); it also releases this module's
# namespace once more per run and inserts the resources folder into sys.path again. So this file only imports
# the class from the slave module (imported once), keeps one reference to its namespace per run (_pins: the one
# pythonfmu gives up) and drops sys.path's repeated entries.
ENTRY = """# pythonfmu entry point of an mbsfmu FMU (mbsfmu.fmu.build; why so small: build.ENTRY). Do not edit.
import sys
from @SLAVE_MODULE@ import MbsfmuSlave
globals().setdefault("_pins", []).append(globals())
sys.path[1:] = [p for p in sys.path[1:] if p != sys.path[0]]
"""

# Runtime parts of the package copied into every FMU (missing optional entries are skipped).
RUNTIME_ENGINE = ("errors.py", "engine/__init__.py", "engine/api.py", "engine/build.py")
# Never needed at FMU run time.
FORBIDDEN_IMPORTS = ("yaml", "sympy", "matplotlib", "tqdm")

def _runtime_files(root: Path) -> dict[str, bytes]:
    """{relative posix path: content} of the run-time part copied into the FMU."""
    files: dict[str, bytes] = {}
    for entry in RUNTIME_ENGINE:
        p = root / entry
        if p.is_file():
            files[entry] = p.read_bytes()
        elif p.is_dir():
            for f in sorted(p.rglob("*.py")):
                if "__pycache__" not in f.parts:
                    files[f.relative_to(root).as_posix()] = f.read_bytes()
            if not (p / "__init__.py").exists():
                files[f"{entry}/__init__.py"] = b""
    files.update(_engine_files(root))
    files["__init__.py"] = b'"""mbsfmu run-time (copied into an FMU by mbsfmu.fmu.build)."""\n'
    return files


def _engine_files(root: Path) -> dict[str, bytes]:
    """The engine's C sources and headers (to compile on a target where the library does not load) and the
    compiled library for this platform (engine/__init__.py loads the one next to it)."""
    from ..engine import build
    srcs, hdrs, _ = build.sources()
    out = {p.relative_to(PACKAGE_ROOT).as_posix(): p.read_bytes() for p in srcs + hdrs}  # engine/ and fmi/
    try:
        lib = build.library_path()
    except build.EngineUnavailable as exc:
        warnings.warn(f"FMU without a compiled engine ({exc}); it compiles on first use where a C compiler is",
                      RuntimeWarning)
        return out
    out[f"engine/{lib.name}"] = lib.read_bytes()
    return out


def forbidden_imports(files: dict[str, bytes]) -> list[str]:
    """'path: module' for each import of a module the FMU must not need at run time."""
    pat = re.compile(r"^\s*(?:import|from)\s+(" + "|".join(FORBIDDEN_IMPORTS) + r")\b", re.M)
    rel = re.compile(r"^\s*from\s+\.+\s*(?:import\s+)?(scene|fmu|bench|cli)\b", re.M)
    found = []
    for path, content in files.items():
        if not path.endswith(".py"):
            continue
        text = content.decode("utf-8", "replace")
        found += [f"{path}: {m.group(1)}" for m in pat.finditer(text)]
        found += [f"{path}: .{m.group(1)}" for m in rel.finditer(text)]
    return found


_ABSOLUTE_FROM = re.compile(rb"^(\s*from\s+)mbsfmu(?=[.\s])", re.M)
_ABSOLUTE_IMPORT = re.compile(rb"^\s*import\s+mbsfmu\b", re.M)


def _rename_absolute_imports(files: dict[str, bytes], package: str) -> dict[str, bytes]:
    """``from mbsfmu.x import y`` -> ``from <package>.x import y`` in the copied runtime.

    The copy must not depend on an installed mbsfmu (the FMU host may not have it, and its classes,
    e.g. IntegrationError, would differ from the copy's)."""
    out = {}
    for path, content in files.items():
        if path.endswith(".py"):
            if _ABSOLUTE_IMPORT.search(content):
                raise RuntimeError(f"{path}: 'import mbsfmu...' cannot be relocated into an FMU; "
                                   "use a relative import")
            content = _ABSOLUTE_FROM.sub(rb"\g<1>" + package.encode(), content)
        out[path] = content
    return out


def _hash(*parts: bytes) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(len(p).to_bytes(8, "little"))
        h.update(p)
    return h.hexdigest()


def _load_scene(scene_or_path):
    if isinstance(scene_or_path, (str, Path)):
        from ..scene import load
        return load(scene_or_path)
    return scene_or_path


def build_fmu(scene_or_path, outdir=".", *, kind="pythonfmu", fmi="2", runtime_root=None, shim=True) -> Path:
    """Build ``<outdir>/<name>.fmu`` from a scene (a YAML path or a loaded scene with ``.spec``).

    ``kind``: "pythonfmu" (default) or "native" (C engine + FMI layer, no Python at run time; native.py).
    ``fmi``: "2" (default) or "3" (FMI 3.0 co-simulation and model exchange: native only).
    ``runtime_root`` (for tests) replaces the directory the runtime sources are copied from.
    ``shim=False`` keeps pythonfmu's plain linux64 binary (needs libpython preloaded in C hosts).
    Returns the path of the written FMU.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown FMU kind {kind!r}: {' or '.join(KINDS)}")
    fmi = str(fmi)
    if fmi not in FMI_VERSIONS:
        raise ValueError(f"unknown FMI version {fmi!r}: {' or '.join(FMI_VERSIONS)}")
    if fmi != "2" and kind != "native":
        raise ValueError(f"FMI {fmi}.0 FMUs are of the native kind only (--kind native): pythonfmu makes FMI 2.0 "
                         "co-simulation FMUs")
    scene = _load_scene(scene_or_path)
    dest = fmu_path(scene, outdir)
    files.check({"the FMU": dest}, {"the scene": getattr(scene, "path", None)})
    if kind == "native":
        from .native import build_native
        return build_native(scene, dest, fmi)
    spec = scene.spec if hasattr(scene, "spec") else scene
    spec = json.loads(json.dumps(spec))  # plain JSON data, exactly what the FMU will read
    name = dest.stem
    root = Path(runtime_root) if runtime_root is not None else PACKAGE_ROOT
    runtime = _runtime_files(root)
    bad = forbidden_imports(runtime)
    if bad:
        warnings.warn("mbsfmu runtime imports modules not available/wanted at FMU run time: "
                      + "; ".join(bad), RuntimeWarning, stacklevel=2)

    version = mbsfmu_version()
    spec_bytes = json.dumps(spec, indent=1, sort_keys=True).encode("utf-8")
    rt_hash = _hash(*[p.encode() + b"\0" + c for p, c in sorted(runtime.items())])
    rt_package = f"mbsfmu_rt_{rt_hash[:16]}"
    runtime = _rename_absolute_imports(runtime, rt_package)
    template = TEMPLATE.read_text(encoding="utf-8")
    fmu_hash = _hash(rt_hash.encode(), spec_bytes, template.encode(), version.encode())
    guid = "{" + str(uuid.UUID(fmu_hash[:32])) + "}"
    module_name = f"mbsfmu_{name}_{fmu_hash[:12]}"
    script = (template.replace("@RUNTIME_PACKAGE@", rt_package)
              .replace("@SCENE_FILE@", SCENE_FILE)
              .replace("@MODEL_NAME@", name)
              .replace("@MBSFMU_VERSION@", version))

    from ..simulation import compiled
    blob, variables, _ = compiled(spec, guid)
    members = {f"resources/{rt_package}/{rel}": content for rel, content in runtime.items()}
    members.update({f"resources/{SCENE_FILE}": blob, f"resources/{module_name}_slave.py": script.encode("utf-8"),
                    f"resources/{module_name}.py": ENTRY.replace("@SLAVE_MODULE@", f"{module_name}_slave").encode(),
                    "resources/slavemodule.txt": module_name.encode(),
                    "modelDescription.xml": model_description(spec, name, variables, version, guid=guid)})
    members.update(drawing_resource(spec))
    members.update(_pythonfmu_binaries(name))
    _slave_loads(members, module_name, rt_package)
    with files.replacing(dest) as tmp:  # a build that fails or is killed leaves the previous FMU intact
        write_zip(tmp, members)
        if shim:
            _attach_shim(Path(tmp), name)
    return dest


def fmu_path(scene, outdir) -> Path:
    """``<outdir>/<model name>.fmu``, where both kinds write the FMU of a loaded scene (or spec)."""
    spec = scene.spec if hasattr(scene, "spec") else scene
    name = getattr(scene, "name", None) or spec["name"]
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", name):  # the modelIdentifier names the binary: a C identifier
        raise ValueError(f"invalid model name {name!r}: letters, digits, underscore; starts with a letter")
    return Path(outdir) / f"{name}.fmu"


def _pythonfmu_binaries(name: str) -> dict[str, bytes]:
    """pythonfmu's prebuilt FMI binaries, named for this model: the only part of pythonfmu an FMU carries (its
    slave protocol is implemented by the slave script itself)."""
    import pythonfmu
    out = {}
    for lib in (Path(pythonfmu.__file__).parent / "resources" / "binaries").glob("*/*"):
        if lib.suffix in (".so", ".dll", ".dylib"):
            out[f"binaries/{lib.parent.name}/{name}{lib.suffix}"] = lib.read_bytes()
    if not out:
        raise RuntimeError("pythonfmu's binaries are missing from its installation (pythonfmu/resources/binaries)")
    return out


def _slave_loads(members: dict[str, bytes], module_name: str, rt_package: str) -> None:
    """Instantiate the slave once from a staged copy of the resources: the FMU fails here, not in a host."""
    path_before, modules_before = list(sys.path), set(sys.modules)
    with tempfile.TemporaryDirectory(prefix="mbsfmu_build_") as stage:
        for member, data in members.items():
            if member.startswith("resources/"):
                f = Path(stage) / member[len("resources/"):]
                f.parent.mkdir(parents=True, exist_ok=True)
                f.write_bytes(data)
        try:
            sys.path.insert(0, stage)
            importlib.import_module(module_name).MbsfmuSlave(instance_name="mbsfmu_build", resources=stage)
        finally:
            sys.path[:] = path_before
            for key in set(sys.modules) - modules_before:  # forget the staged modules
                if key.startswith(module_name) or key == rt_package or key.startswith(rt_package + "."):
                    del sys.modules[key]


def python_runtime() -> dict:
    """The build interpreter, compiled into the linux64 loader shim: the libpython it loads in hosts without
    Python and the executable it names as the program (from which Python finds its standard library)."""
    import sysconfig
    libpython = soname = None
    if sysconfig.get_config_var("Py_ENABLE_SHARED"):
        soname = sysconfig.get_config_var("INSTSONAME") or sysconfig.get_config_var("LDLIBRARY")
        for name in (soname, sysconfig.get_config_var("LDLIBRARY")):
            if name and (Path(sysconfig.get_config_var("LIBDIR") or "") / name).exists():
                libpython = str(Path(sysconfig.get_config_var("LIBDIR")) / name)
                break
    return {"version": list(sys.version_info[:3]), "executable": sys.executable, "prefix": sys.prefix,
            "base_prefix": sys.base_prefix, "libpython": libpython, "libpython_soname": soname}


def _c_string(s: str | None) -> str:
    """A C string literal of s's UTF-8 bytes (printable ASCII kept, everything else an octal escape)."""
    out = []
    for b in (s or "").encode("utf-8"):
        ch = chr(b)
        out.append(ch if 32 <= b < 127 and ch not in '"\\?' else f"\\{b:03o}")
    return '"' + "".join(out) + '"'


_CAUSALITY = {"parameter": "p", "calculatedParameter": "c", "input": "i", "output": "o", "local": "l",
              "independent": "x"}
_VARIABILITY = {"constant": "k", "fixed": "f", "tunable": "t", "discrete": "d", "continuous": "c"}


def shim_model_defines(model_description: bytes) -> str:
    """The model's GUID, log categories and variable table (by value reference) as the C defines shim.c
    checks every call against, read from the modelDescription.xml the host sees."""
    from xml.etree.ElementTree import fromstring
    root = fromstring(model_description)
    table = {}
    for sv in root.iter("ScalarVariable"):
        kind = next(iter(sv))
        table[int(sv.get("valueReference"))] = "{%s, '%s', '%s', '%s'}" % (
            _c_string(sv.get("name")), kind.tag[0], _CAUSALITY[sv.get("causality", "local")],
            _VARIABILITY[sv.get("variability", "continuous")])
    rows = [table.get(vr, "{\"\", '-', 'l', 'c'}") for vr in range(max(table, default=-1) + 1)]
    categories = [c.get("name") for c in root.iter("Category")]
    return (f"#define MBSFMU_GUID {_c_string(root.get('guid'))}\n"
            f"#define MBSFMU_LOG_CATEGORIES {', '.join(map(_c_string, categories)) or _c_string('')}\n"
            f"#define MBSFMU_VARIABLES \\\n    " + ", \\\n    ".join(rows or ["{\"\", '-', 'l', 'c'}"]) + "\n")


def compile_shim(out: Path, real_library: str, model_description: bytes, runtime: dict | None = None,
                 resource_files=()) -> Path | None:
    """Compile the loader shim (``shim.c``) for the model of ``model_description`` into ``out``; None (with a
    warning) without a C compiler. ``resource_files`` (paths relative to resources/) are the files the FMU reads
    at run time: fmi2Instantiate checks that each is a regular file of bounded size before Python reads it."""
    import shutil
    import subprocess
    import sysconfig
    runtime = runtime or python_runtime()
    cc = None
    for cand in (sysconfig.get_config_var("CC") or "").split()[:1] + ["cc", "gcc", "clang"]:
        if cand and shutil.which(cand):
            cc = shutil.which(cand)
            break
    if cc is None:
        warnings.warn("no C compiler found: the FMU keeps pythonfmu's plain binary, which needs "
                      "libpython preloaded (LD_PRELOAD) in non-Python hosts", RuntimeWarning, stacklevel=3)
        return None
    if not runtime.get("libpython"):
        warnings.warn("this Python has no shared libpython: the FMU runs only in Python hosts",
                      RuntimeWarning, stacklevel=3)
    src = out.with_suffix(".c")
    src.write_text(
        f"#define MBSFMU_LIBPYTHON {_c_string(runtime.get('libpython'))}\n"
        f"#define MBSFMU_LIBPYTHON_SONAME {_c_string(runtime.get('libpython_soname'))}\n"
        f"#define MBSFMU_PYTHON_EXECUTABLE {_c_string(runtime.get('executable'))}\n"
        f"#define MBSFMU_REAL_LIBRARY {_c_string(real_library)}\n"
        + shim_model_defines(model_description)
        + f"#define MBSFMU_RESOURCE_FILES {', '.join(map(_c_string, resource_files)) or _c_string('')}\n"
        + SHIM_SOURCE.read_text(encoding="utf-8"), encoding="utf-8")
    shared = [str(f) for f in SHIM_SHARED]
    cmd = [cc, "-shared", "-fPIC", "-O2", "-Wall", "-Wextra", "-fvisibility=hidden",
           *(f"-I{f.parent}" for f in SHIM_SHARED), "-o", str(out),
           str(src), *shared, "-ldl", "-lpthread"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        warnings.warn(f"compiling the FMU loader shim failed ({' '.join(cmd)}): {r.stderr.strip()[:2000]}; "
                      "the FMU keeps pythonfmu's plain binary", RuntimeWarning, stacklevel=3)
        return None
    return out


def _attach_shim(dest: Path, name: str) -> bool:
    """Make ``binaries/linux64/<name>.so`` the loader shim, pythonfmu's binary ``<name>_pythonfmu.so``."""
    if not sys.platform.startswith("linux"):
        return False
    member = f"binaries/linux64/{name}.so"
    real_name = f"{name}_pythonfmu.so"
    with zipfile.ZipFile(dest) as z:
        if member not in z.namelist():
            return False
        real_bytes = z.read(member)
        model_description = z.read("modelDescription.xml")
        resource_files = [n[len("resources/"):] for n in z.namelist() if n.startswith("resources/") and n[-1] != "/"]
    with tempfile.TemporaryDirectory(prefix="mbsfmu_shim_") as tmp:
        so = compile_shim(Path(tmp) / "shim.so", real_name, model_description, resource_files=resource_files)
        if so is None:
            return False
        _rewrite_zip(dest, {member: so.read_bytes(), f"binaries/linux64/{real_name}": real_bytes})
    return True


def _rewrite_zip(path: Path, replace: dict, drop=frozenset()) -> None:
    """Rewrite the FMU archive with the members in `replace` (name → bytes) and without those in `drop`."""
    buf = io.BytesIO()
    with zipfile.ZipFile(path) as zin, zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            if item.filename in replace or item.filename in drop:
                continue
            zout.writestr(item.filename, zin.read(item.filename), zipfile.ZIP_DEFLATED)
        for member, data in replace.items():
            zout.writestr(member, data, zipfile.ZIP_DEFLATED)
    path.write_bytes(buf.getvalue())
