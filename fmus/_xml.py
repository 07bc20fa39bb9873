"""Variable declarations and the FMI 2.0 modelDescription.xml of our slaves.

The FMU binary knows nothing of the interface: the whole model description is
built here from the interface declared in :mod:`.contract` (one :class:`Var`
per scalar).
"""
from __future__ import annotations

import json
import uuid
from xml.etree.ElementTree import Element, SubElement

from .contract import ENUM_TYPES, POSITIVE_MIN, SCHEME_ITEMS, SCHEME_TYPE, Var

__all__ = ["Var", "UNITS", "SCHEME_TYPE", "SCHEME_ITEMS", "model_description", "fmt_real",
           "POSITIVE_MIN", "generation_tool", "model_guid"]

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


def generation_tool() -> str:
    from fmu_sync import __version__
    return f"fmu-sync {__version__} (own FMI 2.0 binary, Python slave)"


def model_guid(model: str, start_values: dict, code: str = "") -> str:
    """Deterministic GUID: changes with the model, the package version, the start
    values and the FMU's code (hash of the carried Python code and the C source)."""
    from fmu_sync import __version__
    key = json.dumps({"model": model, "version": __version__, "start": start_values, "code": code},
                     sort_keys=True)
    return "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, "https://fmu-sync/" + key)) + "}"


def fmt_real(x: float) -> str:
    """Shortest text that reads back as the same double."""
    return repr(float(x))


def _unit_definitions(root: Element, used: set[str]) -> None:
    defs = SubElement(root, "UnitDefinitions")
    for name, exps in UNITS.items():
        if name not in used:
            continue
        u = SubElement(defs, "Unit", name=name)
        SubElement(u, "BaseUnit", {k: str(v) for k, v in exps.items()})


def _type_definitions(root: Element, used: set[str]) -> None:
    defs = SubElement(root, "TypeDefinitions")
    for type_name, (description, items) in ENUM_TYPES.items():
        if type_name not in used:
            continue
        st = SubElement(defs, "SimpleType", name=type_name, description=description)
        en = SubElement(st, "Enumeration")
        for name, value, desc in items:
            SubElement(en, "Item", name=name, value=str(value), description=desc)


def model_description(*, model_name: str, model_identifier: str, guid: str, description: str,
                      generation_tool: str, variables: list[Var], default_experiment: dict,
                      log_categories: dict[str, str]) -> Element:
    """The complete <fmiModelDescription> element (FMI 2.0, co-simulation)."""
    root = Element("fmiModelDescription", {
        "fmiVersion": "2.0",
        "modelName": model_name,
        "guid": guid,
        "description": description,
        "generationTool": generation_tool,
        "variableNamingConvention": "structured",
    })
    SubElement(root, "CoSimulation", {
        "modelIdentifier": model_identifier,
        "needsExecutionTool": "false",
        "canHandleVariableCommunicationStepSize": "true",
        "canInterpolateInputs": "true",
        "maxOutputDerivativeOrder": "0",
        "canRunAsynchronuously": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false",
        "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "true",
        "canSerializeFMUstate": "true",
        "providesDirectionalDerivative": "false",
    })
    _unit_definitions(root, {v.unit for v in variables if v.unit})
    _type_definitions(root, {v.declared_type for v in variables if v.declared_type})
    cats = SubElement(root, "LogCategories")
    for name, desc in log_categories.items():
        SubElement(cats, "Category", name=name, description=desc)
    SubElement(root, "DefaultExperiment", {k: fmt_real(v) for k, v in default_experiment.items()})

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
