"""Moreau time-stepping (docs/design.md §2.3): the loops of one system.

The step maps of both schemes (``MIDPOINT``, ``THETA``: :func:`~fmu_sync.core.steps.step_h`
and its float twin ``step1_h``, bitwise equal) are in :mod:`.steps`, the harmonic forcing in
:mod:`.harmonic`; both are re-exported here.

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
from .jit import njit

from .harmonic import PHASOR_SYNC, harmonic_table  # noqa: F401 (re-exported: the loops' forcing)
from .harmonic import harmonic_workspace, hsum1_cos, hsum1_ph, hsum_cos, hsum_ph, ph_rot, ph_sync
from .steps import MIDPOINT, SCHEMES, THETA, TRAPEZOID  # noqa: F401 (re-exported: the scheme codes)
from .steps import (DIVERGED, OK, all_finite, flush, flush1, hbase, scalar_params, step1_y, step_coeffs1,
                    step_workspace, step_y, theta_matrices)


# ------------------------------------------------------------------ the force: the one injected part
@njit(cache=True, inline="always")
def force(sa, p, q, u, tau, hb, hf, tf, a, y, qe):
    """The built-in linear law's force at the step's force point, into ``y`` (:func:`step_h`'s
    arithmetic): ``y = (f0 + B tau + hf) - (K q + (C + a K) u)``, ``hb = f0 + B tau`` and
    ``hf`` the harmonic forcing at ``tf``. ``p, tau, tf, qe`` serve a user law
    (core/law_loops.py :func:`~fmu_sync.core.law_loops.force`), unused here."""
    n = q.shape[0]
    for i in range(n):
        lin = sa.K[i, 0] * q[0] + (sa.C[i, 0] + a * sa.K[i, 0]) * u[0]
        for j in range(1, n):
            lin += sa.K[i, j] * q[j] + (sa.C[i, j] + a * sa.K[i, j]) * u[j]
        y[i] = (hb[i] + hf[i]) - lin


@njit(cache=True, inline="always")
def force1(c, p, q, u, tau, hb, fc, tf, a, qa, ua, ta):
    """:func:`force` for n = 1 on floats (:func:`~fmu_sync.core.steps.step1_h`'s arithmetic,
    ``c`` from :func:`step_coeffs1`); ``p, tau, tf, a, qa, ua, ta`` serve a user law."""
    return (hb + fc) - (c[0] * q + c[1] * u)


#: the loops below are templates: the built-in law compiles them as they stand, a user force law
#: into its own copies whose ``force``, ``force1`` are the law's (:meth:`ForceLaw.kernels`,
#: core/law_loops.py); the name of each and its numba ``inline`` option
TEMPLATES = {"advance_in": "always", "_advance": "never", "advance_with": "never", "integrate_with": "never",
             "integrate1_with": "never"}


# ------------------------------------------------------------------ the loops
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
    return integrate_with(sa, sa.f0, q, u, t0, dt, n_steps, tau, scheme, theta, record_every, T, Qr, Ur, Pr,
                          phasor, dt_last)


@njit(cache=True)
def integrate_with(sa, p, q, u, t0, dt, n_steps, tau, scheme, theta, record_every, T, Qr, Ur, Pr, phasor, dt_last):
    """:func:`integrate` of the law ``force`` with parameters ``p`` (the template)."""
    n = q.shape[0]
    y, hf, uf, Sinv, Sinv_w, WS = step_workspace(sa, dt, scheme, theta)
    if scheme != MIDPOINT:
        X, iw, WX, a = Sinv, Sinv_w, WS, theta * dt
    else:
        X, iw, WX, a = sa.Minv, sa.Minv_w, sa.W, 0.5 * dt
    Omega, phi, F = sa.Omega, sa.phi, sa.F
    cv, sv, cr, sr = harmonic_workspace(Omega, dt)
    qe = np.zeros(n)
    hb = np.empty(n)
    for i in range(n):
        hb[i] = hbase(sa, tau, i)
    use_ph = phasor and Omega.shape[0] > 0
    c0, s0 = 0.0, 0.0
    T[0] = t0
    Qr[0, :] = q
    Ur[0, :] = u
    Pr[0] = 0.0
    row, Psum, k = 1, 0.0, 0
    to_rec, to_sync = record_every, 0
    while k < n_steps:
        if use_ph and to_sync == 0:
            c0, s0 = ph_sync(Omega, phi, (t0 + k * dt) + a, cv, sv)
            to_sync = PHASOR_SYNC
        m = min(to_rec, n_steps - k)
        if use_ph:
            m = min(m, to_sync)
        for i in range(k, k + m):
            tf = (t0 + i * dt) + a
            if use_ph:
                hsum_ph(F, c0, cv, hf)
                c0, s0 = ph_rot(c0, s0, cr, sr, cv, sv)
            else:
                hsum_cos(F, Omega, phi, tf, hf)
            force(sa, p, q, u, tau, hb, hf, tf, a, y, qe)
            P, g = step_y(sa, X, iw, WX, a, q, u, dt, y, uf)
            if g <= 0.0:
                flush(q, u)
            Psum += P
        k += m
        to_rec -= m
        to_sync -= m
        flush(q, u)
        if not all_finite(q, u):
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
        if scheme != MIDPOINT:
            WS = theta_matrices(sa, dt_last, theta, Sinv, Sinv_w)
            X, iw, WX, a = Sinv, Sinv_w, WS, theta * dt_last
        else:
            a = 0.5 * dt_last
        hsum_cos(F, Omega, phi, t + a, hf)
        force(sa, p, q, u, tau, hb, hf, t + a, a, y, qe)
        P, g = step_y(sa, X, iw, WX, a, q, u, dt_last, y, uf)
        Psum += P
        flush(q, u)
        if not all_finite(q, u):
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
    return advance_with(sa, sa.f0, q, u, t0, H, dt, tau, scheme, theta, taudot, phasor)


@njit(cache=True)
def advance_with(sa, p, q, u, t0, H, dt, tau, scheme, theta, taudot=None, phasor=False):
    """:func:`advance` of the law ``force`` with parameters ``p`` (the template; a user law's
    ``kernels().advance``)."""
    if taudot is None:
        return _advance(sa, p, q, u, t0, H, dt, tau, tau, False, scheme, theta, phasor)
    else:
        foh = False
        for j in range(taudot.shape[0]):
            if taudot[j] != 0.0:
                foh = True
        return _advance(sa, p, q, u, t0, H, dt, tau, taudot, foh, scheme, theta, phasor)


@njit(cache=True)
def _advance(sa, p, q, u, t0, H, dt, tau, taudot, foh, scheme, theta, phasor):
    n = q.shape[0]
    nf = sa.Omega.shape[0]
    return advance_in(sa, p, q, u, t0, H, dt, tau, taudot, foh, scheme, theta, phasor,
                      np.empty(n), np.empty(n), np.empty(n), np.empty((n, n)), np.empty(n),
                      np.empty(nf), np.empty(nf), np.empty(nf), np.empty(nf),
                      np.empty(n), np.empty(n), np.empty(tau.shape[0]))


@njit(cache=True, inline="always")
def advance_in(sa, p, q, u, t0, H, dt, tau, taudot, foh, scheme, theta, phasor,
               y, hf, uf, Sinv, Sinv_w, cv, sv, cr, sr, qe, hb, tk):
    """:func:`advance_with` in caller-provided scratch arrays (nothing is allocated: the
    FMU's stepper calls it once per doStep): ``y, hf, uf, Sinv_w, qe, hb`` (n,),
    ``Sinv`` (n, n), ``cv, sv, cr, sr`` (nf,), ``tk`` like ``tau``. Bit for bit
    :func:`advance_with`."""
    n = q.shape[0]
    WS = 0.0
    if scheme != MIDPOINT:
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
        qe[i] = 0.0
        hb[i] = hbase(sa, tau, i)
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
            if scheme != MIDPOINT and hk != dt:
                WS = theta_matrices(sa, hk, theta, Sinv, Sinv_w)
        if scheme != MIDPOINT:
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
                hb[i] = hbase(sa, tk, i)
        force(sa, p, q, u, tk, hb, hf, t + a, a, y, qe)
        P, g = step_y(sa, X, iw, WX, a, q, u, hk, y, uf)
        if g <= 0.0:
            flush(q, u)
        if P > 0.0:
            impacts += 1
            Psum += P
    flush(q, u)
    if not all_finite(q, u):
        return DIVERGED, Psum, impacts
    return OK, Psum, impacts


@njit(cache=True)
def integrate1(sa, q_, u_, t0, dt, n_steps, tau_, scheme, theta, record_every, T, Qr, Ur, Pr,
               phasor=False, dt_last=0.0):
    """:func:`integrate` for n = m = 1 on scalars (bitwise identical results).

    One loop per forcing path with nothing but the step in it: the record, the
    flush of free flight, the finite check and the phasor's re-synchronisation
    happen between blocks of steps; a single harmonic term's phasor and
    coefficients live in registers.
    """
    return integrate1_with(sa, sa.f0, q_, u_, t0, dt, n_steps, tau_, scheme, theta, record_every, T, Qr, Ur, Pr,
                           phasor, dt_last)


@njit(cache=True)
def integrate1_with(sa, p, q_, u_, t0, dt, n_steps, tau_, scheme, theta, record_every, T, Qr, Ur, Pr, phasor,
                    dt_last):
    """:func:`integrate1` of the law ``force1`` with parameters ``p`` (the template)."""
    sp = scalar_params(sa)
    F = sa.F
    Omega = sa.Omega
    phi = sa.phi
    tau = tau_[0]
    q = q_[0]
    u = u_[0]
    qut = np.empty(3)   # a user law's argument arrays (core/law_loops.py): views of one buffer, so
    qa = qut[0:1]       # the compiler sees they do not overlap and keeps q, u in registers
    ua = qut[1:2]
    ta = qut[2:3]
    _, _, _, Sinv, Sinv_w, WS = step_workspace(sa, dt, scheme, theta)
    if scheme != MIDPOINT:
        a = theta * dt
        c = step_coeffs1(sp, Sinv[0, 0], Sinv_w[0], WS, a, dt)
    else:
        a = 0.5 * dt
        c = step_coeffs1(sp, sp[0], sp[8], sp[9], a, dt)
    hb = sp[3] + sp[4] * tau            # f0 + B tau (as hbase)
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
                for i in range(k, k + m):
                    fc = F00 * c0
                    c0, s0 = c0 * cr0 - s0 * sr0, s0 * cr0 + c0 * sr0
                    y = force1(c, p, q, u, tau, hb, fc, (t0 + i * dt) + a, a, qa, ua, ta)
                    q, u, P = step1_y(c, q, u, y, dt)
                    Psum += P
            else:
                for i in range(k, k + m):
                    tf = (t0 + i * dt) + a
                    fc = F00 * math.cos(Om0 * tf + phi0)
                    y = force1(c, p, q, u, tau, hb, fc, tf, a, qa, ua, ta)
                    q, u, P = step1_y(c, q, u, y, dt)
                    Psum += P
        elif use_ph:
            for i in range(k, k + m):
                fc = hsum1_ph(F, c0, cv)
                c0, s0 = ph_rot(c0, s0, cr, sr, cv, sv)
                y = force1(c, p, q, u, tau, hb, fc, (t0 + i * dt) + a, a, qa, ua, ta)
                q, u, P = step1_y(c, q, u, y, dt)
                Psum += P
        elif Omega.shape[0] == 0:   # unforced: fc = -0.0 (x + -0.0 is x exactly: no add on the chain)
            for i in range(k, k + m):
                y = force1(c, p, q, u, tau, hb, -0.0, (t0 + i * dt) + a, a, qa, ua, ta)
                q, u, P = step1_y(c, q, u, y, dt)
                Psum += P
        else:
            for i in range(k, k + m):
                tf = (t0 + i * dt) + a
                y = force1(c, p, q, u, tau, hb, hsum1_cos(F, Omega, phi, tf), tf, a, qa, ua, ta)
                q, u, P = step1_y(c, q, u, y, dt)
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
        if scheme != MIDPOINT:
            _, _, _, Sinv, Sinv_w, WS = step_workspace(sa, dt_last, scheme, theta)
            a = theta * dt_last
            c = step_coeffs1(sp, Sinv[0, 0], Sinv_w[0], WS, a, dt_last)
        else:
            a = 0.5 * dt_last
            c = step_coeffs1(sp, sp[0], sp[8], sp[9], a, dt_last)
        y = force1(c, p, q, u, tau, hb, hsum1_cos(F, Omega, phi, t + a), t + a, a, qa, ua, ta)
        q, u, P = step1_y(c, q, u, y, dt_last)
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
