"""Where a sweep runs: batches of cases on a Dask cluster (an embedded LocalCluster, one process per core, or
an existing scheduler), or in this process. Progress bar with the estimated time left."""

import asyncio
import collections
import contextlib
import logging
import math
import os
import sys
import weakref

import numpy as np

from .runner import Rows, run_batch

BATCHES_PER_SLOT = 8   # several batches per worker: load balance and progress steps
BATCH_SECONDS = 0.2    # yet at least this much work per batch: each costs a round trip to its worker (~1.5 ms)
MAX_BATCH = 256        # long sweeps still report progress and lose little to a dying worker
AHEAD = 2              # batches in flight per worker thread: the next is there when one ends
WAIT_FOR_WORKERS = 60  # seconds an existing cluster may take to offer its first worker
HANDSHAKE_SECONDS = 3  # a Dask scheduler sends its handshake at once on a connection
LARGE_MODEL = 1 << 16  # bytes: larger models (FMUs) go to each station once; a scene's JSON rides with each batch


def run_cases(model, cases, setup, scheduler=None, workers=None, progress=None):
    """cases (a runner.Cases) → runner.Rows, in case order."""
    if progress is None:
        progress = sys.stderr.isatty()
    say = _say if progress else (lambda line: None)
    if scheduler == "inprocess":
        with _bar(len(cases), progress) as bar:
            parts = []
            for positions in batches(len(cases), 1, contiguous=True):
                parts.append(run_batch(model, cases.take(positions), setup))
                bar.update(len(positions))
            return Rows.join(parts, len(setup.outputs))
    with _client(scheduler, workers, say) as client:
        say(f"{len(cases)} case{'s' if len(cases) != 1 else ''} on {len(_threads(client))} worker(s); the first "
            "runs alone (it builds the model on a worker and times it) …")
        try:
            with _bar(len(cases), progress) as bar:  # from here: the cluster's start-up is no part of the rate
                return _on_cluster(client, model, cases, setup, bar)
        except KeyboardInterrupt:  # the calls in flight fail as the client closes: Dask's and asyncio's reports
            for name in ("asyncio", "distributed", "tornado"):  # of them would be tracebacks; Ctrl-C is one line
                logging.getLogger(name).setLevel(logging.CRITICAL + 1)
            raise


def _say(line):
    print(line, file=sys.stderr, flush=True)


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


def _on_cluster(client, model, cases, setup, bar):
    """The first case runs alone on a worker: its time sizes the batches. Each worker then runs batches through
    its Station (below), two in flight per worker thread, the next sent as one ends (slow workers get fewer).
    Nothing runs in this process: a case that kills its process (a crash in an FMU) takes a worker, never the
    sweep. When a station's call fails (its worker died), its batches' cases run once more, each alone, one at
    a time per worker, on the workers alive then (the nanny restarts dead ones); a case that fails alone again
    is recorded as failed, and the sweep goes on."""
    n_out = len(setup.outputs)
    parts, retry = [], []
    done, failed = _rounds(client, model, [cases.take([0])], setup, bar, ahead=1)
    cost = float(done[0].wall[0]) if done and done[0].status[0] == "ok" else None  # a failure says little
    parts += done
    retry += [c for c, _ in failed]
    rest = np.arange(1, len(cases))
    chunks = [cases.take(rest[p]) for p in batches(len(rest), sum(_threads(client).values()), cost)]
    done, failed = _rounds(client, model, chunks, setup, bar, ahead=AHEAD)
    parts += done
    retry += [c for c, _ in failed]
    alone = [c.take([k]) for c in retry for k in range(len(c))]
    done, failed = _rounds(client, model, alone, setup, bar, ahead=1, per_process=True)
    parts += done + [_failed_rows(c, e, n_out) for c, e in failed]
    bar.update(sum(len(c) for c, _ in failed))
    return Rows.join(parts, n_out)


def _rounds(client, model, chunks, setup, bar, ahead, per_process=False):
    """Run the batches on the stations of the workers alive, again on those alive then for batches no station
    took (all that were sent to died) → (Rows done, [(batch, why)] whose station call failed). per_process:
    one call in flight per worker process, so that a failure belongs to its one case."""
    done, failed, todo = [], [], list(chunks)
    while todo:
        try:
            threads = _living(client)
        except TimeoutError as e:  # no worker came back: what is left fails with the reason
            return done, failed + [(c, f"worker failed: {e}") for c in todo]
        stations = _stations(client, threads)
        sent = _send(client, model, stations)
        per = {a: 1 if per_process else n for a, n in threads.items() if a in stations}
        slots = [a for _ in range(ahead) for a, n in per.items() for _ in range(n)]  # one round over all first
        if not slots:
            return done, failed + [(c, "worker failed: no Dask worker took the case") for c in todo]
        ok, lost, todo = client.sync(_drive, stations, slots, sent, todo, setup, bar)
        done += ok
        unreachable = {addr for _, e, addr in lost if isinstance(e, OSError)}  # no answer: did the process die?
        gone = unreachable - _forget(client, unreachable)
        failed += [(c, "the worker process died running it" if addr in gone
                    else f"worker failed: {type(e).__name__}: {e}".rstrip(": ")) for c, e, addr in lost]
    return done, failed


def _forget(client, dead, wait=3.0):
    """Wait (a bounded time) until the scheduler no longer lists the workers whose stations failed: the next
    round must not send a case to a station that is gone, and blame the case."""
    import time
    end = time.monotonic() + wait
    while dead & set(client.nthreads()) and time.monotonic() < end:
        time.sleep(0.05)
    return dead & set(client.nthreads())  # those still there: the call failed, not the process


def _living(client):
    """{worker: threads} of the workers alive now (asked of the scheduler), waiting for one if none is."""
    threads = client.nthreads()
    if not threads:
        client.wait_for_workers(1, timeout=WAIT_FOR_WORKERS)
        threads = client.nthreads()
    return threads


def _send(client, model, stations):
    """A large model (an FMU) goes to each station once, then travels by its key."""
    if len(model.data) <= LARGE_MODEL:
        return model
    client.sync(asyncio.gather, *(s.keep(model) for s in stations.values()))
    return model._replace(data=None)


def _failed_rows(cases, why, n_out):
    n = len(cases)
    return Rows(cases.index, [f"{why} (twice; the second time the case ran alone)"] * n,
                np.full(n, math.nan), np.full((n, n_out), math.nan), [None] * n)


async def _drive(stations, slots, model, chunks, setup, bar):
    """On the client's event loop: keep every slot busy, the next batch to whichever station finished one; a
    station whose call failed gets no more. → (Rows of the batches done, [(batch, error, worker)] whose station
    call failed, batches never sent: every station failed)."""
    todo, running, done, failed, dead = collections.deque(chunks), {}, [], [], set()

    async def call(addr, chunk):
        return await stations[addr].run(model, chunk, setup)

    def start(addr):
        chunk = todo.popleft()
        task = asyncio.ensure_future(call(addr, chunk))
        task.add_done_callback(_quiet)
        running[task] = (addr, chunk)

    for addr in slots[:len(todo)]:
        start(addr)
    while running:
        finished, _ = await asyncio.wait(running, return_when=asyncio.FIRST_COMPLETED)
        for task in finished:
            addr, chunk = running.pop(task)
            if task.exception() is None:
                done.append(task.result())
                bar.update(len(chunk))
            else:
                failed.append((chunk, task.exception(), addr))
                dead.add(addr)
            if todo and addr not in dead:
                start(addr)
    return done, failed, list(todo)


def _quiet(task):
    """A call still running when the sweep stops (Ctrl-C, an error) fails as the client closes: its error is
    taken here, not printed by asyncio as a traceback ("Task exception was never retrieved")."""
    if not task.cancelled():
        task.exception()


class Station:
    """A sweep's stand on one Dask worker (a Dask actor, one per worker, kept while the client lives): runs
    batches on the worker's own threads. A call to an actor goes from the client straight to its worker; a task
    takes a round trip through the scheduler (here ~1.5 ms against 5–8 ms, most of a short sweep's overhead)."""

    def __init__(self):
        self.kept = {}  # model key → ModelData of a large model, sent once

    async def keep(self, model):
        while len(self.kept) >= 8:
            self.kept.pop(next(iter(self.kept)))
        self.kept[model.key] = model

    async def run(self, model, cases, setup):
        from dask.distributed import get_worker
        if model.data is None:
            model = self.kept[model.key]
        pool = get_worker().executors["default"]  # the worker's threads, as its tasks use them
        return await asyncio.get_running_loop().run_in_executor(pool, run_batch, model, cases, setup)


_STATIONS = weakref.WeakKeyDictionary()  # Client → {worker address: (Station actor, the future that keeps it)}


def _stations(client, threads):
    """{worker: Station actor} for the workers in `threads`, made on first use (one round trip for all)."""
    have = _STATIONS.setdefault(client, {})
    for gone in [a for a, (_, f) in have.items() if a not in threads or f.status != "finished"]:
        del have[gone]  # its worker left, or the actor was lost (a worker restart, client.restart())
    new = [a for a in threads if a not in have]
    if new:  # loose placement: should the worker die first, Dask may place it elsewhere and the call fails over
        made = [client.submit(Station, actor=True, workers=[a], allow_other_workers=True, pure=False) for a in new]
        with client.as_current():  # an actor binds to the current client: with several in this process, ours
            have.update((a, (actor, f)) for a, actor, f in zip(new, client.gather(made), made))
    return {a: actor for a, (actor, _) in have.items()}


def local_cluster(n):
    """The embedded cluster: n single-threaded worker processes; the scheduler hands every task to a
    worker at once (no root-task queuing), so a worker never waits a round trip between batches; the workers'
    statistical profiler is off (sampling every 10 ms, it cost a worker up to a third of its speed here); the
    workers ignore Ctrl-C (sweep/worker_setup.py)."""
    import dask
    from dask.distributed import LocalCluster
    with dask.config.set({"distributed.worker.preload": ["mbsfmu.sweep.worker_setup"],
                          "distributed.scheduler.worker-saturation": math.inf,
                          "distributed.worker.profile.enabled": False,
                          "distributed.admin.tick.interval": "200ms",
                          "distributed.admin.system-monitor.interval": "2s"}):
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address=":0", silence_logs=logging.ERROR)  # a free port: no note that 8787 is taken


@contextlib.contextmanager
def _client(scheduler, workers, say=lambda line: None):
    """A Dask client: on an embedded LocalCluster (closed afterwards), an address, or a Client given; on an
    existing cluster wait until `workers` workers (default 1) have joined (a sweep then uses all it finds)."""
    from dask.distributed import Client
    if scheduler is None:
        n = int(workers or os.cpu_count() or 1)
        if n < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        say(f"starting a local Dask cluster of {n} worker process{'es' if n != 1 else ''} …")
        with local_cluster(n) as cluster, Client(cluster, direct_to_workers=True) as client:  # ours: reachable
            yield client
        return
    with contextlib.ExitStack() as stack:
        if not isinstance(scheduler, Client):
            say(f"connecting to the Dask scheduler at {scheduler} …")
            check_scheduler(scheduler)
        client = scheduler if isinstance(scheduler, Client) else stack.enter_context(
            Client(scheduler, timeout=WAIT_FOR_WORKERS))
        need = int(workers or 1)
        if len(_threads(client)) < need:  # wait only when workers are missing
            try:
                client.wait_for_workers(need, timeout=WAIT_FOR_WORKERS)
            except TimeoutError:
                raise TimeoutError(f"fewer than {need} Dask workers joined {client.scheduler.address} within "
                                   f"{WAIT_FOR_WORKERS} s (start them with: dask worker ADDRESS)") from None
        yield client


def check_scheduler(address, timeout=HANDSHAKE_SECONDS):
    """A tcp:// address answers as a Dask scheduler: on a connection it sends its handshake unasked, a message
    framed by its length (8 bytes, little-endian). An HTTP server (the dashboard's port) sends nothing, and
    Dask would wait for ever; another server sends bytes that Dask would take for a length of exabytes.
    Other schemes (tls://, ucx://, ...) are left to Dask."""
    import socket
    import struct
    from urllib.parse import urlsplit
    text = str(address)
    url = urlsplit(text if "://" in text else f"tcp://{text}")
    if url.scheme != "tcp":
        return
    try:
        host, port = url.hostname, url.port
    except ValueError:
        port = None
    if not host or port is None:
        raise ValueError(f"--scheduler {text}: expected tcp://HOST:PORT")
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            head = b""
            while len(head) < 8:
                got = sock.recv(8 - len(head))
                if not got:
                    break
                head += got
    except socket.timeout:
        raise TimeoutError(f"{text} is not a Dask scheduler: it sent no Dask handshake within {timeout:g} s "
                           "(a dashboard or another server? the scheduler's address is printed when it starts, "
                           "default port 8786)") from None
    except OSError as e:
        raise OSError(f"cannot connect to the Dask scheduler at {text}: {e.strerror or e}") from None
    size = struct.unpack("<Q", head)[0] if len(head) == 8 else 0
    if not 0 < size <= 1 << 20:  # a handshake is a few hundred bytes
        raise ValueError(f"{text} is not a Dask scheduler: it answered with something else than a Dask handshake")


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


class _Bar:
    """tqdm's bar, its time left shown once enough cases have finished to estimate it (the first case alone
    also builds the model on its worker: its time says little of the rest), from the average rate since the
    cluster was up."""

    WAITING = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}, time left: estimating]"

    def __init__(self, bar):
        self.bar, self.enough = bar, max(2, math.ceil(bar.total / 20))

    def update(self, n):
        if self.bar.n < self.enough <= self.bar.n + n:
            self.bar.bar_format = None  # tqdm's own: with the time left
        self.bar.update(n)


@contextlib.contextmanager
def _bar(total, enabled):
    if not enabled:
        yield _NoBar()
        return
    from tqdm import tqdm
    with tqdm(total=total, desc="sweep", unit="case", file=sys.stderr, smoothing=0,
              bar_format=_Bar.WAITING) as bar:
        yield _Bar(bar)
