"""The one fixed-step loop of coupled systems (docs/design.md §2.5): N systems on a graph.

Every step: each node's input ``tau_i = sum_j a_ij tau_i^(j)`` is computed from the
states at the start of the step (:func:`.edges.network_forces`, each edge's law by
:func:`.edges.coupling_step`, the very functions the co-simulation master calls); the midpoint
and θ hold it over the step (Jacobi, zero-order hold), the default trapezoid solves its
trapezoid with the step (:mod:`.implicit_pair` for n = 1, :mod:`.loop_implicit` for n > 1);
then every system takes one Moreau step of :mod:`.moreau`. A co-simulation whose communication
step equals ``dt`` reproduces this run to round-off (the explicit exchange the midpoint, the
implicit exchange the trapezoid).

:func:`integrate_network` is the only such loop in the core:

* :func:`fmu_sync.core.network.simulate_network` runs it as it is;
* :func:`fmu_sync.core.pair.simulate_pair` runs it as the 2-node network (edge (0, 1),
  weights 1), as the master treats a pair;
* :func:`fmu_sync.core.batch.run_pairs1` runs it once per run of a sweep with the
  *decimating recorder* (``dec``): no trajectory, the last row only, every recorded
  distance pushed into the fixed-size recorder of :mod:`.metrics`.

The 1-DOF scalar path (n = 1: the step on floats, :func:`fmu_sync.core.moreau.step1_h`,
bitwise equal to the general step) is chosen once, inside the loop.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from .jit import njit

from .compensation import force_table
from .coupling import BRANCH_NONE, COMPENSATED, EUCLIDEAN, UNCOUPLED, p_norm_diff
from .distance import BRANCH_E
from .edges import coupling_step, coupling_step1, network_forces, node_force
from .harmonic import hsum_cos
from .implicit_pair import NEWTON_PASSES, held_linear, implicit_matrix, implicit_pair, newton_stop
from .loop_implicit import free_state, implicit_forces_nd, implicit_matrix_nd, implicit_workspace
from .metrics import decimator_push
from .model import SystemArrays
from .moreau import force, force1
from .steps import (DIVERGED, MIDPOINT, OK, TRAPEZOID, finish_step, flush1, hbase, scalar_params, step1_y, step_coeffs1, step_y,
                    theta_matrices)

__all__ = ["NodeGeometry", "node_geometry", "coupling_step", "coupling_step1", "network_forces", "node_force", "integrate_network",
           "sample_d", "no_decimator"]


# ------------------------------------------------------------------ recorders
@njit(cache=True, inline="always")
def sample_d(acc, bt, bd, st, t, d):
    """The decimating recorder's sample of d: ``acc`` = (count, d at the first sample, max),
    the rest to the fixed-size recorder of :mod:`.metrics` (:func:`.metrics.decimator_push`)."""
    if acc[0] == 0.0:
        acc[1] = d
        acc[2] = d
    elif d > acc[2]:
        acc[2] = d
    acc[0] += 1.0
    decimator_push(bt, bd, st, t, d)


def no_decimator():
    """``(acc, bt, bd, st)`` for a full record (``dec=False``): unused."""
    return np.zeros(3), np.zeros(0), np.zeros(0), np.zeros(0)


# ------------------------------------------------------------------ the loop
class NodeGeometry(NamedTuple):
    """The nodes' own impact geometry, stacked (the ``base`` of :func:`integrate_network`): each
    node's M, M^-1 (N, n, n), w, M^-1 w (N, n), g0, e, W = w^T M^-1 w (N,); B = I common. Systems
    that differ in M, w, g0 or e run in one loop (docs/design.md §2.5.3)."""

    M: np.ndarray
    Minv: np.ndarray
    B: np.ndarray
    w: np.ndarray
    g0: np.ndarray
    e: np.ndarray
    Minv_w: np.ndarray
    W: np.ndarray


def node_geometry(arrays) -> NodeGeometry:
    """:class:`NodeGeometry` of the nodes' :class:`~.model.SystemArrays` (B of the first)."""
    st = (lambda key, dt=np.float64: np.ascontiguousarray(np.stack([getattr(a, key) for a in arrays]), dtype=dt))
    return NodeGeometry(st("M"), st("Minv"), np.ascontiguousarray(arrays[0].B), st("w"),
                        np.array([float(a.g0) for a in arrays]), np.array([float(a.e) for a in arrays]),
                        st("Minv_w"), np.array([float(a.W) for a in arrays]))


@njit(cache=True, inline="always")
def _node(base, K, C, f0, F, Omega, phi, i):
    """The SystemArrays of node i: its own geometry in ``base`` (:class:`NodeGeometry`), its forces."""
    return SystemArrays(base.M[i], base.Minv[i], K[i], C[i], f0[i], F[i], Omega[i], phi[i], base.B, base.w[i],
                        base.g0[i], base.e[i], base.Minv_w[i], base.W[i])


@njit(cache=True)
def _matrices(base, K, C, f0, F, Omega, phi, scheme, theta, h, Sinv, Sinv_w, WS, co):
    """Per node, for step h: the theta iteration data (S^-1, S^-1 w, W_S) and, for n = 1,
    the scalar step coefficients (:func:`.moreau.step_coeffs1`) into ``co[i]``. (A call: the
    loop's body stays small.)"""
    scalar = K.shape[1] == 1
    for i in range(K.shape[0]):
        sa = _node(base, K, C, f0, F, Omega, phi, i)
        if scheme != MIDPOINT:
            WS[i] = theta_matrices(sa, h, theta, Sinv[i], Sinv_w[i])
        if scalar:
            if scheme != MIDPOINT:
                c = step_coeffs1(scalar_params(sa), Sinv[i, 0, 0], Sinv_w[i, 0], WS[i], theta * h, h)
            else:
                c = step_coeffs1(scalar_params(sa), sa.Minv[0, 0], sa.Minv_w[0], sa.W, 0.5 * h, h)
            (co[i, 0], co[i, 1], co[i, 2], co[i, 3], co[i, 4], co[i, 5], co[i, 6], co[i, 7], co[i, 8], co[i, 9],
             co[i, 10]) = c


@njit(cache=True, inline="always")
def _impact(i, k, imp, ep, last, v, v_imp):
    """Node i had a percussion in step k at speed v: its impact and contact-episode counts
    (an episode: a run of consecutive steps with a percussion); returns the largest speed."""
    imp[i] += 1
    if last[i] != k - 1:   # a new contact episode
        ep[i] += 1
    last[i] = k
    return v if v > v_imp else v_imp


@njit(cache=True, inline="always")
def _forcing1(F1d, Om1d, ph1d, nf, i, tf):
    """Node i's harmonic forcing at tf, n = 1 (:func:`.harmonic.hsum1_cos`, written out on the 1-D
    views: no arrays handed per step)."""
    fc = 0.0
    if nf > 0:
        fc = F1d[i * nf] * math.cos(Om1d[i * nf] * tf + ph1d[i * nf])
        for j in range(1, nf):
            fc += F1d[i * nf + j] * math.cos(Om1d[i * nf + j] * tf + ph1d[i * nf + j])
    return fc


@njit(cache=True, inline="always")
def net_force(sa, f0, i, q, u, tau, hf, tf, a, y, qe):
    """The force of node i (n > 1) at its force point, into y: the built-in law's
    (:func:`.moreau.force`, ``hb = f0 + B tau`` in ``qe``); a user law's copy of the loop takes
    its own (:func:`fmu_sync.core.law_loops.net_force`, parameters ``f0[i]``)."""
    for r in range(q.shape[0]):
        qe[r] = hbase(sa, tau, r)
    force(sa, f0, q, u, tau, qe, hf, tf, a, y, qe)


@njit(cache=True, inline="always")
def net_force1(cf, f0, f01, i, q, u, tau, B0, fc, tf, a, qa, ua, ta):
    """:func:`net_force` for n = 1 on floats (:func:`.moreau.force1`, ``hb = f0 + B tau``)."""
    return force1(cf, f0, q, u, tau, f01[i] + B0 * tau, fc, tf, a, qa, ua, ta)


@njit(cache=True)   # a call, not inlined: compiled once for every law's loop (a third of a law's compile)
def implicit_forces(laws, E2, W2, sg, kp, kd, qf, uf, co, tau1d, dq, du, hp, t, bh, Ainv, r, delta):
    """``tau1d`` (the forces at the step's start) -> the trapezoid of the coupling forces over the
    step (:func:`.implicit_pair.implicit_matrix`), n = 1: ``qf, uf`` the nodes' end states under ``tau1d`` held
    (contact left out), ``bh`` each edge's branch at the start (held over the step, as the master's
    implicit exchange holds it, docs/design.md §4.4); ``dq, du, r, delta`` (N,) scratch. Newton on
    ``R(delta) = (tau(x1(delta)) - tau(x0)) / 2 - delta`` with the matrix of :func:`.implicit_pair.implicit_matrix`:
    one pass when every edge is Euclidean or on branch E (linear), otherwise until
    |2 R| <= 1e-13 max|tau| (at most 8 passes; :func:`newton_stop`)."""
    N = tau1d.shape[0]
    linear = held_linear(laws, bh, E2.shape[0])
    for i in range(N):
        delta[i] = 0.0
    big0 = 0.0
    for it in range(NEWTON_PASSES):
        for i in range(N):
            dq[i] = qf[i] + co[i, 3] * delta[i]
            du[i] = uf[i] + co[i, 2] * delta[i]
            r[i] = 0.0
        for e_ in range(E2.shape[0]):
            lw = laws[e_]
            if lw == UNCOUPLED:
                continue
            ia = E2[e_, 0]
            ib = E2[e_, 1]
            f1, f2, _, _, _ = coupling_step1(lw, sg, kp, kd, dq[ia], du[ia], dq[ib], du[ib], False, hp, ia, ib, t,
                                             bh[e_])
            if W2[e_, 0] > 0.0:
                r[ia] += W2[e_, 0] * f1
            if W2[e_, 1] > 0.0:
                r[ib] += W2[e_, 1] * f2
        big = 0.0
        scale = 1e-300
        for i in range(N):   # 2 R = tau(x1) - tau(x0) - 2 delta
            r[i] = (r[i] - tau1d[i]) - 2.0 * delta[i]
            big = max(big, abs(r[i]))
            scale = max(scale, abs(tau1d[i]))
        if it == 0:
            big0 = big
        stop = newton_stop(it, big, big0, scale)
        if stop == 1:
            break
        for i in range(N):
            s = 0.0
            for j in range(N):
                s += Ainv[i, j] * r[j]
            delta[i] += s
        if linear or stop == 2:
            break
    for i in range(N):
        tau1d[i] += delta[i]


#: the loop's templates, as :data:`.moreau.TEMPLATES`: a user law's copy has its ``net_force``,
#: ``net_force1`` (core/law_loops.py)
TEMPLATES = {"_step_node": "never", "_free_nodes": "always", "_solved_nodes": "always", "integrate_network": "never"}
#: a 1-DOF force law's copy of the loop (:meth:`fmu_sync.core.forcelaw.ForceLaw.kernels`, n = 1) compiles
#: only what it runs: the n > 1 node steps, unreachable there (q has one column, the law's n), are these
#: stand-ins of the same signature and return type (a per-law compile a tenth shorter, docs/design.md
#: "The test suite")
N1_STANDINS = {"_step_node": "_n1_step_node", "_free_nodes": "_n1_free_nodes", "_solved_nodes": "_n1_solved_nodes"}


def _n1_step_node(base, K, C, f0, F, Omega, phi, i, q, u, tau, t, hk, scheme, theta, Sinv, Sinv_w, WS, y, hf, uf,
                  ua, qe):
    """:func:`_step_node`'s stand-in in a 1-DOF law's loop (never called there)."""
    return 0.0


def _n1_free_nodes(base, K, C, f0, F, Omega, phi, q, u, tau, t, hk, theta, Sinv, y, hf, qe, ws):
    """:func:`_free_nodes`'s stand-in in a 1-DOF law's loop (never called there)."""
    return None


def _n1_solved_nodes(base, K, C, f0, F, Omega, phi, q, u, tau, t, hk, theta, Sinv, Sinv_w, WS, y, hf, uf, qe, ws,
                     k, imp, ep, last, Q, zero, v_imp):
    """:func:`_solved_nodes`'s stand-in in a 1-DOF law's loop (never called there)."""
    return v_imp



@njit(cache=True)
def _step_node(base, K, C, f0, F, Omega, phi, i, q, u, tau, t, hk, scheme, theta, Sinv, Sinv_w, WS, y, hf, uf, ua,
               qe):
    """One Moreau step of node i (n > 1) in place, its start velocity into ``ua``; returns P.
    (A call, not inlined: the loop's body stays the small 1-DOF path.)"""
    for c in range(q.shape[1]):
        ua[c] = u[i, c]
    sa = _node(base, K, C, f0, F, Omega, phi, i)
    a = theta * hk if scheme != MIDPOINT else 0.5 * hk
    hsum_cos(sa.F, sa.Omega, sa.phi, t + a, hf)
    net_force(sa, f0, i, q[i], u[i], tau[i], hf, t + a, a, y, qe)
    if scheme != MIDPOINT:
        P = step_y(sa, Sinv[i], Sinv_w[i], WS[i], a, q[i], u[i], hk, y, uf)[0]
    else:
        P = step_y(sa, sa.Minv, sa.Minv_w, sa.W, a, q[i], u[i], hk, y, uf)[0]
    finish_step(q[i], u[i])
    return P


@njit(cache=True, inline="always")
def _free_nodes(base, K, C, f0, F, Omega, phi, q, u, tau, t, hk, theta, Sinv, y, hf, qe, ws):
    """The trapezoid's solve start (n > 1, core/loop_implicit.py): each node's forcing at the force
    point ``t + a`` into ``ws``'s ``hfs`` (kept for :func:`_solved_nodes`), its force under the start
    forces ``tau`` and its end state with the wall left out into ``ws``'s ``qc, uc``
    (:func:`.loop_implicit.free_state`). ``y, hf, qe`` (n,) scratch."""
    a = theta * hk
    hfs = ws[12]
    for i in range(q.shape[0]):
        sa = _node(base, K, C, f0, F, Omega, phi, i)
        hsum_cos(sa.F, sa.Omega, sa.phi, t + a, hf)
        for c in range(q.shape[1]):
            hfs[i, c] = hf[c]
        net_force(sa, f0, i, q[i], u[i], tau[i], hf, t + a, a, y, qe)
        free_state(Sinv, a, hk, q, u, y, ws[1], ws[2], i)


@njit(cache=True, inline="always")
def _solved_nodes(base, K, C, f0, F, Omega, phi, q, u, tau, t, hk, theta, Sinv, Sinv_w, WS, y, hf, uf, qe, ws, k,
                  imp, ep, last, Q, zero, v_imp):
    """The trapezoid's step of every node (n > 1) under the solved forces ``tau``, its wall in, in
    place: :func:`_step_node` with the forcing kept by :func:`_free_nodes` (the start velocities into
    ``ws``'s ``u0``); a percussion counted as the loop counts it
    (:func:`_impact`, step ``k``, speed in the norm of ``Q``). Returns the largest impact speed."""
    a = theta * hk
    hfs = ws[12]
    u0 = ws[13]
    for i in range(q.shape[0]):
        sa = _node(base, K, C, f0, F, Omega, phi, i)
        for c in range(q.shape[1]):
            hf[c] = hfs[i, c]
            u0[i, c] = u[i, c]
        net_force(sa, f0, i, q[i], u[i], tau[i], hf, t + a, a, y, qe)
        P = step_y(sa, Sinv[i], Sinv_w[i], WS[i], a, q[i], u[i], hk, y, uf)[0]
        finish_step(q[i], u[i])
        if P > 0.0:
            v_imp = _impact(i, k, imp, ep, last, p_norm_diff(Q, Q, zero, u0[i], zero, zero), v_imp)
    return v_imp


@njit(cache=True)
def integrate_network(base, K, C, f0, F, Omega, phi, geo, laws, E2, W2, Kp, Kd, q, u, t0, k0, dt,
                      n_steps, scheme, theta, record_every, record_d, T, Qr, Ur, TAU, D, BR, EU, dt_last,
                      dec, acc, bt, bd, st, imp, ep):
    """The loop over steps ``k0 .. k0 + n_steps`` (time ``t0 + k dt``), then, if
    ``dt_last > 0``, the shortened last step of the run; the final state is always a row.

    ``base``: :class:`NodeGeometry`, each node's M, w, g0, e (and B = I); ``K, C``
    (N, n, n), ``f0`` (N, n), ``F`` (N, nf, n), ``Omega, phi`` (N, nf): the
    nodes' forces (padding terms F = 0). ``E2`` (E, 2) edges (i, j); ``W2`` (E, 2)
    weights (a_ij, a_ji); ``laws`` (E,). ``q, u`` (N, n), advanced in place.

    Recorder: a row every ``record_every`` steps (row 0 the start, the last row the end)
    of ``T`` (rows,), ``Qr, Ur, TAU`` (rows, N, n) (TAU: the forces held over the step
    that ends at the row), and with ``record_d`` the edges' ``D, BR, EU`` (rows, E); ``D``, ``BR``
    without columns (rows, 0): the Euclidean error ``EU`` alone, no quotient distance (systems
    without a common impact geometry).
    ``dec`` (decimating recorder): the arrays have one row, each row overwrites it, and
    each row's distance of edge 0 goes to :func:`sample_d` ``(acc, bt, bd, st)``.

    ``imp``, ``ep`` (N,) int64: set to each node's impacts and contact episodes (runs of
    consecutive steps with a percussion) of this call. Output arrays come from the caller
    and only numbers are returned: boxing an array made here would call into Python on
    return, where a pending Ctrl-C or SIGTERM would be raised inside numba's runtime
    (a SystemError or a crash instead of a clean KeyboardInterrupt; tests/test_leftovers.py).

    Returns ``(status, steps_done, rows_written, v_impact, tau_max)``: the largest
    speed sqrt(u^T Q u) of a system at the start of a step with a positive percussion
    (``info["v_impact"]`` of a pair result), and (``dec`` only) max |tau| over the steps.
    ``status`` is DIVERGED if a state or recorded distance is not finite at a row.
    """
    N = q.shape[0]
    n = q.shape[1]
    E = E2.shape[0]
    scalar = n == 1
    qM = np.empty(n)
    h = np.empty(n)
    uf = np.empty(n)
    ua = np.empty(n)
    qe = np.empty(n)
    qut = np.empty(3)   # a user law's 1-DOF argument arrays (views of one buffer, as moreau.integrate1_with)
    qa = qut[0:1]
    uta = qut[1:2]
    ta = qut[2:3]
    zero = np.zeros(n)
    Sinv = np.zeros((N, n, n))
    Sinv_w = np.zeros((N, n))
    WS = np.zeros(N)
    co = np.zeros((N, 11))
    _matrices(base, K, C, f0, F, Omega, phi, scheme, theta, dt, Sinv, Sinv_w, WS, co)
    Ainv = np.zeros((N, N))
    implicit = scheme == TRAPEZOID and scalar
    for e_ in range(E2.shape[0]):
        if laws[e_] == COMPENSATED:   # its own law, held as it is (docs/design.md §2.5.2)
            implicit = False
    if implicit:
        implicit_matrix(laws, E2, W2, Kp[0, 0], Kd[0, 0], co, Ainv)
    implicit_nd = scheme == TRAPEZOID and not scalar   # n > 1: core/loop_implicit.py
    ws = implicit_workspace(N, n, E)
    if implicit_nd:
        implicit_matrix_nd(laws, E2, W2, Kp, Kd, Sinv, theta * dt, dt, ws[0])
    qf = np.zeros(N)
    uf1 = np.zeros(N)
    dq = np.zeros(N)
    du = np.zeros(N)
    rr = np.zeros(N)
    delta = np.zeros(N)
    fcs = np.zeros(N)
    pair = N == 2 and E == 1 and E2[0, 0] == 0 and E2[0, 1] == 1
    bh = np.full(max(E2.shape[0], 1), BRANCH_NONE)
    warm = (0.0, 0.0, 0.0, 0)   # the pair's last jump step's solve (implicit_pair), its branch and step
    br_warm = BRANCH_NONE
    k_warm = -2
    hp = force_table(K, C, f0, F, Omega, phi)
    B0 = base.B[0, 0]
    sg = geo.scalar
    sqQ = math.sqrt(sg.Q11)
    kp0 = Kp[0, 0]
    kd0 = Kd[0, 0]
    tau = np.zeros((N, n))
    # the 1-DOF path's 1-D views (for n = 1 the element i of q, u, tau, f0)
    q1d = q.reshape(N * n)
    u1d = u.reshape(N * n)
    tau1d = tau.reshape(N * n)
    f01 = np.ascontiguousarray(f0[:, 0])   # (a user law's parameters: at least one column, core/pair.py)
    nf = Omega.shape[1]
    F1d = np.ascontiguousarray(F).reshape(N * nf * n)
    Om1d = np.ascontiguousarray(Omega).reshape(N * nf)
    ph1d = np.ascontiguousarray(phi).reshape(N * nf)
    t1 = np.zeros(n)
    t2 = np.zeros(n)
    c1q = np.empty(n)
    c1u = np.empty(n)
    c2q = np.empty(n)
    c2u = np.empty(n)
    dk = np.full(E, np.nan)
    bk = np.full(E, BRANCH_NONE)
    ek = np.full(E, np.nan)
    imp[:] = 0
    ep[:] = 0
    last = np.full(N, -2, dtype=np.int64)   # the last step with a percussion, per node
    v_imp = 0.0
    tau_max = 0.0
    coupled = False
    law0 = laws[0] if E > 0 else UNCOUPLED
    uniform = True   # one law on every edge (a pair): the law is then loop-invariant
    for k in range(E):
        if laws[k] != UNCOUPLED:
            coupled = True
        if laws[k] != law0:
            uniform = False
    implicit = implicit and coupled   # uncoupled: the θ = ½ step alone (its own forcing and last-step matrices)
    dist = record_d and D.shape[1] == E   # D without columns: the Euclidean error alone (no common geometry)
    row = 0
    countdown = 1  # row 0 is the initial state
    total = n_steps + 1 if dt_last > 0.0 else n_steps
    k = 0
    while True:
        is_row = k == total   # the final state is always a row
        countdown -= 1
        if countdown == 0:
            countdown = record_every
            is_row = True
        rec = is_row and record_d
        need_d = rec and dist
        tk = t0 + (k0 + k) * dt if k <= n_steps else t0 + (k0 + n_steps) * dt + dt_last   # the states' time
        # forces from the states at the start of the step (Jacobi, zero-order hold)
        if (coupled or rec) and scalar:
            # network_forces for n = 1 on floats, written out here: the arrays an inlined or called
            # kernel takes cost reference counting on every step (measured: 2 instead of 8 Msteps/s)
            for i in range(N):
                tau1d[i] = 0.0
            for e_ in range(E):
                ia = E2[e_, 0]
                ib = E2[e_, 1]
                lw = law0 if uniform else laws[e_]
                f1, f2, d_, b_, e1 = coupling_step1(lw, sg, kp0, kd0, q1d[ia], u1d[ia], q1d[ib], u1d[ib], need_d,
                                                    hp, ia, ib, tk)
                bh[e_] = b_
                if rec:   # the record is read at rows only
                    dk[e_] = d_
                    bk[e_] = b_
                    ek[e_] = e1
                if lw != UNCOUPLED:
                    if W2[e_, 0] > 0.0:
                        tau1d[ia] += W2[e_, 0] * f1
                    if W2[e_, 1] > 0.0:
                        tau1d[ib] += W2[e_, 1] * f2
        elif coupled or rec:
            network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, need_d, dk, bk, ek, hp,
                           tk)
        r = 0 if dec else row
        if k == 0 and k0 == 0:
            for i in range(N):
                for c in range(n):
                    TAU[0, i, c] = tau[i, c]
        if implicit and coupled and k < total:   # the coupling inside the step: its trapezoid
            hk = dt_last if k == n_steps else dt
            if k == n_steps:
                _matrices(base, K, C, f0, F, Omega, phi, scheme, theta, hk, Sinv, Sinv_w, WS, co)
                implicit_matrix(laws, E2, W2, kp0, kd0, co, Ainv)
            t = t0 + (k0 + k) * dt
            a = theta * hk
            for i in range(N):
                cf = (co[i, 0], co[i, 1], co[i, 2], co[i, 3], co[i, 4], co[i, 5], co[i, 6], co[i, 7], co[i, 8],
                      co[i, 9], co[i, 10])
                fcs[i] = _forcing1(F1d, Om1d, ph1d, nf, i, t + a)
                y = net_force1(cf, f0, f01, i, q1d[i], u1d[i], tau1d[i], B0, fcs[i], t + a, a, qa, uta, ta)
                qf[i] = q1d[i] + (hk * u1d[i] + co[i, 3] * y)
                uf1[i] = u1d[i] + co[i, 2] * y
            if pair and (law0 == EUCLIDEAN or bh[0] == BRANCH_E):   # the pair's linear case on floats
                sE = kp0 * (qf[0] - qf[1]) + kd0 * (uf1[0] - uf1[1])   # the PD law (both laws' branch E)
                f1 = -sE
                f2 = sE
                r0 = W2[0, 0] * f1 - tau1d[0]
                r1 = W2[0, 1] * f2 - tau1d[1]
                tau1d[0] += Ainv[0, 0] * r0 + Ainv[0, 1] * r1
                tau1d[1] += Ainv[1, 0] * r0 + Ainv[1, 1] * r1
            elif pair:   # the switching pair on a jump branch: Newton on floats, warm from the last step
                # (cold at each row: a run in chunks of whole record intervals, progress=, is the same run)
                if is_row or bh[0] != br_warm or k != k_warm + 1:
                    warm = (0.0, 0.0, 0.0, 0)
                tau1d[0], tau1d[1], warm = implicit_pair(law0, bh[0], sg, kp0, kd0, W2[0, 0], W2[0, 1], qf[0],
                                                         uf1[0], qf[1], uf1[1], co[0, 3], co[0, 2], co[1, 3],
                                                         co[1, 2], tau1d[0], tau1d[1], Ainv[0, 0], Ainv[0, 1],
                                                         Ainv[1, 0], Ainv[1, 1], warm)
                br_warm = bh[0]
                k_warm = k
            else:
                implicit_forces(laws, E2, W2, sg, kp0, kd0, qf, uf1, co, tau1d, dq, du, hp, t + hk, bh, Ainv, rr,
                                delta)
            if k == 0 and k0 == 0:
                for i in range(N):
                    TAU[0, i, 0] = tau1d[i]
        if implicit_nd and coupled and k < total:   # n > 1: forces and free end states, then the solve
            hk = dt_last if k == n_steps else dt
            if k == n_steps:
                _matrices(base, K, C, f0, F, Omega, phi, scheme, theta, hk, Sinv, Sinv_w, WS, co)
                implicit_matrix_nd(laws, E2, W2, Kp, Kd, Sinv, theta * hk, hk, ws[0])
            _free_nodes(base, K, C, f0, F, Omega, phi, q, u, tau, t0 + (k0 + k) * dt, hk, theta, Sinv, qM, h, qe,
                        ws)   # contact left out, as for n = 1
            implicit_forces_nd(laws, geo, Kp, Kd, E2, W2, Sinv, theta * hk, hk, tau, bk, hp, t0 + (k0 + k) * dt + hk,
                               t1, t2, c1q, c1u, c2q, c2u, ws)
            if k == 0 and k0 == 0:
                TAU[0, :, :] = tau
        if is_row:
            T[r] = tk
            # the states (then flushed, as moreau.finish_step) and the edges' distance records, on the
            # 1-D views (no array views or calls: with the decimating recorder this is every few steps)
            ok = True
            for i in range(N):
                for c in range(n):
                    x = q1d[i * n + c]
                    v = u1d[i * n + c]
                    Qr[r, i, c] = x
                    Ur[r, i, c] = v
                    q1d[i * n + c] = flush1(x)
                    u1d[i * n + c] = flush1(v)
                    if not (math.isfinite(x) and math.isfinite(v)):
                        ok = False
            if record_d:
                for e_ in range(E):
                    EU[r, e_] = ek[e_]
                    if dist:
                        D[r, e_] = dk[e_]
                        BR[r, e_] = bk[e_]
                    if not math.isfinite(dk[e_] if dist else ek[e_]):
                        ok = False
            if not ok:
                return DIVERGED, k, row, v_imp, tau_max
            if dec:
                sample_d(acc, bt, bd, st, T[0], dk[0] if dist else ek[0])
            row += 1
        if k == total:
            break
        if (countdown == 1 or k == total - 1) and not dec:
            for i in range(N):
                for c in range(n):
                    TAU[row, i, c] = tau[i, c]
        if dec:
            for i in range(N * n):
                a_ = abs(tau1d[i])
                if a_ > tau_max:
                    tau_max = a_
        t = t0 + (k0 + k) * dt
        hk = dt
        if k == n_steps:   # the shortened last step
            hk = dt_last
            if not (implicit or implicit_nd):   # (the implicit solve above made them)
                _matrices(base, K, C, f0, F, Omega, phi, scheme, theta, hk, Sinv, Sinv_w, WS, co)
        a = theta * hk if scheme != MIDPOINT else 0.5 * hk
        if scalar:   # the 1-DOF path: the step on floats (bitwise the general step), 1-D views
            for i in range(N):
                u0 = u1d[i]
                # the forcing (harmonic.hsum1_cos of node i, written out: no arrays handed per step)
                fc = fcs[i] if implicit else _forcing1(F1d, Om1d, ph1d, nf, i, t + a)
                cf = (co[i, 0], co[i, 1], co[i, 2], co[i, 3], co[i, 4], co[i, 5], co[i, 6], co[i, 7], co[i, 8],
                      co[i, 9], co[i, 10])
                y = net_force1(cf, f0, f01, i, q1d[i], u0, tau1d[i], B0, fc, t + a, a, qa, uta, ta)
                qn, un, P = step1_y(cf, q1d[i], u0, y, hk)
                q1d[i] = flush1(qn)
                u1d[i] = flush1(un)
                if P > 0.0:
                    imp[i] += 1
                    if last[i] != k - 1:   # a new contact episode
                        ep[i] += 1
                    last[i] = k
                    v = abs(u0) * sqQ
                    if v > v_imp:
                        v_imp = v
        elif implicit_nd and coupled:   # the step under the solved forces (_free_nodes kept the forcing)
            v_imp = _solved_nodes(base, K, C, f0, F, Omega, phi, q, u, tau, t, hk, theta, Sinv, Sinv_w, WS, qM, h, uf,
                                  qe, ws, k, imp, ep, last, geo.Q, zero, v_imp)
        else:
            for i in range(N):
                P = _step_node(base, K, C, f0, F, Omega, phi, i, q, u, tau, t, hk, scheme, theta, Sinv, Sinv_w, WS,
                               qM, h, uf, ua, qe)
                if P > 0.0:
                    v_imp = _impact(i, k, imp, ep, last, p_norm_diff(geo.Q, geo.Q, zero, ua, zero, zero), v_imp)
        k += 1
    return OK, total, row, v_imp, tau_max
