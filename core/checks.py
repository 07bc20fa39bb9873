"""Checks of run arguments and the messages of a failed run, shared by every
driver (single system, exact solver, pair, co-simulation master, FMU slave)."""
from __future__ import annotations

import math
import os
from typing import NamedTuple

import numpy as np
from .jit import njit

from .errors import LawRefused, RunRefused, UnstableScheme
from .model import MechanicalSystem

__all__ = ["check_step", "check_run", "n_steps", "RunSteps", "run_steps", "record_rows", "record_times",
           "check_record_size", "RecordTooLarge", "StepTooLarge", "record_budget", "GAP_TOL", "InadmissibleState",
           "check_admissible", "penetration_bound", "scheme_code", "check_stable", "coupling_omega",
           "divergence_message", "check_start", "TIME_TOL", "steps_in", "lands", "land_last_row"]

#: two times closer than this fraction of a step are one time: a round-off, never a step of its own
#: (the one rule of :func:`steps_in` and :func:`lands`: run grids, the tolerance controller's last
#: step, the early-return master; docs/design.md §5.1)
TIME_TOL = 1e-9


@njit(cache=True, inline="always")
def steps_in(span, step):
    """``(k, short)``: ``span`` holds ``k`` whole steps of ``step`` and, if ``short``, a shorter
    one more; a rest within :data:`TIME_TOL` of a step (either side) is a round-off, not a step."""
    r = span / step
    k = math.floor(r + TIME_TOL)
    return int(k), r - k > TIME_TOL


@njit(cache=True, inline="always")
def lands(t, h, t_end, step):
    """A step of length ``h`` from ``t`` lands on ``t_end``: it reaches it, or falls short by a
    round-off (:data:`TIME_TOL` of ``step``); the step is then ``t_end - t`` and ends at t_end."""
    return t + h >= t_end - TIME_TOL * step


def check_step(dt, name: str = "dt") -> float:
    """A positive finite step size (ValueError otherwise)."""
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive real number, got {dt!r}") from None
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f"{name} must be a positive finite step, got {dt}")
    return dt


def n_steps(t_end: float, dt: float, t0: float = 0.0) -> int:
    """The number of steps of a run: ceil((t_end - t0)/dt), up to TIME_TOL of a step
    (a run ends exactly at t_end, its last step shortened: :func:`run_steps`)."""
    return run_steps(t_end, dt, t0)[0]


class RunSteps(NamedTuple):
    """The step grid of a run (docs/design.md §5.1): ``steps`` steps, all of length
    ``dt`` but the last, of length ``dt_last``, so that the run ends exactly at
    ``t_end``. ``dt_last == dt`` (bit for bit) when ``t_end - t0`` is a multiple of
    ``dt`` (up to :data:`TIME_TOL` of a step); the grid is then the plain ``t0 + k dt``, its
    last time ``t_end`` itself (never ``t0 + k dt`` a round-off beside it: ``run_steps(0.7, 0.1)``
    ends at 0.7, not 0.7000000000000001)."""

    dt: float
    steps: int
    dt_last: float
    t_end: float

    @property
    def short(self) -> bool:
        """The last step is shortened to land on t_end."""
        return self.dt_last != self.dt


def run_steps(t_end, dt: float, t0: float = 0.0) -> RunSteps:
    """``RunSteps`` of a run over ``[t0, t_end]`` with step ``dt`` (checked positive)."""
    t_end = float(t_end)
    t0 = float(t0)
    if not (math.isfinite(t_end) and t_end >= t0):
        raise ValueError(f"t_end must be finite and >= {t0}, got {t_end}")
    k, short = steps_in(t_end - t0, dt)
    base = t0 + k * dt             # the kernels' time of step k
    if short and t_end - base > TIME_TOL * dt:   # the rest judged on the step it gives, too: a
        return RunSteps(dt, k + 1, t_end - base, t_end)   # ratio a hair over TIME_TOL can leave less
    return RunSteps(dt, k, dt, t_end)   # t_end itself, not t0 + k dt a round-off beside it


def record_rows(steps: int, record_every: int) -> int:
    """Rows of a record: row 0 (the start), one every ``record_every`` steps, and the
    final state (also when ``record_every`` does not divide ``steps``)."""
    return -(-int(steps) // int(record_every)) + 1


def record_times(grid: RunSteps, record_every: int, t0: float = 0.0) -> np.ndarray:
    """The times of the record rows of :func:`record_rows` (the kernels' ``t0 + k dt``,
    the last row at the end of the run)."""
    rows = record_rows(grid.steps, record_every)
    T = t0 + (np.arange(rows, dtype=np.float64) * record_every) * grid.dt
    T[-1] = grid.t_end
    return T


def land_last_row(T, written: int, grid: RunSteps) -> None:
    """The final row of a finished run at t_end itself: the kernels write ``t0 + k dt`` (and
    ``+ dt_last``), which may lie a round-off beside it (0.7 / 0.1: 0.7000000000000001)."""
    if written > 0:
        T[written - 1] = grid.t_end


class RecordTooLarge(RunRefused):
    """A record that cannot be held in memory, refused before anything is allocated."""


def record_budget() -> int:
    """Bytes a record may take in the Python API: the machine's physical memory
    (``os.sysconf``), or 8 GiB where that is unknown."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 8 * 1024**3


def check_record_size(rows: int, values_per_row: int, what: str = "the record", hint: str = "") -> None:
    """Refuse (:class:`RecordTooLarge`) a record of ``rows`` x ``values_per_row`` float64
    above :func:`record_budget`, naming its size, before anything is allocated."""
    size = 8.0 * float(rows) * float(values_per_row)
    budget = record_budget()
    if size > budget:
        raise RecordTooLarge(
            f"{what} would need {rows:.4g} rows x {values_per_row} values = {size / 1024**3:.4g} GiB, more "
            f"than this machine's memory ({budget / 1024**3:.3g} GiB); raise record_every (rows = "
            f"ceil(steps / record_every) + 1), shorten t_end or enlarge the step{hint}")


def check_run(t_end, dt, record_every=1, t0: float = 0.0, dt_name: str = "dt") -> tuple[RunSteps, int]:
    """The run arguments of every driver: returns ``(grid, record_every)``.

    ``dt`` (the step, or the communication step ``H`` with ``dt_name="H"``) must
    be positive and finite, ``t_end`` finite and >= ``t0``, ``record_every`` >= 1.
    ``grid`` (:class:`RunSteps`) ends exactly at ``t_end``.
    """
    dt = check_step(dt, dt_name)
    try:
        record_every = int(record_every)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"record_every must be an integer >= 1, got {record_every!r}") from None
    if record_every < 1:
        raise ValueError(f"record_every must be >= 1, got {record_every}")
    grid = run_steps(t_end, dt, t0)
    span = grid.t_end - float(t0)
    if span > 0.0 and dt >= span:
        raise StepTooLarge(
            f"{dt_name} = {dt:g} s is not shorter than the run (t_end - t0 = {span:g} s): one step tests the wall "
            f"once, at its midpoint, and can end deep inside it (a falling ball at q = -3.9 m); choose {dt_name} "
            f"< {span:g} s, a small fraction of the motion's time scale")
    return grid, record_every


class StepTooLarge(RunRefused):
    """A step not shorter than the run itself (``dt >= t_end - t0``): a single step tests the
    wall once, at its midpoint, and may end deep inside it; refused by every driver through
    :func:`check_run` (the run plan, step 2: core and co-simulation alike)."""


@njit(cache=True)
def penetration_bound(dt: float, speed: float, acc: float = 0.0) -> float:
    """How deep inside the wall (-g) a state the Moreau scheme produced can be: the one rule of
    a state's admissibility (docs/design.md §5.1.1), g(q) >= -penetration_bound(...).

    A contact step (midpoint or theta scheme) starts from a state the previous step left
    at g >= -dt |w^T u-| / 2 and tests the wall once, at its midpoint (theta point), so it
    ends at most dt |w^T u-| inside the wall, u- the normal velocity entering it, plus
    dt^2 |w^T M^-1 h| of the force over the step; ``speed`` bounds |w^T u-| (the caller's
    estimate, e.g. sqrt(W u^T M u) >= |w^T u|), ``acc`` bounds |w^T M^-1 h|. Twice that is
    allowed: 2 (dt speed + dt^2 acc). A start state has had no step: dt = 0, bound 0
    (:func:`check_start`). Compiled (numba) so the coupling FMU's stepper applies the same rule.
    """
    return 2.0 * (dt * speed + dt * dt * acc)


def check_start(system: MechanicalSystem, q, name: str = "x0") -> None:
    """Refuse (:class:`InadmissibleState`) a start position outside the admissible set g(q) >= 0
    (step 4 of the run plan, :func:`fmu_sync.core.plan.plan_run`): the admissibility rule
    g >= -:func:`penetration_bound` with no step taken yet (bound 0)."""
    g = system.gap(q)
    if not g >= -penetration_bound(0.0, 0.0):
        raise InadmissibleState(f"{name} violates the constraint: g(q) = {g:.6g} < 0 (need g >= 0)")


#: Relative tolerance of :func:`check_admissible`: a state is inside the wall when
#: g(q) < -GAP_TOL * max(1, |g0|, |w|^T |q|) (round-off of a state on the wall passes).
GAP_TOL = 1e-9


class InadmissibleState(RunRefused):
    """A state inside the wall (g(q) < 0 beyond :data:`GAP_TOL`)."""


def check_admissible(w, g0: float, q, name: str = "x") -> None:
    """Refuse (:class:`InadmissibleState`) a position inside the wall: the quotient
    distance is defined on the admissible set g(q) = w^T q + g0 >= 0 only."""
    w = np.asarray(w, dtype=np.float64).reshape(-1)
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    g = float(w @ q + g0)
    tol = GAP_TOL * max(1.0, abs(float(g0)), float(np.abs(w) @ np.abs(q)))
    if not g >= -tol:
        raise InadmissibleState(
            f"{name} is not an admissible state: g(q) = w^T q + g0 = {g:.6g} < 0 (inside the wall; the "
            f"quotient distance is defined for g(q) >= 0, tolerance {tol:.3g}). A time-stepping record may "
            f"end a contact step slightly inside the wall: compare its states through the run's own "
            f"distance record (result.d), or move q onto the wall first")


def scheme_code(scheme: str, theta: float) -> tuple[int, float]:
    from .moreau import SCHEMES
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {sorted(SCHEMES)} (or 'exact' where supported), got {scheme!r}")
    if scheme == "trapezoid":   # theta = 1/2 by definition (the θ argument belongs to scheme='theta')
        return SCHEMES[scheme], 0.5
    theta = float(theta)
    if not 0.5 <= theta <= 1.0:
        raise ValueError(f"theta must lie in [0.5, 1] (unconditional stability needs theta >= 1/2), got {theta}")
    return SCHEMES[scheme], theta


def refuse_nonlinear(system, what: str = "the exact solvers") -> None:
    """The exact solvers integrate the built-in linear law in closed form: a user force law is
    refused (:class:`~fmu_sync.core.errors.LawRefused`, naming it and what to use instead)."""
    if getattr(system, "force", None) is not None:
        raise LawRefused(f"{what} integrate the linear law h = -K q - C u + f0 + forcing in closed form; "
                         f"force law {system.force.name!r} is a user law (nonlinear in general): use "
                         f"scheme='midpoint' or scheme='theta'")


def check_stable(system: MechanicalSystem, scheme: str, dt: float) -> None:
    """Refuse a run that is known to diverge before it starts.

    The midpoint scheme is explicit in K: on the free motion it is the
    Störmer–Verlet scheme, stable only for omega_max*dt < 2. Beyond that it
    returns growing garbage long before the state overflows (measured: 5e73 on
    the stiff wall at omega_max*dt = 100), so the run is refused up front with
    :class:`UnstableScheme`, a ValueError (the theta scheme has no such limit).
    """
    if scheme == "midpoint":
        wdt = system.omega_max() * dt
        if wdt >= 2.0:
            raise UnstableScheme(
                f"the explicit midpoint scheme diverges for omega_max*dt >= 2: scheme='midpoint', "
                f"dt = {dt:.3g}, omega_max*dt = {wdt:.3g}. Use scheme='theta' or "
                f"dt < {2.0 / system.omega_max():.3g}.")


def coupling_omega(system: MechanicalSystem, Kp) -> float:
    """omega_c = sqrt(2 lambda_max(M^-1 Kp)): frequency of the relative mode that the
    coupling adds (the explicit, zero-order-hold exchange limits omega_c*dt)."""
    Kp = np.asarray(Kp, dtype=np.float64)
    Kp = Kp * np.eye(system.n) if Kp.ndim == 0 else Kp
    ev = np.linalg.eigvals(system.arrays().Minv @ (0.5 * (Kp + Kp.T)))
    return float(np.sqrt(2.0 * max(np.max(ev.real), 0.0)))


def divergence_message(system: MechanicalSystem, scheme: str, dt: float, t: float, what: str = "the state",
                       Kp=None) -> str:
    wdt = system.omega_max() * dt
    hint = (" The explicit midpoint scheme is stable only for omega_max*dt < 2: use scheme='theta' "
            "or a smaller dt." if scheme == "midpoint" and wdt >= 2.0 else "")
    if Kp is not None:
        wc = coupling_omega(system, Kp) * dt
        hint += (f" The coupling forces are held over each step (explicit exchange): coupling "
                 f"omega_c*dt = {wc:.3g}; it is stable only below min(4 zeta, 1/zeta) <= 2 "
                 f"(zeta: damping ratio of the relative mode): lower Kp or dt, or add Kd.")
    return (f"{what} became non-finite at t = {t:.6g} with scheme={scheme!r}, dt = {dt:.3g} "
            f"(omega_max*dt = {wdt:.3g}).{hint}")
