"""The coupling inside the step for n-DOF systems (scheme ``trapezoid``, n > 1; docs/design.md §2.3).

The n = 1 path lives in :mod:`.loop` and :mod:`.implicit_pair` (``implicit_forces``, ``implicit_matrix``, on floats); this is
the same solve on (N, n) blocks for :func:`fmu_sync.core.loop.integrate_network`'s ``_step_node`` path.
Each node i steps under the held force ``s_i = tau_i(x0) + delta_i``, the trapezoid
``(tau_i(x0) + tau_i(x1)) / 2`` of its coupling force, each edge's law on the branch it has at x0
(held, as the master's implicit exchange holds it). With ``X_i = S_i^-1`` (B = I) the node's end
state is affine in its force: ``u1 = u1free + dt X_i delta_i``, ``q1 = q1free + a dt X_i delta_i``
(``a = dt/2``; the free end state is the node's own step under ``tau(x0)`` with its wall left out, as
for n = 1: contact is applied in the step under the solved force). The PD law of a held branch E is linear, so
``delta = (2 I - J)^-1 (tau(x1free) - tau(x0))`` with J the block Jacobian
``d tau / d delta`` of the PD law: exact for the Euclidean law and branch E (one pass), a Newton
matrix on a jump branch (until |2 R| <= 1e-13 max|tau|, at most 8 passes).

A step computes each node's force once at the solve's start (:func:`fmu_sync.core.loop._free_nodes`:
its forcing, kept for the step under the solved force, and its free end state by :func:`free_state`)
and takes the node's own step, with its wall, once, under the solved force
(:func:`fmu_sync.core.loop._solved_nodes`); on a linear held step (:func:`.implicit_pair.held_linear`)
the forces at the free end state are the PD law written out (:func:`held_pd`, the arithmetic of
:func:`.coupling.coupling_kernel` on branch E) instead of :func:`.edges.network_forces`. The numbers
are those of stepping every node twice (free, then under the solved force), bit for bit.
"""
from __future__ import annotations

import numpy as np

from .coupling import UNCOUPLED
from .jit import njit
from .edges import network_forces
from .implicit_pair import NEWTON_PASSES, NEWTON_TOL, held_linear
from .steps import flush1, inverse

__all__ = ["implicit_workspace", "implicit_matrix_nd", "implicit_forces_nd", "free_state", "held_pd"]


@njit(cache=True)
def implicit_workspace(N, n, E):
    """Scratch of :func:`implicit_forces_nd` (allocated once per loop call): ``(Ainv, qc, uc, q1, u1,
    tau0, tau1, delta, r, bh, dk, ek, hfs, u0)``; ``hfs`` (N, n) the nodes' forcing at the step's
    force point, ``u0`` (N, n) their start velocities (:func:`fmu_sync.core.loop._solved_nodes`)."""
    m = N * n
    e = max(E, 1)
    return (np.zeros((m, m)), np.zeros((N, n)), np.zeros((N, n)), np.zeros((N, n)), np.zeros((N, n)),
            np.zeros((N, n)), np.zeros((N, n)), np.zeros((N, n)), np.zeros(m), np.zeros(e, dtype=np.int64),
            np.zeros(e), np.zeros(e), np.zeros((N, n)), np.zeros((N, n)))


@njit(cache=True, inline="always")
def free_state(X, a, dt, q, u, y, qc, uc, i):
    """Node i's end state under its force ``y`` with its wall left out, into rows i of ``qc, uc``:
    :func:`.steps.step_y`'s arithmetic without contact (``X`` (N, n, n) the nodes' S^-1)."""
    n = y.shape[0]
    for r in range(n):
        s = (dt * X[i, r, 0]) * y[0]
        for j in range(1, n):
            s += (dt * X[i, r, j]) * y[j]
        uc[i, r] = flush1(u[i, r] + s)
        s = (a * (dt * X[i, r, 0])) * y[0]
        for j in range(1, n):
            s += (a * (dt * X[i, r, j])) * y[j]
        qc[i, r] = flush1(q[i, r] + (dt * u[i, r] + s))


@njit(cache=True, inline="always")
def held_pd(laws, Kp, Kd, E2, W2, q, u, tau):
    """The nodes' forces ``tau`` (N, n) at ``q, u`` on a linear held step (every edge uncoupled,
    Euclidean or held on branch E): each edge's PD law ``tau_a = -(Kp (q_a - q_b) + Kd (u_a - u_b))
    = -tau_b`` weighted, the arithmetic of :func:`.edges.network_forces` there (bit for bit) without
    its calls."""
    n = q.shape[1]
    for i in range(q.shape[0]):
        for c in range(n):
            tau[i, c] = 0.0
    for e_ in range(E2.shape[0]):
        if laws[e_] == UNCOUPLED:
            continue
        na = E2[e_, 0]
        nb = E2[e_, 1]
        for c in range(n):
            s = 0.0
            for j in range(n):
                s += Kp[c, j] * (q[na, j] - q[nb, j]) + Kd[c, j] * (u[na, j] - u[nb, j])
            f = 0.0 - 1.0 * s
            if W2[e_, 0] > 0.0:
                tau[na, c] += W2[e_, 0] * f
            if W2[e_, 1] > 0.0:
                tau[nb, c] += W2[e_, 1] * (-f)


@njit(cache=True, inline="always")
def _block(A, G, row, col, wgt, n):
    """A[row, col] += wgt G_col (n x n blocks)."""
    for r in range(n):
        for c in range(n):
            A[row * n + r, col * n + c] += wgt * G[col, r, c]


@njit(cache=True)
def implicit_matrix_nd(laws, E2, W2, Kp, Kd, Sinv, a, dt, Ainv):
    """``Ainv = (2 I - J)^-1`` (N n x N n): J the Jacobian of the nodes' PD coupling forces at the
    step's end with respect to their force increments, ``G_i = dt (a Kp + Kd) X_i``,
    ``d tau_a / d delta_a = -w_ab G_a``, ``d tau_a / d delta_b = w_ab G_b`` per edge (a, b)."""
    N = Sinv.shape[0]
    n = Sinv.shape[1]
    A = np.zeros((N * n, N * n))
    for i in range(N * n):
        A[i, i] = 2.0
    G = np.zeros((N, n, n))
    for i in range(N):
        for r in range(n):
            for c in range(n):
                s = 0.0
                for j in range(n):
                    s += (a * Kp[r, j] + Kd[r, j]) * Sinv[i, j, c]
                G[i, r, c] = dt * s
    for e_ in range(E2.shape[0]):
        if laws[e_] == UNCOUPLED:
            continue
        na = E2[e_, 0]
        nb = E2[e_, 1]
        _block(A, G, na, na, W2[e_, 0], n)
        _block(A, G, na, nb, -W2[e_, 0], n)
        _block(A, G, nb, nb, W2[e_, 1], n)
        _block(A, G, nb, na, -W2[e_, 1], n)
    Ainv[:, :] = inverse(A)


@njit(cache=True, inline="always")
def _add_solve(Ainv, tau1, tau, r):
    """The linear step's solve: ``tau += Ainv (tau1 - tau)``, ``tau1`` the forces at the free end
    state (the first Newton pass's arithmetic, bit for bit up to the sign of a zero); ``r`` scratch."""
    N = tau.shape[0]
    n = tau.shape[1]
    for i in range(N):
        for c in range(n):
            r[i * n + c] = tau1[i, c] - tau[i, c]
    for i in range(N):
        for c in range(n):
            s = 0.0
            for j in range(N * n):
                s += Ainv[i * n + c, j] * r[j]
            tau[i, c] += s


@njit(cache=True, inline="always")
def implicit_forces_nd(laws, geo, Kp, Kd, E2, W2, Sinv, a, dt, tau, bk, hp, t, t1, t2, c1q, c1u, c2q, c2u, ws):
    """``tau`` (N, n), the forces at the step's start -> the trapezoid of the coupling forces over the
    step (module docstring); ``ws`` from :func:`implicit_workspace` with ``Ainv`` filled by
    :func:`implicit_matrix_nd` and the nodes' free end states (their step under ``tau``) in ``qc, uc``;
    ``bk`` each edge's branch at the start (held); ``t`` the end time; ``t1 .. c2u`` (n,) scratch."""
    Ainv, qc, uc, q1, u1, tau0, tau1, delta, r, bh, dk, ek, _, _ = ws
    N = tau.shape[0]
    n = tau.shape[1]
    if held_linear(laws, bk, E2.shape[0]):   # one pass from delta = 0: the forces at the free end state
        held_pd(laws, Kp, Kd, E2, W2, qc, uc, tau1)
        _add_solve(Ainv, tau1, tau, r)
        return
    for i in range(N):
        for c in range(n):
            tau0[i, c] = tau[i, c]
            delta[i, c] = 0.0
    for it in range(NEWTON_PASSES):
        for i in range(N):
            for c in range(n):
                s = 0.0
                for j in range(n):
                    s += Sinv[i, c, j] * delta[i, j]
                u1[i, c] = uc[i, c] + dt * s
                q1[i, c] = qc[i, c] + a * dt * s
        for e_ in range(E2.shape[0]):
            bh[e_] = bk[e_]
        network_forces(laws, geo, Kp, Kd, E2, W2, q1, u1, tau1, t1, t2, c1q, c1u, c2q, c2u, False, dk, bh, ek, hp,
                       t, True)
        big = 0.0
        scale = 1e-300
        for i in range(N):   # 2 R = tau(x1) - tau(x0) - 2 delta
            for c in range(n):
                r[i * n + c] = (tau1[i, c] - tau0[i, c]) - 2.0 * delta[i, c]
                big = max(big, abs(r[i * n + c]))
                scale = max(scale, abs(tau0[i, c]))
        if it > 0 and big <= NEWTON_TOL * scale:
            break
        for i in range(N * n):
            s = 0.0
            for j in range(N * n):
                s += Ainv[i, j] * r[j]
            delta[i // n, i % n] += s
    for i in range(N):
        for c in range(n):
            tau[i, c] = tau0[i, c] + delta[i, c]
