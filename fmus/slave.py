"""FMI 2.0 co-simulation slave over the core (docs/design.md §4.3), written with pythonfmu.

:class:`MechanicalSlave` holds everything the two FMUs share; a model class
(:mod:`.impact_oscillator`, :mod:`.mechanical_system2`) only names its entry
of the FMU contract (:mod:`.contract`), which declares its variables and how its
parameters make a :class:`fmu_sync.core.MechanicalSystem`.

Numerics: none here. ``do_step`` makes exactly one call to the compiled
:func:`fmu_sync.core.moreau.advance` (all internal steps of the communication
step, input held), and the outputs gap and energy are the core's
``MechanicalSystem.gap`` / ``.energy``.

Errors: pythonfmu 0.7.0 turns *any* Python exception into fmi2Fatal and then
double-frees the instance at fmi2FreeInstance, and the only other status a
Python slave can return is fmi2Discard from ``do_step`` (``return False``).
So no method called by the export library ever raises. A bad call is logged
at once with status fmi2Error (reaches the importer when logging is on) and:

* a rejected value (NaN/inf input, parameter out of bounds) is not stored and
  stays flagged until a valid value is set: every doStep returns fmi2Discard;
* an inconsistent configuration found at fmi2ExitInitializationMode
  (``MechanicalSystem`` rejects the data, g(q_start) < 0, bad dt/theta) is
  flagged the same way (fmi2Reset or a new instance start over);
* a call in the wrong state, an unknown value reference or a bad FMU state is
  refused and makes the *next* doStep return fmi2Discard once;
* a negative / non-finite step or a communication point that is not the
  slave's time makes that doStep return fmi2Discard;
* a diverged step (the core reports a non-finite state) is rolled back: the
  state stays the last valid one and doStep returns fmi2Discard.

A refused doStep changes nothing, so the data already produced stays valid.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from pythonfmu import Fmi2Slave
from pythonfmu import Integer as _PfInteger
from pythonfmu import Real as _PfReal
from pythonfmu.enums import Fmi2Causality, Fmi2Initial, Fmi2Status, Fmi2Variability

from fmu_sync.core.moreau import OK as _OK
from fmu_sync.core.moreau import advance
from fmu_sync.core.checks import check_stable, check_step, divergence_message, scheme_code
from fmu_sync.core.errors import SimulationDiverged

from . import _export_lib
from ._xml import SCHEME_ITEMS, Var, generation_tool, model_description, model_guid

__all__ = ["MechanicalSlave", "STATE_FORMAT", "START_FILE", "INSTANTIATED", "INITIALIZATION",
           "STEP", "TERMINATED"]

#: Name of the start-value file in the FMU's resources/ (written by fmu_sync.export).
START_FILE = "fmu_sync_start.json"
#: Tag of the serialised FMU state (JSON).
STATE_FORMAT = "fmu-sync-state/1"

INSTANTIATED, INITIALIZATION, STEP, TERMINATED = 0, 1, 2, 3
_PHASE_NAMES = {INSTANTIATED: "instantiated", INITIALIZATION: "initialization mode",
                STEP: "step mode", TERMINATED: "terminated"}
_INF = math.inf
_NAN = math.nan
_SCHEME_BY_VALUE = {value: name for name, value, _ in SCHEME_ITEMS}
_MODEL_KEY = "<configuration>"


def _is_real(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


class MechanicalSlave(Fmi2Slave):
    """Common part of the fmu-sync co-simulation slaves (not an FMU by itself)."""

    #: export key (``fmu_sync.export.export_fmu(model=...)``)
    MODEL = ""
    #: FMI modelIdentifier: the class name of the FMU's entry-point script
    MODEL_IDENTIFIER = ""
    #: module name of the FMU's entry-point script (unique per model: pythonfmu
    #: puts resources/ first on sys.path and caches modules by name)
    MODULE_NAME = ""
    #: degrees of freedom
    N = 1
    DESCRIPTION = ""
    DEFAULT_EXPERIMENT = {"startTime": 0.0, "stopTime": 10.0, "stepSize": 1e-2}

    #: the model's entry in the FMU contract (fmu_sync.fmus.contract.MODELS)
    CONTRACT = None

    # ------------------------------------------------------------ model (from the contract)
    @classmethod
    def declare(cls) -> list[Var]:
        """The interface, in value-reference order (a fresh list on each call)."""
        return cls.CONTRACT.declare()

    def build_system(self, p: dict):
        """The core system for parameter values ``p`` (raises ValueError)."""
        return self.CONTRACT.system(p)

    def start_state(self, p: dict) -> tuple[list, list]:
        """(q_start, u_start) as lists of n floats."""
        return self.CONTRACT.start_state(p)

    # ------------------------------------------------------------ set-up
    def __init__(self, **kwargs):
        start_values = kwargs.pop("start_values", None)
        super().__init__(**kwargs)
        self.modelName = self.MODEL_IDENTIFIER
        self.description = self.DESCRIPTION
        _export_lib.register_export_library(self.resources, self.MODEL_IDENTIFIER)

        self._phase = INSTANTIATED
        self._bad: dict[str, str] = {}     # flagged conditions (refuse every doStep)
        self._pending: list[str] = []      # refused calls (refuse the next doStep once)
        self._time = 0.0

        if start_values is None:
            start_values = self._read_start_file()
        self._vars = self.declare()
        self._by_name = {v.name: v for v in self._vars}
        self.start_values = self.normalize_start_values(start_values or {})
        for name, value in self.start_values.items():
            self._by_name[name].start = value

        self._params = [v for v in self._vars if v.causality == "parameter"]
        self._inputs = [v for v in self._vars if v.causality == "input"]
        self._p = {v.name: v.start for v in self._params}
        self._tau = np.array([float(v.start) for v in self._inputs], dtype=np.float64)
        q0, u0 = self.start_state(self._p)
        self._q = np.array(q0, dtype=np.float64)
        self._u = np.array(u0, dtype=np.float64)
        self._impacts = 0
        self._percussion = 0.0
        self._system = None       # MechanicalSystem for self._p, None if unknown or invalid
        self._system_error = None
        self._sa = None
        self._dt = float(self._p["solver.dt"])
        self._scheme = 0
        self._theta = 0.5

        self._real_get: list = []
        self._real_set: list = []
        self._int_get: list = []
        self._int_set: list = []
        for vr, v in enumerate(self._vars):
            getter, setter = self._accessors(v)
            is_int = v.type in ("Integer", "Enumeration")
            self._real_get.append(None if is_int else getter)
            self._real_set.append(None if is_int else setter)
            self._int_get.append(getter if is_int else None)
            self._int_set.append(setter if is_int else None)
            cls = _PfInteger if is_int else _PfReal
            pv = cls(v.name, causality=Fmi2Causality[v.causality],
                     variability=Fmi2Variability[v.variability],
                     initial=Fmi2Initial[v.initial] if v.initial else None,
                     description=v.description, getter=getter, setter=setter)
            self.register_variable(pv, nested=False)
            v.value_reference = pv.value_reference
            assert v.value_reference == vr

    def _read_start_file(self) -> dict:
        if not self.resources:
            return {}
        path = Path(str(self.resources).replace("file://", "", 1)) / START_FILE
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            return {}
        except Exception as exc:
            self._error(f"cannot read the start values {path}: {exc}", pending=False)
            self._bad[START_FILE] = f"unreadable start-value file {path}"
            return {}
        if data.get("model") != self.MODEL:
            self._bad[START_FILE] = (f"{path} holds start values of model {data.get('model')!r}, "
                                     f"not {self.MODEL!r}")
            self._error(self._bad[START_FILE], pending=False)
            return {}
        return data.get("start", {})

    @classmethod
    def variable_names(cls) -> list[str]:
        return [v.name for v in cls.declare()]

    @classmethod
    def normalize_start_values(cls, values: dict) -> dict:
        """Check start values (names, types, bounds) and return them in FMI form.

        Only parameters and inputs have start values. ``solver.scheme`` accepts
        the item name ("midpoint", "theta") or its value. Raises ValueError.
        """
        decl = {v.name: v for v in cls.declare()}
        out = {}
        for name, value in values.items():
            v = decl.get(name)
            if v is None:
                raise ValueError(f"{cls.MODEL_IDENTIFIER} has no variable {name!r}; "
                                 f"variables: {', '.join(decl)}")
            if v.causality not in ("parameter", "input"):
                raise ValueError(f"{name} is an {v.causality} (initial={v.initial}): it has no start value")
            if v.type == "Enumeration":
                if isinstance(value, str):
                    items = {n: val for n, val, _ in SCHEME_ITEMS}
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

    # ------------------------------------------------------------ accessors
    def _accessors(self, v: Var):
        name = v.name
        if v.causality == "input":
            i = self._inputs_index(name)
            tau = self._tau
            isfinite = math.isfinite

            def set_input(x, i=i, name=name):
                if self._phase == TERMINATED:
                    return self._refuse(f"cannot set input {name} after fmi2Terminate")
                if isfinite(x):
                    tau[i] = x
                    if self._bad:
                        self._bad.pop(name, None)
                else:
                    msg = (f"input {name} = {x!r} rejected: must be finite; doStep is refused "
                           f"until a finite value is set")
                    self._bad[name] = msg
                    self._error(msg, pending=False)

            return (lambda i=i: float(tau[i])), set_input
        if v.causality == "parameter":
            def set_param(x, v=v):
                if self._phase not in (INSTANTIATED, INITIALIZATION):
                    return self._refuse(
                        f"cannot set parameter {v.name} in {_PHASE_NAMES[self._phase]} "
                        f"(variability fixed: only before fmi2ExitInitializationMode)")
                reason = v.check(x)
                if reason:
                    msg = f"parameter {reason}; value rejected"
                    self._bad[v.name] = msg
                    self._error(msg, pending=False)
                    return
                self._bad.pop(v.name, None)
                self._p[v.name] = float(x) if v.type == "Real" else int(x)
                self._system = None
                self._system_error = None
                q0, u0 = self.start_state(self._p)
                self._q[:] = q0
                self._u[:] = u0

            return (lambda name=name: self._p[name]), set_param
        # outputs
        getter = self._output_getter(name)

        def set_output(x, name=name):
            self._refuse(f"{name} is an output: it cannot be set")

        return getter, set_output

    def _inputs_index(self, name: str) -> int:
        return [v.name for v in self._vars if v.causality == "input"].index(name)

    def _output_getter(self, name: str):
        n = self.N
        if n == 1 and name in ("q", "u"):
            arr = self._q if name == "q" else self._u
            return lambda: float(arr[0])
        if name.startswith(("q[", "u[")):
            arr = self._q if name[0] == "q" else self._u
            i = int(name[2:-1]) - 1
            return lambda: float(arr[i])
        if name == "gap":
            return self._gap
        if name == "energy":
            return self._energy
        if name == "impacts":
            return lambda: self._impacts
        if name == "percussion":
            return lambda: self._percussion
        raise KeyError(name)  # pragma: no cover - declaration error

    def _current_system(self):
        if self._system is None and self._system_error is None:
            try:
                self._system = self.build_system(self._p)
            except ValueError as exc:
                self._system_error = str(exc)
        return self._system

    def _gap(self) -> float:
        s = self._current_system()
        return _NAN if s is None else s.gap(self._q)

    def _energy(self) -> float:
        s = self._current_system()
        return _NAN if s is None else s.energy(self._q, self._u)

    # ------------------------------------------------------------ logging
    def _log(self, status: Fmi2Status, msg: str) -> None:
        # pythonfmu hands the message to the importer's printf-style logger.
        self.log(str(msg).replace("%", "%%"), status)

    def _error(self, msg: str, pending: bool = True) -> None:
        self._log(Fmi2Status.error, msg)
        if pending:
            self._pending.append(msg)

    def _refuse(self, msg: str) -> None:
        """A refused call: logged now, the next doStep returns fmi2Discard."""
        self._error(msg, pending=True)

    # ------------------------------------------------------------ get / set
    def get_real(self, vrs):
        try:
            g = self._real_get
            return [g[vr]() for vr in vrs]
        except Exception:
            return self._get_checked(vrs, "Real")

    def get_integer(self, vrs):
        try:
            g = self._int_get
            return [g[vr]() for vr in vrs]
        except Exception:
            return self._get_checked(vrs, "Integer")

    def set_real(self, vrs, values):
        try:
            s = self._real_set
            for vr, x in zip(vrs, values):
                s[vr](x)
        except Exception:
            self._set_checked(vrs, values, "Real")

    def set_integer(self, vrs, values):
        try:
            s = self._int_set
            for vr, x in zip(vrs, values):
                s[vr](x)
        except Exception:
            self._set_checked(vrs, values, "Integer")

    def get_boolean(self, vrs):
        self._refuse(f"fmi2GetBoolean: {self.MODEL_IDENTIFIER} has no Boolean variables (value references {list(vrs)})")
        return [False] * len(vrs)

    def get_string(self, vrs):
        self._refuse(f"fmi2GetString: {self.MODEL_IDENTIFIER} has no String variables (value references {list(vrs)})")
        return [""] * len(vrs)

    def set_boolean(self, vrs, values):
        self._refuse(f"fmi2SetBoolean: {self.MODEL_IDENTIFIER} has no Boolean variables (value references {list(vrs)})")

    def set_string(self, vrs, values):
        self._refuse(f"fmi2SetString: {self.MODEL_IDENTIFIER} has no String variables (value references {list(vrs)})")

    def _lookup(self, vr, kind: str, table: list, fn: str):
        if not isinstance(vr, int) or not 0 <= vr < len(self._vars):
            self._refuse(f"fmi2{fn}{kind}: unknown value reference {vr!r} "
                         f"(valid: 0..{len(self._vars) - 1})")
            return None
        f = table[vr]
        if f is None:
            v = self._vars[vr]
            self._refuse(f"fmi2{fn}{kind}: value reference {vr} is {v.name}, "
                         f"of type {v.type}{' (use fmi2' + fn + 'Integer)' if v.type == 'Enumeration' else ''}")
        return f

    def _get_checked(self, vrs, kind: str):
        table = self._real_get if kind == "Real" else self._int_get
        bad = _NAN if kind == "Real" else 0
        out = []
        for vr in vrs:
            try:
                f = self._lookup(vr, kind, table, "Get")
                out.append(bad if f is None else f())
            except Exception as exc:  # pragma: no cover - defensive
                self._refuse(f"fmi2Get{kind}({vr}): internal error {exc!r}")
                out.append(bad)
        return out

    def _set_checked(self, vrs, values, kind: str):
        table = self._real_set if kind == "Real" else self._int_set
        for vr, x in zip(vrs, values):
            try:
                f = self._lookup(vr, kind, table, "Set")
                if f is not None:
                    f(x)
            except Exception as exc:  # pragma: no cover - defensive
                self._refuse(f"fmi2Set{kind}({vr}): internal error {exc!r}")

    # ------------------------------------------------------------ life cycle
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        try:
            if self._phase != INSTANTIATED:
                return self._refuse(f"fmi2SetupExperiment called in {_PHASE_NAMES[self._phase]}")
            t = float(start_time)
            if not math.isfinite(t):
                msg = f"start time {start_time!r} rejected: must be finite"
                self._bad["startTime"] = msg
                return self._error(msg, pending=False)
            self._bad.pop("startTime", None)
            self._time = t
        except Exception as exc:  # pragma: no cover - defensive
            self._refuse(f"fmi2SetupExperiment: internal error {exc!r}")

    def enter_initialization_mode(self):
        try:
            if self._phase != INSTANTIATED:
                return self._refuse(f"fmi2EnterInitializationMode called in {_PHASE_NAMES[self._phase]}")
            self._phase = INITIALIZATION
        except Exception as exc:  # pragma: no cover - defensive
            self._refuse(f"fmi2EnterInitializationMode: internal error {exc!r}")

    def exit_initialization_mode(self):
        try:
            if self._phase != INITIALIZATION:
                return self._refuse(f"fmi2ExitInitializationMode called in {_PHASE_NAMES[self._phase]}")
            self._configure(reset_state=True)
            self._phase = STEP
        except Exception as exc:  # pragma: no cover - defensive
            self._bad[_MODEL_KEY] = f"internal error at fmi2ExitInitializationMode: {exc!r}"
            self._error(self._bad[_MODEL_KEY], pending=False)
            self._phase = STEP

    def terminate(self):
        try:
            if self._phase not in (INITIALIZATION, STEP):
                return self._refuse(f"fmi2Terminate called in {_PHASE_NAMES[self._phase]}")
            self._phase = TERMINATED
        except Exception as exc:  # pragma: no cover - defensive
            self._refuse(f"fmi2Terminate: internal error {exc!r}")

    def _configure(self, reset_state: bool) -> bool:
        """Validate the parameters and build the system; flag what is wrong."""
        self._bad.pop(_MODEL_KEY, None)
        self._system = None
        self._system_error = None
        self._sa = None
        p = self._p
        try:
            system = self.build_system(p)
            dt = check_step(p["solver.dt"], "solver.dt")
            scheme_name = _SCHEME_BY_VALUE.get(p["solver.scheme"])
            if scheme_name is None:
                raise ValueError(f"solver.scheme must be one of {sorted(_SCHEME_BY_VALUE)}, got {p['solver.scheme']!r}")
            code, theta = scheme_code(scheme_name, p["solver.theta"])
            try:
                check_stable(system, scheme_name, dt)
            except SimulationDiverged as exc:  # known before the run: a configuration error
                raise ValueError(str(exc)) from None
            q0, u0 = self.start_state(p)
            g = system.gap(q0)
            if not g >= 0.0:
                raise ValueError(f"initial state violates the constraint: g(q_start) = {g:.6g} < 0 "
                                 f"(need g(q_start) >= 0)")
        except ValueError as exc:
            self._system_error = str(exc)
            self._bad[_MODEL_KEY] = f"invalid configuration: {exc}; doStep is refused"
            self._error(self._bad[_MODEL_KEY], pending=False)
            return False
        self._system = system
        self._sa = system.arrays()
        self._dt = dt
        self._scheme = int(code)
        self._theta = float(theta)
        if reset_state:
            self._q[:] = q0
            self._u[:] = u0
            self._impacts = 0
            self._percussion = 0.0
        return True

    # ------------------------------------------------------------ doStep
    def do_step(self, current_time, step_size):
        try:
            t = self._time
            if (self._phase != STEP or self._pending or self._bad
                    or not (0.0 < step_size < _INF)
                    or not (abs(current_time - t) <= 1e-9 * (1.0 if abs(t) < 1.0 else abs(t)))):
                return self._refuse_step(current_time, step_size)
            q = self._q
            u = self._u
            q_prev = q.tolist()
            u_prev = u.tolist()
            status, psum, hits = advance(self._sa, q, u, current_time, step_size, self._dt,
                                         self._tau, self._scheme, self._theta)
            if status != _OK:
                q[:] = q_prev
                u[:] = u_prev
                scheme = _SCHEME_BY_VALUE.get(self._p["solver.scheme"], "?")
                self._log(Fmi2Status.discard, divergence_message(
                    self._system, scheme, self._dt, current_time,
                    what=f"the state (step [{current_time:.9g}, {current_time + step_size:.9g}])")
                    + " The step was rolled back.")
                return False
            self._time = current_time + step_size
            self._impacts += hits
            self._percussion = psum
            return True
        except Exception as exc:
            try:
                self._log(Fmi2Status.error, f"doStep at t = {current_time!r}: internal error {exc!r}")
            except Exception:  # pragma: no cover
                pass
            return False

    def _refuse_step(self, current_time, step_size) -> bool:
        t = self._time
        if self._phase != STEP:
            why = (f"doStep called in {_PHASE_NAMES[self._phase]}"
                   + (" (call fmi2ExitInitializationMode first)" if self._phase < STEP else ""))
        elif self._pending:
            why = "an earlier call failed: " + " | ".join(self._pending)
            self._pending = []
        elif self._bad:
            why = " | ".join(self._bad.values())
        elif not (0.0 < step_size < _INF):
            why = f"communication step size {step_size!r} rejected: must be finite and > 0"
        else:
            why = (f"currentCommunicationPoint = {current_time!r} is not the slave's time {t!r} "
                   f"(restore a saved FMU state to go back in time)")
        self._log(Fmi2Status.discard, f"doStep(t = {current_time!r}, h = {step_size!r}) refused, "
                                      f"state unchanged at t = {t!r}: {why}")
        return False

    # ------------------------------------------------------------ FMU state
    def _get_fmu_state(self):
        try:
            return {
                "format": STATE_FORMAT,
                "model": self.MODEL,
                "phase": self._phase,
                "time": self._time,
                "q": self._q.tolist(),
                "u": self._u.tolist(),
                "tau": self._tau.tolist(),
                "impacts": self._impacts,
                "percussion": self._percussion,
                "parameters": dict(self._p),
                "flagged": dict(self._bad),
                "pending": list(self._pending),
            }
        except Exception as exc:  # pragma: no cover - defensive
            return {"format": "invalid", "error": f"fmi2GetFMUstate failed: {exc!r}"}

    def _set_fmu_state(self, state):
        try:
            reason = self._check_state(state)
            if reason:
                return self._refuse(f"fmi2SetFMUstate: {reason}; state unchanged")
            self._p = {v.name: state["parameters"][v.name] for v in self._params}
            self._system = None
            self._system_error = None
            self._bad = dict(state["flagged"])
            self._pending = list(state["pending"])
            self._phase = state["phase"]
            if self._phase >= STEP and _MODEL_KEY not in self._bad:
                self._configure(reset_state=False)
            self._time = float(state["time"])
            self._q[:] = state["q"]
            self._u[:] = state["u"]
            self._tau[:] = state["tau"]
            self._impacts = int(state["impacts"])
            self._percussion = float(state["percussion"])
        except Exception as exc:  # pragma: no cover - defensive
            self._refuse(f"fmi2SetFMUstate: internal error {exc!r}")

    def _check_state(self, s) -> str | None:
        if not isinstance(s, dict):
            return f"not an FMU state of this slave ({type(s).__name__})"
        if s.get("format") != STATE_FORMAT:
            return s.get("error") or f"unknown state format {s.get('format')!r} (expected {STATE_FORMAT})"
        if s.get("model") != self.MODEL:
            return f"state of model {s.get('model')!r}, this FMU is {self.MODEL!r}"
        n, m = self.N, len(self._inputs)
        try:
            if s["phase"] not in _PHASE_NAMES:
                return f"bad phase {s['phase']!r}"
            for key, size in (("q", n), ("u", n), ("tau", m)):
                x = s[key]
                if (not isinstance(x, list) or len(x) != size
                        or not all(_is_real(a) and math.isfinite(a) for a in x)):
                    return f"{key} must be {size} finite numbers, got {x!r}"
            for key in ("time", "percussion"):
                if not (_is_real(s[key]) and math.isfinite(s[key])):
                    return f"{key} must be a finite number, got {s[key]!r}"
            if not isinstance(s["impacts"], int) or s["impacts"] < 0:
                return f"impacts must be a non-negative integer, got {s['impacts']!r}"
            p = s["parameters"]
            names = {v.name for v in self._params}
            if not isinstance(p, dict) or set(p) != names:
                return "parameters do not match this FMU's parameters"
            for v in self._params:
                r = v.check(p[v.name])
                if r:
                    return r
            if not isinstance(s["flagged"], dict) or not isinstance(s["pending"], list):
                return "bad flagged/pending entries"
        except KeyError as exc:
            return f"missing entry {exc}"
        return None

    @staticmethod
    def _fmu_state_to_bytes(state) -> bytes:
        # Plain JSON: floats are written with repr (shortest round-trip text),
        # so a deserialised state reproduces the run bit for bit.
        try:
            return json.dumps(state, sort_keys=True, separators=(",", ":"),
                              allow_nan=False).encode("utf-8")
        except Exception as exc:
            return json.dumps({"format": "invalid",
                               "error": f"state not serialisable: {exc}"}).encode("utf-8")

    @staticmethod
    def _fmu_state_from_bytes(data: bytes):
        try:
            state = json.loads(bytes(data).decode("utf-8"))
            if not isinstance(state, dict):
                raise ValueError(f"a JSON {type(state).__name__}, not an object")
            return state
        except Exception as exc:
            return {"format": "invalid", "error": f"cannot deserialise the FMU state: {exc}"}

    # ------------------------------------------------------------ description
    def to_xml(self, model_options=None):
        return model_description(
            model_name=self.MODEL_IDENTIFIER, model_identifier=self.MODEL_IDENTIFIER,
            guid=model_guid(self.MODEL, self.start_values), description=self.DESCRIPTION,
            generation_tool=generation_tool(), variables=self._vars,
            default_experiment=self.DEFAULT_EXPERIMENT,
            log_categories=self.log_categories)
