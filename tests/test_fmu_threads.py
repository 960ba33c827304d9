"""Native FMU instances on threads, one per thread (what FMI allows), under ThreadSanitizer: the FMI layer's
registries of instances and FMU states are shared by every instance of the library, and what one thread's
fmi2FreeInstance reads there (each state's owner, to free the instance's states with it) another thread's
fmi2GetFMUstate must not write outside the registry's lock (fmi_services.c: mbs_fmu_state_sized).

The FMI 2.0 layer and the engine are compiled from the package's C sources with -fsanitize=thread, the host
(tests/c/fmu_threads.c) too; any report of ThreadSanitizer fails the test. Skipped where the compiler has no
ThreadSanitizer runtime.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import mbsfmu
from mbsfmu.engine import build
from mbsfmu.fmu import native
from mbsfmu.simulation import compiled

REPO = Path(__file__).resolve().parents[1]
HOST = REPO / "tests" / "c" / "fmu_threads.c"
GUID = "{00000000-0000-0000-0000-000000000034}"
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="pthreads and dlopen: linux")


def _tsan(cc, tmp_path):
    """Whether cc builds and runs a program with -fsanitize=thread here."""
    probe = tmp_path / "probe.c"
    probe.write_text("int main(void) { return 0; }\n")
    r = subprocess.run([cc, "-fsanitize=thread", "-o", str(tmp_path / "probe"), str(probe)], capture_output=True)
    return r.returncode == 0 and subprocess.run([str(tmp_path / "probe")], capture_output=True).returncode == 0


def test_instances_on_threads_take_and_free_states_without_a_data_race(tmp_path):
    """One thread steps its instance and takes its FMU state again and again into the same state; three threads
    instantiate, step, take a state and free their instance, 200 times each: every call OK, and ThreadSanitizer
    reports nothing (before: a data race on the state's owner, written by fmi2GetFMUstate outside the lock and
    read by fmi2FreeInstance under it)."""
    cc = native.compiler()
    if cc is None or not _tsan(cc, tmp_path):
        pytest.skip("no C compiler with a ThreadSanitizer runtime")
    blob, _, _ = compiled(mbsfmu.load(REPO / "models" / "pendulum.yaml").spec, GUID, derivatives=True)
    (tmp_path / "resources").mkdir()
    (tmp_path / "resources" / "scene.bin").write_bytes(blob)
    srcs, _, defs = build.sources(build.features(blob))
    flags = ["-O0", "-g", "-std=c99", "-fsanitize=thread"]
    lib, host = tmp_path / "fmu.so", tmp_path / "host"
    for cmd in ([cc, *flags, "-shared", "-fPIC", *defs, *build.include_flags(), "-o", str(lib),
                 *map(str, srcs), str(build.FMI / "fmi2.c"), "-lm"],
                [cc, *flags, "-o", str(host), str(HOST), "-ldl", "-lpthread"]):
        r = subprocess.run(cmd, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr[-3000:]
    r = subprocess.run([str(host), str(lib), (tmp_path / "resources").as_uri(), GUID, "200"], capture_output=True,
                       text=True, timeout=300, env=dict(os.environ, TSAN_OPTIONS="exitcode=66 report_signal_unsafe=0"))
    assert "ThreadSanitizer" not in r.stderr, r.stderr[:6000]
    assert r.returncode == 0 and r.stdout.strip() == "DONE", (r.stdout, r.stderr[-3000:])
