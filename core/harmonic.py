"""Harmonic forcing of the Moreau loops (docs/design.md §2.3): the cos path and the phasor path.

The cos path evaluates cos(Omega_j tf + phi_j) at every step's force time tf.
The phasor path carries (c, s) = (cos, sin)(Omega_j tf + phi_j) from step to
step by the rotation (c, s) <- (c cr - s sr, s cr + c sr), (cr, sr) =
(cos, sin)(Omega_j dt), and re-synchronises it exactly -- to the very cos/sin
values the cos path computes -- every PHASOR_SYNC steps (and at every block
start). One rotation step adds at most ~4 eps of error (two rounded products
and a rounded sum per component, |c|, |s| <= 1, plus the rounding of cr, sr),
so the drift from the exact harmonic stays below 4 PHASOR_SYNC eps = 5.7e-14
< 1e-13 between re-synchronisations; the cos path itself carries the rounding
of its argument, ~eps |Omega t + phi| (2.7e-14 at Omega t = 240).
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

__all__ = ["PHASOR_SYNC", "harmonic_workspace", "harmonic_table"]

#: steps between exact re-synchronisations of the phasor (4 N eps <= 1e-13)
PHASOR_SYNC = 64
assert 4 * PHASOR_SYNC * 2.220446049250313e-16 < 1e-13


@njit(cache=True, inline="always")
def hsum_cos(F, Omega, phi, tf, hf):
    """hf = sum_j F_j cos(Omega_j tf + phi_j) (the cos path), summed in term order."""
    n = hf.shape[0]
    if Omega.shape[0] == 0:
        for i in range(n):
            hf[i] = 0.0
        return
    c = math.cos(Omega[0] * tf + phi[0])
    for i in range(n):
        hf[i] = F[0, i] * c
    for j in range(1, Omega.shape[0]):
        c = math.cos(Omega[j] * tf + phi[j])
        for i in range(n):
            hf[i] += F[j, i] * c


@njit(cache=True, inline="always")
def hsum1_cos(F, Omega, phi, tf):
    """:func:`hsum_cos` for n = 1 (same operation order)."""
    if Omega.shape[0] == 0:
        return 0.0
    fc = F[0, 0] * math.cos(Omega[0] * tf + phi[0])
    for j in range(1, Omega.shape[0]):
        fc += F[j, 0] * math.cos(Omega[j] * tf + phi[j])
    return fc


@njit(cache=True, inline="always")
def ph_sync(Omega, phi, tf, cv, sv):
    """Exact (re-)synchronisation of the phasor at force time tf: returns the first
    term's (cos, sin) (kept in registers by the loops), the others go to cv, sv."""
    for j in range(1, Omega.shape[0]):
        x = Omega[j] * tf + phi[j]
        cv[j] = math.cos(x)
        sv[j] = math.sin(x)
    x = Omega[0] * tf + phi[0]
    return math.cos(x), math.sin(x)


@njit(cache=True, inline="always")
def ph_rot(c0, s0, cr, sr, cv, sv):
    """Advance the phasor by one step; returns the first term's (cos, sin)."""
    for j in range(1, cv.shape[0]):
        c = cv[j]
        s = sv[j]
        cv[j] = c * cr[j] - s * sr[j]
        sv[j] = s * cr[j] + c * sr[j]
    return c0 * cr[0] - s0 * sr[0], s0 * cr[0] + c0 * sr[0]


@njit(cache=True, inline="always")
def hsum_ph(F, c0, cv, hf):
    """hf = sum_j F_j c_j from the phasor (same operation order as :func:`hsum_cos`)."""
    n = hf.shape[0]
    for i in range(n):
        hf[i] = F[0, i] * c0
    for j in range(1, cv.shape[0]):
        c = cv[j]
        for i in range(n):
            hf[i] += F[j, i] * c


@njit(cache=True, inline="always")
def hsum1_ph(F, c0, cv):
    fc = F[0, 0] * c0
    for j in range(1, cv.shape[0]):
        fc += F[j, 0] * cv[j]
    return fc


@njit(cache=True)
def harmonic_workspace(Omega, dt):
    """(cv, sv, cr, sr): phasor state and the one-step rotation for step dt."""
    nf = Omega.shape[0]
    cr = np.empty(nf)
    sr = np.empty(nf)
    for j in range(nf):
        cr[j] = math.cos(Omega[j] * dt)
        sr[j] = math.sin(Omega[j] * dt)
    return np.zeros(nf), np.zeros(nf), cr, sr


@njit(cache=True)
def harmonic_table(Omega, phi, t0, dt, a, n_steps, phasor):
    """cos(Omega_j (t0 + k dt + a) + phi_j) for k < n_steps, rows k, as the loops
    see them (cos path or phasor path): for tests of the phasor's drift."""
    nf = Omega.shape[0]
    out = np.empty((n_steps, nf))
    cv, sv, cr, sr = harmonic_workspace(Omega, dt)
    c0 = 0.0
    s0 = 0.0
    to_sync = 0
    for k in range(n_steps):
        if not phasor:
            for j in range(nf):
                out[k, j] = math.cos(Omega[j] * ((t0 + k * dt) + a) + phi[j])
            continue
        if to_sync == 0:
            c0, s0 = ph_sync(Omega, phi, (t0 + k * dt) + a, cv, sv)
            to_sync = PHASOR_SYNC
        out[k, 0] = c0
        for j in range(1, nf):
            out[k, j] = cv[j]
        c0, s0 = ph_rot(c0, s0, cr, sr, cv, sv)
        to_sync -= 1
    return out


