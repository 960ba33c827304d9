"""Preloaded by the embedded cluster's worker processes (dispatch.local_cluster): Ctrl-C in a terminal reaches
every process of its group, and a worker interrupted so prints its tracebacks; the sweep's own process stops
the cluster instead, its workers with it."""

import signal


def dask_setup(worker):
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the process's main thread: Ctrl-C reaches the worker as before
        pass
