"""The coupling FMU's hot path: one numba ``cfunc`` the C binary calls.

    int32 step(double *x, double *work, double t, double H)

Same signature and header as :mod:`.stepper` (the slots the binary reads:
H_LEN, H_VERSION, H_TIME, H_PHASE, H_DT, H_CONFIGURED, H_M, H_SCHEME, H_ITAU,
H_ITAUDOT, H_FEEDTHROUGH). The coupling has no state: every call, at doStep
(H > 0) and whenever an output is read after an input was set (H = 0), computes
all outputs from the current inputs with one call of the core's
:func:`fmu_sync.core.network.network_forces` (which calls
:func:`fmu_sync.core.pair.coupling_step` per edge), then V per edge. Returns 0,
1 if an output is not finite or a force exceeds |tau| <= H_BOUND (contract.INPUT_BOUND, the
systems' input bound), or R_INADMISSIBLE (outputs computed) if a system's
state lies inside the wall deeper than the Moreau penetration a step can leave,
:func:`fmu_sync.core.checks.penetration_bound` with dt = the last doStep's H (the
systems' own solver steps are at most H; 0 before the first step: a start state
must satisfy g >= 0) and speed = max(sqrt(W u^T M u) / e, the same at the last
doStep) (the normal velocity entering the contact step: e times it is left after
a Newton impact, and a plastic one leaves 0), below the gap at the last doStep if
that was inside the wall and admissible and w^T u >= 0 now (the scheme constrains
velocities, not positions: a contact keeps the depth it entered with while it
lasts, and its velocity does not approach the wall). The first such system, its gap and
its bound (and H) are written at :func:`report_slot` for the reason the FMU logs.

Work array: the header, then (at H_DATA) the laws, the edges and the weights
(E, 2E, 2E slots; laws and edges as int64 bit patterns), the symmetric weights
(E), Kp, Kd (n*n each), the distance geometry (:class:`DistanceGeometry`
fields and its scalar part), the nodes' force table (its column count, then N rows of at most
HP_COLS: :func:`fmu_sync.core.compensation.force_table` of the systems' force laws, which the
compensated law evaluates at time t), the scratch of the call, the N speeds at the last
doStep and the report (system, gap, bound), and last the m input derivative slots
the binary writes (unused: the coupling does not interpolate).
"""
from __future__ import annotations

import math

import numpy as np
from ..core.jit import carray, cfunc, njit

from ..core.checks import penetration_bound
from ..core.distance import DistanceGeometry, ScalarGeometry
from ..core.network import network_forces
from .contract import INPUT_BOUND
from .stepper import (H_BOUND, H_CONFIGURED, H_DATA, H_DT, H_FEEDTHROUGH, H_ITAU, H_ITAUDOT, H_LEN, H_M, H_NX,
                      H_SCHEME, H_VERSION, R_INADMISSIBLE, STEP_SIGNATURE, WORK_VERSION)
from .workarray import mat, put, put_wall, wall

__all__ = ["step", "pack", "work_size", "H_FEEDTHROUGH", "C_NODES", "C_DOF", "C_EDGES", "C_IQ", "C_IU",
           "C_ITAU", "C_ID", "C_IV", "C_IEU", "C_IBR", "C_HLAST", "NO_SCHEME", "report_slot"]

#: the coupling's own header slots (free in the mechanical layout's header)
C_NODES, C_DOF, C_EDGES = 6, 8, 10
C_IQ, C_IU, C_ITAU, C_ID, C_IV, C_IEU, C_IBR = 12, 13, 15, 16, 17, 18, 19
#: H of the last doStep (0 before the first): the step that produced the current inputs
C_HLAST = 21
#: H_SCHEME of a coupling: no solver (not the binary's exact-scheme code)
NO_SCHEME = -1.0
_NSCALAR = 12   # fields of ScalarGeometry
#: the force table's widest row: k, c, f0 and one harmonic term (F, Omega, phi), as the FMU takes
HP_COLS = 6


def _geo_size(n: int) -> int:
    return 3 * n * n + 3 * n + 7 + _NSCALAR


def work_size(N: int, n: int, E: int, m: int) -> int:
    """Slots for N nodes of n DOF, E edges, m inputs."""
    data = 5 * E + E + 2 * n * n + _geo_size(n) + 1 + N * HP_COLS
    scratch = 3 * N * n + 3 * E + 6 * n
    return H_DATA + data + scratch + 2 * N + 4 + m


def report_slot(work) -> int:
    """First of the 4 slots (system 1-based, gap, bound, the step H it allowed for) of the last
    inadmissible input state; the N speeds and the N gaps at the last doStep precede it."""
    return int(work[H_ITAUDOT]) - 4


def init_header(work: np.ndarray, N: int, n: int, E: int, m: int, nx: int, index: dict) -> None:
    """The header of a fresh work array (sizes, indices of the variables in x)."""
    work[H_LEN] = work.shape[0]
    work[H_VERSION] = WORK_VERSION
    work[H_NX] = nx
    work[H_M] = m
    work[H_ITAUDOT] = work.shape[0] - m
    work[H_DT] = math.inf             # no internal steps: the binary's step count is 0
    work[H_SCHEME] = NO_SCHEME
    work[H_FEEDTHROUGH] = 1.0
    work[H_BOUND] = INPUT_BOUND       # |tau| the systems accept as input (the binary names it when exceeded)
    work[C_NODES], work[C_DOF], work[C_EDGES] = N, n, E
    work[C_HLAST] = 0.0
    for slot, key in ((C_IQ, "q"), (C_IU, "u"), (C_ITAU, "tau"), (C_ID, "d"), (C_IV, "V"), (C_IEU, "euclidean"),
                      (C_IBR, "branch")):
        work[slot] = index[key]
    work[H_ITAU] = index["q"]         # the first input (the binary resets input derivatives from here)


def pack(work: np.ndarray, cfg, edges) -> None:
    """Write a validated configuration (:class:`fmu_sync.fmus.coupling.CouplingConfiguration`)."""
    E = len(edges)
    k = H_DATA
    ints = np.concatenate([np.asarray(cfg.laws, dtype=np.int64),
                           np.asarray(edges, dtype=np.int64).reshape(-1)])
    work[k:k + 3 * E] = ints.view(np.float64)
    k += 3 * E
    work[k:k + 2 * E] = cfg.W2.reshape(-1)
    k += 2 * E
    work[k:k + E] = 0.5 * (cfg.W2[:, 0] + cfg.W2[:, 1])
    k += E
    g = cfg.geo
    k = put(work, k, (cfg.Kp, cfg.Kd, g.Q, g.M))
    k = put_wall(work, k, g.w, g.g0, g.e, g.Minv_w, g.W)
    n = g.w.shape[0]
    work[k:k + n] = g.Qinv_w
    work[k + n], work[k + n + 1], work[k + n + 2] = g.WQ, g.sqrtW, g.sqrtWQ
    k += n + 3
    work[k:k + _NSCALAR] = np.array(tuple(g.scalar), dtype=np.float64)
    k += _NSCALAR
    N, cols = cfg.hp.shape
    if cols > HP_COLS:
        raise ValueError(f"the coupling FMU takes one harmonic term per system, the force table has "
                         f"{(cols - 3) // 3}")
    work[k] = cols
    work[k + 1:k + 1 + N * cols] = cfg.hp.reshape(-1)
    work[H_CONFIGURED] = 1.0


@njit(cache=True)
def _normal(q, u, M, wv, g0, W):
    """(g(q), w^T u, sqrt(W u^T M u)) of one system: its gap, normal velocity and the bound of
    |w^T u| over its kinetic energy."""
    g = g0
    wu = 0.0
    uMu = 0.0
    for a in range(q.shape[0]):
        g += wv[a] * q[a]
        wu += wv[a] * u[a]
        for b in range(q.shape[0]):
            uMu += u[a] * M[a, b] * u[b]
    return g, wu, math.sqrt(max(W * uMu, 0.0))


@njit(cache=True)
def _evaluate(x, w, t):
    N = int(w[C_NODES])
    n = int(w[C_DOF])
    E = int(w[C_EDGES])
    k = H_DATA
    ints = w[k:k + 3 * E].view(np.int64)
    laws = ints[:E]
    E2 = mat(ints, E, E, 2)
    k += 3 * E
    W2 = mat(w, k, E, 2)
    k += 2 * E
    asym = w[k:k + E]
    k += E
    Kp = mat(w, k, n, n)
    k += n * n
    Kd = mat(w, k, n, n)
    k += n * n
    Q = mat(w, k, n, n)
    k += n * n
    M = mat(w, k, n, n)
    k += n * n
    wv, g0, e, Minv_w, W, k = wall(w, k, n)
    Qinv_w = w[k:k + n]
    WQ = w[k + n]
    sqrtW = w[k + n + 1]
    sqrtWQ = w[k + n + 2]
    k += n + 3
    sg = ScalarGeometry(w[k], w[k + 1], w[k + 2], w[k + 3], w[k + 4], w[k + 5], w[k + 6], w[k + 7], w[k + 8],
                        w[k + 9], w[k + 10], w[k + 11])
    k += _NSCALAR
    cols = int(w[k])
    hp = mat(w, k + 1, N, cols)
    k += 1 + N * HP_COLS
    geo = DistanceGeometry(Q, M, wv, g0, e, Minv_w, W, Qinv_w, WQ, sqrtW, sqrtWQ, sg)
    iq = int(w[C_IQ])
    iu = int(w[C_IU])
    it = int(w[C_ITAU])
    q = mat(x, iq, N, n)
    u = mat(x, iu, N, n)
    tau = mat(x, it, N, n)
    s = w[k:]
    dk = s[0:E]
    ek = s[E:2 * E]
    bk = s[2 * E:3 * E].view(np.int64)
    j = 3 * E
    # the states' time t: the compensated law evaluates each system's h(t) at its chain end
    network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, s[j:j + n], s[j + n:j + 2 * n],
                   s[j + 2 * n:j + 3 * n], s[j + 3 * n:j + 4 * n], s[j + 4 * n:j + 5 * n],
                   s[j + 5 * n:j + 6 * n], True, dk, bk, ek, hp, t)
    ok = True
    i_d = int(w[C_ID])
    i_v = int(w[C_IV])
    i_e = int(w[C_IEU])
    i_b = int(w[C_IBR])
    for a in range(E):
        x[i_d + a] = dk[a]
        x[i_v + a] = 0.5 * asym[a] * dk[a] * dk[a]
        x[i_e + a] = ek[a]
        x[i_b + a] = bk[a]
        if not (math.isfinite(dk[a]) and math.isfinite(ek[a])):
            ok = False
    bound = w[H_BOUND]
    for i in range(N):
        for c in range(n):
            if not abs(tau[i, c]) <= bound:      # non-finite, or beyond what the systems accept
                ok = False
    if not ok:
        return 1
    # admissibility of the inputs (core.checks.penetration_bound, the one rule)
    rep = int(w[H_ITAUDOT]) - 4
    spd = w[rep - 2 * N:rep - N]
    floor = w[rep - N:rep]
    for i in range(N):
        g, wu, s_now = _normal(q[i], u[i], M, wv, g0, W)
        speed = max(s_now / e if e > 0.0 else s_now, spd[i])
        kept = min(floor[i], 0.0) if wu >= 0.0 else 0.0    # a contact (w^T u >= 0) keeps its depth
        bound = penetration_bound(w[C_HLAST], speed, 0.0) - kept
        if not g >= -bound:
            w[rep], w[rep + 1], w[rep + 2], w[rep + 3] = i + 1, g, bound, w[C_HLAST]
            return R_INADMISSIBLE
    return 0


@njit(cache=True)
def _remember(x, w, H, rc):
    """After a doStep of H: the speeds sqrt(W u^T M u) of the inputs it started from, their
    gaps (those found admissible: a Moreau contact keeps the depth it reached while it lasts), and H."""
    N = int(w[C_NODES])
    n = int(w[C_DOF])
    rep = int(w[H_ITAUDOT]) - 4
    k = H_DATA + 6 * int(w[C_EDGES]) + 3 * n * n
    M = mat(w, k, n, n)
    wv, g0, e, Minv_w, W, k = wall(w, k + n * n, n)
    u = mat(x, int(w[C_IU]), N, n)
    q = mat(x, int(w[C_IQ]), N, n)
    for i in range(N):
        g, wu, w[rep - 2 * N + i] = _normal(q[i], u[i], M, wv, g0, W)
        if not (rc == R_INADMISSIBLE and w[rep] == i + 1):
            w[rep - N + i] = g
    w[C_HLAST] = H


@cfunc(STEP_SIGNATURE, cache=True, nopython=True)
def step(x_ptr, w_ptr, t, H):
    w = carray(w_ptr, (int(w_ptr[H_LEN]),))
    x = carray(x_ptr, (int(w[H_NX]),))
    if w[H_CONFIGURED] == 0.0:
        return 1
    rc = _evaluate(x, w, t)
    if H > 0.0 and rc != 1:
        _remember(x, w, H, rc)
    return rc
