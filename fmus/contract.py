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

from ..core.model import MechanicalSystem
from ..core.moreau import MIDPOINT, THETA

__all__ = ["Var", "FmuModel", "ContractError", "MODELS", "POSITIVE_MIN", "INPUT_BOUND", "STATE_BOUND",
           "SCHEME_TYPE", "SCHEME_ITEMS", "SCHEME_EXACT", "LAW_TYPE", "LAW_ITEMS", "ENUM_TYPES",
           "SOLVER_DT", "SOLVER_SCHEME", "SOLVER_THETA", "GAP", "IMPACTS", "PERCUSSION", "ENERGY",
           "model", "model_for", "identify", "indexed", "scheme_value", "scheme_name"]

# ---------------------------------------------------------------- names
SOLVER_DT, SOLVER_SCHEME, SOLVER_THETA = "solver.dt", "solver.scheme", "solver.theta"
GAP, IMPACTS, PERCUSSION, ENERGY = "gap", "impacts", "percussion", "energy"

#: Smallest positive normal double: the inclusive FMI ``min`` of quantities that
#: must be strictly positive (m > 0, dt > 0).
POSITIVE_MIN = 2.2250738585072014e-308
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
#: THETA) and the exact communication step after them. The FMU's enumeration values,
#: the stepper's dispatch and the binary's constants (generated at export) are these.
SCHEME_EXACT = 2
#: FMI enumeration items of solver.scheme: (name, value, description); the
#: name is the core's scheme name (fmu_sync.core.moreau.SCHEMES).
SCHEME_ITEMS = (
    ("midpoint", MIDPOINT, "Moreau midpoint scheme, explicit in the smooth forces (stable for omega_max*dt < 2)"),
    ("theta", THETA, "Moreau-Jean theta scheme, linear part (K, C) implicit"),
    ("exact", SCHEME_EXACT, "Exact communication step (1-DOF only): closed-form flow, impacts, completed "
                            "accumulations and persistent contact, tau constant over the step; solver.dt unused"),
)
assert sorted(v for _, v, _ in SCHEME_ITEMS) == list(range(len(SCHEME_ITEMS))), "one numbering, 0..n-1"


LAW_TYPE = "fmu_sync.Law"
#: FMI enumeration items of the coupling FMU's law[e]: the core's law names and codes
#: (fmu_sync.core.coupling.LAWS), so that the value is the code the kernels take.
LAW_ITEMS = (
    ("switching", 0, "Switching quotient coupling (forces from the quotient distance and its chain ends)"),
    ("euclidean", 1, "Euclidean PD coupling tau_i = -Kp (q_i - q_j) - Kd (u_i - u_j)"),
    ("none", 2, "No force on this edge (d, V and the Euclidean error are still computed)"),
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
            "Solver of a communication step: Moreau midpoint or theta with internal step solver.dt, "
            "or exact (1-DOF model only)",
            initial="exact", start=MIDPOINT, declared_type=SCHEME_TYPE),
        _param(SOLVER_THETA, "1", "Theta of the Moreau-Jean scheme (used when solver.scheme = theta)",
               0.5, min=0.5, max=1.0),
    ]


def _inputs(n: int) -> list[Var]:
    if n == 1:
        return [Var("tau", "Real", "input", "continuous", "Control force (held over each communication step)",
                    unit="N", start=0.0, min=-INPUT_BOUND, max=INPUT_BOUND)]
    return [Var(name, "Real", "input", "continuous",
                f"Control force on coordinate {i + 1} (B = I; held over each communication step)",
                unit="N", start=0.0, min=-INPUT_BOUND, max=INPUT_BOUND) for i, name in enumerate(indexed("tau", n))]


def _outputs(n: int, depends: dict) -> list[Var]:
    """Outputs q, u, gap, impacts, percussion, energy (q[i], u[i] for n > 1)."""
    out = []
    for i, name in enumerate(indexed("q", n)):
        out.append(Var(name, "Real", "output", "continuous",
                       "Generalized position" + ("" if n == 1 else f" {i + 1}"), initial="calculated",
                       unit="m", initial_depends=tuple(depends[name])))
    for i, name in enumerate(indexed("u", n)):
        out.append(Var(name, "Real", "output", "continuous",
                       "Generalized velocity" + ("" if n == 1 else f" {i + 1}")
                       + " (right limit after an impact)", initial="calculated",
                       unit="m/s", initial_depends=tuple(depends[name])))
    out += [
        Var(GAP, "Real", "output", "continuous",
            "Gap g(q) = w^T q + g0 to the wall (>= 0 up to the scheme's O(dt) penetration)",
            initial="calculated", unit="m", initial_depends=tuple(depends[GAP])),
        Var(IMPACTS, "Integer", "output", "discrete",
            "Number of internal steps with a positive contact percussion since the start",
            initial="calculated", min=0),
        Var(PERCUSSION, "Real", "output", "discrete",
            "Contact percussion (impulse) summed over the last communication step",
            initial="calculated", unit="N.s", min=0.0),
        Var(ENERGY, "Real", "output", "continuous",
            "Mechanical energy 1/2 u^T M u + 1/2 q^T K q - f0^T q (without forcing and input)",
            initial="calculated", unit="J", initial_depends=tuple(depends[ENERGY])),
    ]
    return out


# ---------------------------------------------------------------- the registry
@dataclass(frozen=True)
class FmuModel:
    """One model of the registry: its FMU interface and its link to the core (the one
    model object: :class:`.slave.MechanicalSlave` and the instance behind the binary are
    generic and take everything model-specific from it).

    ``declare()`` returns the interface (a fresh :class:`Var` list, in
    value-reference order); ``system(values)`` builds the core system from
    parameter values; ``values(system)`` is the inverse; ``geometry`` names the
    parameters from which an importer rebuilds M, w, g0 and e.
    """

    key: str                 # export key (fmu_sync.export_fmu(model=...))
    identifier: str          # FMI modelIdentifier
    family: str              # the scenes' system.model
    n: int
    description: str
    declare: Callable[[], list]
    system: Callable[[dict], MechanicalSystem]
    values: Callable[[MechanicalSystem], dict]
    geometry: tuple
    _geometry_system: Callable[[dict], MechanicalSystem] = field(repr=False, default=None)

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

    def required(self) -> list[str]:
        """What an importer (the master) needs from an FMU of this model."""
        return self.q + self.u + self.tau + self.q_start + self.u_start + [IMPACTS] + list(self.geometry)

    def start_state(self, values: dict) -> tuple[list, list]:
        """(q_start, u_start) as lists of n floats, from parameter values."""
        return [values[k] for k in self.q_start], [values[k] for k in self.u_start]

    def state_values(self, q, u) -> dict:
        """Start values q_start/u_start of a state (q, u)."""
        return dict(zip(self.q_start + self.u_start, [float(x) for x in q] + [float(x) for x in u]))

    def solver_values(self, dt: float, scheme: str = "midpoint", theta: float | None = None) -> dict:
        """Start values of solver.dt, solver.scheme (and solver.theta for the theta scheme)."""
        out = {SOLVER_DT: float(dt), SOLVER_SCHEME: scheme_value(scheme)}
        if scheme == "theta":
            out[SOLVER_THETA] = float(theta)
        return out

    def geometry_system(self, values: dict) -> MechanicalSystem:
        """M, w, g0, e from the values of :attr:`geometry` (K = C = f0 = 0: the
        distance and the coupling need only the geometry)."""
        missing = [k for k in self.geometry if k not in values]
        if missing:
            raise ContractError(f"{self.identifier}: missing geometry values {', '.join(missing)}")
        return self._geometry_system(values)


def _io_system(p: dict) -> MechanicalSystem:
    from ..core.model import ImpactOscillator
    return ImpactOscillator(m=p["m"], k=p["k"], c=p["c"], f0=p["f0"], F=p["F"],
                            Omega=p["Omega"], e=p["e"], phi=p["phi"], g0=p["g0"])


def _forcing_values(system: MechanicalSystem, n: int) -> tuple:
    if len(system.forcing) > 1:
        raise ContractError(f"the FMU takes one forcing term, the system has {len(system.forcing)}")
    if system.forcing:
        F, Om, ph = system.forcing[0]
        return [float(x) for x in F], float(Om), float(ph)
    return [0.0] * n, None, None


def _io_values(s: MechanicalSystem) -> dict:
    if s.n != 1:
        raise ContractError(f"the impact-oscillator FMU has 1 degree of freedom, the system has {s.n}")
    if float(s.w[0]) != 1.0:
        raise ContractError(f"the impact-oscillator FMU has the wall g(q) = q + g0 (w = 1), "
                            f"the system has w = {s.w.tolist()}")
    F, Om, ph = _forcing_values(s, 1)
    out = {"m": float(s.M[0, 0]), "k": float(s.K[0, 0]), "c": float(s.C[0, 0]),
           "f0": float(s.f0[0]), "F": F[0]}
    if Om is not None:
        out.update(Omega=Om, phi=ph)
    out["e"] = float(s.e)
    out["g0"] = float(s.g0)
    return out


def _io_geometry(p: dict) -> MechanicalSystem:
    z = np.zeros((1, 1))
    return MechanicalSystem(M=[[p["m"]]], K=z, C=z, f0=np.zeros(1), w=np.ones(1), g0=p["g0"], e=p["e"])


# 1-DOF impact oscillator (ImpactOscillator): m q'' + c q' + k q = f0 + F cos(Omega t + phi) + tau,
# g(q) = q + g0 >= 0 (wall at q = -g0), Newton restitution e. Defaults: scenes/forced-pair.toml,
# system 1 (g0 = 0).
def _io_declare() -> list[Var]:
    outputs = _outputs(1, {
        "q": ["q_start"], "u": ["u_start"], GAP: ["g0", "q_start"],
        ENERGY: ["m", "k", "f0", "q_start", "u_start"],
    })
    params = [
        _param("m", "kg", "Mass (> 0)", 1.0, min=POSITIVE_MIN),
        _param("k", "N/m", "Spring stiffness", 1.0, min=0.0),
        _param("c", "N.s/m", "Viscous damping", 0.0, min=0.0),
        _param("f0", "N", "Constant force", 0.2),
        _param("F", "N", "Amplitude of the harmonic force F cos(Omega t + phi)", 0.5),
        _param("Omega", "rad/s", "Angular frequency of the harmonic force", 2.5, min=0.0),
        _param("phi", "rad", "Phase of the harmonic force", 0.0),
        _param("e", "1", "Newton restitution coefficient at the wall", 0.9, min=0.0, max=1.0),
        _param("g0", "m", "Wall offset g0 in g(q) = q + g0 (the wall stands at q = -g0)", 0.0),
        _param("q_start", "m", "Initial position (g(q_start) = q_start + g0 >= 0)", 1.0, min=-STATE_BOUND,
               max=STATE_BOUND),
        _param("u_start", "m/s", "Initial velocity", 0.0, min=-STATE_BOUND, max=STATE_BOUND),
    ]
    return _inputs(1) + outputs + params + _solver_variables()


# 2-DOF defaults: scenes/two-dof.toml, system 1 (the project's own choice)
_N2 = 2
_M2 = ((2.0, 0.5), (0.5, 1.0))
_K2 = ((3.0, -1.0), (-1.0, 2.0))
_C2 = ((0.02, 0.0), (0.0, 0.02))


def _matrix_params(sym, unit, what, values, diag_min, n=_N2):
    return [_param(f"{sym}[{i + 1},{j + 1}]", unit, f"{what}, row {i + 1}, column {j + 1}",
                   values[i][j], min=diag_min if i == j else None) for i in range(n) for j in range(n)]


def _vector_params(sym, unit, what, values, min=None, n=_N2, max=None):
    return [_param(f"{sym}[{i + 1}]", unit, f"{what}, component {i + 1}", values[i], min=min, max=max)
            for i in range(n)]


def _ms2_declare() -> list[Var]:
    n = _N2
    qs, us = indexed("q_start", n), indexed("u_start", n)
    outputs = _outputs(n, {
        "q[1]": ["q_start[1]"], "q[2]": ["q_start[2]"],
        "u[1]": ["u_start[1]"], "u[2]": ["u_start[2]"],
        GAP: indexed("w", n) + ["g0"] + qs,
        ENERGY: matrix("M", n) + matrix("K", n) + indexed("f0", n) + qs + us,
    })
    params = (
        _matrix_params("M", "kg", "Mass matrix (symmetric positive definite)", _M2, POSITIVE_MIN)
        + _matrix_params("K", "N/m", "Stiffness matrix", _K2, 0.0)
        + _matrix_params("C", "N.s/m", "Damping matrix", _C2, 0.0)
        + _vector_params("f0", "N", "Constant force", (0.1, 0.2))
        + _vector_params("F", "N", "Amplitude of the harmonic force F cos(Omega t + phi)", (0.6, 0.0))
        + [_param("Omega", "rad/s", "Angular frequency of the harmonic force", 1.3, min=0.0),
           _param("phi", "rad", "Phase of the harmonic force", 0.0)]
        + _vector_params("w", "1", "Wall normal w in g(q) = w^T q + g0 (not zero)", (1.0, 0.5))
        + [_param("g0", "m", "Wall offset g0 in g(q) = w^T q + g0", 0.0),
           _param("e", "1", "Newton restitution coefficient at the wall", 0.7, min=0.0, max=1.0)]
        + _vector_params("q_start", "m", "Initial position (g(q_start) >= 0)", (0.6, 0.2),
                         min=-STATE_BOUND, max=STATE_BOUND)
        + _vector_params("u_start", "m/s", "Initial velocity", (0.0, 0.0), min=-STATE_BOUND, max=STATE_BOUND)
    )
    return _inputs(n) + outputs + params + _solver_variables()


def _mat(p: dict, sym: str, n: int):
    names = matrix(sym, n)
    return [[p[names[i * n + j]] for j in range(n)] for i in range(n)]


def _vec(p: dict, sym: str, n: int):
    return [p[k] for k in indexed(sym, n)]


def _ms2_system(p: dict) -> MechanicalSystem:
    n = _N2
    F = _vec(p, "F", n)
    forcing = ((F, p["Omega"], p["phi"]),) if any(x != 0.0 for x in F) else ()
    return MechanicalSystem(M=_mat(p, "M", n), K=_mat(p, "K", n), C=_mat(p, "C", n), f0=_vec(p, "f0", n),
                            w=_vec(p, "w", n), g0=p["g0"], e=p["e"], forcing=forcing)


def _ms2_values(s: MechanicalSystem) -> dict:
    n = _N2
    if s.n != n:
        raise ContractError(f"the mechanical-system-2 FMU has {n} degrees of freedom, the system has {s.n}")
    out = {}
    for sym, a in (("M", s.M), ("K", s.K), ("C", s.C)):
        out.update(zip(matrix(sym, n), (float(x) for x in a.reshape(-1))))
    for sym, a in (("f0", s.f0), ("w", s.w)):
        out.update(zip(indexed(sym, n), (float(x) for x in a)))
    out["g0"] = float(s.g0)
    out["e"] = float(s.e)
    F, Om, ph = _forcing_values(s, n)
    out.update(zip(indexed("F", n), F))
    out.update(Omega=0.0 if Om is None else Om, phi=0.0 if ph is None else ph)
    return out


def _ms2_geometry(p: dict) -> MechanicalSystem:
    n = _N2
    z = np.zeros((n, n))
    return MechanicalSystem(M=_mat(p, "M", n), K=z, C=z, f0=np.zeros(n), w=_vec(p, "w", n),
                            g0=p["g0"], e=p["e"])


#: The model registry: export key -> :class:`FmuModel`.
MODELS: dict[str, FmuModel] = {m.key: m for m in (
    FmuModel(
        key="impact-oscillator", identifier="ImpactOscillator", family="impact-oscillator", n=1,
        description=("1-DOF impact oscillator m q'' + c q' + k q = f0 + F cos(Omega t + phi) + tau, "
                     "q + g0 >= 0, Newton restitution e; Moreau time-stepping (fmu-sync core)"),
        declare=_io_declare, system=_io_system, values=_io_values, geometry=("m", "g0", "e"),
        _geometry_system=_io_geometry),
    FmuModel(
        key="mechanical-system-2", identifier="MechanicalSystem2", family="mechanical-system", n=_N2,
        description=("2-DOF mechanical system M q'' + C q' + K q = f0 + F cos(Omega t + phi) + tau "
                     "with the unilateral constraint w^T q + g0 >= 0 and Newton restitution e; "
                     "Moreau time-stepping (fmu-sync core)"),
        declare=_ms2_declare, system=_ms2_system, values=_ms2_values,
        geometry=tuple(matrix("M", _N2) + indexed("w", _N2) + ["g0", "e"]),
        _geometry_system=_ms2_geometry),
)}


def model(key: str) -> FmuModel:
    """The registered model of an export key (ValueError names the registered ones)."""
    if key not in MODELS:
        raise ValueError(f"unknown model {key!r}; choose one of {', '.join(MODELS)}")
    return MODELS[key]


def model_for(family: str, n: int) -> FmuModel | None:
    """The registered model of a scene's ``system.model`` with n degrees of freedom (None if none)."""
    for m in MODELS.values():
        if m.family == family and m.n == n:
            return m
    return None


def identify(variables, model_name: str = "") -> FmuModel:
    """The registered model whose interface an FMU with these variable names offers.

    Raises :class:`ContractError` naming the variables the FMU lacks (for the
    closest registered model) when it is not an fmu-sync mechanical model.
    """
    names = set(variables)
    best, best_missing = None, None
    for m in MODELS.values():
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
