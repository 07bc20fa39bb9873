"""The exact event-driven solvers (docs/design.md §2.3): one public entry each,
dispatching on the system's number of degrees of freedom.

* :func:`exact_events` -- the exact solution on ``[t0, t_end]`` as its events
  (impacts, completed accumulations, contact intervals, grazings) and the
  closed form between them (:meth:`ExactEvents.state`);
* :func:`simulate_exact` -- that solution sampled on the grid ``t0 + i dt``, a
  :class:`~fmu_sync.core.result.SimulationResult` with ``scheme="exact"`` and the
  :class:`ExactEvents` in ``result.events``.

n = 1 with a constant input: the compiled closed-form solver in the gap
coordinate -- :mod:`.exact_flow` (the flow between events), :mod:`.exact_search`
(the certified search of the next event), :mod:`.exact_run` (the event loop:
impacts, Zeno completion, persistent contact; sampling). n > 1, or an input ramp
``taudot``: the matrix-flow solver :mod:`.exact_nd`. Both are exact to round-off
and agree with each other for n = 1 (tests/test_exact_nd.py). The communication
step of an FMU slave (:func:`exact_model`, :func:`exact_step`,
:func:`exact_step_early`) is :mod:`.exact_step`, re-exported here.

Output
------
:func:`simulate_exact` evaluates the closed form at the grid times (nothing is
integrated on the grid). ``percussion[i]`` is the wall impulse over
``(t[i-1], t[i]]``: impacts, completed Zeno series and the integral of the
persistent contact force (as in the Moreau schemes, whose contact steps also
report the contact impulse).

Limitations: the built-in linear force law only (any number of harmonic terms;
``tau`` constant over the run, or ``tau + taudot (t - t_c)``), one constraint.
Negative damping or stiffness is supported only as far as ``exp`` does not
overflow. Near a grazing the impact speed is ill-conditioned (``|v-| ~ sqrt(2 g''
depth)``): penetrations shallower than the round-off tolerance (~1e-14 of the
gap's magnitude, i.e. impact speeds below ~1e-7 of the velocity scale) are
reported as grazings, not impacts.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from . import exact_nd
from .checks import refuse_nonlinear, check_record_size, check_run, check_start, record_rows, record_times
from .exact_flow import flow_model
from .exact_run import CONTACT, IMPACT_EV, ZENO_EV, run_events, sample
from .exact_step import STEP_NO_PROGRESS, STEP_OK, STEP_TOO_MANY_EVENTS, exact_model, exact_step, exact_step_early
from .model import MechanicalSystem, as_state
from .result import SimulationResult

__all__ = ["simulate_exact", "exact_events", "ExactEvents", "exact_model", "exact_step", "exact_step_early",
           "STEP_OK", "STEP_TOO_MANY_EVENTS", "STEP_NO_PROGRESS"]

#: most events of a run by default: the compiled 1-DOF loop, the Python n-DOF loop
MAX_EVENTS_1, MAX_EVENTS_ND = 10_000_000, 1_000_000
#: the 1-DOF micro-bounce cut-off of elastic chatter (e = 1) by default (module docstring of .exact_run)
CUTOFF_VTOL = 1e-6


@dataclass
class ExactEvents:
    """Events of an exact (event-driven) run, for any n.

    ``impact_velocities`` are the pre-impact velocities ``u-`` in the model's
    coordinates (shape (k,) for n = 1, (k, n) for n > 1), ``impact_normal_velocities``
    their normal components ``w^T u- < 0``; percussions in N s (``P = (1+e)|w^T u-|/W``).
    ``zeno_times`` are the completed accumulation points ``t_inf`` (each followed
    by persistent contact), ``zeno_start_times`` the impact at which the
    geometric series was summed and ``zeno_percussions`` the summed percussion of
    the infinitely many remaining impacts. ``contact_intervals[i] = (t_start,
    t_end)`` of persistent contact (``t_end = horizon`` if still in contact, see
    ``contact_open``). ``graze_times``: tangential contacts with zero speed (no impact).
    """

    impact_times: np.ndarray
    impact_velocities: np.ndarray
    impact_normal_velocities: np.ndarray
    impact_percussions: np.ndarray
    zeno_start_times: np.ndarray
    zeno_times: np.ndarray
    zeno_percussions: np.ndarray
    contact_intervals: np.ndarray
    contact_open: bool
    graze_times: np.ndarray
    t0: float
    t_end: float
    _solution: object = field(repr=False)    # the solver's closed form: state(t), sample(T)

    @property
    def n_impacts(self) -> int:
        """Number of individually resolved impacts (completed Zeno tails not counted)."""
        return int(self.impact_times.size)

    def state(self, t):
        """``(q, u)`` of the exact solution at times ``t`` in ``[t0, t_end]``;
        right-continuous (post-impact velocity at an impact time). For n = 1 float
        arrays shaped like ``t``; for n > 1 shaped ``t.shape + (n,)``."""
        t = np.asarray(t, dtype=np.float64)
        flat = t.reshape(-1)
        if flat.size and (not np.all(np.isfinite(flat)) or flat.min() < self.t0
                          or flat.max() > self.t_end):
            raise ValueError(f"times must lie in [{self.t0}, {self.t_end}]")
        q, u = self._solution.state(flat)
        return q.reshape(t.shape + q.shape[1:]), u.reshape(t.shape + u.shape[1:])


_EVENT_FIELDS = tuple(f.name for f in fields(ExactEvents) if f.name not in ("t0", "t_end", "_solution"))


class _Closed1:
    """The 1-DOF solution: the closed-form segments and the events of :func:`.exact_run.run_events`."""

    def __init__(self, md, segs, evs, grz, t_end):
        self.md, self.segs, self.evs = md, segs, evs
        nseg = segs.shape[0]
        imp = evs[:, 1] == IMPACT_EV
        zen = evs[:, 1] == ZENO_EV
        ci = np.nonzero(segs[:, 1].astype(int) == CONTACT)[0]
        ends = np.array([segs[i + 1, 0] if i + 1 < nseg else t_end for i in ci])
        self.impact_times = evs[imp, 0].copy()
        self.impact_normal_velocities = evs[imp, 2].copy()
        self.impact_velocities = evs[imp, 2] / md.w
        self.impact_percussions = evs[imp, 3].copy()
        self.zeno_start_times = evs[zen, 4].copy()
        self.zeno_times = evs[zen, 0].copy()
        self.zeno_percussions = evs[zen, 3].copy()
        self.contact_intervals = np.column_stack([segs[ci, 0], ends]) if ci.size else np.zeros((0, 2))
        self.contact_open = bool(ci.size and ci[-1] == nseg - 1)
        self.graze_times = grz

    def _eval(self, T, with_p):
        q = np.empty(T.size)
        u = np.empty(T.size)
        P = np.zeros(T.size) if with_p else np.empty(0)
        md = self.md
        sample(T, self.segs, self.segs.shape[0], self.evs, self.evs.shape[0], md.prm, md.rc, md.roots,
               md.hs, md.hO, md.hph, md.hcc, md.hcs, md.w, md.g0, q, u, P, with_p)
        return q, u, P

    def state(self, flat):
        order = np.argsort(flat, kind="stable")
        q, u, _ = self._eval(np.ascontiguousarray(flat[order]), False)
        qo = np.empty_like(q)
        uo = np.empty_like(u)
        qo[order] = q
        uo[order] = u
        return qo, uo

    def sample(self, T):
        q, u, P = self._eval(T, True)
        return q.reshape(-1, 1), u.reshape(-1, 1), P


def _solve1(system, q0, u0, t0, t_end, tau, max_events, zeno_ttol, zeno_vtol, cutoff_vtol):
    md = flow_model(system, tau)
    g = float(md.w * q0[0] + md.g0)
    v = float(md.w * u0[0])
    status, segs, nseg, evs, nev, grz, ngr, _ = run_events(
        md.prm, md.rc, md.roots, md.hs, md.hO, md.hph, md.hcc, md.hcs, t0, g, v, t_end,
        max_events, float(zeno_ttol), float(zeno_vtol), float(cutoff_vtol))
    if status == 2:
        raise RuntimeError(
            f"exact solver: no progress of time near t = {segs[nseg - 1, 0] if nseg else t0:.17g} "
            "(undecidable contact/release at round-off level); please report this case")
    if status != 0:
        raise RuntimeError(
            f"exact solver: more than max_events = {max_events} events before t = {t_end} "
            f"(stopped near t = {segs[nseg - 1, 0] if nseg else t0:.9g}); the run may be chattering "
            "without a completable accumulation (e = 1?) — raise max_events or use a Moreau scheme")
    return _Closed1(md, np.ascontiguousarray(segs[:nseg]), np.ascontiguousarray(evs[:nev]), grz[:ngr].copy(),
                    t_end)


def _inputs(system, name, value):
    """``tau`` / ``taudot``: None or ``system.n_inputs`` finite numbers (float64 array)."""
    if value is None:
        return None
    a = np.array(value, dtype=np.float64, ndmin=1).reshape(-1)
    if a.shape != (system.n_inputs,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be {system.n_inputs} finite numbers, got {a.tolist()}")
    return a


def _solve(system, x0, t_end, tau, t0, taudot, t_c, max_events, zeno_ttol, zeno_vtol, cutoff_vtol) -> ExactEvents:
    """Check the run once and dispatch: the compiled 1-DOF solver for n = 1 with a
    constant input, the n-DOF matrix-flow solver otherwise."""
    if not isinstance(system, MechanicalSystem):
        raise ValueError(f"system must be a MechanicalSystem, got {type(system).__name__}")
    refuse_nonlinear(system)
    t0 = float(t0)
    if not math.isfinite(t0):
        raise ValueError(f"t0 must be finite, got {t0}")
    t_end = float(t_end)
    if not (math.isfinite(t_end) and t_end >= t0):
        raise ValueError(f"t_end must be finite and >= t0 = {t0}, got {t_end}")
    tau = _inputs(system, "tau", tau)
    taudot = _inputs(system, "taudot", taudot)
    q0, u0 = as_state(system, x0)
    check_start(system, q0, "x0")   # the run plan's start check (no step grid here)
    if system.n == 1 and (taudot is None or not np.any(taudot)):
        max_events = MAX_EVENTS_1 if max_events is None else int(max_events)
        cutoff_vtol = CUTOFF_VTOL if cutoff_vtol is None else cutoff_vtol
        sol = _solve1(system, q0, u0, t0, t_end, tau, max_events, zeno_ttol, zeno_vtol, cutoff_vtol)
    else:
        if cutoff_vtol is not None:
            raise ValueError(f"cutoff_vtol (the micro-bounce cut-off of elastic chatter) belongs to the 1-DOF "
                             f"solver with a constant input; this run (n = {system.n}"
                             f"{', an input ramp' if taudot is not None else ''}) uses the n-DOF solver: "
                             f"leave cutoff_vtol unset")
        max_events = MAX_EVENTS_ND if max_events is None else int(max_events)
        sol = exact_nd.solve(system, q0, u0, t0, t_end, tau, taudot, float(t_c), max_events,
                             float(zeno_ttol), float(zeno_vtol))
    return ExactEvents(**{name: getattr(sol, name) for name in _EVENT_FIELDS}, t0=t0, t_end=t_end, _solution=sol)


def exact_events(system: MechanicalSystem, x0, t_end: float, tau=None, t0: float = 0.0, *, taudot=None,
                 t_c: float = 0.0, max_events: int | None = None, zeno_ttol: float = 1e-12,
                 zeno_vtol: float = 1e-10, cutoff_vtol: float | None = None) -> ExactEvents:
    """Event-driven exact solution on ``[t0, t_end]``: impacts, completed Zeno
    accumulations, contact intervals and grazings (module docstring), for any n.

    The input is ``tau`` (constant), or ``tau + taudot (t - t_c)`` with ``taudot``.
    ``max_events`` bounds the work (default 10^7 for the compiled 1-DOF solver,
    10^6 for the n-DOF one; ``RuntimeError`` beyond); ``zeno_ttol``, ``zeno_vtol``:
    the completion criteria of accumulations; ``cutoff_vtol`` (1-DOF, default 1e-6):
    the micro-bounce cut-off of elastic chatter (:mod:`.exact_run`).
    ``ExactEvents.state(t)`` evaluates the closed-form solution at any times.
    Raises ``ValueError`` for bad inputs or ``g(q0) < 0``.
    """
    return _solve(system, x0, t_end, tau, t0, taudot, t_c, max_events, zeno_ttol, zeno_vtol, cutoff_vtol)


def simulate_exact(system: MechanicalSystem, x0, t_end: float, dt: float, tau=None,
                   record_every: int = 1, t0: float = 0.0, *, taudot=None, t_c: float = 0.0,
                   max_events: int | None = None, zeno_ttol: float = 1e-12,
                   zeno_vtol: float = 1e-10, cutoff_vtol: float | None = None) -> SimulationResult:
    """Exact solution sampled on ``t0 + i dt`` and at ``t_end`` (the last row),
    keeping every ``record_every``-th sample (row 0 = initial state); the other
    arguments as :func:`exact_events`.

    Returns a :class:`SimulationResult` with ``scheme="exact"`` and the
    :class:`ExactEvents` in ``result.events``. ``percussion[i]`` is
    the wall impulse over ``(t[i-1], t[i]]`` (impacts, completed Zeno series and
    persistent-contact force).
    """
    t0 = float(t0)
    if not math.isfinite(t0):
        raise ValueError(f"t0 must be finite, got {t0}")
    grid, record_every = check_run(t_end, dt, record_every, t0)
    rows = record_rows(grid.steps, record_every)
    n = system.n if isinstance(system, MechanicalSystem) else 1
    check_record_size(rows, 2 * n + 2, "the record of simulate_exact")
    T = record_times(grid, record_every, t0)
    horizon = max(float(t_end), float(T[-1]))
    ev = _solve(system, x0, horizon, tau, t0, taudot, t_c, max_events, zeno_ttol, zeno_vtol, cutoff_vtol)
    Q, U, P = ev._solution.sample(T)
    return SimulationResult(T, Q, U, P, "exact", grid.dt, events=ev)
