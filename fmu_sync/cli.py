"""The ``fmu-sync`` command line.

    fmu-sync demo [-o DIR] [--quick]           export the FMU, co-simulate the forced pair 3 ways
    fmu-sync run SCENE [-o DIR] [--set k=v]..  run a built-in scene (name) or a scene file (path)
    fmu-sync run SCENE --convergence           rerun at the step, /2, /4: decay rate and t_sync
    fmu-sync scenes                            list the built-in scenes
    fmu-sync scenes --show NAME                print a scene as TOML (every key, defaults filled)
    fmu-sync plot DIR [--only KIND]..          draw a finished run's (or sweep's) plots again from its data
    fmu-sync export ...                        export an FMU (see `fmu-sync export --help`)
    fmu-sync validate FILE.fmu                 check an FMU with fmpy (exit 1 on problems)
    fmu-sync bench [--quick] [-o DIR]          the benchmark report DIR/benchmarks.md (see `fmu-sync bench --help`)
    fmu-sync report work-precision|stability   one of the mission's reports alone (options of `fmu-sync bench`)
    fmu-sync docs --regenerate | --check       the docs' published numbers, rewritten or checked (docs/benchmarks.md)
    fmu-sync sweep SCENE --grid K=V.. [-o DIR] gain maps, basins, samples (see `fmu-sync sweep --help`)

Exit status:

    0  every run reached its end
    2  bad input, refused before anything ran or was written: a bad scene or
       option, a missing file, an output path that is a file or not writable,
       a step not shorter than the run (dt or H >= t_end), a step known to be
       unstable (midpoint omega_max*dt >= 2, or the held
       coupling exchange beyond its limit: the message names omega_c*H and the
       largest stable H), a record above the memory/disk budget, an FMU that
       refuses to instantiate (the line gives the FMU's logged reason)
    3  a run failed mid-way (diverged, a slave failed): the summary says which,
       its record up to the failure is written marked partial (no plots)
  130  interrupted

Errors end with one line ``fmu-sync: error: ...`` on stderr.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from . import __version__

__all__ = ["main"]

PROG = "fmu-sync"
EXIT_BAD_INPUT = 2
EXIT_FAILED = 3


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Controlled synchronization of impacting mechanical "
                                "systems: Moreau core, quotient distance, FMI 2.0 co-simulation.")
    p.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)

    _add_demo(sub)
    _add_run(sub)

    sp = sub.add_parser("ssp", help="write a coupled scene as an SSP 1.0 package (systems + coupling FMU)")
    sp.add_argument("scene", help="built-in scene name or path to a .toml file (a pair or a network)")
    sp.add_argument("--variant", default=None, metavar="NAME", help="the variant (required if the scene has several)")
    sp.add_argument("-o", "--output", type=Path, required=True, help="package to write (FILE.ssp)")
    sp.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="override a scene key, e.g. --set run.t_end=60 (TOML values)")

    sc = sub.add_parser("scenes", help="list the built-in scenes, or print one as TOML (--show)")
    sc.add_argument("--show", metavar="NAME", default=None,
                    help="print the scene (built-in name or .toml path) as TOML with every key, defaults "
                         "filled; it loads back to the same scene")
    pl = sub.add_parser("plot", help="draw a finished run's plots again from its data files (or a sweep's "
                        "maps from its sweep.nc)")
    pl.add_argument("dir", type=Path, help="the output folder of `fmu-sync run`, `demo` or `sweep`")
    pl.add_argument("--only", action="append", default=[], metavar="KIND",
                    help="draw only this plot (repeatable): positions, distance, impact-zoom, lyapunov, "
                         "forces, phase")
    sub.add_parser("export", help="export an FMU (options: see `fmu-sync export --help`)", add_help=False)
    v = sub.add_parser("validate", help="validate an FMU with fmpy; exit 1 if it has problems")
    v.add_argument("fmu", type=Path, help="path of the .fmu file")
    sub.add_parser("bench", help="the benchmark report DIR/benchmarks.md (options: see `fmu-sync bench --help`)",
                   add_help=False)
    sub.add_parser("report", help="one of the mission's reports: work-precision (error against run time) or "
                   "stability (stiff and extreme cases); options as `fmu-sync bench`", add_help=False)
    sub.add_parser("docs", help="the README's and docs' published numbers and figures: --regenerate, --check "
                   "(options: see `fmu-sync docs --help`)", add_help=False)
    from .sweeps.cli import add_parser as add_sweep
    add_sweep(sub)
    return p


def _add_demo(sub) -> None:
    """``fmu-sync demo``."""
    d = sub.add_parser("demo", help="export the FMU and co-simulate the forced pair (uncoupled, "
                       "Euclidean, switching); compare with the monolithic core")
    d.add_argument("-o", "--out", type=Path, default=Path("fmu-sync-demo"), help="output folder "
                   "(default ./fmu-sync-demo)")
    d.add_argument("--quick", action="store_true", help="shorter run (40 s simulated instead of 100 s)")
    d.add_argument("--t-end", type=float, default=None, metavar="SECONDS",
                   help="simulated time (default 100 s, 40 s with --quick)")
    d.add_argument("--starts", type=int, default=16, metavar="N",
                   help="compare the Euclidean and switching laws by their decay rate over N start states "
                        "(median and interquartile range; default 16, 0: not computed)")
    d.add_argument("--quiet", action="store_true", help="no progress display")


def _add_run(sub) -> None:
    """``fmu-sync run``: a scene or an SSP package."""
    r = sub.add_parser("run", help="run a scene (built-in name or .toml path) or an SSP package (.ssp)")
    r.add_argument("scene", help="built-in scene name (see `fmu-sync scenes`), path to a .toml file, or an "
                   "SSP package written by `fmu-sync ssp` (run in our master)")
    r.add_argument("-o", "--out", type=Path, default=None, help="output folder (default ./fmu-sync-out/<scene>)")
    r.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene key, e.g. --set coupling.Kp=2 --set run.t_end=50 (TOML values); "
                        "an SSP package takes run.t_end, run.H, run.exchange, run.hold, run.tol, run.event_aware "
                        "and run.H_min")
    r.add_argument("--variant", action="append", default=[], metavar="NAME",
                   help="run only this variant of the scene (repeatable)")
    r.add_argument("--no-plots", action="store_true", help="write data and summary only")
    r.add_argument("--quiet", action="store_true", help="no progress display")
    r.add_argument("--format", dest="formats", default=None, metavar="LIST",
                   help="data files to write, comma separated: csv, npz, nc (NetCDF, the result's "
                        "xarray Dataset) or none (default: the scene's record.formats, csv and npz)")
    r.add_argument("--allow-unstable", action="store_true",
                   help="run even if the coupling exchange is unstable at this step (same as "
                        "--set run.allow_unstable=true); a run that then diverges exits with status 3")
    r.add_argument("--max-memory", default=None, metavar="SIZE",
                   help="memory budget of a run's record, e.g. 4GB (default 2GB); a core pair above it "
                        "is written in chunks while it runs, other runs are refused")
    r.add_argument("--max-disk", default=None, metavar="SIZE",
                   help="disk budget of a run's data files, e.g. 50GB (default 20GB)")
    r.add_argument("--overwrite", action="store_true",
                   help="replace another scene's results found in the output folder (refused otherwise)")
    r.add_argument("--starts", type=int, default=0, metavar="N",
                   help="also run each coupled pair variant from N start states (its own first) and report "
                        "the ensemble decay rate: median and interquartile range (summary.md, the terminal)")
    r.add_argument("--convergence", action="store_true",
                   help="rerun each variant at its step, /2 and /4 (solver.dt in core mode, run.H in cosim) "
                        "and write only the metrics (decay rate, t_sync, bound) to convergence.md/.csv")
    r.add_argument("--method", default="jacobi", metavar="ORDER",
                   help="SSP package only: the exchange order, jacobi (default), gauss-seidel, delayed "
                        "(libcosim's) or delayed-zero (fmpy's SSP runner); see docs/ssp.md")


def _progress(label: str, quiet: bool):
    from .progress import Progress
    return Progress(label, force=False if quiet else None)


def _print_summary(sr, title: str) -> None:
    from . import report
    print(f"\n{title}")
    written = [r for r in sr.runs if r.result is not None]
    if written:
        header, table = report.rows(written, demo=title.startswith("demo"))
        report.print_table(header, table)
        for note in report.run_notes(written):
            print("  " + note.replace("**", ""))
    for r in sr.runs:
        if r.metrics.get("error"):
            kept = "record kept, marked partial, no plots" if r.result is not None else "nothing recorded"
            print(f"  FAILED: {r.name}: {r.metrics['error']} ({kept})")
    if sr.summary is not None:
        print(f"\nwritten to {sr.out_dir}/ (summary: {sr.summary.name}, {len(sr.files)} data/plot files)")
    else:
        print("\nnothing written")


def _cmd_plot(args) -> int:
    from .results import redraw
    files = redraw(args.dir, [k for x in args.only for k in x.split(",") if k])
    for f in files:
        print(f)
    print(f"\n{len(files)} plot file(s) written to {args.dir}/")
    return 0


def _cmd_scenes(show=None) -> int:
    if show is not None:
        from .scenes.reference import scene_toml
        print(scene_toml(show), end="")
        return 0
    from .scenes.loading import list_scenes
    from .scenes import SCENE_DIR
    rows = list_scenes()
    width = max(len(n) for n, _ in rows)
    for name, desc in rows:
        print(f"{name.ljust(width)}  {desc}")
    print(f"\nrun one with `{PROG} run NAME`; copy a file from {SCENE_DIR} to make your own.")
    return 0


def _cmd_ssp(args) -> int:
    from .scenes.loading import parse_override
    from .ssp import write_ssp
    overrides = dict(parse_override(s) for s in args.overrides)
    path = write_ssp(args.scene, args.output, args.variant, overrides)
    print(f"wrote {path}")
    return 0


def _cmd_run_ssp(args) -> int:
    from .core import RunFailed
    from .output import check_out_dir, parse_formats
    from .scenes.loading import parse_override
    from .ssp import run_ssp, save_result
    from .ssp.settings import SET_KEYS, overrides
    if args.variant or args.convergence:
        raise ValueError(f"an SSP package takes --method, -o, --format, --no-plots, --allow-unstable, --quiet and "
                         f"--set {', '.join(SET_KEYS)} only (its values are the package's: edit its .ssv files, "
                         f"or the scene and write it again)")
    experiment, settings = overrides(dict(parse_override(s) for s in args.overrides))
    formats = parse_formats(args.formats) if args.formats is not None else ("csv", "npz")
    out = check_out_dir(args.out or Path("fmu-sync-out") / Path(args.scene).stem)
    failed = None
    with _progress(Path(args.scene).name, args.quiet) as bar:
        try:
            res = run_ssp(args.scene, method=args.method, progress=bar, allow_unstable=args.allow_unstable,
                          settings=settings, **experiment)
        except RunFailed as exc:   # keep the record up to the failure, marked partial
            if exc.partial is None:
                raise
            res, failed = exc.partial, exc
            res.error = res.error or str(exc)
    summary = save_result(res, out, formats, plots=not args.no_plots, method=args.method)
    if failed is not None:
        print(f"{PROG}: error: {_one_line(failed)} (record kept, marked partial, no plots: {summary.parent}/)",
              file=sys.stderr)
        return EXIT_FAILED
    m = res.sync()
    print(f"{args.scene}: {len(res.info['components'])} systems, method {args.method}, H = {res.info['H_package']:g}, "
          f"t_end = {res.t[-1]:g} s; max d at the end {res.d_max[-1]:.3g}, t_sync(1e-6) = {m.t_sync:.4g} s")
    print(f"written to {summary.parent}/ (summary: {summary.name})")
    return 0


def _cmd_run(args) -> int:
    if str(args.scene).endswith(".ssp"):
        return _cmd_run_ssp(args)
    from .scenes.loading import load_scene, parse_override
    from .scenes.running import run_scene
    from .output import parse_formats, parse_size
    _check_starts(args.starts)
    overrides = dict(parse_override(s) for s in args.overrides)
    if args.allow_unstable:
        overrides["run.allow_unstable"] = True
    formats = parse_formats(args.formats) if args.formats is not None else None
    max_memory = parse_size(args.max_memory) if args.max_memory is not None else None
    max_disk = parse_size(args.max_disk) if args.max_disk is not None else None
    scene = load_scene(args.scene, overrides, args.variant or None)
    idle = _idle_keys(scene)
    _announce_compilation(scene, args.quiet)
    if args.convergence:
        return _cmd_convergence(scene, args, max_memory, max_disk)
    with _progress(scene.name, args.quiet) as bar:
        sr = run_scene(scene, args.out, progress=bar, plots=not args.no_plots, formats=formats,
                       max_memory=max_memory, max_disk=max_disk, overwrite=args.overwrite)
    _print_summary(sr, f"scene {scene.name}")
    if idle:
        print(f"  note: {idle}")
        if sr.summary is not None:
            from .ensemble import add_to_summary
            add_to_summary(sr.summary, [f"- note: {idle}", ""])
    if args.starts and not sr.failed:
        from . import ensemble
        with _progress(f"{scene.name} ensemble", args.quiet) as bar:
            ens = ensemble.scene_ensembles(sr.runs, args.starts, sr.out_dir, bar, scene.name)
        if ens:
            ensemble.print_table(ens)
            if sr.summary is not None:
                ensemble.add_to_summary(sr.summary, ensemble.markdown(ens, args.starts))
        else:
            print("\n--starts: no coupled pair variant to run (single systems, networks and uncoupled pairs "
                  "have no ensemble rate)")
    return EXIT_FAILED if sr.failed else 0


def _idle_keys(scene) -> str | None:
    """When the variants mix modes, the note saying which variants a co-simulation key given with
    --set does not apply to (None if none). A run whose variants are all in the core refuses such
    a key when the scene loads (:func:`fmu_sync.scenes.loading.load_scene`, issue 44 item 4)."""
    from .scenes.schema import COSIM_KEYS
    given = [k for k in scene.overrides if k in COSIM_KEYS]
    core = [v.name for v in scene.variants if v.mode != "cosim"]
    if not given or not core:
        return None
    keys = ", ".join(f"--set {k}" for k in given)
    return f"{keys} applies to the co-simulated variants only: not to {', '.join(core)} (run.mode = 'core')"


def _cmd_convergence(scene, args, max_memory, max_disk) -> int:
    from .scenes.convergence import convergence, format_table, refined_key, refined_what, verdicts
    from .output import estimate
    steps = sum(estimate(v).steps for v in scene.variants)
    if not args.quiet:
        for what in dict.fromkeys(refined_what(refined_key(v)) for v in scene.variants):
            names = ", ".join(v.name for v in scene.variants if refined_what(refined_key(v)) == what)
            print(f"convergence check: {names} at {what}", file=sys.stderr)
        print(f"({7 * steps:.4g} steps in all at fixed steps; a tolerance run takes the steps it needs), only "
              f"the metrics kept", file=sys.stderr, flush=True)
    with _progress(f"{scene.name} convergence", args.quiet) as bar:
        cr = convergence(scene, args.out, progress=bar, max_memory=max_memory, max_disk=max_disk)
    print(f"\nscene {scene.name}: convergence of the synchronization metrics")
    print(format_table(cr.variants))
    print()
    for line in verdicts(cr.variants):
        print(f"  {line}")
    print(f"\nwritten to {cr.out_dir}/ (convergence.md, convergence.csv)")
    return 0


def _announce_compilation(scene, quiet: bool) -> None:
    """Say so when numba's caches are cold: the first run compiles the kernels (up to a minute)."""
    if quiet:
        return
    from .progress import caches_cold
    if caches_cold():
        print("compiling kernels, first run only (about a minute; later runs load them from the cache)",
              file=sys.stderr, flush=True)


def _check_starts(n: int) -> None:
    """``--starts N``: refused before anything runs unless N >= 0 (0: no ensemble)."""
    if n < 0:
        raise ValueError(f"--starts must be a whole number >= 0 (0: no ensemble rate), got {n}")


def _cmd_demo(args) -> int:
    from .scenes.demo import run_demo
    _check_starts(args.starts)
    _announce_compilation(None, args.quiet)
    with _progress("demo", args.quiet) as bar:
        sr = run_demo(args.out, quick=args.quick, progress=bar, t_end=args.t_end, n_starts=args.starts)
    _print_summary(sr, "demo: forced pair, co-simulation vs core")
    if sr.ensembles:
        from .ensemble import print_table
        print_table(sr.ensembles)
    return EXIT_FAILED if sr.failed else 0


def _cmd_validate(path: Path) -> int:
    if not path.is_file():
        raise FileNotFoundError(f"no such FMU: {path}")
    from fmpy.validation import validate_fmu
    try:
        problems = validate_fmu(str(path))
    except Exception as exc:  # not a zip, unreadable XML, ...: a problem of the file, not a crash
        problems = [f"cannot read the FMU: {type(exc).__name__}: {exc}"]
    if problems:
        print(f"{path}: {len(problems)} problem(s):")
        for p in problems:
            print(f"  - {p}")
        return 1
    print(f"{path}: valid (no problems found by fmpy)")
    return 0


def _cmd_report(argv) -> int:
    """``fmu-sync report NAME [bench options]``: the bench run with that one report section."""
    from .benchmarks import REPORTS, main as bench_main
    names = " | ".join(REPORTS)
    if argv and argv[0] in ("-h", "--help"):
        print(f"usage: {PROG} report {{{names}}} [--quick] [-o DIR] [--no-cosim]\n\n"
              "work-precision: error against run time of every solver on the built-in scenes; "
              "stability: stiff and extreme cases, each row with its criterion. Writes DIR/benchmarks.md "
              f"(and the report's CSV), as `{PROG} bench --only NAME` does.")
        return 0
    if not argv or argv[0] not in REPORTS:
        got = repr(argv[0]) if argv else "nothing"
        raise ValueError(f"{PROG} report needs a report name, one of {names}; got {got}")
    return int(bench_main(["--only", argv[0], *argv[1:]]) or 0)


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:   # plain words, not "[Errno 13] ..."
        from .output import plain_os_error
        return plain_os_error(exc)
    msg = str(exc).strip() or type(exc).__name__
    return " ".join(line.strip() for line in msg.splitlines() if line.strip())


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    import warnings

    import numpy as np
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        # a diverging run's arithmetic (overflow, nan) is reported by the run's own failure,
        # not by numpy RuntimeWarnings
        warnings.simplefilter("ignore", RuntimeWarning)
        return _main(argv)


def _terminate(signum, frame):
    """SIGTERM ends a run as Ctrl-C does: what is finished is kept, nothing half-written stays."""
    raise KeyboardInterrupt


def _main(argv) -> int:
    import signal

    from .core import RunFailed
    from .fmi_bridge import InstantiationFailed
    from .scenes.schema import SceneError   # refusals are ValueErrors (exit 2) by type, never by message
    try:
        signal.signal(signal.SIGTERM, _terminate)
    except ValueError:   # not the main thread (an embedding host): leave the handler alone
        pass
    try:
        # export and bench keep their own option parsers: hand them the rest of the line
        if argv and argv[0] == "export":
            from .export import main_export
            return int(main_export(argv[1:]) or 0)
        if argv and argv[0] == "bench":
            from .benchmarks import main as bench_main
            return int(bench_main(argv[1:]) or 0)
        if argv and argv[0] == "report":
            return _cmd_report(argv[1:])
        if argv and argv[0] == "docs":
            from .published import main as docs_main
            return int(docs_main(argv[1:]) or 0)
        args = _parser().parse_args(argv)
        if args.command == "scenes":
            return _cmd_scenes(args.show)
        if args.command == "plot":
            return _cmd_plot(args)
        if args.command == "run":
            return _cmd_run(args)
        if args.command == "ssp":
            return _cmd_ssp(args)
        if args.command == "demo":
            return _cmd_demo(args)
        if args.command == "validate":
            return _cmd_validate(args.fmu)
        if args.command == "sweep":
            from .sweeps.cli import run as run_sweep
            return run_sweep(args)
        raise AssertionError(args.command)
    except InstantiationFailed as exc:   # an FMU that refused to instantiate: nothing ran
        print(f"{PROG}: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except RunFailed as exc:   # a run that failed mid-way (or a diverging single system)
        print(f"{PROG}: error: {_one_line(exc)}", file=sys.stderr)
        # an FMU that refuses to instantiate (its logged reason: an edited file, the GUID): nothing ran
        return EXIT_BAD_INPUT if str(getattr(exc, "call", "")).endswith("Instantiate") else EXIT_FAILED
    except (SceneError, FileNotFoundError, FileExistsError, ValueError, ImportError) as exc:
        prefix = "missing component: " if isinstance(exc, ImportError) else ""
        print(f"{PROG}: error: {prefix}{_one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:   # the disk filled up, a folder vanished, ...: while writing
        print(f"{PROG}: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt as exc:   # the run or sweep says what it kept and how to go on
        print(f"{PROG}: {_one_line(exc) if str(exc) else 'interrupted'}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
