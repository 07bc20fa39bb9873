"""The implicit coupling's Newton for 1-DOF systems on floats (scheme ``trapezoid``,
docs/design.md §2.3): the network's Newton matrix (:func:`implicit_matrix`), its solve (:func:`implicit_forces`), their
stopping rule (:func:`newton_stop`) and the pair's solve on a jump branch of the switching law
(:func:`implicit_pair`), called by :func:`fmu_sync.core.loop.integrate_network`; and for a user law
nonlinear in u, whose corrected step is not affine in the held force, the pieces of the Newton on the true
step (docs/design.md §2.8.1: :func:`heun_stop`, the pair's pass on floats :func:`heun_pair`, the warm start
:func:`heun_warm`; the node passes are the loop's, :func:`fmu_sync.core.loop._heun_newton`)."""
from __future__ import annotations

import numpy as np

from .coupling import EUCLIDEAN, UNCOUPLED, coupling_kernel1
from .distance import BRANCH_E
from .edges import coupling_step1
from .jit import njit
from .steps import inverse

__all__ = ["NEWTON_TOL", "NEWTON_PASSES", "held_linear", "implicit_matrix", "newton_stop", "implicit_pair", "implicit_forces",
           "heun_stop", "heun_pair", "heun_warm"]

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
    the Newton of :func:`implicit_forces` / :func:`.loop_implicit.implicit_forces_nd` solves
    the step in one pass. ``E`` the number of edges."""
    for e_ in range(E):
        if laws[e_] != UNCOUPLED and laws[e_] != EUCLIDEAN and branches[e_] != BRANCH_E:
            return False
    return True


@njit(cache=True, inline="always")
def newton_stop(it, big, big0, scale):
    """The stopping rule of the implicit coupling's Newton (:func:`implicit_forces`,
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


@njit(cache=True)   # a call, not inlined: one compile for every law's loop (docs/design.md "The test suite")
def implicit_pair(law, br, sg, kp, kd, w0, w1, qf0, uf0, qf1, uf1, g0q, g0u, g1q, g1u, tau0, tau1, A00, A01, A10,
                  A11, warm):
    """:func:`implicit_forces` of the pair (one edge (0, 1), weights ``w0, w1``) on floats: ``qf, uf``
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


# ------------------------------------------------------------------ a law nonlinear in u (loop._heun_newton)
@njit(cache=True, inline="always")
def heun_stop(it, big, big0, prev, rho, scale):
    """:func:`.loop._heun_newton`'s stopping rule at pass ``it`` (``big`` = max|2R|, ``big0`` that of pass 0,
    ``prev`` that of the last pass, ``rho`` the contraction measured, ``scale`` = max|tau| + kp max|q1| +
    kd max|u1|: the coupling's round-off at the end states, as the master's ``force_scale``, so that a
    synchronized pair with tau near 0 still stops): ``(stop, rho)`` with stop as
    :func:`newton_stop` (0 go on, 1 done, 2 take this update and stop). Pass 0 stops on
    ``rho``'s prediction, pass 1 measures rho, and a pass that no longer halves |2R| is the round-off floor."""
    if it == 0:
        stop = 2 if rho > 0.0 and 10.0 * rho * big <= NEWTON_TOL * scale else 0
        if big <= NEWTON_TOL * scale and rho > 0.0:
            stop = 1
        return stop, rho
    if it == 1 and big0 > 0.0:
        rho = max(big / big0, 1e-300)
    if not big < 0.5 * prev:
        return 1, rho
    return newton_stop(it, big, big0, scale), rho


@njit(cache=True, inline="always")
def heun_pair(law, br, sg, kp, kd, w0, w1, q0, v0, q1, v1, tau0, tau1, s0, s1, A00, A01, A10, A11, it, big0, prev,
              rho):
    """One pass of :func:`.loop._heun_newton` for the pair on floats (no arrays handed to a kernel in the loop:
    reference counting every step): ``q0, v0, q1, v1`` the nodes' end states under the held forces
    ``s0, s1``, ``tau0, tau1`` the start forces. Returns ``(s0, s1, stop, big0, big, rho)``, the update
    taken unless stop is 1."""
    if law == EUCLIDEAN or br == BRANCH_E:   # the PD law (both laws' branch E)
        f2 = kp * (q0 - q1) + kd * (v0 - v1)
        f1 = -f2
    else:
        f1, f2, _, _ = coupling_kernel1(law, sg, kp, kd, q0, v0, q1, v1, br)
    r0 = (w0 * f1 if w0 > 0.0 else 0.0) - tau0 - 2.0 * (s0 - tau0)
    r1 = (w1 * f2 if w1 > 0.0 else 0.0) - tau1 - 2.0 * (s1 - tau1)
    big = max(abs(r0), abs(r1))
    if it == 0:
        big0 = big
    scale = max(abs(tau0), abs(tau1)) + kp * max(abs(q0), abs(q1)) + kd * max(abs(v0), abs(v1))
    stop, rho = heun_stop(it, big, big0, prev, rho, scale)
    if stop != 1:
        s0 += A00 * r0 + A01 * r1
        s1 += A10 * r0 + A11 * r1
    return s0, s1, stop, big0, big, rho


@njit(cache=True, inline="always")
def heun_warm(bh, bw, dl, warm, cold):
    """The start of :func:`.loop._heun_newton`'s solve: ``warm = (rho, n)`` of the last step, kept when it held
    the same branches (``bw``, set to ``bh``), rho was measured and fewer than 16 steps ago, and
    ``cold`` is False (the loop starts cold at each row: a run in chunks is the same run); otherwise
    ``(0, 0)`` and the increments ``dl`` zeroed (the solve starts at the start forces)."""
    rho, n = warm
    for e_ in range(bh.shape[0]):
        if bw[e_] != bh[e_]:
            rho = 0.0
        bw[e_] = bh[e_]
    if cold or not rho > 0.0 or n >= 16:
        for i in range(dl.shape[0]):
            dl[i] = 0.0
        return 0.0, 0
    return rho, n


@njit(cache=True)   # a call, not inlined: one compile for every law's loop (docs/design.md "The test suite")
def implicit_forces(laws, E2, W2, sg, kp, kd, qf, uf, co, tau1d, dq, du, hp, t, bh, Ainv, r, delta):
    """``tau1d`` (the forces at the step's start) -> the trapezoid of the coupling forces over the
    step (:func:`implicit_matrix`), n = 1: ``qf, uf`` the nodes' end states under ``tau1d`` held
    (contact left out), ``bh`` each edge's branch at the start (held over the step, as the master's
    implicit exchange holds it, docs/design.md §4.4); ``dq, du, r, delta`` (N,) scratch. Newton on
    ``R(delta) = (tau(x1(delta)) - tau(x0)) / 2 - delta`` with the matrix of :func:`implicit_matrix`:
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
