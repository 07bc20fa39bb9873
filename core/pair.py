"""Two coupled systems in one compiled loop (monolithic reference of the master).

The pair is the 2-node network (edge (0, 1), weights 1), as in the master: it runs
the one loop of :mod:`.loop` (:func:`~fmu_sync.core.loop.integrate_network`). Every
step: the coupling forces are computed from the states at the start of the step
(:func:`coupling_step`, the very function the co-simulation master calls) and held
over it (zero-order hold), then both systems take one Moreau step. So a
co-simulation whose communication step equals ``dt`` reproduces this run to
round-off (docs/design.md §2.5).
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from .coupling import LAWS as COUPLING_LAWS
from .coupling import BRANCH_NONE, QUOTIENT_LAWS, UNCOUPLED, gain_matrix, law_metric, metric_info
from .loop import coupling_step, integrate_network, no_decimator, node_geometry
from .steps import DEFAULT_SCHEME, DIVERGED, OK, TRAPEZOID
from .result import PairResult, concat_pairs
from .checks import divergence_message, land_last_row
from .errors import ForceLawFailed, SimulationDiverged
from .failure import force_offset, law_nonfinite, law_raised, rows_written
from .plan import coupling_exchange, as_systems, check_common_geometry, network_geometry, plan_run

__all__ = ["simulate_pair", "coupling_step", "LAWS", "gain_matrix", "check_common_geometry", "as_systems"]

#: Coupling names accepted by :func:`simulate_pair` and the master.
LAWS = {None: UNCOUPLED, **COUPLING_LAWS}


#: The pair as a graph: the one edge (0, 1) and its weights (a_01, a_10) (``network.edge_arrays``).
PAIR_EDGES = np.array([[0, 1]], dtype=np.int64)
PAIR_WEIGHTS = np.ones((1, 2))


def network_loop(systems, code=None):
    """The coupled loop of these systems: :func:`~fmu_sync.core.loop.integrate_network` for
    the built-in linear law, the law's own copy (:meth:`ForceLaw.kernels`, the same arguments;
    the trapezoid's copy for scheme ``code`` TRAPEZOID) for a user force law, which every node shares (its parameters may differ; checked by the run
    plan, :func:`~fmu_sync.core.plan.check_common_geometry`)."""
    law = systems[0].force
    return integrate_network if law is None else law.kernels(code == TRAPEZOID).network


def stack_nodes(*systems):
    """``(base, K, C, f0, F, Omega, phi)`` of the loop: the common geometry (the first
    system's arrays) and the nodes' forces stacked, forcing padded with F = 0 terms. For a user
    force law: K, C the nodes' linear parts, the forcing its declared terms and, in the slot of
    f0, the parameters (N, n_p)."""
    arrays = [s.arrays() for s in systems]
    N, n, nf = len(arrays), arrays[0].M.shape[0], max(a.Omega.shape[0] for a in arrays)
    K, C, f0 = np.zeros((N, n, n)), np.zeros((N, n, n)), np.zeros((N, n))
    F, Om, ph = np.zeros((N, nf, n)), np.zeros((N, nf)), np.zeros((N, nf))
    for i, sa in enumerate(arrays):
        m = sa.Omega.shape[0]
        K[i], C[i], f0[i], F[i, :m], Om[i, :m], ph[i, :m] = sa.K, sa.C, sa.f0, sa.F, sa.Omega, sa.phi
    if systems[0].force is not None:   # the law's parameters in the slot of f0 (at least one column:
        n_p = systems[0].p.shape[0]     # the loop reads a column 0 it leaves unused for a law)
        f0 = np.zeros((N, max(n_p, 1)))
        f0[:, :n_p] = np.stack([s.p for s in systems]).reshape(N, n_p)
    return node_geometry(arrays), K, C, f0, F, Om, ph


def locate_failure(loop, nodes, geo, laws, E2, W2, Kp, Kd, q, u, t0, k, dt, steps, code, theta, record_d, dt_last,
                   alloc):
    """The failing step of a coupled run (core/failure.py): the loop again from the recorded states
    ``q, u`` (N, n) at step ``k`` over the ``steps`` (and ``dt_last``) to the next row, a row at every
    step, into ``alloc(rows)``'s arrays (the driver's own layout: the same compiled loop).
    Returns ``(arrays, j, raised)``: ``j`` the last good row (None: it ran through), ``raised`` the
    exception the law raised again (or None)."""
    bufs = alloc(steps + 2)
    N = q.shape[0]
    imp, ep = np.zeros(N, dtype=np.int64), np.zeros(N, dtype=np.int64)
    try:
        status, _, written, _, _ = loop(*nodes, geo, laws, E2, W2, Kp, Kd, np.array(q, order="C"),
                                        np.array(u, order="C"), float(t0), k, dt, steps, code, theta, 1, record_d,
                                        *bufs, dt_last, False, *no_decimator(), imp, ep)
        return bufs, (written - 1 if status != OK else None), None
    except Exception as exc:   # raised by the user's law inside the compiled loop
        return bufs, rows_written(bufs[0]) - 1, exc


def failure_message(systems, P, bufs, j, raised, code, theta, h, labels):
    """The message of a located failure (:func:`locate_failure`) of a user force law at row ``j``
    of the rerun's ``bufs``, or None when the law is not at fault (finite there). ``P``: each
    node's parameters; ``labels``: the nodes' names."""
    law = systems[0].force
    T2, Qr2, Ur2, TAU2 = bufs[:4]
    here = [(labels[i], Qr2[j, i], Ur2[j, i], TAU2[j + 1, i]) for i in range(len(labels))]
    if raised is not None:
        return law_raised(law, raised, T2[j], here)
    if law is None:
        return None
    return law_nonfinite(law, force_offset(code, theta, h), T2[j], here, P)


def simulate_pair(system, x1, x2, t_end: float, dt: float, coupling=None,
                  Kp=0.0, Kd=0.0, Q=None, scheme: str = DEFAULT_SCHEME, theta: float = 0.5,
                  record_every: int = 1, record_distance: bool = True, progress=None,
                  t0: float = 0.0, allow_unstable: bool = False, sink=None,
                  chunk_rows: int = 65536) -> PairResult:
    """Simulate two systems from ``x1``, ``x2``, coupled by ``coupling``.

    ``system``: one :class:`MechanicalSystem` (two identical copies) or a pair
    ``(system1, system2)`` of non-identical systems; they must share M, w, g0
    and e (the impact geometry of the quotient distance) and may differ in K,
    C, f0 and forcing.
    ``coupling``: None (uncoupled), ``"euclidean"`` (PD baseline) or
    ``"switching"`` (the quotient coupling of docs/design.md §2.5) or ``"switching-compensated"``
    (1-DOF: V = d^2/2 non-increasing on every branch under a force toward the wall,
    docs/design.md §2.5.2), gains ``Kp``, ``Kd``
    (scalars or n×n), position weight ``Q`` of the norm: by default (None or "energy") the
    law's own metric ``energy_metric`` (Q = K + 2 Kp: V = d^2/2 is the energy of the relative
    motion, docs/design.md §2.5.1); an explicit Q is used as given and the result says that V is
    then not a Lyapunov function of the law (``info["metric"]``, ``info["Q"]``,
    ``info["metric_note"]``; ``result.metric``).
    The forces act through ``B = I`` (τ has n entries). With
    ``record_distance=False`` and no coupling, no distance is computed.
    ``progress``: callable ``progress(fraction)``; the run is then made in
    ~100 compiled chunks (same numbers as one chunk).
    ``sink``: callable ``sink(chunk)``; the record then goes to it in chunks of
    at most ``chunk_rows`` rows (each a :class:`PairResult` of consecutive rows,
    in order, no row twice) and only one chunk is held in memory: the memory of
    a run no longer grows with its length (same numbers as one chunk). The
    returned result then holds the last row only (``info["rows"]``: the rows
    sent to the sink).
    ``tau1[0]``, ``tau2[0]``: the forces at the start (those held over the first step).

    ``scheme``: ``"trapezoid"`` (default: θ = 1/2 with, for 1-DOF systems, the coupling inside the
    step, docs/design.md §2.3), ``"midpoint"`` (the coupling held: what the explicit exchange at
    H = dt reproduces) or ``"theta"``.
    Before the first step, a step known to diverge is refused (the run plan,
    :func:`fmu_sync.core.plan.plan_run`): the explicit midpoint scheme
    (omega_max*dt >= 2, :class:`~fmu_sync.core.errors.UnstableScheme`) and the
    held coupling forces (omega_c*dt beyond min(4 zeta, 1/zeta),
    :class:`fmu_sync.core.exchange.UnstableExchange`, a ValueError); pass
    ``allow_unstable=True`` to run anyway.
    Returns a :class:`PairResult`; raises :class:`SimulationDiverged` (with the
    records up to the failure, marked failed, in ``.partial``) if a state
    becomes non-finite.
    """
    if coupling not in LAWS:
        raise ValueError(f"coupling must be one of {list(LAWS)}, got {coupling!r}")
    law = LAWS[coupling]
    systems = as_systems(system, 2)
    s1, n = systems[0], systems[0].n
    record_d = bool(record_distance) or law in QUOTIENT_LAWS
    plan = plan_run(systems, (x1, x2), t_end, dt, scheme=scheme, theta=theta, laws=[law], Kp=Kp, Kd=Kd,
                    exchange=coupling_exchange(scheme, systems),
                    record_every=record_every, t0=t0, allow_unstable=allow_unstable,
                    record_values=None if sink is not None else 4 * n + 2 * n + (4 if record_d else 1),
                    record_what="the record of simulate_pair", distance=record_d,
                    record_hint=", or pass sink= to stream it in chunks")   # every check, once (docs/design.md §5.1.1)
    lm = law_metric(Q, [s.K for s in systems], plan.Kp, coupled=law != UNCOUPLED, stiffness=s1.metric_source)
    geo = network_geometry(systems, lm.Q)[0]   # without one impact map: the Euclidean error's norm alone
    cap, chunks = chunk_plan(plan, sink, chunk_rows, progress)
    rec = pair_record(cap, n)
    info = dict(mode="core", dt=plan.dt, scheme=scheme, steps=plan.grid.steps, identical=s1 is systems[1],
                **metric_info(lm, geo), v_impact=0.0)
    if plan.grid.short:
        info["dt_last"] = plan.dt_last
    if plan.limit is not None:
        info.update(omega_c_dt=plan.limit.h, exchange_bound=plan.limit.bound, zeta=plan.limit.zeta,
                    dt_max=plan.limit.H_max)
    run = SimpleNamespace(systems=systems, plan=plan, law=law, geo=geo, rec=rec, cap=cap, sink=sink, info=info,
                          record_d=record_d, coupling=coupling, loop=network_loop(systems, plan.code), nodes=stack_nodes(*systems),
                          laws=np.full(1, law, dtype=np.int64), imp1=0, imp2=0, sent=0, scheme=scheme)
    status, raised, at = run_chunks(run, chunks, progress, t0)
    if status == OK:
        if sink is not None:
            info["rows"] = run.sent
            last_row = max(at.written - 1, 0)
            return pair_result(run, slice(last_row, last_row + 1))
        return pair_result(run, slice(0, plan.rows))
    raise pair_failure(run, raised, at, t0)


def chunk_plan(plan, sink, chunk_rows, progress):
    """``(cap, chunks)``: the record's rows held at once and the steps of each compiled call. With a
    ``sink``, chunks of ``chunk_rows`` records (and the one that takes a shortened last step); with
    ``progress``, ~100 chunks; else one. Chunks are whole record intervals: chunking changes no number."""
    n_steps, record_every, grid = plan.whole_steps, plan.record_every, plan.grid
    if sink is not None:
        chunk_rows = int(chunk_rows)
        if chunk_rows < 1:
            raise ValueError(f"chunk_rows must be >= 1, got {chunk_rows}")
        per = chunk_rows * record_every
        chunks = [per] * (n_steps // per) + ([n_steps % per] if n_steps % per else [])
        if not chunks or (grid.short and n_steps % per == 0):
            chunks.append(0)   # the chunk that takes the shortened last step
        return min(plan.rows, chunk_rows + 1), chunks   # a chunk re-records its start row (dropped)
    return plan.rows, progress_chunks(n_steps, record_every, progress)


def progress_chunks(n_steps: int, record_every: int, progress) -> list:
    """The steps of each compiled call of a run kept whole in memory: one call, or with ``progress``
    ~100 calls of whole record intervals (the pair's and the network's)."""
    if progress is None:
        return [n_steps]
    per = max(1, (n_steps // record_every) // 100) * record_every
    return [per] * (n_steps // per) + ([n_steps % per] if n_steps % per else []) or [0]


def pair_result(run, sl, rec=None) -> PairResult:
    """The rows ``sl`` of the run's record (or of ``rec``) as a :class:`PairResult` (copies with a sink)."""
    return pair_rows(run.rec if rec is None else rec, sl, run.record_d, copy=run.sink is not None,
                     impacts1=run.imp1, impacts2=run.imp2,
                     coupling=run.coupling if run.coupling != "none" else None, info=dict(run.info))


def run_chunks(run, chunks, progress, t0):
    """The compiled loop over ``chunks`` (:func:`chunk_plan`), in place on ``run`` (counts, rows sent to
    the sink). Returns ``(status, raised, at)``: ``raised`` a user law's exception, ``at`` where the last
    chunk stopped (``row0``, ``k0``, ``written``, ``done``, ``chunk_k``)."""
    plan, rec = run.plan, run.rec
    T = rec[0]
    q, u = np.stack((plan.q[0], plan.q[1])), np.stack((plan.u[0], plan.u[1]))
    at = SimpleNamespace(row0=0, k0=0, written=0, done=0, chunk_k=0)
    imp, ep = np.zeros(2, dtype=np.int64), np.zeros(2, dtype=np.int64)   # each chunk's counts
    status, raised, dec = OK, None, no_decimator()
    for c, steps in enumerate(chunks):
        last = c == len(chunks) - 1
        if run.sink is not None:  # every chunk fills the buffer from row 0 (its start row, sent once)
            at.row0 = 0
            T[:] = np.nan     # the rows it did not write (core/failure.py)
        sl = slice(at.row0, run.cap)
        at.chunk_k = at.k0
        # a chunk records its start row; the next chunk starts on the row it ended on
        try:
            status, at.done, at.written, v, _ = run.loop(
                *run.nodes, run.geo, run.laws, PAIR_EDGES, PAIR_WEIGHTS, plan.Kp, plan.Kd, q, u, float(t0), at.k0,
                plan.dt, steps, plan.code, plan.theta, plan.record_every, run.record_d, *(a[sl] for a in rec),
                plan.dt_last if last else 0.0, False, *dec, imp, ep)
        except Exception as exc:   # raised by the user's law inside the compiled loop (core/failure.py)
            if run.systems[0].force is None:
                raise
            status, at.done, at.written, v, raised = DIVERGED, 0, rows_written(T[sl]), 0.0, exc
        if last and status == OK:
            land_last_row(T[sl], at.written, plan.grid)
        run.imp1, run.imp2 = run.imp1 + int(imp[0]), run.imp2 + int(imp[1])
        run.info["v_impact"] = max(run.info["v_impact"], v)
        if run.sink is not None:
            first = 0 if c == 0 else 1
            if at.written > first:
                run.sink(pair_result(run, slice(first, at.written)))
                run.sent += at.written - first
        if status != OK:
            at.row0 += at.written
            at.k0 += at.done
            break
        at.k0 += steps
        at.row0 += at.written - (0 if last else 1)
        if progress is not None:
            progress(min(at.k0 / max(plan.whole_steps, 1), 1.0))
    return status, raised, at


def pair_failure(run, raised, at, t0):
    """The error of a failed run (core/failure.py): the failing step located from the last row (every
    step again with a row each), the partial record (with the last good step) in ``.partial``; or the
    law's own exception when it did not raise again from the same state."""
    plan, n = run.plan, run.systems[0].n
    _, Qr, Ur = run.rec[:3]
    b = at.row0 - 1                                       # the last row, in the buffer
    k_b = at.chunk_k + (at.written - 1) * plan.record_every   # its step
    m = min(plan.record_every, plan.whole_steps - k_b)
    if plan.code == TRAPEZOID and raised is not None and m < plan.whole_steps - k_b:
        m += 1   # the coupling inside the step evaluates the next step's law before it writes a row's record
    h_last = plan.dt_last if m == plan.whole_steps - k_b else 0.0
    bufs, j, again = locate_failure(run.loop, run.nodes, run.geo, run.laws, PAIR_EDGES, PAIR_WEIGHTS, plan.Kp,
                                    plan.Kd, Qr[b], Ur[b], t0, k_b, plan.dt, m, plan.code, plan.theta,
                                    run.record_d, h_last, lambda c: pair_record(c, n))
    if raised is not None and again is None:
        return raised   # not the law's (it did not raise again from the same state): as it came
    res = pair_result(run, slice(b, b + 1)) if run.sink is not None else pair_result(run, slice(0, at.row0))
    msg = None
    if j is not None:
        if j >= 1:   # the last good step as the last row
            extra = pair_result(run, slice(j, j + 1), bufs)
            if run.sink is not None:
                run.sink(extra)
                run.sent += 1
                res = extra
            else:
                res = concat_pairs([res, extra])
        hk = h_last if (j == m and h_last > 0.0) else plan.dt
        msg = failure_message(run.systems, [s.p for s in run.systems], bufs, j, again, plan.code, plan.theta, hk,
                              ["system 1", "system 2"])
        t_fail = min(float(bufs[0][j]) + hk, plan.grid.t_end)
    else:
        t_fail = min(t0 + at.k0 * plan.dt, plan.grid.t_end)
    if run.sink is not None:
        run.info["rows"] = run.sent
        res.info["rows"] = run.sent
    cls = ForceLawFailed if again is not None else SimulationDiverged
    err = cls(msg or divergence_message(run.systems[0], run.scheme, plan.dt, t_fail, what="a coupled state",
                                        Kp=plan.Kp if run.law != UNCOUPLED else None))
    res.error = str(err)
    err.partial = res
    return err


def network_record(rows: int, N: int, n: int, E: int, dist: bool = True):
    """The record arrays of a coupled run as the loop takes them, ``(T, Qr, Ur, TAU, D, BR, EU)``:
    T (rows,); Qr, Ur, TAU each node's rows contiguous (node-major (N, rows + 1, n), seen by the loop as
    (rows, N, n); the unused last row of each node keeps that view from being contiguous for any n: numba
    types it A for n = 1 as for n > 1, so pairs, networks and the sweep share one compiled loop,
    docs/design.md §5.6); the edges' D, BR, EU (rows, E); NaN until written (core/failure.py). ``dist``
    False: D and BR without columns, the Euclidean error alone."""
    T = np.full(rows, np.nan)
    Qr, Ur, TAU = (np.full((N, rows + 1, n), np.nan)[:, :rows].transpose(1, 0, 2) for _ in range(3))
    Ed = E if dist else 0
    D, EU = np.full((rows, Ed), np.nan), np.full((rows, E), np.nan)
    BR = np.full((rows, Ed), BRANCH_NONE, dtype=np.int64)
    return T, Qr, Ur, TAU, D, BR, EU


def pair_record(cap: int, n: int):
    """The record arrays of a pair run (:func:`network_record` of two nodes and one edge)."""
    return network_record(cap, 2, n, 1)


def pair_rows(rec, sl, record_d: bool, copy: bool = False, **kw) -> PairResult:
    """The rows ``sl`` of a pair record (:func:`pair_record`) as a :class:`PairResult` (views, or
    copies with ``copy``); ``kw`` its counts, coupling and info."""
    T, Qr, Ur, TAU, D2, BR2, EU2 = rec
    take = (lambda a: a[sl].copy()) if copy else (lambda a: a[sl])
    cols = (T, Qr[:, 0], Ur[:, 0], Qr[:, 1], Ur[:, 1], TAU[:, 0], TAU[:, 1])
    dist = (take(D2[:, 0]), take(BR2[:, 0]), take(EU2[:, 0])) if record_d else (None, None, None)
    return PairResult(*(take(a) for a in cols), *dist, **kw)
