"""Synchronization metrics of a distance record d(t) (docs/design.md §2.7).

The first time after which d stays below a threshold (``t_sync``) is
ill-conditioned on a d that oscillates under a decaying envelope (the PD part
of the coupling makes d oscillate): a peak that grazes the threshold moves
``t_sync`` by a whole oscillation period when dt changes. The decay *rate* of
the envelope is the number to compare runs by. Definitions (all on samples ``(t_i, d_i)``):

* **envelope** ``env_i = max_{j >= i} d_j`` (running maximum from the right):
  nonincreasing; its **hull** is the points where ``d_i = env_i`` that are local
  maxima of d (the peaks of the oscillation), with the first maximum of d in front;
  with fewer than ``MIN_PEAKS`` peaks (a monotone d), the centres of its plateaus (a d that falls
  in steps, :func:`_plateaus`), and with fewer than ``MIN_PEAKS`` of those, every point with
  ``d_i = env_i``.
  Between hull points log d is interpolated linearly in t, so a level's crossing
  time does not jump by half an oscillation.
* **where d stops falling** (``stall``): ``max d`` over the last ``tail`` fraction of
  the record (default 0.2): the ultimate bound of non-identical systems, the
  round-off level of identical ones, or (d still falling at the end) the level d
  had reached at 80 % of the run.
* **decay window**: from ``d_from = hi * max d`` (default ``hi = 0.1``: the first
  clear descent, the transient skipped) down to ``d_to``, the lowest whole decade
  below ``d_from`` that is still at least ``max(lo * max d, floor_abs, STALL * stall)``
  (default ``lo = 1e-13``; ``STALL = 10``: a decade above where d stops falling), and
  reached by the hull. ``t_from``, ``t_to``: the hull's crossing times of these levels.
* **per-decade rates** ``r_k = ln 10 / (tau_{k+1} - tau_k)``, ``tau_k`` the crossing
  time of ``d_from * 10^-k``: the local decay of each decade the window spans.
* **rate** ``sigma`` = the median of the per-decade rates (so d ~ exp(-sigma t),
  V = d^2/2 ~ exp(-2 sigma t)); **rate_err** = their spread: half the range
  between their 16th and 84th percentiles (half the whole range with fewer than 5
  decades), or the difference between the median and the window's average rate
  ``decades ln 10 / (t_to - t_from)`` if that is larger (a few slow decades). A rate
  that differs between decades says so in its uncertainty.
* **resolved** (:func:`verdict`): the window spans at least ``MIN_DECADES`` decades and
  ``MIN_SAMPLES`` samples of d, and the spread is at most ``MAX_REL_ERR`` of the rate;
  otherwise a code and a reason.
* **t_sync**: the time of the first sample after the last sample with
  ``d >= threshold`` (``t_0`` if d never reaches it; ``inf`` if the last
  sample is still at or above it; NaN d counts as above).
* **t_fit**: the time where the fitted envelope ``exp(a - sigma t)`` crosses the
  threshold, ``a`` the median over the window's levels of ``log d_k + sigma tau_k``.
* **bound** (practical synchronization, ultimate bound): ``max d`` over the
  last ``tail`` fraction of the run, for runs that cannot synchronize exactly.

No formula of the step cuts the window: where the step limits what d can show, the
per-decade rates differ (the spread) and the same run at half the step differs
(``fmu-sync run SCENE --convergence``). For a forced impacting pair a single start
state's rate is one sample: :mod:`.ensemble` gives the statistic over start states.

For compiled sweeps with O(1) memory per run, :func:`decimator` keeps a
fixed-size buffer of block maxima of d (block length doubling when full, the
maximum and its time kept, so the envelope survives decimation) plus the exact
``t_sync`` and running tail maximum; :func:`decimated_metrics` evaluates the
same metrics from it.

This module imports only numpy and numba (no other module of the project).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from .jit import njit

__all__ = ["SyncMetrics", "sync_metrics", "metrics_kernel", "decimator", "decimator_push",
           "decimated_metrics", "decimated_kernel", "HI", "LO", "TAIL", "STALL", "MIN_PEAKS", "MIN_DECADES",
           "MAX_REL_ERR", "MIN_SAMPLES", "RESOLVED", "NO_RECORD", "NO_DESCENT", "TOO_FEW_DECADES", "SPREAD",
           "FEW_SAMPLES", "verdict",
           "reason_text", "REASON_NAMES"]

HI = 0.1          #: the window starts where the envelope falls below HI * max(d)
LO = 1e-13        #: ... and ends at LO * max(d) at the lowest (or where d stops falling)
TAIL = 0.2        #: the ultimate bound (where d stops falling) is max d over the last TAIL of the run
STALL = 10.0      #: the window ends at least STALL times above where d stops falling
MIN_PEAKS = 8     #: fewer envelope peaks than this: the hull is every envelope point
#: A rate is resolved when its window spans at least MIN_DECADES decades and MIN_SAMPLES samples
#: of d (fewer: the record or the step, not the law, decides it) and its spread (rate_err) is at
#: most MAX_REL_ERR of it.
MIN_DECADES = 2
MIN_SAMPLES = 20
MAX_REL_ERR = 0.5

#: Verdict codes (:func:`verdict`), the same in the compiled sweeps' tables.
RESOLVED, NO_RECORD, NO_DESCENT, TOO_FEW_DECADES, SPREAD, FEW_SAMPLES = range(6)
REASON_NAMES = ("resolved", "no record", "no descent", "too few decades", "spread", "few samples")


@njit(cache=True)
def verdict(rate, err, decades, samples):
    """The verdict code of a rate (:data:`RESOLVED` ... :data:`FEW_SAMPLES`) from the window's
    whole decades, the samples of d in it, the median per-decade rate and its spread."""
    if decades < 0:
        return NO_RECORD
    if decades == 0 or not rate > 0.0:
        return NO_DESCENT
    if decades < MIN_DECADES:
        return TOO_FEW_DECADES
    if samples < MIN_SAMPLES:
        return FEW_SAMPLES
    if not (err <= MAX_REL_ERR * rate):
        return SPREAD
    return RESOLVED


def reason_text(code, rate=math.nan, err=math.nan, decades=0, stall=math.nan, d_from=math.nan) -> str:
    """Why a rate means nothing, in words ('' when resolved); the numbers are optional (``stall``:
    where d stops falling, ``d_from``: the window's top, a tenth of max d)."""
    code = int(code) if code == code else NO_RECORD
    if code == RESOLVED:
        return ""
    if code == NO_RECORD:
        return "no record to fit (fewer than 3 finite samples, or d is 0 throughout)"
    at = f" (it stops falling at about {stall:.2g})" if stall == stall and stall > 0 else ""
    if code == NO_DESCENT:
        top = f" ({d_from:.2g})" if d_from == d_from and d_from > 0 else ""
        if stall == stall and d_from == d_from and stall >= d_from > 0:
            return f"d never falls below a tenth of its maximum{top}: it stops falling at about {stall:.2g}"
        if stall == stall and stall > 0 and d_from == d_from and STALL * stall * 10.0 >= d_from:
            return (f"the fit window, from a tenth of d's maximum{top} down to {STALL:g} times the level where d "
                    f"stops falling ({STALL * stall:.2g}; d stops at about {stall:.2g}, its largest value over the "
                    f"last {TAIL:.0%} of the run), spans less than one decade, too little for a rate")
        return f"d never falls a decade below a tenth of its maximum{top}"
    if code == TOO_FEW_DECADES:
        return (f"d falls through {int(decades)} whole decade(s) below a tenth of its maximum before it stops "
                f"falling or the run ends{at}; at least {MIN_DECADES} are needed")
    if code == FEW_SAMPLES:
        return (f"d falls through its window within fewer than {MIN_SAMPLES} samples: the record or the step, "
                "not the law, decides the rate (record more often or take a smaller step)")
    return (f"the local decay rate varies too much across the window: spread {err:.2g} 1/s exceeds "
            f"{MAX_REL_ERR:.0%} of the median {rate:.3g} 1/s")


class SyncMetrics(NamedTuple):
    """Synchronization metrics of one distance record (see the module docstring)."""

    rate: float        #: decay rate sigma: median of the per-decade rates (1/s); NaN without a window
    rate_err: float    #: their spread (half the 16-84 % range, or |median - window average|; 1/s)
    t_from: float      #: decay window start (the hull crosses d_from)
    t_to: float        #: decay window end (the hull crosses d_to)
    decades: int       #: whole decades the window spans
    t_sync: float      #: time after which d stays below ``threshold`` (inf: never)
    t_fit: float       #: time where the fitted envelope crosses ``threshold``
    bound: float       #: ultimate bound: max d over the last ``tail`` of the run
    threshold: float   #: the threshold of t_sync (absolute, or threshold_rel * d0)
    d_from: float = math.nan     #: the window's top level (HI * max d)
    d_to: float = math.nan       #: the window's end level
    decade_rates: tuple = ()     #: the local rate of each decade of the window (1/s)
    code: int = NO_RECORD        #: verdict code (:func:`verdict`)
    reason: str = ""             #: why the rate means nothing ('' when resolved)
    d0: float = math.nan         #: d at the first sample
    threshold_rel: float = math.nan  #: the relative threshold asked for (NaN: absolute only)
    intercept: float = math.nan  #: a of the fitted envelope exp(a - rate t)

    @property
    def resolved(self) -> bool:
        """The rate means something (:func:`verdict`); otherwise show "—" and :attr:`reason`."""
        return self.code == RESOLVED

    @property
    def starts_below(self) -> bool:
        """d starts below the threshold: t_sync says nothing about synchronization."""
        return bool(self.d0 < self.threshold)

    def rate_text(self) -> str:
        """``rate ± err 1/s`` when resolved, else ``— (reason)``."""
        if not self.resolved:
            return f"— ({self.reason})"
        return f"{self.rate:.4g} ± {self.rate_err:.2g} 1/s"

    def window_text(self) -> str:
        """The decay window: times, levels and decades (empty without one)."""
        if not self.decades > 0:
            return ""
        return (f"window [{self.t_from:.4g}, {self.t_to:.4g}] s, d from {self.d_from:.3g} to {self.d_to:.3g} "
                f"({self.decades} decades; per-decade rates {min(self.decade_rates):.3g} to "
                f"{max(self.decade_rates):.3g} 1/s)")

    def summary(self) -> str:
        w = self.window_text()
        r = "rate " + self.rate_text() + (f" ({w})" if w and self.resolved else "")
        ts = "never" if math.isinf(self.t_sync) else f"{self.t_sync:.4g} s"
        if self.starts_below:
            ts += f" (d0 = {self.d0:.3g} already below the threshold: says nothing)"
        return f"{r}; t_sync(d < {self.threshold:g}) = {ts}; ultimate bound {self.bound:.3g}"


@njit(cache=True)
def _crossing(ht, hy, nh, y):
    """Time where the hull (ht, hy = log d, nh points, hy nonincreasing) first reaches log level
    y, log-linear between hull points; NaN if it never does."""
    for j in range(nh):
        if hy[j] <= y:
            if j == 0:
                return ht[0]
            return ht[j - 1] + (ht[j] - ht[j - 1]) * (hy[j - 1] - y) / (hy[j - 1] - hy[j])
    return np.nan


@njit(cache=True)
def _plateaus(t, d, env, imax, M, ht, hy):
    """The hull of a d that falls without oscillating, in steps (the energy norm of a damped
    oscillation: d' = 0 where the velocity vanishes): after the first maximum ``ht[0]``, the
    envelope points where the decay speed -(log d)' is locally slowest (the plateaus' centres),
    each refined by a parabola through the three decay speeds around it. These points sit at one
    phase of each oscillation, so they lie on the line exp(-sigma t) itself, where every envelope
    point would bend the hull by the oscillation's phase at each level (a bias of up to a few %
    over few decades, docs/design.md §2.7). A plateau decays slower than half the mean speed
    after the first maximum (a smooth exp(-sigma t) has none and keeps every envelope point).
    Returns the hull's length."""
    nh = 1
    # the mean decay speed after the first maximum: a plateau's centre decays far slower than it (a
    # d that falls smoothly, exp(-sigma t), has none: its speed's round-off wiggles are no plateaus)
    j = M - 1
    while j > imax and not d[j] > 0.0:
        j -= 1
    if j <= imax:
        return nh
    slow = 0.5 * (math.log(d[imax]) - math.log(d[j])) / (t[j] - t[imax])
    s0 = np.inf     # decay speeds between samples i-1, i and i, i+1 (s1) and i+1, i+2 (s2)
    for i in range(imax + 1, M - 2):
        if not (d[i] > 0.0 and d[i + 1] > 0.0 and d[i + 2] > 0.0 and d[i - 1] > 0.0):
            s0 = np.inf
            continue
        s1 = (math.log(d[i]) - math.log(d[i + 1])) / (t[i + 1] - t[i])
        if s0 == np.inf:
            s0 = (math.log(d[i - 1]) - math.log(d[i])) / (t[i] - t[i - 1])
        s2 = (math.log(d[i + 1]) - math.log(d[i + 2])) / (t[i + 2] - t[i + 1])
        if s1 < s0 and s1 <= s2 and s1 < slow and d[i] == env[i]:
            # the slowest decay lies in (t[i], t[i+1]): the parabola through the speeds at the
            # interval midpoints, its vertex tm; log d there by the speeds integrated
            h = 0.5 * (t[i + 2] - t[i])
            den = s0 - 2.0 * s1 + s2
            x = 0.5 * (s0 - s2) / den if den > 0.0 else 0.0
            x = min(max(x, -0.5), 0.5)
            tm = 0.5 * (t[i] + t[i + 1]) + x * h
            ht[nh] = tm
            hy[nh] = math.log(d[i]) - s1 * (tm - t[i])
            nh += 1
        s0 = s1
    return nh


@njit(cache=True)
def metrics_kernel(t, d, threshold, hi, lo, floor_abs, tail):
    """The metrics of ``(t, d)`` (arrays of equal length, t increasing).

    Returns ``(rate, rate_err, t_from, t_to, decades, t_sync, t_fit, bound, code, d_from, d_to,
    stall, intercept, decade_rates)``. Samples from the first non-finite d on are ignored by the
    window (they count as "above" for t_sync and make the bound inf)."""
    N = t.shape[0]
    nan = np.nan
    none = np.empty(0)
    if N == 0:
        return nan, nan, nan, nan, -1, nan, nan, nan, NO_RECORD, nan, nan, nan, nan, none
    # t_sync: first sample after the last one with d >= threshold (NaN counts as above)
    last_above = -1
    for i in range(N - 1, -1, -1):
        if not (d[i] < threshold):
            last_above = i
            break
    if last_above < 0:
        t_sync = t[0]
    elif last_above == N - 1:
        t_sync = np.inf
    else:
        t_sync = t[last_above + 1]
    # finite prefix
    M = N
    for i in range(N):
        if not math.isfinite(d[i]):
            M = i
            break
    # ultimate bound over the last `tail` of the run
    t_tail = t[N - 1] - tail * (t[N - 1] - t[0])
    bound = -np.inf
    for i in range(N - 1, -1, -1):
        if t[i] < t_tail:
            break
        v = d[i]
        if not math.isfinite(v):
            bound = np.inf
            break
        if v > bound:
            bound = v
    if M < 3:
        return nan, nan, nan, nan, -1, t_sync, nan, bound, NO_RECORD, nan, nan, nan, nan, none
    # where d stops falling: max d over the last `tail` of the finite prefix
    t_tail = t[M - 1] - tail * (t[M - 1] - t[0])
    stall = 0.0
    for i in range(M - 1, -1, -1):
        if t[i] < t_tail:
            break
        if d[i] > stall:
            stall = d[i]
    env = np.empty(M)
    m = -np.inf
    for i in range(M - 1, -1, -1):
        if d[i] > m:
            m = d[i]
        env[i] = m
    dmax = env[0]
    if not dmax > 0.0:
        return nan, nan, nan, nan, -1, t_sync, nan, bound, NO_RECORD, nan, nan, stall, nan, none
    imax = 0
    while d[imax] != dmax:
        imax += 1
    # the hull: the first maximum, then the envelope's peaks (or every envelope point)
    ht = np.empty(M - imax)
    hy = np.empty(M - imax)
    ht[0] = t[imax]
    hy[0] = math.log(dmax)
    nh = 1
    for i in range(imax + 1, M):
        if d[i] > 0.0 and d[i] == env[i] and d[i - 1] < d[i] and (i + 1 == M or d[i] >= d[i + 1]):
            ht[nh] = t[i]
            hy[nh] = math.log(d[i])
            nh += 1
    if nh - 1 < MIN_PEAKS:
        nh = _plateaus(t, d, env, imax, M, ht, hy)
    if nh - 1 < MIN_PEAKS:
        nh = 1
        for i in range(imax + 1, M):
            if d[i] > 0.0 and d[i] == env[i]:
                ht[nh] = t[i]
                hy[nh] = math.log(d[i])
                nh += 1
    d_from = hi * dmax
    end = max(lo * dmax, floor_abs, STALL * stall)
    low = hy[nh - 1]          # the lowest level the hull reaches
    if end < math.exp(low):
        end = math.exp(low)
    if not end < d_from:
        return nan, nan, nan, nan, 0, t_sync, nan, bound, NO_DESCENT, d_from, nan, stall, nan, none
    decades = int(math.floor(math.log10(d_from / end) + 1e-9))
    y0 = math.log(d_from)
    ln10 = math.log(10.0)
    tau = np.empty(decades + 1)
    for k in range(decades + 1):
        tau[k] = _crossing(ht, hy, nh, y0 - k * ln10)
    d_to = d_from * 10.0 ** (-decades)
    if decades == 0:
        return nan, nan, tau[0], tau[0], 0, t_sync, nan, bound, NO_DESCENT, d_from, d_to, stall, nan, none
    samples = 0
    for i in range(imax, M):
        if tau[0] <= t[i] <= tau[decades]:
            samples += 1
    rates = np.empty(decades)
    for k in range(decades):
        span = tau[k + 1] - tau[k]
        rates[k] = ln10 / span if span > 0.0 else np.inf
    rate = np.median(rates)
    if decades < 5:
        err = 0.5 * (np.max(rates) - np.min(rates))
    else:
        err = 0.5 * (np.percentile(rates, 84.0) - np.percentile(rates, 16.0))
    # a few slow (or fast) decades move the window's average rate away from the median: the
    # uncertainty covers that difference too
    mean = decades * ln10 / (tau[decades] - tau[0]) if tau[decades] > tau[0] else np.inf
    err = max(err, abs(mean - rate))
    a = np.empty(decades + 1)
    for k in range(decades + 1):
        a[k] = y0 - k * ln10 + rate * tau[k]
    intercept = np.median(a)
    t_fit = (intercept - math.log(threshold)) / rate if rate > 0.0 and math.isfinite(rate) and threshold > 0.0 else nan
    return (rate, err, tau[0], tau[decades], decades, t_sync, t_fit, bound, verdict(rate, err, decades, samples),
            d_from, d_to, stall, intercept, rates)


def _pack(r, threshold, d, threshold_rel=math.nan) -> SyncMetrics:
    rate, err, ta, tb, dec, ts, tf, bound, code, d_from, d_to, stall, a, rates = r
    d0 = float(d[0]) if d is not None and len(d) else math.nan
    why = reason_text(code, float(rate), float(err), int(dec), float(stall), float(d_from))
    return SyncMetrics(float(rate), float(err), float(ta), float(tb), max(int(dec), 0), float(ts), float(tf),
                       float(bound), float(threshold), float(d_from), float(d_to),
                       tuple(float(x) for x in rates), int(code), why, d0, float(threshold_rel), float(a))


def _check(threshold, hi, lo, floor_abs, tail):
    threshold = float(threshold)
    if not (math.isfinite(threshold) and threshold > 0.0):
        raise ValueError(f"threshold must be a positive finite distance, got {threshold}")
    if not 0.0 < lo < hi <= 1.0:
        raise ValueError(f"the decay window needs 0 < lo < hi <= 1, got lo = {lo}, hi = {hi}")
    if not (math.isfinite(floor_abs) and floor_abs >= 0.0):
        raise ValueError(f"floor_abs must be finite and >= 0, got {floor_abs}")
    if not 0.0 < tail <= 1.0:
        raise ValueError(f"tail must lie in (0, 1], got {tail}")
    return threshold, float(hi), float(lo), float(floor_abs), float(tail)


def sync_metrics(t, d, threshold: float = 1e-6, hi: float = HI, lo: float = LO,
                 floor_abs: float = 0.0, tail: float = TAIL, threshold_rel: float | None = None) -> SyncMetrics:
    """:class:`SyncMetrics` of a distance record ``d`` sampled at times ``t``.

    ``threshold_rel``: a threshold for t_sync relative to d0 = d[0]; when given, ``threshold_rel * d0``
    replaces the absolute ``threshold``. ``hi``, ``lo``, ``tail``: the window (module docstring);
    ``floor_abs``: an absolute level the window must not go below (default 0: none)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    d = np.ascontiguousarray(d, dtype=np.float64)
    if t.ndim != 1 or t.shape != d.shape:
        raise ValueError(f"t and d must be 1-D arrays of equal length, got shapes {t.shape} and {d.shape}")
    rel = math.nan
    if threshold_rel is not None:
        rel = float(threshold_rel)
        if not (math.isfinite(rel) and 0.0 < rel < 1.0):
            raise ValueError(f"threshold_rel must lie in (0, 1) (a fraction of d0), got {threshold_rel}")
        if d.size and d[0] > 0.0 and math.isfinite(d[0]):
            threshold = rel * float(d[0])
    threshold, hi, lo, floor_abs, tail = _check(threshold, hi, lo, floor_abs, tail)
    return _pack(metrics_kernel(t, d, threshold, hi, lo, floor_abs, tail), threshold, d, rel)


# ------------------------------------------------------------ O(1)-memory record
# state vector of the decimator
_N, _BLOCK, _FILL, _BMAX, _BT, _LAST_ABOVE, _AFTER, _THR, _T0, _T1, _TAIL_START, _TAIL_MAX = range(12)
_STATE = 12


@njit(cache=True)
def decimator_init(size, threshold, t_tail_start):
    """Buffers ``(bt, bd, state)`` for :func:`decimator_push` (``size`` even >= 16).

    ``t_tail_start``: the ultimate bound is the exact max of d over t >= it."""
    bt = np.full(size, np.nan)
    bd = np.full(size, np.nan)
    st = np.zeros(_STATE)
    st[_BLOCK] = 1.0
    st[_BMAX] = -np.inf
    st[_LAST_ABOVE] = np.nan
    st[_AFTER] = np.nan
    st[_THR] = threshold
    st[_T0] = np.nan
    st[_TAIL_START] = t_tail_start
    st[_TAIL_MAX] = -np.inf
    return bt, bd, st


@njit(cache=True)
def decimator_push(bt, bd, st, t, d):
    """Add the sample ``(t, d)``: O(1) time and memory (compiled-loop friendly)."""
    if st[_T0] != st[_T0]:
        st[_T0] = t
    st[_T1] = t
    if not (d < st[_THR]):
        st[_LAST_ABOVE] = t
        st[_AFTER] = np.nan
    elif st[_AFTER] != st[_AFTER] and st[_LAST_ABOVE] == st[_LAST_ABOVE]:
        st[_AFTER] = t
    if t >= st[_TAIL_START]:
        if not (d <= st[_TAIL_MAX]):  # NaN wins
            st[_TAIL_MAX] = d if d == d else np.inf
    # block maximum (NaN wins: it must stay visible)
    if st[_FILL] == 0.0 or (st[_BMAX] == st[_BMAX] and not (d <= st[_BMAX])):
        st[_BMAX] = d
        st[_BT] = t
    st[_FILL] += 1.0
    if st[_FILL] >= st[_BLOCK]:
        n = int(st[_N])
        size = bt.shape[0]
        if n == size:  # full: merge neighbours, double the block
            for k in range(size // 2):
                a = 2 * k
                if bd[a] == bd[a] and not (bd[a + 1] <= bd[a]):
                    bt[k] = bt[a + 1]
                    bd[k] = bd[a + 1]
                else:
                    bt[k] = bt[a]
                    bd[k] = bd[a]
            for k in range(size // 2, size):
                bt[k] = np.nan
                bd[k] = np.nan
            n = size // 2
            st[_BLOCK] *= 2.0
        bt[n] = st[_BT]
        bd[n] = st[_BMAX]
        st[_N] = n + 1
        st[_FILL] = 0.0
        st[_BMAX] = -np.inf


@njit(cache=True)
def decimated_kernel(bt, bd, st, hi, lo, floor_abs, tail):
    """:func:`metrics_kernel` on the buffer, with the exact t_sync and bound of the stream."""
    n = int(st[_N])
    m = n + (1 if st[_FILL] > 0.0 else 0)
    t = np.empty(m)
    d = np.empty(m)
    for i in range(n):
        t[i] = bt[i]
        d[i] = bd[i]
    if m > n:
        t[n] = st[_BT]
        d[n] = st[_BMAX]
    rate, err, ta, tb, dec, _, t_fit, bound, code, d_from, d_to, stall, a, rates = metrics_kernel(
        t, d, st[_THR], hi, lo, floor_abs, tail)
    if st[_LAST_ABOVE] != st[_LAST_ABOVE]:
        t_sync = st[_T0]
    elif st[_AFTER] != st[_AFTER]:
        t_sync = np.inf
    else:
        t_sync = st[_AFTER]
    if st[_TAIL_START] > -np.inf and st[_TAIL_MAX] > -np.inf:
        bound = st[_TAIL_MAX]
    return rate, err, ta, tb, dec, t_sync, t_fit, bound, code, d_from, d_to, stall, a, rates


class decimator:
    """Fixed-memory recorder of d for the metrics (Python face of the kernels).

    ``decimator(size, threshold, t_tail_start)``; ``push(t, d)`` per sample (or
    call :func:`decimator_push` on ``.bt, .bd, .state`` from a compiled loop);
    :meth:`metrics` returns :class:`SyncMetrics`."""

    def __init__(self, size: int = 2048, threshold: float = 1e-6, t_tail_start: float = -np.inf):
        size = int(size)
        if size < 16 or size % 2:
            raise ValueError(f"size must be an even number >= 16, got {size}")
        threshold = _check(threshold, HI, LO, 0.0, TAIL)[0]
        self.bt, self.bd, self.state = decimator_init(size, threshold, float(t_tail_start))

    def push(self, t: float, d: float) -> None:
        decimator_push(self.bt, self.bd, self.state, float(t), float(d))

    def metrics(self, hi: float = HI, lo: float = LO, floor_abs: float = 0.0,
                tail: float = TAIL) -> SyncMetrics:
        return decimated_metrics(self.bt, self.bd, self.state, hi, lo, floor_abs, tail)


def decimated_metrics(bt, bd, state, hi: float = HI, lo: float = LO, floor_abs: float = 0.0,
                      tail: float = TAIL) -> SyncMetrics:
    """:class:`SyncMetrics` from a decimator's buffers (see :class:`decimator`)."""
    thr, hi, lo, floor_abs, tail = _check(state[_THR], hi, lo, floor_abs, tail)
    n = int(state[_N])
    return _pack(decimated_kernel(bt, bd, state, hi, lo, floor_abs, tail), thr, bd[:n])
