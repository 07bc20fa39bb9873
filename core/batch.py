"""Many coupled 1-DOF pairs in one compiled, parallel call (the sweep engine).

:func:`run_pairs1` runs R independent pairs, one per iteration of a numba
``prange`` loop (one thread per core, dynamic scheduling), with no Python per
run and no trajectory: every run keeps a fixed set of numbers (the columns
``COLUMNS``, written into one row of ``out``), so memory is O(1) per run
whatever its length.

Each run is the very loop of :func:`fmu_sync.core.pair.integrate_pair` on its
1-DOF fast path (the same step functions, the same operation order, the same
forces held over each step), so its final state, distances and impact counts
equal a single :func:`~fmu_sync.core.pair.simulate_pair` run bit for bit
(tests/test_sweep.py checks a sample of a gain map).

Per run the loop samples ``d`` at the start of every ``every``-th step and at
the end (the record grid of ``simulate_pair(record_every=every)``) and keeps:
final state, d at the start, at the end and its maximum, max |tau| over all
steps, impacts and contact episodes of each system, the time after which d
stays below the threshold (``t_sync``) and the fitted exponential decay rate
of d (:mod:`.metrics`).

Systems differ between runs only through a small table of *system groups*
(one row of floats per distinct system, see :func:`group_row`), so a sweep
over e or m needs no Python per run either.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .coupling import SWITCHING, UNCOUPLED
from .distance import ScalarGeometry
from .moreau import THETA, midpoint_step1, theta_step1
from .pair import coupling_step1

__all__ = ["run_pairs1", "COLUMNS", "COL", "OK", "DIVERGED", "REFUSED", "STATUS_NAMES", "group_row",
           "GROUP_FIELDS", "GEO_FIELDS", "empty_out",
           "metrics_from_records"]

OK = 0
DIVERGED = 1
REFUSED = 2
STATUS_NAMES = ("ok", "diverged", "refused")

#: One row of ``out`` per run.
COLUMNS = ("status", "steps", "t_stop", "q1", "u1", "q2", "u2", "d0", "d_final", "d_max", "tau_max",
           "impacts1", "impacts2", "episodes1", "episodes2", "t_sync", "decay_rate", "decay_rate_err",
           "samples")
COL = {name: i for i, name in enumerate(COLUMNS)}

#: Floats of a system group row (the scalar system of :func:`.moreau.scalar_params` plus M).
GROUP_FIELDS = ("M", "Minv", "K", "C", "f0", "B", "w", "g0", "e", "Minv_w", "W")
#: Floats of the distance geometry (:class:`.distance.ScalarGeometry`, in order).
GEO_FIELDS = ScalarGeometry._fields


def group_row(system, geo):
    """``(sys_row, geo_row, F, Omega, phi)`` of a 1-DOF system and its distance geometry:
    the floats the kernel needs, taken from the very arrays ``simulate_pair`` uses."""
    sa = system.arrays()
    if sa.M.shape[0] != 1 or sa.B.shape[1] != 1:
        raise ValueError(f"run_pairs1 runs 1-DOF systems (n = m = 1), got n = {sa.M.shape[0]}, "
                         f"m = {sa.B.shape[1]}")
    sys_row = np.array([sa.M[0, 0], sa.Minv[0, 0], sa.K[0, 0], sa.C[0, 0], sa.f0[0], sa.B[0, 0], sa.w[0],
                        sa.g0, sa.e, sa.Minv_w[0], sa.W])
    geo_row = np.array([float(x) for x in geo.scalar])
    return sys_row, geo_row, sa.F[:, 0].copy(), sa.Omega.copy(), sa.phi.copy()


def empty_out(R: int) -> np.ndarray:
    """An output table for R runs (NaN everywhere)."""
    return np.full((R, len(COLUMNS)), np.nan)


@njit(cache=True, inline="always")
def _geo(row):
    return ScalarGeometry(row[0], row[1], row[2], row[3], row[4], row[5], row[6], row[7], row[8], row[9],
                          row[10], row[11])


# ---------------------------------------------------------------------------
# PROVISIONAL decay-rate fit (to be replaced by core/metrics.py of issue 10):
# a fixed-size buffer of (t, ln d) samples, thinned by two (and its stride
# doubled) whenever it is full, and a least-squares line through the samples
# with d above threshold * 1e-3 (below that the run has synchronized).
# ---------------------------------------------------------------------------
FIT_N = 128
FIT_SIZE = 3 + 2 * FIT_N


@njit(cache=True, inline="always")
def _fit_add(buf, t, d, threshold):
    if not (d > threshold * 1e-3) or not math.isfinite(d):
        return
    buf[2] += 1.0
    if buf[2] < buf[1]:
        return
    buf[2] = 0.0
    n = int(buf[0])
    if n == FIT_N:
        for i in range(FIT_N // 2):
            buf[3 + i] = buf[3 + 2 * i]
            buf[3 + FIT_N + i] = buf[3 + FIT_N + 2 * i]
        n = FIT_N // 2
        buf[1] = 2.0 * max(buf[1], 1.0)
    buf[3 + n] = t
    buf[3 + FIT_N + n] = math.log(d)
    buf[0] = n + 1


@njit(cache=True)
def _fit_result(buf):
    """``(rate, standard error)`` of ln d = a - rate t; NaN with fewer than 3 samples."""
    n = int(buf[0])
    if n < 3:
        return np.nan, np.nan
    st = 0.0
    sy = 0.0
    for i in range(n):
        st += buf[3 + i]
        sy += buf[3 + FIT_N + i]
    tm = st / n
    ym = sy / n
    stt = 0.0
    sty = 0.0
    for i in range(n):
        dt_ = buf[3 + i] - tm
        stt += dt_ * dt_
        sty += dt_ * (buf[3 + FIT_N + i] - ym)
    if stt <= 0.0:
        return np.nan, np.nan
    slope = sty / stt
    ss = 0.0
    for i in range(n):
        r = buf[3 + FIT_N + i] - ym - slope * (buf[3 + i] - tm)
        ss += r * r
    return -slope, math.sqrt(ss / (n - 2) / stt)



# ---------------------------------------------------------------------------
# Metrics of the sampled distance, O(1) memory: d at the first sample, its
# maximum, t_sync (the first sample time after which d stays below the
# threshold, as PairResult.time_to_sync) and the decay fit.
# acc = [n_samples, d0, d_max, above_is_last, t_first_below, fit buffer...]
# ---------------------------------------------------------------------------
ACC_SIZE = 5 + FIT_SIZE


@njit(cache=True, inline="always")
def _acc_sample(acc, t, d, threshold):
    n = acc[0]
    if n == 0.0:
        acc[1] = d
        acc[2] = d
    elif d > acc[2]:
        acc[2] = d
    acc[0] = n + 1.0
    if not (d < threshold):
        acc[3] = 1.0
    elif acc[3] == 1.0 or n == 0.0:
        acc[4] = t
        acc[3] = 0.0
    _fit_add(acc[5:], t, d, threshold)


@njit(cache=True)
def _acc_finish(acc, failed, res):
    """d0, d_max, t_sync, decay rate (and its error) and the sample count into ``res``."""
    res[7] = acc[1] if acc[0] > 0 else np.nan
    res[9] = acc[2] if acc[0] > 0 else np.nan
    res[15] = np.inf if (failed or acc[3] == 1.0 or acc[0] == 0) else acc[4]
    rate, err = _fit_result(acc[5:])
    res[16] = rate
    res[17] = err
    res[18] = acc[0]


@njit(cache=True)
def metrics_from_records(t, d, tau1, tau2, n_ok, threshold, res):
    """The same metrics from recorded samples (co-simulated or n-DOF runs):
    ``t, d`` (N,), forces ``tau1, tau2`` (N, m); only the first ``n_ok`` records
    are used. Fills the d/tau columns of ``res``; state and count columns are
    the caller's."""
    acc = np.zeros(ACC_SIZE)
    tau_max = 0.0
    for i in range(n_ok):
        _acc_sample(acc, t[i], d[i], threshold)
        for j in range(tau1.shape[1]):
            a = abs(tau1[i, j])
            if a > tau_max:
                tau_max = a
            a = abs(tau2[i, j])
            if a > tau_max:
                tau_max = a
    res[8] = d[n_ok - 1] if n_ok > 0 else np.nan
    res[10] = tau_max
    _acc_finish(acc, n_ok < t.shape[0] or not math.isfinite(res[8]), res)



@njit(cache=True)
def _pair1(law, scheme, theta, p, M, F, Omega, phi, sg, kp, kd, q1, u1, q2, u2, dt, n_steps, every,
           threshold, res):
    """One run of the ``integrate_pair`` 1-DOF loop (t0 = 0), metrics into ``res``."""
    Si = 0.0
    Si_w = 0.0
    WS = 0.0
    if scheme == THETA:  # theta_matrices for n = 1, same operations
        a = theta * dt
        S = M + a * p[2] + a * a * p[1]
        Si = 1.0 / S
        s = 0.0
        s += Si * p[5]
        Si_w = s
        WS = 0.0
        WS += p[5] * s
    tau1 = 0.0
    tau2 = 0.0
    d = np.nan
    imp1 = 0
    imp2 = 0
    ep1 = 0
    ep2 = 0
    in1 = False
    in2 = False
    tau_max = 0.0
    acc = np.zeros(ACC_SIZE)
    status = OK
    steps = n_steps
    countdown = 1
    for k in range(n_steps + 1):
        is_row = False
        countdown -= 1
        if countdown == 0:
            countdown = every
            is_row = True
        if k == n_steps:
            is_row = True
        need_d = is_row
        if law != UNCOUPLED or need_d:
            tau1, tau2, d_, br, E = coupling_step1(law, sg, kp, kd, q1, u1, q2, u2, need_d)
            if need_d or law == SWITCHING:
                d = d_
        t = 0.0 + k * dt
        if is_row:
            if not (math.isfinite(q1) and math.isfinite(u1) and math.isfinite(q2) and math.isfinite(u2)
                    and math.isfinite(d)):
                status = DIVERGED
                steps = k
                break
            _acc_sample(acc, t, d, threshold)
        if k == n_steps:
            break
        a1 = abs(tau1)
        if a1 > tau_max:
            tau_max = a1
        a2 = abs(tau2)
        if a2 > tau_max:
            tau_max = a2
        if scheme == THETA:
            q1, u1, P1 = theta_step1(p, F, Omega, phi, Si, Si_w, WS, theta, q1, u1, tau1, t, dt)
            q2, u2, P2 = theta_step1(p, F, Omega, phi, Si, Si_w, WS, theta, q2, u2, tau2, t, dt)
        else:
            q1, u1, P1 = midpoint_step1(p, F, Omega, phi, q1, u1, tau1, t, dt)
            q2, u2, P2 = midpoint_step1(p, F, Omega, phi, q2, u2, tau2, t, dt)
        if P1 > 0.0:
            imp1 += 1
            if not in1:
                ep1 += 1
            in1 = True
        else:
            in1 = False
        if P2 > 0.0:
            imp2 += 1
            if not in2:
                ep2 += 1
            in2 = True
        else:
            in2 = False
    res[0] = status
    res[1] = steps
    res[2] = steps * dt
    res[3] = q1
    res[4] = u1
    res[5] = q2
    res[6] = u2
    res[8] = d
    res[10] = tau_max
    res[11] = imp1
    res[12] = imp2
    res[13] = ep1
    res[14] = ep2
    _acc_finish(acc, status != OK, res)


@njit(cache=True, parallel=True)
def run_pairs1(law, scheme, theta, sys_rows, geo_rows, F, Omega, phi, nf, group, kp, kd, q1, u1, q2, u2,
               dt, n_steps, every, threshold, out):
    """Run ``R = group.shape[0]`` pairs in parallel; metrics of run r into ``out[r]``.

    Per run (arrays of length R): ``law`` (coupling code), ``scheme`` (MIDPOINT
    or THETA), ``theta``, ``group`` (row of the system tables), gains ``kp,
    kd``, start states ``q1, u1, q2, u2``, step ``dt``, ``n_steps``, sample
    interval ``every``. System tables (G rows): ``sys_rows`` (G, 11)
    (:data:`GROUP_FIELDS`), ``geo_rows`` (G, 12) (:data:`GEO_FIELDS`),
    forcing ``F, Omega, phi`` (G, NF) with ``nf`` (G,) terms used.
    Runs whose ``out[r, 0]`` is already REFUSED are skipped.
    """
    R = group.shape[0]
    for r in prange(R):
        if out[r, 0] == REFUSED:
            continue
        g = group[r]
        s = sys_rows[g]
        p = (s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8], s[9], s[10])
        m = nf[g]
        Fg = F[g, :m].reshape((m, 1))
        _pair1(law[r], scheme[r], theta[r], p, s[0], Fg, Omega[g, :m], phi[g, :m], _geo(geo_rows[g]),
               kp[r], kd[r], q1[r], u1[r], q2[r], u2[r], dt[r], n_steps[r], every[r], threshold, out[r])
