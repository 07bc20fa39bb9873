"""Summary metrics, data files and tables (markdown ``summary.md`` and terminal).

Takes a :class:`~fmu_sync.core.result.PairResult` (monolithic or co-simulated)
or, for single-system scenes, a :class:`~fmu_sync.core.SimulationResult`.
"""
from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np


__all__ = ["SYNC_THRESHOLD", "is_pair", "wall", "impact_rows", "impact_records", "contact_starts", "metrics", "record_columns", "record_meta", "write_data", "write_netcdf", "rows", "write_summary", "md_table",
           "print_table", "max_abs_difference", "format_value", "run_notes", "decay_resolved",
           "EUCLIDEAN_MEASURE"]

#: d below this counts as synchronized (time to sync = first time after which d stays below it).
SYNC_THRESHOLD = 1e-6


def is_pair(result) -> bool:
    """PairResult (two systems) rather than a single-system SimulationResult."""
    return hasattr(result, "q2")


def is_network(result) -> bool:
    """NetworkResult (N systems on a graph)."""
    return hasattr(result, "edges")


def _sync(result, threshold):
    """The robust synchronization metrics (``result.sync``: fitted decay rate with its
    uncertainty, t_sync, ultimate bound), or None where the core does not provide them."""
    if getattr(result, "d", None) is None or not hasattr(result, "sync"):
        return None
    try:
        return result.sync(threshold)
    except ValueError:
        return None


def _sync_fields(m) -> dict:
    if m is None:
        return {}
    return dict(rate=m.rate, rate_err=m.rate_err, t_fit=m.t_fit, bound=m.bound, fit_from=m.t_from,
                fit_to=m.t_to, fit_floor=m.d_to, rate_reason=m.reason, rate_resolved=m.resolved,
                rate_window=m.window_text(), d0=m.d0, starts_below=m.starts_below)


def _metric_fields(result) -> dict:
    """Which position weight Q the run's distance used (docs/design.md §2.5.1)."""
    info = getattr(result, "info", {}) or {}
    if info.get("metric") is None:
        return {}
    return dict(metric=info["metric"], Q=info.get("Q"), metric_note=info.get("metric_note", ""))


def exchange_fields(result) -> dict:
    """What a co-simulation's exchange adds to its metrics: the implicit exchange's FMU steps per
    communication step (median, max; docs/design.md §4.4) and a run to a tolerance's steps and
    estimate (:func:`adaptive_fields`, §4.4.1); empty for other runs."""
    info = getattr(result, "info", {}) or {}
    it = info.get("iterations")
    out = {} if it is None or len(it) == 0 else dict(iterations_median=float(np.median(it)),
                                                      iterations_max=int(np.max(it)))
    out.update(adaptive_fields(info))
    t = np.asarray(getattr(result, "t", ()), dtype=float)
    if "tol" in out and t.size > 1:   # tol chooses the steps: the record's intervals as they were
        dt = np.diff(t)
        out.update(row_dt_min=float(dt.min()), row_dt_median=float(np.median(dt)), row_dt_max=float(dt.max()))
    return out


def network_metrics(result, threshold: float = SYNC_THRESHOLD) -> dict:
    """Summary numbers of a network run (d: the largest pairwise distance d_max)."""
    t = np.asarray(result.t)
    tau = np.abs(np.asarray(result.tau))
    out = {"t_end": float(t[-1]) if t.size else 0.0, "records": int(t.size), "kind": "network",
           "N": int(np.asarray(result.q).shape[1]), "edges": len(result.edges),
           "coupling": _coupling_name(result.info.get("coupling")),
           "impact_steps": int(np.sum(result.impacts)), "peak_tau": float(np.nanmax(tau)) if tau.size else 0.0,
           "error": result.error, **exchange_fields(result)}
    if result.d is None and result.euclidean is not None and t.size:   # no common impact geometry
        return _euclidean_fields(out, t, np.max(np.asarray(result.euclidean), axis=1), threshold)
    if result.d is None:
        out.update(t_sync=None, final_d=None)
        return out
    dmax = result.d_max
    above = np.nonzero(~(dmax < threshold))[0]
    t_sync = float(t[0]) if above.size == 0 else (math.inf if above[-1] == len(t) - 1 else float(t[above[-1] + 1]))
    out.update(t_sync=t_sync, final_d=float(dmax[-1]), **_sync_fields(_sync(result, threshold)),
               **_metric_fields(result))
    return out


#: how the summary names the measure of a run without a common impact geometry (docs/design.md §2.5.3)
EUCLIDEAN_MEASURE = "Euclidean error"


def _euclidean_fields(out: dict, t, emax, threshold) -> dict:
    """A network without one impact map: d and V are not defined; t_sync, the decay rate and the
    bound are those of the largest Euclidean error ||x_i - x_j||_P over the edges, named as such."""
    from .core.metrics import sync_metrics
    above = np.nonzero(~(emax < threshold))[0]
    t_sync = float(t[0]) if above.size == 0 else (math.inf if above[-1] == len(t) - 1 else float(t[above[-1] + 1]))
    try:
        m = sync_metrics(t, emax, threshold)
    except ValueError:
        m = None
    out.update(t_sync=t_sync, final_d=None, measure=EUCLIDEAN_MEASURE, final_euclidean=float(emax[-1]),
               **_sync_fields(m))
    return out


def _coupling_name(c) -> str:
    if c is None:
        return "none"
    if isinstance(c, str):
        return c
    names = sorted({x or "none" for x in c})
    return "/".join(names) + " (per edge)"


def wall(system, n: int):
    """``(w, g0)`` of the constraint; without a system the 1-DOF wall q >= 0."""
    if system is None:
        return np.ones(n), 0.0
    return np.asarray(system.w, dtype=float), float(system.g0)


def impact_rows(t, q, u, system=None) -> np.ndarray:
    """Indices ``i`` of records whose last interval contains an impact, from the samples alone.

    A record counts when the normal velocity ``w.u`` went from approaching the wall
    (< 0) to leaving or resting (>= 0), the approach was smooth (the previous change
    of ``w.u`` is below half the approach speed) and the gap is within reach of the wall
    (``g <= 2 dt_record (|w.u-| + |w.u+|)``). ``system`` gives ``w, g0`` (default:
    1-DOF wall at q = 0). Used for plots and metrics of runs that do not carry the
    per-step percussions (pair runs); turning points in free flight far from the
    wall never count.
    """
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float).reshape(len(t), -1)
    u = np.asarray(u, dtype=float).reshape(len(t), -1)
    if len(t) < 2:
        return np.zeros(0, dtype=int)
    w, g0 = wall(system, q.shape[1])
    vn = u @ w
    g = q @ w + g0
    scale = max(float(np.max(np.abs(vn))), 1e-300)
    before, after = vn[:-1], vn[1:]
    reach = 2.0 * np.diff(t) * (np.abs(before) + np.abs(after)) + 1e-12 * (1.0 + np.abs(g0))
    # smooth flight before: the approach speed exceeds the last change of w.u. This
    # excludes the velocity chatter of persistent contact (w.u flips sign every step).
    earlier = np.concatenate((vn[:1], vn[:-2]))
    flight = np.abs(before - earlier) < 0.5 * np.abs(before)
    tol = 1e-9 * scale   # velocities below this are round-off (resting in contact)
    hit = (before < -tol) & (after >= -tol) & (g[1:] <= reach) & flight
    return np.nonzero(hit)[0] + 1


def impact_records(result, i: int, system=None) -> np.ndarray:
    """Records of system ``i`` (1 or 2) of a pair run that contain an impact.

    Uses per-record percussions when the result carries them (``percussion1`` /
    ``percussion2`` as attributes or in ``info``): the records that start a contact
    episode. Otherwise they are inferred from the samples by :func:`impact_rows`.
    """
    p = getattr(result, f"percussion{i}", None)
    if p is None:
        p = (getattr(result, "info", None) or {}).get(f"percussion{i}")
    if p is not None and len(p) == len(result.t):
        return contact_starts(p)
    return impact_rows(result.t, getattr(result, f"q{i}"), getattr(result, f"u{i}"), system)


def contact_starts(percussion) -> np.ndarray:
    """Records that start a contact episode (P > 0 after a record with P = 0)."""
    p = np.asarray(percussion) > 0.0
    prev = np.concatenate(([False], p[:-1]))
    return np.nonzero(p & ~prev)[0]


def metrics(result, system=None, threshold: float = SYNC_THRESHOLD) -> dict:
    """Summary numbers of one run (keys documented in :data:`PAIR_COLUMNS` / :data:`SINGLE_COLUMNS`)."""
    if is_network(result):
        return network_metrics(result, threshold)
    t = np.asarray(result.t)
    out = {"t_end": float(t[-1]) if t.size else 0.0, "records": int(t.size)}
    if not is_pair(result):
        starts = contact_starts(result.percussion)
        p = np.asarray(result.percussion) > 0.0
        free = np.nonzero(~p)[0]
        resting = bool(p.size and p[-1])
        out.update(kind="single", impacts=int(result.impacts), episodes=int(starts.size),
                   q_final=result.q[-1].tolist(), u_final=result.u[-1].tolist(),
                   contact_from=(float(t[free[-1] + 1]) if free.size else float(t[0])) if resting else None,
                   scheme=result.scheme, dt=float(result.dt))
        return out
    tau = np.concatenate([np.abs(np.asarray(result.tau1)).ravel(), np.abs(np.asarray(result.tau2)).ravel()])
    e1, e2 = impact_records(result, 1, system), impact_records(result, 2, system)
    out.update(kind="pair", coupling=result.coupling or "none", impacts1=int(result.impacts1),
               impacts2=int(result.impacts2), episodes1=int(e1.size), episodes2=int(e2.size),
               peak_tau=float(np.nanmax(tau)) if tau.size else 0.0, error=result.error, **exchange_fields(result))
    if result.d is None:
        out.update(t_sync=None, final_d=None, euclid_max=None, peaking=None, dV_impact=None, dE_impact=None)
        return out
    d, E, V = np.asarray(result.d), np.asarray(result.euclidean), np.asarray(result.V)
    hits = np.union1d(e1, e2)
    hits = hits[hits > 0]
    out.update(_sync_fields(_sync(result, threshold)), **_metric_fields(result))
    out.update(t_sync=result.time_to_sync(threshold), final_d=float(d[-1]), euclid_max=float(E.max()),
               peaking=float(np.max(E - d)),
               dV_impact=float(np.max(np.abs(V[hits] - V[hits - 1]))) if hits.size else None,
               dE_impact=float(np.max(np.abs(E[hits] - E[hits - 1]))) if hits.size else None,
               impact_records=int(hits.size))
    return out


def adaptive_fields(info) -> dict:
    """A co-simulation to a tolerance (docs/design.md §4.4.1): its tol, communication steps
    (accepted, rejected), shortest and longest step and estimated error (empty otherwise)."""
    if not info or info.get("tol") is None:
        return {}
    H = np.asarray(info["step_lengths"], dtype=float)
    return dict(tol=info["tol"], comm_steps=int(info["steps"]), rejected=int(info["rejected"]),
                H_shortest=float(H.min()) if H.size else None, H_longest=float(H.max()) if H.size else None,
                error_estimate=float(info["error_estimate"]), tol_met=bool(info.get("tol_met", True)),
                tol_not_met=info.get("tol_not_met") or "")


def max_abs_difference(a, b, attr: str = "d") -> float | None:
    """max |a.attr - b.attr| on a's time grid (b linearly interpolated where the grids differ),
    over the common time span; None if either run lacks ``attr``."""
    x, y = getattr(a, attr, None), getattr(b, attr, None)
    if x is None or y is None:
        return None
    ta, tb = np.asarray(a.t), np.asarray(b.t)
    x, y = np.asarray(x).reshape(len(ta), -1)[:, 0], np.asarray(y).reshape(len(tb), -1)[:, 0]
    keep = (ta >= tb[0] - 1e-12) & (ta <= tb[-1] + 1e-12)
    if ta.shape == tb.shape and np.allclose(ta, tb, rtol=0, atol=1e-9 * max(1.0, abs(ta[-1]))):
        yb = y
    else:
        yb = np.interp(ta, tb, y)
    return float(np.max(np.abs(x[keep] - yb[keep]))) if keep.any() else None


# ---------------------------------------------------------------- data files
def record_columns(result) -> tuple[list, dict]:
    """``(columns, data)`` of a result for :class:`~fmu_sync.output.RecordWriter`."""
    from .output import network_columns, pair_columns, single_columns
    if is_network(result):
        rows, N, n = np.asarray(result.q).shape
        E = len(result.edges)
        only_e = result.d is None and result.euclidean is not None   # no common geometry: the Euclidean error
        cols = network_columns(N, n, E, "euclidean" if only_e else result.d is not None)
        data = {"t": result.t, "q": np.asarray(result.q).reshape(rows, N * n),
                "u": np.asarray(result.u).reshape(rows, N * n), "tau": np.asarray(result.tau).reshape(rows, N * n)}
        if only_e:
            data.update(euclidean=result.euclidean)
        elif result.d is not None:
            data.update(d=result.d, euclidean=result.euclidean, branch=result.branch, V=result.V,
                        d_max=result.d_max)
    elif is_pair(result):
        n = np.asarray(result.q1).reshape(len(result.t), -1).shape[1]
        cols = pair_columns(n, result.d is not None)
        data = {k: getattr(result, k) for k, _ in cols}
    else:
        n = np.asarray(result.q).reshape(len(result.t), -1).shape[1]
        cols = single_columns(n)
        data = {k: getattr(result, k) for k, _ in cols}
    return cols, data


def record_meta(result, extra: dict | None = None) -> dict:
    """What a data file keeps besides the arrays (the ``.npz`` member ``meta``): the layout
    (kind, N, n, edges), counts, coupling, the run's ``info`` and ``extra`` (the scene's
    settings, plots, title and wall), so :func:`fmu_sync.load` rebuilds the result."""
    from . import __version__
    from .core.views import layout, plain_settings
    meta = {"fmu_sync": __version__, **layout(result), "error": getattr(result, "error", None),
            "info": plain_settings(getattr(result, "info", None) or {})}
    if is_network(result):
        meta["impacts"] = [int(x) for x in result.impacts]
    elif is_pair(result):
        meta.update(impacts1=int(result.impacts1), impacts2=int(result.impacts2), coupling=result.coupling)
    else:
        meta.update(scheme=result.scheme, dt=float(result.dt))
    meta.update(extra or {})
    return meta


def write_data(result, stem, formats=("csv", "npz"), progress=None, partial: bool = False,
               extra: dict | None = None) -> list[Path]:
    """Write ``<stem>.csv`` (tidy, one row per record), ``<stem>.npz`` (arrays and
    :func:`record_meta`) in chunks of rows (``progress(fraction)`` after each) and/or
    ``<stem>.nc`` (the result's xarray Dataset, settings as attributes); a failed run's
    record is named ``<stem>.partial.*``. Returns the paths written."""
    from .output import WRITE_ROWS, RecordWriter
    if not formats:
        return []
    cols, data = record_columns(result)
    meta = record_meta(result, extra)
    files = []
    if "csv" in formats or "npz" in formats:
        w = RecordWriter(stem, cols, formats, layout=meta, meta=meta)
        try:
            n = len(result.t)
            for a in range(0, max(n, 1), WRITE_ROWS):
                w.append({k: np.asarray(v)[a:a + WRITE_ROWS] for k, v in data.items()})
                if progress is not None:
                    progress(min(1.0, (a + WRITE_ROWS) / max(n, 1)))
            files += w.close(partial=partial)
        except BaseException:
            w.abort()
            raise
    if "nc" in formats:
        files.append(write_netcdf(result, Path(f"{stem}{'.partial' if partial else ''}.nc"), meta))
    return files


def write_netcdf(result, path, meta: dict | None = None) -> Path:
    """``result.to_xarray()`` as NetCDF-4 (h5netcdf), atomically; ``meta``'s settings,
    plots, title and wall become attributes."""
    import json
    path = Path(path)
    keep = {k: v for k, v in (meta or {}).items() if k in ("settings", "plots", "title", "wall", "fmu_sync")}
    settings = {k: (json.dumps(v) if isinstance(v, (dict, list)) else v) for k, v in keep.items()}
    ds = result.to_xarray(settings)
    tmp = path.with_name(path.name + ".tmp")
    try:
        ds.to_netcdf(tmp, engine="h5netcdf")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


# ---------------------------------------------------------------- tables
def format_value(x) -> str:
    if x is None:
        return "—"
    if isinstance(x, str):
        return x
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(format_value(v) for v in x) + "]"
    if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
        return str(int(x))
    x = float(x)
    if math.isinf(x):
        return "never" if x > 0 else "-inf"
    if math.isnan(x):
        return "nan"
    return f"{x:.4g}"


def _episodes(m):
    """``e1/e2``; "—" for a system whose solver counted impact steps while its record shows no
    arrival at the wall (unresolved chatter, or a record too coarse to see them)."""
    if "episodes1" not in m:
        return "—"
    cells = []
    for i in (1, 2):
        e, k = m[f"episodes{i}"], m.get(f"impacts{i}", 0)
        cells.append("—" if e == 0 and k > 0 else str(e))
    return "/".join(cells)


def _rate(m):
    """``rate ± err`` of the fitted decay of d's envelope when it is resolved, else — (the reason
    goes to the notes: :func:`run_notes`)."""
    r, e = m.get("rate"), m.get("rate_err")
    if not decay_resolved(m):
        return None
    return f"{r:.4g} ± {e:.2g}"


def decay_resolved(m) -> bool:
    """A decay rate worth showing: the metrics' own verdict (:attr:`SyncMetrics.resolved
    <fmu_sync.core.metrics.SyncMetrics.resolved>`)."""
    return bool(m.get("rate_resolved")) and m.get("rate") is not None


def _t_sync(m):
    t = m.get("t_sync")
    if t == math.inf:
        return "not within t_end"
    if m.get("starts_below") and isinstance(t, (int, float)):
        return f"{format_value(t)} (d0 below)"
    return t


def run_notes(runs) -> list[str]:
    """Per run: why a decay rate is not shown, a start below the threshold, the fit window's end,
    and which Q the distance used (a user Q: V is then not a Lyapunov function of the law)."""
    out = []
    for r in runs:
        m = r.metrics
        if m.get("error") or m.get("kind") == "single":
            continue
        bits = []
        if m.get("measure") == EUCLIDEAN_MEASURE:
            bits.append(f"no common impact geometry (the nodes differ in M, w, g0 or e): d and V are not defined; "
                        f"t_sync, the decay rate and the bound are those of the largest {EUCLIDEAN_MEASURE} "
                        f"||x_i - x_j||_P (P = diag(Q, mean M)), final {format_value(m['final_euclidean'])}")
        if m.get("rate_reason"):
            bits.append(f"decay rate — : {m['rate_reason']}")
        elif m.get("rate_window"):
            bits.append(f"decay rate over its {m['rate_window']}")
        if m.get("starts_below"):
            bits.append(f"d0 = {m['d0']:.3g} starts below the t_sync threshold: its t_sync says nothing")
        if m.get("metric"):
            bits.append(f"Q = {m['Q']} ({m['metric']}): {m.get('metric_note', '')}")
        if m.get("iterations_max") is not None:
            bits.append(f"implicit exchange: FMU steps per communication step median "
                        f"{m['iterations_median']:g}, max {m['iterations_max']}; its recorded tau is each step's "
                        f"force at the step's start, the FMUs integrated the line to the law at its end (the "
                        f"mean with the zero-order hold): fmu_sync.applied.applied_forces(result)")
        if m.get("tol") is not None:
            bits.append(f"co-simulated to tol = {m['tol']:g}: {m['comm_steps']} communication steps of "
                        f"{format_value(m['H_shortest'])} to {format_value(m['H_longest'])} s "
                        f"({m['rejected']} rejected and retaken), estimated error {m['error_estimate']:.3g} "
                        f"(q's unit, docs/design.md §4.4.1)"
                        + ("" if m.get("tol_met", True) else f"; tolerance NOT met: {m['tol_not_met']}"))
        if m.get("row_dt_median") is not None:
            bits.append(f"its record's rows came every {format_value(m['row_dt_min'])} to "
                        f"{format_value(m['row_dt_max'])} s (median {format_value(m['row_dt_median'])} s)")
        if bits:
            out.append(f"**{m.get('name', r.name)}**: " + "; ".join(bits))
    return out


#: (column header, function of the metrics dict)
PAIR_COLUMNS = [
    ("variant", lambda m: m["name"]),
    ("coupling", lambda m: m.get("coupling", "—")),
    (f"t_sync [s] (d<{SYNC_THRESHOLD:g})", _t_sync),
    ("decay rate [1/s]", lambda m: _rate(m)),
    ("ultimate bound", lambda m: m.get("bound")),
    ("max|tau| [N]", lambda m: m.get("peak_tau")),
    ("impact steps 1/2", lambda m: f"{m['impacts1']}/{m['impacts2']}" if "impacts1" in m else "—"),
    ("contact episodes 1/2", lambda m: _episodes(m)),
    ("max(|x1-x2|-d)", lambda m: m.get("peaking")),
    ("final d", lambda m: m.get("final_d")),
    ("max dV over an episode start", lambda m: m.get("dV_impact")),
]
DEMO_COLUMNS = [("variant", lambda m: m.get("variant", m["name"])), ("mode", lambda m: m.get("mode"))] + PAIR_COLUMNS[1:] + [
    ("max|d - d_core|", lambda m: m.get("d_vs_core"))]
NETWORK_COLUMNS = [
    ("variant", lambda m: m["name"]),
    ("N", lambda m: m.get("N")),
    ("coupling", lambda m: m.get("coupling", "—")),
    (f"t_sync [s] (max d<{SYNC_THRESHOLD:g})", _t_sync),
    ("decay rate [1/s]", lambda m: _rate(m)),
    ("ultimate bound", lambda m: m.get("bound")),
    ("final max d", lambda m: m.get("final_d")),
    ("max|tau| [N]", lambda m: m.get("peak_tau")),
    ("impact steps (all nodes)", lambda m: m.get("impact_steps")),
]
#: the columns a co-simulation to a tolerance adds (docs/design.md §4.4.1)
ADAPTIVE_COLUMNS = [
    ("tol", lambda m: m.get("tol")),
    ("steps (rejected)", lambda m: f"{m['comm_steps']} ({m['rejected']})" if "comm_steps" in m else "—"),
    ("error estimate", lambda m: m.get("error_estimate")),
    ("tol met", lambda m: ("yes" if m["tol_met"] else "NO") if "tol_met" in m else "—"),
]
SINGLE_COLUMNS = [
    ("run", lambda m: m["name"]),
    ("t_end [s]", lambda m: m["t_end"]),
    ("impact steps", lambda m: m.get("impacts")),
    ("contact episodes", lambda m: m.get("episodes")),
    ("rests on wall from [s]", lambda m: m.get("contact_from")),
    ("final q", lambda m: m.get("q_final")),
    ("final u", lambda m: m.get("u_final")),
]


def rows(runs, demo: bool = False) -> tuple[list[str], list[list[str]]]:
    """Header and formatted rows for a list of runs (objects with ``.name`` and ``.metrics``)."""
    single = all(r.metrics.get("kind") == "single" for r in runs)
    network = all(r.metrics.get("kind") == "network" for r in runs)
    cols = SINGLE_COLUMNS if single else NETWORK_COLUMNS if network else (DEMO_COLUMNS if demo else PAIR_COLUMNS)
    if any(r.metrics.get("tol") is not None for r in runs):
        cols = cols + ADAPTIVE_COLUMNS
    table = []
    for r in runs:
        m = {**r.metrics, "name": r.name}
        if m.get("error"):   # a failed run: no synchronization numbers from its garbage
            m.update(t_sync="FAILED", rate=None, bound=None, final_d=None)
        table.append([format_value(f(m)) if (single or network or m.get("kind") == "pair" or i == 0) else "—"
                      for i, (_, f) in enumerate(cols)])
    from .core.views import units_of
    tau = {units_of(r.result)["tau"] for r in runs if getattr(r, "result", None) is not None}
    unit = tau.pop() if len(tau) == 1 else "N"   # the runs' declared unit of tau (one model's)
    return [h.replace("|tau| [N]", f"|tau| [{unit}]") for h, _ in cols], table


def print_table(header, table, file=None) -> None:
    """Aligned plain-text table (first column left-aligned, the others right-aligned)."""
    file = sys.stdout if file is None else file
    widths = [max(len(str(c)) for c in col) for col in zip(header, *table)]

    def line(cells):
        return "  ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w)
                         for i, (c, w) in enumerate(zip(cells, widths)))

    print(line(header), file=file)
    print("  ".join("-" * w for w in widths), file=file)
    for r in table:
        print(line(r), file=file)


def _md_cell(x) -> str:
    return str(x).replace("|", "\\|").replace("\n", " ")


def _numeric(cells) -> bool:
    """A column of numbers (or never / — / counts like 3/4): right-aligned."""
    def num(c):
        c = str(c)
        if c in ("never", "not within t_end", "FAILED", "—", "-inf", "nan"):
            return True
        if " ± " in c:
            c = c.split(" ± ")[0]
        try:
            for part in c.split("/"):
                if part != "—":
                    float(part)
            return True
        except ValueError:
            return False
    return all(num(c) for c in cells)


def md_table(header, table) -> list[str]:
    columns = list(zip(*table)) if table else [()] * len(header)
    out = ["| " + " | ".join(_md_cell(h) for h in header) + " |",
           "|" + "|".join("---:" if col and _numeric(col) else "---" for col in columns) + "|"]
    out += ["| " + " | ".join(_md_cell(c) for c in r) + " |" for r in table]
    return out


def write_summary(path, title: str, description: str, rows, settings=(), files=(), base=None,
                  notes=(), sections=()) -> Path:
    """Write ``summary.md``: results table, notes, further ``sections`` (markdown lines; the
    ensemble rate), settings and the list of files written."""
    path = Path(path)
    header, table = rows
    lines = [f"# {title}", ""]
    if description:
        lines += [description.strip(), ""]
    lines += ["## Results", ""] + md_table(header, table) + [""]
    lines += ["- decay rate: decay rate of the envelope of d (of max d for a network): the median of its "
              "per-decade rates over the decades d falls through, from a tenth of its maximum down to a decade "
              "above where it stops falling (round-off or the ultimate bound), ± their spread (compare runs with "
              "this, not with t_sync differences; — where it means nothing: fewer than 2 decades, or a spread "
              "above 50 % of the rate; the window and the reason are in the notes; docs/design.md §2.7). "
              "For a forced impacting pair one start state's rate is a sample: compare laws by the ensemble "
              "rate over start states (fmu-sync run SCENE --starts N). "
              "ultimate bound: max d over the last 20 % of the run "
              "(practical synchronization of non-identical systems)."]
    lines += [f"- t_sync: first time after which the quotient distance d stays below {SYNC_THRESHOLD:g} "
              "(not within t_end: d was still at or above it at the end of the run; a longer run may get there).",
              "- max(|x1-x2|-d): the Euclidean error's peaking above d (largest at impact mismatches).",
              "- impact steps: steps (dt in the core, H in co-simulation) with a positive percussion; "
              "a plastic impact or persistent contact gives many per contact.",
              "- contact episodes: arrivals at the wall seen in the record (each begins one episode of "
              "contact; the markers of the position plots).",
              "- max dV over an episode start: largest change of V = d^2/2 over a record in which a contact "
              "episode begins (O(dt) for the quotient distance, while the Euclidean error jumps by about "
              "(1+e)|w.u-|); — when the record shows no contact episode (a contact episodes cell — : the "
              "solver counted impact steps but the record does not resolve the arrivals, e.g. unresolved "
              "stiff chatter or a coarse record_every)."]
    lines += [f"- {n}" for n in notes] + [""]
    lines += list(sections)
    if settings:
        lines += ["## Settings", ""] + md_table(["key", "value"], [[k, f"`{v}`"] for k, v in settings]) + [""]
    if files:
        lines += ["## Files", ""]
        for f in files:
            f = Path(f)
            shown = os.path.relpath(f, base) if base is not None else str(f)
            lines.append(f"- [`{shown}`]({shown})")
        lines.append("")
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
