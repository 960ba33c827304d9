"""Where a sweep runs: batches of cases on a Dask cluster (an embedded LocalCluster, one process per core, or
an existing scheduler), or in this process. Progress bar with the estimated time left."""

import contextlib
import logging
import math
import os
import sys

import numpy as np

from .runner import run_batch

BATCHES_PER_SLOT = 8   # a few batches per worker: load balance and progress steps, little scheduling overhead
MAX_BATCH = 256        # long sweeps still report progress and lose little to a dying worker
WAIT_FOR_WORKERS = 60  # seconds an existing cluster may take to offer its first worker


def run_cases(model, cases, setup, scheduler=None, workers=None, progress=None):
    """cases [(case number, {name: value})] → rows of run_batch, in completion order."""
    if progress is None:
        progress = sys.stderr.isatty()
    with _bar(len(cases), progress) as bar:
        if scheduler == "inprocess":
            rows = []
            for batch in batches(cases, 1):
                rows += run_batch(model, batch, setup)
                bar.update(len(batch))
            return rows
        with _client(scheduler, workers) as client:
            return _on_cluster(client, model, cases, setup, bar)


def batches(cases, slots):
    size = min(MAX_BATCH, max(1, math.ceil(len(cases) / (slots * BATCHES_PER_SLOT))))
    return [cases[k:k + size] for k in range(0, len(cases), size)]


def _on_cluster(client, model, cases, setup, bar):
    from dask.distributed import as_completed
    slots = sum(client.nthreads().values())
    [shared] = client.scatter([model], broadcast=True, hash=False)  # the model travels once per worker
    pending = {client.submit(run_batch, shared, b, setup, pure=False): b for b in batches(cases, slots)}
    rows = []
    for fut in as_completed(list(pending)):
        batch = pending.pop(fut)
        try:
            rows += fut.result()
        except Exception as e:  # the worker died (e.g. killed): its cases fail, the sweep goes on
            nan = np.full(len(setup.outputs), np.nan)
            rows += [(i, f"worker failed: {type(e).__name__}: {e}", math.nan, nan, None) for i, _ in batch]
        fut.release()
        bar.update(len(batch))
    return rows


@contextlib.contextmanager
def _client(scheduler, workers):
    """A Dask client: on an embedded LocalCluster (closed afterwards), an address, or a Client given."""
    from dask.distributed import Client, LocalCluster
    if isinstance(scheduler, Client):
        yield scheduler
        return
    if scheduler is None:
        n = int(workers or os.cpu_count() or 1)
        if n < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                          silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
            yield client
        return
    with Client(scheduler, timeout=WAIT_FOR_WORKERS) as client:
        try:
            client.wait_for_workers(int(workers or 1), timeout=WAIT_FOR_WORKERS)
        except TimeoutError:
            raise TimeoutError(f"no Dask worker joined {scheduler} within {WAIT_FOR_WORKERS} s "
                               f"(start them with: dask worker {scheduler})") from None
        yield client


class _NoBar:
    def update(self, n):
        pass


@contextlib.contextmanager
def _bar(total, enabled):
    if not enabled:
        yield _NoBar()
        return
    from tqdm import tqdm
    with tqdm(total=total, desc="sweep", unit="case", file=sys.stderr, smoothing=0.1) as bar:
        yield bar
