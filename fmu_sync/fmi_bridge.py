"""A small fmpy host for one FMI 2.0 co-simulation instance.

What fmpy's ``FMU2Slave`` leaves to the caller, done once:

* status codes instead of exceptions (``FMICallException`` -> its status), so a
  master can tell fmi2Discard from fmi2Error/fmi2Fatal and stop calling a dead
  instance (no call after fmi2Fatal except freeing it);
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

__all__ = ["FMUHost", "OK", "WARNING", "DISCARD", "ERROR", "FATAL", "STATUS_NAMES"]

OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4
STATUS_NAMES = {0: "OK", 1: "WARNING", 2: "DISCARD", 3: "ERROR", 4: "FATAL", 5: "PENDING"}


class FMUHost:
    """One instance of an FMI 2.0 co-simulation FMU, driven through fmpy.

    ``path`` is an ``.fmu`` file (unpacked to a temporary folder, removed by
    :meth:`close`) or an already unpacked folder (kept; several hosts may
    share it). ``logging=True`` switches the FMU's logging on.
    """

    def _open(self, path, model_description=None) -> None:
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
        self.last_status = OK
        self.dead = False
        self._stepping = False
        self._freed = False

    def __init__(self, path, instance_name: str = "instance", logging: bool = True,
                 model_description=None):
        from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        from fmpy import calloc, free

        self._open(path, model_description)

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
        self.fmu.instantiate(callbacks=cb, loggingOn=logging)
        if logging:
            self.fmu.setDebugLogging(True, [])

    # ---------------------------------------------------------------- calls
    def call(self, name: str, *args):
        """Call an ``FMU2Slave`` method; return ``(status, result)`` (never raises an FMI error)."""
        from fmpy.fmi1 import FMICallException
        if self.dead:
            raise RuntimeError("the instance returned fmi2Fatal: only close() is allowed")
        try:
            result = getattr(self.fmu, name)(*args)
            status = OK
        except FMICallException as exc:
            result, status = None, int(exc.status)
        self.last_status = status
        if status == FATAL:
            self.dead = True
        return status, result

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

    def initialize(self, start_time: float = 0.0, start_values: dict | None = None) -> int:
        """setupExperiment, enterInitializationMode, set start values, exitInitializationMode."""
        return max(self.enter_initialization(start_time), self.exit_initialization(start_values))

    def enter_initialization(self, start_time: float = 0.0) -> int:
        """setupExperiment and enterInitializationMode (parameters can be read from here on)."""
        return max(self.call("setupExperiment", None, start_time)[0], self.call("enterInitializationMode")[0])

    def exit_initialization(self, start_values: dict | None = None) -> int:
        """Set start values, then exitInitializationMode."""
        worst = max(self.set(start_values or {}), self.call("exitInitializationMode")[0])
        self._stepping = True
        return worst

    def do_step(self, t: float, h: float) -> int:
        return self.call("doStep", t, h)[0]

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

    def serialize_state(self, state) -> bytes:
        st, data = self.call("serializeFMUstate", state)
        return data

    def deserialize_state(self, data: bytes):
        """(status, state) from serialised bytes."""
        return self.call("deSerializeFMUstate", bytes(data))

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
