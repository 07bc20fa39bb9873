"""Coupling laws between two systems (docs/design.md §2.5).

Both laws produce non-impulsive generalized forces ``tau1, tau2`` with n entries
each: the input matrix is assumed to be ``B = I`` (tau acts directly as a
generalized force; this is the default ``B`` of :class:`MechanicalSystem`).

* **Switching quotient coupling** (:func:`switching_coupling`): with the
  quotient distance ``d`` and its chain ends ``c1, c2`` (:mod:`.distance`),
  ``E_i = d (x_i - c_i) / ||x_i - c_i||_P`` (0 if the denominator is 0) and
  ``tau_i = -Kp E_i^q - Kd E_i^u``.  On branch E (``c1 = x2``, ``c2 = x1``,
  ``d = ||x1 - x2||_P``) this *is* the classical PD law, and it is computed as
  such there, so that ``tau1 = -tau2`` holds exactly.
* **Euclidean PD coupling** (:func:`euclidean_coupling`):
  ``tau1 = -Kp (q1 - q2) - Kd (u1 - u2) = -tau2``.

Since ``||E_i||_P = d``: ``|tau_i| <= (|Kp| / sqrt(lmin Q) + |Kd| / sqrt(lmin M)) d``
(spectral norms), so the forces are bounded by the distance -- no impulses.

Kernels (all ``@njit(cache=True)``, nopython, allocation-free):

* array kernels for any n -- :func:`switching_coupling`,
  :func:`euclidean_coupling`, :func:`coupling_kernel` (dispatch on an integer
  law code).  The caller owns the force arrays and the chain-end work arrays
  (:func:`chain_work`); gains are (n, n) arrays (:func:`gain_matrix`).  They
  are numba-inlined into the calling loop and dispatch n = 1 to:
* scalar 1-DOF kernels -- :func:`switching_coupling1`,
  :func:`euclidean_coupling1`, :func:`coupling_kernel1` -- floats in and out,
  taking ``geo.scalar`` and scalar gains; bit-identical to the array kernels.

The co-simulation master and ``simulate_pair`` call these same kernels.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from .jit import njit

from .compensation import compensated_coupling1, force_table, node_force1, pull1
from .distance import BRANCH_E, BRANCH_FREE, BRANCH_NAMES, resolve_geometry, geometry_state, distance1, distance_kernel

__all__ = ["SWITCHING", "EUCLIDEAN", "UNCOUPLED", "COMPENSATED", "QUOTIENT_LAWS", "QUOTIENT_LAW_NAMES", "LAWS",
           "LAW_NAMES", "BRANCH_NONE",
           "switching_coupling", "euclidean_coupling", "coupling_kernel",
           "switching_coupling1", "euclidean_coupling1", "coupling_kernel1",
           "gain_matrix", "chain_work", "law_code", "branch_code", "coupling_forces", "energy_metric",
           "laplacian_factor",
           "METRICS", "LawMetric", "law_metric", "metric_info"]

SWITCHING = 0
EUCLIDEAN = 1
UNCOUPLED = 2
#: The compensated switching law (:mod:`.compensation`, docs/design.md §2.5.2): the switching law
#: on branch E, and on a jump branch blended toward the chain law that cancels each system's
#: force at its chain end whenever the switching law would let the chain grow (1-DOF).
COMPENSATED = 3
LAWS = {"switching": SWITCHING, "euclidean": EUCLIDEAN, "none": UNCOUPLED, "switching-compensated": COMPENSATED}
#: A law's name by its code.
LAW_NAMES = {code: name for name, code in LAWS.items()}
#: The laws whose forces come from the quotient distance (a run records d with them; the systems
#: must share one impact map): by code, and by name.
QUOTIENT_LAWS = (SWITCHING, COMPENSATED)
QUOTIENT_LAW_NAMES = tuple(LAW_NAMES[c] for c in QUOTIENT_LAWS)
#: Branch code returned for the laws that compute no quotient distance.
BRANCH_NONE = -1


# ------------------------------------------------------------ scalar (1-DOF)
@njit(cache=True, error_model="numpy")
def switching_coupling1(sg, kp, kd, q1, u1, q2, u2, fix=BRANCH_FREE):
    """Switching quotient coupling, 1-DOF, floats: ``sg = geo.scalar``; ``fix`` a branch code
    to evaluate the law on that branch's chain (:data:`.distance.BRANCH_FREE`: the law's own).

    Returns ``(tau1, tau2, d, branch)``."""
    d, branch, c1q, c1u, c2q, c2u = distance1(sg, q1, u1, q2, u2, fix)
    if branch == BRANCH_E:
        s = kp * (q1 - q2) + kd * (u1 - u2)
        return -s, s, d, branch
    return (pull1(sg, kp, kd, d, q1 - c1q, u1 - c1u),
            pull1(sg, kp, kd, d, q2 - c2q, u2 - c2u), d, branch)


@njit(cache=True, error_model="numpy")
def euclidean_coupling1(sg, kp, kd, q1, u1, q2, u2):
    """Euclidean PD coupling, 1-DOF, floats.  Returns ``(tau1, tau2, E)`` with
    ``E = ||x1 - x2||_P``."""
    dq = q1 - q2
    du = u1 - u2
    s = kp * dq + kd * du
    return -s, s, math.sqrt(max(dq * (sg.Q11 * dq) + du * (sg.M11 * du), 0.0))


@njit(cache=True, error_model="numpy")
def coupling_kernel1(law, sg, kp, kd, q1, u1, q2, u2, fix=BRANCH_FREE):
    """1-DOF dispatch on ``law``: ``(tau1, tau2, value, branch)`` -- for
    SWITCHING the quotient distance and its branch code (``fix``: the branch held,
    :func:`switching_coupling1`), otherwise the
    Euclidean error and ``BRANCH_NONE`` (UNCOUPLED: zero forces)."""
    if law == SWITCHING:
        return switching_coupling1(sg, kp, kd, q1, u1, q2, u2, fix)
    t1, t2, E = euclidean_coupling1(sg, kp, kd, q1, u1, q2, u2)
    if law != EUCLIDEAN:
        t1 = 0.0
        t2 = 0.0
    return t1, t2, E, BRANCH_NONE


# ------------------------------------------------------------- arrays (any n)
@njit(cache=True, inline="always", error_model="numpy")
def _euclidean_forces(Kp, Kd, q1, u1, q2, u2, tau1, tau2):
    """tau1 = -Kp (q1 - q2) - Kd (u1 - u2) = -tau2: the pull of system 1 toward system 2."""
    _pull(Kp, Kd, 1.0, q1, u1, q2, u2, tau1)
    for k in range(q1.shape[0]):
        tau2[k] = -tau1[k]


@njit(cache=True, inline="always", error_model="numpy")
def p_norm_diff(Q, M, q, u, cq, cu):
    """||(q - cq, u - cu)||_P."""
    n = q.shape[0]
    acc = 0.0
    for i in range(n):
        rq = 0.0
        ru = 0.0
        for j in range(n):
            rq += Q[i, j] * (q[j] - cq[j])
            ru += M[i, j] * (u[j] - cu[j])
        acc += (q[i] - cq[i]) * rq + (u[i] - cu[i]) * ru
    return math.sqrt(max(acc, 0.0))


@njit(cache=True, inline="always", error_model="numpy")
def _pull(Kp, Kd, scale, q, u, cq, cu, tau):
    """tau = -scale (Kp (q - cq) + Kd (u - cu))."""
    n = q.shape[0]
    for k in range(n):
        s = 0.0
        for j in range(n):
            s += Kp[k, j] * (q[j] - cq[j]) + Kd[k, j] * (u[j] - cu[j])
        tau[k] = 0.0 - scale * s


@njit(cache=True, inline="always", error_model="numpy")
def switching_coupling(geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u, fix=BRANCH_FREE):
    """Switching quotient coupling into ``tau1``, ``tau2``; returns ``(d, branch)``.

    ``Kp, Kd``: (n, n) gains.  ``c1q, c1u, c2q, c2u``: (n,) work arrays (not
    aliasing the states); on return they hold the chain ends c1, c2 of
    :func:`.distance.distance_kernel`.  ``fix``: :data:`.distance.BRANCH_FREE` (the law's own
    branch) or the branch whose chain the law is evaluated on (d is then that chain's length).
    Allocates nothing.
    """
    if q1.shape[0] == 1:
        sg = geo.scalar
        kp = Kp[0, 0]
        kd = Kd[0, 0]
        x1q = q1[0]
        x1u = u1[0]
        x2q = q2[0]
        x2u = u2[0]
        d, branch, a1q, a1u, a2q, a2u = distance1(sg, x1q, x1u, x2q, x2u, fix)
        c1q[0] = a1q
        c1u[0] = a1u
        c2q[0] = a2q
        c2u[0] = a2u
        if branch == BRANCH_E:
            s = kp * (x1q - x2q) + kd * (x1u - x2u)
            tau1[0] = -s
            tau2[0] = s
        else:
            tau1[0] = pull1(sg, kp, kd, d, x1q - a1q, x1u - a1u)
            tau2[0] = pull1(sg, kp, kd, d, x2q - a2q, x2u - a2u)
        return d, branch
    d, branch = distance_kernel(geo, q1, u1, q2, u2, c1q, c1u, c2q, c2u, fix)
    if branch == BRANCH_E:
        _euclidean_forces(Kp, Kd, q1, u1, q2, u2, tau1, tau2)
    else:
        n1 = p_norm_diff(geo.Q, geo.M, q1, u1, c1q, c1u)
        n2 = p_norm_diff(geo.Q, geo.M, q2, u2, c2q, c2u)
        _pull(Kp, Kd, d / n1 if n1 > 0.0 else 0.0, q1, u1, c1q, c1u, tau1)
        _pull(Kp, Kd, d / n2 if n2 > 0.0 else 0.0, q2, u2, c2q, c2u, tau2)
    return d, branch


@njit(cache=True, inline="always", error_model="numpy")
def euclidean_coupling(geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2):
    """Euclidean PD law into ``tau1`` and ``tau2 = -tau1``.  Returns the
    Euclidean error ``||x1 - x2||_P`` (Q, M from ``geo``).  Allocates nothing."""
    if q1.shape[0] == 1:
        t1, t2, E = euclidean_coupling1(geo.scalar, Kp[0, 0], Kd[0, 0], q1[0], u1[0], q2[0], u2[0])
        tau1[0] = t1
        tau2[0] = t2
        return E
    _euclidean_forces(Kp, Kd, q1, u1, q2, u2, tau1, tau2)
    return p_norm_diff(geo.Q, geo.M, q1, u1, q2, u2)


@njit(cache=True, inline="always", error_model="numpy")
def coupling_kernel(law, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u, fix=BRANCH_FREE):
    """Dispatch on ``law`` (``SWITCHING``, ``EUCLIDEAN``, ``UNCOUPLED``).

    Returns ``(value, branch)``: for SWITCHING the quotient distance d and its
    branch code (chain ends in ``c1q..c2u``); for EUCLIDEAN and UNCOUPLED (zero
    forces) the Euclidean error ``||x1 - x2||_P`` and ``BRANCH_NONE`` (no
    distance computed; use :func:`.distance.distance_value` to record d). ``fix``: the
    branch the switching law is held on (:func:`switching_coupling`).
    """
    if law == SWITCHING:
        return switching_coupling(geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u, fix)
    E = euclidean_coupling(geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2)
    if law != EUCLIDEAN:
        for i in range(tau1.shape[0]):
            tau1[i] = 0.0
            tau2[i] = 0.0
    return E, BRANCH_NONE


# ------------------------------------------------------------------ Python API
def gain_matrix(K, n: int, name: str = "Kp") -> np.ndarray:
    """(n, n) float64 gain from a scalar ``s >= 0`` (-> ``s I``) or an n x n matrix
    whose symmetric part is positive semidefinite."""
    try:
        a = np.array(K, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a nonnegative scalar or an {n}x{n} matrix, got {K!r}") from None
    if a.ndim == 0:
        s = float(a)
        if not (math.isfinite(s) and s >= 0.0):
            raise ValueError(f"{name} must be a finite gain >= 0, got {s}")
        return np.eye(n) * s
    if a.shape != (n, n):
        raise ValueError(f"{name} must be a scalar or {n}x{n}, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    lmin = float(np.linalg.eigvalsh(0.5 * (a + a.T))[0])
    if lmin < -1e-12 * max(1.0, float(np.max(np.abs(a)))):
        raise ValueError(f"{name} must be positive semidefinite (gains >= 0), got smallest eigenvalue "
                         f"{lmin:.6g} of its symmetric part for {name} = {a.tolist()}")
    return np.ascontiguousarray(a)


def chain_work(n: int):
    """Four (n,) float64 work arrays ``(c1q, c1u, c2q, c2u)`` for the kernels."""
    c = np.zeros((4, n))
    return c[0], c[1], c[2], c[3]


def law_code(law) -> int:
    """Integer code of a law name ("switching", "euclidean", "none")."""
    if isinstance(law, str) and law in LAWS:
        return LAWS[law]
    raise ValueError(f"law must be one of {sorted(LAWS)}, got {law!r}")


@njit(cache=True, error_model="numpy")
def _coupling_call(law, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u, fix):
    return coupling_kernel(law, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u, fix)


def branch_code(branch) -> int:
    """The kernels' ``fix`` of a branch name ("E", "J12", "J21", "J2") or None (the law's own
    branch: :data:`.distance.BRANCH_FREE`)."""
    if branch is None:
        return BRANCH_FREE
    if isinstance(branch, str) and branch in BRANCH_NAMES:
        return BRANCH_NAMES.index(branch)
    raise ValueError(f"branch must be None (the law's own) or one of {list(BRANCH_NAMES)}, got {branch!r}")


def coupling_forces(system, x1, x2, law, Kp, Kd, Q=None, t=0.0, branch=None):
    """Coupling forces ``(tau1, tau2)`` of docs/design.md §2.5: two (n,) arrays, B = I.

    Parameters
    ----------
    system : MechanicalSystem, SystemArrays or DistanceGeometry
    x1, x2 : states (q, u), floats for 1-DOF or arrays
    law : "switching", "euclidean", "none" or "switching-compensated" (1-DOF, a system with its
        force law -- not a bare DistanceGeometry -- and the time ``t`` of the states, §2.5.2)
    Kp, Kd : gains, scalars >= 0 or n x n matrices (positive semidefinite)
    Q : position weight of the distance (positive scalar or n x n SPD); default: the law's own
        metric :func:`energy_metric` (Q = K + 2 Kp) when ``system`` has a stiffness K, else I
    branch : None (the law's own branch, that of the quotient distance) or a branch name ("E",
        "J12", "J21", "J2"): the quotient laws evaluated on that branch's chain (the implicit
        exchange's held branch, docs/design.md §4.4); no effect on "euclidean" and "none"
    """
    code = law_code(law)
    fix = branch_code(branch)
    if (Q is None or isinstance(Q, str)) and hasattr(system, "K"):
        n = np.shape(system.K)[0]
        Q = law_metric(Q, [system.K], gain_matrix(Kp, n, "Kp"), coupled=code != UNCOUPLED).Q
    geo = resolve_geometry(system, Q)
    n = geo.w.shape[0]
    B = getattr(system, "B", None)
    if B is not None and np.shape(B) != (n, n):
        raise ValueError(f"the coupling forces have n = {n} entries (B = I assumed); the system's B "
                         f"has shape {np.shape(B)}")
    q1, u1 = geometry_state(geo, x1, "x1")
    q2, u2 = geometry_state(geo, x2, "x2")
    Kp = gain_matrix(Kp, n, "Kp")
    Kd = gain_matrix(Kd, n, "Kd")
    tau1 = np.zeros(n)
    tau2 = np.zeros(n)
    if code == COMPENSATED:
        sa = system.arrays() if hasattr(system, "arrays") else system
        if n != 1 or not hasattr(sa, "Omega"):
            raise ValueError(f"law 'switching-compensated' needs a 1-DOF system with its force law (it evaluates "
                             f"h at the chain ends), got n = {n} and {type(system).__name__}")
        hp = force_table(sa.K[None], sa.C[None], sa.f0[None], sa.F[None], sa.Omega[None], sa.phi[None])
        k, c, f = node_force1(hp, 0, float(t))
        tau1[0], tau2[0] = compensated_coupling1(geo.scalar, Kp[0, 0], Kd[0, 0], q1[0], u1[0], q2[0], u2[0],
                                                 k, c, f, k, c, f, fix)[:2]
        return tau1, tau2
    c1q, c1u, c2q, c2u = chain_work(n)
    _coupling_call(code, geo, Kp, Kd, q1, u1, q2, u2, tau1, tau2, c1q, c1u, c2q, c2u, fix)
    return tau1, tau2


# ------------------------------------------------- the law's own metric (§2.5.1)
#: How the position weight Q of a coupled run's quotient distance was chosen (the ``metric``
#: of every result): "energy" -- :func:`energy_metric`, V = d^2/2 is the energy of the relative
#: motion (a Lyapunov function of the law); "user" -- an explicit Q (V is then not a
#: Lyapunov function of the law unless Q happens to equal the energy metric); "identity" -- the
#: fallback Q = I of a run with no coupling whose K + 2 Kp is not positive definite.
METRICS = ("energy", "linearized", "user", "identity")

#: How the stiffness of a law's metric was obtained (result.info["metric_stiffness"]).
METRIC_SOURCES = {
    "declared": "the stiffness the law declares (stiffness(p))",
    "linear": "the law's declared linear part K_L",
    "jacobian": "-dh/dq at q = 0, u = 0, tau = 0, t = 0 (central differences)",
}


def laplacian_factor(A=None):
    """``(lam, exact)`` for the weights ``A`` (N x N, a_ij >= 0; None: a pair with weight 1).

    ``lam``: the mean of the nonzero eigenvalues of the Laplacian L of the symmetrised weights
    (trace(L) / rank(L)); ``exact``: all nonzero eigenvalues equal ``lam`` (L^2 = lam L: a pair,
    all-to-all with equal weights), the case in which the common per-edge weight
    ``Q = K + lam Kp`` makes V the exact energy of the relative motion (docs/design.md §2.5.1)."""
    if A is None:
        return 2.0, True
    a = np.array(A, dtype=np.float64)
    a = 0.5 * (a + a.T)
    L = np.diag(a.sum(axis=1)) - a
    ev = np.linalg.eigvalsh(L)
    tol = 1e-9 * max(float(np.max(np.abs(ev))), 1e-300)
    nz = ev[ev > tol]
    if nz.size == 0:
        raise ValueError("the coupling graph has no weighted edge (all weights are zero): "
                         "no energy metric to take")
    lam = float(np.mean(nz))
    return lam, bool(np.all(np.abs(nz - lam) <= 1e-9 * lam))


def energy_metric(K, Kp, A=None) -> np.ndarray:
    """The law's own position weight Q (docs/design.md §2.5.1): (n, n), symmetric positive definite.

    ``K``: the systems' stiffness, (n, n) or a scalar, or a sequence of them (non-identical
    systems: their mean is used); ``Kp``: the position gain, scalar >= 0 or (n, n); ``A``: the
    graph's weights (None: a pair of weight 1). Returns ``Q = sym(K) + lam sym(Kp)`` with ``lam``
    from :func:`laplacian_factor` (2 for a pair: ``Q = K + 2 Kp``, so that V = d^2/2 is the
    energy of the relative motion: V' = -du^T (C + 2 Kd) du between impacts).
    Raises ValueError (naming the smallest eigenvalue) when Q is not positive definite
    (e.g. K = 0 and Kp = 0, or a negative stiffness that the gain does not outweigh)."""
    Ks = K if isinstance(K, (list, tuple)) else [K]
    try:
        Kp_a = np.array(Kp, dtype=np.float64)
        Ks_a = [np.array(k, dtype=np.float64) for k in Ks]
    except (TypeError, ValueError):
        raise ValueError(f"energy_metric needs numeric K and Kp, got K={K!r}, Kp={Kp!r}") from None
    n = next((a.shape[0] for a in [*Ks_a, Kp_a] if a.ndim == 2), 1)
    mats = []
    for name, a in [*(("K", k) for k in Ks_a), ("Kp", Kp_a)]:
        if a.ndim == 0:
            a = np.eye(n) * float(a)
        if a.shape != (n, n) or not np.all(np.isfinite(a)):
            raise ValueError(f"energy_metric: {name} must be a finite scalar or an {n}x{n} matrix, "
                             f"got {a.tolist()}")
        mats.append(0.5 * (a + a.T))
    lam, _ = laplacian_factor(A)
    Kbar = sum(mats[:-1]) / (len(mats) - 1)
    Q = Kbar + lam * mats[-1]
    ev = np.linalg.eigvalsh(Q)
    if not ev[0] > 1e-12 * max(1.0, float(np.max(np.abs(Q)))):
        raise ValueError(f"the energy metric Q = K + {lam:g} Kp = {Q.tolist()} is not positive definite "
                         f"(smallest eigenvalue {ev[0]:.6g}): the relative motion has no energy norm "
                         f"(K = 0 with Kp = 0, or a negative stiffness the gain does not outweigh); "
                         f"pass an explicit SPD Q")
    return np.ascontiguousarray(Q)


class LawMetric(NamedTuple):
    """The position weight of a run's quotient distance and how it was chosen (:func:`law_metric`)."""

    Q: np.ndarray        # (n, n) SPD
    metric: str          # one of METRICS
    lyapunov: bool       # V = d^2/2 is a Lyapunov function of the law (identical systems, exact graph)
    note: str            # one sentence for summaries


def law_metric(Q, K, Kp, A=None, coupled: bool = True, stiffness: str | None = None) -> LawMetric:
    """Choose the position weight of a run (docs/design.md §2.5.1; :func:`_law_metric`).

    ``stiffness``: for a user force law, how its metric stiffness K was obtained (a key of
    :data:`fmu_sync.core.forcelaw.METRIC_SOURCES`): the energy metric is then the energy of the
    relative motion *linearized* at the synchronized motion (docs/design.md §2.8.2): metric
    ``"linearized"``, not a Lyapunov function of the law in general (a local one)."""
    lm = _law_metric(Q, K, Kp, A, coupled)
    if stiffness is None or lm.metric != "energy":
        return lm
    return LawMetric(lm.Q, "linearized", False,
                     f"the energy metric with the law's stiffness K_m = {METRIC_SOURCES[stiffness]} in place of K: "
                     "V = d^2/2 is the energy of the relative motion "
                     "linearized at the synchronized motion; it decreases near synchrony (locally), "
                     "not in general for a nonlinear law (docs/design.md §2.8.2)")


def _law_metric(Q, K, Kp, A=None, coupled: bool = True) -> LawMetric:
    """Choose the position weight of a run (docs/design.md §2.5.1).

    ``Q``: None or "energy" (the default: :func:`energy_metric`) or an explicit weight (positive
    scalar or n x n SPD, kept as given: ``metric = "user"`` unless it equals the energy metric);
    ``K``: the stiffness of each system (a sequence: equal entries are identical systems);
    ``Kp``: the position gain; ``A``: the graph (None: a pair); ``coupled``: False when no edge
    carries a force (then the gain is 0 and a singular energy metric falls back to Q = I
    instead of raising)."""
    Ks = [np.asarray(k, dtype=np.float64) for k in K]
    n = Ks[0].shape[0] if Ks[0].ndim == 2 else 1
    same = all(np.array_equal(k, Ks[0]) for k in Ks)
    Kp_eff = Kp if coupled else 0.0
    lam, exact = laplacian_factor(A) if coupled else (2.0, True)
    try:
        Qe = energy_metric(Ks[:1] if same else Ks, Kp_eff, A if coupled else None)
    except ValueError as err:
        Qe, why = None, str(err)
    if Q is None or (isinstance(Q, str) and Q == "energy"):
        if Qe is None:
            if coupled:
                raise ValueError(why)
            return LawMetric(np.eye(n), "identity", False,
                             "Q = I: no coupling and K is not positive definite, so the relative motion "
                             "has no energy norm; V = d^2/2 is a distance only")
        if not same:
            note = ("Q = mean(K) + 2 Kp (energy metric of the mean system): the systems differ, so V grows "
                    "at most as the mismatch allows (docs/design.md §2.5.1)")
        elif not exact:
            note = (f"Q = K + {lam:.4g} Kp (mean nonzero Laplacian eigenvalue): on this graph L^2 is not "
                    "proportional to L, so V = d^2/2 is not exactly the energy of the relative motion "
                    "and may grow between impacts (docs/design.md §2.5.1)")
        elif not coupled:
            note = "Q = K (no coupling): V = d^2/2 is the energy of the relative motion of the free systems"
        else:
            note = (f"Q = K + {lam:.4g} Kp: V = d^2/2 is the energy of the relative motion, a Lyapunov "
                    "function of the law")
        return LawMetric(Qe, "energy", same and exact, note)
    if isinstance(Q, str):
        raise ValueError(f"Q must be None, 'energy', a positive scalar or an SPD matrix, got {Q!r}")
    Qa = np.array(Q, dtype=np.float64)
    Qm = np.eye(n) * float(Qa) if Qa.ndim == 0 else Qa
    if Qe is not None and Qm.shape == Qe.shape and np.allclose(Qm, Qe, rtol=1e-12, atol=0.0):
        return LawMetric(Qe, "energy", same and exact, "Q given explicitly, equal to the energy metric")
    return LawMetric(Qm, "user", False,
                     "Q given explicitly" + (f" (the energy metric would be {np.round(Qe, 6).tolist()})"
                                             if Qe is not None else "")
                     + ": V = d^2/2 is then not a Lyapunov function of the law")


def metric_info(lm: LawMetric, geo) -> dict:
    """The ``info`` entries of a result that say which Q was used, and the wall (w, g0) of its
    distance geometry ``geo``."""
    return dict(metric=lm.metric, Q=np.asarray(lm.Q).tolist(), lyapunov=bool(lm.lyapunov), metric_note=lm.note,
                w=np.asarray(geo.w).tolist(), g0=float(geo.g0))
