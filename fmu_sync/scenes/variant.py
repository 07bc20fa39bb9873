"""One variant of a scene (docs/design.md §4.5): its plan, its FMU and start values, and its run in
the core (:func:`~fmu_sync.core.simulate`, :func:`~fmu_sync.core.simulate_pair`) or the master
(:func:`~fmu_sync.master.cosimulate`, values named by the FMU contract). The scene's loop, its
files and ``summary.md`` are in :mod:`.running`; streamed runs in :mod:`.streamed`."""
from __future__ import annotations


from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..core import ForceLawFailed, RunFailed, RunRefused, SimulationDiverged, UnstableExchange, UnstableScheme, simulate
from ..fmus import contract
from ..user_export import built_key, fmu_model_of
from .loading import Scene
from .schema import SceneError, Variant


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
        model = contract.identify([v.name for v in md.modelVariables], md.modelName, built_key(fmu_path))
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


def variant_label(variant: Variant, scene_name: str = "") -> str:
    return f"scene {scene_name!r}, variant {variant.name!r}" if scene_name else f"variant {variant.name!r}"


def plan_variant(variant: Variant):
    """The run plan (:func:`fmu_sync.core.plan.plan_run`, docs/design.md §5.1.1) of the run the
    variant makes: its systems, start states, grid and scheme, and (coupled) its exchange: in
    co-simulation at ``run.H`` with ``run.hold`` (the slaves' internal step ``solver.dt``), in
    the core at ``solver.dt`` with the exchange of its loop for the scheme (the zero-order hold;
    the trapezoid's on 1-DOF systems: inside the step, :func:`fmu_sync.core.plan.coupling_exchange`,
    as simulate_pair and simulate_network plan it). ``run.allow_unstable`` skips the limits
    as the drivers do (a single system has no such switch). Raises the plan's typed refusals."""
    from ..core.network import edge_laws, edges_of
    from ..core.plan import coupling_exchange, plan_run
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
    exchange = coupling_exchange(cfg["solver.scheme"], spec.systems if variant.is_network else [systems])
    return plan_run(systems, states, cfg["run.t_end"], cfg["solver.dt"], A=A, laws=laws, Kp=variant.Kp, Kd=variant.Kd,
                    exchange=exchange, allow_unstable=bool(cfg["run.allow_unstable"]), distance=not variant.is_network,
                    system_names=[f"node {i + 1}" for i in range(len(states))] if variant.is_network else None,
                    **common)


def preflight(variant: Variant, scene_name: str = ""):
    """Refuse, before anything runs or is written, a variant that its driver would refuse: the
    run plan of :func:`plan_variant` (the core's and the master's one plan, so the two cannot
    disagree). A refusal keeps its type (:class:`~fmu_sync.core.errors.RunRefused`: ``UnstableScheme``,
    ``UnstableExchange``, ``InadmissibleState``, ...), its message prefixed with the scene and
    variant. Returns the plan."""
    label = variant_label(variant, scene_name)
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
        return with_units(_run_variant(variant, fmu_path, progress, scene_name, sink, chunk_rows, every), variant)
    except RunFailed as exc:
        with_units(exc.partial, variant)
        raise


def declared_units(variant: Variant) -> dict:
    """``{"units": ...}`` of the variant's model when it declares units other than m, m/s, N
    (:func:`fmu_sync.core.views.units_info`), else ``{}``."""
    from ..core.views import units_info
    from .loading import model_of
    return units_info(model_of(variant.cfg))


def with_units(result, variant: Variant):
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
    label = variant_label(variant, scene_name)
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
