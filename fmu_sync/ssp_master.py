"""Our master in the exchange orders of other masters (docs/ssp.md): libcosim's and
fmpy's SSP runner, measured on the coupling FMU's direct feedthrough.

The orders are entries of the strategy registry (:mod:`fmu_sync.strategies`), each one value
of the compiled loop's ``delay`` flag (:mod:`fmu_sync.cosim_loop`), run by
:class:`fmu_sync.master.NetworkMaster` like every order (``method="delayed"`` in
:func:`fmu_sync.master.cosimulate_network` too):

* ``delayed`` -- libcosim's fixed-step algorithm: every slave steps (the coupling
  too, with the inputs transferred after the previous step), then the outputs are
  transferred; so each step is held at the forces of the states one step older, the
  first at those of the start states (its initialization transfers them once);
* ``delayed-zero`` -- fmpy's ``simulate_ssp``: the same order, but every connection
  starts at 0, so the first two steps run without forces (at the first, the
  coupling's inputs are all 0 and equal states give no force).

Both run with the zero-order hold and without the event-aware retake (the other
masters have neither): the registry's checks of their entries.
"""
from __future__ import annotations

from .master import NetworkMaster
from .strategies import STRATEGIES

__all__ = ["SspMaster", "ORDERS"]

#: the other masters' orders (the registry's delayed entries), by the name of our method
ORDERS = {name: s.summary for name, s in STRATEGIES.items() if s.flags.get("delay")}

#: kept for its importers: the master that runs every order of the registry
SspMaster = NetworkMaster
