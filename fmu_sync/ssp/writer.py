"""Writing a coupled scene as an SSP 1.0 package (:func:`write_ssp`, docs/ssp.md)."""
from __future__ import annotations

import io
import tempfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from ..fmus import contract
from .common import (COUPLING_FMU, CONNECTION_ENDS, COUPLING_COMPONENT, OMS, OMS_SOLVER, OSP, SSD, fmt_real, qname,
                     coupling_connections, system_component)
from .settings import write_run


def _ssv(name: str, values: dict) -> bytes:
    root = ET.Element(qname("ssv", "ParameterSet"), {"version": "1.0", "name": name})
    params = ET.SubElement(root, qname("ssv", "Parameters"))
    for key, value in values.items():
        p = ET.SubElement(params, qname("ssv", "Parameter"), {"name": key})
        ET.SubElement(p, qname("ssv", "Real"), {"value": fmt_real(value)})
    return _xml_bytes(root)


def _xml_bytes(root) -> bytes:
    ET.indent(root, space="  ")
    buf = io.BytesIO()
    ET.ElementTree(root).write(buf, encoding="UTF-8", xml_declaration=True)
    return buf.getvalue() + b"\n"


def _connector(parent, name: str, kind: str, typ: str = "Real", unit: str | None = None) -> None:
    c = ET.SubElement(parent, qname("ssd", "Connector"), {"name": name, "kind": kind})
    ET.SubElement(c, qname("ssc", typ), {"unit": unit} if unit else {})


def _ssm(mapping: dict) -> bytes:
    """An SSP parameter mapping (source name -> target name)."""
    root = ET.Element(qname("ssm", "ParameterMapping"), {"version": "1.0"})
    for a, b in mapping.items():
        ET.SubElement(root, qname("ssm", "MappingEntry"), {"source": a, "target": b})
    return _xml_bytes(root)


def _component(elements, name: str, source: str, connectors, ssv: str, mapped=()):
    """A component bound to its own ``ssv`` after the ``mapped`` (ssv, ssm) bindings (the later
    binding takes priority, SSP 1.0)."""
    comp = ET.SubElement(elements, qname("ssd", "Component"),
                         {"name": name, "type": "application/x-fmu-sharedlibrary", "source": source})
    cons = ET.SubElement(comp, qname("ssd", "Connectors"))
    for args in connectors:
        _connector(cons, *args)
    binds = ET.SubElement(comp, qname("ssd", "ParameterBindings"))
    for src, ssm in mapped:
        b = ET.SubElement(binds, qname("ssd", "ParameterBinding"), {"source": src})
        ET.SubElement(b, qname("ssd", "ParameterMapping"), {"source": ssm})
    ET.SubElement(binds, qname("ssd", "ParameterBinding"), {"source": ssv})
    _oms_annotation(comp)
    return comp


def _oms_annotation(element, H: float | None = None) -> None:
    """OMSimulator's fixed-step solver as the last child of a ``ssd:System`` (with its step
    ``H``) or a ``ssd:Component`` (the solver's name only): without it OMSimulator steps at
    its default 1 ms whatever the package's experiment says."""
    ann = ET.SubElement(ET.SubElement(element, qname("ssd", "Annotations")), qname("ssc", "Annotation"), {"type": OMS})
    info = {"name": OMS_SOLVER["name"]} if H is None else {**OMS_SOLVER, "fixedStepSize": fmt_real(H)}
    ET.SubElement(ET.SubElement(ann, qname("oms", "Annotations")), qname("oms", "SimulationInformation"), info)


def _real_values(decl, values: dict) -> dict:
    """The Real parameters of ``values`` in declaration order."""
    real = [v.name for v in decl if v.causality == "parameter" and v.type == "Real"]
    return {k: float(values[k]) for k in real if k in values}


def _coupling_values(variant, systems, A, edges, laws, n: int) -> tuple[dict, dict]:
    """(Real parameter values, enumeration start values) of the variant's coupling FMU. Its Q
    is the one our master uses for the same run (the law's metric, core.coupling.law_metric)."""
    from ..core.coupling import gain_matrix, law_metric
    from ..core.distance import geometry
    from ..fmus.coupling import edge_names
    real = {}
    for i, j in edges:
        for a, b in ((i, j), (j, i)):
            real[f"a[{a + 1},{b + 1}]"] = float(A[a, b])
    coupled = any(law not in (None, "none") for law in laws)
    Ac = np.array(A, dtype=np.float64)
    for (i, j), law in zip(edges, laws):
        if law in (None, "none"):
            Ac[i, j] = Ac[j, i] = 0.0
    metric = law_metric(variant.Q, [s.K for s in systems], gain_matrix(variant.Kp, n, "Kp"),
                        Ac if coupled else None, coupled=coupled, stiffness=systems[0].metric_source)
    geo = geometry(systems[0], metric.Q)
    for sym, mat in (("Kp", gain_matrix(variant.Kp, n, "Kp")), ("Kd", gain_matrix(variant.Kd, n, "Kd")),
                     ("Q", geo.Q), ("M", geo.M)):
        names = [sym] if n == 1 else contract.matrix(sym, n)
        real.update(zip(names, (float(x) for x in np.asarray(mat).reshape(-1))))
    real.update(zip(["w"] if n == 1 else [f"w[{k + 1}]" for k in range(n)], (float(x) for x in geo.w)))
    real.update(g0=float(geo.g0), e=float(geo.e))
    enum = dict(zip(edge_names("law", len(edges)), laws))
    return real, enum


def write_ssp(scene, path, variant: str | None = None, overrides: dict | None = None) -> Path:
    """Write the scene's coupled variant as an SSP 1.0 archive at ``path`` (``.ssp``).

    ``scene``: a built-in scene name, a TOML path or a loaded Scene; ``variant``:
    its name (required when the scene has several). Raises ValueError
    (:class:`fmu_sync.scenes.SceneError`) for a single-system variant or an
    unknown variant, naming the choices."""
    from ..core.compensation import check_compensated
    from ..core.model import as_state
    from ..core.network import edges_of
    from ..export import export_coupling, export_fmu, write_archive
    from ..scenes.loading import as_scene
    from ..scenes.running import export_spec, scene_values
    from ..scenes.schema import SceneError

    # a package is a co-simulation: the master's keys (run.H, ...) are its settings whatever the scene's mode
    sc = as_scene(scene, {**(overrides or {}), "run.mode": "cosim"})
    if variant is None:
        if len(sc.variants) != 1:
            raise SceneError(f"scene {sc.name!r} has the variants {', '.join(v.name for v in sc.variants)}: "
                             f"choose one with --variant")
        v = sc.variants[0]
    else:
        v = sc.variant(variant)
    if not v.pair:
        raise SceneError(f"scene {sc.name!r}, variant {v.name!r} is a single system: an SSP package holds "
                         f"coupled systems (a pair or a network)")
    path = Path(path)
    if path.suffix != ".ssp":
        raise ValueError(f"the package file name must end in .ssp, got {str(path)!r}")
    cfg = v.cfg
    if v.is_network:
        spec = v.network
        A, systems, states = np.array(spec.A, dtype=np.float64), list(spec.systems), list(spec.states)
        names, nodes = spec.laws, list(spec.nodes)
    else:
        A, systems, states, names = np.array([[0.0, 1.0], [1.0, 0.0]]), [v.system] * 2, [v.x1, v.x2], None
        nodes = [None, None]
    edges = edges_of(A)
    laws = list(names) if names is not None else [v.law] * len(edges)
    system = systems[0]
    n = system.n
    model, export_key, _ = export_spec(v)   # a registered model, or a declaration with a force law
    if model is None:
        raise SceneError(f"no FMU model for system.model = {cfg['system.model']!r} with n = {n}")
    if "switching-compensated" in laws:     # the coupling FMU evaluates the built-in linear law's h only
        check_compensated(n, system.force)
    solver = model.solver_values(cfg["solver.dt"], cfg["solver.scheme"], cfg["solver.theta"])
    decl = model.declare()
    comp_values = []
    for s, x, node in zip(systems, states, nodes):
        q0, u0 = as_state(s, x, "x")
        try:
            values = scene_values(model, v, s, node)
        except contract.ContractError as exc:
            raise SceneError(f"scene {sc.name!r}, variant {v.name!r}: {exc}") from None
        comp_values.append(_real_values(decl, {**values, **model.state_values(q0, u0)}))
    coupling_real, coupling_enum = _coupling_values(v, systems, A, edges, laws, n)
    N = len(comp_values)
    maps = _force_maps(laws, N, n)   # the compensated law's h: bound from the systems' own values
    h_starts = {b: comp_values[i][a] for i, m in enumerate(maps) for a, b in m.items()}
    # one FMU file per system, whose start values are that system's bound values: a master that
    # ignores the bindings (fmpy's simulate_ssp without parameter_set) still runs the scene
    osc_names = [f"resources/{system_component(i, N)}.fmu" for i in range(N)]
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="fmu-sync-ssp-") as tmp:
        oscs = [export_fmu(export_key, Path(tmp) / f"osc{i}.fmu", {**vals, contract.SOLVER_SCHEME:
                                                                  solver[contract.SOLVER_SCHEME]})
                for i, vals in enumerate(comp_values)]
        cpl = export_coupling(Path(tmp) / "coupling.fmu", A, n, {**coupling_real, **coupling_enum, **h_starts},
                              units=model.declaration.units)
        files = [(SSD, _ssd(sc.name, v, model, edges, N, n, osc_names, cfg, bool(maps)))]
        files += [(name, osc.read_bytes()) for name, osc in zip(osc_names, oscs)]
        files.append((COUPLING_FMU, cpl.read_bytes()))
    files += [(f"resources/{system_component(i, N)}.ssv", _ssv(system_component(i, N), vals))
              for i, vals in enumerate(comp_values)]
    files += [(_ssm_name(i, N), _ssm(m)) for i, m in enumerate(maps)]
    files.append((f"resources/{COUPLING_COMPONENT}.ssv", _ssv(COUPLING_COMPONENT, coupling_real)))
    write_archive(path, files)
    return path


def _force_maps(laws, N: int, n: int) -> list[dict]:
    """Per system, the names of its force law h -> the coupling's copy (``k`` -> ``k[i]``, ..):
    what the law switching-compensated evaluates (none for the other laws, none for n > 1,
    where the coupling FMU refuses that law)."""
    from ..fmus.coupling import force_names
    if n > 1 or "switching-compensated" not in laws:
        return []
    return [{a: f"{a}[{i + 1}]" for a in force_names()} for i in range(N)]


def _ssm_name(i: int, N: int) -> str:
    return f"resources/{COUPLING_COMPONENT}-{system_component(i, N)}.ssm"


def _ssd(scene_name, v, model, edges, N, n, osc_names, cfg, mapped=False) -> bytes:
    from ..fmus.coupling import edge_names, node_names
    root = ET.Element(qname("ssd", "SystemStructureDescription"),
                      {"version": "1.0", "name": f"{scene_name}-{v.name}",
                       "generationTool": "fmu-sync", "description": v.description or scene_name})
    system = ET.SubElement(root, qname("ssd", "System"), {"name": scene_name, "description": v.description or ""})
    elements = ET.SubElement(system, qname("ssd", "Elements"))
    qn, un, tn = model.q, model.u, model.tau
    units = model.declaration.units          # the system FMU's own (rad, rad/s, N.m for the pendulum)
    for i in range(N):
        cons = [(a, "output", "Real", units["q"]) for a in qn] + [(a, "output", "Real", units["u"]) for a in un] + \
               [(a, "input", "Real", units["tau"]) for a in tn]
        _component(elements, system_component(i, N), osc_names[i], cons, f"resources/{system_component(i, N)}.ssv")
    E = len(edges)
    cons = []
    for base in ("q", "u"):
        cons += [(a, "input", "Real", units[base]) for i in range(N) for a in node_names(base, i, n)]
    cons += [(a, "output", "Real", units["tau"]) for i in range(N) for a in node_names("tau", i, n)]
    cons += [(a, "output", "Real", None) for base in ("d", "V", "euclidean") for a in edge_names(base, E)]
    cons += [(a, "output", "Integer", None) for a in edge_names("branch", E)]
    _component(elements, COUPLING_COMPONENT, COUPLING_FMU, cons, f"resources/{COUPLING_COMPONENT}.ssv",
               [(f"resources/{system_component(i, N)}.ssv", _ssm_name(i, N)) for i in range(N)] if mapped else ())
    conns = ET.SubElement(system, qname("ssd", "Connections"))
    for ends in coupling_connections([system_component(i, N) for i in range(N)], qn, un, tn):
        ET.SubElement(conns, qname("ssd", "Connection"), dict(zip(CONNECTION_ENDS, ends)))
    _oms_annotation(system, cfg["run.H"])
    exp = ET.SubElement(root, qname("ssd", "DefaultExperiment"),
                        {"startTime": "0.0", "stopTime": fmt_real(cfg["run.t_end"])})
    anns = ET.SubElement(exp, qname("ssd", "Annotations"))
    ann = ET.SubElement(anns, qname("ssc", "Annotation"), {"type": OSP})
    alg = ET.SubElement(ann, qname("osp", "Algorithm"))
    ET.SubElement(alg, qname("osp", "FixedStepAlgorithm"), {"baseStepSize": fmt_real(cfg["run.H"])})
    write_run(anns, cfg)   # the exchange, hold, tol, ... of the scene (fmu_sync.ssp.settings)
    return _xml_bytes(root)

