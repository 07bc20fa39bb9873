"""The errors of a run (docs/design.md §5.1, the failure convention).

* Bad input (a value out of its domain, an inconsistent system, a scheme known
  to diverge for this step) raises a :class:`ValueError` (or a subclass) before
  anything runs, naming the argument, its value and what is allowed.
  (:class:`SimulationDiverged` raised up front by the midpoint stability check
  is the one run-time error known in advance; it is raised before the run too.)
* A run that fails mid-way raises a :class:`RunFailed`; its ``partial``
  attribute holds the result recorded up to the failure (``partial.success``
  is False, ``partial.message`` says what happened), or None where no record
  exists (the single-system driver records nothing of a diverged state).
"""
from __future__ import annotations

__all__ = ["RunFailed", "SimulationDiverged"]


class RunFailed(RuntimeError):
    """A run stopped before its end; ``partial`` holds the records up to the failure."""

    def __init__(self, message: str, partial=None):
        super().__init__(message)
        self.partial = partial


class SimulationDiverged(RunFailed):
    """The state became non-finite: the scheme is unstable for this step size."""
