"""Single-system simulation: the plain functional entry point over the kernels
(Moreau schemes of :mod:`.moreau`, or the exact solver of :mod:`.exact`)."""
from __future__ import annotations

import numpy as np

from .checks import divergence_message, land_last_row
from .errors import ForceLawFailed, SimulationDiverged
from .exact import simulate_exact
from .failure import force_offset, law_nonfinite, law_raised, rows_written
from .model import MechanicalSystem
from .moreau import DIVERGED, kernels_for
from .steps import DEFAULT_SCHEME, TRAPEZOID
from .plan import plan_run
from .result import SimulationResult

__all__ = ["simulate"]


def simulate(system: MechanicalSystem, x0, t_end: float, dt: float, scheme: str = DEFAULT_SCHEME,
             theta: float = 0.5, tau=None, record_every: int = 1, t0: float = 0.0,
             phasor: bool = True) -> SimulationResult:
    """Simulate one system from ``x0 = (q0, u0)`` over ``[t0, t_end]`` with fixed step ``dt``.

    ``scheme`` is ``"trapezoid"`` (default: Moreau–Jean θ = 1/2, second order between impacts),
    ``"midpoint"`` (first order), ``"theta"`` (Moreau–Jean, ``theta`` in [0.5, 1]) or ``"exact"``
    (event-driven, linear force law: :func:`.exact.simulate_exact`, any n).
    ``tau`` is a constant input (length m). The run ends exactly at ``t_end``: its
    last step is shortened when ``t_end - t0`` is not a multiple of ``dt``, and
    the final state is the last row of the record (also when ``record_every``
    does not divide the step count). A record larger than the machine's memory
    is refused before anything is allocated (:class:`.checks.RecordTooLarge`, a ValueError). ``phasor`` (default): harmonic forcing by
    the phasor recurrence, within 1e-13 of a cos per step (``phasor=False``; see
    :mod:`.moreau`). Raises :class:`SimulationDiverged` if the
    state becomes non-finite (never returns NaN data), :class:`ForceLawFailed` if a user force
    law raises mid-run; either with the record up to the last good step in ``.partial`` (its
    ``error`` the message: the law's, the time and the state, docs/design.md §5.1).
    """
    plan = plan_run(system, [x0], t_end, dt, scheme=scheme, theta=theta, record_every=record_every, t0=t0,
                    record_values=2 + 2 * system.n, record_what="the record of simulate",
                    exact=True)   # every check, once (docs/design.md §5.1.1)
    grid, dt, record_every, rows, n = plan.grid, plan.dt, plan.record_every, plan.rows, system.n
    q0, u0 = plan.q[0], plan.u[0]
    tau = np.zeros(system.n_inputs) if tau is None else np.array(tau, dtype=np.float64, ndmin=1).reshape(-1)
    if tau.shape != (system.n_inputs,) or not np.all(np.isfinite(tau)):
        raise ValueError(f"tau must be {system.n_inputs} finite numbers, got {tau.tolist()}")
    if scheme == "exact":
        return simulate_exact(system, (q0, u0), t_end, dt, tau=tau, record_every=record_every, t0=t0)
    code, theta = plan.code, plan.theta
    T = np.full(rows, np.nan)   # NaN: the rows a failed loop did not complete (core/failure.py)
    Q = np.empty((rows, n))
    U = np.empty((rows, n))
    P = np.zeros(rows)
    sa = system.arrays()
    law = system.force
    full = grid.steps - 1 if grid.short else grid.steps
    dt_last = grid.dt_last if grid.short else 0.0

    def run(q, u, t_start, steps, every, T, Q, U, P, last):
        if law is not None:   # a user force law: its copy of the loop, the law's force (core/law_loops.py)
            return law.kernels(code == TRAPEZOID).integrate(sa, system.p, q, u, float(t_start), dt, steps, tau, code, theta, every,
                                           T, Q, U, P, bool(phasor), last)
        return kernels_for(sa)(sa, q, u, float(t_start), dt, steps, tau, code, theta, every, T, Q, U, P,
                               bool(phasor), last)

    try:
        status, done, written = run(q0.copy(), u0.copy(), t0, full, record_every, T, Q, U, P, dt_last)
        raised = None
    except Exception as exc:   # raised by the user's law inside the compiled loop
        if law is None:
            raise
        status, done, written, raised = DIVERGED, None, rows_written(T), exc
    if status != DIVERGED:
        land_last_row(T, rows, grid)
        return SimulationResult(T, Q, U, P, scheme, dt)
    raise single_failure(system, scheme, plan, run, (T, Q, U, P), written, done, raised, tau, code, theta)


def single_failure(system, scheme, plan, run, rec, written, done, raised, tau, code, theta):
    """The error of a failed :func:`simulate` (core/failure.py): from the last row, every step again with
    a row each (``run``: the compiled loop), the partial record (with the last good step) in
    ``.partial``; or the law's own exception when it did not raise again from the same state."""
    T, Q, U, P = rec
    grid, dt, record_every, n, law = plan.grid, plan.dt, plan.record_every, system.n, system.force
    full = grid.steps - 1 if grid.short else grid.steps
    dt_last = grid.dt_last if grid.short else 0.0
    r = written - 1
    m = min(record_every, full - r * record_every)
    last = dt_last if m == full - r * record_every else 0.0
    T2, Q2, U2, P2 = np.full(m + 2, np.nan), np.empty((m + 2, n)), np.empty((m + 2, n)), np.zeros(m + 2)
    again = None
    try:
        st2, _, w2 = run(Q[r].copy(), U[r].copy(), T[r], m, 1, T2, Q2, U2, P2, last)
        j = w2 - 1 if st2 == DIVERGED else None
    except Exception as exc:
        again, j = exc, rows_written(T2) - 1
    if raised is not None and again is None:
        return raised   # not the law's (it did not raise again from the same state): as it came
    keep = slice(0, written)
    partial = SimulationResult(T[keep], Q[keep], U[keep], P[keep], scheme, dt)
    if j is None:   # the rerun did not diverge again (round-off): the block's end, as the loop saw it
        msg = divergence_message(system, scheme, dt, float(T[0]) + done * dt)   # T[0] = t0
        partial.error = msg
        return SimulationDiverged(msg, partial=partial)
    if j >= 1:      # the last good step as the last row
        partial = SimulationResult(np.append(T[keep], T2[j]), np.vstack((Q[keep], Q2[j])),
                                   np.vstack((U[keep], U2[j])), np.append(P[keep], P2[1:j + 1].sum()), scheme, dt)
    here = [("", Q2[j], U2[j], tau)]
    if again is not None:
        partial.error = law_raised(law, again, T2[j], here)
        return ForceLawFailed(partial.error, partial=partial)
    hk = last if (j == m and last > 0.0) else dt
    msg = law_nonfinite(law, force_offset(code, theta, hk), T2[j], here, [system.p]) if law is not None else None
    partial.error = msg or divergence_message(system, scheme, dt, float(T2[j]) + hk)
    return SimulationDiverged(partial.error, partial=partial)
