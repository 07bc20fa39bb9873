"""Running a scene (docs/design.md §4.5): each variant goes to the core
(:func:`~fmu_sync.core.simulate`, :func:`~fmu_sync.core.simulate_pair`) or to the
master (:func:`~fmu_sync.master.cosimulate`, values named by the FMU contract), then
its data, plots and ``summary.md`` are written."""
from __future__ import annotations


from pathlib import Path
from typing import Callable

from ..core import RunFailed, RunRefused
from ..progress import scaled
from .loading import Scene, as_scene
from .record import record_interval
from .schema import COSIM_KEYS, DEFAULT_OUT, TABLES, Variant
from .variant import (RunRecord, SceneRun, check_export, declared_units, export_for, export_spec, fmu_start_values,
                      plan_variant, preflight, run_variant, scene_values, variant_label)

__all__ = ["RunRecord", "SceneRun", "RunRefused", "RunInterrupted", "preflight", "plan_variant", "run_scene", "run_variant",
           "fmu_start_values", "scene_values", "check_export", "export_for", "export_spec", "write_run", "run_extra", "record_interval", "clean_written", "error_notes", "skipped_notes", "settings_table"]



def write_run(run: RunRecord, out_dir: Path, plots, title: str, formats=("csv", "npz"),
              progress: Callable | None = None, draw: bool = True) -> None:
    """Data (``formats``) and ``plots`` of a run (``draw=False``: the data only; its files
    still name the plots for ``fmu-sync plot DIR``); a failed run (``run.result.error``) gets
    its record marked partial and no plots (its data may be garbage past the failure)."""
    from .. import report
    failed = bool(getattr(run.result, "error", None))
    title = _title(title, run.name)
    if not run.streamed:
        run.files += report.write_data(run.result, out_dir / run.name, formats, progress=progress,
                                       partial=failed, extra=run_extra(run.variant, plots, title))
    if plots and draw and not failed:
        from .. import plots as P
        for p in plots:
            why = P.skip_reason(p, run.result)
            if why is not None:
                run.skipped.append((p, why))
            else:
                run.files.append(P.PLOTTERS[p](run.result, out_dir / f"{run.name}-{p}.png",
                                               system=run.variant.system, title=title))
        if (getattr(run.result, "info", None) or {}).get("tol") is not None:   # run.tol: H over time
            run.files.append(P.plot_steps(run.result, out_dir / f"{run.name}-steps.png", title=title))


def run_extra(variant: Variant, plots, title: str) -> dict:
    """What a data file keeps of the scene (:func:`fmu_sync.report.record_meta`): the variant's
    settings, the plots and title of ``fmu-sync plot DIR``, the wall (w, g0) they draw, and the
    record interval in seconds (:func:`record_interval`)."""
    from ..core.views import plain_settings
    return {"settings": plain_settings(variant.cfg), "plots": list(plots), "title": title,
            "wall": {"w": [float(x) for x in variant.system.w], "g0": float(variant.system.g0)},
            "record_interval": record_interval(variant)[0]}


def _title(scene_name: str, name: str) -> str:
    return scene_name if name == scene_name else f"{scene_name}, {name}"


def _scene_plan(scene, chosen, formats, max_memory, max_disk) -> list:
    """Every check of a scene run before anything is written: the FMU export, each variant's run
    plan (:func:`preflight`) and its record's budget; ``[(variant, formats, estimate, stream)]``."""
    from ..output import check_budget
    check_export(chosen)
    plan = []
    for v in chosen:
        preflight(v, scene.name)
        fmts = tuple(v.cfg["record.formats"]) if formats is None else tuple(formats)
        est, stream = check_budget(v, fmts, max_memory, max_disk,
                                   can_stream=v.pair and v.mode == "core" and not v.is_network,
                                   label=variant_label(v, scene.name))
        if stream and "nc" in fmts:
            from ..output import OutputTooLarge
            raise OutputTooLarge(f"{variant_label(v, scene.name)}: refused before running: the record exceeds the memory "
                                 f"budget and is written in chunks, which NetCDF (--format nc) cannot be: "
                                 f"{est.describe()}. Choose csv and/or npz, raise run.record_every, or raise "
                                 "--max-memory.")
        plan.append((v, fmts, est, stream))
    return plan


def _run_one(scene, v, out_dir, fmu_path, progress, marks, fmts, est, stream, max_memory) -> RunRecord:
    """One variant's run (streamed, at full resolution or as it is); a failure with nothing
    recorded: a RunRecord without result."""
    from .. import report
    from .streamed import full_resolution_run, stream_run
    a, mid, b = marks
    if stream:
        return stream_run(v, out_dir, fmu_path, scaled(progress, a, b), scene.name, fmts, est, max_memory,
                          run_extra(v, scene.plots, _title(scene.name, v.name)))
    try:
        if v.pair and not v.is_network:   # metrics and impact window from every step
            result, metrics = full_resolution_run(v, fmu_path, scaled(progress, a, mid), scene.name, max_memory)
        else:
            result, metrics = run_variant(v, fmu_path, scaled(progress, a, mid), scene.name), None
    except RunFailed as exc:
        if exc.partial is None:
            return RunRecord(v.name, v, None, {"error": str(exc), "kind": "failed"})
        result = exc.partial
        result.error = result.error or str(exc)
        metrics = getattr(exc, "metrics", None)
    return RunRecord(v.name, v, result, metrics or report.metrics(result, v.system))


def run_scene(scene, out_dir=None, overrides: dict | None = None, progress: Callable | None = None,
              variants=None, plots: bool = True, formats=None, max_memory: float | None = None,
              max_disk: float | None = None, overwrite: bool = False) -> SceneRun:
    """Run every (or the named) variant(s) of a scene and write data, plots and ``summary.md``.

    ``scene`` is a :class:`Scene` or a name/path for :func:`load_scene`. ``out_dir``
    defaults to ``./fmu-sync-out/<scene>``. ``progress(fraction)`` gets the overall
    fraction done (running and writing). ``formats``: data files (``("csv", "npz")``,
    default the scene's ``record.formats``). ``max_memory``/``max_disk`` (bytes): the
    budget of a run's record (:mod:`fmu_sync.output`); a core pair whose whole record
    exceeds ``max_memory`` is written in chunks while it runs.

    Everything is checked before anything is written: the output folder, the
    stability of each variant's step (:func:`preflight`) and its record size
    (:func:`fmu_sync.output.check_budget`). A variant that fails mid-way keeps
    its record, marked partial, without plots (``SceneRun.failed``); if nothing
    was recorded, nothing is left behind. A folder holding another scene's results
    (its ``summary.md``) is refused unless ``overwrite`` (which removes them).
    Interrupted (Ctrl-C, SIGTERM through the CLI): the finished variants are kept with
    a ``summary.md``, the interrupted one is removed, and :class:`RunInterrupted` says so.
    Returns a :class:`SceneRun`.
    """
    from ..output import DEFAULT_MAX_DISK, DEFAULT_MAX_MEMORY, check_out_dir, make_out_dir, results_in

    scene = as_scene(scene, overrides, variants)
    chosen = list(scene.variants)
    out_dir = check_out_dir(Path(out_dir) if out_dir is not None else DEFAULT_OUT / scene.name)
    max_memory = DEFAULT_MAX_MEMORY if max_memory is None else float(max_memory)
    max_disk = DEFAULT_MAX_DISK if max_disk is None else float(max_disk)
    plan = _scene_plan(scene, chosen, formats, max_memory, max_disk)

    old = results_in(out_dir, f"Scene `{scene.name}`", overwrite)
    clean_written(out_dir, False, old)   # --overwrite: another scene's results go, after every check passed
    created = make_out_dir(out_dir)
    fmus = {}
    runs = []
    current = None
    try:
        for i, (v, fmts, est, stream) in enumerate(plan):
            current = v.name
            fmu_path = None
            if v.pair and v.mode == "cosim":
                model = (v.cfg["system.model"], v.system.n)
                if model not in fmus:
                    fmus[model] = export_for(v, out_dir)
                fmu_path = fmus[model]
            a, b = i / len(plan), (i + 1) / len(plan)
            mid = a + 0.8 * (b - a) if not stream else b
            run = _run_one(scene, v, out_dir, fmu_path, progress, (a, mid, b), fmts, est, stream, max_memory)
            if run.result is None:
                runs.append(run)
                continue
            if run.result is not None and getattr(run.result, "error", None):
                run.metrics["error"] = run.result.error
            try:
                write_run(run, out_dir, scene.plots, scene.name, fmts, scaled(progress, mid, b), draw=plots)
            except BaseException:
                clean_written(out_dir, False, run.files)   # never half a variant's files
                raise
            if progress is not None:
                progress(b)
            runs.append(run)
            current = None
    except KeyboardInterrupt:
        raise _interrupted(scene, out_dir, created, runs, fmus, current, plots, chosen) from None
    except BaseException:
        clean_written(out_dir, created, [f for r in runs for f in r.files] + list(fmus.values()))
        raise
    return _summarize(scene, out_dir, created, runs, fmus, plots, chosen)


class RunInterrupted(KeyboardInterrupt):
    """A scene run interrupted: the message says what was kept and how to run the rest."""


def _interrupted(scene, out_dir, created, runs, fmus, current, plots, chosen) -> RunInterrupted:
    done = [r for r in runs if r.result is not None]
    rest = [v.name for v in chosen if v.name not in {r.name for r in runs}]
    if not done:
        clean_written(out_dir, created, list(fmus.values()))
        return RunInterrupted(f"interrupted during variant {current!r}: nothing kept (no variant had finished)")
    sr = _summarize(scene, out_dir, created, runs, fmus, plots, chosen)
    again = " ".join(f"--variant {n}" for n in rest)
    return RunInterrupted(
        f"interrupted during variant {current!r}: kept {', '.join(r.name for r in done)} in {sr.out_dir}/ "
        f"({'data, plots, summary.md' if plots else 'data, summary.md'}); to run the rest, repeat the command "
        f"with {again} and another -o")


def _summarize(scene, out_dir, created, runs, fmus, plots, chosen) -> SceneRun:
    from .. import report
    written = [r for r in runs if r.result is not None]
    if not written:   # every run failed without a record: leave nothing behind
        clean_written(out_dir, created, list(fmus.values()))
        sr = SceneRun(scene, out_dir, runs, [])
        return sr
    files = list(fmus.values()) + [f for r in runs for f in r.files]
    ok = [r for r in written if not r.metrics.get("error")]
    if plots and scene.compare and len(ok) > 1 and all(r.variant.has_distance for r in ok):
        from .. import plots as P
        files.append(P.compare_plot({r.name: r.result for r in ok}, out_dir / "compare-distance.png",
                                    title=f"{scene.name}: quotient distance d of each variant"))
    sr = SceneRun(scene, out_dir, runs, files)
    sr.summary = report.write_summary(out_dir / "summary.md", title=f"Scene `{scene.name}`",
                                      description=scene.description, rows=report.rows(written),
                                      settings=settings_table(scene, chosen), files=files, base=out_dir,
                                      notes=error_notes(runs) + stream_notes(runs) + skipped_notes(runs) + report.run_notes(written))
    return sr


def clean_written(out_dir: Path, created: bool, files) -> None:
    """Remove what this run wrote (and the folder if it made it and it is empty)."""
    for f in files:
        try:
            Path(f).unlink()
        except OSError:
            pass
    if created:
        try:
            out_dir.rmdir()
        except OSError:
            pass


def skipped_notes(runs) -> list[str]:
    return [f"**{r.name}**: no {p} plot: {why}" for r in runs for p, why in r.skipped]


def stream_notes(runs) -> list[str]:
    return [f"**{r.name}**: its record exceeded the memory budget and was written in chunks while it ran; "
            f"the plots, the fitted decay rate and the ultimate bound use every "
            f"{r.metrics['thinned_every']}-th of its steps (t_sync, maxima and jumps use all of them; its "
            f"record has {r.metrics['records']} rows)"
            for r in runs if r.metrics.get("thinned_every", 1) > 1]


def _relevant(key: str, variants) -> bool:
    """Settings worth listing: set (not None) and used by at least one variant."""
    for v in variants:
        if v.cfg.get(key) is None or key.startswith("plot."):
            continue
        if key.startswith("coupling.") and not v.pair:
            continue
        if key.startswith("network.") and not v.is_network:
            continue
        if key.startswith("initial.") and v.is_network:
            continue
        if key in COSIM_KEYS and v.mode != "cosim":
            continue
        if key == "solver.theta" and v.cfg["solver.scheme"] != "theta":
            continue
        return True
    return False


def error_notes(runs) -> list[str]:
    return [f"**{r.name} failed**: {r.metrics['error']}"
            + (" Its record up to the failure is marked partial (no plots)." if r.result is not None else
               " Nothing was recorded.")
            for r in runs if r.metrics.get("error")]


def settings_table(scene: Scene, variants, names=None) -> list[tuple[str, str]]:
    """Settings of the variants that ran (one value, or each run's own: ``names`` label
    the runs, default the variant names)."""
    names = [v.name for v in variants] if names is None else list(names)
    rows = [("scene file", str(scene.path))]
    if scene.overrides:
        rows.append(("overrides", ", ".join(f"{k}={v!r}" for k, v in scene.overrides.items())))
    keys = [k for k in variants[0].cfg if _relevant(k, variants)]
    for k in sorted(keys, key=lambda k: TABLES.index(k.split(".")[0])):
        values = {repr(v.cfg[k]) for v in variants}
        if len(values) == 1:
            rows.append((k, values.pop()))
        else:
            rows.append((k, "; ".join(f"{n}: {v.cfg[k]!r}" for n, v in zip(names, variants))))
    units = [declared_units(v).get("units") for v in variants]
    if any(units):
        rows.append(("units", ", ".join(f"{k} [{u}]" for k, u in units[0].items()) if units.count(units[0]) == len(units)
                     else "; ".join(f"{n}: {u}" for n, u in zip(names, units))))
    every = [record_interval(v)[1] for v in variants]
    rows.append(("record interval", every[0] if len(set(every)) == 1 else
                 "; ".join(f"{n}: {x}" for n, x in zip(names, every))))
    return rows


