"""Native FMUs (``kind="native"``): the engine's C sources and an FMI layer (``fmi/fmi2.c`` for FMI 2.0, the
default, ``fmi/fmi3.c`` for FMI 3.0: co-simulation and model exchange each) compiled into
``binaries/<platform>/<modelIdentifier>``; the scene is data (``resources/scene.bin``). No Python at run time:
the binary needs only the C library and libm.

An FMU holds

* ``binaries/linux64/<id>.so`` (``cc``) and ``binaries/win64/<id>.dll`` when a MinGW-w64 cross compiler
  (``x86_64-w64-mingw32-gcc``) is installed (FMI 3.0: ``x86_64-linux``, ``x86_64-windows``),
* ``resources/scene.bin``: the compiled scene (``compiler.scene_file.compile_scene``) with the FMU's GUID,
* ``resources/mbsfmu_drawing.json``: the scene for ``mbsfmu animate`` (``common.drawing_resource``),
* ``sources/``: exactly the C files compiled into the binaries (the engine parts the scene needs, the FMI layer,
  the headers they include), listed in ``<SourceFiles>`` (FMI 3.0: ``sources/buildDescription.xml``), plus a
  CMakeLists.txt and a README,
* ``modelDescription.xml`` from the FMI version's writer (``common.model_description``, the pythonfmu kind's
  too, or ``common.model_description3``).
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
import uuid
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from .. import files
from .common import drawing_resource, mbsfmu_version, model_description, model_description3, write_zip

ENGINE = Path(__file__).resolve().parent.parent / "engine"
FMI = ENGINE.parent / "fmi"  # the FMI layers and what they share
FMI_LAYER = FMI / "fmi2.c"
FMI_LAYERS = {"2": FMI_LAYER, "3": FMI / "fmi3.c"}  # FMI version → its layer
PLATFORMS = {"2": ("linux64", "win64"), "3": ("x86_64-linux", "x86_64-windows")}  # binaries/ folders per version
SHARED = ("-shared", "-fvisibility=hidden")  # with the engine's CFLAGS: the numbers of the in-process library
MINGW = "x86_64-w64-mingw32-gcc"
SCENE_FILE = "scene.bin"  # in resources/: the compiled scene the FMI layer reads
_INCLUDE = re.compile(rb'^\s*#\s*include\s+"([^"]+)"', re.M)

# Co-simulation capabilities that differ from the pythonfmu kind.
COSIMULATION = {"needsExecutionTool": "false", "canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true",
                "canHandleVariableCommunicationStepSize": "true", "providesDirectionalDerivative": "true"}


def source_files(blob: bytes, fmi: str = "2") -> dict[str, bytes]:
    """The FMI version's layer and the engine C sources it links with the scene's switches
    (engine.build.linked_sources), with their headers (collect_sources). The
    engine's feature switches (-DMBS_WITH_...) are written at the top of each C file, so that compiling the
    files of sources/ needs no flags."""
    from ..engine import build as engine_build
    _, _, defs = engine_build.sources(engine_build.features(blob))
    out = collect_sources(engine_build.linked_sources([FMI_LAYERS[fmi]], defs))
    if defs:
        banner = "/* this FMU's engine parts (mbsfmu engine/build.py) */\n" + "".join(
            f"#define {d[2:].replace('=', ' ', 1)}\n" for d in defs)
        for name in c_names(out):
            out[name] = (banner + f'#line 1 "{name}"\n').encode() + out[name]
    return out


def collect_sources(c_files) -> dict[str, bytes]:
    """{flat file name: content} of the C files and every header they include, followed transitively
    (looked up next to the including file, then in engine/, fmi/, fmi/fmi2/ and fmi/fmi3/)."""
    out: dict[str, bytes] = {}
    todo = list(c_files)
    while todo:
        path = todo.pop()
        if path.name in out:
            continue
        data = path.read_bytes()
        out[path.name] = data
        for inc in _INCLUDE.findall(data):
            name = inc.decode()
            found = next((d / name for d in (path.parent, ENGINE, FMI, FMI / "fmi2", FMI / "fmi3")
                          if (d / name).is_file()), None)
            if found is None:
                raise FileNotFoundError(f"{path.name} includes \"{name}\", which is not in {ENGINE} or {FMI}")
            todo.append(found)
    return out


def c_names(sources: dict) -> list[str]:
    return sorted(n for n in sources if n.endswith(".c"))


def compiler() -> str | None:
    """The C compiler for this platform's binary ($CC, cc, gcc, clang), or None."""
    for cand in (os.environ.get("CC", "").split() or [""])[:1] + ["cc", "gcc", "clang"]:
        if cand and shutil.which(cand):
            return shutil.which(cand)
    return None


def compile_library(src_dir: Path, out: Path, cc: str, windows: bool = False) -> Path:
    """Compile every ``*.c`` of src_dir into the shared library ``out`` (the FMI functions are the only
    exported symbols). Raises RuntimeError with the compiler's message."""
    from ..engine.build import CFLAGS, run_cc
    c_files = sorted(str(p) for p in Path(src_dir).glob("*.c"))
    if windows:  # no MinGW runtime DLL needed on the target
        flags = [f for f in CFLAGS if f != "-fPIC"]
        cmd = [cc, *flags, *SHARED, "-static-libgcc", "-I", str(src_dir), "-o", str(out), *c_files]
    else:  # -z defs: everything must resolve in libc/libm at link time, not at the user's dlopen
        cmd = [cc, *CFLAGS, *SHARED, "-I", str(src_dir), "-o", str(out), *c_files, "-lm", "-Wl,-z,defs"]
    r = run_cc(cmd)
    if r.returncode != 0:
        raise RuntimeError(f"compiling the native FMU failed: {' '.join(cmd)}\n{r.stderr.strip()[:4000]}")
    return out


_BINARIES: dict[str, bytes] = {}  # scenes with the same engine parts get the same binary: compile it once


def _binary(src: Path, sources: dict[str, bytes], cc: str, windows: bool) -> bytes:
    h = hashlib.sha256(f"{cc}\0{windows}".encode())
    for name, data in sorted(sources.items()):
        h.update(name.encode() + b"\0" + hashlib.sha256(data).digest())
    key = h.hexdigest()
    if key not in _BINARIES:
        out = src.parent / ("lib.dll" if windows else "lib.so")
        _BINARIES[key] = compile_library(src, out, cc, windows).read_bytes()
    return _BINARIES[key]


def cmake_lists(identifier: str, c_names: list[str]) -> str:
    return f"""# Builds binaries/<platform>/{identifier} from these sources (the same files the shipped binaries come from):
#   cmake -S sources -B build && cmake --build build --config Release
cmake_minimum_required(VERSION 3.10)
project({identifier} C)
set(CMAKE_C_STANDARD 99)
add_library({identifier} SHARED {' '.join(c_names)})
set_target_properties({identifier} PROPERTIES PREFIX "" C_VISIBILITY_PRESET hidden)
target_include_directories({identifier} PRIVATE ${{CMAKE_CURRENT_SOURCE_DIR}})
if(NOT WIN32)
  target_link_libraries({identifier} PRIVATE m)
endif()
"""


def build_description(identifier: str, c_names: list[str]) -> bytes:
    """sources/buildDescription.xml (FMI 3.0's list of the sources, in place of FMI 2.0's <SourceFiles>)."""
    from xml.etree.ElementTree import Element, SubElement, tostring
    root = Element("fmiBuildDescription", {"fmiVersion": "3.0"})
    files = SubElement(SubElement(root, "BuildConfiguration", {"modelIdentifier": identifier}), "SourceFileSet",
                       {"language": "C99"})
    for name in c_names:
        SubElement(files, "SourceFile", {"name": name})
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root) + b"\n"


def readme(identifier: str, c_names: list[str], notes: list[str], fmi: str = "2") -> str:
    layer = f"FMI {fmi}.0 co-simulation and model-exchange"
    binaries = "binaries/<platform>/" if fmi == "2" else "binaries/<platform tuple>/ (x86_64-linux, x86_64-windows)"
    return (f"Sources of the native FMU '{identifier}' (mbsfmu engine + {layer} layer).\n\n"
            "Compiling all *.c files of this folder into a shared library gives a working FMU binary, e.g.\n\n"
            f"  cc -O2 -std=c99 -shared -fPIC -fvisibility=hidden -I. -o {identifier}.so {' '.join(c_names)} -lm\n"
            f"  x86_64-w64-mingw32-gcc -O2 -std=c99 -shared -static-libgcc -I. -o {identifier}.dll {' '.join(c_names)}\n\n"
            f"or use CMakeLists.txt. Put the library into {binaries} of the FMU; it reads\n"
            f"resources/scene.bin at instantiation. The FMI functions carry no prefix in a shared library;\n"
            f"define FMI{fmi}_FUNCTION_PREFIX to link the FMU statically under prefixed names.\n\n"
            + "".join(f"Build note: {n}\n" for n in notes))


def guid_for(spec: dict, version: str) -> str:
    """From the scene, the mbsfmu version and every engine source: any change gives another GUID."""
    h = hashlib.sha256(json.dumps(spec, sort_keys=True).encode() + b"\0" + version.encode())
    for path in sorted(ENGINE.rglob("*.[ch]")):
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return "{" + str(uuid.UUID(h.hexdigest()[:32])) + "}"


def build_native(scene, dest: Path, fmi: str = "2") -> Path:
    """Write the FMU ``dest`` (``build.fmu_path``: ``<outdir>/<name>.fmu``, native kind, FMI version ``fmi``)
    for a loaded scene; returns its path."""
    from ..simulation import compiled

    spec = json.loads(json.dumps(scene.spec if hasattr(scene, "spec") else scene))
    name = dest.stem
    version = mbsfmu_version()
    guid = guid_for(spec, version)
    blob, variables, _ = compiled(spec, guid, derivatives=True)  # model exchange too (animate checks the same)
    sources = source_files(blob, fmi)
    extra = drawing_resource(spec)
    if fmi == "3":
        xml = model_description3(spec, name, variables, version, guid)
        extra["sources/buildDescription.xml"] = build_description(name, c_names(sources))
    else:
        xml = model_description(spec, name, variables, version, guid=guid, cosimulation=COSIMULATION,
                                source_files=c_names(sources), model_exchange=True)
    for n in package(dest, name, sources, blob, xml, extra, fmi):
        warnings.warn(f"native FMU {name}: {n}", RuntimeWarning, stacklevel=3)
    return dest


def package(dest: Path, identifier: str, sources: dict[str, bytes], scene_bin: bytes, xml: bytes,
            extra: dict[str, bytes] | None = None, fmi: str = "2") -> list[str]:
    """Compile the sources into the FMI version's binaries/ folders (linux64, and win64 with MinGW-w64) and
    write the FMU ``dest`` with sources/, resources/scene.bin, the modelDescription and the `extra` members.
    Returns build notes (what is missing)."""
    cc = compiler()
    if cc is None:
        raise RuntimeError("a native FMU needs a C compiler (cc, gcc or clang, or $CC); none was found. "
                           "Install one (Debian: apt-get install gcc) or build the default (pythonfmu) kind")
    notes = []
    linux, windows = PLATFORMS[fmi]
    mingw = shutil.which(MINGW)
    if mingw is None:
        notes.append(f"no binaries/{windows}: {MINGW} (Debian gcc-mingw-w64-x86-64) was not found on the build machine")
    names = c_names(sources)
    with tempfile.TemporaryDirectory(prefix="mbsfmu_native_") as tmp:
        src = Path(tmp) / "sources"  # compiled from the very files that ship
        src.mkdir()
        for fname, data in sources.items():
            (src / fname).write_bytes(data)
        members = {"modelDescription.xml": xml, f"resources/{SCENE_FILE}": scene_bin, **(extra or {})}
        with ThreadPoolExecutor(2) as pool:  # the two compilers side by side
            jobs = {f"binaries/{linux}/{identifier}.so": pool.submit(_binary, src, sources, cc, False)}
            if mingw:
                jobs[f"binaries/{windows}/{identifier}.dll"] = pool.submit(_binary, src, sources, mingw, True)
            members.update({member: job.result() for member, job in jobs.items()})
        members.update({f"sources/{f}": d for f, d in sorted(sources.items())})
        members["sources/CMakeLists.txt"] = cmake_lists(identifier, names).encode()
        members["sources/README"] = readme(identifier, names, notes, fmi).encode()
    with files.replacing(dest) as tmp:  # a build that fails or is killed leaves the previous FMU intact
        write_zip(tmp, members)
    return notes
