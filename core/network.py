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

The systems may differ in K, C, f0 and forcing, and in M, w, g0 and e (their impact
geometry) unless a quotient law or the distance record needs one impact map
(docs/design.md §2.5.3). Graph helpers: :func:`ring`,
:func:`path`, :func:`star`, :func:`all_to_all`, or any N x N weight matrix.
"""
from __future__ import annotations

import numpy as np

from .coupling import QUOTIENT_LAWS, law_metric, metric_info
from .checks import divergence_message, land_last_row
from .errors import ForceLawFailed, SimulationDiverged
from .failure import rows_written
from .loop import network_forces, no_decimator, node_force
from .steps import DEFAULT_SCHEME, DIVERGED, OK
from .pair import (LAWS, failure_message, locate_failure, network_loop, network_record, progress_chunks,
                   stack_nodes)
from .plan import coupling_exchange, as_systems, coupled_weights, edges_of, geometry_difference, held_exchange, \
    network_geometry, plan_run, weights
from .result import NetworkResult

__all__ = ["simulate_network", "ring", "path", "star", "all_to_all", "GRAPHS", "graph", "weights",
           "edges_of", "edge_laws", "coupled_weights", "edge_arrays", "network_forces", "node_force",
           "held_exchange", "network_geometry", "record_modes", "geometry_info", "network_record"]


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


def record_modes(record_distance, laws, shared: bool):
    """``(record_d, dist)`` of a network run: ``record_d`` the edges' records are kept, ``dist``
    with the quotient distance (a quotient law always). ``record_distance``: True (the distance:
    refused by the plan without one impact map), False (none; a quotient law still records it),
    None (the default: the distance where the systems share one impact map, else the Euclidean
    error alone)."""
    quotient = bool(np.any(np.isin(laws, QUOTIENT_LAWS)))
    if record_distance is None:
        return True, quotient or shared
    record_d = bool(record_distance) or quotient
    return record_d, record_d


# ------------------------------------------------------------------ Python API
def simulate_network(system, states, A, t_end: float, dt: float, coupling="switching", Kp=0.0,
                     Kd=0.0, Q=None, scheme: str = DEFAULT_SCHEME, theta: float = 0.5,
                     record_every: int = 1, record_distance: bool | None = None, progress=None,
                     t0: float = 0.0, allow_unstable: bool = False) -> NetworkResult:
    """Simulate N systems coupled on the graph ``A`` (monolithic, compiled).

    ``system``: one :class:`MechanicalSystem` for every node or a sequence of N (K, C, f0,
    forcing per node; M, w, g0, e per node too unless a quotient law or ``record_distance=True``
    needs one impact map, docs/design.md §2.5.3); ``states``: N start states
    (q, u); ``A``: N x N weights (``a_ij``: weight of the force on i from edge
    (i, j); zero diagonal), e.g. :func:`ring`; ``coupling``: a law name for every
    edge or one per edge (order of :func:`edges_of`); gains ``Kp``, ``Kd``; norm
    weight ``Q`` (default: the law's own metric, ``energy_metric(K, Kp, A)``, Q = K + lam Kp with
    lam the mean nonzero eigenvalue of the graph's Laplacian; ``info["metric"]`` says which,
    docs/design.md §2.5.1). ``record_distance``: None (default) the quotient distance where the
    systems share one impact map, else the Euclidean error alone (``d``, ``V`` None,
    ``info["error"] = "euclidean"``); True the distance (refused without one impact map); False no
    record of the edges. The same stability checks as :func:`fmu_sync.core.pair.simulate_pair`
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
    record_d, dist = record_modes(record_distance, laws, geometry_difference(systems) is None)
    E = len(edges)
    plan = plan_run(systems, states, t_end, dt, scheme=scheme, theta=theta, A=A, laws=laws, Kp=Kp, Kd=Kd,
                    exchange=coupling_exchange(scheme, systems), distance=dist,
                    record_every=record_every, t0=t0, allow_unstable=allow_unstable,
                    record_values=1 + 3 * N * systems[0].n + ((3 if dist else 1) * E + 1 if record_d else 0),
                    record_what="the record of simulate_network",
                    system_names=[f"node {i + 1}" for i in range(N)])   # every check, once (docs/design.md §5.1.1)
    lm = law_metric(Q, [s.K for s in systems], plan.Kp, coupled_weights(A, edges, laws) if plan.coupled else None,
                    coupled=plan.coupled, stiffness=systems[0].metric_source)
    geo, shared = network_geometry(systems, lm.Q)
    run = _NetworkRun(plan, systems, geo, laws, *edge_arrays(A, edges), record_d, dist, E, t0)
    status = run.chunks(progress_chunks(plan.whole_steps, plan.record_every, progress), progress)
    if status != OK:
        run.locate()
    sl = slice(0, run.row0 if status != OK else plan.rows)
    T, Qr, Ur, TAU, D, BR, EU = run.rec
    V = None
    if dist:
        a_sym = np.array([0.5 * (A[i, j] + A[j, i]) for i, j in edges])
        with np.errstate(over="ignore"):  # a failed run may end on huge (finite) d
            V = 0.5 * (D[sl] ** 2) @ a_sym
    info = dict(mode="core", dt=plan.dt, scheme=scheme, steps=plan.grid.steps, N=N,
                coupling=coupling if isinstance(coupling, str) or coupling is None else list(coupling),
                **metric_info(lm, geo), **geometry_info(shared, record_d and not dist))
    if plan.limit is not None:
        info.update(omega_c_dt=plan.limit.h, exchange_bound=plan.limit.bound, zeta=plan.limit.zeta,
                    dt_max=plan.limit.H_max)
    res = NetworkResult(T[sl], Qr[sl], Ur[sl], TAU[sl], edges, D[sl] if dist else None,
                        BR[sl] if dist else None, EU[sl] if record_d else None, V,
                        impacts=[int(v) for v in run.imp], info=info)
    if status != OK:
        run.fail(res, scheme)
    return res


def geometry_info(shared: bool, euclidean_only: bool) -> dict:
    """The ``info`` entries that say whether the systems share one impact map and, without it,
    that the record carries the Euclidean error instead of d (docs/design.md §2.5.3)."""
    out = dict(common_geometry=bool(shared))
    if euclidean_only:
        out.update(error="euclidean", error_note="no common impact geometry (M, w, g0, e differ): the record "
                   "carries the Euclidean error ||x_i - x_j||_P, P = diag(Q, mean M), not d or V")
    return out


class _NetworkRun:
    """The compiled loop of :func:`simulate_network` over its chunks, and the failing step."""

    def __init__(self, plan, systems, geo, laws, E2, W2, record_d, dist, E, t0):
        self.plan, self.systems, self.geo, self.laws, self.E2, self.W2 = plan, systems, geo, laws, E2, W2
        self.record_d, self.dist, self.E, self.t0 = record_d, dist, E, float(t0)
        N, n = len(systems), systems[0].n
        self.alloc = lambda rows: network_record(rows, N, n, E, dist)
        self.rec = self.alloc(plan.rows)
        self.nodes, self.loop = stack_nodes(*systems), network_loop(systems, plan.code)
        self.q, self.u = plan.q.copy(), plan.u.copy()
        self.imp = np.zeros(N, dtype=np.int64)
        self.row0 = self.k0 = self.chunk_k = self.written = 0
        self.raised = None

    def _call(self, q, u, k, steps, every, bufs, dt_last, i_, ep):
        p = self.plan
        return self.loop(*self.nodes, self.geo, self.laws, self.E2, self.W2, p.Kp, p.Kd, q, u, self.t0, k, p.dt,
                         steps, p.code, p.theta, every, self.record_d, *bufs, dt_last, False, *no_decimator(), i_, ep)

    def chunks(self, chunks, progress) -> int:
        """Run the chunks; returns the status (rows up to ``row0``, steps up to ``k0``)."""
        p, N, status = self.plan, self.q.shape[0], OK
        i_, ep = np.zeros(N, dtype=np.int64), np.zeros(N, dtype=np.int64)   # each chunk's counts
        for c, steps in enumerate(chunks):
            last = c == len(chunks) - 1
            sl = slice(self.row0, p.rows)
            self.chunk_k = self.k0
            try:
                status, done, self.written, _, _ = self._call(self.q, self.u, self.k0, steps, p.record_every,
                                                              [a[sl] for a in self.rec],
                                                              p.dt_last if last else 0.0, i_, ep)
            except Exception as exc:   # raised by the user's law inside the compiled loop (core/failure.py)
                if self.systems[0].force is None:
                    raise
                status, done, self.written, self.raised = DIVERGED, 0, rows_written(self.rec[0][sl]), exc
            if last and status == OK:
                land_last_row(self.rec[0][sl], self.written, p.grid)
            self.imp += i_
            if status != OK:
                self.row0 += self.written
                self.k0 += done
                return status
            self.k0 += steps
            self.row0 += self.written - (0 if last else 1)
            if progress is not None:
                progress(min(self.k0 / max(p.whole_steps, 1), 1.0))
        return status

    def locate(self) -> None:
        """The failing step (core/failure.py): from the last row, every step again with a row each."""
        p, N = self.plan, self.q.shape[0]
        self.fail_msg, self.again = None, None
        self.t_fail = min(self.t0 + self.k0 * p.dt, p.grid.t_end)
        b = self.row0 - 1
        k_b = self.chunk_k + (self.written - 1) * p.record_every
        m = min(p.record_every, p.whole_steps - k_b)
        h_last = p.dt_last if m == p.whole_steps - k_b else 0.0
        Qr, Ur = self.rec[1], self.rec[2]
        bufs, j, self.again = locate_failure(self.loop, self.nodes, self.geo, self.laws, self.E2, self.W2, p.Kp, p.Kd,
                                             Qr[b], Ur[b], self.t0, k_b, p.dt, m, p.code, p.theta, self.record_d,
                                             h_last, self.alloc)
        if self.raised is not None and self.again is None:
            raise self.raised   # not the law's (it did not raise again from the same state): as it came
        if j is not None:
            if j >= 1:   # the last good step as the last row
                for big, small in zip(self.rec, bufs):
                    big[self.row0] = small[j]
                self.row0 += 1
            hk = h_last if (j == m and h_last > 0.0) else p.dt
            self.fail_msg = failure_message(self.systems, [s.p for s in self.systems], bufs, j, self.again, p.code,
                                            p.theta, hk, [f"node {i + 1}" for i in range(N)])
            self.t_fail = min(float(bufs[0][j]) + hk, p.grid.t_end)

    def fail(self, res, scheme) -> None:
        """Raise the run's failure with the partial result ``res``."""
        p, msg = self.plan, self.fail_msg
        if msg is None:
            msg = divergence_message(self.systems[0], scheme, p.dt, self.t_fail, what="a network state or distance",
                                     Kp=p.Kp if p.coupled else None)
            if p.limit is not None:
                msg += f" ({p.limit.message()})"
        err = (ForceLawFailed if self.again is not None else SimulationDiverged)(msg)
        res.error = str(err)
        err.partial = res
        raise err
