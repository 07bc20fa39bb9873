"""The default scheme (trapezoid) is second order between impacts for user force laws nonlinear in u
without a declared linear part (issue 40 item 1; docs/design.md §2.8.1: the explicit part of h taken
again at the step's middle velocity), single systems, n = 2 and the coupled pair. Reference: scipy's
DOP853 at rtol = atol = 1e-12, wall far away; the midpoint stays first order on the same runs."""
from __future__ import annotations

import math

import numpy as np
import pytest
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


def test_a_law_linear_in_u_runs_the_trapezoid_as_it_stands():
    """No second evaluation where h is linear in u through its declared part: the pendulum's trapezoid is
    its theta = 1/2 run bit for bit (the theta scheme's copy has no correction)."""
    p = Pendulum(c=0.2, q_w=0.3)
    a = simulate(p, (0.1, 2.0), 2.0, 1e-3, scheme="trapezoid")
    b = simulate(p, (0.1, 2.0), 2.0, 1e-3, scheme="theta", theta=0.5)
    assert a.impacts > 0                       # it impacts
    assert np.array_equal(a.q, b.q) and np.array_equal(a.u, b.u)
