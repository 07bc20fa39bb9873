"""The event loop of the 1-DOF exact solver (docs/design.md §2.3): impacts, the
completion of accumulations (Zeno), persistent contact and release, and the
sampling of the event-driven solution on given times.

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
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .exact_flow import EPS, derivs, force, phases, sticks
from .exact_flow import P_A, P_E, P_F0, P_OMX, P_S, P_S0, P_W
from .exact_search import GRAZE, NONE, search

__all__ = ["FREE", "CONTACT", "ZENO", "IMPACT_EV", "ZENO_EV", "vref_start", "run_events", "sample"]

FREE, CONTACT, ZENO = 0, 1, 2
IMPACT_EV, ZENO_EV = 0, 1


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
def vref_start(prm, g, v, vref0):
    """The run's velocity scale at its start: initial speed, free-fall speed from
    the initial gap, forcing amplitude over the fastest time scale (``vref0 > 0``:
    carried over from an earlier part of the run). Impacts raise it (:func:`run_events`)."""
    smax = prm[P_S]
    vref = max(abs(v), math.sqrt(2.0 * prm[P_F0] * max(g, 0.0)))
    if smax > 0.0:
        vref = max(vref, prm[P_F0] / smax)
    if vref0 > 0.0:
        vref = vref0
    return vref


@njit(cache=True)
def _push(rows, n, c0, c1, c2, c3, c4):
    """Append the row (c0, ..., c4) to ``rows[:n]`` (grown when full): returns (rows, n + 1)."""
    if n == rows.shape[0]:
        rows = _grow2(rows)
    rows[n, 0] = c0
    rows[n, 1] = c1
    rows[n, 2] = c2
    rows[n, 3] = c3
    rows[n, 4] = c4
    return rows, n + 1


@njit(cache=True)
def _impact_law(prm, hs, hO, hph, t, vm, vref, zeno_vtol, zeno_ttol, cutoff_vtol):
    """Newton's law at an impact at t with gap velocity vm < 0, and whether the bounce
    sequence it starts is completed (module docstring): returns (v+, P, complete, T_rem, a_w)."""
    e = prm[P_E]
    W = prm[P_W]
    smax = prm[P_S]
    v = -e * vm
    P = (1.0 + e) * (-vm) / W
    complete = False
    Trem = 0.0
    aw = 0.0
    if v > 0.0:
        aw = force(prm, hs, hO, hph, t)[0] - prm[P_A] * v
        if aw < 0.0:
            small = v <= zeno_vtol * vref
            if e < 1.0:
                den = (-aw) * (1.0 - e)      # 0 if a subnormal a_w underflows: no completion
                Trem = 2.0 * v / den if den > 0.0 else np.inf
                ez = smax * Trem
                complete = ((smax > 0.0 and ez <= zeno_ttol)
                            or (small and ez <= 1e-6)
                            or Trem * (1.0 - e) <= 16.0 * EPS * abs(t))
            elif v <= cutoff_vtol * vref:
                # e = 1: no geometric accumulation; micro-bounce cut-off (plastic)
                v = 0.0
                P = (-vm) / W
    return v, P, complete, Trem, aw


@njit(cache=True)
def _impact(prm, hs, hO, hph, t, vm, vref, zeno_vtol, zeno_ttol, cutoff_vtol, segs, nseg, evs, nev):
    """An impact at t with gap velocity vm < 0 recorded (and the completed accumulation it
    starts, if any): returns (t, v, segs, nseg, evs, nev) after it."""
    v, P, complete, Trem, aw = _impact_law(prm, hs, hO, hph, t, vm, vref, zeno_vtol, zeno_ttol,
                                           cutoff_vtol)
    evs, nev = _push(evs, nev, t, IMPACT_EV, vm, P, t)
    if complete:
        e = prm[P_E]
        segs, nseg = _push(segs, nseg, t, ZENO, 0.0, v, aw)
        evs, nev = _push(evs, nev, t + Trem, ZENO_EV, v, (1.0 + e) * v / ((1.0 - e) * prm[P_W]), t)
        t = t + Trem
        v = 0.0
    return t, v, segs, nseg, evs, nev


@njit(cache=True)
def _crossing(mode, depart, taumax, H0, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g, v, t,
              grz, ngr, count, max_events):
    """The segment's first crossing after t (search), the grazes on the way appended to grz;
    each graze counts as an event. Returns (status, tau, grz, ngr, count)."""
    alpha = 0.0
    while True:
        st, tau = search(mode, alpha, depart, taumax, H0, prm, rc, roots, hs, hO, hcc, hcs,
                         cps, sps, g, v)
        if st != GRAZE:
            return st, tau, grz, ngr, count
        if ngr == grz.shape[0]:
            grz = _grow1(grz)
        grz[ngr] = t + tau
        ngr += 1
        count += 1
        if count > max_events:
            return st, tau, grz, ngr, count
        alpha = tau
        depart = True


@njit(cache=True)
def _progress(count, max_events, t, t_last, stall):
    """(status, t_last, stall): status 1 past max_events, 2 when time has not moved for 64
    events (should not happen), else 0."""
    if count > max_events:
        return 1, t_last, stall
    if t > t_last:
        return 0, t, 0
    stall += 1
    return (2 if stall > 64 else 0), t_last, stall


@njit(cache=True)
def _classify(prm, hs, hO, hph, t, g, v, left, stick):
    """The next segment's kind and start (kind, g, v): FREE off the wall or leaving it, else
    CONTACT where the state sticks (or after a completed accumulation), at rest on the wall."""
    if g > 0.0 or v > 0.0 or left:
        return FREE, g, v
    return (CONTACT if (stick or sticks(prm, hs, hO, hph, t)) else FREE), 0.0, 0.0


@njit(cache=True)
def run_events(prm, rc, roots, hs, hO, hph, hcc, hcs, t0, g_init, v_init, t_hor, max_events,
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
    smax = prm[P_S]
    H0g = 0.5 / smax if smax > 0.0 else np.inf
    H0c = 0.5 / prm[P_OMX] if prm[P_OMX] > 0.0 else np.inf
    t = t0
    g = g_init
    v = v_init
    left = False
    stick = False
    t_last = t0
    stall = 0
    # velocity scale of the run: initial speed, free-fall speed from the initial gap,
    # forcing amplitude over the fastest time scale; raised by every impact speed
    vref = vref_start(prm, g, v, vref0)
    count = 0
    status = 0
    while t <= t_hor:
        count += 1
        status, t_last, stall = _progress(count, max_events, t, t_last, stall)
        if status:
            break
        # ---- impact at t
        if g <= 0.0 and v < 0.0 and not left:
            vref = max(vref, -v)
            g = 0.0
            t, v, segs, nseg, evs, nev = _impact(prm, hs, hO, hph, t, v, vref, zeno_vtol, zeno_ttol,
                                                 cutoff_vtol, segs, nseg, evs, nev)
            continue
        # ---- classify
        kind, g, v = _classify(prm, hs, hO, hph, t, g, v, left, stick)
        stick = False
        segs, nseg = _push(segs, nseg, t, kind, g, v, 0.0)
        phases(hO, hph, t, cps, sps)
        mode = 0 if kind == FREE else 1
        st, tau, grz, ngr, count = _crossing(mode, (kind == CONTACT) or g <= 0.0, t_hor - t,
                                             H0g if kind == FREE else H0c, prm, rc, roots, hs, hO,
                                             hcc, hcs, cps, sps, g, v, t, grz, ngr, count, max_events)
        if count > max_events:
            status = 1
            break
        left = False
        if st == NONE:
            break
        if kind == FREE:
            vm = derivs(0, tau, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, g, v)[1]
            # leaving the wall at rest, the motion turned into it at once: contact
            stick = tau == 0.0 and vm >= 0.0
            v = min(vm, 0.0)
        else:
            v = 0.0
            left = True
        t = t + tau
        g = 0.0
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
def sample(T, segs, nseg, evs, nev, prm, rc, roots, hs, hO, hph, hcc, hcs, w, g0w,
            Q, U, P, with_p):
    R = T.shape[0]
    nh = hs.shape[0]
    cps = np.empty(nh)
    sps = np.empty(nh)
    e = prm[P_E]
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
                phases(hO, hph, ts, cps, sps)
                cur = k
            d = derivs(0, t - ts, prm, rc, roots, hs, hO, hcc, hcs, cps, sps, segs[k, 2], segs[k, 3])
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
    W = prm[P_W]
    s0 = prm[P_S0]
    for k in range(nseg):
        if int(segs[k, 1]) != CONTACT:
            continue
        cs = segs[k, 0]
        ce = segs[k + 1, 0] if k + 1 < nseg else np.inf
        phases(hO, hph, cs, cps, sps)
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
