"""A coupled scene as an SSP 1.0 package, and our master running one (docs/ssp.md).

    write_ssp("forced-pair", "pair.ssp", variant="switching")
    fmu-sync ssp forced-pair --variant switching -o pair.ssp
    run_ssp("pair.ssp")            # fmu-sync run pair.ssp

The package (a zip archive) holds:

* ``SystemStructure.ssd``: one component per system (``system1`` .. ``systemN``,
  all instances of one oscillator FMU file), the coupling component
  (``coupling``, the coupling FMU of :mod:`fmu_sync.fmus.coupling`), the
  connections (each system's q, u to the coupling's ``q[i]``, ``u[i]``; the
  coupling's ``tau[i]`` to the system's ``tau``) and a DefaultExperiment with
  the scene's ``t_end`` and, as the Open Simulation Platform annotation that
  libcosim reads, its communication step H;
* ``resources/<model>.fmu`` and ``resources/coupling.fmu``;
* ``resources/<component>.ssv``: each component's parameter values (a system's
  parameters and start state, the coupling's weights, gains, metric Q and the
  impact geometry). With the law ``switching-compensated`` the coupling's copy of each
  system's force law (``k[i]`` .. ``phi[i]``) is bound from that system's own ``.ssv``
  through a parameter mapping ``resources/coupling-<system>.ssm`` (``k`` -> ``k[i]``, ..):
  one set of numbers for both, and :func:`run_ssp` refuses a package whose coupling
  holds another. Only Real values are bound: the enumerations (the solver
  scheme, the law of each edge) are the FMUs' start values, since libcosim
  cannot set FMI enumerations and fmpy's runner cannot read SSV enumeration names.

:func:`run_ssp` reads a package back (ours, or one edited by another tool that
keeps this structure) and runs it in :class:`fmu_sync.master.NetworkMaster`: the
coupling component's parameters become the master's graph, laws and gains
(:class:`fmu_sync.ssp_master.SspMaster`, which also runs libcosim's and fmpy's orders).
"""
from __future__ import annotations

import io
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from xml.etree import ElementTree as ET

import numpy as np

from .fmus import contract

__all__ = ["write_ssp", "read_ssp", "run_ssp", "save_result", "SspPackage", "fmpy_parameter_set", "SSD", "SsdError",
           "COUPLING_COMPONENT", "system_component"]

SSD = "SystemStructure.ssd"
NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
      "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
      "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
      "ssm": "http://ssp-standard.org/SSP1/SystemStructureParameterMapping",
      "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
      "oms": "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd"}
#: the annotation types of the two masters that read a step from a package (SSP 1.0 has none):
#: libcosim reads the Open Simulation Platform's, OMSimulator its own (docs/ssp.md)
OSP = "com.opensimulationplatform"
OMS = "org.openmodelica"
#: OMSimulator's solver of a fixed-step co-simulation: ``oms_ma``, an undelayed Jacobi exchange
OMS_SOLVER = {"name": "fixedstep", "method": "oms_ma"}
COUPLING_COMPONENT = "coupling"
_COUPLING_FMU = "resources/coupling.fmu"
for _p, _u in NS.items():
    ET.register_namespace(_p, _u)


class SsdError(ValueError):
    """A package that is not an fmu-sync coupled system (names what is missing)."""


def system_component(i: int, N: int = 9) -> str:
    """The component name of system i (0-based) of N: ``system1`` .. (zero-padded for N >= 10,
    ``system01``: fmpy's runner matches parameters by the prefix of the component name, so no
    name may be the prefix of another)."""
    return f"system{i + 1:0{len(str(N))}d}"


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _fmt(x: float) -> str:
    return repr(float(x))


# ------------------------------------------------------------------ writing
def _ssv(name: str, values: dict) -> bytes:
    root = ET.Element(_q("ssv", "ParameterSet"), {"version": "1.0", "name": name})
    params = ET.SubElement(root, _q("ssv", "Parameters"))
    for key, value in values.items():
        p = ET.SubElement(params, _q("ssv", "Parameter"), {"name": key})
        ET.SubElement(p, _q("ssv", "Real"), {"value": _fmt(value)})
    return _xml_bytes(root)


def _xml_bytes(root) -> bytes:
    ET.indent(root, space="  ")
    buf = io.BytesIO()
    ET.ElementTree(root).write(buf, encoding="UTF-8", xml_declaration=True)
    return buf.getvalue() + b"\n"


def _connector(parent, name: str, kind: str, typ: str = "Real", unit: str | None = None) -> None:
    c = ET.SubElement(parent, _q("ssd", "Connector"), {"name": name, "kind": kind})
    ET.SubElement(c, _q("ssc", typ), {"unit": unit} if unit else {})


def _ssm(mapping: dict) -> bytes:
    """An SSP parameter mapping (source name -> target name)."""
    root = ET.Element(_q("ssm", "ParameterMapping"), {"version": "1.0"})
    for a, b in mapping.items():
        ET.SubElement(root, _q("ssm", "MappingEntry"), {"source": a, "target": b})
    return _xml_bytes(root)


def _component(elements, name: str, source: str, connectors, ssv: str, mapped=()):
    """A component bound to its own ``ssv`` after the ``mapped`` (ssv, ssm) bindings (the later
    binding takes priority, SSP 1.0)."""
    comp = ET.SubElement(elements, _q("ssd", "Component"),
                         {"name": name, "type": "application/x-fmu-sharedlibrary", "source": source})
    cons = ET.SubElement(comp, _q("ssd", "Connectors"))
    for args in connectors:
        _connector(cons, *args)
    binds = ET.SubElement(comp, _q("ssd", "ParameterBindings"))
    for src, ssm in mapped:
        b = ET.SubElement(binds, _q("ssd", "ParameterBinding"), {"source": src})
        ET.SubElement(b, _q("ssd", "ParameterMapping"), {"source": ssm})
    ET.SubElement(binds, _q("ssd", "ParameterBinding"), {"source": ssv})
    _oms_annotation(comp)
    return comp


def _oms_annotation(element, H: float | None = None) -> None:
    """OMSimulator's fixed-step solver as the last child of a ``ssd:System`` (with its step
    ``H``) or a ``ssd:Component`` (the solver's name only): without it OMSimulator steps at
    its default 1 ms whatever the package's experiment says."""
    ann = ET.SubElement(ET.SubElement(element, _q("ssd", "Annotations")), _q("ssc", "Annotation"), {"type": OMS})
    info = {"name": OMS_SOLVER["name"]} if H is None else {**OMS_SOLVER, "fixedStepSize": _fmt(H)}
    ET.SubElement(ET.SubElement(ann, _q("oms", "Annotations")), _q("oms", "SimulationInformation"), info)


def _real_values(decl, values: dict) -> dict:
    """The Real parameters of ``values`` in declaration order."""
    real = [v.name for v in decl if v.causality == "parameter" and v.type == "Real"]
    return {k: float(values[k]) for k in real if k in values}


def _coupling_values(variant, systems, A, edges, laws, n: int) -> tuple[dict, dict]:
    """(Real parameter values, enumeration start values) of the variant's coupling FMU. Its Q
    is the one our master uses for the same run (the law's metric, core.coupling.law_metric)."""
    from .core.coupling import gain_matrix, law_metric
    from .core.distance import geometry
    from .fmus.coupling import edge_names
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
    from .core.network import edges_of
    from .export import export_coupling, export_fmu, write_archive
    from .scenes.loading import as_scene
    from .scenes.schema import SceneError

    sc = as_scene(scene, overrides)
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
        names = spec.laws
    else:
        A, systems, states, names = np.array([[0.0, 1.0], [1.0, 0.0]]), [v.system] * 2, [v.x1, v.x2], None
    edges = edges_of(A)
    laws = list(names) if names is not None else [v.law] * len(edges)
    system = systems[0]
    n = system.n
    model = contract.model_for(cfg["system.model"], n)
    if model is None:
        raise SceneError(f"no FMU model for system.model = {cfg['system.model']!r} with n = {n}")
    solver = model.solver_values(cfg["solver.dt"], cfg["solver.scheme"], cfg["solver.theta"])
    decl = model.declare()
    comp_values = []
    for s, x in zip(systems, states):
        from .core.model import as_state
        q0, u0 = as_state(s, x, "x")
        comp_values.append(_real_values(decl, {**model.values(s), **model.state_values(q0, u0), **solver}))
    coupling_real, coupling_enum = _coupling_values(v, systems, A, edges, laws, n)
    N = len(comp_values)
    maps = _force_maps(laws, N, n)   # the compensated law's h: bound from the systems' own values
    h_starts = {b: comp_values[i][a] for i, m in enumerate(maps) for a, b in m.items()}
    # one FMU file per system, whose start values are that system's bound values: a master that
    # ignores the bindings (fmpy's simulate_ssp without parameter_set) still runs the scene
    osc_names = [f"resources/{system_component(i, N)}.fmu" for i in range(N)]
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="fmu-sync-ssp-") as tmp:
        oscs = [export_fmu(model.key, Path(tmp) / f"osc{i}.fmu", {**vals, contract.SOLVER_SCHEME:
                                                                  solver[contract.SOLVER_SCHEME]})
                for i, vals in enumerate(comp_values)]
        cpl = export_coupling(Path(tmp) / "coupling.fmu", A, n, {**coupling_real, **coupling_enum, **h_starts})
        files = [(SSD, _ssd(sc.name, v, model, edges, N, n, osc_names, cfg, bool(maps)))]
        files += [(name, osc.read_bytes()) for name, osc in zip(osc_names, oscs)]
        files.append((_COUPLING_FMU, cpl.read_bytes()))
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
    from .fmus.coupling import force_names
    if n > 1 or "switching-compensated" not in laws:
        return []
    return [{a: f"{a}[{i + 1}]" for a in force_names()} for i in range(N)]


def _ssm_name(i: int, N: int) -> str:
    return f"resources/{COUPLING_COMPONENT}-{system_component(i, N)}.ssm"


def _ssd(scene_name, v, model, edges, N, n, osc_names, cfg, mapped=False) -> bytes:
    from .fmus.coupling import edge_names, node_names
    root = ET.Element(_q("ssd", "SystemStructureDescription"),
                      {"version": "1.0", "name": f"{scene_name}-{v.name}",
                       "generationTool": "fmu-sync", "description": v.description or scene_name})
    system = ET.SubElement(root, _q("ssd", "System"), {"name": scene_name, "description": v.description or ""})
    elements = ET.SubElement(system, _q("ssd", "Elements"))
    qn, un, tn = model.q, model.u, model.tau
    for i in range(N):
        cons = [(a, "output", "Real", "m") for a in qn] + [(a, "output", "Real", "m/s") for a in un] + \
               [(a, "input", "Real", "N") for a in tn]
        _component(elements, system_component(i, N), osc_names[i], cons, f"resources/{system_component(i, N)}.ssv")
    E = len(edges)
    cons = []
    for base, unit in (("q", "m"), ("u", "m/s")):
        cons += [(a, "input", "Real", unit) for i in range(N) for a in node_names(base, i, n)]
    cons += [(a, "output", "Real", "N") for i in range(N) for a in node_names("tau", i, n)]
    cons += [(a, "output", "Real", None) for base in ("d", "V", "euclidean") for a in edge_names(base, E)]
    cons += [(a, "output", "Integer", None) for a in edge_names("branch", E)]
    _component(elements, COUPLING_COMPONENT, _COUPLING_FMU, cons, f"resources/{COUPLING_COMPONENT}.ssv",
               [(f"resources/{system_component(i, N)}.ssv", _ssm_name(i, N)) for i in range(N)] if mapped else ())
    conns = ET.SubElement(system, _q("ssd", "Connections"))
    for i in range(N):
        for mine, theirs in list(zip(qn, node_names("q", i, n))) + list(zip(un, node_names("u", i, n))):
            ET.SubElement(conns, _q("ssd", "Connection"), {
                "startElement": system_component(i, N), "startConnector": mine,
                "endElement": COUPLING_COMPONENT, "endConnector": theirs})
        for mine, theirs in zip(tn, node_names("tau", i, n)):
            ET.SubElement(conns, _q("ssd", "Connection"), {
                "startElement": COUPLING_COMPONENT, "startConnector": theirs,
                "endElement": system_component(i, N), "endConnector": mine})
    _oms_annotation(system, cfg["run.H"])
    exp = ET.SubElement(root, _q("ssd", "DefaultExperiment"),
                        {"startTime": "0.0", "stopTime": _fmt(cfg["run.t_end"])})
    ann = ET.SubElement(ET.SubElement(exp, _q("ssd", "Annotations")), _q("ssc", "Annotation"), {"type": OSP})
    alg = ET.SubElement(ann, _q("osp", "Algorithm"))
    ET.SubElement(alg, _q("osp", "FixedStepAlgorithm"), {"baseStepSize": _fmt(cfg["run.H"])})
    return _xml_bytes(root)


# ------------------------------------------------------------------ reading
@dataclass
class SspPackage:
    """What :func:`read_ssp` finds in a package: components (name -> FMU source inside
    the archive), their bound Real parameter values, the connections
    ((start element, start connector, end element, end connector)), t_end and H."""

    path: Path
    name: str
    sources: dict
    parameters: dict
    connections: list
    t_end: float | None
    H: float | None
    extra: dict = field(default_factory=dict)


def _read_ssv(zf: zipfile.ZipFile, name: str) -> dict:
    try:
        root = ET.fromstring(zf.read(name))
    except KeyError:
        raise SsdError(f"the package binds {name}, which it does not hold") from None
    out = {}
    for p in root.iter(_q("ssv", "Parameter")):
        real = p.find(_q("ssv", "Real"))
        if real is not None:
            out[p.get("name")] = float(real.get("value"))
    return out


def _mapped(zf: zipfile.ZipFile, values: dict, mapping) -> dict:
    """A binding's values under its parameter mapping (an ``.ssm`` source or inline entries):
    the mapped names renamed, the others dropped (the binding is meant for those it maps)."""
    if mapping is None:
        return values
    root = mapping
    if mapping.get("source"):
        try:
            root = ET.fromstring(zf.read(mapping.get("source")))
        except KeyError:
            raise SsdError(f"the package maps parameters by {mapping.get('source')}, which it does not hold") from None
    entries = {e.get("source"): e.get("target") for e in root.iter(_q("ssm", "MappingEntry"))}
    return {entries[k]: v for k, v in values.items() if k in entries}


def read_ssp(path) -> SspPackage:
    """Read a package's structure, bindings and experiment (ValueError naming what is wrong)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"SSP package not found: {path}")
    try:
        zf = zipfile.ZipFile(path)
    except zipfile.BadZipFile:
        raise SsdError(f"{path} is not an SSP package (not a zip archive)") from None
    with zf:
        try:
            root = ET.fromstring(zf.read(SSD))
        except KeyError:
            raise SsdError(f"{path} has no {SSD} at its root (entries: {', '.join(zf.namelist()[:8])})") from None
        system = root.find(_q("ssd", "System"))
        if system is None:
            raise SsdError(f"{path}: {SSD} has no ssd:System")
        sources, params = {}, {}
        for comp in system.iter(_q("ssd", "Component")):
            name = comp.get("name")
            sources[name] = comp.get("source")
            params[name] = {}
            for b in comp.iter(_q("ssd", "ParameterBinding")):
                if b.get("source"):
                    params[name].update(_mapped(zf, _read_ssv(zf, b.get("source")), b.find(_q("ssd", "ParameterMapping"))))
                for ps in b.iter(_q("ssv", "ParameterSet")):
                    for p in ps.iter(_q("ssv", "Parameter")):
                        real = p.find(_q("ssv", "Real"))
                        if real is not None:
                            params[name][p.get("name")] = float(real.get("value"))
        conns = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
                 for c in system.iter(_q("ssd", "Connection"))]
        exp = root.find(_q("ssd", "DefaultExperiment"))
        t_end = float(exp.get("stopTime")) if exp is not None and exp.get("stopTime") else None
        H = _package_step(path, root, system)
    return SspPackage(path, root.get("name"), sources, params, conns, t_end, H)


def _package_step(path, root, system) -> float | None:
    """The communication step the package gives: libcosim's (``osp:FixedStepAlgorithm``) and
    OMSimulator's (the system's ``oms:SimulationInformation fixedStepSize``), which must agree
    when both are there (a package edited in one tool only is refused, naming both)."""
    fs = root.find(f".//{_q('osp', 'FixedStepAlgorithm')}")
    steps = {"osp:FixedStepAlgorithm baseStepSize": fs.get("baseStepSize") if fs is not None else None}
    for ann in system.findall(f"{_q('ssd', 'Annotations')}/{_q('ssc', 'Annotation')}"):
        info = ann.find(f".//{_q('oms', 'SimulationInformation')}") if ann.get("type") == OMS else None
        if info is not None and info.get("fixedStepSize"):
            steps["oms:SimulationInformation fixedStepSize"] = info.get("fixedStepSize")
    try:
        given = {k: float(v) for k, v in steps.items() if v is not None}
    except ValueError:
        raise SsdError(f"{path}: a step size is not a number: {steps}") from None
    if len(set(given.values())) > 1:
        raise SsdError(f"{path}: the package gives two different communication steps: "
                       + ", ".join(f"{k} = {v!r}" for k, v in given.items()) + " (edit both, or give H)")
    return next(iter(given.values()), None)


def fmpy_parameter_set(path):
    """The package's bindings as one fmpy ``ParameterSet`` (names ``component.variable``):
    fmpy's ``simulate_ssp`` applies only the ``parameter_set`` it is given, not the
    bindings of the SystemStructure.ssd (docs/ssp.md)."""
    from fmpy.ssp.ssd import Parameter, ParameterSet
    pkg = read_ssp(path)
    ps = ParameterSet(name=pkg.name)
    for comp, values in pkg.parameters.items():
        for k, v in values.items():
            p = Parameter(name=f"{comp}.{k}")
            p.type, p.value, p.unit = "Real", repr(v), None
            ps.parameters.append(p)
    return ps


# ------------------------------------------------------------------ running in our master
def _coupling_setup(pkg: SspPackage, zf: zipfile.ZipFile, tmp: Path):
    """(coupling slave class, its parameter values): the FMU's start values under the bindings."""
    import json

    from .fmus.coupling import CouplingSlave, CouplingSpec
    src = pkg.sources.get(COUPLING_COMPONENT)
    if src is None:
        raise SsdError(f"{pkg.path}: no component {COUPLING_COMPONENT!r} (the coupling FMU); components: "
                       f"{', '.join(pkg.sources)}")
    with zipfile.ZipFile(io.BytesIO(zf.read(src))) as fz:
        try:
            start = json.loads(fz.read("resources/fmu_sync_start.json"))
        except KeyError:
            raise SsdError(f"{pkg.path}: {src} is not an fmu-sync coupling FMU (no resources/"
                           f"fmu_sync_start.json)") from None
    if start.get("model") != "coupling":
        raise SsdError(f"{pkg.path}: {src} is the {start.get('model')!r} model, not the coupling FMU")
    cls = CouplingSlave(CouplingSpec.from_dict(start["structure"]))
    values = cls.start_parameters(cls.normalize_start_values(start["start"]))
    values.update(cls.normalize_start_values(pkg.parameters.get(COUPLING_COMPONENT, {})))
    return cls, values


def run_ssp(path, method: str = "jacobi", t_end: float | None = None, H: float | None = None,
            record_every: int = 1, progress=None, allow_unstable: bool = False):
    """Run an fmu-sync SSP package in our master (:class:`fmu_sync.master.NetworkMaster`).

    The systems are the package's oscillator components (one FMU file, each with its
    bound parameters and start state); the graph, the law per edge, Kp, Kd and Q are
    the coupling component's parameters; t_end and H the package's DefaultExperiment
    (overridable). ``method``: the master's exchange order ("jacobi", "gauss-seidel",
    or another master's (:class:`fmu_sync.ssp_master.SspMaster`): "delayed" = libcosim,
    "delayed-zero" = fmpy's SSP runner; docs/ssp.md). Returns a :class:`~fmu_sync.core.result.NetworkResult`; a package
    whose coupling geometry differs from the systems' is refused (ValueError).
    """
    pkg = read_ssp(path)
    t_end = pkg.t_end if t_end is None else t_end
    H = pkg.H if H is None else H
    if t_end is None or H is None:
        raise SsdError(f"{pkg.path}: no stopTime or no step size (osp:FixedStepAlgorithm baseStepSize in "
                       f"its DefaultExperiment, or OMSimulator's fixedStepSize in its system): give t_end and H")
    with zipfile.ZipFile(pkg.path) as zf, tempfile.TemporaryDirectory(prefix="fmu-sync-ssp-") as tmp:
        ccls, cvals = _coupling_setup(pkg, zf, Path(tmp))
        spec = ccls.SPEC
        cfg = ccls.configure(cvals)
        nodes = {}
        for a, ac, b, bc in pkg.connections:
            if b == COUPLING_COMPONENT and bc.startswith("q["):
                nodes[int(bc[2:].split(",")[0].rstrip("]")) - 1] = a
        if sorted(nodes) != list(range(spec.N)):
            raise SsdError(f"{pkg.path}: the coupling's inputs q[1]..q[{spec.N}] must each be connected to a "
                           f"system's q, found {', '.join(f'q[{i + 1}] <- {c}' for i, c in sorted(nodes.items()))}")
        names = [nodes[i] for i in range(spec.N)]
        fmu = Path(tmp) / "system.fmu"
        fmu.write_bytes(_one_model(pkg, zf, names))
        return _run_master(pkg, fmu, names, spec, cfg, t_end, H, method, record_every, progress, allow_unstable,
                           cvals)


def _one_model(pkg: SspPackage, zf: zipfile.ZipFile, names: list[str]) -> bytes:
    """The FMU our master instantiates N times: the systems' FMU files (one per system, as
    :func:`write_ssp` writes them, or one shared) must be one model whose start values differ
    only in what each component's bindings set (refused otherwise, naming the first difference)."""
    import json
    srcs = list(dict.fromkeys(pkg.sources[c] for c in names))
    blobs = {s: zf.read(s) for s in srcs}

    def identity(src):
        with zipfile.ZipFile(io.BytesIO(blobs[src])) as fz:
            try:
                build = json.loads(fz.read("resources/fmu_sync_build.json"))
                start = json.loads(fz.read("resources/fmu_sync_start.json"))["start"]
            except KeyError:
                raise SsdError(f"{pkg.path}: {src} is not an fmu-sync FMU (no resources/fmu_sync_build.json "
                               f"or fmu_sync_start.json)") from None
        return (build.get("model"), build.get("code_hash")), start

    seen = {src: identity(src) for src in srcs}
    first, start0 = seen[srcs[0]]
    for c in names:              # each system runs srcs[0] under its own bindings: the rest must be equal
        src = pkg.sources[c]
        ident, start = seen[src]
        if ident != first:
            raise SsdError(f"{pkg.path}: our master runs N instances of one model; {srcs[0]} is {first[0]!r} "
                           f"(code {first[1][:12]}) but {src} is {ident[0]!r} (code {str(ident[1])[:12]})")
        bound = pkg.parameters.get(c, {})
        diff = sorted(k for k in set(start) | set(start0) if k not in bound and start.get(k) != start0.get(k))
        if diff:
            k = diff[0]
            raise SsdError(f"{pkg.path}: the systems' FMUs differ in {k!r}, which the bindings of {c!r} do not "
                           f"set ({srcs[0]}: {start0.get(k)!r}, {src}: {start.get(k)!r}): our master runs N "
                           f"instances of one model")
    return blobs[srcs[0]]


def _run_master(pkg, fmu, names, spec, cfg, t_end, H, method, record_every, progress, allow_unstable, cvals):
    from fmpy import read_model_description

    from .core.coupling import LAWS
    from .core.errors import RunFailed
    from .core.model import MechanicalSystem
    from .core.pair import check_common_geometry
    from .ssp_master import SspMaster
    model = contract.identify([v.name for v in read_model_description(str(fmu)).modelVariables])
    starts, states = [], []
    for c in names:
        p = dict(pkg.parameters.get(c, {}))
        q0, u0 = [p.pop(k) for k in model.q_start], [p.pop(k) for k in model.u_start]
        starts.append(p)
        states.append((np.array(q0), np.array(u0)) if model.n > 1 else (q0[0], u0[0]))
    A = np.zeros((spec.N, spec.N))
    for (i, j), (aij, aji) in zip(spec.edges, cfg.W2):
        A[i, j], A[j, i] = aij, aji
    code_name = {v: k for k, v in LAWS.items()}
    laws = [code_name[int(c)] for c in cfg.laws]
    geo = cfg.geo
    # the coupling's geometry must be the systems' (the master itself reads theirs from the FMU)
    declared = {v.name: v.start for v in model.declare() if v.start is not None}
    systems = [model.geometry_system({**declared, **p}) for p in starts]
    z = np.zeros((spec.n, spec.n))
    mine = MechanicalSystem(M=geo.M, K=z, C=z, f0=np.zeros(spec.n), w=geo.w, g0=geo.g0, e=geo.e)
    check_common_geometry(systems + [mine], names + ["the coupling component"])
    if "switching-compensated" in laws:   # and the force law h it evaluates must be theirs
        _check_force_laws(pkg, names, cvals, [{**declared, **p} for p in starts])
    master = SspMaster(fmu, states, A, t_end, H, [None if x == "none" else x for x in laws], cfg.Kp, cfg.Kd,
                           geo.Q, method=method, record_every=record_every, start_values=starts,
                           allow_unstable=allow_unstable)
    about = dict(package=str(pkg.path), components=names, method=method, H=float(H),
                 wall={"w": [float(x) for x in np.ravel(geo.w)], "g0": float(geo.g0)})
    try:
        res = master.run(progress)
    except RunFailed as exc:   # the record up to the failure says what it is too
        if exc.partial is not None:
            exc.partial.info.update(about)
        raise
    res.info.update(about)
    return res


def _check_force_laws(pkg, names, cvals, values) -> None:
    """The coupling's copy of each system's force law (``k[i]`` .. ``phi[i]``) must be that
    system's (SsdError naming the first parameter that differs)."""
    from .fmus.coupling import force_names
    for i, (c, p) in enumerate(zip(names, values)):
        for a in force_names():
            mine, theirs = cvals.get(f"{a}[{i + 1}]"), p.get(a)
            if mine != theirs:
                raise SsdError(f"{pkg.path}: the law switching-compensated evaluates each system's force law, "
                               f"but the coupling component's {a}[{i + 1}] = {mine!r} differs from {c}'s "
                               f"{a} = {theirs!r} (bind it from {c}'s parameters, as fmu-sync ssp writes it)")


def save_result(res, out, formats=("csv", "npz"), plots: bool = True, method: str | None = None) -> Path:
    """Write a package run as a scene run is written (docs/results.md): ``out/result.npz``
    (with its ``meta``: layout, counts, the package's settings, plots, title and wall) and/or
    ``result.csv``, the network plots and ``summary.md``; a failed run (``res.error``) keeps its
    record as ``result.partial.*``, no plots. ``fmu_sync.load`` and ``fmu-sync plot`` read the
    folder back. Returns the summary's path."""
    from . import plots as P
    from . import report
    from .output import check_out_dir, make_out_dir, results_in
    from .scenes.running import clean_written
    from .scenes.schema import plots_for
    out = check_out_dir(out)
    name = Path(res.info.get("package", "package")).name
    head = f"Package `{name}`"
    results_in(out, head)                             # another run's results there: refused
    created = make_out_dir(out)
    failed = bool(res.error)
    info = res.info
    wall = info.get("wall")
    kinds = plots_for(True, res.d is not None, True)
    settings = {"package": info.get("package"), "method": method or info.get("method"), "H": info.get("H"),
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
