"""Variable declarations and the FMI 2.0 modelDescription.xml of our slaves.

The FMU binary knows nothing of the interface: the slaves declare it here
(one :class:`Var` per scalar) and
build the whole model description themselves.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from xml.etree.ElementTree import Element, SubElement

__all__ = ["Var", "UNITS", "SCHEME_TYPE", "SCHEME_ITEMS", "model_description", "fmt_real",
           "POSITIVE_MIN"]

#: Smallest positive normal double: the inclusive FMI ``min`` of quantities that
#: must be strictly positive (m > 0, dt > 0).
POSITIVE_MIN = 2.2250738585072014e-308

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

SCHEME_TYPE = "fmu_sync.Scheme"
#: FMI enumeration items of solver.scheme: (name, value, description); the
#: name is the core's scheme name (fmu_sync.core.moreau.SCHEMES).
SCHEME_ITEMS = (
    ("midpoint", 1, "Moreau midpoint scheme, explicit in the smooth forces (stable for omega_max*dt < 2)"),
    ("theta", 2, "Moreau-Jean theta scheme, linear part (K, C) implicit"),
)


@dataclass
class Var:
    """One scalar variable of the FMU interface."""

    name: str
    type: str                    # "Real" | "Integer" | "Enumeration"
    causality: str               # "parameter" | "input" | "output"
    variability: str             # "fixed" | "continuous" | "discrete"
    description: str
    initial: str | None = None   # "exact" | "calculated" | None (inputs)
    unit: str | None = None
    min: float | None = None
    max: float | None = None
    start: object = None         # parameters and inputs
    declared_type: str | None = None
    #: outputs: names of the parameters/inputs their initial value depends on
    initial_depends: tuple = field(default_factory=tuple)
    value_reference: int = -1

    def check(self, value) -> str | None:
        """None if ``value`` is admissible for this variable, else the reason."""
        if self.type == "Enumeration":
            allowed = [v for _, v, _ in SCHEME_ITEMS]
            if value not in allowed:
                names = ", ".join(f"{v} ({n})" for n, v, _ in SCHEME_ITEMS)
                return f"{self.name} must be one of {names}, got {value!r}"
            return None
        if self.type == "Integer":
            if not isinstance(value, int):
                return f"{self.name} must be an integer, got {value!r}"
        else:
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                return f"{self.name} must be a real number, got {value!r}"
            if not math.isfinite(value):
                return f"{self.name} must be finite, got {value!r}"
        if self.min is not None and value < self.min:
            bound = "> 0" if self.min == POSITIVE_MIN else f">= {self.min:g}"
            return f"{self.name} ({self.description.split(';')[0]}) must be {bound}, got {value!r}"
        if self.max is not None and value > self.max:
            return f"{self.name} ({self.description.split(';')[0]}) must be <= {self.max:g}, got {value!r}"
        return None


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


def _type_definitions(root: Element) -> None:
    defs = SubElement(root, "TypeDefinitions")
    st = SubElement(defs, "SimpleType", name=SCHEME_TYPE,
                    description="Moreau time-stepping scheme of the internal steps")
    en = SubElement(st, "Enumeration")
    for name, value, desc in SCHEME_ITEMS:
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
        "canInterpolateInputs": "false",
        "maxOutputDerivativeOrder": "0",
        "canRunAsynchronuously": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false",
        "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": "true",
        "canSerializeFMUstate": "true",
        "providesDirectionalDerivative": "false",
    })
    _unit_definitions(root, {v.unit for v in variables if v.unit})
    _type_definitions(root)
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
            # No output depends directly on an input at the same communication
            # point (tau only acts through the next step): empty dependencies.
            SubElement(out, "Unknown", index=str(index[v.name]), dependencies="")
        init = SubElement(ms, "InitialUnknowns")
        for v in outputs:
            if v.initial in ("approx", "calculated"):
                deps = sorted(index[d] for d in v.initial_depends)
                SubElement(init, "Unknown", index=str(index[v.name]),
                           dependencies=" ".join(map(str, deps)))
    return root
