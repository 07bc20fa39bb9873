"""Two coupled systems in one compiled loop (monolithic reference of the master).

Every step: the coupling forces are computed from the states at the start of
the step (:func:`coupling_step`, the very function the co-simulation master
calls) and held over it (zero-order hold), then both systems take one Moreau
step. So a co-simulation whose communication step equals ``dt`` reproduces
this run to round-off (docs/design.md §2.5).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .coupling import LAWS as COUPLING_LAWS
from .coupling import (BRANCH_NONE, SWITCHING, UNCOUPLED, p_norm_diff, coupling_kernel,
                       coupling_kernel1, euclidean_coupling1, gain_matrix, law_metric, metric_info)
from .distance import distance1, distance_value, geometry
from .moreau import (DIVERGED, OK, THETA, finish_step, midpoint_step, midpoint_step1, scalar_params,
                     step_workspace, theta_matrices, theta_step, theta_step1)
from .result import PairResult
from .checks import divergence_message
from .errors import SimulationDiverged
from .plan import as_systems, check_common_geometry, plan_run

__all__ = ["simulate_pair", "coupling_step", "LAWS", "gain_matrix", "check_common_geometry", "as_systems"]

#: Coupling names accepted by :func:`simulate_pair` and the master.
LAWS = {None: UNCOUPLED, **COUPLING_LAWS}


@njit(cache=True)
def coupling_step(law, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u, need_d):
    """Coupling forces into ``tau1, tau2`` and the distance record at this state.

    Returns ``(d, branch, euclidean)``: the quotient distance (NaN and branch
    ``BRANCH_NONE`` unless the law uses it or ``need_d``), its branch code and
    ``||x1 - x2||_P``. ``c1q, c1u, c2q, c2u``: (n,) scratch arrays for the chain
    ends (:func:`fmu_sync.core.coupling.chain_work`). One compiled call,
    used once per step by :func:`simulate_pair` and once per communication step
    by the master.
    """
    if law == SWITCHING:
        d, branch = coupling_kernel(law, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u)
        return d, branch, p_norm_diff(geo.Q, geo.M, q1, u1, q2, u2)
    E, _ = coupling_kernel(law, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u)
    if need_d:
        d, branch = distance_value(geo, q1, u1, q2, u2)
        return d, branch, E
    return np.nan, BRANCH_NONE, E


@njit(cache=True, inline="always")
def coupling_step1(law, sg, kp, kd, q1, u1, q2, u2, need_d):
    """:func:`coupling_step` for 1-DOF on floats (``sg = geo.scalar``, scalar
    gains): ``(tau1, tau2, d, branch, euclidean)``, the same arithmetic as the
    array kernels (which hand n = 1 to the same float kernels)."""
    tau1, tau2, value, branch = coupling_kernel1(law, sg, kp, kd, q1, u1, q2, u2)
    if law == SWITCHING:
        return tau1, tau2, value, branch, euclidean_coupling1(sg, kp, kd, q1, u1, q2, u2)[2]
    if need_d:
        r = distance1(sg, q1, u1, q2, u2)
        return tau1, tau2, r[0], r[1], value
    return tau1, tau2, np.nan, BRANCH_NONE, value


@njit(cache=True)
def integrate_pair(sa1, sa2, geo, law, Kp, Kd, q1, u1, q2, u2, t0, k0, dt, n_steps, scheme, theta,
                   record_every, record_d, T, Q1, U1, Q2, U2, TAU1, TAU2, D, BR, EU, dt_last=0.0):
    """The monolithic loop over steps ``k0 .. k0 + n_steps`` (time ``t0 + k dt``),
    then, if ``dt_last > 0``, one more step of length ``dt_last`` (the shortened
    last step of a run, :func:`.checks.run_steps`). The final state is always
    recorded (also when ``record_every`` does not divide the step count).

    ``sa1``, ``sa2``: the two systems (the same object for identical systems).
    Returns ``(status, steps_done, rows_written, impacts1, impacts2, v_impact)``: ``v_impact`` the
    largest speed sqrt(u^T Q u) of a system at the start of a step with a positive percussion
    (for :meth:`PairResult.window_floor`, as :func:`fmu_sync.core.batch.run_pairs1` keeps it)."""
    n = q1.shape[0]
    qM, h, uf, Sinv1, Sinv_w1, WS1 = step_workspace(sa1, dt, scheme, theta)
    _, _, _, Sinv2, Sinv_w2, WS2 = step_workspace(sa2, dt, scheme, theta)
    tau1 = np.zeros(n)
    tau2 = np.zeros(n)
    zero1 = np.zeros(n)  # forces of the uncoupled law (zero), for distance-only records
    zero2 = np.zeros(n)
    c1q = np.empty(n)
    c1u = np.empty(n)
    c2q = np.empty(n)
    c2u = np.empty(n)
    scalar = n == 1 and sa1.B.shape[1] == 1 and sa2.B.shape[1] == 1
    p1 = scalar_params(sa1) if scalar else (0.0,) * 10
    p2 = scalar_params(sa2) if scalar else (0.0,) * 10
    sg = geo.scalar
    kp = Kp[0, 0]
    kd = Kd[0, 0]
    F1 = sa1.F
    Omega1 = sa1.Omega
    phi1 = sa1.phi
    F2 = sa2.F
    Omega2 = sa2.Omega
    phi2 = sa2.phi
    Si1 = Sinv1[0, 0]
    Si_w1 = Sinv_w1[0]
    Si2 = Sinv2[0, 0]
    Si_w2 = Sinv_w2[0]
    imp1 = 0
    imp2 = 0
    v_imp = 0.0
    row = 0
    countdown = 1  # row 0 is the initial state
    total = n_steps + 1 if dt_last > 0.0 else n_steps
    for k in range(total + 1):
        is_row = k == total   # the final state is always a row
        countdown -= 1
        if countdown == 0:
            countdown = record_every
            is_row = True
        # forces from the states at the start of the step (zero-order hold)
        need_d = is_row and record_d
        if scalar:
            if law != UNCOUPLED or need_d:
                tau1[0], tau2[0], d, br, E = coupling_step1(law, sg, kp, kd, q1[0], u1[0], q2[0], u2[0],
                                                            need_d)
        elif law != UNCOUPLED:
            d, br, E = coupling_step(law, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u, need_d)
        elif need_d:
            d, br, E = coupling_step(UNCOUPLED, geo, Kp, Kd, q1, u1, q2, u2, zero1, zero2, c1q, c1u, c2q, c2u, True)
        if k == 0 and k0 == 0:  # row 0 of the run: the forces at the start
            for i in range(n):
                TAU1[0, i] = tau1[i]
                TAU2[0, i] = tau2[i]
        if is_row:
            T[row] = t0 + (k0 + k) * dt if k <= n_steps else t0 + (k0 + n_steps) * dt + dt_last
            for i in range(n):
                Q1[row, i] = q1[i]
                U1[row, i] = u1[i]
                Q2[row, i] = q2[i]
                U2[row, i] = u2[i]
            if record_d:
                D[row] = d
                BR[row] = br
                EU[row] = E
            if not (finish_step(q1, u1) and finish_step(q2, u2)) or (record_d and not math.isfinite(d)):
                return DIVERGED, k, row, imp1, imp2, v_imp
            row += 1
        if k == total:
            break
        # the forces held over this step belong to the row that ends it
        if countdown == 1 or k == total - 1:
            for i in range(n):
                TAU1[row, i] = tau1[i]
                TAU2[row, i] = tau2[i]
        t = t0 + (k0 + k) * dt
        hk = dt
        if k == n_steps:   # the shortened last step
            hk = dt_last
            if scheme == THETA:
                WS1 = theta_matrices(sa1, hk, theta, Sinv1, Sinv_w1)
                WS2 = theta_matrices(sa2, hk, theta, Sinv2, Sinv_w2)
                Si1 = Sinv1[0, 0]
                Si_w1 = Sinv_w1[0]
                Si2 = Sinv2[0, 0]
                Si_w2 = Sinv_w2[0]
        if scalar:  # the 1-DOF fast path (bitwise identical to the general step)
            va = abs(u1[0]) * math.sqrt(sg.Q11)
            vb = abs(u2[0]) * math.sqrt(sg.Q11)
            if scheme == THETA:
                q1[0], u1[0], P1 = theta_step1(p1, F1, Omega1, phi1, Si1, Si_w1, WS1, theta, q1[0],
                                               u1[0], tau1[0], t, hk)
                q2[0], u2[0], P2 = theta_step1(p2, F2, Omega2, phi2, Si2, Si_w2, WS2, theta, q2[0],
                                               u2[0], tau2[0], t, hk)
            else:
                q1[0], u1[0], P1 = midpoint_step1(p1, F1, Omega1, phi1, q1[0], u1[0], tau1[0], t, hk)
                q2[0], u2[0], P2 = midpoint_step1(p2, F2, Omega2, phi2, q2[0], u2[0], tau2[0], t, hk)
        else:
            va = p_norm_diff(geo.Q, geo.Q, zero1, u1, zero1, zero2)
            vb = p_norm_diff(geo.Q, geo.Q, zero1, u2, zero1, zero2)
            if scheme == THETA:
                P1 = theta_step(sa1, q1, u1, tau1, t, hk, theta, Sinv1, Sinv_w1, WS1, qM, h, uf)
                P2 = theta_step(sa2, q2, u2, tau2, t, hk, theta, Sinv2, Sinv_w2, WS2, qM, h, uf)
            else:
                P1 = midpoint_step(sa1, q1, u1, tau1, t, hk, qM, h, uf)
                P2 = midpoint_step(sa2, q2, u2, tau2, t, hk, qM, h, uf)
            finish_step(q1, u1)
            finish_step(q2, u2)
        if P1 > 0.0:
            imp1 += 1
            v_imp = max(v_imp, va)
        if P2 > 0.0:
            imp2 += 1
            v_imp = max(v_imp, vb)
    return OK, total, row, imp1, imp2, v_imp


def simulate_pair(system, x1, x2, t_end: float, dt: float, coupling=None,
                  Kp=0.0, Kd=0.0, Q=None, scheme: str = "midpoint", theta: float = 0.5,
                  record_every: int = 1, record_distance: bool = True, progress=None,
                  t0: float = 0.0, allow_unstable: bool = False, sink=None,
                  chunk_rows: int = 65536) -> PairResult:
    """Simulate two systems from ``x1``, ``x2``, coupled by ``coupling``.

    ``system``: one :class:`MechanicalSystem` (two identical copies) or a pair
    ``(system1, system2)`` of non-identical systems; they must share M, w, g0
    and e (the impact geometry of the quotient distance) and may differ in K,
    C, f0 and forcing.
    ``coupling``: None (uncoupled), ``"euclidean"`` (PD baseline) or
    ``"switching"`` (the quotient coupling of docs/design.md §2.5), gains ``Kp``, ``Kd``
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
    s1, s2 = systems
    n = s1.n
    record_d = bool(record_distance) or law == SWITCHING
    plan = plan_run(systems, (x1, x2), t_end, dt, scheme=scheme, theta=theta, laws=[law], Kp=Kp, Kd=Kd,
                    record_every=record_every, t0=t0, allow_unstable=allow_unstable,
                    record_values=None if sink is not None else 4 * n + 2 * n + (4 if record_d else 1),
                    record_what="the record of simulate_pair",
                    record_hint=", or pass sink= to stream it in chunks")   # every check, once (docs/design.md §5.1.1)
    grid, dt, record_every, rows = plan.grid, plan.dt, plan.record_every, plan.rows
    n_steps, dt_last, code, theta = plan.whole_steps, plan.dt_last, plan.code, plan.theta
    q1, q2, u1, u2 = (a.copy() for a in (plan.q[0], plan.q[1], plan.u[0], plan.u[1]))
    Kp_m, Kd_m, limit = plan.Kp, plan.Kd, plan.limit
    lm = law_metric(Q, [s.K for s in systems], Kp_m, coupled=law != UNCOUPLED)
    geo = geometry(s1, lm.Q)
    if sink is not None:
        chunk_rows = int(chunk_rows)
        if chunk_rows < 1:
            raise ValueError(f"chunk_rows must be >= 1, got {chunk_rows}")
        cap = min(rows, chunk_rows + 1)   # a chunk re-records its start row (dropped)
        per = chunk_rows * record_every
        chunks = [per] * (n_steps // per) + ([n_steps % per] if n_steps % per else [])
        if not chunks or (grid.short and n_steps % per == 0):
            chunks.append(0)   # the chunk that takes the shortened last step
    else:
        cap = rows
        # chunks of whole record intervals, so that chunking changes no number
        if progress is None:
            chunks = [n_steps]
        else:
            per = max(1, (n_steps // record_every) // 100) * record_every
            chunks = [per] * (n_steps // per) + ([n_steps % per] if n_steps % per else [])
            if not chunks:
                chunks = [0]
    T = np.full(cap, np.nan)
    Q1, U1, Q2, U2, TAU1, TAU2 = (np.full((cap, n), np.nan) for _ in range(6))
    D, EU = np.full(cap, np.nan), np.full(cap, np.nan)
    BR = np.full(cap, BRANCH_NONE, dtype=np.int64)
    sa1 = s1.arrays()
    sa2 = s2.arrays()
    info = dict(mode="core", dt=dt, scheme=scheme, steps=grid.steps, identical=s1 is s2, **metric_info(lm, geo),
                v_impact=0.0)
    if grid.short:
        info["dt_last"] = dt_last
    if limit is not None:
        info.update(omega_c_dt=limit.h, exchange_bound=limit.bound, zeta=limit.zeta,
                    dt_max=limit.H_max)
    arrays = (T, Q1, U1, Q2, U2, TAU1, TAU2)

    def result(sl):
        take = (lambda a: a[sl].copy()) if sink is not None else (lambda a: a[sl])
        return PairResult(*(take(a) for a in arrays),
                          take(D) if record_d else None, take(BR) if record_d else None,
                          take(EU) if record_d else None, impacts1=imp1, impacts2=imp2,
                          coupling=coupling if coupling != "none" else None, info=dict(info))

    row0, k0, imp1, imp2, sent = 0, 0, 0, 0, 0
    status = OK
    for c, steps in enumerate(chunks):
        last = c == len(chunks) - 1
        if sink is not None:  # every chunk fills the buffer from row 0 (its start row, sent once)
            row0 = 0
        sl = slice(row0, cap)
        # a chunk records its start row; the next chunk starts on the row it ended on
        status, done, written, i1, i2, v = integrate_pair(
            sa1, sa2, geo, law, Kp_m, Kd_m, q1, u1, q2, u2, t0, k0, dt, steps, code, theta,
            record_every, record_d, T[sl], Q1[sl], U1[sl], Q2[sl], U2[sl], TAU1[sl], TAU2[sl],
            D[sl], BR[sl], EU[sl], dt_last if last else 0.0)
        imp1 += i1
        imp2 += i2
        info["v_impact"] = max(info["v_impact"], v)
        if sink is not None:
            first = 0 if c == 0 else 1
            if written > first:
                sink(result(slice(first, written)))
                sent += written - first
        if status != OK:
            row0 += written
            k0 += done
            break
        k0 += steps
        row0 += written - (0 if last else 1)
        if progress is not None:
            progress(min(k0 / max(n_steps, 1), 1.0))
    if sink is not None:
        info["rows"] = sent
        last_row = max(written - 1, 0)
        res = result(slice(last_row, last_row + 1))
    else:
        res = result(slice(0, row0 if status != OK else rows))
    if status != OK:
        err = SimulationDiverged(divergence_message(s1, scheme, dt, min(t0 + k0 * dt, grid.t_end),
                                                    what="a coupled state",
                                                    Kp=Kp_m if law != UNCOUPLED else None))
        res.error = str(err)
        err.partial = res
        raise err
    return res
