"""Stability of the explicit exchange of coupling forces (zero-order hold).

Both the monolithic pair/network and the co-simulation master compute the
coupling forces from the states at the start of a step and hold them over the
step (``dt`` in the core, the communication step ``H`` in the master). On the
Euclidean branch the relative motion of identical systems is linear; on a graph
with (symmetrised) weights ``a_ij`` it splits along the eigenvectors of the
weighted Laplacian ``L`` (eigenvalues ``lambda_k``; a pair has ``lambda = 2``)
into modes

    M x'' = -lambda_k (Kp x + Kd x')      (forces held over each step).

With modal gains (``Kp``, ``Kd`` diagonal in the M-orthonormal eigenvectors of
``M^-1 Kp``) each mode is a scalar oscillator with ``omega = sqrt(lambda kp)``
and damping ratio ``zeta = lambda kd / (2 omega)`` (per unit modal mass), and
the zero-order-hold map of the step ``H`` is stable exactly for

    omega H < h*(zeta) = min(4 zeta, 1/zeta)           (h* <= 2, = 2 at zeta = 1/2)

(``fmu_sync.benchmarks.stability.zoh_limit``, measured by ``fmu-sync bench``);
a mode with ``kp = 0`` needs ``lambda kd H < 2``. Without damping (``Kd = 0``)
no H is stable (the map grows by ``1 + (omega H)^2 / 4`` per step). For
non-modal gains the spectral radius of the hold map itself is bisected.

First-order hold (the master's ``hold="foh"``): the force over a step is the
line through the forces at the last two communication points,
``f(t) = f_k + (f_k - f_{k-1}) (t - t_k)/H``; the step map acts on
``(x_k, v_k, f_{k-1})`` and its stable range is another one (measured by the
spectral radius, :func:`hold_bound`): ``omega H < 0.69, 0.90, 1.35, 1.62,
1.10, 0.51, 0.25`` at ``zeta = 0.05, 0.1, 0.25, 0.354, 0.5, 1, 2`` against
``0.2, 0.4, 1.0, 1.41, 2.0, 1.0, 0.5`` for the zero-order hold: larger for
light damping, smaller (about half) for ``zeta >= 0.5``.

Implicit exchange (the master's ``exchange="implicit"``, docs/design.md §2.6): the force over
a step depends on the states at both ends, ``f_k`` and ``f_{k+1}``, and the step is iterated
until they agree. With the first-order hold the force is the line between them, with the
zero-order hold their mean is held; the step map of a mode is Newmark's with ``gamma = 1/2``
and ``beta = 1/6`` (the line: ``x' = x + H v + H^2 (f/3 + f'/6)``) or ``beta = 1/4`` (the
mean: ``x' = x + H v + H^2 (f + f')/4``), ``v' = v + H (f + f')/2``. The mean is A-stable
(any H, any damping) and at ``Kd = 0`` conserves the mode's energy exactly; the line conserves
it too (``|lambda| = 1``) up to ``omega H < 2 sqrt(3) = 3.46`` and is unstable beyond.
Both are second order.

The systems' own forces (docs/design.md §2.6.1): in a co-simulation each slave integrates its own
stiffness ``K`` and damping ``C`` inside the step (at its solver.dt, far below H), and only the
coupling force is held. The relative mode is then ``x'' = -M^-1 (K x + C x') + f``, ``f`` the held
coupling force, and the step map is the exact flow of the systems under the held force line
(:func:`held_flow_map`). Its limit lies below the bare coupling's: the pendulum pair (m g l = 9.81,
Euclidean Kp = 500, Kd = 0, the line) is stable up to H = 0.1087, not the 0.1095 of
``omega_c H < 2 sqrt 3``. :func:`exchange_limit` takes ``K`` and ``C`` (``own=``; the master's
plan passes them) and then bisects the spectral radius of this map for each Laplacian mode.

:func:`exchange_limit` computes the limit; :func:`check_exchange` refuses an
unstable step with :class:`UnstableExchange` (a ``ValueError``) unless the
caller passes ``allow_unstable=True``. The core (``simulate_pair``,
``simulate_network``) and the master call these same functions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import RunRefused

__all__ = ["UnstableExchange", "ExchangeLimit", "exchange_limit", "check_exchange", "zoh_bound",
           "laplacian_modes", "hold_map_radius", "hold_bound", "HOLDS", "EXCHANGES", "check_exchange_name",
           "held_flow_map", "largest_stable"]

#: the input holds over a step: zero-order (forces constant) and first-order (extrapolated line)
HOLDS = ("zoh", "foh")
#: the exchanges: the forces from the step's start (explicit), or iterated to the states at both
#: of its ends (implicit: the line between them with the first-order hold, their mean with the zero-order)
EXCHANGES = ("explicit", "implicit")


def check_exchange_name(exchange: str) -> str:
    """``exchange``, or ValueError naming the allowed ones."""
    if exchange not in EXCHANGES:
        raise ValueError(f"exchange must be {' or '.join(repr(e) for e in EXCHANGES)}, got {exchange!r}")
    return exchange


class UnstableExchange(RunRefused):
    """The coupling forces held over a step make the relative motion grow."""


def zoh_bound(zeta: float) -> float:
    """h*(zeta) = min(4 zeta, 1/zeta): the zero-order-hold limit of omega*H (0 for zeta <= 0)."""
    return min(4.0 * zeta, 1.0 / zeta) if zeta > 0.0 else 0.0


@dataclass(frozen=True)
class ExchangeLimit:
    """The binding (least stable) relative mode of the held coupling at step ``H``.

    ``omega_c``: its frequency; ``zeta``: its damping ratio (NaN for non-modal
    gains); ``bound``: the limit of ``omega_c*H`` (``min(4 zeta, 1/zeta)``);
    ``H_max``: the largest stable step over all modes (inf: no coupling);
    ``stable``: ``H < H_max``."""

    H: float
    omega_c: float
    zeta: float
    bound: float
    H_max: float
    lam: float
    step_name: str = "H"
    hold: str = "zoh"
    exchange: str = "explicit"
    own: float = 0.0   # the largest eigenvalue of M^-1 K of the systems' own forces in the map (0: none)

    @property
    def h(self) -> float:
        """omega_c * H."""
        return self.omega_c * self.H

    @property
    def stable(self) -> bool:
        return self.H < self.H_max

    def message(self) -> str:
        s = self.step_name
        if math.isinf(self.H_max):
            if self.exchange == "implicit" and self.omega_c > 0.0:
                return f"the implicit exchange with hold={self.hold!r} is A-stable: any {s} is stable"
            return f"the coupling adds no relative mode: any {s} is stable"
        if self.H_max == 0.0:
            largest = (f"no {s} is stable without damping of the relative mode (Kd = 0: the held "
                       f"forces grow it by 1 + (omega_c*{s})^2/4 per step); add Kd > 0")
        else:
            largest = f"largest stable {s} = {largest_stable(self.H_max):.4g}"
        if self.own > 0.0:
            z = "" if math.isnan(self.zeta) else f", zeta = {self.zeta:.4g}"
            against = (f"the limit {self.bound:.4g} of the hold map with the systems' own stiffness integrated "
                       f"by them (largest eigenvalue of M^-1 K = {self.own:.4g} 1/s^2{z}), hold={self.hold!r}")
        elif math.isnan(self.zeta):
            against = (f"the limit {self.bound:.4g} of the hold map (gains not modal: no single "
                       f"zeta)")
        elif self.exchange == "implicit":
            against = f"the implicit exchange's bound {self.bound:.4g} with hold={self.hold!r} (zeta = {self.zeta:.4g})"
        elif self.hold == "foh":
            against = f"the first-order-hold bound {self.bound:.4g} (zeta = {self.zeta:.4g})"
        else:
            against = (f"the zero-order-hold bound min(4 zeta, 1/zeta) = {self.bound:.4g} "
                       f"(zeta = {self.zeta:.4g})")
        return (f"coupling forces held over {s} = {self.H:.4g}: omega_c*{s} = {self.h:.4g} against "
                f"{against}, omega_c = {self.omega_c:.4g} rad/s; {largest}")


def largest_stable(H_max: float) -> float:
    """The step a refusal names as the largest stable one: ``H_max`` rounded down to 4 significant
    digits and strictly below it, so that the named step is itself accepted."""
    if not (math.isfinite(H_max) and H_max > 0.0):
        return H_max
    e = math.floor(math.log10(H_max)) - 3
    m = math.floor(H_max / 10.0 ** e)
    H = m * 10.0 ** e
    while H >= H_max:
        m -= 1
        H = m * 10.0 ** e
    return H


def expm(A) -> np.ndarray:
    """The matrix exponential by scaling and squaring with the diagonal Pade approximant of degree
    6 (Moler and Van Loan's method 3): ``A / 2^s`` with its infinity norm at most 1/2, whose
    approximant is exact to about 1e-16, then squared ``s`` times. Numpy only: the master's stability
    check runs on the package's own dependencies (scipy is a test and bench extra)."""
    A = np.asarray(A, dtype=np.float64)
    norm = float(np.max(np.sum(np.abs(A), axis=1))) if A.size else 0.0
    s = max(0, int(math.ceil(math.log2(norm / 0.5)))) if norm > 0.5 else 0
    X = A / 2.0 ** s
    q, c = 6, 1.0
    N = np.eye(A.shape[0])
    D = np.eye(A.shape[0])
    P = np.eye(A.shape[0])
    for k in range(1, q + 1):
        c = c * (q - k + 1) / (k * (2 * q - k + 1))
        P = P @ X
        N = N + c * P
        D = D + (-1) ** k * c * P
    E = np.linalg.solve(D, N)
    for _ in range(s):
        E = E @ E
    return E


def held_flow_map(Ap, Ad, Ks, Cs, H: float, hold: str = "zoh", exchange: str = "explicit") -> np.ndarray:
    """The step map of ``x'' = -Ks x - Cs x' + f`` under the coupling force ``f = -(Ap x + Ad x')``
    held by ``hold``/``exchange`` (as :func:`hold_map_radius`), the systems' own forces ``Ks``, ``Cs``
    integrated exactly (the slaves' fine steps): the flow's response to the force line
    ``f0 + f1 s/H`` from one matrix exponential. State ``(x, v)``, with ``f_prev`` for the explicit
    first-order hold. At ``Ks = Cs = 0`` it is :func:`hold_map_radius`'s map."""
    n = Ap.shape[0]
    I, Z = np.eye(n), np.zeros((n, n))
    Aug = np.zeros((4 * n, 4 * n))
    Aug[:2 * n, :2 * n] = H * np.block([[Z, I], [-Ks, -Cs]])
    Aug[n:2 * n, 2 * n:3 * n] = H * I
    Aug[2 * n:3 * n, 3 * n:] = I
    E = expm(Aug)
    Phi, G0, G1 = E[:2 * n, :2 * n], E[:2 * n, 2 * n:3 * n], E[:2 * n, 3 * n:]
    Kz = np.hstack([Ap, Ad])
    I2 = np.eye(2 * n)
    if exchange == "implicit":
        if hold == "foh":   # f0 = F(z), f1 = F(z') - F(z)
            return np.linalg.solve(I2 + G1 @ Kz, Phi - G0 @ Kz + G1 @ Kz)
        return np.linalg.solve(I2 + 0.5 * G0 @ Kz, Phi - 0.5 * G0 @ Kz)   # the mean held
    if hold == "foh":       # f0 = F(z), f1 = F(z) - f_prev
        return np.block([[Phi - (G0 + G1) @ Kz, -G1], [-Kz, Z]])
    return Phi - G0 @ Kz


def laplacian_modes(A) -> np.ndarray:
    """Nonzero eigenvalues of the weighted Laplacian of the symmetrised weights
    ``(A + A^T)/2`` (a pair with weight 1: ``[2]``)."""
    A = np.asarray(A, dtype=np.float64)
    S = 0.5 * (A + A.T)
    L = np.diag(S.sum(axis=1)) - S
    ev = np.linalg.eigvalsh(L)
    tol = 1e-12 * max(1.0, float(np.max(np.abs(ev))) if ev.size else 1.0)
    return ev[ev > tol]


def hold_map_radius(Ap: np.ndarray, Ad: np.ndarray, H: float, hold: str = "zoh",
                    exchange: str = "explicit", own=None) -> float:
    """Spectral radius of the held step of ``x'' = -Ap x - Ad x'`` (exact free
    flight under the held force; the midpoint step gives the same map).
    ``hold="zoh"``: the force at the start held; ``"foh"``: the line through the
    forces at the last two communication points (state ``(x, v, f_prev)``).
    ``exchange="implicit"``: the converged implicit step (Newmark, gamma = 1/2, beta = 1/6
    for the line of ``"foh"``, 1/4 for the mean of ``"zoh"``; see the module docstring).
    ``own``: ``(Ks, Cs)``, the systems' own forces integrated exactly (:func:`held_flow_map`)."""
    if own is not None:
        return float(np.max(np.abs(np.linalg.eigvals(held_flow_map(Ap, Ad, own[0], own[1], H, hold, exchange)))))
    n = Ap.shape[0]
    I = np.eye(n)
    if exchange == "implicit":
        # f = -(Ap x + Ad v): [x'; v'] solves L [x'; v'] = R [x; v] with f' = -(Ap x' + Ad v')
        a, b = (1.0 / 3.0, 1.0 / 6.0) if hold == "foh" else (0.25, 0.25)
        Lm = np.block([[I + b * H * H * Ap, b * H * H * Ad], [0.5 * H * Ap, I + 0.5 * H * Ad]])
        Rm = np.block([[I - a * H * H * Ap, H * I - a * H * H * Ad], [-0.5 * H * Ap, I - 0.5 * H * Ad]])
        Phi = np.linalg.solve(Lm, Rm)
    elif hold == "foh":
        # f = -(Ap x + Ad v), slope (f - f_prev)/H:  x' = x + H v + 2H^2/3 f - H^2/6 f_prev,
        # v' = v + 3H/2 f - H/2 f_prev, f_prev' = f
        Fx, Fv, Z = -Ap, -Ad, np.zeros((n, n))
        Phi = np.block([[I + (2.0 * H * H / 3.0) * Fx, H * I + (2.0 * H * H / 3.0) * Fv, -(H * H / 6.0) * I],
                        [1.5 * H * Fx, I + 1.5 * H * Fv, -0.5 * H * I],
                        [Fx, Fv, Z]])
    else:
        Phi = np.block([[I - 0.5 * H * H * Ap, H * I - 0.5 * H * H * Ad], [-H * Ap, I - H * Ad]])
    return float(np.max(np.abs(np.linalg.eigvals(Phi))))


def _bisect_radius(Ap, Ad, scale, hold: str = "zoh", exchange: str = "explicit", own=None):
    """Largest H with radius <= 1 (bisection from a step known stable or 0). The
    zero-order hold doubles from 1/scale; the first-order hold scans in steps of
    1/(64 scale) up to the first unstable step (its stable range ends at
    omega H < 1.7, and doubling could step over it); the implicit exchange with the
    zero-order hold (the mean) is A-stable (inf; with the systems' own stiffness too: radius 1 to
    round-off measured up to omega H = 100 on the pendulum pair), with the line it scans as the
    first-order hold. ``own``: the systems' own forces (:func:`held_flow_map`)."""
    if exchange == "implicit" and hold == "zoh":
        return math.inf

    def ok(H):
        return hold_map_radius(Ap, Ad, H, hold, exchange, own) <= 1.0 + 1e-12
    if hold == "zoh":
        lo, hi = 0.0, 1.0 / scale
        while ok(hi):
            lo, hi = hi, 2.0 * hi
            if hi > 1e6 / scale:
                return math.inf
    else:
        lo, step = 0.0, 1.0 / (64.0 * scale)
        hi = step
        while ok(hi):
            lo, hi = hi, hi + step
            if hi > 64.0 / scale:
                return math.inf
    if not ok(hi * 1e-6):
        return 0.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return lo


def hold_bound(zeta: float, hold: str = "zoh", exchange: str = "explicit") -> float:
    """The limit of ``omega H`` of a scalar mode with damping ratio ``zeta`` under
    the hold (``zoh``: min(4 zeta, 1/zeta); ``foh``: from the hold map; implicit: from
    its map, inf for the mean)."""
    if hold == "zoh" and exchange == "explicit":
        return zoh_bound(zeta)
    if hold not in HOLDS:
        raise ValueError(f"hold must be one of {', '.join(HOLDS)}, got {hold!r}")
    return _bisect_radius(np.array([[1.0]]), np.array([[2.0 * zeta]]), 1.0, hold, exchange)


def exchange_limit(M, Kp, Kd, H: float, A=None, step_name: str = "H", hold: str = "zoh",
                   exchange: str = "explicit", own=None) -> ExchangeLimit:
    """The stability limit of the held coupling (see the module docstring).

    ``M``: the (common) mass matrix; ``Kp, Kd``: gains (scalars or n x n);
    ``A``: graph weights (default: a pair with weight 1); ``hold``: ``"zoh"``
    or ``"foh"`` (first-order hold of the master); ``exchange``: ``"explicit"`` or
    the master's ``"implicit"``; ``own``: ``(K, C)``, the systems' own stiffness and damping,
    integrated by the systems inside the step (the co-simulation's slaves): the map is then
    :func:`held_flow_map` (a K or C that is not positive semidefinite, a system unstable by
    itself, is left out: its growth is the system's, not the exchange's)."""
    if hold not in HOLDS:
        raise ValueError(f"hold must be one of {', '.join(HOLDS)}, got {hold!r}")
    check_exchange_name(exchange)
    M = np.atleast_2d(np.asarray(M, dtype=np.float64))
    n = M.shape[0]
    Kp = np.asarray(Kp, dtype=np.float64)
    Kd = np.asarray(Kd, dtype=np.float64)
    Kp = Kp * np.eye(n) if Kp.ndim == 0 else 0.5 * (Kp + Kp.T)
    Kd = Kd * np.eye(n) if Kd.ndim == 0 else 0.5 * (Kd + Kd.T)
    lams = laplacian_modes([[0.0, 1.0], [1.0, 0.0]] if A is None else A)
    H = float(H)
    # M-orthonormal coordinates: M = L L^T, Kp~ = L^-1 Kp L^-T
    Lc = np.linalg.cholesky(M)
    Li = np.linalg.inv(Lc)
    kp_t = Li @ Kp @ Li.T
    kd_t = Li @ Kd @ Li.T
    kappa, V = np.linalg.eigh(kp_t)
    D = V.T @ kd_t @ V
    off = D - np.diag(np.diag(D))
    modal = np.max(np.abs(off), initial=0.0) <= 1e-9 * max(1e-300, np.max(np.abs(D), initial=0.0))
    own_m, own_w = _own_forces(M, own)
    modal = modal and own_m is None
    best = None  # (H_max, omega, zeta, bound, lam)
    for lam in lams:
        if modal:
            for kp, kd in zip(np.maximum(kappa, 0.0), np.diag(D)):
                w = math.sqrt(lam * kp)
                if w > 0.0:
                    zeta = lam * kd / (2.0 * w)
                    bound = hold_bound(zeta, hold, exchange)
                    H_max = bound / w
                elif kd > 0.0:
                    # ZOH: lam kd H < 2; FOH (the Adams-Bashforth-2 map of v' = -lam kd v): < 1;
                    # implicit: v' = v - lam kd H (v + v')/2, the trapezoidal rule: any H
                    zeta = math.inf
                    bound = math.inf if exchange == "implicit" else (2.0 if hold == "zoh" else 1.0)
                    H_max = bound / (lam * kd)
                else:
                    continue
                if best is None or H_max < best[0]:
                    best = (H_max, w, zeta, bound, lam)
        else:
            Minv = np.linalg.inv(M)
            Ap, Ad = lam * Minv @ Kp, lam * Minv @ Kd
            if own_m is not None and not (np.any(Ap) or np.any(Ad)):
                continue
            w = math.sqrt(max(float(np.max(np.linalg.eigvals(Ap).real)), 0.0))
            scale = math.sqrt(w * w + own_w) if own_m is not None else w
            H_max = _bisect_radius(Ap, Ad, max(scale, 1e-300), hold, exchange, own_m)
            bound = w * H_max if math.isfinite(H_max) else math.inf
            zeta = Ad[0, 0] / (2.0 * w) if n == 1 and w > 0.0 else math.nan   # one DOF: the mode's own zeta
            if best is None or H_max < best[0]:
                best = (H_max, w, zeta, bound, lam)
    if best is None:
        return ExchangeLimit(H, 0.0, math.nan, math.inf, math.inf, 0.0, step_name, hold, exchange)
    H_max, w, zeta, bound, lam = best
    return ExchangeLimit(H, w, zeta, bound, H_max, lam, step_name, hold, exchange, own_w)


def _own_forces(M, own):
    """``((M^-1 K, M^-1 C), largest eigenvalue of M^-1 K)`` of the systems' own forces for
    :func:`held_flow_map`, or ``(None, 0.0)`` when there are none (or they are not positive
    semidefinite: a system unstable by itself)."""
    if own is None:
        return None, 0.0
    n = M.shape[0]
    K, C = (np.asarray(x, dtype=np.float64) * (np.eye(n) if np.ndim(x) == 0 else 1.0) for x in own)
    K, C = 0.5 * (K + K.T), 0.5 * (C + C.T)
    if not (np.any(K) or np.any(C)):
        return None, 0.0
    if min(np.linalg.eigvalsh(K).min(), np.linalg.eigvalsh(C).min()) < -1e-12 * max(1.0, np.abs(K).max()):
        return None, 0.0
    Minv = np.linalg.inv(M)
    Ks = Minv @ K
    return (Ks, Minv @ C), max(float(np.max(np.linalg.eigvals(Ks).real)), 0.0)


def check_exchange(M, Kp, Kd, H: float, A=None, allow_unstable: bool = False,
                   step_name: str = "H", hold: str = "zoh", exchange: str = "explicit", own=None) -> ExchangeLimit:
    """:func:`exchange_limit`, refused with :class:`UnstableExchange` when unstable
    (``H >= H_max``) unless ``allow_unstable``. The co-simulation's refusal (``step_name``
    ``"H"``) of the explicit exchange names ``exchange="implicit"`` as the fix."""
    lim = exchange_limit(M, Kp, Kd, H, A, step_name, hold, exchange, own)
    if not lim.stable and not allow_unstable:
        implicit = (f"use exchange=\"implicit\" (iterated to the states at the step's end, stable at any "
                    f"{step_name} with hold='zoh'), " if step_name == "H" and exchange == "explicit" else "")
        raise UnstableExchange(
            f"refused before the first step: the {exchange} exchange is unstable: {lim.message()}. "
            f"Lower Kp or {step_name}, add Kd, {implicit}or pass allow_unstable=True to run anyway "
            f"(the run then stops as failed when it diverges).")
    return lim
