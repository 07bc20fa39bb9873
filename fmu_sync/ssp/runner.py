"""Running an fmu-sync SSP package in our master (:func:`run_ssp`) and writing its result (:func:`save_result`)."""
from __future__ import annotations

import re
import tempfile
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .common import CONNECTION_ENDS, COUPLING_COMPONENT, SSD, coupling_connections
from .reader import SspPackage, Archive, read_ssp
from .settings import DEFAULTS


_START = "resources/fmu_sync_start.json"
_BUILD = "resources/fmu_sync_build.json"
#: a coupling input connector: q[i] (n = 1) or q[i,k]
_COUPLING_Q = re.compile(r"q\[(\d+)(?:,\d+)?\]")


def _checked_values(pkg: SspPackage, component: str, slave, start: dict):
    """(values, configuration) of a component: its FMU's ``start`` values under the package's
    bindings, each bound value checked as the FMU checks it (name, type, range) and the whole set
    configured as the FMU's exitInitializationMode configures it; SspError naming where a value was
    read (the .ssv and its element) or, for a set that is not valid as a whole, the bindings' files."""
    src = pkg.sources[component]
    try:
        own = slave.normalize_start_values(start)
    except ValueError as exc:
        raise pkg.fail(src, _START, f"component {component!r}: {exc}") from None
    bound = {}
    for k, v in pkg.parameters.get(component, {}).items():
        try:
            bound.update(slave.normalize_start_values({k: v}))
        except ValueError as exc:
            raise pkg.fail(*pkg.origin(component, k), f"component {component!r}: {exc}") from None
    values = slave.start_parameters({**own, **bound})
    try:
        return values, slave.configure(values)
    except ValueError as exc:
        raise pkg.fail(", ".join(pkg.bindings.get(component) or [src]), f'<ssd:Component name="{component}">',
                       f"its parameters are not a valid set: {exc}") from None


def _coupling_setup(pkg: SspPackage, arc: Archive):
    """(coupling slave, its parameter values, its configuration): the coupling FMU's start values
    under the bindings, checked as the FMU checks them."""
    from ..fmus.coupling import CouplingSlave, CouplingSpec
    src = pkg.sources.get(COUPLING_COMPONENT)
    if src is None:
        raise pkg.fail(SSD, "<ssd:System> <ssd:Elements>", f"no component {COUPLING_COMPONENT!r} (the coupling "
                       f"FMU); components: {', '.join(pkg.sources) or 'none'}")
    start = arc.fmu_json(src, _START, COUPLING_COMPONENT)
    if not isinstance(start, dict) or start.get("model") != "coupling":
        got = start.get("model") if isinstance(start, dict) else start
        raise pkg.fail(src, _START, f"the {got!r} model, not the coupling FMU")
    try:
        cls = CouplingSlave(CouplingSpec.from_dict(start["structure"]))
        own = dict(start["start"])
    except (KeyError, TypeError, ValueError) as exc:
        raise pkg.fail(src, _START, f"no valid coupling structure and start values ({exc!r})") from None
    values, cfg = _checked_values(pkg, COUPLING_COMPONENT, cls, own)
    return cls, values, cfg


def _system_components(pkg: SspPackage, N: int) -> list[str]:
    """The components connected to the coupling's inputs q[1] .. q[N], in that order."""
    nodes = {}
    for a, ac, b, bc in pkg.connections:
        if b != COUPLING_COMPONENT or not bc.startswith("q["):
            continue
        m = _COUPLING_Q.fullmatch(bc)
        here = f'<ssd:Connection endElement="{b}" endConnector="{bc}">'
        if m is None or not 1 <= int(m.group(1)) <= N:
            raise pkg.fail(SSD, here, f"the coupling has no input {bc!r} (q[1] .. q[{N}])")
        if not a or a == COUPLING_COMPONENT:
            raise pkg.fail(SSD, here, f"must start at a system component, starts at {a!r}")
        i = int(m.group(1)) - 1
        if nodes.setdefault(i, a) != a:
            raise pkg.fail(SSD, here, f"connects {a!r} to q[{i + 1}], which {nodes[i]!r} is connected to already")
    if sorted(nodes) != list(range(N)):
        raise pkg.fail(SSD, "<ssd:Connections>", f"the coupling's inputs q[1]..q[{N}] must each be connected to a "
                       f"system's q, found {', '.join(f'q[{i + 1}] <- {c}' for i, c in sorted(nodes.items())) or 'none'}")
    return [nodes[i] for i in range(N)]


def run_ssp(path, method: str = "jacobi", t_end: float | None = None, H: float | None = None,
            record_every: int = 1, progress=None, allow_unstable: bool = False, settings: dict | None = None):
    """Run an fmu-sync SSP package in our master (:class:`fmu_sync.master.NetworkMaster`).

    The systems are the package's oscillator components (one FMU file, each with its
    bound parameters and start state); the graph, the law per edge, Kp, Kd and Q are
    the coupling component's parameters; t_end and H the package's DefaultExperiment
    (overridable). ``method``: the master's exchange order, an order of the strategy registry
    (:data:`fmu_sync.strategies.FMI2_METHODS`: "jacobi", "gauss-seidel", or another master's:
    "delayed" = libcosim, "delayed-zero" = fmpy's SSP runner; docs/ssp.md). Returns a :class:`~fmu_sync.core.result.NetworkResult`.
    Every fault of the package is refused before the run with an :class:`SspError` naming the
    package, the file inside it, the element and what is wrong: the checks of :func:`read_ssp`, every
    component's values as its FMU checks them, a coupling geometry that differs from the systems', connections
    other than the ones our master runs. ``settings``: the package's run settings (``exchange``, ``hold``,
    ``tol``, ``event_aware``, ``H_min``; kept by :func:`write_ssp`, fmu_sync.ssp.settings) overridden for this run.
    """
    pkg = read_ssp(path)
    unknown = sorted(set(settings or {}) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"settings: unknown run setting {unknown[0]!r} (allowed: {', '.join(DEFAULTS)})")
    run = {**pkg.run, **(settings or {})}
    t_end = pkg.t_end if t_end is None else t_end
    H = pkg.H if H is None else H
    if t_end is None or H is None:
        raise pkg.fail(SSD, "<ssd:DefaultExperiment>", "no stopTime or no step size (osp:FixedStepAlgorithm "
                       "baseStepSize in its DefaultExperiment, or OMSimulator's fixedStepSize in its system): "
                       "give t_end and H")
    with zipfile.ZipFile(pkg.path) as zf, tempfile.TemporaryDirectory(prefix="fmu-sync-ssp-") as tmp:
        arc = Archive(pkg.path, zf)
        ccls, cvals, cfg = _coupling_setup(pkg, arc)
        names = _system_components(pkg, ccls.SPEC.N)
        fmu = Path(tmp) / "system.fmu"
        fmu.write_bytes(_one_model(pkg, arc, names))
        return _run_master(pkg, arc, fmu, names, ccls.SPEC, cfg, t_end, H, method, record_every, progress,
                           allow_unstable, cvals, run)


def _one_model(pkg: SspPackage, arc: Archive, names: list[str]) -> bytes:
    """The FMU our master instantiates N times: the systems' FMU files (one per system, as
    :func:`write_ssp` writes them, or one shared) must be one model whose start values differ
    only in what each component's bindings set (refused otherwise, naming the first difference)."""
    srcs = list(dict.fromkeys(pkg.sources[c] for c in names))
    first_of = {pkg.sources[c]: c for c in reversed(names)}

    def identity(src):
        build, start = (arc.fmu_json(src, entry, first_of[src]) for entry in (_BUILD, _START))
        if not (isinstance(build, dict) and isinstance(start, dict) and isinstance(start.get("start"), dict)):
            raise pkg.fail(src, f"{_BUILD}, {_START}", "not the build record and start values of an fmu-sync FMU")
        return (build.get("model"), build.get("code_hash")), start["start"]

    seen = {src: identity(src) for src in srcs}
    first, start0 = seen[srcs[0]]
    for c in names:              # each system runs srcs[0] under its own bindings: the rest must be equal
        src = pkg.sources[c]
        ident, start = seen[src]
        if ident != first:
            raise pkg.fail(src, f'<ssd:Component name="{c}">', f"our master runs N instances of one model; "
                           f"{srcs[0]} is {first[0]!r} (code {str(first[1])[:12]}) but {src} is {ident[0]!r} "
                           f"(code {str(ident[1])[:12]})")
        bound = pkg.parameters.get(c, {})
        diff = sorted(k for k in set(start) | set(start0) if k not in bound and start.get(k) != start0.get(k))
        if diff:
            k = diff[0]
            raise pkg.fail(src, f'<ssd:Component name="{c}">', f"the systems' FMUs differ in {k!r}, which the "
                           f"bindings of {c!r} do not set ({srcs[0]}: {start0.get(k)!r}, {src}: "
                           f"{start.get(k)!r}): our master runs N instances of one model")
    return arc.data(srcs[0], SSD, f'<ssd:Component name="{names[0]}">')


def _run_master(pkg, arc, fmu, names, spec, cfg, t_end, H, method, record_every, progress, allow_unstable, cvals,
                run):
    from ..core.coupling import LAW_NAMES, QUOTIENT_LAW_NAMES
    from ..core.errors import RunFailed
    from ..core.pair import check_common_geometry
    from ..fmus.slave import MechanicalSlave
    from ..master import fmu_model, model_description
    from ..strategies import master_of, select
    model = fmu_model(model_description(str(fmu)), str(fmu))   # a force-law model: registered from its FMU
    _check_connections(pkg, names, model)
    slave = MechanicalSlave(model)
    own = arc.fmu_json(pkg.sources[names[0]], _START, names[0])["start"]
    starts, states, values = [], [], []
    for c in names:
        full, _ = _checked_values(pkg, c, slave, own)
        values.append(full)
        p = {k: full[k] for k in pkg.parameters.get(c, {}) if k not in model.q_start + model.u_start}
        q0, u0 = [full[k] for k in model.q_start], [full[k] for k in model.u_start]
        starts.append(p)
        states.append((np.array(q0), np.array(u0)) if model.n > 1 else (q0[0], u0[0]))
    A = np.zeros((spec.N, spec.N))
    for (i, j), (aij, aji) in zip(spec.edges, cfg.W2):
        A[i, j], A[j, i] = aij, aji
    laws = [LAW_NAMES[int(c)] for c in cfg.laws]
    geo = cfg.geo
    # the coupling's geometry must be the systems' (the master itself reads theirs from the FMU)
    systems = [model.geometry_system(v) for v in values]
    # the coupling's geometry beside the systems' (their force law: only the geometry is compared)
    mine = SimpleNamespace(n=spec.n, force=systems[0].force, M=geo.M, w=geo.w, g0=geo.g0, e=geo.e)
    try:   # a quotient law needs one impact map; the Euclidean law and none run systems that differ
        if any(x in QUOTIENT_LAW_NAMES for x in laws):
            check_common_geometry(systems + [mine], names + ["the coupling component"])
    except ValueError as exc:
        raise pkg.fail(", ".join(pkg.bindings.get(COUPLING_COMPONENT) or [pkg.sources[COUPLING_COMPONENT]]),
                       "the geometry M, w, g0, e", str(exc)) from None
    if "switching-compensated" in laws:   # and the force law h it evaluates must be theirs
        _check_force_laws(pkg, names, cvals, values)
    tol = run["tol"]
    # the run's strategies from the registry (fmu_sync.strategies): its checks refuse what does not combine
    kind = master_of(select(method, run["exchange"], tol, run["event_aware"], run["hold"]))
    master = kind(fmu, states, A, t_end, H, [None if x == "none" else x for x in laws], cfg.Kp, cfg.Kd,
                  geo.Q, method=method, record_every=record_every, start_values=starts,
                  allow_unstable=allow_unstable, hold=run["hold"], exchange=run["exchange"],
                  event_aware=run["event_aware"], H_min=run["H_min"], **({} if tol is None else {"tol": tol}))
    about = dict(package=str(pkg.path), components=names, method=method, H_package=float(H),
                 wall={"w": [float(x) for x in np.ravel(geo.w)], "g0": float(geo.g0)}, **run)
    about["H"] = float(H)   # the nominal step in every mode (with tol: info["step_lengths"])
    try:
        res = master.run(progress)
    except RunFailed as exc:   # the record up to the failure says what it is too
        if exc.partial is not None:
            exc.partial.info.update(about)
        raise
    res.info.update(about)
    return res


def _check_connections(pkg, names, model) -> None:
    """The package's connections must be the ones our master runs (:func:`coupling_connections`), no
    more, no fewer: SspError naming the first connection that differs (a connector the FMUs do not
    have, a crossed, swapped, extra or missing connection): never another system than the package's."""
    want = coupling_connections(names, list(model.q), list(model.u), list(model.tau))
    have = list(pkg.connections)
    inputs = {(b, bc) for _, _, b, bc in want}
    outputs = {(a, ac) for a, ac, _, _ in want}
    for ends in have:
        if ends in want:
            continue
        a, ac, b, bc = ends
        if (b, bc) not in inputs and b != COUPLING_COMPONENT and (a, ac) not in outputs:
            why = f"neither {a}.{ac} nor {b}.{bc} is a connector of the coupled system our master runs"
        elif (a, ac) not in outputs:
            why = f"{a}.{ac} is not an output that our master connects"
        elif (b, bc) not in inputs:
            why = f"{b}.{bc} is not an input that our master connects"
        else:
            theirs = next(w for w in want if (w[0], w[1]) == (a, ac))
            why = f"our master connects {a}.{ac} to {theirs[2]}.{theirs[3]}, not to {b}.{bc}"
        raise pkg.fail(SSD, _connection(ends), f"the package's connections differ from the coupled system our master "
                       f"runs ({why}); it runs exactly each system's {', '.join([*model.q, *model.u])} to the "
                       f"coupling's q[i], u[i] and the coupling's tau[i] to the system's "
                       f"{', '.join(model.tau)}: refused rather than running another system")
    for ends in want:
        if ends not in have:
            raise pkg.fail(SSD, "<ssd:Connections>", f"the connection {_connection(ends)} is missing: the coupling our "
                           f"master runs has it all the same, which is another system than the package "
                           f"describes: refused")
    if len(have) != len(set(have)):
        dup = next(e for e in have if have.count(e) > 1)
        raise pkg.fail(SSD, _connection(dup), "this connection is given twice")


def _connection(ends) -> str:
    return "<ssd:Connection " + " ".join(f'{k}="{v}"' for k, v in zip(CONNECTION_ENDS, ends)) + ">"


def _check_force_laws(pkg, names, cvals, values) -> None:
    """The coupling's copy of each system's force law (``k[i]`` .. ``phi[i]``) must be that
    system's (SspError naming the first parameter that differs, where the coupling's was read)."""
    from ..fmus.coupling import force_names
    for i, (c, p) in enumerate(zip(names, values)):
        for a in force_names():
            mine, theirs = cvals.get(f"{a}[{i + 1}]"), p.get(a)
            if mine != theirs:
                raise pkg.fail(*pkg.origin(COUPLING_COMPONENT, f"{a}[{i + 1}]"),
                               f"the law switching-compensated evaluates each system's force law, but the "
                               f"coupling component's {a}[{i + 1}] = {mine!r} differs from {c}'s {a} = {theirs!r} "
                               f"(bind it from {c}'s parameters, as fmu-sync ssp writes it)")


def save_result(res, out, formats=("csv", "npz"), plots: bool = True, method: str | None = None) -> Path:
    """Write a package run as a scene run is written (docs/results.md): ``out/result.npz``
    (with its ``meta``: layout, counts, the package's settings, plots, title and wall) and/or
    ``result.csv``, the network plots and ``summary.md``; a failed run (``res.error``) keeps its
    record as ``result.partial.*``, no plots. ``fmu_sync.load`` and ``fmu-sync plot`` read the
    folder back. Returns the summary's path."""
    from .. import plots as P
    from .. import report
    from ..output import check_out_dir, make_out_dir, results_in
    from ..scenes.running import clean_written
    from ..scenes.schema import plots_for
    out = check_out_dir(out)
    name = Path(res.info.get("package", "package")).name
    head = f"Package `{name}`"
    results_in(out, head)                             # another run's results there: refused
    created = make_out_dir(out)
    failed = bool(res.error)
    info = res.info
    wall = info.get("wall")
    kinds = plots_for(True, res.d is not None, True)
    settings = {"package": info.get("package"), "method": method or info.get("method"),
                "H": info.get("H_package", info.get("H")), **{k: info.get(k) for k in DEFAULTS if k in info},
                "t_end": float(res.t[-1]) if len(res.t) else None, "components": info.get("components")}
    extra = {"settings": settings, "plots": kinds, "title": name, "wall": wall}
    files = []
    try:
        files += report.write_data(res, out / "result", formats, partial=failed, extra=extra)
        skipped = []
        if plots and not failed:
            system = None if wall is None else _wall_system(wall)
            for k in kinds:
                why = P.skip_reason(k, res)
                if why is None:
                    files.append(P.PLOTTERS[k](res, out / f"result-{k}.png", system=system, title=name))
                else:
                    skipped.append(f"no {k} plot: {why}")
        run = SimpleNamespace(name=name, metrics={**report.metrics(res), "error": res.error})
        notes = ([f"**the run failed**: {res.error} Its record up to the failure is marked partial (no plots)."]
                 if failed else []) + skipped + report.run_notes([run])
        summary = report.write_summary(
            out / "summary.md", title=head, description=f"The SSP package `{info.get('package')}` run in "
            f"fmu-sync's master (`fmu-sync run {name}`).", rows=report.rows([run]),
            settings=[(k, repr(v)) for k, v in settings.items() if v is not None], files=files, base=out,
            notes=notes)
    except BaseException:
        clean_written(out, created, files)
        raise
    return summary


def _wall_system(wall: dict):
    return SimpleNamespace(w=np.asarray(wall["w"], dtype=float), g0=float(wall["g0"]))
