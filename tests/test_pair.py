"""Two coupled systems in one compiled loop (docs/design.md §2.5)."""
import numpy as np
import pytest

from fmu_sync.core import ImpactOscillator, MechanicalSystem, SimulationDiverged, UnstableScheme, moreau
from fmu_sync.core.pair import simulate_pair

from builtin_scenes import FORCED_PAIR as PAPER
from builtin_scenes import FORCED_X1 as X1
from builtin_scenes import FORCED_X2 as X2


@pytest.fixture(scope="module")
def paper():
    return ImpactOscillator(**PAPER)


@pytest.fixture(scope="module")
def uncoupled(paper):
    return simulate_pair(paper, X1, X2, 100.0, 1e-4)


@pytest.fixture(scope="module")
def switching(paper):
    return simulate_pair(paper, X1, X2, 100.0, 1e-4, coupling="switching", Kp=1.0, Kd=0.5, scheme="midpoint")


@pytest.mark.parametrize("scheme", ["midpoint", "trapezoid"])
def test_uncoupled_pair_equals_two_single_runs_bitwise(paper, scheme):
    # the pair loop's scalar steps against the general n-DOF kernel, one system at a time (the
    # default uncoupled: its forcing, which the coupled trapezoid's path evaluates, kept)
    r = simulate_pair(paper, X1, X2, 20.0, 1e-3, record_distance=False, scheme=scheme)
    assert r.d is None and r.branch is None
    sa = paper.arrays()
    for x, q, u in ((X1, r.q1, r.u1), (X2, r.q2, r.u2)):
        rows = r.t.size
        rec = (np.empty(rows), np.empty((rows, 1)), np.empty((rows, 1)), np.empty(rows))
        moreau.integrate(sa, np.array([x[0]]), np.array([x[1]]), 0.0, 1e-3, rows - 1, np.zeros(1),
                         moreau.SCHEMES[scheme], 0.5, 1, *rec, False, 0.0)
        assert np.array_equal(rec[1], q) and np.array_equal(rec[2], u)


def test_distance_is_continuous_while_euclidean_error_peaks(uncoupled):
    r = uncoupled
    assert r.impacts1 > 10 and r.impacts2 > 10
    # d moves by O(dt) per step; the Euclidean error jumps by ~(1+e)|u-| at impacts
    assert np.max(np.abs(np.diff(r.d))) < 5e-3
    assert np.max(np.abs(np.diff(r.euclidean))) > 0.5
    assert np.all(r.d <= r.euclidean + 1e-12)


def test_uncoupled_pair_does_not_synchronize(uncoupled):
    assert np.min(uncoupled.d[uncoupled.t > 50]) > 1e-2


def test_switching_coupling_synchronizes(switching):
    r = switching
    assert r.d[-1] < 1e-8
    assert r.time_to_sync(1e-8) < 100.0
    # V = d^2/2 decays without jumps at impacts (only O(dt) blips)
    assert np.max(np.diff(r.V)) < 1e-3
    # forces stay bounded (no impulses): |tau| <= (Kp + Kd) d_max for Q = M = 1
    bound = 1.5 * np.max(r.d) * 1.0001
    assert np.max(np.abs(r.tau1)) <= bound and np.max(np.abs(r.tau2)) <= bound
    # the law switched between branches (impacts happened while not yet in sync)
    assert len(set(r.branch.tolist())) >= 2


def test_on_branch_E_switching_forces_are_the_pd_law(switching):
    r = switching
    # row i holds the forces held over the step that ended at t[i], i.e. computed at row i-1
    E = r.branch[:-1] == 0
    assert E.sum() > 0.9 * E.size
    pd = -1.0 * (r.q1 - r.q2) - 0.5 * (r.u1 - r.u2)
    np.testing.assert_allclose(r.tau1[1:][E], pd[:-1][E], rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.tau2[1:][E], -pd[:-1][E], rtol=0, atol=1e-12)


def test_euclidean_coupling_also_synchronizes_here(paper):
    r = simulate_pair(paper, X1, X2, 100.0, 1e-4, coupling="euclidean", Kp=1.0, Kd=0.5,
                      record_every=10)
    assert r.d[-1] < 1e-6


def test_identical_states_stay_identical(paper):
    r = simulate_pair(paper, X1, X1, 30.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5)
    assert np.all(r.d == 0.0) and np.array_equal(r.q1, r.q2)


def test_progress_chunks_change_no_number(paper):
    kw = dict(coupling="switching", Kp=1.0, Kd=0.5, record_every=7)
    a = simulate_pair(paper, X1, X2, 20.0, 1e-3, **kw)
    seen = []
    b = simulate_pair(paper, X1, X2, 20.0, 1e-3, progress=seen.append, **kw)
    assert seen[-1] == 1.0 and len(seen) > 10
    for k in ("t", "q1", "u1", "q2", "u2", "tau1", "tau2", "d", "branch", "euclidean"):
        assert np.array_equal(getattr(a, k), getattr(b, k))


def test_two_dof_pair_synchronizes():
    M = np.array([[2.0, 0.5], [0.5, 1.0]])
    s = MechanicalSystem(M=M, K=np.diag([1.0, 2.0]), C=0.05 * np.eye(2), f0=[0.0, -0.2],
                         w=[1.0, -0.5], g0=0.3, e=0.7, forcing=(([0.3, 0.1], 1.7, 0.0),))
    r = simulate_pair(s, ([0.5, 0.2], [0.3, -0.4]), ([0.1, 0.0], [-0.2, 0.3]), 60.0, 1e-3,
                      coupling="switching", Kp=2.0, Kd=1.0, record_every=10)
    assert r.impacts1 > 0 and r.impacts2 > 0
    assert r.d[-1] < 1e-6 * r.d[0]


def test_divergence_is_reported_with_partial_record():
    # the explicit (zero-order-hold) coupling with Kd = 0 is unstable: omega_c*dt = 14;
    # refused up front, and when forced, it stops as failed with the finite part of the record
    ball = ImpactOscillator(m=1, k=0, f0=-1, e=0.5)
    with pytest.raises(SimulationDiverged, match=r"coupling omega_c\*dt = 14.1") as err:
        simulate_pair(ball, (1.0 + 1e-6, 0.0), (1.0, 0.0), 10.0, 1e-2, coupling="euclidean", Kp=1e6,
                      allow_unstable=True, scheme="midpoint")
    part = err.value.partial
    assert not part.success and "non-finite" in part.error
    assert part.t.size > 1 and np.all(np.isfinite(part.q1)) and np.all(np.isfinite(part.d))


def test_unstable_exchange_is_refused_before_the_first_step(paper):
    from fmu_sync.core.exchange import UnstableExchange, exchange_limit
    # the case: Kp = 1e5, Kd = 150 -> omega_c = 447, zeta = 0.335, bound 1.342
    with pytest.raises(UnstableExchange, match=r"omega_c\*dt = 4.472 against the zero-order-hold "
                                               r"bound min\(4 zeta, 1/zeta\) = 1.342 \(zeta = 0.3354\)"
                                               r".*largest stable dt = 0.002999\b"):
        simulate_pair(paper, X1, X2, 5.0, 1e-2, coupling="switching", Kp=1e5, Kd=150, scheme="midpoint")
    # a ValueError: bad input, like the other refusals
    with pytest.raises(ValueError, match="no dt is stable without damping"):
        simulate_pair(paper, X1, X2, 5.0, 1e-3, coupling="euclidean", Kp=1.0, Kd=0.0, scheme="midpoint")
    # the limit is the measured ZOH limit: d decays just below it and grows just above it
    lim = exchange_limit(paper.M, 1e5, 150, 1e-2)
    assert lim.H_max == pytest.approx(1.342 / 447.2, rel=1e-3)

    def growth(factor):
        r = simulate_pair(paper, X1, X2, 1.0, factor * lim.H_max, coupling="euclidean", Kp=1e5,
                          Kd=150, allow_unstable=factor > 1, scheme="midpoint")
        k = r.t.size // 5
        return r, np.max(r.d[-k:]) / np.max(r.d[:k])
    r, below = growth(0.97)
    assert below < 0.5
    assert r.info["dt_max"] == lim.H_max and r.info["omega_c_dt"] < r.info["exchange_bound"]
    assert growth(1.03)[1] > 2.0
    # the midpoint scheme's own limit is checked first, and opt-in skips both
    stiff = ImpactOscillator(m=1, k=1e8, f0=-1, e=0.5)
    with pytest.raises(UnstableScheme, match=r"omega_max\*dt = 10"):
        simulate_pair(stiff, (1e-6, 0.0), (0.0, 0.0), 1e-2, 1e-3, scheme="midpoint")


def test_mismatched_pair_is_practically_synchronized(paper):
    # 5 % stiffness mismatch: exact synchronization is impossible, d settles to a small bound
    other = ImpactOscillator(**{**PAPER, "k": 1.05})
    r = simulate_pair((paper, other), X1, X2, 100.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5)
    assert r.success and r.info["identical"] is False
    m = r.sync(1e-6)
    assert m.t_sync == np.inf                 # never below 1e-6
    assert 1e-4 < m.bound < 0.05 * np.max(r.d)
    same = simulate_pair((paper, paper), X1, X2, 100.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5)
    assert same.bound < 1e-9
    # the same pair with the systems given once is bitwise the same run
    assert np.array_equal(same.d, simulate_pair(paper, X1, X2, 100.0, 1e-3, coupling="switching",
                                                Kp=1.0, Kd=0.5).d)


@pytest.mark.parametrize("change, match", [
    (dict(m=1.1), r"M differs: system 1 has M = \[\[1.0\]\], system 2 has M = \[\[1.1\]\]"),
    (dict(e=0.8), r"e differs: system 1 has e = 0.9, system 2 has e = 0.8"),
])
def test_mismatched_impact_geometry_is_refused(paper, change, match):
    other = ImpactOscillator(**{**PAPER, **change})
    with pytest.raises(ValueError, match=match):
        simulate_pair((paper, other), X1, X2, 1.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5)


def test_mismatched_wall_is_refused():
    a = MechanicalSystem(M=[[1.0]], K=[[1.0]], C=[[0.0]], f0=[0.0], w=[1.0], g0=0.0, e=0.5)
    b = MechanicalSystem(M=[[1.0]], K=[[1.0]], C=[[0.0]], f0=[0.0], w=[1.0], g0=0.1, e=0.5)
    with pytest.raises(ValueError, match=r"g0 differs: system 1 has g0 = 0.0, system 2 has g0 = 0.1"):
        simulate_pair((a, b), X1, X2, 1.0, 1e-3)
    c = MechanicalSystem(M=[[1.0]], K=[[1.0]], C=[[0.0]], f0=[0.0], w=[2.0], g0=0.0, e=0.5)
    with pytest.raises(ValueError, match=r"w differs: system 1 has w = \[1.0\], system 2 has w = \[2.0\]"):
        simulate_pair((a, c), X1, X2, 1.0, 1e-3)
    with pytest.raises(ValueError, match="sequence of 2"):
        simulate_pair((a, a, a), X1, X2, 1.0, 1e-3)


@pytest.mark.parametrize("kwargs, match", [
    (dict(coupling="magnetic"), "coupling must be one of"),
    (dict(x1=(-1.0, 0.0)), r"x1 violates the constraint: g\(q\) = -1 < 0"),
    (dict(Kp=-1.0), "Kp must be a finite gain >= 0, got -1.0"),
    (dict(dt=0.0), "dt must be a positive finite step, got 0.0"),
    (dict(record_every=0), "record_every must be >= 1, got 0"),
])
def test_simulate_pair_rejects_bad_input(paper, kwargs, match):
    args = dict(x1=X1, x2=X2, t_end=1.0, dt=1e-3, coupling="switching")
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        simulate_pair(paper, **args)
