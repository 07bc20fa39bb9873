"""Running a scene (docs/design.md §4.5): each variant goes to the core
(:func:`~fmu_sync.core.simulate`, :func:`~fmu_sync.core.simulate_pair`) or to the
master (:func:`~fmu_sync.master.cosimulate`, values named by the FMU contract), then
its data, plots and ``summary.md`` are written."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..core import RunFailed, SimulationDiverged, simulate
from ..fmus import contract
from ..progress import scaled
from .loading import Scene, load_scene
from .schema import DEFAULT_OUT, TABLES, SceneError, Variant

__all__ = ["RunRecord", "SceneRun", "run_scene", "run_variant", "fmu_start_values", "export_for",
           "write_run", "error_notes", "settings_table"]


@dataclass
class RunRecord:
    name: str
    variant: Variant
    result: Any                 # PairResult or SimulationResult
    metrics: dict
    files: list = field(default_factory=list)


@dataclass
class SceneRun:
    scene: Scene
    out_dir: Path
    runs: list
    files: list
    summary: Path | None = None


# ---------------------------------------------------------------- running
def _coupling_arg(law: str):
    return None if law == "none" else law


def fmu_start_values(fmu_path, variant: Variant) -> dict:
    """Start values for the FMU's parameters from the scene, as the FMU contract names them.

    The FMU must be the contract's model of the variant's system family
    (:func:`fmu_sync.fmus.contract.identify`); anything else raises :class:`SceneError`.
    """
    from fmpy import read_model_description  # cosim branch only

    cfg = variant.cfg
    name = Path(fmu_path).name
    try:
        md = read_model_description(str(fmu_path))
        model = contract.identify([v.name for v in md.modelVariables], md.modelName)
        want = contract.model_for(cfg["system.model"], variant.system.n)
        if model is not want:
            raise contract.ContractError(f"it is the {model.key} model, the scene needs "
                                         f"{want.key if want else 'a model the registry does not have'}")
        return {**model.values(variant.system),
                **model.solver_values(cfg["solver.dt"], cfg["solver.scheme"], cfg["solver.theta"])}
    except contract.ContractError as exc:
        raise SceneError(f"{name}: cannot take the scene's values: {exc}") from None
    except ValueError as exc:  # an unknown scheme
        raise SceneError(f"{name}: {exc}") from None


def export_for(variant: Variant, out_dir) -> Path:
    """Export the FMU of the variant's model family into ``out_dir`` (cosim only)."""
    from ..export import export_fmu  # cosim branch only

    model = contract.model_for(variant.cfg["system.model"], variant.system.n).key
    return Path(export_fmu(model, Path(out_dir) / f"{model.replace('-', '_')}.fmu", None))


def run_variant(variant: Variant, fmu_path=None, progress: Callable | None = None, scene_name: str = ""):
    """Run one variant: ``simulate`` (single system), ``simulate_pair`` (core) or ``cosimulate``."""
    cfg = variant.cfg
    label = f"scene {scene_name!r}, variant {variant.name!r}" if scene_name else f"variant {variant.name!r}"
    try:
        if not variant.pair:
            result = simulate(variant.system, variant.x1, cfg["run.t_end"], cfg["solver.dt"],
                              scheme=cfg["solver.scheme"], theta=cfg["solver.theta"],
                              record_every=cfg["run.record_every"])
            if progress is not None:
                progress(1.0)
            return result
        if variant.mode == "core":
            from ..core.pair import simulate_pair
            return simulate_pair(variant.system, variant.x1, variant.x2, cfg["run.t_end"], cfg["solver.dt"],
                                 coupling=_coupling_arg(variant.law), Kp=variant.Kp, Kd=variant.Kd, Q=variant.Q,
                                 scheme=cfg["solver.scheme"], theta=cfg["solver.theta"],
                                 record_every=cfg["run.record_every"],
                                 record_distance=bool(cfg["record.distance"]), progress=progress)
        from ..master import cosimulate  # imports fmpy: cosim branch only
        if fmu_path is None:
            raise ValueError(f"{label}: mode = cosim needs an exported FMU (fmu_path)")
        try:
            return cosimulate(fmu_path, variant.x1, variant.x2, cfg["run.t_end"], cfg["run.H"],
                              coupling=_coupling_arg(variant.law), Kp=variant.Kp, Kd=variant.Kd, Q=variant.Q,
                              method=cfg["run.method"], record_every=cfg["run.record_every"],
                              event_aware=cfg["run.event_aware"], H_min=cfg["run.H_min"],
                              hold=cfg["run.hold"], start_values=fmu_start_values(fmu_path, variant),
                              record_distance=bool(cfg["record.distance"]), progress=progress)
        except RunFailed as exc:  # a failed slave: the scene reports it and keeps the record
            if exc.partial is None:
                raise
            return exc.partial
    except SimulationDiverged as exc:
        raise SimulationDiverged(f"{label}: {exc}") from None


def write_run(run: RunRecord, out_dir: Path, plots, title: str) -> None:
    from .. import report
    run.files += report.write_data(run.result, out_dir / run.name)
    if plots:
        from .. import plots as P
        if run.name != title:
            title = f"{title}: {run.name}"
        for p in plots:
            run.files.append(P.PLOTTERS[p](run.result, out_dir / f"{run.name}-{p}.png",
                                           system=run.variant.system, title=title))


def run_scene(scene, out_dir=None, overrides: dict | None = None, progress: Callable | None = None,
              variants=None, plots: bool = True) -> SceneRun:
    """Run every (or the named) variant(s) of a scene and write data, plots and ``summary.md``.

    ``scene`` is a :class:`Scene` or a name/path for :func:`load_scene`. ``out_dir``
    defaults to ``./fmu-sync-out/<scene>``. ``progress(fraction)`` gets the overall
    fraction done. Returns a :class:`SceneRun`.
    """
    from .. import report

    if not isinstance(scene, Scene):
        scene = load_scene(scene, overrides, variants)
    else:
        if overrides:
            scene = scene.with_overrides(overrides)
        if variants:
            scene = scene.select(variants)
    chosen = list(scene.variants)
    out_dir = Path(out_dir) if out_dir is not None else DEFAULT_OUT / scene.name
    out_dir.mkdir(parents=True, exist_ok=True)

    fmus = {}
    runs = []
    for i, v in enumerate(chosen):
        fmu_path = None
        if v.pair and v.mode == "cosim":
            model = (v.cfg["system.model"], v.system.n)
            if model not in fmus:
                fmus[model] = export_for(v, out_dir)
            fmu_path = fmus[model]
        result = run_variant(v, fmu_path, scaled(progress, i / len(chosen), (i + 1) / len(chosen)), scene.name)
        run = RunRecord(v.name, v, result, report.metrics(result, v.system))
        write_run(run, out_dir, scene.plots if plots else (), scene.name)
        runs.append(run)

    files = list(fmus.values()) + [f for r in runs for f in r.files]
    if plots and scene.compare and len(runs) > 1 and all(r.variant.has_distance for r in runs):
        from .. import plots as P
        files.append(P.compare_plot({r.name: r.result for r in runs}, out_dir / "compare-distance.png",
                                    title=scene.name))
    sr = SceneRun(scene, out_dir, runs, files)
    sr.summary = report.write_summary(out_dir / "summary.md", title=f"Scene `{scene.name}`",
                                      description=scene.description, rows=report.rows(runs),
                                      settings=settings_table(scene, chosen), files=files, base=out_dir,
                                      notes=error_notes(runs))
    return sr


_COSIM_KEYS = ("run.H", "run.H_min", "run.method", "run.event_aware", "run.hold")


def _relevant(key: str, variants) -> bool:
    """Settings worth listing: set (not None) and used by at least one variant."""
    for v in variants:
        if v.cfg.get(key) is None or key.startswith("plot."):
            continue
        if key.startswith("coupling.") and not v.pair:
            continue
        if key in _COSIM_KEYS and v.mode != "cosim":
            continue
        if key == "solver.theta" and v.cfg["solver.scheme"] != "theta":
            continue
        return True
    return False


def error_notes(runs) -> list[str]:
    return [f"**{r.name} stopped early**: {r.metrics['error']}" for r in runs if r.metrics.get("error")]


def settings_table(scene: Scene, variants) -> list[tuple[str, str]]:
    rows = [("scene file", str(scene.path))]
    if scene.overrides:
        rows.append(("overrides", ", ".join(f"{k}={v!r}" for k, v in scene.overrides.items())))
    keys = [k for k in variants[0].cfg if _relevant(k, variants)]
    for k in sorted(keys, key=lambda k: TABLES.index(k.split(".")[0])):
        values = {repr(v.cfg[k]) for v in variants}
        if len(values) == 1:
            rows.append((k, values.pop()))
        else:
            rows.append((k, "; ".join(f"{v.name}: {v.cfg[k]!r}" for v in variants)))
    return rows


