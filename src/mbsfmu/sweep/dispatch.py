"""Where a sweep runs: batches of cases on a Dask cluster (an embedded LocalCluster, one process per core, or
an existing scheduler), or in this process. Progress bar with the estimated time left."""

import contextlib
import logging
import math
import os
import sys

import numpy as np

from .runner import Rows, run_batch

BATCHES_PER_SLOT = 8   # several batches per worker: load balance and progress steps
BATCH_SECONDS = 0.2    # yet at least this much work per task: a task costs ~2 ms of scheduling, a round trip ~6
MAX_BATCH = 256        # long sweeps still report progress and lose little to a dying worker
WAIT_FOR_WORKERS = 60  # seconds an existing cluster may take to offer its first worker
SCATTER_BYTES = 1 << 16  # larger models (FMUs) go to each worker once ahead; a scene's JSON rides with the tasks


def run_cases(model, cases, setup, scheduler=None, workers=None, progress=None):
    """cases (a runner.Cases) → runner.Rows, in case order."""
    if progress is None:
        progress = sys.stderr.isatty()
    with _bar(len(cases), progress) as bar:
        if scheduler == "inprocess":
            parts = []
            for positions in batches(len(cases), 1, contiguous=True):
                parts.append(run_batch(model, cases.take(positions), setup))
                bar.update(len(positions))
            return Rows.join(parts, len(setup.outputs))
        with _client(scheduler, workers) as (client, slots):
            return _on_cluster(client, slots, model, cases, setup, bar)


def batches(n, slots, cost=None, contiguous=False):
    """Split n cases into batches (numpy arrays of positions): about BATCHES_PER_SLOT per slot, but (given the
    seconds one case costs) at least BATCH_SECONDS of work each, a whole number per slot, never fewer batches
    than slots. Batch k takes every count-th case from the k-th on (contiguous: a run of cases), so that a grid's
    cheap and dear corners spread over all batches."""
    if n <= 0:
        return []
    size = max(1, math.ceil(n / (slots * BATCHES_PER_SLOT)))
    if cost is not None and math.isfinite(cost) and cost > 0:
        size = max(size, min(math.ceil(BATCH_SECONDS / cost), math.ceil(n / slots)))
    size = min(size, max(MAX_BATCH, math.ceil(n / slots)))
    count = math.ceil(n / size)
    count = math.ceil(count / slots) * slots if count > slots else count  # a whole number per slot: balance
    if contiguous:
        size = math.ceil(n / count)
        return [np.arange(k, min(k + size, n)) for k in range(0, n, size)]
    return [np.arange(k, n, count) for k in range(min(count, n))]


def _on_cluster(client, slots, model, cases, setup, bar):
    """The first case runs here, in the calling process: its row counts and its time sizes the batches, which
    then all go out at once in one message (no wave of probes: one round trip to the cluster in all)."""
    from dask.distributed import wait
    n_out = len(setup.outputs)
    parts, rest, cost = [], np.arange(len(cases)), None
    try:
        first = run_batch(model, cases.take(rest[:1]), setup)
        if first.status[0] == "ok":  # a failed case's time says little about the others'
            cost = float(first.wall[0])
        parts, rest = [first], rest[1:]
        bar.update(1)
    except Exception:  # the model does not load here (e.g. an FMU for the workers' platform): the workers say why
        pass
    shared = model
    if len(model.data) > SCATTER_BYTES:
        [shared] = client.scatter([model], broadcast=True, hash=False)
    chunks = [cases.take(rest[p]) for p in batches(len(rest), slots, cost)]
    futures = client.map(run_batch, [shared] * len(chunks), chunks, [setup] * len(chunks), pure=False)
    chunk = {f.key: c for f, c in zip(futures, chunks)}
    pending = set(futures)
    while pending:  # each batch's results are fetched as soon as it ends, while the other workers still compute
        done, pending = wait(pending, return_when="FIRST_COMPLETED")  # no polling (as_completed's thread waits
        for fut in done:                                              # in 100 ms steps)
            c = chunk[fut.key]
            try:
                got = fut.result()
            except (KeyboardInterrupt, SystemExit):
                raise
            except BaseException as e:  # the worker died (e.g. killed), the task failed or was cancelled
                msg = f"worker failed: {type(e).__name__}: {e}"
                got = Rows(c.index, [msg] * len(c), np.full(len(c), math.nan), np.full((len(c), n_out), math.nan),
                           [None] * len(c))
            parts.append(got)
            bar.update(len(c))
    return Rows.join(parts, n_out)  # the futures go with this frame: released without a request to wait for


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
    """(a Dask client, its worker threads): on an embedded LocalCluster (closed afterwards), an address, or a
    Client given; on an existing cluster wait until `workers` workers (default 1) have joined."""
    from dask.distributed import Client
    if scheduler is None:
        n = int(workers or os.cpu_count() or 1)
        if n < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        with local_cluster(n) as cluster, Client(cluster) as client:
            yield client, n
        return
    with contextlib.ExitStack() as stack:
        client = scheduler if isinstance(scheduler, Client) else stack.enter_context(
            Client(scheduler, timeout=WAIT_FOR_WORKERS))
        need = int(workers or 1)
        threads = _threads(client)  # wait only when workers are missing
        if len(threads) < need:
            try:
                client.wait_for_workers(need, timeout=WAIT_FOR_WORKERS)
            except TimeoutError:
                raise TimeoutError(f"fewer than {need} Dask workers joined {client.scheduler.address} within "
                                   f"{WAIT_FOR_WORKERS} s (start them with: dask worker ADDRESS)") from None
            threads = client.nthreads()
        yield client, max(1, sum(threads.values()))


def _threads(client):
    """{worker: threads}: from a cluster object made in this process (LocalCluster, dask-jobqueue, ...), which
    keeps a current copy over its watch stream, else one request to the scheduler."""
    info = getattr(getattr(client, "cluster", None), "scheduler_info", None)
    workers = info.get("workers") if info else None
    if workers:
        return {a: int(w.get("nthreads", 1)) for a, w in workers.items()}
    return client.nthreads()


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
