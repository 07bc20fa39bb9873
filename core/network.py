"""N coupled systems on a weighted graph in one compiled loop (monolithic
reference of :func:`fmu_sync.master.cosimulate_network`).

System i receives ``tau_i = sum_j a_ij tau_i^(j)``, where ``tau_i^(j)`` is the
force on i of the pairwise law of edge (i, j) (switching or Euclidean, one law
per edge; :func:`fmu_sync.core.pair.coupling_step`, the function the master
calls) and ``a_ij >= 0`` the weight of the directed link j -> i. As in the pair,
every step computes all forces from the states at its start (Jacobi, zero-order
hold) and then advances each system by one Moreau step, so a co-simulation with
``H = dt`` reproduces this run to round-off.

The systems may differ in K, C, f0 and forcing; they share M, w, g0 and e (the
impact geometry of the quotient distance). Graph helpers: :func:`ring`,
:func:`path`, :func:`star`, :func:`all_to_all`, or any N x N weight matrix.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .coupling import BRANCH_NONE, UNCOUPLED, gain_matrix, law_metric, metric_info
from .distance import geometry
from .model import MechanicalSystem, SystemArrays
from .checks import divergence_message
from .errors import SimulationDiverged
from .moreau import DIVERGED, OK, THETA, finish_step, midpoint_step, theta_matrices, theta_step
from .pair import LAWS, coupling_step, coupling_step1
from .plan import as_systems, coupled_weights, edges_of, held_exchange, plan_run, weights
from .result import NetworkResult

__all__ = ["simulate_network", "ring", "path", "star", "all_to_all", "GRAPHS", "graph", "weights",
           "edges_of", "edge_laws", "coupled_weights", "edge_arrays", "network_forces", "node_force",
           "held_exchange"]


# ------------------------------------------------------------------ graphs
def _count(N) -> int:
    N = int(N)
    if N < 2:
        raise ValueError(f"a network needs N >= 2 systems, got {N}")
    return N


def ring(N: int, weight: float = 1.0) -> np.ndarray:
    """Cycle 0-1-...-(N-1)-0 (for N = 2: the single pair)."""
    N = _count(N)
    A = np.zeros((N, N))
    for i in range(N):
        j = (i + 1) % N
        if i != j:
            A[i, j] = A[j, i] = weight
    return A


def path(N: int, weight: float = 1.0) -> np.ndarray:
    """Chain 0-1-...-(N-1)."""
    N = _count(N)
    A = np.zeros((N, N))
    for i in range(N - 1):
        A[i, i + 1] = A[i + 1, i] = weight
    return A


def star(N: int, weight: float = 1.0, center: int = 0) -> np.ndarray:
    """Every node linked to ``center``."""
    N = _count(N)
    if not 0 <= center < N:
        raise ValueError(f"center must be a node index in [0, {N - 1}], got {center}")
    A = np.zeros((N, N))
    for i in range(N):
        if i != center:
            A[i, center] = A[center, i] = weight
    return A


def all_to_all(N: int, weight: float = 1.0) -> np.ndarray:
    """Complete graph."""
    N = _count(N)
    return weight * (np.ones((N, N)) - np.eye(N))


GRAPHS = {"ring": ring, "path": path, "star": star, "all-to-all": all_to_all}


def graph(kind: str, N: int, weight: float = 1.0) -> np.ndarray:
    """Weight matrix of a named graph (``ring``, ``path``, ``star``, ``all-to-all``)."""
    if kind not in GRAPHS:
        raise ValueError(f"graph must be one of {sorted(GRAPHS)} or an N x N weight matrix, got {kind!r}")
    return GRAPHS[kind](N, weight)


def edge_laws(coupling, edges) -> np.ndarray:
    """Law codes per edge from one law name or a sequence of names (one per edge)."""
    if coupling is None or isinstance(coupling, str):
        if coupling not in LAWS:
            raise ValueError(f"coupling must be one of {list(LAWS)} or one of them per edge, got {coupling!r}")
        return np.full(len(edges), LAWS[coupling], dtype=np.int64)
    names = list(coupling)
    if len(names) != len(edges):
        raise ValueError(f"coupling per edge needs {len(edges)} laws (edges {edges}), got {len(names)}")
    for k, c in enumerate(names):
        if c not in LAWS:
            raise ValueError(f"coupling of edge {edges[k]} must be one of {list(LAWS)}, got {c!r}")
    return np.array([LAWS[c] for c in names], dtype=np.int64)


def edge_arrays(A, edges):
    """``(E2, W2)``: the edges (i, j) as an (E, 2) int array and their weights (a_ij, a_ji) as
    an (E, 2) float array, the form the compiled kernels take."""
    E = len(edges)
    E2 = np.array(edges, dtype=np.int64).reshape(E, 2)
    W2 = np.array([[A[i, j], A[j, i]] for i, j in edges], dtype=np.float64).reshape(E, 2)
    return E2, W2


# ------------------------------------------------------------------ kernel
@njit(cache=True, inline="always")
def _node(base, K, C, f0, F, Omega, phi, i):
    """The SystemArrays of node i: the common geometry of ``base``, the node's forces."""
    return SystemArrays(base.M, base.Minv, K[i], C[i], f0[i], F[i], Omega[i], phi[i], base.B, base.w,
                        base.g0, base.e, base.Minv_w, base.W)


@njit(cache=True, inline="always")
def _edge(law, geo, Kp, Kd, q, u, a, b, t1, t2, c1q, c1u, c2q, c2u, need_d):
    """:func:`fmu_sync.core.pair.coupling_step` of the edge (a, b) (its 1-DOF float form
    ``coupling_step1`` for n = 1, the same arithmetic): forces into t1, t2; returns
    ``(d, branch, euclidean)``."""
    if q.shape[1] == 1:
        t1[0], t2[0], d, br, eu = coupling_step1(law, geo.scalar, Kp[0, 0], Kd[0, 0], q[a, 0], u[a, 0], q[b, 0],
                                                 u[b, 0], need_d)
        return d, br, eu
    return coupling_step(law, geo, Kp, Kd, q[a], u[a], q[b], u[b], t1, t2, c1q, c1u, c2q, c2u, need_d)


@njit(cache=True)
def network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, need_d, dk, bk, ek):
    """Every node's input ``tau_i = sum_j a_ij tau_i^(j)`` at the states ``q, u`` (N, n), each
    edge's law evaluated once (:func:`fmu_sync.core.pair.coupling_step`), and each edge's
    distance record into ``dk, bk, ek`` (E,). ``E2`` (E, 2) edges (i, j); ``W2`` (E, 2) weights
    (a_ij, a_ji); ``t1, t2, c1q, c1u, c2q, c2u``: (n,) scratch. Used by
    :func:`integrate_network` and, per communication step, by the master's exchange loop."""
    n = q.shape[1]
    for i in range(q.shape[0]):
        for c in range(n):
            tau[i, c] = 0.0
    for e_ in range(E2.shape[0]):
        a = E2[e_, 0]
        b = E2[e_, 1]
        d, br, eu = _edge(laws[e_], geo, Kp, Kd, q, u, a, b, t1, t2, c1q, c1u, c2q, c2u, need_d)
        if laws[e_] != UNCOUPLED:
            if W2[e_, 0] > 0.0:
                for c in range(n):
                    tau[a, c] += W2[e_, 0] * t1[c]
            if W2[e_, 1] > 0.0:
                for c in range(n):
                    tau[b, c] += W2[e_, 1] * t2[c]
        dk[e_] = d
        bk[e_] = br
        ek[e_] = eu


@njit(cache=True)
def node_force(i, laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u):
    """Node i's input alone at the states ``q, u`` (the Gauss–Seidel exchange: each node's
    input from the newest states of the others); arguments as :func:`network_forces`."""
    n = q.shape[1]
    for c in range(n):
        tau[i, c] = 0.0
    for e_ in range(E2.shape[0]):
        a = E2[e_, 0]
        b = E2[e_, 1]
        if laws[e_] == UNCOUPLED or (i != a and i != b):
            continue
        w = W2[e_, 0] if i == a else W2[e_, 1]
        if w > 0.0:
            _edge(laws[e_], geo, Kp, Kd, q, u, a, b, t1, t2, c1q, c1u, c2q, c2u, False)
            for c in range(n):
                tau[i, c] += w * (t1[c] if i == a else t2[c])


@njit(cache=True)
def integrate_network(base, K, C, f0, F, Omega, phi, geo, laws, E2, W2, Kp, Kd, q, u, t0, k0, dt,
                      n_steps, scheme, theta, record_every, record_d, T, Qr, Ur, TAU, D, BR, EU, dt_last=0.0):
    """The monolithic loop over steps ``k0 .. k0 + n_steps`` (time ``t0 + k dt``), then,
    if ``dt_last > 0``, the shortened last step of the run; the final state is always
    recorded (as :func:`fmu_sync.core.pair.integrate_pair`).

    ``base``: SystemArrays with the common M, w, g0, e (and B = I); ``K, C``
    (N, n, n), ``f0`` (N, n), ``F`` (N, nf, n), ``Omega, phi`` (N, nf): the
    nodes' forces. ``E2`` (E, 2) edges (i, j); ``W2`` (E, 2) weights
    (a_ij, a_ji); ``laws`` (E,). ``q, u`` (N, n), advanced in place.
    Returns ``(status, steps_done, rows_written, impacts (N,))``."""
    N = q.shape[0]
    n = q.shape[1]
    E = E2.shape[0]
    qM = np.empty(n)
    h = np.empty(n)
    uf = np.empty(n)
    Sinv = np.zeros((N, n, n))
    Sinv_w = np.zeros((N, n))
    WS = np.zeros(N)
    if scheme == THETA:
        for i in range(N):
            WS[i] = theta_matrices(_node(base, K, C, f0, F, Omega, phi, i), dt, theta, Sinv[i], Sinv_w[i])
    tau = np.zeros((N, n))
    t1 = np.zeros(n)
    t2 = np.zeros(n)
    c1q = np.empty(n)
    c1u = np.empty(n)
    c2q = np.empty(n)
    c2u = np.empty(n)
    dk = np.full(E, np.nan)
    bk = np.full(E, BRANCH_NONE)
    ek = np.full(E, np.nan)
    imp = np.zeros(N, dtype=np.int64)
    coupled = False
    for k in range(E):
        if laws[k] != UNCOUPLED:
            coupled = True
    row = 0
    countdown = 1  # row 0 is the initial state
    total = n_steps + 1 if dt_last > 0.0 else n_steps
    for k in range(total + 1):
        is_row = k == total   # the final state is always a row
        countdown -= 1
        if countdown == 0:
            countdown = record_every
            is_row = True
        need_d = is_row and record_d
        # forces from the states at the start of the step (Jacobi, zero-order hold)
        if coupled or need_d:
            network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, need_d, dk, bk, ek)
        if k == 0 and k0 == 0:
            for i in range(N):
                for c in range(n):
                    TAU[0, i, c] = tau[i, c]
        if is_row:
            T[row] = t0 + (k0 + k) * dt if k <= n_steps else t0 + (k0 + n_steps) * dt + dt_last
            ok = True
            for i in range(N):
                for c in range(n):
                    Qr[row, i, c] = q[i, c]
                    Ur[row, i, c] = u[i, c]
                if not finish_step(q[i], u[i]):
                    ok = False
            if record_d:
                for e_ in range(E):
                    D[row, e_] = dk[e_]
                    BR[row, e_] = bk[e_]
                    EU[row, e_] = ek[e_]
                    if not math.isfinite(dk[e_]):
                        ok = False
            if not ok:
                return DIVERGED, k, row, imp
            row += 1
        if k == total:
            break
        if countdown == 1 or k == total - 1:
            for i in range(N):
                for c in range(n):
                    TAU[row, i, c] = tau[i, c]
        t = t0 + (k0 + k) * dt
        hk = dt
        if k == n_steps:   # the shortened last step
            hk = dt_last
            if scheme == THETA:
                for i in range(N):
                    WS[i] = theta_matrices(_node(base, K, C, f0, F, Omega, phi, i), hk, theta, Sinv[i],
                                           Sinv_w[i])
        for i in range(N):
            sa = _node(base, K, C, f0, F, Omega, phi, i)
            if scheme == THETA:
                P = theta_step(sa, q[i], u[i], tau[i], t, hk, theta, Sinv[i], Sinv_w[i], WS[i], qM, h, uf)
            else:
                P = midpoint_step(sa, q[i], u[i], tau[i], t, hk, qM, h, uf)
            finish_step(q[i], u[i])
            if P > 0.0:
                imp[i] += 1
    return OK, total, row, imp


# ------------------------------------------------------------------ Python API
def _stack(systems, n):
    nf = max(len(s.forcing) for s in systems)
    N = len(systems)
    K = np.zeros((N, n, n))
    C = np.zeros((N, n, n))
    f0 = np.zeros((N, n))
    F = np.zeros((N, nf, n))
    Om = np.zeros((N, nf))
    ph = np.zeros((N, nf))
    for i, s in enumerate(systems):
        sa = s.arrays()
        K[i], C[i], f0[i] = sa.K, sa.C, sa.f0
        m = sa.Omega.shape[0]
        F[i, :m], Om[i, :m], ph[i, :m] = sa.F, sa.Omega, sa.phi  # padding: F = 0 terms
    return K, C, f0, F, Om, ph


def simulate_network(system, states, A, t_end: float, dt: float, coupling="switching", Kp=0.0,
                     Kd=0.0, Q=None, scheme: str = "midpoint", theta: float = 0.5,
                     record_every: int = 1, record_distance: bool = True, progress=None,
                     t0: float = 0.0, allow_unstable: bool = False) -> NetworkResult:
    """Simulate N systems coupled on the graph ``A`` (monolithic, compiled).

    ``system``: one :class:`MechanicalSystem` for every node or a sequence of N
    (equal M, w, g0, e; K, C, f0, forcing per node); ``states``: N start states
    (q, u); ``A``: N x N weights (``a_ij``: weight of the force on i from edge
    (i, j); zero diagonal), e.g. :func:`ring`; ``coupling``: a law name for every
    edge or one per edge (order of :func:`edges_of`); gains ``Kp``, ``Kd``; norm
    weight ``Q`` (default: the law's own metric, ``energy_metric(K, Kp, A)``, Q = K + lam Kp with
    lam the mean nonzero eigenvalue of the graph's Laplacian; ``info["metric"]`` says which,
    docs/design.md §2.5.1). The same stability checks as :func:`fmu_sync.core.pair.simulate_pair`
    (``allow_unstable`` to skip them). Returns a :class:`NetworkResult`
    (``d_max``: the largest pairwise distance per row); raises
    :class:`SimulationDiverged` with the finite part of the record, marked
    failed, in ``.partial``.
    """
    states = list(states)
    N = len(states)
    if N < 2:
        raise ValueError(f"a network needs at least 2 states, got {N}")
    systems = as_systems(system, N)
    A = weights(A, N)
    edges = edges_of(A)
    laws = edge_laws(coupling, edges)
    record_d = bool(record_distance) or bool(np.any(laws == LAWS["switching"]))
    E = len(edges)
    plan = plan_run(systems, states, t_end, dt, scheme=scheme, theta=theta, A=A, laws=laws, Kp=Kp, Kd=Kd,
                    record_every=record_every, t0=t0, allow_unstable=allow_unstable,
                    record_values=1 + 3 * N * systems[0].n + (3 * E + 1 if record_d else 0),
                    record_what="the record of simulate_network",
                    system_names=[f"node {i + 1}" for i in range(N)])   # every check, once (docs/design.md §5.1.1)
    s0, n, grid, dt = systems[0], systems[0].n, plan.grid, plan.dt
    n_steps, dt_last, record_every = plan.whole_steps, plan.dt_last, plan.record_every
    code, theta, q, u, rows = plan.code, plan.theta, plan.q.copy(), plan.u.copy(), plan.rows
    coupled, Kp_m, Kd_m, limit = plan.coupled, plan.Kp, plan.Kd, plan.limit
    lm = law_metric(Q, [s.K for s in systems], Kp_m, coupled_weights(A, edges, laws) if coupled else None,
                    coupled=coupled)
    geo = geometry(s0, lm.Q)
    T = np.full(rows, np.nan)
    Qr, Ur, TAU = (np.full((rows, N, n), np.nan) for _ in range(3))
    D, EU = np.full((rows, E), np.nan), np.full((rows, E), np.nan)
    BR = np.full((rows, E), BRANCH_NONE, dtype=np.int64)
    E2, W2 = edge_arrays(A, edges)
    K, C, f0, F, Om, ph = _stack(systems, n)
    base = s0.arrays()
    if progress is None:
        chunks = [n_steps]
    else:
        per = max(1, (n_steps // record_every) // 100) * record_every
        chunks = [per] * (n_steps // per) + ([n_steps % per] if n_steps % per else [])
        if not chunks:
            chunks = [0]
    row0, k0 = 0, 0
    imp = np.zeros(N, dtype=np.int64)
    status = OK
    for c, steps in enumerate(chunks):
        last = c == len(chunks) - 1
        sl = slice(row0, rows)
        status, done, written, i_ = integrate_network(
            base, K, C, f0, F, Om, ph, geo, laws, E2, W2, Kp_m, Kd_m, q, u, float(t0), k0, dt, steps,
            code, theta, record_every, record_d, T[sl], Qr[sl], Ur[sl], TAU[sl], D[sl], BR[sl], EU[sl],
            dt_last if last else 0.0)
        imp += i_
        if status != OK:
            row0 += written
            k0 += done
            break
        k0 += steps
        row0 += written - (0 if last else 1)
        if progress is not None:
            progress(min(k0 / max(n_steps, 1), 1.0))
    sl = slice(0, row0 if status != OK else rows)
    V = None
    if record_d:
        a_sym = np.array([0.5 * (A[i, j] + A[j, i]) for i, j in edges])
        with np.errstate(over="ignore"):  # a failed run may end on huge (finite) d
            V = 0.5 * (D[sl] ** 2) @ a_sym
    info = dict(mode="core", dt=dt, scheme=scheme, steps=grid.steps, N=N,
                coupling=coupling if isinstance(coupling, str) or coupling is None else list(coupling),
                **metric_info(lm, geo))
    if limit is not None:
        info.update(omega_c_dt=limit.h, exchange_bound=limit.bound, zeta=limit.zeta,
                    dt_max=limit.H_max)
    res = NetworkResult(T[sl], Qr[sl], Ur[sl], TAU[sl], edges, D[sl] if record_d else None,
                        BR[sl] if record_d else None, EU[sl] if record_d else None, V,
                        impacts=[int(v) for v in imp], info=info)
    if status != OK:
        msg = divergence_message(s0, scheme, dt, min(t0 + k0 * dt, grid.t_end), what="a network state or distance",
                                 Kp=Kp_m if coupled else None)
        if limit is not None:
            msg += f" ({limit.message()})"
        err = SimulationDiverged(msg)
        res.error = str(err)
        err.partial = res
        raise err
    return res
