"""Moreau time-stepping against closed forms (docs/design.md §2.3)."""
import math

import numpy as np

from fmu_sync.core.checks import record_rows
import pytest

from builtin_scenes import FORCED_PAIR
from fmu_sync.core import ImpactOscillator, MechanicalSystem, UnstableScheme, simulate
from fmu_sync.core import moreau

G = 9.81


def bouncing_ball(e=0.8):
    return ImpactOscillator(m=1.0, k=0.0, c=0.0, f0=-G, e=e)


def rest_time(r):
    """Start of the final run of steps that all carry a contact percussion (persistent contact)."""
    free = np.nonzero(r.percussion == 0.0)[0]
    return r.t[free[-1] + 1]


def t_inf_closed_form(e=0.8, q0=1.0):
    t1 = math.sqrt(2 * q0 / G)
    v1 = G * t1
    return t1 + 2 * e * v1 / (G * (1 - e)), v1


def test_free_flight_is_exact():
    # constant force, wall never reached: the midpoint scheme integrates a quadratic exactly
    s = ImpactOscillator(m=2.0, f0=-1.0, e=0.5)
    r = simulate(s, (10.0, 1.0), 3.0, 1e-3)
    t = r.t
    q_exact = 10.0 + t - 0.25 * t**2
    u_exact = 1.0 - 0.5 * t
    assert np.max(np.abs(r.q[:, 0] - q_exact)) < 1e-12
    assert np.max(np.abs(r.u[:, 0] - u_exact)) < 1e-12
    assert r.impacts == 0


def test_bouncing_ball_rest_time_and_convergence():
    t_inf, v1 = t_inf_closed_form()
    errs = []
    dts = (4e-4, 1e-4, 2.5e-5)
    for dt in dts:
        r = simulate(bouncing_ball(), (1.0, 0.0), t_inf + 1.0, dt)
        errs.append(abs(rest_time(r) - t_inf))
        # after rest: at rest up to round-off of the contact step (|u| ~ eps*g*dt), no drift
        after = r.t > t_inf + 0.5
        assert np.all(np.abs(r.u[after, 0]) < 1e-12 * v1)
        assert np.ptp(r.q[after, 0]) < 1e-15
        assert np.all(np.abs(r.q[after, 0]) < dt * v1)
    assert errs[1] < 1e-2, errs  # dt = 1e-4
    # first order: the error is O(dt) (measured constant 5-11; the bound 20 dt leaves room)
    # and it shrinks monotonically along the ladder
    assert all(err < 20 * dt for err, dt in zip(errs, dts)), errs
    assert errs[0] > errs[1] > errs[2], errs


def test_no_subnormal_velocities_in_accumulation():
    r = simulate(bouncing_ball(), (1.0, 0.0), 6.0, 1e-4)
    a = np.abs(np.concatenate([r.u[:, 0], r.q[:, 0]]))
    assert not np.any((a > 0) & (a < np.finfo(float).tiny))


def test_grazing_orbit_follows_closed_form():
    s = ImpactOscillator(m=1, k=1, c=0, f0=0.4, F=0.3, Omega=0.5, e=0.8)
    r = simulate(s, (0.8, 0.0), 4 * math.pi + 1.0, 1e-4)
    q_exact = 0.4 + 0.4 * np.cos(r.t / 2)
    assert np.max(np.abs(r.q[:, 0] - q_exact)) < 1e-4


@pytest.mark.parametrize("scheme", ["midpoint", "theta"])
def test_penetration_is_bounded_by_dt_times_impact_speed(scheme):
    s = ImpactOscillator(**FORCED_PAIR)
    dt = 1e-3
    r = simulate(s, (1.0, 0.0), 50.0, dt, scheme=scheme)
    assert r.impacts > 5
    speed = np.max(np.abs(r.u[:, 0]))
    assert -np.min(r.q[:, 0]) <= dt * speed


def test_stiff_wall_theta_bounded_midpoint_reports_divergence():
    s = ImpactOscillator(m=1, k=1e8, c=0, f0=-1, e=0.5)
    for theta in (0.5, 1.0):
        r = simulate(s, (1e-6, 0.0), 1.0, 1e-3, scheme="theta", theta=theta)
        assert np.all(np.isfinite(r.q)) and np.max(np.abs(r.q)) <= 1.1e-6
        assert np.max(np.abs(r.u)) < 0.1
    # refused before the run: beyond omega_max*dt = 2 the explicit scheme returns growing garbage
    for dt, wdt in ((1e-3, "10"), (2e-4, "2"), (1e-2, "100")):
        with pytest.raises(UnstableScheme, match=rf"midpoint.*dt = {dt:g}.*omega_max\*dt = {wdt}\. "
                                                      r"Use scheme='theta' or dt < 0.0002"):
            simulate(s, (1e-6, 0.0), 1.0, dt, scheme="midpoint")
    # just below the limit it runs and stays bounded
    r = simulate(s, (1e-6, 0.0), 0.05, 1.9e-4, scheme="midpoint")
    assert np.max(np.abs(r.q)) <= 1.1e-6


def test_theta_half_equals_midpoint_without_linear_part():
    # with K = C = 0, S = M: the theta = 1/2 scheme is the midpoint scheme
    s = ImpactOscillator(m=1.5, f0=-1.0, F=0.7, Omega=2.0, e=0.6)
    a = simulate(s, (0.5, 0.3), 20.0, 1e-3)
    b = simulate(s, (0.5, 0.3), 20.0, 1e-3, scheme="theta", theta=0.5)
    assert a.impacts > 3
    assert np.max(np.abs(a.q - b.q)) < 1e-12 and np.max(np.abs(a.u - b.u)) < 1e-12


@pytest.mark.parametrize("phasor", [False, True])
@pytest.mark.parametrize("code", [moreau.MIDPOINT, moreau.THETA])
@pytest.mark.parametrize("terms", [1, 2])
def test_scalar_fast_path_is_bitwise_identical(code, phasor, terms):
    forcing = ((1.0, 1.2, 0.3), (0.4, 3.1, -0.7))[:terms]
    s = MechanicalSystem(M=[[1.3]], K=[[1.0]], C=[[0.1]], f0=[0.3], w=[1.0], e=0.8,
                         forcing=[([F], Om, ph) for F, Om, ph in forcing])
    sa = s.arrays()
    n, every = 40000, 7
    outs = []
    for kernel in (moreau.integrate, moreau.integrate1):
        rows = record_rows(n, every)   # the final state is always a row (40000 = 7 * 5714 + 2)
        rec = (np.empty(rows), np.empty((rows, 1)), np.empty((rows, 1)), np.empty(rows))
        kernel(sa, np.array([1.0]), np.array([0.0]), 0.25, 1e-3, n, np.array([0.05]), code, 0.7,
               every, *rec, phasor, 0.0)
        outs.append(rec)
    assert np.count_nonzero(outs[0][3]) > 3
    for a, b in zip(*outs):
        assert np.array_equal(a, b)


def test_advance_matches_integrate():
    # the FMU's stepper (advance) and simulate() run the same arithmetic (the default scheme)
    s = ImpactOscillator(**FORCED_PAIR)
    dt, H = 1e-3, 1e-2
    ref = simulate(s, (1.0, 0.0), 30.0, dt, record_every=10)
    q, u = np.array([1.0]), np.array([0.0])
    sa = s.arrays()
    tau = np.zeros(1)
    qs = [q[0]]
    for k in range(3000):
        status, P, imp = moreau.advance(sa, q, u, k * H, H, dt, tau, moreau.TRAPEZOID, 0.5, None, False)
        assert status == moreau.OK
        qs.append(q[0])
    assert np.max(np.abs(np.array(qs) - ref.q[:, 0])) < 1e-12


def test_phasor_drift_below_1e13_of_the_cos_path():
    # the harmonic values the loops use: phasor (re-synchronised every PHASOR_SYNC steps)
    # against a cos per step, over 5e5 steps (t up to 50, Omega t up to 155, where the
    # cos path's own argument rounding eps |Omega t| stays ~3e-14)
    Omega = np.array([1.2, 3.1])
    phi = np.array([0.3, -0.7])
    dt = 1e-4
    n = 500_000
    a = moreau.harmonic_table(Omega, phi, 0.0, dt, 0.5 * dt, n, True)
    b = moreau.harmonic_table(Omega, phi, 0.0, dt, 0.5 * dt, n, False)
    # equal at every re-synchronisation, and within 1e-13 in between
    assert np.array_equal(a[::moreau.PHASOR_SYNC], b[::moreau.PHASOR_SYNC])
    assert 0.0 < np.max(np.abs(a - b)) < 1e-13      # (> 0: not the cos path in disguise)
    # independent reference: the harmonic of the exact time k dt + dt/2 in extended precision
    k = np.arange(n, dtype=np.longdouble)
    t = k * np.longdouble(dt) + np.longdouble(0.5 * dt)
    exact = np.cos(t[:, None] * Omega.astype(np.longdouble) + phi.astype(np.longdouble))
    if np.finfo(np.longdouble).eps < 1e-18:        # x86 80-bit long double
        assert np.max(np.abs(a - exact.astype(float))) < 1e-13


@pytest.mark.parametrize("scheme", ["midpoint", "theta"])
def test_phasor_path_reproduces_cos_path_over_long_runs(scheme):
    # 2e6 steps with impacts: final and recorded states within 1e-12
    s = ImpactOscillator(m=1.0, k=1.0, c=0.1, f0=0.3, F=1.0, Omega=1.2, e=0.8)
    kw = dict(scheme=scheme, record_every=1000)
    a = simulate(s, (1.0, 0.0), 200.0, 1e-4, phasor=True, **kw)
    b = simulate(s, (1.0, 0.0), 200.0, 1e-4, phasor=False, **kw)
    assert a.impacts > 20 and a.impacts == b.impacts
    assert np.max(np.abs(a.q - b.q)) < 1e-12 and np.max(np.abs(a.u - b.u)) < 1e-12
    # default is the phasor path
    c = simulate(s, (1.0, 0.0), 200.0, 1e-4, **kw)
    assert np.array_equal(c.q, a.q)


def test_midpoint_and_theta_half_coincide_without_linear_part_phasor():
    # same formula: with K = C = 0, S = M and theta = 1/2 is the midpoint scheme, bit for bit
    s = ImpactOscillator(m=1.5, f0=-1.0, F=0.7, Omega=2.0, e=0.6)
    a = simulate(s, (0.5, 0.3), 20.0, 1e-3)
    b = simulate(s, (0.5, 0.3), 20.0, 1e-3, scheme="theta", theta=0.5)
    assert a.impacts > 3 and np.array_equal(a.q, b.q) and np.array_equal(a.u, b.u)


def test_advance_first_order_hold_zero_slope_is_bitwise_zero_order_hold():
    s = MechanicalSystem(M=[[2.0, 0.5], [0.5, 1.0]], K=[[3.0, -1.0], [-1.0, 2.0]], C=0.02 * np.eye(2),
                         f0=[0.1, 0.2], w=[1.0, 0.5], e=0.7, forcing=[([0.6, 0.0], 1.3, 0.0)])
    sa = s.arrays()
    for code in (moreau.MIDPOINT, moreau.THETA):
        for ph in (False, True):
            x = [np.array([0.6, 0.2]), np.array([0.0, 0.0])]
            y = [np.array([0.6, 0.2]), np.array([0.0, 0.0])]
            tau = np.array([0.3, -0.1])
            for k in range(300):
                ra = moreau.advance(sa, x[0], x[1], k * 0.025, 0.025, 1e-3, tau, code, 0.6, None, ph)
                rb = moreau.advance(sa, y[0], y[1], k * 0.025, 0.025, 1e-3, tau, code, 0.6,
                                    np.zeros(2), ph)
                assert ra == rb
            assert np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1])


def test_advance_shortens_last_substep():
    s = ImpactOscillator(m=1, f0=-1.0)
    q, u = np.array([10.0]), np.array([0.0])
    # H = 2.5 dt: steps dt, dt, 0.5 dt; constant force: exact quadratic
    moreau.advance(s.arrays(), q, u, 0.0, 0.25, 0.1, np.zeros(1), moreau.MIDPOINT, 0.5, None, False)
    assert abs(q[0] - (10.0 - 0.5 * 0.25**2)) < 1e-14 and abs(u[0] + 0.25) < 1e-14


def test_two_dof_oblique_wall_energy_and_admissibility():
    M = np.array([[2.0, 0.5], [0.5, 1.0]])
    s = MechanicalSystem(M=M, K=np.diag([1.0, 2.0]), C=np.zeros((2, 2)), f0=[0.0, 0.0],
                         w=[1.0, -0.5], g0=0.3, e=1.0)
    r = simulate(s, ([0.5, 0.2], [0.3, -0.4]), 30.0, 1e-4)
    assert r.impacts > 3
    E = [s.energy(q, u) for q, u in zip(r.q, r.u)]
    # elastic impacts, no damping: energy is conserved up to O(dt) per impact
    assert abs(E[-1] - E[0]) < 1e-2 * E[0]
    g = r.q @ s.w + s.g0
    assert g.min() > -1e-4


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize("kwargs, match", [
    (dict(x0=(-0.1, 0.0)), r"x0 violates the constraint: g\(q\) = -0.1 < 0"),
    (dict(dt=0.0), r"dt must be a positive finite step, got 0.0"),
    (dict(dt=-1e-3), r"dt must be a positive finite step, got -0.001"),
    (dict(dt=float("nan")), r"dt must be a positive finite step, got nan"),
    (dict(x0=(float("nan"), 0.0)), r"x0 must be finite"),
    (dict(x0=(1.0,)), r"x0 must be a pair"),
    (dict(scheme="rk4"), r"scheme must be one of .*'rk4'"),
    (dict(scheme="theta", theta=0.2), r"theta must lie in \[0.5, 1\].*0.2"),
    (dict(record_every=0), r"record_every must be >= 1, got 0"),
    (dict(tau=[float("inf")]), r"tau must be 1 finite numbers"),
])
def test_simulate_rejects_bad_input(kwargs, match):
    s = ImpactOscillator(m=1, k=1, e=0.5)
    args = dict(x0=(1.0, 0.0), t_end=1.0, dt=1e-3)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        simulate(s, **args)


@pytest.mark.parametrize("kwargs, match", [
    (dict(m=0.0), r"m \(mass\) must be > 0, got 0.0"),
    (dict(e=1.5), r"e \(restitution\) must lie in \[0, 1\], got 1.5"),
    (dict(k=float("inf")), r"k must be finite, got inf"),
])
def test_model_rejects_bad_parameters(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ImpactOscillator(**kwargs)


def test_mechanical_system_rejects_bad_matrices():
    z = np.zeros((2, 2))
    with pytest.raises(ValueError, match="M must be symmetric"):
        MechanicalSystem(M=[[1, 2], [0, 1]], K=z, C=z, f0=[0, 0], w=[1, 0])
    with pytest.raises(ValueError, match="M must be positive definite, got smallest eigenvalue -1"):
        MechanicalSystem(M=[[1, 0], [0, -1]], K=z, C=z, f0=[0, 0], w=[1, 0])
    with pytest.raises(ValueError, match="w must be nonzero"):
        MechanicalSystem(M=np.eye(2), K=z, C=z, f0=[0, 0], w=[0, 0])
    with pytest.raises(ValueError, match=r"K must be 2x2 to match M"):
        MechanicalSystem(M=np.eye(2), K=np.eye(3), C=z, f0=[0, 0], w=[1, 0])


# ---------------------------------------------------------------- first-order hold in advance
def _event_driven_reference(m, k, c, f0, F, Om, e, alpha, beta, x0, t_eval):
    """DOP853 (rtol 1e-13) with a terminal g = 0 event and restarts: the exact solution
    of m q'' + c q' + k q = f0 + F cos(Om t) + alpha + beta t, q >= 0 (no accumulation)."""
    from scipy.integrate import solve_ivp

    def rhs(t, y):
        return [y[1], (f0 + F * math.cos(Om * t) + alpha + beta * t - k * y[0] - c * y[1]) / m]

    def hit(t, y):
        return y[0]
    hit.terminal, hit.direction = True, -1
    t, y = t_eval[0], np.array(x0, dtype=float)
    out = np.empty((t_eval.size, 2))
    out[0] = y
    i = 1
    impacts = 0
    while i < t_eval.size:
        te = t_eval[(t_eval > t)]
        sol = solve_ivp(rhs, (t, t_eval[-1]), y, method="DOP853", rtol=1e-13, atol=1e-15,
                        events=hit, t_eval=te, dense_output=False)
        n = sol.t.size
        out[i:i + n] = sol.y.T
        i += n
        if sol.status == 1:
            t = sol.t_events[0][0]
            y = sol.y_events[0][0].copy()
            y[0], y[1] = 0.0, -e * y[1]
            impacts += 1
        else:
            break
    return out, impacts


def test_advance_first_order_hold_converges_to_the_linear_input_solution():
    # tau(t) = alpha + beta t handed over per communication step as (tau(t_c), taudot = beta):
    # with it the midpoint converges (first order, impacts) to the exact solution with that tau(t)
    p = dict(m=1.0, k=1.0, c=0.1, f0=0.1, F=0.5, Omega=2.5, e=0.8)
    s = ImpactOscillator(**p)
    alpha, beta = -0.2, 0.06
    H, t_end = 0.05, 12.0
    tc = np.arange(int(round(t_end / H)) + 1) * H
    ref, impacts = _event_driven_reference(p["m"], p["k"], p["c"], p["f0"], p["F"], p["Omega"], p["e"],
                                           alpha, beta, (1.0, 0.0), tc)
    assert impacts >= 3
    sa = s.arrays()
    errs, errs_zoh = [], []
    dts = (2e-3, 1e-3, 5e-4, 2.5e-4, 1.25e-4, 6.25e-5)
    for dt in dts:
        for foh, errl in ((True, errs), (False, errs_zoh)):
            q, u = np.array([1.0]), np.array([0.0])
            Q = [1.0]
            for t in tc[:-1]:
                tau = np.array([alpha + beta * t])
                st = moreau.advance(sa, q, u, t, H, dt, tau, moreau.MIDPOINT, 0.5,
                                    np.array([beta]) if foh else None, True)
                assert st[0] == moreau.OK
                Q.append(q[0])
            errl.append(np.max(np.abs(np.array(Q) - ref[:, 0])))
    # first order: O(dt) along the whole ladder, fitted slope ~1 (the impact-time error makes
    # single halvings erratic: measured 3.4e-3 .. 6.0e-5, slope 1.2)
    assert all(err < 5 * dt for err, dt in zip(errs, dts)), errs
    slope = np.polyfit(np.log(dts), np.log(errs), 1)[0]
    assert 0.7 < slope < 2.0, (slope, errs)
    # the zero-order hold converges to another solution: its error stalls at O(beta H)
    assert min(errs_zoh) > 2e-3 and errs_zoh[-1] > 20 * errs[-1], (errs, errs_zoh)
