"""Running a scene (docs/design.md §4.5): each variant goes to the core
(:func:`~fmu_sync.core.simulate`, :func:`~fmu_sync.core.simulate_pair`) or to the
master (:func:`~fmu_sync.master.cosimulate`, values named by the FMU contract), then
its data, plots and ``summary.md`` are written."""
from __future__ import annotations


from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..core import ForceLawFailed, RunFailed, RunRefused, SimulationDiverged, UnstableExchange, UnstableScheme, simulate
from ..fmus import contract
from ..progress import scaled
from ..user_export import fmu_model_of
from .loading import Scene, as_scene
from .record import record_interval
from .schema import COSIM_KEYS, DEFAULT_OUT, TABLES, SceneError, Variant

__all__ = ["RunRecord", "SceneRun", "RunRefused", "RunInterrupted", "preflight", "plan_variant", "run_scene", "run_variant",
           "fmu_start_values", "scene_values", "check_export", "export_for", "export_spec", "write_run", "run_extra", "record_interval", "clean_written", "error_notes", "skipped_notes", "settings_table"]


@dataclass
class RunRecord:
    name: str
    variant: Variant
    result: Any                 # PairResult or SimulationResult
    metrics: dict
    files: list = field(default_factory=list)
    streamed: bool = False
    skipped: list = field(default_factory=list)   #: (plot, why it was not drawn)


@dataclass
class SceneRun:
    scene: Scene
    out_dir: Path
    runs: list
    files: list
    summary: Path | None = None
    ensembles: list = field(default_factory=list)   #: (name, mode, law, EnsembleRate) (fmu_sync.ensemble)

    @property
    def failed(self) -> list:
        """The runs that stopped before their end."""
        return [r for r in self.runs if r.metrics.get("error")]


# ---------------------------------------------------------------- running
def _coupling_arg(law: str):
    return None if law == "none" else law


def _net_distance(cfg):
    """A network's ``record_distance``: ``record.distance = true`` records d where the nodes share one
    impact map and the Euclidean error where they do not (None, docs/design.md §2.5.3)."""
    return None if cfg["record.distance"] else False


def fmu_start_values(fmu_path, variant: Variant, system=None, node: dict | None = None) -> dict:
    """Start values for the FMU's parameters from the scene, as the FMU contract names them.

    The FMU must be the contract's model of the variant's system family
    (:func:`fmu_model_of`); anything else raises :class:`SceneError`. A declaration without
    an inverse (a force law's: the pendulum, a user's file) takes the scene's ``[system]`` values
    themselves, with a network node's table ``node`` laid over them.
    """
    from fmpy import read_model_description  # cosim branch only

    cfg = variant.cfg
    name = Path(fmu_path).name
    try:
        md = read_model_description(str(fmu_path))
        model = contract.identify([v.name for v in md.modelVariables], md.modelName)
        want = fmu_model_of(cfg["system.model"], variant.system.n)
        if want is None or not (model is want or (model.key == want.key and model.declaration is want.declaration)):
            raise contract.ContractError(f"it is the {model.key} model, the scene needs "
                                         f"{want.key if want else 'a model the registry does not have'}")
        return scene_values(model, variant, system, node)
    except contract.ContractError as exc:
        raise SceneError(f"{name}: cannot take the scene's values: {exc}") from None
    except ValueError as exc:  # an unknown scheme
        raise SceneError(f"{name}: {exc}") from None


def scene_values(model, variant: Variant, system=None, node: dict | None = None) -> dict:
    """The FMU parameter values (as the contract's ``model`` names them) of the variant's system, or
    of a network node's (``system``, its table ``node``), and the solver's: a declaration without
    an inverse (a force law's) takes the scene's ``[system]`` values themselves, with ``node`` laid
    over them. Raises :class:`~fmu_sync.fmus.contract.ContractError` for a system the model cannot hold."""
    cfg = variant.cfg
    if model.declaration.values is None:
        values = model.flat(_declared_values(variant, node))
    else:
        values = model.values(variant.system if system is None else system)
    return {**values, **model.solver_values(cfg["solver.dt"], cfg["solver.scheme"], cfg["solver.theta"])}


def _declared_values(variant: Variant, node: dict | None = None) -> dict:
    """The declared parameter values of the variant's ``[system]`` (a network node's table over them)."""
    from .loading import model_of
    from .schema import system_keys
    decl = model_of(variant.cfg)
    values = {k: variant.cfg[f"system.{k}"] for k in decl.names}
    keys = system_keys(decl)
    values.update({k: keys[k][0](v) for k, v in (node or {}).items()})
    return decl.check(values)


def check_export(variants) -> None:
    """Before anything is written: a co-simulated variant needs an FMU, and exporting one needs the
    numba the export is tested with (:func:`fmu_sync.native.require_export_versions`, one line)."""
    if any(v.pair and v.mode == "cosim" for v in variants):
        from ..native import require_export_versions
        require_export_versions()


def export_for(variant: Variant, out_dir) -> Path:
    """Export the FMU of the variant's model into ``out_dir`` (cosim only): a registered model by
    its key, a declaration with a force law by the scene's ``system.model`` (its file, for a user's)."""
    from ..export import export_fmu  # cosim branch only

    model, spec, name = export_spec(variant)
    return Path(export_fmu(spec, Path(out_dir) / f"{name}.fmu", None))


def export_spec(variant: Variant):
    """(the contract's model, what :func:`fmu_sync.export.export_fmu` exports it by, a file stem) of
    the variant's system: a registered model by its key, a declaration with a force law by the
    scene's ``system.model`` (its file, for a user's); the model is None if it has no FMU."""
    family = variant.cfg["system.model"]
    model = fmu_model_of(family, variant.system.n)
    if model is None:
        return None, None, None
    spec = model.key if model.key in contract.MODELS else family
    return model, spec, (model.identifier if spec == family else model.key.replace("-", "_"))


def _label(variant: Variant, scene_name: str = "") -> str:
    return f"scene {scene_name!r}, variant {variant.name!r}" if scene_name else f"variant {variant.name!r}"


def plan_variant(variant: Variant):
    """The run plan (:func:`fmu_sync.core.plan.plan_run`, docs/design.md §5.1.1) of the run the
    variant makes: its systems, start states, grid and scheme, and (coupled) its exchange: in
    co-simulation at ``run.H`` with ``run.hold`` (the slaves' internal step ``solver.dt``), in
    the core at ``solver.dt`` with the zero-order hold. ``run.allow_unstable`` skips the limits
    as the drivers do (a single system has no such switch). Raises the plan's typed refusals."""
    from ..core.network import edge_laws, edges_of
    from ..core.plan import plan_run
    cfg = variant.cfg
    cosim = variant.pair and variant.mode == "cosim"
    common = dict(scheme=cfg["solver.scheme"], theta=cfg["solver.theta"], record_every=cfg["run.record_every"])
    if not variant.pair:
        return plan_run(variant.system, [variant.x1], cfg["run.t_end"], cfg["solver.dt"], exact=True, **common)
    if variant.is_network:
        spec = variant.network
        systems, states, A = list(spec.systems), list(spec.states), spec.A
        laws = edge_laws(_laws_arg(variant), edges_of(A))
    else:
        systems, states, A = variant.system, [variant.x1, variant.x2], None
        laws = edge_laws(_coupling_arg(variant.law), [(0, 1)])
    if cosim:   # the master's plan: the exchange at H, each instance's scheme at its internal step
        return plan_run(systems, states, cfg["run.t_end"], cfg["run.H"], dt=cfg["solver.dt"], hold=cfg["run.hold"],
                        exchange=cfg["run.exchange"], A=A, laws=laws, Kp=variant.Kp, Kd=variant.Kd, step_name="H", exact=True,
                        allow_unstable=bool(cfg["run.allow_unstable"]), distance=not variant.is_network, **common)
    return plan_run(systems, states, cfg["run.t_end"], cfg["solver.dt"], A=A, laws=laws, Kp=variant.Kp, Kd=variant.Kd,
                    allow_unstable=bool(cfg["run.allow_unstable"]), distance=not variant.is_network,
                    system_names=[f"node {i + 1}" for i in range(len(states))] if variant.is_network else None,
                    **common)


def preflight(variant: Variant, scene_name: str = ""):
    """Refuse, before anything runs or is written, a variant that its driver would refuse: the
    run plan of :func:`plan_variant` (the core's and the master's one plan, so the two cannot
    disagree). A refusal keeps its type (:class:`~fmu_sync.core.errors.RunRefused`: ``UnstableScheme``,
    ``UnstableExchange``, ``InadmissibleState``, ...), its message prefixed with the scene and
    variant. Returns the plan."""
    label = _label(variant, scene_name)
    try:
        return plan_variant(variant)
    except RunRefused as exc:
        hint = (" From the command line: --allow-unstable (or --set run.allow_unstable=true)."
                if isinstance(exc, (UnstableExchange, UnstableScheme)) and variant.pair else "")
        said = isinstance(exc, UnstableExchange)   # its message says "refused before the first step"
        raise type(exc)(f"{label}: {'' if said else 'refused before the first step: '}{exc}{hint}") from None


def run_variant(variant: Variant, fmu_path=None, progress: Callable | None = None, scene_name: str = "",
                sink: Callable | None = None, chunk_rows: int = 65536, every: int | None = None):
    """Run one variant: ``simulate`` (single system), ``simulate_pair`` (core) or ``cosimulate``.

    ``sink``/``chunk_rows`` (core pairs only): stream the record in chunks
    (:func:`fmu_sync.core.simulate_pair`). A run that fails mid-way raises
    :class:`~fmu_sync.core.RunFailed` naming the scene and variant, with the
    record up to the failure in ``.partial`` (None where there is none). ``every``: the record's
    interval in steps of the run (default ``run.record_every`` in them,
    :func:`fmu_sync.output.record_steps`; pairs: 1 for the full resolution).
    """
    try:
        return _with_units(_run_variant(variant, fmu_path, progress, scene_name, sink, chunk_rows, every), variant)
    except RunFailed as exc:
        _with_units(exc.partial, variant)
        raise


def declared_units(variant: Variant) -> dict:
    """``{"units": ...}`` of the variant's model when it declares units other than m, m/s, N
    (:func:`fmu_sync.core.views.units_info`), else ``{}``."""
    from ..core.views import units_info
    from .loading import model_of
    return units_info(model_of(variant.cfg))


def _with_units(result, variant: Variant):
    """The result with its model's declared units in ``info`` (its files' headers, meta and plots say them)."""
    own = declared_units(variant)
    if result is not None and own:
        if getattr(result, "info", None) is None:
            result.info = {}
        result.info.update(own)
    return result


def _run_variant(variant: Variant, fmu_path, progress, scene_name, sink, chunk_rows, every=None):
    from ..output import record_steps
    cfg = variant.cfg
    label = _label(variant, scene_name)
    every = record_steps(cfg) if every is None else every   # run.record_every in the run's steps
    extra = {"allow_unstable": True} if cfg["run.allow_unstable"] else {}
    try:
        if variant.is_network:
            return _run_network(variant, fmu_path, progress, label, extra)
        if not variant.pair:
            result = simulate(variant.system, variant.x1, cfg["run.t_end"], cfg["solver.dt"],
                              scheme=cfg["solver.scheme"], theta=cfg["solver.theta"],
                              record_every=cfg["run.record_every"])
            if progress is not None:
                progress(1.0)
            return result
        if variant.mode == "core":
            from ..core.pair import simulate_pair
            if sink is not None:
                extra.update(sink=sink, chunk_rows=chunk_rows)
            return simulate_pair(variant.system, variant.x1, variant.x2, cfg["run.t_end"], cfg["solver.dt"],
                                 coupling=_coupling_arg(variant.law), Kp=variant.Kp, Kd=variant.Kd, Q=variant.Q,
                                 scheme=cfg["solver.scheme"], theta=cfg["solver.theta"],
                                 record_every=every,
                                 record_distance=bool(cfg["record.distance"]), progress=progress, **extra)
        from ..master import cosimulate  # imports fmpy: cosim branch only
        if fmu_path is None:
            raise ValueError(f"{label}: mode = cosim needs an exported FMU (fmu_path)")
        result = cosimulate(fmu_path, variant.x1, variant.x2, cfg["run.t_end"], cfg["run.H"],
                            coupling=_coupling_arg(variant.law), Kp=variant.Kp, Kd=variant.Kd, Q=variant.Q,
                            method=cfg["run.method"], record_every=every,
                            event_aware=cfg["run.event_aware"], H_min=cfg["run.H_min"], hold=cfg["run.hold"],
                            exchange=cfg["run.exchange"], tol=cfg["run.tol"],
                            start_values=fmu_start_values(fmu_path, variant),
                            record_distance=bool(cfg["record.distance"]), progress=progress, **extra)
        if getattr(result, "error", None):   # a record that stopped early (older masters return it)
            raise RunFailed(result.error, partial=result)
        return result
    except RunFailed as exc:
        if getattr(exc, "variant_label", None) == label:   # named already (by attribute, not by its text)
            raise
        cls = next(c for c in (ForceLawFailed, SimulationDiverged, RunFailed) if isinstance(exc, c))
        err = cls(f"{label}: {exc}")
        err.partial, err.variant_label = exc.partial, label
        raise err from None


def _laws_arg(variant: Variant):
    """The coupling of a network variant: one law name (None: uncoupled) or one per edge."""
    spec = variant.network
    if spec is not None and spec.laws is not None:
        return [None if x == "none" else x for x in spec.laws]
    return _coupling_arg(variant.law)


def _run_network(variant: Variant, fmu_path, progress, label, extra):
    """A network variant: ``simulate_network`` (core) or ``cosimulate_network`` (master)."""
    from ..output import record_steps
    cfg = variant.cfg
    spec = variant.network
    if variant.mode == "core":
        from ..core.network import simulate_network
        return simulate_network(list(spec.systems), list(spec.states), spec.A, cfg["run.t_end"], cfg["solver.dt"],
                                coupling=_laws_arg(variant), Kp=variant.Kp, Kd=variant.Kd, Q=variant.Q,
                                scheme=cfg["solver.scheme"], theta=cfg["solver.theta"],
                                record_every=cfg["run.record_every"],
                                record_distance=_net_distance(cfg), progress=progress, **extra)
    from ..master import cosimulate_network
    if fmu_path is None:
        raise ValueError(f"{label}: mode = cosim needs an exported FMU (fmu_path)")
    starts = [fmu_start_values(fmu_path, variant, s, t) for s, t in zip(spec.systems, spec.nodes)]
    result = cosimulate_network(fmu_path, list(spec.states), spec.A, cfg["run.t_end"], cfg["run.H"],
                                coupling=_laws_arg(variant), Kp=variant.Kp, Kd=variant.Kd, Q=variant.Q,
                                method=cfg["run.method"], record_every=record_steps(cfg),
                                event_aware=cfg["run.event_aware"], H_min=cfg["run.H_min"], hold=cfg["run.hold"],
                                exchange=cfg["run.exchange"], tol=cfg["run.tol"],
                                start_values=starts, record_distance=_net_distance(cfg),
                                progress=progress, **extra)
    if getattr(result, "error", None):
        raise RunFailed(result.error, partial=result)
    return result


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
                                   label=_label(v, scene.name))
        if stream and "nc" in fmts:
            from ..output import OutputTooLarge
            raise OutputTooLarge(f"{_label(v, scene.name)}: refused before running: the record exceeds the memory "
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


