"""Variable declarations and the FMI 2.0 / FMI 3.0 modelDescription.xml of our slaves.

The FMU binary knows nothing of the interface: the whole model description is
built here from the interface declared in :mod:`.contract` (one :class:`Var`
per scalar).
"""
from __future__ import annotations

import itertools
import json
import re
import uuid
from xml.etree.ElementTree import Element, SubElement

from .contract import ENUM_TYPES, POSITIVE_MIN, SCHEME_ITEMS, SCHEME_TYPE, Var

__all__ = ["Var", "UNITS", "SCHEME_TYPE", "SCHEME_ITEMS", "model_description", "fmt_real",
           "POSITIVE_MIN", "unit_exponents", "generation_tool", "model_guid", "model_description3", "fmi3_groups",
           "FMI3_TYPES"]

#: SI units used by the slaves: name -> exponents of the SI base units
#: (plus rad), as written in <UnitDefinitions>.
UNITS: dict[str, dict[str, int]] = {
    "1": {},
    "m": {"m": 1},
    "m/s": {"m": 1, "s": -1},
    "s": {"s": 1},
    "kg": {"kg": 1},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N.s": {"kg": 1, "m": 1, "s": -1},
    "N/m": {"kg": 1, "s": -2},
    "N.s/m": {"kg": 1, "s": -1},
    "J": {"kg": 1, "m": 2, "s": -2},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
}


#: needsExecutionTool, FMI 2.0 §4.3.1 / FMI 3.0 §4.3.1: "a tool is needed to execute the model and the
#: FMU just contains the communication to this tool", the tool being the generationTool. Not so here:
#: the FMU carries its model (binary and code); the target needs a Python runtime with numpy, not
#: fmu-sync, stated in the FMU's documentation/ (docs/fmu.md "needsExecutionTool").
NEEDS_EXECUTION_TOOL = "false"


def generation_tool(version: str, fmi_version: int = 2) -> str:
    """generationTool of an FMU exported by fmu-sync ``version`` (the FMU's code never imports fmu_sync)."""
    return f"fmu-sync {version} (own FMI {fmi_version}.0 binary, Python slave)"


def model_guid(model: str, start_values: dict, code: str = "", version: str = "") -> str:
    """Deterministic GUID: changes with the model, the package version, the start
    values and the FMU's code (hash of the carried Python code and the C source)."""
    key = json.dumps({"model": model, "version": version, "start": start_values, "code": code},
                     sort_keys=True)
    return "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, "https://fmu-sync/" + key)) + "}"


def fmt_real(x: float) -> str:
    """Shortest text that reads back as the same double."""
    return repr(float(x))


#: the unit symbols a declared unit may be written with (FMI/Modelica spelling: factors joined by
#: ".", a "/" divides by what follows, an integer exponent after a symbol: "N.m.s/rad", "m/s2")
_SYMBOLS: dict[str, dict[str, int]] = {
    "m": {"m": 1}, "s": {"s": 1}, "kg": {"kg": 1}, "rad": {"rad": 1}, "A": {"A": 1}, "K": {"K": 1},
    "mol": {"mol": 1}, "cd": {"cd": 1}, "N": {"kg": 1, "m": 1, "s": -2},
    "J": {"kg": 1, "m": 2, "s": -2}, "W": {"kg": 1, "m": 2, "s": -3}, "Pa": {"kg": 1, "m": -1, "s": -2},
    "Hz": {"s": -1},
}


def unit_exponents(name: str) -> dict[str, int]:
    """The SI base-unit exponents of a unit written as declared (:data:`UNITS`, else parsed from
    :data:`_SYMBOLS`: "N.m.s/rad" -> kg m^2 s^-1 rad^-1); ValueError naming an unknown symbol."""
    if name in UNITS:
        return UNITS[name]
    out: dict[str, int] = {}
    for i, part in enumerate(name.split("/")):
        for factor in part.split("."):
            m = re.fullmatch(r"([A-Za-z]+)(-?\d+)?", factor)
            if m is None or m.group(1) not in _SYMBOLS:
                raise ValueError(f"unit {name!r}: cannot read {factor!r} (write SI symbols "
                                 f"{', '.join(_SYMBOLS)} joined by '.', '/' and integer "
                                 f"exponents, e.g. 'N.m.s/rad', 'm/s2', or '1')")
            power = int(m.group(2) or 1) * (-1 if i > 0 else 1)
            for base, e in _SYMBOLS[m.group(1)].items():
                out[base] = out.get(base, 0) + e * power
    return {k: v for k, v in out.items() if v != 0}


def _unit_definitions(root: Element, used: set[str]) -> None:
    defs = SubElement(root, "UnitDefinitions")
    names = [n for n in UNITS if n in used] + sorted(used - set(UNITS))
    for name in names:
        u = SubElement(defs, "Unit", name=name)
        SubElement(u, "BaseUnit", {k: str(v) for k, v in unit_exponents(name).items()})


def _type_definitions(root: Element, used: set[str], fmi3: bool = False) -> None:
    """The enumeration types the variables use (FMI 2.0 SimpleType, FMI 3.0 EnumerationType)."""
    defs = SubElement(root, "TypeDefinitions")
    for type_name, (description, items) in ENUM_TYPES.items():
        if type_name not in used:
            continue
        if fmi3:
            en = SubElement(defs, "EnumerationType", name=type_name, description=description)
        else:
            en = SubElement(SubElement(defs, "SimpleType", name=type_name, description=description), "Enumeration")
        for name, value, desc in items:
            SubElement(en, "Item", name=name, value=str(value), description=desc)

def _categories_and_experiment(root: Element, log_categories: dict[str, str], default_experiment: dict) -> None:
    cats = SubElement(root, "LogCategories")
    for name, desc in log_categories.items():
        SubElement(cats, "Category", name=name, description=desc)
    SubElement(root, "DefaultExperiment", {k: fmt_real(v) for k, v in default_experiment.items()})


def _head(fmi_version: str, identity: dict, model_name: str, description: str, generation_tool: str,
          cosimulation: dict, variables: list[Var], log_categories: dict, default_experiment: dict) -> Element:
    """<fmiModelDescription> with its attributes (``identity``: the GUID or FMI 3.0 instantiation
    token), <CoSimulation>, unit and type definitions, log categories and the default experiment:
    what both FMI versions write before the variables."""
    root = Element("fmiModelDescription", {"fmiVersion": fmi_version, "modelName": model_name, **identity,
                                           "description": description, "generationTool": generation_tool,
                                           "variableNamingConvention": "structured"})
    SubElement(root, "CoSimulation", cosimulation)
    _unit_definitions(root, {v.unit for v in variables if v.unit})
    _type_definitions(root, {v.declared_type for v in variables if v.declared_type}, fmi3=fmi_version == "3.0")
    _categories_and_experiment(root, log_categories, default_experiment)
    return root


def model_description(*, model_name: str, model_identifier: str, guid: str, description: str,
                      generation_tool: str, variables: list[Var], default_experiment: dict,
                      log_categories: dict[str, str]) -> Element:
    """The complete <fmiModelDescription> element (FMI 2.0, co-simulation)."""
    root = _head("2.0", {"guid": guid}, model_name, description, generation_tool, {
        "modelIdentifier": model_identifier,
        "needsExecutionTool": NEEDS_EXECUTION_TOOL,
        "canHandleVariableCommunicationStepSize": "true",
        "canInterpolateInputs": "true",
        "maxOutputDerivativeOrder": "0",
        "canRunAsynchronuously": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false",
        "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "true",
        "canSerializeFMUstate": "true",
        "providesDirectionalDerivative": "false",
    }, variables, log_categories, default_experiment)

    mv = SubElement(root, "ModelVariables")
    index = {}
    for i, v in enumerate(variables):
        index[v.name] = i + 1
        attrs = {"name": v.name, "valueReference": str(v.value_reference),
                 "description": v.description, "causality": v.causality,
                 "variability": v.variability}
        if v.initial is not None:
            attrs["initial"] = v.initial
        sv = SubElement(mv, "ScalarVariable", attrs)
        t = {}
        if v.declared_type:
            t["declaredType"] = v.declared_type
        if v.unit and v.type == "Real":
            t["unit"] = v.unit
        if v.min is not None:
            t["min"] = fmt_real(v.min) if v.type == "Real" else str(int(v.min))
        if v.max is not None:
            t["max"] = fmt_real(v.max) if v.type == "Real" else str(int(v.max))
        if v.start is not None:
            t["start"] = fmt_real(v.start) if v.type == "Real" else str(int(v.start))
        SubElement(sv, v.type, t)

    ms = SubElement(root, "ModelStructure")
    outputs = [v for v in variables if v.causality == "output"]
    if outputs:
        out = SubElement(ms, "Outputs")
        for v in outputs:
            # A mechanical model's outputs do not depend directly on an input at the
            # same communication point (tau only acts through the next step): empty
            # dependencies. The coupling's outputs are functions of its inputs.
            deps = sorted(index[d] for d in v.depends)
            SubElement(out, "Unknown", index=str(index[v.name]), dependencies=" ".join(map(str, deps)))
        init = SubElement(ms, "InitialUnknowns")
        for v in outputs:
            if v.initial in ("approx", "calculated"):
                deps = sorted(index[d] for d in v.initial_depends)
                SubElement(init, "Unknown", index=str(index[v.name]),
                           dependencies=" ".join(map(str, deps)))
    return root


# ----------------------------------------------------------------------------- FMI 3.0
#: FMI 2.0 type of a Var -> FMI 3.0 element (Integer and Enumeration values are int64 in FMI 3.0)
FMI3_TYPES = {"Real": "Float64", "Integer": "Int64", "Enumeration": "Enumeration"}
_INDEXED = re.compile(r"^(?P<base>[A-Za-z_][\w.]*)\[(?P<idx>\d+(?:,\d+)*)\]$")
_SAME = ("type", "causality", "variability", "initial", "unit", "min", "max", "declared_type")


def fmi3_groups(variables: list[Var]) -> list[tuple[str, list[Var], tuple]]:
    """The FMI 3.0 variables: (name, scalars, dimensions), in value-reference order.

    One rule: a run of consecutive scalars ``base[i]`` (or ``base[i,j]``) with the
    same base that fills a whole array in row-major order and agrees in type,
    causality, variability, initial, unit and bounds is one FMI 3.0 array (its value
    reference is its first scalar's); anything else stays a scalar."""
    out = []
    i = 0
    while i < len(variables):
        m = _INDEXED.match(variables[i].name)
        j = i + 1
        if m:
            while j < len(variables):
                mj = _INDEXED.match(variables[j].name)
                if not mj or mj["base"] != m["base"] or any(
                        getattr(variables[j], a) != getattr(variables[i], a) for a in _SAME):
                    break
                j += 1
            idx = [tuple(int(k) for k in _INDEXED.match(v.name)["idx"].split(",")) for v in variables[i:j]]
            dims = tuple(max(ix[d] for ix in idx) for d in range(len(idx[0])))
            full = list(itertools.product(*(range(d) for d in dims)))
            if [tuple(a - 1 for a in ix) for ix in idx] == full and j - i > 1:
                out.append((m["base"], variables[i:j], dims))
                i = j
                continue
            j = i + 1
        out.append((variables[i].name, [variables[i]], ()))
        i = j
    return out


def _fmt_value(v: Var, x) -> str:
    return fmt_real(x) if v.type == "Real" else str(int(x))


def model_description3(*, model_name: str, model_identifier: str, token: str, description: str,
                       generation_tool: str, variables: list[Var], default_experiment: dict,
                       log_categories: dict[str, str], time_vr: int) -> Element:
    """The complete <fmiModelDescription> element (FMI 3.0, co-simulation with
    early return and event mode); ``time_vr``: value reference of the independent
    variable ``time``."""
    root = _head("3.0", {"instantiationToken": token}, model_name, description, generation_tool, {
        "modelIdentifier": model_identifier,
        "needsExecutionTool": NEEDS_EXECUTION_TOOL,
        "canBeInstantiatedOnlyOncePerProcess": "false",
        "canGetAndSetFMUState": "true",
        "canSerializeFMUState": "true",
        "providesDirectionalDerivatives": "false",
        "providesAdjointDerivatives": "false",
        "canHandleVariableCommunicationStepSize": "true",
        "maxOutputDerivativeOrder": "0",
        "providesIntermediateUpdate": "false",
        "mightReturnEarlyFromDoStep": "true",
        "canReturnEarlyAfterIntermediateUpdate": "false",
        "hasEventMode": "true",
        "providesEvaluateDiscreteStates": "false",
    }, variables, log_categories, default_experiment)

    mv = SubElement(root, "ModelVariables")
    SubElement(mv, "Float64", name="time", valueReference=str(time_vr), causality="independent",
               variability="continuous", description="Simulation time")
    groups = fmi3_groups(variables)
    vr_of = {}
    for name, scalars, dims in groups:
        v = scalars[0]
        for s in scalars:
            vr_of[s.name] = v.value_reference
        desc = re.sub(r"\b1\b", "i", v.description) + f" (i = 1..{dims[0]})" if len(dims) == 1 else v.description
        attrs = {"name": name, "valueReference": str(v.value_reference), "description": desc,
                 "causality": v.causality, "variability": v.variability}
        if v.declared_type:
            attrs["declaredType"] = v.declared_type
        if v.initial is not None:
            attrs["initial"] = v.initial
        if v.unit and v.type == "Real":
            attrs["unit"] = v.unit
        if v.min is not None:
            attrs["min"] = _fmt_value(v, v.min)
        if v.max is not None:
            attrs["max"] = _fmt_value(v, v.max)
        if v.start is not None:
            attrs["start"] = " ".join(_fmt_value(s, s.start) for s in scalars)
        el = SubElement(mv, FMI3_TYPES[v.type], attrs)
        for d in dims:
            SubElement(el, "Dimension", start=str(d))

    ms = SubElement(root, "ModelStructure")
    heads = [scalars[0] for _, scalars, _ in groups]
    outputs = [v for v in heads if v.causality == "output"]
    for v in outputs:
        # no output depends directly on an input at the same communication point
        SubElement(ms, "Output", valueReference=str(v.value_reference), dependencies="")
    for v in outputs:
        if v.initial in ("approx", "calculated"):
            deps = sorted({vr_of[d] for d in v.initial_depends})
            SubElement(ms, "InitialUnknown", valueReference=str(v.value_reference),
                       dependencies=" ".join(map(str, deps)))
    return root
