"""FMI 3.0 early return as an exchange strategy of the co-simulation master (docs/fmi3.md).

The event-aware retake of :class:`fmu_sync.master.NetworkMaster` notices an impact
after the step (an impact counter moved), restores every instance and retakes the
whole step in pieces of ``H_min``: the coupling forces are exchanged every
``H_min`` around the impact, never *at* it. With FMI 3.0 the FMU says where the
impact is: each instance steps with early return allowed and stops at its first
impact; the master takes the earliest stop t*, brings every other instance to t*
(restoring its saved state and stepping it to t*), lets the stopped ones handle
the impact in event mode, exchanges the coupling forces at t* from the
post-impact states, and continues the step from t*. Between impacts the exchange
is the Jacobi exchange of :meth:`NetworkMaster.step_jacobi`, every H.

:func:`cosimulate_early_return` is the pair entry point (a two-node graph);
:class:`EarlyReturnMaster` the strategy. The instances are FMI 3.0 instances of
an fmu-sync FMU (``fmu-sync export --fmi-version 3``).
"""
from __future__ import annotations

from .core.errors import RunFailed
from .core.result import NetworkResult, PairResult
from .fmus import contract
from .master import NetworkMaster, SlaveError, pair_result

__all__ = ["EarlyReturnMaster", "cosimulate_early_return"]


class EarlyReturnMaster(NetworkMaster):
    """:class:`NetworkMaster` whose steps stop at every impact (FMI 3.0 early return)
    and exchange the coupling forces there; Jacobi exchange, zero-order hold."""

    METHODS = ("jacobi",)
    EARLY_RETURN = True

    def __init__(self, fmu, states, A, t_end: float, H: float, coupling: str | None = "switching",
                 Kp=0.0, Kd=0.0, Q=None, record_every: int = 1, start_values=None,
                 record_distance: bool = True, allow_unstable: bool = False):
        super().__init__(fmu, states, A, t_end, H, coupling, Kp, Kd, Q, "jacobi", record_every, False, None,
                         start_values, record_distance, allow_unstable, "zoh")
        cs = self.md.coSimulation
        if self.md.fmiVersion != "3.0" or cs is None or not cs.mightReturnEarlyFromDoStep:
            raise ValueError(f"the early-return exchange needs an FMI 3.0 co-simulation FMU that may return early "
                             f"(mightReturnEarlyFromDoStep = true); {self.fmu} is FMI {self.md.fmiVersion}"
                             + ("" if self.md.fmiVersion != "3.0" else " without early return")
                             + ": export it with fmu-sync export --fmi-version 3, or use event_aware=True")
        self.early_stops = 0

    def communication_step(self, t: float, x, impacts: list) -> tuple[list, list]:
        """[t, t + H], stopping at every impact: all instances brought to the earliest
        stop, the impact handled in event mode, the forces exchanged there."""
        end = t + self.H
        tc = t
        while True:
            saved = [s.save() for s in self.slaves]
            self.inputs(x)
            for i in range(self.N):
                self.check_forces(i, tc, end - tc)
            for i, s in enumerate(self.slaves):
                s.set(dict(zip(self.model.tau, self.tau[i])))
                s.do_step(tc, end - tc)
                s.t = s.host.last_time if s.host.early_return else end
            t_star = min(s.t for s in self.slaves)
            if t_star < end:
                self.early_stops += 1
                for i, (s, st) in enumerate(zip(self.slaves, saved)):
                    if s.t > t_star:      # past the impact of another one: back to t*
                        s.restore(st, tc)
                        s.set(dict(zip(self.model.tau, self.tau[i])))
                        s.do_step(tc, t_star - tc)
                        s.t = t_star
                for s in self.slaves:
                    if s.host.event_needed:
                        st = s.host.handle_event()
                        if st > 1:
                            raise SlaveError(s.name, s.t, "fmi3UpdateDiscreteStates", st, s.host.errors(1))
            for s, st in zip(self.slaves, saved):
                s.free_state(st)
            self.history.remember(self.tau, tc)
            x = [self.read(s) for s in self.slaves]
            if t_star >= end:
                return x, [s.get_integer(contract.IMPACTS) for s in self.slaves]
            tc = t_star

    def result(self, rows: int, impacts: list, error: str | None) -> NetworkResult:
        r = super().result(rows, impacts, error)
        r.info.update(method="early-return", early_stops=self.early_stops)
        return r


def cosimulate_early_return(fmu, x1, x2, t_end: float, H: float, coupling: str | None = None, Kp=0.0, Kd=0.0,
                            Q=None, record_every: int = 1, start_values=None, progress=None,
                            record_distance: bool = True, allow_unstable: bool = False) -> PairResult:
    """:func:`fmu_sync.master.cosimulate` of an FMI 3.0 FMU with the early-return
    exchange: the coupling forces are also exchanged at every impact instant."""
    try:
        r = EarlyReturnMaster(fmu, [x1, x2], [[0.0, 1.0], [1.0, 0.0]], t_end, H, coupling, Kp, Kd, Q, record_every,
                              start_values, record_distance, allow_unstable).run(progress)
    except RunFailed as exc:
        if exc.partial is not None:
            exc.partial = pair_result(exc.partial, coupling)
        raise
    return pair_result(r, coupling)
