"""The force the FMUs integrated over each communication step, from a co-simulation's record
(docs/cosimulation.md, *What the record's tau is*).

A record row at t_k holds, as ``tau``, the force of the step that ends at t_k as it was at that step's
start: the coupling law at the states of t_(k-1) (row 0: the law at the start states). So:

* explicit exchange, zero-order hold: row k+1's tau is the force held over [t_k, t_k+1] (the
  record is the applied force);
* implicit exchange: the FMUs were given the line from that force (the law at t_k's states) to the law
  at the step's end states, which is row k+2's tau (to the iteration's tolerance): with ``hold="foh"``
  the line itself, with ``hold="zoh"`` its mean, held over the step. The recorded tau is the line's
  start, not the mean, and the last step's end is not in the record.

:func:`applied_forces` gives both ends of each step's force from a record kept every step
(``record_every = 1``); their mean is what the zero-order hold applied.
"""
from __future__ import annotations

import numpy as np

__all__ = ["applied_forces"]


def applied_forces(result):
    """``(t, start, end)`` of the communication steps of a co-simulation recorded every step: ``t`` the
    steps' start times, ``start`` and ``end`` the force at the step's two ends as given to the FMUs
    (rows shaped as ``result.tau``'s, or (tau1, tau2) of a pair stacked as [:, 0], [:, 1]). Under the
    implicit exchange the force over the step is the line between them (``hold="foh"``) or their mean
    held (``hold="zoh"``); the last step is left out (its end is not recorded). Under the explicit
    zero-order hold ``end`` is ``start`` (every step).

    ValueError for a record that cannot say it: not a co-simulation, rows thinned (``record_every`` > 1:
    a step's ends are not in the record), the explicit first-order hold (its end is extrapolated from
    the step before)."""
    info = getattr(result, "info", None) or {}
    if info.get("mode") != "cosim":
        raise ValueError("applied_forces: not a co-simulation (a core run applies the law at every solver step)")
    t = np.asarray(result.t, dtype=float)
    H, lengths = info.get("H"), info.get("step_lengths")   # a run to a tolerance: each step's length
    steps = np.size(lengths) if lengths is not None else None
    thinned = (len(t) - 1 != steps) if steps is not None else bool(
        len(t) > 1 and np.max(np.diff(t)) > float(H) * (1 + 1e-9))
    if thinned:
        raise ValueError("applied_forces: the record was thinned (run.record_every / record_every > 1): the "
                         "force over a step needs its two ends, recorded every step")
    tau = np.asarray(result.tau) if getattr(result, "tau", None) is not None and not hasattr(result, "tau1") \
        else np.stack([np.asarray(result.tau1), np.asarray(result.tau2)], axis=1)
    exchange, hold = info.get("exchange", "explicit"), info.get("hold", "zoh")
    if exchange == "implicit":
        return t[:-2], tau[1:-1], tau[2:]
    if hold == "zoh":
        return t[:-1], tau[1:], tau[1:]
    raise ValueError("applied_forces: the explicit first-order hold extrapolates each step's end from the step "
                     "before; the record holds the line's start only (tau)")
