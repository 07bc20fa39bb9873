"""The planar core of the quotient distance (docs/design.md §2.4): the branches E,
J and J2 of the distance in the plane of normal coordinates ``(X, Y)`` to which
:mod:`.distance` reduces every n-DOF pair of states exactly.

Planar branches (:func:`distance_2d`):

* ``J(a, b) = min_{s<=0} f(s)``, ``f(s) = |a - (0,s)| + |(0,-e s) - b|``, convex;
  closed forms for ``e = 0``, ``aX = 0`` and ``bX = 0``, otherwise a safeguarded
  Newton iteration (Newton inside a bracket, bisection fallback) on ``f'``.
* ``J2`` in closed form: splitting ``|s1 - s2|`` by sign gives two separable
  convex problems whose minimisers are explicit; a candidate counts when its
  ordering holds (otherwise the optimum has ``s1 = s2`` and ``J2 >= E``).
  For ``e = 1``, ``J2 >= E`` always and the branch is skipped.
* Cheap lower bounds (distances to the half-lines ``{X = 0, Y <= 0}`` and
  ``{X = 0, Y >= 0}``) skip branches that cannot beat the best value so far.
  Ties go to E, then J12, J21, J2.

All kernels take floats only (no arrays: see the cost note in :mod:`.distance`).
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

__all__ = ["BRANCH_E", "BRANCH_J12", "BRANCH_J21", "BRANCH_J2", "BRANCH_NAMES", "BRANCH_FREE", "core_2d",
           "distance_2d", "branch_values_2d"]

BRANCH_E = 0
BRANCH_J12 = 1
BRANCH_J21 = 2
BRANCH_J2 = 3
BRANCH_NAMES = ("E", "J12", "J21", "J2")
#: The ``fix`` argument of the kernels that lets the distance choose its branch (the minimum
#: over the branches); a branch code instead evaluates that branch's chain alone (the implicit
#: exchange holds the law on one branch within a communication step, docs/design.md §4.4).
BRANCH_FREE = -1

#: Iteration cap of the safeguarded Newton solve for J (bisection alone needs
#: < 1100 halvings to exhaust any float64 bracket; in practice 3-8 steps).
_MAX_ITER = 200
#: Relative step tolerance of that solve.  Where f is smooth at its minimiser
#: the value is quadratic in the error of s (Newton gets there in 1-2 more
#: steps anyway), but next to a kink (|aX| or |bX| below the tolerance) it is
#: linear, so s is resolved to a few ulps of the bracket.
_S_RTOL = 1e-13


@njit(cache=True, inline="always", error_model="numpy")
def _hyp(x, y):
    return math.sqrt(x * x + y * y)


@njit(cache=True, inline="always", error_model="numpy")
def _dJ(s, aX2, aY, bX2, bY, e):
    """f'(s) and f''(s) of f(s) = sqrt(aX^2 + (aY-s)^2) + sqrt(bX^2 + (bY+e s)^2)."""
    t1 = s - aY
    t2 = bY + e * s
    r1 = math.sqrt(aX2 + t1 * t1)
    r2 = math.sqrt(bX2 + t2 * t2)
    fp = 0.0
    fpp = 0.0
    # one division per term; aX^2 / r1^3 as ((aX^2 i1) i1) i1, which neither
    # under- nor overflows for tiny r1 (r1 >= |aX|)
    if r1 > 0.0:
        i1 = 1.0 / r1
        fp += t1 * i1
        fpp += aX2 * i1 * i1 * i1
    if r2 > 0.0:
        i2 = 1.0 / r2
        fp += e * (t2 * i2)
        fpp += e * e * (bX2 * i2 * i2 * i2)
    return fp, fpp


@njit(cache=True, inline="always", error_model="numpy")
def _bracket(s, fp, xl, xh):
    """The bracket [xl, xh] of the root of f' shrunk to s by the sign of f'(s)."""
    if fp < 0.0:
        return s, xh
    return xl, s


@njit(cache=True, inline="always", error_model="numpy")
def _J_start(aY, bY, e, k, ax, bx, bX2):
    """(s, xl, xh): the start of the Newton solve for J and the bracket (:func:`_J_newton`),
    before the constraint s <= 0."""
    if e < 1.0:
        # start: Snell's condition with the direction to b frozen at s = aY
        # (exact in the limit |aX| << distance to b, e.g. right at an impact)
        t2 = bY + e * aY
        beta = e * t2 / math.sqrt(bX2 + t2 * t2)
        return aY - beta * ax / math.sqrt(1.0 - beta * beta), aY - k * ax, aY + k * ax
    # start: the mirror formula (exact for e = 1): where the segment from
    # (|aX|, aY) to (-|bX|, -bY) crosses X = 0
    return aY + ax / (ax + bx) * (-bY - aY), min(aY, -bY), 0.0


@njit(cache=True, error_model="numpy")
def _J_newton(aX, aY, bX, bY, e, k, aX2, bX2):
    """Minimiser s <= 0 of f(s) = sqrt(aX^2 + (aY-s)^2) + sqrt(bX^2 + (bY+e s)^2)
    for e > 0, aX != 0, bX != 0 (f smooth and strictly convex).

    Bracket [xl, xh] with f'(xl) <= 0 <= f'(xh).  At the minimiser
    (s - aY)/r1 = -e (bY + e s)/r2, so |s - aY| <= k|aX| with k = e/sqrt(1-e^2)
    (Snell): for e < 1 the root lies within k|aX| of aY, and (s - aY)/r1 = -+e
    there makes f' <= 0 resp. >= 0.  For e = 1 both terms of f' are <= 0 at
    min(aY, -bY).  The constraint s <= 0 is active iff f'(0) <= 0.
    Safeguarded Newton (Newton inside the bracket, bisection when a step would
    leave it or stalls), with a probe that confirms convergence next to kinks.
    """
    ax = abs(aX)
    bx = abs(bX)
    s, xl, xh = _J_start(aY, bY, e, k, ax, bx, bX2)
    if xh >= 0.0:
        fp, fpp = _dJ(0.0, aX2, aY, bX2, bY, e)
        if fp <= 0.0:
            return 0.0
        xh = 0.0
    if s > xh:
        s = xh
    if s < xl:
        s = xl
    # relative to the size of the states (not of the bracket, which is wide
    # for e -> 1): next to a kink the value error is linear in that of s
    tol = _S_RTOL * (abs(aY) + abs(bY) + ax + bx)
    fp, fpp = _dJ(s, aX2, aY, bX2, bY, e)
    if fp == 0.0:
        return s
    xl, xh = _bracket(s, fp, xl, xh)
    dx = xh - xl
    dxold = dx
    bisect = False
    for _ in range(_MAX_ITER):
        if (bisect or ((s - xh) * fpp - fp) * ((s - xl) * fpp - fp) > 0.0
                or abs(2.0 * fp) > abs(dxold * fpp)):
            # Newton would leave the bracket or is not shrinking fast: bisect
            dxold = dx
            dx = 0.5 * (xh - xl)
            s = xl + dx
            bisect = False
            if s == xl or s == xh:   # bracket exhausted in float64
                return s
        else:
            dxold = dx
            dx = fp / fpp
            s -= dx
            if abs(dx) <= tol:
                # Converged -- unless stalled next to a kink of f' (|aX| or |bX|
                # tiny, f'' huge).  f' is monotone: a sign change within tol
                # beyond s (on the far side from the previous iterate) confirms.
                probe = s - tol if dx > 0.0 else s + tol
                if probe == s:
                    return s
                fq, fqq = _dJ(probe, aX2, aY, bX2, bY, e)
                if fq == 0.0:
                    return probe
                if (fq > 0.0) != (dx > 0.0):
                    return s
                s = probe          # stalled: continue from the probe, bisecting
                fp = fq
                fpp = fqq
                xl, xh = _bracket(s, fp, xl, xh)
                bisect = True
                continue
        fp, fpp = _dJ(s, aX2, aY, bX2, bY, e)
        if fp == 0.0:
            return s
        xl, xh = _bracket(s, fp, xl, xh)
        if xh - xl <= tol:
            return s
    return s


@njit(cache=True, error_model="numpy")
def _J(aX, aY, bX, bY, e, k):
    """J(a, b) = min_{s<=0} |a - (0,s)| + |(0,-e s) - b| in the plane;
    ``k = e / sqrt(1 - e^2)`` (inf for e = 1).

    Returns ``(J, s, r1, r2)`` with ``r1 = |a - (0,s)|``, ``r2 = |(0,-e s) - b|``.
    """
    aX2 = aX * aX
    bX2 = bX * bX
    if e == 0.0 or aX2 == 0.0:
        # e = 0: the second term does not depend on s.  aX = 0: the kink of the
        # first term at s = aY is optimal because |d r2/ds| <= e <= 1.
        s = min(aY, 0.0)
    elif bX2 == 0.0:
        # kink of the second term at sk = -bY/e, where f' jumps by 2e; the
        # first term's slope there, g = t/sqrt(aX^2 + t^2) with t = sk - aY,
        # decides: |g| <= e <=> |t| <= k|aX| (comparisons stay right when sk
        # overflows to -+inf for tiny e).
        sk = -bY / e
        t = sk - aY
        if t > k * abs(aX):      # g > e: root of g(s) = e, left of sk (e < 1)
            s = aY + k * abs(aX)
        elif t < -k * abs(aX):   # g < -e: root of g(s) = -e, right of sk
            s = aY - k * abs(aX)
        else:
            s = sk
        s = min(s, 0.0)
    else:
        s = _J_newton(aX, aY, bX, bY, e, k, aX2, bX2)
    r1 = _hyp(aX, aY - s)
    r2 = _hyp(bX, bY + e * s)
    return r1 + r2, s, r1, r2


@njit(cache=True, error_model="numpy")
def _J2(aX, aY, bX, bY, e, k):
    """J2(a, b) = min_{s1,s2<=0} |a-(0,s1)| + e|s1-s2| + |(0,s2)-b| for 0 <= e < 1,
    ``k = e / sqrt(1 - e^2)``.

    Returns ``(J2, s1, s2, r1, r3, r2)`` (r3 = e|s1 - s2|, the middle segment);
    ``J2 = inf`` when neither sign case has its ordering (then J2 >= E).
    """
    ax = abs(aX)
    bx = abs(bX)
    best = np.inf
    b1 = 0.0
    b2 = 0.0
    q1 = 0.0
    q2 = 0.0
    # case s1 >= s2: min r1(s1) + e s1  and  min r2(s2) - e s2, separately
    s1 = min(0.0, aY - k * ax)
    s2 = min(0.0, bY + k * bx)
    if s1 >= s2:
        r1 = _hyp(aX, aY - s1)
        r2 = _hyp(bX, bY - s2)
        v = r1 + e * (s1 - s2) + r2
        if v < best:
            best, b1, b2, q1, q2 = v, s1, s2, r1, r2
    # case s2 >= s1
    s1 = min(0.0, aY + k * ax)
    s2 = min(0.0, bY - k * bx)
    if s2 >= s1:
        r1 = _hyp(aX, aY - s1)
        r2 = _hyp(bX, bY - s2)
        v = r1 + e * (s2 - s1) + r2
        if v < best:
            best, b1, b2, q1, q2 = v, s1, s2, r1, r2
    return best, b1, b2, q1, e * abs(b1 - b2), q2


@njit(cache=True, inline="always", error_model="numpy")
def _j12(aX, aY, bX, bY, e, k):
    """J(a, b) with its boundary point s and the tangential fraction of that point."""
    v, s, r1, r2 = _J(aX, aY, bX, bY, e, k)
    return v, s, r1 / v if v > 0.0 else 0.5


@njit(cache=True, inline="always", error_model="numpy")
def _j21(aX, aY, bX, bY, e, k):
    """J(b, a) with its boundary point s and the tangential fraction of that point (from a)."""
    v, s, r1, r2 = _J(bX, bY, aX, aY, e, k)
    return v, s, r2 / v if v > 0.0 else 0.5


@njit(cache=True, inline="always", error_model="numpy")
def _j2(aX, aY, bX, bY, e, k):
    """J2(a, b) with its boundary points s1, s2 and their tangential fractions."""
    v, t1, t2, r1, r3, r2 = _J2(aX, aY, bX, bY, e, k)
    R = r1 + r3 + r2
    if R > 0.0:
        return v, t1, t2, r1 / R, (r1 + r3) / R
    return v, t1, t2, 0.5, 0.5


@njit(cache=True, error_model="numpy")
def core_2d(aX, aY, bX, bY, dX, dY, e, k, prune, fix=BRANCH_FREE):
    """Planar distance with branch, jump parameters and tangential fractions.

    ``(dX, dY) = a - b`` is passed separately so that callers can form it from
    ``x1 - x2`` directly: E is then exact for nearby states even where X holds
    a large offset g0 (X1 - X2 would cancel).

    Returns ``(d, branch, s1, s2, lam1, lam2)``: for J12/J21 the boundary point
    is ``(0, s1)`` and its tangential part sits at fraction ``lam1`` from x1
    towards x2; for J2 the points are ``(0, s1)``, ``(0, s2)`` at ``lam1``,
    ``lam2``.  ``k = e / sqrt(1 - e^2)`` (inf for e = 1).  ``prune=False``
    evaluates every branch (benchmarks, tests). ``fix``: :data:`BRANCH_FREE`
    (the minimum over the branches) or a branch code: the length of that branch's
    shortest chain alone (>= d), whether or not it is the shortest; J2 where it is not
    defined (e = 1, or neither ordering holds: J2 >= E there) gives the free choice.
    """
    if fix == BRANCH_E:
        return _hyp(dX, dY), BRANCH_E, 0.0, 0.0, 0.0, 0.0
    if fix == BRANCH_J12:
        v, s, lam = _j12(aX, aY, bX, bY, e, k)
        return v, BRANCH_J12, s, 0.0, lam, 0.0
    if fix == BRANCH_J21:
        v, s, lam = _j21(aX, aY, bX, bY, e, k)
        return v, BRANCH_J21, s, 0.0, lam, 0.0
    if fix == BRANCH_J2 and e < 1.0:
        v, t1, t2, lam1, lam2 = _j2(aX, aY, bX, bY, e, k)
        if v < np.inf:
            return v, BRANCH_J2, t1, t2, lam1, lam2
    d = _hyp(dX, dY)
    branch = BRANCH_E
    s1 = 0.0
    s2 = 0.0
    lam1 = 0.0
    lam2 = 0.0
    # distances to the pre-impact half-line {X=0, Y<=0} (m) and its image
    # {X=0, Y>=0} (p): one of them is |X|, the other |(X, Y)|
    ra = _hyp(aX, aY)
    rb = _hyp(bX, bY)
    am = ra if aY > 0.0 else abs(aX)
    ap = abs(aX) if aY > 0.0 else ra
    bm = rb if bY > 0.0 else abs(bX)
    bp = abs(bX) if bY > 0.0 else rb
    if not prune or am + bp < d:
        v, s, lam = _j12(aX, aY, bX, bY, e, k)
        if v < d:
            d = v
            branch = BRANCH_J12
            s1 = s
            lam1 = lam
    if not prune or bm + ap < d:
        v, s, lam = _j21(aX, aY, bX, bY, e, k)
        if v < d:
            d = v
            branch = BRANCH_J21
            s1 = s
            lam1 = lam
    if e < 1.0 and (not prune or am + bm < d):
        v, t1, t2, l1, l2 = _j2(aX, aY, bX, bY, e, k)
        if v < d:
            d = v
            branch = BRANCH_J2
            s1 = t1
            s2 = t2
            lam1 = l1
            lam2 = l2
    return d, branch, s1, s2, lam1, lam2


@njit(cache=True, inline="always", error_model="numpy")
def _snell(e):
    """k = e / sqrt(1 - e^2): |s - aY| <= k |aX| at the minimiser of J (inf for e = 1)."""
    return e / math.sqrt(1.0 - e * e) if e < 1.0 else np.inf


@njit(cache=True, error_model="numpy")
def distance_2d(aX, aY, bX, bY, e):
    """Planar quotient distance (wall X = 0, dA- = {(0, s): s <= 0}, Zbar(0,s) = (0,-e s)).

    Returns ``(d, branch, s1, s2, lam1, lam2)`` (see :func:`core_2d`).
    """
    return core_2d(aX, aY, bX, bY, aX - bX, aY - bY, e, _snell(e), True)


@njit(cache=True, error_model="numpy")
def branch_values_2d(aX, aY, bX, bY, e):
    """All four planar branch values ``(E, J12, J21, J2)`` without pruning.
    ``J2`` is reported as ``inf`` for ``e = 1`` (where ``J2 >= E``) and when
    neither ordering case applies (then ``J2 >= E`` as well)."""
    k = _snell(e)
    E = _hyp(aX - bX, aY - bY)
    J12 = _J(aX, aY, bX, bY, e, k)[0]
    J21 = _J(bX, bY, aX, aY, e, k)[0]
    J2 = np.inf
    if e < 1.0:
        J2 = _J2(aX, aY, bX, bY, e, k)[0]
    return E, J12, J21, J2
