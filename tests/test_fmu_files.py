"""What an FMU reads at run time, both kinds, in the plain C host (tests/c/fmu_host.c): the fmuResourceLocation
forms FMI 2.0 allows (fmi2Instantiate: a URI per RFC 3986, scheme "file"; pathlib's `as_uri` is the independent
encoder), the ones it does not (refused with a message), files that are not regular files or are too large
(refused, never waited on), and memory over 10,000 instantiate/free cycles (optimizers, Monte Carlo).
Skipped without a C compiler or a shared libpython (the pythonfmu kind in a C host needs one).
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

import mbsfmu
from mbsfmu.fmu import native

REPO = Path(__file__).resolve().parents[1]
KINDS = ("pythonfmu", "native")
SCENE = {"pythonfmu": "mbsfmu_scene.bin", "native": "scene.bin"}
LIMIT = 1 << 30   # engine/fmu_files.h MBS_SCENE_FILE_LIMIT

pytestmark = pytest.mark.skipif(native.compiler() is None or not sysconfig.get_config_var("Py_ENABLE_SHARED"),
                                reason="needs a C compiler and a shared libpython")


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    out = tmp_path_factory.mktemp("fmus")
    return {kind: mbsfmu.build_fmu(REPO / "models" / "pendulum.yaml", out / kind, kind=kind) for kind in KINDS}


@pytest.fixture(scope="module")
def host(tmp_path_factory):
    exe = tmp_path_factory.mktemp("host") / "fmu_host"
    subprocess.run([native.compiler(), "-O2", "-o", str(exe), str(REPO / "tests" / "c" / "fmu_host.c"), "-ldl"],
                   check=True)
    return exe


def unpack(fmu, where):
    """(library, resources folder, GUID, output value references) of the FMU extracted into where."""
    with zipfile.ZipFile(fmu) as z:
        z.extractall(where)
        md = z.read("modelDescription.xml").decode()
    guid = re.search(r'guid="([^"]+)"', md).group(1)
    outs = ",".join(re.findall(r'valueReference="(\d+)"[^>]*causality="output"', md))
    return Path(where) / "binaries" / "linux64" / "pendulum.so", Path(where) / "resources", guid, outs


def run(host, lib, uri, guid, *args, timeout=60):
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON") and k != "LD_PRELOAD"}
    return subprocess.run([str(host), str(lib), uri, guid, *args], capture_output=True, text=True, timeout=timeout,
                          env=env)


def refused(r):
    """The logged reason of a refused fmi2Instantiate (exit code 3 of fmu_host), else fail."""
    errors = [ln for ln in r.stdout.splitlines() if ln.startswith("LOG 3 logStatusError host: fmi2Instantiate: ")]
    assert r.returncode == 3 and errors and "FAIL fmi2Instantiate" in r.stdout, (r.returncode, r.stdout, r.stderr)
    return errors[0]


@pytest.mark.parametrize("kind", KINDS)
def test_every_file_uri_form_loads_the_same_model(fmus, host, tmp_path, kind):
    """A folder name needing escapes (UTF-8, space, '#', '%'): file:///, file:/, file://localhost/, lower-case
    escapes, upper-case scheme, trailing slash or not: all run and give the same outputs."""
    lib, res, guid, outs = unpack(fmus[kind], tmp_path / "ü #%41 x")
    uri = res.as_uri()   # RFC 3986 escapes: ü -> %C3%BC, ' ' -> %20, '#' -> %23, '%' -> %25
    assert "%C3%BC%20%23%2541" in uri and uri.startswith("file:///")
    path = uri[len("file://"):]
    forms = [uri, uri + "/", "file:" + path, "file://localhost" + path, "file://localhost" + path + "/",
             "FILE://" + path, "file://LocalHost" + path,
             "file://" + re.sub(r"%[0-9A-F]{2}", lambda m: m.group().lower(), path)]
    rows = set()
    for form in forms:
        r = run(host, lib, form, guid, "-n", "5", "-o", outs, "-p")
        assert r.returncode == 0 and "DONE" in r.stdout, (form, r.stdout[-2000:], r.stderr[-2000:])
        rows.add(tuple(ln for ln in r.stdout.splitlines() if ln.startswith("OUT ")))
    assert len(rows) == 1 and len(next(iter(rows))) == 6


@pytest.mark.parametrize("kind", KINDS)
def test_locations_the_standard_does_not_allow_are_refused(fmus, host, tmp_path, kind):
    lib, res, guid, _ = unpack(fmus[kind], tmp_path / "fmu")
    path = res.as_uri()[len("file://"):]
    cases = {"http:" + "//host" + path: "not a file URI", "https://host" + path: "not a file URI",
             "ftp://host" + path: "not a file URI", str(res): "not a file URI", "resources": "not a file URI",
             "./resources": "not a file URI", "file:resources": "absolute path",
             "file://otherhost" + path: "absolute path",
             "file://" + path + "%4": "percent escape", "file://" + path + "%zz": "percent escape",
             "file://" + path + "%00": "percent escape", "file://" + path + "%2Fx": "percent escape",
             "file://" + path + "#x": "fragment", "file://" + path + "?x=1": "query",
             "file://" + path + "/../nothing": "", "": "no fmuResourceLocation"}
    for uri, why in cases.items():
        message = refused(run(host, lib, uri, guid))
        assert why in message, (uri, message)


def special(kind, path):
    """Put a non-regular or oversized file at path."""
    path.unlink()
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    elif kind == "device":
        path.symlink_to("/dev/zero")
    else:   # sparse: no disk used
        with open(path, "wb") as f:
            f.truncate(LIMIT + 1)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("what", ["fifo", "folder", "device", "oversized"])
def test_special_files_as_the_scene_are_refused_without_hanging(fmus, host, tmp_path, kind, what):
    lib, res, guid, _ = unpack(fmus[kind], tmp_path / "fmu")
    special(what, res / SCENE[kind])
    message = refused(run(host, lib, res.as_uri(), guid, timeout=30))   # a FIFO opened blocking would hang here
    assert SCENE[kind] in message
    assert ("more than this FMU reads" if what == "oversized" else "not a regular file") in message, message


@pytest.mark.parametrize("member", ["slavemodule.txt", "entry", "slave", "engine", "bytecode"])
def test_pythonfmu_kind_checks_every_file_it_reads(fmus, host, tmp_path, member):
    """pythonfmu reads slavemodule.txt and the entry script, Python imports the slave and the runtime (and reads
    their cached bytecode) and loads the engine library: a FIFO in place of any of them is refused before anything
    opens it."""
    lib, res, guid, _ = unpack(fmus["pythonfmu"], tmp_path / "fmu")
    module = (res / "slavemodule.txt").read_text().strip()
    cache = next(res.glob("mbsfmu_rt_*")) / "__pycache__"
    cache.mkdir()
    (cache / f"errors.{sys.implementation.cache_tag}.pyc").write_bytes(b"")
    target = {"slavemodule.txt": res / "slavemodule.txt", "entry": res / f"{module}.py",
              "slave": res / f"{module}_slave.py", "engine": next(res.glob("mbsfmu_rt_*/engine/libmbsfmu_engine_*")),
              "bytecode": cache / f"errors.{sys.implementation.cache_tag}.pyc"}
    special("fifo", target[member])
    message = refused(run(host, lib, res.as_uri(), guid, timeout=30))
    assert target[member].name in message and "not a regular file" in message, message


@pytest.mark.parametrize("kind", KINDS)
def test_instantiate_free_cycles_keep_memory_flat(fmus, host, tmp_path, kind):
    """10,000 cycles of fmi2Instantiate, initialization, one step, fmi2FreeInstance: the resident set grows by at
    most 1 kB per cycle between cycles 1,000 and 10,000 (the pythonfmu kind used to grow 36 kB per cycle)."""
    lib, res, guid, _ = unpack(fmus[kind], tmp_path / "fmu")
    r = run(host, lib, res.as_uri(), guid, "-C", "10000", "-n", "1", timeout=300)
    assert r.returncode == 0 and "DONE" in r.stdout, (r.stdout[-2000:], r.stderr[-2000:])
    rss = dict(map(int, ln.split()[1:]) for ln in r.stdout.splitlines() if ln.startswith("RSS "))
    assert rss[1000] > 0 and (rss[10000] - rss[1000]) / 9000 <= 1.0, rss


REUSE = r'''
from fmpy.fmi2 import fmi2LastSuccessfulTime
fmu, work = sys.argv[1:3]
md = read_model_description(fmu)
vr = {v.name: v.valueReference for v in md.modelVariables}
outs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
folder = {where: fmpy.extract(fmu, os.path.join(work, where)) for where in ("shared", "other")}


def new(tag, where, logging=False):
    s = FMU2Slave(guid=md.guid, unzipDirectory=folder[where], modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=tag)
    s.instantiate(callbacks=cb, loggingOn=logging)
    return s


def run(s, t0=None):
    """Initialization (without fmi2SetupExperiment if t0 is None), then 5 steps; (start time, output rows)."""
    if t0 is not None:
        s.setupExperiment(startTime=t0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    t = s.getRealStatus(fmi2LastSuccessfulTime)
    rows = [s.getReal(outs)]
    steps(s, t, 5)
    return t, rows + [s.getReal(outs)]


a = new("a", "shared")
a.setReal([vr["L"]], [1.3])
a.setString([vr["integrator.method"]], ["rk4"])
a_time, _ = run(a, 2.0)
a.terminate()
a.freeInstance()                  # fmpy also unloads the library here: the shim stays, with its pool
n = len(LOG)
b = new("b", "shared", logging=True)   # gets a's pythonfmu component from the shim's pool
method = b.getString([vr["integrator.method"]])[0].decode()
refused = status(b.setString, [vr["integrator.method"]], ["bogus"])
b.setString([vr["integrator.method"]], [method])
b_time, b_rows = run(b)
b.freeInstance()
ref = new("ref", "other")              # another folder: a component of its own
ref_time, ref_rows = run(ref, 0.0)
print("RESULT " + json.dumps({"a_time": a_time, "b": [b_time, b_rows], "ref": [ref_time, ref_rows],
                              "refused": refused, "log": LOG[n:]}))
'''


def test_a_reused_instance_is_a_fresh_one(fmus, tmp_path):
    """The shim gives a freed instance's pythonfmu component to the next fmi2Instantiate of the same folder: the
    new instance starts as a new one would (parameters, integrator and start time of the scene), and messages of
    the component reach the new instance's logger under its name. Reference: an instance from another folder."""
    import json
    from test_fmu_hostile import FMPY_CHILD
    r = subprocess.run([sys.executable, "-c", FMPY_CHILD + REUSE, str(fmus["pythonfmu"]), str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")]
    assert r.returncode == 0 and lines, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    res = json.loads(lines[0][7:])
    assert res["a_time"] == 2.0 and res["b"][0] == 0.0 and res["b"] == res["ref"]
    assert res["refused"] == 3
    names = {name for name, *_ in res["log"]}
    slave = [msg for name, _, _, msg in res["log"] if msg.startswith("set integrator.method='bogus'")]
    assert names == {"b"} and slave, res["log"]   # the slave's own message, through pythonfmu, named b


def test_resource_path_decodes_as_pythons_uri_parser():
    """engine/fmu_files.c's parser (both kinds) against urllib's RFC 3986 parsing on 2,000 random folder names
    (UTF-8, spaces, '#', '?', '%', reserved characters) written as pathlib's file URIs in every allowed form and with
    the characters RFC 3986 allows in a path left unescaped."""
    import ctypes
    import random
    from urllib.parse import quote, unquote_to_bytes, urlsplit
    from mbsfmu.engine import library
    fn = library().mbs_resource_path
    fn.restype, fn.argtypes = ctypes.c_int, [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_size_t,
                                             ctypes.c_char_p, ctypes.c_size_t]

    def parse(uri):
        out, err = ctypes.create_string_buffer(4096), ctypes.create_string_buffer(512)
        return None if fn(uri.encode(), b"scene.bin", out, len(out), err, len(err)) else out.value

    rng = random.Random(7)
    chars = "aZ09 -_.~#?%&=+;,:@!$'()*[]üé中\u00a0"
    for _ in range(2000):
        folder = Path("/tmp", *("".join(rng.choice(chars) for _ in range(rng.randint(1, 8))) for _ in range(3)))
        uri = folder.as_uri()
        want = unquote_to_bytes(urlsplit(uri).path).rstrip(b"/") + b"/scene.bin"
        assert want == os.fsencode(folder) + b"/scene.bin"
        path = uri[len("file://"):]
        raw = "file://" + quote(os.fsencode(folder), safe="/:@!$&'()*+,;=")   # RFC 3986 pchars left unescaped
        for form in (uri, uri + "/", "file:" + path, "file://localhost" + path, raw):
            assert parse(form) == want, form
    for uri in ("file://host/x", "http://localhost/x", "file:x/y", "/abs/path", "file:///a%2Fb", "file:///a%0",
                "file:///a#b", "file:///a?b", "file:///a%00b"):
        assert parse(uri) is None, uri
