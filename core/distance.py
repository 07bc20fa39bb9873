"""Quotient distance between two states of the same system (docs/design.md §2.4).

Norm on states: ``||x||_P^2 = q^T Q q + u^T M u``.  Every pre-impact boundary
state ``y in dA- = {g(q) = 0, w^T u <= 0}`` is identified with its post-impact
image ``Zbar(y) = (q, Z u)``, ``Z u = u - (1+e) M^-1 w min(0, w^T u) / W``.
The quotient pseudometric is

    d(x1, x2) = min{ E, J(x1, x2), J(x2, x1), J2(x1, x2) }
    E         = ||x1 - x2||_P
    J(a, b)   = min_{y in dA-}      ||a - y|| + ||Zbar(y) - b||
    J2(a, b)  = min_{y1, y2 in dA-} ||a - y1|| + ||Zbar(y1) - Zbar(y2)|| + ||y2 - b||

Exact reduction to a plane
--------------------------
In the coordinates ``q~ = Q^(1/2) q``, ``u~ = M^(1/2) u`` the norm is Euclidean,
the wall ``g = 0`` is a hyperplane in ``q~`` and ``Z`` only acts on the normal
component of ``u~``.  Each state splits into

* normal coordinates ``X = g(q) / sqrt(WQ)`` (``WQ = w^T Q^-1 w``: signed
  distance to the wall in the Q-metric) and ``Y = w^T u / sqrt(W)`` (normal
  velocity in the M-metric), and
* a tangential part ``T = (q_par, u_t)`` on which ``Zbar`` is the identity and
  on which ``dA-`` places no constraint.

Minimising over the free tangential points of a chain whose k segments have
normal "heights" ``r_1..r_k`` gives ``sqrt(D^2 + (r_1 + ... + r_k)^2)`` with
``D = |T1 - T2|`` (Minkowski; attained with the tangential points spaced in
proportion to ``r_i``).  Hence, exactly, for every branch

    d_nDOF(x1, x2) = sqrt(D^2 + d_2D(a, b)^2),  a = (X1, Y1), b = (X2, Y2),

where ``d_2D`` is the same distance for the planar problem: wall ``X = 0``,
``dA- = {(0, s): s <= 0}``, ``Zbar(0, s) = (0, -e s)``.  ``D^2`` is computed from
the Q-/M-orthogonal projections of ``x1 - x2`` onto the tangential directions
(never as ``E^2 - E_2D^2``, which cancels).  For n = 1, ``D = 0``.

Planar branches: :mod:`.distance_planar` (J by safeguarded Newton, J2 in closed form,
lower bounds that prune branches).

Chain ends (used by the coupling law, docs/design.md §2.5): E: ``c1 = x2, c2 = x1``;
J12: ``c1 = y, c2 = Zbar(y)``; J21: ``c1 = Zbar(y), c2 = y``; J2: ``c1 = y1,
c2 = y2``.  The shortest chain is then ``x1 -> c1 ~ ... ~ c2 -> x2``.

Kernels
-------
All are ``@njit(cache=True, error_model="numpy")`` (IEEE arithmetic, no
exceptions inside a simulation loop), nopython and allocation-free:

* :func:`distance_kernel` (any n, arrays; fills the chain ends),
  :func:`distance_value` (d and branch only) -- take a :class:`DistanceGeometry`
  built once in Python by :func:`geometry` / :func:`make_geometry`;
* :func:`distance1` -- the 1-DOF kernel on floats (``geo.scalar``), for loops
  that hold a 1-DOF state in scalars; the array kernels call it for n = 1;
* :func:`distance_2d`, :func:`branch_values_2d` -- the planar core (:mod:`.distance_planar`).

Python API: :func:`quotient_distance`.
"""
from __future__ import annotations

import math
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np
from .jit import njit

from .model import MechanicalSystem, SystemArrays, as_state
from .checks import check_admissible
from .distance_planar import (BRANCH_E, BRANCH_J12, BRANCH_J21, BRANCH_J2, BRANCH_NAMES, BRANCH_FREE,
                              branch_values_2d, core_2d, distance_2d)

__all__ = [
    "BRANCH_E", "BRANCH_J12", "BRANCH_J21", "BRANCH_J2", "BRANCH_NAMES", "BRANCH_FREE",
    "DistanceGeometry", "ScalarGeometry", "DistanceResult", "geometry", "make_geometry",
    "distance_2d", "branch_values_2d", "distance_kernel", "distance1", "distance_value", "distance_kernel_unpruned",
    "quotient_distance",
]


class ScalarGeometry(NamedTuple):
    """The float parameters of the geometry (a tuple of floats only).

    The planar core and the scalar 1-DOF kernels take this instead of
    :class:`DistanceGeometry`: passing a tuple that holds arrays into a compiled
    function costs numba reference-count updates on every call (~100 ns
    measured), floats cost nothing.  ``w1, Minv_w1, Qinv_w1, Q11, M11`` are the
    first entries of the arrays (the whole data when n = 1).
    """

    g0: float
    e: float
    W: float             # w^T M^-1 w
    WQ: float            # w^T Q^-1 w
    sqrtW: float
    sqrtWQ: float
    w1: float
    Minv_w1: float
    Qinv_w1: float
    Q11: float
    M11: float
    k: float             # e / sqrt(1 - e^2), inf for e = 1 (Snell bound of J)


class DistanceGeometry(NamedTuple):
    """Everything the distance kernels need, as float64 arrays and floats.

    Build it with :func:`geometry` (from a system) or :func:`make_geometry`
    (from raw M, w, g0, e, e.g. parameters read from an FMU).
    """

    Q: np.ndarray        # (n, n) SPD weight of positions in ||.||_P
    M: np.ndarray        # (n, n) mass matrix (weight of velocities)
    w: np.ndarray        # (n,) wall normal, g(q) = w^T q + g0
    g0: float
    e: float             # restitution coefficient in [0, 1]
    Minv_w: np.ndarray   # (n,) M^-1 w
    W: float             # w^T M^-1 w
    Qinv_w: np.ndarray   # (n,) Q^-1 w
    WQ: float            # w^T Q^-1 w
    sqrtW: float         # sqrt(W)
    sqrtWQ: float        # sqrt(WQ)
    scalar: ScalarGeometry  # the float parameters again, for the array-free kernels


class DistanceResult(NamedTuple):
    """Distance with its branch name and chain ends ``c1, c2`` (each a (q, u) pair)."""

    d: float
    branch: str
    c1: tuple
    c2: tuple


# ---------------------------------------------------------------- validation
def _spd(name: str, value, n: int | None, allow_scalar: bool) -> np.ndarray:
    """Validate a symmetric positive definite matrix (or a positive scalar times I)."""
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive scalar or an SPD matrix, got {value!r}") from None
    if a.ndim == 0:
        if not allow_scalar:
            raise ValueError(f"{name} must be a square matrix, got the scalar {float(a)}")
        s = float(a)
        if not (math.isfinite(s) and s > 0.0):
            raise ValueError(f"{name} must be a positive finite scalar or an SPD matrix, got {s}")
        if n is None:
            raise ValueError(f"{name}: a scalar needs a known dimension")
        return np.eye(n) * s
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"{name} must be a square matrix, got shape {a.shape}")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"{name} must be {n}x{n} (or a positive scalar), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    scale = float(np.max(np.abs(a))) if a.size else 0.0
    if not np.allclose(a, a.T, rtol=0.0, atol=1e-12 * scale):
        raise ValueError(f"{name} must be symmetric, got {a.tolist()}")
    a = 0.5 * (a + a.T)
    eig = np.linalg.eigvalsh(a)
    if not eig[0] > 0.0:
        raise ValueError(f"{name} must be positive definite, got smallest eigenvalue {eig[0]:.6g} "
                         f"for {name} = {a.tolist()}")
    return np.ascontiguousarray(a)


def make_geometry(M, w, g0, e, Q=None) -> DistanceGeometry:
    """Geometry from raw data: mass matrix ``M``, wall ``g(q) = w^T q + g0``,
    restitution ``e`` and position weight ``Q`` (positive scalar or n x n SPD,
    default identity).  Raises ValueError naming the offending argument."""
    M = _spd("M", M, None, allow_scalar=False)
    n = M.shape[0]
    w = np.array(w, dtype=np.float64, ndmin=1).reshape(-1)
    if w.shape != (n,):
        raise ValueError(f"w must have {n} entries to match M, got shape {w.shape}")
    if not np.all(np.isfinite(w)) or not np.any(w != 0.0):
        raise ValueError(f"w must be finite and nonzero, got {w.tolist()}")
    try:
        g0 = float(g0)
        e = float(e)
    except (TypeError, ValueError):
        raise ValueError(f"g0 and e must be real numbers, got g0={g0!r}, e={e!r}") from None
    if not math.isfinite(g0):
        raise ValueError(f"g0 must be finite, got {g0}")
    if not 0.0 <= e <= 1.0:
        raise ValueError(f"e (restitution) must lie in [0, 1], got {e}")
    Q = np.eye(n) if Q is None else _spd("Q", Q, n, allow_scalar=True)
    Minv_w = np.ascontiguousarray(np.linalg.solve(M, w))
    Qinv_w = np.ascontiguousarray(np.linalg.solve(Q, w))
    W = float(w @ Minv_w)
    WQ = float(w @ Qinv_w)
    sg = ScalarGeometry(g0, e, W, WQ, math.sqrt(W), math.sqrt(WQ), float(w[0]), float(Minv_w[0]),
                        float(Qinv_w[0]), float(Q[0, 0]), float(M[0, 0]),
                        e / math.sqrt(1.0 - e * e) if e < 1.0 else math.inf)
    return DistanceGeometry(np.ascontiguousarray(Q), np.ascontiguousarray(M), np.ascontiguousarray(w),
                            g0, e, Minv_w, W, Qinv_w, WQ, sg.sqrtW, sg.sqrtWQ, sg)


def geometry(system, Q=None) -> DistanceGeometry:
    """Distance geometry of a :class:`MechanicalSystem` (or its :class:`SystemArrays`)
    with position weight ``Q``: a positive scalar (``Q I``) or an n x n SPD
    matrix; default identity."""
    if isinstance(system, MechanicalSystem):
        sa = system.arrays()
    elif isinstance(system, SystemArrays):
        sa = system
    else:
        raise ValueError(f"system must be a MechanicalSystem or SystemArrays, got {type(system).__name__}")
    return make_geometry(sa.M, sa.w, sa.g0, sa.e, Q)


def resolve_geometry(system, Q):
    """DistanceGeometry from a system (with Q) or a ready DistanceGeometry."""
    if isinstance(system, DistanceGeometry):
        if Q is not None:
            raise ValueError("Q must be None when a DistanceGeometry is given (it already holds Q)")
        return system
    return geometry(system, Q)


def geometry_state(geo: DistanceGeometry, x, name: str):
    return as_state(SimpleNamespace(n=geo.w.shape[0]), x, name)


# --------------------------------------------------------------- n-DOF kernels
# Chain ends in one affine form:  c_k = ((1-mu_k) q1 + mu_k q2 - gam_k Q^-1 w,
#                                        (1-mu_k) u1 + mu_k u2 + del_k M^-1 w)
# E: mu1 = 1, mu2 = 0 (c1 = x2, c2 = x1 exactly).  A boundary point y at
# tangential fraction lam with normal velocity Y = s: mu = lam,
# gam = g(q~)/WQ (projection onto g = 0 along Q^-1 w, g is affine so
# g(q~) = (1-lam) g1 + lam g2), del = (s sqrt(W) - w^T u~)/W; Zbar(y) adds
# -(1+e) s / sqrt(W) to del.
#
# Cost note: numba updates reference counts (atomic operations) of every array
# passed into a non-inlined compiled function and of arrays read from tuples in
# branchy code: ~100-300 ns per call measured, against ~40 ns for the whole
# 1-DOF distance.  Hence: the planar core and the 1-DOF kernels take floats
# only (ScalarGeometry); the public array kernels are numba-inlined into their
# callers and dispatch n = 1 to the scalar kernels; outputs are written once,
# in straight-line loops after all branching.

@njit(cache=True, inline="always", error_model="numpy")
def _chain_params(sg, branch, s1, s2, lam1, lam2, g1, g2, wu1, wu2):
    """(mu1, gam1, del1, mu2, gam2, del2) of the chain ends (form above)."""
    mu1 = 1.0
    gam1 = 0.0
    del1 = 0.0
    mu2 = 0.0
    gam2 = 0.0
    del2 = 0.0
    if branch != BRANCH_E:
        mu1 = lam1
        gam1 = ((1.0 - lam1) * g1 + lam1 * g2) / sg.WQ
        del1 = (s1 * sg.sqrtW - ((1.0 - lam1) * wu1 + lam1 * wu2)) / sg.W
        jump = -(1.0 + sg.e) * s1 / sg.sqrtW      # Zbar: u -> u + jump M^-1 w
        if branch == BRANCH_J2:
            mu2 = lam2
            gam2 = ((1.0 - lam2) * g1 + lam2 * g2) / sg.WQ
            del2 = (s2 * sg.sqrtW - ((1.0 - lam2) * wu1 + lam2 * wu2)) / sg.W
        else:
            mu2 = lam1
            gam2 = gam1
            del2 = del1
            if branch == BRANCH_J12:    # c1 = y, c2 = Zbar(y)
                del2 += jump
            else:                       # c2 = y, c1 = Zbar(y)
                del1 += jump
    return mu1, gam1, del1, mu2, gam2, del2


@njit(cache=True, error_model="numpy")
def _distance_nd(geo, q1, u1, q2, u2, prune, fix=BRANCH_FREE):
    """``(d, branch, mu1, gam1, del1, mu2, gam2, del2)``: d via the planar
    problem, d = sqrt(D^2 + d_2D^2), and the chain ends in the form above
    (``fix``: the branch held, :func:`.distance_planar.core_2d`)."""
    n = q1.shape[0]
    sg = geo.scalar
    w = geo.w
    g1 = sg.g0
    g2 = sg.g0
    wu1 = 0.0
    wu2 = 0.0
    for i in range(n):
        g1 += w[i] * q1[i]
        g2 += w[i] * q2[i]
        wu1 += w[i] * u1[i]
        wu2 += w[i] * u2[i]
    wdq = 0.0
    wdu = 0.0
    for i in range(n):
        wdq += w[i] * (q1[i] - q2[i])
        wdu += w[i] * (u1[i] - u2[i])
    d, branch, s1, s2, lam1, lam2 = core_2d(g1 / sg.sqrtWQ, wu1 / sg.sqrtW, g2 / sg.sqrtWQ, wu2 / sg.sqrtW,
                                             wdq / sg.sqrtWQ, wdu / sg.sqrtW, sg.e, sg.k, prune, fix)
    if n > 1:
        # D^2 = |dq_par|_Q^2 + |du_t|_M^2 from the projections (no cancellation):
        # dq_par = dq - (w^T dq / WQ) Q^-1 w,  du_t = du - (w^T du / W) M^-1 w.
        Q = geo.Q
        M = geo.M
        Qinv_w = geo.Qinv_w
        Minv_w = geo.Minv_w
        cq = wdq / sg.WQ
        cu = wdu / sg.W
        D2 = 0.0
        for i in range(n):
            vq = (q1[i] - q2[i]) - cq * Qinv_w[i]
            vu = (u1[i] - u2[i]) - cu * Minv_w[i]
            rq = 0.0
            ru = 0.0
            for j in range(n):
                rq += Q[i, j] * ((q1[j] - q2[j]) - cq * Qinv_w[j])
                ru += M[i, j] * ((u1[j] - u2[j]) - cu * Minv_w[j])
            D2 += vq * rq + vu * ru
        d = math.sqrt(max(D2, 0.0) + d * d)
    mu1, gam1, del1, mu2, gam2, del2 = _chain_params(sg, branch, s1, s2, lam1, lam2, g1, g2, wu1, wu2)
    return d, branch, mu1, gam1, del1, mu2, gam2, del2


@njit(cache=True, error_model="numpy")
def distance1(sg, q1, u1, q2, u2, fix=BRANCH_FREE):
    """Scalar 1-DOF kernel: ``sg`` a :class:`ScalarGeometry` (``geo.scalar``),
    floats in and out, no arrays touched. ``fix``: :data:`BRANCH_FREE` (the
    distance: the shortest chain) or the branch whose chain is taken
    (:func:`.distance_planar.core_2d`).

    Returns ``(d, branch, c1q, c1u, c2q, c2u)``; same arithmetic as
    :func:`distance_kernel` (which calls it for n = 1), so the results agree
    bit for bit.  For compiled 1-DOF loops that hold the state in scalars.
    """
    g1 = sg.g0
    g1 += sg.w1 * q1
    g2 = sg.g0
    g2 += sg.w1 * q2
    wu1 = 0.0
    wu1 += sg.w1 * u1
    wu2 = 0.0
    wu2 += sg.w1 * u2
    wdq = 0.0
    wdq += sg.w1 * (q1 - q2)
    wdu = 0.0
    wdu += sg.w1 * (u1 - u2)
    d, branch, s1, s2, lam1, lam2 = core_2d(g1 / sg.sqrtWQ, wu1 / sg.sqrtW, g2 / sg.sqrtWQ, wu2 / sg.sqrtW,
                                             wdq / sg.sqrtWQ, wdu / sg.sqrtW, sg.e, sg.k, True, fix)
    mu1, gam1, del1, mu2, gam2, del2 = _chain_params(sg, branch, s1, s2, lam1, lam2, g1, g2, wu1, wu2)
    return (d, branch,
            (1.0 - mu1) * q1 + mu1 * q2 - gam1 * sg.Qinv_w1,
            (1.0 - mu1) * u1 + mu1 * u2 + del1 * sg.Minv_w1,
            (1.0 - mu2) * q1 + mu2 * q2 - gam2 * sg.Qinv_w1,
            (1.0 - mu2) * u1 + mu2 * u2 + del2 * sg.Minv_w1)


@njit(cache=True, inline="always", error_model="numpy")
def _write_chain(geo, q1, u1, q2, u2, mu1, gam1, del1, mu2, gam2, del2, c1q, c1u, c2q, c2u):
    Qinv_w = geo.Qinv_w
    Minv_w = geo.Minv_w
    for i in range(q1.shape[0]):
        c1q[i] = (1.0 - mu1) * q1[i] + mu1 * q2[i] - gam1 * Qinv_w[i]
        c1u[i] = (1.0 - mu1) * u1[i] + mu1 * u2[i] + del1 * Minv_w[i]
        c2q[i] = (1.0 - mu2) * q1[i] + mu2 * q2[i] - gam2 * Qinv_w[i]
        c2u[i] = (1.0 - mu2) * u1[i] + mu2 * u2[i] + del2 * Minv_w[i]


@njit(cache=True, inline="always", error_model="numpy")
def distance_kernel(geo, q1, u1, q2, u2, c1q, c1u, c2q, c2u, fix=BRANCH_FREE):
    """Quotient distance d(x1, x2) and its branch code; fills the chain ends.

    ``c1q, c1u, c2q, c2u`` are (n,) float64 output arrays that must not alias
    the inputs.  Returns ``(d, branch)`` with branch in ``BRANCH_E``,
    ``BRANCH_J12``, ``BRANCH_J21``, ``BRANCH_J2``.  Allocates nothing.
    ``fix``: a branch code to take that branch's chain whether or not it is the
    shortest (:func:`.distance_planar.core_2d`); :data:`BRANCH_FREE`: the distance.
    """
    if q1.shape[0] == 1:
        d, branch, c1q[0], c1u[0], c2q[0], c2u[0] = distance1(geo.scalar, q1[0], u1[0], q2[0], u2[0], fix)
        return d, branch
    d, branch, mu1, gam1, del1, mu2, gam2, del2 = _distance_nd(geo, q1, u1, q2, u2, True, fix)
    _write_chain(geo, q1, u1, q2, u2, mu1, gam1, del1, mu2, gam2, del2, c1q, c1u, c2q, c2u)
    return d, branch


@njit(cache=True, inline="always", error_model="numpy")
def distance_value(geo, q1, u1, q2, u2):
    """``(d, branch)`` without chain ends (e.g. to record V = d^2/2)."""
    if q1.shape[0] == 1:
        r1 = distance1(geo.scalar, q1[0], u1[0], q2[0], u2[0])
        return r1[0], r1[1]
    r = _distance_nd(geo, q1, u1, q2, u2, True)
    return r[0], r[1]


@njit(cache=True, inline="always", error_model="numpy")
def distance_kernel_unpruned(geo, q1, u1, q2, u2, c1q, c1u, c2q, c2u):
    """:func:`distance_kernel` evaluating every branch (no lower-bound skipping):
    the worst-case cost, for benchmarks and tests; same results."""
    d, branch, mu1, gam1, del1, mu2, gam2, del2 = _distance_nd(geo, q1, u1, q2, u2, False)
    _write_chain(geo, q1, u1, q2, u2, mu1, gam1, del1, mu2, gam2, del2, c1q, c1u, c2q, c2u)
    return d, branch


# ------------------------------------------------------------------ Python API
def quotient_distance(system, x1, x2, Q=None, full=False):
    """Quotient distance d(x1, x2) of docs/design.md §2.4.

    Parameters
    ----------
    system : MechanicalSystem, SystemArrays or DistanceGeometry
    x1, x2 : pairs (q, u) -- floats for 1-DOF or arrays of n entries
    Q : positive scalar or (n, n) SPD, optional
        Position weight of ``||x||_P^2 = q^T Q q + u^T M u`` (default identity;
        must be None when ``system`` is a DistanceGeometry).
    full : bool
        If True return a :class:`DistanceResult` ``(d, branch, c1, c2)`` with the
        branch name ("E", "J12", "J21", "J2") and the chain ends as (q, u) pairs.

    A state inside the wall (g(q) < 0 beyond the round-off tolerance
    :data:`fmu_sync.core.checks.GAP_TOL`) raises
    :class:`fmu_sync.core.checks.InadmissibleState` (a ValueError).
    """
    geo = resolve_geometry(system, Q)
    q1, u1 = geometry_state(geo, x1, "x1")
    q2, u2 = geometry_state(geo, x2, "x2")
    check_admissible(geo.w, geo.g0, q1, "x1")
    check_admissible(geo.w, geo.g0, q2, "x2")
    n = q1.shape[0]
    c = np.empty((4, n))
    d, branch = distance_kernel(geo, q1, u1, q2, u2, c[0], c[1], c[2], c[3])
    if not full:
        return float(d)
    return DistanceResult(float(d), BRANCH_NAMES[branch], (c[0].copy(), c[1].copy()),
                          (c[2].copy(), c[3].copy()))
