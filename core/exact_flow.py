"""The flow of the 1-DOF exact solver (docs/design.md §2.3): the closed-form free
motion between events, in the gap coordinate, and the model's parameters.

Model (docs/design.md §2.1 with n = 1)::

    m q'' + c q' + k q = f0 + B tau + sum_j F_j cos(Omega_j t + phi_j),
    g = w q + g0 >= 0,   Newton impact  u+ = -e u-  when g = 0 and w u- < 0.

Everything is done in the gap coordinate ``g = w q + g0`` (``v = w u``)::

    g'' + a g' + b g = f(t),   a = c/m,  b = k/m,
    f(t) = s0 + sum_j s_j cos(Omega_j t + phi_j),
    s0 = (w/m)(f0 + B tau) + b g0,   s_j = (w/m) F_j,

so that the wall is ``g = 0`` for every scalar ``w != 0`` and ``g0``. The impact
map Z of docs/design.md §2.2 reduces to ``v+ = -e v-`` with percussion ``P = (1+e)|v-|/W``,
``W = w^2/m``; in persistent contact the multiplier is ``lambda = -f(t)/W >= 0``.

Closed form between events
--------------------------
With local time ``s = t - t_k`` from the start of a free segment::

    g(s) = g_k Phi11(s) + v_k Phi12(s) + s0 R0(s)
           + sum_j s_j [cos psi_j Yc_j(s) - sin psi_j Ys_j(s)],   psi_j = Omega_j t_k + phi_j,

where ``Phi`` is the homogeneous transition matrix, ``R0`` the (zero initial
condition) response to a unit constant force and ``Yc + i Ys`` the response to
``exp(i Omega s)``. Each basis function is evaluated without catastrophic
cancellation in every regime:

* ``Phi`` in the ``exp(-a s/2) [C(s), S(s)]`` form with ``S = sin(mu s)/mu`` or
  ``sinh(nu s)/nu`` (entire in ``mu^2 = b - a^2/4``: no cancellation near critical
  damping; exactly critical, undamped and ``k = 0`` are the same formula) and, for
  strongly overdamped motion (``nu s >= 1/4``), the two-exponential form with the
  roots computed stably (no overflow).
* ``R0`` by its Taylor series when ``s max(|a|, sqrt|b|) <= 1`` and otherwise by
  ``(1 - Phi11)/b`` written with ``expm1`` and ``2 sin^2(x/2)`` (under/critically
  damped), or as a divided difference of ``expm1(r s)/r`` (overdamped, ``k = 0``).
* ``Yc + i Ys`` is the second divided difference ``exp[i Omega, r1, r2](s)`` of
  ``lambda -> exp(lambda s)`` at the forcing frequency and the two characteristic
  roots, built from first divided differences ``exp(p s) s phi1((q-p) s)`` with the
  pair of most separated nodes outside. This single formula is uniformly accurate
  for resonance (the secular ``s sin`` term of undamped resonant forcing is the
  confluent case), near resonance, critical damping and ``k = 0``; for
  ``s max(|a|, sqrt|b|, Omega) <= 1`` the Taylor series is used instead.

The absolute error of ``g`` is a few ulps of the sum of the magnitudes of the
terms above (the grazing tolerance of :mod:`.exact_search` is relative to this sum).

The contact phase is described by the free wall acceleration ``f(t)``
(:func:`force`, :func:`sticks`); the forcing phasors ``(cos, sin)(Omega_j t_k + phi_j)``
of a segment start are :func:`phases`. The event search is :mod:`.exact_search`,
the event loop :mod:`.exact_run`, the public entries :mod:`.exact`.
"""
from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np
from .jit import njit

from .checks import refuse_nonlinear
from .model import MechanicalSystem

__all__ = ["EPS", "NT", "TOLF", "NPRM", "FlowModel", "flow_model", "derivs", "force", "sticks", "phases"]

EPS = 2.220446049250313e-16
NT = 28                      # Taylor terms (|x| <= 1 and roots <= 1.62 s: < 1e-19)
TOLF = 64.0 * EPS            # grazing / sign tolerance, relative to the term magnitude

# indices into the scalar parameter vector
P_A, P_B, P_S0, P_DISC, P_MU, P_R1, P_R2, P_SAB, P_S, P_F0, P_F1, P_F2, P_F4, P_E, P_W, P_OMX = range(16)
NPRM = 16


# --------------------------------------------------------------------------- basis
@njit(cache=True)
def horner(c, x):
    p = c[NT - 1]
    for n in range(NT - 2, -1, -1):
        p = p * x + c[n]
    return p


@njit(cache=True)
def horner_d(c, x):
    p = (NT - 1) * c[NT - 1]
    for n in range(NT - 2, 0, -1):
        p = p * x + n * c[n]
    return p


@njit(cache=True)
def phi(prm, s):
    """Homogeneous transition: (Phi11, Phi12, Phi22), Phi21 = -b Phi12."""
    a = prm[P_A]
    disc = prm[P_DISC]
    if disc < 0.0:
        nu = prm[P_MU]
        y = nu * s
        if y >= 0.25:
            r1 = prm[P_R1]
            r2 = prm[P_R2]
            e1 = math.exp(r1 * s)
            e2 = math.exp(r2 * s)
            d = r1 - r2
            return (r1 * e2 - r2 * e1) / d, (e1 - e2) / d, (r1 * e1 - r2 * e2) / d
        C = math.cosh(y)
        S = math.sinh(y) / nu
    elif disc > 0.0:
        mu = prm[P_MU]
        C = math.cos(mu * s)
        S = math.sin(mu * s) / mu
    else:
        C = 1.0
        S = s
    E = math.exp(-0.5 * a * s)
    return E * (C + 0.5 * a * S), E * S, E * (C - 0.5 * a * S)


@njit(cache=True)
def ef(r, s):
    """expm1(r s)/r (= s for r = 0; series for tiny, possibly subnormal, r s)."""
    x = r * s
    if abs(x) < 1e-4:
        return s * (1.0 + 0.5 * x * (1.0 + x / 3.0 * (1.0 + 0.25 * x)))
    return math.expm1(x) / r


@njit(cache=True)
def r0(prm, rc, s):
    """Zero-initial-condition response to a unit constant force."""
    if s * prm[P_SAB] <= 1.0:
        return horner(rc, s)
    a = prm[P_A]
    b = prm[P_B]
    disc = prm[P_DISC]
    if disc >= 0.0:                       # b > 0 here (b = 0 = a is the series case)
        E = math.exp(-0.5 * a * s)
        if disc > 0.0:
            mu = prm[P_MU]
            sh = math.sin(0.5 * mu * s)
            S = math.sin(mu * s) / mu
            num = -math.expm1(-0.5 * a * s) + E * (2.0 * sh * sh - 0.5 * a * S)
        else:
            num = -math.expm1(-0.5 * a * s) - E * 0.5 * a * s
        return num / b
    nu = prm[P_MU]
    y = nu * s
    if y < 0.25:                          # then b > 0 and |a| s > 1 (see docs)
        E = math.exp(-0.5 * a * s)
        sh = math.sinh(0.5 * y)
        S = math.sinh(y) / nu
        return (-math.expm1(-0.5 * a * s) - E * (2.0 * sh * sh + 0.5 * a * S)) / b
    r1 = prm[P_R1]
    r2 = prm[P_R2]
    return (ef(r2, s) - ef(r1, s)) / (r2 - r1)


@njit(cache=True)
def phi1c(z):
    """(exp(z) - 1)/z for complex z, accurate near 0 (nested Taylor for |z| < 1/2)."""
    if abs(z) < 0.5:
        p = complex(1.0, 0.0)
        for k in range(18, 0, -1):
            p = 1.0 + z * p / (k + 1)
        return p
    return (cmath.exp(z) - 1.0) / z


@njit(cache=True)
def dd1(p, q, s):
    """(exp(p s) - exp(q s))/(p - q), factored on the node with the larger real part."""
    if p.real < q.real:
        p, q = q, p
    return cmath.exp(p * s) * s * phi1c((q - p) * s)


@njit(cache=True)
def harm(prm, roots, Om, cc, cs, s, P12):
    """(Yc, Yc', Ys, Ys'): zero-IC responses to cos(Om s) and sin(Om s)."""
    if s * max(prm[P_SAB], Om) <= 1.0:
        return horner(cc, s), horner_d(cc, s), horner(cs, s), horner_d(cs, s)
    x0 = complex(0.0, Om)
    r1 = roots[0]
    r2 = roots[1]
    d01 = abs(x0 - r1)
    d02 = abs(x0 - r2)
    d12 = abs(r1 - r2)
    if d02 >= d01 and d02 >= d12:
        p, m, q = x0, r1, r2
    elif d01 >= d12:
        p, m, q = x0, r2, r1
    else:
        p, m, q = r1, x0, r2
    y = (dd1(p, m, s) - dd1(m, q, s)) / (p - q)
    yp = x0 * y + P12
    return y.real, yp.real, y.imag, yp.imag


@njit(cache=True)
def derivs(mode, s, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g0, v0):
    """Derivatives (d0..d3) at local time s and the magnitude of the terms.

    mode 0: the gap g of a free segment with initial (g0, v0);
    mode 1: minus the free wall acceleration, -f(t) (the contact-force sign).
    """
    nh = hs.shape[0]
    if mode == 1:
        f = prm[P_S0]
        f1 = 0.0
        f2 = 0.0
        f3 = 0.0
        sc = abs(prm[P_S0])
        for j in range(nh):
            Om = hO[j]
            sj = hs[j]
            co = math.cos(Om * s)
            si = math.sin(Om * s)
            cph = cps[j] * co - sps[j] * si
            sph = sps[j] * co + cps[j] * si
            f += sj * cph
            f1 -= sj * Om * sph
            f2 -= sj * Om * Om * cph
            f3 += sj * Om * Om * Om * sph
            sc += abs(sj)
        return -f, -f1, -f2, -f3, sc
    a = prm[P_A]
    b = prm[P_B]
    s0 = prm[P_S0]
    P11, P12, P22 = phi(prm, s)
    R0 = r0(prm, rc, s)
    d0 = g0 * P11 + v0 * P12 + s0 * R0
    d1 = -b * g0 * P12 + v0 * P22 + s0 * P12
    sc = abs(g0 * P11) + abs(v0 * P12) + abs(s0 * R0)
    f = s0
    f1 = 0.0
    for j in range(nh):
        Om = hO[j]
        Yc, Ycp, Ys, Ysp = harm(prm, roots, Om, hcc[j], hcs[j], s, P12)
        c = cps[j]
        sn = sps[j]
        sj = hs[j]
        d0 += sj * (c * Yc - sn * Ys)
        d1 += sj * (c * Ycp - sn * Ysp)
        sc += abs(sj) * (abs(c * Yc) + abs(sn * Ys))
        co = math.cos(Om * s)
        si = math.sin(Om * s)
        f += sj * (c * co - sn * si)
        f1 -= sj * Om * (sn * co + c * si)
    d2 = f - a * d1 - b * d0
    d3 = f1 - a * d2 - b * d1
    return d0, d1, d2, d3, sc


@njit(cache=True)
def force(prm, hs, hO, hph, t):
    """Free acceleration at the wall f(t) (gap coordinates), f'(t) and f''(t)."""
    f = prm[P_S0]
    f1 = 0.0
    f2 = 0.0
    for j in range(hs.shape[0]):
        x = hO[j] * t + hph[j]
        c = math.cos(x)
        f += hs[j] * c
        f1 -= hs[j] * hO[j] * math.sin(x)
        f2 -= hs[j] * hO[j] * hO[j] * c
    return f, f1, f2


@njit(cache=True)
def sticks(prm, hs, hO, hph, t):
    """At rest on the wall at t: does the contact persist (force into the wall
    now or, if f is zero within round-off, immediately after)?"""
    f, f1, f2 = force(prm, hs, hO, hph, t)
    tol = TOLF * prm[P_F0]
    if f < -tol:
        return True
    if f > tol:
        return False
    tol1 = TOLF * prm[P_F1]
    if f1 < -tol1:
        return True
    if f1 > tol1:
        return False
    return f2 <= 0.0


@njit(cache=True)
def phases(hO, hph, t, cps, sps):
    for j in range(hO.shape[0]):
        x = hO[j] * t + hph[j]
        cps[j] = math.cos(x)
        sps[j] = math.sin(x)



# --------------------------------------------------------------------------- set-up (Python)
@dataclass
class FlowModel:
    """The flow's parameters: ``prm`` (indices ``P_*``), the Taylor series ``rc`` of
    ``R0``, the characteristic ``roots``, the harmonic terms (gap amplitudes ``hs``,
    frequencies ``hO``, phases ``hph``) with the series ``hcc``, ``hcs`` of ``Yc``, ``Ys``;
    the wall normal ``w``, offset ``g0`` and ``W = w^2/m``."""

    prm: np.ndarray
    rc: np.ndarray
    roots: np.ndarray
    hs: np.ndarray
    hO: np.ndarray
    hph: np.ndarray
    hcc: np.ndarray
    hcs: np.ndarray
    w: float
    g0: float
    W: float


def _series(a, b, forcing):
    """Taylor coefficients of the zero-IC response to a forcing with coefficients ``forcing``."""
    c = np.zeros(NT)
    for n in range(NT - 2):
        c[n + 2] = (forcing[n] - a * (n + 1) * c[n + 1] - b * c[n]) / ((n + 1) * (n + 2))
    return c


def _harmonics(sa, w, m, s0):
    """The forcing's harmonics in the gap coordinate: (s0 with the constant ones added, gap
    amplitudes hs, frequencies hO > 0, phases hph); zero amplitudes left out."""
    hs, hO, hph = [], [], []
    for j in range(sa.F.shape[0]):
        Fj, Om, ph = float(sa.F[j, 0]), float(sa.Omega[j]), float(sa.phi[j])
        if Fj == 0.0:
            continue
        if Om == 0.0:
            s0 += w * Fj * math.cos(ph) / m
            continue
        if Om < 0.0:
            Om, ph = -Om, -ph
        hs.append(w * Fj / m)
        hO.append(Om)
        hph.append(ph)
    hs = np.array(hs, dtype=np.float64)
    hO = np.array(hO, dtype=np.float64)
    hph = np.array(hph, dtype=np.float64)
    return s0, hs, hO, hph


def _roots(a, b):
    """The characteristic roots of ``g'' + a g' + b g``: (disc, mu, r1, r2, roots); the real
    roots r1, r2 are 0 unless overdamped, the smaller one then from r1 r2 = b (no cancellation)."""
    r1 = r2 = 0.0
    disc = b - 0.25 * a * a
    if disc > 0.0:
        mu = math.sqrt(disc)
        roots = np.array([complex(-0.5 * a, mu), complex(-0.5 * a, -mu)])
    elif disc == 0.0:
        mu = 0.0
        roots = np.array([complex(-0.5 * a, 0.0), complex(-0.5 * a, 0.0)])
    else:
        mu = math.sqrt(-disc)
        if a >= 0.0:
            r2 = -(0.5 * a + mu)
            r1 = b / r2
        else:
            r1 = -0.5 * a + mu
            r2 = b / r1
        roots = np.array([complex(r1, 0.0), complex(r2, 0.0)])
    return disc, mu, r1, r2, roots


def _flow_series(a, b, hO):
    """The Taylor series ``rc`` of R0 and, per harmonic, ``hcc``, ``hcs`` of Yc, Ys."""
    nh = hO.size
    f = np.zeros(NT)
    f[0] = 1.0
    rc = _series(a, b, f)
    hcc = np.zeros((max(nh, 1), NT))
    hcs = np.zeros((max(nh, 1), NT))
    for j in range(nh):
        Om = hO[j]
        fc = np.zeros(NT)
        fs = np.zeros(NT)
        term = 1.0
        for n in range(NT):
            if n > 0:
                term *= Om / n
            fc[n] = term * (1.0, 0.0, -1.0, 0.0)[n % 4]
            fs[n] = term * (0.0, 1.0, 0.0, -1.0)[n % 4]
        hcc[j] = _series(a, b, fc)
        hcs[j] = _series(a, b, fs)
    if nh == 0:
        hcc = np.zeros((0, NT))
        hcs = np.zeros((0, NT))
    return rc, np.ascontiguousarray(hcc), np.ascontiguousarray(hcs)


def flow_model(system: MechanicalSystem, tau) -> FlowModel:
    """The flow of a 1-DOF system in the gap coordinate with the constant input ``tau``
    (``None``: 0; length ``system.n_inputs``, checked by the caller). ValueError for n != 1."""
    refuse_nonlinear(system)   # a user law: the run plan's refusal
    if not isinstance(system, MechanicalSystem):
        raise ValueError(f"system must be a MechanicalSystem, got {type(system).__name__}")
    if system.n != 1:
        raise ValueError(f"the compiled exact solver supports 1-DOF systems only (n = 1), got n = {system.n}; "
                         "for n > 1 the exact solver runs in Python (exact_events, simulate_exact), "
                         "not as a communication step")
    sa = system.arrays()
    m = float(sa.M[0, 0])
    k = float(sa.K[0, 0])
    c = float(sa.C[0, 0])
    w = float(sa.w[0])
    g0 = float(sa.g0)
    e = float(sa.e)
    tau = np.zeros(system.n_inputs) if tau is None else np.array(tau, dtype=np.float64, ndmin=1).reshape(-1)
    a = c / m
    b = k / m
    ext = float(sa.f0[0] + sa.B[0] @ tau)
    s0 = w * ext / m + b * g0
    s0, hs, hO, hph = _harmonics(sa, w, m, s0)
    nh = hs.size
    disc, mu, r1, r2, roots = _roots(a, b)
    sab = max(abs(a), math.sqrt(abs(b)))
    omx = float(hO.max()) if nh else 0.0
    smax = max(sab, omx)
    ah = np.abs(hs)
    prm = np.zeros(NPRM)
    prm[P_A], prm[P_B], prm[P_S0], prm[P_DISC], prm[P_MU] = a, b, s0, disc, mu
    prm[P_R1], prm[P_R2], prm[P_SAB], prm[P_S] = r1, r2, sab, smax
    prm[P_F0] = abs(s0) + ah.sum()
    prm[P_F1] = float((ah * hO).sum())
    prm[P_F2] = float((ah * hO ** 2).sum())
    prm[P_F4] = float((ah * hO ** 4).sum())
    prm[P_E] = e
    W = w * w / m
    prm[P_W] = W
    prm[P_OMX] = omx
    rc, hcc, hcs = _flow_series(a, b, hO)
    return FlowModel(prm, rc, roots.astype(np.complex128), hs, hO, hph,
                  hcc, hcs, w, g0, W)
