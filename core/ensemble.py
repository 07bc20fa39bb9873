"""The decay rate of a coupled pair as a statistic over start states (docs/design.md §2.7).

A forced impacting pair is likely chaotic: the decay rate of d along one trajectory
(:func:`.metrics.sync_metrics`) is a sample, and two laws compared on one start state
can swap places on another. The number to compare laws by is the distribution of the
rate over start states: :func:`sync_rate` runs the pair from ``n_starts`` start states
(the given one first, the others drawn by :func:`start_states`) and returns an
:class:`EnsembleRate`: the median of the resolved rates and their interquartile range.

The law is taken by name (any law of :data:`.coupling.LAWS`); ``run`` runs one start
state some other way (co-simulation: :func:`fmu_sync.sync_rate` with ``mode="cosim"``).
"""
from __future__ import annotations

import math
from typing import Callable, NamedTuple

import numpy as np

from .errors import RunFailed
from .metrics import sync_metrics

__all__ = ["EnsembleRate", "ensemble_rate", "start_states", "sync_rate", "N_STARTS", "SPREAD"]

N_STARTS = 16     #: start states of an ensemble rate by default
SPREAD = 0.5      #: the start box: the two given states' box, widened by SPREAD of its size each side


class EnsembleRate(NamedTuple):
    """The decay rate of d over start states: median and interquartile range of the resolved
    per-start rates (1/s), with every start's rate (NaN where unresolved) and reason."""

    median: float
    q25: float
    q75: float
    n_resolved: int
    n_starts: int
    rates: tuple      #: the rate of each start (NaN: unresolved or failed)
    reasons: tuple    #: why each start's rate is missing ('' where resolved)
    starts: tuple     #: the start states ((q1, u1), (q2, u2)) of each run
    law: str | None = None

    @property
    def iqr(self) -> float:
        return self.q75 - self.q25

    def text(self) -> str:
        """``median [q25, q75] 1/s (k of N starts)``, or why there is none."""
        if not self.n_resolved:
            return f"— (no start of {self.n_starts} gives a resolved rate)"
        return (f"{self.median:.3g} [{self.q25:.3g}, {self.q75:.3g}] 1/s "
                f"({self.n_resolved} of {self.n_starts} starts)")


def ensemble_rate(metrics, starts=(), law=None) -> EnsembleRate:
    """The :class:`EnsembleRate` of per-start :class:`~.metrics.SyncMetrics` (None: the run
    failed) or ``(None, reason)`` pairs."""
    rates, reasons = [], []
    for m in metrics:
        if isinstance(m, tuple) and m[0] is None:
            rates.append(math.nan)
            reasons.append(str(m[1]))
        elif m is not None and m.resolved:
            rates.append(float(m.rate))
            reasons.append("")
        else:
            rates.append(math.nan)
            reasons.append("the run failed" if m is None else m.reason)
    ok = np.array([r for r in rates if r == r])
    med, q25, q75 = ((float(np.median(ok)), float(np.percentile(ok, 25)), float(np.percentile(ok, 75)))
                     if ok.size else (math.nan,) * 3)
    return EnsembleRate(med, q25, q75, int(ok.size), len(rates), tuple(rates), tuple(reasons), tuple(starts), law)


def _admissible(system, q) -> bool:
    sa = system.arrays()
    return float(np.dot(sa.w, q) + sa.g0) >= 0.0


def start_states(system, x1, x2, n_starts: int = N_STARTS, seed: int = 0, spread: float = SPREAD) -> list:
    """``n_starts`` start-state pairs ``((q1, u1), (q2, u2))``: the given one first, then pairs
    drawn uniformly (numpy ``default_rng(seed)``) from the box spanned by the two given states,
    widened by ``spread`` of its size on each side (at least 0.1 wide), each system's q on the
    admissible side of the wall (g(q) >= 0; drawn again otherwise)."""
    n_starts = int(n_starts)
    if n_starts < 1:
        raise ValueError(f"n_starts must be a positive whole number, got {n_starts}")
    if not (math.isfinite(spread) and spread >= 0.0):
        raise ValueError(f"spread must be finite and >= 0, got {spread}")
    q1, u1 = (np.atleast_1d(np.asarray(a, dtype=float)) for a in x1)
    q2, u2 = (np.atleast_1d(np.asarray(a, dtype=float)) for a in x2)
    lo = np.minimum(np.r_[q1, u1], np.r_[q2, u2])
    hi = np.maximum(np.r_[q1, u1], np.r_[q2, u2])
    pad = np.maximum(spread * (hi - lo), 0.05)
    lo, hi = lo - pad, hi + pad
    n = q1.size
    rng = np.random.default_rng(seed)
    out = [((q1, u1), (q2, u2))]
    while len(out) < n_starts:
        pair = []
        for _ in range(2):
            for _try in range(1000):
                x = rng.uniform(lo, hi)
                if _admissible(system, x[:n]):
                    break
            else:
                raise ValueError("no admissible start state found in the start box "
                                 f"{lo.tolist()} .. {hi.tolist()} (g(q) >= 0 never held)")
            pair.append((x[:n].copy(), x[n:].copy()))
        out.append(tuple(pair))
    if n == 1:
        out = [tuple((float(q[0]), float(u[0])) for q, u in p) for p in out]
    return out


def sync_rate(system, law: str | None = "switching", n_starts: int = N_STARTS, *, x1, x2, t_end: float,
              dt: float, Kp=0.0, Kd=0.0, seed: int = 0, spread: float = SPREAD, threshold: float = 1e-6,
              run: Callable | None = None, progress: Callable | None = None, **options) -> EnsembleRate:
    """The decay rate of d of the pair ``system`` coupled by ``law`` over ``n_starts`` start
    states (:func:`start_states` around ``x1, x2``): median and interquartile range.

    Each start runs ``simulate_pair(system, a, b, t_end, dt, coupling=law, Kp=Kp, Kd=Kd,
    **options)`` (``run(a, b)`` instead when given: any callable returning a result with
    ``.sync()``). A start whose run fails counts as unresolved, with the failure as its reason.
    Bad arguments raise before anything runs (the first start's run plan)."""
    from .pair import simulate_pair
    law = None if law in (None, "none") else law
    starts = start_states(system, x1, x2, n_starts, seed, spread)
    if run is None:
        def run(a, b):
            return simulate_pair(system, a, b, t_end, dt, coupling=law, Kp=Kp, Kd=Kd, **options)
    out = []
    for k, (a, b) in enumerate(starts):
        try:
            out.append(run(a, b).sync(threshold))
        except RunFailed as exc:
            out.append((None, f"the run failed: {exc}"))
        if progress is not None:
            progress((k + 1) / len(starts))
    return ensemble_rate(out, starts, law)
