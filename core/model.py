"""Mechanical systems with one affine unilateral constraint (docs/design.md §2.1).

    dq = u dt
    M du - h(q, u, tau, t) dt = w (lambda dt + Lambda deta)
    g(q) = w^T q + g0 >= 0

with the built-in force law

    h = -K q - C u + f0 + sum_j F_j cos(Omega_j t + phi_j) + B tau.

The classes here only hold and validate data; every numerical kernel takes the
plain arrays returned by :meth:`MechanicalSystem.arrays` so that numba sees
nothing but float64 arrays and scalars.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .declaration import POSITIVE_MIN, Model, ModelError, Param

__all__ = ["MechanicalSystem", "ImpactOscillator", "SystemArrays", "as_state", "IMPACT_OSCILLATOR",
           "MECHANICAL_SYSTEM"]


class SystemArrays(NamedTuple):
    """The system as the compiled kernels see it (all float64, C-contiguous).

    Order and names are the positional arguments of every kernel in the core.
    """

    M: np.ndarray        # (n, n) mass matrix
    Minv: np.ndarray     # (n, n) its inverse
    K: np.ndarray        # (n, n) stiffness
    C: np.ndarray        # (n, n) damping
    f0: np.ndarray       # (n,) constant force
    F: np.ndarray        # (nf, n) harmonic force amplitudes
    Omega: np.ndarray    # (nf,) angular frequencies
    phi: np.ndarray      # (nf,) phases
    B: np.ndarray        # (n, m) input matrix
    w: np.ndarray        # (n,) constraint direction, g = w^T q + g0
    g0: float
    e: float             # Newton restitution coefficient in [0, 1]
    Minv_w: np.ndarray   # (n,) M^-1 w
    W: float             # w^T M^-1 w > 0


def _matrix(name: str, value, n: int | None) -> np.ndarray:
    a = np.array(value, dtype=np.float64, ndmin=2)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"{name} must be a square matrix, got shape {np.shape(value)}")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"{name} must be {n}x{n} to match M, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    return np.ascontiguousarray(a)


def _vector(name: str, value, n: int) -> np.ndarray:
    a = np.array(value, dtype=np.float64, ndmin=1).reshape(-1)
    if a.shape != (n,):
        raise ValueError(f"{name} must have {n} entries to match M, got shape {np.shape(value)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    return np.ascontiguousarray(a)


def _scalar(name: str, value) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    return x


@dataclass(frozen=True)
class MechanicalSystem:
    """n-DOF system with one affine unilateral constraint ``g(q) = w^T q + g0 >= 0``.

    Parameters
    ----------
    M, K, C : (n, n) array_like
        Mass (symmetric positive definite), stiffness and damping matrices.
    f0 : (n,) array_like
        Constant force.
    w : (n,) array_like, nonzero
        Constraint direction (generalized force direction of the wall).
    g0 : float
        Constraint offset.
    e : float in [0, 1]
        Newton restitution coefficient.
    forcing : sequence of (F, Omega, phi)
        Harmonic forces ``F cos(Omega t + phi)`` with ``F`` of shape (n,).
    B : (n, m) array_like, optional
        Input matrix of the control forces tau (default identity, m = n).
    force : ForceLaw, optional
        A user force law ``h(q, u, tau, t, p)`` (:class:`fmu_sync.core.forcelaw.ForceLaw`,
        docs/user-model.md) in place of the built-in linear law; K, C, f0, forcing and B are
        then left out: ``K`` becomes the stiffness of the metric (the law's, docs/design.md
        §2.7.2), ``C`` its declared linear damping (zeros if none), B = I, and the packed
        arrays carry the law's linear part (the θ-scheme's implicit part).
    params : mapping, optional
        The law's parameter values (missing names take their defaults; each is checked
        against its declared range). ``system.p`` is the checked parameter array.
    """

    M: np.ndarray
    K: np.ndarray | None = None
    C: np.ndarray | None = None
    f0: np.ndarray | None = None
    w: np.ndarray | None = None
    g0: float = 0.0
    e: float = 0.0
    forcing: tuple = ()
    B: np.ndarray | None = None
    force: object = None
    params: object = None
    _arrays: SystemArrays = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        M = _matrix("M", self.M, None)
        n = M.shape[0]
        if not np.all(np.abs(M - M.T) <= 1e-12 * np.abs(M.T)):   # np.allclose(M, M.T, rtol=1e-12, atol=0): M is finite
            raise ValueError(f"M must be symmetric, got {M.tolist()}")
        eig = np.linalg.eigvalsh(M)
        if eig[0] <= 0.0:
            raise ValueError(
                f"M must be positive definite, got smallest eigenvalue {eig[0]:.6g} for M = {M.tolist()}")
        if self.w is None:
            raise ValueError("w (the wall's normal, g = w^T q + g0) is required")
        law, p, KL, CL = self._law(n)
        object.__setattr__(self, "_metric_source", None)
        if law is not None:
            Km, source = law.metric_stiffness(p)
            object.__setattr__(self, "_metric_source", source)
            object.__setattr__(self, "K", Km)
            object.__setattr__(self, "C", CL)
            object.__setattr__(self, "f0", np.zeros(n))
            object.__setattr__(self, "forcing", law.forcing_terms(p))   # the law's declared forcing
        for name in ("K", "C", "f0"):
            if getattr(self, name) is None:
                raise ValueError(f"{name} is required for the built-in linear law (or give force=ForceLaw)")
        K = _matrix("K", self.K, n)
        C = _matrix("C", self.C, n)
        f0 = _vector("f0", self.f0, n)
        w = _vector("w", self.w, n)
        if not np.any(w != 0.0):
            raise ValueError(f"w must be nonzero (it is the wall's normal), got {w.tolist()}")
        g0 = _scalar("g0", self.g0)
        e = _scalar("e", self.e)
        if not 0.0 <= e <= 1.0:
            raise ValueError(f"e (restitution) must lie in [0, 1], got {e}")
        Fs, Om, ph = [], [], []
        for j, term in enumerate(self.forcing):
            try:
                Fj, Omj, phj = term
            except (TypeError, ValueError):
                raise ValueError(f"forcing[{j}] must be a triple (F, Omega, phi), got {term!r}") from None
            Fs.append(_vector(f"forcing[{j}].F", Fj, n))
            Om.append(_scalar(f"forcing[{j}].Omega", Omj))
            ph.append(_scalar(f"forcing[{j}].phi", phj))
        F = np.ascontiguousarray(np.array(Fs, dtype=np.float64).reshape(len(Fs), n))
        Omega = np.array(Om, dtype=np.float64)
        phi = np.array(ph, dtype=np.float64)
        if self.B is None:
            B = np.eye(n)
        else:
            B = np.array(self.B, dtype=np.float64, ndmin=2)
            if B.shape[0] != n:
                raise ValueError(f"B must have {n} rows to match M, got shape {B.shape}")
            if not np.all(np.isfinite(B)):
                raise ValueError(f"B must be finite, got {B.tolist()}")
            B = np.ascontiguousarray(B)
        Minv = np.ascontiguousarray(np.linalg.inv(M))
        Minv_w = np.ascontiguousarray(Minv @ w)
        W = float(w @ Minv_w)
        for name, val in (("M", M), ("K", K), ("C", C), ("f0", f0), ("w", w), ("g0", g0),
                          ("e", e), ("B", B)):
            object.__setattr__(self, name, val)
        object.__setattr__(self, "forcing", tuple(zip(map(tuple, F), Om, ph)))
        object.__setattr__(self, "_p", p)
        object.__setattr__(self, "_arrays", SystemArrays(
            M, Minv, K if law is None else KL, C, f0, F, Omega, phi, B, w, g0, e, Minv_w, W))

    def _law(self, n):
        """``(law, p, K_L, C_L)`` of a user force law (None, empty, None, None without one)."""
        law = self.force
        if law is None:
            if self.params is not None:
                raise ValueError("params= gives a force law's parameter values: pass force= too")
            return None, np.zeros(0), None, None
        if not all(hasattr(law, a) for a in ("values", "kernels", "linear_part", "metric_stiffness")):
            # a ForceLaw (core/forcelaw.py, not imported here: it compiles into loops that use this module)
            raise ValueError(f"force must be a ForceLaw (fmu_sync.core.ForceLaw), got {law!r}")
        if law.n != n:
            raise ValueError(f"force law {law.name!r} has n = {law.n} degrees of freedom, M is {n}x{n}")
        given = [k for k in ("K", "C", "f0", "B") if getattr(self, k) is not None]
        if given or self.forcing:
            raise ValueError(f"with force law {law.name!r}, leave out {given or ['forcing']}: the law is the "
                             f"whole force (its linear part: ForceLaw(linear=...))")
        p = law.values(self.params)
        KL, CL = law.linear_part(p)
        return law, p, KL, CL

    @property
    def metric_source(self) -> str | None:
        """How the metric's stiffness ``K`` of a user force law was obtained (a key of
        ``forcelaw.METRIC_SOURCES``); None for the built-in linear law (K is its stiffness)."""
        return self._metric_source

    @property
    def p(self) -> np.ndarray:
        """The force law's checked parameter array (empty for the built-in linear law)."""
        return self._p

    # ------------------------------------------------------------------ views
    @property
    def n(self) -> int:
        """Number of degrees of freedom."""
        return self.M.shape[0]

    @property
    def n_inputs(self) -> int:
        """Number of inputs tau (columns of B). (There is no ``.m``: the mass is ``M``.)"""
        return self.B.shape[1]

    def arrays(self) -> SystemArrays:
        """The packed float64 arrays every compiled kernel takes."""
        return self._arrays

    def gap(self, q) -> float:
        """g(q) = w^T q + g0."""
        return float(self.w @ np.asarray(q, dtype=np.float64).reshape(self.n) + self.g0)

    def omega_max(self) -> float:
        """Largest undamped natural frequency sqrt(eig(M^-1 K)) (0 if K has none)."""
        ev = np.linalg.eigvals(self._arrays.Minv @ self.K)
        return float(np.sqrt(np.max(np.abs(ev)))) if ev.size else 0.0

    def energy(self, q, u) -> float:
        """Mechanical energy 1/2 u^T M u + 1/2 q^T K q - f0^T q (no forcing, no input)."""
        q = np.asarray(q, dtype=np.float64).reshape(self.n)
        u = np.asarray(u, dtype=np.float64).reshape(self.n)
        return float(0.5 * u @ self.M @ u + 0.5 * q @ self.K @ q - self.f0 @ q)


def ImpactOscillator(m: float = 1.0, k: float = 0.0, c: float = 0.0, f0: float = 0.0,
                     F: float = 0.0, Omega: float = 0.0, e: float = 0.0,
                     phi: float = 0.0, g0: float = 0.0) -> MechanicalSystem:
    """1-DOF impact oscillator ``m q'' + c q' + k q = f0 + F cos(Omega t + phi) + tau`` with the
    wall ``g(q) = q + g0 >= 0`` (w = 1; the wall stands at q = -g0, default 0).

    Positions stay in the user's coordinates: the spring is relaxed at q = 0 whatever g0 is.
    The same motion in gap coordinates x = q + g0 is the oscillator with g0 = 0, constant
    force f0 + k g0 and start position q0 + g0 (docs/design.md §2.1).
    """
    m = _scalar("m", m)
    if m <= 0.0:
        raise ValueError(f"m (mass) must be > 0, got {m}")
    forcing = ((F, Omega, phi),) if _scalar("F", F) != 0.0 else ()
    return MechanicalSystem(M=[[m]], K=[[_scalar("k", k)]], C=[[_scalar("c", c)]],
                            f0=[_scalar("f0", f0)], w=[1.0], g0=g0, e=e, forcing=forcing)


# ---------------------------------------------------------------- the built-in declarations
# (docs/design.md §2.1.1): each parameter once; the FMU (fmus/contract.py), the scenes
# (fmu_sync/scenes/schema.py) and the docs read them from here.

def _one_term(s: MechanicalSystem, what: str):
    if len(s.forcing) > 1:
        raise ModelError(f"the {what} takes one forcing term, the system has {len(s.forcing)}")
    return s.forcing[0] if s.forcing else None


def _io_values(s: MechanicalSystem) -> dict:
    """Parameter values of a 1-DOF system with w = 1 (inverse of ImpactOscillator)."""
    if s.n != 1:
        raise ModelError(f"the impact-oscillator FMU has 1 degree of freedom, the system has {s.n}")
    if float(s.w[0]) != 1.0:
        raise ModelError(f"the impact-oscillator FMU has the wall g(q) = q + g0 (w = 1), "
                         f"the system has w = {s.w.tolist()}")
    term = _one_term(s, "FMU")
    out = {"m": float(s.M[0, 0]), "k": float(s.K[0, 0]), "c": float(s.C[0, 0]),
           "f0": float(s.f0[0]), "F": float(term[0][0]) if term else 0.0}
    if term:
        out.update(Omega=float(term[1]), phi=float(term[2]))
    out.update(e=float(s.e), g0=float(s.g0))
    return out


def _ms_values(s: MechanicalSystem) -> dict:
    """Parameter values of an n-DOF system (inverse of MechanicalSystem)."""
    return {"M": s.M.tolist(), "K": s.K.tolist(), "C": s.C.tolist(), "f0": s.f0.tolist(),
            "forcing": [(list(F), Om, ph) for F, Om, ph in s.forcing], "w": s.w.tolist(),
            "g0": float(s.g0), "e": float(s.e)}


def _ms_system(p) -> MechanicalSystem:
    n = len(p.M)
    z = np.zeros((n, n))
    return MechanicalSystem(M=p.M, K=z if p.K is None else p.K, C=z if p.C is None else p.C,
                            f0=np.zeros(n) if p.f0 is None else p.f0, w=p.w, g0=p.g0, e=p.e,
                            forcing=tuple(p.forcing or ()))


_E = Param("e", None, "1", 0.0, 1.0, "Newton restitution coefficient at the wall")
_HARMONIC = "Amplitude of the harmonic force F cos(Omega t + phi)"

#: 1-DOF impact oscillator (ImpactOscillator); the FMU ImpactOscillator.
IMPACT_OSCILLATOR = Model(
    name="impact-oscillator",
    description=("1-DOF impact oscillator m q'' + c q' + k q = f0 + F cos(Omega t + phi) + tau, "
                 "q + g0 >= 0, Newton restitution e"),
    params=(Param("m", 1.0, "kg", POSITIVE_MIN, None, "Mass (> 0)"),
            Param("k", 0.0, "N/m", 0.0, None, "Spring stiffness"),
            Param("c", 0.0, "N.s/m", 0.0, None, "Viscous damping"),
            Param("f0", 0.0, "N", None, None, "Constant force"),
            Param("F", 0.0, "N", None, None, _HARMONIC),
            Param("Omega", 0.0, "rad/s", 0.0, None, "Angular frequency of the harmonic force"),
            Param("phi", 0.0, "rad", None, None, "Phase of the harmonic force"),
            _E,
            Param("g0", 0.0, "m", None, None, "Wall offset g0 in g(q) = q + g0 (the wall stands at q = -g0)")),
    system=lambda p: ImpactOscillator(**p), n=1, geometry=("m", "g0", "e"), values=_io_values)

#: n-DOF mechanical system (MechanicalSystem with the linear force law); the FMU MechanicalSystem2.
MECHANICAL_SYSTEM = Model(
    name="mechanical-system",
    description=("n-DOF mechanical system M q'' + C q' + K q = f0 + sum F cos(Omega t + phi) + tau "
                 "with the unilateral constraint w^T q + g0 >= 0 and Newton restitution e"),
    params=(Param("M", None, "kg", POSITIVE_MIN, None, "Mass matrix (symmetric positive definite)",
                  ("n", "n"), required=True),
            Param("K", None, "N/m", 0.0, None, "Stiffness matrix", ("n", "n")),
            Param("C", None, "N.s/m", 0.0, None, "Damping matrix", ("n", "n")),
            Param("f0", None, "N", None, None, "Constant force", ("n",)),
            Param("forcing", (), "1", None, None, "Harmonic forces F cos(Omega t + phi) (F in N, Omega "
                  "in rad/s, phi in rad)", ("terms",)),
            Param("w", None, "1", None, None, "Wall normal w in g(q) = w^T q + g0 (not zero)", ("n",),
                  required=True),
            Param("g0", 0.0, "m", None, None, "Wall offset g0 in g(q) = w^T q + g0"),
            _E),
    system=_ms_system, geometry=("M", "w", "g0", "e"), values=_ms_values)



def as_state(system: MechanicalSystem, x, name: str = "x0"):
    """Normalise a state ``(q, u)`` (floats for 1-DOF, or arrays) to two float64 (n,) arrays."""
    try:
        q, u = x
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (q, u), got {x!r}") from None
    n = system.n
    q = np.array(q, dtype=np.float64, ndmin=1).reshape(-1)
    u = np.array(u, dtype=np.float64, ndmin=1).reshape(-1)
    if q.shape != (n,) or u.shape != (n,):
        raise ValueError(f"{name} = (q, u) must hold {n} entries each, got shapes {q.shape} and {u.shape}")
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(u))):
        raise ValueError(f"{name} must be finite, got q = {q.tolist()}, u = {u.tolist()}")
    return q, u
