"""Our master in the exchange orders of other masters (docs/ssp.md): libcosim's and
fmpy's SSP runner, measured on the coupling FMU's direct feedthrough.

:class:`SspMaster` is :class:`fmu_sync.master.NetworkMaster` with two more exchange
orders, each one value of the compiled loop's ``DELAY`` flag
(:mod:`fmu_sync.cosim_loop`, as the master's design asks):

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

from . import cosim_loop as loop
from .master import NetworkMaster

__all__ = ["SspMaster", "ORDERS"]

#: the other masters' orders, by the name of our method
ORDERS = {"delayed": "libcosim", "delayed-zero": "fmpy.ssp.simulate_ssp"}


class SspMaster(NetworkMaster):
    """:class:`NetworkMaster` with the exchange orders of libcosim and fmpy's SSP runner."""

    METHODS = NetworkMaster.METHODS + tuple(ORDERS)
    DELAY = {"delayed": loop.DELAYED, "delayed-zero": loop.DELAYED_ZERO}

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.method in ORDERS and (self.event_aware or self.hold != "zoh"):
            raise ValueError(f"method {self.method!r} ({ORDERS[self.method]}'s exchange order) runs with "
                             f"hold='zoh' and without event_aware, got hold={self.hold!r}, "
                             f"event_aware={self.event_aware!r}")
