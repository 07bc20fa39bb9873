"""The master's one compiled driver (docs/design.md §4.4.2): it walks the run's time, for every
strategy of the registry that the compiled loop runs (:mod:`fmu_sync.strategies`).

:func:`drive` takes up to ``budget`` tries of a communication step. Each try: the step's time and
length (the fixed grid k H, its last step shortened to land on t_end exactly; or, with ``tol``,
the controller's proposal on the grid of whole ``solver.dt``), the strategy's step
(:func:`fmu_sync.cosim_loop.take_step`: Jacobi, Gauss–Seidel, delayed, the event-aware retake, the
implicit exchange), the impact counters, the divergence check, with ``tol`` the estimate and the
accept/reject of :mod:`fmu_sync.cosim_adaptive` (a rejected step rolled back to the controller's
FMU states and retaken shorter), then the record (every ``record_every`` accepted steps and the
final state). The start (row 0) is :func:`fmu_sync.cosim_loop.loop_start`'s.
"""
from __future__ import annotations

import math

from numba import njit

from .core.checks import TIME_TOL, lands
from .core.kernels import depends_on_core
from .cosim_adaptive import (A_H, A_T_END, A_TOL, A_UNIT, C_DONE, C_FORCED, C_REJECTED, C_STEPS, FAC_MIN,
                             FOH_KIND, IMPLICIT_KIND, IMPLICIT_MEAN, S_ERR, S_H, S_T, ZOH, next_step, step_copies,
                             step_error)
from .cosim_loop import (DELAY, DISTANCE_DIVERGED, DONE, EVENT_AWARE, FOH, FREE_STATE, FRESH, FULL, GAUSS_SEIDEL,
                         GET_STATE, IMPLICIT, NEED_D, NOT_CONVERGED, NOT_DELAYED, PIECES, PIECES_LAST, RECORD_EVERY,
                         ROW, SET_STATE, STATE_DIVERGED, STEPS, TOL, copy_rows, fail_at, fmu_states, record_row,
                         take_step, unmanaged)

depends_on_core(__file__, neighbours=True)   # its cache follows the core's edits and cosim_loop's (inlined)

__all__ = ["drive", "grid_step"]


@njit(cache=True, inline="always")
def _finite(q, u):
    for i in range(q.shape[0]):
        for c in range(q.shape[1]):
            if not (math.isfinite(q[i, c]) and math.isfinite(u[i, c])):
                return False
    return True


@njit(cache=True, inline="always")
def _reject(ctl, actl, ast, q, u, hist_tau, tau, keep, extra, hist, fresh, h_next):
    """A rejected step: the master's copies back (the instances are already back at t), retaken
    with the step ``h_next``."""
    actl[C_REJECTED] += 1
    step_copies(True, (q, u, hist_tau, tau), (keep.qs, keep.us, keep.hts, extra.taus), hist, keep.hs, ctl)
    ctl[FRESH] = fresh
    ast[S_H] = h_next


@njit(cache=True, inline="always")
def grid_step(k, flags, H, H_last, t_last):
    """The fixed grid's step k: (t, h, t_next, pieces, last), the last one landing on t_end."""
    last = k == flags[STEPS] - 1
    if last:
        return k * H, H_last, t_last, flags[PIECES_LAST], last
    return k * H, H, (k + 1) * H, flags[PIECES], last


@njit(cache=True, inline="always")
def _proposed(ast, unit, t_end):
    """The controller's step: (t, h, floor, last); at the floor (always accepted) a proposal of
    one unit or the short rest of the run, the test on the proposal, never on h stretched by a
    round-off to land on t_end (0.6.0 looped there)."""
    t = ast[S_T]
    h = ast[S_H]
    floor = h <= unit * (1.0 + TIME_TOL)
    last = lands(t, h, t_end, unit)
    if last:
        h = t_end - t
        floor = floor or h <= unit * (1.0 + TIME_TOL)
    return t, h, floor, last


@njit(cache=True, inline="always")
def _accepted(actl, ast, HS, ES, k, t, h, err, share, last, t_end, unit):
    """An accepted step's bookkeeping with tol; returns its end on the unit grid (whole units from
    0, as the slaves count their steps: no drift of t) or t_end."""
    if err > share:
        actl[C_FORCED] += 1
    HS[k] = h
    ES[k] = err
    ast[S_ERR] += err
    return t_end if last else unit * math.floor((t + h) / unit + 0.5)


@njit(cache=True, inline="always")
def _saved(fn, comp, extra, keep, q, u, hist_tau, tau, hist, ctl, FAIL, fail_t, t):
    """With tol, the step's start: the controller's FMU states (its own handles) and the master's
    copies; True on a failure."""
    if fmu_states(extra.pmine, fn, comp, FREE_STATE, extra.mine, FAIL, fail_t, t) or fmu_states(
            extra.pmine, fn, comp, GET_STATE, extra.mine, FAIL, fail_t, t):
        return True
    step_copies(False, (q, u, hist_tau, tau), (keep.qs, keep.us, keep.hts, extra.taus), hist, keep.hs, ctl)
    return False


@njit(cache=True, inline="always")
def _advance(ctl, ast, extra, tau, jacobi, t_next, h_next):
    """With tol, after an accepted step: the next step's forces are those of the estimate (Jacobi),
    the controller at t_next with the step h_next."""
    if jacobi and ctl[FRESH] == 0:
        copy_rows(extra.tau_end, tau)
        ctl[FRESH] = 1
    ast[S_T] = t_next
    ast[S_H] = h_next


@njit(cache=True)
def drive(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, H, H_last, t_last, ad, norm, budget, q, u, tau,
          tau_next, hist_tau, hist, imp, ctl, saved, keep, extra, ast, actl, T, Qr, Ur, TAU, D, BR, EU, HS, ES, w,
          FAIL, fail_t):
    """Up to ``budget`` tries of a communication step from ``actl[C_STEPS]`` accepted ones (the
    arguments of :class:`fmu_sync.cosim_args.LoopArgs`, :class:`fmu_sync.cosim_args.LoopState`, and
    the controller's: ``ad``, ``norm``, ``extra``, ``ast``, ``actl``, ``HS``, ``ES`` the accepted
    steps' lengths and estimates; used with ``flags[TOL]`` only). Returns DONE (finished if
    ``actl[C_DONE]``, else the budget is spent), FULL (with tol: the record or the step arrays are
    full; grow them and call again) or a failure (``FAIL``)."""
    (ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, q, u, tau, tau_next, hist_tau, hist, imp, ctl, saved, keep,
     extra, T, Qr, Ur, TAU, D, BR, EU, HS, ES, w, FAIL, fail_t) = unmanaged(
        (ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, q, u, tau, tau_next, hist_tau, hist, imp, ctl, saved,
         keep, extra, T, Qr, Ur, TAU, D, BR, EU, HS, ES, w, FAIL, fail_t))
    tol_on, implicit = flags[TOL] != 0, flags[IMPLICIT] != 0
    foh = flags[FOH] != 0 or implicit   # the implicit exchange is measured against its explicit prediction
    mean = implicit and flags[FOH] == 0   # the implicit exchange holding the mean of the step's end forces
    kind = (IMPLICIT_MEAN if mean else IMPLICIT_KIND) if implicit else FOH_KIND if foh else ZOH
    jacobi = flags[GAUSS_SEIDEL] == 0 and flags[DELAY] == NOT_DELAYED   # the record may compute tau
    retake = flags[EVENT_AWARE] != 0 and not tol_on
    tol, t_end, unit, H_max = ad[A_TOL], ad[A_T_END], ad[A_UNIT], ad[A_H]
    FAIL[0] = DONE
    retry = False   # the step being tried follows a rejection (the controller does not grow it)
    for _ in range(budget):
        if actl[C_DONE]:
            return DONE
        k, fresh, floor = actl[C_STEPS], ctl[FRESH], False
        if tol_on and (ctl[ROW] >= T.shape[0] or k >= HS.shape[0] or (implicit and k >= keep.iw.iters.shape[0])):
            return FULL
        err = eq = eu = em = 0.0
        if tol_on:
            t, h, floor, last = _proposed(ast, unit, t_end)
            t_next = t + h
            pieces = 1
            if _saved(fn, comp, extra, keep, q, u, hist_tau, tau, hist, ctl, FAIL, fail_t, t):   # (implicit: its own)
                return FAIL[0]
        else:   # the run's grid: k H, the last step landing on t_end
            t, h, t_next, pieces, last = grid_step(k, flags, H, H_last, t_last)
        if take_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, t, h, k, pieces, retake, q, u, tau,
                     tau_next, hist_tau, hist, imp, ctl, saved, keep, w, FAIL, fail_t):
            if not (tol_on and FAIL[0] == NOT_CONVERGED and not floor):
                return FAIL[0]
            FAIL[0] = DONE   # not converged (the slaves are back at t): retaken shorter, as a rejected step
            _reject(ctl, actl, ast, q, u, hist_tau, tau, keep, extra, hist, fresh,
                    unit * max(1.0, math.floor(FAC_MIN * h / unit + TIME_TOL)))
            retry = True
            continue
        if not _finite(q, u):
            fail_at(FAIL, fail_t, STATE_DIVERGED, -1, -1, 0, t_next)
            return FAIL[0]
        if tol_on:
            err, eq, eu, em = step_error(laws, geo, Kp, Kd, E2, W2, hp, q, u, tau, t, h, keep.hts, keep.hs, w, extra,
                                         norm, foh, mean, kind, unit)
            share = tol * h / t_end
            if err > share and not floor:   # rejected: every instance back to t, retaken shorter
                if fmu_states(extra.pmine, fn, comp, SET_STATE, extra.mine, FAIL, fail_t, t):
                    return FAIL[0]
                _reject(ctl, actl, ast, q, u, hist_tau, tau, keep, extra, hist, fresh,
                        next_step(h, eq, eu, tol, t_end, kind, unit, H_max, 2, em))
                retry = True
                continue
            t_next = _accepted(actl, ast, HS, ES, k, t, h, err, share, last, t_end, unit)
        actl[C_STEPS] = k + 1
        for i in range(q.shape[0]):
            imp[i] = keep.imp_new[i]
        if (k + 1) % flags[RECORD_EVERY] == 0 or last:   # the final state is always a row
            row = ctl[ROW]
            if not record_row(row, t_next, q, u, tau, laws, geo, Kp, Kd, E2, W2, flags[NEED_D] != 0, jacobi, ctl, T,
                              Qr, Ur, TAU, D, BR, EU, keep.scratch, w, hp):
                fail_at(FAIL, fail_t, DISTANCE_DIVERGED, -1, -1, 0, t_next)
                return FAIL[0]
            ctl[ROW] = row + 1
        if tol_on:
            _advance(ctl, ast, extra, tau, jacobi, t_next,
                     next_step(h, eq, eu, tol, t_end, kind, unit, H_max, 1 if retry else 0, em))
            retry = False
        if last:
            actl[C_DONE] = 1
            return DONE
    return DONE
