"""FMI 2.0 co-simulation slave over the core (SPEC §7): the Python half of the FMU.

The FMU's binary (``fmus/c/fmu_sync_fmi2.c``, the FMI glue, over
``fmus/c/fmu_sync_runtime.c``, the Python embedding) is the FMI ABI; this module is
what it runs in Python, carried inside the FMU (``resources/fmu_sync_code``):

* :class:`Slave` — what every FMU's slave shares, the coupling FMU's too: the
  interface (one :class:`~.contract.Var` per scalar, value reference = position),
  the model description, start values, the FMU state bytes;
* :class:`MechanicalSlave` — the one slave of every mechanical model: built on the
  model's entry of the FMU contract (``MechanicalSlave(contract.MODELS[key])``,
  :func:`slave`), which declares its variables and how its parameters make a core
  system; it validates a parameter set (a valid core ``MechanicalSystem``, a known
  scheme, g(q_start) >= 0, a scheme not known to diverge) and an FMU state.

The C-facing instance (arrays, layout, replies) is :mod:`.runtime`; the hot
path (one core ``advance`` per doStep, no Python) is :mod:`.stepper`.
Numerics: none here.
"""
from __future__ import annotations

import hashlib
import json
import math

import numpy as np

from ..core.checks import penetration_bound
from ..core.plan import plan_run
from ._xml import generation_tool, model_description, model_description3, model_guid, unit_exponents
from .contract import INPUT_BOUND, SCHEME_ITEMS, STATE_BOUND, FmuModel, Var, model

__all__ = ["Slave", "MechanicalSlave", "slave", "STATE_FORMAT", "START_FILE", "Configuration", "PHASES", "RUNNING_PHASES",
           "INPUT_BOUND", "generation_tool", "model_guid", "seal", "unseal", "unit_exponents"]

#: Name of the start-value file in the FMU's resources/ (written by fmu_sync.export).
START_FILE = "fmu_sync_start.json"
#: Tag of the serialised FMU state: the first line of the bytes is the tag and
#: the sha256 of the rest (JSON), so a damaged or altered state is refused
#: instead of being read as another valid state (:func:`seal`, :func:`unseal`).
STATE_FORMAT = "fmu-sync-state/4"
#: FMU phases as saved in a state (names) and their C codes (fmu_sync_constants.h: FSR_INSTANTIATED ...;
#: event mode: fmu_sync_fmi3.c's ST_EVENT = FSR_EVENT)
PHASES = {"instantiated": 1, "initialization": 2, "step": 4, "terminated": 8, "event": 16}
#: phases in which the instance runs a validated configuration (FMI 3.0 adds event mode)
RUNNING_PHASES = ("step", "terminated", "event")
_SCHEME_BY_VALUE = {value: name for name, value, _ in SCHEME_ITEMS}


def seal(payload: bytes) -> bytes:
    """Serialised state: ``<STATE_FORMAT> <sha256 of payload>\n<payload>``."""
    return f"{STATE_FORMAT} {hashlib.sha256(payload).hexdigest()}\n".encode() + payload


def unseal(data: bytes) -> bytes:
    """The payload of :func:`seal`'s bytes; ValueError if the header or checksum does not match."""
    head, sep, payload = bytes(data).partition(b"\n")
    tag, _, digest = head.partition(b" ")
    if not sep or tag != STATE_FORMAT.encode():
        raise ValueError(f"not an fmu-sync FMU state of format {STATE_FORMAT!r} (header {head[:40]!r})")
    if digest != hashlib.sha256(payload).hexdigest().encode():
        raise ValueError("checksum mismatch: the serialized state was damaged or altered (sha256 of its "
                         "content differs from the one in its header)")
    return payload


def _is_real(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


class Configuration:
    """A validated parameter set: the core system, solver data and the start state."""

    def __init__(self, system, dt, scheme_name, scheme, theta, q0, u0):
        self.system = system
        self.dt = dt
        self.scheme_name = scheme_name
        self.scheme = scheme          # the core's scheme code
        self.theta = theta
        self.q0 = q0
        self.u0 = u0


class Slave:
    """What the slave of every fmu-sync FMU shares (the mechanical models' and the coupling's):
    the interface, the model description, start values and FMU state bytes. A kind of model
    sets the attributes below in its constructor and gives :meth:`declare` and ``configure``."""

    #: export key (``fmu_sync.export.export_fmu(model=...)``)
    MODEL = ""
    #: FMI modelIdentifier (name of the binary)
    MODEL_IDENTIFIER = ""
    #: degrees of freedom
    N = 1
    #: most harmonic forcing terms a parameter set can make (sizes the work array)
    NF_MAX = 1
    #: parameters of the model's force law in the work array (0: the built-in linear law)
    N_P = 0
    DESCRIPTION = ""
    DEFAULT_EXPERIMENT = {"startTime": 0.0, "stopTime": 10.0, "stepSize": 1e-2}
    LOG_CATEGORIES = {
        "logStatusWarning": "Warnings (passed on with logging on)",
        "logStatusDiscard": "Why a doStep was refused or rolled back (always passed on)",
        "logStatusError": "Why a call was refused (always passed on)",
        "logStatusFatal": "Why the instance became unusable (always passed on)",
        "logAll": "Everything, including informational messages (with logging on)",
    }

    def declare(self) -> list[Var]:
        """The interface, in value-reference order (a fresh list on each call)."""
        raise NotImplementedError

    # ------------------------------------------------------------ interface
    def variables(self, start_values: dict | None = None) -> list[Var]:
        """The declared variables with value references and the given start values."""
        vars_ = self.declare()
        for vr, v in enumerate(vars_):
            v.value_reference = vr
        by_name = {v.name: v for v in vars_}
        for name, value in (start_values or {}).items():
            by_name[name].start = value
        return vars_

    def description(self, start_values: dict, guid: str, version: str, fmi_version: int = 2):
        """The complete <fmiModelDescription> element of an FMU with these start values
        (``version``: the exporting fmu-sync's; FMI 2.0, or FMI 3.0 with ``time`` after the
        last scalar's value reference)."""
        variables = self.variables(start_values)
        common = dict(model_name=self.MODEL_IDENTIFIER, model_identifier=self.MODEL_IDENTIFIER,
                      description=self.DESCRIPTION, generation_tool=generation_tool(version, fmi_version),
                      variables=variables, default_experiment=self.DEFAULT_EXPERIMENT,
                      log_categories=self.LOG_CATEGORIES)
        if fmi_version == 3:
            return model_description3(token=guid, time_vr=len(variables), **common)
        return model_description(guid=guid, **common)

    def variable_names(self) -> list[str]:
        return [v.name for v in self.declare()]

    def normalize_start_values(self, values: dict) -> dict:
        """Check start values (names, types, bounds) and return them in FMI form.

        Only parameters and inputs have start values. ``solver.scheme`` accepts
        the item name ("midpoint", "theta") or its value. Raises ValueError.
        """
        decl = {v.name: v for v in self.declare()}
        out = {}
        for name, value in values.items():
            v = decl.get(name)
            if v is None:
                raise ValueError(f"{self.MODEL_IDENTIFIER} has no variable {name!r}; "
                                 f"variables: {', '.join(decl)}")
            if v.causality not in ("parameter", "input"):
                raise ValueError(f"{name} is an {v.causality} (initial={v.initial}): it has no start value")
            if v.type == "Enumeration":
                if isinstance(value, str):
                    items = {n: val for n, val, _ in v.items}
                    if value.strip() in items:
                        value = items[value.strip()]
                    else:
                        try:
                            value = int(value)
                        except ValueError:
                            raise ValueError(f"{name} must be one of {', '.join(items)}, got {value!r}") from None
            elif isinstance(value, str):
                try:
                    value = float(value)
                except ValueError:
                    raise ValueError(f"{name} must be a real number, got {value!r}") from None
            if v.type == "Real" and _is_real(value):
                value = float(value)
            reason = v.check(value)
            if reason:
                raise ValueError(reason)
            out[name] = value
        return out

    def start_parameters(self, start_values: dict | None = None) -> dict:
        """Every parameter and input with its start value (the declared default
        unless ``start_values`` overrides it)."""
        out = {v.name: v.start for v in self.declare() if v.start is not None}
        out.update(start_values or {})
        return out

    # ------------------------------------------------------------ FMU state bytes
    @staticmethod
    def state_to_bytes(state: dict) -> bytes:
        # JSON under a checksummed header: floats are written with repr (shortest
        # round-trip text), so a deserialised state reproduces the run bit for bit.
        return seal(json.dumps(state, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8"))

    @staticmethod
    def state_from_bytes(data: bytes):
        state = json.loads(unseal(data).decode("utf-8"))
        if not isinstance(state, dict):
            raise ValueError(f"a JSON {type(state).__name__}, not an object")
        return state


class MechanicalSlave(Slave):
    """The slave of a mechanical model of the contract's registry: ``MechanicalSlave(model)``
    with ``model`` a :class:`~.contract.FmuModel` (its variables and how its parameters make
    a core system); the same class for every model."""

    def __init__(self, fmu_model: FmuModel):
        #: the model's entry in the FMU contract (fmu_sync.fmus.contract.MODELS)
        self.contract = fmu_model
        self.MODEL = fmu_model.key
        self.MODEL_IDENTIFIER = fmu_model.identifier
        self.N = fmu_model.n
        self.DESCRIPTION = fmu_model.description
        self.N_P = fmu_model.n_params
        self.NF_MAX = fmu_model.nf_max

    # ------------------------------------------------------------ model (from the contract)
    def declare(self) -> list[Var]:
        return self.contract.declare()

    def build_system(self, p: dict):
        """The core system for parameter values ``p`` (raises ValueError)."""
        return self.contract.system(p)

    def start_state(self, p: dict) -> tuple[list, list]:
        """(q_start, u_start) as lists of n floats."""
        return self.contract.start_state(p)

    # ------------------------------------------------------------ validation
    def configure(self, p: dict) -> Configuration:
        """Validate a complete parameter set; raises ValueError naming what is wrong."""
        system = self.build_system(p)
        if len(system.forcing) > self.NF_MAX:
            raise ValueError(f"the force law makes {len(system.forcing)} harmonic forcing terms at these parameters; "
                             f"this FMU holds at most {self.NF_MAX} (the number its declaration makes at the "
                             f"parameters' defaults)")
        scheme_name = _SCHEME_BY_VALUE.get(p["solver.scheme"])
        if scheme_name is None:
            raise ValueError(f"solver.scheme must be one of {sorted(_SCHEME_BY_VALUE)}, got {p['solver.scheme']!r}")
        if scheme_name == "exact" and self.N != 1:
            raise ValueError(f"solver.scheme = exact is offered by the 1-DOF model only (the exact "
                             f"communication step of the core, core.exact.exact_step); this model has "
                             f"{self.N} degrees of freedom: use midpoint or theta")
        # the run plan's single-system part (docs/design.md §5.1.1): the step, the scheme and its
        # limit (UnstableScheme), the start state (InadmissibleState); no end time, no record
        plan = plan_run(system, [self.start_state(p)], None, p["solver.dt"], scheme=scheme_name,
                        theta=p["solver.theta"], exact=True, step_name="solver.dt", state_names=["q_start"])
        if scheme_name == "exact":
            from .stepper import EXACT
            code, theta = EXACT, float(p["solver.theta"])
        else:
            code, theta = plan.code, plan.theta
        dt, q0, u0 = plan.dt, plan.q[0], plan.u[0]
        return Configuration(system, dt, scheme_name, int(code), float(theta), q0, u0)

    @staticmethod
    def penetration_bound(cfg: Configuration, q, u, tau) -> float:
        """How far below the wall (g < 0) a state the scheme produced can be.

        A Moreau step detects contact at its midpoint (or theta point) and moves
        by at most dt times the velocity along w, plus dt^2 times the
        acceleration along w:  |g| <= dt sqrt(W u^T M u) + dt^2 (|w^T M^-1 h| +
        sum_j |w^T M^-1 F_j|), h = f0 - K q - C u + B tau (sqrt(W u^T M u) bounds
        |w^T u| over the kinetic energy). Twice that is allowed: the one rule,
        :func:`fmu_sync.core.checks.penetration_bound`.
        """
        s = cfg.system
        a = s.arrays()
        q = np.asarray(q, dtype=np.float64)
        u = np.asarray(u, dtype=np.float64)
        if s.force is not None:   # a user force law: h itself (plain Python on the target)
            h = s.force.evaluate(q, u, tau, 0.0, s.p)
        else:
            h = a.f0 - a.K @ q - a.C @ u + a.B @ np.asarray(tau, dtype=np.float64)
        speed = math.sqrt(max(a.W * float(u @ a.M @ u), 0.0))
        acc = abs(float(a.Minv_w @ h)) + float(np.sum(np.abs(a.F @ a.Minv_w)))
        return penetration_bound(cfg.dt, speed, acc)

    def check_state(self, s, params: list[Var], inputs: list[Var]) -> tuple[str | None, Configuration | None]:
        """(reason, None) if ``s`` is not a valid saved state of this model, else (None, cfg)."""
        if not isinstance(s, dict):
            return f"not an FMU state of this slave ({type(s).__name__})", None
        if s.get("format") != STATE_FORMAT:
            return f"unknown state format {s.get('format')!r} (expected {STATE_FORMAT!r})", None
        if s.get("model") != self.MODEL:
            return f"state of model {s.get('model')!r}, this FMU is {self.MODEL!r}", None
        n, m = self.N, len(inputs)
        try:
            if s["phase"] not in PHASES:
                return f"bad phase {s['phase']!r} (one of {', '.join(PHASES)})", None
            for key, size in (("q", n), ("u", n), ("tau", m), ("taudot", m)):
                x = s[key]
                if (not isinstance(x, list) or len(x) != size
                        or not all(_is_real(a) and math.isfinite(a) for a in x)):
                    return f"{key} must be a list of {size} finite numbers, got {x!r}", None
            for key in ("q", "u"):
                if not all(abs(a) <= STATE_BOUND for a in s[key]):
                    return (f"{key} = {s[key]!r} out of range: |q| and |u| must be <= {STATE_BOUND:g} "
                            f"(the bound of q_start and u_start, contract.STATE_BOUND)"), None
            for key in ("time", "percussion", "vref"):
                if not (_is_real(s[key]) and math.isfinite(s[key])):
                    return f"{key} must be a finite number, got {s[key]!r}", None
            pend = s["pending"]
            if (not isinstance(pend, list) or len(pend) != 2 or not all(_is_real(a) and math.isfinite(a)
                                                                        for a in pend) or pend[1] < 0.0):
                return (f"pending must be [u after, percussion >= 0] of an impact held for event mode, "
                        f"got {pend!r}"), None
            for key in ("percussion", "vref"):
                if s[key] < 0.0:
                    return f"{key} must be >= 0, got {s[key]!r}", None
            if not isinstance(s["impacts"], int) or isinstance(s["impacts"], bool) or not 0 <= s["impacts"] < 2**53:
                return f"impacts must be a non-negative integer, got {s['impacts']!r}", None
            for v, x in zip(inputs, s["tau"]):
                r = v.check(x)
                if r:
                    return f"input {r}", None
            p = s["parameters"]
            names = {v.name for v in params}
            if not isinstance(p, dict) or set(p) != names:
                return "parameters do not match this FMU's parameters", None
            for v in params:
                r = v.check(p[v.name])
                if r:
                    return f"parameter {r}", None
        except KeyError as exc:
            return f"missing entry {exc}", None
        try:
            cfg = self.configure(p)
        except ValueError as exc:
            return f"its parameters are invalid: {exc}", None
        g = cfg.system.gap(s["q"])
        bound = self.penetration_bound(cfg, s["q"], s["u"], s["tau"])
        if not g >= -bound:
            return (f"q = {s['q']!r} is inside the wall: g(q) = {g:.6g} is below the scheme's penetration "
                    f"bound -{bound:.3g} (2 (dt sqrt(W u^T M u) + dt^2 |w^T M^-1 h|) for solver.dt = "
                    f"{cfg.dt:g})"), None
        return None, cfg


def slave(key: str) -> MechanicalSlave:
    """The slave of the registered mechanical model ``key`` (ValueError names the registered ones)."""
    return MechanicalSlave(model(key))
