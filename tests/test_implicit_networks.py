"""The implicit exchange on networks with impacts (issue 39 items 1 and 2, docs/design.md §4.4).

Rings of forced impact oscillators (m = 1, k = 1, c = 0, f0 = 0.2, F = 0.5, Omega = 2.5, e = 0.9,
wall at q = 0, solver.dt = 1e-3), random starts q in [0.2, 1.5], u in [-0.5, 0.5], Kp = 1, Kd = 0.5,
H = 0.01. On 0.6.0 the ring of 32 failed with ExchangeNotConverged at t = 1.54 (zoh) and 1.55 (foh)
and its tolerance run diverged right after the first shortened step. The reference is the
monolithic core (``simulate_network``, dt = 1e-3), against which the implicit run must be no
worse than twice the explicit one. The full N = 8 ... 256 measurement: ``fmu-sync bench``, section
``networks``.
"""
from __future__ import annotations

import numpy as np
import pytest

from fmu_sync.core import ImpactOscillator, ring, simulate_network
from fmu_sync.master import cosimulate_network

RING = dict(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
GAINS = dict(Kp=1.0, Kd=0.5)


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    from fmu_sync.export import export_fmu
    return str(export_fmu("impact-oscillator", tmp_path_factory.mktemp("rings") / "io.fmu",
                          {**RING, "solver.dt": 1e-3}))


def _starts(N: int, seed: int = 0):
    g = np.random.default_rng(seed)
    return [(g.uniform(0.2, 1.5), g.uniform(-0.5, 0.5)) for _ in range(N)]


def _error(r, ref):
    """max |q - q_core| at the record's times (each a multiple of the core's dt = 1e-3)."""
    idx = np.rint(r.t / 1e-3).astype(int)
    return float(np.abs(r.q[:, :, 0] - ref.q[idx, :, 0]).max())


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_a_ring_of_32_with_impacts_runs_implicit_as_well_as_explicit(fmu, hold):
    N, T = 32, 2.0
    xs = _starts(N)
    ref = simulate_network(ImpactOscillator(**RING), xs, ring(N), T, 1e-3, "euclidean", **GAINS)
    ex = cosimulate_network(fmu, xs, ring(N), T, 0.01, "euclidean", **GAINS, hold=hold)
    im = cosimulate_network(fmu, xs, ring(N), T, 0.01, "euclidean", **GAINS, hold=hold, exchange="implicit")
    assert im.success and im.t[-1] == pytest.approx(T) and sum(im.impacts) > 0
    it = im.info["iterations"]
    assert len(it) == 200 and np.median(it) <= 3 and it.max() <= 6, (np.median(it), it.max())
    assert _error(im, ref) <= 2 * _error(ex, ref), (_error(im, ref), _error(ex, ref))


@pytest.mark.parametrize("exchange", ["implicit", "explicit"])
def test_a_tolerance_run_on_a_ring_of_32_completes(fmu, exchange):
    """tol = 1e-3: 0.6.0's implicit run diverged at t = 0.007, right after the first shortened
    step (the quasi-Newton history of another step length); each FMU's secant now belongs to
    one step length."""
    N, T = 32, 1.0
    xs = _starts(N)
    r = cosimulate_network(fmu, xs, ring(N), T, 0.01, "euclidean", **GAINS, exchange=exchange, tol=1e-3)
    assert r.success and r.t[-1] == pytest.approx(T)
    assert np.all(np.isfinite(r.q)) and np.abs(r.q).max() < 10.0
    if exchange == "implicit":
        it = r.info["iterations"]
        assert np.median(it) <= 3 and it.max() <= 6, (np.median(it), it.max())
        ref = simulate_network(ImpactOscillator(**RING), xs, ring(N), T, 1e-3, "euclidean", **GAINS)
        assert _error(r, ref) <= 0.02


# ------------------------------------------------------------ the per-FMU secants (cosim_newton)
from hypothesis import given, settings, strategies as st  # noqa: E402


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 2), h=st.sampled_from([0.01, 0.002]), foh=st.booleans(), seed=st.integers(0, 10**6))
def test_each_fmus_secant_is_its_own_response_and_is_forgotten_at_an_impact(n, h, foh, seed):
    """Linear FMU responses x_i = x0_i + R_i te_i (R_i random, 2n x n): after iterates with the
    same impact count Broyden's J_i satisfies the secant equation of the last iterate (for n = 1:
    J_i = R_i exactly); an FMU whose impact count moves takes the free-mass prior (dq/dte =
    h^2 M^-1/4 for the mean, /6 for the line, du/dte = h M^-1/2) or, once one was measured without
    impact, that response; another h forgets everything."""
    from fmu_sync.cosim_newton import MEASURED, PRIOR, newton_work, secants, step_start
    g = np.random.default_rng(seed)
    N = 3
    Minv = np.stack([np.linalg.inv(np.eye(n) * g.uniform(0.5, 2.0)) for _ in range(N)])
    nw = newton_work(N, n, np.zeros(1, dtype=np.int32), Minv)
    J, jimp, jkn, imp0, impc = nw[0], nw[1], nw[2], nw[5], nw[6]
    R = g.normal(size=(N, 2 * n, n))
    x0 = g.normal(size=(N, 2 * n))
    step_start(nw, h, foh)
    te = np.zeros((N, n))
    for it in range(1, 4):
        te = g.normal(size=(N, n))
        x = x0 + np.einsum("iab,ib->ia", R, te)
        secants(nw, te, np.ascontiguousarray(x[:, :n]), np.ascontiguousarray(x[:, n:]), it)
    assert np.all(jkn == MEASURED)
    if n == 1:
        np.testing.assert_allclose(J, R, rtol=1e-9, atol=1e-12)
    measured = J[0].copy()
    impc[1] += 1   # FMU 1 hits its wall in the next iterate
    te2 = te + g.normal(size=(N, n))
    x = x0 + np.einsum("iab,ib->ia", R, te2)
    secants(nw, te2, np.ascontiguousarray(x[:, :n]), np.ascontiguousarray(x[:, n:]), 4)
    assert jkn[1] == PRIOR and jimp[1] == 1
    np.testing.assert_allclose(J[1], J[0])   # the response just measured without impact (FMU 0's)
    assert not np.allclose(J[1], R[1]) or n > 1
    step_start(nw, h / 2, foh)   # another h: nothing kept, the free-mass prior
    impc[:] = imp0
    secants(nw, te2, np.ascontiguousarray(x[:, :n]), np.ascontiguousarray(x[:, n:]), 1)
    cq = (h / 2) ** 2 / (6.0 if foh else 4.0)
    np.testing.assert_allclose(J[:, :n, :], cq * Minv)
    np.testing.assert_allclose(J[:, n:, :], 0.5 * (h / 2) * Minv)
    assert np.all(jkn == PRIOR) and measured.shape == (2 * n, n)
