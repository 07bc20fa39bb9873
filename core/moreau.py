"""Moreau time-stepping (docs/design.md §2.3): compiled kernels.

Two schemes share one step interface ``step(sa, q, u, tau, t, dt, work) -> P``
that advances ``(q, u)`` in place over ``[t, t + dt]`` and returns the contact
percussion ``P >= 0`` (N s) applied in that step:

* ``MIDPOINT`` — Moreau's midpoint scheme, explicit in the smooth forces;
* ``THETA`` — Moreau–Jean θ-scheme, the linear part (K, C) implicit with the
  iteration matrix ``S = M + θ dt C + θ² dt² K``, which also takes the place of
  M in the (scalar, explicit) contact problem.

Two loops use them, so that the monolithic simulation and the FMU slave run the
very same arithmetic:

* :func:`integrate` — ``n_steps`` fixed steps, recording every ``record_every``;
* :func:`advance` — one communication step ``H`` made of internal steps ``dt``,
  the last one adjusted to land exactly on ``t + H`` (one call per FMU doStep).

Everything is nopython and ``cache=True``; the loops allocate nothing per step.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

MIDPOINT = 0
THETA = 1
SCHEMES = {"midpoint": MIDPOINT, "theta": THETA}

OK = 0
DIVERGED = 1

#: Velocities and positions below this magnitude are set to 0 after each step.
#: Geometric decay in accumulation phases (u -> -e u per contact step) would
#: otherwise drift into subnormal numbers, which slow arithmetic ~20x; 1e-280 is
#: hundreds of decades below any physical velocity or position.
FLUSH = 1e-280


@njit(cache=True, inline="always")
def _force(sa, q, u, tau, t, h):
    """h = -K q - C u + f0 + sum_j F_j cos(Omega_j t + phi_j) + B tau, written into h."""
    n = q.shape[0]
    for i in range(n):
        s = sa.f0[i]
        for j in range(n):
            s -= sa.K[i, j] * q[j] + sa.C[i, j] * u[j]
        for j in range(tau.shape[0]):
            s += sa.B[i, j] * tau[j]
        h[i] = s
    for j in range(sa.Omega.shape[0]):
        c = math.cos(sa.Omega[j] * t + sa.phi[j])
        for i in range(n):
            h[i] += sa.F[j, i] * c


@njit(cache=True, inline="always")
def _gap(sa, q):
    s = sa.g0
    for i in range(q.shape[0]):
        s += sa.w[i] * q[i]
    return s


@njit(cache=True, inline="always")
def _wdot(sa, v):
    s = 0.0
    for i in range(v.shape[0]):
        s += sa.w[i] * v[i]
    return s


@njit(cache=True, inline="always")
def _contact(sa, g, uf, u, W_, iw):
    """The scalar contact problem of one step, in place on ``uf``; returns P >= 0.

    If the gap g (at the contact-detection point) is closed and Newton's law
    ``w^T u_E + e w^T u_A >= 0`` is violated by the free velocity, apply the
    percussion ``P = -xi / W_`` along ``iw`` (``W_ = w^T M^-1 w``, ``iw = M^-1 w``
    for the midpoint scheme; S in place of M for the theta scheme).
    """
    P = 0.0
    if g <= 0.0:
        xi = _wdot(sa, uf) + sa.e * _wdot(sa, u)
        if xi < 0.0:
            P = -xi / W_
            for i in range(uf.shape[0]):
                uf[i] += iw[i] * P
    return P


@njit(cache=True, inline="always")
def midpoint_step(sa, q, u, tau, t, dt, qM, h, uf):
    """One Moreau midpoint step (docs/design.md §2.3), in place. Returns the percussion P."""
    n = q.shape[0]
    half = 0.5 * dt
    for i in range(n):
        qM[i] = q[i] + half * u[i]
    _force(sa, qM, u, tau, t + half, h)
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += sa.Minv[i, j] * h[j]
        uf[i] = u[i] + dt * s
    P = _contact(sa, _gap(sa, qM), uf, u, sa.W, sa.Minv_w)
    for i in range(n):
        u[i] = uf[i]
        q[i] = qM[i] + half * uf[i]
    return P


@njit(cache=True)
def _inverse(A):
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
    Sinv[:, :] = _inverse(S)
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
    """One Moreau–Jean θ step, in place. Returns the percussion P.

    S (u1 - u0) = dt h(q0 + θ dt u0, u0, tau, t + θ dt) + w P,
    q1 = q0 + dt (θ u1 + (1 - θ) u0),
    contact active if g(q0 + dt/2 u0) <= 0, Newton's law on w^T u1 + e w^T u0.
    """
    n = q.shape[0]
    a = theta * dt
    for i in range(n):
        qM[i] = q[i] + a * u[i]
    _force(sa, qM, u, tau, t + a, h)
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += Sinv[i, j] * h[j]
        uf[i] = u[i] + dt * s
    for i in range(n):
        qM[i] = q[i] + 0.5 * dt * u[i]
    P = _contact(sa, _gap(sa, qM), uf, u, WS, Sinv_w)
    for i in range(n):
        q[i] += dt * (theta * uf[i] + (1.0 - theta) * u[i])
        u[i] = uf[i]
    return P


@njit(cache=True)
def step_workspace(sa, dt, scheme, theta):
    """Scratch arrays of a step ``(qM, h, uf)`` and, for the theta scheme, the
    iteration data ``(S^-1, S^-1 w, W_S)`` for step ``dt`` (unused otherwise)."""
    n = sa.M.shape[0]
    Sinv = np.empty((n, n))
    Sinv_w = np.empty(n)
    WS = 0.0
    if scheme == THETA:
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


@njit(cache=True)
def integrate(sa, q, u, t0, dt, n_steps, tau, scheme, theta, record_every, T, Qr, Ur, Pr):
    """Run ``n_steps`` steps of ``scheme`` from ``(q, u)`` at ``t0`` (in place).

    Row 0 of the records is the initial state; row r >= 1 is the state after
    ``r * record_every`` steps with, in ``Pr[r]``, the percussion summed over
    those ``record_every`` steps. Returns ``(status, steps_done, rows_written)``;
    ``status`` is DIVERGED if the state became non-finite (rows written so far
    are valid).
    """
    n = q.shape[0]
    qM, h, uf, Sinv, Sinv_w, WS = step_workspace(sa, dt, scheme, theta)
    T[0] = t0
    Qr[0, :] = q
    Ur[0, :] = u
    Pr[0] = 0.0
    row = 1
    Psum = 0.0
    countdown = record_every  # (k + 1) % record_every without an integer division per step
    for k in range(n_steps):
        t = t0 + k * dt
        if scheme == THETA:
            P = theta_step(sa, q, u, tau, t, dt, theta, Sinv, Sinv_w, WS, qM, h, uf)
        else:
            P = midpoint_step(sa, q, u, tau, t, dt, qM, h, uf)
        Psum += P
        if not finish_step(q, u):
            return DIVERGED, k + 1, row
        countdown -= 1
        if countdown == 0:
            countdown = record_every
            T[row] = t0 + (k + 1) * dt
            for i in range(n):
                Qr[row, i] = q[i]
                Ur[row, i] = u[i]
            Pr[row] = Psum
            Psum = 0.0
            row += 1
    return OK, n_steps, row


@njit(cache=True)
def substeps(H, dt):
    """Number of internal steps for a communication step H: ceil(H/dt), tolerant
    of round-off (H = 10 dt in floating point gives 10, not 11)."""
    r = H / dt
    k = math.floor(r + 1e-9)
    if r - k > 1e-9:
        k += 1
    return max(k, 1)


@njit(cache=True)
def advance(sa, q, u, t0, H, dt, tau, scheme, theta):
    """Advance ``(q, u)`` in place from ``t0`` to ``t0 + H`` with internal step ``dt``.

    The internal steps are ``dt`` except the last, which ends exactly at
    ``t0 + H``. The input ``tau`` is held over the step. Returns
    ``(status, percussion_sum, steps_with_impact)``.
    """
    qM, h, uf, Sinv, Sinv_w, WS = step_workspace(sa, dt, scheme, theta)
    k_steps = substeps(H, dt)
    Psum = 0.0
    impacts = 0
    for k in range(k_steps):
        t = t0 + k * dt
        if k == k_steps - 1:
            hk = (t0 + H) - t if k > 0 else H
            if scheme == THETA and hk != dt:
                WS = theta_matrices(sa, hk, theta, Sinv, Sinv_w)
        else:
            hk = dt
        if scheme == THETA:
            P = theta_step(sa, q, u, tau, t, hk, theta, Sinv, Sinv_w, WS, qM, h, uf)
        else:
            P = midpoint_step(sa, q, u, tau, t, hk, qM, h, uf)
        if P > 0.0:
            impacts += 1
            Psum += P
        if not finish_step(q, u):
            return DIVERGED, Psum, impacts
    return OK, Psum, impacts


# ----------------------------------------------------------------------------
# 1-DOF fast path.  The general kernels above index small arrays whose size is
# only known at run time; for n = m = 1 that costs ~6x (measured: 9 vs 58
# Msteps/s).  The kernels below are the same schemes on scalars, written with
# the *same operation order* so that they reproduce the general kernels bit
# for bit (tests/test_moreau.py checks this).  Dispatch: :func:`kernels_for`.
# ----------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _force1(f0, K, C, B, F, Omega, phi, q, u, tau, t):
    s = f0
    s -= K * q + C * u
    s += B * tau
    for j in range(Omega.shape[0]):
        s += F[j, 0] * math.cos(Omega[j] * t + phi[j])
    return s


@njit(cache=True, inline="always")
def _flush1(x):
    return 0.0 if abs(x) < FLUSH else x


@njit(cache=True, inline="always")
def scalar_params(sa):
    """The 1-DOF system as a tuple of floats (no arrays: nothing to reference-count
    in a hot loop): (Minv, K, C, f0, B, w, g0, e, Minv_w, W)."""
    return (sa.Minv[0, 0], sa.K[0, 0], sa.C[0, 0], sa.f0[0], sa.B[0, 0], sa.w[0], sa.g0, sa.e,
            sa.Minv_w[0], sa.W)


@njit(cache=True, inline="always")
def _contact1(w, e, g, uf, u, W_, iw):
    """:func:`_contact` on scalars (same operation order). Returns (uf, P)."""
    P = 0.0
    if g <= 0.0:
        xi = 0.0
        xi += w * uf
        xu = 0.0
        xu += w * u
        xi = xi + e * xu
        if xi < 0.0:
            P = -xi / W_
            uf += iw * P
    return uf, P


@njit(cache=True, inline="always")
def midpoint_step1(p, F, Omega, phi, q, u, tau, t, dt):
    """:func:`midpoint_step` on scalars (same operation order). Returns (q, u, P)."""
    Minv, K, C, f0, B, w, g0, e, Minv_w, W = p
    half = 0.5 * dt
    qM = q + half * u
    h = _force1(f0, K, C, B, F, Omega, phi, qM, u, tau, t + half)
    s = 0.0
    s += Minv * h
    uf = u + dt * s
    g = g0
    g += w * qM
    uf, P = _contact1(w, e, g, uf, u, W, Minv_w)
    return _flush1(qM + half * uf), _flush1(uf), P


@njit(cache=True, inline="always")
def theta_step1(p, F, Omega, phi, Si, Si_w, WS, theta, q, u, tau, t, dt):
    """:func:`theta_step` on scalars (same operation order); ``Si = S^-1``,
    ``Si_w = S^-1 w``, ``WS = w^T S^-1 w``. Returns (q, u, P)."""
    Minv, K, C, f0, B, w, g0, e, Minv_w, W = p
    a = theta * dt
    h = _force1(f0, K, C, B, F, Omega, phi, q + a * u, u, tau, t + a)
    s = 0.0
    s += Si * h
    uf = u + dt * s
    g = g0
    g += w * (q + 0.5 * dt * u)
    uf, P = _contact1(w, e, g, uf, u, WS, Si_w)
    q = q + dt * (theta * uf + (1.0 - theta) * u)
    return _flush1(q), _flush1(uf), P


@njit(cache=True)
def integrate1(sa, q_, u_, t0, dt, n_steps, tau_, scheme, theta, record_every, T, Qr, Ur, Pr):
    """:func:`integrate` for n = m = 1 on scalars (bitwise identical results)."""
    p = scalar_params(sa)
    F = sa.F
    Omega = sa.Omega
    phi = sa.phi
    tau = tau_[0]
    q = q_[0]
    u = u_[0]
    _, _, _, Sinv, Sinv_w, WS = step_workspace(sa, dt, scheme, theta)
    Si = Sinv[0, 0]
    Si_w = Sinv_w[0]
    T[0] = t0
    Qr[0, 0] = q
    Ur[0, 0] = u
    Pr[0] = 0.0
    row = 1
    Psum = 0.0
    countdown = record_every  # (k + 1) % record_every without an integer division per step
    for k in range(n_steps):
        t = t0 + k * dt
        if scheme == THETA:
            q, u, P = theta_step1(p, F, Omega, phi, Si, Si_w, WS, theta, q, u, tau, t, dt)
        else:
            q, u, P = midpoint_step1(p, F, Omega, phi, q, u, tau, t, dt)
        Psum += P
        countdown -= 1
        if countdown == 0 or k == n_steps - 1:
            # A non-finite value never turns finite again (inf - inf = NaN, NaN
            # propagates), so checking once per record is enough and keeps the
            # hot loop free of it.
            if not (math.isfinite(q) and math.isfinite(u)):
                q_[0] = q
                u_[0] = u
                return DIVERGED, k + 1, row
        if countdown == 0:
            countdown = record_every
            T[row] = t0 + (k + 1) * dt
            Qr[row, 0] = q
            Ur[row, 0] = u
            Pr[row] = Psum
            Psum = 0.0
            row += 1
    q_[0] = q
    u_[0] = u
    return OK, n_steps, row


def kernels_for(sa):
    """The integrate kernel for this system: the scalar fast path when n = m = 1."""
    if sa.M.shape[0] == 1 and sa.B.shape[1] == 1:
        return integrate1
    return integrate
