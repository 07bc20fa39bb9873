"""Exact event-driven n-DOF solver (core/exact_nd.py, behind core.exact's entries) against an independent
DOP853 event-restart reference (tests/_nd_reference.py), on the two-dof scene."""
from __future__ import annotations

import numpy as np
import pytest

from fmu_sync.core import InadmissibleState, MechanicalSystem, simulate
from fmu_sync.core import exact_events, simulate_exact

from _nd_reference import reference

TOL = 1e-10
X0 = ([0.6, 0.2], [0.0, 0.0])      # two-dof scene, x1


def two_dof(f0=(0.1, 0.2), F=(0.6, 0.0), e=0.7, g0=0.0):
    """fmu_sync/scenes/two-dof.toml (M, K, C, w, Omega as there)."""
    return MechanicalSystem(M=[[2.0, 0.5], [0.5, 1.0]], K=[[3.0, -1.0], [-1.0, 2.0]],
                            C=0.02 * np.eye(2), f0=list(f0), w=[1.0, 0.5], g0=g0, e=e,
                            forcing=[(list(F), 1.3, 0.0)])


def _compare(system, x0, t_end, dt=0.01, max_step=np.inf, **kw):
    r = simulate_exact(system, x0, t_end, dt, **kw)
    ev = r.events
    ref, log = reference(system, x0, r.t, max_step=max_step, **kw)
    err = np.max(np.abs(np.hstack([r.q, r.u]) - ref))
    return r, ev, log, err


def test_two_dof_scene_impacts_match_reference():
    s = two_dof()
    r, ev, log, err = _compare(s, X0, 60.0)
    assert ev.n_impacts >= 10 and ev.n_impacts == sum(1 for l in log if l[0] == "impact")
    ref_times = np.array([l[1] for l in log if l[0] == "impact"])
    assert np.max(np.abs(ev.impact_times - ref_times)) < TOL
    assert err < TOL, err
    # dispatch through simulate, and admissibility
    r2 = simulate(s, X0, 60.0, 0.01, scheme="exact")
    assert np.array_equal(r2.q, r.q)
    assert np.min(r.q @ s.w) > -1e-12
    # percussions: one per impact, (1+e)|w^T u-|/W
    assert r.impacts == ev.n_impacts
    np.testing.assert_allclose(r.percussion.sum(), ev.impact_percussions.sum(), rtol=1e-12)


def test_two_dof_accumulation_contact_and_release_match_reference():
    # force into the wall: bounce sequences accumulate (Zeno, completed), persistent contact
    # sliding along the wall while lambda >= 0, release when the forcing turns
    s = two_dof(f0=(-1.0, -1.0), F=(2.0, 0.0), e=0.5)
    x0 = ([0.3, 0.1], [0.0, 0.0])
    r, ev, log, err = _compare(s, x0, 20.0)
    assert ev.zeno_times.size >= 2
    assert ev.contact_intervals.shape[0] >= 2
    rel = [l[1] for l in log if l[0] == "release"]
    assert len(rel) >= 2
    # releases (contact force changing sign) at the reference's times
    ends = ev.contact_intervals[:, 1][ev.contact_intervals[:, 1] < 20.0]
    assert np.max(np.abs(ends[:2] - np.array(rel[:2]))) < 1e-8
    assert err < TOL, err
    # in contact: on the wall (g = 0) with zero normal velocity; lambda >= 0 integrated
    a, b = ev.contact_intervals[0]
    inside = (r.t > a + 0.05) & (r.t < b - 0.05)
    assert inside.sum() > 50
    assert np.max(np.abs(r.q[inside] @ s.w)) < 1e-12 and np.max(np.abs(r.u[inside] @ s.w)) < 1e-12
    assert np.all(r.percussion[inside] > 0)
    # the tangential motion goes on while in contact (sliding along the wall)
    assert np.ptp(r.q[inside, 1]) > 1e-3


@pytest.mark.parametrize("depth", [1e-4, -1e-4])
def test_two_dof_near_grazing_matches_reference(depth):
    # shift the wall so that the first approach of the free motion misses it by `depth`
    # (> 0: no impact) or penetrates by |depth| (< 0: a slow impact, speed ~ sqrt(depth))
    s0 = two_dof(g0=10.0)     # wall far away: the free motion
    free = simulate_exact(s0, X0, 6.0, 1e-3)
    g = free.q @ s0.w
    i = int(np.argmin(g))
    assert 0 < i < g.size - 1
    from scipy.optimize import minimize_scalar
    ev0 = exact_events(s0, X0, 6.0)
    res = minimize_scalar(lambda t: ev0.state(t)[0] @ s0.w, bracket=(free.t[i - 1], free.t[i], free.t[i + 1]),
                          tol=1e-12)
    wq_min = float(res.fun)
    s = two_dof(g0=depth - wq_min)
    r, ev, log, err = _compare(s, X0, 8.0, max_step=1e-3)    # the dip is ~0.04 s wide
    n_ref = sum(1 for l in log if l[0] == "impact" and l[1] < res.x + 0.1)
    n_ex = int(np.count_nonzero(ev.impact_times < res.x + 0.1))
    assert n_ex == n_ref == (1 if depth < 0 else 0)
    assert err < TOL, err


def test_exact_grazing_touches_without_impact():
    # wall exactly tangent to the free motion: a grazing contact (recorded), no impact, and
    # the motion equals the free motion without the wall (independent: DOP853, no events)
    from scipy.integrate import solve_ivp
    s0 = two_dof(g0=10.0)     # wall far away: the free motion
    ev0 = exact_events(s0, X0, 6.0)
    from scipy.optimize import minimize_scalar
    res = minimize_scalar(lambda t: ev0.state(t)[0] @ s0.w, bracket=(3.5, 4.1, 4.7), tol=1e-14)
    s = two_dof(g0=-float(res.fun))
    r = simulate_exact(s, X0, 6.0, 0.01)
    ev = r.events
    assert ev.n_impacts == 0 and ev.graze_times.size == 1
    assert abs(ev.graze_times[0] - res.x) < 1e-6
    sa = s.arrays()

    def rhs(t, y):
        h = sa.f0 - sa.K @ y[:2] - sa.C @ y[2:] + sa.F[0] * np.cos(sa.Omega[0] * t)
        return np.concatenate([y[2:], sa.Minv @ h])
    sol = solve_ivp(rhs, (0, 6.0), np.concatenate(X0), method="DOP853", rtol=1e-13, atol=1e-15,
                    t_eval=r.t)
    assert np.max(np.abs(np.hstack([r.q, r.u]) - sol.y.T)) < TOL


def test_linear_input_matches_reference():
    # tau(t) = tau + taudot (t - t_c): the ramp is one more state of the augmented flow
    s = two_dof()
    kw = dict(tau=[0.1, -0.05], taudot=[0.02, 0.01], t_c=1.0)
    r, ev, log, err = _compare(s, X0, 30.0, **kw)
    assert ev.n_impacts >= 4
    assert err < TOL, err


def test_bad_input():
    s = two_dof()
    with pytest.raises(InadmissibleState, match=r"x0 violates the constraint: g\(q\)"):
        simulate_exact(s, ([-1.0, 0.0], [0, 0]), 1.0, 1e-2)
    with pytest.raises(ValueError, match="tau must be 2 finite numbers"):
        simulate_exact(s, X0, 1.0, 1e-2, tau=[1.0])
    with pytest.raises(ValueError, match="t_end must be"):
        exact_events(s, X0, -1.0)


@pytest.mark.parametrize("params, x0", [
    (dict(m=1.0, k=1.0, c=0.1, f0=0.3, F=1.0, Omega=1.2, e=0.8), (1.0, 0.0)),
    (dict(m=1.0, k=1.0, c=0.0, f0=-0.2, F=0.8, Omega=1.0, e=0.5), (0.5, 0.0)),   # accumulations
])
def test_one_dof_agrees_with_the_one_dof_solver(params, x0):
    # two independent implementations (gap closed forms vs augmented matrix flow)
    from fmu_sync.core import ImpactOscillator, exact_nd
    s = ImpactOscillator(**params)
    a = simulate_exact(s, x0, 20.0, 0.01)          # n = 1: the compiled closed-form solver
    b = exact_nd.solve(s, np.array([x0[0]]), np.array([x0[1]]), 0.0, 20.0, None, None, 0.0, 10 ** 6, 1e-12, 1e-10)
    bq, bu, bp = b.sample(a.t)
    assert np.max(np.abs(a.q - bq)) < TOL and np.max(np.abs(a.u - bu)) < TOL


def test_one_dof_linear_input_matches_reference():
    # the linear input tau(t) = tau + taudot (t - t_c) of a first-order hold, exact (Python) for n = 1 too
    from fmu_sync.core import ImpactOscillator
    s = ImpactOscillator(m=1.0, k=1.0, c=0.1, f0=0.1, F=0.5, Omega=2.5, e=0.8)
    r, ev, log, err = _compare(s, (1.0, 0.0), 12.0, dt=0.05, tau=[-0.2], taudot=[0.06], t_c=0.0)
    assert ev.n_impacts >= 3
    assert err < TOL, err


def test_one_entry_for_every_n_with_one_result_type():
    """simulate_exact / exact_events dispatch on n (and the input ramp); the events of the
    1-DOF and the n-DOF solver are one type with the same fields and meanings."""
    import fmu_sync.core as core
    from fmu_sync.core import ExactEvents
    assert not {"simulate_exact_nd", "exact_events_nd", "ExactEventsND"} & set(dir(core))
    s = two_dof(f0=(-1.0, -1.0), F=(2.0, 0.0), e=0.5)        # impacts, accumulations, contact
    ev = exact_events(s, ([0.3, 0.1], [0.0, 0.0]), 20.0)
    osc = MechanicalSystem(M=[[2.0]], K=[[1.0]], C=[[0.1]], f0=[1.5], w=[-1.5], g0=1.0, e=0.5,
                           forcing=[([1.0], 1.2, 0.0)])                    # a wall above, w != 1
    one = exact_events(osc, (0.1, 0.0), 20.0)
    ramp = exact_events(osc, (0.1, 0.0), 20.0, taudot=[1e-6])   # n = 1 with a ramp: the n-DOF solver
    assert type(ev) is type(one) is type(ramp) is ExactEvents
    for e_, n, sys_ in ((ev, 2, s), (one, 1, osc), (ramp, 1, osc)):
        sa = sys_.arrays()
        k = e_.n_impacts
        assert k >= 3 and e_.zeno_times.size >= 1
        assert e_.impact_velocities.shape == ((k,) if e_ is one else (k, n))
        # w^T u- is the normal part of u-, negative; P = (1+e)|w^T u-|/W
        un = e_.impact_velocities.reshape(k, -1) @ sa.w
        np.testing.assert_allclose(un, e_.impact_normal_velocities, rtol=1e-14, atol=0)
        assert np.all(e_.impact_normal_velocities < 0)
        np.testing.assert_allclose(e_.impact_percussions, (1 + sa.e) * np.abs(un) / sa.W, rtol=1e-13)
        # u- is the left limit of the solution at the impact (an impact well after the previous event)
        gaps = np.diff(np.concatenate([[0.0], e_.impact_times]))
        i = int(np.argmax(gaps))
        _, u_before = e_.state(e_.impact_times[i] - 1e-7)
        np.testing.assert_allclose(np.reshape(u_before, -1), np.reshape(e_.impact_velocities[i], -1), atol=1e-5)
        # a completed accumulation sums the remaining bounces: (1+e) v+ / ((1-e) W), v+ = -e w^T u-
        j = int(np.nonzero(e_.impact_times == e_.zeno_start_times[0])[0][-1])
        vp = -sa.e * e_.impact_normal_velocities[j]
        assert e_.zeno_percussions[0] == pytest.approx((1 + sa.e) * vp / ((1 - sa.e) * sa.W), rel=1e-12)
        assert e_.zeno_percussions.shape == e_.zeno_times.shape == e_.zeno_start_times.shape
        assert e_.contact_open == (e_.contact_intervals.size > 0 and e_.contact_intervals[-1, 1] == 20.0)
        # state: shaped like t for n = 1 (the compiled solver), t.shape + (n,) otherwise
        q, u = e_.state(np.full((2, 3), 1.0))
        assert q.shape == u.shape == ((2, 3) if e_ is one else (2, 3, n))
    # the two solvers on one motion (the ramp's effect is ~1e-6 here): the same solution
    ts = np.linspace(0.0, 5.0, 51)
    assert np.max(np.abs(one.state(ts)[0] - ramp.state(ts)[0][:, 0])) < 1e-4
