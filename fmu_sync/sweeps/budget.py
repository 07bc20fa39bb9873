"""The size of a sweep, estimated before anything is built, run or written.

A sweep is refused (:class:`SweepTooLarge`, a :class:`~fmu_sync.sweeps.spec.SweepSpecError`)
when its run count, its memory or its run time exceeds the budget:

* the run count of a grid is the product of the axis lengths, read from the
  specs without building them (``logspace(-1, 1, 1e9)`` is 1e9 runs, refused
  before any value exists);
* memory: :data:`RUN_BYTES` per run (the run's parameters, its row of metrics,
  the stored chunk and the Dataset; measured in tests/test_sweep_budget.py);
* time: steps per run (the longest ``run.t_end`` over the smallest step) over
  the engine's throughput (:data:`COMPILED_STEPS_PER_S` per thread for the
  compiled engine, :data:`PROCESS_STEPS_PER_S` per worker for co-simulated or
  n-DOF runs), an estimate of the order of magnitude, not a promise.
"""
from __future__ import annotations

import math
import re

from .spec import SweepSpecError

__all__ = ["SweepTooLarge", "SweepEstimate", "grid_size", "estimate_sweep", "check_sweep_budget",
           "RUN_BYTES", "DEFAULT_MAX_TIME", "DEFAULT_MAX_RUNS"]

#: bytes held per run while a sweep runs and is stored (upper estimate; measured 1.1-1.3 KiB)
RUN_BYTES = 2048
#: steps per second of one thread of the compiled 1-DOF pair engine (lower estimate)
COMPILED_STEPS_PER_S = 1.0e7
#: communication (or core) steps per second of one worker running a scene variant
PROCESS_STEPS_PER_S = 2.0e4
#: a sweep estimated to run longer than this is refused unless the budget is raised
DEFAULT_MAX_TIME = 24 * 3600.0
#: no sweep has more runs than this unless the budget is raised
DEFAULT_MAX_RUNS = 10_000_000

_SPACE = re.compile(r"^\s*(linspace|logspace)\s*\((.*)\)\s*$")


class SweepTooLarge(SweepSpecError):
    """The sweep exceeds its run-count, memory or time budget (refused before it starts)."""


def _axis_length(key: str, spec) -> int:
    """Values of one grid axis, without building them."""
    if isinstance(spec, str):
        m = _SPACE.match(spec)
        parts = [p.strip() for p in m.group(2).split(",")] if m else []
        try:
            n = float(parts[2]) if len(parts) == 3 else math.nan
        except ValueError:
            n = math.nan
        if math.isfinite(n) and n >= 1 and n == int(n):
            return int(n)
        return -1   # a list, a single value or a malformed spec: spec.parse_values reads (or refuses) it
    try:
        return len(spec) if not isinstance(spec, (str, bytes)) else 1
    except TypeError:
        return 1


def grid_size(grid: dict) -> int:
    """Number of runs of a full grid (product of the axis lengths), nothing allocated."""
    from .spec import parse_values
    total = 1
    for key, spec in grid.items():
        n = _axis_length(key, spec)
        total *= n if n >= 0 else len(parse_values(key, spec))
    return total


class SweepEstimate:
    """Runs, memory (bytes) and time (s) of a sweep, estimated before it runs."""

    def __init__(self, runs: int, steps: int = 0, compiled: bool = True, threads: int = 1, workers: int = 1):
        self.runs, self.steps, self.compiled = int(runs), int(steps), compiled
        self.memory = float(runs) * RUN_BYTES
        rate = COMPILED_STEPS_PER_S * max(threads, 1) if compiled else PROCESS_STEPS_PER_S * max(workers, 1)
        self.time = float(runs) * float(steps) / rate

    def describe(self) -> str:
        from ..output import format_size
        steps = f" x {self.steps:.3g} steps" if self.steps else ""
        t = f", about {_duration(self.time)}" if self.steps else ""
        return f"{self.runs:.4g} runs{steps}: {format_size(self.memory)} of memory{t}"


def _duration(s: float) -> str:
    for unit, f in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if s >= f:
            return f"{s / f:.3g} {unit}"
    return f"{s:.2g} s"


def estimate_sweep(runs: int, scene_cfg: dict | None = None, swept: dict | None = None, compiled: bool = True,
                   threads: int = 1, workers: int = 1) -> SweepEstimate:
    """The estimate of ``runs`` runs of a scene variant (``scene_cfg``: its settings);
    ``swept``: the swept values of run.t_end / solver.dt / run.H, if any (the worst case is used)."""
    if scene_cfg is None:
        return SweepEstimate(runs)
    swept = swept or {}
    cosim = scene_cfg.get("run.mode") == "cosim"
    step_key = "run.H" if cosim else "solver.dt"

    def numbers(key, default):
        vals = [v for v in swept.get(key, []) if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0]
        return vals or [default]
    t_end = max(numbers("run.t_end", float(scene_cfg["run.t_end"])))
    step = min(numbers(step_key, float(scene_cfg[step_key])))
    from ..core.checks import run_steps   # the one grid rule (whole steps, a short last one)
    steps = run_steps(t_end, step).steps
    return SweepEstimate(runs, steps, compiled and not cosim, threads, workers)


def check_sweep_budget(est: SweepEstimate, max_memory: float, max_time: float | None = DEFAULT_MAX_TIME,
                       max_runs: int = DEFAULT_MAX_RUNS) -> SweepEstimate:
    """Refuse a sweep above its budget (:class:`SweepTooLarge`), naming the estimate."""
    from ..output import format_size
    why = []
    if est.runs > max_runs:
        why.append(f"{est.runs:.4g} runs > {max_runs:.4g}")
    if est.memory > max_memory:
        why.append(f"memory {format_size(est.memory)} > budget {format_size(max_memory)} (--max-memory)")
    if max_time is not None and est.time > max_time:
        why.append(f"estimated time {_duration(est.time)} > budget {_duration(max_time)} (--max-time)")
    if why:
        raise SweepTooLarge(f"sweep refused before running: {'; '.join(why)}. Estimate: {est.describe()}. "
                            "Use fewer values per axis or fewer samples, a shorter run.t_end or a larger "
                            "step, or raise the budget.")
    return est
