"""Reading an SSP package: its structure, bindings and experiment (:func:`read_ssp`), every refusal an
:class:`~fmu_sync.ssp.common.SspError` naming the package, the file inside it and the element."""
from __future__ import annotations

import io
import json
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree as ET

from .common import CONNECTION_ENDS, OMS, SSD, SspError, element_of, qname, tag_of
from .settings import read_run


#: the largest entry of a package (or of a component FMU inside it) that is read, inflated: the
#: packages fmu-sync writes hold entries below 1 MB; an entry above it is refused, never inflated
MAX_ENTRY_BYTES = 64 * 2**20


def bounded_read(zf: zipfile.ZipFile, name: str, fail) -> bytes:
    """The entry ``name`` of ``zf``, inflated only if its size is at most :data:`MAX_ENTRY_BYTES`
    (``fail(reason)``: the error to raise above it). zipfile stops inflating at the size the entry
    declares and checks its CRC, so a declared size that lies is caught too."""
    size = zf.getinfo(name).file_size
    if size > MAX_ENTRY_BYTES:
        raise fail(f"inflates to {size:,} bytes, above the {MAX_ENTRY_BYTES:,} bytes an entry may have "
                   f"(fmu_sync.ssp.reader.MAX_ENTRY_BYTES): not read")
    try:
        return zf.read(name)
    except (zipfile.BadZipFile, EOFError, OSError) as exc:
        raise fail(f"a damaged entry ({exc})") from None


def _no_duplicates(zf: zipfile.ZipFile, fail) -> None:
    """Refuse a zip archive holding two entries of one name (which one a tool reads is its choice)."""
    seen = set()
    for name in zf.namelist():
        if name in seen:
            raise fail(name, "two entries of this name in one archive: which one is meant is not known "
                             "(write the archive again with one)")
        seen.add(name)


class Archive:
    """The open package behind every check of a read or a run: each refusal is an :class:`SspError`
    naming the package, the file inside it and the element."""

    def __init__(self, path: Path, zf: zipfile.ZipFile):
        self.path, self.zf = path, zf
        self.names = set(zf.namelist())
        _no_duplicates(zf, lambda name, reason: self.fail(name, None, reason))

    def fail(self, file: str | None, element: str | None, reason: str) -> SspError:
        return SspError(self.path, file, element, reason)

    def data(self, name: str | None, file: str, element: str) -> bytes:
        """The entry ``name`` that ``element`` of ``file`` refers to."""
        if not name:
            raise self.fail(file, element, "names no file (its source attribute is missing or empty)")
        if name not in self.names:
            held = ", ".join(sorted(self.names)[:12]) + (", ..." if len(self.names) > 12 else "")
            raise self.fail(file, element, f"refers to {name}, which the package does not hold (it holds: {held})")
        return bounded_read(self.zf, name, lambda reason: self.fail(name, None, reason))

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
            raise self.fail(name, f"root element <{tag_of(tree.tag)}>", f"not an SSP file of this kind: its root "
                                                                     f"element must be <{tag_of(root)}>")
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
                _no_duplicates(fz, lambda name, reason: self.fail(src, name, reason))
                raw = bounded_read(fz, entry, lambda reason: self.fail(src, entry, reason))
        except zipfile.BadZipFile:
            raise self.fail(src, element, "not an FMU (not a zip archive)") from None
        except KeyError:
            raise self.fail(src, entry, f"not an fmu-sync FMU: it has no {entry}") from None
        try:
            return json.loads(raw)
        except ValueError as exc:
            raise self.fail(src, entry, f"not valid JSON ({exc})") from None



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
    #: the run settings it keeps (exchange, hold, tol, event_aware, H_min: fmu_sync.ssp.settings)
    run: dict = field(default_factory=dict)
    origins: dict = field(default_factory=dict)
    bindings: dict = field(default_factory=dict)   #: per component, the files its bindings read

    def fail(self, file: str | None, element: str | None, reason: str) -> SspError:
        return SspError(self.path, file, element, reason)

    def origin(self, component: str, name: str) -> tuple[str, str]:
        """(file, element) that bound ``name`` of ``component`` (its FMU's start value if none did)."""
        return self.origins.get(component, {}).get(name) or (self.sources.get(component),
                                                              f"start value of {name!r}")


def _parameters(arc: Archive, file: str, root) -> dict:
    """name -> (value, element) of the Real parameters of an ``ssv:ParameterSet`` (in ``file``)."""
    out = {}
    for p in root.iter(qname("ssv", "Parameter")):
        name = p.get("name")
        if not name:
            raise arc.fail(file, element_of(p), "has no name attribute")
        real = p.find(qname("ssv", "Real"))
        if real is not None:
            element = f'<ssv:Parameter name="{name}"> <ssv:Real>'
            out[name] = (arc.number(file, element, real.get("value")), element)
    return out


def _mapped(arc: Archive, values: dict, mapping, file: str, element: str) -> dict:
    """A binding's values under its parameter mapping (an ``.ssm`` source or inline entries, the
    ``ssd:ParameterMapping`` ``element`` of ``file``): the mapped names renamed, the others dropped
    (the binding is meant for those it maps)."""
    if mapping is None:
        return values
    root, where = mapping, file
    if mapping.get("source"):
        where = mapping.get("source")
        root = arc.xml(where, qname("ssm", "ParameterMapping"), file, element)
    entries = {}
    for e in root.iter(qname("ssm", "MappingEntry")):
        if not (e.get("source") and e.get("target")):
            raise arc.fail(where, element_of(e, "source", "target"), "needs both a source and a target attribute")
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
        arc = Archive(path, zf)
        if SSD not in arc.names:
            raise arc.fail(SSD, None, "missing: an SSP package holds it at its root (the package holds: "
                           f"{', '.join(sorted(arc.names)[:8]) or 'nothing'})")
        root = arc.xml(SSD, qname("ssd", "SystemStructureDescription"), SSD, None)
        system = root.find(qname("ssd", "System"))
        if system is None:
            raise arc.fail(SSD, element_of(root, "name"), "has no <ssd:System>")
        sources, params, origins, bindings = {}, {}, {}, {}
        for comp in system.iter(qname("ssd", "Component")):
            name, src = comp.get("name"), comp.get("source")
            here = element_of(comp, "name", "source")
            if not name:
                raise arc.fail(SSD, here, "has no name attribute")
            if name in sources:
                raise arc.fail(SSD, here, f"a second component named {name!r}")
            arc.data(src, SSD, here)           # the component's FMU is in the package
            sources[name], params[name], origins[name], bindings[name] = src, {}, {}, []
            for b in comp.iter(qname("ssd", "ParameterBinding")):
                found = {}
                if b.get("source"):
                    ssv = b.get("source")
                    bind = element_of(b, "source")
                    found = _parameters(arc, ssv, arc.xml(ssv, qname("ssv", "ParameterSet"), SSD, bind))
                    found = _mapped(arc, found, b.find(qname("ssd", "ParameterMapping")), SSD, bind)
                    bindings[name].append(ssv)
                for ps in b.iter(qname("ssv", "ParameterSet")):     # inline values
                    found.update({k: (v, f"{e} (inline, component {name!r})")
                                  for k, (v, e) in _parameters(arc, SSD, ps).items()})
                for k, (v, e) in found.items():
                    params[name][k] = v
                    origins[name][k] = (b.get("source") or SSD, e)
        conns = []
        for c in system.iter(qname("ssd", "Connection")):
            ends = tuple(c.get(a) for a in CONNECTION_ENDS)
            here = element_of(c, *CONNECTION_ENDS)
            if not (ends[1] and ends[3]):
                raise arc.fail(SSD, here, "needs a startConnector and an endConnector")
            for el in (ends[0], ends[2]):
                if el and el not in sources:
                    raise arc.fail(SSD, here, f"names the element {el!r}, which is not a component "
                                              f"({', '.join(sources)})")
            conns.append(ends)
        exp = root.find(qname("ssd", "DefaultExperiment"))
        t_end = None
        if exp is not None:
            for a in ("startTime", "stopTime"):
                if exp.get(a) is not None:
                    x = arc.number(SSD, "<ssd:DefaultExperiment>", exp.get(a), a, positive=a == "stopTime")
                    t_end = x if a == "stopTime" else t_end
        H = _package_step(arc, root, system)
        run = read_run(arc, root)
    return SspPackage(path, root.get("name"), sources, params, conns, t_end, H, origins=origins, bindings=bindings,
                      run=run)


def _package_step(arc: Archive, root, system) -> float | None:
    """The communication step the package gives: libcosim's (``osp:FixedStepAlgorithm``) and
    OMSimulator's (the system's ``oms:SimulationInformation fixedStepSize``), each a finite number > 0,
    which must agree when both are there (a package edited in one tool only is refused, naming both)."""
    fs = root.find(f".//{qname('osp', 'FixedStepAlgorithm')}")
    steps = {}
    if fs is not None and fs.get("baseStepSize") is not None:
        steps["<osp:FixedStepAlgorithm> baseStepSize"] = fs.get("baseStepSize")
    for ann in system.findall(f"{qname('ssd', 'Annotations')}/{qname('ssc', 'Annotation')}"):
        info = ann.find(f".//{qname('oms', 'SimulationInformation')}") if ann.get("type") == OMS else None
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

