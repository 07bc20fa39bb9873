"""Co-simulation to a tolerance: the adaptive communication step's controller (docs/design.md §4.4.1).

The one compiled driver (:func:`fmu_sync.cosim_driver.drive`) takes the run's step over
[t, t + h] (``take_step``: Jacobi or Gauss–Seidel, zero- or first-order hold, or the implicit
exchange) and, with ``tol``, wraps it in this module's error test with FMU-state rollback
(numba nopython, ``cache=True``, no Python per step):

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

from .core.network import network_forces
from .cosim_loop import FREE_STATE, FULL, HIST_VALID, copy_rows, fmu_states

__all__ = ["step_error", "step_copies", "next_step", "local_error", "error_forms", "Extra", "controller_arrays",
           "controller_state", "SETTINGS", "FLOATS", "COUNTS", "free_states", "SAFETY", "FAC_MIN", "FAC_MAX", "FULL",
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
def step_copies(back, live, kept, hist, hs, ctl):
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


@njit(cache=True, inline="always")
def step_error(laws, geo, Kp, Kd, E2, W2, hp, q, u, tau, t, h, hts, hs, w, extra, norm, foh, mean, kind, unit):
    """The estimate of a step [t, t + h] just taken (docs/design.md §4.4.1): the forces at its end
    from the new states (into ``extra.tau_end``) against those the hold gave there (``tau``, with the
    first-order hold's slope from ``hts``, ``hs``); per node the local error (:func:`local_error`),
    the largest over the nodes. Returns (err, eq, eu, eq_mean) (their forms' largest, for
    :func:`next_step`); inf if not finite."""
    taus, tau_end, delta, v, mine, pmine = extra
    Minv, Qn, Mn = norm
    N, n = q.shape[0], q.shape[1]
    network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau_end, w.t1, w.t2, w.c1q, w.c1u, w.c2q, w.c2u, False, w.dk,
                   w.bk, w.ek, hp, t + h)
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
    if not math.isfinite(err):
        return np.inf, np.inf, np.inf, np.inf
    return err, eq_max, eu_max, em_max


@njit(cache=True)
def free_states(pmine, fn, comp, mine, FAIL, fail_t):
    """fmi2FreeFMUstate of every instance's state the controller kept (at the end of a run)."""
    fmu_states(pmine, fn, comp, FREE_STATE, mine, FAIL, fail_t, 0.0)
