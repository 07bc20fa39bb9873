"""Many coupled 1-DOF pairs in one compiled, parallel call (the sweep engine).

:func:`run_pairs1` runs R independent pairs on one thread per core, each thread
taking the next block of runs (dynamic scheduling) and running it compiled without
the GIL (:func:`run_block`), with no Python per run and no trajectory: every run
keeps a fixed set of numbers (the columns ``COLUMNS``, written into one row of
``out``), so memory is O(1) per run whatever its length.

Each run is the one loop of the core, :func:`fmu_sync.core.loop.integrate_network`,
on the 2-node network (the loop :func:`~fmu_sync.core.pair.simulate_pair` runs, on
its 1-DOF path) with the decimating recorder instead of a trajectory, so its final
state, distances and impact counts equal a single ``simulate_pair`` run bit for bit
(tests/test_sweep.py checks a sample of a gain map).

Per run the loop samples ``d`` at the start of every ``every``-th step and at
the end (the record grid of ``simulate_pair(record_every=every)``) and keeps:
final state, d at the start, at the end and its maximum, max |tau| over all
steps, impacts and contact episodes of each system, and from the fixed-size
decimated recorder of :mod:`.metrics`: the time after which d stays below the
threshold (``t_sync``), the decay rate of the envelope of d with its
spread, its verdict code and the decades its window spans, the envelope-fit time ``t_fit`` and the ultimate bound.

Systems differ between runs only through a small table of *system groups*
(one row of floats per distinct system, see :func:`group_row`), so a sweep
over e or m needs no Python per run either.
"""
from __future__ import annotations

import math
import threading

import numpy as np
from .jit import NUMBA, njit

from .distance import DistanceGeometry, ScalarGeometry
from .loop import NodeGeometry, integrate_network, sample_d
from .metrics import HI, LO, TAIL, decimated_kernel, decimator_init

__all__ = ["run_pairs1", "run_block", "COLUMNS", "COL", "MEASURE_D", "MEASURE_EUCLIDEAN", "OK", "DIVERGED", "REFUSED", "STATUS_NAMES", "group_row",
           "GROUP_FIELDS", "GEO_FIELDS", "empty_out",
           "metrics_from_records"]

OK = 0
DIVERGED = 1
REFUSED = 2
STATUS_NAMES = ("ok", "diverged", "refused")

#: One row of ``out`` per run.
COLUMNS = ("status", "steps", "t_stop", "q1", "u1", "q2", "u2", "d0", "d_final", "d_max", "tau_max",
           "impacts1", "impacts2", "episodes1", "episodes2", "t_sync", "decay_rate", "decay_rate_err",
           "t_fit", "bound", "samples", "exchange_stable", "rate_code", "rate_decades", "measure")
COL = {name: i for i, name in enumerate(COLUMNS)}
COL_D0, COL_DFINAL, COL_DMAX, COL_TAUMAX = COL["d0"], COL["d_final"], COL["d_max"], COL["tau_max"]
COL_TSYNC, COL_RATE, COL_RATE_ERR = COL["t_sync"], COL["decay_rate"], COL["decay_rate_err"]
COL_TFIT, COL_BOUND, COL_SAMPLES = COL["t_fit"], COL["bound"], COL["samples"]
#: what the d columns measure (column "measure"): the quotient distance, or the Euclidean error of
#: systems without one impact map (docs/design.md §2.5.3)
MEASURE_D, MEASURE_EUCLIDEAN = 0.0, 1.0
COL_MEASURE = COL["measure"]
COL_RATE_CODE, COL_DECADES = COL["rate_code"], COL["rate_decades"]

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


@njit(cache=True)
def _finish_metrics(acc, bt, bd, st, failed, res):
    """d0, d_max, t_sync, decay rate, its spread, verdict code and decades, t_fit, bound, sample
    count into ``res``."""
    res[COL_D0] = acc[1] if acc[0] > 0 else np.nan
    res[COL_DMAX] = acc[2] if acc[0] > 0 else np.nan
    rate, err, _, _, dec, t_sync, t_fit, bound, code, _, _, _, _, _ = decimated_kernel(bt, bd, st, HI, LO, 0.0,
                                                                                        TAIL)
    res[COL_RATE_CODE] = code
    res[COL_DECADES] = max(dec, 0)
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
        sample_d(acc, bt, bd, st, t[i], d[i])
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
def _node1(i, s, Fi, Oi, pi, K, C, f0, F, Om, ph):
    """Node i's forces from its group row ``s`` and forcing (as ``pair._nodes``, padding F = 0)."""
    K[i, 0, 0] = s[2]
    C[i, 0, 0] = s[3]
    f0[i, 0] = s[4]
    for j in range(Oi.shape[0]):
        F[i, j, 0] = Fi[j]
        Om[i, j] = Oi[j]
        ph[i, j] = pi[j]


@njit(cache=True)
def _pair1(law, scheme, theta, s1, F1, Omega1, phi1, s2, F2, Omega2, phi2, sg, kp, kd,
           q1, u1, q2, u2, dt, n_steps, dt_last, every, threshold, res):
    """One run (t0 = 0), metrics into ``res``: the loop of :func:`.loop.integrate_network` on
    the 2-node network with the decimating recorder, ``n_steps`` steps of ``dt``, then
    (``dt_last > 0``) the shortened last step. ``s1, s2``: the systems' group rows
    (:data:`GROUP_FIELDS`); they may differ in K, C, f0 and forcing."""
    nf = max(Omega1.shape[0], Omega2.shape[0])
    K = np.empty((2, 1, 1))
    C = np.empty((2, 1, 1))
    f0 = np.empty((2, 1))
    F = np.zeros((2, nf, 1))
    Om = np.zeros((2, nf))
    ph = np.zeros((2, nf))
    _node1(0, s1, F1, Omega1, phi1, K, C, f0, F, Om, ph)
    _node1(1, s2, F2, Omega2, phi2, K, C, f0, F, Om, ph)
    M = np.full((1, 1), s1[0])
    w = np.full(1, s1[6])
    Minv_w = np.full(1, s1[9])
    base = NodeGeometry(np.array([s1[0], s2[0]]).reshape(2, 1, 1), np.array([s1[1], s2[1]]).reshape(2, 1, 1),
                        np.full((1, 1), s1[5]), np.array([s1[6], s2[6]]).reshape(2, 1), np.array([s1[7], s2[7]]),
                        np.array([s1[8], s2[8]]), np.array([s1[9], s2[9]]).reshape(2, 1), np.array([s1[10], s2[10]]))
    same = s1[0] == s2[0] and s1[6] == s2[6] and s1[7] == s2[7] and s1[8] == s2[8]   # one impact map
    geo = DistanceGeometry(np.full((1, 1), sg.Q11), M, w, sg.g0, sg.e, Minv_w, sg.W, np.full(1, sg.Qinv_w1), sg.WQ,
                           sg.sqrtW, sg.sqrtWQ, sg)
    q = np.empty((2, 1))
    u = np.empty((2, 1))
    q[0, 0] = q1
    q[1, 0] = q2
    u[0, 0] = u1
    u[1, 0] = u2
    T = np.empty(1)
    # A: the type numba gives every coupled record (pair.network_record), so that the sweep, pairs and
    # networks share one compiled loop (docs/design.md §5.6)
    Qr = np.empty((2, 2, 1))[:, :1].transpose(1, 0, 2)
    Ur = np.empty((2, 2, 1))[:, :1].transpose(1, 0, 2)
    TAU = np.empty((2, 2, 1))[:, :1].transpose(1, 0, 2)
    D = np.full((1, 1 if same else 0), np.nan)   # no common geometry: the Euclidean error alone
    EU = np.full((1, 1), np.nan)
    BR = np.zeros((1, 1), dtype=np.int64)
    acc = np.zeros(3)
    t_stop = n_steps * dt + dt_last if dt_last > 0.0 else n_steps * dt
    bt, bd, st = decimator_init(RECORDER_SIZE, threshold, (1.0 - TAIL) * t_stop)
    E2 = np.zeros((1, 2), dtype=np.int64)   # the pair's edge (0, 1), weights 1 (pair.PAIR_EDGES)
    E2[0, 1] = 1
    imp = np.zeros(2, dtype=np.int64)
    ep = np.zeros(2, dtype=np.int64)
    status, steps, _, _, tau_max = integrate_network(   # (its constants typed by value: core/jit.py)
        base, K, C, f0, F, Om, ph, geo, np.full(1, law), E2, np.ones((1, 2)), np.full((1, 1), kp),
        np.full((1, 1), kd), q, u, 0.0, 0, dt, n_steps, scheme, theta, every, True, T, Qr, Ur, TAU, D, BR, EU,
        dt_last, True, acc, bt, bd, st, imp, ep)
    res[0] = status
    res[1] = steps
    res[2] = T[0] if status != OK else t_stop
    res[3] = q[0, 0]
    res[4] = u[0, 0]
    res[5] = q[1, 0]
    res[6] = u[1, 0]
    res[COL_DFINAL] = D[0, 0] if same else EU[0, 0]
    res[COL_MEASURE] = MEASURE_D if same else MEASURE_EUCLIDEAN
    res[COL_TAUMAX] = tau_max
    res[11] = imp[0]
    res[12] = imp[1]
    res[13] = ep[0]
    res[14] = ep[1]
    _finish_metrics(acc, bt, bd, st, status != OK, res)


@njit(cache=True, nogil=True)
def run_block(lo, hi, law, scheme, theta, sys_rows, geo_rows, F, Omega, phi, nf, group1, group2, kp, kd,
              q1, u1, q2, u2, dt, n_steps, dt_last, every, threshold, out, qw):
    """The runs ``lo .. hi - 1`` of :func:`run_pairs1` (its arguments), one after the other, without
    the GIL (so that threads run blocks side by side)."""
    for r in range(lo, hi):
        if out[r, 0] == REFUSED:
            continue
        g1 = group1[r]
        g2 = group2[r]
        m1 = nf[g1]
        m2 = nf[g2]
        _pair1(law[r], scheme[r], theta[r], sys_rows[g1], F[g1, :m1], Omega[g1, :m1], phi[g1, :m1],
               sys_rows[g2], F[g2, :m2], Omega[g2, :m2], phi[g2, :m2],
               _geo(geo_rows[g1], qw[r]), kp[r], kd[r], q1[r], u1[r], q2[r], u2[r], dt[r], n_steps[r], dt_last[r],
               every[r],
               threshold, out[r])


#: blocks per thread: a thread takes the next block of runs when it is done with one (dynamic
#: scheduling: runs differ in length), at one Python call per block
BLOCKS_PER_THREAD = 8


def run_pairs1(law, scheme, theta, sys_rows, geo_rows, F, Omega, phi, nf, group1, group2, kp, kd,
               q1, u1, q2, u2, dt, n_steps, dt_last, every, threshold, out, qw, threads=None):
    """Run ``R = group1.shape[0]`` pairs in parallel; metrics of run r into ``out[r]``.

    Per run (arrays of length R): ``law`` (coupling code), ``scheme`` (MIDPOINT
    or THETA), ``theta``, ``group1``, ``group2`` (rows of the system tables for
    system 1 and 2: the same row for identical systems; different rows must
    share M, w, g0, e, the distance geometry being that of system 1), gains
    ``kp, kd``, start states ``q1, u1, q2, u2``, step ``dt``, ``n_steps`` whole
    steps and ``dt_last`` (> 0: the shortened last step that lands on t_end),
    sample interval ``every``, position weight ``qw`` of the run's distance (the law's own metric
    k + 2 kp by default, chosen by the caller: :func:`.coupling.law_metric`; NaN: the
    group row's Q). System tables (G rows): ``sys_rows`` (G, 11)
    (:data:`GROUP_FIELDS`), ``geo_rows`` (G, 12) (:data:`GEO_FIELDS`),
    forcing ``F, Omega, phi`` (G, NF) with ``nf`` (G,) terms used.
    Runs whose ``out[r, 0]`` is already REFUSED are skipped.

    ``threads`` (at most one per core; default: numba's thread count): threads that each take the next block
    of runs (:data:`BLOCKS_PER_THREAD` per thread) and run it compiled without the GIL
    (:func:`run_block`); the runs are independent, so the rows are the same whatever the threads.
    A Ctrl-C (or an error) in a block stops the others at the end of theirs.
    """
    args = (law, scheme, theta, sys_rows, geo_rows, F, Omega, phi, nf, group1, group2, kp, kd, q1, u1, q2, u2,
            dt, n_steps, dt_last, every, threshold, out, qw)
    R = group1.shape[0]
    n = max(1, min(_threads(threads), R)) if NUMBA else 1   # (plain Python: the GIL held anyway)
    if n == 1:
        run_block(0, R, *args)
        return
    size = max(1, -(-R // (n * BLOCKS_PER_THREAD)))
    starts = iter(range(0, R, size))
    lock = threading.Lock()
    stop = threading.Event()
    failed: list = []

    def work():
        try:
            while not stop.is_set():
                with lock:
                    lo = next(starts, None)
                if lo is None:
                    return
                run_block(lo, min(lo + size, R), *args)
        except BaseException as exc:   # (a Ctrl-C too: raised in the caller's thread below)
            failed.append(exc)
            stop.set()

    helpers = [threading.Thread(target=work, name=f"fmu-sync-sweep-{i}", daemon=True) for i in range(n - 1)]
    for h in helpers:
        h.start()
    try:
        work()
    finally:
        stop.set()   # no block is taken after this
        for h in helpers:
            while h.is_alive():
                try:
                    h.join()
                except KeyboardInterrupt:   # the helpers end at the end of their block
                    failed.append(KeyboardInterrupt())
    if failed:
        raise failed[0]


def _threads(threads) -> int:
    """The threads of a call: ``threads`` up to the cores (``NUMBA_NUM_THREADS``), by default numba's
    thread count (one per core; ``numba.set_num_threads`` lowers it)."""
    import numba
    return min(int(threads), numba.config.NUMBA_NUM_THREADS) if threads else numba.get_num_threads()
