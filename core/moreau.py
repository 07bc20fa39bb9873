"""Moreau time-stepping (docs/design.md §2.3): compiled kernels.

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

The loops over these steps (docs/design.md §2.3, "one loop per scheme"):

* :func:`integrate` — one system, ``n_steps`` fixed steps, recording every
  ``record_every`` (its 1-DOF twin :func:`integrate1` on floats, bit for bit);
* :func:`advance` — one communication step ``H`` made of internal steps ``dt``,
  the last one adjusted to land exactly on ``t + H`` (one call per FMU doStep),
  so that the monolithic simulation and the FMU slave run the very same arithmetic;
* coupled systems (pair, network, sweeps): :func:`fmu_sync.core.loop.integrate_network`.

Harmonic forcing (:mod:`.harmonic`): a cos per step and term (the *cos path*) or
a rotation recurrence re-synchronised exactly every :data:`PHASOR_SYNC` steps (the
*phasor path*, within 1e-13 of the cos path).

Everything is nopython and ``cache=True``; the loops allocate nothing per step.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .harmonic import (PHASOR_SYNC, hsum1_cos, hsum1_ph, hsum_cos, hsum_ph, ph_rot, ph_sync,  # noqa: F401 (the loops)
                       harmonic_table, harmonic_workspace)

MIDPOINT = 0
THETA = 1
SCHEMES = {"midpoint": MIDPOINT, "theta": THETA}

OK = 0
DIVERGED = 1

#: Velocities and positions below this magnitude are set to 0 (see :func:`_flush`).
#: Geometric decay in accumulation phases (u -> -e u per contact step) would
#: otherwise drift into subnormal numbers, which slow arithmetic ~20x; 1e-280 is
#: hundreds of decades below any physical velocity or position.
FLUSH = 1e-280


# ----------------------------------------------------------------------------
# The step
# ----------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _hbase(sa, tau, i):
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
        hc[i] = _hbase(sa, tau, i) + hc[i]


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
    hd = 0.5 * dt
    for i in range(n):
        lin = sa.K[i, 0] * q[0] + (sa.C[i, 0] + a * sa.K[i, 0]) * u[0]
        for j in range(1, n):
            lin += sa.K[i, j] * q[j] + (sa.C[i, j] + a * sa.K[i, j]) * u[j]
        y[i] = hc[i] - lin
    g = sa.g0
    for i in range(n):
        g += sa.w[i] * (q[i] + hd * u[i])
    for i in range(n):
        s = (dt * X[i, 0]) * y[0]
        for j in range(1, n):
            s += (dt * X[i, j]) * y[j]
        uf[i] = u[i] + s
    P = _contact(sa, g, uf, u, WX, iw)
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


@njit(cache=True, inline="always")
def _flush(q, u):
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
def _finite(q, u):
    # a non-finite value never turns finite again (inf - inf = NaN, NaN propagates),
    # so checking once per block is enough and keeps the hot loop free of it
    ok = True
    for i in range(q.shape[0]):
        if not (math.isfinite(q[i]) and math.isfinite(u[i])):
            ok = False
    return ok


@njit(cache=True)
def integrate(sa, q, u, t0, dt, n_steps, tau, scheme, theta, record_every, T, Qr, Ur, Pr,
              phasor=False, dt_last=0.0):
    """Run ``n_steps`` steps of ``scheme`` from ``(q, u)`` at ``t0`` (in place),
    then, if ``dt_last > 0``, one more step of length ``dt_last`` (the shortened
    last step that lands a run on its end, :func:`fmu_sync.core.checks.run_steps`).

    Row 0 of the records is the initial state; row r >= 1 is the state after
    ``r * record_every`` steps with, in ``Pr[r]``, the percussion summed over
    those ``record_every`` steps; the final state is always the last row (also
    when ``record_every`` does not divide the step count: :func:`.checks.record_rows`). ``phasor``: harmonic forcing by the phasor
    recurrence (within 1e-13 of the cos path, see above) instead of a cos per
    step. Returns ``(status, steps_done, rows_written)``; ``status`` is DIVERGED
    if the state became non-finite (checked at the end of each block of steps,
    i.e. at least at every record; rows written so far are valid).
    """
    n = q.shape[0]
    y, hf, uf, Sinv, Sinv_w, WS = step_workspace(sa, dt, scheme, theta)
    if scheme == THETA:
        X, iw, WX, a = Sinv, Sinv_w, WS, theta * dt
    else:
        X, iw, WX, a = sa.Minv, sa.Minv_w, sa.W, 0.5 * dt
    Omega = sa.Omega
    phi = sa.phi
    F = sa.F
    cv, sv, cr, sr = harmonic_workspace(Omega, dt)
    hc = np.zeros(n)
    hb = np.empty(n)
    for i in range(n):
        hb[i] = _hbase(sa, tau, i)
    use_ph = phasor and Omega.shape[0] > 0
    c0 = 0.0
    s0 = 0.0
    T[0] = t0
    Qr[0, :] = q
    Ur[0, :] = u
    Pr[0] = 0.0
    row = 1
    Psum = 0.0
    k = 0
    to_rec = record_every
    to_sync = 0
    while k < n_steps:
        if use_ph and to_sync == 0:
            c0, s0 = ph_sync(Omega, phi, (t0 + k * dt) + a, cv, sv)
            to_sync = PHASOR_SYNC
        m = min(to_rec, n_steps - k)
        if use_ph:
            m = min(m, to_sync)
        for i in range(k, k + m):
            if use_ph:
                hsum_ph(F, c0, cv, hf)
                c0, s0 = ph_rot(c0, s0, cr, sr, cv, sv)
            else:
                hsum_cos(F, Omega, phi, (t0 + i * dt) + a, hf)
            for j in range(n):
                hc[j] = hb[j] + hf[j]
            P, g = step_h(sa, X, iw, WX, a, q, u, hc, dt, y, uf)
            if g <= 0.0:
                _flush(q, u)
            Psum += P
        k += m
        to_rec -= m
        to_sync -= m
        _flush(q, u)
        if not _finite(q, u):
            return DIVERGED, k, row
        if to_rec == 0:
            to_rec = record_every
            T[row] = t0 + k * dt
            for i in range(n):
                Qr[row, i] = q[i]
                Ur[row, i] = u[i]
            Pr[row] = Psum
            Psum = 0.0
            row += 1
    if dt_last > 0.0:
        t = t0 + n_steps * dt
        if scheme == THETA:
            WS = theta_matrices(sa, dt_last, theta, Sinv, Sinv_w)
            X, iw, WX, a = Sinv, Sinv_w, WS, theta * dt_last
        else:
            a = 0.5 * dt_last
        hsum_cos(F, Omega, phi, t + a, hf)
        for j in range(n):
            hc[j] = hb[j] + hf[j]
        P, g = step_h(sa, X, iw, WX, a, q, u, hc, dt_last, y, uf)
        Psum += P
        _flush(q, u)
        if not _finite(q, u):
            return DIVERGED, n_steps, row
    if dt_last > 0.0 or to_rec != record_every:
        T[row] = t0 + n_steps * dt + dt_last if dt_last > 0.0 else t0 + n_steps * dt
        for i in range(n):
            Qr[row, i] = q[i]
            Ur[row, i] = u[i]
        Pr[row] = Psum
        row += 1
    return OK, n_steps + (1 if dt_last > 0.0 else 0), row


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
def advance(sa, q, u, t0, H, dt, tau, scheme, theta, taudot=None, phasor=False):
    """Advance ``(q, u)`` in place from ``t0`` to ``t0 + H`` with internal step ``dt``.

    The internal steps are ``dt`` except the last, which ends exactly at
    ``t0 + H``. The input is ``tau`` held over the step (zero-order hold) or,
    with ``taudot`` given (array like ``tau``), the first-order hold
    ``tau(t) = tau + taudot (t - t0)`` evaluated at each internal step's force
    time (``t + dt/2`` for the midpoint, ``t + θ dt`` for theta), where the
    scheme evaluates every other time-dependent force; ``taudot = 0`` (or None)
    gives bit for bit the zero-order hold. ``phasor``: harmonic forcing by the
    phasor recurrence (re-synchronised at ``t0``; a shortened last step uses
    cos). Returns ``(status, percussion_sum, steps_with_impact)``.
    """
    if taudot is None:
        return _advance(sa, q, u, t0, H, dt, tau, tau, False, scheme, theta, phasor)
    else:
        foh = False
        for j in range(taudot.shape[0]):
            if taudot[j] != 0.0:
                foh = True
        return _advance(sa, q, u, t0, H, dt, tau, taudot, foh, scheme, theta, phasor)


@njit(cache=True)
def _advance(sa, q, u, t0, H, dt, tau, taudot, foh, scheme, theta, phasor):
    n = q.shape[0]
    nf = sa.Omega.shape[0]
    return advance_in(sa, q, u, t0, H, dt, tau, taudot, foh, scheme, theta, phasor,
                      np.empty(n), np.empty(n), np.empty(n), np.empty((n, n)), np.empty(n),
                      np.empty(nf), np.empty(nf), np.empty(nf), np.empty(nf),
                      np.empty(n), np.empty(n), np.empty(tau.shape[0]))


@njit(cache=True, inline="always")
def advance_in(sa, q, u, t0, H, dt, tau, taudot, foh, scheme, theta, phasor,
               y, hf, uf, Sinv, Sinv_w, cv, sv, cr, sr, hc, hb, tk):
    """:func:`advance` in caller-provided scratch arrays (nothing is allocated: the
    FMU's stepper calls it once per doStep): ``y, hf, uf, Sinv_w, hc, hb`` (n,),
    ``Sinv`` (n, n), ``cv, sv, cr, sr`` (nf,), ``tk`` like ``tau``. Bit for bit
    :func:`advance`."""
    n = q.shape[0]
    WS = 0.0
    if scheme == THETA:
        WS = theta_matrices(sa, dt, theta, Sinv, Sinv_w)
    Omega = sa.Omega
    phi = sa.phi
    F = sa.F
    for j in range(Omega.shape[0]):      # harmonic_workspace, in place
        cr[j] = math.cos(Omega[j] * dt)
        sr[j] = math.sin(Omega[j] * dt)
        cv[j] = 0.0
        sv[j] = 0.0
    for i in range(n):
        hc[i] = 0.0
        hb[i] = _hbase(sa, tau, i)
    use_ph = phasor and Omega.shape[0] > 0
    c0 = 0.0
    s0 = 0.0
    for j in range(tau.shape[0]):
        tk[j] = tau[j]
    k_steps = substeps(H, dt)
    Psum = 0.0
    impacts = 0
    to_sync = 0
    for k in range(k_steps):
        t = t0 + k * dt
        hk = dt
        if k == k_steps - 1:
            hk = (t0 + H) - t if k > 0 else H
            if scheme == THETA and hk != dt:
                WS = theta_matrices(sa, hk, theta, Sinv, Sinv_w)
        if scheme == THETA:
            X, iw, WX, a = Sinv, Sinv_w, WS, theta * hk
        else:
            X, iw, WX, a = sa.Minv, sa.Minv_w, sa.W, 0.5 * hk
        if use_ph and hk == dt:
            if to_sync == 0:
                c0, s0 = ph_sync(Omega, phi, t + a, cv, sv)
                to_sync = PHASOR_SYNC
            hsum_ph(F, c0, cv, hf)
            c0, s0 = ph_rot(c0, s0, cr, sr, cv, sv)
            to_sync -= 1
        else:                     # cos path (and a shortened last step of the phasor path)
            hsum_cos(F, Omega, phi, t + a, hf)
        if foh:
            for j in range(tau.shape[0]):
                tk[j] = tau[j] + taudot[j] * ((t + a) - t0)
            for i in range(n):
                hb[i] = _hbase(sa, tk, i)
        for i in range(n):
            hc[i] = hb[i] + hf[i]
        P, g = step_h(sa, X, iw, WX, a, q, u, hc, hk, y, uf)
        if g <= 0.0:
            _flush(q, u)
        if P > 0.0:
            impacts += 1
            Psum += P
    _flush(q, u)
    if not _finite(q, u):
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
    Returns (q, u, P). (The contact correction sits inside the contact branch, so
    that the free-flight path carries no select on its dependency chain.)"""
    K, CK, G1, G2, w, g0, e, iw, aiw, WX, hd = c
    y = hc - (K * q + CK * u)
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


@njit(cache=True)
def integrate1(sa, q_, u_, t0, dt, n_steps, tau_, scheme, theta, record_every, T, Qr, Ur, Pr,
               phasor=False, dt_last=0.0):
    """:func:`integrate` for n = m = 1 on scalars (bitwise identical results).

    One loop per forcing path with nothing but the step in it: the record, the
    flush of free flight, the finite check and the phasor's re-synchronisation
    happen between blocks of steps; a single harmonic term's phasor and
    coefficients live in registers.
    """
    p = scalar_params(sa)
    F = sa.F
    Omega = sa.Omega
    phi = sa.phi
    tau = tau_[0]
    q = q_[0]
    u = u_[0]
    _, _, _, Sinv, Sinv_w, WS = step_workspace(sa, dt, scheme, theta)
    if scheme == THETA:
        a = theta * dt
        c = step_coeffs1(p, Sinv[0, 0], Sinv_w[0], WS, a, dt)
    else:
        a = 0.5 * dt
        c = step_coeffs1(p, p[0], p[8], p[9], a, dt)
    hb = p[3] + p[4] * tau            # f0 + B tau (as _hbase)
    cv, sv, cr, sr = harmonic_workspace(Omega, dt)
    use_ph = phasor and Omega.shape[0] > 0
    one = Omega.shape[0] == 1
    F00 = F[0, 0] if one else 0.0
    Om0 = Omega[0] if one else 0.0
    phi0 = phi[0] if one else 0.0
    cr0 = cr[0] if one else 0.0
    sr0 = sr[0] if one else 0.0
    c0 = 0.0
    s0 = 0.0
    T[0] = t0
    Qr[0, 0] = q
    Ur[0, 0] = u
    Pr[0] = 0.0
    row = 1
    Psum = 0.0
    k = 0
    to_rec = record_every
    to_sync = 0
    while k < n_steps:
        if use_ph and to_sync == 0:
            c0, s0 = ph_sync(Omega, phi, (t0 + k * dt) + a, cv, sv)
            to_sync = PHASOR_SYNC
        m = min(to_rec, n_steps - k)
        if use_ph:
            m = min(m, to_sync)
        if one:   # a single harmonic term: phasor and coefficients in registers
            if use_ph:
                for i in range(m):
                    fc = F00 * c0
                    c0, s0 = c0 * cr0 - s0 * sr0, s0 * cr0 + c0 * sr0
                    q, u, P = step1_h(c, q, u, hb + fc, dt)
                    Psum += P
            else:
                for i in range(k, k + m):
                    fc = F00 * math.cos(Om0 * ((t0 + i * dt) + a) + phi0)
                    q, u, P = step1_h(c, q, u, hb + fc, dt)
                    Psum += P
        elif use_ph:
            for i in range(m):
                fc = hsum1_ph(F, c0, cv)
                c0, s0 = ph_rot(c0, s0, cr, sr, cv, sv)
                q, u, P = step1_h(c, q, u, hb + fc, dt)
                Psum += P
        else:
            for i in range(k, k + m):
                fc = hsum1_cos(F, Omega, phi, (t0 + i * dt) + a)
                q, u, P = step1_h(c, q, u, hb + fc, dt)
                Psum += P
        k += m
        to_rec -= m
        to_sync -= m
        q = flush1(q)
        u = flush1(u)
        if not (math.isfinite(q) and math.isfinite(u)):
            q_[0] = q
            u_[0] = u
            return DIVERGED, k, row
        if to_rec == 0:
            to_rec = record_every
            T[row] = t0 + k * dt
            Qr[row, 0] = q
            Ur[row, 0] = u
            Pr[row] = Psum
            Psum = 0.0
            row += 1
    if dt_last > 0.0:
        t = t0 + n_steps * dt
        if scheme == THETA:
            _, _, _, Sinv, Sinv_w, WS = step_workspace(sa, dt_last, scheme, theta)
            a = theta * dt_last
            c = step_coeffs1(p, Sinv[0, 0], Sinv_w[0], WS, a, dt_last)
        else:
            a = 0.5 * dt_last
            c = step_coeffs1(p, p[0], p[8], p[9], a, dt_last)
        q, u, P = step1_h(c, q, u, hb + hsum1_cos(F, Omega, phi, t + a), dt_last)
        Psum += P
        q = flush1(q)
        u = flush1(u)
        q_[0] = q
        u_[0] = u
        if not (math.isfinite(q) and math.isfinite(u)):
            return DIVERGED, n_steps, row
    if dt_last > 0.0 or to_rec != record_every:
        T[row] = t0 + n_steps * dt + dt_last if dt_last > 0.0 else t0 + n_steps * dt
        Qr[row, 0] = q
        Ur[row, 0] = u
        Pr[row] = Psum
        row += 1
    q_[0] = q
    u_[0] = u
    return OK, n_steps + (1 if dt_last > 0.0 else 0), row


def kernels_for(sa):
    """The integrate kernel for this system: the scalar fast path when n = m = 1."""
    if sa.M.shape[0] == 1 and sa.B.shape[1] == 1:
        return integrate1
    return integrate
