"""Convergence check of a scene's synchronization metrics (``fmu-sync run SCENE --convergence``).

Each variant is rerun at its step, /2 and /4 (core mode: ``solver.dt``; cosim
mode: ``run.H``, with ``solver.dt`` kept <= H and dividing it: halved alongside
when it equals H). ``run.record_every`` is scaled with the step, so every rerun
records the same times and holds a record of the same size. No record is
written: only the metrics (:mod:`fmu_sync.core.metrics`: fitted decay rate of
the envelope of d with its uncertainty, t_sync, ultimate bound) and the final d
go to ``convergence.md`` and ``convergence.csv``.

The verdict of a variant compares the rates of successive steps, only where both are
resolved (never two rates that mean nothing): converged when the intervals
``rate ± rate_err`` (median ± spread of the per-decade rates) of every two successive
steps overlap, ``|rate_k - rate_{k-1}| <= rate_err_k + rate_err_{k-1}``.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..progress import scaled
from .loading import Scene, as_scene, load_scene
from .schema import DEFAULT_OUT, SceneError, Variant

__all__ = ["ConvergenceRow", "VariantConvergence", "ConvergenceRun", "refined_overrides", "convergence", "compare_rows",
           "LEVELS", "TOL_FACTOR", "refined_what", "refined_key"]

#: the steps checked: the scene's step divided by 1, 2, 4 (a tolerance: by 1, 4, 16, the factor that
#: halves the step of a second-order exchange)
LEVELS = 3
TOL_FACTOR = 4


@dataclass
class ConvergenceRow:
    step: float            #: the step refined (solver.dt in core mode, run.H in cosim mode)
    dt: float              #: solver.dt of the rerun
    record_every: int
    rate: float
    rate_err: float
    t_sync: float
    t_fit: float
    bound: float
    final_d: float
    reason: str = ""              #: why the rate means nothing ('' when resolved)
    change: float = math.nan      #: relative change of the rate from the previous (coarser) step
    within: bool | None = None    #: the two rates' intervals overlap (None: either is unresolved)
    label: str = "step"           #: what ``step`` is: "step" or "tolerance"


@dataclass
class VariantConvergence:
    name: str
    step_name: str                #: "solver.dt" or "run.H"
    rows: list = field(default_factory=list)
    verdict: str = ""
    converged: bool = False


@dataclass
class ConvergenceRun:
    scene: Scene
    out_dir: Path
    variants: list
    files: list


def refined_overrides(variant: Variant, level: int) -> dict:
    """The keys of ``variant`` at its step divided by ``2**level`` (record_every scaled: the same
    record times)."""
    from ..output import record_steps
    cfg = variant.cfg
    f = 2 ** level
    if refined_key(variant) == "run.tol":   # the tolerance chooses the steps: refine it, not H
        return {"run.tol": cfg["run.tol"] / TOL_FACTOR ** level, "record.distance": True}
    out = {"run.record_every": int(cfg["run.record_every"]) * f, "record.distance": True}
    if variant.mode == "cosim" and variant.pair:
        H = cfg["run.H"] / f
        dt = cfg["solver.dt"]
        # the largest internal step <= the scene's dt that divides H (dt = H: halved alongside)
        m = max(1, math.ceil(H / dt * (1 - 1e-9)))
        # run.record_every counts solver.dt (fmu_sync.output.record_steps): the same record times,
        # every (its steps of the scene's H) x f steps of H / f, each m internal steps
        out.update({"run.H": H, "solver.dt": H / m, "run.record_every": record_steps(cfg) * f * m})
        if cfg.get("run.H_min") is not None:
            out["run.H_min"] = min(cfg["run.H_min"], H)
    else:
        out["solver.dt"] = cfg["solver.dt"] / f
    return out


def refined_key(v: Variant) -> str:
    """What the check refines: ``solver.dt`` (core), ``run.H`` (co-simulation), or ``run.tol`` when
    a tolerance chooses the co-simulation's steps (then H is only the first and largest step, and
    halving it changes nothing: 0.6.0 labelled such rows H, H/2, H/4 and they agreed to 0.001 %)."""
    if v.mode == "cosim" and v.pair:
        return "run.tol" if v.cfg.get("run.tol") is not None else "run.H"
    return "solver.dt"


def refined_what(step_name: str, levels: int = LEVELS) -> str:
    """The words for what the check varies: "its step, /2 and /4" or "its tolerance, /4 and /16"."""
    if step_name == "run.tol":
        return "its tolerance run.tol, " + " and ".join(f"/{TOL_FACTOR ** k}" for k in range(1, levels))
    return "its step, " + " and ".join(f"/{2 ** k}" for k in range(1, levels))


def compare_rows(rows) -> tuple[str, bool]:
    """Set each row's ``change`` and ``within`` against the previous (coarser) step, only where
    both rates are resolved (never two rates that mean nothing); return the verdict and whether
    the rate converged."""
    for prev, row in zip(rows, rows[1:]):
        if row.reason or prev.reason:
            continue
        row.change = (row.rate - prev.rate) / abs(prev.rate)
        row.within = bool(abs(row.rate - prev.rate) <= row.rate_err + prev.rate_err)
    return _verdict(rows)


def _verdict(rows) -> tuple[str, bool]:
    why = [r.reason for r in rows if r.reason]
    if why:
        return f"no verdict: the rate means nothing at some step ({why[0]})", False
    changes = [abs(r.change) for r in rows[1:]]
    worst = max(changes)
    if all(r.within for r in rows[1:]):
        how = " as the tolerance run.tol is refined" if rows[0].label == "tolerance" else ""
        return f"rate converged{how}: changes up to {100 * worst:.3g} %, within the rates' spreads", True
    bad = [r for r in rows[1:] if not r.within]
    return (f"not converged: rate changes {100 * abs(bad[0].change):.3g} % at {bad[0].label} {bad[0].step:g}, "
            f"beyond the spreads of the two rates (refine the {bad[0].label} further)"), False


def _metrics(result, threshold):
    """``result.sync(threshold)`` (fitted rate, t_sync, bound), None without a distance record."""
    if getattr(result, "d", None) is None:
        return None
    return result.sync(threshold)


def _final_d(result) -> float:
    d = getattr(result, "d_max", None) if hasattr(result, "edges") else result.d
    return float(d[-1]) if d is not None and len(d) else math.nan


def convergence(scene, out_dir=None, overrides: dict | None = None, variants=None, levels: int = LEVELS,
                progress: Callable | None = None, max_memory: float | None = None,
                max_disk: float | None = None) -> ConvergenceRun:
    """Rerun every (or the named) variant(s) of a coupled scene at its step, /2, /4 and write
    ``convergence.md`` and ``convergence.csv`` in ``out_dir`` (default
    ``./fmu-sync-out/<scene>``); returns a :class:`ConvergenceRun`.

    Everything is checked before anything runs: the stability of every rerun
    (:func:`~.running.preflight`) and the memory of its record
    (:func:`fmu_sync.output.check_budget`; the record size is the same at each
    step, the cost of the reruns is 1 + 2 + 4 = 7 times the steps of one run).
    Single systems (no distance d) are refused (:class:`SceneError`).
    """
    from ..core import RunFailed
    from ..output import DEFAULT_MAX_DISK, DEFAULT_MAX_MEMORY, check_out_dir
    from .running import check_export, export_for, run_variant

    scene = as_scene(scene, overrides, variants)
    check_export(scene.variants)
    levels = int(levels)
    if levels < 2:
        raise ValueError(f"a convergence check needs at least 2 steps, got levels = {levels}")
    out_dir = check_out_dir(Path(out_dir) if out_dir is not None else DEFAULT_OUT / scene.name)
    max_memory = DEFAULT_MAX_MEMORY if max_memory is None else float(max_memory)
    max_disk = DEFAULT_MAX_DISK if max_disk is None else float(max_disk)
    plan = _plan(scene, levels, max_memory, max_disk)
    total = sum(s for _, runs in plan for _, s in runs)

    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    fmus, results, done = {}, [], 0
    try:
        for v, runs in plan:
            vc = VariantConvergence(v.name, refined_key(v))
            for vk, steps in runs:
                fmu_path = None
                if vk.mode == "cosim":
                    model = (vk.cfg["system.model"], vk.system.n)
                    if model not in fmus:
                        fmus[model] = export_for(vk, out_dir)
                    fmu_path = fmus[model]
                a, b = done / total, (done + steps) / total
                try:
                    result = run_variant(vk, fmu_path, scaled(progress, a, b), scene.name)
                except RunFailed as exc:
                    raise RunFailed(f"{exc} (convergence check at {vc.step_name} = "
                                    f"{vk.cfg[vc.step_name]:g})", partial=None) from None
                done += steps
                vc.rows.append(_row(vc.step_name, vk, result))
            vc.verdict, vc.converged = compare_rows(vc.rows)
            results.append(vc)
    except BaseException:
        for f in fmus.values():
            Path(f).unlink(missing_ok=True)
        if created:
            try:
                out_dir.rmdir()
            except OSError:
                pass
        raise
    files = list(fmus.values()) + _write(scene, results, out_dir)
    if progress is not None:
        progress(1.0)
    return ConvergenceRun(scene, out_dir, results, files)


def _plan(scene, levels, max_memory, max_disk) -> list:
    """[(variant, [(rerun variant, steps), ...]), ...]: every rerun loaded, its stability and its
    record's memory checked (before anything runs); a single system is refused."""
    from ..output import check_budget
    from .running import preflight
    plan = []
    for v in scene.variants:
        if not v.pair:
            raise SceneError(f"scene {scene.name!r}, variant {v.name!r}: the convergence check compares the "
                             "decay of the distance d of coupled systems; this variant is a single system "
                             "(give [initial] x2 or a [network])")
        runs = []
        for k in range(levels):
            vk = load_scene(scene.path, {**scene.overrides, **refined_overrides(v, k)}, [v.name]).variants[0]
            preflight(vk, scene.name)
            est, _ = check_budget(vk, (), max_memory, max_disk, can_stream=False,
                                  label=f"scene {scene.name!r}, variant {v.name!r} at {refined_key(v)}/"
                                        f"{(TOL_FACTOR if refined_key(v) == 'run.tol' else 2) ** k}")
            runs.append((vk, est.steps))
        plan.append((v, runs))
    return plan


def _row(step_name, vk, result) -> ConvergenceRow:
    """The metrics of one rerun ``vk`` (NaN where it has no distance record)."""
    from .. import report
    m = _metrics(result, report.SYNC_THRESHOLD)
    nan = math.nan
    return ConvergenceRow(
        label="tolerance" if step_name == "run.tol" else "step",
        step=float(vk.cfg[step_name]), dt=float(vk.cfg["solver.dt"]),
        record_every=int(vk.cfg["run.record_every"]),
        rate=m.rate if m else nan, rate_err=m.rate_err if m else nan,
        t_sync=m.t_sync if m else nan, t_fit=m.t_fit if m else nan,
        bound=m.bound if m else nan, final_d=_final_d(result),
        reason=(m.reason if m else "no distance recorded"))


# ---------------------------------------------------------------- tables
HEADER = ("variant", "step", "solver.dt", "record_every", "rate (1/s)", "rate_err (1/s)", "t_sync (s)",
          "t_fit (s)", "ultimate bound", "final d", "rate change", "within uncertainty")


def _g(x, fmt=".4g") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    if isinstance(x, float) and math.isinf(x):
        return "never"
    return format(x, fmt)


def table_rows(results) -> list[list[str]]:
    """The table's rows (strings), one per variant and step."""
    out = []
    for vc in results:
        for r in vc.rows:
            out.append([vc.name, f"{vc.step_name} = {r.step:g}", f"{r.dt:g}", str(r.record_every),
                        _g(r.rate) if not r.reason else "—", _g(r.rate_err, ".2g"), _g(r.t_sync, ".4g"), _g(r.t_fit, ".4g"),
                        _g(r.bound, ".3g"), _g(r.final_d, ".3g"),
                        "-" if math.isnan(r.change) else f"{100 * r.change:+.3g} %",
                        "-" if r.within is None else ("yes" if r.within else "no")])
    return out


def format_table(results) -> str:
    rows = [list(HEADER)] + table_rows(results)
    lines = ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(r) + " |" for r in rows[1:]]
    return "\n".join(lines)


def verdicts(results) -> list[str]:
    return [f"{vc.name}: {vc.verdict}" for vc in results]


def _write(scene: Scene, results, out_dir: Path) -> list[Path]:
    md = out_dir / "convergence.md"
    text = [f"# Convergence check of scene `{scene.name}`", "",
            "Each variant rerun at its step, /2 and /4 (record_every scaled: the same record times; a variant "
            "co-simulated to a tolerance at run.tol, /4 and /16 instead, since its steps are chosen by the "
            "tolerance, not by run.H: the step column says which); "
            "rate: decay rate of the envelope of d (median of its per-decade rates) ± their spread, — where "
            "it means nothing; t_sync: time "
            "after which d stays below 1e-6; t_fit: where the fitted envelope crosses 1e-6; ultimate "
            "bound: max d over the last 20 % of the run. Rate change: relative to the previous (coarser) "
            "step; within uncertainty: the intervals rate ± rate_err overlap (|change| <= the sum of the two "
            "rate_err; only where both rates are resolved).", "",
            format_table(results), "", "## Verdicts", ""]
    text += [f"- {line}" for line in verdicts(results)]
    md.write_text("\n".join(text) + "\n")
    path = out_dir / "convergence.csv"
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["variant", "step_name", "step", "solver_dt", "record_every", "rate", "rate_err", "t_sync",
                    "t_fit", "bound", "final_d", "rate_change", "within_uncertainty", "converged"])
        for vc in results:
            for r in vc.rows:
                w.writerow([vc.name, vc.step_name, repr(r.step), repr(r.dt), r.record_every, repr(r.rate),
                            repr(r.rate_err), repr(r.t_sync), repr(r.t_fit), repr(r.bound), repr(r.final_d),
                            repr(r.change), "" if r.within is None else r.within, vc.converged])
    return [md, path]
