"""Benchmark of the fmu-sync co-simulation slave (docs/design.md §4.3).

    python -m fmu_sync.benchmarks.fmu_cost                      # per-step cost + first-step latency
    python -m fmu_sync.benchmarks.fmu_cost --exit-check 200     # + 200 fresh fmpy processes must exit with 0
    python -m fmu_sync.benchmarks.fmu_cost --exit-check 50 --without-fix   # same, exit workaround disabled

Per-step cost: one communication step = setReal(tau) + doStep + getReal(q, u)
through fmpy's FMU2Slave, next to the same loop calling the core's compiled
``advance`` directly (what the slave's doStep runs, without FMI and pythonfmu),
for H = dt (1 internal step) and H = 10 dt. Times are per communication step,
best of ``--repeat`` runs of ``--steps`` steps (CPU time of this process).

First-step latency: fresh ``python`` processes (numba cache warm: one untimed
process runs first) time instantiate -> setup/enter/exit initialization -> the
first finished doStep; the median over ``--fresh`` processes is printed.

Exit check: pythonfmu 0.7.0's export library writes into freed memory at
process exit (see fmu_sync/fmus/_export_lib.py); whether that aborts the
process ("corrupted double-linked list") depends on the heap layout: 46 of 50
processes with a first probe slave, few or none with the current FMU, while
valgrind shows the invalid access in every unfixed run and none with the fix.
``--without-fix`` disables the workaround in the children to compare.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

CHILD_LATENCY = r"""
import json, sys, time
t_start = time.perf_counter()
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
path = sys.argv[1]
md = read_model_description(path)
d = extract(path)
t_import = time.perf_counter()
fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName="latency")
t0 = time.perf_counter()
fmu.instantiate()
t1 = time.perf_counter()
fmu.setupExperiment(startTime=0.0); fmu.enterInitializationMode(); fmu.exitInitializationMode()
t2 = time.perf_counter()
fmu.doStep(0.0, 1e-2)
t3 = time.perf_counter()
fmu.doStep(1e-2, 1e-2)
t4 = time.perf_counter()
fmu.terminate(); fmu.freeInstance()
import shutil; shutil.rmtree(d, ignore_errors=True)
print(json.dumps({"imports_and_unzip": t_import - t_start, "instantiate": t1 - t0, "initialization": t2 - t1,
                  "first_doStep": t3 - t2, "instantiate_to_first_step": t3 - t0,
                  "second_doStep": t4 - t3}))
"""

CHILD_EXIT = r"""
import sys, shutil
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
path, without_fix = sys.argv[1], sys.argv[2] == "1"
md = read_model_description(path)
d = extract(path)
fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName="exit")
fmu.instantiate(); fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode(); fmu.exitInitializationMode()
t = 0.0
for i in range(100):
    fmu.doStep(t, 1e-2); t += 1e-2
q = fmu.getReal([1])[0]
fmu.terminate(); fmu.freeInstance()
shutil.rmtree(d, ignore_errors=True)
if without_fix:   # demonstrate the unfixed pythonfmu teardown
    import atexit
    from fmu_sync.fmus import _export_lib
    atexit.unregister(_export_lib.finalize_export_libraries)
print("ok", q)
"""


def _cpu_per_step(fn, steps: int, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn(steps)
        best = min(best, (time.process_time() - t0) / steps)
    return best


def per_step_costs(fmu_path: Path, steps: int, repeat: int) -> dict:
    import numpy as np
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    from fmu_sync.core import ImpactOscillator
    from fmu_sync.core.kernels import advance

    md = read_model_description(str(fmu_path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    d = extract(str(fmu_path))
    dt = 1e-3
    out = {}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="bench")
    fmu.instantiate()
    try:
        for k in (1, 10):
            H = k * dt
            if k != 1:
                fmu.reset()
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
            state = {"t": 0.0}
            vin, vout = [vr["tau"]], [vr["q"], vr["u"]]

            def fmi_loop(n, H=H):
                t = state["t"]
                for i in range(n):
                    fmu.setReal(vin, [0.1])
                    fmu.doStep(t, H)
                    fmu.getReal(vout)
                    t += H
                state["t"] = t

            def do_step_only(n, H=H):
                t = state["t"]
                for i in range(n):
                    fmu.doStep(t, H)
                    t += H
                state["t"] = t

            fmi_loop(100)  # warm
            out[f"fmpy set+doStep+get, H={k}dt"] = _cpu_per_step(fmi_loop, steps, repeat)
            out[f"fmpy doStep only,     H={k}dt"] = _cpu_per_step(do_step_only, steps, repeat)
            fmu.terminate()

            system = ImpactOscillator(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
            sa = system.arrays()
            q = np.array([1.0])
            u = np.array([0.0])
            tau = np.zeros(1)
            cstate = {"t": 0.0}

            def core_loop(n, H=H):
                t = cstate["t"]
                for i in range(n):
                    tau[0] = 0.1
                    advance(sa, q, u, t, H, dt, tau, 0, 0.5)
                    float(q[0]), float(u[0])
                    t += H
                cstate["t"] = t

            core_loop(100)
            out[f"core advance (direct), H={k}dt"] = _cpu_per_step(core_loop, steps, repeat)
    finally:
        fmu.freeInstance()
        import shutil
        shutil.rmtree(d, ignore_errors=True)
    return out


def _run_child(code: str, args: list[str], timeout: float = 120.0):
    p = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=timeout)
    return p.returncode, p.stdout, p.stderr


def first_step_latency(fmu_path: Path, fresh: int) -> dict:
    _run_child(CHILD_LATENCY, [str(fmu_path)])  # warm the numba cache
    runs = []
    for _ in range(fresh):
        rc, out, err = _run_child(CHILD_LATENCY, [str(fmu_path)])
        if rc != 0:
            raise RuntimeError(f"latency child failed ({rc}): {err[-2000:]}")
        runs.append(json.loads(out.strip().splitlines()[-1]))
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def exit_check(fmu_path: Path, n: int, without_fix: bool, jobs: int = 2) -> dict:
    def one(_):
        rc, out, err = _run_child(CHILD_EXIT, [str(fmu_path), "1" if without_fix else "0"])
        return rc, (err.strip().splitlines() or [""])[-1]

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        results = list(pool.map(one, range(n)))
    failures = [(rc, msg) for rc, msg in results if rc != 0]
    return {"processes": n, "failed": len(failures),
            "examples": sorted({f"rc={rc}: {msg}" for rc, msg in failures})[:3]}


def run(quick: bool = False) -> str:
    """Per-step cost and first-step latency as a markdown section (for ``fmu-sync bench``)."""
    from fmu_sync import export_fmu
    steps, repeat, fresh = (5000, 3, 3) if quick else (20000, 3, 5)
    with tempfile.TemporaryDirectory(prefix="bench-fmu-") as tmp:
        fmu_path = export_fmu("impact-oscillator", Path(tmp) / "ImpactOscillator.fmu")
        per = per_step_costs(fmu_path, steps, repeat)
        lat = first_step_latency(fmu_path, fresh)
    lines = [f"## FMU cost (CPU time per communication step, best of {repeat} x {steps} steps)", "",
             "| loop | µs per step |", "|---|---:|"]
    lines += [f"| {k} | {v * 1e6:.2f} |" for k, v in per.items()]
    lines += ["", f"First doStep in a fresh process (warm numba cache, median of {fresh}):", "",
              "| phase | ms |", "|---|---:|"]
    lines += [f"| {k} | {v * 1e3:.1f} |" for k, v in lat.items()]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--fresh", type=int, default=5, help="fresh processes for the first-step latency")
    ap.add_argument("--exit-check", type=int, default=0, metavar="N",
                    help="also run N fresh fmpy processes and count non-zero exits")
    ap.add_argument("--without-fix", action="store_true",
                    help="exit check with the exit workaround disabled (pythonfmu's use-after-free at exit)")
    ap.add_argument("--json", action="store_true", help="print the results as JSON")
    args = ap.parse_args(argv)

    from fmu_sync import export_fmu
    results = {}
    with tempfile.TemporaryDirectory(prefix="bench-fmu-") as tmp:
        fmu_path = export_fmu("impact-oscillator", Path(tmp) / "ImpactOscillator.fmu")
        results["per_step_us"] = {k: v * 1e6 for k, v in per_step_costs(fmu_path, args.steps, args.repeat).items()}
        results["first_step_latency_ms"] = {k: v * 1e3 for k, v in first_step_latency(fmu_path, args.fresh).items()}
        if args.exit_check:
            results["exit_check"] = exit_check(fmu_path, args.exit_check, args.without_fix)
            results["exit_check"]["teardown_fix"] = not args.without_fix

    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print("Per communication step (CPU time, best of %d x %d steps):" % (args.repeat, args.steps))
    for k, v in results["per_step_us"].items():
        print(f"  {k:<36} {v:8.2f} us")
    print(f"First doStep in a fresh process (warm numba cache, median of {args.fresh}):")
    for k, v in results["first_step_latency_ms"].items():
        print(f"  {k:<36} {v:8.1f} ms")
    if "exit_check" in results:
        e = results["exit_check"]
        fix = "with" if e["teardown_fix"] else "WITHOUT"
        print(f"Exit check ({fix} the teardown fix): {e['failed']} of {e['processes']} fresh fmpy "
              f"processes exited non-zero")
        for ex in e["examples"]:
            print(f"  {ex}")
        return 1 if (e["failed"] and e["teardown_fix"]) else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
