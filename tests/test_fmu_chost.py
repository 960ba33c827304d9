"""The FMU in a C host without Python (like ecos/libcosim): a tiny FMI 2.0 master compiled with gcc.

pythonfmu's binary does not link libpython; the FMU's loader shim (fmu/shim.c) loads it with global
symbols, so the host runs with no LD_PRELOAD/PYTHONPATH/PYTHONHOME and must exit cleanly.
Skipped without gcc or a shared libpython.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sysconfig
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

HOST_C = r"""
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
typedef unsigned int vr_t;
typedef struct {
  void (*logger)(void*, const char*, int, const char*, const char*, ...);
  void* (*alloc)(size_t, size_t); void (*free)(void*); void* stepFinished; void* env;
} cb_t;
static void logger(void* env, const char* inst, int st, const char* cat, const char* msg, ...) {
  va_list ap; va_start(ap, msg); printf("LOG %d %s ", st, cat); vprintf(msg, ap); printf("\n"); va_end(ap);
  fflush(stdout);
}
int main(int argc, char** argv) {  /* lib resources_uri vr_out n h guid */
  void* h = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
  if (!h) { printf("DLOPEN %s\n", dlerror()); return 2; }
  void* (*inst)(const char*, int, const char*, const char*, const cb_t*, int, int) = dlsym(h, "fmi2Instantiate");
  int (*setup)(void*, int, double, double, int, double) = dlsym(h, "fmi2SetupExperiment");
  int (*enter)(void*) = dlsym(h, "fmi2EnterInitializationMode");
  int (*exitI)(void*) = dlsym(h, "fmi2ExitInitializationMode");
  int (*doStep)(void*, double, double, int) = dlsym(h, "fmi2DoStep");
  int (*getR)(void*, const vr_t*, size_t, double*) = dlsym(h, "fmi2GetReal");
  int (*term)(void*) = dlsym(h, "fmi2Terminate");
  void (*freeI)(void*) = dlsym(h, "fmi2FreeInstance");
  cb_t cb = { logger, calloc, free, NULL, NULL };
  void* c = inst("chost", 1, argv[6], argv[2], &cb, 0, 1);
  if (!c) { printf("INSTANTIATE failed\n"); return 3; }
  vr_t vout = (vr_t)atoi(argv[3]); int n = atoi(argv[4]); double dt = atof(argv[5]), t = 0, y = 0;
  setup(c, 0, 0, 0.0, 0, 0); enter(c); exitI(c);
  for (int i = 0; i < n; i++) {
    int s = doStep(c, t, dt, 1);
    if (s) { printf("DOSTEP %d\n", s); return 4; }
    t = (i + 1) * dt;
  }
  getR(c, &vout, 1, &y);
  printf("RESULT %.17g %.17g\n", t, y); fflush(stdout);
  term(c); freeI(c);
  printf("FREED\n"); fflush(stdout);
  return 0;
}
"""


def _libpython():
    if not sysconfig.get_config_var("Py_ENABLE_SHARED"):
        return None
    lib = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("LDLIBRARY")
    return lib if lib.exists() else None


@pytest.mark.skipif(shutil.which("gcc") is None or _libpython() is None, reason="needs gcc and a shared libpython")
def test_fmu_runs_in_a_c_host(tmp_path):
    import mbsfmu
    from fmpy import read_model_description

    from mbsfmu.simulation import Simulation

    host = tmp_path / "host"
    (tmp_path / "host.c").write_text(HOST_C)
    subprocess.run(["gcc", "-O1", "-o", str(host), str(tmp_path / "host.c"), "-ldl"], check=True)
    model = REPO / "models" / "double_pendulum.yaml"
    fmu = mbsfmu.build_fmu(model, tmp_path / "out")
    unz = tmp_path / "unz"
    zipfile.ZipFile(fmu).extractall(unz)
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    lib = unz / "binaries" / "linux64" / "double_pendulum.so"
    # no LD_PRELOAD, PYTHONPATH, PYTHONHOME: the FMU's loader shim finds libpython and site-packages
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON") and k != "LD_PRELOAD"}
    r = subprocess.run([str(host), str(lib), (unz / "resources").as_uri(), str(vr["y.phi1"]), "20", "0.01", md.guid],
                       capture_output=True, text=True, env=env, timeout=120, cwd=tmp_path)
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT")]
    assert lines, (r.returncode, r.stdout, r.stderr)
    t, y = map(float, lines[0].split()[1:])
    sim = Simulation(json.loads(json.dumps(mbsfmu.load(model).spec)))
    sim.initialize(0.0)
    for i in range(20):
        sim.do_step(i * 0.01, 0.01)
    assert t == pytest.approx(0.2) and y == pytest.approx(sim.get("y.phi1"), abs=1e-12)
    assert "FREED" in r.stdout
    # the host returns from main without dlclose: exit handlers and library destructors run in
    # exit()'s order (pythonfmu 0.7.0 used to write into freed heap there, see shim.c)
    assert r.returncode == 0, (r.returncode, r.stdout[-2000:], r.stderr[-4000:])
    assert "corrupted" not in r.stderr and "double free" not in r.stderr, r.stderr[-4000:]
