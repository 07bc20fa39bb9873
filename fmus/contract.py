"""The FMU contract: what an fmu-sync FMU looks like, in one place (docs/design.md §4.2).

Everything that crosses the FMI boundary is named here and nowhere else:

* the variable names: ``q``/``q[i]``, ``u``/``u[i]``, ``tau``/``tau[i]``,
  ``q_start``, ``u_start``, the parameters (``m``, ``M[i,j]``, ``w[i]``, ``g0``,
  ``e``, ...), the solver parameters ``solver.*`` and the outputs
  (``gap``, ``impacts``, ``percussion``, ``energy``);
* the model registry (:data:`MODELS`): export key, FMI model identifier,
  degrees of freedom and the full declaration (:class:`Var` list) of each model;
* the conversion between a core :class:`~fmu_sync.core.MechanicalSystem` (plus
  start state and solver settings) and the FMU's parameter/start values, both
  ways, and the geometry (M, w, g0, e) an importer reads back from an FMU.

The one slave of every model (:class:`.slave.MechanicalSlave`, built on an
:class:`FmuModel`), the export (:mod:`fmu_sync.export`), the
master (:mod:`fmu_sync.master`) and the scenes all go through this module. It
imports nothing but the standard library, numpy and the core, so that it can
travel inside an FMU together with ``core/``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..core.declaration import DEFAULT_UNITS, POSITIVE_MIN, Model, ModelError, Param
from ..core.model import IMPACT_OSCILLATOR, MECHANICAL_SYSTEM, MechanicalSystem
from ..core.moreau import MIDPOINT, SCHEMES, THETA, TRAPEZOID
from ..core.steps import DEFAULT_SCHEME

__all__ = ["Var", "FmuModel", "ContractError", "MODELS", "POSITIVE_MIN", "INPUT_BOUND", "STATE_BOUND",
           "SCHEME_TYPE", "SCHEME_ITEMS", "SCHEME_EXACT", "LAW_TYPE", "LAW_ITEMS", "ENUM_TYPES",
           "SOLVER_DT", "SOLVER_SCHEME", "SOLVER_THETA", "GAP", "IMPACTS", "PERCUSSION", "ENERGY",
           "model", "model_for", "identify", "declared", "DECLARED", "identifier_of", "indexed", "scheme_value",
           "scheme_name"]

# ---------------------------------------------------------------- names
SOLVER_DT, SOLVER_SCHEME, SOLVER_THETA = "solver.dt", "solver.scheme", "solver.theta"
GAP, IMPACTS, PERCUSSION, ENERGY = "gap", "impacts", "percussion", "energy"

#: Inputs must lie in [-INPUT_BOUND, INPUT_BOUND] (the min/max of every input in
#: modelDescription.xml; the FMU's binary refuses other values at fmi2SetReal).
#: Larger forces are far outside any mechanical model and overflow the energy.
INPUT_BOUND = 1e12
#: Positions and velocities must lie in [-STATE_BOUND, STATE_BOUND]: the bounds of
#: q_start and u_start, of q and u in an FMU state (fmi2SetFMUstate,
#: fmi2DeSerializeFMUstate) and of the state a doStep reaches (else rolled back).
STATE_BOUND = 1e12

SCHEME_TYPE = "fmu_sync.Scheme"
#: The one numbering of the schemes: the core's Moreau codes (core.moreau: MIDPOINT,
#: THETA, TRAPEZOID = 3, the default) and the exact communication step (2). The FMU's enumeration values,
#: the stepper's dispatch and the binary's constants (generated at export) are these.
SCHEME_EXACT = 2
#: FMI enumeration items of solver.scheme: (name, value, description); the
#: name is the core's scheme name (fmu_sync.core.moreau.SCHEMES).
SCHEME_ITEMS = (
    ("midpoint", MIDPOINT, "Moreau midpoint scheme, explicit in the smooth forces (stable for omega_max*dt < 2)"),
    ("theta", THETA, "Moreau-Jean theta scheme, linear part (K, C) implicit"),
    ("exact", SCHEME_EXACT, "Exact communication step (1-DOF only): closed-form flow, impacts, completed "
                            "accumulations and persistent contact, tau constant over the step; solver.dt unused"),
    ("trapezoid", TRAPEZOID, "Moreau-Jean theta = 1/2 (second order between impacts; the default, as in the "
                             "core): under the master's implicit exchange the coupling inside the step"),
)
assert sorted(v for _, v, _ in SCHEME_ITEMS) == list(range(len(SCHEME_ITEMS))), "one numbering, 0..n-1"


LAW_TYPE = "fmu_sync.Law"
#: FMI enumeration items of the coupling FMU's law[e]: the core's law names and codes
#: (fmu_sync.core.coupling.LAWS), so that the value is the code the kernels take.
LAW_ITEMS = (
    ("switching", 0, "Switching quotient coupling (forces from the quotient distance and its chain ends)"),
    ("euclidean", 1, "Euclidean PD coupling tau_i = -Kp (q_i - q_j) - Kd (u_i - u_j)"),
    ("none", 2, "No force on this edge (d, V and the Euclidean error are still computed)"),
    ("switching-compensated", 3, "Compensated switching law (1-DOF; V non-increasing on every branch): "
                                 "evaluates the systems' force law h, the parameters k[i] .. phi[i]"),
)
#: declared enumeration types: name -> (description, items)
ENUM_TYPES = {
    SCHEME_TYPE: ("Solver of a communication step (Moreau schemes or the exact 1-DOF step)", SCHEME_ITEMS),
    LAW_TYPE: ("Coupling law of an edge", LAW_ITEMS),
}


def indexed(base: str, n: int) -> list[str]:
    """Names of the n components of ``base``: ``[base]`` for n = 1, else ``base[1]..base[n]``."""
    return [base] if n == 1 else [f"{base}[{i + 1}]" for i in range(n)]


def matrix(base: str, n: int) -> list[str]:
    """Names of an n x n matrix parameter, row by row: ``M[1,1], M[1,2], ...``."""
    return [f"{base}[{i + 1},{j + 1}]" for i in range(n) for j in range(n)]


def scheme_value(name: str) -> int:
    """FMI enumeration value of a scheme name (ValueError names the allowed ones)."""
    for item, value, _ in SCHEME_ITEMS:
        if item == name:
            return value
    raise ValueError(f"{SOLVER_SCHEME} has no scheme {name!r} (it offers "
                     f"{', '.join(n for n, _, _ in SCHEME_ITEMS)})")


def scheme_name(value) -> str | None:
    """Scheme name of an FMI enumeration value (None if unknown)."""
    for item, v, _ in SCHEME_ITEMS:
        if v == value:
            return item
    return None


class ContractError(ValueError):
    """An FMU or a set of values does not follow the fmu-sync FMU contract."""


# ---------------------------------------------------------------- declarations
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
    #: outputs: names of the inputs they depend on directly (ModelStructure/Outputs)
    depends: tuple = field(default_factory=tuple)
    value_reference: int = -1

    @property
    def items(self) -> tuple:
        """(name, value, description) of an Enumeration's declared type (() otherwise)."""
        return ENUM_TYPES[self.declared_type][1] if self.type == "Enumeration" else ()

    def check(self, value) -> str | None:
        """None if ``value`` is admissible for this variable, else the reason."""
        if self.type == "Enumeration":
            allowed = [v for _, v, _ in self.items]
            if value not in allowed:
                names = ", ".join(f"{v} ({n})" for n, v, _ in self.items)
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


def _param(name, unit, description, start, min=None, max=None):
    return Var(name, "Real", "parameter", "fixed", description, initial="exact", unit=unit,
               min=min, max=max, start=start)


def _solver_variables(dt: float = 1e-3) -> list[Var]:
    """solver.dt, solver.scheme, solver.theta (shared by all models)."""
    return [
        _param(SOLVER_DT, "s", "Internal Moreau step; the last internal step of a "
               "communication step is shortened to land on the communication point (> 0)",
               dt, min=POSITIVE_MIN),
        Var(SOLVER_SCHEME, "Enumeration", "parameter", "fixed",
            "Solver of a communication step: Moreau trapezoid (theta = 1/2, the default), midpoint or theta "
            "with internal step solver.dt, or exact (1-DOF model only)",
            initial="exact", start=SCHEMES[DEFAULT_SCHEME], declared_type=SCHEME_TYPE),
        _param(SOLVER_THETA, "1", "Theta of the Moreau-Jean scheme (used when solver.scheme = theta)",
               0.5, min=0.5, max=1.0),
    ]


def _inputs(n: int, unit: str = "N") -> list[Var]:
    if n == 1:
        return [Var("tau", "Real", "input", "continuous", "Control force (held over each communication step)",
                    unit=unit, start=0.0, min=-INPUT_BOUND, max=INPUT_BOUND)]
    return [Var(name, "Real", "input", "continuous",
                f"Control force on coordinate {i + 1} (B = I; held over each communication step)",
                unit=unit, start=0.0, min=-INPUT_BOUND, max=INPUT_BOUND) for i, name in enumerate(indexed("tau", n))]


_ENERGY = "Mechanical energy 1/2 u^T M u + 1/2 q^T K q - f0^T q (without forcing and input)"
_ENERGY_LAW = ("Energy 1/2 u^T M u + 1/2 q^T K_L q of the force law's declared linear part K_L (the rest of "
               "h(q, u, tau, t, p) has no declared potential: not conserved in general)")


def _outputs(n: int, depends: dict, energy: str = _ENERGY, units: dict | None = None) -> list[Var]:
    """Outputs q, u, gap, impacts, percussion, energy (q[i], u[i] for n > 1), in the model's
    ``units`` (:attr:`fmu_sync.core.Model.units`; the gap in q's)."""
    units = units or DEFAULT_UNITS
    out = []
    for i, name in enumerate(indexed("q", n)):
        out.append(Var(name, "Real", "output", "continuous",
                       "Generalized position" + ("" if n == 1 else f" {i + 1}"), initial="calculated",
                       unit=units["q"], initial_depends=tuple(depends[name])))
    for i, name in enumerate(indexed("u", n)):
        out.append(Var(name, "Real", "output", "continuous",
                       "Generalized velocity" + ("" if n == 1 else f" {i + 1}")
                       + " (right limit after an impact)", initial="calculated",
                       unit=units["u"], initial_depends=tuple(depends[name])))
    out += [
        Var(GAP, "Real", "output", "continuous",
            "Gap g(q) = w^T q + g0 to the wall (>= 0 up to the scheme's O(dt) penetration)",
            initial="calculated", unit=units["q"], initial_depends=tuple(depends[GAP])),
        Var(IMPACTS, "Integer", "output", "discrete",
            "Number of internal steps with a positive contact percussion since the start",
            initial="calculated", min=0),
        Var(PERCUSSION, "Real", "output", "discrete",
            "Contact percussion (impulse) summed over the last communication step",
            initial="calculated", unit=f"{units['tau']}.s", min=0.0),
        Var(ENERGY, "Real", "output", "continuous",
            energy, initial="calculated", unit="J", initial_depends=tuple(depends[ENERGY])),
    ]
    return out


# ---------------------------------------------------------------- the registry
def _model_params(decl: Model, n: int, start: dict) -> list[Var]:
    """The FMU parameters of a model declaration with n degrees of freedom (docs/design.md §4.2):
    a number as itself, a vector as ``name[i]``, a matrix as ``name[i,j]`` (min/max on the
    diagonal), harmonic terms as the one term ``F[i]``, ``Omega``, ``phi``. Start values:
    ``start``, else the declared default."""
    out = []
    for p in decl.params:
        v = start.get(p.name, p.default)
        if p.shape == ():
            out.append(_param(p.name, p.unit, p.description, v, min=p.min, max=p.max))
        elif p.shape == ("n",):
            v = [0.0] * n if v is None else v
            out += [_param(x, p.unit, f"{p.description}, component {i + 1}" if n > 1 else p.description, v[i],
                           min=p.min, max=p.max) for i, x in enumerate(indexed(p.name, n))]
        elif p.shape == ("n", "n"):
            v = [[0.0] * n] * n if v is None else v
            out += [_param(f"{p.name}[{i + 1},{j + 1}]", p.unit, f"{p.description}, row {i + 1}, column {j + 1}",
                           v[i][j], min=p.min if i == j else None, max=p.max if i == j else None)
                    for i in range(n) for j in range(n)]
        else:   # ("terms",): the FMU takes one harmonic term
            F, Om, ph = v[0] if v else ([0.0] * n, 0.0, 0.0)
            out += [_param(x, "N", f"{_HARMONIC}, component {i + 1}" if n > 1 else _HARMONIC, F[i])
                    for i, x in enumerate(indexed("F", n))]
            out += [_param("Omega", "rad/s", "Angular frequency of the harmonic force", Om, min=0.0),
                    _param("phi", "rad", "Phase of the harmonic force", ph)]
    return out


_HARMONIC = "Amplitude of the harmonic force F cos(Omega t + phi)"


def _flat_names(p: Param, n: int) -> list[str]:
    """The FMU variable names of a declared parameter."""
    if p.shape == ():
        return [p.name]
    if p.shape == ("n",):
        return indexed(p.name, n)
    if p.shape == ("n", "n"):
        return matrix(p.name, n)
    return indexed("F", n) + ["Omega", "phi"]


@dataclass(frozen=True)
class FmuModel:
    """One model of the registry: the FMU of a model declaration (:class:`~fmu_sync.core.Model`,
    docs/design.md §2.1.1) with n degrees of freedom. The one slave of every model
    (:class:`.slave.MechanicalSlave`) and the instance behind the binary are generic and take
    everything model-specific from it, and it takes everything from the declaration.

    :meth:`declare` returns the interface (a fresh :class:`Var` list, in value-reference
    order); :meth:`system` builds the core system from parameter values; :meth:`values` is the
    inverse; :attr:`geometry` names the parameters from which an importer rebuilds M, w, g0, e.
    ``start`` holds the FMU's start values where they differ from the declared defaults (the
    FMU runs as exported); ``energy_params`` the parameters the energy output depends on.
    """

    key: str                 # export key (fmu_sync.export_fmu(model=...))
    identifier: str          # FMI modelIdentifier
    n: int
    description: str
    declaration: Model
    start: dict = field(default_factory=dict)
    energy_params: tuple = ()
    q_start_default: tuple = (1.0,)

    @property
    def n_params(self) -> int:
        """Number of parameters of the declaration's force law (0: the built-in linear law)."""
        law = self.declaration.force
        return 0 if law is None else len(law.params)

    @property
    def nf_max(self) -> int:
        """Most harmonic forcing terms the FMU's work array holds: one for the built-in linear
        law; a force law's declared forcing (``ForceLaw(forcing=...)``) counted at its parameters'
        defaults (a required parameter counted as 0.0)."""
        law = self.declaration.force
        if law is None or law.forcing is None:
            return 1
        p = np.array([0.0 if q.default is None else float(q.default) for q in law.params], dtype=np.float64)
        return max(1, len(law.forcing_terms(p)))

    @property
    def family(self) -> str:
        """The scenes' ``system.model``: the declaration's name."""
        return self.declaration.name

    # names of the state and input variables
    @property
    def q(self) -> list[str]:
        return indexed("q", self.n)

    @property
    def u(self) -> list[str]:
        return indexed("u", self.n)

    @property
    def tau(self) -> list[str]:
        return indexed("tau", self.n)

    @property
    def q_start(self) -> list[str]:
        return indexed("q_start", self.n)

    @property
    def u_start(self) -> list[str]:
        return indexed("u_start", self.n)

    def _names(self, params) -> list[str]:
        return [x for name in params for x in _flat_names(self.declaration.param(name), self.n)]

    @property
    def geometry(self) -> tuple:
        """The FMU parameters of the declaration's impact geometry (M, w, g0, e)."""
        return tuple(self._names(self.declaration.geometry))

    def declare(self) -> list[Var]:
        """inputs, outputs, the declaration's parameters, q_start, u_start, solver.*"""
        n, qs, us = self.n, self.q_start, self.u_start
        wall = [x for x in ("w", "g0") if x in self.declaration.names]
        depends = {**{q: [s] for q, s in zip(self.q + self.u, qs + us)},
                   GAP: self._names(wall) + qs, ENERGY: self._names(self.energy_params) + qs + us}
        suffix = (lambda i: "") if n == 1 else (lambda i: f", component {i + 1}")
        units = self.declaration.units
        states = ([_param(x, units["q"], "Initial position (g(q_start) >= 0)" + suffix(i), self.q_start_default[i],
                          min=-STATE_BOUND, max=STATE_BOUND) for i, x in enumerate(qs)]
                  + [_param(x, units["u"], "Initial velocity" + suffix(i), 0.0, min=-STATE_BOUND, max=STATE_BOUND)
                     for i, x in enumerate(us)])
        energy = _ENERGY if self.declaration.force is None else _ENERGY_LAW
        return (_inputs(n, units["tau"]) + _outputs(n, depends, energy, units) + _model_params(self.declaration, n, self.start)
                + states + _solver_variables())

    def _declared(self, values: dict, names) -> dict:
        out = {}
        for name in names:
            p = self.declaration.param(name)
            flat = _flat_names(p, self.n)
            if p.shape == ():
                out[name] = values[name]
            elif p.shape == ("n",):
                out[name] = [values[x] for x in flat]
            elif p.shape == ("n", "n"):
                out[name] = [[values[flat[i * self.n + j]] for j in range(self.n)] for i in range(self.n)]
            else:
                F = [values[x] for x in flat[:self.n]]
                out[name] = ((F, values["Omega"], values["phi"]),) if any(x != 0.0 for x in F) else ()
        return out

    def system(self, values: dict) -> MechanicalSystem:
        """The core system of the FMU's parameter values (the declaration checks and builds it)."""
        return self.declaration(self._declared(values, self.declaration.names))

    def values(self, system: MechanicalSystem) -> dict:
        """The FMU's parameter values of a core system (ContractError if it cannot hold it)."""
        if system.n != self.n:
            raise ContractError(f"the {self.key} FMU has {self.n} degree{'s' if self.n > 1 else ''} of "
                                f"freedom, the system has {system.n}")
        law = getattr(system, "force", None)
        if law is not None and law is not self.declaration.force:
            raise ContractError(f"the system has the force law {getattr(law, 'name', law)!r}, the {self.key} FMU "
                                f"{'the built-in linear law' if self.declaration.force is None else 'another'}: "
                                f"export the system's own model declaration (docs/user-model.md)")
        if self.declaration.values is None:
            raise ContractError(f"model {self.declaration.name!r} gives no parameter values of a system (its "
                                f"declaration has no inverse): set the FMU's declared parameters "
                                f"({', '.join(self.declaration.names)}) themselves")
        try:
            declared = self.declaration.values(system)
        except ModelError as exc:
            raise ContractError(str(exc)) from None
        return self.flat(declared)

    def flat(self, declared: dict) -> dict:
        """The FMU's parameter values of declared values (name -> value as the declaration takes
        it, e.g. a scene's ``[system]`` keys): a vector as ``name[i]``, a matrix as ``name[i,j]``."""
        out = {}
        for p in self.declaration.params:
            if p.name not in declared:
                continue
            v = declared[p.name]
            if v is None and p.shape in (("n",), ("n", "n")):   # a declared vector/matrix left out: zeros
                v = np.zeros((self.n,) * len(p.shape))
            if p.shape == ():
                out[p.name] = float(v)
            elif p.shape == ("n",):
                out.update(zip(indexed(p.name, self.n), (float(x) for x in v)))
            elif p.shape == ("n", "n"):
                out.update(zip(matrix(p.name, self.n), (float(x) for r in v for x in r)))
            else:
                if len(v) > 1:
                    raise ContractError(f"the FMU takes one forcing term, the system has {len(v)}")
                F, Om, ph = v[0] if v else ([0.0] * self.n, 0.0, 0.0)
                out.update(zip(indexed("F", self.n), (float(x) for x in F)))
                out.update(Omega=float(Om), phi=float(ph))
        return out

    def required(self) -> list[str]:
        """What an importer (the master) needs from an FMU of this model."""
        return self.q + self.u + self.tau + self.q_start + self.u_start + [IMPACTS] + list(self.geometry)

    def start_state(self, values: dict) -> tuple[list, list]:
        """(q_start, u_start) as lists of n floats, from parameter values."""
        return [values[k] for k in self.q_start], [values[k] for k in self.u_start]

    def state_values(self, q, u) -> dict:
        """Start values q_start/u_start of a state (q, u)."""
        return dict(zip(self.q_start + self.u_start, [float(x) for x in q] + [float(x) for x in u]))

    def solver_values(self, dt: float, scheme: str = DEFAULT_SCHEME, theta: float | None = None) -> dict:
        """Start values of solver.dt, solver.scheme (and solver.theta for the theta scheme)."""
        out = {SOLVER_DT: float(dt), SOLVER_SCHEME: scheme_value(scheme)}
        if scheme == "theta":
            out[SOLVER_THETA] = float(theta)
        return out

    def geometry_system(self, values: dict) -> MechanicalSystem:
        """M, w, g0, e from the values of :attr:`geometry`, every other parameter at its declared
        default (the distance and the coupling need only the geometry)."""
        missing = [k for k in self.geometry if k not in values]
        if missing:
            raise ContractError(f"{self.identifier}: missing geometry values {', '.join(missing)}")
        return self.declaration(self._declared(values, self.declaration.geometry))


#: The model registry: export key -> :class:`FmuModel`. Start values: the 1-DOF FMU runs the
#: forced-pair scene's system 1, the 2-DOF FMU the two-dof scene's system 1 (our own choices).
MODELS: dict[str, FmuModel] = {m.key: m for m in (
    FmuModel(
        key="impact-oscillator", identifier="ImpactOscillator", n=1,
        description=IMPACT_OSCILLATOR.description + "; Moreau time-stepping (fmu-sync core)",
        declaration=IMPACT_OSCILLATOR, start=dict(k=1.0, f0=0.2, F=0.5, Omega=2.5, e=0.9),
        energy_params=("m", "k", "f0")),
    FmuModel(
        key="mechanical-system-2", identifier="MechanicalSystem2", n=2,
        description=("2-DOF mechanical system M q'' + C q' + K q = f0 + F cos(Omega t + phi) + tau "
                     "with the unilateral constraint w^T q + g0 >= 0 and Newton restitution e; "
                     "Moreau time-stepping (fmu-sync core)"),
        declaration=MECHANICAL_SYSTEM,
        start=dict(M=((2.0, 0.5), (0.5, 1.0)), K=((3.0, -1.0), (-1.0, 2.0)), C=((0.02, 0.0), (0.0, 0.02)),
                   f0=(0.1, 0.2), forcing=(((0.6, 0.0), 1.3, 0.0),), w=(1.0, 0.5), e=0.7),
        energy_params=("M", "K", "f0"), q_start_default=(0.6, 0.2)),
)}


#: FMUs of model declarations with a force law (the built-in pendulum and Duffing, a user's model
#: file): export key -> FmuModel, registered by :func:`declared` (at export, in a master that reads
#: such an FMU, and by the carried code of the FMU itself: the build's generated runtime module)
DECLARED: dict[str, FmuModel] = {}


def identifier_of(name: str) -> str:
    """The FMI modelIdentifier of a declaration's name: "my-pendulum" -> "MyPendulum" (a C name)."""
    parts = [p for p in "".join(c if c.isalnum() else " " for c in name).split() if p]
    ident = "".join(p[:1].upper() + p[1:] for p in parts)
    if not ident or not ident.isascii() or not ident[0].isalpha():
        raise ContractError(f"model name {name!r} gives no C identifier for the FMU (start it with an ASCII "
                            f"letter)")
    return ident


def declared(decl: Model, key: str | None = None) -> FmuModel:
    """The FMU of a model declaration with a force law (docs/user-model.md "Export"), registered
    under ``key`` (default the declaration's name): its declared parameters are the FMU's, with
    their units and ranges; the default start state is the point on the wall's normal at gap 1
    of the default system (q_start = w (1 - g0) / |w|^2)."""
    key = key or decl.name
    if decl.force is None:
        raise ContractError(f"model {decl.name!r} has no force law: its FMU is a registered model "
                            f"({', '.join(MODELS)})")
    if key in MODELS:
        raise ContractError(f"model key {key!r} is a registered built-in model")
    if decl.n is None:
        raise ContractError(f"model {decl.name!r} does not fix its degrees of freedom (Model(n=...))")
    try:
        s = decl()
    except ValueError as exc:
        raise ContractError(f"model {decl.name!r}: its declared defaults make no system: {exc}") from None
    q0 = s.w * (1.0 - s.g0) / float(s.w @ s.w)
    fm = FmuModel(key=key, identifier=identifier_of(decl.name), n=int(decl.n),
                  description=f"{decl.description}; force law {decl.force.name!r}; Moreau time-stepping "
                              f"(fmu-sync core)",
                  declaration=decl, energy_params=decl.names, q_start_default=tuple(float(x) for x in q0))
    DECLARED[key] = fm
    return fm


def model(key: str) -> FmuModel:
    """The registered model of an export key (ValueError names the registered ones)."""
    if key in DECLARED:
        return DECLARED[key]
    if key not in MODELS:
        raise ValueError(f"unknown model {key!r}; choose one of {', '.join([*MODELS, *DECLARED])}")
    return MODELS[key]


def model_for(family: str, n: int) -> FmuModel | None:
    """The registered model of a scene's ``system.model`` with n degrees of freedom (None if none)."""
    for m in MODELS.values():
        if m.family == family and m.n == n:
            return m
    return None


def identify(variables, model_name: str = "", key: str | None = None) -> FmuModel:
    """The registered model whose interface an FMU with these variable names offers.

    ``key``: the export key the FMU's build record names (``fmu_sync.user_export.built_key``); the
    model registered under it is the FMU's when it offers that interface. Two declarations of one
    interface (the same model in two files of a session: their variables and identifier agree)
    are told apart only so. Raises :class:`ContractError` naming the variables the FMU lacks (for
    the closest registered model) when it is not an fmu-sync mechanical model.
    """
    names = set(variables)
    own = (DECLARED.get(key) or MODELS.get(key)) if key is not None else None
    if own is not None and all(k in names for k in own.required()):
        return own
    best, best_missing = None, None
    for m in [*MODELS.values(), *DECLARED.values()]:
        missing = [k for k in m.required() if k not in names]
        if not missing and (best is None or best_missing or m.identifier == model_name):
            best, best_missing = m, missing
        elif best is None or (best_missing and len(missing) < len(best_missing)):
            best, best_missing = m, missing
    if best_missing:
        raise ContractError(
            f"FMU {model_name!r} is not an fmu-sync mechanical model: it lacks the variables "
            f"{', '.join(best_missing)} (closest registered model: {best.key}, which needs "
            f"{', '.join(best.required())})")
    return best
