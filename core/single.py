"""Single-system simulation: the plain functional entry point over the kernels
(Moreau schemes of :mod:`.moreau`, or the exact solver of :mod:`.exact`)."""
from __future__ import annotations

import numpy as np

from .checks import check_record_size, check_run, check_stable, divergence_message, record_rows, scheme_code
from .errors import SimulationDiverged
from .exact import simulate_exact
from .model import MechanicalSystem, as_state
from .moreau import DIVERGED, kernels_for
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
    grid, record_every = check_run(t_end, dt, record_every, t0)
    dt = grid.dt
    q0, u0 = as_state(system, x0)
    g = system.gap(q0)
    if g < 0.0:
        raise ValueError(f"initial state violates the constraint: g(q0) = {g:.6g} < 0 (need g(q0) >= 0)")
    tau = np.zeros(system.m) if tau is None else np.array(tau, dtype=np.float64, ndmin=1).reshape(-1)
    if tau.shape != (system.m,) or not np.all(np.isfinite(tau)):
        raise ValueError(f"tau must be {system.m} finite numbers, got {tau.tolist()}")
    if scheme == "exact":
        return simulate_exact(system, (q0, u0), t_end, dt, tau=tau, record_every=record_every, t0=t0)
    code, theta = scheme_code(scheme, theta)
    check_stable(system, scheme, dt)
    rows = record_rows(grid.steps, record_every)
    n = system.n
    check_record_size(rows, 2 + 2 * n, "the record of simulate")
    T = np.empty(rows)
    Q = np.empty((rows, n))
    U = np.empty((rows, n))
    P = np.empty(rows)
    sa = system.arrays()
    full = grid.steps - 1 if grid.short else grid.steps
    status, done, written = kernels_for(sa)(sa, q0.copy(), u0.copy(), float(t0), dt, full, tau, code, theta,
                                            record_every, T, Q, U, P, bool(phasor),
                                            grid.dt_last if grid.short else 0.0)
    if status == DIVERGED:
        raise SimulationDiverged(divergence_message(system, scheme, dt, t0 + done * dt))
    return SimulationResult(T, Q, U, P, scheme, dt)
