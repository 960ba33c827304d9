"""The test session's one setting: BLAS (OpenBLAS, MKL, OpenMP) on one thread. The suite runs one test at a
time; on a machine whose cores are busy, a BLAS thread pool spinning for a core it does not get costs 15-30×
(the 1275-DOF dense eigh of tests/test_fe_reduce.py: 17 s instead of 1 s on two busy cores), and with the cores
idle a second thread saves little at these sizes. The variables reach every child process (fresh interpreters,
Dask workers, mbsfmu's own subprocesses); threadpoolctl limits the libraries this process may have loaded
before this file (a plugin importing numpy)."""
import os
import sys
from pathlib import Path

# the developer benchmarks (benchmarks/, not in the package) that some tests hold to the engine, and the oracles
# beside the tests (pinocchio_twin.py), importable in every worker whatever the current folder
sys.path[:0] = [str(Path(__file__).resolve().parents[1]), str(Path(__file__).resolve().parent)]

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

try:
    from threadpoolctl import threadpool_limits
except ImportError:  # not installed: the variables above still hold for what loads from here on
    pass
else:
    _BLAS = threadpool_limits(1)  # kept: the limit holds for the session


import pytest  # noqa: E402


@pytest.fixture
def private_fe_cache(tmp_path, monkeypatch):
    """$MBSFMU_CACHE in the test's own folder, so that FE reductions are made and cached afresh (tests/test_fe_*.py),
    with the compiled engine and its fastcall extension linked in from the shared cache: that cache is keyed by
    the engine's sources, and compiling it again costs about 20 s of CPU in every test that builds a pythonfmu
    FMU or starts a fresh interpreter."""
    from pathlib import Path

    from mbsfmu.engine import build
    cache = tmp_path / "cache"
    cache.mkdir()
    for find in (build.library_path, build.fastcall_path):
        try:
            path = find()
        except Exception:  # no compiler: the test meets the same failure where it needs the engine
            path = None
        if path is not None:
            (cache / Path(path).name).symlink_to(path)
    monkeypatch.setenv("MBSFMU_CACHE", str(cache))


# fmpy's logger proxy (fmpy/logging, addLoggerProxy) keeps ONE process-wide C pointer, s_logger, to the Python
# logger of the last fmi2CallbackFunctions it was given, and every FMI 2.0 message of every FMU whose callbacks went
# through it (fmpy's defaultCallbacks too) is formatted and passed to that pointer. A test's callbacks that die with
# the test (tests/test_fmu3.py's extreme-state test) leave it dangling: the freed ctypes thunk's memory is handed to
# the next one (an FMI 3.0 intermediateUpdate callback of tests/test_fmu3_intermediate.py), and the next FMI 2.0
# message (a pythonfmu FMU's discard in tests/test_fmu_build.py) called that callback on a freed FMU: a segfault.
# So every callbacks structure registered with the proxy lives for the session (a few per session).
try:
    import fmpy.logging as _fmpy_logging
except Exception:  # no fmpy, or no proxy for this platform: nothing keeps a pointer
    pass
else:
    _PROXIED = []
    _add_logger_proxy = _fmpy_logging.addLoggerProxy

    def _add_logger_proxy_kept(callbacks):
        _PROXIED.append(getattr(callbacks, "_obj", callbacks))  # byref(s) -> s, with its thunks
        return _add_logger_proxy(callbacks)

    _fmpy_logging.addLoggerProxy = _add_logger_proxy_kept
