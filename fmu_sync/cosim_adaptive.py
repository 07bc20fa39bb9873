"""Co-simulation to a tolerance: the adaptive communication step (docs/design.md §4.4.1).

A layer on top of the compiled exchange loop (:mod:`fmu_sync.cosim_loop`): it takes that
loop's one exchange over [t, t + h] (``exchange_step``: Jacobi or Gauss–Seidel, zero- or
first-order hold) and wraps it in an error test with FMU-state rollback, compiled like the
loop (numba nopython, ``cache=True``, no Python per step):

* before each step every instance's FMU state is taken (fmi2GetFMUstate into the same handle
  every step) with the master's own copies (states, input history, held forces);
* after it, the forces at the step's end are computed from the new states and compared with
  the force the hold gave at the step's end; their difference delta_i is the coupling error
  of the step, and its effect on node i's state is estimated as the response to the ramp
  delta_i (s/h) over the step (:func:`local_error`);
* a step whose estimate exceeds its share of the tolerance, ``tol h / t_end``, is rolled back
  (fmi2SetFMUstate, the master's copies) and retaken shorter; an accepted step's estimate is
  added to the run's error estimate and the next step grows or shrinks by the controller
  (:func:`next_step`).

Steps are whole multiples of the slaves' ``solver.dt`` (``unit``), from ``unit`` (the floor,
always accepted: a step shorter than the slaves' own is not possible) to ``H``, their ends on
the grid of whole units (no drift of t); the last one lands on t_end exactly, stretched by at most a
round-off (:func:`fmu_sync.core.checks.lands`) and never followed by a step of a round-off's length.
The estimate is against the coupled system, the floor's own error included: a run whose steps at
the floor exceed their share says so (``info["tol_met"]``, the master).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .core.checks import TIME_TOL, lands
from .core.network import network_forces
from .cosim_loop import (DONE, FULL, FREE_STATE, GET_STATE, fmu_states, HIST_VALID, FRESH, IMPLICIT, NOT_CONVERGED, ROW, SET_STATE,
                         SLAVE_FAILED, STATE_DIVERGED, DISTANCE_DIVERGED, WARNING, FOH, GAUSS_SEIDEL, RECORD_EVERY,
                         NEED_D, copy_rows, exchange_step, fail_at, implicit_step, read_impacts, record_row, unmanaged)

__all__ = ["adaptive_chunk", "Extra", "controller_arrays", "controller_state", "SETTINGS", "FLOATS", "COUNTS", "free_states", "SAFETY", "FAC_MIN", "FAC_MAX", "FULL",
           "A_TOL", "A_T_END", "A_UNIT", "A_H", "AD", "S_T", "S_H", "S_ERR", "AST",
           "C_STEPS", "C_REJECTED", "C_FORCED", "C_DONE", "ACTL"]

#: the controller's safety factor and bounds on the ratio of one step to the previous one
SAFETY, FAC_MIN, FAC_MAX = 0.9, 0.2, 5.0
#: the estimate's kinds (``kind`` of :func:`local_error`): the explicit zero- and first-order hold, the
#: implicit exchange
ZOH, FOH_KIND, IMPLICIT_KIND, IMPLICIT_MEAN = range(4)
#: Milne's factor of the implicit exchange: its converged (trapezoidal) force line misses a quadratic
#: force by tau'' s (s - h)/2, whose effect on u over the step is tau'' h^3/12, against tau'' h^3/2
#: for the ramp of the predictor-corrector difference delta = tau'' h^2 in the formulas
MILNE = 1.0 / 6.0


class Extra(NamedTuple):
    """The controller's own arrays: the held forces' copy ``taus`` and the forces at the step's end
    ``tau_end`` (N, n), scratch ``delta``, ``v`` (n,), its FMU-state handles ``mine`` (N,) and ``pmine``
    (the loop's ``ptr`` with the address of ``mine`` in its ``P_SAVED`` slot)."""
    taus: np.ndarray
    tau_end: np.ndarray
    delta: np.ndarray
    v: np.ndarray
    mine: np.ndarray
    pmine: np.ndarray


# ad: the run's settings (tolerance, t_end, the step unit = the slaves' solver.dt, the largest step H)
SETTINGS = ("tol", "t_end", "unit", "H")
A_TOL, A_T_END, A_UNIT, A_H = range(len(SETTINGS))
AD = len(SETTINGS)
# ast: the controller's float state (time, next step, the run's error estimate)
FLOATS = ("t", "h", "error_estimate")
S_T, S_H, S_ERR = range(len(FLOATS))
AST = len(FLOATS)
# actl: accepted steps, rejected steps, steps accepted at the floor over their share, finished
COUNTS = ("steps", "rejected", "floor_steps", "done")
C_STEPS, C_REJECTED, C_FORCED, C_DONE = range(len(COUNTS))
ACTL = len(COUNTS)


def controller_arrays(tol: float, t_end: float, unit: float, H: float, h0: float):
    """The controller's arrays, filled by name: ``ad`` (:data:`SETTINGS`), ``ast`` (:data:`FLOATS`:
    time 0, the first step ``h0``, estimate 0) and ``actl`` (:data:`COUNTS`, all 0)."""
    settings = dict(tol=tol, t_end=t_end, unit=unit, H=H)
    return (np.array([float(settings[k]) for k in SETTINGS]), np.array([0.0, float(h0), 0.0]),
            np.zeros(len(COUNTS), dtype=np.int64))


def controller_state(ast, actl) -> dict:
    """The controller's state by name (:data:`FLOATS` and :data:`COUNTS`)."""
    return {**{k: float(ast[i]) for i, k in enumerate(FLOATS)}, **{k: int(actl[i]) for i, k in enumerate(COUNTS)}}


@njit(cache=True, inline="always")
def _copies(back, live, kept, hist, hs, ctl):
    """The master's own state at a step's start (``live``: states, input history, held forces;
    ``hist``, ``ctl[HIST_VALID]``) kept in ``kept``, ``hs`` (``back`` False) or put back (True)."""
    for j in range(len(live)):
        if back:
            copy_rows(kept[j], live[j])
        else:
            copy_rows(live[j], kept[j])
    if back:
        hist[0] = hs[0]
        ctl[HIST_VALID] = np.int64(hs[1])
    else:
        hs[0] = hist[0]
        hs[1] = ctl[HIST_VALID]


@njit(cache=True, inline="always")
def error_forms(delta, Minv, Qn, Mn, v):
    """(v' Qn v, v' Mn v) of v = M^-1 delta: the two quadratic forms of :func:`local_error`.
    ``Qn``, ``Mn``: Q and M divided by lambda_min(Q); ``v`` scratch (n,)."""
    n = delta.shape[0]
    for a in range(n):
        s = 0.0
        for b in range(n):
            s += Minv[a, b] * delta[b]
        v[a] = s
    eq = 0.0
    eu = 0.0
    for a in range(n):
        for b in range(n):
            eq += v[a] * Qn[a, b] * v[b]
            eu += v[a] * Mn[a, b] * v[b]
    return eq, eu


@njit(cache=True, inline="always")
def local_error(h_new, h, eq, eu, unit, kind, eq_mean=0.0):
    """The estimated local coupling error of one node over a step of length ``h_new``, against
    the coupled system (the exact force the law gives along the exact motion), in q's unit, from
    the force mismatch delta of a step of length ``h`` (its forms ``eq``, ``eu``,
    :func:`error_forms`; ``h_new = h``: the step's own estimate). ``unit`` (the slaves' solver.dt)
    is not subtracted: the floor h = unit has its own error, which the estimate keeps.

    delta is the force at the step's end from the new states minus the force the hold gave
    there; its effect is the response to the ramp delta (s/h), s in [0, h]:
    Delta u = M^-1 delta c_u, Delta q = M^-1 delta c_q, c_u = h/2, c_q = h^2/6 for every hold.
    The norm is the law's metric ``sqrt(dq' Q dq + du' M du)`` over sqrt(lambda_min(Q)): for one
    degree of freedom sqrt(dq^2 + du^2 m/Q), the position amplitude the state error carries. For
    another step length delta is scaled as the hold's mismatch grows away from impacts: as h
    (zero-order hold) or h^2 (first-order hold). ``kind`` :data:`IMPLICIT_KIND`: delta is the
    converged end force against the explicit first-order prediction, taken as the first-order
    hold's and scaled by :data:`MILNE` (the converged line's own error, Milne's device);
    :data:`IMPLICIT_MEAN` adds the mean's own error: holding the mean (f0 + f1)/2 instead of the
    line from f0 to f1 moves q by M^-1 (f1 - f0) h^2/12 (u unchanged); ``eq_mean`` is the form
    v' Qn v of v = M^-1 (f1 - f0) of the step h, scaled as h for another step length."""
    second = kind != ZOH
    cu = 0.5 * h_new
    cq = h_new * h_new / 6.0
    r = h_new / h
    scale = r * r if second else r
    if kind == IMPLICIT_KIND or kind == IMPLICIT_MEAN:
        scale *= MILNE
    err = scale * math.sqrt(max(cq * cq * eq + cu * cu * eu, 0.0))
    if kind == IMPLICIT_MEAN:
        err += r * h_new * h_new / 12.0 * math.sqrt(max(eq_mean, 0.0))
    return err


@njit(cache=True, inline="always")
def next_step(h, eq, eu, tol, t_end, kind, unit, H, mode, eq_mean=0.0):
    """The controller: the longest whole multiple m unit of the step unit whose predicted error
    (:func:`local_error` from this step's mismatch) is at most SAFETY times its share
    tol m unit / t_end, with m unit in [FAC_MIN h, FAC_MAX h] and [unit, H]; ``mode`` 1: not
    longer than h (right after a rejection), 2: shorter than h (a rejected step); ``eq_mean``: as
    :func:`local_error`."""
    m_h = math.floor(h / unit + 1e-9)
    m_hi = min(math.floor(H / unit + 1e-9), math.floor(FAC_MAX * h / unit + 1e-9))
    if mode == 1:
        m_hi = min(m_hi, m_h)
    elif mode == 2:
        m_hi = min(m_hi, m_h - 1)
    m_hi = max(1.0, m_hi)
    m_lo = min(m_hi, max(1.0, math.ceil(FAC_MIN * h / unit - 1e-9)))
    if local_error(m_hi * unit, h, eq, eu, unit, kind, eq_mean) <= SAFETY * tol * m_hi * unit / t_end:
        return m_hi * unit
    if not local_error(m_lo * unit, h, eq, eu, unit, kind, eq_mean) <= SAFETY * tol * m_lo * unit / t_end:
        return m_lo * unit
    while m_hi - m_lo > 1:   # m_lo passes, m_hi does not
        m = math.floor(0.5 * (m_lo + m_hi))
        if local_error(m * unit, h, eq, eu, unit, kind, eq_mean) <= SAFETY * tol * m * unit / t_end:
            m_lo = m
        else:
            m_hi = m
    return m_lo * unit


@njit(cache=True)
def adaptive_chunk(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, ad, norm, budget, q, u, tau, tau_next,
                   hist_tau, hist, imp, ctl, saved, keep, extra, ast, actl, T, Qr, Ur, TAU, D, BR, EU, HS, ES, w,
                   FAIL, fail_t):
    """Up to ``budget`` tries of a communication step (accepted or rejected), from the time
    ``ast[S_T]`` with the proposed step ``ast[S_H]``; the start (row 0) is made before by
    :func:`fmu_sync.cosim_loop.exchange_chunk` with ``k0 = -1``. Arguments as ``exchange_chunk``
    and: ``ad`` (:data:`A_TOL` ...), ``norm`` (M^-1, Q/lambda_min(Q), M/lambda_min(Q)),
    ``extra`` (held forces' copy and forces at the step's end (N, n), scratch (n,) twice, the
    controller's own FMU-state handles ``mine`` (N,) and ``pmine``, ``ptr`` with the address of
    ``mine`` in its ``P_SAVED`` slot, for ``cosim_loop.fmu_states``); with the implicit exchange
    (``flags[IMPLICIT]``) the step is :func:`fmu_sync.cosim_loop.implicit_step` (its per-step
    arrays in ``keep.iw`` indexed by the accepted step), its estimate the converged end force
    against its explicit first-order prediction, and a step that does not converge is retaken
    shorter, ``ast``, ``actl``
    (:data:`C_STEPS` ...), ``HS``, ``ES`` the accepted steps' lengths and local estimates.
    Returns the outcome code: DONE (finished if ``actl[C_DONE]``, else the budget is spent),
    :data:`FULL` (the record or the step arrays are full: grow them and call again) or a
    failure (``FAIL``)."""
    (ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, q, u, tau, tau_next, hist_tau, hist, imp, ctl, saved, keep,
     extra, T, Qr, Ur, TAU, D, BR, EU, HS, ES, w, FAIL, fail_t) = unmanaged(
        (ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, q, u, tau, tau_next, hist_tau, hist, imp, ctl, saved,
         keep, extra, T, Qr, Ur, TAU, D, BR, EU, HS, ES, w, FAIL, fail_t))
    N, n = q.shape[0], q.shape[1]
    need_d = flags[NEED_D] != 0
    implicit = flags[IMPLICIT] != 0
    foh = flags[FOH] != 0 or implicit   # the implicit exchange is measured against its explicit prediction
    mean = implicit and flags[FOH] == 0   # the implicit exchange holding the mean of the step's end forces
    kind = (IMPLICIT_MEAN if mean else IMPLICIT_KIND) if implicit else FOH_KIND if foh else ZOH
    jacobi = flags[GAUSS_SEIDEL] == 0
    every = flags[RECORD_EVERY]
    tol, t_end, unit, H = ad[A_TOL], ad[A_T_END], ad[A_UNIT], ad[A_H]
    Minv, Qn, Mn = norm
    qs, us, hts, hs, scratch, imp_new, ibuf, iw = keep
    taus, tau_end, delta, v, mine, pmine = extra
    t1, t2, c1q, c1u, c2q, c2u, dk, bk, ek, buf, slope = w
    FAIL[0] = DONE
    retry = False   # the step being tried follows a rejection (the controller does not grow it)
    for _ in range(budget):
        if actl[C_DONE]:
            return DONE
        if ctl[ROW] >= T.shape[0] or actl[C_STEPS] >= HS.shape[0] or (implicit and actl[C_STEPS] >= iw.iters.shape[0]):
            return FULL
        t = ast[S_T]
        h = ast[S_H]
        # at the floor (always accepted): a proposal of one unit, or the short rest of the run; the
        # test is on the proposal, never on h stretched by a round-off to land on t_end (0.6.0 looped
        # there: a step of unit + 1e-15 was "above the floor", rejected and stretched again, forever)
        floor = h <= unit * (1.0 + TIME_TOL)
        last = lands(t, h, t_end, unit)
        if last:
            h = t_end - t
            floor = floor or h <= unit * (1.0 + TIME_TOL)
        # the step's start in the controller's own handles (the implicit step keeps its own)
        if fmu_states(pmine, fn, comp, FREE_STATE, mine, FAIL, fail_t, t) or fmu_states(pmine, fn, comp, GET_STATE,
                                                                                   mine, FAIL, fail_t, t):
            return FAIL[0]
        _copies(False, (q, u, hist_tau, tau), (qs, us, hts, taus), hist, hs, ctl)
        fresh = ctl[FRESH]
        if implicit:
            if implicit_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, t, h, actl[C_STEPS], q, u, tau,
                              hist_tau, hist, ctl, saved, qs, us, iw, w, FAIL, fail_t, hp):
                if FAIL[0] != NOT_CONVERGED or floor:
                    return FAIL[0]
                # not converged (the slaves are back at t): retaken shorter, as a rejected step
                FAIL[0] = DONE
                actl[C_REJECTED] += 1
                _copies(True, (q, u, hist_tau, tau), (qs, us, hts, taus), hist, hs, ctl)
                ctl[FRESH] = fresh
                ast[S_H] = unit * max(1.0, math.floor(FAC_MIN * h / unit + TIME_TOL))
                retry = True
                continue
        elif exchange_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, t, h, q, u, tau, tau_next, hist_tau, hist,
                       ctl, w, FAIL, fail_t, hp):
            return FAIL[0]
        if read_impacts(ptr, fn, comp, ibuf, imp_new, FAIL, fail_t, t + h):
            return FAIL[0]
        finite = True
        for i in range(N):
            for c in range(n):
                if not (math.isfinite(q[i, c]) and math.isfinite(u[i, c])):
                    finite = False
        if not finite:
            fail_at(FAIL, fail_t, STATE_DIVERGED, -1, -1, 0, t + h)
            return FAIL[0]
        # the estimate: the forces at the step's end against those the hold gave there
        network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau_end, t1, t2, c1q, c1u, c2q, c2u, False, dk, bk, ek, hp,
                       t + h)
        err = 0.0
        eq_max = 0.0
        eu_max = 0.0
        em_max = 0.0
        for i in range(N):
            em = 0.0
            if mean:   # the force's change over the step: the mean's own error
                for c in range(n):
                    delta[c] = tau_end[i, c] - taus[i, c]
                em, _ = error_forms(delta, Minv, Qn, Mn, v)
            for c in range(n):
                held = tau[i, c]
                if foh and hs[1] != 0 and t > hs[0]:
                    held += (tau[i, c] - hts[i, c]) / (t - hs[0]) * h
                delta[c] = tau_end[i, c] - held
            eq, eu = error_forms(delta, Minv, Qn, Mn, v)
            err = max(err, local_error(h, h, eq, eu, unit, kind, em))
            eq_max = max(eq_max, eq)
            eu_max = max(eu_max, eu)
            em_max = max(em_max, em)
        share = tol * h / t_end
        if not math.isfinite(err):
            err = np.inf
            eq_max = eu_max = em_max = np.inf
        if err > share and not floor:
            # rejected: every instance and the master's copies back to t, retaken shorter
            actl[C_REJECTED] += 1
            if fmu_states(pmine, fn, comp, SET_STATE, mine, FAIL, fail_t, t):
                return FAIL[0]
            _copies(True, (q, u, hist_tau, tau), (qs, us, hts, taus), hist, hs, ctl)
            ctl[FRESH] = fresh
            ast[S_H] = next_step(h, eq_max, eu_max, tol, t_end, kind, unit, H, 2, em_max)
            retry = True
            continue
        # accepted
        if err > share:
            actl[C_FORCED] += 1
        k = actl[C_STEPS]
        HS[k] = h
        ES[k] = err
        actl[C_STEPS] = k + 1
        ast[S_ERR] += err
        for i in range(N):
            imp[i] = imp_new[i]
        # on the unit grid (whole units from 0, as the slaves count their steps): no drift of t over
        # many steps, so the last step is a whole number of units or the run's own short rest
        t_next = t_end if last else unit * math.floor((t + h) / unit + 0.5)
        if actl[C_STEPS] % every == 0 or last:
            row = ctl[ROW]
            if not record_row(row, t_next, q, u, tau, laws, geo, Kp, Kd, E2, W2, need_d, jacobi, ctl, T, Qr, Ur, TAU,
                           D, BR, EU, scratch, w, hp):
                fail_at(FAIL, fail_t, DISTANCE_DIVERGED, -1, -1, 0, t_next)
                return FAIL[0]
            ctl[ROW] = row + 1
        if jacobi and ctl[FRESH] == 0:   # the next step's forces are those of the estimate
            copy_rows(tau_end, tau)
            ctl[FRESH] = 1
        ast[S_T] = t_next
        ast[S_H] = next_step(h, eq_max, eu_max, tol, t_end, kind, unit, H, 1 if retry else 0, em_max)
        retry = False
        if last:
            actl[C_DONE] = 1
            return DONE
    return DONE


@njit(cache=True)
def free_states(pmine, fn, comp, mine, FAIL, fail_t):
    """fmi2FreeFMUstate of every instance's state the controller kept (at the end of a run)."""
    fmu_states(pmine, fn, comp, FREE_STATE, mine, FAIL, fail_t, 0.0)
