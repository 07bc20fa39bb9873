"""Coupling laws (docs/design.md §2.5): switching quotient coupling and Euclidean PD."""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numba import njit

from fmu_sync.core.coupling import (
    BRANCH_NONE, EUCLIDEAN, SWITCHING, UNCOUPLED, chain_work, coupling_forces, coupling_kernel,
    coupling_kernel1, euclidean_coupling, euclidean_coupling1, gain_matrix, switching_coupling,
    switching_coupling1)
from fmu_sync.core.distance import (
    BRANCH_E, BRANCH_J12, BRANCH_J21, BRANCH_J2, branch_values_2d, distance1, distance_kernel,
    make_geometry)
from fmu_sync.core.model import ImpactOscillator, MechanicalSystem

M2 = [[2.0, 0.5], [0.5, 1.0]]
SYSTEMS = {  # name -> (M, w, g0, Q)
    "1a": ([[1.0]], [1.0], 0.0, 1.0),
    "1b": ([[2.5]], [2.0], -0.5, 0.7),
    "2b": (M2, [1.0, -0.3], 0.2, [[0.8, -0.2], [-0.2, 1.3]]),
}
GAINS = {  # name -> (Kp, Kd) per dimension
    1: [(1.0, 0.5), (0.0, 2.0), (3.0, 0.0), ([[2.0]], [[0.1]])],
    2: [(1.0, 0.5), ([[2.0, 0.5], [0.5, 1.0]], [[0.3, 0.0], [0.0, 0.7]]),
        ([[1.0, 1.0], [-1.0, 1.0]], 0.2)],   # non-symmetric Kp with PSD symmetric part
}


@functools.lru_cache(maxsize=None)
def geo_of(name, e):
    M, w, g0, Q = SYSTEMS[name]
    return make_geometry(M, w, g0, e, Q)


dyadic = st.integers(-192, 192).map(lambda k: k / 64.0)
coord = st.one_of(st.floats(-3.0, 3.0), dyadic, st.sampled_from([0.0, 1e-12, -1e-9]))


@st.composite
def scene(draw):
    name = draw(st.sampled_from(list(SYSTEMS)))
    e = draw(st.one_of(st.sampled_from([0.0, 0.05, 0.8, 1.0]), st.floats(0.0, 1.0)))
    M, w, g0, Q = SYSTEMS[name]
    n = len(w)
    kp, kd = draw(st.sampled_from(GAINS[n]))

    def state():
        q = np.array([draw(coord) for _ in range(n)])
        u = np.array([draw(coord) for _ in range(n)])
        if draw(st.booleans()):  # move q onto the wall g = 0 (pre- or post-impact u)
            w_ = np.array(w, float)
            q = q - (w_ @ q + g0) / (w_ @ w_) * w_
            if n == 1:
                q = np.array([-g0 / w[0]])
        return q, u

    return name, e, gain_matrix(kp, n, "Kp"), gain_matrix(kd, n, "Kd"), state(), state()


def kernel_d(geo, x1, x2):
    """The distance kernel itself: the coupling laws see states slightly inside the wall
    (a Moreau contact step), which quotient_distance refuses as a public entry point."""
    n = x1[0].size
    return distance_kernel(geo, *x1, *x2, *chain_work(n))[0]


def run_switching(geo, Kp, Kd, x1, x2):
    n = x1[0].size
    t1, t2 = np.zeros(n), np.zeros(n)
    c = chain_work(n)
    d, b = switching_coupling(geo, Kp, Kd, *x1, *x2, t1, t2, *c)
    return t1, t2, d, b, c


def run_euclidean(geo, Kp, Kd, x1, x2):
    n = x1[0].size
    t1, t2 = np.zeros(n), np.zeros(n)
    E = euclidean_coupling(geo, Kp, Kd, *x1, *x2, t1, t2)
    return t1, t2, E


def p_norm(geo, dq, du):
    return math.sqrt(max(float(dq @ geo.Q @ dq + du @ geo.M @ du), 0.0))


FAST = settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(scene())
def test_switching_law_definition(sc):
    """tau_i = -Kp E_i^q - Kd E_i^u with E_i = d (x_i - c_i)/||x_i - c_i||_P,
    recomputed in numpy from the chain ends; ||E_i||_P = d; E branch is PD."""
    name, e, Kp, Kd, x1, x2 = sc
    geo = geo_of(name, e)
    t1, t2, d, b, c = run_switching(geo, Kp, Kd, x1, x2)
    scale = 1.0 + sum(np.abs(v).sum() for v in (*x1, *x2))
    assert d == pytest.approx(kernel_d(geo, x1, x2), abs=1e-15 * scale)
    for (q, u), cq, cu, tau in ((x1, c[0], c[1], t1), (x2, c[2], c[3], t2)):
        nrm = p_norm(geo, q - cq, u - cu)
        if b == BRANCH_E or nrm == 0.0:
            Eq, Eu = (q - cq, u - cu) if b == BRANCH_E else (0 * q, 0 * u)
        else:
            Eq, Eu = d * (q - cq) / nrm, d * (u - cu) / nrm
            if nrm > 1e-150:   # below, the squares in the norm underflow
                assert p_norm(geo, Eq, Eu) == pytest.approx(d, rel=1e-12, abs=1e-300)
        expected = -Kp @ Eq - Kd @ Eu
        assert np.allclose(tau, expected, rtol=1e-12, atol=1e-13 * scale * (1 + np.abs(Kp).max() + np.abs(Kd).max()))


@FAST
@given(scene())
def test_branch_E_is_euclidean_pd(sc):
    """On branch E the switching law is exactly the PD law, and tau1 = -tau2."""
    name, e, Kp, Kd, x1, x2 = sc
    geo = geo_of(name, e)
    t1, t2, d, b, _ = run_switching(geo, Kp, Kd, x1, x2)
    et1, et2, E = run_euclidean(geo, Kp, Kd, x1, x2)
    assert np.array_equal(et1, -et2)
    assert np.allclose(et1, -Kp @ (x1[0] - x2[0]) - Kd @ (x1[1] - x2[1]), rtol=1e-13, atol=1e-13)
    # abs: below ~1e-154 the squares in the norm are subnormal and lose relative precision
    # (hypothesis found d = 5.5e-160); 1e-155 m is far below any physical length.
    assert E == pytest.approx(p_norm(geo, x1[0] - x2[0], x1[1] - x2[1]), rel=1e-13, abs=1e-155)
    if b == BRANCH_E:
        assert np.array_equal(t1, et1) and np.array_equal(t2, et2)
        assert np.array_equal(t1, -t2)
        assert d == pytest.approx(E, rel=1e-13, abs=1e-155)


@FAST
@given(scene())
def test_forces_bounded_by_distance(sc):
    """|tau_i|_2 <= (|Kp|_2 / sqrt(lmin Q) + |Kd|_2 / sqrt(lmin M)) d: no impulses,
    whatever the branch, however large the Euclidean error."""
    name, e, Kp, Kd, x1, x2 = sc
    geo = geo_of(name, e)
    t1, t2, d, b, _ = run_switching(geo, Kp, Kd, x1, x2)
    gain = (np.linalg.norm(Kp, 2) / math.sqrt(np.linalg.eigvalsh(geo.Q)[0])
            + np.linalg.norm(Kd, 2) / math.sqrt(np.linalg.eigvalsh(geo.M)[0]))
    # d below ~1e-154: subnormal squares lose relative precision (as in test_branch_E above;
    # hypothesis found d = 4.5e-159), so the bound is taken at d >= 1e-155
    for tau in (t1, t2):
        assert np.linalg.norm(tau) <= gain * max(d, 1e-155) * (1 + 1e-12)


@FAST
@given(scene())
def test_zero_when_states_coincide(sc):
    name, e, Kp, Kd, x1, _ = sc
    geo = geo_of(name, e)
    t1, t2, d, b, _ = run_switching(geo, Kp, Kd, x1, (x1[0].copy(), x1[1].copy()))
    assert d == 0.0 and b == BRANCH_E
    assert not np.any(t1) and not np.any(t2)
    et1, et2, E = run_euclidean(geo, Kp, Kd, x1, (x1[0].copy(), x1[1].copy()))
    assert E == 0.0 and not np.any(et1) and not np.any(et2)


@FAST
@given(scene(), st.sampled_from([SWITCHING, EUCLIDEAN, UNCOUPLED]))
def test_scalar_kernels_match_array_kernels_bitwise(sc, law):
    """The 1-DOF scalar kernels and the array kernels give identical bits (the
    array kernels dispatch n = 1 to them; the n-DOF distance path agrees too)."""
    name, e, Kp, Kd, x1, x2 = sc
    if x1[0].size != 1:
        return
    geo = geo_of(name, e)
    n = 1
    t1, t2 = np.zeros(n), np.zeros(n)
    c = chain_work(n)
    v, b = coupling_kernel(law, geo, Kp, Kd, *x1, *x2, t1, t2, *c)
    s1, s2, sv, sb = coupling_kernel1(law, geo.scalar, Kp[0, 0], Kd[0, 0], x1[0][0], x1[1][0], x2[0][0], x2[1][0])
    assert (v, b) == (sv, sb) and t1[0] == s1 and t2[0] == s2
    if law == SWITCHING:
        r = distance1(geo.scalar, x1[0][0], x1[1][0], x2[0][0], x2[1][0])
        assert r[:2] == (v, b) and (c[0][0], c[1][0], c[2][0], c[3][0]) == r[2:]
        assert switching_coupling1(geo.scalar, Kp[0, 0], Kd[0, 0], x1[0][0], x1[1][0], x2[0][0], x2[1][0]) == (s1, s2, sv, sb)
    else:
        assert b == BRANCH_NONE
        if law == UNCOUPLED:
            assert t1[0] == 0.0 and t2[0] == 0.0
        else:
            assert euclidean_coupling1(geo.scalar, Kp[0, 0], Kd[0, 0], x1[0][0], x1[1][0], x2[0][0], x2[1][0]) == (s1, s2, sv)


def test_law_dispatch_n_dof():
    geo = geo_of("2b", 0.5)
    Kp, Kd = gain_matrix(1.5, 2), gain_matrix([[0.3, 0.1], [0.1, 0.4]], 2, "Kd")
    x1 = (np.array([0.1, 0.3]), np.array([-1.0, 0.2]))
    x2 = (np.array([-0.1, 0.4]), np.array([0.5, 0.1]))
    for law in (SWITCHING, EUCLIDEAN, UNCOUPLED):
        t1, t2 = np.full(2, np.nan), np.full(2, np.nan)
        v, b = coupling_kernel(law, geo, Kp, Kd, *x1, *x2, t1, t2, *chain_work(2))
        if law == SWITCHING:
            assert b in (BRANCH_E, BRANCH_J12, BRANCH_J21, BRANCH_J2)
            assert v == pytest.approx(kernel_d(geo, x1, x2), rel=1e-14)
        else:
            assert b == BRANCH_NONE and v == pytest.approx(p_norm(geo, x1[0] - x2[0], x1[1] - x2[1]))
        if law == UNCOUPLED:
            assert not np.any(t1) and not np.any(t2)
        else:
            assert np.all(np.isfinite(t1)) and np.all(np.isfinite(t2))


def test_impact_invariance_of_own_force_1dof():
    """System 1's force does not jump when system 2 jumps through an impact:
    replacing x2 = y in dA- by Zbar(y) leaves the shortest chain's start (and so
    tau1) unchanged.  Generic random states (unique minimisers), ties skipped."""
    rng = np.random.default_rng(3)
    checked = 0
    for e in (0.0, 0.3, 0.8, 1.0):
        geo = geo_of("1a", e)
        Kp, Kd = gain_matrix(1.0, 1), gain_matrix(0.5, 1)
        for _ in range(300):
            x1 = (np.array([rng.uniform(0, 1)]), np.array([rng.uniform(-2, 2)]))
            y = (np.array([0.0]), np.array([-rng.uniform(0.01, 2)]))
            zy = (np.array([0.0]), -e * y[1])
            vals = [sorted(branch_values_2d(x1[0][0], x1[1][0], x[0][0], x[1][0], e))[:2] for x in (y, zy)]
            if any(v[1] - v[0] < 1e-6 for v in vals):
                continue
            ta = run_switching(geo, Kp, Kd, x1, y)
            tb = run_switching(geo, Kp, Kd, x1, zy)
            assert ta[2] == pytest.approx(tb[2], abs=1e-12)
            assert ta[0][0] == pytest.approx(tb[0][0], rel=1e-9, abs=1e-12)
            checked += 1
    assert checked > 600


def test_euclidean_peaks_switching_does_not():
    """docs/design.md §2.5: at an impact mismatch (x1 just before, x2 just after the same
    impact) the Euclidean PD force is ~(1+e)|u| Kd, the switching force ~0."""
    osc = ImpactOscillator(m=1.0, e=0.8)
    x1, x2 = (1e-4, -1.0), (1e-4, 0.8)
    t_sw, _ = coupling_forces(osc, x1, x2, "switching", 1.0, 1.0)
    t_eu, _ = coupling_forces(osc, x1, x2, "euclidean", 1.0, 1.0)
    assert abs(t_eu[0]) == pytest.approx(1.8, rel=1e-3)
    assert abs(t_sw[0]) < 1e-3


def test_compiled_loop_can_call_kernels():
    """The kernels compose inside a user's njit loop (what simulate_pair does)."""
    @njit
    def loop(law, geo, Kp, Kd, q1, u1, q2, u2, steps):
        n = q1.shape[0]
        t1 = np.zeros(n)
        t2 = np.zeros(n)
        c1q, c1u, c2q, c2u = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
        acc = 0.0
        for k in range(steps):
            q2[0] += 1e-3
            v, b = coupling_kernel(law, geo, Kp, Kd, q1, u1, q2, u2, t1, t2, c1q, c1u, c2q, c2u)
            acc += v + t1[0]
            d, b2 = distance_kernel(geo, q1, u1, q2, u2, c1q, c1u, c2q, c2u)
            acc += d
        return acc

    for name in ("1a", "2b"):
        geo = geo_of(name, 0.8)
        n = geo.w.size
        Kp, Kd = gain_matrix(1.0, n), gain_matrix(0.5, n)
        for law in (SWITCHING, EUCLIDEAN, UNCOUPLED):
            assert math.isfinite(loop(law, geo, Kp, Kd, np.full(n, 0.1), np.full(n, -1.0),
                                      np.full(n, 0.2), np.full(n, 0.5), 50))


# ---------------------------------------------------------------- Python API
def test_coupling_forces_api():
    osc = ImpactOscillator(m=2.0, e=0.5)
    t1, t2 = coupling_forces(osc, (0.5, 0.1), (0.4, -0.2), "euclidean", 2.0, 1.0)
    assert t1.shape == (1,) and t1[0] == pytest.approx(-2.0 * 0.1 - 1.0 * 0.3) and t2[0] == -t1[0]
    s1, s2 = coupling_forces(osc, (0.5, 0.1), (0.4, -0.2), "switching", 2.0, 1.0)
    assert np.array_equal(s1, t1) and np.array_equal(s2, t2)   # branch E here
    z1, z2 = coupling_forces(osc, (0.5, 0.1), (0.4, -0.2), "none", 2.0, 1.0)
    assert not np.any(z1) and not np.any(z2)
    sys2 = MechanicalSystem(M=M2, K=np.eye(2), C=np.zeros((2, 2)), f0=[0, 0], w=[1.0, -0.3], g0=0.2, e=0.5)
    t1, t2 = coupling_forces(sys2, (np.zeros(2), np.zeros(2)), ([0.1, 0.0], [0.0, 0.1]), "switching",
                             [[1.0, 0.0], [0.0, 2.0]], 0.5, Q=[[0.8, -0.2], [-0.2, 1.3]])
    assert t1.shape == (2,) and np.all(np.isfinite(t1))


@pytest.mark.parametrize("kwargs, match", [
    (dict(law="pd"), r"law must be one of \['euclidean', 'none', 'switching', 'switching-compensated'\], got 'pd'"),
    (dict(Kp=-1.0), r"Kp must be a finite gain >= 0, got -1.0"),
    (dict(Kd=float("nan")), r"Kd must be a finite gain >= 0, got nan"),
    (dict(Kp=[[1.0, 0.0]]), r"Kp must be a scalar or 1x1, got shape \(1, 2\)"),
    (dict(Kd=[[-2.0]]), r"Kd must be positive semidefinite.*-2"),
    (dict(x1=(0.1, float("inf"))), r"x1 must be finite.*inf"),
    (dict(x2=(0.1,)), r"x2 must be a pair"),
    (dict(x2=([0.1, 0.2], [0.0, 0.0])), r"x2 = \(q, u\) must hold 1 entries"),
    (dict(Q=-2.0), r"Q must be a positive finite scalar.*-2.0"),
])
def test_coupling_forces_errors(kwargs, match):
    args = dict(x1=(0.1, 0.0), x2=(0.2, 0.0), law="switching", Kp=1.0, Kd=1.0, Q=None)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        coupling_forces(ImpactOscillator(), **args)


def test_gain_matrix():
    assert np.array_equal(gain_matrix(2.0, 3), 2.0 * np.eye(3))
    K = gain_matrix([[1.0, 2.0], [0.0, 1.0]], 2)   # symmetric part [[1,1],[1,1]] is PSD
    assert K.flags["C_CONTIGUOUS"] and K.dtype == np.float64
    with pytest.raises(ValueError, match="Kp must be positive semidefinite"):
        gain_matrix([[1.0, 3.0], [0.0, 1.0]], 2)


@FAST
@given(scene())
def test_the_law_on_a_held_branch(sc):
    """coupling_forces(..., branch=) (the implicit exchange's held branch, docs/design.md §4.4): the
    law's own branch gives the law bit for bit; branch E gives the PD law (the Euclidean forces)
    wherever the states are; an unknown branch is refused, naming the names."""
    from fmu_sync.core.distance import BRANCH_NAMES
    name, e, Kp, Kd, x1, x2 = sc
    geo = geo_of(name, e)
    n = x1[0].size
    _, b = coupling_kernel(SWITCHING, geo, Kp, Kd, *x1, *x2, np.zeros(n), np.zeros(n), *chain_work(n))
    free = coupling_forces(geo, x1, x2, "switching", Kp, Kd)
    own = coupling_forces(geo, x1, x2, "switching", Kp, Kd, branch=BRANCH_NAMES[b])
    assert all(np.array_equal(f, o) for f, o in zip(free, own))
    pd = coupling_forces(geo, x1, x2, "euclidean", Kp, Kd)
    on_e = coupling_forces(geo, x1, x2, "switching", Kp, Kd, branch="E")
    assert all(np.array_equal(f, o) for f, o in zip(pd, on_e))
    with pytest.raises(ValueError, match=r"branch must be None \(the law's own\) or one of \['E', 'J12', 'J21', "
                                         r"'J2'\], got 'K'"):
        coupling_forces(geo, x1, x2, "switching", Kp, Kd, branch="K")
