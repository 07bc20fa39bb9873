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
steps, impacts and contact episodes of each system, and from the fixed-size
decimated recorder of :mod:`.metrics`: the time after which d stays below the
threshold (``t_sync``), the decay rate of the envelope of d with its
uncertainty, the envelope-fit time ``t_fit`` and the ultimate bound.

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
from .metrics import HI, LO, TAIL, resolution_floor, decimated_kernel, decimator_init, decimator_push
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
           "t_fit", "bound", "samples", "exchange_stable")
COL = {name: i for i, name in enumerate(COLUMNS)}
COL_D0, COL_DFINAL, COL_DMAX, COL_TAUMAX = COL["d0"], COL["d_final"], COL["d_max"], COL["tau_max"]
COL_TSYNC, COL_RATE, COL_RATE_ERR = COL["t_sync"], COL["decay_rate"], COL["decay_rate_err"]
COL_TFIT, COL_BOUND, COL_SAMPLES = COL["t_fit"], COL["bound"], COL["samples"]

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
    """An output table for R runs (NaN everywhere; ``exchange_stable`` is the caller's)."""
    return np.full((R, len(COLUMNS)), np.nan)


@njit(cache=True, inline="always")
def _geo(row, Q):
    """The run's geometry: the group's row with the run's position weight ``Q`` (> 0; NaN: the
    row's own), computed as :func:`.distance.make_geometry` does for n = 1."""
    if not Q > 0.0:
        return ScalarGeometry(row[0], row[1], row[2], row[3], row[4], row[5], row[6], row[7], row[8], row[9],
                              row[10], row[11])
    w = row[6]
    Qinv_w = w / Q
    WQ = w * Qinv_w
    return ScalarGeometry(row[0], row[1], row[2], WQ, row[4], math.sqrt(WQ), w, row[7], Qinv_w, Q, row[10],
                          row[11])


# ---------------------------------------------------------------------------
# Metrics of the sampled distance, O(1) memory: d at the first sample and its
# maximum here; t_sync, the decay rate of the envelope (with its uncertainty),
# the envelope-fit time t_fit and the ultimate bound from the fixed-size
# decimated recorder of :mod:`.metrics` (the definitions live there).
# ---------------------------------------------------------------------------
#: Samples kept by the decimated recorder of each run.
RECORDER_SIZE = 1024


@njit(cache=True, inline="always")
def _sample(acc, bt, bd, st, t, d):
    """One sample of d: running d0 / max here, the rest to the recorder."""
    if acc[0] == 0.0:
        acc[1] = d
        acc[2] = d
    elif d > acc[2]:
        acc[2] = d
    acc[0] += 1.0
    decimator_push(bt, bd, st, t, d)


@njit(cache=True)
def _finish_metrics(acc, bt, bd, st, failed, res, floor=0.0):
    """d0, d_max, t_sync, decay rate and its error, t_fit, bound, sample count into ``res``."""
    res[COL_D0] = acc[1] if acc[0] > 0 else np.nan
    res[COL_DMAX] = acc[2] if acc[0] > 0 else np.nan
    rate, err, ta, tb, nf, t_sync, t_fit, bound, _, _ = decimated_kernel(bt, bd, st, HI, LO, floor, TAIL)
    res[COL_TSYNC] = np.inf if failed or acc[0] == 0 else t_sync
    res[COL_RATE] = rate
    res[COL_RATE_ERR] = err
    res[COL_TFIT] = t_fit
    res[COL_BOUND] = bound
    res[COL_SAMPLES] = acc[0]


@njit(cache=True)
def metrics_from_records(t, d, tau1, tau2, n_ok, threshold, t_end, res):
    """The same metrics from recorded samples (co-simulated or n-DOF runs), through the
    same recorder: ``t, d`` (N,), forces ``tau1, tau2`` (N, m); only the first
    ``n_ok`` records are used. Fills the d/tau columns of ``res``."""
    acc = np.zeros(3)
    bt, bd, st = decimator_init(RECORDER_SIZE, threshold, (1.0 - TAIL) * t_end)
    tau_max = 0.0
    for i in range(n_ok):
        _sample(acc, bt, bd, st, t[i], d[i])
        for j in range(tau1.shape[1]):
            a = abs(tau1[i, j])
            if a > tau_max:
                tau_max = a
            a = abs(tau2[i, j])
            if a > tau_max:
                tau_max = a
    res[COL_DFINAL] = d[n_ok - 1] if n_ok > 0 else np.nan
    res[COL_TAUMAX] = tau_max
    _finish_metrics(acc, bt, bd, st, n_ok < t.shape[0] or not math.isfinite(res[COL_DFINAL]), res)


@njit(cache=True, inline="always")
def _theta1(p, M, theta, dt):
    """``theta_matrices`` for n = 1 (same operations): (S^-1, S^-1 w, w^T S^-1 w)."""
    a = theta * dt
    S = M + a * p[2] + a * a * p[1]
    Si = 1.0 / S
    s = 0.0
    s += Si * p[5]
    WS = 0.0
    WS += p[5] * s
    return Si, s, WS


@njit(cache=True)
def _pair1(law, scheme, theta, p1, M1, F1, Omega1, phi1, p2, M2, F2, Omega2, phi2, sg, kp, kd,
           q1, u1, q2, u2, dt, n_steps, every, threshold, res):
    """One run of the ``integrate_pair`` 1-DOF loop (t0 = 0), metrics into ``res``.
    System 1 and 2 (``p*, M*, F*, Omega*, phi*``) may differ in K, C, f0 and forcing."""
    Si1 = 0.0
    Si_w1 = 0.0
    WS1 = 0.0
    Si2 = 0.0
    Si_w2 = 0.0
    WS2 = 0.0
    if scheme == THETA:
        Si1, Si_w1, WS1 = _theta1(p1, M1, theta, dt)
        Si2, Si_w2, WS2 = _theta1(p2, M2, theta, dt)
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
    v_imp = 0.0  # largest impact speed (for the window's floor, metrics.resolution_floor)
    acc = np.zeros(3)
    bt, bd, st = decimator_init(RECORDER_SIZE, threshold, (1.0 - TAIL) * (n_steps * dt))
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
            _sample(acc, bt, bd, st, t, d)
        if k == n_steps:
            break
        a1 = abs(tau1)
        if a1 > tau_max:
            tau_max = a1
        a2 = abs(tau2)
        if a2 > tau_max:
            tau_max = a2
        ua = abs(u1)
        ub = abs(u2)
        if scheme == THETA:
            q1, u1, P1 = theta_step1(p1, F1, Omega1, phi1, Si1, Si_w1, WS1, theta, q1, u1, tau1, t, dt)
            q2, u2, P2 = theta_step1(p2, F2, Omega2, phi2, Si2, Si_w2, WS2, theta, q2, u2, tau2, t, dt)
        else:
            q1, u1, P1 = midpoint_step1(p1, F1, Omega1, phi1, q1, u1, tau1, t, dt)
            q2, u2, P2 = midpoint_step1(p2, F2, Omega2, phi2, q2, u2, tau2, t, dt)
        if P1 > 0.0 and ua > v_imp:
            v_imp = ua
        if P2 > 0.0 and ub > v_imp:
            v_imp = ub
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
    res[COL_DFINAL] = d
    res[COL_TAUMAX] = tau_max
    res[11] = imp1
    res[12] = imp2
    res[13] = ep1
    res[14] = ep2
    _finish_metrics(acc, bt, bd, st, status != OK, res, resolution_floor(dt, v_imp * math.sqrt(sg.Q11)))


@njit(cache=True, parallel=True)
def run_pairs1(law, scheme, theta, sys_rows, geo_rows, F, Omega, phi, nf, group1, group2, kp, kd,
               q1, u1, q2, u2, dt, n_steps, every, threshold, out, qw):
    """Run ``R = group1.shape[0]`` pairs in parallel; metrics of run r into ``out[r]``.

    Per run (arrays of length R): ``law`` (coupling code), ``scheme`` (MIDPOINT
    or THETA), ``theta``, ``group1``, ``group2`` (rows of the system tables for
    system 1 and 2: the same row for identical systems; different rows must
    share M, w, g0, e, the distance geometry being that of system 1), gains
    ``kp, kd``, start states ``q1, u1, q2, u2``, step ``dt``, ``n_steps``,
    sample interval ``every``, position weight ``qw`` of the run's distance (the law's own metric
    k + 2 kp by default, chosen by the caller: :func:`.coupling.law_metric`; NaN: the
    group row's Q). System tables (G rows): ``sys_rows`` (G, 11)
    (:data:`GROUP_FIELDS`), ``geo_rows`` (G, 12) (:data:`GEO_FIELDS`),
    forcing ``F, Omega, phi`` (G, NF) with ``nf`` (G,) terms used.
    Runs whose ``out[r, 0]`` is already REFUSED are skipped.
    """
    R = group1.shape[0]
    for r in prange(R):
        if out[r, 0] == REFUSED:
            continue
        g1 = group1[r]
        g2 = group2[r]
        s1 = sys_rows[g1]
        s2 = sys_rows[g2]
        p1 = (s1[1], s1[2], s1[3], s1[4], s1[5], s1[6], s1[7], s1[8], s1[9], s1[10])
        p2 = (s2[1], s2[2], s2[3], s2[4], s2[5], s2[6], s2[7], s2[8], s2[9], s2[10])
        m1 = nf[g1]
        m2 = nf[g2]
        _pair1(law[r], scheme[r], theta[r], p1, s1[0], F[g1, :m1].reshape((m1, 1)), Omega[g1, :m1],
               phi[g1, :m1], p2, s2[0], F[g2, :m2].reshape((m2, 1)), Omega[g2, :m2], phi[g2, :m2],
               _geo(geo_rows[g1], qw[r]), kp[r], kd[r], q1[r], u1[r], q2[r], u2[r], dt[r], n_steps[r], every[r],
               threshold, out[r])
