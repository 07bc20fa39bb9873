"""What a co-simulation run says about itself (docs/design.md §4.4.1, §2.6.1): the growth guard
(a run never ends with success after it has grown without bound) and the verdict of a run to a
tolerance (``info["tol_met"]``, :class:`fmu_sync.core.errors.ToleranceNotMet`).

Growth guard: the energy of the network, ``W = sum_i (u_i' M u_i + q_i' K+ q_i)/2 + sum_edges
a_ij (dq' Kp dq + du' M du)/2`` (``K+``: the systems' own stiffness where it is positive
semidefinite, else 0; ``dq = q_i - q_j``), is compared between chunks of steps and at the end
with ``GROWTH`` times its scale at the start: ``W(0)``, the energy the forcing can put in
(``|F|^2 / (2 m Omega^2)`` per term and node, ``|f0|^2 / (2 m)`` for a constant force) and the
energy of a unit displacement of every node (so that a run starting at rest has a scale). A run
beyond it stops as :class:`fmu_sync.core.errors.SimulationDiverged` with its record so far.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from .core.errors import SimulationDiverged, ToleranceNotMet

__all__ = ["GROWTH", "GrowthGuard", "tolerance_verdict", "floor_error"]

#: the energy factor beyond the start's scale at which a run is stopped as grown without bound
#: (1e4 in energy: 100 in amplitude)
GROWTH = 1e4


class GrowthGuard:
    """The growth guard of one run (module docstring): ``check(q, u, t)`` raises when ``W``
    exceeds ``GROWTH`` times the start's scale."""

    def __init__(self, system, Kp, A, edges, q0, u0, hint: str = ""):
        M = np.atleast_2d(np.asarray(system.M, dtype=np.float64))
        n = M.shape[0]
        K = 0.5 * (np.atleast_2d(system.K) + np.atleast_2d(system.K).T)
        self.K = K if np.linalg.eigvalsh(K).min() >= 0.0 else np.zeros((n, n))
        self.M = M
        Kp = np.asarray(Kp, dtype=np.float64)
        self.Kp = Kp * np.eye(n) if Kp.ndim == 0 else np.atleast_2d(Kp)
        self.pairs = [(i, j, 0.5 * (A[i, j] + A[j, i])) for i, j in edges]
        N = len(q0)
        m = float(np.linalg.eigvalsh(M).min())
        forced = sum(float(np.dot(F, F)) / (2.0 * m * max(Om, 1e-12) ** 2) for F, Om, _ in system.forcing)
        forced += float(np.dot(system.f0, system.f0)) / (2.0 * m)
        stiff = float(np.linalg.eigvalsh(self.K + self.Kp * (1.0 + len(self.pairs)) + M).max())
        self.scale = self.energy(np.asarray(q0), np.asarray(u0)) + N * (forced + 0.5 * stiff)
        self.hint = hint

    def energy(self, q, u) -> float:
        W = 0.0
        for i in range(q.shape[0]):
            W += 0.5 * (u[i] @ self.M @ u[i] + q[i] @ self.K @ q[i])
        for i, j, a in self.pairs:
            dq, du = q[i] - q[j], u[i] - u[j]
            W += 0.5 * a * (dq @ self.Kp @ dq + du @ self.M @ du)
        return float(W)

    def check(self, q, u, t: float):
        """None, or the :class:`SimulationDiverged` of a run that grew without bound by ``t``."""
        with np.errstate(over="ignore", invalid="ignore"):
            W = self.energy(q, u)
        if math.isfinite(W) and W <= GROWTH * self.scale:
            return None
        return SimulationDiverged(
            f"the co-simulation grew without bound: the energy of the network (the systems' own and the "
            f"coupling's, docs/design.md §2.6.1) reached {W:.4g} by t = {t:.6g}, more than {GROWTH:g} times its "
            f"scale at the start {self.scale:.4g} (start states, forcing, a unit displacement); the run stopped "
            f"there and the record ends at the last row{self.hint}")


def floor_error(omega: float, unit: float, t_end: float, amplitude: float) -> float:
    """The slaves' own error at their solver.dt ``unit`` against the exact motion: the phase error
    of their second-order step on the fastest mode ``omega``, ``(omega unit)^2 / 24`` per radian,
    over ``omega t_end`` radians of the amplitude ``amplitude``."""
    return amplitude * omega ** 3 * unit ** 2 * t_end / 24.0


def tolerance_verdict(tol: float, estimate: float, floor: float, forced: int, unit: float, hold: str,
                      impacts: int) -> tuple[bool, str]:
    """``(tol_met, why)`` of a run to ``tol``: met when the estimate (coupling and floor, the
    ``forced`` steps at the floor over their share included) is within tol and no impact occurred (the estimate covers the smooth coupling error, not an impact's
    timing inside a step); ``why`` names every reason it is not. A :class:`ToleranceNotMet` warning
    is issued when not met."""
    why = []
    if estimate > tol:
        why.append(f"the estimated error {estimate:.3g} exceeds tol = {tol:g}")
    if forced and estimate > tol:
        held = ("the zero-order hold holds the force over each solver.dt, an error of first order in it"
                if hold == "zoh" else "the hold's own error there")
        why.append(f"{forced} steps at the floor H = solver.dt = {unit:g} exceeded their share of tol ({held}; "
                   f"a smaller solver.dt or hold='foh' / exchange='implicit' lowers it)")
    if floor > tol:
        why.append(f"the slaves' own scheme at solver.dt = {unit:g} errs by about {floor:.3g} on its own (a "
                   f"smaller solver.dt lowers it)")
    if impacts:
        why.append(f"{impacts} impacts: the estimate covers the smooth coupling error, not where an impact falls "
                   f"inside a step")
    met = not why
    text = "; ".join(why)
    if not met:
        warnings.warn(f"tolerance tol = {tol:g} not met: {text}", ToleranceNotMet, stacklevel=4)
    return met, text
