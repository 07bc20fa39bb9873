"""Sweep throughput: the embedded engine and a Dask LocalCluster against single runs, in one run.

Through the public API only (``fmu_sync.sweep``, ``simulate_pair``), on the
switching-coupled pair of the ``forced-pair`` scene (dt = 1e-3):

* **single pair**: pair steps per second of ``simulate_pair`` (one run at a
  time, the scene's record_every), runs taken from the sweep's own gains;
* **embedded**: ``sweep(...)`` of R runs of S steps on this machine (one
  compiled call per chunk, one thread per core): R*S / wall time;
* **Dask**: the same sweep through a ``LocalCluster`` with one worker process
  per core (1 thread each), cluster started and warmed up before timing;
* **memory**: peak RSS of a fresh process running a sweep of the same number of
  runs with S and 100 S steps (no trajectories: it must not grow).

Single and embedded measurements are interleaved and repeated (medians):
the machine is shared, so every number comes with the load average.

    python -m fmu_sync.benchmarks.sweep_speed [--quick]
"""
from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time

SCENE = "forced-pair"
VARIANT = "switching"
DT = 1e-3


def _kps(R):
    import numpy as np
    return np.linspace(0.5, 2.0, R)


def _single_rate(kps, steps):
    """Pair steps per second of simulate_pair, one run after another."""
    from fmu_sync.core import ImpactOscillator, simulate_pair
    from fmu_sync import load_scene
    v = load_scene(SCENE, None, [VARIANT]).variants[0]
    s = ImpactOscillator(m=v.cfg["system.m"], k=v.cfg["system.k"], c=v.cfg["system.c"], f0=v.cfg["system.f0"],
                         F=v.cfg["system.F"], Omega=v.cfg["system.Omega"], phi=v.cfg["system.phi"],
                         e=v.cfg["system.e"])
    kw = dict(coupling=VARIANT, Kd=v.Kd, record_every=v.cfg["run.record_every"])
    simulate_pair(s, v.x1, v.x2, 10 * DT, DT, Kp=1.0, **kw)
    t = time.perf_counter()
    c = time.process_time()
    for kp in kps:
        simulate_pair(s, v.x1, v.x2, steps * DT, DT, Kp=float(kp), **kw)
    cpu = time.process_time() - c
    return len(kps) * steps / (time.perf_counter() - t), len(kps) * steps / cpu


def _sweep_rate(R, steps, **kw):
    import fmu_sync
    t = time.perf_counter()
    c = time.process_time()
    ds = fmu_sync.sweep(SCENE, variant=VARIANT, grid={"coupling.Kp": _kps(R)},
                        overrides={"run.t_end": steps * DT, "solver.dt": DT}, quiet=True, **kw)
    sec = time.perf_counter() - t
    cpu = time.process_time() - c
    assert int(ds.attrs["computed_runs"]) == R
    return R * steps / sec, ds, R * steps / cpu, cpu / sec


_MEM_CHILD = r"""
import resource, sys
import fmu_sync
R, steps = int(sys.argv[1]), int(sys.argv[2])
fmu_sync.sweep("forced-pair", variant="switching", grid={"coupling.Kp": "linspace(0.5, 2, %d)" % R},
               overrides={"run.t_end": steps * 1e-3}, quiet=True)
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def _peak_rss_mb(R, steps):
    env = {**os.environ, "FMU_SYNC_PROGRESS": "0"}
    p = subprocess.run([sys.executable, "-c", _MEM_CHILD, str(R), str(steps)], capture_output=True, text=True,
                       env=env, check=True)
    return int(p.stdout.split()[-1]) / 1024.0


def measure(R=1000, steps=100_000, repeats=3, dask=True, mem_runs=50, mem_steps=10_000, client=None):
    """The numbers of the section (``client``: an existing Dask client instead of a new
    LocalCluster with one worker process per core)."""
    import numba
    cores = int(numba.config.NUMBA_NUM_THREADS)
    kps = _kps(R)
    base_kps = kps[:: max(1, R // 4)][:4]
    _sweep_rate(2 * cores, 1000)   # compile / load the cache
    single, emb, single_cpu, emb_cpu, busy = [], [], [], [], []
    for _ in range(repeats):
        w, c = _single_rate(base_kps, steps)
        single.append(w)
        single_cpu.append(c)
        w, _, c, b = _sweep_rate(R, steps)
        emb.append(w)
        emb_cpu.append(c)
        busy.append(b)
    w, c = _single_rate(base_kps, steps)
    single.append(w)
    single_cpu.append(c)
    res = dict(cores=cores, runs=R, steps=steps, single=statistics.median(single),
               single_all=single, embedded=statistics.median(emb), embedded_all=emb,
               cpu_efficiency=statistics.median(emb_cpu) / statistics.median(single_cpu),
               cores_obtained=statistics.median(busy))
    res["ratio_embedded"] = res["embedded"] / (cores * res["single"])
    if dask and client is not None:
        _sweep_rate(4 * cores, 1000, client=client)
        dk = [_sweep_rate(R, steps, client=client)[0]]
        emb2 = [_sweep_rate(R, steps)[0]]
        res.update(dask=dk[0], dask_all=dk, embedded_dask_pair=emb2[0], ratio_dask=dk[0] / emb2[0])
    elif dask:
        try:
            import logging

            from distributed import Client, LocalCluster
        except ImportError as exc:  # pragma: no cover
            res["dask_error"] = f"dask.distributed missing: {exc}"
        else:
            with LocalCluster(n_workers=cores, threads_per_worker=1, processes=True, dashboard_address=None,
                              silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
                _sweep_rate(4 * cores, 1000, client=client)   # workers import and load the cache
                dk = []
                emb2 = []
                for _ in range(max(1, repeats - 1)):
                    dk.append(_sweep_rate(R, steps, client=client)[0])
                    emb2.append(_sweep_rate(R, steps)[0])
            res.update(dask=statistics.median(dk), dask_all=dk, embedded_dask_pair=statistics.median(emb2))
            res["ratio_dask"] = res["dask"] / res["embedded_dask_pair"]
    res["mem_short"] = _peak_rss_mb(mem_runs, mem_steps)
    res["mem_long"] = _peak_rss_mb(mem_runs, 100 * mem_steps)
    res.update(mem_runs=mem_runs, mem_steps=mem_steps)
    return res


def _load():
    try:
        return "/".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover
        return "n/a"


def run(quick: bool = False, smoke: bool = False) -> str:
    """Measure; return a markdown section."""
    if smoke:
        kw = dict(R=16, steps=2000, repeats=1, mem_runs=4, mem_steps=1000)
    elif quick:
        kw = dict(R=200, steps=20_000, repeats=2, mem_runs=20, mem_steps=5000)
    else:
        kw = dict(R=1000, steps=100_000, repeats=3, mem_runs=50, mem_steps=10_000)
    load0 = _load()
    r = measure(**kw)
    M = 1e6
    lines = ["## Sweep throughput", "", f"{r['runs']} runs x {r['steps']:.0e} steps, switching-coupled "
             f"forced-pair pair, {r['cores']} cores.", "",
             f"load average {load0} at the start, {_load()} at the end (shared machine: the parallel "
             "ratios need idle cores).", "",
             "| measurement | value | target |", "|---|---|---|",
             f"| single `simulate_pair`, one run at a time (median of {len(r['single_all'])}) | "
             f"{r['single'] / M:.2f} Msteps/s ({', '.join(f'{x / M:.2f}' for x in r['single_all'])}) | |",
             f"| embedded sweep, {r['cores']} threads (median of {len(r['embedded_all'])}) | "
             f"{r['embedded'] / M:.2f} Msteps/s ({', '.join(f'{x / M:.2f}' for x in r['embedded_all'])}) | |",
             f"| embedded / (cores x single) | {r['ratio_embedded']:.2f} | >= 0.9 |",
             f"| CPU cores the embedded sweep obtained (CPU time / wall time) | {r['cores_obtained']:.2f} "
             f"of {r['cores']} | |",
             f"| embedded per CPU-second / single per CPU-second (per-core efficiency) | "
             f"{r['cpu_efficiency']:.2f} | |"]
    if "dask" in r:
        lines += [f"| Dask LocalCluster, {r['cores']} worker processes x 1 thread | {r['dask'] / M:.2f} Msteps/s "
                  f"({', '.join(f'{x / M:.2f}' for x in r['dask_all'])}) | |",
                  f"| embedded, interleaved with the Dask runs | {r['embedded_dask_pair'] / M:.2f} Msteps/s | |",
                  f"| Dask / embedded | {r['ratio_dask']:.2f} | >= 0.8 |"]
    elif "dask_error" in r:
        lines.append(f"| Dask | not run: {r['dask_error']} | |")
    lines.append(f"| peak RSS of a {r['mem_runs']}-run sweep, {r['mem_steps']:.0e} vs {100 * r['mem_steps']:.0e} "
                 f"steps per run | {r['mem_short']:.0f} MB vs {r['mem_long']:.0f} MB | independent of run length |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # pragma: no cover
    print(run(quick="--quick" in sys.argv, smoke="--smoke" in sys.argv))
