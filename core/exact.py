"""Exact event-driven reference solver for the 1-DOF linear impact oscillator (docs/design.md §2.3).

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
terms above (this sum is also what the grazing tolerance below is relative to).

Next event
----------
The next impact is the first down-crossing of ``g`` after the segment start. The
time axis is swept in steps ``H <= 1/(2 s_max)`` (``s_max = max(|a|, sqrt|b|,
Omega_j)``); on each step the derivatives ``g, g', g'', g'''`` at the left end and a
rigorous bound ``J`` of ``|g''''|`` over the step (Gronwall on the ODE) prove one
of: ``g`` increasing, ``g`` bounded away from 0, ``g`` decreasing, ``g`` convex or
``g`` concave on the step — otherwise the step is halved. In the convex case the
minimum of ``g`` is located as a root of ``g'`` and its value decides between an
impact (``g_min < -tol``), a *grazing* contact (``|g_min| <= tol``: recorded, no
impact, the flight continues) and nothing. Roots are refined by safeguarded
Newton (bracket kept, bisection fallback, started from the root of the local
quadratic Taylor model, so that a flight 1e-100 times shorter than the step is
found in a few iterations) to a few ulps. ``tol = 64 eps x`` the
magnitude of the terms of ``g`` (its round-off level), so a grazing orbit is
neither missed nor turned into a spurious impact/Zeno loop.

Zeno completion and persistent contact
--------------------------------------
After an impact with post-impact speed ``v+ > 0``, ``e < 1`` and free acceleration at
the wall ``a_w = f(t_k) - a v+ < 0``, the remaining flights of a constant-acceleration
bounce sequence take ``2 e^i v+/|a_w|`` and sum to ``T_rem = 2 v+ / (|a_w| (1-e))``.
The sequence is completed (``t_inf = t_k + T_rem``, total remaining percussion
``(1+e) v+ / ((1-e) W)``, then persistent contact ``g = v = 0``) as soon as one of

* ``s_max T_rem <= zeno_ttol`` (default 1e-12: remaining time negligible on the
  system's fastest time scale),
* ``v+ <= zeno_vtol V_ref`` (default 1e-10) and ``s_max T_rem <= 1e-6``, with the
  velocity scale ``V_ref`` = max(initial speed, sqrt(2 F0 g(q0)), F0/s_max, every
  impact speed so far), ``F0 = |s0| + sum |s_j|``,
* ``(1-e) T_rem = 2 v+/|a_w| <= 16 eps |t_k|`` (the next flight is below the
  resolution of the time axis).

The acceleration is frozen at its value at ``t_k``; with time-varying forcing the
error of ``t_inf`` is second order in the remaining time, ``O(|a_w'/a_w| T_rem^2)``,
i.e. below ``1e-6 T_rem`` (usually ~1e-10 T_rem) with the criteria above. For
constant forcing (``s_max = 0``) the completion is exact.

For ``e = 1`` there is no geometric accumulation (with damping the speeds of a
chattering sequence decay only like ``1/n``). An impact with ``v+ <= cutoff_vtol
V_ref`` (default 1e-6) under a force into the wall is then taken as plastic
(micro-bounce cut-off: the neglected bounces are slower than ``v+`` and lower than
``v+^2 / (2|a_w|)``). Such chatter still costs ``~1/(kappa cutoff_vtol)`` impacts
(``kappa ~ a/|a_w|``); raise ``cutoff_vtol`` for long runs of damped elastic chatter.
``max_events`` bounds the work of a run (``RuntimeError``, never a hang).

Contact lasts while the contact force ``lambda = -f(t)/W`` is non-negative; the
release time is the first down-crossing of ``-f`` (same root finder; a tangency of
``f`` to zero from below is a grazing release that keeps the contact). At rest on
the wall the state sticks if ``f < 0``, or, when ``f`` is zero within round-off,
if ``f' < 0`` (or ``f' = 0`` and ``f'' <= 0``).

Output
------
:func:`simulate_exact` samples the event-driven solution on the grid
``t0 + i dt`` by evaluating the closed form at the grid times (nothing is
integrated on the grid). ``percussion[i]`` is the wall impulse over
``(t[i-1], t[i]]``: impacts, completed Zeno series and the integral of the
persistent contact force (as in the Moreau schemes, whose contact steps also
report the contact impulse). :func:`exact_events` returns the event list.

Limitations: 1-DOF and the built-in linear force law only (any number of
harmonic terms; ``tau`` constant over the run). Negative damping or stiffness is
supported only as far as ``exp`` does not overflow. Near a grazing the impact
speed is ill-conditioned (``|v-| ~ sqrt(2 g'' depth)``): penetrations shallower than
the round-off tolerance (~1e-14 of the gap's magnitude, i.e. impact speeds below
~1e-7 of the velocity scale) are reported as grazings, not impacts.
"""
from __future__ import annotations

import cmath
import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from .roots import taylor_start
from .model import MechanicalSystem, as_state
from .checks import check_record_size, check_run, record_rows, record_times
from .result import SimulationResult

__all__ = ["simulate_exact", "exact_events", "ExactEvents"]

EPS = 2.220446049250313e-16
NT = 28                      # Taylor terms (|x| <= 1 and roots <= 1.62 s: < 1e-19)
TOLF = 64.0 * EPS            # grazing / sign tolerance, relative to the term magnitude
NONE, ROOT, GRAZE = 0, 1, 2
FREE, CONTACT, ZENO = 0, 1, 2
IMPACT_EV, ZENO_EV = 0, 1

# indices into the scalar parameter vector
_A, _B, _S0, _DISC, _MU, _R1, _R2, _SAB, _S, _F0, _F1, _F2, _F4, _E, _W, _OMX = range(16)
_NPRM = 16


# --------------------------------------------------------------------------- basis
@njit(cache=True)
def _horner(c, x):
    p = c[NT - 1]
    for n in range(NT - 2, -1, -1):
        p = p * x + c[n]
    return p


@njit(cache=True)
def _horner_d(c, x):
    p = (NT - 1) * c[NT - 1]
    for n in range(NT - 2, 0, -1):
        p = p * x + n * c[n]
    return p


@njit(cache=True)
def _phi(prm, s):
    """Homogeneous transition: (Phi11, Phi12, Phi22), Phi21 = -b Phi12."""
    a = prm[_A]
    disc = prm[_DISC]
    if disc < 0.0:
        nu = prm[_MU]
        y = nu * s
        if y >= 0.25:
            r1 = prm[_R1]
            r2 = prm[_R2]
            e1 = math.exp(r1 * s)
            e2 = math.exp(r2 * s)
            d = r1 - r2
            return (r1 * e2 - r2 * e1) / d, (e1 - e2) / d, (r1 * e1 - r2 * e2) / d
        C = math.cosh(y)
        S = math.sinh(y) / nu
    elif disc > 0.0:
        mu = prm[_MU]
        C = math.cos(mu * s)
        S = math.sin(mu * s) / mu
    else:
        C = 1.0
        S = s
    E = math.exp(-0.5 * a * s)
    return E * (C + 0.5 * a * S), E * S, E * (C - 0.5 * a * S)


@njit(cache=True)
def _ef(r, s):
    """expm1(r s)/r (= s for r = 0; series for tiny, possibly subnormal, r s)."""
    x = r * s
    if abs(x) < 1e-4:
        return s * (1.0 + 0.5 * x * (1.0 + x / 3.0 * (1.0 + 0.25 * x)))
    return math.expm1(x) / r


@njit(cache=True)
def _r0(prm, rc, s):
    """Zero-initial-condition response to a unit constant force."""
    if s * prm[_SAB] <= 1.0:
        return _horner(rc, s)
    a = prm[_A]
    b = prm[_B]
    disc = prm[_DISC]
    if disc >= 0.0:                       # b > 0 here (b = 0 = a is the series case)
        E = math.exp(-0.5 * a * s)
        if disc > 0.0:
            mu = prm[_MU]
            sh = math.sin(0.5 * mu * s)
            S = math.sin(mu * s) / mu
            num = -math.expm1(-0.5 * a * s) + E * (2.0 * sh * sh - 0.5 * a * S)
        else:
            num = -math.expm1(-0.5 * a * s) - E * 0.5 * a * s
        return num / b
    nu = prm[_MU]
    y = nu * s
    if y < 0.25:                          # then b > 0 and |a| s > 1 (see docs)
        E = math.exp(-0.5 * a * s)
        sh = math.sinh(0.5 * y)
        S = math.sinh(y) / nu
        return (-math.expm1(-0.5 * a * s) - E * (2.0 * sh * sh + 0.5 * a * S)) / b
    r1 = prm[_R1]
    r2 = prm[_R2]
    return (_ef(r2, s) - _ef(r1, s)) / (r2 - r1)


@njit(cache=True)
def _phi1c(z):
    """(exp(z) - 1)/z for complex z, accurate near 0 (nested Taylor for |z| < 1/2)."""
    if abs(z) < 0.5:
        p = complex(1.0, 0.0)
        for k in range(18, 0, -1):
            p = 1.0 + z * p / (k + 1)
        return p
    return (cmath.exp(z) - 1.0) / z


@njit(cache=True)
def _dd1(p, q, s):
    """(exp(p s) - exp(q s))/(p - q), factored on the node with the larger real part."""
    if p.real < q.real:
        p, q = q, p
    return cmath.exp(p * s) * s * _phi1c((q - p) * s)


@njit(cache=True)
def _harm(prm, roots, Om, cc, cs, s, P12):
    """(Yc, Yc', Ys, Ys'): zero-IC responses to cos(Om s) and sin(Om s)."""
    if s * max(prm[_SAB], Om) <= 1.0:
        return _horner(cc, s), _horner_d(cc, s), _horner(cs, s), _horner_d(cs, s)
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
    y = (_dd1(p, m, s) - _dd1(m, q, s)) / (p - q)
    yp = x0 * y + P12
    return y.real, yp.real, y.imag, yp.imag


@njit(cache=True)
def _ev(mode, s, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g0, v0):
    """Derivatives (d0..d3) at local time s and the magnitude of the terms.

    mode 0: the gap g of a free segment with initial (g0, v0);
    mode 1: minus the free wall acceleration, -f(t) (the contact-force sign).
    """
    nh = hs.shape[0]
    if mode == 1:
        f = prm[_S0]
        f1 = 0.0
        f2 = 0.0
        f3 = 0.0
        sc = abs(prm[_S0])
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
    a = prm[_A]
    b = prm[_B]
    s0 = prm[_S0]
    P11, P12, P22 = _phi(prm, s)
    R0 = _r0(prm, rc, s)
    d0 = g0 * P11 + v0 * P12 + s0 * R0
    d1 = -b * g0 * P12 + v0 * P22 + s0 * P12
    sc = abs(g0 * P11) + abs(v0 * P12) + abs(s0 * R0)
    f = s0
    f1 = 0.0
    for j in range(nh):
        Om = hO[j]
        Yc, Ycp, Ys, Ysp = _harm(prm, roots, Om, hcc[j], hcs[j], s, P12)
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
def _force(prm, hs, hO, hph, t):
    """Free acceleration at the wall f(t) (gap coordinates), f'(t) and f''(t)."""
    f = prm[_S0]
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
def _sticks(prm, hs, hO, hph, t):
    """At rest on the wall at t: does the contact persist (force into the wall
    now or, if f is zero within round-off, immediately after)?"""
    f, f1, f2 = _force(prm, hs, hO, hph, t)
    tol = TOLF * prm[_F0]
    if f < -tol:
        return True
    if f > tol:
        return False
    tol1 = TOLF * prm[_F1]
    if f1 < -tol1:
        return True
    if f1 > tol1:
        return False
    return f2 <= 0.0


@njit(cache=True)
def _phases(hO, hph, t, cps, sps):
    for j in range(hO.shape[0]):
        x = hO[j] * t + hph[j]
        cps[j] = math.cos(x)
        sps[j] = math.sin(x)


@njit(cache=True)
def _j4(mode, prm, d0, d1, h):
    """Bound of the fourth derivative over a step of length h."""
    if mode == 1:
        return prm[_F4]
    s = prm[_S]
    F0 = prm[_F0]
    N = max(s * abs(d0), abs(d1))
    Nmax = (N + F0 * h) * math.exp(2.0 * s * h)
    return 5.0 * s * s * s * Nmax + 2.0 * s * s * F0 + s * prm[_F1] + prm[_F2]


# --------------------------------------------------------------------------- roots
@njit(cache=True)
def _refine(which, lo, hi, flo, fplo, fpplo, mode, prm, rc, roots, hs, hO, hcc, hcs, cps, sps,
            g0, v0):
    """Root of F = d[which] in [lo, hi] (F(lo) = flo and F(hi) of opposite signs).

    Start: first root of the quadratic Taylor model of F at lo (flo, fplo, fpplo),
    which also handles roots many orders of magnitude closer to lo than hi;
    then safeguarded Newton on F' = d[which+1] (bracket kept, bisection fallback)
    down to a few ulps.
    """
    if flo == 0.0:
        return lo
    if which == 0 and flo < 0.0:
        return lo
    slo = flo > 0.0
    x = taylor_start(lo, hi, flo, fplo, fpplo)
    dxold = hi - lo
    for _ in range(2200):
        r = _ev(mode, x, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g0, v0)
        if which == 0:
            F = r[0]
            Fp = r[1]
        else:
            F = r[1]
            Fp = r[2]
        if F == 0.0:
            return x
        if (F > 0.0) == slo:
            lo = x
        else:
            hi = x
        width = hi - lo
        if width <= 4.0 * EPS * max(abs(lo), abs(hi)) or width <= 1e-300:
            return x
        xn = x - F / Fp if Fp != 0.0 else lo - 1.0
        if lo < xn < hi and abs(xn - x) <= 0.5 * dxold:
            step = abs(xn - x)
            dxold = step
            x = xn
            if step <= 2.0 * EPS * abs(x):
                return x
        else:
            dxold = width
            x = lo + 0.5 * width
    return x


@njit(cache=True)
def _search(mode, alpha, depart, taumax, H0, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g0, v0):
    """First down-crossing of d0 in (alpha, taumax]: returns (status, s).

    status ROOT: d0 crosses to < -tol at s (refined root);
    GRAZE: d0 touches 0 (|min| <= tol) at the critical point s, no crossing;
    NONE: no crossing up to taumax.
    ``depart``: the start lies on zero and the function leaves it (clamp
    the round-off of d0, d1, d2 at the start so that it is not taken as a root).

    Each step [alpha, alpha + h] is classified with the derivatives d0..d3 at
    alpha and the bound J >= |d4| on the step: increasing (L1 > 0), positive
    (lower bound lb > 0), decreasing (U1 < 0), convex (d2 >= 0 on the step) or
    concave (d2 <= 0); otherwise it is halved. (Single call sites of the
    refinement keep the compiled code small.)
    """
    if alpha >= taumax:
        return NONE, taumax
    d0, d1, d2, d3, sc = _ev(mode, alpha, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g0, v0)
    if depart and d0 <= TOLF * sc:
        d0 = max(d0, 0.0)
        d1 = max(d1, 0.0)
        if d1 == 0.0:
            d2 = max(d2, 0.0)
    H = min(H0, taumax)
    Hmin = 1e-11 * min(H0, taumax)
    while alpha < taumax:
        h = min(H, taumax - alpha)
        beta = alpha + h
        if beta <= alpha:
            return NONE, taumax
        J = _j4(mode, prm, d0, d1, h)
        h2 = h * h
        h3 = h2 * h
        L1 = d1 + min(0.0, d2) * h + min(0.0, d3) * h2 * 0.5 - J * h3 / 6.0
        lb = (d0 + min(0.0, d1) * h + min(0.0, d2) * h2 * 0.5 + min(0.0, d3) * h3 / 6.0
              - J * h2 * h2 / 24.0)
        U1 = d1 + max(0.0, d2) * h + max(0.0, d3) * h2 * 0.5 + J * h3 / 6.0
        L2 = d2 + d3 * h - J * h2 * 0.5
        U2 = d2 + d3 * h + J * h2 * 0.5
        adv = L1 > 0.0 or lb > 0.0
        decreasing = U1 < 0.0
        convex = d2 >= 0.0 and L2 >= 0.0
        concave = d2 <= 0.0 and U2 <= 0.0
        if not (adv or decreasing or convex or concave or h <= Hmin):
            H = 0.5 * h
            continue
        e0, e1, e2, e3, esc = _ev(mode, beta, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g0, v0)
        if not adv:
            tolb = TOLF * esc
            want_root = False
            want_crit = False
            if decreasing:
                want_root = e0 < -tolb
            elif convex:
                if d1 < 0.0:
                    if e1 <= 0.0:
                        want_root = e0 < -tolb
                    else:
                        want_crit = True          # interior minimum
            elif concave:
                if e0 < -tolb:
                    if d1 <= 0.0:
                        want_root = True
                    elif e1 < 0.0:
                        want_crit = True          # interior maximum, root after it
            elif e0 < -tolb:                      # degenerate step below Hmin
                if d1 <= 0.0:
                    want_root = True
                elif e1 < 0.0:
                    want_crit = True
            lo = alpha
            hi = beta
            flo = d0
            fplo = d1
            fpplo = d2
            if want_crit:
                tc = _refine(1, alpha, beta, d1, d2, d3, mode, prm, rc, roots, hs, hO, hcc, hcs,
                             cps, sps, g0, v0)
                c0, c1, c2, c3, csc = _ev(mode, tc, prm, rc, roots, hs, hO, hcc, hcs, cps, sps,
                                          g0, v0)
                if convex:
                    tolm = TOLF * csc
                    if c0 < -tolm:
                        want_root = True
                        hi = tc
                    elif c0 <= tolm:
                        return GRAZE, tc
                else:
                    want_root = True
                    lo = tc
                    flo = c0
                    fplo = c1
                    fpplo = c2
            if want_root:
                return ROOT, _refine(0, lo, hi, flo, fplo, fpplo, mode, prm, rc, roots, hs, hO,
                                     hcc, hcs, cps, sps, g0, v0)
        d0, d1, d2, d3, sc = e0, e1, e2, e3, esc
        alpha = beta
        H = min(2.0 * h, H0)
    return NONE, taumax


# --------------------------------------------------------------------------- event loop
@njit(cache=True)
def _grow2(x):
    y = np.empty((2 * x.shape[0], x.shape[1]))
    for i in range(x.shape[0]):
        for j in range(x.shape[1]):
            y[i, j] = x[i, j]
    return y


@njit(cache=True)
def _grow1(x):
    y = np.empty(2 * x.shape[0])
    for i in range(x.shape[0]):
        y[i] = x[i]
    return y


@njit(cache=True)
def _vref_start(prm, g, v, vref0):
    """The run's velocity scale at its start: initial speed, free-fall speed from
    the initial gap, forcing amplitude over the fastest time scale (``vref0 > 0``:
    carried over from an earlier part of the run). Impacts raise it (:func:`_run`)."""
    smax = prm[_S]
    vref = max(abs(v), math.sqrt(2.0 * prm[_F0] * max(g, 0.0)))
    if smax > 0.0:
        vref = max(vref, prm[_F0] / smax)
    if vref0 > 0.0:
        vref = vref0
    return vref


@njit(cache=True)
def _run(prm, rc, roots, hs, hO, hph, hcc, hcs, t0, g_init, v_init, t_hor, max_events,
         zeno_ttol, zeno_vtol, cutoff_vtol, vref0=0.0):
    """Event loop. Returns (status, segs, nseg, evs, nev, grz, ngr, vref).

    ``vref0 > 0``: the velocity scale V_ref carried over from an earlier part of
    the run (communication steps); otherwise it is initialised from the state.

    segs rows: (t_start, kind, g, v, aux) with kind FREE (initial g, v), CONTACT,
    ZENO (completed accumulation: v = first post-impact speed, aux = a_w).
    evs rows: (t, kind, v, P, t_ref): IMPACT_EV (v = pre-impact gap velocity),
    ZENO_EV (t = t_inf, v = post-impact speed at the completion, t_ref = its start).
    status: 0 ok, 1 too many events, 2 no progress of time (should not happen).
    """
    nh = hs.shape[0]
    cps = np.empty(nh)
    sps = np.empty(nh)
    segs = np.empty((64, 5))
    evs = np.empty((64, 5))
    grz = np.empty(16)
    nseg = 0
    nev = 0
    ngr = 0
    a = prm[_A]
    e = prm[_E]
    W = prm[_W]
    smax = prm[_S]
    H0g = 0.5 / smax if smax > 0.0 else np.inf
    H0c = 0.5 / prm[_OMX] if prm[_OMX] > 0.0 else np.inf
    t = t0
    g = g_init
    v = v_init
    left = False
    stick = False
    t_last = t0
    stall = 0
    # velocity scale of the run: initial speed, free-fall speed from the initial gap,
    # forcing amplitude over the fastest time scale; raised by every impact speed
    vref = _vref_start(prm, g, v, vref0)
    count = 0
    status = 0
    while t <= t_hor:
        count += 1
        if count > max_events:
            status = 1
            break
        if t > t_last:
            t_last = t
            stall = 0
        else:
            stall += 1
            if stall > 64:
                status = 2
                break
        # ---- impact at t
        if g <= 0.0 and v < 0.0 and not left:
            vm = v
            vref = max(vref, -vm)
            v = -e * vm
            g = 0.0
            P = (1.0 + e) * (-vm) / W
            complete = False
            Trem = 0.0
            aw = 0.0
            if v > 0.0:
                aw = _force(prm, hs, hO, hph, t)[0] - a * v
                if aw < 0.0:
                    small = v <= zeno_vtol * vref
                    if e < 1.0:
                        Trem = 2.0 * v / ((-aw) * (1.0 - e))
                        ez = smax * Trem
                        complete = ((smax > 0.0 and ez <= zeno_ttol)
                                    or (small and ez <= 1e-6)
                                    or Trem * (1.0 - e) <= 16.0 * EPS * abs(t))
                    elif v <= cutoff_vtol * vref:
                        # e = 1: no geometric accumulation; micro-bounce cut-off (plastic)
                        v = 0.0
                        P = (-vm) / W
            if nev == evs.shape[0]:
                evs = _grow2(evs)
            evs[nev, 0] = t
            evs[nev, 1] = IMPACT_EV
            evs[nev, 2] = vm
            evs[nev, 3] = P
            evs[nev, 4] = t
            nev += 1
            if complete:
                if nseg == segs.shape[0]:
                    segs = _grow2(segs)
                segs[nseg, 0] = t
                segs[nseg, 1] = ZENO
                segs[nseg, 2] = 0.0
                segs[nseg, 3] = v
                segs[nseg, 4] = aw
                nseg += 1
                if nev == evs.shape[0]:
                    evs = _grow2(evs)
                evs[nev, 0] = t + Trem
                evs[nev, 1] = ZENO_EV
                evs[nev, 2] = v
                evs[nev, 3] = (1.0 + e) * v / ((1.0 - e) * W)
                evs[nev, 4] = t
                nev += 1
                t = t + Trem
                v = 0.0
            continue
        # ---- classify
        if g > 0.0 or v > 0.0 or left:
            kind = FREE
        else:
            kind = CONTACT if (stick or _sticks(prm, hs, hO, hph, t)) else FREE
            g = 0.0
            v = 0.0
        stick = False
        if nseg == segs.shape[0]:
            segs = _grow2(segs)
        segs[nseg, 0] = t
        segs[nseg, 1] = kind
        segs[nseg, 2] = g
        segs[nseg, 3] = v
        segs[nseg, 4] = 0.0
        nseg += 1
        _phases(hO, hph, t, cps, sps)
        taumax = t_hor - t
        mode = 0 if kind == FREE else 1
        H0 = H0g if kind == FREE else H0c
        depart = (kind == CONTACT) or g <= 0.0
        alpha = 0.0
        while True:
            st, tau = _search(mode, alpha, depart, taumax, H0, prm, rc, roots, hs, hO, hcc, hcs,
                              cps, sps, g, v)
            if st != GRAZE:
                break
            if ngr == grz.shape[0]:
                grz = _grow1(grz)
            grz[ngr] = t + tau
            ngr += 1
            count += 1
            if count > max_events:
                break
            alpha = tau
            depart = True
        if count > max_events:
            status = 1
            break
        left = False
        if st == NONE:
            break
        if kind == FREE:
            vm = _ev(0, tau, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g, v)[1]
            # leaving the wall at rest, the motion turned into it at once: contact
            stick = tau == 0.0 and vm >= 0.0
            t = t + tau
            g = 0.0
            v = min(vm, 0.0)
        else:
            t = t + tau
            g = 0.0
            v = 0.0
            left = True
    return status, segs, nseg, evs, nev, grz, ngr, vref


# --------------------------------------------------------------------------- sampling
@njit(cache=True)
def _zeno_tail(e, v, aw, sig):
    A = -aw
    for _ in range(100000):
        if v <= 0.0:
            break
        dlt = 2.0 * v / A
        if sig < dlt:
            return max(v * sig - 0.5 * A * sig * sig, 0.0), v - A * sig
        sig -= dlt
        v *= e
    return 0.0, 0.0


@njit(cache=True)
def _sample(T, segs, nseg, evs, nev, prm, rc, roots, hs, hO, hph, hcc, hcs, w, g0w,
            Q, U, P, with_p):
    R = T.shape[0]
    nh = hs.shape[0]
    cps = np.empty(nh)
    sps = np.empty(nh)
    e = prm[_E]
    k = 0
    cur = -1
    for r in range(R):
        t = T[r]
        while k + 1 < nseg and segs[k + 1, 0] <= t:
            k += 1
        kind = int(segs[k, 1])
        ts = segs[k, 0]
        if kind == FREE:
            if cur != k:
                _phases(hO, hph, ts, cps, sps)
                cur = k
            d = _ev(0, t - ts, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, segs[k, 2], segs[k, 3])
            g = d[0]
            v = d[1]
        elif kind == CONTACT:
            g = 0.0
            v = 0.0
        else:
            g, v = _zeno_tail(e, segs[k, 3], segs[k, 4], t - ts)
        Q[r] = (g - g0w) / w
        U[r] = v / w
    if not with_p:
        return
    for r in range(R):
        P[r] = 0.0
    r = 1
    for i in range(nev):
        tp = evs[i, 0]
        while r < R and T[r] < tp:
            r += 1
        if r >= R:
            break
        P[r] += evs[i, 3]
    W = prm[_W]
    s0 = prm[_S0]
    for k in range(nseg):
        if int(segs[k, 1]) != CONTACT:
            continue
        cs = segs[k, 0]
        ce = segs[k + 1, 0] if k + 1 < nseg else np.inf
        _phases(hO, hph, cs, cps, sps)
        r = np.searchsorted(T, cs, side="right")
        if r < 1:
            r = 1
        while r < R and T[r - 1] < ce:
            lo = max(cs, T[r - 1]) - cs
            hi = min(ce, T[r]) - cs
            if hi > lo:
                I = s0 * (hi - lo)
                for j in range(nh):
                    Om = hO[j]
                    mid = 0.5 * Om * (lo + hi)
                    cm = cps[j] * math.cos(mid) - sps[j] * math.sin(mid)
                    I += hs[j] * 2.0 * cm * math.sin(0.5 * Om * (hi - lo)) / Om
                P[r] += max(-I / W, 0.0)
            r += 1


# --------------------------------------------------------------------------- python API
@dataclass
class _Model:
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


def _model(system: MechanicalSystem, tau) -> _Model:
    if not isinstance(system, MechanicalSystem):
        raise ValueError(f"system must be a MechanicalSystem, got {type(system).__name__}")
    if system.n != 1:
        raise ValueError(f"the exact solver supports 1-DOF systems only (n = 1), got n = {system.n}; "
                         "use scheme='midpoint' or 'theta' for n > 1")
    sa = system.arrays()
    m = float(sa.M[0, 0])
    k = float(sa.K[0, 0])
    c = float(sa.C[0, 0])
    w = float(sa.w[0])
    g0 = float(sa.g0)
    e = float(sa.e)
    tau = np.zeros(system.m) if tau is None else np.array(tau, dtype=np.float64, ndmin=1).reshape(-1)
    if tau.shape != (system.m,) or not np.all(np.isfinite(tau)):
        raise ValueError(f"tau must be {system.m} finite numbers, got {tau.tolist()}")
    a = c / m
    b = k / m
    ext = float(sa.f0[0] + sa.B[0] @ tau)
    s0 = w * ext / m + b * g0
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
    nh = hs.size
    disc = b - 0.25 * a * a
    r1 = r2 = 0.0
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
    sab = max(abs(a), math.sqrt(abs(b)))
    omx = float(hO.max()) if nh else 0.0
    smax = max(sab, omx)
    ah = np.abs(hs)
    prm = np.zeros(_NPRM)
    prm[_A], prm[_B], prm[_S0], prm[_DISC], prm[_MU] = a, b, s0, disc, mu
    prm[_R1], prm[_R2], prm[_SAB], prm[_S] = r1, r2, sab, smax
    prm[_F0] = abs(s0) + ah.sum()
    prm[_F1] = float((ah * hO).sum())
    prm[_F2] = float((ah * hO ** 2).sum())
    prm[_F4] = float((ah * hO ** 4).sum())
    prm[_E] = e
    W = w * w / m
    prm[_W] = W
    prm[_OMX] = omx
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
    return _Model(prm, rc, roots.astype(np.complex128), hs, hO, hph,
                  np.ascontiguousarray(hcc), np.ascontiguousarray(hcs), w, g0, W)


@dataclass
class ExactEvents:
    """Events of an exact (event-driven) run.

    Velocities are in the model's coordinate ``u`` (``w u < 0`` before an impact);
    percussions in N s (``P = (1+e)|w u^-|/W``). ``zeno_times`` are the completed
    accumulation points ``t_inf`` (each followed by persistent contact),
    ``zeno_start_times`` the impact at which the geometric series was summed and
    ``zeno_percussions`` the summed percussion of the infinitely many remaining
    impacts. ``contact_intervals[i] = (t_start, t_end)`` of persistent contact
    (``t_end = horizon`` if still in contact, see ``contact_open``).
    ``graze_times``: tangential contacts with zero speed (no impact).
    """

    impact_times: np.ndarray
    impact_velocities: np.ndarray
    impact_percussions: np.ndarray
    zeno_start_times: np.ndarray
    zeno_times: np.ndarray
    zeno_percussions: np.ndarray
    contact_intervals: np.ndarray
    contact_open: bool
    graze_times: np.ndarray
    t0: float
    t_end: float
    _model: _Model = field(repr=False)
    _segs: np.ndarray = field(repr=False)
    _evs: np.ndarray = field(repr=False)

    @property
    def n_impacts(self) -> int:
        """Number of individually resolved impacts (completed Zeno tails not counted)."""
        return int(self.impact_times.size)

    def state(self, t):
        """``(q, u)`` (float arrays shaped like ``t``) of the exact solution at times ``t``
        in ``[t0, t_end]``; right-continuous (post-impact velocity at an impact time)."""
        t = np.asarray(t, dtype=np.float64)
        flat = t.reshape(-1)
        if flat.size and (not np.all(np.isfinite(flat)) or flat.min() < self.t0
                          or flat.max() > self.t_end):
            raise ValueError(f"times must lie in [{self.t0}, {self.t_end}]")
        order = np.argsort(flat, kind="stable")
        ts = np.ascontiguousarray(flat[order])
        q = np.empty(ts.size)
        u = np.empty(ts.size)
        md = self._model
        _sample(ts, self._segs, self._segs.shape[0], self._evs, self._evs.shape[0], md.prm, md.rc,
                md.roots, md.hs, md.hO, md.hph, md.hcc, md.hcs, md.w, md.g0, q, u, np.empty(0), False)
        qo = np.empty_like(q)
        uo = np.empty_like(u)
        qo[order] = q
        uo[order] = u
        return qo.reshape(t.shape), uo.reshape(t.shape)


def _run_events(system, x0, t_end, tau, t0, max_events, zeno_ttol, zeno_vtol, cutoff_vtol):
    md = _model(system, tau)
    t0 = float(t0)
    if not math.isfinite(t0):
        raise ValueError(f"t0 must be finite, got {t0}")
    t_end = float(t_end)
    if not (math.isfinite(t_end) and t_end >= t0):
        raise ValueError(f"t_end must be finite and >= t0 = {t0}, got {t_end}")
    q0, u0 = as_state(system, x0)
    g = float(md.w * q0[0] + md.g0)
    if g < 0.0:
        raise ValueError(f"initial state violates the constraint: g(q0) = {g:.6g} < 0 (need g(q0) >= 0)")
    v = float(md.w * u0[0])
    max_events = int(max_events)
    status, segs, nseg, evs, nev, grz, ngr, _ = _run(
        md.prm, md.rc, md.roots, md.hs, md.hO, md.hph, md.hcc, md.hcs, t0, g, v, t_end,
        max_events, float(zeno_ttol), float(zeno_vtol), float(cutoff_vtol))
    if status == 2:
        raise RuntimeError(
            f"exact solver: no progress of time near t = {segs[nseg - 1, 0] if nseg else t0:.17g} "
            "(undecidable contact/release at round-off level); please report this case")
    if status != 0:
        raise RuntimeError(
            f"exact solver: more than max_events = {max_events} events before t = {t_end} "
            f"(stopped near t = {segs[nseg - 1, 0] if nseg else t0:.9g}); the run may be chattering "
            "without a completable accumulation (e = 1?) — raise max_events or use a Moreau scheme")
    segs = np.ascontiguousarray(segs[:nseg])
    evs = np.ascontiguousarray(evs[:nev])
    imp = evs[:, 1] == IMPACT_EV
    zen = evs[:, 1] == ZENO_EV
    kinds = segs[:, 1].astype(int)
    ci = np.nonzero(kinds == CONTACT)[0]
    ends = np.array([segs[i + 1, 0] if i + 1 < nseg else t_end for i in ci])
    intervals = np.column_stack([segs[ci, 0], ends]) if ci.size else np.zeros((0, 2))
    open_ = bool(ci.size and ci[-1] == nseg - 1)
    ev = ExactEvents(
        impact_times=evs[imp, 0].copy(),
        impact_velocities=evs[imp, 2] / md.w,
        impact_percussions=evs[imp, 3].copy(),
        zeno_start_times=evs[zen, 4].copy(),
        zeno_times=evs[zen, 0].copy(),
        zeno_percussions=evs[zen, 3].copy(),
        contact_intervals=intervals,
        contact_open=open_,
        graze_times=grz[:ngr].copy(),
        t0=t0, t_end=t_end, _model=md, _segs=segs, _evs=evs)
    return ev


def exact_events(system: MechanicalSystem, x0, t_end: float, tau=None, t0: float = 0.0,
                 max_events: int = 10_000_000, zeno_ttol: float = 1e-12,
                 zeno_vtol: float = 1e-10, cutoff_vtol: float = 1e-6) -> ExactEvents:
    """Event-driven exact solution on ``[t0, t_end]``: impacts, completed Zeno
    accumulations, contact intervals and grazings (see the module docstring).

    ``ExactEvents.state(t)`` evaluates the closed-form solution at any times.
    Raises ``ValueError`` for n != 1, bad inputs or ``g(q0) < 0`` and
    ``RuntimeError`` if more than ``max_events`` events occur.
    """
    return _run_events(system, x0, t_end, tau, t0, max_events, zeno_ttol, zeno_vtol, cutoff_vtol)


def simulate_exact(system: MechanicalSystem, x0, t_end: float, dt: float, tau=None,
                   record_every: int = 1, t0: float = 0.0,
                   max_events: int = 10_000_000, zeno_ttol: float = 1e-12,
                   zeno_vtol: float = 1e-10, cutoff_vtol: float = 1e-6):
    """Exact solution sampled on ``t0 + i dt`` and at ``t_end`` (the last row),
    keeping every ``record_every``-th sample (row 0 = initial state).

    Returns a :class:`SimulationResult` with ``scheme="exact"`` and the
    :class:`ExactEvents` in ``result.events``. ``percussion[i]`` is
    the wall impulse over ``(t[i-1], t[i]]`` (impacts, completed Zeno series and
    persistent-contact force).
    """
    t0 = float(t0)
    if not math.isfinite(t0):
        raise ValueError(f"t0 must be finite, got {t0}")
    grid, record_every = check_run(t_end, dt, record_every, float(t0))
    dt = grid.dt
    rows = record_rows(grid.steps, record_every)
    check_record_size(rows, 4, "the record of simulate_exact")
    T = record_times(grid, record_every, float(t0))
    horizon = max(float(t_end), float(T[-1]))
    ev = _run_events(system, x0, horizon, tau, t0, max_events, zeno_ttol, zeno_vtol, cutoff_vtol)
    md = ev._model
    q = np.empty(rows)
    u = np.empty(rows)
    P = np.zeros(rows)
    _sample(T, ev._segs, ev._segs.shape[0], ev._evs, ev._evs.shape[0], md.prm, md.rc, md.roots,
            md.hs, md.hO, md.hph, md.hcc, md.hcs, md.w, md.g0, q, u, P, True)
    return SimulationResult(T, q.reshape(rows, 1), u.reshape(rows, 1), P, "exact", dt, events=ev)


# --------------------------------------------------------------------------- communication step
# The exact solver as an FMU slave's internal solver: one call per communication
# step [t, t + H] with tau constant over it. Plain arrays and floats only, so that
# a numba cfunc (the FMU binary) can call it.

#: layout of the packed model (:func:`exact_model`)
_M_NH, _M_NIN, _M_W, _M_G0, _M_PRM = 0, 1, 2, 3, 4
_M_RC = _M_PRM + _NPRM
_M_ROOTS = _M_RC + NT
_M_SB = _M_ROOTS + 4

#: exact_step status codes
STEP_OK, STEP_TOO_MANY_EVENTS, STEP_NO_PROGRESS = 0, 1, 2


def exact_model(system: MechanicalSystem) -> np.ndarray:
    """The 1-DOF system packed into one float64 array for :func:`exact_step`.

    Layout: ``[nh, m, w, g0, prm (16), rc (28), roots (re, im, re, im), sB (m),
    then per harmonic term j < nh: s_j, Omega_j, phi_j, Yc series (28), Ys series (28)]``
    with ``prm`` for ``tau = 0`` and ``sB = w B / m`` (the gap acceleration per
    unit input). Raises ValueError for n != 1.
    """
    md = _model(system, np.zeros(system.m))
    sa = system.arrays()
    nh = md.hs.size
    sB = md.w * sa.B[0, :] / float(sa.M[0, 0])
    parts = [np.array([nh, system.m, md.w, md.g0], dtype=np.float64), md.prm, md.rc,
             np.array([md.roots[0].real, md.roots[0].imag, md.roots[1].real, md.roots[1].imag]),
             sB.astype(np.float64)]
    for j in range(nh):
        parts += [np.array([md.hs[j], md.hO[j], md.hph[j]]), md.hcc[j], md.hcs[j]]
    return np.ascontiguousarray(np.concatenate(parts))


@njit(cache=True)
def _unpack(model, tau):
    nh = int(model[_M_NH])
    nin = int(model[_M_NIN])
    w = model[_M_W]
    g0w = model[_M_G0]
    prm = model[_M_PRM:_M_PRM + _NPRM].copy()
    rc = model[_M_RC:_M_RC + NT].copy()
    roots = np.empty(2, dtype=np.complex128)
    roots[0] = complex(model[_M_ROOTS], model[_M_ROOTS + 1])
    roots[1] = complex(model[_M_ROOTS + 2], model[_M_ROOTS + 3])
    s0 = prm[_S0]
    for j in range(nin):
        s0 += model[_M_SB + j] * tau[j]
    off = _M_SB + nin
    hs = np.empty(nh)
    hO = np.empty(nh)
    hph = np.empty(nh)
    hcc = np.empty((nh, NT))
    hcs = np.empty((nh, NT))
    F0 = abs(s0)
    for j in range(nh):
        b = off + j * (3 + 2 * NT)
        hs[j] = model[b]
        hO[j] = model[b + 1]
        hph[j] = model[b + 2]
        for k in range(NT):
            hcc[j, k] = model[b + 3 + k]
            hcs[j, k] = model[b + 3 + NT + k]
        F0 += abs(hs[j])
    prm[_S0] = s0
    prm[_F0] = F0
    return prm, rc, roots, hs, hO, hph, hcc, hcs, w, g0w


@njit(cache=True)
def exact_step(model, q, u, t, H, tau, vref, max_events=1_000_000, zeno_ttol=1e-12,
               zeno_vtol=1e-10, cutoff_vtol=1e-6):
    """Advance the 1-DOF state exactly over one communication step ``[t, t + H]``
    with the input ``tau`` (array, length m) constant over it.

    ``model``: :func:`exact_model` of the system; ``q, u, t, H``: floats. The
    flow between events is the closed form, impacts are located by the certified
    root search, accumulations are completed and followed by persistent contact
    with release when the contact force changes sign -- exactly as
    :func:`simulate_exact`, which this step reproduces when chained (same
    ``vref``). ``vref`` is the run's velocity scale for the Zeno criteria: pass
    0.0 on the first step and the returned value on the next one (it is part of
    the slave's state). Returns ``(status, q, u, percussion, impacts, vref)``:
    the state at ``t + H`` (post-impact if an impact falls on ``t + H``), the
    wall impulse over ``(t, t + H]`` (impacts, completed accumulations and the
    persistent contact force), the number of individually resolved impacts, and
    status STEP_OK, STEP_TOO_MANY_EVENTS (more than ``max_events`` events in the
    step) or STEP_NO_PROGRESS (undecidable contact; the state is unchanged then).
    """
    st, _, q1, u1, _, P, _, hits, vref = exact_step_early(
        model, q, u, t, H, tau, vref, False, max_events, zeno_ttol, zeno_vtol, cutoff_vtol)
    return st, q1, u1, P, hits, vref


@njit(cache=True)
def exact_step_early(model, q, u, t, H, tau, vref, early, max_events=1_000_000, zeno_ttol=1e-12,
                     zeno_vtol=1e-10, cutoff_vtol=1e-6):
    """:func:`exact_step` that, with ``early``, stops at the first impact inside
    ``(t, t + H)`` (an FMI 3.0 early return).

    Returns ``(status, t_stop, q, u, u_minus, percussion, p_impact, impacts, vref)``:
    ``t_stop`` is ``t + H`` or the impact instant; ``q, u`` the state there
    (post-impact), ``u_minus`` the velocity just before the stop (the pre-impact
    velocity of an early stop, else ``u``), ``percussion`` the wall impulse over
    ``(t, t_stop]`` including the impact's ``p_impact``, ``vref`` the run's
    velocity scale at ``t_stop``. Continuing from ``(t_stop, q, u, vref)`` runs
    the same closed-form segments as one step over the whole interval (an
    impact that completes an accumulation is then resolved from the post-impact
    state instead)."""
    prm, rc, roots, hs, hO, hph, hcc, hcs, w, g0w = _unpack(model, tau)
    g = w * q + g0w
    if g != 0.0 and abs(g) <= 4.0 * EPS * (abs(w * q) + abs(g0w)):
        g = 0.0                      # on the wall within the round-off of q = (0 - g0)/w
    if g < 0.0:
        g = 0.0
    v = w * u
    vref_in = vref
    status, segs, nseg, evs, nev, grz, ngr, vref = _run(
        prm, rc, roots, hs, hO, hph, hcc, hcs, t, g, v, t + H, max_events, zeno_ttol,
        zeno_vtol, cutoff_vtol, vref)
    if status != 0:
        return status, t, q, u, u, 0.0, 0.0, 0, vref
    t_stop = t + H
    first = -1
    if early:
        for i in range(nev):
            if evs[i, 1] == IMPACT_EV and t < evs[i, 0]:
                if evs[i, 0] < t_stop:
                    first = i
                break
    if first >= 0:
        t_stop = evs[first, 0]
        vref = _vref_start(prm, g, v, vref_in)
        for i in range(first + 1):
            if evs[i, 1] == IMPACT_EV:
                vref = max(vref, -evs[i, 2])
    T = np.empty(2)
    T[0] = t
    T[1] = t_stop
    Q = np.empty(2)
    U = np.empty(2)
    P = np.zeros(2)
    _sample(T, segs, nseg, evs, nev, prm, rc, roots, hs, hO, hph, hcc, hcs, w, g0w, Q, U, P, True)
    impacts = 0
    for i in range(nev):
        if evs[i, 1] == IMPACT_EV and t < evs[i, 0] <= t_stop:
            impacts += 1
    if first >= 0:
        return STEP_OK, t_stop, Q[1], U[1], evs[first, 2] / w, P[1], evs[first, 3], impacts, vref
    return STEP_OK, t_stop, Q[1], U[1], U[1], P[1], 0.0, impacts, vref
