"""Work–precision: error against run time for every solver on the built-in scenes (docs/design.md §4.7; `fmu-sync report work-precision`).

Methods (``method`` column of ``work_precision.csv``; ``step`` is the method's own knob):

============== ===============================================================  ==========
method         what runs                                                        step
============== ===============================================================  ==========
midpoint       core ``simulate`` / ``simulate_pair``, Moreau midpoint           dt
theta0.5       core, Moreau–Jean θ = 0.5                                        dt
theta1         core, Moreau–Jean θ = 1                                          dt
trapezoid      core, θ = 0.5 with a pair's coupling inside the step (its        dt
               trapezoid, docs/design.md §2.3)
exact          core/exact.py, event-driven closed form, sampled every 1 ms      (1e-3)
solve_ivp      ``scipy.integrate.solve_ivp`` RK45 with a terminal g = 0 event,  rtol
               restart with u -> -e u, Zeno guard (see :func:`ivp_impacts`)
cosim          FMU + master (fmpy), Jacobi, slave's internal dt = H             H
cosim-ea       same, ``event_aware=True`` (impact steps retaken in H/16)        H
cosim-fine     coupled pair only: slave dt = 1e-4 (coupling error alone)        H
cosim-fine-ea  same, event-aware                                                H
cosim-fine-    same, ``exchange="implicit"``, ``hold="foh"`` (each step iterated  H
implicit       to its end states with FMU-state rollback)
============== ===============================================================  ==========

Errors (``metric`` column), all absolute, SI units:

* ``max_q``: max over the method's output times of |q - q_exact(t)| (exact: core/exact.py
  evaluated at the same times);
* ``rest_time`` (bouncing ball): |t_rest - t_inf|, ``t_inf = t1 + 2 e v1 / (g (1 - e))`` in
  closed form; t_rest is the first output time after which |u| <= 1e-6 v1 for good (the
  exact solver and solve_ivp report theirs directly);
* ``d`` (forced pair, coupled pair, switching coupling Kp = 1, Kd = 0.5): max over a
  10 ms grid of |d - d_ref|, the reference being ``simulate_pair`` (midpoint) at a much finer
  dt — the exact solver does not apply to a coupled pair (the coupling force depends on
  both states), so this reference is labelled in the ``reference`` column.

Timing: every configuration is warmed up (compiled / cache loaded, FMU instantiated once)
before it is timed; repeats are interleaved (all configurations once, then again), the
figure is the median and ``spread`` = (max - min) / median of the repeats. Long runs are
repeated fewer times (``repeats`` column). Error evaluation is never timed.
"""

from __future__ import annotations

import time


from .ivp_baseline import ivp_impacts  # noqa: F401
from .work_precision_cases import (METHOD_DOC, SCENES, Point, Case, WorkPrecision,  # noqa: F401
                                   closed_form_rest_time, measure, rest_time_of)
from .work_precision_report import measured_order, report, write_csv  # noqa: F401

__all__ = ["SCENES", "Case", "Point", "WorkPrecision", "run", "ivp_impacts", "METHOD_DOC",
           "measured_order", "rest_time_of", "closed_form_rest_time", "write_csv"]


def run(quick: bool = False, fmu=None, progress=None, smoke: bool = False) -> WorkPrecision:
    """Measure every configuration; return the points, the markdown section and the findings."""
    mode = "smoke" if smoke else ("quick" if quick else "full")
    t0 = time.perf_counter()
    points = measure(mode, fmu=fmu, progress=progress)
    seconds = time.perf_counter() - t0
    md, findings = report(points, mode, seconds)
    return WorkPrecision(points, md, findings, quick, seconds)
