"""A small fmpy host for one FMI 2.0 co-simulation instance: the one wrapper of an instance,
for the co-simulation master and for tests alike.

What fmpy's ``FMU2Slave`` leaves to the caller, done once:

* a failed call, in one of two conventions chosen when the host is made: with
  ``raises=True`` (the master's) a status worse than fmi2Warning raises
  :class:`SlaveError` at the call (instance, time, FMI call, status, the FMU's logged
  reason); otherwise (a test probing the FMU) the call returns the status
  (``FMICallException`` -> its status), so fmi2Discard is told from
  fmi2Error/fmi2Fatal. Either way no call follows fmi2Fatal except freeing;
* the FMU's log messages captured per instance (``messages``), through a
  per-instance callback (fmpy's logger proxy is one global for the process);
* variables by name, Integer/Enumeration vs Real dispatch;
* get/set/serialise FMU states;
* a clean shutdown: terminate, fmi2FreeInstance, then remove the unpacked files.

Refused calls return fmi2Error and change nothing (the instance stays usable);
a doStep that cannot complete returns fmi2Discard (see the README, *The FMU*).
"""
from __future__ import annotations

import shutil

from .core.errors import RunFailed

__all__ = ["FMUHost", "SlaveError", "OK", "WARNING", "DISCARD", "ERROR", "FATAL", "STATUS_NAMES"]

OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4
STATUS_NAMES = {0: "OK", 1: "WARNING", 2: "DISCARD", 3: "ERROR", 4: "FATAL", 5: "PENDING"}
#: the statuses as the FMI names them (after fmi2/fmi3)
STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")


class SlaveError(RunFailed):
    """A slave answered an FMI call with a status worse than Warning (``call`` names the FMI
    call, or what of the master's stopped the slave, e.g. "coupling")."""

    def __init__(self, slave: str, t: float, call: str, status: int, log: list[str]):
        reason = log[-1] if log else "no message logged"
        label = STATUS[status] if 0 <= status < len(STATUS) else str(status)
        prefix = call[:4] if call.startswith(("fmi2", "fmi3")) else "fmi2"
        super().__init__(f"slave {slave!r} failed at t = {t:.6g}: {call} returned {prefix}{label}: {reason}")
        self.slave, self.t, self.call, self.status, self.log = slave, t, call, status, list(log)


class FMUHost:
    """One instance of an FMI 2.0 co-simulation FMU, driven through fmpy.

    ``path`` is an ``.fmu`` file (unpacked to a temporary folder, removed by
    :meth:`close`) or an already unpacked folder (kept; several hosts may
    share it). ``logging=True`` switches the FMU's logging on; ``raises=True``:
    failed calls raise :class:`SlaveError` (the master's convention), else they
    return their status. ``t`` is the instance's time as the host last set it.
    """

    #: the prefix of this FMI version's function names
    PREFIX = "fmi2"

    def _open(self, path, model_description=None, instance_name: str = "instance", raises: bool = False) -> None:
        """The unpacked folder (an .fmu is unpacked, and removed by :meth:`close`), the model
        description, the variables by name and the host's bookkeeping (FMI 2.0 and 3.0)."""
        import os

        from fmpy import extract, read_model_description
        path = str(path)
        self._owns_dir = not os.path.isdir(path)
        self.unzip_dir = extract(path) if self._owns_dir else path
        self.md = model_description or read_model_description(self.unzip_dir)
        self.variables = {v.name: v for v in self.md.modelVariables}
        self.messages: list[tuple[int, str, str]] = []
        self.name, self.t, self.raises = instance_name, 0.0, bool(raises)
        self.last_status = OK
        self.dead = False
        self._stepping = False
        self._freed = False

    def __init__(self, path, instance_name: str = "instance", logging: bool = True,
                 model_description=None, raises: bool = False):
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        from fmpy import calloc, free

        self._open(path, model_description, instance_name, raises)

        def _logger(env, instance, status, category, message):
            # Our FMUs escape '%' (the message is a printf format): undo it.
            text = (message or b"").decode("utf-8", "replace").replace("%%", "%")
            self.messages.append((int(status), (category or b"").decode("utf-8", "replace"), text))

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(_logger)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._callbacks = cb
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzip_dir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName=instance_name)
        try:
            self.fmu.instantiate(callbacks=cb, loggingOn=logging)
        except Exception:   # fmpy's bare "Failed to instantiate model": the FMU's logged reason instead
            raise self._not_instantiated() from None
        if logging:
            self.fmu.setDebugLogging(True, [])

    def _not_instantiated(self) -> SlaveError:
        """The :class:`SlaveError` of a failed fmi2Instantiate (the one error path of instantiation,
        whatever ``raises`` says), carrying what the FMU logged (its start file, hash or GUID check);
        the unpacked files are removed (there is no instance to free)."""
        self._freed = True
        if self._owns_dir:
            shutil.rmtree(self.unzip_dir, ignore_errors=True)
        log = self.errors(min_status=WARNING) or [m for _, _, m in self.messages]
        if not log:
            log = ["the FMU logged no reason (its start files, resources or GUID may not match this build)"]
        return SlaveError(self.name, 0.0, self.PREFIX + "Instantiate", ERROR, log)

    # ---------------------------------------------------------------- calls
    def call(self, name: str, *args):
        """Call an fmpy slave method (``"doStep"``); return ``(status, result)``, or with
        ``raises`` raise :class:`SlaveError` for a status worse than Warning."""
        from fmpy.fmi1 import FMICallException
        if self.dead:
            raise RuntimeError(f"the instance returned {self.PREFIX}Fatal: only close() is allowed")
        try:
            result = getattr(self.fmu, name)(*args)
            status = OK
        except FMICallException as exc:
            result, status = None, int(exc.status)
        self.last_status = status
        if status == FATAL:
            self.dead = True
        if status > WARNING and self.raises:
            raise self.failure(self.PREFIX + name[0].upper() + name[1:], status)
        return status, result

    def failure(self, call: str, status: int, t: float | None = None) -> SlaveError:
        """The :class:`SlaveError` of ``call`` answering ``status`` at ``t`` (default: the
        host's time), with the FMU's logged reason."""
        return SlaveError(self.name, self.t if t is None else t, call, status,
                          self.errors(min_status=WARNING) or [m for _, _, m in self.messages])

    def vr(self, name: str) -> int:
        return self.variables[name].valueReference

    def _is_int(self, name: str) -> bool:
        return self.variables[name].type in ("Integer", "Enumeration")

    def set(self, values: dict) -> int:
        """Set variables by name; returns the worst status."""
        worst = OK
        for name, value in values.items():
            if self._is_int(name):
                st, _ = self.call("setInteger", [self.vr(name)], [int(value)])
            else:
                st, _ = self.call("setReal", [self.vr(name)], [float(value)])
            worst = max(worst, st)
        return worst

    def set_input_derivatives(self, values: dict, order: int = 1) -> int:
        """fmi2SetRealInputDerivatives: the ``order``-th time derivatives of the named inputs."""
        if not values:
            return OK
        names = list(values)
        st, _ = self.call("setRealInputDerivatives", [self.vr(n) for n in names], [int(order)] * len(names),
                          [float(values[n]) for n in names])
        return st

    def get(self, names) -> list:
        """Values of the named variables (ints for Integer/Enumeration)."""
        out = []
        for name in names:
            fn = "getInteger" if self._is_int(name) else "getReal"
            st, res = self.call(fn, [self.vr(name)])
            out.append(res[0] if res is not None else None)
        return out

    def get_integer(self, name: str) -> int:
        """The value of one Integer or Enumeration variable (None if the call failed without raising)."""
        value = self.get([name])[0]
        return None if value is None else int(value)

    def initialize(self, start_time: float = 0.0, start_values: dict | None = None) -> int:
        """setupExperiment, enterInitializationMode, set start values, exitInitializationMode."""
        return max(self.enter_initialization(start_time), self.exit_initialization(start_values))

    def enter_initialization(self, start_time: float = 0.0) -> int:
        """setupExperiment and enterInitializationMode (parameters can be read from here on)."""
        self.t = start_time
        return max(self.call("setupExperiment", None, start_time)[0], self.call("enterInitializationMode")[0])

    def exit_initialization(self, start_values: dict | None = None) -> int:
        """Set start values, then exitInitializationMode."""
        worst = max(self.set(start_values or {}), self.call("exitInitializationMode")[0])
        self._stepping = True
        return worst

    def do_step(self, t: float, h: float) -> int:
        self.t = t
        status = self.call("doStep", t, h)[0]
        if status <= WARNING:
            self.t = t + h
        return status

    def last_successful_time(self) -> float:
        from fmpy.fmi2 import fmi2LastSuccessfulTime
        return self.call("getRealStatus", fmi2LastSuccessfulTime)[1]

    # ---------------------------------------------------------------- state
    def get_state(self):
        return self.call("getFMUstate")

    def set_state(self, state) -> int:
        return self.call("setFMUstate", state)[0]

    def free_state(self, state) -> int:
        return self.call("freeFMUstate", state)[0]

    def save(self):
        """The instance's FMU state (None if the call failed without raising)."""
        return self.get_state()[1]

    def restore(self, state, t: float) -> int:
        """Set the FMU state saved at time ``t``."""
        status = self.set_state(state)
        self.t = t
        return status

    def serialize_state(self, state) -> bytes:
        st, data = self.call("serializeFMUstate", state)
        return data

    def deserialize_state(self, data: bytes):
        """(status, state) from serialised bytes."""
        return self.call("deSerializeFMUstate", bytes(data))

    def reset(self) -> int:
        """fmi2Reset: the instance as after instantiation (time 0, not stepping, an empty log);
        returns the status (a status worse than Warning raises with ``raises``)."""
        status = self.call("reset")[0]
        if status <= WARNING:
            self._stepping = False
            self.t = 0.0
            self.messages.clear()     # the next run's SlaveError reports its own log only
            self.last_status = OK
        return status

    # ---------------------------------------------------------------- close
    def close(self) -> None:
        """Terminate (if stepping and alive), free the instance, remove unpacked files."""
        if self._freed:
            return
        self._freed = True
        try:
            if self._stepping and not self.dead:
                self.call("terminate")
        finally:
            try:
                self.fmu.freeInstance()
            finally:
                if self._owns_dir:
                    shutil.rmtree(self.unzip_dir, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def errors(self, min_status: int = ERROR) -> list[str]:
        """Logged messages with at least ``min_status``."""
        return [m for s, _, m in self.messages if s >= min_status]
