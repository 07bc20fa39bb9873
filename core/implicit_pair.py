"""The implicit coupling's Newton for 1-DOF systems on floats (scheme ``trapezoid``,
docs/design.md §2.3): the network's Newton matrix (:func:`implicit_matrix`), its stopping rule (:func:`newton_stop`, also that of
:func:`fmu_sync.core.loop.implicit_forces`) and the pair's solve on a jump branch of the switching law
(:func:`implicit_pair`), called by :func:`fmu_sync.core.loop.integrate_network`."""
from __future__ import annotations

import numpy as np

from .coupling import EUCLIDEAN, UNCOUPLED, coupling_kernel1
from .distance import BRANCH_E
from .jit import njit
from .steps import inverse

__all__ = ["NEWTON_TOL", "NEWTON_PASSES", "held_linear", "implicit_matrix", "newton_stop", "implicit_pair"]

#: the implicit coupling's Newton stops when |2 R| <= NEWTON_TOL max|tau| (at most NEWTON_PASSES passes)
NEWTON_TOL = 1e-13
NEWTON_PASSES = 8


@njit(cache=True)
def implicit_matrix(laws, E2, W2, kp, kd, co, Ainv):
    """The coupling inside the step (scheme ``trapezoid``, n = 1; docs/design.md §2.3): each node i
    steps with the held force ``s_i = tau_i(x0) + delta_i``, the trapezoid of its coupling force
    ``(tau_i(x0) + tau_i(x1)) / 2``. A node's end state is affine in its force (``u1 += G1 delta``,
    ``q1 += G2 delta``, ``G1 = dt X``, ``G2 = a dt X`` of :func:`.steps.step_coeffs1` in ``co``), and
    the PD law of a held branch E is linear: ``tau(x1) = tau(x1 free) + J delta``. Fills
    ``Ainv = (2 I - J)^-1``, so that ``delta = Ainv (tau(x1 free) - tau(x0))`` solves the step
    (exactly for the Euclidean law and branch E; a Newton matrix on a jump branch)."""
    N = Ainv.shape[0]
    A = np.zeros((N, N))
    for i in range(N):
        A[i, i] = 2.0
    for e_ in range(E2.shape[0]):
        if laws[e_] == UNCOUPLED:
            continue
        a = E2[e_, 0]
        b = E2[e_, 1]
        ga = kp * co[a, 3] + kd * co[a, 2]
        gb = kp * co[b, 3] + kd * co[b, 2]
        # tau_a += W(-kp (q_a - q_b) - kd (u_a - u_b)), tau_b the opposite: -J in A
        A[a, a] += W2[e_, 0] * ga
        A[a, b] -= W2[e_, 0] * gb
        A[b, b] += W2[e_, 1] * gb
        A[b, a] -= W2[e_, 1] * ga
    Ainv[:, :] = inverse(A)


@njit(cache=True, inline="always")
def held_linear(laws, branches, E):
    """Whether the coupling of a step is linear in its force increment: every edge uncoupled,
    Euclidean, or held on branch E (``branches``: each edge's branch at the step's start). Then
    the Newton of :func:`.loop.implicit_forces` / :func:`.loop_implicit.implicit_forces_nd` solves
    the step in one pass. ``E`` the number of edges."""
    for e_ in range(E):
        if laws[e_] != UNCOUPLED and laws[e_] != EUCLIDEAN and branches[e_] != BRANCH_E:
            return False
    return True


@njit(cache=True, inline="always")
def newton_stop(it, big, big0, scale):
    """The stopping rule of the implicit coupling's Newton (:func:`.loop.implicit_forces`,
    :func:`implicit_pair`) at pass ``it`` with the residual ``big`` = max|2 R| (``big0`` that of pass 0)
    and ``scale`` = max|tau|: 0 go on (take the step), 1 done (this pass's residual is small), 2 take
    this step and stop: the chord iteration contracts by about ``big / big0`` per pass, so the next
    residual, ``big^2 / big0``, is predicted 10x inside the tolerance (the pass that would only
    confirm it, one more coupling evaluation, is saved: on a switching law's jump branch each costs
    a distance, about 200 ns)."""
    if it == 0:
        return 0
    if big <= NEWTON_TOL * scale:
        return 1
    if 10.0 * big * (big / big0) <= NEWTON_TOL * scale:
        return 2
    return 0


@njit(cache=True)   # a call, not inlined: compiled once for every law's loop (a third of a law's compile)
def implicit_pair(law, br, sg, kp, kd, w0, w1, qf0, uf0, qf1, uf1, g0q, g0u, g1q, g1u, tau0, tau1, A00, A01, A10,
                  A11, warm):
    """:func:`.loop.implicit_forces` of the pair (one edge (0, 1), weights ``w0, w1``) on floats: ``qf, uf``
    the nodes' free end states, ``g*q, g*u`` their gains (``co[i, 3], co[i, 2]``), ``tau0, tau1`` the
    start forces, ``A`` = ``Ainv``, ``br`` the edge's branch held. No arrays (an array handed to a
    kernel in the loop costs reference counting every step).

    ``warm`` = (delta0, delta1, rho, n) of the previous step when it was a jump step on the same
    branch and no row lies between (``rho`` > 0; the loop starts cold at each row): Newton starts
    from its delta (the increments change by O(dt^2) per step) and, when ``rho`` (the chord
    iteration's contraction measured there) predicts the next residual 10x inside the tolerance,
    takes one pass: one distance per jump step instead of two or three
    (each about 200 ns), the solve's result the same to round-off; ``rho`` is measured afresh every
    16 steps. Returns ``(tau0 + delta0, tau1 + delta1, warm)``; with ``rho = 0`` (and on branch E,
    one pass) the arithmetic and its order are :func:`implicit_forces`' (bit for bit)."""
    linear = law == EUCLIDEAN or br == BRANCH_E
    d0, d1, rho, n = warm
    if linear or not rho > 0.0 or n >= 16:
        d0 = 0.0
        d1 = 0.0
        rho = 0.0
        n = 0
    big0 = 0.0
    for it in range(NEWTON_PASSES):
        f1, f2, _, _ = coupling_kernel1(law, sg, kp, kd, qf0 + g0q * d0, uf0 + g0u * d0, qf1 + g1q * d1,
                                        uf1 + g1u * d1, br)
        r0 = 0.0
        r1 = 0.0
        if w0 > 0.0:
            r0 += w0 * f1
        if w1 > 0.0:
            r1 += w1 * f2
        r0 = (r0 - tau0) - 2.0 * d0   # 2 R = tau(x1) - tau(x0) - 2 delta
        r1 = (r1 - tau1) - 2.0 * d1
        big = max(max(0.0, abs(r0)), abs(r1))
        scale = max(max(1e-300, abs(tau0)), abs(tau1))
        if it == 0:
            big0 = big
            stop = 2 if rho > 0.0 and 10.0 * rho * big <= NEWTON_TOL * scale else 0
            if big <= NEWTON_TOL * scale and rho > 0.0:
                stop = 1
        else:
            if it == 1 and big0 > 0.0:
                rho = big / big0
            stop = newton_stop(it, big, big0, scale)
        if stop == 1:
            break
        d0 += (0.0 + A00 * r0) + A01 * r1
        d1 += (0.0 + A10 * r0) + A11 * r1
        if linear or stop == 2:
            break
    if linear:
        rho = 0.0
    return tau0 + d0, tau1 + d1, (d0, d1, rho, n + 1)
