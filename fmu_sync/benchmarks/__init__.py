"""``fmu-sync bench [--quick] [-o DIR]``: core speed, work–precision and stability reports.

Writes into DIR (default ``./fmu-sync-bench/``):

* ``work_precision.csv`` — method, scene, metric, step, error, seconds, repeats, spread,
  reference, note (one row per run; see :mod:`.work_precision`);
* ``work_precision_<scene>_<metric>.png`` — log–log error vs run time;
* ``stability.csv`` — one row per stability case with its criterion and pass/FAIL;
* ``bench.md`` — the reports (tables and one-line interpretations); the speed section includes
  the sweep throughput (:mod:`.sweep_speed`, also alone with ``--only sweep``).

``--quick`` shrinks ladders, horizons and repeats (a few minutes on 2 cores);
``--smoke`` (for the test suite) shrinks everything further and skips the core speed
section, so that the whole pipeline runs in seconds — its numbers mean nothing.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["main", "EXTRA_SECTIONS"]

#: optional sibling benchmark modules, included when they provide ``run(quick) -> markdown``
EXTRA_SECTIONS = ("fmu_cost", "sweep_speed", "cosim_speed")  # distance_cost is part of core_speed


def _versions() -> str:
    out = [f"Python {platform.python_version()}"]
    for mod in ("numpy", "numba", "scipy", "fmpy", "matplotlib"):
        try:
            out.append(f"{mod} {__import__(mod).__version__}")
        except Exception:  # pragma: no cover
            out.append(f"{mod} n/a")
    return ", ".join(out)


def _load() -> str:
    try:
        return "/".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover
        return "n/a"


def _export(tmp: Path):
    try:
        from fmu_sync import export_fmu
        return export_fmu("impact-oscillator", tmp / "ImpactOscillator.fmu"), None
    except Exception as ex:  # pragma: no cover - FMU tool chain missing
        return None, f"{type(ex).__name__}: {ex}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="fmu-sync bench",
        description="Core speed, work-precision (error vs run time) and stability reports.")
    parser.add_argument("--quick", action="store_true", help="smaller ladders and fewer repeats (minutes)")
    parser.add_argument("-o", "--output", default="fmu-sync-bench", metavar="DIR",
                        help="output folder (default: ./fmu-sync-bench/)")
    parser.add_argument("--smoke", action="store_true",
                        help="tiny ladders, no core speed section: checks the pipeline only (for tests)")
    parser.add_argument("--no-cosim", action="store_true", help="leave out the FMU co-simulation runs")
    parser.add_argument("--only", choices=("speed", "work-precision", "stability", "sweep", "hold"), action="append",
                        help="run only these sections (repeatable)")
    args = parser.parse_args(argv)
    quick = args.quick or args.smoke
    sections = set(args.only or ("speed", "work-precision", "stability", "hold"))
    if args.smoke:
        sections.discard("speed")

    from fmu_sync.progress import Progress

    from . import stability, work_precision
    from .plots import work_precision_plots

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    mode = "smoke" if args.smoke else ("quick" if args.quick else "full")
    t_start = time.perf_counter()
    load0 = _load()
    print(f"fmu-sync bench ({mode}) -> {out}/  [{os.cpu_count()} CPUs, load {load0}]", flush=True)
    parts = []
    timings = {}
    with tempfile.TemporaryDirectory(prefix="fmu-sync-bench-") as tmp:
        fmu, why = (None, "--no-cosim") if args.no_cosim else _export(Path(tmp))
        if fmu is None:
            print(f"co-simulation runs skipped: {why}", flush=True)

        if "speed" in sections:
            from . import core_speed
            t0 = time.perf_counter()
            with Progress("core speed") as bar:
                bar(0.0)
                md = core_speed.run(quick=quick)
                bar(1.0)
            timings["core speed"] = time.perf_counter() - t0
            print(md, flush=True)
            parts.append(md)
        elif not args.smoke:
            parts.append("## Core speed\n\nnot run (--only).\n")
        else:
            parts.append("## Core speed\n\nskipped (--smoke).\n")

        if sections & {"speed", "sweep"}:
            # sibling benchmarks that offer the same entry point as core_speed: run(quick) -> markdown
            import importlib
            for name in EXTRA_SECTIONS:
                need = {"speed", "sweep"} if name == "sweep_speed" else {"speed"}
                if not need & sections:
                    continue
                try:
                    mod = importlib.import_module(f"{__name__}.{name}")
                except ImportError:
                    continue
                if not callable(getattr(mod, "run", None)):
                    continue
                t0 = time.perf_counter()
                with Progress(name) as bar:
                    bar(0.0)
                    md = mod.run(quick=quick)
                    bar(1.0)
                timings[name] = time.perf_counter() - t0
                print(md, flush=True)
                parts.append(md)

        if "work-precision" in sections:
            t0 = time.perf_counter()
            with Progress("work-precision") as bar:
                wp = work_precision.run(quick=quick, fmu=fmu, progress=bar, smoke=args.smoke)
            work_precision.write_csv(wp.points, out / "work_precision.csv")
            pngs = work_precision_plots(wp.points, out)
            timings["work-precision"] = time.perf_counter() - t0
            md = wp.markdown + "\nDiagrams: " + ", ".join(f"`{p.name}`" for p in pngs) + ".\n"
            print(md, flush=True)
            parts.append(md)

        if "stability" in sections:
            t0 = time.perf_counter()
            with Progress("stability") as bar:
                rows, md = stability.run(quick=quick, fmu=fmu, progress=bar, smoke=args.smoke)
            stability.write_csv(rows, out / "stability.csv")
            timings["stability"] = time.perf_counter() - t0
            print(md, flush=True)
            parts.append(md)

        if "hold" in sections:
            if fmu is None:
                parts.append(f"## Co-simulation hold: zero- vs first-order (and the exact slave)\n\nnot run "
                             f"(co-simulation skipped: {why}).\n")
            else:
                from . import hold_order
                t0 = time.perf_counter()
                with Progress("hold") as bar:
                    md = hold_order.run(quick=quick, smoke=args.smoke, progress=bar)
                timings["hold"] = time.perf_counter() - t0
                print(md, flush=True)
                parts.append(md)

    total = time.perf_counter() - t_start
    head = [
        "# fmu-sync benchmarks", "",
        f"- mode: **{mode}**; wall time {total:.0f} s ("
        + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()) + ")",
        f"- machine: {platform.machine()}, {os.cpu_count()} CPUs, load average (1/5/15 min) {load0} at the "
        f"start, {_load()} at the end — shared machine: timings are medians of interleaved repeats and "
        "the cost columns are ratios to a baseline measured in the same run",
        f"- {_versions()}",
        f"- co-simulation: {'FMU exported by fmu_sync.export, run by fmu_sync.master (fmpy)' if fmu else 'skipped (' + str(why) + ')'}",
        "",
    ]
    (out / "bench.md").write_text("\n".join(head) + "\n" + "\n".join(parts))
    written = [out / "bench.md"]
    if "work-precision" in sections:
        written += [out / "work_precision.csv", out / "work_precision_*.png"]
    if "stability" in sections:
        written.append(out / "stability.csv")
    print(f"wrote {', '.join(map(str, written))} in {total:.0f} s", flush=True)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
