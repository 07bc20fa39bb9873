"""The implicit exchange's update: a block quasi-Newton step (docs/design.md §4.4, issue 39).

The implicit exchange looks for end forces ``te`` (N, n) with ``te = L(S(te))``: ``S`` the FMUs'
end states (each FMU's (q_i, u_i) depends on its own ``te_i`` only) and ``L`` the coupling law,
the master's own. Only each FMU's response is unknown, so the master keeps one secant Jacobian
``J_i = d(q_i, u_i)/d te_i`` (2n x n) per FMU (Broyden's update from the iterates of the step, kept
across steps of the same length while the FMU's impact count within the step stays the same) and
composes it with the law's Jacobian, which it evaluates exactly (a directional difference of the
law on the branch held within the step). The Newton step ``(I - L' J) delta = r`` (r = L(S(te)) -
te) is solved matrix-free by the Neumann series (one law evaluation per sweep: the cost grows with
the edges, not with (N n)^2) where it contracts, else by a dense LU of the assembled ``L' J``
(small or very stiff couplings). An FMU whose response is not known in its current impact regime
takes a prior: the last response measured without impact (of any FMU at this step length), else
its free response to the held force, from its mass (d u / d te = h M^-1 / 2, d q / d te = h^2 M^-1 / 4
for the mean, / 6 for the line: exact for a free mass, so that even a very stiff coupling's first
update lands near the fixed point), or, with neither, a damped fixed-point update. The steps are bounded (:data:`GROW` times the residual)
and the caller keeps every iterate inside the trust region.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .core.network import network_forces
from .fmus.contract import INPUT_BOUND
from .core.kernels import depends_on_core

depends_on_core(__file__, neighbours=True)

__all__ = ["NewtonWork", "newton_work", "OMEGA0", "GROW", "NEUMANN_MAX", "LINEAR_TOL", "TRUST"]

#: the relaxation of an FMU's update while its response is unknown (no secant, no prior) and of
#: the damped fixed point the step falls back to (Aitken's relaxation from there)
OMEGA0 = 0.5
#: no update is larger than GROW times the largest residual (an update beyond it is scaled down)
GROW = 4.0
#: the Neumann series' sweeps before the dense solve, and its accuracy (relative to max |r|; and at
#: most a tenth of the exchange's tolerance: a linear step then converges at its first update)
NEUMANN_MAX = 12
LINEAR_TOL = 1e-6
# the prior's state (fl): step length the secants belong to, measured prior valid, masses known
F_H, F_PRIOR, F_MASS = range(3)
# jkn: what an FMU's J_i is in its current impact regime
UNKNOWN, PRIOR, MEASURED = range(3)


class NewtonWork(NamedTuple):
    """The block quasi-Newton's arrays by name (:func:`newton_work`)."""
    J: np.ndarray
    jimp: np.ndarray
    jkn: np.ndarray
    xp: np.ndarray
    tp: np.ndarray
    imp0: np.ndarray
    impc: np.ndarray
    impp: np.ndarray
    ibuf: np.ndarray
    Am: np.ndarray
    piv: np.ndarray
    d1: np.ndarray
    d2: np.ndarray
    qx: np.ndarray
    ux: np.ndarray
    J0: np.ndarray
    fl: np.ndarray
    Minv: np.ndarray
    Jm: np.ndarray


def newton_work(N: int, n: int, ibuf, Minv=None) -> NewtonWork:
    """The block quasi-Newton's arrays: ``J`` (N, 2n, n) the FMUs' responses, ``jimp`` (N,) the
    impact count within the step each belongs to, ``jkn`` (N,) :data:`UNKNOWN` ..., ``xp`` (N, 2n)
    and ``tp`` (N, n) the last iterate's end states and forces, ``imp0, impc, impp`` (N,) impact
    counters at the step's start, now and at the last iterate, ``ibuf`` (1,) int32 (the loop's
    ``P_IBUF`` array), ``Am`` (C, C) and ``piv`` (C,) the dense solve (C = N n), ``d1, d2, qx, ux``
    (N, n) scratch, ``J0`` (2n, n) the measured prior, ``fl`` (3,) (:data:`F_H` ...), ``Minv``
    (N, n, n) each FMU's M^-1 (``Minv`` None: no mass prior) and ``Jm`` (N, 2n, n) its free
    response at the step length ``fl[F_H]``."""
    C = N * n
    z = (lambda: np.zeros((N, n)))
    i64 = (lambda: np.zeros(N, dtype=np.int64))
    return NewtonWork(np.zeros((N, 2 * n, n)), np.full(N, -1, dtype=np.int64), i64(), np.zeros((N, 2 * n)), z(), i64(), i64(),
                      i64(), ibuf, np.zeros((C, C)), np.zeros(C, dtype=np.int64), z(), z(), z(), z(), np.zeros((2 * n, n)),
                      np.array([np.nan, 0.0, float(Minv is not None)]),
                      np.zeros((N, n, n)) if Minv is None else np.ascontiguousarray(Minv, dtype=float),
                      np.zeros((N, 2 * n, n)))


@njit(cache=True)
def step_start(nw, h, foh):
    """At a step's start: every response measured in a step with impacts, or at another step
    length, is forgotten (the FMU's response differs there); at a new step length the free
    responses ``Jm`` (the line ``foh``, else the mean)."""
    J, jimp, jkn, xp, tp, imp0, impc, impp, ibuf, Am, piv, d1, d2, qx, ux, J0, fl, Minv, Jm = nw
    if fl[F_H] != h:
        fl[F_H] = h
        fl[F_PRIOR] = 0.0
        for i in range(jimp.shape[0]):
            jimp[i] = -1
        n = Minv.shape[1]
        cq = h * h / 6.0 if foh else h * h / 4.0
        for i in range(Minv.shape[0]):
            for a in range(n):
                for b in range(n):
                    Jm[i, a, b] = cq * Minv[i, a, b]
                    Jm[i, n + a, b] = 0.5 * h * Minv[i, a, b]
    for i in range(jimp.shape[0]):
        if jimp[i] != 0:
            jimp[i] = -1


@njit(cache=True)
def secants(nw, te, q, u, it):
    """After iterate ``it`` (end states q, u from forces te, impact counters in ``impc``): each
    FMU's response J_i updated by Broyden's rule from the last iterate, if its impact count within
    the step did not change between them (or nothing is known of it: no prior); an FMU in an impact regime its J_i does not belong to
    starts from the prior (or unknown). The iterate becomes the last one."""
    J, jimp, jkn, xp, tp, imp0, impc, impp, ibuf, Am, piv, d1, d2, qx, ux, J0, fl, Minv, Jm = nw
    N, n = te.shape[0], te.shape[1]
    for i in range(N):
        cnt = impc[i] - imp0[i]
        if jimp[i] != cnt:   # another regime: the prior, or nothing
            jimp[i] = cnt
            jkn[i] = PRIOR if fl[F_PRIOR] != 0.0 or fl[F_MASS] != 0.0 else UNKNOWN
            for a in range(2 * n):
                for b in range(n):
                    J[i, a, b] = J0[a, b] if fl[F_PRIOR] != 0.0 else Jm[i, a, b] if fl[F_MASS] != 0.0 else 0.0
        same = impc[i] == impp[i]
        if it > 1 and (same or jkn[i] == UNKNOWN):   # with nothing known, a secant across an impact
            s2 = 0.0
            for b in range(n):
                s2 += (te[i, b] - tp[i, b]) ** 2
            if s2 > 0.0:
                for a in range(2 * n):
                    x_new = q[i, a] if a < n else u[i, a - n]
                    pred = 0.0
                    for b in range(n):
                        pred += J[i, a, b] * (te[i, b] - tp[i, b])
                    c = (x_new - xp[i, a] - pred) / s2
                    for b in range(n):
                        J[i, a, b] += c * (te[i, b] - tp[i, b])
                jkn[i] = MEASURED
                if cnt == 0 and same:
                    for a in range(2 * n):
                        for b in range(n):
                            J0[a, b] = J[i, a, b]
                    fl[F_PRIOR] = 1.0
        for b in range(n):
            tp[i, b] = te[i, b]
            xp[i, b] = q[i, b]
            xp[i, n + b] = u[i, b]
        impp[i] = impc[i]


@njit(cache=True)
def _apply(nw, v, out, g, q, u, laws, geo, Kp, Kd, E2, W2, w, hp, t, node, col):
    """out = L'(x) J v (the law's directional difference on the held branch), or with ``node`` >= 0
    the column of L' J for FMU ``node``'s force component ``col``."""
    J, jimp, jkn, xp, tp, imp0, impc, impp, ibuf, Am, piv, d1, d2, qx, ux, J0, fl, Minv, Jm = nw
    t1, t2, c1q, c1u, c2q, c2u, dk, bk, ek, buf, slope = w
    N, n = q.shape[0], q.shape[1]
    s = 0.0
    x = 1.0
    for i in range(N):
        for a in range(n):
            dq = 0.0
            du = 0.0
            if node < 0:
                for b in range(n):
                    dq += J[i, a, b] * v[i, b]
                    du += J[i, n + a, b] * v[i, b]
            elif i == node:
                dq = J[i, a, col]
                du = J[i, n + a, col]
            qx[i, a] = dq
            ux[i, a] = du
            s = max(s, abs(dq), abs(du))
            x = max(x, abs(q[i, a]), abs(u[i, a]))
    if s == 0.0:
        for i in range(N):
            for a in range(n):
                out[i, a] = 0.0
        return
    eps = 1e-7 * x / s
    for i in range(N):
        for a in range(n):
            qx[i, a] = q[i, a] + eps * qx[i, a]
            ux[i, a] = u[i, a] + eps * ux[i, a]
    network_forces(laws, geo, Kp, Kd, E2, W2, qx, ux, out, t1, t2, c1q, c1u, c2q, c2u, False, dk, bk, ek, hp, t, True)
    for i in range(N):
        for a in range(n):
            out[i, a] = (out[i, a] - g[i, a]) / eps


@njit(cache=True)
def _dense(nw, r, g, q, u, laws, geo, Kp, Kd, E2, W2, w, hp, t):
    """d1 = (I - L' J)^-1 r by LU with partial pivoting; False if singular."""
    J, jimp, jkn, xp, tp, imp0, impc, impp, ibuf, Am, piv, d1, d2, qx, ux, J0, fl, Minv, Jm = nw
    N, n = q.shape[0], q.shape[1]
    C = N * n
    for j in range(N):
        for b in range(n):
            _apply(nw, d1, d2, g, q, u, laws, geo, Kp, Kd, E2, W2, w, hp, t, j, b)
            for i in range(N):
                for a in range(n):
                    Am[i * n + a, j * n + b] = (1.0 if i == j and a == b else 0.0) - d2[i, a]
    for k in range(C):
        p = k
        for i in range(k + 1, C):
            if abs(Am[i, k]) > abs(Am[p, k]):
                p = i
        piv[k] = p
        if not abs(Am[p, k]) > 1e-300:
            return False
        if p != k:
            for j in range(C):
                Am[k, j], Am[p, j] = Am[p, j], Am[k, j]
        for i in range(k + 1, C):
            f = Am[i, k] / Am[k, k]
            Am[i, k] = f
            if f != 0.0:
                for j in range(k + 1, C):
                    Am[i, j] -= f * Am[k, j]
    y = d2.ravel()   # contiguous (N, n): the right-hand side, permuted
    for i in range(N):
        for a in range(n):
            y[i * n + a] = r[i, a]
    for k in range(C):
        p = piv[k]
        if p != k:
            y[k], y[p] = y[p], y[k]
    for i in range(C):
        for j in range(i):
            y[i] -= Am[i, j] * y[j]
    for i in range(C - 1, -1, -1):
        for j in range(i + 1, C):
            y[i] -= Am[i, j] * y[j]
        y[i] /= Am[i, i]
    for i in range(N):
        for a in range(n):
            d1[i, a] = y[i * n + a]
    return True


@njit(cache=True)
def newton_update(nw, te, r, rmax, target, g, q, u, laws, geo, Kp, Kd, E2, W2, w, hp, t):
    """te += delta, delta the block quasi-Newton step ``(I - L' J) delta = r`` (Neumann sweeps to
    ``target`` or :data:`LINEAR_TOL` ``rmax``, whichever is smaller, the exchange's own tolerance
    being ``target``'s measure; the dense solve if they do not contract), an FMU with unknown response damped by :data:`OMEGA0`,
    ``max |delta| <= GROW rmax``."""
    J, jimp, jkn, xp, tp, imp0, impc, impp, ibuf, Am, piv, d1, d2, qx, ux, J0, fl, Minv, Jm = nw
    N, n = te.shape[0], te.shape[1]
    for i in range(N):
        for a in range(n):
            d1[i, a] = r[i, a]
    solved = False
    last = math.inf
    for _ in range(NEUMANN_MAX):
        _apply(nw, d1, d2, g, q, u, laws, geo, Kp, Kd, E2, W2, w, hp, t, -1, 0)
        change = 0.0
        for i in range(N):
            for a in range(n):
                v = r[i, a] + d2[i, a]
                change = max(change, abs(v - d1[i, a]))
                d1[i, a] = v
        if not math.isfinite(change) or change > 0.5 * last:
            break
        last = change
        if change <= min(LINEAR_TOL * rmax, target):
            solved = True
            break
    if not solved and not _dense(nw, r, g, q, u, laws, geo, Kp, Kd, E2, W2, w, hp, t):
        for i in range(N):
            for a in range(n):
                d1[i, a] = r[i, a]
    big = 0.0
    for i in range(N):
        for a in range(n):
            if jkn[i] == UNKNOWN:
                d1[i, a] *= OMEGA0
            big = max(big, abs(d1[i, a]))
    f = GROW * rmax / big if big > GROW * rmax else 1.0
    if not math.isfinite(big):
        f = 0.0
    for i in range(N):
        for a in range(n):
            te[i, a] += f * d1[i, a]


# the implicit exchange's helpers (fmu_sync.cosim_loop.implicit_step): its tolerance's force scale,
# the residual, and the trust region of its iterates
#: the trust region of the implicit exchange's iterates: no FMU is given a force beyond this
#: fraction of its input bound (an iterate outside it is moved to its edge; the law's own force at
#: the step's start, inside the bound, stays inside: issue 44 item 7)
TRUST = 0.5


@njit(cache=True, inline="always")
def force_scale(g, ta, q, u, Kp, Kd):
    """The force scale of the implicit exchange's tolerance: the largest force at either end of
    the step plus the largest law terms Kp q and Kd u could carry (round-off of the law)."""
    fmax = 0.0
    xq = 0.0
    xu = 0.0
    for i in range(g.shape[0]):
        for c in range(g.shape[1]):
            fmax = max(fmax, abs(g[i, c]), abs(ta[i, c]))
            xq = max(xq, abs(q[i, c]))
            xu = max(xu, abs(u[i, c]))
    kp = 0.0
    kd = 0.0
    for a in range(Kp.shape[0]):
        for b in range(Kp.shape[1]):
            kp = max(kp, abs(Kp[a, b]))
            kd = max(kd, abs(Kd[a, b]))
    return fmax + kp * xq + kd * xu


@njit(cache=True, inline="always")
def residual_max(g, te, r):
    """r = g - te; returns max |r| (inf if an entry is not finite)."""
    rmax = 0.0
    for i in range(g.shape[0]):
        for c in range(g.shape[1]):
            r[i, c] = g[i, c] - te[i, c]
            rmax = max(rmax, abs(r[i, c])) if math.isfinite(r[i, c]) else math.inf
    return rmax


@njit(cache=True, inline="always")
def dot_rows(a, b):
    s = 0.0
    for i in range(a.shape[0]):
        for c in range(a.shape[1]):
            s += a[i, c] * b[i, c]
    return s


@njit(cache=True, inline="always")
def trust_clip(te):
    """Every iterate inside the trust region: each force component clipped to +-TRUST * INPUT_BOUND
    (a box: the quasi-Newton secants stay exact, since they are built from the forces applied)."""
    b = TRUST * INPUT_BOUND
    for i in range(te.shape[0]):
        for c in range(te.shape[1]):
            if te[i, c] > b:
                te[i, c] = b
            elif te[i, c] < -b:
                te[i, c] = -b
