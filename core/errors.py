"""The errors of a run (docs/design.md §5.1, the failure convention).

* Bad input (a value out of its domain, an inconsistent system, a scheme known
  to diverge for this step) raises a :class:`ValueError` (or a subclass with its
  own type, all :class:`RunRefused`: :class:`UnstableScheme`, ``UnstableExchange``,
  ``RecordTooLarge``, ``InadmissibleState``) before anything runs, naming the argument,
  its value and what is allowed; the checks are made once, by the run plan
  (:func:`fmu_sync.core.plan.plan_run`, docs/design.md §5.1.1). Callers tell refusals apart
  by type, never by message text.
* A run that fails mid-way raises a :class:`RunFailed`; its ``partial``
  attribute holds the result recorded up to the failure (``partial.success``
  is False, ``partial.message`` says what happened), or None where no record
  exists.
* A user force law that raises mid-run ends the run as a :class:`ForceLawFailed` (a
  RunFailed) with the law's own message, the time and the state of the failing step, and the
  record up to the last good step in ``partial``; one that returns a non-finite force ends it as
  a :class:`SimulationDiverged` whose message names the law (:mod:`fmu_sync.core.failure`).
"""
from __future__ import annotations

__all__ = ["RunFailed", "SimulationDiverged", "ToleranceNotMet", "ExchangeNotConverged", "ForceLawFailed", "RunRefused", "UnstableScheme",
           "LawRefused"]


class RunFailed(RuntimeError):
    """A run stopped before its end; ``partial`` holds the records up to the failure."""

    def __init__(self, message: str, partial=None):
        super().__init__(message)
        self.partial = partial


class SimulationDiverged(RunFailed):
    """The state became non-finite: the scheme is unstable for this step size."""


class ToleranceNotMet(UserWarning):
    """A co-simulation to a tolerance ended without meeting it (``info["tol_met"]`` False): the
    message says why (steps at the floor H = solver.dt over their share, the slaves' own error at
    solver.dt, impacts); the record is complete (docs/design.md §4.4.1)."""


class ExchangeNotConverged(RunFailed):
    """The implicit exchange of a co-simulation step did not converge within its iteration cap
    (docs/design.md §4.4): the step is not accepted; the record ends at the step's start."""


class ForceLawFailed(RunFailed):
    """A user force law raised an exception mid-run; the message carries the law's name, its own
    message, the time and the state of the step; ``partial`` the record up to the last good step."""


class RunRefused(ValueError):
    """A run refused before its first step by the run plan (:func:`fmu_sync.core.plan.plan_run`);
    each reason is a subclass of its own."""


class UnstableScheme(RunRefused):
    """Refused before the first step: the explicit midpoint scheme diverges for
    omega_max*dt >= 2 (:func:`fmu_sync.core.checks.check_stable`)."""


class LawRefused(RunRefused):
    """Refused before the first step: a user force law (:class:`fmu_sync.core.forcelaw.ForceLaw`)
    that numba cannot compile, that returns the wrong shape or non-finite values, or a
    parameter outside its declared range; the message names the law and the offending value."""
