"""Co-simulation to a tolerance (docs/design.md §4.4.1): :class:`AdaptiveMaster` is the
:class:`fmu_sync.master.NetworkMaster` run whose communication step is chosen by the compiled
controller of :mod:`fmu_sync.cosim_adaptive`; ``cosimulate(..., tol=T)`` and
``cosimulate_network(..., tol=T)`` make it.

What the result carries (``info``): ``steps`` (accepted communication steps), ``rejected``
(steps rolled back and retaken shorter), ``H`` (the accepted steps' lengths, an array, one
per step), ``H_first`` (the first and largest step), ``step_unit`` (the floor: the slaves'
solver.dt), ``tol``, ``error_estimate`` (the estimated global error: the sum of the accepted
steps' local estimates, in q's unit like tol), ``floor_steps`` (steps accepted at the floor
although their estimate exceeded their share: an impact accumulation, for example) and
``error_norm`` (the norm, in words). The record has a row every ``record_every`` accepted
steps and the final state.
"""
from __future__ import annotations

import math

import numpy as np

from . import cosim_adaptive as ad
from . import cosim_loop as loop
from .cosim_loop import CALLS
from .master import CHUNK_STEPS, NetworkMaster

__all__ = ["AdaptiveMaster", "check_tol", "ERROR_NORM"]

#: what tol and info["error_estimate"] measure (docs/design.md §4.4.1)
ERROR_NORM = ("q's unit: per node the state error (dq, du) in the law's metric, sqrt(dq' Q dq + du' M du) / "
              "sqrt(lambda_min(Q)) (one degree of freedom: sqrt(dq^2 + du^2 m/Q)), summed over the accepted "
              "steps, largest over the nodes")
_STATE_CALLS = ("fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate")


def check_tol(tol) -> float:
    """``tol``: a finite number > 0 (ValueError otherwise)."""
    if isinstance(tol, bool) or not isinstance(tol, (int, float, np.floating, np.integer)) or not (
            math.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a finite number > 0 (the co-simulation's error tolerance, in q's unit), "
                         f"got {tol!r}")
    return float(tol)


class AdaptiveMaster(NetworkMaster):
    """A co-simulation run to the tolerance ``tol``: ``H`` is the first and largest step."""

    def __init__(self, *args, tol, **kwargs):
        super().__init__(*args, **kwargs)
        self.tol = check_tol(tol)
        if self.event_aware:
            raise ValueError("tol and event_aware=True exclude each other: with tol a step in which an impact "
                             "counter moves is retaken shorter by the error control itself")
        if self.DELAY.get(self.method):
            raise ValueError(f"tol needs method 'jacobi' or 'gauss-seidel', got {self.method!r}")
        self.steps = self.rejected = self.forced = 0
        self.estimate = 0.0

    def plan(self, values, schemes):
        plan = super().plan(values, schemes)
        self.unit = max(plan.dts)   # the floor of the step: the slaves' own solver.dt
        if self.H < self.unit * (1 - 1e-9):
            raise ValueError(f"tol: H = {self.H:g} is below the slaves' solver.dt = {self.unit:g}, the "
                             f"smallest communication step with tol; H (the first and largest step) must be "
                             f">= solver.dt")
        return plan

    def _loop_arrays(self) -> None:
        super()._loop_arrays()
        if not getattr(self.md.coSimulation, "canGetAndSetFMUstate", False) or not np.all(
                self.fn[:, [CALLS.index(c) for c in _STATE_CALLS]]):
            raise ValueError(f"{self.fmu}: tol rolls rejected steps back with the FMU state, but the FMU does not "
                             f"declare canGetAndSetFMUstate (or its binary lacks {', '.join(_STATE_CALLS)})")
        flags = self.loop_args[9]
        flags[loop.EVENT_AWARE] = 1   # the slaves may be set back: noSetFMUStatePriorToCurrentPoint = false
        N, n = self.N, self.model.n
        M = np.atleast_2d(np.asarray(self.system.M, dtype=np.float64))
        Q = np.asarray(self.metric.Q, dtype=np.float64)
        Q = Q * np.eye(n) if Q.ndim == 0 else np.atleast_2d(Q)
        lam = float(np.linalg.eigvalsh(0.5 * (Q + Q.T)).min())
        self.norm = (np.linalg.inv(M), Q / lam, M / lam)
        self.ad = np.array([self.tol, self.grid.t_end, self.unit, self.H])
        self.ast = np.array([0.0, self.unit * max(1.0, math.floor(self.H / self.unit + 1e-9)), 0.0])
        self.actl = np.zeros(ad.ACTL, dtype=np.int64)
        self.mine = np.zeros(N, dtype=np.int64)   # the controller's FMU-state handles
        self.pmine = self.loop_args[0].copy()
        self.pmine[loop.P_SAVED] = self.mine.ctypes.data
        self.extra = (np.zeros((N, n)), np.zeros((N, n)), np.zeros(n), np.zeros(n), self.mine, self.pmine)
        cap = 2 * self.n_steps + 16
        self.HS, self.ES = np.full(cap, np.nan), np.full(cap, np.nan)
        self._implicit_room(cap)

    def _implicit_room(self, cap: int) -> None:
        """The implicit exchange's per-step arrays (iterations, residuals) for ``cap`` accepted steps."""
        if not self.implicit:
            return
        it, res = self.iw[-3], self.iw[-2]
        grown = (np.zeros(cap, dtype=np.int64), np.full(cap, np.nan))
        grown[0][:min(cap, it.size)], grown[1][:min(cap, res.size)] = it[:cap], res[:cap]
        self.iw = self.iw[:-3] + grown + self.iw[-1:]
        s = self.loop_state
        self.loop_state = s[:9] + (s[9][:7] + (self.iw,),) + s[10:]

    def _grow(self) -> None:
        """Twice the room for rows and steps (the number of steps is not known in advance)."""
        def grow(a, fill):
            b = np.full((2 * a.shape[0],) + a.shape[1:], fill, dtype=a.dtype)
            b[:a.shape[0]] = a
            return b
        self.T, self.Qr, self.Ur, self.TAU, self.D, self.EU = (
            grow(a, np.nan) for a in (self.T, self.Qr, self.Ur, self.TAU, self.D, self.EU))
        self.BR = grow(self.BR, -1)
        self.HS, self.ES = grow(self.HS, np.nan), grow(self.ES, np.nan)
        self._implicit_room(self.HS.size)

    def _adaptive(self, budget: int) -> int:
        s = self.loop_state   # (q, u, tau, tau_next, hist_tau, hist, imp, ctl, saved, keep, T...)
        code = ad.adaptive_chunk(*self.loop_args[:11], self.ad, self.norm, budget, *s[:10], self.extra, self.ast,
                                 self.actl, self.T, self.Qr, self.Ur, self.TAU, self.D, self.BR, self.EU, self.HS,
                                 self.ES, *s[17:])
        return int(code)

    def run(self, progress=None):
        failure = None
        with self.instances() as unzipdir:
            self._start(unzipdir)
            self._loop_arrays()
            try:
                code = self._chunk(-1, 0)   # the start: states, impact counters, row 0
                if code != loop.DONE:
                    raise self._failure(code)
                budget = 256 if progress is not None else CHUNK_STEPS
                while not self.actl[ad.C_DONE]:
                    code = self._adaptive(budget)
                    if code == ad.FULL:
                        self._grow()
                    elif code != loop.DONE:
                        failure = self._failure(code)
                        break
                    elif progress is not None:
                        progress(min(1.0, float(self.ast[ad.S_T]) / self.grid.t_end))
            finally:
                ad.free_states(self.pmine, self.fn, self.comp, self.mine, np.zeros(4, dtype=np.int64), np.zeros(1))
        self.steps, self.rejected = int(self.actl[ad.C_STEPS]), int(self.actl[ad.C_REJECTED])
        self.forced, self.estimate = int(self.actl[ad.C_FORCED]), float(self.ast[ad.S_ERR])
        return self.finish(int(self.ctl[loop.ROW]), [int(v) for v in self.imp], failure)

    def result(self, rows, impacts, error):
        res = super().result(rows, impacts, error)
        res.info.update(tol=self.tol, steps=self.steps, rejected=self.rejected, H=self.HS[:self.steps].copy(),
                        H_first=self.H, step_unit=self.unit, error_estimate=self.estimate,
                        floor_steps=self.forced, error_norm=ERROR_NORM)
        return res
