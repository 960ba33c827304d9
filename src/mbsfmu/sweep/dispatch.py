"""Where a sweep runs: batches of cases on a Dask cluster (an embedded LocalCluster, one process per core, or
an existing scheduler), or in this process. Progress bar with the estimated time left."""

import contextlib
import logging
import math
import os
import sys

import numpy as np

from .runner import run_batch

BATCHES_PER_SLOT = 8   # several batches per worker: load balance and progress steps
BATCH_SECONDS = 0.2    # yet at least this much work per task: a task costs ~2 ms of scheduling, a round trip ~6
MAX_BATCH = 256        # long sweeps still report progress and lose little to a dying worker
WAIT_FOR_WORKERS = 60  # seconds an existing cluster may take to offer its first worker
SCATTER_BYTES = 1 << 16  # larger models (FMUs) go to each worker once ahead; a scene's JSON rides with the tasks


def run_cases(model, cases, setup, scheduler=None, workers=None, progress=None):
    """cases [(case number, {name: value})] → rows of run_batch (any order)."""
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


def batches(cases, slots, cost=None):
    """Split cases into equal batches: about BATCHES_PER_SLOT per slot, but (given the seconds one case costs)
    at least BATCH_SECONDS of work each, and never fewer batches than slots."""
    if not cases:
        return []
    size = max(1, math.ceil(len(cases) / (slots * BATCHES_PER_SLOT)))
    if cost is not None and math.isfinite(cost) and cost > 0:
        size = max(size, min(math.ceil(BATCH_SECONDS / cost), math.ceil(len(cases) / slots)))
    size = min(size, max(MAX_BATCH, math.ceil(len(cases) / slots)))
    count = math.ceil(len(cases) / size)
    count = math.ceil(count / slots) * slots if count > slots else count  # a whole number per slot: balance
    size = math.ceil(len(cases) / count)
    return [cases[k:k + size] for k in range(0, len(cases), size)]


def _on_cluster(client, model, cases, setup, bar):
    """The first case runs here, in the calling process: its row counts and its time sizes the batches, which
    then all go out at once (no wave of probes: one round trip to the cluster in all)."""
    slots = max(1, sum(client.nthreads().values()))
    try:
        rows, rest = run_batch(model, cases[:1], setup), cases[1:]
        cost = rows[0][2]
        bar.update(1)
    except Exception:  # the model does not load here (e.g. an FMU for the workers' platform): the workers say why
        rows, rest, cost = [], cases, None
    shared = model
    if len(model.data) > SCATTER_BYTES:
        [shared] = client.scatter([model], broadcast=True, hash=False)
    pending = {client.submit(run_batch, shared, b, setup, pure=False): b for b in batches(rest, slots, cost)}
    for fut, batch in pending.items():  # in order: the last batch ends the sweep anyway, and no watcher thread
        try:
            done = fut.result()
        except Exception as e:  # the worker died (e.g. killed): its cases fail, the sweep goes on
            nan = np.full(len(setup.outputs), np.nan)
            done = [(i, f"worker failed: {type(e).__name__}: {e}", math.nan, nan, None) for i, _ in batch]
        rows += done
        fut.release()
        bar.update(len(batch))
    return rows


def local_cluster(n):
    """The embedded cluster: n single-threaded worker processes; the scheduler hands every task to a
    worker at once (no root-task queuing), so a worker never waits a round trip between batches; the workers'
    statistical profiler is off (sampling every 10 ms, it cost a worker up to a third of its speed here)."""
    import dask
    from dask.distributed import LocalCluster
    with dask.config.set({"distributed.scheduler.worker-saturation": math.inf,
                          "distributed.worker.profile.enabled": False,
                          "distributed.admin.tick.interval": "200ms",
                          "distributed.admin.system-monitor.interval": "2s"}):
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=None, silence_logs=logging.ERROR)


@contextlib.contextmanager
def _client(scheduler, workers):
    """A Dask client: on an embedded LocalCluster (closed afterwards), an address, or a Client given; on an
    existing cluster wait until `workers` workers (default 1) have joined."""
    from dask.distributed import Client
    if scheduler is None:
        n = int(workers or os.cpu_count() or 1)
        if n < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        with local_cluster(n) as cluster, Client(cluster) as client:
            yield client
        return
    with contextlib.ExitStack() as stack:
        client = scheduler if isinstance(scheduler, Client) else stack.enter_context(
            Client(scheduler, timeout=WAIT_FOR_WORKERS))
        try:
            client.wait_for_workers(int(workers or 1), timeout=WAIT_FOR_WORKERS)
        except TimeoutError:
            raise TimeoutError(f"fewer than {workers or 1} Dask workers joined {client.scheduler.address} within "
                               f"{WAIT_FOR_WORKERS} s (start them with: dask worker ADDRESS)") from None
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
