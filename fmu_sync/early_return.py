"""FMI 3.0 early return as an exchange strategy of the co-simulation master (docs/fmi3.md).

The event-aware retake of the compiled loop (:mod:`fmu_sync.cosim_loop`) notices an
impact after the step (an impact counter moved), restores every instance and retakes
the whole step in pieces of ``H_min``: the coupling forces are exchanged every
``H_min`` around the impact, never *at* it. With FMI 3.0 the FMU says where the
impact is: each instance steps with early return allowed and stops at its first
impact; the master takes the earliest stop t*, brings every other instance to t*
(restoring its saved state and stepping it to t*), lets the stopped ones handle
the impact in event mode, exchanges the coupling forces at t* from the
post-impact states, and continues the step from t*. Between impacts the exchange
is the Jacobi exchange (zero-order hold), every H.

The compiled loop calls FMI 2.0 functions; this driver runs its own exchange in
Python over FMI 3.0 instances (:class:`fmu_sync.fmi3_bridge.FMU3Host` through
:func:`fmu_sync.master.open_instance`), with the coupling law of the core
(:func:`fmu_sync.core.network.network_forces`, the function the compiled loop and
``integrate_network`` call). The arguments, the set-up checks, the record and the
failures are those of :class:`fmu_sync.master.NetworkMaster`.

:class:`EarlyReturnMaster` is the strategy ``"early-return"`` of the registry
(:mod:`fmu_sync.strategies`), selected by ``cosimulate(..., method="early-return")`` or
``cosimulate_network``; :func:`cosimulate_early_return` is an alias of the first. The instances are FMI 3.0 instances of
an fmu-sync FMU (``fmu-sync export --fmi-version 3``).
"""
from __future__ import annotations

import numpy as np

from .core.coupling import chain_work
from .core.network import edge_arrays, network_forces
from .core.result import NetworkResult, PairResult
from .fmus import contract
from .cosim_args import Work, named_flags
from .cosim_driver import grid_step
from .cosim_loop import CTL, record_row
from .master import NetworkMaster, SlaveError, cosimulate

__all__ = ["EarlyReturnMaster", "cosimulate_early_return"]


class EarlyReturnMaster(NetworkMaster):
    """:class:`NetworkMaster` over FMI 3.0 instances whose steps stop at every impact
    (early return) and exchange the coupling forces there; Jacobi exchange, zero-order hold."""

    EARLY_RETURN = True

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)   # method='early-return': the registry's checks (fmu_sync.strategies)
        self.early_stops, self.imp, self.stop_times = 0, [0] * self.N, []

    # ------------------------------------------------------------ the exchange
    def _arrays(self) -> None:
        N, n, E = self.N, self.model.n, len(self.edges)
        self.E2, self.W2 = edge_arrays(self.A, self.edges)
        self.q, self.u, self.tau, self.scratch = (np.zeros((N, n)) for _ in range(4))
        self.work = (np.zeros(n), np.zeros(n), *chain_work(n))
        self.dk, self.bk, self.ek = np.zeros(E), np.zeros(E, dtype=np.int64), np.zeros(E)
        # the compiled driver's grid and record (cosim_driver.grid_step, cosim_loop.record_row)
        self.w = Work(*self.work, self.dk, self.bk, self.ek, np.zeros(2 * n), np.zeros(n))
        self.flags = named_flags(steps=self.n_steps, record_every=self.record_every, need_d=self.need_d)
        self.ctl = np.zeros(CTL, dtype=np.int64)

    def forces(self, tau, need_d: bool, t: float) -> None:
        """The Jacobi forces at the current states (time t) into ``tau`` (and each edge's distance)."""
        network_forces(self.laws, self.geo, self.Kp_m, self.Kd_m, self.E2, self.W2, self.q, self.u, tau,
                       *self.work, need_d, self.dk, self.bk, self.ek, self.hp, float(t))

    def read(self) -> None:
        n = self.model.n
        for i, s in enumerate(self.slaves):
            v = s.get(self.model.q + self.model.u)
            self.q[i], self.u[i] = v[:n], v[n:]

    def give(self, tc: float, h: float) -> None:
        for i, s in enumerate(self.slaves):
            s.set(dict(zip(self.model.tau, self.tau[i])))
            s.do_step(tc, h)

    def communication_step(self, t: float, end: float) -> None:
        """[t, end] (end = t + H, or t_end for the run's last step), stopping at every impact: all
        instances brought to the earliest stop, the impact handled in event mode, the forces
        exchanged there."""
        tc = t
        while True:
            if self.coupled:
                self.forces(self.tau, False, tc)
                for i in range(self.N):
                    if not np.all(np.abs(self.tau[i]) <= contract.INPUT_BOUND):   # also catches NaN
                        raise self.force_bound(i, tc)
            saved, done = [s.save() for s in self.slaves], False
            try:
                self.give(tc, end - tc)
                stops = [s.last_time if s.early_return else end for s in self.slaves]
                t_star = min(stops)
                if t_star < end:
                    if not t_star > tc:
                        i = stops.index(t_star)
                        raise SlaveError(self.slaves[i].name, tc, "fmi3DoStep", 3, [
                            f"returned early at lastSuccessfulTime = {t_star!r} without advancing from {tc!r}"])
                    self.early_stops += 1
                    self.stop_times.append(t_star)
                    for i, (s, st) in enumerate(zip(self.slaves, saved)):
                        if stops[i] > t_star:      # past the impact of another one: back to t*
                            s.restore(st, tc)
                            s.set(dict(zip(self.model.tau, self.tau[i])))
                            s.do_step(tc, t_star - tc)
                    for s in self.slaves:
                        s.t = t_star
                        if s.event_needed:
                            s.handle_event()      # a failed call raises SlaveError
                done = True
            finally:
                for s, st in zip(self.slaves, saved):
                    try:
                        s.free_state(st)
                    except SlaveError:
                        if done:     # otherwise the failure that got us here is the one to report
                            raise
            self.read()
            if t_star >= end:
                self.imp = [s.get_integer(contract.IMPACTS) for s in self.slaves]
                return
            tc = t_star

    def record(self, row: int, t: float) -> bool:
        """Row ``row`` at t: states, the inputs held over the step that ended here, distances;
        False if a distance is not finite (the compiled driver's record, :func:`fmu_sync.cosim_loop.record_row`)."""
        return bool(record_row(row, float(t), self.q, self.u, self.tau, self.laws, self.geo, self.Kp_m, self.Kd_m,
                               self.E2, self.W2, self.need_d, False, self.ctl, self.T, self.Qr, self.Ur, self.TAU,
                               self.D, self.BR, self.EU, self.scratch, self.w, self.hp))

    def run(self, progress=None) -> NetworkResult:
        """Run to t_end (failures as :meth:`NetworkMaster.run`: ``partial`` holds the record so far)."""
        failure, row = None, 0
        with self.instances() as unzipdir:
            self._start(unzipdir)
            self._arrays()
            self.read()
            self.imp = [s.get_integer(contract.IMPACTS) for s in self.slaves]
            if self.coupled:
                self.forces(self.tau, False, 0.0)
            n_steps, last = self.n_steps, self.n_steps - 1
            g = (self.flags, self.H, self.grid.dt_last, self.grid.t_end)
            if self.record(0, 0.0):
                row = 1
            else:
                failure, n_steps = self.diverged(0.0, "a distance"), 0
            report_every = max(1, n_steps // 200)
            for k in range(n_steps):
                # the driver's grid (core.checks.run_steps): the last step lands on t_end exactly
                t0, _, t, _, _ = grid_step(k, *g)
                try:
                    self.communication_step(t0, t)
                except SlaveError as exc:
                    failure = exc
                    break
                if not (np.all(np.isfinite(self.q)) and np.all(np.isfinite(self.u))):
                    failure = self.diverged(t, "a state")
                    break
                if (k + 1) % self.record_every == 0 or k == last:   # the final state is always a row
                    if not self.record(row, t):
                        failure = self.diverged(t, "a distance")
                        break
                    row += 1
                if progress is not None and (k + 1) % report_every == 0:
                    progress((k + 1) / n_steps)
            if progress is not None and failure is None:
                progress(1.0)
        return self.finish(row, list(self.imp), failure)

    def result(self, rows: int, impacts: list, error: str | None) -> NetworkResult:
        r = super().result(rows, impacts, error)
        r.info.update(method="early-return", early_stops=self.early_stops, stop_times=list(self.stop_times))
        return r


def cosimulate_early_return(fmu, x1, x2, t_end: float, H: float, coupling: str | None = None, Kp=0.0, Kd=0.0,
                            Q=None, record_every: int = 1, start_values=None, progress=None,
                            record_distance: bool = True, allow_unstable: bool = False) -> PairResult:
    """:func:`fmu_sync.master.cosimulate` of an FMI 3.0 FMU with ``method="early-return"`` (an
    alias): the coupling forces are also exchanged at every impact instant."""
    return cosimulate(fmu, x1, x2, t_end, H, coupling, Kp, Kd, Q, method="early-return", record_every=record_every,
                      start_values=start_values, progress=progress, record_distance=record_distance,
                      allow_unstable=allow_unstable)
