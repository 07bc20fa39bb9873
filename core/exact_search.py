"""The event search of the 1-DOF exact solver (docs/design.md §2.3): the first
down-crossing of the gap (the next impact) or of the contact force (the release)
after a segment start, certified step by step, and its refinement to a few ulps.

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
"""
from __future__ import annotations

import math

from .jit import njit

from .exact_flow import EPS, TOLF, derivs
from .exact_flow import P_F0, P_F1, P_F2, P_F4, P_S
from .roots import taylor_start

__all__ = ["NONE", "ROOT", "GRAZE", "search", "step_shape", "step_crossing", "newton_step"]

NONE, ROOT, GRAZE = 0, 1, 2


@njit(cache=True)
def j4(mode, prm, d0, d1, h):
    """Bound of the fourth derivative over a step of length h."""
    if mode == 1:
        return prm[P_F4]
    s = prm[P_S]
    F0 = prm[P_F0]
    N = max(s * abs(d0), abs(d1))
    Nmax = (N + F0 * h) * math.exp(2.0 * s * h)
    return 5.0 * s * s * s * Nmax + 2.0 * s * s * F0 + s * prm[P_F1] + prm[P_F2]


# --------------------------------------------------------------------------- shared with .exact_nd
@njit(cache=True)
def step_shape(d0, d1, d2, d3, J, h):
    """What the derivatives ``d0..d3`` of F at the left end of a step of length ``h``
    and the bound ``J >= |d4|`` over it prove: ``(adv, decreasing, convex, concave)``
    -- F increasing (``L1 > 0``) or positive (``lb > 0``) on the whole step, F
    decreasing (``U1 < 0``), ``d2 >= 0`` or ``d2 <= 0`` on the step."""
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
    return adv, decreasing, convex, concave


@njit(cache=True)
def step_crossing(decreasing, convex, concave, d1, e0, e1, tolb):
    """On a step that does not advance (:func:`step_shape`), with the slope ``d1`` at its
    left end and the value and slope ``e0, e1`` at its right end: ``(want_root, want_crit)`` --
    F crosses below ``-tolb`` (refine the root) or has an interior critical point to
    locate first (the minimum of a convex step, the maximum of a concave one)."""
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
    return want_root, want_crit


@njit(cache=True)
def newton_step(x, F, Fp, lo, hi, slo, dxold):
    """One safeguarded Newton step on F (value ``F``, slope ``Fp`` at x) in the bracket ``(lo, hi)``
    whose left end has the sign ``slo``: the bracket is kept, bisection when Newton
    leaves it or does not halve the step. Returns ``(x, lo, hi, dxold, done)``."""
    if F == 0.0:
        return x, lo, hi, dxold, True
    if (F > 0.0) == slo:
        lo = x
    else:
        hi = x
    width = hi - lo
    if width <= 4.0 * EPS * max(abs(lo), abs(hi)) or width <= 1e-300:
        return x, lo, hi, dxold, True
    xn = x - F / Fp if Fp != 0.0 else lo - 1.0
    if lo < xn < hi and abs(xn - x) <= 0.5 * dxold:
        step = abs(xn - x)
        return xn, lo, hi, step, step <= 2.0 * EPS * abs(xn)
    return lo + 0.5 * width, lo, hi, width, False


# --------------------------------------------------------------------------- roots
@njit(cache=True)
def refine(which, lo, hi, flo, fplo, fpplo, mode, prm, rc, roots, hs, hO, hcc, hcs, cps, sps,
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
        r = derivs(mode, x, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g0, v0)
        if which == 0:
            F = r[0]
            Fp = r[1]
        else:
            F = r[1]
            Fp = r[2]
        x, lo, hi, dxold, done = newton_step(x, F, Fp, lo, hi, slo, dxold)
        if done:
            return x
    return x


@njit(cache=True)
def search(mode, alpha, depart, taumax, H0, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g0, v0):
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
    d0, d1, d2, d3, sc = derivs(mode, alpha, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g0, v0)
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
        adv, decreasing, convex, concave = step_shape(d0, d1, d2, d3, j4(mode, prm, d0, d1, h), h)
        if not (adv or decreasing or convex or concave or h <= Hmin):
            H = 0.5 * h
            continue
        e0, e1, e2, e3, esc = derivs(mode, beta, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g0, v0)
        if not adv:
            want_root, want_crit = step_crossing(decreasing, convex, concave, d1, e0, e1, TOLF * esc)
            lo = alpha
            hi = beta
            flo = d0
            fplo = d1
            fpplo = d2
            if want_crit:
                tc = refine(1, alpha, beta, d1, d2, d3, mode, prm, rc, roots, hs, hO, hcc, hcs,
                            cps, sps, g0, v0)
                c0, c1, c2, c3, csc = derivs(mode, tc, prm, rc, roots, hs, hO, hcc, hcs, cps, sps,
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
                return ROOT, refine(0, lo, hi, flo, fplo, fpplo, mode, prm, rc, roots, hs, hO,
                                    hcc, hcs, cps, sps, g0, v0)
        d0, d1, d2, d3, sc = e0, e1, e2, e3, esc
        alpha = beta
        H = min(2.0 * h, H0)
    return NONE, taumax
