"""Co-simulation speed (``fmu-sync bench``, section "Co-simulation speed").

All in one run, in this process, CPU time:

* per communication step of the co-simulated forced pair (two instances of the
  exported 1-DOF FMU, switching law, H = solver.dt = 1 ms, d recorded every step,
  :func:`fmu_sync.master.cosimulate`, the compiled exchange loop) next to
  :func:`fmu_sync.core.simulate_pair` on the same problem and next to libcosimpy's
  C++ fixed-step master stepping two instances of the same FMU with no coupling;
  a step's cost is the slope between a short and a long run (the set-up cancels);
* per communication step of a ring of 8 (H = solver.dt = 10 ms) next to
  :func:`fmu_sync.core.network.simulate_network`;
* a Kp x Kd gain map of the forced pair, co-simulated (worker processes; each worker
  keeps its FMU instances from run to run, reset with fmi2Reset:
  :func:`fmu_sync.instance_pool.keep_instances`) and in the core (compiled chunks), with
  :func:`fmu_sync.sweep`, wall time.

The per-step costs are measured as before (issue 18); since the FMU's stepper and the
loop stopped reference counting and the loop inlines the coupling forces, the co-simulated
step costs about a third of what it did.

    python -m fmu_sync.benchmarks.cosim_speed [--quick]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time

SCENE, VARIANT = "forced-pair", "switching"
DT = 1e-3
#: targets of issue 18: co-simulated pair step <= 20 x simulate_pair, >= 30 x faster than libcosimpy
TARGET_VS_CORE, TARGET_VS_LIBCOSIM = 20.0, 30.0


def _slope(run, n1: int, n2: int, repeat: int) -> tuple:
    """(CPU, wall) seconds per step: medians over interleaved repeats of (t(n2) - t(n1)) / (n2 - n1)."""
    cpu, wall = [], []
    for _ in range(repeat):
        times = []
        for n in (n1, n2):
            c, w = time.process_time(), time.perf_counter()
            run(n)
            times.append((time.process_time() - c, time.perf_counter() - w))
        cpu.append((times[1][0] - times[0][0]) / (n2 - n1))
        wall.append((times[1][1] - times[0][1]) / (n2 - n1))
    return statistics.median(cpu), statistics.median(wall)


def _variant():
    from fmu_sync import load_scene
    return load_scene(SCENE, {"run.mode": "cosim", "run.H": DT, "solver.dt": DT, "run.record_every": 1,
                              "record.distance": True}, [VARIANT]).variants[0]


def _libcosim_runner(fmu):
    """n steps of libcosimpy's fixed-step master over two instances of ``fmu`` (no connections)."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimSlave import CosimLocalSlave
    log_output_level(CosimLogLevel.ERROR)

    def run(n):
        ex = CosimExecution.from_step_size(step_size=round(DT * 1e9))
        for name in ("a", "b"):
            ex.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name=name))
        if not ex.step(n):
            raise RuntimeError(f"libcosimpy failed: {ex.status()}")
    return run


def pair_costs(fmu, n1: int, n2: int, repeat: int) -> dict:
    """µs per communication step: co-simulated pair, simulate_pair, libcosimpy (two instances)."""
    from fmu_sync import cosimulate
    from fmu_sync.core import simulate_pair
    v = _variant()
    kw = dict(coupling=VARIANT, Kp=v.Kp, Kd=v.Kd)
    cos = (lambda n: cosimulate(fmu, v.x1, v.x2, n * DT, DT, **kw))
    core = (lambda n: simulate_pair(v.system, v.x1, v.x2, n * DT, DT, **kw))
    cos(10)
    core(10)
    lib = _libcosim_runner(fmu)
    lib(10)
    us = (lambda run: tuple(x * 1e6 for x in _slope(run, n1, n2, repeat)))
    return {"cosimulate (compiled loop)": us(cos), "simulate_pair (core)": us(core),
            "libcosimpy, 2 instances, no coupling": us(lib)}


def ring_costs(fmu, n1: int, n2: int, repeat: int) -> dict:
    """µs per communication step of a ring of 8, co-simulated and in the core (H = dt = 10 ms)."""
    from fmu_sync import cosimulate_network
    from fmu_sync.core import ring, simulate_network
    v = _variant()
    sv = {"solver.dt": 1e-2}
    xs = [(0.2 + 0.9 * (i % 3) / 2, 0.5 * ((i * 7) % 5 - 2) / 2) for i in range(8)]
    kw = dict(coupling="switching", Kp=4.0, Kd=2.0)
    cos = (lambda n: cosimulate_network(fmu, xs, ring(8), n * 1e-2, 1e-2, start_values=sv, **kw))
    core = (lambda n: simulate_network(v.system, xs, ring(8), n * 1e-2, 1e-2, **kw))
    cos(10)
    core(10)
    return {"cosimulate_network, ring of 8": _slope(cos, n1, n2, repeat)[0] * 1e6,
            "simulate_network, ring of 8": _slope(core, n1, n2, repeat)[0] * 1e6}


def gain_map_times(side: int, t_end: float) -> dict:
    """Wall seconds of a side x side (Kp, Kd) gain map of the forced pair, co-simulated and core."""
    import numpy as np

    import fmu_sync
    grid = {"coupling.Kp": np.linspace(0.5, 4.0, side), "coupling.Kd": np.linspace(0.2, 2.0, side)}
    out = {}
    for mode in ("core", "cosim"):
        over = {"run.t_end": t_end, "run.mode": mode, "solver.dt": DT}
        fmu_sync.sweep(SCENE, variant=VARIANT, grid={"coupling.Kp": [1.0], "coupling.Kd": [0.5]},
                       overrides=over, quiet=True)   # warm: compile, export
        t = time.perf_counter()
        ds = fmu_sync.sweep(SCENE, variant=VARIANT, grid=grid, overrides=over, quiet=True)
        out[mode] = time.perf_counter() - t
        out[mode + "_runs"] = int(ds.attrs["computed_runs"])
    return out


def measure(quick: bool = False) -> dict:
    with tempfile.TemporaryDirectory(prefix="fmu-sync-cosim-bench-") as tmp:
        from fmu_sync import export_fmu
        from fmu_sync.fmus.contract import model as contract_model
        model = contract_model("impact-oscillator")
        fmu = export_fmu(model.key, f"{tmp}/osc.fmu", {**model.values(_variant().system), "solver.dt": DT})
        n1, n2, rep = (2000, 20000, 3) if quick else (5000, 100000, 5)
        pair = pair_costs(fmu, n1, n2, rep)
        ring = ring_costs(fmu, n1 // 5, n2 // 5, rep)
    gm = gain_map_times(*((6, 6.0) if quick else (11, 6.0)))
    return {"pair": pair, "ring": ring, "gain_map": gm, "quick": quick}


def markdown(m: dict) -> str:
    p, r, g = m["pair"], m["ring"], m["gain_map"]
    cos, core, lib = (p["cosimulate (compiled loop)"], p["simulate_pair (core)"],
                      p["libcosimpy, 2 instances, no coupling"])
    ok = (lambda good: "meets" if good else "MISSES")
    rows = ["## Co-simulation speed", "",
            "µs per communication step (slope between a short and a long run: the set-up cancels; medians "
            "of interleaved repeats), forced pair (switching law, H = solver.dt = 1 ms, d recorded every "
            "step), in one process. libcosimpy's master steps its instances on worker threads: its wall "
            "time exceeds its CPU time.", "",
            "| run | CPU µs per step | wall µs per step | CPU ratio | wall ratio |", "|---|---:|---:|---:|---:|",
            f"| simulate_pair (core) | {core[0]:.3f} | {core[1]:.3f} | 1 | 1 |",
            f"| cosimulate, two FMU instances, compiled exchange loop | {cos[0]:.3f} | {cos[1]:.3f} | "
            f"{cos[0] / core[0]:.1f} × core | {cos[1] / core[1]:.1f} × core |",
            f"| libcosimpy fixed-step master, two instances, no coupling (`step(n)`) | {lib[0]:.2f} | "
            f"{lib[1]:.2f} | {lib[0] / cos[0]:.1f} × cosimulate | {lib[1] / cos[1]:.1f} × cosimulate |", ""]
    for k, label in ((0, "CPU"), (1, "wall")):
        vs_core, vs_lib = cos[k] / core[k], lib[k] / cos[k]
        rows.append(f"- {label}: co-simulated step / core step = **{vs_core:.1f}** (target <= "
                    f"{TARGET_VS_CORE:.0f}: {ok(vs_core <= TARGET_VS_CORE)}); libcosimpy step / co-simulated "
                    f"step = **{vs_lib:.1f}** (target >= {TARGET_VS_LIBCOSIM:.0f}: "
                    f"{ok(vs_lib >= TARGET_VS_LIBCOSIM)})")
    rows += [f"- ring of 8 (H = solver.dt = 10 ms, CPU): cosimulate_network "
             f"{r['cosimulate_network, ring of 8']:.2f} µs per step, simulate_network "
             f"{r['simulate_network, ring of 8']:.3f} µs "
             f"({r['cosimulate_network, ring of 8'] / r['simulate_network, ring of 8']:.1f} ×)",
             f"- gain map, {g['core_runs']} runs of the forced pair (Kp x Kd, t_end = 6 s; core: dt = 1 ms, "
             f"compiled chunks; cosim: H = 10 ms, worker processes, FMU instances kept and reset between runs): "
             f"cosim {g['cosim']:.1f} s, core {g['core']:.2f} s ({g['cosim'] / g['core']:.0f} ×, wall time)",
             ""]
    return "\n".join(rows)


def run(quick: bool = False) -> str:
    return markdown(measure(quick))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m fmu_sync.benchmarks.cosim_speed")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    print(run(args.quick))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
