"""Checks of run arguments and the messages of a failed run, shared by every
driver (single system, exact solver, pair, co-simulation master, FMU slave)."""
from __future__ import annotations

import math

import numpy as np

from .errors import SimulationDiverged
from .model import MechanicalSystem

__all__ = ["check_step", "check_run", "n_steps", "scheme_code", "check_stable", "coupling_omega",
           "divergence_message", "check_start"]


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
    """floor((t_end - t0)/dt) (up to 1e-9 of a step): the number of steps of a run."""
    t_end = float(t_end)
    if not (math.isfinite(t_end) and t_end >= t0):
        raise ValueError(f"t_end must be finite and >= {t0}, got {t_end}")
    r = (t_end - t0) / dt
    k = math.floor(r + 1e-9)
    return int(k)


def check_run(t_end, dt, record_every=1, t0: float = 0.0, dt_name: str = "dt") -> tuple[float, int, int]:
    """The run arguments of every driver: returns ``(dt, steps, record_every)``.

    ``dt`` (the step, or the communication step ``H`` with ``dt_name="H"``) must
    be positive and finite, ``t_end`` finite and >= ``t0``, ``record_every`` >= 1.
    """
    dt = check_step(dt, dt_name)
    record_every = int(record_every)
    if record_every < 1:
        raise ValueError(f"record_every must be >= 1, got {record_every}")
    return dt, n_steps(t_end, dt, t0), record_every


def check_start(system: MechanicalSystem, q, name: str = "x0") -> None:
    """Refuse a start position outside the admissible set g(q) >= 0."""
    g = system.gap(q)
    if g < 0.0:
        raise ValueError(f"{name} violates the constraint: g(q) = {g:.6g} < 0 (need g >= 0)")


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
