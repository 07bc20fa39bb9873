# long module: the SSP reader, writer and runner share one checking layer (SspError) and its element names
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
import json
import math
import re
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from xml.etree import ElementTree as ET

import numpy as np

from .fmus import contract

__all__ = ["write_ssp", "read_ssp", "run_ssp", "save_result", "SspPackage", "fmpy_parameter_set", "SSD", "SspError", "SsdError",
           "COUPLING_COMPONENT", "system_component",
           "coupling_connections"]

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
#: the most a package entry may inflate to when it is read (an FMU of ours is about 1.3 MB; a
#: zip bomb is refused instead of read whole): FMUs, and the XML/JSON files read into memory
MAX_ENTRY_BYTES = 256 * 2**20
MAX_TEXT_BYTES = 16 * 2**20
for _p, _u in NS.items():
    ET.register_namespace(_p, _u)


class SspError(ValueError):
    """A package that cannot be read or run: the one refusal of this module's checking layer, naming
    the ``package``, the ``file`` inside it, the ``element`` and what is wrong (``reason``); either
    of ``file`` and ``element`` may be None where the fault has none (a package that is not a zip)."""

    def __init__(self, package, file: str | None = None, element: str | None = None, reason: str = ""):
        self.package, self.file, self.element, self.reason = str(package), file, element, reason
        where = "".join(f", {x}" for x in (file, element) if x)
        super().__init__(f"SSP package {package}{where}: {reason}")


#: the former name of :class:`SspError` (the same class)
SsdError = SspError
_PREFIX = {uri: prefix for prefix, uri in NS.items()}


def _tag(tag: str) -> str:
    """``ssd:Component`` of ``{uri}Component``."""
    uri, _, local = tag[1:].partition("}") if tag.startswith("{") else ("", "", tag)
    return f"{_PREFIX.get(uri, uri)}:{local}" if uri else local


def _element(el, *attrs: str) -> str:
    """An element as the message names it: ``<ssv:Parameter name="m">`` (the given attributes that it has)."""
    shown = "".join(f' {a}="{el.get(a)}"' for a in attrs if el.get(a) is not None)
    return f"<{_tag(el.tag)}{shown}>"


class _Archive:
    """The open package behind every check of a read or a run: each refusal is an :class:`SspError`
    naming the package, the file inside it and the element."""

    def __init__(self, path: Path, zf: zipfile.ZipFile):
        self.path, self.zf = path, zf
        self.names = set(zf.namelist())
        if len(self.names) != len(zf.namelist()):    # zipfile would read the last of them, silently
            twice = sorted({n for n in zf.namelist() if zf.namelist().count(n) > 1})
            raise self.fail(twice[0], None, f"the package holds {len(twice)} entry name(s) twice "
                            f"({', '.join(twice[:4])}): which one a master reads is undefined, so it is refused")

    def fail(self, file: str | None, element: str | None, reason: str) -> SspError:
        return SspError(self.path, file, element, reason)

    def read(self, name: str, limit: int = MAX_TEXT_BYTES, zf: zipfile.ZipFile | None = None,
             where: str | None = None) -> bytes:
        """Entry ``name`` of the package (or of the inner archive ``zf``), refused above ``limit`` bytes
        as declared or as it inflates (it is never read whole beyond the limit)."""
        zf = zf or self.zf
        size = zf.getinfo(name).file_size
        with zf.open(name) as f:
            raw = f.read(limit + 1) if size <= limit else b""
        if size > limit or len(raw) > limit:
            raise self.fail(where or name, None if where is None else name,
                            f"inflates to {max(size, len(raw)) / 2**20:.1f} MiB, above the limit of "
                            f"{limit / 2**20:g} MiB for {'an FMU' if limit == MAX_ENTRY_BYTES else 'a text file'} "
                            f"of a package")
        return raw

    def data(self, name: str | None, file: str, element: str) -> bytes:
        """The entry ``name`` that ``element`` of ``file`` refers to."""
        if not name:
            raise self.fail(file, element, "names no file (its source attribute is missing or empty)")
        if name not in self.names:
            held = ", ".join(sorted(self.names)[:12]) + (", ..." if len(self.names) > 12 else "")
            raise self.fail(file, element, f"refers to {name}, which the package does not hold (it holds: {held})")
        return self.read(name, MAX_ENTRY_BYTES if name.lower().endswith(".fmu") else MAX_TEXT_BYTES)

    def xml(self, name: str, root: str, file: str, element: str):
        """The root of the XML entry ``name`` (referred to by ``element`` of ``file``), which must be ``root``."""
        raw = self.data(name, file, element)
        try:
            tree = ET.fromstring(raw)
        except ET.ParseError as exc:
            line, col = exc.position
            raise self.fail(name, f"line {line}, column {col}",
                            f"not well-formed XML ({str(exc).split(':')[0]})") from None
        if tree.tag != root:
            raise self.fail(name, f"root element <{_tag(tree.tag)}>", f"not an SSP file of this kind: its root "
                                                                     f"element must be <{_tag(root)}>")
        return tree

    def number(self, file: str, element: str, text, what: str = "value", positive: bool = False) -> float:
        """``text`` as a finite float (> 0 if ``positive``)."""
        if text is None:
            raise self.fail(file, element, f"has no {what} attribute")
        try:
            x = float(text)
        except ValueError:
            raise self.fail(file, element, f"{what} {text!r} is not a number") from None
        if not math.isfinite(x):
            raise self.fail(file, element, f"{what} {text!r} is not a finite number")
        if positive and not x > 0.0:
            raise self.fail(file, element, f"{what} {text!r} must be > 0")
        return x

    def fmu_json(self, src: str, entry: str, component: str):
        """The JSON file ``entry`` of the component FMU ``src`` (an fmu-sync FMU)."""
        element = f'<ssd:Component name="{component}">'
        try:
            with zipfile.ZipFile(io.BytesIO(self.data(src, SSD, element))) as fz:
                raw = self.read(entry, MAX_TEXT_BYTES, fz, src)
        except zipfile.BadZipFile:
            raise self.fail(src, element, "not an FMU (not a zip archive)") from None
        except KeyError:
            raise self.fail(src, entry, f"not an fmu-sync FMU: it has no {entry}") from None
        try:
            return json.loads(raw)
        except ValueError as exc:
            raise self.fail(src, entry, f"not valid JSON ({exc})") from None


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
    from .core.compensation import check_compensated
    from .core.model import as_state
    from .core.network import edges_of
    from .export import export_coupling, export_fmu, write_archive
    from .scenes.loading import as_scene
    from .scenes.running import export_spec, scene_values
    from .scenes.schema import SceneError

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
    _component(elements, COUPLING_COMPONENT, _COUPLING_FMU, cons, f"resources/{COUPLING_COMPONENT}.ssv",
               [(f"resources/{system_component(i, N)}.ssv", _ssm_name(i, N)) for i in range(N)] if mapped else ())
    conns = ET.SubElement(system, _q("ssd", "Connections"))
    for ends in coupling_connections([system_component(i, N) for i in range(N)], model):
        ET.SubElement(conns, _q("ssd", "Connection"), dict(zip(_ENDS, ends)))
    _oms_annotation(system, cfg["run.H"])
    exp = ET.SubElement(root, _q("ssd", "DefaultExperiment"),
                        {"startTime": "0.0", "stopTime": _fmt(cfg["run.t_end"])})
    ann = ET.SubElement(ET.SubElement(exp, _q("ssd", "Annotations")), _q("ssc", "Annotation"), {"type": OSP})
    alg = ET.SubElement(ann, _q("osp", "Algorithm"))
    ET.SubElement(alg, _q("osp", "FixedStepAlgorithm"), {"baseStepSize": _fmt(cfg["run.H"])})
    return _xml_bytes(root)


_ENDS = ("startElement", "startConnector", "endElement", "endConnector")


def coupling_connections(names: list[str], model) -> list[tuple]:
    """The connections of the coupled system our master runs, the one definition the writer
    writes and the runner holds a package to: system i's q and u to the coupling's ``q[i]``,
    ``u[i]``, the coupling's ``tau[i]`` to system i's tau (``names``: the system components in
    node order; ``model``: their FMU model, its variable names and n)."""
    from .fmus.coupling import node_names
    out = []
    for i, c in enumerate(names):
        for base, mine in (("q", model.q), ("u", model.u)):
            out += [(c, a, COUPLING_COMPONENT, b) for a, b in zip(mine, node_names(base, i, model.n))]
        out += [(COUPLING_COMPONENT, b, c, a) for a, b in zip(model.tau, node_names("tau", i, model.n))]
    return out


def _check_connections(pkg: SspPackage, names: list[str], model) -> None:
    """The package's connections must be the coupled system our master runs (it computes the forces
    itself and sets them as :func:`coupling_connections` says): a connection missing, added,
    crossed or to a connector that does not exist is refused, naming it, instead of running
    another system than the package describes."""
    want = coupling_connections(names, model)
    have = [tuple(c) for c in pkg.connections]
    show = (lambda e: f'<ssd:Connection startElement="{e[0]}" startConnector="{e[1]}" endElement="{e[2]}" '
                      f'endConnector="{e[3]}">')
    rule = (f"our master runs each system's {'/'.join(model.q + model.u)} into the coupling's q[i]/u[i] and the "
            f"coupling's tau[i] into system i's {'/'.join(model.tau)}, nothing else")
    for e in have:
        if e not in want:
            raise pkg.fail(SSD, show(e), f"is not a connection of the coupled system our master can run ({rule}); "
                           f"it would run another system than this package describes")
    for e in want:
        if e not in have:
            raise pkg.fail(SSD, "<ssd:Connections>", f"lacks the connection {e[0]}.{e[1]} -> {e[2]}.{e[3]} "
                           f"({rule}); it would run another system than this package describes")


# ------------------------------------------------------------------ reading
@dataclass
class SspPackage:
    """What :func:`read_ssp` finds in a package: components (name -> FMU source inside
    the archive), their bound Real parameter values, the connections
    ((start element, start connector, end element, end connector)), t_end and H;
    ``origins``: per component, where each bound value was read (file inside the package, element)."""

    path: Path
    name: str
    sources: dict
    parameters: dict
    connections: list
    t_end: float | None
    H: float | None
    extra: dict = field(default_factory=dict)
    origins: dict = field(default_factory=dict)
    bindings: dict = field(default_factory=dict)   #: per component, the files its bindings read

    def fail(self, file: str | None, element: str | None, reason: str) -> SspError:
        return SspError(self.path, file, element, reason)

    def origin(self, component: str, name: str) -> tuple[str, str]:
        """(file, element) that bound ``name`` of ``component`` (its FMU's start value if none did)."""
        return self.origins.get(component, {}).get(name) or (self.sources.get(component),
                                                              f"start value of {name!r}")


def _parameters(arc: _Archive, file: str, root) -> dict:
    """name -> (value, element) of the Real parameters of an ``ssv:ParameterSet`` (in ``file``)."""
    out = {}
    for p in root.iter(_q("ssv", "Parameter")):
        name = p.get("name")
        if not name:
            raise arc.fail(file, _element(p), "has no name attribute")
        real = p.find(_q("ssv", "Real"))
        if real is not None:
            element = f'<ssv:Parameter name="{name}"> <ssv:Real>'
            out[name] = (arc.number(file, element, real.get("value")), element)
    return out


def _mapped(arc: _Archive, values: dict, mapping, file: str, element: str) -> dict:
    """A binding's values under its parameter mapping (an ``.ssm`` source or inline entries, the
    ``ssd:ParameterMapping`` ``element`` of ``file``): the mapped names renamed, the others dropped
    (the binding is meant for those it maps)."""
    if mapping is None:
        return values
    root, where = mapping, file
    if mapping.get("source"):
        where = mapping.get("source")
        root = arc.xml(where, _q("ssm", "ParameterMapping"), file, element)
    entries = {}
    for e in root.iter(_q("ssm", "MappingEntry")):
        if not (e.get("source") and e.get("target")):
            raise arc.fail(where, _element(e, "source", "target"), "needs both a source and a target attribute")
        entries[e.get("source")] = e.get("target")
    return {entries[k]: v for k, v in values.items() if k in entries}


def read_ssp(path) -> SspPackage:
    """Read a package's structure, bindings and experiment: every refusal is an :class:`SspError`
    naming the package, the file inside it, the element and what is wrong (not a zip, an .ssd that
    is not SSP XML, a component FMU, .ssv or .ssm it does not hold, a value that is not a finite number)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"SSP package not found: {path}")
    try:
        zf = zipfile.ZipFile(path)
    except zipfile.BadZipFile:
        raise SspError(path, None, None, "not an SSP package (not a zip archive)") from None
    with zf:
        arc = _Archive(path, zf)
        if SSD not in arc.names:
            raise arc.fail(SSD, None, "missing: an SSP package holds it at its root (the package holds: "
                           f"{', '.join(sorted(arc.names)[:8]) or 'nothing'})")
        root = arc.xml(SSD, _q("ssd", "SystemStructureDescription"), SSD, None)
        system = root.find(_q("ssd", "System"))
        if system is None:
            raise arc.fail(SSD, _element(root, "name"), "has no <ssd:System>")
        sources, params, origins, bindings = {}, {}, {}, {}
        for comp in system.iter(_q("ssd", "Component")):
            name, src = comp.get("name"), comp.get("source")
            here = _element(comp, "name", "source")
            if not name:
                raise arc.fail(SSD, here, "has no name attribute")
            if name in sources:
                raise arc.fail(SSD, here, f"a second component named {name!r}")
            arc.data(src, SSD, here)           # the component's FMU is in the package
            sources[name], params[name], origins[name], bindings[name] = src, {}, {}, []
            for b in comp.iter(_q("ssd", "ParameterBinding")):
                found = {}
                if b.get("source"):
                    ssv = b.get("source")
                    bind = _element(b, "source")
                    found = _parameters(arc, ssv, arc.xml(ssv, _q("ssv", "ParameterSet"), SSD, bind))
                    found = _mapped(arc, found, b.find(_q("ssd", "ParameterMapping")), SSD, bind)
                    bindings[name].append(ssv)
                for ps in b.iter(_q("ssv", "ParameterSet")):     # inline values
                    found.update({k: (v, f"{e} (inline, component {name!r})")
                                  for k, (v, e) in _parameters(arc, SSD, ps).items()})
                for k, (v, e) in found.items():
                    params[name][k] = v
                    origins[name][k] = (b.get("source") or SSD, e)
        conns = []
        for c in system.iter(_q("ssd", "Connection")):
            ends = tuple(c.get(a) for a in ("startElement", "startConnector", "endElement", "endConnector"))
            here = _element(c, "startElement", "startConnector", "endElement", "endConnector")
            if not (ends[1] and ends[3]):
                raise arc.fail(SSD, here, "needs a startConnector and an endConnector")
            for el in (ends[0], ends[2]):
                if el and el not in sources:
                    raise arc.fail(SSD, here, f"names the element {el!r}, which is not a component "
                                              f"({', '.join(sources)})")
            conns.append(ends)
        exp = root.find(_q("ssd", "DefaultExperiment"))
        t_end = None
        if exp is not None:
            for a in ("startTime", "stopTime"):
                if exp.get(a) is not None:
                    x = arc.number(SSD, "<ssd:DefaultExperiment>", exp.get(a), a, positive=a == "stopTime")
                    t_end = x if a == "stopTime" else t_end
        H = _package_step(arc, root, system)
    return SspPackage(path, root.get("name"), sources, params, conns, t_end, H, origins=origins, bindings=bindings)


def _package_step(arc: _Archive, root, system) -> float | None:
    """The communication step the package gives: libcosim's (``osp:FixedStepAlgorithm``) and
    OMSimulator's (the system's ``oms:SimulationInformation fixedStepSize``), each a finite number > 0,
    which must agree when both are there (a package edited in one tool only is refused, naming both)."""
    fs = root.find(f".//{_q('osp', 'FixedStepAlgorithm')}")
    steps = {}
    if fs is not None and fs.get("baseStepSize") is not None:
        steps["<osp:FixedStepAlgorithm> baseStepSize"] = fs.get("baseStepSize")
    for ann in system.findall(f"{_q('ssd', 'Annotations')}/{_q('ssc', 'Annotation')}"):
        info = ann.find(f".//{_q('oms', 'SimulationInformation')}") if ann.get("type") == OMS else None
        if info is not None and info.get("fixedStepSize") is not None:
            steps["<oms:SimulationInformation> fixedStepSize"] = info.get("fixedStepSize")
    given = {k: arc.number(SSD, k.split()[0], v, k.split()[1], positive=True) for k, v in steps.items()}
    if len(set(given.values())) > 1:
        raise arc.fail(SSD, " and ".join(given), "the package gives two different communication steps: "
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


def _coupling_setup(pkg: SspPackage, arc: _Archive):
    """(coupling slave, its parameter values, its configuration): the coupling FMU's start values
    under the bindings, checked as the FMU checks them."""
    from .fmus.coupling import CouplingSlave, CouplingSpec
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
            record_every: int = 1, progress=None, allow_unstable: bool = False):
    """Run an fmu-sync SSP package in our master (:class:`fmu_sync.master.NetworkMaster`).

    The systems are the package's oscillator components (one FMU file, each with its
    bound parameters and start state); the graph, the law per edge, Kp, Kd and Q are
    the coupling component's parameters; t_end and H the package's DefaultExperiment
    (overridable). ``method``: the master's exchange order ("jacobi", "gauss-seidel",
    or another master's (:class:`fmu_sync.ssp_master.SspMaster`): "delayed" = libcosim,
    "delayed-zero" = fmpy's SSP runner; docs/ssp.md). Returns a :class:`~fmu_sync.core.result.NetworkResult`.
    Every fault of the package is refused before the run with an :class:`SspError` naming the
    package, the file inside it, the element and what is wrong: the checks of :func:`read_ssp`, every
    component's values as its FMU checks them, a coupling geometry that differs from the systems'.
    """
    pkg = read_ssp(path)
    t_end = pkg.t_end if t_end is None else t_end
    H = pkg.H if H is None else H
    if t_end is None or H is None:
        raise pkg.fail(SSD, "<ssd:DefaultExperiment>", "no stopTime or no step size (osp:FixedStepAlgorithm "
                       "baseStepSize in its DefaultExperiment, or OMSimulator's fixedStepSize in its system): "
                       "give t_end and H")
    with zipfile.ZipFile(pkg.path) as zf, tempfile.TemporaryDirectory(prefix="fmu-sync-ssp-") as tmp:
        arc = _Archive(pkg.path, zf)
        ccls, cvals, cfg = _coupling_setup(pkg, arc)
        names = _system_components(pkg, ccls.SPEC.N)
        fmu = Path(tmp) / "system.fmu"
        fmu.write_bytes(_one_model(pkg, arc, names))
        return _run_master(pkg, arc, fmu, names, ccls.SPEC, cfg, t_end, H, method, record_every, progress,
                           allow_unstable, cvals)


def _one_model(pkg: SspPackage, arc: _Archive, names: list[str]) -> bytes:
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
    return arc.read(srcs[0], MAX_ENTRY_BYTES)


def _run_master(pkg, arc, fmu, names, spec, cfg, t_end, H, method, record_every, progress, allow_unstable, cvals):
    from .core.coupling import LAWS
    from .core.errors import RunFailed
    from .core.pair import check_common_geometry
    from .fmus.slave import MechanicalSlave
    from .master import fmu_model, model_description
    from .ssp_master import SspMaster
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
    code_name = {v: k for k, v in LAWS.items()}
    laws = [code_name[int(c)] for c in cfg.laws]
    geo = cfg.geo
    # the coupling's geometry must be the systems' (the master itself reads theirs from the FMU)
    systems = [model.geometry_system(v) for v in values]
    # the coupling's geometry beside the systems' (their force law: only the geometry is compared)
    mine = SimpleNamespace(n=spec.n, force=systems[0].force, M=geo.M, w=geo.w, g0=geo.g0, e=geo.e)
    try:
        check_common_geometry(systems + [mine], names + ["the coupling component"])
    except ValueError as exc:
        raise pkg.fail(", ".join(pkg.bindings.get(COUPLING_COMPONENT) or [pkg.sources[COUPLING_COMPONENT]]),
                       "the geometry M, w, g0, e", str(exc)) from None
    if "switching-compensated" in laws:   # and the force law h it evaluates must be theirs
        _check_force_laws(pkg, names, cvals, values)
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
    system's (SspError naming the first parameter that differs, where the coupling's was read)."""
    from .fmus.coupling import force_names
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
