"""The second-order scheme ``trapezoid`` (issue 40, docs/design.md §2.3): Moreau–Jean θ = 1/2 between
impacts, and in coupled runs (1-DOF) the coupling forces inside the step (their trapezoid, the branch of
a switching law held from the step's start).

References: scipy's DOP853 at rtol = atol = 1e-12 (smooth runs, wall far away: the orders), the exact
event-driven solver (impacts), a fine run of the scheme itself (the stiff impacting pair's amplitude),
and the midpoint scheme (which stays the first-order option, refused where the held coupling diverges).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from fmu_sync.core import ImpactOscillator, simulate, simulate_exact, simulate_network, simulate_pair
from fmu_sync.core.examples import Pendulum
from fmu_sync.core.exchange import UnstableExchange

# the damped forced oscillator, the wall far away
OSC = dict(m=1.0, k=1.0, c=0.1, F=0.5, Omega=2.5)
X1, X2 = (0.3, 0.0), (-0.2, 0.4)


def _dop(rhs, x, T):
    return solve_ivp(rhs, (0.0, T), list(x), method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]


def _pd_pair(Kp, Kd, starts, T):
    """The coupled damped forced oscillators (PD coupling: the Euclidean law, and the switching law on
    branch E) by DOP853."""
    m, k, c, F, Om = (OSC[n] for n in ("m", "k", "c", "F", "Omega"))

    def rhs(t, z):
        q1, u1, q2, u2 = z
        tau = -Kp * (q1 - q2) - Kd * (u1 - u2)
        f = F * math.cos(Om * t)
        return [u1, (f - k * q1 - c * u1 + tau) / m, u2, (f - k * q2 - c * u2 - tau) / m]
    return _dop(rhs, (*starts[0], *starts[1]), T)


def _end(r):
    return np.array([r.q1[-1, 0], r.u1[-1, 0], r.q2[-1, 0], r.u2[-1, 0]])


def _order(e1, e2, ratio=10.0):
    return math.log(e1 / e2) / math.log(ratio)


def test_single_systems_are_second_order_against_dop853():
    T = 1.0
    osc = ImpactOscillator(**OSC, g0=100.0)
    z = _dop(lambda t, x: [x[1], 0.5 * math.cos(2.5 * t) - x[0] - 0.1 * x[1]], (0.3, 0.2), T)
    pend = Pendulum(c=0.2, q_w=3.0)     # the user law of core/examples.py, damped, the wall far away
    zp = _dop(lambda t, x: [x[1], -9.81 * math.sin(x[0]) - 0.2 * x[1]], (0.5, 0.0), T)
    for system, x0, ref in ((osc, (0.3, 0.2), z), (pend, (0.5, 0.0), zp)):
        err = {}
        for scheme in ("midpoint", "trapezoid"):
            e = []
            for dt in (1e-3, 1e-4):
                r = simulate(system, x0, T, dt, scheme=scheme, record_every=10 ** 6)
                e.append(max(abs(r.q[-1, 0] - ref[0]), abs(r.u[-1, 0] - ref[1])))
            err[scheme] = e
        assert _order(*err["trapezoid"]) >= 1.9
        assert _order(*err["midpoint"]) < 1.2          # the first-order option it replaces
        assert err["trapezoid"][0] < err["midpoint"][0] / 50


@pytest.mark.parametrize("law", ["euclidean", "switching"])
def test_the_pair_is_second_order_with_the_coupling_inside_the_step(law):
    T = 1.0
    s = ImpactOscillator(**OSC, g0=100.0)
    ref = _pd_pair(1.0, 0.5, (X1, X2), T)
    err = {}
    for scheme in ("midpoint", "trapezoid"):
        err[scheme] = [np.max(np.abs(_end(simulate_pair(s, X1, X2, T, dt, coupling=law, Kp=1.0, Kd=0.5,
                                                        scheme=scheme, record_every=10 ** 6)) - ref))
                       for dt in (1e-3, 1e-4)]
    assert _order(*err["trapezoid"]) >= 1.9
    assert _order(*err["midpoint"]) < 1.2          # the coupling held over the step: first order
    assert err["trapezoid"][1] < 1e-8


def test_kd_zero_and_stiff_gains_are_accepted_and_second_order():
    """Euclidean Kp = 400, Kd = 0 over 10 s: the midpoint's held exchange is refused at every dt; the
    trapezoid of the coupling is A-stable, accepted, second order, and close at dt = 1e-3."""
    T = 10.0
    s = ImpactOscillator(**OSC, g0=100.0)
    with pytest.raises(UnstableExchange):
        simulate_pair(s, X1, X2, T, 1e-3, coupling="euclidean", Kp=400.0, Kd=0.0, scheme="midpoint")
    ref = _pd_pair(400.0, 0.0, (X1, X2), T)
    e = []
    for dt in (1e-3, 5e-4):
        r = simulate_pair(s, X1, X2, T, dt, coupling="euclidean", Kp=400.0, Kd=0.0, scheme="trapezoid",
                          record_every=10 ** 6)
        e.append(np.max(np.abs(_end(r)[[0, 2]] - ref[[0, 2]])))   # positions
    assert _order(*e, ratio=2.0) >= 1.9
    assert e[0] <= 5e-3


def test_a_stiff_impacting_pair_is_accepted_and_its_amplitude_right():
    """The forced pair with impacts, Euclidean Kp = 1e4, Kd = 1: the midpoint refuses it at dt = 1e-3;
    the trapezoid runs it, and its amplitude is within 2x of the run at dt = 1e-5."""
    s = ImpactOscillator(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
    x1, x2 = (1.0, 0.0), (0.2, 0.5)
    with pytest.raises(UnstableExchange):
        simulate_pair(s, x1, x2, 2.0, 1e-3, coupling="euclidean", Kp=1e4, Kd=1.0, scheme="midpoint")
    amp = {}
    for dt in (1e-3, 1e-5):
        r = simulate_pair(s, x1, x2, 5.0, dt, coupling="euclidean", Kp=1e4, Kd=1.0, scheme="trapezoid",
                          record_every=max(1, round(1e-3 / dt)))
        assert r.impacts1 + r.impacts2 > 0
        amp[dt] = max(np.ptp(r.q1[:, 0]), np.ptp(r.q2[:, 0]))
    assert 0.5 <= amp[1e-3] / amp[1e-5] <= 2.0


def test_a_network_is_second_order_with_the_coupling_inside_the_step():
    """A ring of 3 (Euclidean, Kp = 1, Kd = 0.5, weights 1) against DOP853 of the Laplacian system."""
    T = 1.0
    s = ImpactOscillator(**OSC, g0=100.0)
    xs = [(0.3, 0.0), (-0.2, 0.4), (0.1, -0.3)]
    A = np.ones((3, 3)) - np.eye(3)
    L = np.diag(A.sum(1)) - A

    def rhs(t, z):
        q, u = z[:3], z[3:]
        a = 0.5 * math.cos(2.5 * t) - q - 0.1 * u - L @ (1.0 * q + 0.5 * u)
        return np.concatenate((u, a))
    ref = _dop(rhs, [x[0] for x in xs] + [x[1] for x in xs], T)
    e = []
    for dt in (1e-3, 1e-4):
        r = simulate_network(s, xs, A, T, dt, coupling="euclidean", Kp=1.0, Kd=0.5, scheme="trapezoid",
                             record_every=10 ** 6)
        end = np.concatenate((r.q[-1, :, 0], r.u[-1, :, 0]))
        e.append(np.max(np.abs(end - ref)))
    assert _order(*e) >= 1.9


def test_impacts_are_no_worse_than_the_midpoint():
    """The forced oscillator with impacts against the exact solver, dt = 1e-3: every Moreau scheme is
    first order there; the trapezoid's error stays within 1.2x of the midpoint's."""
    s = ImpactOscillator(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
    T, dt = 5.0, 1e-3
    ex = simulate_exact(s, (1.0, 0.0), T, dt)
    err = {}
    for scheme in ("midpoint", "trapezoid"):
        r = simulate(s, (1.0, 0.0), T, dt, scheme=scheme)
        assert r.percussion.sum() > 0
        err[scheme] = np.max(np.abs(r.q[:, 0] - ex.q[:, 0]))
    assert err["trapezoid"] <= 1.2 * err["midpoint"]


def test_the_trapezoid_is_theta_one_half_on_one_system_bit_for_bit():
    s = ImpactOscillator(**OSC, e=0.8, g0=0.5)
    a = simulate(s, (0.3, 0.2), 3.0, 1e-3, scheme="trapezoid", theta=0.9)   # theta belongs to 'theta'
    b = simulate(s, (0.3, 0.2), 3.0, 1e-3, scheme="theta", theta=0.5)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.u, b.u)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_the_implicit_cosimulation_at_H_dt_is_the_trapezoid_pair(tmp_path, hold):
    """One scheme everywhere: the FMU's default solver.scheme is the core's default (trapezoid: its internal
    θ = 1/2 step), and the master's implicit exchange (converged: the FMU's step under the mean of the
    forces at the step's ends, or their line with the first-order hold) is the monolithic trapezoid step:
    at H = solver.dt it reproduces the default simulate_pair to 1e-9, also at Kd = 0 and a stiff gain,
    which the midpoint core refuses."""
    import zipfile
    from fmu_sync.export import export_fmu
    from fmu_sync.master import cosimulate
    far = dict(m=1.0, k=1.0, c=0.1, f0=0.0, F=0.5, Omega=2.5, e=0.9, g0=10.0)
    fmu = str(export_fmu("impact-oscillator", tmp_path / "far.fmu", {**far, "solver.dt": 1e-3}))
    xml = zipfile.ZipFile(fmu).read("modelDescription.xml").decode()
    assert '<Item name="trapezoid" value="3"' in xml and 'name="solver.scheme"' in xml
    s = ImpactOscillator(**far)
    x1, x2 = (1.0, 0.0), (0.2, 0.5)
    for law, Kp, Kd in (("euclidean", 1.0, 0.5), ("switching", 1.0, 0.5), ("euclidean", 400.0, 0.0)):
        ref = simulate_pair(s, x1, x2, 0.2, 1e-3, coupling=law, Kp=Kp, Kd=Kd)
        r = cosimulate(fmu, x1, x2, 0.2, 1e-3, law, Kp, Kd, exchange="implicit", hold=hold)
        for a, b in ((r.q1, ref.q1), (r.u1, ref.u1), (r.q2, ref.q2), (r.u2, ref.u2)):
            assert np.max(np.abs(a - b)) <= 1e-9


def test_a_stiff_user_law_pair_is_second_order():
    """The damped pendulum pair (the user law of core/examples.py), Euclidean Kp = 500, Kd = 0: refused by
    the midpoint's held exchange, second order with the coupling inside the step (DOP853 reference)."""
    p = Pendulum(c=0.2, q_w=3.0)
    x1, x2, T = (0.5, 0.0), (-0.3, 0.2), 1.0
    with pytest.raises(UnstableExchange):
        simulate_pair(p, x1, x2, T, 1e-3, coupling="euclidean", Kp=500.0, Kd=0.0, scheme="midpoint")

    def rhs(t, z):
        q1, u1, q2, u2 = z
        tau = -500.0 * (q1 - q2)
        return [u1, -9.81 * math.sin(q1) - 0.2 * u1 + tau, u2, -9.81 * math.sin(q2) - 0.2 * u2 - tau]
    ref = _dop(rhs, (*x1, *x2), T)
    e = [np.max(np.abs(_end(simulate_pair(p, x1, x2, T, dt, coupling="euclidean", Kp=500.0, Kd=0.0,
                                          scheme="trapezoid", record_every=10 ** 6)) - ref)) for dt in (1e-3, 1e-4)]
    assert _order(*e) >= 1.9


def test_the_default_scheme_is_the_trapezoid():
    """simulate, simulate_pair and simulate_network without a scheme run the trapezoid, bit for bit, and
    accept what only the trapezoid accepts (Kd = 0, Kp = 400); the midpoint stays by name."""
    from fmu_sync.core.network import ring
    s = ImpactOscillator(**OSC, e=0.8, g0=0.5)
    a, b = simulate(s, (0.3, 0.2), 2.0, 1e-3), simulate(s, (0.3, 0.2), 2.0, 1e-3, scheme="trapezoid")
    assert a.scheme == "trapezoid" and np.array_equal(a.q, b.q) and np.array_equal(a.u, b.u)
    assert not np.array_equal(a.q, simulate(s, (0.3, 0.2), 2.0, 1e-3, scheme="midpoint").q)
    a = simulate_pair(s, X1, X2, 1.0, 1e-3, coupling="euclidean", Kp=400.0, Kd=0.0)
    b = simulate_pair(s, X1, X2, 1.0, 1e-3, coupling="euclidean", Kp=400.0, Kd=0.0, scheme="trapezoid")
    assert a.info["scheme"] == "trapezoid" and np.array_equal(_end(a), _end(b))
    xs = [(0.3, 0.0), (-0.2, 0.4), (0.1, -0.3)]
    a = simulate_network(s, xs, ring(3), 1.0, 1e-3, coupling="euclidean", Kp=400.0, Kd=0.0)
    b = simulate_network(s, xs, ring(3), 1.0, 1e-3, coupling="euclidean", Kp=400.0, Kd=0.0, scheme="trapezoid")
    assert np.array_equal(a.q, b.q) and np.array_equal(a.u, b.u)


def test_the_smooth_damped_pair_of_the_work_precision_figure():
    """The work-precision figure's smooth case (damped-pair, its truth DOP853): the trapezoid is second
    order and at the midpoint's cost per step (bench: fmu-sync bench, core speed) >= 10x closer."""
    from fmu_sync.benchmarks.work_precision_cases import PAIR_GRID, SCENES, _core_pair, dop853_pair
    sc = next(s for s in SCENES if s.name == "damped-pair")
    T = 5.0
    t = np.arange(int(round(T / PAIR_GRID)) + 1) * PAIR_GRID
    ref = dop853_pair(sc, t)
    err = {}
    for scheme in ("midpoint", "trapezoid"):
        err[scheme] = []
        for dt in (1e-3, 1e-4):
            out = _core_pair(sc, T, scheme, 0.5, dt)()
            assert np.allclose(out[0], t)
            err[scheme].append(max(np.max(np.abs(q - r)) for q, r in zip(out[2:], ref)))
    assert _order(*err["trapezoid"]) >= 1.9 and _order(*err["midpoint"]) < 1.2
    assert err["trapezoid"][0] * 10 <= err["midpoint"][0]
