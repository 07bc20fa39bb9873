"""The Python object behind one FMU instance (called by the FMU binary, ``fmus/c/fmu_sync_runtime.c``).

The binary holds a reference to an :class:`FMUInstance` and reads, once, its
:meth:`layout`: the addresses of the variable array ``x`` (float64, one slot per
value reference; Integer and Enumeration values are exact in a double), of the
per-variable table (type, causality, min, max, names, allowed values) and of the
work array. Those arrays are owned here and never reallocated, so the addresses
stay valid for the instance's life. The stepper is native code in the binary
(compiled at export, :mod:`fmu_sync.native`): the binary hands its address over at
instantiation (``stepper``), and this side calls it through ctypes (the outputs
in initialization mode, after a restore).

Every method the binary calls returns a *reply*: messages separated by
``\\x1e``, each prefixed ``I:``/``W:``/``D:``/``E:`` (status of the call) or
``N:`` (a notice, logged as a warning; the call stays OK); the empty string is OK. No method raises on bad input: a refused call changes nothing.
"""
from __future__ import annotations

import json
import math
import os
import struct

import numpy as np

from . import stepper as S
from ._xml import POSITIVE_MIN, fmi3_groups
from .contract import model as contract_model
from .slave import PHASES, RUNNING_PHASES, START_FILE, STATE_FORMAT, MechanicalSlave

__all__ = ["FMUInstance", "create", "LAYOUT", "TYPES", "CAUSALITIES", "CALL_NAMES", "variable_table",
           "InstanceBase", "create_instance", "address"]

#: what layout() hands over, in order (one uint64 each; the binary's FSR_L_* indices)
LAYOUT = ("version", "nvars", "x", "type", "caus", "min", "max", "work", "names", "hints")
#: codes of the per-variable table (the binary's FSR_T_* and FSR_C_*)
TYPES = {"Real": 0, "Integer": 1, "Enumeration": 2}
CAUSALITIES = {"parameter": 0, "input": 1, "output": 2}
_PHASE_NAMES = {code: name for name, code in PHASES.items()}
#: the FMI calls a reply names, per FMI version of the glue in use (the build record's fmi_version)
CALL_NAMES = {
    2: {"instantiate": "fmi2Instantiate", "exit": "fmi2ExitInitializationMode", "reset": "fmi2Reset",
        "set_state": "fmi2SetFMUstate", "deserialize": "fmi2DeSerializeFMUstate", "error": "fmi2Error"},
    3: {"instantiate": "fmi3InstantiateCoSimulation", "exit": "fmi3ExitInitializationMode", "reset": "fmi3Reset",
        "set_state": "fmi3SetFMUState", "deserialize": "fmi3DeserializeFMUState", "error": "fmi3Error"},
}


def address(a: np.ndarray) -> int:
    """The address of an array's data. Not ``a.ctypes.data``: numpy looks its helper up under a name
    made afresh per call, which CPython's type attribute cache keeps (its slots are keyed on the
    name's address), so every instance grew the process a little (issue 35)."""
    return a.__array_interface__["data"][0]


def _q_u_names(n):
    if n == 1:
        return ["q"], ["u"]
    return [f"q[{i + 1}]" for i in range(n)], [f"u[{i + 1}]" for i in range(n)]



def variable_table(vars_: list) -> tuple:
    """The arrays the binary reads per variable: (starts, type, causality, min, max,
    names, hints); names and hints as '\\0'-separated bytes."""
    nv = len(vars_)
    starts = np.array([float(v.start) if v.start is not None else math.nan for v in vars_])
    vtype = np.array([TYPES[v.type] for v in vars_], dtype=np.int32)
    vcaus = np.array([CAUSALITIES[v.causality] for v in vars_], dtype=np.int32)
    vmin = np.full(nv, -math.inf)
    vmax = np.full(nv, math.inf)
    hints = []
    for i, v in enumerate(vars_):
        hint = ""
        if v.type == "Enumeration":
            values = [val for _, val, _ in v.items]
            vmin[i], vmax[i] = min(values), max(values)
            assert sorted(values) == list(range(min(values), max(values) + 1))
            hint = ", ".join(f"{val} ({name})" for name, val, _ in v.items)
        if v.min is not None:
            vmin[i] = v.min
        if v.max is not None:
            vmax[i] = v.max
        hints.append(hint)
    assert POSITIVE_MIN == 2.2250738585072014e-308  # DBL_MIN: the binary prints "> 0" for it
    names = np.frombuffer(b"".join(v.name.encode() + b"\0" for v in vars_), dtype=np.uint8).copy()
    hint_bytes = np.frombuffer(b"".join(h.encode() + b"\0" for h in hints), dtype=np.uint8).copy()
    return starts, vtype, vcaus, vmin, vmax, names, hint_bytes


class InstanceBase:
    """What every Python instance behind the binary shares (a mechanical model's and the
    coupling's): the slave, the variables and their table, the layout handed to the binary,
    the parameter values, the FMU state's common part and its bytes. A kind of instance
    gives ``_reset_values``, ``refresh``, ``exit_initialization``, ``_state``, ``_restore``
    and ``state_reason``."""

    #: the format tag of this kind's FMU states
    STATE_FORMAT = STATE_FORMAT

    def __init__(self, slave, start_values: dict, fmi_version: int = 2, stepper: int = 0):
        self.slave = slave
        self._bind(stepper)
        self.calls = CALL_NAMES[fmi_version]
        self.vars = slave.variables(start_values)
        self.index = {v.name: i for i, v in enumerate(self.vars)}
        self.params = [v for v in self.vars if v.causality == "parameter"]
        self.inputs = [v for v in self.vars if v.causality == "input"]
        (self.starts, self.vtype, self.vcaus, self.vmin, self.vmax, self._names,
         self._hints) = variable_table(self.vars)
        self.x = self.starts.copy()
        self.m = len(self.inputs)
        self.cfg = None

    def _bind(self, stepper: int) -> None:
        """The binary's stepper at address ``stepper`` (``int32 (double *x, double *work, double t,
        double H)``, the same for every model: fsr_python_step), callable from Python."""
        import ctypes
        if not isinstance(stepper, int) or stepper <= 0:
            raise ValueError(f"no native stepper address from the binary (got {stepper!r}): the FMU's binary "
                             f"and its Python code do not match (export it again)")
        self._step = ctypes.CFUNCTYPE(ctypes.c_int32, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double,
                                      ctypes.c_double)(stepper)

    def layout(self) -> bytes:
        """What the binary reads once (LAYOUT, version stepper.WORK_VERSION): the arrays."""
        fields = {"version": S.WORK_VERSION, "nvars": self.x.shape[0], "x": address(self.x),
                  "type": address(self.vtype), "caus": address(self.vcaus), "min": address(self.vmin),
                  "max": address(self.vmax), "work": address(self.work),
                  "names": address(self._names), "hints": address(self._hints)}
        return struct.pack(f"<{len(LAYOUT)}Q", *(fields[k] for k in LAYOUT))

    def free(self) -> None:
        self.cfg = None

    def _parameters(self, x=None) -> dict:
        """The parameter values in ``x`` (default: the instance's variables)."""
        x = self.x if x is None else x
        out = {}
        for v in self.params:
            a = x[self.index[v.name]]
            out[v.name] = int(a) if v.type in ("Integer", "Enumeration") else float(a)
        return out

    def _configuration(self) -> tuple[str, object]:
        """("", configuration) of the current parameters, or (the reply refusing
        the exit of initialization mode, None)."""
        try:
            return "", self.slave.configure(self._parameters())
        except ValueError as exc:
            return (f"E:{self.calls['exit']}: invalid configuration: {exc}; the instance stays in "
                    f"initialization mode (set valid parameters and call it again, or {self.calls['reset']})"), None

    def _clear(self) -> None:
        """Back to the start values, unconfigured, at time 0 (each kind then clears its own slots)."""
        self.x[:] = self.starts
        self.work[S.H_TIME] = 0.0
        self.work[S.H_CONFIGURED] = 0.0
        self.cfg = None

    def reset(self) -> str:
        self._reset_values()
        return ""

    # ------------------------------------------------------------ FMU state
    # The binary saves and restores a state natively: a copy of the arrays x and work (fmus/c/
    # fmu_sync_runtime.c, "FMU states"). Here: that copy's serialized form (``serialize``, the dict of
    # ``get_state`` sealed), and a serialized state checked and turned into such a copy
    # (``deserialize``: what ``set_state`` makes of it, computed on copies of the arrays).
    def get_state(self, x=None, work=None) -> dict:
        """The state held by the arrays ``x`` and ``work`` (default: the instance's own): the part every
        kind shares and the kind's own (``_state``)."""
        x = self.x if x is None else x
        work = self.work if work is None else work
        return {"format": self.STATE_FORMAT, "model": self.slave.MODEL,
                "phase": _PHASE_NAMES.get(int(work[S.H_PHASE]), "instantiated"),
                "time": float(work[S.H_TIME]), "parameters": self._parameters(x), **self._state(x, work)}

    def set_state(self, s) -> str:
        """Restore a saved state (checked by ``state_reason``; a refused one changes nothing)."""
        reason, cfg = self.state_reason(s)
        if reason:
            return f"E:{self.calls['set_state']}: {reason}; state unchanged"
        self._apply(s, cfg)
        return ""

    def _apply(self, s, cfg) -> None:
        for name, value in s["parameters"].items():
            self.x[self.index[name]] = value
        self.work[S.H_TIME] = s["time"]
        self.work[S.H_PHASE] = PHASES[s["phase"]]
        self._restore(s, cfg)

    def state_reason(self, s) -> tuple[str | None, object]:
        """(None, configuration) for a valid saved state of this instance, else (reason, None)."""
        raise NotImplementedError

    def _split(self, arrays: bytes) -> tuple[np.ndarray, np.ndarray]:
        """x and work of a native state's bytes (x, then work, float64)."""
        a = np.frombuffer(arrays, dtype=np.float64)
        nx = self.x.shape[0]
        if a.shape[0] != nx + self.work.shape[0]:
            raise ValueError(f"a native FMU state of {a.shape[0]} values, this instance has {nx} + "
                             f"{self.work.shape[0]}")
        return a[:nx], a[nx:]

    def serialize(self, arrays: bytes) -> bytes:
        """The sealed JSON form of a native state (its arrays' bytes)."""
        return self.slave.state_to_bytes(self.get_state(*self._split(arrays)))

    def deserialize(self, data: bytes) -> tuple[str, bytes | None]:
        """(reply, the arrays x and work, as bytes, of the state ``data`` restored) or (the refusal,
        None); this instance is unchanged."""
        try:
            s = self.slave.state_from_bytes(data)
        except Exception as exc:
            return (f"E:{self.calls['deserialize']}: cannot deserialise the FMU state ({len(data)} bytes): {exc}",
                    None)
        reason, cfg = self.state_reason(s)
        if reason:
            return f"E:{self.calls['deserialize']}: {reason}", None
        own = self.x, self.work, self.cfg
        self.x, self.work = self.x.copy(), self.work.copy()
        try:
            self._apply(s, cfg)
            return "", self.x.tobytes() + self.work.tobytes()
        finally:
            self.x, self.work, self.cfg = own


class FMUInstance(InstanceBase):
    """One instance: variable array, table, work array; validation and state."""

    def __init__(self, slave: MechanicalSlave, start_values: dict, max_substeps: float = math.inf,
                 fmi_version: int = 2, stepper: int = 0):
        super().__init__(slave, start_values, fmi_version, stepper)
        self.max_substeps = max_substeps     # the binary's limit of internal steps per doStep
        nv = len(self.vars)

        n, m = slave.N, self.m
        qn, un = _q_u_names(n)
        self.n = n
        self.work = np.zeros(S.work_size(n, m, slave.NF_MAX, nv, slave.N_P))
        w = self.work
        w[S.H_LEN] = w.shape[0]
        w[S.H_VERSION] = S.WORK_VERSION
        w[S.H_NX] = nv
        w[S.H_M] = m
        w[S.H_ITAUDOT] = w.shape[0] - m          # the input derivatives: the last m slots
        w[S.H_ICOUNT] = w.shape[0] - m - nv      # before them: the FMI 3.0 variable sizes per slot
        self.i_taudot = int(w[S.H_ITAUDOT])
        for _, scalars, _ in fmi3_groups(self.vars):   # slot of an FMI 3.0 variable: its size; inner: 0
            w[int(w[S.H_ICOUNT]) + scalars[0].value_reference] = len(scalars)
        w[S.H_IQ], w[S.H_IU] = self.index[qn[0]], self.index[un[0]]
        w[S.H_ITAU] = self.index[self.inputs[0].name]
        assert [self.index[a] for a in qn] == list(range(int(w[S.H_IQ]), int(w[S.H_IQ]) + n))
        assert [self.index[a] for a in un] == list(range(int(w[S.H_IU]), int(w[S.H_IU]) + n))
        assert [self.index[v.name] for v in self.inputs] == list(range(int(w[S.H_ITAU]), int(w[S.H_ITAU]) + m))
        self.i_q, self.i_u, self.i_tau = int(w[S.H_IQ]), int(w[S.H_IU]), int(w[S.H_ITAU])
        w[S.H_IGAP], w[S.H_IENERGY] = self.index["gap"], self.index["energy"]
        w[S.H_IIMPACTS], w[S.H_IPERC] = self.index["impacts"], self.index["percussion"]
        self.i_gap, self.i_energy = self.index["gap"], self.index["energy"]
        self.i_impacts, self.i_perc = self.index["impacts"], self.index["percussion"]
        self._reset_values()

    # ------------------------------------------------------------ helpers
    def _reset_values(self) -> None:
        self._clear()
        self.x[self.i_impacts] = 0.0
        self.x[self.i_perc] = 0.0
        self.work[S.H_VREF] = 0.0
        self.work[S.H_PEND_P] = 0.0
        self.work[self.i_taudot:self.i_taudot + self.m] = 0.0
        self.refresh()

    def _install(self, cfg) -> None:
        """Pack a validated configuration into the work array."""
        exact = None
        if cfg.scheme == S.EXACT:
            from ..core.exact_step import exact_model
            exact = exact_model(cfg.system)
        S.pack(self.work, cfg.system.arrays(), cfg.dt, cfg.scheme, cfg.theta, exact, cfg.system.p)
        self.work[S.H_CONFIGURED] = 1.0
        self.cfg = cfg

    def _outputs_from_stepper(self) -> None:
        """gap and energy by the stepper's own code (H = 0): the same numbers as after a step."""
        self._step(address(self.x), address(self.work), float(self.work[S.H_TIME]), 0.0)

    # ------------------------------------------------------------ life cycle
    def refresh(self) -> str:
        """Outputs in initialization mode: q, u from q_start, u_start; gap and
        energy of the current parameters (NaN while they are not a valid system)."""
        p = self._parameters()
        q0, u0 = self.slave.start_state(p)
        self.x[self.i_q:self.i_q + self.n] = q0
        self.x[self.i_u:self.i_u + self.n] = u0
        try:
            system = self.slave.build_system(p)
            self.x[self.i_gap] = system.gap(q0)
            self.x[self.i_energy] = system.energy(q0, u0)
        except ValueError as exc:
            self.x[self.i_gap] = math.nan
            self.x[self.i_energy] = math.nan
            return (f"W:outputs gap and energy are NaN in initialization mode: the parameters are not a valid "
                    f"system yet ({exc}); set valid parameters before {self.calls['exit']}")
        return ""

    def exit_initialization(self) -> str:
        reply, cfg = self._configuration()
        if cfg is None:
            return reply
        self._install(cfg)
        self.x[self.i_q:self.i_q + self.n] = cfg.q0
        self.x[self.i_u:self.i_u + self.n] = cfg.u0
        self.x[self.i_impacts] = 0.0
        self.x[self.i_perc] = 0.0
        self.work[S.H_VREF] = 0.0               # the exact run's velocity scale: set by its first step
        self.work[S.H_PEND_P] = 0.0
        self._outputs_from_stepper()
        return self._default_step_warning(cfg)

    def _default_step_warning(self, cfg) -> str:
        """A notice when the default experiment's step needs more internal steps than a doStep may take
        (logged as a warning; the call stays OK: an importer may use smaller steps, and some importers,
        fmusim for one, stop at any status other than OK)."""
        H = float(self.slave.DEFAULT_EXPERIMENT["stepSize"])
        count = math.ceil(H / cfg.dt - 1e-9)      # as fsr_step (fmus/c/fmu_sync_runtime.c) counts them
        if cfg.scheme == S.EXACT or count <= self.max_substeps:
            return ""
        return (f"N:{self.calls['exit']}: solver.dt = {cfg.dt:g} makes a doStep of the default "
                f"experiment's step H = {H:g} (modelDescription.xml) need {count:.6g} internal steps, more "
                f"than the limit {self.max_substeps:.0f}: every doStep with H > {self.max_substeps * cfg.dt:.6g} "
                f"will be refused ({self.calls['error']}); use solver.dt >= {H / self.max_substeps:.6g} or smaller steps")

    # ------------------------------------------------------------ FMU state
    def _state(self, x, work) -> dict:
        return {
            "q": x[self.i_q:self.i_q + self.n].tolist(),
            "u": x[self.i_u:self.i_u + self.n].tolist(),
            "tau": x[self.i_tau:self.i_tau + self.m].tolist(),
            "taudot": work[self.i_taudot:self.i_taudot + self.m].tolist(),
            "vref": float(work[S.H_VREF]),
            "pending": [float(work[S.H_PEND_U]), float(work[S.H_PEND_P])],
            "impacts": int(x[self.i_impacts]),
            "percussion": float(x[self.i_perc]),
        }

    def _restore(self, s: dict, cfg) -> None:
        x = self.x
        x[self.i_q:self.i_q + self.n] = s["q"]
        x[self.i_u:self.i_u + self.n] = s["u"]
        x[self.i_tau:self.i_tau + self.m] = s["tau"]
        x[self.i_impacts] = s["impacts"]
        x[self.i_perc] = s["percussion"]
        self.work[self.i_taudot:self.i_taudot + self.m] = s["taudot"]
        self.work[S.H_PEND_U], self.work[S.H_PEND_P] = s["pending"]
        if s["phase"] in RUNNING_PHASES:
            self._install(cfg)
            self.work[S.H_VREF] = s["vref"]
            self._outputs_from_stepper()
        else:
            self.cfg = None
            self.work[S.H_CONFIGURED] = 0.0
            self.work[S.H_VREF] = 0.0
            self.refresh()

    def state_reason(self, s) -> tuple[str | None, object]:
        return self.slave.check_state(s, self.params, self.inputs)


def create_instance(resources_dir: str, model: str, fmi_version: int, make) -> tuple[str, object]:
    """(reply, ``make(contents of resources/fmu_sync_start.json)`` or None): what every kind of
    instance shares at instantiation (the start file read and checked, refusals as replies)."""
    call = CALL_NAMES[fmi_version]["instantiate"]
    path = os.path.join(resources_dir, START_FILE)
    try:
        with open(path, "rb") as f:        # bytes: no text decoder set up per instance (issue 35)
            data = json.loads(f.read())
    except Exception as exc:
        return f"E:{call}: cannot read the start values {path}: {exc}", None
    if data.get("model") != model:
        return f"E:{call}: {path} holds start values of model {data.get('model')!r}, not {model!r}", None
    try:
        return "", make(data)
    except (KeyError, TypeError, ValueError) as exc:
        return f"E:{call}: bad start value in {path}: {exc}", None


def create(resources_dir: str, model: str, max_substeps: float = math.inf,
           fmi_version: int = 2, stepper: int = 0) -> tuple[str, FMUInstance | None]:
    """A new instance of the registered model ``model`` (its one slave, :class:`MechanicalSlave`)
    with the start values of ``resources/fmu_sync_start.json``; ``max_substeps``: the binary's
    limit of internal steps per doStep (from the build record); ``stepper``: the address of the
    binary's native stepper."""
    def make(data):
        slave = MechanicalSlave(contract_model(model))
        return FMUInstance(slave, slave.normalize_start_values(data.get("start", {})), max_substeps, fmi_version,
                           stepper)
    return create_instance(resources_dir, model, fmi_version, make)
