"""Moreau time-stepping (docs/design.md §2.3): the step maps of both schemes.

Two schemes share one step interface ``step(sa, q, u, tau, t, dt, work) -> P``
that advances ``(q, u)`` in place over ``[t, t + dt]`` and returns the contact
percussion ``P >= 0`` (N s) applied in that step:

* ``MIDPOINT`` — Moreau's midpoint scheme, explicit in the smooth forces;
* ``THETA`` — Moreau–Jean θ-scheme, the linear part (K, C) implicit with the
  iteration matrix ``S = M + θ dt C + θ² dt² K``, which also takes the place of
  M in the (scalar, explicit) contact problem.

Both are one formula (:func:`step_h`) with ``a = θ dt`` (midpoint: θ = 1/2) and
``X = M^-1`` (midpoint) or ``S^-1`` (theta)::

    y   = hc - (K q0 + (C + a K) u0)          hc = f0 + B tau + sum_j F_j cos(Omega_j tf + phi_j)
    u1  = u0 + (dt X) y + X w P               tf = t + a
    q1  = q0 + (dt u0 + (a dt X) y) + a X w P
    contact if g(q0 + dt/2 u0) <= 0; P = max(0, -(w^T u1free + e w^T u0)) / (w^T X w)

(the midpoint scheme: ``qM = q0 + dt/2 u0``, ``u1 = u0 + dt M^-1 h(qM, u0, tf)``,
``q1 = qM + dt/2 u1``; theta: ``S (u1 - u0) = dt h(q0 + θ dt u0, u0, tf) + w P``,
``q1 = q0 + dt (θ u1 + (1 - θ) u0)``). The operation order keeps everything
that does not depend on the state (hc, the coefficient products) off the
dependency chain from one step's state to the next: 6 dependent operations per
step, which is what bounds a long run's speed once the forcing costs nothing
(and a single rounding at the magnitude of q per step).

The loops over these steps live in :mod:`.moreau` (one system, one communication
step) and :mod:`.loop` (coupled systems).
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .harmonic import hsum_cos


MIDPOINT = 0
THETA = 1
#: Moreau–Jean θ = 1/2 (the trapezoidal rule between impacts: second order) with, in coupled runs,
#: the coupling forces inside the step: their trapezoid (mean of the step's ends, the branch of a
#: switching law held from the start) solved with the step (core/loop.py, docs/design.md §2.3)
TRAPEZOID = 3   # (2 is the FMU's exact scheme, fmus/contract.py SCHEME_EXACT: one numbering everywhere)
SCHEMES = {"midpoint": MIDPOINT, "theta": THETA, "trapezoid": TRAPEZOID}
#: The default scheme of the core (simulate, simulate_pair, simulate_network), the FMU's solver.scheme
#: and the exported steppers: second order between impacts (issue 40); "midpoint" stays, by name, as
#: the first-order option
DEFAULT_SCHEME = "trapezoid"

OK = 0
DIVERGED = 1

#: Velocities and positions below this magnitude are set to 0 (see :func:`flush`).
#: Geometric decay in accumulation phases (u -> -e u per contact step) would
#: otherwise drift into subnormal numbers, which slow arithmetic ~20x; 1e-280 is
#: hundreds of decades below any physical velocity or position.
FLUSH = 1e-280


# ----------------------------------------------------------------------------
# The step
# ----------------------------------------------------------------------------

@njit(cache=True, inline="always")
def hbase(sa, tau, i):
    """f0_i + (B tau)_i: the constant part of the force, row i."""
    s = sa.f0[i]
    for j in range(tau.shape[0]):
        s += sa.B[i, j] * tau[j]
    return s


@njit(cache=True, inline="always")
def _hc_cos(sa, tau, tf, hc):
    """hc = (f0 + B tau) + sum_j F_j cos(Omega_j tf + phi_j) (cos path, term order)."""
    hsum_cos(sa.F, sa.Omega, sa.phi, tf, hc)
    for i in range(hc.shape[0]):
        hc[i] = hbase(sa, tau, i) + hc[i]


@njit(cache=True, inline="always")
def contact(sa, g, uf, u, W_, iw):
    """The scalar contact problem of one step, in place on ``uf``; returns P >= 0.

    If the gap g (at the contact-detection point) is closed and Newton's law
    ``w^T u_E + e w^T u_A >= 0`` is violated by the free velocity, apply the
    percussion ``P = -xi / W_`` along ``iw`` (``W_ = w^T M^-1 w``, ``iw = M^-1 w``
    for the midpoint scheme; S in place of M for the theta scheme).
    """
    P = 0.0
    if g <= 0.0:
        xi = 0.0
        for i in range(uf.shape[0]):
            xi += sa.w[i] * uf[i]
        xu = 0.0
        for i in range(u.shape[0]):
            xu += sa.w[i] * u[i]
        xi = xi + sa.e * xu
        if xi < 0.0:
            P = -xi / W_
            for i in range(uf.shape[0]):
                uf[i] += iw[i] * P
    return P


@njit(cache=True, inline="always")
def step_h(sa, X, iw, WX, a, q, u, hc, dt, y, uf):
    """One step of either scheme (module docstring), in place on (q, u).

    ``X`` = M^-1 (midpoint, ``a = dt/2``) or S^-1 (theta, ``a = θ dt``), ``iw = X w``,
    ``WX = w^T X w``; ``hc`` the state-independent force at ``t + a``; ``y`` and
    ``uf`` scratch. The coefficient products (dt X, a dt X, C + a K, a X w) are
    written inline: the scalar kernels precompute the same products, and numba
    hoists them out of the loops. Returns (P, g): the percussion and the gap at
    the contact-detection point ``q0 + dt/2 u0``.
    """
    n = q.shape[0]
    for i in range(n):
        lin = sa.K[i, 0] * q[0] + (sa.C[i, 0] + a * sa.K[i, 0]) * u[0]
        for j in range(1, n):
            lin += sa.K[i, j] * q[j] + (sa.C[i, j] + a * sa.K[i, j]) * u[j]
        y[i] = hc[i] - lin
    return step_y(sa, X, iw, WX, a, q, u, dt, y, uf)


@njit(cache=True, inline="always")
def step_y(sa, X, iw, WX, a, q, u, dt, y, uf):
    """The rest of a step once the force ``y`` at the force point is known (:func:`step_h`;
    the loops' step after their force, core/moreau.py): contact, then (q, u) in place; returns (P, g)."""
    n = q.shape[0]
    hd = 0.5 * dt
    g = sa.g0
    for i in range(n):
        g += sa.w[i] * (q[i] + hd * u[i])
    for i in range(n):
        s = (dt * X[i, 0]) * y[0]
        for j in range(1, n):
            s += (dt * X[i, j]) * y[j]
        uf[i] = u[i] + s
    P = contact(sa, g, uf, u, WX, iw)
    for i in range(n):
        s = (a * (dt * X[i, 0])) * y[0]
        for j in range(1, n):
            s += (a * (dt * X[i, j])) * y[j]
        qn = q[i] + (dt * u[i] + s)
        if P > 0.0:
            qn = qn + (a * iw[i]) * P
        q[i] = qn
        u[i] = uf[i]
    return P, g


@njit(cache=True, inline="always")
def midpoint_step(sa, q, u, tau, t, dt, qM, h, uf):
    """One Moreau midpoint step (docs/design.md §2.3) at time t with input tau, in place
    (``qM, h, uf``: scratch). Returns the percussion P."""
    a = 0.5 * dt
    _hc_cos(sa, tau, t + a, h)
    return step_h(sa, sa.Minv, sa.Minv_w, sa.W, a, q, u, h, dt, qM, uf)[0]


@njit(cache=True)
def inverse(A):
    """Gauss–Jordan inverse with partial pivoting (small n; no LAPACK needed)."""
    n = A.shape[0]
    a = A.copy()
    inv = np.eye(n)
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(a[r, c]) > abs(a[p, c]):
                p = r
        if p != c:
            for k in range(n):
                a[c, k], a[p, k] = a[p, k], a[c, k]
                inv[c, k], inv[p, k] = inv[p, k], inv[c, k]
        d = a[c, c]
        for k in range(n):
            a[c, k] /= d
            inv[c, k] /= d
        for r in range(n):
            if r != c:
                f = a[r, c]
                if f != 0.0:
                    for k in range(n):
                        a[r, k] -= f * a[c, k]
                        inv[r, k] -= f * inv[c, k]
    return inv


@njit(cache=True)
def theta_matrices(sa, dt, theta, Sinv, Sinv_w):
    """Fill S^-1 and S^-1 w for S = M + θ dt C + θ² dt² K; return W_S = w^T S^-1 w."""
    n = sa.M.shape[0]
    S = np.empty((n, n))
    a = theta * dt
    for i in range(n):
        for j in range(n):
            S[i, j] = sa.M[i, j] + a * sa.C[i, j] + a * a * sa.K[i, j]
    Sinv[:, :] = inverse(S)
    WS = 0.0
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += Sinv[i, j] * sa.w[j]
        Sinv_w[i] = s
        WS += sa.w[i] * s
    return WS


@njit(cache=True, inline="always")
def theta_step(sa, q, u, tau, t, dt, theta, Sinv, Sinv_w, WS, qM, h, uf):
    """One Moreau–Jean θ step at time t with input tau, in place. Returns P.

    S (u1 - u0) = dt h(q0 + θ dt u0, u0, tau, t + θ dt) + w P,
    q1 = q0 + dt (θ u1 + (1 - θ) u0),
    contact active if g(q0 + dt/2 u0) <= 0, Newton's law on w^T u1 + e w^T u0.
    """
    a = theta * dt
    _hc_cos(sa, tau, t + a, h)
    return step_h(sa, Sinv, Sinv_w, WS, a, q, u, h, dt, qM, uf)[0]


@njit(cache=True)
def step_workspace(sa, dt, scheme, theta):
    """Scratch arrays of a step ``(qM, h, uf)`` and, for the theta scheme, the
    iteration data ``(S^-1, S^-1 w, W_S)`` for step ``dt`` (unused otherwise)."""
    n = sa.M.shape[0]
    Sinv = np.empty((n, n))
    Sinv_w = np.empty(n)
    WS = 0.0
    if scheme != MIDPOINT:
        WS = theta_matrices(sa, dt, theta, Sinv, Sinv_w)
    return np.empty(n), np.empty(n), np.empty(n), Sinv, Sinv_w, WS


@njit(cache=True, inline="always")
def finish_step(q, u):
    """Flush would-be subnormals to zero; return False if the state is not finite."""
    ok = True
    for i in range(q.shape[0]):
        if abs(q[i]) < FLUSH:
            q[i] = 0.0
        if abs(u[i]) < FLUSH:
            u[i] = 0.0
        if not (math.isfinite(q[i]) and math.isfinite(u[i])):
            ok = False
    return ok


@njit(cache=True, inline="always")
def flush(q, u):
    """Set |x| < FLUSH to 0 (would-be subnormals).

    The loops flush after every *contact* step (where the geometric decay
    u -> -e u of an accumulation happens, and where the velocity of persistent
    contact lives at round-off level) and at the end of every block of steps
    (record or phasor re-synchronisation, at most PHASOR_SYNC steps with the
    phasor); free flight in between is not flushed. Decay from |x| >= FLUSH to a
    subnormal (< 2.2e-308, 28 decades further) within one block would need a
    contraction by > 0.6 per step, far outside the step sizes that resolve a
    physical system; and a subnormal is only slow, never wrong.
    """
    for i in range(q.shape[0]):
        if abs(q[i]) < FLUSH:
            q[i] = 0.0
        if abs(u[i]) < FLUSH:
            u[i] = 0.0


@njit(cache=True, inline="always")
def all_finite(q, u):
    # a non-finite value never turns finite again (inf - inf = NaN, NaN propagates),
    # so checking once per block is enough and keeps the hot loop free of it
    ok = True
    for i in range(q.shape[0]):
        if not (math.isfinite(q[i]) and math.isfinite(u[i])):
            ok = False
    return ok


# ----------------------------------------------------------------------------
# 1-DOF fast path.  The general kernels above index small arrays whose size is
# only known at run time; for n = m = 1 that costs ~6x (measured: 9 vs 58
# Msteps/s).  The kernels below are the same schemes on scalars, written with
# the *same operation order* so that they reproduce the general kernels bit
# for bit (tests/test_moreau.py checks this); used by :func:`.moreau.integrate1`
# and by the coupled loop (:func:`.loop.integrate_network`).
# ----------------------------------------------------------------------------

@njit(cache=True, inline="always")
def flush1(x):
    return 0.0 if abs(x) < FLUSH else x


@njit(cache=True, inline="always")
def scalar_params(sa):
    """The 1-DOF system as a tuple of floats (no arrays: nothing to reference-count
    in a hot loop): (Minv, K, C, f0, B, w, g0, e, Minv_w, W)."""
    return (sa.Minv[0, 0], sa.K[0, 0], sa.C[0, 0], sa.f0[0], sa.B[0, 0], sa.w[0], sa.g0, sa.e,
            sa.Minv_w[0], sa.W)


@njit(cache=True, inline="always")
def step_coeffs1(p, X, iw, WX, a, dt):
    """The scalar coefficients of :func:`step_h` (the same products):
    (K, C + a K, dt X, a dt X, w, g0, e, X w, a X w, w X w, dt/2)."""
    Minv, K, C, f0, B, w, g0, e, Minv_w, W = p
    G1 = dt * X
    return (K, C + a * K, G1, a * G1, w, g0, e, iw, a * iw, WX, 0.5 * dt)


@njit(cache=True, inline="always")
def step1_h(c, q, u, hc, dt):
    """:func:`step_h` on scalars (same operation order), flushing would-be
    subnormals after a contact step; ``c`` from :func:`step_coeffs1`.
    Returns (q, u, P)."""
    return step1_y(c, q, u, hc - (c[0] * q + c[1] * u), dt)


@njit(cache=True, inline="always")
def step1_y(c, q, u, y, dt):
    """:func:`step_y` on scalars: the rest of :func:`step1_h` once the force ``y`` at the
    force point is known (the one-DOF loops' step after their force, core/moreau.py). (The
    contact correction sits inside the contact branch, so that the free-flight path carries no
    select on its dependency chain.)"""
    K, CK, G1, G2, w, g0, e, iw, aiw, WX, hd = c
    g = g0
    g += w * (q + hd * u)
    uf = u + G1 * y
    qn = q + (dt * u + G2 * y)
    if g <= 0.0:
        P = 0.0
        xi = 0.0
        xi += w * uf
        xu = 0.0
        xu += w * u
        xi = xi + e * xu
        if xi < 0.0:
            P = -xi / WX
            uf += iw * P
            qn = qn + aiw * P
        return flush1(qn), flush1(uf), P
    return qn, uf, 0.0
