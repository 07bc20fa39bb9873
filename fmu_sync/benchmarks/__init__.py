"""``fmu-sync bench [--quick] [-o DIR]``: the benchmark report, DIR/benchmarks.md.

Two kinds of section (``--only`` picks among them):

* the mission's **reports**, also run alone by ``fmu-sync report NAME`` (:data:`REPORTS`):
  ``work-precision`` (error against run time, every solver on the built-in scenes:
  :mod:`.work_precision`, its cases and analysis in ``work_precision_*``) and ``stability``
  (stiff and extreme cases, each row with its criterion: :mod:`.stability`, ``stability_*``);
* **timings** (developer benchmarks, ratios against a baseline measured in the same run):
  ``speed`` (core kernels vs a C loop, the quotient distance, the FMU per step and at start-up,
  :mod:`.core_speed`, :mod:`.distance_cost`, :mod:`.fmu_cost`), ``sweep`` (sweep throughput,
  :mod:`.sweep_speed`), ``hold`` (co-simulation hold order, :mod:`.hold_order`), ``implicit``
  (the implicit exchange on a stiff pair, :mod:`.implicit_exchange`) and ``networks`` (the
  implicit exchange on rings of impacting oscillators, N = 8 ... 256, :mod:`.implicit_networks`).

Writes into DIR (default ``./fmu-sync-bench/``):

* ``benchmarks.md`` — all sections run (tables and one-line interpretations), with the machine,
  its load and the versions; copy it to the repository's ``docs/benchmarks.md`` to publish it
  (docs/benchmarks.md says how);
* ``work_precision.csv`` — method, scene, metric, step, error, seconds, repeats, spread,
  reference, note (one row per run; see :mod:`.work_precision`);
* ``work_precision_<scene>_<metric>.png`` — log–log error vs run time;
* ``stability.csv`` — one row per stability case with its criterion and pass/FAIL.

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

__all__ = ["main", "EXTRA_SECTIONS", "REPORTS", "SECTIONS", "PAGE", "publish", "generated_part"]

#: the mission's reports (``fmu-sync report NAME``): error against run time, stability on stiff
#: and extreme cases
REPORTS = ("work-precision", "stability")
#: every section of ``fmu-sync bench`` (``--only``); the default runs all but ``sweep``
SECTIONS = ("speed", "sweep", "hold", "implicit", "networks") + REPORTS
#: the markdown page ``fmu-sync bench`` writes into its output folder (docs/benchmarks.md when published)
PAGE = "benchmarks.md"
#: the lines between which ``--publish`` replaces a page's generated part (the rest of the page stays)
BEGIN = "<!-- fmu-sync bench: begin"
END = "<!-- fmu-sync bench: end -->"

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


def _generated_span(text: str, page: Path, begin: str = BEGIN, end: str = END) -> tuple[int, int]:
    """Where the generated part of ``page`` lies: from the end of the begin-marker line to the
    start of the end-marker line. A page without one pair of markers, in order, is refused.
    (Also the rule of every published block of the docs: :mod:`fmu_sync.published`.)"""
    b, e = text.find(begin), text.find(end)
    if b < 0 or e < 0 or text.count(begin) != 1 or text.count(end) != 1 or e < b:
        raise ValueError(f"{page}: the page must hold one line starting {begin!r} and, after it, one "
                         f"line {end!r} (the part between them is replaced); found begin at {b}, end at {e}")
    start = text.find("\n", b)
    return (len(text) if start < 0 else start + 1), e


def generated_part(page, begin: str = BEGIN, end: str = END) -> str:
    """The text between the markers of ``page`` (ValueError without one pair of them)."""
    page = Path(page)
    text = page.read_text()
    a, b = _generated_span(text, page, begin, end)
    return text[a:b]


def publish(report: str, page, begin: str = BEGIN, end: str = END) -> Path:
    """Write ``report`` into ``page`` between its markers (a new page: the markers around it)."""
    page = Path(page)
    if not page.exists():
        page.write_text(f"{begin} (replaced by `fmu-sync bench --publish`) -->\n{report.rstrip()}\n{end}\n")
        return page
    text = page.read_text()
    a, b = _generated_span(text, page, begin, end)
    page.write_text(text[:a] + report.rstrip() + "\n" + text[b:])
    return page


def _check_publish(page) -> None:
    """Refuse a --publish target before anything runs."""
    page = Path(page)
    if page.is_dir() or not page.parent.is_dir():
        raise ValueError(f"--publish {page}: not a file in an existing folder")
    if page.exists():
        _generated_span(page.read_text(), f"--publish {page}")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fmu-sync bench",
        description=f"The benchmark report DIR/{PAGE}: timings (speed, sweep, hold) and the reports "
                    "work-precision (error vs run time) and stability (stiff and extreme cases).")
    parser.add_argument("--quick", action="store_true", help="smaller ladders and fewer repeats (minutes)")
    parser.add_argument("-o", "--output", default="fmu-sync-bench", metavar="DIR",
                        help="output folder (default: ./fmu-sync-bench/)")
    parser.add_argument("--publish", metavar="PAGE", default=None,
                        help=f"also write the report into PAGE (e.g. docs/benchmarks.md) between its lines "
                             f"'{BEGIN} ...' and '{END}'; the rest of the page stays")
    parser.add_argument("--smoke", action="store_true",
                        help="tiny ladders, no core speed section: checks the pipeline only (for tests)")
    parser.add_argument("--no-cosim", action="store_true", help="leave out the FMU co-simulation runs")
    parser.add_argument("--only", choices=SECTIONS, action="append",
                        help="run only these sections (repeatable); the reports alone: fmu-sync report NAME")
    return parser


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    argv_shown = list(sys.argv[1:] if argv is None else argv)
    if args.publish is not None:
        _check_publish(args.publish)
    quick = args.quick or args.smoke
    sections = set(args.only or (s for s in SECTIONS if s != "sweep"))
    if args.smoke:
        sections.discard("speed")

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    mode = "smoke" if args.smoke else ("quick" if args.quick else "full")
    t_start = time.perf_counter()
    load0 = _load()
    print(f"fmu-sync bench ({mode}) -> {out}/  [{os.cpu_count()} CPUs, load {load0}]", flush=True)
    parts = []
    timings = {}

    def section(name, run):
        """Run one section (``run() -> markdown``), timed under ``name``, printed and kept."""
        t0 = time.perf_counter()
        md = run()
        timings[name] = time.perf_counter() - t0
        print(md, flush=True)
        parts.append(md)

    with tempfile.TemporaryDirectory(prefix="fmu-sync-bench-") as tmp:
        fmu, why = (None, "--no-cosim") if args.no_cosim else _export(Path(tmp))
        if fmu is None:
            print(f"co-simulation runs skipped: {why}", flush=True)
        _timing_sections(sections, quick, args.smoke, section, parts)
        _report_sections(sections, quick, args.smoke, fmu, out, section)
        _cosim_sections(sections, quick, args.smoke, fmu, why, section, parts)

    total = time.perf_counter() - t_start
    report = _head(mode, argv_shown, total, timings, load0, fmu, why) + "\n" + "\n".join(parts)
    (out / PAGE).write_text(report)
    written = [out / PAGE]
    if args.publish is not None:
        written.append(publish(report, args.publish))
    if "work-precision" in sections:
        written += [out / "work_precision.csv", out / "work_precision_*.png"]
    if "stability" in sections:
        written.append(out / "stability.csv")
    print(f"wrote {', '.join(map(str, written))} in {total:.0f} s", flush=True)
    return 0


def _with_bar(name, run):
    """``run()`` under a progress bar that only says started / done."""
    from fmu_sync.progress import Progress
    with Progress(name) as bar:
        bar(0.0)
        md = run()
        bar(1.0)
    return md


def _timing_sections(sections, quick, smoke, section, parts) -> None:
    """The core speed section, then the sibling timing modules (:data:`EXTRA_SECTIONS`)."""
    if "speed" in sections:
        from . import core_speed
        section("core speed", lambda: _with_bar("core speed", lambda: core_speed.run(quick=quick)))
    else:
        parts.append("## Core speed\n\nnot run (--only).\n" if not smoke
                     else "## Core speed\n\nskipped (--smoke).\n")
    if not sections & {"speed", "sweep"}:
        return
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
        if callable(getattr(mod, "run", None)):
            section(name, lambda: _with_bar(name, lambda: mod.run(quick=quick)))


def _report_sections(sections, quick, smoke, fmu, out, section) -> None:
    """The mission's reports: work-precision (with its csv, diagrams and the tolerance table)
    and stability (with its csv)."""
    from fmu_sync.progress import Progress

    from . import stability, work_precision
    from .plots import work_precision_plots
    if "work-precision" in sections:
        def wp_section():
            with Progress("work-precision") as bar:
                wp = work_precision.run(quick=quick, fmu=fmu, progress=bar, smoke=smoke)
            work_precision.write_csv(wp.points, out / "work_precision.csv")
            pngs = work_precision_plots(wp.points, out)
            return wp.markdown + "\nDiagrams: " + ", ".join(f"`{p.name}`" for p in pngs) + ".\n"
        section("work-precision", wp_section)
        if fmu is not None:   # the co-simulation to a tolerance against fixed H (issue 34)
            from . import tolerance
            section("work-precision: tolerance", lambda: tolerance.run(quick=quick, out=out, smoke=smoke))
    if "stability" in sections:
        def stab_section():
            with Progress("stability") as bar:
                rows, md = stability.run(quick=quick, fmu=fmu, progress=bar, smoke=smoke)
            stability.write_csv(rows, out / "stability.csv")
            return md
        section("stability", stab_section)


def _cosim_sections(sections, quick, smoke, fmu, why, section, parts) -> None:
    """The co-simulation timings: hold order, implicit exchange, networks (need the FMU)."""
    import importlib

    from fmu_sync.progress import Progress
    for name, title, module in (("hold", "Co-simulation hold: zero- vs first-order", "hold_order"),
                                ("implicit", "Implicit exchange on a stiff pair", "implicit_exchange"),
                                ("networks", "Implicit exchange on networks with impacts", "implicit_networks")):
        if name not in sections:
            continue
        if fmu is None:
            parts.append(f"## {title}\n\nnot run (co-simulation skipped: {why}).\n")
            continue
        mod = importlib.import_module(f".{module}", __name__)

        def run(mod=mod, name=name):
            with Progress(name) as bar:
                return mod.run(quick=quick, smoke=smoke, progress=bar)
        section(name, run)


def _head(mode, argv_shown, total, timings, load0, fmu, why) -> str:
    """The report's head: the command, mode and wall times, the machine and its load, versions."""
    return "\n".join([
        "# fmu-sync benchmarks", "",
        f"Written by `fmu-sync bench{' ' + ' '.join(argv_shown) if argv_shown else ''}`; every number below "
        "was measured in this run.", "",
        f"- mode: **{mode}**; wall time {total:.0f} s ("
        + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()) + ")",
        f"- machine: {platform.machine()}, {os.cpu_count()} CPUs, load average (1/5/15 min) {load0} at the "
        f"start, {_load()} at the end — shared machine: timings are medians of interleaved repeats and "
        "the cost columns are ratios to a baseline measured in the same run",
        f"- {_versions()}",
        f"- co-simulation: {'FMU exported by fmu_sync.export, run by fmu_sync.master (fmpy)' if fmu else 'skipped (' + str(why) + ')'}",
        "",
    ])


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
