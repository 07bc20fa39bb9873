"""Synchronization metrics of a distance record d(t) (robust to the step size).

The first time after which d stays below a threshold (``t_sync``) is
ill-conditioned on a d that oscillates under a decaying envelope (the PD part
of the coupling makes d oscillate): a peak that grazes the threshold moves
``t_sync`` by a whole oscillation period when dt changes. The decay *rate* of
the envelope is well-conditioned. Definitions (all on samples ``(t_i, d_i)``):

* **envelope** ``env_i = max_{j >= i} d_j`` (running maximum from the right):
  nonincreasing; ``d_i = env_i`` marks a point of the upper envelope.
* **decay window** ``[t_a, t_b]``: ``t_a`` the first time ``env <= hi * dmax``
  (``dmax = max d``, default ``hi = 0.1``: the transient is skipped), ``t_b``
  the first time ``env <= floor = max(lo * dmax, floor_abs)`` (default
  ``lo = 1e-10``, above round-off), or the last sample if d never gets there.
* **fit points**: the envelope points in the window that are local maxima of d
  (the peaks of the oscillation, ``d_{i-1} < d_i >= d_{i+1}``); if there are
  fewer than ``MIN_PEAKS`` (a monotone d), every envelope point of the window.
  d = 0 points are skipped (log 0).
* **rate** ``sigma``: least squares of ``log d = a - sigma t`` over the fit
  points (so d ~ exp(-sigma t), V = d^2/2 ~ exp(-2 sigma t)).
* **rate_err**: standard uncertainty of sigma, the larger of the least-squares
  standard error of the slope and half the difference of the slopes fitted on
  the two halves of the window (a non-exponential decay shows up there even
  when the residuals of the global fit are correlated and small).
* **t_sync**: the time of the first sample after the last sample with
  ``d >= threshold`` (``t_0`` if d never reaches it; ``inf`` if the last
  sample is still at or above it; NaN d counts as above).
* **t_fit**: the time where the fitted envelope ``exp(a - sigma t)`` crosses
  the threshold (well-conditioned companion of t_sync; NaN without a fit).
* **bound** (practical synchronization, ultimate bound): ``max d`` over the
  last ``tail`` fraction of the run (default 0.2), for runs that cannot
  synchronize exactly (non-identical systems).

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
           "decimated_metrics", "decimated_kernel", "HI", "LO", "TAIL", "MIN_PEAKS", "rate_verdict",
           "resolution_floor", "MAX_REL_ERR", "MAX_RESIDUAL", "MIN_RESOLVED_PEAKS", "RESOLUTION_FACTOR"]

HI = 0.1          #: window starts when the envelope falls below HI * max(d)
LO = 1e-10        #: window ends when the envelope falls below LO * max(d) (or floor_abs)
TAIL = 0.2        #: the ultimate bound is max d over the last TAIL of the run
MIN_PEAKS = 8     #: fewer envelope peaks than this: fit all envelope points


#: A decay rate is shown only when resolved (:func:`rate_verdict`): its standard uncertainty at
#: most MAX_REL_ERR of it, the RMS residual of log d about the fit at most MAX_RESIDUAL (a factor
#: e^0.5 = 1.65), at least MIN_RESOLVED_PEAKS envelope peaks in the window (or 2 MIN_RESOLVED_PEAKS
#: envelope points of a monotone d), and d above the window's floor when the window starts.
MAX_REL_ERR = 0.2
MAX_RESIDUAL = 0.5
MIN_RESOLVED_PEAKS = 4
#: The default window ends at the first power of ten at or above RESOLUTION_FACTOR * h * v: h the
#: step that decides an impact (dt, or H in co-simulation), v the largest impact speed in the
#: P-norm, sqrt(u^T Q u). Below h * v the step, not the law, decides how d passes an impact
#: (d moves by up to ~h v there); rounding up to a decade puts runs whose steps differ by a factor
#: of up to 10 on the same window, so their rates compare (docs/design.md §2.7).
RESOLUTION_FACTOR = 5.0


@njit(cache=True)
def resolution_floor(h, speed):
    """The level the default decay window ends at, at least: the first power of ten at or above
    RESOLUTION_FACTOR * h * speed (``speed``: the largest impact speed in the P-norm; 0 without
    impacts or with h = 0)."""
    x = RESOLUTION_FACTOR * h * speed
    if not (x > 0.0 and x < np.inf):
        return 0.0
    return 10.0 ** math.ceil(math.log10(x))


def rate_verdict(rate, rate_err, n_fit=None, peaks=None, residual=None, d_top=None, floor=None) -> str:
    """Why a fitted decay rate means nothing ('' when it is resolved).

    The criteria (constants above): a finite positive rate; ``rate_err <= MAX_REL_ERR * rate``;
    ``residual <= MAX_RESIDUAL``; enough peaks; d not already at the floor (``d_top`` the largest
    d, ``floor`` the window's end level). Arguments left None are not checked (a sweep table
    keeps only the rate and its uncertainty)."""
    if d_top is not None and floor is not None and floor > 0.0 and not d_top > 10.0 * floor:
        return (f"d never rises a decade above the level the step resolves (max d = {d_top:.3g}, "
                f"window floor {floor:.3g})")
    if rate is None or not math.isfinite(rate):
        return "no decay window (d never fell to a tenth of its maximum above the floor)"
    if not rate > 0.0:
        return f"d does not decay (fitted rate {rate:.3g} 1/s)"
    if peaks is not None and n_fit is not None and peaks < MIN_RESOLVED_PEAKS and n_fit < 2 * MIN_RESOLVED_PEAKS:
        return f"d collapsed to the floor within {peaks} peaks ({n_fit} envelope points fitted)"
    if not (math.isfinite(rate_err) and rate_err <= MAX_REL_ERR * rate):
        return (f"uncertainty {rate_err:.2g} 1/s exceeds {MAX_REL_ERR:.0%} of the rate {rate:.3g} 1/s")
    if residual is not None and not residual <= MAX_RESIDUAL:
        return f"d is not exponential on the window (fit residual {residual:.2g} in log d > {MAX_RESIDUAL})"
    return ""


class SyncMetrics(NamedTuple):
    """Synchronization metrics of one distance record (see the module docstring)."""

    rate: float        #: decay rate sigma of the envelope of d (1/s); NaN without a decay window
    rate_err: float    #: standard uncertainty of ``rate``
    t_from: float      #: decay window start
    t_to: float        #: decay window end
    n_fit: int         #: number of points fitted
    t_sync: float      #: time after which d stays below ``threshold`` (inf: never)
    t_fit: float       #: time where the fitted envelope crosses ``threshold``
    bound: float       #: ultimate bound: max d over the last ``tail`` of the run
    threshold: float   #: the threshold of t_sync (absolute, or threshold_rel * d0)
    residual: float = math.nan   #: RMS residual of log d about the fitted line
    peaks: int = 0               #: envelope peaks in the window
    floor: float = 0.0           #: the level the window ends at (max(lo * max d, floor_abs))
    reason: str = ""             #: why the rate means nothing ('' when resolved: :func:`rate_verdict`)
    d0: float = math.nan         #: d at the first sample
    threshold_rel: float = math.nan  #: the relative threshold asked for (NaN: absolute only)

    @property
    def resolved(self) -> bool:
        """The rate means something (:func:`rate_verdict`); otherwise show "—" and :attr:`reason`."""
        return self.reason == ""

    @property
    def starts_below(self) -> bool:
        """d starts below the threshold: t_sync says nothing about synchronization."""
        return bool(self.d0 < self.threshold)

    def rate_text(self) -> str:
        """``rate ± err 1/s`` when resolved, else ``— (reason)``."""
        if not self.resolved:
            return f"— ({self.reason})"
        return f"{self.rate:.4g} ± {self.rate_err:.2g} 1/s"

    def summary(self) -> str:
        r = ("rate " + self.rate_text()
             + (f" (fit on [{self.t_from:.4g}, {self.t_to:.4g}] s, {self.n_fit} points, window down to "
                f"d = {self.floor:.3g})" if self.resolved else ""))
        ts = "never" if math.isinf(self.t_sync) else f"{self.t_sync:.4g} s"
        if self.starts_below:
            ts += f" (d0 = {self.d0:.3g} already below the threshold: says nothing)"
        return f"{r}; t_sync(d < {self.threshold:g}) = {ts}; ultimate bound {self.bound:.3g}"


@njit(cache=True)
def _slope(t, y, sel, i0, i1):
    """Least-squares slope and intercept of y(t) over the selected indices in [i0, i1).

    Returns ``(slope, intercept, stderr, count)``; slope NaN with fewer than 3 points."""
    n = 0
    st = 0.0
    sy = 0.0
    for i in range(i0, i1):
        if sel[i]:
            n += 1
            st += t[i]
            sy += y[i]
    if n < 3:
        return np.nan, np.nan, np.nan, n
    tm = st / n
    ym = sy / n
    stt = 0.0
    sty = 0.0
    for i in range(i0, i1):
        if sel[i]:
            dtm = t[i] - tm
            stt += dtm * dtm
            sty += dtm * (y[i] - ym)
    if stt <= 0.0:
        return np.nan, np.nan, np.nan, n
    b = sty / stt
    a = ym - b * tm
    rss = 0.0
    for i in range(i0, i1):
        if sel[i]:
            r = y[i] - a - b * t[i]
            rss += r * r
    se = math.sqrt(rss / (n - 2) / stt)
    return b, a, se, n


@njit(cache=True)
def metrics_kernel(t, d, threshold, hi, lo, floor_abs, tail):
    """The metrics of ``(t, d)`` (arrays of equal length, t increasing).

    Returns ``(rate, rate_err, t_from, t_to, n_fit, t_sync, t_fit, bound)``.
    Samples from the first non-finite d on are ignored by the fit (they count
    as "above" for t_sync)."""
    N = t.shape[0]
    nan = np.nan
    if N == 0:
        return nan, nan, nan, nan, 0, nan, nan, nan, nan, 0
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
        return nan, nan, nan, nan, 0, t_sync, nan, bound, nan, 0
    env = np.empty(M)
    m = -np.inf
    for i in range(M - 1, -1, -1):
        if d[i] > m:
            m = d[i]
        env[i] = m
    dmax = env[0]
    if not dmax > 0.0:
        return nan, nan, nan, nan, 0, t_sync, nan, bound, nan, 0
    top = hi * dmax
    floor = max(lo * dmax, floor_abs)
    i0 = -1
    for i in range(M):
        if env[i] <= top:
            i0 = i
            break
    if i0 < 0:
        return nan, nan, nan, nan, 0, t_sync, nan, bound, nan, 0
    i1 = M
    for i in range(i0, M):
        if env[i] <= floor:
            i1 = i + 1
            break
    sel = np.zeros(M, dtype=np.bool_)
    y = np.empty(M)
    peaks = 0
    for i in range(i0, i1):
        y[i] = math.log(d[i]) if d[i] > 0.0 else -np.inf
        if d[i] > 0.0 and d[i] == env[i]:
            left = d[i - 1] if i > 0 else -np.inf
            right = d[i + 1] if i + 1 < M else -np.inf
            if left < d[i] and d[i] >= right:
                sel[i] = True
                peaks += 1
    if peaks < MIN_PEAKS:
        for i in range(i0, i1):
            sel[i] = d[i] > 0.0 and d[i] == env[i]
    b, a, se, n = _slope(t, y, sel, i0, i1)
    if not math.isfinite(b):
        return nan, nan, t[i0], t[i1 - 1], n, t_sync, nan, bound, nan, peaks
    # the two halves of the window (by time)
    tm = 0.5 * (t[i0] + t[i1 - 1])
    ih = i0
    while ih < i1 and t[ih] < tm:
        ih += 1
    b1, _, _, _ = _slope(t, y, sel, i0, ih)
    b2, _, _, _ = _slope(t, y, sel, ih, i1)
    err = se
    if math.isfinite(b1) and math.isfinite(b2):
        err = max(err, 0.5 * abs(b1 - b2))
    rate = -b
    t_fit = (a - math.log(threshold)) / rate if rate > 0.0 and threshold > 0.0 else nan
    rss = 0.0
    for i in range(i0, i1):
        if sel[i]:
            r = y[i] - a - b * t[i]
            rss += r * r
    return rate, err, t[i0], t[i1 - 1], n, t_sync, t_fit, bound, math.sqrt(rss / n), peaks


def _pack(r, threshold, d, lo, floor_abs, threshold_rel=math.nan) -> SyncMetrics:
    rate, err, ta, tb, n, ts, tf, bound, rms, peaks = r
    fin = d[np.isfinite(d)] if d is not None else np.empty(0)
    dmax = float(fin.max()) if fin.size else math.nan
    floor = max(lo * dmax, floor_abs) if math.isfinite(dmax) else floor_abs
    d0 = float(d[0]) if d is not None and len(d) else math.nan
    why = rate_verdict(float(rate), float(err), int(n), int(peaks), float(rms), dmax, floor)
    return SyncMetrics(float(rate), float(err), float(ta), float(tb), int(n), float(ts), float(tf),
                       float(bound), float(threshold), float(rms), int(peaks), float(floor), why, d0,
                       float(threshold_rel))


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
    replaces the absolute ``threshold``. ``floor_abs``: the level the decay window
    ends at, at least (:func:`resolution_floor` is what the drivers' results pass)."""
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
    return _pack(metrics_kernel(t, d, threshold, hi, lo, floor_abs, tail), threshold, d, lo, floor_abs, rel)


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
    rate, err, ta, tb, nf, _, t_fit, bound, rms, peaks = metrics_kernel(t, d, st[_THR], hi, lo, floor_abs, tail)
    if st[_LAST_ABOVE] != st[_LAST_ABOVE]:
        t_sync = st[_T0]
    elif st[_AFTER] != st[_AFTER]:
        t_sync = np.inf
    else:
        t_sync = st[_AFTER]
    if st[_TAIL_START] > -np.inf and st[_TAIL_MAX] > -np.inf:
        bound = st[_TAIL_MAX]
    return rate, err, ta, tb, nf, t_sync, t_fit, bound, rms, peaks


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
    return _pack(decimated_kernel(bt, bd, state, hi, lo, floor_abs, tail), thr, bd[:n], lo, floor_abs)
