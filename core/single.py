"""Single-system simulation: the plain functional entry point over the kernels
(Moreau schemes of :mod:`.moreau`, or the exact solver of :mod:`.exact`)."""
from __future__ import annotations

import numpy as np

from .checks import divergence_message
from .errors import SimulationDiverged
from .exact import simulate_exact
from .model import MechanicalSystem
from .moreau import DIVERGED, kernels_for
from .plan import plan_run
from .result import SimulationResult

__all__ = ["simulate"]


def simulate(system: MechanicalSystem, x0, t_end: float, dt: float, scheme: str = "midpoint",
             theta: float = 0.5, tau=None, record_every: int = 1, t0: float = 0.0,
             phasor: bool = True) -> SimulationResult:
    """Simulate one system from ``x0 = (q0, u0)`` over ``[t0, t_end]`` with fixed step ``dt``.

    ``scheme`` is ``"midpoint"`` (default), ``"theta"`` (Moreau–Jean, ``theta`` in
    [0.5, 1]) or ``"exact"`` (event-driven, linear force law: :func:`.exact.simulate_exact`,
    any n).
    ``tau`` is a constant input (length m). The run ends exactly at ``t_end``: its
    last step is shortened when ``t_end - t0`` is not a multiple of ``dt``, and
    the final state is the last row of the record (also when ``record_every``
    does not divide the step count). A record larger than the machine's memory
    is refused before anything is allocated (:class:`.checks.RecordTooLarge`, a ValueError). ``phasor`` (default): harmonic forcing by
    the phasor recurrence, within 1e-13 of a cos per step (``phasor=False``; see
    :mod:`.moreau`). Raises :class:`SimulationDiverged` if the
    state becomes non-finite (never returns NaN data).
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
    T = np.empty(rows)
    Q = np.empty((rows, n))
    U = np.empty((rows, n))
    P = np.empty(rows)
    sa = system.arrays()
    full = grid.steps - 1 if grid.short else grid.steps
    dt_last = grid.dt_last if grid.short else 0.0
    if system.force is not None:   # a user force law: its copy of the loop, the law's force (core/law_loops.py)
        status, done, written = system.force.kernels().integrate(
            sa, system.p, q0.copy(), u0.copy(), float(t0), dt, full, tau, code, theta, record_every, T, Q, U, P,
            bool(phasor), dt_last)
    else:
        status, done, written = kernels_for(sa)(sa, q0.copy(), u0.copy(), float(t0), dt, full, tau, code, theta,
                                                record_every, T, Q, U, P, bool(phasor), dt_last)
    if status == DIVERGED:
        raise SimulationDiverged(divergence_message(system, scheme, dt, t0 + done * dt))
    return SimulationResult(T, Q, U, P, scheme, dt)
