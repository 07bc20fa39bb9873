"""The coupling forces of one edge and of a network at a state (docs/design.md §2.3): what the core's
loop (:mod:`.loop`), its n-DOF implicit solve (:mod:`.loop_implicit`), the network API
(:mod:`.network`) and the master's compiled loop share. The Jacobi exchange, a branch held from the
step's start (``fix``/``held``) for the implicit solves."""
from __future__ import annotations

import numpy as np
from .jit import njit

from .compensation import compensated_coupling1, node_force1
from .coupling import (BRANCH_NONE, COMPENSATED, SWITCHING, UNCOUPLED, coupling_kernel, coupling_kernel1,
                       euclidean_coupling1, p_norm_diff)
from .distance import BRANCH_FREE, distance1, distance_value

__all__ = ["coupling_step", "coupling_step1", "network_forces", "node_force"]

# ------------------------------------------------------------------ one edge
@njit(cache=True)
def coupling_step(law, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u, need_d, fix=BRANCH_FREE):
    """Coupling forces into ``tau1, tau2`` and the distance record at this state.

    Returns ``(d, branch, euclidean)``: the quotient distance (NaN and branch
    ``BRANCH_NONE`` unless the law uses it or ``need_d``), its branch code and
    ``||x1 - x2||_P``. ``c1q, c1u, c2q, c2u``: (n,) scratch arrays for the chain
    ends (:func:`fmu_sync.core.coupling.chain_work`). One compiled call,
    used once per step and edge by :func:`integrate_network` and once per
    communication step by the master. ``fix``: the branch the switching law is held on
    (:data:`.distance.BRANCH_FREE`: its own; the implicit exchange's iterates, docs/design.md §4.4).
    """
    if law == SWITCHING:
        d, branch = coupling_kernel(law, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u, fix)
        return d, branch, p_norm_diff(geo.Q, geo.M, q1, u1, q2, u2)
    E, _ = coupling_kernel(law, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u)
    if need_d:
        d, branch = distance_value(geo, q1, u1, q2, u2)
        return d, branch, E
    return np.nan, BRANCH_NONE, E


@njit(cache=True, inline="always")
def coupling_step1(law, sg, kp, kd, q1, u1, q2, u2, need_d, hp, ia, ib, t, fix=BRANCH_FREE):
    """:func:`coupling_step` for 1-DOF on floats (``sg = geo.scalar``, scalar
    gains): ``(tau1, tau2, d, branch, euclidean)``, the same arithmetic as the
    array kernels (which hand n = 1 to the same float kernels). The compensated law
    (docs/design.md §2.5.2) takes the nodes' ``ia``, ``ib`` force laws from the table ``hp``
    (:func:`fmu_sync.core.compensation.force_table`) at time ``t``."""
    if law == COMPENSATED:
        k1, c1, f1 = node_force1(hp, ia, t)
        k2, c2, f2 = node_force1(hp, ib, t)
        tau1, tau2, d, branch, _ = compensated_coupling1(sg, kp, kd, q1, u1, q2, u2, k1, c1, f1, k2, c2, f2, fix)
        return tau1, tau2, d, branch, euclidean_coupling1(sg, kp, kd, q1, u1, q2, u2)[2]
    tau1, tau2, value, branch = coupling_kernel1(law, sg, kp, kd, q1, u1, q2, u2, fix)
    if law == SWITCHING:
        return tau1, tau2, value, branch, euclidean_coupling1(sg, kp, kd, q1, u1, q2, u2)[2]
    if need_d:
        r = distance1(sg, q1, u1, q2, u2)
        return tau1, tau2, r[0], r[1], value
    return tau1, tau2, np.nan, BRANCH_NONE, value


@njit(cache=True, inline="always")
def _edge(law, geo, Kp, Kd, q, u, a, b, t1, t2, c1q, c1u, c2q, c2u, need_d, hp, t, fix=BRANCH_FREE):
    """:func:`coupling_step` of the edge (a, b) (its 1-DOF float form
    :func:`coupling_step1` for n = 1, the same arithmetic): forces into t1, t2; returns
    ``(d, branch, euclidean)``."""
    if q.shape[1] == 1:
        t1[0], t2[0], d, br, eu = coupling_step1(law, geo.scalar, Kp[0, 0], Kd[0, 0], q[a, 0], u[a, 0], q[b, 0],
                                                 u[b, 0], need_d, hp, a, b, t, fix)
        return d, br, eu
    return coupling_step(law, geo, Kp, Kd, q[a], u[a], q[b], u[b], t1, t2, c1q, c1u, c2q, c2u, need_d, fix)


# ------------------------------------------------------------------ all edges
@njit(cache=True, inline="always")
def _forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, need_d, dk, bk, ek, hp, t, held):
    n = q.shape[1]
    for i in range(q.shape[0]):
        for c in range(n):
            tau[i, c] = 0.0
    for e_ in range(E2.shape[0]):
        a = E2[e_, 0]
        b = E2[e_, 1]
        d, br, eu = _edge(laws[e_], geo, Kp, Kd, q, u, a, b, t1, t2, c1q, c1u, c2q, c2u, need_d, hp, t,
                          bk[e_] if held else BRANCH_FREE)
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
def network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, need_d, dk, bk, ek, hp, t,
                   held=False):
    """Every node's input ``tau_i = sum_j a_ij tau_i^(j)`` at the states ``q, u`` (N, n), each
    edge's law evaluated once (:func:`coupling_step`), and each edge's distance record into
    ``dk, bk, ek`` (E,). ``E2`` (E, 2) edges (i, j); ``W2`` (E, 2) weights (a_ij, a_ji);
    ``t1, t2, c1q, c1u, c2q, c2u``: (n,) scratch; ``hp`` the nodes' force table
    (:func:`fmu_sync.core.compensation.force_table`) and ``t`` the time of the states (the
    compensated law evaluates each system's force at its chain end). ``held``: each quotient law is
    evaluated on the branch ``bk`` holds on entry (the implicit exchange's iterates hold the branch
    decided once per communication step, docs/design.md §4.4) instead of its own. The forces of
    :func:`integrate_network` (called there for n > 1) and, per communication step, of the master's
    exchange loop."""
    _forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, need_d, dk, bk, ek, hp, t, held)


@njit(cache=True)
def node_force(i, laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, hp, t):
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
            _edge(laws[e_], geo, Kp, Kd, q, u, a, b, t1, t2, c1q, c1u, c2q, c2u, False, hp, t)
            for c in range(n):
                tau[i, c] += w * (t1[c] if i == a else t2[c])


