"""The Python object behind one coupling FMU instance (called by the FMU's binary).

The same binary as the mechanical models (``fmus/c/fmu_sync_fmi2.c``) and the
same protocol as :class:`fmu_sync.fmus.runtime.FMUInstance` (layout, replies,
states); only the variables, the work array and the cfunc
(:mod:`.coupling_stepper`) differ. The coupling has no state of its own: an FMU
state holds the time, the phase, the inputs and the parameters.
"""
from __future__ import annotations

import math

import numpy as np

from . import coupling_stepper as CS
from .coupling import CouplingSpec, coupling_slave
from .runtime import InstanceBase, read_start_file
from .slave import PHASES, START_FILE
from .stepper import H_CONFIGURED, H_PHASE, H_TIME

__all__ = ["CouplingInstance", "create", "STATE_FORMAT"]

STATE_FORMAT = "fmu-sync-coupling-state/1"
_PHASE_NAMES = {code: name for name, code in PHASES.items()}


class CouplingInstance(InstanceBase):
    """One instance of a coupling FMU: variable array, table, work array; validation and state."""

    def __init__(self, slave_cls, start_values: dict):
        self._declare(slave_cls, start_values)
        spec = self.spec = slave_cls.SPEC
        N, n, E, m = spec.N, spec.n, len(spec.edges), len(self.inputs)
        self.m = m
        self.work = np.zeros(CS.work_size(N, n, E, m))
        first = {key: self.index[(f"{key}[1]" if key not in ("q", "u", "tau") or n == 1 else f"{key}[1,1]")]
                 for key in ("q", "u", "tau", "d", "V", "euclidean", "branch")}
        CS.init_header(self.work, N, n, E, m, len(self.vars), first)
        self.i_in = int(self.work[CS.C_IQ])
        self.outputs = [self.index[v.name] for v in self.vars if v.causality == "output"]
        self.cfg = None
        self._bind(CS.step)
        self._reset_values()

    def _reset_values(self) -> None:
        self.x[:] = self.starts
        self.work[H_TIME] = 0.0
        self.cfg = None
        self.work[H_CONFIGURED] = 0.0
        self.refresh()

    def _evaluate(self) -> None:
        """The outputs from the current inputs, by the stepper's own code (H = 0)."""
        self._step(self.x.ctypes.data, self.work.ctypes.data, 0.0, 0.0)

    def _install(self, cfg) -> None:
        CS.pack(self.work, cfg, self.spec.edges)
        self.cfg = cfg

    # ------------------------------------------------------------ life cycle
    def exit_initialization(self) -> str:
        """Outputs computed from the current inputs and parameters; refused (the reply)
        while the parameters are not a valid set."""
        reply, cfg = self._configuration()
        if cfg is None:
            self.work[H_CONFIGURED] = 0.0
            self.x[self.outputs] = math.nan
            return reply
        self._install(cfg)
        self._evaluate()
        return ""

    def refresh(self) -> str:
        """Outputs in initialization mode (NaN while the parameters are not a valid set)."""
        self.exit_initialization()
        return ""

    # ------------------------------------------------------------ FMU state
    def get_state(self) -> dict:
        return {"format": STATE_FORMAT, "model": self.cls.MODEL, "spec": self.spec.as_dict(),
                "phase": _PHASE_NAMES.get(int(self.work[H_PHASE]), "instantiated"),
                "time": float(self.work[H_TIME]),
                "inputs": self.x[self.i_in:self.i_in + self.m].tolist(),
                "parameters": self._parameters()}

    def state_reason(self, s) -> tuple[str | None, object]:
        if not isinstance(s, dict) or s.get("format") != STATE_FORMAT:
            return f"not a coupling FMU state (format {getattr(s, 'get', lambda k: None)('format')!r}, " \
                   f"expected {STATE_FORMAT!r})", None
        if s.get("spec") != self.spec.as_dict():
            return f"state of a coupling with structure {s.get('spec')!r}, this FMU is {self.spec.as_dict()!r}", None
        try:
            if s["phase"] not in PHASES:
                return f"bad phase {s['phase']!r} (one of {', '.join(PHASES)})", None
            t = s["time"]
            if not (isinstance(t, (int, float)) and math.isfinite(t)):
                return f"time must be a finite number, got {t!r}", None
            x = s["inputs"]
            if not isinstance(x, list) or len(x) != self.m:
                return f"inputs must be a list of {self.m} numbers", None
            for v, a in zip(self.inputs, x):
                r = v.check(a)
                if r:
                    return f"input {r}", None
            p = s["parameters"]
            if not isinstance(p, dict) or set(p) != {v.name for v in self.params}:
                return "parameters do not match this FMU's parameters", None
            for v in self.params:
                r = v.check(p[v.name])
                if r:
                    return f"parameter {r}", None
            cfg = self.cls.configure(p)
        except KeyError as exc:
            return f"missing entry {exc}", None
        except ValueError as exc:
            return f"its parameters are invalid: {exc}", None
        return None, cfg

    def set_state(self, s) -> str:
        reason, cfg = self.state_reason(s)
        if reason:
            return f"E:fmi2SetFMUstate: {reason}; state unchanged"
        for name, value in s["parameters"].items():
            self.x[self.index[name]] = value
        self.x[self.i_in:self.i_in + self.m] = s["inputs"]
        self.work[H_TIME] = s["time"]
        self.work[H_PHASE] = PHASES[s["phase"]]
        self._install(cfg)
        self._evaluate()
        return ""


def create(slave_base, resources_dir: str, model: str,
           max_substeps: float = math.inf) -> tuple[str, CouplingInstance | None]:
    """A new instance: the structure and start values of ``resources/fmu_sync_start.json``
    (``max_substeps``: unused, the coupling has no internal steps)."""
    reply, data = read_start_file(resources_dir, model)
    if data is None:
        return reply, None
    try:
        cls = coupling_slave(CouplingSpec.from_dict(data["structure"]))
        starts = cls.normalize_start_values(data.get("start", {}))
    except (KeyError, TypeError, ValueError) as exc:
        return f"E:fmi2Instantiate: bad structure or start value in {START_FILE}: {exc!r}", None
    return "", CouplingInstance(cls, starts)
