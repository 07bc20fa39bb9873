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
  impact geometry). Only Real values are bound: the enumerations (the solver
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
from xml.etree import ElementTree as ET

import numpy as np

from .fmus import contract

__all__ = ["write_ssp", "read_ssp", "run_ssp", "save_result", "SspPackage", "fmpy_parameter_set", "SSD", "SsdError",
           "COUPLING_COMPONENT", "system_component"]

SSD = "SystemStructure.ssd"
NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
      "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
      "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
      "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations"}
OSP = "com.opensimulationplatform"
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


def _component(elements, name: str, source: str, connectors, ssv: str):
    comp = ET.SubElement(elements, _q("ssd", "Component"),
                         {"name": name, "type": "application/x-fmu-sharedlibrary", "source": source})
    cons = ET.SubElement(comp, _q("ssd", "Connectors"))
    for args in connectors:
        _connector(cons, *args)
    binds = ET.SubElement(comp, _q("ssd", "ParameterBindings"))
    ET.SubElement(binds, _q("ssd", "ParameterBinding"), {"source": ssv})
    return comp


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
    osc_name = f"resources/{model.key.replace('-', '_')}.fmu"
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="fmu-sync-ssp-") as tmp:
        osc = export_fmu(model.key, Path(tmp) / "osc.fmu", {**comp_values[0], contract.SOLVER_SCHEME:
                                                            solver[contract.SOLVER_SCHEME]})
        cpl = export_coupling(Path(tmp) / "coupling.fmu", A, n, {**coupling_real, **coupling_enum})
        files = [(SSD, _ssd(sc.name, v, model, edges, len(systems), n, osc_name, cfg)),
                 (osc_name, osc.read_bytes()), (_COUPLING_FMU, cpl.read_bytes())]
    N = len(comp_values)
    files += [(f"resources/{system_component(i, N)}.ssv", _ssv(system_component(i, N), vals))
              for i, vals in enumerate(comp_values)]
    files.append((f"resources/{COUPLING_COMPONENT}.ssv", _ssv(COUPLING_COMPONENT, coupling_real)))
    write_archive(path, files)
    return path


def _ssd(scene_name, v, model, edges, N, n, osc_name, cfg) -> bytes:
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
        _component(elements, system_component(i, N), osc_name, cons, f"resources/{system_component(i, N)}.ssv")
    E = len(edges)
    cons = []
    for base, unit in (("q", "m"), ("u", "m/s")):
        cons += [(a, "input", "Real", unit) for i in range(N) for a in node_names(base, i, n)]
    cons += [(a, "output", "Real", "N") for i in range(N) for a in node_names("tau", i, n)]
    cons += [(a, "output", "Real", None) for base in ("d", "V", "euclidean") for a in edge_names(base, E)]
    cons += [(a, "output", "Integer", None) for a in edge_names("branch", E)]
    _component(elements, COUPLING_COMPONENT, _COUPLING_FMU, cons, f"resources/{COUPLING_COMPONENT}.ssv")
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
                    params[name].update(_read_ssv(zf, b.get("source")))
                for ps in b.iter(_q("ssv", "ParameterSet")):
                    for p in ps.iter(_q("ssv", "Parameter")):
                        real = p.find(_q("ssv", "Real"))
                        if real is not None:
                            params[name][p.get("name")] = float(real.get("value"))
        conns = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
                 for c in system.iter(_q("ssd", "Connection"))]
        exp = root.find(_q("ssd", "DefaultExperiment"))
        t_end = float(exp.get("stopTime")) if exp is not None and exp.get("stopTime") else None
        fs = root.find(f".//{_q('osp', 'FixedStepAlgorithm')}")
        H = float(fs.get("baseStepSize")) if fs is not None else None
    return SspPackage(path, root.get("name"), sources, params, conns, t_end, H)


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
        raise SsdError(f"{pkg.path}: no stopTime or no step size (osp:FixedStepAlgorithm baseStepSize) in "
                       f"its DefaultExperiment: give t_end and H")
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
        srcs = {pkg.sources[c] for c in names}
        if len(srcs) != 1:
            raise SsdError(f"{pkg.path}: our master runs N instances of one FMU; the systems use {sorted(srcs)}")
        fmu = Path(tmp) / "system.fmu"
        fmu.write_bytes(zf.read(srcs.pop()))
        return _run_master(pkg, fmu, names, spec, cfg, t_end, H, method, record_every, progress, allow_unstable)


def _run_master(pkg, fmu, names, spec, cfg, t_end, H, method, record_every, progress, allow_unstable):
    from fmpy import read_model_description

    from .core.coupling import LAWS
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
    master = SspMaster(fmu, states, A, t_end, H, [None if x == "none" else x for x in laws], cfg.Kp, cfg.Kd,
                           geo.Q, method=method, record_every=record_every, start_values=starts,
                           allow_unstable=allow_unstable)
    res = master.run(progress)
    res.info.update(package=str(pkg.path), components=names)
    return res


def save_result(res, out) -> Path:
    """Write a package run's record to ``out/result.npz`` (t, q, u, tau, d, branch, euclidean,
    V, edges) and return its path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "result.npz"
    arrays = {k: getattr(res, k) for k in ("t", "q", "u", "tau", "d", "branch", "euclidean", "V")
              if getattr(res, k) is not None}
    np.savez(path, edges=np.array(res.edges, dtype=np.int64).reshape(-1, 2), **arrays)
    return path
