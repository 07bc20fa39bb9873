"""The default scheme (trapezoid) is second order between impacts for user force laws nonlinear in u
without a declared linear part (issue 40 item 1; docs/design.md §2.8.1: the explicit part of h taken
again at the step's middle velocity), single systems, n = 2 and the coupled pair. Reference: scipy's
DOP853 at rtol = atol = 1e-12, wall far away; the midpoint stays first order on the same runs."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.integrate import solve_ivp

from fmu_sync.core import MechanicalSystem, simulate, simulate_pair
from fmu_sync.core.examples import Pendulum

from _nonlinear_u_laws import DRAG, DRAG2, VDP, rhs_drag, rhs_vdp

LAWS = {"drag": (DRAG, rhs_drag), "vdp": (VDP, rhs_vdp)}
X0, X1, X2, T = (0.5, 0.2), (0.5, 0.2), (-0.3, 0.4), 1.0


def _dop(rhs, x):
    return solve_ivp(rhs, (0.0, T), list(x), method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]


def _order(e):
    return math.log10(e[0] / e[1])


def _system(law, n=1):
    return MechanicalSystem(M=np.eye(n), w=np.eye(n)[0], g0=100.0, e=0.9, force=law, params={})


def test_the_probe_tells_laws_nonlinear_in_u():
    assert not DRAG.linear_in_u and not VDP.linear_in_u and not DRAG2.linear_in_u
    assert Pendulum(c=0.2).force.linear_in_u    # damping declared linear, gravity in q only


@pytest.mark.parametrize("name", sorted(LAWS))
def test_a_single_user_law_nonlinear_in_u_is_second_order(name):
    law, f = LAWS[name]
    s = _system(law)
    ref = _dop(lambda t, x: [x[1], f(x[0], x[1], t)], X0)
    err = {}
    for scheme in ("midpoint", "trapezoid"):
        err[scheme] = [max(abs(r.q[-1, 0] - ref[0]), abs(r.u[-1, 0] - ref[1]))
                       for r in (simulate(s, X0, T, dt, scheme=scheme, record_every=10 ** 6) for dt in (1e-3, 1e-4))]
    assert _order(err["trapezoid"]) >= 1.9
    assert _order(err["midpoint"]) < 1.2      # the explicit part at u0: first order
    assert err["trapezoid"][1] < 1e-8


@pytest.mark.parametrize("name", sorted(LAWS))
def test_a_pair_of_user_laws_nonlinear_in_u_is_second_order(name):
    law, f = LAWS[name]
    s = _system(law)

    def rhs(t, z):
        q1, u1, q2, u2 = z
        tau = -1.0 * (q1 - q2) - 0.5 * (u1 - u2)
        return [u1, f(q1, u1, t) + tau, u2, f(q2, u2, t) - tau]
    ref = _dop(rhs, (*X1, *X2))
    e = []
    for dt in (1e-3, 1e-4):
        r = simulate_pair(s, X1, X2, T, dt, coupling="switching", Kp=1.0, Kd=0.5, record_every=10 ** 6)
        e.append(np.max(np.abs(np.array([r.q1[-1, 0], r.u1[-1, 0], r.q2[-1, 0], r.u2[-1, 0]]) - ref)))
    assert _order(e) >= 1.9


def test_an_n2_user_law_nonlinear_in_u_is_second_order():
    s = _system(DRAG2, 2)
    x0 = ([0.5, -0.2], [0.2, 0.6])

    def rhs(t, z):
        q, u = z[:2], z[2:]
        return [*u, -2 * q[0] + q[1] - 0.3 * u[0] * abs(u[0]), q[0] - 2 * q[1] - 0.3 * u[1] * abs(u[1])]
    ref = _dop(rhs, (*x0[0], *x0[1]))
    e = []
    for dt in (1e-3, 1e-4):
        r = simulate(s, x0, T, dt, record_every=10 ** 6)
        e.append(np.max(np.abs(np.concatenate([r.q[-1], r.u[-1]]) - ref)))
    assert _order(e) >= 1.9


def _true_step_pair(f, x, t, dt, Kp, Kd):
    """One step of the corrected trapezoid (docs/design.md §2.8.1; no declared linear part: X = 1) of the
    pair under the PD law (far wall: branch E), the held force s = (tau(x0) + tau(x1(s))) / 2 solved to
    round-off by the secant method on the true step (no affine model of the end state)."""
    q1, u1, q2, u2 = x
    a = dt / 2

    def node(q, u, s):
        qa = q + a * u
        y = f(qa, u + a * (f(qa, u, t + a) + s), t + a) + s    # h again at the middle velocity ub
        return q + dt * u + a * dt * y, u + dt * y

    def ends(s):
        return (*node(q1, u1, s), *node(q2, u2, -s))

    def res(s):
        e = ends(s)
        return 2 * s - t0 + Kp * (e[0] - e[2]) + Kd * (e[1] - e[3])
    t0 = -Kp * (q1 - q2) - Kd * (u1 - u2)
    s0, s1 = t0, t0 + 1e-3 * (1.0 + abs(t0))
    r0, r1 = res(s0), res(s1)
    for _ in range(50):
        if r1 == 0.0 or r1 == r0:
            break
        s0, s1, r0 = s1, s1 - r1 * (s1 - s0) / (r1 - r0), r1
        r1 = res(s1)
    return ends(s1)


@settings(max_examples=12, deadline=None)
@given(name=st.sampled_from(sorted(LAWS)), coupling=st.sampled_from(["euclidean", "switching"]),
       Kp=st.floats(1.0, 1000.0), Kd=st.floats(0.0, 2.0), x=st.tuples(*[st.floats(-2.0, 2.0)] * 4),
       dt=st.sampled_from([1e-3, 2e-3]))
def test_the_core_solves_the_true_implicit_step_of_a_law_nonlinear_in_u(name, coupling, Kp, Kd, x, dt):
    """The 1-DOF coupled solve of a law with the trapezoid's correction is the true implicit step, not its
    affine model (the end state's O(dt^2) dependence on the force through the middle velocity kept):
    30 steps of simulate_pair against the step's fixed point solved to round-off in Python. (0.9.0's
    affine solve was 1.4e-7 off over 200 steps at Kp = 400, Kd = 0.)"""
    law, f = LAWS[name]
    steps = 30
    r = simulate_pair(_system(law), x[:2], x[2:], steps * dt, dt, coupling=coupling, Kp=Kp, Kd=Kd,
                      record_every=10 ** 6)
    z = x
    for k in range(steps):
        z = _true_step_pair(f, z, k * dt, dt, Kp, Kd)
    got = np.array([r.q1[-1, 0], r.u1[-1, 0], r.q2[-1, 0], r.u2[-1, 0]])
    assert np.max(np.abs(got - np.array(z))) <= 1e-12 * max(1.0, np.max(np.abs(z)))


@pytest.mark.parametrize("Kp, Kd", [(1.0, 0.5), (400.0, 0.0)])
def test_a_network_of_a_law_nonlinear_in_u_runs_the_true_implicit_step(Kp, Kd):
    """The same on a 3-ring (simulate_network: the N-node solve on arrays, not the pair's on floats),
    against the nodes' held forces s = (tau(x0) + tau(x1(s))) / 2 solved by scipy's root (hybr)."""
    from scipy.optimize import root
    from fmu_sync.core import ring, simulate_network
    A, dt, steps = ring(3), 1e-3, 20
    x0 = np.array([[0.5, 0.2], [-0.3, 0.4], [0.1, -0.6]])

    def tau(q, u):
        return np.array([sum(A[i, j] * (-Kp * (q[i] - q[j]) - Kd * (u[i] - u[j])) for j in range(3))
                         for i in range(3)])

    def ends(x, s, t):
        q, u, a = x[:, 0], x[:, 1], dt / 2
        qa = q + a * u
        y = np.array([rhs_vdp(qa[i], u[i] + a * (rhs_vdp(qa[i], u[i], t + a) + s[i]), t + a) + s[i]
                      for i in range(3)])
        return q + dt * u + a * dt * y, u + dt * y
    x = x0.copy()
    for k in range(steps):
        t0 = tau(x[:, 0], x[:, 1])
        s = root(lambda s: 2 * s - t0 - tau(*ends(x, s, k * dt)), t0, method="hybr", tol=1e-15).x
        x = np.stack(ends(x, s, k * dt), 1)
    r = simulate_network(_system(VDP), [([a], [b]) for a, b in x0], A, steps * dt, dt, coupling="euclidean",
                         Kp=Kp, Kd=Kd, record_every=10 ** 6)
    got = np.stack([r.q[-1, :, 0], r.u[-1, :, 0]], 1)
    assert np.max(np.abs(got - x)) <= 1e-12 * max(1.0, np.max(np.abs(x)))


def test_a_law_linear_in_u_runs_the_trapezoid_as_it_stands():
    """No second evaluation where h is linear in u through its declared part: the pendulum's trapezoid is
    its theta = 1/2 run bit for bit (the theta scheme's copy has no correction)."""
    p = Pendulum(c=0.2, q_w=0.3)
    a = simulate(p, (0.1, 2.0), 2.0, 1e-3, scheme="trapezoid")
    b = simulate(p, (0.1, 2.0), 2.0, 1e-3, scheme="theta", theta=0.5)
    assert a.impacts > 0                       # it impacts
    assert np.array_equal(a.q, b.q) and np.array_equal(a.u, b.u)


def test_the_user_law_fmu_follows_the_core_default(tmp_path):
    """The exported law's native stepper runs the same corrected trapezoid (solver.scheme default). Under
    the implicit exchange at H = solver.dt (its tolerance: 1e-9 of the force scale) the master converges the
    step's fixed point, and so does the core's 1-DOF solve (on the true step: the correction's own
    dependence on the force kept): they agree to 1e-9 over 0.2 s at dt = 1e-3, Euclidean and switching,
    Kp = 1, Kd = 0.5 and the stiff Kp = 400, Kd = 0 (measured 5e-13 and 7e-11 of max|u| = 10; 0.9.0's affine
    solve: 1.4e-7), >= 100x closer than the uncorrected step (the FMU at solver.scheme = theta, 1/2). The FMU is the drag law of the tests
    above (tests/_nonlinear_u_laws.drag_model, its forcing term written in h): its loops are compiled once for both."""
    from fmu_sync.core.registry import load_model
    from fmu_sync.export import export_fmu
    from fmu_sync.master import cosimulate
    spec = f"{Path(__file__).with_name('_nonlinear_u_laws.py')}:drag_model"   # the drag law of the tests above
    fmu = str(export_fmu(spec, tmp_path / "drag.fmu", {"solver.dt": 1e-3}))
    s = load_model(spec)()
    x1, x2 = ([1.0], [0.0]), ([0.2], [0.5])
    for law in ("switching", "euclidean"):
        for Kp, Kd in ((1.0, 0.5), (400.0, 0.0)):
            ref = simulate_pair(s, x1, x2, 0.2, 1e-3, coupling=law, Kp=Kp, Kd=Kd)
            r = cosimulate(fmu, x1, x2, 0.2, 1e-3, law, Kp, Kd, exchange="implicit")
            assert r.info["exchange_tol"] == 1e-9
            for a, b in ((r.q1, ref.q1), (r.u1, ref.u1), (r.q2, ref.q2), (r.u2, ref.u2)):
                assert np.max(np.abs(a - b)) <= 1e-9
    plain = cosimulate(fmu, x1, x2, 0.2, 1e-3, "euclidean", 400.0, 0.0, exchange="implicit",
                       start_values={"solver.scheme": 1, "solver.theta": 0.5})
    assert np.max(np.abs(r.u1 - ref.u1)) * 100 <= np.max(np.abs(plain.u1 - ref.u1))


# ------------------------------------------------------------------ coupled n-DOF (issue 40 item 1, n > 1)
M2 = np.array([[2.0, 0.5], [0.5, 1.0]])         # the two-dof scene's system, its wall far away
K2 = np.array([[3.0, -1.0], [-1.0, 2.0]])
C2 = 0.02 * np.eye(2)
F0, F1, OM = np.array([0.1, 0.2]), np.array([0.6, 0.0]), 1.3
Y1, Y2 = ([0.6, 0.2], [0.0, 0.0]), ([0.2, -0.1], [0.3, -0.2])


def _two_dof():
    return MechanicalSystem(M=M2, K=K2, C=C2, f0=F0, forcing=[(F1, OM, 0.0)], w=[1.0, 0.5], g0=100.0, e=0.7)


def _two_dof_pair(Kp, Kd, T):
    Mi = np.linalg.inv(M2)

    def rhs(t, z):
        q1, u1, q2, u2 = z[0:2], z[2:4], z[4:6], z[6:8]
        tau = -Kp * (q1 - q2) - Kd * (u1 - u2)
        f = F0 + F1 * math.cos(OM * t)
        return np.concatenate([u1, Mi @ (f - K2 @ q1 - C2 @ u1 + tau), u2, Mi @ (f - K2 @ q2 - C2 @ u2 - tau)])
    z0 = np.concatenate([Y1[0], Y1[1], Y2[0], Y2[1]])
    return solve_ivp(rhs, (0.0, T), z0, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]


def _end2(r):
    return np.concatenate([r.q1[-1], r.u1[-1], r.q2[-1], r.u2[-1]])


@pytest.mark.parametrize("law", ["euclidean", "switching"])
def test_a_coupled_two_dof_pair_is_second_order_with_the_coupling_inside_the_step(law):
    s, ref = _two_dof(), _two_dof_pair(2.0, 1.0, T)
    err = {sc: [np.max(np.abs(_end2(simulate_pair(s, Y1, Y2, T, dt, coupling=law, Kp=2.0, Kd=1.0, scheme=sc,
                                                  record_every=10 ** 6)) - ref)) for dt in (1e-3, 1e-4)]
           for sc in ("midpoint", "trapezoid")}
    assert _order(err["trapezoid"]) >= 1.9
    assert _order(err["midpoint"]) < 1.2          # the coupling held over the step
    assert err["trapezoid"][1] < 1e-8


def test_a_stiff_two_dof_pair_with_kd_zero_is_accepted_and_second_order():
    from fmu_sync.core.exchange import UnstableExchange
    s, T2 = _two_dof(), 2.0
    with pytest.raises(UnstableExchange):
        simulate_pair(s, Y1, Y2, T2, 1e-3, coupling="euclidean", Kp=400.0, Kd=0.0, scheme="midpoint")
    ref = _two_dof_pair(400.0, 0.0, T2)
    e = [np.max(np.abs(_end2(simulate_pair(s, Y1, Y2, T2, dt, coupling="euclidean", Kp=400.0, Kd=0.0,
                                          record_every=10 ** 6))[[0, 1, 4, 5]] - ref[[0, 1, 4, 5]]))
         for dt in (1e-3, 5e-4)]
    assert math.log2(e[0] / e[1]) >= 1.9 and e[0] <= 5e-3
