"""Parameter sweeps (issue 14): results against an independent scipy integration of the pendulum ODE,
Latin-hypercube properties, failures recorded per case, an embedded 2-worker cluster and an external
`dask scheduler` + `dask worker` used through `mbsfmu sweep --scheduler`."""

import json
import math
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

pd = pytest.importorskip("pandas", reason="sweeps need pandas (pip install 'mbsfmu[sweep]')")
pytest.importorskip("dask.distributed", reason="sweeps need dask[distributed] (pip install 'mbsfmu[sweep]')")

import mbsfmu  # noqa: E402
from mbsfmu.cli import main  # noqa: E402
from mbsfmu.sweep.cases import latin_hypercube, make_cases  # noqa: E402

MODELS = Path(__file__).resolve().parents[1] / "models"
STOP = 1.5
M_ROD, M_BOB, R_BOB, G = 0.3, 1.0, 0.031, 9.81  # models/pendulum.yaml


def pendulum_angle(L, theta0, stop=STOP):
    """θ(stop) of models/pendulum.yaml, written here from scratch: rod (m_rod, length L, hinged at one end)
    plus a solid sphere (m_bob, r_bob) at its end; I_O θ'' = −g (m_rod L/2 + m_bob L) sin θ."""
    I_O = M_ROD * L**2 / 3 + M_BOB * (L**2 + 0.4 * R_BOB**2)
    w2 = G * (M_ROD * L / 2 + M_BOB * L) / I_O
    sol = solve_ivp(lambda t, x: [x[1], -w2 * math.sin(x[0])], (0, stop), [theta0, 0.0],
                    method="DOP853", rtol=1e-12, atol=1e-14)
    return sol.y[0, -1]


@pytest.fixture(scope="module")
def pendulum_theta0(tmp_path_factory):
    """models/pendulum.yaml with its initial angle as a parameter theta0 (varied like any parameter)."""
    text = (MODELS / "pendulum.yaml").read_text()
    assert "initial: {theta: pi/6}" in text
    text = text.replace("initial: {theta: pi/6}", "initial: {theta: theta0}")
    text = text.replace("parameters:\n", "parameters:\n  theta0: {value: 0.5, description: initial angle}\n", 1)
    path = tmp_path_factory.mktemp("sweep") / "pendulum_theta0.yaml"
    path.write_text(text)
    return path


def _check_angles(table, angle_name):
    assert (table["status"] == "ok").all(), table["status"].tolist()
    for _, row in table.iterrows():
        assert row["y.theta"] == pytest.approx(pendulum_angle(row["L"], row[angle_name]), abs=1e-6)


def test_grid_on_two_local_workers_matches_scipy(pendulum_theta0):
    """Length × initial angle on an embedded LocalCluster of 2 processes; rtol varied as an integrator setting."""
    vary = {"L": "0.5:1.1:3", "theta0": "0.2,1.0,2.5", "integrator.rtol": [1e-11]}
    table = mbsfmu.sweep(pendulum_theta0, vary=vary, stop=STOP, workers=2, outputs=["y.theta", "yd.theta"])
    assert len(table) == 9
    assert list(table.columns) == ["case", "L", "theta0", "integrator.rtol", "y.theta", "yd.theta", "status",
                                   "wall_time"]
    assert sorted(zip(table["L"], table["theta0"])) == sorted((L, a) for L in (0.5, 0.8, 1.1) for a in (0.2, 1.0, 2.5))
    _check_angles(table, "theta0")
    assert (table["wall_time"] > 0).all()


def test_initial_angle_as_y0():
    table = mbsfmu.sweep(MODELS / "pendulum.yaml", vary={"L": "0.5,1.1", "y0.theta": "0.2,2.5", "integrator.rtol": [1e-11]},
                         stop=STOP, scheduler="inprocess", outputs="y.theta")
    _check_angles(table, "y0.theta")


def test_series_long_format(pendulum_theta0):
    table, series = mbsfmu.sweep(pendulum_theta0, vary={"L": "0.6,0.9", "integrator.rtol": [1e-11]}, stop=0.5,
                                 step=0.1, series=True, scheduler="inprocess", outputs=["y.theta", "bob.r.z"])
    assert len(series) == 2 * 6 and list(series.columns) == ["case", "time", "y.theta", "bob.r.z"]
    for (case, t), row in series.set_index(["case", "time"]).iterrows():
        L = table.loc[case, "L"]
        assert row["y.theta"] == pytest.approx(pendulum_angle(L, 0.5, t) if t > 0 else 0.5, abs=1e-6)
        assert row["bob.r.z"] == pytest.approx(-L * math.cos(row["y.theta"]), abs=1e-12)  # bob at (0, 0, −L)
    last = series[series["time"] == 0.5].set_index("case")
    assert np.allclose(last["y.theta"], table["y.theta"], rtol=0, atol=0)


def test_latin_hypercube_reproducible_and_stratified():
    ranges = {"L": (0.5, 1.5), "m": (2.0, 3.0), "k": (-1.0, 1.0)}
    n = 40
    a, b, c = latin_hypercube(ranges, n, seed=7), latin_hypercube(ranges, n, seed=7), latin_hypercube(ranges, n, seed=8)
    assert a == b and a != c
    for name, (lo, hi) in ranges.items():
        x = np.array(a[name])
        assert ((x >= lo) & (x <= hi)).all()
        strata = np.floor((x - lo) / (hi - lo) * n).astype(int)
        assert sorted(strata) == list(range(n)), name  # one sample in each of the n equal strata


def test_samples_through_the_api(pendulum_theta0):
    vary = {"L": "0.5:1.5", "theta0": (0.1, 0.3)}
    table = mbsfmu.sweep(pendulum_theta0, vary=vary, samples=12, seed=3, stop=0.2, scheduler="inprocess")
    cases = make_cases(vary, samples=12, seed=3)
    assert table["L"].tolist() == cases["L"] and table["theta0"].tolist() == cases["theta0"]
    assert (table["status"] == "ok").all()


def test_failing_cases_are_recorded_and_the_rest_complete():
    """m_rod = 0 leaves the rod's inertia (xx = yy = 0, zz = 1e-7) breaking the triangle inequality, as the loader
    would say of the same numbers; 'bogus' is no method; the rest run."""
    table = mbsfmu.sweep(MODELS / "pendulum.yaml", vary={"m_rod": [0.0, 1e-6], "m_bob": "0,1",
                                                          "integrator.method": "dop853,bogus"}, stop=0.5, scheduler="inprocess", outputs=["y.theta"])
    status = dict(zip(zip(table["m_rod"], table["m_bob"], table["integrator.method"]), table["status"]))
    for m_bob in (0.0, 1.0):
        assert "m_rod = 0" in status[(0.0, m_bob, "dop853")] and "bodies.rod.inertia" in status[(0.0, m_bob, "dop853")]
        assert "triangle inequality" in status[(0.0, m_bob, "dop853")]
        assert "bogus" in status[(1e-6, m_bob, "bogus")]
    assert status[(1e-6, 1.0, "dop853")] == "ok"
    ok = table[table["status"] == "ok"]
    for _, row in ok.iterrows():
        # a compound pendulum: bob (a sphere at L) on a slender rod, I about the hinge and m g d by hand
        m_rod, m_bob, L = row["m_rod"], row["m_bob"], 0.8
        w2 = G * (m_bob * L + m_rod * L / 2) / (m_bob * (L**2 + 0.4 * R_BOB**2) + m_rod * L**2 / 3)
        ref = solve_ivp(lambda t, x: [x[1], -w2 * math.sin(x[0])], (0, 0.5), [math.pi / 6, 0], rtol=1e-12, atol=1e-14)
        assert row["y.theta"] == pytest.approx(ref.y[0, -1], abs=1e-6)
    assert len(ok) == 2  # m_bob = 0 too: the rod alone
    assert table[table["status"] != "ok"]["y.theta"].isna().all()


@pytest.mark.parametrize("argv, message", [
    (["--vary", "L=1:2"], "start:stop:count"),
    (["--vary", "L=1:2:x"], "not an integer"),
    (["--vary", "nope=1,2"], "cannot vary 'nope'"),
    (["--vary", "L=1,2", "--seed", "3"], "--seed applies to --samples"),
    (["--vary", "L=1,2", "--samples", "5"], "range lo:hi"),
    (["--vary", "L=1,2", "--outputs", "y.nope"], "not an output"),
    (["--vary", "L=1,2", "--out", "r.xlsx"], ".parquet or .csv"),
    (["--vary", "L"], "NAME=VALUE"),
])
def test_cli_errors_are_one_line(capsys, argv, message):
    assert main(["sweep", str(MODELS / "pendulum.yaml"), "--scheduler", "inprocess", *argv]) == 1
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_cli_grid_writes_table_series_and_plot(tmp_path, capsys):
    out, series, png = tmp_path / "r.parquet", tmp_path / "s.csv", tmp_path / "p.png"
    rc = main(["sweep", str(MODELS / "pendulum.yaml"), "--vary", "L=0.6:1.0:3", "--vary", "m_bob=0.5,1",
               "--stop", "0.3", "--scheduler", "inprocess", "-q", "--out", str(out), "--series", str(series),
               "--plot", str(png), "--outputs", "y.theta,bob.r.x"])
    assert rc == 0, capsys.readouterr().err
    table = pd.read_parquet(out)
    assert len(table) == 6 and (table["status"] == "ok").all()
    assert len(pd.read_csv(series)) == 6 * 31
    assert png.stat().st_size > 10_000


@pytest.fixture
def external_cluster(tmp_path):
    """`dask scheduler` and one `dask worker` as subprocesses on 127.0.0.1; yields the scheduler address."""
    dask = shutil.which("dask") or pytest.skip("the dask command is not on PATH")
    info = tmp_path / "scheduler.json"
    common = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path)
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(info)], **common)]
    try:
        deadline = time.monotonic() + 30
        while not info.exists() or not info.read_text().strip():
            assert time.monotonic() < deadline and procs[0].poll() is None, "dask scheduler did not start"
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        procs.append(subprocess.Popen([dask, "worker", address, "--host", "127.0.0.1", "--nthreads", "1",
                                       "--no-nanny", "--no-dashboard"], **common))
        yield address
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()


def test_external_scheduler_through_cli(external_cluster, pendulum_theta0, tmp_path, capsys):
    out = tmp_path / "r.csv"
    rc = main(["sweep", str(pendulum_theta0), "--vary", "L=0.7,1.2", "--vary", "theta0=0.4,2.0",
               "--vary", "integrator.rtol=1e-11", "--stop", str(STOP), "--scheduler", external_cluster,
               "--workers", "1", "-q", "--out", str(out), "--outputs", "y.theta"])
    assert rc == 0, capsys.readouterr().err
    table = pd.read_csv(out)
    assert len(table) == 4
    _check_angles(table, "theta0")


def test_sweep_of_a_built_fmu(tmp_path):
    """Explicit cases (a DataFrame) through fmpy on the pythonfmu FMU: instantiated once, fmi2Reset between
    cases, a fresh instance after the failing case (a massless rod whose inertia breaks the triangle inequality)."""
    fmu = mbsfmu.build_fmu(MODELS / "pendulum.yaml", tmp_path)
    cases = pd.DataFrame({"L": [0.5, 0.8, 1.1], "m_rod": [M_ROD, 0.0, M_ROD], "m_bob": [M_BOB, 0.0, M_BOB],
                          "integrator.rtol": [1e-11] * 3})
    table = mbsfmu.sweep(str(fmu), vary=cases, stop=STOP, step=0.05, scheduler="inprocess", outputs=["y.theta"])
    assert table["status"].tolist()[::2] == ["ok", "ok"]
    assert "m_rod = 0, m_bob = 0 make bodies.rod.inertia" in table["status"][1] and "triangle" in table["status"][1]
    for _, row in table.iloc[::2].iterrows():
        assert row["y.theta"] == pytest.approx(pendulum_angle(row["L"], math.pi / 6), abs=1e-6)


@pytest.mark.parametrize("n, slots, cost", [(200, 1, 6.6e-4), (200, 2, 6.6e-4), (5, 4, 1.0), (10_000, 32, 0.2),
                                            (7, 2, None), (1000, 3, math.nan), (0, 2, 1e-3), (1999, 2, 5e-4)])
def test_batches_cover_every_case_once_and_feed_every_slot(n, slots, cost):
    from mbsfmu.sweep.dispatch import BATCH_SECONDS, batches
    for contiguous in (False, True):
        bs = batches(n, slots, cost, contiguous=contiguous)
        assert sorted(int(i) for b in bs for i in b) == list(range(n))
        assert len(bs) >= min(n, slots)
        if contiguous:
            assert [int(i) for b in bs for i in b] == list(range(n))
        else:  # strided: a grid's corners spread over all batches; sizes differ by at most one
            assert all(np.all(np.diff(b) == len(bs)) for b in bs)
            assert not bs or max(map(len, bs)) - min(map(len, bs)) <= 1
        if (n, slots) == (1999, 2):  # 5 batches would leave one worker idle for the last fifth: 6 batches
            assert len(bs) == 6
        if cost and math.isfinite(cost) and len(bs) > slots:  # more batches than slots only with enough work each
            assert len(bs[0]) * cost >= BATCH_SECONDS / 2 or len(bs[0]) >= 256  # halved at most by whole rounds


def test_cases_by_column_round_trip():
    """Cases travel as columns (floats as float64 arrays, words and ints as lists) and come back as the same
    Python values, bit for bit, in the order taken."""
    import pickle
    from mbsfmu.sweep.runner import Cases
    cols = {"L": [0.1, 1 / 3, 2.5e-300], "integrator.method": ["dop853", "rk4", "radau5"], "n": [1, 2, 3]}
    cases = pickle.loads(pickle.dumps(Cases.from_columns(cols)))
    part = cases.take(np.array([2, 0]))
    assert part.index.tolist() == [2, 0]
    assert part.values(0) == {"L": 2.5e-300, "integrator.method": "radau5", "n": 3}
    assert type(part.values(1)["L"]) is float and part.values(1)["L"] == 0.1


@pytest.mark.parametrize("progress", [False, True])
def test_a_failed_batch_fails_its_cases_only(monkeypatch, progress):
    """A batch whose run fails on the cluster (here: raises for any batch holding case 5) runs its cases again,
    each alone: only case 5 is recorded as failed, with the reason; every other case completes. Threads in this
    process, so the patch reaches them."""
    from dask.distributed import Client, LocalCluster
    from mbsfmu.sweep import dispatch
    real = dispatch.run_batch

    def flaky(model, cases, setup):
        if 5 in cases.index:
            raise RuntimeError("lost the batch")
        return real(model, cases, setup)

    monkeypatch.setattr(dispatch, "run_batch", flaky)
    with LocalCluster(n_workers=1, threads_per_worker=4, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        table = mbsfmu.sweep(MODELS / "pendulum.yaml", vary={"L": "0.5:1.5:24"}, stop=0.1, scheduler=client,
                             outputs=["y.theta"], progress=progress)
    failed = table[table["status"] != "ok"]
    assert failed["case"].tolist() == [5]
    assert failed["status"].str.contains("worker failed: RuntimeError: lost the batch").all()
    assert failed["y.theta"].isna().all() and table.loc[table["status"] == "ok", "y.theta"].notna().all()
    assert table["case"].tolist() == list(range(24))


def test_a_failed_station_call_runs_its_cases_again(monkeypatch):
    """A batch whose call to its worker's Station fails (as when the worker dies: OSError) runs its cases once
    more, each alone; every case completes, equal to an in-process sweep."""
    from dask.distributed import Client, LocalCluster
    from mbsfmu.sweep import dispatch
    real, calls = dispatch.Station.run, []

    async def lost(self, model, cases, setup):
        calls.append(cases.index.tolist())
        if len(calls) == 1:
            raise OSError("Unable to contact Actor's worker")
        return await real(self, model, cases, setup)

    monkeypatch.setattr(dispatch.Station, "run", lost)
    kw = dict(vary={"L": "0.5:1.5:24"}, stop=0.1, outputs=["y.theta"], progress=False)
    with LocalCluster(n_workers=2, threads_per_worker=2, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        table = mbsfmu.sweep(MODELS / "pendulum.yaml", scheduler=client, **kw)
    assert len(calls) >= 2 and (table["status"] == "ok").all()
    ref = mbsfmu.sweep(MODELS / "pendulum.yaml", scheduler="inprocess", **kw)
    assert table["y.theta"].tolist() == ref["y.theta"].tolist()


def test_sweeps_on_two_clients_in_one_process():
    """Dask binds an actor to the process's current client; with two clients (the second the default), each
    sweep's stations must still answer through their own client: results, no hang."""
    from dask.distributed import Client, LocalCluster
    kw = dict(vary={"L": "0.5:1.5:6"}, stop=0.1, outputs=["y.theta"], progress=False)
    with LocalCluster(n_workers=1, processes=False, dashboard_address=None) as c1, Client(c1) as a, \
            LocalCluster(n_workers=1, processes=False, dashboard_address=None) as c2, Client(c2) as b:
        tables = [mbsfmu.sweep(MODELS / "pendulum.yaml", scheduler=c, **kw) for c in (a, b, a)]
    ref = mbsfmu.sweep(MODELS / "pendulum.yaml", scheduler="inprocess", **kw)
    for t in tables:
        assert t["y.theta"].tolist() == ref["y.theta"].tolist()


def test_a_worker_killed_mid_sweep_loses_no_case():
    """A worker process killed (SIGKILL) while its batches run: those batches run again as tasks on the living
    worker (the nanny restarts the dead one), every case ends ok, and the next sweep uses the new worker."""
    import os
    import signal
    import threading
    from dask.distributed import Client
    from mbsfmu.sweep.dispatch import local_cluster
    kw = dict(vary={"L": "0.5:1.5:400"}, stop=60.0, outputs=["y.theta"], progress=False)  # ~1.5 s per worker
    with local_cluster(2) as cluster, Client(cluster) as client:
        pids = list(client.run(os.getpid).values())
        mbsfmu.sweep(MODELS / "pendulum.yaml", scheduler=client, **{**kw, "stop": 0.1})  # stations made, warm
        timer = threading.Timer(0.3, os.kill, (pids[0], signal.SIGKILL))
        timer.start()
        first = mbsfmu.sweep(MODELS / "pendulum.yaml", scheduler=client, **kw)
        timer.join()
        client.wait_for_workers(2, timeout=60)
        assert pids[0] not in client.run(os.getpid).values()
        again = mbsfmu.sweep(MODELS / "pendulum.yaml", scheduler=client, **kw)
    assert (first["status"] == "ok").all() and (again["status"] == "ok").all()
    assert first["y.theta"].tolist() == again["y.theta"].tolist()


def test_an_unknown_name_lists_every_name_that_can_vary():
    with pytest.raises(ValueError) as e:
        mbsfmu.sweep(MODELS / "spinning_top.yaml", vary={"yd0.top.q0": [1.0]}, stop=0.1, scheduler="inprocess")
    assert "yd0.top.wz" in str(e.value) and "y0.top.q3" in str(e.value) and "spin" in str(e.value)


def test_a_native_fmu_sweeps_on_a_cluster(tmp_path):
    """A large model (the native FMU, ~350 KB) goes to each worker's station once, then batches name it by its
    key; two sweeps give the in-process sweep's values."""
    from dask.distributed import Client, LocalCluster
    fmu = mbsfmu.build_fmu(MODELS / "pendulum.yaml", tmp_path, kind="native")
    kw = dict(vary={"L": "0.5:1.5:8"}, stop=0.2, step=0.05, outputs=["y.theta"], progress=False)
    ref = mbsfmu.sweep(str(fmu), scheduler="inprocess", **kw)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        tables = [mbsfmu.sweep(str(fmu), scheduler=client, **kw) for _ in range(2)]
    for t in tables:
        assert (t["status"] == "ok").all() and t["y.theta"].tolist() == ref["y.theta"].tolist()


def test_sweeps_before_and_after_a_cluster_restart():
    """client.restart() kills the workers and with them the stations: the next sweep makes new ones."""
    from dask.distributed import Client
    from mbsfmu.sweep import dispatch
    from mbsfmu.sweep.dispatch import local_cluster
    kw = dict(vary={"L": "0.5:1.5:12"}, stop=0.2, outputs=["y.theta"], progress=False)
    with local_cluster(1) as cluster, Client(cluster) as client:
        before = mbsfmu.sweep(MODELS / "pendulum.yaml", scheduler=client, **kw)
        client.restart()
        after = mbsfmu.sweep(MODELS / "pendulum.yaml", scheduler=client, **kw)
        live = [f.status for _, f in dispatch._STATIONS[client].values()]
    assert (after["status"] == "ok").all() and after["y.theta"].tolist() == before["y.theta"].tolist()
    assert live == ["finished"]  # a new station, not the lost one (whose batches would go the slow way)


CRASH = """#include <signal.h>
int mbs_do_step(MbsInstance *s, double t, double h) {
    if (s->a < 0) {  /* this test's model: a case with a < 0 logs its a and kills its process */
        FILE *log = fopen(getenv("MBSFMU_TEST_CRASH_LOG"), "a");
        if (log) fprintf(log, "%g\\n", s->a), fclose(log);
        raise(SIGSEGV);
    }"""


@pytest.fixture(scope="module")
def crashing_fmu(tmp_path_factory):
    """A native FMU (benchmarks/fmu_trivial.c: x' = -a x, x(0) = 1, RK4 at 1 ms) whose step segfaults for a < 0:
    a model that kills the process running it in some cases. Built here only, from a patched copy."""
    from benchmarks import fmu_speed
    out = tmp_path_factory.mktemp("crash")
    src = fmu_speed.TRIVIAL_SOURCE.read_text()
    head = "int mbs_do_step(MbsInstance *s, double t, double h) {"
    assert head in src
    (out / "fmu_trivial.c").write_text(src.replace(head, CRASH))
    with pytest.MonkeyPatch.context() as m:
        m.setattr(fmu_speed, "TRIVIAL_SOURCE", out / "fmu_trivial.c")
        return fmu_speed.build_trivial_fmu(out)


def test_a_case_that_kills_its_worker_is_retried_once_then_recorded(crashing_fmu, tmp_path, monkeypatch, capsys):
    """Cases that segfault their worker (the first case among them, which once ran in the calling process and
    took the sweep along): each runs exactly twice (the crash log), then its row says the worker process died;
    every other case ends ok at the closed form exp(-a t); the command writes its table."""
    log = tmp_path / "crashes.txt"
    monkeypatch.setenv("MBSFMU_TEST_CRASH_LOG", str(log))  # the workers inherit it
    a = [-1.0, 1.0, 2.0, -2.0, 0.5, 3.0, 0.25, 1.5]
    out = tmp_path / "t.csv"
    assert main(["sweep", str(crashing_fmu), "--vary", "a=" + ",".join(map(str, a)), "--stop", "0.5",
                 "--step", "0.1", "--workers", "2", "--out", str(out), "-q", "--allow-failures"]) == 0
    table = pd.read_csv(out)
    assert table["case"].tolist() == list(range(len(a))) and table["a"].tolist() == a
    crashed = table["a"] < 0
    assert table.loc[crashed, "status"].str.contains("worker process died").all()
    assert table.loc[crashed, "status"].str.contains("twice").all() and table.loc[crashed, "y.x1"].isna().all()
    assert (table.loc[~crashed, "status"] == "ok").all()
    assert np.allclose(table.loc[~crashed, "y.x1"], np.exp(-table.loc[~crashed, "a"] * 0.5), rtol=1e-10, atol=0)
    assert sorted(map(float, log.read_text().split())) == [-2.0, -2.0, -1.0, -1.0]  # each crash case twice
    assert f"{len(a)} cases, 2 failed" in capsys.readouterr().out


def test_failed_cases_exit_1_and_a_dash_is_no_range(tmp_path, capsys):
    """Issue 34, item 8: failed cases make a non-zero exit after the table is written (--allow-failures: 0);
    `0.5-1.5` (or any word for a numeric name) is refused before any case runs, pointing to start:stop:count."""
    pendulum, out = str(MODELS / "pendulum.yaml"), tmp_path / "r.csv"
    argv = ["sweep", pendulum, "--vary", "m_rod=0,0.3", "--stop", "0.1", "--scheduler", "inprocess", "-q", "--out", str(out)]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: 1 of 2 cases failed (the first: m_rod = 0") and err.count("\n") == 1, err
    assert pd.read_csv(out)["status"].tolist()[1] == "ok"
    assert main(argv + ["--allow-failures"]) == 0
    for spec, words in (("0.5-1.5", "e.g. 0.5:1.5:11"), ("abc", "a range start:stop:count")):
        out.unlink(missing_ok=True)
        assert main(["sweep", pendulum, "--vary", f"L={spec}", "--scheduler", "inprocess", "--out", str(out)]) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"error: --vary L: '{spec}' is not a number") and words in err, err
        assert err.count("\n") == 1 and not out.exists()
    with pytest.raises(ValueError, match="'fast' is not a number"):
        mbsfmu.sweep(pendulum, vary={"L": ["fast"]}, scheduler="inprocess")
    assert (mbsfmu.sweep(pendulum, vary={"integrator.method": "rk4,dop853"}, stop=0.1, scheduler="inprocess")["status"] == "ok").all()


@pytest.mark.parametrize("reply", [b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n", b"\xff" * 64, None])
def test_a_scheduler_address_that_is_no_dask_scheduler(reply, capsys):
    """Issue 34, item 16: an address whose server answers HTTP or garbage, or says nothing (a dashboard's port):
    one line within a few seconds, not a wait for ever or Dask's "Unable to allocate 3.07 EiB"."""
    import socket
    import threading
    server = socket.create_server(("127.0.0.1", 0))
    conns = []

    def serve():
        while True:
            try:
                c, _ = server.accept()
            except OSError:
                return
            conns.append(c)
            if reply is not None:
                c.sendall(reply)
    threading.Thread(target=serve, daemon=True).start()
    address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
    t0 = time.monotonic()
    try:
        assert main(["sweep", str(MODELS / "pendulum.yaml"), "--vary", "L=1,2", "--stop", "0.1", "-q",
                     "--scheduler", address]) == 1
    finally:
        server.close()
        for c in conns:
            c.close()
    assert time.monotonic() - t0 < 15
    err = capsys.readouterr().err
    assert err.startswith(f"error: {address} is not a Dask scheduler: ") and err.count("\n") == 1, err
    assert ("no Dask handshake within 3 s" if reply is None else "something else") in err


def test_ctrl_c_during_a_sweep_is_one_line(tmp_path):
    """Issue 34, item 16: Ctrl-C in a terminal (SIGINT to the whole process group: the sweep and its embedded
    cluster's workers) while cases run: one line, exit 130, no traceback from any process."""
    import os
    import signal
    import sys
    script = tmp_path / "run.py"
    script.write_text(
        "import sys\nfrom mbsfmu.sweep import dispatch\nfrom mbsfmu.cli import main\n"
        "real = dispatch._on_cluster\n"
        "def running(*a, **k):\n    print('RUNNING', file=sys.stderr, flush=True)\n    return real(*a, **k)\n"
        "dispatch._on_cluster = running\n"
        f"if __name__ == '__main__':\n    sys.exit(main(['sweep', {str(MODELS / 'pendulum.yaml')!r}, '--vary', 'L=0.5:1.5:100000', '--stop', '20',"
        " '--workers', '2', '-q']))\n")
    p = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True, cwd=tmp_path)
    try:
        assert p.stderr.readline() == "RUNNING\n"
        time.sleep(1.5)  # batches on both workers
        os.killpg(p.pid, signal.SIGINT)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 130 and err == "interrupted\n", err


def test_an_input_table_is_held_in_every_case(tmp_path, capsys):
    """Issue 34, item 7: a sweep reads an input CSV as mbsfmu.simulate does (each row held until the next row's
    time, a row between communication points included), on a scene and on its FMU; against the closed form
    of a free mass m under the held force: x = Σ piecewise quadratics, and the CLI's --input FILE."""
    scene = tmp_path / "slider.yaml"
    scene.write_text("mbsfmu: 1\nname: slider\ngravity: [0, 0, 0]\nparameters:\n  m: {value: 2.0}\nbodies:\n"
                     "  cart:\n    parent: world\n    joint: {type: prismatic, axis: [1, 0, 0], coordinates: [x]}\n"
                     "    mass: m\n    inertia: {xx: 0.01, yy: 0.01, zz: 0.01}\n"
                     "integrator: {method: rk4}\nexperiment: {start: 0, stop: 3, step: 0.1}\n")
    table = tmp_path / "u.csv"
    table.write_text("time,q.x\n0,0\n1,5\n1.55,-1\n")

    def x(m, t=3.0):  # force 0 to 1 s, 5 N to 1.55 s, -1 N after
        a1, a2, h1, h2 = 5 / m, -1 / m, 0.55, t - 1.55
        return a1 * h1**2 / 2 + a1 * h1 * h2 + a2 * h2**2 / 2
    fmu = mbsfmu.build_fmu(scene, tmp_path)
    for model in (scene, fmu):
        res = mbsfmu.sweep(str(model), vary={"m": [1.0, 2.0, 4.0]}, input_table=str(table), scheduler="inprocess",
                           outputs=["y.x"])
        assert np.allclose(res["y.x"], [x(m) for m in res["m"]], rtol=0, atol=1e-12), res
    out = tmp_path / "r.csv"
    assert main(["sweep", str(scene), "--vary", "m=1,2", "--input", str(table), "--scheduler", "inprocess", "-q",
                 "--out", str(out)]) == 0
    assert np.allclose(pd.read_csv(out)["y.x"], [x(1.0), x(2.0)], rtol=0, atol=1e-12)
    assert main(["sweep", str(scene), "--vary", "q.x=1,2", "--input", str(table), "--scheduler", "inprocess"]) == 1
    assert "'q.x' is a column of the input table" in capsys.readouterr().err


PROXY_AFTER_SWEEP = """
import ctypes, gc, sys
import mbsfmu
from mbsfmu.sweep import runner
table = mbsfmu.sweep(sys.argv[1], vary={"L": [0.5, 1.0]}, stop=0.1, step=0.05, outputs=["y.theta"],
                     scheduler="inprocess", progress=False)
assert (table["status"] == "ok").all(), table
for r in list(runner._MODELS.values()):
    r.close()
runner._MODELS.clear()
gc.collect()
from fmpy.fmi2 import defaultCallbacks
from fmpy.fmi3 import fmi3IntermediateUpdateCallback
called = []
decoys = [fmi3IntermediateUpdateCallback(lambda *a: called.append(a)) for _ in range(8)]  # take freed thunks
defaultCallbacks.logger(None, b"other", 2, b"logStatusDiscard", b"another FMU's message")  # fmpy's C proxy
print("decoy called" if called else "ok")
"""


def test_fmu_sweep_leaves_no_dangling_fmpy_logger(tmp_path):
    """fmpy's logger proxy keeps one pointer per process to the last FMI 2.0 logger it was given; a sweep of an
    FMU in this process gives it the runner's, which must outlive the runner: after the sweep (runners closed), a
    ctypes callback made afresh is never called by another FMU's message (before: the freed logger's memory was
    the new callback's, and the message called it, here a harmless decoy, in the suite a freed FMU's
    intermediateUpdate: a segfault). In a fresh interpreter: conftest.py keeps the suite's loggers alive."""
    import sys
    fmu = mbsfmu.build_fmu(MODELS / "pendulum.yaml", tmp_path, kind="native")
    r = subprocess.run([sys.executable, "-c", PROXY_AFTER_SWEEP, str(fmu)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 and r.stdout.split()[-1:] == ["ok"], (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
