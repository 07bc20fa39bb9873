"""N coupled systems on a weighted graph in one compiled loop (monolithic
reference of :func:`fmu_sync.master.cosimulate_network`).

System i receives ``tau_i = sum_j a_ij tau_i^(j)``, where ``tau_i^(j)`` is the
force on i of the pairwise law of edge (i, j) (switching or Euclidean, one law
per edge; :func:`fmu_sync.core.loop.coupling_step`, the function the master
calls) and ``a_ij >= 0`` the weight of the directed link j -> i. Every step
computes all forces from the states at its start (Jacobi, zero-order hold) and
then advances each system by one Moreau step, so a co-simulation with ``H = dt``
reproduces this run to round-off. The loop is :func:`fmu_sync.core.loop.integrate_network`,
the one loop of the core (the pair is its 2-node network).

The systems may differ in K, C, f0 and forcing; they share M, w, g0 and e (the
impact geometry of the quotient distance). Graph helpers: :func:`ring`,
:func:`path`, :func:`star`, :func:`all_to_all`, or any N x N weight matrix.
"""
from __future__ import annotations

import numpy as np

from .coupling import BRANCH_NONE, QUOTIENT_LAWS, law_metric, metric_info
from .distance import geometry
from .checks import divergence_message, land_last_row
from .errors import ForceLawFailed, SimulationDiverged
from .failure import rows_written
from .loop import network_forces, no_decimator, node_force
from .steps import DEFAULT_SCHEME, DIVERGED, OK
from .pair import LAWS, failure_message, locate_failure, network_loop, stack_nodes
from .plan import coupling_exchange, as_systems, coupled_weights, edges_of, held_exchange, plan_run, weights
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




def network_record(rows: int, N: int, n: int, E: int):
    """The record arrays of a network run as the loop takes them, ``(T, Qr, Ur, TAU, D, BR, EU)``:
    T (rows,), Qr, Ur, TAU (rows, N, n), the edges' D, BR, EU (rows, E); NaN until written
    (core/failure.py)."""
    T = np.full(rows, np.nan)
    Qr, Ur, TAU = (np.full((rows, N, n), np.nan) for _ in range(3))
    D, EU = np.full((rows, E), np.nan), np.full((rows, E), np.nan)
    BR = np.full((rows, E), BRANCH_NONE, dtype=np.int64)
    return T, Qr, Ur, TAU, D, BR, EU


# ------------------------------------------------------------------ Python API
def simulate_network(system, states, A, t_end: float, dt: float, coupling="switching", Kp=0.0,
                     Kd=0.0, Q=None, scheme: str = DEFAULT_SCHEME, theta: float = 0.5,
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
    record_d = bool(record_distance) or bool(np.any(np.isin(laws, QUOTIENT_LAWS)))
    E = len(edges)
    plan = plan_run(systems, states, t_end, dt, scheme=scheme, theta=theta, A=A, laws=laws, Kp=Kp, Kd=Kd,
                    exchange=coupling_exchange(scheme, systems),
                    record_every=record_every, t0=t0, allow_unstable=allow_unstable,
                    record_values=1 + 3 * N * systems[0].n + (3 * E + 1 if record_d else 0),
                    record_what="the record of simulate_network",
                    system_names=[f"node {i + 1}" for i in range(N)])   # every check, once (docs/design.md §5.1.1)
    s0, n, grid, dt = systems[0], systems[0].n, plan.grid, plan.dt
    n_steps, dt_last, record_every = plan.whole_steps, plan.dt_last, plan.record_every
    code, theta, q, u, rows = plan.code, plan.theta, plan.q.copy(), plan.u.copy(), plan.rows
    coupled, Kp_m, Kd_m, limit = plan.coupled, plan.Kp, plan.Kd, plan.limit
    lm = law_metric(Q, [s.K for s in systems], Kp_m, coupled_weights(A, edges, laws) if coupled else None,
                    coupled=coupled, stiffness=s0.metric_source)
    geo = geometry(s0, lm.Q)
    T, Qr, Ur, TAU, D, BR, EU = network_record(rows, N, n, E)
    E2, W2 = edge_arrays(A, edges)
    nodes = stack_nodes(*systems)
    loop = network_loop(systems)
    dec = no_decimator()
    if progress is None:
        chunks = [n_steps]
    else:
        per = max(1, (n_steps // record_every) // 100) * record_every
        chunks = [per] * (n_steps // per) + ([n_steps % per] if n_steps % per else [])
        if not chunks:
            chunks = [0]
    row0, k0 = 0, 0
    imp = np.zeros(N, dtype=np.int64)
    i_, ep = np.zeros(N, dtype=np.int64), np.zeros(N, dtype=np.int64)   # each chunk's counts
    status, raised, chunk_k = OK, None, 0
    for c, steps in enumerate(chunks):
        last = c == len(chunks) - 1
        sl = slice(row0, rows)
        chunk_k = k0
        try:
            status, done, written, _, _ = loop(
                *nodes, geo, laws, E2, W2, Kp_m, Kd_m, q, u, float(t0), k0, dt, steps,
                code, theta, record_every, record_d, T[sl], Qr[sl], Ur[sl], TAU[sl], D[sl], BR[sl], EU[sl],
                dt_last if last else 0.0, False, *dec, i_, ep)
        except Exception as exc:   # raised by the user's law inside the compiled loop (core/failure.py)
            if s0.force is None:
                raise
            status, done, written, raised = DIVERGED, 0, rows_written(T[sl]), exc
        if last and status == OK:
            land_last_row(T[sl], written, grid)
        imp += i_
        if status != OK:
            row0 += written
            k0 += done
            break
        k0 += steps
        row0 += written - (0 if last else 1)
        if progress is not None:
            progress(min(k0 / max(n_steps, 1), 1.0))
    fail_msg, again, t_fail = None, None, min(t0 + k0 * dt, grid.t_end)
    if status != OK:   # the failing step (core/failure.py): from the last row, every step again with a row each
        b = row0 - 1
        k_b = chunk_k + (written - 1) * record_every
        m = min(record_every, n_steps - k_b)
        h_last = dt_last if m == n_steps - k_b else 0.0
        bufs, j, again = locate_failure(loop, nodes, geo, laws, E2, W2, Kp_m, Kd_m, Qr[b], Ur[b], t0, k_b, dt, m,
                                        code, theta, record_d, h_last, lambda c: network_record(c, N, n, E))
        if raised is not None and again is None:
            raise raised   # not the law's (it did not raise again from the same state): as it came
        if j is not None:
            if j >= 1:   # the last good step as the last row
                for big, small in zip((T, Qr, Ur, TAU, D, BR, EU), bufs):
                    big[row0] = small[j]
                row0 += 1
            hk = h_last if (j == m and h_last > 0.0) else dt
            fail_msg = failure_message(systems, [s.p for s in systems], bufs, j, again, code, theta, hk,
                                       [f"node {i + 1}" for i in range(N)])
            t_fail = min(float(bufs[0][j]) + hk, grid.t_end)
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
        msg = fail_msg
        if msg is None:
            msg = divergence_message(s0, scheme, dt, t_fail, what="a network state or distance",
                                     Kp=Kp_m if coupled else None)
            if limit is not None:
                msg += f" ({limit.message()})"
        err = (ForceLawFailed if again is not None else SimulationDiverged)(msg)
        res.error = str(err)
        err.partial = res
        raise err
    return res
