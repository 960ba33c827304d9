"""fmpy's FMI 2.0 logger proxy (fmpy.logging.addLoggerProxy) and the suite: it keeps ONE process-wide pointer to
the Python logger of the last callbacks given to it and calls it for every FMI 2.0 message of every FMU, so a
test's callbacks that die with the test left it dangling. Once, the freed logger's memory became an FMI 3.0
intermediateUpdate callback (tests/test_fmu3_intermediate.py) and a pythonfmu FMU's discard message
(tests/test_fmu_build.py) called it on a freed FMU: a segfault of the full run. conftest.py keeps every callbacks
structure registered with the proxy for the session."""
import ctypes
import gc

import pytest

pytest.importorskip("fmpy")
from fmpy.fmi2 import defaultCallbacks, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE  # noqa: E402
from fmpy.fmi3 import fmi3IntermediateUpdateCallback  # noqa: E402

got = []


def _register_and_drop():
    """A test's way: local callbacks with its own logger, registered with the proxy, gone at return."""
    from fmpy.logging import addLoggerProxy
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg: got.append(msg.decode()))
    addLoggerProxy(ctypes.byref(cb))


def test_a_dropped_logger_never_becomes_another_callback():
    """After the callbacks are gone and ctypes callbacks are made afresh (the freed thunk's memory is reused), an
    FMI 2.0 message through fmpy's proxy reaches the registered logger, never a new callback."""
    called = []
    _register_and_drop()
    gc.collect()
    decoys = [fmi3IntermediateUpdateCallback(lambda *a: called.append(a)) for _ in range(8)]
    defaultCallbacks.logger(None, b"inst", 2, b"logStatusDiscard", b"t = 0.5: q.x is nan")  # fmpy's C proxy
    assert called == [] and got[-1:] == ["t = 0.5: q.x is nan"]
    del decoys
