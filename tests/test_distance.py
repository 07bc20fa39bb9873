"""Quotient distance (docs/design.md §2.4): properties and agreement with brute force.

The reference here is independent of the kernel's planar reduction: it works in
ORIGINAL coordinates, parametrising dA- = {g(q) = 0, w^T u <= 0} directly and
minimising the chain lengths with scipy from several starts.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize

from fmu_sync.core.distance import (
    BRANCH_E, BRANCH_J12, BRANCH_J21, BRANCH_J2, BRANCH_NAMES, DistanceGeometry,
    branch_values_2d, distance_2d, distance_kernel, distance_kernel_unpruned, distance_value,
    geometry, make_geometry, quotient_distance)
from fmu_sync.core.impact import impact_map_kernel as impact_map
from fmu_sync.core.model import ImpactOscillator, MechanicalSystem

E_VALUES = (0.0, 0.05, 0.8, 1.0)
M2 = [[2.0, 0.5], [0.5, 1.0]]

# name -> (M, w, g0, Q).  1a: the Q = m = 1 oscillator; 1b: a scaled and
# shifted wall (g = 2q - 0.5) with m, Q != 1; 2a: oblique wall with exact
# dyadic boundary points; 2b: the oblique, non-normalised w = (1, -0.3).
SYSTEMS = {
    "1a": ([[1.0]], [1.0], 0.0, 1.0),
    "1b": ([[2.5]], [2.0], -0.5, 0.7),
    "2a": (M2, [1.0, -0.5], 0.25, [[1.5, 0.3], [0.3, 0.7]]),
    "2b": (M2, [1.0, -0.3], 0.2, [[0.8, -0.2], [-0.2, 1.3]]),
}


@functools.lru_cache(maxsize=None)
def geo_of(name, e):
    M, w, g0, Q = SYSTEMS[name]
    return make_geometry(M, w, g0, e, Q)


class Ref:
    """Independent reference in original coordinates (numpy/scipy only).

    dA- is parametrised affinely: y(p) = (qw + V t, V a + min(sigma, 0) M^-1 w / W)
    with p = (t, a, sigma), V a basis of w-perp, so that w^T u = min(sigma, 0) <= 0.
    On dA-, Zbar(y) = (q, u - (1+e) M^-1 w min(sigma, 0) / W) is affine in p too, and
    every chain length is a sum of terms ||c - B p'||_P = |L (c - B p')| (L^T L =
    blockdiag(Q, M)) with p' = p after clipping sigma.
    """

    def __init__(self, name, e):
        M, w, g0, Q = SYSTEMS[name]
        self.M = np.array(M, float)
        self.w = np.array(w, float)
        self.g0 = float(g0)
        self.e = float(e)
        n = self.M.shape[0]
        self.n = n
        self.Q = np.eye(n) * Q if np.ndim(Q) == 0 else np.array(Q, float)
        self.Mw = np.linalg.inv(self.M) @ self.w
        self.W = float(self.w @ self.Mw)
        self.qw = -self.g0 * self.w / (self.w @ self.w)      # a point of g = 0
        self.V = np.linalg.svd(self.w.reshape(1, -1))[2][1:].T  # (n, n-1) basis of w-perp
        k = n - 1
        self.k = k
        L = np.zeros((2 * n, 2 * n))
        L[:n, :n] = np.linalg.cholesky(self.Q).T
        L[n:, n:] = np.linalg.cholesky(self.M).T
        self.L = L
        # y(p) = Y0 + Yp p',  Zbar(y(p)) = Y0 + Zp p'   (stacked (q, u), 2n entries)
        Yp = np.zeros((2 * n, 2 * k + 1))
        Yp[:n, :k] = self.V
        Yp[n:, k:2 * k] = self.V
        Yp[n:, 2 * k] = self.Mw / self.W
        Zp = Yp.copy()
        Zp[n:, 2 * k] = -self.e * self.Mw / self.W
        self.Y0 = np.concatenate([self.qw, np.zeros(n)])
        self.LYp, self.LZp, self.LY0 = L @ Yp, L @ Zp, L @ self.Y0

    def norm(self, dq, du):
        return math.sqrt(max(float(dq @ self.Q @ dq + du @ self.M @ du), 0.0))

    def Zbar(self, q, u):
        return q, u - (1.0 + self.e) * self.Mw * min(0.0, float(self.w @ u)) / self.W

    def params(self, q, u):
        """Parameters of (roughly) the nearest boundary point to (q, u)."""
        return np.concatenate([self.V.T @ (q - self.qw), self.V.T @ u, [min(float(self.w @ u), 0.0)]])

    def E(self, x1, x2):
        return self.norm(x1[0] - x2[0], x1[1] - x2[1])

    def _L(self, x):
        return self.L @ np.concatenate([x[0], x[1]]) - self.LY0

    def _terms_J(self, a, b):
        """J(a, b) = sum_i |A_i p - c_i| over p = (t, alpha, sigma), sigma <= 0."""
        return [(self.LYp, self._L(a)), (self.LZp, self._L(b))]

    def _terms_J2(self, a, b):
        """J2(a, b) over p = (p1, p2): |a - y1| + |Zbar y1 - Zbar y2| + |y2 - b|."""
        m = self.LYp.shape[1]
        Z = np.zeros_like(self.LYp)
        return [(np.hstack([self.LYp, Z]), self._L(a)),
                (np.hstack([self.LZp, -self.LZp]), np.zeros(2 * self.n)),
                (np.hstack([Z, self.LYp]), self._L(b))]

    @staticmethod
    def _minimise(terms, starts):
        """min sum_i |A_i p - c_i| subject to sigma <= 0 (the last parameter of
        each boundary point).  The problem is convex; its kinks (zero-length
        segments, typical for boundary states) are smoothed: SLSQP with the exact
        gradient on sum_i sqrt(|A_i p - c_i|^2 + eps^2), eps = 1e-3 -> 1e-6 -> 1e-9
        (continuation), which changes the optimal value by at most len(terms) * eps.
        Returns the exact objective at the best point found, i.e. the length of a
        feasible chain (an upper bound of the infimum, within ~3e-9 of it)."""
        P = terms[0][0].shape[1]
        sig = [k for k in range(P) if (k + 1) % (P // (len(terms) - 1)) == 0]
        bounds = [(None, 0.0) if k in sig else (None, None) for k in range(P)]

        def exact(p):
            p = p.copy()
            p[sig] = np.minimum(p[sig], 0.0)
            return sum(math.sqrt(float(r @ r)) for r in (A @ p - c for A, c in terms))

        best = math.inf
        for p0 in starts:
            p = np.asarray(p0, float).copy()
            p[sig] = np.minimum(p[sig], 0.0)
            for eps in (1e-3, 1e-6, 1e-9):
                def smooth(p, eps=eps):
                    f, g = 0.0, np.zeros(P)
                    for A, c in terms:
                        r = A @ p - c
                        nr = math.sqrt(float(r @ r) + eps * eps)
                        f += nr
                        g += A.T @ r / nr
                    return f, g
                p = minimize(smooth, p, jac=True, method="SLSQP", bounds=bounds,
                             options=dict(maxiter=1000, ftol=1e-15)).x
            best = min(best, exact(p))
        return best

    def J(self, a, b):
        pa, pb = self.params(*a), self.params(*b)
        deep = 0.5 * (pa + pb)
        deep[-1] = -1.0 - abs(deep[-1])  # a start deep in dA- as well
        return self._minimise(self._terms_J(a, b), [pa, deep])

    def J2(self, a, b):
        pa, pb = self.params(*a), self.params(*b)
        mid = 0.5 * (pa + pb)
        starts = [np.concatenate([pa, pb]), np.concatenate([mid, mid])]  # convex: 2 suffice
        return self._minimise(self._terms_J2(a, b), starts)


def planar_branches(geo: DistanceGeometry, x1, x2):
    """(E, J12, J21, J2) of the n-DOF problem through the reduction d = sqrt(D^2 + d_2D^2).

    Written out here from the formulas (normal coordinates, tangential projections)
    to test the reduction itself against the brute force in original coordinates.
    """
    (q1, u1), (q2, u2) = x1, x2
    w, Q, M = geo.w, geo.Q, geo.M
    Qw, Mw = np.linalg.solve(Q, w), np.linalg.solve(M, w)
    WQ, W = w @ Qw, w @ Mw
    X = lambda q: (w @ q + geo.g0) / math.sqrt(WQ)
    Y = lambda u: (w @ u) / math.sqrt(W)
    dq, du = q1 - q2, u1 - u2
    dqp = dq - (w @ dq) / WQ * Qw
    dut = du - (w @ du) / W * Mw
    D2 = dqp @ Q @ dqp + dut @ M @ dut if q1.size > 1 else 0.0
    vals = branch_values_2d(X(q1), Y(u1), X(q2), Y(u2), geo.e)
    return tuple(math.sqrt(D2 + v * v) for v in vals)


# ------------------------------------------------------------------ strategies
dyadic = st.integers(-192, 192).map(lambda k: k / 64.0)
tiny = st.sampled_from([0.0, 1e-300, 1e-14, -1e-14, 1e-9, 1e-6])
free_coord = st.one_of(st.floats(-3.0, 3.0, allow_subnormal=False), dyadic, tiny)


@st.composite
def states(draw, name, kind=None):
    """Boundary-heavy states of system ``name`` as (q, u) float64 arrays."""
    M, w, g0, Q = SYSTEMS[name]
    w = np.array(w, float)
    n = w.size
    if kind is None:
        kind = draw(st.sampled_from(["free", "free", "pre", "post", "graze", "near"]))
    if kind == "free":
        q = np.array([draw(free_coord) for _ in range(n)])
        u = np.array([draw(free_coord) for _ in range(n)])
        return q, u
    # a point on g = 0 (exact for the dyadic systems 1a, 1b, 2a)
    if n == 1:
        q = np.array([-g0 / w[0]])
        tangent = None
    else:
        t = draw(dyadic)
        q = np.array([(w[1] * -t - g0) / w[0], t]) if name == "2b" else np.array([0.5 * t - 0.25, t])
        tangent = np.array([-w[1], w[0]])  # w^T tangent = 0 exactly
    if kind == "near":
        q = q + draw(st.sampled_from([1e-300, 1e-13, -1e-13, 1e-8, 3e-5])) * w
    s = draw(dyadic)
    if kind == "pre" or kind == "near":
        s = -abs(s)
    elif kind == "post":
        s = abs(s)
    else:
        s = 0.0
    # normal velocity w^T u = s (via M^-1 w direction is not exact; use e_1 / w_1)
    u = np.zeros(n)
    u[0] = s / w[0]
    if tangent is not None:
        u = u + draw(dyadic) * tangent
    return q, u


def scale_of(*xs):
    return 1.0 + sum(float(np.abs(q).sum() + np.abs(u).sum()) for q, u in xs)


def d_of(geo, x1, x2):
    n = x1[0].size
    c = np.zeros((4, n))
    return distance_kernel(geo, x1[0], x1[1], x2[0], x2[1], c[0], c[1], c[2], c[3])[0]


def full_of(geo, x1, x2):
    n = x1[0].size
    c = np.zeros((4, n))
    d, b = distance_kernel(geo, x1[0], x1[1], x2[0], x2[1], c[0], c[1], c[2], c[3])
    return d, b, (c[0], c[1]), (c[2], c[3])


def Zbar_ref(geo, q, u):
    Mw = np.linalg.solve(geo.M, geo.w)
    return q.copy(), u - (1.0 + geo.e) * Mw * min(0.0, float(geo.w @ u)) / float(geo.w @ Mw)


def on_pre_impact(geo, x, tol=1e-12):
    q, u = x
    return abs(geo.w @ q + geo.g0) <= tol and geo.w @ u <= tol


system_names = st.sampled_from(list(SYSTEMS))
restitutions = st.one_of(st.sampled_from(E_VALUES), st.floats(0.0, 1.0))


@st.composite
def scene(draw, k=2):
    name = draw(system_names)
    e = draw(restitutions)
    return (name, e) + tuple(draw(states(name)) for _ in range(k))


FAST = settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SLOW = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ---------------------------------------------------------------- pseudometric
@FAST
@given(scene(2))
def test_symmetric_nonnegative_and_at_most_E(sc):
    name, e, x1, x2 = sc
    geo = geo_of(name, e)
    d12 = d_of(geo, x1, x2)
    d21 = d_of(geo, x2, x1)
    E = Ref(name, e).E(x1, x2)
    tol = 1e-12 * scale_of(x1, x2)
    assert d12 >= 0.0
    assert abs(d12 - d21) <= tol
    assert d12 <= E + tol
    assert d_of(geo, x1, x1) == 0.0


@settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene(3))
def test_triangle_inequality(sc):
    name, e, x, y, z = sc
    geo = geo_of(name, e)
    tol = 1e-9 * scale_of(x, y, z)
    assert d_of(geo, x, z) <= d_of(geo, x, y) + d_of(geo, y, z) + tol


@st.composite
def scene_pre(draw):
    """(name, e, x, y) with y in dA- (pre-impact or grazing boundary state)."""
    name = draw(system_names)
    e = draw(restitutions)
    return name, e, draw(states(name)), draw(states(name, draw(st.sampled_from(["pre", "graze"]))))


@FAST
@given(scene_pre())
def test_invariant_under_impact_map(sc):
    """d(x, y) = d(x, Zbar(y)) for y in dA- (equivalent states are at distance 0)."""
    name, e, x, y = sc
    geo = geo_of(name, e)
    assume(on_pre_impact(geo, y, 1e-15))
    zy = Zbar_ref(geo, *y)
    tol = 1e-12 * scale_of(x, y, zy)
    assert abs(d_of(geo, x, y) - d_of(geo, x, zy)) <= tol
    assert d_of(geo, y, zy) <= tol


@FAST
@given(scene(2))
def test_pruned_equals_unpruned(sc):
    """Skipping branches by their lower bounds never changes d or the branch."""
    name, e, x1, x2 = sc
    geo = geo_of(name, e)
    c = np.zeros((8, x1[0].size))
    d, b = distance_kernel(geo, *x1, *x2, c[0], c[1], c[2], c[3])
    du, bu = distance_kernel_unpruned(geo, *x1, *x2, c[4], c[5], c[6], c[7])
    assert d == du and b == bu
    assert np.array_equal(c[:4], c[4:])
    assert distance_value(geo, *x1, *x2) == (d, b)


@FAST
@given(scene(2), st.sampled_from([BRANCH_E, BRANCH_J12, BRANCH_J21, BRANCH_J2]))
def test_a_held_branch_is_that_branch_alone(sc, fix):
    """``fix`` (the implicit exchange's held branch, docs/design.md §4.4): holding the branch the
    distance picks gives its result bit for bit (d, branch, chain ends); holding another gives that
    branch's chain, no shorter than d -- except J2 where it is not defined (inf in
    branch_values_2d), which gives the free result."""
    name, e, x1, x2 = sc
    geo = geo_of(name, e)
    c = np.zeros((8, x1[0].size))
    d, b = distance_kernel(geo, *x1, *x2, c[0], c[1], c[2], c[3])
    assert distance_kernel(geo, *x1, *x2, c[4], c[5], c[6], c[7], b) == (d, b) and np.array_equal(c[:4], c[4:])
    dh, bh = distance_kernel(geo, *x1, *x2, c[4], c[5], c[6], c[7], fix)
    if bh != fix:
        assert fix == BRANCH_J2 and (dh, bh) == (d, b)
    else:
        assert dh >= d * (1.0 - 1e-12)


@settings(max_examples=800, deadline=None)
@given(st.floats(0.0, 3.0), st.floats(-3.0, 3.0), st.floats(0.0, 3.0), st.floats(-3.0, 3.0),
       st.one_of(st.sampled_from(E_VALUES), st.floats(0.01, 1.0)))
def test_a_held_planar_branch_has_the_value_of_branch_values_2d(aX, aY, bX, bY, e):
    """core_2d with a branch held returns that branch's value as branch_values_2d computes it."""
    from fmu_sync.core.distance_planar import core_2d
    k = e / math.sqrt(1.0 - e * e) if e < 1.0 else math.inf
    free = core_2d(aX, aY, bX, bY, aX - bX, aY - bY, e, k, True)
    for fix, v in enumerate(branch_values_2d(aX, aY, bX, bY, e)):
        held = core_2d(aX, aY, bX, bY, aX - bX, aY - bY, e, k, True, fix)
        if math.isfinite(v):
            assert held[:2] == (v, fix)
        else:
            assert held == free


small = st.one_of(st.just(0.0), st.floats(1e-120, 1e-9), st.floats(-1e-9, -1e-120))


@FAST
@given(system_names, restitutions, st.floats(0.5, 3.0), st.floats(-3.0, 3.0), small, small,
       st.integers(0, 1))
def test_nearby_states_keep_relative_accuracy(name, e, dist, u, dq, du, k):
    """Away from the wall d = E, computed from x1 - x2 (not from differences of
    wall coordinates that carry the offset g0): relative accuracy at tiny E.
    (Below ~1e-150 the squares underflow -- as does V = d^2/2 itself.)"""
    ref = Ref(name, e)
    geo = geo_of(name, e)
    n = ref.n
    q1 = ref.qw + dist * ref.w / np.linalg.norm(ref.w) + 0.3 * k
    x1 = (q1, np.full(n, u))
    x2 = (q1 + dq, x1[1] + du)
    E = ref.E(x1, x2)
    assert abs(d_of(geo, x1, x2) - E) <= 1e-12 * E


# ---------------------------------------------------------------- brute force
@SLOW
@given(scene(2))
def test_agrees_with_brute_force(sc):
    """Each branch, and d, against scipy in original coordinates.

    Tolerance: the reference is a feasible chain, so kernel <= reference must
    hold to round-off (1e-10 scaled); Nelder-Mead on these convex (but kinked,
    for boundary states) problems reaches ~1e-9, so the other side gets 1e-6
    relative to the size of the states.
    """
    name, e, x1, x2 = sc
    ref = Ref(name, e)
    geo = geo_of(name, e)
    scale = scale_of(x1, x2)
    E, J12, J21, J2 = planar_branches(geo, x1, x2)
    assert abs(E - ref.E(x1, x2)) <= 1e-12 * scale
    for mine, theirs in ((J12, ref.J(x1, x2)), (J21, ref.J(x2, x1))):
        assert mine <= theirs + 1e-10 * scale
        assert theirs <= mine + 1e-6 * scale
    r2 = ref.J2(x1, x2)
    if math.isinf(J2):  # e = 1 or no sign ordering: the optimum is not below E
        assert r2 >= E - 1e-6 * scale
    else:
        assert J2 <= r2 + 1e-10 * scale
        assert r2 <= J2 + 1e-6 * scale
    d = d_of(geo, x1, x2)
    brute = min(ref.E(x1, x2), ref.J(x1, x2), ref.J(x2, x1), r2)
    assert d <= brute + 1e-10 * scale
    assert brute <= d + 1e-6 * scale
    assert abs(d - min(E, J12, J21, J2)) <= 1e-12 * scale


@pytest.mark.parametrize("name", list(SYSTEMS))
@pytest.mark.parametrize("e", E_VALUES)
def test_brute_force_fixed_cases(name, e):
    """A few hand-picked configurations (both sides of the wall, grazing, far)."""
    ref = Ref(name, e)
    geo = geo_of(name, e)
    rng = np.random.default_rng(7)
    n = ref.n
    for _ in range(1):
        x1 = (ref.qw + 0.3 * rng.standard_normal(n), rng.standard_normal(n))
        x2 = (ref.qw + 0.3 * rng.standard_normal(n), rng.standard_normal(n))
        d = d_of(geo, x1, x2)
        brute = min(ref.E(x1, x2), ref.J(x1, x2), ref.J(x2, x1), ref.J2(x1, x2))
        scale = scale_of(x1, x2)
        assert d <= brute + 1e-10 * scale
        assert brute <= d + 1e-7 * scale


# ------------------------------------------------------------- planar core
planar_X = st.one_of(st.floats(-3.0, 3.0), dyadic,
                     st.sampled_from([0.0, -0.0, 1e-300, 1e-170, 1e-17, -1e-17, 1e-12, 1e-8]))
planar_Y = st.one_of(st.floats(-3.0, 3.0), dyadic, st.sampled_from([0.0, 1e-17, -1e-17, 1e-9]))
planar_e = st.one_of(st.sampled_from(E_VALUES), st.floats(0.01, 1.0))


def J_grid(aX, aY, bX, bY, e):
    """min_{s<=0} |a - (0,s)| + |(0,-e s) - b| by a grid + bounded Brent (f is convex)."""
    f = lambda s: math.hypot(aX, aY - s) + math.hypot(bX, bY + e * s)
    lo = min(aY, -bY / e if e > 0 else 0.0, 0.0) - 1.0
    S = np.linspace(lo, 0.0, 4001)
    F = np.hypot(aX, aY - S) + np.hypot(bX, bY + e * S)
    i = int(np.argmin(F))
    lo, hi = S[max(i - 1, 0)], S[min(i + 1, S.size - 1)]
    g = 0.5 * (math.sqrt(5.0) - 1.0)
    for _ in range(120):   # golden section to float resolution (f is convex)
        m1, m2 = hi - g * (hi - lo), lo + g * (hi - lo)
        if f(m1) <= f(m2):
            hi = m2
        else:
            lo = m1
    kinks = [min(aY, 0.0)] + ([min(-bY / e, 0.0)] if e > 0 else [])
    return min([float(F[i]), f(lo), f(hi), f(0.0)] + [f(k) for k in kinks])


@settings(max_examples=800, deadline=None)
@given(planar_X, planar_Y, planar_X, planar_Y, planar_e)
def test_planar_J_against_grid(aX, aY, bX, bY, e):
    """The safeguarded Newton / closed forms of J, including the kinks aX = 0,
    bX = 0 and their neighbourhoods (|X| tiny, f'' huge), against a grid search."""
    _, J12, J21, _ = branch_values_2d(aX, aY, bX, bY, e)
    scale = 1.0 + abs(aX) + abs(aY) + abs(bX) + abs(bY)
    for mine, ref in ((J12, J_grid(aX, aY, bX, bY, e)), (J21, J_grid(bX, bY, aX, aY, e))):
        assert mine <= ref + 1e-12 * scale
        assert ref <= mine + 1e-10 * scale


@settings(max_examples=800, deadline=None)
@given(planar_X, planar_Y, planar_X, planar_Y, planar_e,
       st.sampled_from([1e-300, 1e-17, -1e-17, 1e-12, -1e-9, 1e-6]), st.booleans())
def test_planar_lipschitz_near_wall(aX, aY, bX, bY, e, dX, move_a):
    """d is 1-Lipschitz in each argument (triangle inequality + d <= E); probed
    by tiny moves across/along the wall, where J has kinks."""
    d0 = distance_2d(aX, aY, bX, bY, e)[0]
    d1 = (distance_2d(aX + dX, aY, bX, bY, e) if move_a else distance_2d(aX, aY, bX + dX, bY, e))[0]
    assert abs(d1 - d0) <= abs(dX) + 1e-12 * (1.0 + abs(aX) + abs(aY) + abs(bX) + abs(bY))


@settings(max_examples=300, deadline=None)
@given(planar_X, planar_Y, planar_X, planar_Y, st.sampled_from([5e-324, 1e-300, 1e-200, 1e-100, 1e-20]))
def test_planar_tiny_restitution_is_continuous(aX, aY, bX, bY, e):
    """e -> 0+ (where -bY/e overflows) gives the e = 0 distance."""
    d = distance_2d(aX, aY, bX, bY, e)[0]
    assert math.isfinite(d)
    assert abs(d - distance_2d(aX, aY, bX, bY, 0.0)[0]) <= 1e-12 * (1.0 + abs(aX) + abs(aY) + abs(bX) + abs(bY))


# ------------------------------------------------------------- special cases
@FAST
@given(st.floats(0.0, 3.0), st.floats(-3.0, 3.0), st.floats(0.0, 3.0), st.floats(-3.0, 3.0))
def test_elastic_1dof_is_mirror_formula(q1, u1, q2, u2):
    """e = 1, 1-DOF: d = min(E, ||x1 - R x2||), R(q, u) = (-q, -u), for q1, q2 >= 0.

    For states on the admissible side the mirror segment x1 -> R x2 crosses q = 0
    at some u = s, and exactly one of the chains x1 -> (0,s) ~ (0,-s) -> x2 (s <= 0)
    or its mirror image (s >= 0, as J21) is admissible, with the same length."""
    geo = geo_of("1a", 1.0)
    x1 = (np.array([q1]), np.array([u1]))
    x2 = (np.array([q2]), np.array([u2]))
    E = math.hypot(q1 - q2, u1 - u2)
    mirror = math.hypot(q1 + q2, u1 + u2)
    assert abs(d_of(geo, x1, x2) - min(E, mirror)) <= 1e-12 * (1 + abs(q1) + abs(q2) + abs(u1) + abs(u2))


def test_spec_triangle_example_needs_J2():
    """docs/design.md §2.4: 1-DOF, Q = m = 1, e = 0.8."""
    sysm = ImpactOscillator(m=1.0, e=0.8)
    a, b, c = (0.0, -0.334), (0.0, 1.168), (0.0134, -2.781)
    dab = quotient_distance(sysm, a, b)
    dbc = quotient_distance(sysm, b, c)
    dac = quotient_distance(sysm, a, c)
    assert dac <= dab + dbc + 1e-12
    assert quotient_distance(sysm, a, c, full=True).branch == "J2"

    def one_jump(x, y):
        E, J12, J21, _ = branch_values_2d(x[0], x[1], y[0], y[1], 0.8)
        return min(E, J12, J21)

    assert one_jump(a, c) == pytest.approx(2.447, abs=5e-3)
    assert one_jump(a, b) + one_jump(b, c) == pytest.approx(1.97, abs=5e-3)
    assert one_jump(a, c) > one_jump(a, b) + one_jump(b, c) + 0.4   # violated without J2


def test_plastic_collapses_pre_impact_states():
    """docs/design.md §2.4: e = 0, d((0,-5), (0,-3)) = 0 (same post-impact image (0, 0))."""
    sysm = ImpactOscillator(m=1.0, e=0.0)
    r = quotient_distance(sysm, (0.0, -5.0), (0.0, -3.0), full=True)
    assert r.d == 0.0 and r.branch == "J2"
    assert quotient_distance(sysm, (0.0, -5.0), (0.0, 0.0)) == 0.0


def test_known_values_1dof():
    sysm = ImpactOscillator(m=1.0, e=0.5)
    # pre-impact (0,-2) ~ post-impact (0,1)
    assert quotient_distance(sysm, (0.0, -2.0), (0.0, 1.0)) == 0.0
    r = quotient_distance(sysm, (0.0, -2.0), (0.0, 1.5), full=True)
    assert r.d == pytest.approx(0.5) and r.branch == "J12"
    r = quotient_distance(sysm, (0.0, 1.5), (0.0, -2.0), full=True)
    assert r.d == pytest.approx(0.5) and r.branch == "J21"
    # far from the wall: Euclidean
    r = quotient_distance(sysm, (1.0, 0.0), (1.5, 0.2), full=True)
    assert r.branch == "E" and r.d == pytest.approx(math.hypot(0.5, 0.2))


@FAST
@given(scene(1))
def test_impact_map_kernel(sc):
    name, e, x = sc
    geo = geo_of(name, e)
    zq, zu = np.empty_like(x[0]), np.empty_like(x[1])
    impact_map(geo, x[0], x[1], zq, zu)
    rq, ru = Zbar_ref(geo, *x)
    assert np.array_equal(zq, rq) and np.allclose(zu, ru, rtol=1e-14, atol=1e-15)
    if geo.w @ x[1] >= 0.0:
        assert np.array_equal(zu, x[1])   # post-impact states are fixed points


# ----------------------------------------------------------------- chain ends
@FAST
@given(scene(2))
def test_chain_ends_realise_d(sc):
    """The branch's chain through (c1, c2) is admissible and has length d."""
    name, e, x1, x2 = sc
    geo = geo_of(name, e)
    ref = Ref(name, e)
    d, b, c1, c2 = full_of(geo, x1, x2)
    scale = scale_of(x1, x2)
    tol = 1e-9 * scale
    L1 = ref.E(x1, c1)
    L2 = ref.E(c2, x2)
    if b == BRANCH_E:
        assert np.array_equal(c1[0], x2[0]) and np.array_equal(c2[1], x1[1])
        length = L1
    elif b == BRANCH_J12:
        assert on_pre_impact(geo, c1, 1e-12 * scale)
        assert ref.E(ref.Zbar(*c1), c2) <= tol
        length = L1 + L2
    elif b == BRANCH_J21:
        assert on_pre_impact(geo, c2, 1e-12 * scale)
        assert ref.E(ref.Zbar(*c2), c1) <= tol
        length = L1 + L2
    else:
        assert b == BRANCH_J2
        assert on_pre_impact(geo, c1, 1e-12 * scale) and on_pre_impact(geo, c2, 1e-12 * scale)
        length = L1 + ref.E(ref.Zbar(*c1), ref.Zbar(*c2)) + L2
    assert abs(length - d) <= tol


# -------------------------------------------------------------------- API/errors
def test_python_api_forms():
    osc = ImpactOscillator(m=2.0, e=0.3)
    d1 = quotient_distance(osc, (0.1, -1.0), (0.2, 0.5))
    d2 = quotient_distance(osc, (np.array([0.1]), [-1.0]), ([0.2], np.array([0.5])))
    assert isinstance(d1, float) and d1 == d2
    geo = geometry(osc, Q=3.0)
    assert quotient_distance(geo, (0.1, -1.0), (0.2, 0.5)) == quotient_distance(osc, (0.1, -1.0), (0.2, 0.5), Q=3.0)
    assert quotient_distance(osc, (0.1, -1.0), (0.2, 0.5), Q=[[3.0]]) == quotient_distance(geo, (0.1, -1.0), (0.2, 0.5))
    assert geometry(osc.arrays()).W == geometry(osc).W  # SystemArrays accepted
    r = quotient_distance(osc, (0.1, -1.0), (0.2, 0.5), full=True)
    assert r.branch in BRANCH_NAMES and len(r.c1) == 2 and r.c1[0].shape == (1,)
    # default Q is identity, velocity part weighted by M
    assert quotient_distance(osc, (1.0, 0.0), (1.0, 1.0)) == pytest.approx(math.sqrt(2.0))


def _system2(e=0.5):
    return MechanicalSystem(M=M2, K=np.eye(2), C=np.zeros((2, 2)), f0=[0, 0], w=[1.0, -0.3], g0=0.2, e=e)


@pytest.mark.parametrize("Q, match", [
    (0.0, r"Q must be a positive finite scalar.*0\.0"),
    (-1.0, r"Q .*-1\.0"),
    (float("nan"), r"Q .*nan"),
    ([[1.0, 2.0], [2.0, 1.0]], r"Q must be positive definite.*eigenvalue -1"),
    ([[1.0, 0.5], [0.0, 1.0]], r"Q must be symmetric"),
    (np.eye(3), r"Q must be 2x2.*\(3, 3\)"),
    ([1.0, 2.0], r"Q must be a square matrix"),
    ([[1.0, np.inf], [np.inf, 1.0]], r"Q must be finite"),
    ("abc", r"Q must be a positive scalar or an SPD matrix"),
])
def test_bad_Q(Q, match):
    with pytest.raises(ValueError, match=match):
        geometry(_system2(), Q)


@pytest.mark.parametrize("x1, match", [
    ((np.array([0.1, 0.2]), np.array([0.0, np.nan])), r"x1 must be finite.*nan"),
    ((np.array([0.1, 0.2, 0.3]), np.zeros(2)), r"x1 = \(q, u\) must hold 2 entries.*\(3,\)"),
    ((0.1,), r"x1 must be a pair"),
    ((np.array([np.inf, 0.2]), np.zeros(2)), r"x1 must be finite.*inf"),
])
def test_bad_states(x1, match):
    with pytest.raises(ValueError, match=match):
        quotient_distance(_system2(), x1, (np.zeros(2), np.zeros(2)))
    with pytest.raises(ValueError, match=match.replace("x1", "x2")):
        quotient_distance(_system2(), (np.zeros(2), np.zeros(2)), x1)


def test_bad_geometry_inputs():
    with pytest.raises(ValueError, match=r"e \(restitution\) must lie in \[0, 1\], got 1.5"):
        make_geometry([[1.0]], [1.0], 0.0, 1.5)
    with pytest.raises(ValueError, match=r"w must be finite and nonzero"):
        make_geometry([[1.0]], [0.0], 0.0, 0.5)
    with pytest.raises(ValueError, match=r"M must be positive definite"):
        make_geometry([[-1.0]], [1.0], 0.0, 0.5)
    with pytest.raises(ValueError, match=r"Q must be None"):
        quotient_distance(geo_of("1a", 0.5), (0.0, 0.0), (0.0, 0.0), Q=2.0)
    with pytest.raises(ValueError, match=r"system must be a MechanicalSystem"):
        geometry("not a system")
