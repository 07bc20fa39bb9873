"""Our master in the exchange orders of other masters (docs/ssp.md): libcosim's and
fmpy's SSP runner, measured on the coupling FMU's direct feedthrough.

:class:`SspMaster` is :class:`fmu_sync.master.NetworkMaster` with two more exchange
strategies (one ``step_<name>`` method each, as the master's design asks):

* ``delayed`` -- libcosim's fixed-step algorithm: every slave steps (the coupling
  too, with the inputs transferred after the previous step), then the outputs are
  transferred; so each step is held at the forces of the states one step older, the
  first at those of the start states (its initialization transfers them once);
* ``delayed-zero`` -- fmpy's ``simulate_ssp``: the same order, but every connection
  starts at 0, so the first two steps run without forces (at the first, the
  coupling's inputs are all 0 and equal states give no force).

Both run with the zero-order hold and without the event-aware retake (the other
masters have neither).
"""
from __future__ import annotations

import numpy as np

from .master import NetworkMaster

__all__ = ["SspMaster", "ORDERS"]

#: the other masters' orders, by the name of our method
ORDERS = {"delayed": "libcosim", "delayed-zero": "fmpy.ssp.simulate_ssp"}


class SspMaster(NetworkMaster):
    """:class:`NetworkMaster` with the exchange orders of libcosim and fmpy's SSP runner."""

    METHODS = NetworkMaster.METHODS + tuple(ORDERS)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.method in ORDERS and (self.event_aware or self.hold != "zoh"):
            raise ValueError(f"method {self.method!r} ({ORDERS[self.method]}'s exchange order) runs with "
                             f"hold='zoh' and without event_aware, got hold={self.hold!r}, "
                             f"event_aware={self.event_aware!r}")
        self._next = None   # the forces transferred for the next step

    def step_delayed(self, t: float, h: float, x) -> list:
        """Every instance steps with the forces transferred after the previous step, then
        the forces of x are computed for the next one."""
        fresh = self.tau.copy() if self._next is None else self._next
        self.inputs(x)
        self._next, self.tau = self.tau, fresh
        return self._step_all(t, h)

    def step_delayed_zero(self, t: float, h: float, x) -> list:
        """As :meth:`step_delayed`, every connection starting at 0."""
        if self._next is None:
            self._next, self.tau = np.zeros_like(self.tau), np.zeros_like(self.tau)
            return self._step_all(t, h)
        return self.step_delayed(t, h, x)

    def _step_all(self, t: float, h: float) -> list:
        for i, s in enumerate(self.slaves):
            self.check_forces(i, t, h)
            self._give(i, s, t, h)
        return [self.read(s) for s in self.slaves]

    def record(self, row: int, t: float, x, held) -> None:
        if row == 0 and self.method == "delayed-zero":   # the force held over the first step: 0
            held = np.zeros_like(held)
        super().record(row, t, x, held)
