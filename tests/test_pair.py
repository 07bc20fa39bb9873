"""Two coupled systems in one compiled loop (docs/design.md §2.5)."""
import numpy as np
import pytest

from fmu_sync.core import ImpactOscillator, MechanicalSystem, SimulationDiverged, moreau
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
    return simulate_pair(paper, X1, X2, 100.0, 1e-4, coupling="switching", Kp=1.0, Kd=0.5)


def test_uncoupled_pair_equals_two_single_runs_bitwise(paper):
    # the pair loop's scalar steps against the general n-DOF kernel, one system at a time
    r = simulate_pair(paper, X1, X2, 20.0, 1e-3, record_distance=False)
    assert r.d is None and r.branch is None
    sa = paper.arrays()
    for x, q, u in ((X1, r.q1, r.u1), (X2, r.q2, r.u2)):
        rows = r.t.size
        rec = (np.empty(rows), np.empty((rows, 1)), np.empty((rows, 1)), np.empty(rows))
        moreau.integrate(sa, np.array([x[0]]), np.array([x[1]]), 0.0, 1e-3, rows - 1, np.zeros(1),
                         moreau.MIDPOINT, 0.5, 1, *rec)
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
    # the explicit (zero-order-hold) coupling with Kd = 0 is unstable: omega_c*dt = 14
    ball = ImpactOscillator(m=1, k=0, f0=-1, e=0.5)
    with pytest.raises(SimulationDiverged, match=r"coupling omega_c\*dt = 14.1") as err:
        simulate_pair(ball, (1.0 + 1e-6, 0.0), (1.0, 0.0), 10.0, 1e-2, coupling="euclidean", Kp=1e6)
    part = err.value.partial
    assert part.t.size > 1 and np.all(np.isfinite(part.q1)) and np.all(np.isfinite(part.d))


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
