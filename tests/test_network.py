"""Monolithic network of N coupled systems (core/network.py), the master's reference."""
import math

import numpy as np
import pytest

from fmu_sync.core import ImpactOscillator, SimulationDiverged
from fmu_sync.core.exchange import UnstableExchange, largest_stable, laplacian_modes
from fmu_sync.core.metrics import sync_metrics
from fmu_sync.core.network import all_to_all, graph, path, ring, simulate_network, star
from fmu_sync.core.pair import simulate_pair

PAPER = dict(m=1, k=1, c=0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
RING_X = [(0.2 + 0.9 * (i % 3) / 2, 0.5 * math.sin(1.7 * i)) for i in range(8)]


@pytest.fixture(scope="module")
def paper():
    return ImpactOscillator(**PAPER)


def test_graph_helpers():
    R = ring(8)
    assert R.shape == (8, 8) and np.array_equal(R, R.T) and np.all(R.sum(axis=1) == 2)
    assert R[0, 7] == R[7, 0] == 1 and R[0, 2] == 0
    # Laplacian spectra (closed forms): ring 2 - 2 cos(2 pi k / N), star {1, N}, complete {N}
    lam = np.sort(laplacian_modes(R))
    k = np.arange(1, 8)
    np.testing.assert_allclose(lam, np.sort(2 - 2 * np.cos(2 * np.pi * k / 8)), atol=1e-12)
    np.testing.assert_allclose(laplacian_modes(star(5)), [1, 1, 1, 5], atol=1e-12)
    np.testing.assert_allclose(laplacian_modes(all_to_all(4)), [4, 4, 4], atol=1e-12)
    assert np.count_nonzero(path(5)) == 8 and np.array_equal(graph("path", 5, 2.0), 2 * path(5))
    with pytest.raises(ValueError, match="graph must be one of"):
        graph("torus", 4)
    with pytest.raises(ValueError, match="N >= 2"):
        ring(1)


def test_two_nodes_are_the_pair_bitwise(paper):
    x = [(1.0, 0.0), (0.2, 0.5)]
    net = simulate_network(paper, x, ring(2), 30.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5, scheme="midpoint")
    pair = simulate_pair(paper, *x, 30.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5, scheme="midpoint")
    assert net.edges == [(0, 1)] and net.impacts == [pair.impacts1, pair.impacts2]
    for a, b in ((net.q[:, 0], pair.q1), (net.u[:, 1], pair.u2), (net.d[:, 0], pair.d),
                 (net.branch[:, 0], pair.branch), (net.tau[1:, 0], pair.tau1[1:])):
        assert np.array_equal(a, b)
    # row 0 holds the forces at the start (as the master records them)
    assert net.tau[0, 0, 0] == pytest.approx(-(1.0 * 0.8 + 0.5 * -0.5))
    # the default scheme (trapezoid: the coupling inside the step) too
    net = simulate_network(paper, x, ring(2), 5.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5)
    pair = simulate_pair(paper, *x, 5.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5)
    assert np.array_equal(net.q[:, 0], pair.q1) and np.array_equal(net.d[:, 0], pair.d)


def test_ring_without_impacts_decays_at_the_slowest_laplacian_mode():
    # f0 = 10 k keeps every node far from the wall: branch E everywhere, the PD law on each
    # edge. Mode k of the Laplacian: m x'' + (c + lam_k Kd) x' + (k + lam_k Kp) x = 0, so
    # max d decays like exp(-(c + lam_2 Kd)/(2 m) t), lam_2 = 2 - 2 cos(2 pi / 8).
    m_, k, c, Kp, Kd = 1.0, 1.0, 0.02, 1.0, 0.5
    s = ImpactOscillator(m=m_, k=k, c=c, f0=10.0 * k)
    x = [(10.0 + q, u) for q, u in RING_X]
    r = simulate_network(s, x, ring(8), 120.0, 1e-3, coupling="switching", Kp=Kp, Kd=Kd,
                         record_every=10)
    assert r.impacts == [0] * 8 and np.all(r.branch == 0)
    lam2 = 2 - 2 * math.cos(2 * math.pi / 8)
    sigma = (c + lam2 * Kd) / (2 * m_)
    # default window (from 0.1 max d): the median of the per-decade rates, within 2 % of the
    # slowest mode's (issue 25) and within its spread
    m = r.sync(1e-9)
    assert m.resolved and m.rate == pytest.approx(sigma, rel=0.02)
    assert abs(m.rate - sigma) <= m.rate_err + 1e-3 * sigma
    # a window from 1e-3 max d on sees the slowest mode almost alone (measured: 0.15686 vs 0.15645
    # with the energy metric, which weighs the faster modes more than Q = I did: 0.1563)
    assert r.sync(1e-9, hi=1e-3).rate == pytest.approx(sigma, rel=4e-3)


def test_ring_of_8_synchronizes_under_the_switching_law(paper):
    r = simulate_network(paper, RING_X, ring(8), 60.0, 1e-2, coupling="switching", Kp=4.0, Kd=2.0)
    assert len(r.edges) == 8 and r.q.shape == (6001, 8, 1) and r.d.shape == (6001, 8)
    assert all(i > 10 for i in r.impacts)                  # impacting while synchronizing
    assert len(set(r.branch.ravel().tolist())) >= 2        # the law switched branches
    m = r.sync(1e-6)
    assert m.t_sync < 40.0 and r.d_max[-1] < 1e-9
    # the window follows d down to a decade above round-off (issue 25: no formula of the step cuts
    # it); the decay is the slowest Laplacian mode's (lam_2 Kd / 2 = 0.586) within its spread
    lam2 = 2 - 2 * math.cos(2 * math.pi / 8)
    assert m.resolved and m.decades >= 8, m.reason
    assert abs(m.rate - lam2 * 2.0 / 2) < max(2 * m.rate_err, 0.05)
    assert r.V[-1] == pytest.approx(0.5 * np.sum(r.d[-1] ** 2))


def test_mixed_laws_and_mismatched_nodes(paper):
    # per-node stiffness +-5 %: the ring cannot synchronize exactly; its ultimate bound is small
    nodes = [ImpactOscillator(**{**PAPER, "k": 1.0 + 0.05 * ((i % 3) - 1)}) for i in range(8)]
    r = simulate_network(nodes, RING_X, ring(8), 60.0, 1e-2,
                         coupling=["switching", "euclidean"] * 4, Kp=4.0, Kd=2.0)
    m = r.sync(1e-6)
    assert m.t_sync == math.inf and 1e-5 < m.bound < 0.05 * np.max(r.d_max)
    with pytest.raises(ValueError, match=r"coupling per edge needs 8 laws"):
        simulate_network(paper, RING_X, ring(8), 1.0, 1e-2, coupling=["switching"] * 3)
    with pytest.raises(ValueError, match=r"the switching law is refused: the quotient distance needs one impact "
                       r"map .*e differs: node 1 has e = 0.9, node 2 has e = 0.9, node 3 has e = 0.5"):
        simulate_network([paper, paper, ImpactOscillator(**{**PAPER, "e": 0.5})],
                         RING_X[:3], ring(3), 1.0, 1e-2)


def test_network_stability_is_checked_on_the_largest_laplacian_mode(paper):
    # all-to-all on 8 nodes: lam_max = 8, omega_c = sqrt(8 Kp); Kd = 0.5 -> zeta = 8*0.5/(2*omega)
    Kp, Kd = 100.0, 0.5
    w = math.sqrt(8 * Kp)
    zeta = 8 * Kd / (2 * w)
    H_max = 4 * zeta / w
    with pytest.raises(UnstableExchange, match=r"largest stable dt = " + f"{largest_stable(H_max):.4g}"):
        simulate_network(paper, RING_X, all_to_all(8), 1.0, 1.05 * H_max, coupling="euclidean",
                         Kp=Kp, Kd=Kd, scheme="midpoint")
    # forced to run: it stops, marked failed, with the finite part of the record
    with pytest.raises(SimulationDiverged) as err:
        simulate_network(paper, RING_X, all_to_all(8), 200.0, 5 * H_max, coupling="euclidean",
                         Kp=Kp, Kd=Kd, allow_unstable=True, scheme="midpoint")
    part = err.value.partial
    assert not part.success and np.all(np.isfinite(part.d)) and np.all(np.isfinite(part.q))
    ok = simulate_network(paper, RING_X, all_to_all(8), 2.0, 0.95 * H_max, coupling="euclidean",
                          Kp=Kp, Kd=Kd, scheme="midpoint")
    assert ok.success


def test_progress_chunks_change_no_number(paper):
    kw = dict(coupling="switching", Kp=4.0, Kd=2.0, record_every=3)
    a = simulate_network(paper, RING_X, ring(8), 10.0, 1e-2, **kw)
    seen = []
    b = simulate_network(paper, RING_X, ring(8), 10.0, 1e-2, progress=seen.append, **kw)
    assert seen[-1] == 1.0 and len(seen) > 10
    for k in ("t", "q", "u", "tau", "d", "branch", "euclidean"):
        assert np.array_equal(getattr(a, k), getattr(b, k))


@pytest.mark.parametrize("scheme", ["midpoint", "theta"])
def test_two_nodes_are_the_pair_for_both_schemes_and_two_dofs(scheme):
    from fmu_sync.core import MechanicalSystem
    M = np.array([[2.0, 0.5], [0.5, 1.0]])
    s = MechanicalSystem(M=M, K=np.diag([1.0, 2.0]), C=0.05 * np.eye(2), f0=[0.0, -0.2],
                         w=[1.0, -0.5], g0=0.3, e=0.7, forcing=(([0.3, 0.1], 1.7, 0.0),))
    s2 = MechanicalSystem(M=M, K=np.diag([1.1, 2.0]), C=0.05 * np.eye(2), f0=[0.0, -0.2],
                          w=[1.0, -0.5], g0=0.3, e=0.7)       # stiffer, unforced: K and forcing per node
    x = [([0.5, 0.2], [0.3, -0.4]), ([0.1, 0.0], [-0.2, 0.3])]
    kw = dict(coupling="switching", Kp=2.0, Kd=1.0, scheme=scheme, record_every=10)
    net = simulate_network([s, s2], x, ring(2), 20.0, 1e-3, **kw)
    pair = simulate_pair((s, s2), *x, 20.0, 1e-3, **kw)
    assert pair.impacts1 > 0 and net.impacts == [pair.impacts1, pair.impacts2]
    np.testing.assert_allclose(net.q[:, 1], pair.q2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(net.d[:, 0], pair.d, rtol=0, atol=1e-12)
