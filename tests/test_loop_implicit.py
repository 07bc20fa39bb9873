"""The n-DOF trapezoid's step (core/loop_implicit.py, core/loop.py's n > 1 path; issue 40 item 4):
the PD law written out for a linear held step is network_forces' arithmetic bit for bit, and an
impacting coupled 2-DOF pair follows the documented step (docs/design.md §2.3) computed here in numpy."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fmu_sync.core import MechanicalSystem, simulate_pair
from fmu_sync.core.coupling import EUCLIDEAN, SWITCHING, UNCOUPLED, chain_work
from fmu_sync.core.distance import BRANCH_E, geometry
from fmu_sync.core.edges import network_forces
from fmu_sync.core.loop_implicit import held_pd


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 3), st.integers(2, 4), st.integers(0, 2 ** 32 - 1))
def test_the_written_out_pd_law_is_network_forces_on_a_linear_held_step(n, N, seed):
    rng = np.random.default_rng(seed)
    pairs = [(i, j) for i in range(N) for j in range(i + 1, N)]
    pick = rng.choice(len(pairs), size=rng.integers(1, len(pairs) + 1), replace=False)
    E2 = np.array([pairs[k] for k in pick], dtype=np.int64)
    W2 = rng.uniform(0.0, 2.0, (len(E2), 2)) * (rng.random((len(E2), 2)) > 0.2)
    laws = rng.choice(np.array([EUCLIDEAN, SWITCHING, UNCOUPLED]), size=len(E2)).astype(np.int64)
    A = rng.normal(size=(n, n))
    Kp, Kd = A @ A.T + np.eye(n), rng.normal(size=(n, n))
    geo = geometry(MechanicalSystem(M=np.eye(n) + 0.1 * np.ones((n, n)), K=np.eye(n), C=np.zeros((n, n)), f0=np.zeros(n),
                                    w=rng.normal(size=n), g0=0.0, e=0.7))
    q, u = rng.normal(size=(N, n)), rng.normal(size=(N, n))
    ref, mine = np.zeros((N, n)), np.full((N, n), np.nan)
    bk = np.full(len(E2), BRANCH_E)   # the branch held: E (the switching law there is the PD law)
    work = [np.zeros(n) for _ in range(2)] + list(chain_work(n))
    network_forces(laws, geo, Kp, Kd, E2, W2, q, u, ref, *work, False, np.zeros(len(E2)), bk, np.zeros(len(E2)),
                   np.zeros((N, 3)), 0.0, True)
    held_pd(laws, Kp, Kd, E2, W2, q, u, mine)
    assert np.array_equal(mine, ref)


M2 = np.array([[2.0, 0.5], [0.5, 1.0]])      # the two-dof scene's system (its oblique wall in)
K2 = np.array([[3.0, -1.0], [-1.0, 2.0]])
C2 = 0.02 * np.eye(2)
W, F1, OM = np.array([1.0, 0.5]), np.array([0.6, 0.0]), 1.3


def _reference(f0, e, Kp, Kd, x1, x2, dt, steps):
    """The trapezoid step of the pair with the Euclidean law (docs/design.md §2.3) in numpy: each node's
    force at the step's force point under tau(x_k); delta from (2 I - J) delta = tau(x_free) - tau(x_k);
    the node's step under tau(x_k) + delta with its wall (Moreau's contact in the S metric)."""
    a = dt / 2
    X = np.linalg.inv(M2 + a * C2 + a * a * K2)
    Xw = X @ W
    G = dt * (a * Kp + Kd) * X                      # d tau_1(x1) / d delta_1 = -G, d / d delta_2 = +G
    A = np.block([[2 * np.eye(2) + G, -G], [-G, 2 * np.eye(2) + G]])
    q, u = np.array([x1[0], x2[0]], float), np.array([x1[1], x2[1]], float)
    pd = (lambda q, u: -(Kp * (q[0] - q[1]) + Kd * (u[0] - u[1])))
    out, hits = [], 0
    for k in range(steps):
        t = k * dt
        tau0 = pd(q, u)
        tau = np.array([tau0, -tau0])
        y = np.array([f0 + tau[i] + F1 * np.cos(OM * (t + a)) - (K2 @ q[i] + (C2 + a * K2) @ u[i]) for i in range(2)])
        qf, uf = q + dt * u + a * dt * (y @ X.T), u + dt * (y @ X.T)
        t1 = pd(qf, uf)
        delta = np.linalg.solve(A, np.concatenate([t1 - tau[0], -t1 - tau[1]])).reshape(2, 2)
        for i in range(2):
            yi = y[i] + delta[i]
            u1 = u[i] + dt * X @ yi
            q1 = q[i] + dt * u[i] + a * dt * X @ yi
            if 0.0 + W @ (q[i] + 0.5 * dt * u[i]) <= 0.0:
                xi = W @ u1 + e * (W @ u[i])
                if xi < 0.0:
                    P = -xi / (W @ Xw)
                    u1, q1, hits = u1 + Xw * P, q1 + a * Xw * P, hits + 1
            q[i], u[i] = q1, u1
        out.append(np.concatenate([q.ravel(), u.ravel()]))
    return np.array(out), hits


def test_an_impacting_two_dof_pair_follows_the_documented_trapezoid_step():
    """With its wall in (the scene's impacts; f0 toward a plastic wall from a start on it: persistent
    contact, a percussion every step): the core's n > 1 trapezoid (one force and one step per node, the
    solve between) is the documented step to round-off over 3000 steps."""
    cases = ((np.array([0.1, 0.2]), 0.7, 2.0, 1.0, ([0.6, 0.2], [0.0, 0.0]), ([0.2, -0.1], [0.3, -0.2]), 2),
             (np.array([-0.5, -0.5]), 0.0, 20.0, 0.5, ([-0.2, 0.4], [-1.0, 0.0]), ([0.1, -0.2], [0.0, -0.5]), 1000))
    for f0, e, Kp, Kd, x1, x2, least in cases:
        s = MechanicalSystem(M=M2, K=K2, C=C2, f0=f0, forcing=[(F1, OM, 0.0)], w=W, g0=0.0, e=e)
        steps, dt = 3000, 1e-3
        r = simulate_pair(s, x1, x2, steps * dt, dt, coupling="euclidean", Kp=Kp, Kd=Kd)
        ref, hits = _reference(f0, e, Kp, Kd, x1, x2, dt, steps)
        core = np.concatenate([r.q1[1:], r.q2[1:], r.u1[1:], r.u2[1:]], axis=1)
        assert hits >= least and r.impacts1 + r.impacts2 == hits
        assert np.max(np.abs(core - ref)) <= 1e-10 * max(1.0, np.max(np.abs(ref)))
