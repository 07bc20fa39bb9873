"""A small fmpy host for one FMI 3.0 co-simulation instance (docs/fmi3.md).

:class:`FMU3Host` is :class:`fmu_sync.fmi_bridge.FMUHost` for FMI 3.0: the same
calls (statuses instead of exceptions, messages captured per instance, variables
by name, FMU states, clean shutdown), plus what FMI 3.0 adds for impacts:

* ``early_return`` / ``event_mode``: the instance is created with
  ``earlyReturnAllowed`` / ``eventModeUsed``; :meth:`do_step` keeps the step's
  ``early_return``, ``event_needed`` and ``last_time`` (lastSuccessfulTime);
* :meth:`handle_event`: event mode at that instant (set inputs, update the
  discrete states until none is pending, back to step mode);
* arrays: ``get(["q"])`` of an n-DOF FMU gives the list of n values; the FMI 2.0
  scalar names (``"q[2]"``) address one element, so a master can use one set of
  names for both versions.
"""
from __future__ import annotations

import re

from .fmi_bridge import DISCARD, ERROR, FATAL, OK, WARNING, FMUHost

__all__ = ["FMU3Host", "open_host", "element_names", "OK", "WARNING", "DISCARD", "ERROR", "FATAL"]

_ELEMENT = re.compile(r"^(?P<base>.+)\[(?P<i>\d+)\]$")


def open_host(unzipdir, md, name: str, early_return: bool = False, raises: bool = False):
    """An :class:`FMUHost` (FMI 2.0) or :class:`FMU3Host` (FMI 3.0: early return and
    event mode if ``early_return``) on an unpacked FMU with model description ``md``
    (``raises``: failed calls raise :class:`fmu_sync.fmi_bridge.SlaveError`)."""
    if md.fmiVersion == "3.0":
        return FMU3Host(unzipdir, name, True, md, early_return=early_return, event_mode=early_return, raises=raises)
    return FMUHost(unzipdir, instance_name=name, model_description=md, raises=raises)


def element_names(md) -> list[str]:
    """The variable names of an FMU, an FMI 3.0 array (1-D) as its elements' FMI 2.0 names."""
    names = []
    for v in md.modelVariables:
        size = int(v.dimensions[0].start) if getattr(v, "dimensions", None) else 0
        names += [f"{v.name}[{i + 1}]" for i in range(size)] if size else [v.name]
    return names


class FMU3Host(FMUHost):
    """One instance of an FMI 3.0 co-simulation FMU, driven through fmpy."""

    PREFIX = "fmi3"

    def __init__(self, path, instance_name: str = "instance", logging: bool = True, model_description=None,
                 early_return: bool = True, event_mode: bool = True, raises: bool = False):
        from fmpy.fmi3 import FMU3Slave

        self._open(path, model_description, instance_name, raises)
        if self.md.fmiVersion != "3.0":
            if self._owns_dir:
                import shutil
                shutil.rmtree(self.unzip_dir, ignore_errors=True)
            raise ValueError(f"{path} is an FMI {self.md.fmiVersion} FMU; FMU3Host drives FMI 3.0 FMUs "
                             f"(use fmu_sync.fmi_bridge.FMUHost)")
        self.early_return_allowed = bool(early_return)
        self.event_mode = bool(event_mode)
        self.early_return = False
        self.event_needed = False
        self.last_time = 0.0

        def _logger(env, status, category, message):
            self.messages.append((int(status), (category or b"").decode("utf-8", "replace"),
                                  (message or b"").decode("utf-8", "replace")))

        self.fmu = FMU3Slave(guid=self.md.guid, unzipDirectory=self.unzip_dir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=instance_name)
        try:
            self.fmu.instantiate(loggingOn=logging, eventModeUsed=self.event_mode,
                                 earlyReturnAllowed=self.early_return_allowed, logMessage=_logger)
        except Exception:   # fmpy's bare exception: the FMU's logged reason instead (as FMUHost)
            raise self._not_instantiated() from None

    # ---------------------------------------------------------------- variables
    def _where(self, name: str):
        """(variable, element index or None, number of values)."""
        v = self.variables.get(name)
        i = None
        if v is None:
            m = _ELEMENT.match(name)
            if not (m and m["base"] in self.variables and self.variables[m["base"]].dimensions):
                raise KeyError(f"{name}: no such variable in {self.md.modelName}")
            v, i = self.variables[m["base"]], int(m["i"]) - 1
        n = 1
        for d in v.dimensions:
            n *= int(d.start)
        return v, i, n

    def vr(self, name: str) -> int:
        return self._where(name)[0].valueReference

    def _is_int(self, name: str) -> bool:
        return self._where(name)[0].type in ("Int64", "Enumeration")

    def set(self, values: dict) -> int:
        """Set variables by name (an element of an array by its FMI 2.0 name); the worst status."""
        worst = OK
        for name, value in values.items():
            v, i, n = self._where(name)
            if i is not None:        # one element: read the array, change it, write it back
                cur = self._get_all(v, n)
                cur[i] = value
                value = cur
            vals = list(value) if isinstance(value, (list, tuple)) else [value]
            fn = "setInt64" if self._is_int(name) else "setFloat64"
            st, _ = self.call(fn, [v.valueReference], [int(x) if fn == "setInt64" else float(x) for x in vals])
            worst = max(worst, st)
        return worst

    def _get_all(self, v, n: int) -> list:
        fn = "getInt64" if v.type in ("Int64", "Enumeration") else "getFloat64"
        st, res = self.call(fn, [v.valueReference], n)
        return list(res) if res is not None else [None] * n

    def get(self, names) -> list:
        """Values by name: a number per scalar or element, a list per whole array."""
        out = []
        for name in names:
            v, i, n = self._where(name)
            vals = self._get_all(v, n)
            out.append(vals[i] if i is not None else vals if v.dimensions else vals[0])
        return out

    # ---------------------------------------------------------------- life cycle
    def enter_initialization(self, start_time: float = 0.0) -> int:
        self.last_time = self.t = start_time
        return self.call("enterInitializationMode", None, start_time)[0]

    def exit_initialization(self, start_values: dict | None = None) -> int:
        """Set start values, exitInitializationMode (and, in event mode, settle the
        discrete states and enter step mode)."""
        worst = max(self.set(start_values or {}), self.call("exitInitializationMode")[0])
        if worst < ERROR and self.event_mode:
            worst = max(worst, self.handle_event())
        self._stepping = worst < ERROR
        return worst

    def do_step(self, t: float, h: float) -> int:
        """fmi3DoStep; keeps ``early_return``, ``event_needed`` and ``last_time``."""
        self.t = t
        st, res = self.call("doStep", t, h)
        if st <= WARNING:
            self.t = t + h
        if res is not None:
            self.event_needed, _, self.early_return, self.last_time = res
        else:
            self.event_needed, self.early_return = False, False
        return st

    def handle_event(self, inputs: dict | None = None) -> int:
        """Event mode at the current instant: set ``inputs``, update the discrete
        states until none is pending, enter step mode. The worst status."""
        worst = OK
        if self._stepping:
            worst = self.call("enterEventMode")[0]
        if worst >= ERROR:
            return worst
        worst = max(worst, self.set(inputs or {}))
        for _ in range(100):
            st, res = self.call("updateDiscreteStates")
            worst = max(worst, st)
            if st >= ERROR or not res[0]:
                break
        if worst < ERROR:
            worst = max(worst, self.call("enterStepMode")[0])
        self.event_needed = False
        return worst

    def last_successful_time(self) -> float:
        return self.last_time

    # ---------------------------------------------------------------- state
    def get_state(self):
        return self.call("getFMUState")

    def set_state(self, state) -> int:
        """fmi3SetFMUState; ``last_time`` becomes the restored instance's time."""
        st = self.call("setFMUState", state)[0]
        if st < ERROR:
            self.last_time = self.get(["time"])[0]
        return st

    def free_state(self, state) -> int:
        return self.call("freeFMUState", state)[0]

    def serialize_state(self, state) -> bytes:
        return self.call("serializeFMUState", state)[1]

    def deserialize_state(self, data: bytes):
        return self.call("deserializeFMUState", bytes(data))
