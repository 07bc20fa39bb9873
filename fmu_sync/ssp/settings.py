"""The run settings an SSP package keeps (docs/ssp.md): the exchange, the hold, the tolerance and the
event-aware retake of the scene it was written from, beside its t_end and H.

SSP 1.0 has no place for them: they are an annotation of the ``ssd:DefaultExperiment`` (type
:data:`RUN_ANNOTATION`), ``<fs:Run exchange="implicit" hold="foh" tol="0.001" />``, which other tools
ignore as the standard asks of annotations they do not know. :func:`~fmu_sync.ssp.write_ssp` writes it,
:func:`~fmu_sync.ssp.run_ssp` runs with it, and ``fmu-sync run X.ssp --set run.KEY=VALUE`` overrides
it (and t_end, H) for one run.
"""
from __future__ import annotations

import math

from .common import NS, SSD, fmt_real, qname

#: the annotation's type and its namespace (prefix ``fs``)
RUN_ANNOTATION = "org.fmu-sync.run"
NS.setdefault("fs", "urn:fmu-sync:ssp:run")
#: the package's run settings: the scene key -> the master's argument; their values when a package has none
RUN_KEYS = {"run.exchange": "exchange", "run.hold": "hold", "run.tol": "tol", "run.event_aware": "event_aware",
            "run.H_min": "H_min"}
DEFAULTS = {"exchange": "explicit", "hold": "zoh", "tol": None, "event_aware": False, "H_min": None}
#: the keys ``--set`` takes for a package: its experiment's and its run settings
SET_KEYS = ("run.t_end", "run.H", *RUN_KEYS)


def register() -> None:
    from xml.etree import ElementTree as ET
    ET.register_namespace("fs", NS["fs"])


register()


def write_run(annotations, cfg) -> None:
    """The ``fs:Run`` annotation of a scene variant's settings ``cfg`` in ``annotations`` (the
    DefaultExperiment's ``ssd:Annotations``): every setting, defaults too, so that the package says them."""
    from xml.etree import ElementTree as ET
    ann = ET.SubElement(annotations, qname("ssc", "Annotation"), {"type": RUN_ANNOTATION})
    attrs = {}
    for key, arg in RUN_KEYS.items():
        value = cfg.get(key)
        if value is None:
            continue
        attrs[arg] = ("true" if value else "false") if isinstance(value, bool) else \
            fmt_real(value) if isinstance(value, (int, float)) else str(value)
    ET.SubElement(ann, qname("fs", "Run"), attrs)


def read_run(arc, root) -> dict:
    """The package's run settings (the master's argument names; :data:`DEFAULTS` for what it does not
    give): SspError naming the attribute for a value that is not one."""
    from ..core.exchange import EXCHANGES, HOLDS
    run = dict(DEFAULTS)
    el = root.find(f"{qname('ssd', 'DefaultExperiment')}//{qname('fs', 'Run')}")
    if el is None:
        return run
    here = "<ssd:DefaultExperiment> <fs:Run>"
    unknown = sorted(set(el.attrib) - set(DEFAULTS))
    if unknown:
        raise arc.fail(SSD, here, f"unknown run setting {unknown[0]!r} (allowed: {', '.join(DEFAULTS)})")
    choices = {"exchange": EXCHANGES, "hold": HOLDS, "event_aware": ("true", "false")}
    for k, text in el.attrib.items():
        if k in choices:
            if text not in choices[k]:
                raise arc.fail(SSD, here, f"{k} {text!r} is not one of {', '.join(choices[k])}")
            run[k] = text == "true" if k == "event_aware" else text
        else:
            run[k] = arc.number(SSD, here, text, k, positive=True)
    return run


def overrides(pairs: dict) -> tuple[dict, dict]:
    """``--set`` pairs of an SSP run -> (t_end/H keyword arguments, run settings); ValueError naming a
    key that a package's run does not take (its values are in its .ssv files) or a value of the wrong kind."""
    exp, run = {}, {}
    for key, value in pairs.items():
        if key not in SET_KEYS:
            raise ValueError(f"--set {key}: an SSP run takes --set {', '.join(SET_KEYS)} only (the package's "
                             f"parameter values are in its .ssv files: edit them, or the scene and write it again)")
        if key in ("run.t_end", "run.H", "run.tol", "run.H_min"):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value)
                                                                                   and value > 0):
                raise ValueError(f"--set {key}={value!r}: must be a finite number > 0")
            value = float(value)
        elif key == "run.event_aware" and not isinstance(value, bool):
            raise ValueError(f"--set {key}={value!r}: must be true or false")
        elif key in ("run.exchange", "run.hold") and not isinstance(value, str):
            raise ValueError(f"--set {key}={value!r}: must be a string (TOML: quoted, or a bare word)")
        if key in ("run.t_end", "run.H"):
            exp[key.split(".")[1]] = value
        else:
            run[RUN_KEYS[key]] = value
    return exp, run
