"""The compensated switching law, ``"switching-compensated"`` (docs/design.md §2.5.2).

On branch E it is the switching law (the classical PD law, bit for bit). On a jump branch
(J12, J21, J2), and on branch E when one system rests on the wall while the other approaches
it (the contact chain), it computes the exact rate of change of the chain's length with the
chain ends held fixed (the envelope theorem), ``dd/dt = sum_i <n_i, x_i'>_P`` with
``x_i' = (u_i, M^-1 (h_i(x_i, t) + tau_i))``, for two candidate force pairs:

* the switching law's ``tau^S`` (the pulls ``-d/r_i (Kp dq_i + Kd du_i)``), and
* the fully compensated chain law ``tau^C_i = -h_i(c_i, t) - 2 Kp (q_i - c_iq) - 2 Kd (u_i - c_iu)``:
  each system's own force evaluated at its chain end is cancelled (the asymmetry that the
  mirror image through the impact map introduces) and each system is pulled toward its fixed
  chain end with the whole relative gain 2 Kp, 2 Kd (with Q = K + 2 Kp its rate is
  ``sum_i <q_i - c_iq, c_iu>_Q / r_i - du_i^T (C + 2 Kd) du_i / r_i <= 0``, design.md §2.5.2),

and applies ``tau = (1 - kappa) tau^S + kappa tau^C`` with the smallest ``kappa`` in [0, 1] that
brings the rate down to ``MU`` times that of ``tau^C`` (``kappa = 0`` -- the switching law --
whenever its rate is already <= 0). The rate is affine in kappa, so kappa is explicit.

The system's force ``h(q, u, t)`` is evaluated in one place, :func:`force1`, from the node's
affine force law at the current time (``f = f0 + sum_j F_j cos(Omega_j t + phi_j)``,
:func:`node_force1`, from the nodes' force table :func:`force_table`): a user force law plugs in
there.

1-DOF kernels on floats (``sg = geo.scalar``), nopython, allocation-free.
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .distance import BRANCH_E, BRANCH_FREE, distance1
from .errors import LawRefused

__all__ = ["MU", "REST_TOL", "check_compensated", "pull1", "force1", "node_force1", "force_table", "chain_rate1", "compensated_coupling1"]

#: The blended law brings a growing chain's rate down to MU times the rate of the fully
#: compensated law (<= 0): MU = 0 would only stop the growth (then the discrete step's own
#: O(h^2) error could still let V creep), MU = 1 is the full compensation.
MU = 0.5
#: A system rests on the wall (the contact chain on branch E) when its normal coordinates
#: (X, Y) = (g / sqrt(w^T Q^-1 w), w^T u / sqrt(W)) satisfy X <= REST_TOL d and |Y| <= REST_TOL d.
REST_TOL = 1e-9


def check_compensated(n: int, force=None) -> None:
    """The one rule of what the compensated law is implemented for: 1-DOF systems (n = 1) with
    the built-in linear force law (``force`` None; else the user :class:`ForceLaw`). Raises
    ValueError for n > 1 and :class:`.errors.LawRefused` for a user force law, naming what to use
    instead (the core's run plan, the master and the coupling FMU all refuse by it)."""
    if n > 1:
        raise ValueError(f"coupling 'switching-compensated' is implemented for 1-DOF systems (n = 1), got "
                         f"n = {n}: in n-DOF its guarantee does not carry over as it is (docs/design.md "
                         f"§2.5.2); use 'switching'")
    if force is not None:
        raise LawRefused(f"coupling 'switching-compensated' compensates the built-in linear law's force "
                         f"(docs/design.md §2.5.2); the systems use the force law {force.name!r}: "
                         f"use 'switching'")


@njit(cache=True, inline="always", error_model="numpy")
def force1(k, c, f, q, u):
    """The system's force ``h(q, u, t) = f - k q - c u`` of a 1-DOF node (``f`` = its
    state-independent force at time t, :func:`forcing1`): the one evaluation of h."""
    return f - k * q - c * u


@njit(cache=True, inline="always", error_model="numpy")
def node_force1(hp, i, t):
    """``(k, c, f)`` of 1-DOF node i at time t from its row of the force table ``hp``
    (:func:`force_table`): ``f = f0 + sum_j F_j cos(Omega_j t + phi_j)``."""
    nf = (hp.shape[1] - 3) // 3
    s = 0.0
    for j in range(nf):
        s += hp[i, 3 + j] * math.cos(hp[i, 3 + nf + j] * t + hp[i, 3 + 2 * nf + j])
    return hp[i, 0], hp[i, 1], hp[i, 2] + s


@njit(cache=True)
def force_table(K, C, f0, F, Omega, phi):
    """The nodes' 1-DOF force laws as one (N, 3 + 3 nf) table, row i = (k, c, f0, F_1.., Omega_1..,
    phi_1..) (zeros for n > 1, where the compensated law is refused): what the coupling needs of
    each system's h (one array through the loops instead of six)."""
    N = K.shape[0]
    nf = Omega.shape[1]
    hp = np.zeros((N, 3 + 3 * nf))
    if K.shape[1] == 1:
        for i in range(N):
            hp[i, 0] = K[i, 0, 0]
            hp[i, 1] = C[i, 0, 0]
            hp[i, 2] = f0[i, 0]
            for j in range(nf):
                hp[i, 3 + j] = F[i, j, 0]
                hp[i, 3 + nf + j] = Omega[i, j]
                hp[i, 3 + 2 * nf + j] = phi[i, j]
    return hp


@njit(cache=True, inline="always", error_model="numpy")
def chain_rate1(sg, q, u, cq, cu, a):
    """``<n, x'>_P`` of the segment from the fixed chain end ``(cq, cu)`` to the state ``(q, u)``
    moving with ``q' = u``, ``m u' = a``: ``((q - cq) Q u + (u - cu) a) / r`` (0 if r = 0)."""
    dq = q - cq
    du = u - cu
    r = math.sqrt(max(dq * (sg.Q11 * dq) + du * (sg.M11 * du), 0.0))
    if r > 0.0:
        return (dq * (sg.Q11 * u) + du * a) / r
    return 0.0


@njit(cache=True, inline="always", error_model="numpy")
def pull1(sg, kp, kd, d, dq, du):
    """The switching law's pull toward a chain end (docs/design.md §2.5): -kp E^q - kd E^u with
    E = d (dq, du) / ||(dq, du)||_P (0 if that is 0); used by both quotient laws."""
    acc = dq * (sg.Q11 * dq) + du * (sg.M11 * du)
    nrm = math.sqrt(max(acc, 0.0))
    scale = d / nrm if nrm > 0.0 else 0.0
    return 0.0 - scale * (kp * dq + kd * du)


@njit(cache=True, inline="always", error_model="numpy")
def _rests(sg, q, u, d):
    """The state rests on the wall (within REST_TOL d in the normal coordinates)."""
    X = (sg.g0 + sg.w1 * q) / sg.sqrtWQ
    Y = sg.w1 * u / sg.sqrtW
    return X <= REST_TOL * d and abs(Y) <= REST_TOL * d


@njit(cache=True, error_model="numpy")
def compensated_coupling1(sg, kp, kd, q1, u1, q2, u2, k1, c1, f1, k2, c2, f2, fix=BRANCH_FREE):
    """The compensated switching law, 1-DOF (module docstring). ``(k_i, c_i, f_i)``: node i's
    force law at the current time (h_i = f_i - k_i q - c_i u, :func:`force1`); ``fix``: the
    branch whose chain the law is evaluated on (:data:`.distance.BRANCH_FREE`: its own).

    Returns ``(tau1, tau2, d, branch, kappa)``."""
    d, branch, a1q, a1u, a2q, a2u = distance1(sg, q1, u1, q2, u2, fix)
    if branch == BRANCH_E:
        s = kp * (q1 - q2) + kd * (u1 - u2)
        t1 = -s
        t2 = s
        # the contact chain: a system resting on the wall, pushed into it by the PD force, while
        # the other approaches the wall (its contact force would enter the relative motion)
        h1 = force1(k1, c1, f1, q1, u1)
        h2 = force1(k2, c2, f2, q2, u2)
        rest1 = _rests(sg, q1, u1, d) and sg.w1 * (h1 + t1) < 0.0 and sg.w1 * u2 < 0.0
        rest2 = _rests(sg, q2, u2, d) and sg.w1 * (h2 + t2) < 0.0 and sg.w1 * u1 < 0.0
        if not (rest1 or rest2):
            return t1, t2, d, branch, 0.0
        qw = -sg.g0 / sg.w1
        a1q = qw
        a2q = qw
        a1u = 0.0
        a2u = 0.0
    else:
        t1 = pull1(sg, kp, kd, d, q1 - a1q, u1 - a1u)
        t2 = pull1(sg, kp, kd, d, q2 - a2q, u2 - a2u)
        h1 = force1(k1, c1, f1, q1, u1)
        h2 = force1(k2, c2, f2, q2, u2)
    r0 = chain_rate1(sg, q1, u1, a1q, a1u, h1 + t1) + chain_rate1(sg, q2, u2, a2q, a2u, h2 + t2)
    if r0 <= 0.0:
        return t1, t2, d, branch, 0.0
    F1 = -force1(k1, c1, f1, a1q, a1u) - 2.0 * kp * (q1 - a1q) - 2.0 * kd * (u1 - a1u)
    F2 = -force1(k2, c2, f2, a2q, a2u) - 2.0 * kp * (q2 - a2q) - 2.0 * kd * (u2 - a2u)
    r1 = chain_rate1(sg, q1, u1, a1q, a1u, h1 + F1) + chain_rate1(sg, q2, u2, a2q, a2u, h2 + F2)
    target = MU * min(r1, 0.0)
    kappa = 1.0
    if r0 - r1 > 0.0:
        kappa = min(1.0, (r0 - target) / (r0 - r1))
    return ((1.0 - kappa) * t1 + kappa * F1, (1.0 - kappa) * t2 + kappa * F2, d, branch, kappa)
