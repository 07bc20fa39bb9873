"""The time between two record rows of a scene's run, as summary.md and the data files say it
(:func:`record_interval`): one rule for the core, co-simulated pairs and networks, and runs to a tolerance."""
from __future__ import annotations

from .schema import Variant

__all__ = ["record_interval"]


def record_interval(variant: Variant) -> tuple[float, str]:
    """``(seconds, words)``: the time between two record rows of the variant's run.
    ``run.record_every`` counts steps of ``solver.dt`` in both modes; a co-simulation records at
    the nearest whole number of communication steps (:func:`fmu_sync.output.record_steps`); the
    summary and the data file say the interval as a time."""
    from ..output import record_steps, run_grid
    _, step, name = run_grid(variant.cfg)
    k, dt = int(variant.cfg["run.record_every"]), variant.cfg["solver.dt"]
    every = record_steps(variant.cfg)
    said = f"run.record_every = {k} step{'s' if k > 1 else ''} of solver.dt = {dt:g} s"
    if name != "solver.dt" and variant.cfg.get("run.tol") is not None:   # tol chooses the steps
        return every * step, (f"a row every {every} accepted step{'s' if every > 1 else ''} of the tolerance "
                              f"control, each between solver.dt = {dt:g} s and run.H = {step:g} s (the "
                              f"intervals as they were: in the run's notes)")
    if name != "solver.dt":
        said += f"; in co-simulation every {every} step{'s' if every > 1 else ''} of run.H = {step:g} s"
    return every * step, f"{every * step:g} s ({said})"
