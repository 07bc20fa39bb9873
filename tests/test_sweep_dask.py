"""Sweeps on a real Dask cluster (LocalCluster, 2 worker processes with 1 thread each)."""
import logging
import os
import signal

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from fmu_sync.sweeps import sweep  # noqa: E402

SCENE = "forced-pair"
KW = dict(variant="switching", grid={"coupling.Kp": "logspace(-1, 1, 8)", "coupling.Kd": "logspace(-1, 0.5, 6)"},
          overrides={"run.t_end": 20.0}, chunk_size=3, plots=False, quiet=True)      # 48 runs, 16 chunks
VARS = ("status", "q1", "u1", "q2", "u2", "d0", "d_final", "d_max", "tau_max", "t_sync", "decay_rate",
        "impacts1", "impacts2", "episodes1", "episodes2")


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=logging.ERROR)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def embedded():
    return sweep(SCENE, **KW)


def _equal(a, b):
    for v in VARS:
        np.testing.assert_array_equal(a[v].values, b[v].values, err_msg=v)


def test_dask_sweep_equals_the_embedded_one(client, embedded):
    ds = sweep(SCENE, client=client, **KW)
    assert ds.attrs["engine"] == "dask" and ds.attrs["computed_runs"] == 48
    _equal(ds, embedded)


def test_scheduler_address_gives_the_same_sweep(client, embedded):
    ds = sweep(SCENE, scheduler=client.scheduler.address, **KW)
    assert ds.attrs["engine"] == "dask"
    _equal(ds, embedded)


def test_a_worker_killed_mid_sweep_loses_no_run_and_counts_none_twice(client, embedded, tmp_path):
    pids = client.run(os.getpid)               # worker processes of the cluster this test started
    assert len(pids) == 2
    victim = sorted(pids.values())[0]
    progress = []

    def kill_after_some_chunks(done, total, failed):
        progress.append(done)
        if done >= 9 and not killed:
            os.kill(victim, signal.SIGKILL)
            killed.append((victim, done))

    killed = []
    ds = sweep(SCENE, client=client, out=tmp_path, progress=kill_after_some_chunks, **KW)
    assert killed and killed[0][1] < 48          # killed mid-sweep
    with pytest.raises(ProcessLookupError):
        os.kill(victim, 0)
    # every chunk counted once: the count rises by whole chunks to exactly 48
    assert progress[-1] == 48 and all(b - a == 3 for a, b in zip(progress[1:], progress[2:]))
    assert ds.attrs["computed_runs"] == 48
    _equal(ds, embedded)
    assert not (tmp_path / ".partial").exists() and (tmp_path / "sweep.nc").exists()


def test_sweep_bench_section_at_smoke_size(client):
    from fmu_sync.benchmarks import sweep_speed
    r = sweep_speed.measure(R=8, steps=2000, repeats=1, mem_runs=4, mem_steps=1000, client=client)
    for k in ("single", "embedded", "dask", "ratio_embedded", "ratio_dask"):
        assert r[k] > 0, k
    # no trajectories: 100 times longer runs need no more memory
    assert r["mem_long"] < 1.05 * r["mem_short"] + 8.0


def test_cosimulated_runs_as_dask_tasks_equal_local_worker_processes(client):
    kw = dict(variant="switching", grid={"coupling.Kp": [0.5, 2.0]}, plots=False, quiet=True,
              overrides={"run.t_end": 2.0, "run.mode": "cosim", "run.record_every": 1})
    ds = sweep(SCENE, client=client, **kw)
    local = sweep(SCENE, workers=1, **kw)
    assert ds.attrs["process_runs"] == 2 and ds.attrs["engine"] == "dask"
    assert (ds["status"].values == 0).all()
    for v in ("q1", "u1", "q2", "u2", "d_final", "d_max", "tau_max", "impacts1"):
        np.testing.assert_array_equal(ds[v].values, local[v].values, err_msg=v)
