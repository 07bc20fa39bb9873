"""Benchmark of the fmu-sync co-simulation FMU (our own FMI 2.0 binary).

    python -m fmu_sync.benchmarks.fmu_cost                      # per-step cost + first-step latency
    python -m fmu_sync.benchmarks.fmu_cost --exit-check 200     # + 200 fresh fmpy processes must exit with 0

Per-step cost: one communication step = setReal(tau) + doStep + getReal(q, u)
through fmpy's FMU2Slave, for our ``ImpactOscillator`` FMU (H = dt: one
internal Moreau step; H = 10 dt) next to a minimal C FMU with the same
interface (``minimal_fmu.c``: the same variables, one input, a trivial step,
no checks), which this benchmark builds itself with gcc, in the same loop and
process. The ratio ours / minimal is the price of our FMI layer and model over
what any FMU costs in that loop. Times are CPU time per communication step,
best of ``--repeat`` interleaved runs of ``--steps`` steps.

Rollback: fmi2GetFMUstate (+ fmi2FreeFMUstate) and fmi2SetFMUstate against a doStep of 10
internal steps (H = 10 dt), CPU time per call through fmpy, for our oscillator FMU and our
coupling FMU (the master's event-aware retake and any rollback pay them; target: a set costs
at most 5 doSteps of 10 internal steps).

First-step latency: fresh ``python`` processes, each with an empty cache folder
(``FMU_SYNC_CACHE``: a first use), time instantiate -> setup/enter/exit initialization -> the
first finished doStep; the median over ``--fresh`` processes is printed, with, for the
explanation, the import time of numpy alone in a fresh process. The stepper is native
code in the binary (compiled at export): numba is neither imported nor needed.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import zipfile
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
print(json.dumps({"fmpy imports and unzip": t_import - t_start, "instantiate": t1 - t0,
                  "initialization": t2 - t1, "first doStep": t3 - t2,
                  "instantiate to first step": t3 - t0, "second doStep": t4 - t3}))
"""

CHILD_IMPORTS = r"""
import json, time
t0 = time.perf_counter()
import numpy
t1 = time.perf_counter()
print(json.dumps({"import numpy (fresh process)": t1 - t0}))
"""

CHILD_EXIT = r"""
import sys, shutil
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
path = sys.argv[1]
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
print("ok", q)
"""


def build_minimal_fmu(fmu_path: Path, out: Path) -> Path:
    """A C FMU with our FMU's modelDescription.xml and a trivial binary (minimal_fmu.c)."""
    from fmpy import read_model_description
    md = read_model_description(str(fmu_path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    ident = md.coSimulation.modelIdentifier
    src = Path(__file__).with_name("minimal_fmu.c")
    with tempfile.TemporaryDirectory(prefix="bench-min-") as tmp:
        so = Path(tmp) / f"{ident}.so"
        cmd = [os.environ.get("CC", "gcc"), "-O2", "-fPIC", "-shared", "-fvisibility=hidden",
               f"-DNVARS={len(md.modelVariables)}", f"-DVR_TAU={vr['tau']}", f"-DVR_Q={vr['q']}",
               f"-DVR_U={vr['u']}", "-o", str(so), str(src)]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            raise RuntimeError(f"cannot build the minimal C FMU: {p.stderr[-2000:]}")
        with zipfile.ZipFile(fmu_path) as zin, zipfile.ZipFile(out, "w") as zout:
            zout.writestr("modelDescription.xml", zin.read("modelDescription.xml"))
            zout.write(so, f"binaries/linux64/{ident}.so")
    return out


def _cpu_per_step(fn, steps: int, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn(steps)
        best = min(best, (time.process_time() - t0) / steps)
    return best


def _started(path: Path, name: str):
    """(fmpy FMU2Slave in step mode at t = 0, its unpacked folder, its model description)."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    md = read_model_description(str(path))
    d = extract(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName=name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return fmu, d, md


def _best_interleaved(loops: dict, n: int, repeat: int) -> dict:
    """CPU seconds per iteration of each ``loops[key](n)``, best of ``repeat`` interleaved rounds."""
    best = {k: float("inf") for k in loops}
    for _ in range(repeat):
        for key, fn in loops.items():
            t0 = time.process_time()
            fn(n)
            best[key] = min(best[key], (time.process_time() - t0) / n)
    return best


def _close(opened) -> None:
    import shutil
    for fmu, d in opened:
        fmu.terminate()
        fmu.freeInstance()
        shutil.rmtree(d, ignore_errors=True)


def per_step_costs(fmu_path: Path, minimal_path: Path, steps: int, repeat: int) -> dict:
    """CPU µs per communication step (set + doStep + get), ours and the minimal C FMU, interleaved."""
    dt = 1e-3
    loops, cleanup = {}, []
    try:
        for label, path, H in (("our FMU, H = dt (1 internal step)", fmu_path, dt),
                               ("our FMU, H = 10 dt", fmu_path, 10 * dt),
                               ("minimal C FMU (trivial step)", minimal_path, dt)):
            fmu, d, md = _started(path, label[:12])
            cleanup.append((fmu, d))
            vr = {v.name: v.valueReference for v in md.modelVariables}
            state = {"t": 0.0}
            vin, vout = [vr["tau"]], [vr["q"], vr["u"]]

            def loop(n, fmu=fmu, H=H, state=state, vin=vin, vout=vout):
                t = state["t"]
                setReal, doStep, getReal = fmu.setReal, fmu.doStep, fmu.getReal
                for _ in range(n):
                    setReal(vin, [0.1])
                    doStep(t, H)
                    getReal(vout)
                    t += H
                state["t"] = t

            loop(200)  # warm
            loops[label] = loop
        return _best_interleaved(loops, steps, repeat)
    finally:
        _close(cleanup)


def state_costs(fmu_path: Path, coupling_path: Path, calls: int, repeat: int) -> dict:
    """CPU µs per call of doStep (H = 10 dt), fmi2GetFMUstate + fmi2FreeFMUstate and fmi2SetFMUstate,
    through fmpy, for our oscillator FMU and our coupling FMU (best of ``repeat``, interleaved)."""
    H = 10 * 1e-3
    opened, states, loops = [], [], {}
    try:
        for label, path in (("oscillator FMU", fmu_path), ("coupling FMU", coupling_path)):
            fmu, d, _ = _started(path, label[:10])
            opened.append((fmu, d))
            clock = {"t": 0.0}
            saved = fmu.getFMUstate()
            states.append((fmu, saved))

            def step(n, fmu=fmu, clock=clock):
                t = clock["t"]
                for _ in range(n):
                    fmu.doStep(t, H)
                    t += H
                clock["t"] = t

            def get(n, fmu=fmu):
                for _ in range(n):
                    fmu.freeFMUstate(fmu.getFMUstate())

            def put(n, fmu=fmu, saved=saved, clock=clock):
                for _ in range(n):
                    fmu.setFMUstate(saved)
                clock["t"] = 0.0

            for what, fn in (("doStep (H = 10 dt)", step), ("get + free state", get), ("set state", put)):
                loops[(label, what)] = fn
        best = _best_interleaved(loops, calls, repeat)
    finally:
        for fmu, saved in states:
            fmu.freeFMUstate(saved)
        _close(opened)
    return {f"{label}: {what}": v * 1e6 for (label, what), v in best.items()}


def _run_child(code: str, args: list[str], timeout: float = 120.0, env: dict | None = None):
    p = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=timeout,
                       env=None if env is None else {**os.environ, **env})
    return p.returncode, p.stdout, p.stderr


def first_step_latency(fmu_path: Path, fresh: int) -> dict:
    runs, imports = [], []
    for _ in range(fresh):
        with tempfile.TemporaryDirectory(prefix="bench-fmu-cache-") as cache:
            rc, out, err = _run_child(CHILD_LATENCY, [str(fmu_path)], env={"FMU_SYNC_CACHE": cache})
        if rc != 0:
            raise RuntimeError(f"latency child failed ({rc}): {err[-2000:]}")
        runs.append(json.loads(out.strip().splitlines()[-1]))
        rc, out, err = _run_child(CHILD_IMPORTS, [])
        if rc == 0:
            imports.append(json.loads(out.strip().splitlines()[-1]))
    res = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    if imports:
        res.update({k: statistics.median(r[k] for r in imports) for k in imports[0]})
    return res


def exit_check(fmu_path: Path, n: int, jobs: int = 2) -> dict:
    def one(_):
        rc, out, err = _run_child(CHILD_EXIT, [str(fmu_path)])
        return rc, (err.strip().splitlines() or [""])[-1]

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        results = list(pool.map(one, range(n)))
    failures = [(rc, msg) for rc, msg in results if rc != 0]
    return {"processes": n, "failed": len(failures),
            "examples": sorted({f"rc={rc}: {msg}" for rc, msg in failures})[:3]}


def _measure(steps: int, repeat: int, fresh: int, exit_n: int = 0) -> dict:
    from fmu_sync import export_fmu
    with tempfile.TemporaryDirectory(prefix="bench-fmu-") as tmp:
        fmu_path = export_fmu("impact-oscillator", Path(tmp) / "ImpactOscillator.fmu")
        minimal = build_minimal_fmu(fmu_path, Path(tmp) / "Minimal.fmu")
        coupling = export_fmu("coupling", Path(tmp) / "Coupling.fmu")
        res = {"per_step_us": {k: v * 1e6 for k, v in per_step_costs(fmu_path, minimal, steps, repeat).items()},
               "state_us": state_costs(fmu_path, coupling, max(steps // 10, 200), repeat),
               "first_step_latency_ms": {k: v * 1e3 for k, v in first_step_latency(fmu_path, fresh).items()}}
        if exit_n:
            res["exit_check"] = exit_check(fmu_path, exit_n)
    per, sc = res["per_step_us"], res["state_us"]
    res["ratio_H_dt"] = per["our FMU, H = dt (1 internal step)"] / per["minimal C FMU (trivial step)"]
    step = sc["oscillator FMU: doStep (H = 10 dt)"]
    res["set_vs_doStep"] = {k.split(":")[0]: sc[k] / step for k in sc if k.endswith("set state")}
    return res


def run(quick: bool = False) -> str:
    """Per-step cost and first-step latency as a markdown section (for ``fmu-sync bench``)."""
    steps, repeat, fresh = (5000, 3, 3) if quick else (20000, 5, 5)
    res = _measure(steps, repeat, fresh)
    per, lat = res["per_step_us"], res["first_step_latency_ms"]
    lines = ["## FMU cost", "", f"fmpy loop: setReal + doStep + getReal, CPU time per communication step, "
             f"best of {repeat} x {steps} interleaved steps.", "",
             "| FMU | µs per step | vs minimal C FMU |", "|---|---:|---:|"]
    base = per["minimal C FMU (trivial step)"]
    lines += [f"| {k} | {v:.2f} | ×{v / base:.2f} |" for k, v in per.items()]
    lines += ["", f"Target: our FMU at H = dt ≤ ×1.2 the minimal C FMU; measured ×{res['ratio_H_dt']:.2f}.", ""]
    lines += [f"Rollback (CPU µs per call through fmpy, best of {repeat}; the FMU state is a native copy of "
              f"the instance's arrays):", "", "| call | µs | vs the oscillator's doStep of 10 internal steps |",
              "|---|---:|---:|"]
    step = res["state_us"]["oscillator FMU: doStep (H = 10 dt)"]
    lines += [f"| {k} | {v:.2f} | ×{v / step:.2f} |" for k, v in res["state_us"].items()]
    worst = max(res["set_vs_doStep"].values())
    lines += ["", f"Target: fmi2SetFMUstate ≤ ×5 a doStep of 10 internal steps; measured ×{worst:.2f} at most.", "",
              f"First doStep in a fresh process, empty cache (median of {fresh}):", "",
              "| phase | ms |", "|---|---:|"]
    lines += [f"| {k} | {v:.1f} |" for k, v in lat.items()]
    lines += ["", "fmi2Instantiate imports the FMU's plain-Python code (numpy; no numba: the stepper is native "
              "code in the binary); the import row is measured alone, in fresh processes."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--fresh", type=int, default=5, help="fresh processes for the first-step latency")
    ap.add_argument("--exit-check", type=int, default=0, metavar="N",
                    help="also run N fresh fmpy processes and count non-zero exits")
    ap.add_argument("--json", action="store_true", help="print the results as JSON")
    args = ap.parse_args(argv)
    results = _measure(args.steps, args.repeat, args.fresh, args.exit_check)
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print("Per communication step, fmpy loop setReal + doStep + getReal (CPU time, best of %d x %d steps):"
          % (args.repeat, args.steps))
    base = results["per_step_us"]["minimal C FMU (trivial step)"]
    for k, v in results["per_step_us"].items():
        print(f"  {k:<40} {v:8.2f} us   x{v / base:.2f}")
    print("Rollback, CPU time per call (vs the oscillator's doStep of 10 internal steps):")
    step = results["state_us"]["oscillator FMU: doStep (H = 10 dt)"]
    for k, v in results["state_us"].items():
        print(f"  {k:<40} {v:8.2f} us   x{v / step:.2f}")
    print(f"First doStep in a fresh process, empty cache (median of {args.fresh}):")
    for k, v in results["first_step_latency_ms"].items():
        print(f"  {k:<40} {v:8.1f} ms")
    if "exit_check" in results:
        e = results["exit_check"]
        print(f"Exit check: {e['failed']} of {e['processes']} fresh fmpy processes exited non-zero")
        for ex in e["examples"]:
            print(f"  {ex}")
        return 1 if e["failed"] else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
