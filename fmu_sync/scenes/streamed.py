"""The streamed runs of a scene (docs/design.md §4.5): a core pair whose record exceeds the memory
budget, written in chunks while it runs (:func:`stream_run`), and a pair run at every step of its
grid with its rows folded as they come (:func:`full_resolution_run`). Split from
:mod:`.running` (which calls them)."""
from __future__ import annotations

import math
from pathlib import Path

from ..core import RunFailed
from .variant import RunRecord, with_units, declared_units, run_variant
from .schema import Variant

__all__ = ["stream_run", "full_resolution_run", "window_rows", "WINDOW_SECONDS"]


def stream_run(v: Variant, out_dir: Path, fmu_path, progress, scene_name, formats, est, max_memory, extra):
    """A core pair whose whole record exceeds the memory budget: written in chunks while it runs."""
    from .. import report
    from ..core.views import units_with
    from ..output import RecordWriter, pair_columns
    per_row = 8.0 * est.values_per_row
    chunk_rows = max(16, min(1 << 18, int(max_memory / (per_row * 8))))  # the chunk, its copies, the CSV block
    plot_rows = max(1000, min(20000, int(max_memory / (per_row * 8))))
    own = declared_units(v)
    lay = dict(kind="pair", N=2, n=v.system.n, edges=[[0, 1]], distance=v.has_distance,
               **({"units": units_with(own["units"])} if own else {}))
    writer = RecordWriter(out_dir / v.name, pair_columns(v.system.n, v.has_distance), formats, layout=lay)
    from ..output import record_steps, run_grid
    from ..stream import StreamRecord
    steps, step, _ = run_grid(v.cfg)
    # every step streamed (the metrics and the impact window from all of them), a row written every
    # run.record_every of them (full_resolution_run)
    sink = StreamRecord(writer, v.system, steps + 2, plot_rows, write_every=record_steps(v.cfg),
                        window_rows=window_rows(step, per_row, max_memory))
    try:
        last = run_variant(v, fmu_path, progress, scene_name, sink=sink, chunk_rows=chunk_rows, every=1)
        sink.close_rows()
    except RunFailed as exc:
        if sink.rows == 0:
            writer.abort()
            raise
        sink.close_rows()
        result = with_units(sink.thinned(), v)
        result.error = str(exc)
        result.impact_record = sink.window()
        writer.meta = report.record_meta(_counted(result, sink), extra)
        files = writer.close(partial=True)
        run = RunRecord(v.name, v, result, sink.metrics(result), files=files, streamed=True)
        run.metrics["error"] = str(exc)
        run.metrics["records"] = sink.rows_written
        return run
    except BaseException:
        writer.abort()
        raise
    result = with_units(sink.thinned(), v)
    writer.meta = report.record_meta(_counted(result, sink, last), extra)
    files = writer.close()
    result.impact_record = sink.window()
    metrics = sink.metrics(last)
    metrics["records"] = sink.rows_written
    # the fitted decay (envelope of d) and the ultimate bound from the thinned record (sampled
    # every `thinned_every` steps); t_sync, the maxima and the jumps above are exact
    metrics.update(report._sync_fields(report._sync(result, report.SYNC_THRESHOLD)))
    run = RunRecord(v.name, v, result, metrics, files=files, streamed=True)
    return run


#: the impact window's data at full resolution: the rows within this many seconds of the largest
#: impact mismatch (fmu_sync.plots.impact_window draws at most max(1.5 x the episode, 0.3 s) around it)
WINDOW_SECONDS = 2.0


def window_rows(step: float, per_row: float, max_memory: float) -> int:
    """Rows each side of the impact window's peak: :data:`WINDOW_SECONDS` of steps, at most what
    keeps the window (its rows, the rows before the next chunk, their copies) within a sixteenth of
    ``max_memory`` (``per_row``: bytes of a row)."""
    return max(16, min(int(math.ceil(WINDOW_SECONDS / step)), int(max_memory / (16.0 * per_row))))


def full_resolution_run(v: Variant, fmu_path, progress, scene_name, max_memory: float):
    """A pair variant (not a network) run at every step of its grid (``solver.dt``; ``run.H`` in
    co-simulation), its rows folded as they come (:class:`fmu_sync.stream.StreamRecord`): the summary's
    metrics (maxima, jumps at impacts, contact episodes, t_sync, the decay fit) and the impact
    window's rows (:attr:`PairResult.impact_record`) from every step, the record kept every
    ``run.record_every`` (:func:`fmu_sync.output.record_steps`): the metrics do not depend on it.
    The core streams its steps in chunks; a co-simulation records every communication step when
    that record fits ``max_memory`` (else at ``run.record_every``, its metrics from that record).
    Returns ``(result, metrics)``; a failure mid-way raises RunFailed with ``.partial`` the kept
    record and ``.metrics``."""
    from .. import report
    from ..output import estimate, record_steps, run_grid
    from ..stream import StreamRecord
    steps, step, _ = run_grid(v.cfg)
    every = record_steps(v.cfg)
    est = estimate(v)
    full_rows = steps + 2
    if v.mode == "cosim" and est.memory * est.record_every > max_memory:   # the full record does not fit
        every_run = every
    else:
        every_run = 1
    keep_d = 16.0 * full_rows / every_run <= 0.5 * max_memory   # every row's (t, d) for the decay fit
    sink = StreamRecord(None, v.system, full_rows, every=every // every_run, keep_distance=keep_d,
                        window_rows=window_rows(step * every_run, 8.0 * est.values_per_row, max_memory))

    def finish(last, error=None):
        result = sink.thinned()
        result.info = {k: val for k, val in (last or result).info.items() if k not in ("rows", "thinned_every")}
        result.impacts1, result.impacts2 = (last or result).impacts1, (last or result).impacts2
        result.error = error
        result.impact_record = sink.window()
        with_units(result, v)
        if result.impact_record is not None:
            result.impact_record.info = dict(result.info)
        m = sink.metrics(result)
        m.pop("thinned_every", None)
        m["records"] = len(result.t)
        fit = sink.sync() if keep_d else report._sync(result, report.SYNC_THRESHOLD)
        m.update(report._sync_fields(fit), **report._metric_fields(result))
        return result, m

    try:
        if v.mode == "core":
            chunk = max(64, min(65536, steps // 100))   # about 100 chunks: the progress moves (and Ctrl-C stops)
            last = run_variant(v, fmu_path, progress, scene_name, sink=sink, chunk_rows=chunk, every=1)
        else:
            last = run_variant(v, fmu_path, progress, scene_name, every=every_run)
            sink(last)
    except RunFailed as exc:
        if v.mode != "core" and exc.partial is not None:
            sink(exc.partial)
        if sink.rows == 0:
            raise
        exc.partial, exc.metrics = finish(exc.partial if v.mode != "core" else sink.last, str(exc))
        raise
    return finish(last)


def _counted(result, sink, last=None):
    """A streamed run for its file's meta: the counts and settings of the whole run (not those of
    the thinned copy the plots use)."""
    import copy
    src = last if last is not None else sink.last
    out = copy.copy(result)
    out.impacts1, out.impacts2 = src.impacts1, src.impacts2
    out.info = {k: v for k, v in src.info.items() if k not in ("rows", "thinned_every")}
    return out
