"""Single-system simulation: the plain functional entry point over the kernels."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .model import MechanicalSystem, as_state

__all__ = ["SimulationResult", "SimulationDiverged", "simulate", "check_step", "check_stable", "scheme_code",
           "divergence_message", "coupling_omega"]


class SimulationDiverged(RuntimeError):
    """The state became non-finite: the scheme is unstable for this step size."""


@dataclass
class SimulationResult:
    """Sampled trajectory. ``percussion[i]`` is the impulse (N s) applied over the
    steps that end at ``t[i]`` (one step for ``record_every=1``)."""

    t: np.ndarray
    q: np.ndarray
    u: np.ndarray
    percussion: np.ndarray
    scheme: str
    dt: float

    @property
    def impacts(self) -> int:
        """Number of records with a positive percussion."""
        return int(np.count_nonzero(self.percussion > 0.0))


def check_step(dt, name: str = "dt") -> float:
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive real number, got {dt!r}") from None
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f"{name} must be a positive finite step, got {dt}")
    return dt


def scheme_code(scheme: str, theta: float) -> tuple[int, float]:
    from .moreau import SCHEMES
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {sorted(SCHEMES)} (or 'exact' where supported), got {scheme!r}")
    theta = float(theta)
    if not 0.5 <= theta <= 1.0:
        raise ValueError(f"theta must lie in [0.5, 1] (unconditional stability needs theta >= 1/2), got {theta}")
    return SCHEMES[scheme], theta


def check_stable(system: MechanicalSystem, scheme: str, dt: float) -> None:
    """Refuse a run that is known to diverge before it starts.

    The midpoint scheme is explicit in K: on the free motion it is the
    Störmer–Verlet scheme, stable only for omega_max*dt < 2. Beyond that it
    returns growing garbage long before the state overflows (measured: 5e73 on
    the stiff wall at omega_max*dt = 100), so the run is refused up front with
    :class:`SimulationDiverged` (the theta scheme has no such limit).
    """
    if scheme == "midpoint":
        wdt = system.omega_max() * dt
        if wdt >= 2.0:
            raise SimulationDiverged(
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


def _n_steps(t_end: float, dt: float, t0: float = 0.0) -> int:
    t_end = float(t_end)
    if not (math.isfinite(t_end) and t_end >= t0):
        raise ValueError(f"t_end must be finite and >= {t0}, got {t_end}")
    r = (t_end - t0) / dt
    k = math.floor(r + 1e-9)
    return int(k)


def simulate(system: MechanicalSystem, x0, t_end: float, dt: float, scheme: str = "midpoint",
             theta: float = 0.5, tau=None, record_every: int = 1, t0: float = 0.0,
             phasor: bool = True) -> SimulationResult:
    """Simulate one system from ``x0 = (q0, u0)`` over ``[t0, t_end]`` with fixed step ``dt``.

    ``scheme`` is ``"midpoint"`` (default), ``"theta"`` (Moreau–Jean, ``theta`` in
    [0.5, 1]) or ``"exact"`` (event-driven, linear force law: :mod:`.exact` for
    n = 1, :mod:`.exact_nd` for n > 1).
    ``tau`` is a constant input (length m). The run ends after
    ``floor((t_end - t0)/dt)`` steps. ``phasor`` (default): harmonic forcing by
    the phasor recurrence, within 1e-13 of a cos per step (``phasor=False``; see
    :mod:`.moreau`). Raises :class:`SimulationDiverged` if the
    state becomes non-finite (never returns NaN data).
    """
    dt = check_step(dt)
    q0, u0 = as_state(system, x0)
    g = system.gap(q0)
    if g < 0.0:
        raise ValueError(f"initial state violates the constraint: g(q0) = {g:.6g} < 0 (need g(q0) >= 0)")
    record_every = int(record_every)
    if record_every < 1:
        raise ValueError(f"record_every must be >= 1, got {record_every}")
    tau = np.zeros(system.m) if tau is None else np.array(tau, dtype=np.float64, ndmin=1).reshape(-1)
    if tau.shape != (system.m,) or not np.all(np.isfinite(tau)):
        raise ValueError(f"tau must be {system.m} finite numbers, got {tau.tolist()}")
    if scheme == "exact":
        if system.n > 1:
            from .exact_nd import simulate_exact_nd
            return simulate_exact_nd(system, (q0, u0), t_end, dt, tau=tau, record_every=record_every, t0=t0)
        from .exact import simulate_exact
        return simulate_exact(system, (q0, u0), t_end, dt, tau=tau, record_every=record_every, t0=t0)
    code, theta = scheme_code(scheme, theta)
    check_stable(system, scheme, dt)
    n_steps = _n_steps(t_end, dt, t0)
    rows = n_steps // record_every + 1
    n = system.n
    T = np.empty(rows)
    Q = np.empty((rows, n))
    U = np.empty((rows, n))
    P = np.empty(rows)
    from .moreau import kernels_for, DIVERGED
    sa = system.arrays()
    status, done, written = kernels_for(sa)(sa, q0.copy(), u0.copy(), float(t0), dt, n_steps,
                                      tau, code, theta, record_every, T, Q, U, P, bool(phasor))
    if status == DIVERGED:
        raise SimulationDiverged(divergence_message(system, scheme, dt, t0 + done * dt))
    return SimulationResult(T, Q, U, P, scheme, dt)
