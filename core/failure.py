"""Where a run failed and whose fault it was (docs/design.md §5.1).

The compiled loops record into the caller's arrays, their time column filled with NaN
beforehand, so a loop that stops keeps its rows up to the failure: a user force law that
raises inside it (numba propagates the exception out of nopython code, past every row the loop
wrote) or a state that turns non-finite (the loop returns ``DIVERGED`` and its row count).
A row is recorded every ``record_every`` steps, so the drivers locate the failing step by
running again, from the last recorded row, the steps up to the next one with a row at every
step (:func:`rows_written` counts the rows each run completed): the last good step is then a
row of the partial record, and the message names the law, what it raised or returned, the time
and the state of the step it failed in. A rerun repeats the run's arithmetic (the harmonic
forcing's phasor restarts at the row: within 1e-13 of it).
"""
from __future__ import annotations

import numpy as np

from .steps import MIDPOINT

__all__ = ["rows_written", "state_text", "law_raised", "law_nonfinite", "force_offset"]


def force_offset(code: int, theta: float, h: float) -> float:
    """``a``: the scheme's force point t + a of a step of length h (θ h, or h/2 for the midpoint)."""
    return theta * h if code != MIDPOINT else 0.5 * h


def rows_written(T) -> int:
    """The rows a loop completed in the record ``T`` (prefilled with NaN): its leading finite times."""
    bad = np.flatnonzero(~np.isfinite(np.asarray(T)))
    return int(bad[0]) if bad.size else len(T)


def _vec(x) -> str:
    return "[" + ", ".join(f"{float(v):.9g}" for v in np.asarray(x).reshape(-1)) + "]"


def state_text(t: float, nodes) -> str:
    """``t = ...: q = [...], u = [...], tau = [...]`` of each ``(label, q, u, tau)`` in ``nodes``
    (label '' for a single system)."""
    parts = []
    for label, q, u, tau in nodes:
        s = f"q = {_vec(q)}, u = {_vec(u)}" + ("" if tau is None else f", tau = {_vec(tau)}")
        parts.append(f"{label}: {s}" if label else s)
    return f"t = {float(t):.9g} ({'; '.join(parts)})"


def law_raised(law, exc: BaseException, t: float, nodes) -> str:
    """The message of a run whose force law raised ``exc`` in the step from ``t`` at ``nodes``'s states."""
    return (f"force law {law.name!r} raised {type(exc).__name__}: {exc} in the step from {state_text(t, nodes)}; "
            f"the run stopped there and its record up to t = {float(t):.9g} is kept (.partial)")


def law_nonfinite(law, a: float, t: float, nodes, params) -> str | None:
    """The message naming the force law when h is not finite at the force point (q + a u, u, tau,
    t + a) of some node of the step from ``t`` (``nodes``: ``(label, q, u, tau)``, ``params``: each
    node's p), else None (h is finite there: the step, not the law, diverged)."""
    for (label, q, u, tau), p in zip(nodes, params):
        q, u = np.asarray(q, dtype=np.float64).reshape(-1), np.asarray(u, dtype=np.float64).reshape(-1)
        tau = np.zeros_like(q) if tau is None else np.asarray(tau, dtype=np.float64).reshape(-1)
        qe = np.ascontiguousarray(q + a * u)
        try:
            y = law.dispatcher(qe, np.ascontiguousarray(u), np.ascontiguousarray(tau), float(t + a),
                               np.ascontiguousarray(p, dtype=np.float64))
        except Exception as exc:   # the law raises at this point (a rerun that failed otherwise)
            return law_raised(law, exc, t, nodes)
        y = np.array(y, dtype=np.float64, ndmin=1)
        if not np.all(np.isfinite(y)):
            who = f" of {label}" if label else ""
            return (f"force law {law.name!r} returned the non-finite force h = {_vec(y)}{who} in the step from "
                    f"{state_text(t, nodes)}, at its force point q + {a:.6g} u, t = {float(t + a):.9g}: the law, "
                    f"not the scheme or the coupling, produced it; the run stopped there and its record up to "
                    f"t = {float(t):.9g} is kept (.partial)")
    return None
