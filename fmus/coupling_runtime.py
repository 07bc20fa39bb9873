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
from .coupling import CouplingSlave, CouplingSpec
from .runtime import InstanceBase, address, create_instance
from .slave import PHASES
from . import stepper as S
from .stepper import H_CONFIGURED, R_INADMISSIBLE

__all__ = ["CouplingInstance", "create", "STATE_FORMAT"]

STATE_FORMAT = "fmu-sync-coupling-state/1"


class CouplingInstance(InstanceBase):
    """One instance of a coupling FMU: variable array, table, work array; validation and state."""

    STATE_FORMAT = STATE_FORMAT

    def __init__(self, slave: CouplingSlave, start_values: dict, fmi_version: int = 2, stepper: int = 0):
        super().__init__(slave, start_values, fmi_version, stepper)
        spec = self.spec = slave.SPEC
        N, n, E, m = spec.N, spec.n, len(spec.edges), self.m
        self.work = np.zeros(CS.work_size(N, n, E, m))
        first = {key: self.index[(f"{key}[1]" if key not in ("q", "u", "tau") or n == 1 else f"{key}[1,1]")]
                 for key in ("q", "u", "tau", "d", "V", "euclidean", "branch")}
        CS.init_header(self.work, N, n, E, m, len(self.vars), first)
        self.i_in = int(self.work[CS.C_IQ])
        self.outputs = [self.index[v.name] for v in self.vars if v.causality == "output"]
        self._reset_values()

    def _reset_values(self) -> None:
        self._clear()
        self._set_memory([0.0] * (2 * self.spec.N + 1))
        self.refresh()

    def _memory(self, work) -> list:
        """What the admissibility check remembers of the last doStep: [H, N speeds, N gaps]."""
        r = CS.report_slot(work)
        return [float(work[CS.C_HLAST])] + work[r - 2 * self.spec.N:r].tolist()

    def _set_memory(self, m) -> None:
        r = CS.report_slot(self.work)
        self.work[CS.C_HLAST] = m[0]
        self.work[r - 2 * self.spec.N:r] = m[1:]

    def _evaluate(self) -> str:
        """The outputs from the current inputs, by the stepper's own code (H = 0); the
        warning reply if an input state is inside the wall (:meth:`inadmissible`)."""
        rc = self._step(address(self.x), address(self.work), float(self.work[S.H_TIME]), 0.0)
        return self.inadmissible() if rc == R_INADMISSIBLE else ""

    def inadmissible(self) -> str:
        """The reason of the stepper's R_INADMISSIBLE (called by the binary): which system is
        inside the wall, its gap and the allowed bound (fmi2Warning: docs/fmu.md)."""
        r = CS.report_slot(self.work)
        i, g, bound, H = int(self.work[r]), float(self.work[r + 1]), float(self.work[r + 2]), float(self.work[r + 3])
        rule = (f"2 H v with H = {H:g} s, the last communication step, and v the largest normal speed the "
                f"inputs allow, below the depth of a contact that lasts (core.checks.penetration_bound)" if H > 0 else
                "no step taken yet: a start state must satisfy g >= 0")
        return (f"W:t = {self.work[S.H_TIME]:g}: the inputs put system {i} inside the wall: g(q) = w^T q + g0 = "
                f"{g:.6g} m is below the allowed Moreau penetration {-bound if bound > 0.0 else 0.0:.3g} m ({rule}); tau, "
                f"d, V computed "
                f"from it are outside the quotient distance's domain (g >= 0): check the systems' wall "
                f"parameters (w, g0 must equal theirs) and their solver.dt")

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
        return self._evaluate()

    def refresh(self) -> str:
        """Outputs in initialization mode; NaN while the parameters are not a valid set, said
        with a warning (the reason :meth:`exit_initialization` would refuse with)."""
        reply = self.exit_initialization()
        if not reply or not self.work[S.H_CONFIGURED] == 0.0:
            return reply
        why = reply[2:].split("invalid configuration: ", 1)[-1].split("; the instance stays", 1)[0]
        return (f"W:the coupling's outputs are NaN in initialization mode: the parameters are not a valid set "
                f"yet ({why}); set valid parameters before {self.calls['exit']}")

    # ------------------------------------------------------------ FMU state
    def _state(self, x, work) -> dict:
        return {"spec": self.spec.as_dict(), "inputs": x[self.i_in:self.i_in + self.m].tolist(),
                "memory": self._memory(work)}

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
            N = self.spec.N
            mem = s.get("memory", [0.0] * (2 * N + 1))
            if (not isinstance(mem, list) or len(mem) != 2 * N + 1
                    or not all(isinstance(a, (int, float)) and math.isfinite(a) for a in mem)
                    or not all(a >= 0.0 for a in mem[:N + 1])):
                return (f"memory must be [H, N speeds, N gaps], {2 * N + 1} finite numbers (H and the speeds "
                        f">= 0), got {mem!r}"), None
            p = s["parameters"]
            if not isinstance(p, dict) or set(p) != {v.name for v in self.params}:
                return "parameters do not match this FMU's parameters", None
            for v in self.params:
                r = v.check(p[v.name])
                if r:
                    return f"parameter {r}", None
            cfg = self.slave.configure(p)
        except KeyError as exc:
            return f"missing entry {exc}", None
        except ValueError as exc:
            return f"its parameters are invalid: {exc}", None
        return None, cfg

    def _restore(self, s: dict, cfg) -> None:
        self.x[self.i_in:self.i_in + self.m] = s["inputs"]
        self._set_memory(s.get("memory", [0.0] * (2 * self.spec.N + 1)))
        self._install(cfg)
        self._evaluate()


def create(resources_dir: str, model: str, max_substeps: float = math.inf,
           fmi_version: int = 2, stepper: int = 0) -> tuple[str, CouplingInstance | None]:
    """A new instance: the structure and start values of ``resources/fmu_sync_start.json``
    (``max_substeps``: unused, the coupling has no internal steps; ``stepper``: the address of
    the binary's native stepper)."""
    def make(data):
        slave = CouplingSlave(CouplingSpec.from_dict(data["structure"]))
        return CouplingInstance(slave, slave.normalize_start_values(data.get("start", {})), fmi_version, stepper)
    return create_instance(resources_dir, model, fmi_version, make)
