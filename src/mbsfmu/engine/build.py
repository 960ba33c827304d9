"""Compiling the engine: which C sources a scene needs, and the in-process shared library.

The in-process library has every part (any scene can be loaded); a native FMU carries only the parts its scene
uses: the scene's feature bits set the switches (`sources(features)`: no elastic-body code for a rigid scene, no
expression machine where no number depends on parameters or time), and the files are those the FMI layer's
calls reach under these switches (`linked_sources`, read off the compiled objects), never a list kept by hand.
The integrators always stay, since `integrator.method` is a parameter.

The library is compiled once per source version with the system C compiler (`$CC` or `cc`) into
`$MBSFMU_CACHE` or `~/.cache/mbsfmu` (at install by `python -m mbsfmu.engine.build`, else on first use): a
directory of the user's that no one else can write, and a library there is loaded only if it is the one built
(its sha256 recorded beside it), never one a name alone points to (_cache_dirs, _cached).
Without a C compiler nothing can run in-process: `library_path()` raises EngineUnavailable saying so.
"""

import os
import sys
from pathlib import Path

from ..errors import EngineUnavailable

HERE = Path(__file__).parent
FMI = HERE.parent / "fmi"  # the FMI layers (fmi2.c, fmi3.c) and what they share
INCLUDE_DIRS = (HERE, FMI, FMI / "fmi2", FMI / "fmi3")  # where the engine's and FMI layers' #include "..." are found
# (folder, file): the engine's own files, then the FMI parts the in-process library carries too (scene files, the
# state header check, and the layers' shared code, which ctypes hosts in the tests call)
INSTANCE = ("instance.c", "rules.c", "ode.c", "run.c", "variables.c", "exchange.c", "state_bytes.c")  # instance.h
CORE = tuple((HERE, n) for n in ("fmu_files.c", "state_header.c", "model.c", "tree.c", "forces.c", "dynamics.c", "cholesky.c", "forward.c", "deriv.c", *INSTANCE, "linalg.c")) \
    + tuple((FMI, n) for n in ("call_guard.c", "fmi_services.c", "fmi_calls.c")) \
    + tuple((HERE, p.name) for p in sorted(HERE.glob("integ_*.c")))
HEADERS = tuple((HERE, n) for n in ("mbs_engine.h", "mbs_integrator.h", "mbs_model.h", "mbs_layout.h", "mbs_vec3.h",
                                    "integ_base.h", "linalg.h", "instance.h", "rules.h", "fmu_files.h", "state_header.h")) \
    + tuple((FMI, n) for n in ("call_guard.h", "fmi_services.h", "fmi_calls.h"))
# optional parts: their files (elastic bodies: the equations and their complex twin for directional derivatives) and
# the switch that turns them on
OPTIONAL = {"expr": (("expr.c",), "-DMBS_WITH_EXPR"), "elastic": (("elastic.c", "deriv_elastic.c"), "-DMBS_WITH_ELASTIC")}
CFLAGS = ("-O2", "-std=c99", "-fPIC")
# Tried first, dropped where the compiler lacks them: link-time optimization (the engine's small accessors inline
# across files into the per-step path, issue 10) and plain complex arithmetic for deriv.c's complex step (no
# overflow-guarded division or NaN recovery calls: its numbers are the evaluation's, never near the limits)
LTO = ("-flto=auto", "-fcx-limited-range")


def features(blob):
    """Optional parts a compiled scene needs (from its header's feature bits)."""
    from . import layout as L
    import struct
    nsec = struct.unpack_from("<i", blob, L.FH_NSEC)[0]
    for s in range(nsec):
        sid, _, off, _ = struct.unpack_from(L.SECTION_ROW, blob, L.FH_SIZE + L.SR_SIZE * s)
        if sid == L.S_HEADER:
            bits = struct.unpack_from("<i", blob, off + 4 * L.H_FEATURES)[0]
            return {name for name, bit in L.names("MBS_FEATURES", 2).items() if bits & bit}
    raise ValueError("compiled scene without header")


def sources(feats=("expr", "elastic")):
    """(C sources, headers, -D flags) of an engine with the given optional parts."""
    feats = [f for f in OPTIONAL if f in feats and (HERE / OPTIONAL[f][0][0]).exists()]
    srcs = [d / s for d, s in CORE if (d / s).exists()] + [HERE / c for f in feats for c in OPTIONAL[f][0]]
    return srcs, [d / h for d, h in HEADERS if (d / h).exists()], [OPTIONAL[f][1] for f in feats]


def include_flags():
    """-I flags for compiling engine and FMI sources from the package's folders."""
    return [f"-I{d}" for d in INCLUDE_DIRS]


_LINKED: dict = {}


def linked_sources(roots, defs, cc=None):
    """The engine C files a program made of `roots` (e.g. the FMI layer) links, compiled with the switches
    `defs`: the closure over undefined symbols, read off the compiled objects with nm. Derived from what each
    kept file calls, so a call a switch leaves in can never meet a file left out (the link would fail).
    Without nm: every engine file."""
    import hashlib
    import shutil
    import subprocess
    import tempfile
    cands = [d / s for d, s in CORE] + [HERE / c for files, _ in OPTIONAL.values() for c in files]
    files = [*roots, *(c for c in cands if c not in roots)]
    key = hashlib.sha256(" ".join(defs).encode())
    for p in sorted(files) + sorted(p for d in INCLUDE_DIRS for p in d.glob("*.h")):
        key.update(p.name.encode() + p.read_bytes())
    key = key.hexdigest()
    if key in _LINKED:
        return _LINKED[key]
    cc = cc or compiler()
    nm = shutil.which("nm") or subprocess.run([cc, "-print-prog-name=nm"], capture_output=True, text=True).stdout.strip()
    if not nm or not shutil.which(nm):
        return list(files)
    defined, undefined = {}, {}
    with tempfile.TemporaryDirectory(prefix="mbsfmu_nm_") as tmp:
        for k, f in enumerate(files):
            obj = Path(tmp) / f"{k}.o"
            r = subprocess.run([cc, "-c", "-O0", "-std=c99", *defs, *include_flags(), "-o", str(obj),
                                str(f)], capture_output=True, text=True)
            if r.returncode:
                raise EngineUnavailable(f"compiling {f.name} failed: {r.stderr.strip()[:2000]}")
            table = subprocess.run([nm, "-P", "-g", str(obj)], capture_output=True, text=True, check=True).stdout
            syms = [ln.split()[:2] for ln in table.splitlines() if len(ln.split()) >= 2]
            undefined[f] = {s for s, t in syms if t == "U"}
            for s, t in syms:
                if t != "U":
                    defined.setdefault(s, f)
    keep, todo = set(), list(roots)
    while todo:
        f = todo.pop()
        if f not in keep:
            keep.add(f)
            todo += [defined[s] for s in undefined[f] if s in defined]
    _LINKED[key] = [f for f in files if f in keep]
    return _LINKED[key]


def compiler():
    import shutil
    cc = os.environ.get("CC") or "cc"
    if shutil.which(cc) is None:
        raise EngineUnavailable(f"no C compiler ('{cc}'): mbsfmu's engine is C and compiles on first use; install "
                                "gcc (Debian: apt-get install gcc) or set $CC")
    return cc


def run_cc(cmd):
    """Run a compile command [cc, args...] with the LTO flags, or without them where the compiler lacks them; the
    CompletedProcess of the last try."""
    import subprocess
    res = subprocess.run([cmd[0], *LTO, *cmd[1:]], capture_output=True, text=True)
    return subprocess.run(cmd, capture_output=True, text=True) if res.returncode else res


def compile_shared(out, feats=("expr", "elastic"), extra=(), cc=None):
    """Compile the engine (and extra sources, e.g. the FMI layer) into the shared library `out`."""
    srcs, _, defs = sources(feats)
    cmd = [cc or compiler(), *CFLAGS, "-shared", *defs, *include_flags(), "-o", str(out), *map(str, srcs), *map(str, extra), "-lm"]
    res = run_cc(cmd)
    if res.returncode:
        raise EngineUnavailable(f"compiling the engine failed: {res.stderr.strip()[:2000]}")
    return out


def _tag():
    import hashlib
    srcs, hdrs, defs = sources()
    h = hashlib.sha256(" ".join(CFLAGS + LTO + tuple(defs)).encode() + sys.platform.encode())
    for p in sorted(srcs + hdrs):
        h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()[:16]


def _unsafe(path, kind, follow=False):
    """Why code loaded from path (a directory, or a file: `kind` stat.S_ISDIR or S_ISREG) could be someone
    else's (None if it cannot): it must be this user's and writable by no one else, who could plant a library
    there. `follow`: path may be a symbolic link (one the user set up)."""
    import stat
    try:
        st = os.stat(path) if follow else os.lstat(path)
    except OSError as e:
        return (e.strerror or str(e)).lower()
    if not kind(st.st_mode):
        return "not a directory" if kind is stat.S_ISDIR else "not a regular file"
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        return f"owned by uid {st.st_uid}, not by this user (uid {os.getuid()})"
    if hasattr(os, "getuid") and st.st_mode & 0o022:
        who = " and ".join(w for bit, w in ((0o020, "its group"), (0o002, "others")) if st.st_mode & bit)
        return f"writable by {who} (mode {stat.S_IMODE(st.st_mode):o})"
    return None


def _private(d, follow=False):
    """d created (mode 0o700) if missing; None if it is then a directory only this user can write, else why not."""
    import stat
    try:
        d.parent.mkdir(parents=True, exist_ok=True)
        os.mkdir(d, 0o700)
    except FileExistsError:
        pass
    except OSError as e:
        return (e.strerror or str(e)).lower()
    return _unsafe(d, stat.S_ISDIR, follow)


_SCRATCH = None  # this process's own cache (tempfile.mkdtemp) where no other is usable, removed at exit


def _cache_dirs():
    """Where the compiled engine may be, in order: $MBSFMU_CACHE alone (EngineUnavailable if it is not a private
    directory), else ~/.cache/mbsfmu and $TMPDIR/mbsfmu-<uid> where private, and last a directory of this
    process's own (an unguessable name: compiled again by every process)."""
    global _SCRATCH
    import tempfile
    if os.environ.get("MBSFMU_CACHE"):
        d = Path(os.environ["MBSFMU_CACHE"]).expanduser()
        why = _private(d, follow=True)
        if why:
            raise EngineUnavailable(f"$MBSFMU_CACHE ({d}) cannot hold the compiled engine: {why}; compiled code is "
                                    "loaded only from a directory of yours that no one else can write (mkdir -m "
                                    "700), or unset $MBSFMU_CACHE for ~/.cache/mbsfmu")
        yield d
        return
    uid = os.getuid() if hasattr(os, "getuid") else 0
    # (in the shared temporary folder a symbolic link is refused: its owner could point it elsewhere later)
    home, shared = Path.home() / ".cache" / "mbsfmu", Path(tempfile.gettempdir()) / f"mbsfmu-{uid}"
    for d, follow in ((home, True), (shared, False)):
        if _private(d, follow) is None:
            yield d
    if _SCRATCH is None:
        import atexit
        import shutil
        try:
            _SCRATCH = Path(tempfile.mkdtemp(prefix="mbsfmu-"))  # mode 0o700
        except OSError as e:
            raise EngineUnavailable(f"no directory for the compiled engine ({e}): set $MBSFMU_CACHE") from None
        atexit.register(shutil.rmtree, _SCRATCH, True)
    yield _SCRATCH


def _digest(path):
    import hashlib
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def _intact(out, sidecar):
    """Whether out is the library this user built there: both files this user's alone (_unsafe), out's sha256
    the one written into sidecar when it was built."""
    import stat
    try:
        return not (_unsafe(out, stat.S_ISREG) or _unsafe(sidecar, stat.S_ISREG)) and \
            sidecar.read_text().strip() == _digest(out)
    except OSError:
        return False


def _cached(name, build):
    """The file `name` in the first cache directory (_cache_dirs) that has it as built (_intact), else made there
    by build(path), or in the next where one is not writable; anything else in its place, damaged or planted, is
    built again. Atomic for concurrent processes (the compiler gives the same bytes for the same sources)."""
    import tempfile
    why = None
    for cache in _cache_dirs():
        out, sidecar = cache / name, cache / f"{name}.sha256"
        if _intact(out, sidecar):
            return out
        tmp = tmp_sum = None
        try:
            fd, tmp = tempfile.mkstemp(suffix=".so", dir=cache)
            os.close(fd)
            build(tmp)
            fd, tmp_sum = tempfile.mkstemp(suffix=".sha256", dir=cache)
            os.write(fd, _digest(tmp).encode())
            os.close(fd)
            os.replace(tmp, out)
            os.replace(tmp_sum, sidecar)
            return out
        except OSError as e:
            why = f"cannot write the compiled engine into {cache}: {e.strerror or e}"
        finally:
            for t in (tmp, tmp_sum):
                if t and os.path.exists(t):
                    os.unlink(t)
    raise EngineUnavailable(why)


def library_path():
    """The in-process engine library (compiled into the cache on first use)."""
    import sysconfig
    return _cached(f"libmbsfmu_engine_{_tag()}{sysconfig.get_config_var('SHLIB_SUFFIX') or '.so'}.1", compile_shared)


def fastcall_path():
    """The CPython extension of Instance.rhs (fastcall.c), compiled for this interpreter into the cache on first use;
    None where it cannot be (no Python headers, no compiler): Instance.rhs then calls through ctypes."""
    import hashlib
    import subprocess
    import sysconfig
    include = sysconfig.get_paths().get("include")
    src = HERE / "fastcall.c"
    if not include or not (Path(include) / "Python.h").exists():
        return None
    tag = hashlib.sha256(src.read_bytes() + include.encode() + sys.version.encode()).hexdigest()[:16]

    def build(out):
        r = subprocess.run([compiler(), *CFLAGS, "-shared", f"-I{include}", "-o", str(out), str(src)],
                           capture_output=True, text=True)
        if r.returncode:
            raise EngineUnavailable(f"compiling fastcall.c failed: {r.stderr.strip()[:2000]}")
    try:
        return _cached(f"_mbsfmu_fastcall_{tag}{sysconfig.get_config_var('EXT_SUFFIX') or '.so'}", build)
    except EngineUnavailable:
        return None


if __name__ == "__main__":  # python -m mbsfmu.engine.build: compile into the cache now (at install)
    print(library_path())
    print(fastcall_path() or "fastcall.c: not built (no Python headers); Instance.rhs calls through ctypes")
