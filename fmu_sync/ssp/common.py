"""The names and the one refusal shared by the SSP reader, writer and runner (:mod:`fmu_sync.ssp`)."""
from __future__ import annotations

from xml.etree import ElementTree as ET

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
#: the attributes of an ``ssd:Connection``, in the order of a connection tuple
CONNECTION_ENDS = ("startElement", "startConnector", "endElement", "endConnector")
COUPLING_FMU = "resources/coupling.fmu"
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


def tag_of(tag: str) -> str:
    """``ssd:Component`` of ``{uri}Component``."""
    uri, _, local = tag[1:].partition("}") if tag.startswith("{") else ("", "", tag)
    return f"{_PREFIX.get(uri, uri)}:{local}" if uri else local


def element_of(el, *attrs: str) -> str:
    """An element as the message names it: ``<ssv:Parameter name="m">`` (the given attributes that it has)."""
    shown = "".join(f' {a}="{el.get(a)}"' for a in attrs if el.get(a) is not None)
    return f"<{tag_of(el.tag)}{shown}>"



def system_component(i: int, N: int = 9) -> str:
    """The component name of system i (0-based) of N: ``system1`` .. (zero-padded for N >= 10,
    ``system01``: fmpy's runner matches parameters by the prefix of the component name, so no
    name may be the prefix of another)."""
    return f"system{i + 1:0{len(str(N))}d}"


def qname(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def fmt_real(x: float) -> str:
    return repr(float(x))



def coupling_connections(systems: list[str], q: list[str], u: list[str], tau: list[str]) -> list[tuple]:
    """The connections of a coupled system as fmu-sync writes and runs it, as (start element, start
    connector, end element, end connector): each system's q and u to the coupling's ``q[i]``, ``u[i]``
    (``q[i,k]`` for n > 1), the coupling's ``tau[i]`` to the system's tau; ``q``, ``u``, ``tau``: the
    system FMU's variable names. :func:`~fmu_sync.ssp.write_ssp` writes these, :func:`~fmu_sync.ssp.run_ssp`
    runs a package only if it holds exactly these (docs/ssp.md)."""
    from ..fmus.coupling import node_names
    n, out = len(q), []
    for i, c in enumerate(systems):
        for mine, theirs in list(zip(q, node_names("q", i, n))) + list(zip(u, node_names("u", i, n))):
            out.append((c, mine, COUPLING_COMPONENT, theirs))
        out += [(COUPLING_COMPONENT, theirs, c, mine) for mine, theirs in zip(tau, node_names("tau", i, n))]
    return out
