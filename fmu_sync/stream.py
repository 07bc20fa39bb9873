"""A pair run streamed to disk in chunks (``simulate_pair(..., sink=...)``): the sink
that writes each chunk, keeps the metrics of :func:`fmu_sync.report.metrics` exact over
the whole record, and a thinned copy for the plots (memory: one chunk, whatever the run)."""
from __future__ import annotations

import numpy as np

from .core.result import concat_pairs as _concat
from .report import SYNC_THRESHOLD, exchange_fields, impact_records

__all__ = ["StreamRecord"]


class StreamRecord:
    """Sink of a pair run streamed in chunks (``simulate_pair(..., sink=...)``).

    Each chunk is written (``writer``: a :class:`~fmu_sync.output.RecordWriter`),
    folded into the metrics of :func:`metrics` (exact: maxima, t_sync, final d,
    contact episodes and the jumps of V and of the Euclidean error over them,
    found with the two rows before each chunk), and thinned to every
    ``every``-th row for the plots (:meth:`thinned`). Memory: one chunk plus the
    thinned copy, whatever the length of the run.
    """

    def __init__(self, writer, system=None, total_rows: int = 0, plot_rows: int = 20000,
                 threshold: float = SYNC_THRESHOLD, progress=None, every: int | None = None,
                 keep_distance: bool = False, window_rows: int = 0, write_every: int = 1):
        self.writer, self.system, self.threshold, self.progress = writer, system, threshold, progress
        self.total = max(int(total_rows), 1)
        # the rows written: every write_every-th (a record every run.record_every steps of a stream
        # of every step) and the last (:meth:`close_rows`); the plots' rows: a multiple of those
        self.write_every, self.written_to = max(1, int(write_every)), -1
        written = -(-self.total // self.write_every)
        self.every = (self.write_every * max(1, -(-written // max(int(plot_rows), 1))) if every is None
                      else max(1, int(every)))
        self.rows = 0
        self.keep = []
        # full resolution (the scene runner, fmu_sync/scenes/running.py): every row's d for the
        # decay fit (:meth:`sync`), and the rows around the largest impact mismatch (:meth:`window`)
        self.keep_distance, self.t_d = keep_distance, []
        self.window_rows, self.recent, self.win, self.win_peak, self.win_until = int(window_rows), None, None, -1.0, -1
        self.tail = None             # the last 2 rows of the previous chunk
        self.last = None             # the last row
        self.m = dict(peak_tau=0.0, euclid_max=-np.inf, peaking=-np.inf, dV=None, dE=None, hits=0,
                      e1=0, e2=0, last_above=None, first_t=None, any_d=False)

    _FIELDS = ("t", "q1", "u1", "q2", "u2", "tau1", "tau2", "d", "branch", "euclidean")

    def __call__(self, chunk) -> None:
        from .output import pair_columns
        n = np.asarray(chunk.q1).shape[1]
        cols = pair_columns(n, chunk.d is not None)
        if self.writer is not None:
            idx = np.arange(self.rows, self.rows + len(chunk.t))
            sel = np.nonzero(idx % self.write_every == 0)[0]
            if sel.size:
                part = chunk if sel.size == len(idx) else _take(chunk, sel)
                self.writer.append({k: getattr(part, k) for k, _ in cols})
                self.written_to = int(idx[sel[-1]])
        if chunk.d is not None:
            if self.keep_distance:
                self.t_d.append((np.array(chunk.t, dtype=float), np.array(chunk.d, dtype=float)))
            if self.window_rows > 0:
                self._follow_window(chunk)
        m = self.m
        t = np.asarray(chunk.t)
        if m["first_t"] is None:
            m["first_t"] = float(t[0])
        tau = np.concatenate([np.abs(chunk.tau1).ravel(), np.abs(chunk.tau2).ravel()])
        if tau.size:
            m["peak_tau"] = max(m["peak_tau"], float(np.nanmax(tau)))
        # contact episodes and the jumps over them, with the two rows before the chunk
        ext = chunk if self.tail is None else _concat([self.tail, chunk])
        off = 0 if self.tail is None else len(self.tail.t)
        e = []
        for i in (1, 2):
            h = impact_records(ext, i, self.system)
            h = h[h >= max(off, 1)]
            m[f"e{i}"] += int(h.size)
            e.append(h)
        if chunk.d is not None:
            m["any_d"] = True
            d, E = np.asarray(chunk.d), np.asarray(chunk.euclidean)
            m["euclid_max"] = max(m["euclid_max"], float(np.max(E)))
            m["peaking"] = max(m["peaking"], float(np.max(E - d)))
            above = np.nonzero(~(d < self.threshold))[0]
            if above.size:
                m["last_above"] = self.rows + int(above[-1])
                m["after_above"] = float(t[above[-1] + 1]) if above[-1] + 1 < len(t) else None
            elif m["last_above"] is not None and m.get("after_above") is None:
                m["after_above"] = float(t[0])
            hits = np.union1d(*e)
            if hits.size:
                V, Ee = np.asarray(ext.V), np.asarray(ext.euclidean)
                dV = float(np.max(np.abs(V[hits] - V[hits - 1])))
                dE = float(np.max(np.abs(Ee[hits] - Ee[hits - 1])))
                m["dV"] = dV if m["dV"] is None else max(m["dV"], dV)
                m["dE"] = dE if m["dE"] is None else max(m["dE"], dE)
                m["hits"] += int(hits.size)
        # thinning for the plots: global rows 0, every, 2 every, ...
        idx = np.arange(self.rows, self.rows + len(t))
        sel = np.nonzero(idx % self.every == 0)[0]
        if sel.size:
            self.keep.append(_take(chunk, sel))
        self.tail = _take(chunk, np.arange(max(0, len(t) - 2), len(t)))
        self.last = _take(chunk, np.arange(len(t) - 1, len(t)))
        self.last.impacts1, self.last.impacts2 = chunk.impacts1, chunk.impacts2
        self.rows += len(t)
        if self.progress is not None:
            self.progress(min(1.0, self.rows / self.total))

    def close_rows(self) -> None:
        """Write the last row when it is not one of every ``write_every``-th (the run's final state is
        always a row of its record)."""
        if self.writer is not None and self.last is not None and self.written_to != self.rows - 1:
            from .output import pair_columns
            cols = pair_columns(np.asarray(self.last.q1).shape[1], self.last.d is not None)
            self.writer.append({k: getattr(self.last, k) for k, _ in cols})
            self.written_to = self.rows - 1

    @property
    def rows_written(self) -> int:
        """The rows written so far (with :meth:`close_rows`: the record's)."""
        return 0 if self.written_to < 0 else self.written_to // self.write_every + 1 + \
            (1 if self.written_to % self.write_every else 0)

    def _follow_window(self, chunk) -> None:
        """Keep the rows within ``window_rows`` of the largest peaking ``E - d`` seen so far
        (the impact window's data, :func:`fmu_sync.plots.impact_window`), at the stream's resolution."""
        W = self.window_rows
        gap = np.asarray(chunk.euclidean) - np.asarray(chunk.d)
        gap = np.where(np.isfinite(gap), gap, -np.inf)
        k = int(np.argmax(gap))
        ext = chunk if self.recent is None else _concat([self.recent, chunk])
        off = 0 if self.recent is None else len(self.recent.t)
        if gap[k] > self.win_peak:
            self.win_peak = float(gap[k])
            self.win = _take(ext, np.arange(max(0, off + k - W), len(ext.t)))
            self.win_until = self.rows + k + W          # the last global row the window keeps
        elif self.win is not None and self.rows <= self.win_until:
            self.win = _concat([self.win, _take(chunk, np.arange(0, min(len(chunk.t), self.win_until - self.rows + 1)))])
        if self.win is not None and len(self.win.t) > 2 * W + 1:
            peak = int(np.argmax(np.asarray(self.win.euclidean) - np.asarray(self.win.d)))
            self.win = _take(self.win, np.arange(max(0, peak - W), min(len(self.win.t), peak + W + 1)))
        self.recent = _take(ext, np.arange(max(0, len(ext.t) - W), len(ext.t)))

    def window(self):
        """The rows around the largest impact mismatch at the stream's resolution (a PairResult), or None."""
        return self.win

    def sync(self):
        """:func:`fmu_sync.core.metrics.sync_metrics` of every row's d (``keep_distance``), or None."""
        from .core.metrics import sync_metrics
        if not self.t_d:
            return None
        t = np.concatenate([a for a, _ in self.t_d])
        d = np.concatenate([b for _, b in self.t_d])
        keep = np.concatenate(([True], np.diff(t) > 0))   # a chunk's start row repeats the last one
        try:
            return sync_metrics(t[keep], d[keep], self.threshold)
        except ValueError:
            return None

    def thinned(self):
        """The kept rows (every ``every``-th and the last) as one PairResult, for the plots."""
        parts = list(self.keep)
        if self.last is not None and (not parts or parts[-1].t[-1] != self.last.t[-1]):
            parts.append(self.last)
        r = _concat(parts)
        r.info = dict(r.info, thinned_every=self.every, rows=self.rows)
        return r

    def metrics(self, result=None) -> dict:
        """The :func:`metrics` dict of the whole streamed record."""
        m, last = self.m, self.last
        res = last if result is None else result
        out = {"t_end": float(last.t[-1]), "records": self.rows, "kind": "pair",
               "coupling": res.coupling or "none", "impacts1": int(res.impacts1),
               "impacts2": int(res.impacts2), "episodes1": m["e1"], "episodes2": m["e2"],
               "peak_tau": m["peak_tau"], "error": res.error, "thinned_every": self.every, **exchange_fields(res)}
        if not m["any_d"]:
            out.update(t_sync=None, final_d=None, euclid_max=None, peaking=None, dV_impact=None,
                       dE_impact=None)
            return out
        if m["last_above"] is None:
            t_sync = m["first_t"]
        else:
            t_sync = m.get("after_above")
            t_sync = float("inf") if t_sync is None else t_sync
        out.update(t_sync=t_sync, final_d=float(last.d[-1]), euclid_max=m["euclid_max"],
                   peaking=m["peaking"], dV_impact=m["dV"], dE_impact=m["dE"], impact_records=m["hits"])
        return out


def _take(r, idx):
    from .core.result import PairResult
    g = lambda a: None if a is None else np.asarray(a)[idx]  # noqa: E731
    return PairResult(*(g(getattr(r, k)) for k in StreamRecord._FIELDS), impacts1=r.impacts1,
                      impacts2=r.impacts2, coupling=r.coupling, info=dict(r.info), error=r.error)
