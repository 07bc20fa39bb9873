"""Stability criteria of the cheap rows of the stability report (fmu_sync.benchmarks.stability).

Core only (no FMU in the pytest process); the co-simulated rows run in `tests/test_bench.py`
through the CLI in a child process. Every row carries its own stated criterion (`Row.passed`);
these tests assert them and a few facts of the theory the report compares against.
"""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as hst

from fmu_sync.benchmarks import stability as st
from fmu_sync.core import ImpactOscillator, hold_bound, simulate
from fmu_sync.core import UnstableScheme

pytestmark = pytest.mark.stability


def _assert_rows(rows):
    bad = [f"{r.case} / {r.method} / {r.setting}: {r.outcome} ({r.measured}); criterion: {r.criterion}"
           for r in rows if not r.passed]
    assert not bad, "\n".join(bad)


# ------------------------------------------------------------------ stiff wall
def test_stiff_wall_theta_scheme_bounded_for_every_step():
    _assert_rows(st.stiff_wall(dts=(1e-6, 1e-4, 2e-4, 1e-3, 1e-2), t_end=0.05,
                               schemes=(("theta0.5", "theta", 0.5), ("theta1", "theta", 1.0))))


def test_stiff_wall_midpoint_bounded_below_the_limit():
    rows = st.stiff_wall(dts=(1e-6, 1e-5, 1e-4), t_end=0.05, schemes=(("midpoint", "midpoint", 0.5),))
    _assert_rows(rows)
    assert all(r.outcome == "bounded" for r in rows)


def test_stiff_wall_midpoint_divergence_is_an_error_naming_dt_and_omega():
    s = ImpactOscillator(**st.STIFF)
    with pytest.raises(UnstableScheme, match=r"dt = 0\.001.*omega_max\*dt = 10"):
        simulate(s, st.STIFF_X0, 0.2, 1e-3, scheme="midpoint")
    rows = st.stiff_wall(dts=(1e-3,), t_end=0.2, schemes=(("midpoint", "midpoint", 0.5),))
    _assert_rows(rows)
    assert rows[0].outcome == "SimulationDiverged"


def test_stiff_wall_midpoint_never_returns_data_outside_the_energy_bound():
    _assert_rows(st.stiff_wall(dts=(2e-4, 1e-2), t_end=0.2, schemes=(("midpoint", "midpoint", 0.5),)))


def test_stiff_wall_energy_bound_is_that_of_the_initial_state():
    q_b, u_b = st._stiff_bounds()
    m, k, f0 = st.STIFF["m"], st.STIFF["k"], st.STIFF["f0"]
    E0 = 0.5 * k * st.STIFF_X0[0] ** 2 - f0 * st.STIFF_X0[0]
    assert f0 < 0    # the larger root of 1/2 k q^2 - f0 q = E0 lies behind the wall
    assert 0.5 * k * q_b ** 2 - f0 * (-q_b) == pytest.approx(E0, rel=1e-9)
    assert 0.5 * m * u_b ** 2 == pytest.approx(E0 + f0 ** 2 / (2 * k), rel=1e-12)


# ------------------------------------------------------------------ e = 0, e = 1
def test_restitution_limits():
    rows = st.restitution_limits(n_impacts=1000)
    _assert_rows(rows)
    mid = [r for r in rows if r.case.startswith("e=1 bouncing") and r.method == "midpoint"][0]
    assert mid.value <= 1e-12          # the midpoint conserves the elastic ball's energy to round-off


# ------------------------------------------------------------------ Zeno
def test_zeno_rest_time_error_bound():
    rows = st.zeno_rest_times(dts=(1e-3,))
    _assert_rows(rows)
    assert {r.method for r in rows} == {"exact", "midpoint"}


# ------------------------------------------------------------------ grazing
def test_grazing():
    rows = st.grazing(dts=(1e-3,), t_end=20.0)
    _assert_rows(rows)
    assert rows[0].method == "exact" and rows[0].value == 2


# ------------------------------------------------------------------ coupling gains
@pytest.mark.parametrize("zeta", [0.1, st.ZETA, 0.5, 0.8, 1.0])
def test_zoh_limit_is_the_spectral_radius_crossing(zeta):
    h = hold_bound(zeta)                 # the core's bound, against the report's own ZOH matrix
    assert st.zoh_limit(zeta) == h
    assert st.zoh_rho(0.99 * h, zeta) < 1.0 < st.zoh_rho(1.01 * h, zeta)
    assert h <= 2.0 + 1e-12


def test_zoh_without_damping_is_unstable_for_every_step():
    for h in (1e-3, 0.1, 1.0, 1.9):
        assert st.zoh_rho(h, 0.0) == pytest.approx(math.sqrt(1 + h * h / 2), rel=1e-12)


def test_gauss_seidel_map_grows_for_every_step():
    for h in (0.01, 0.1, 0.5, 1.0, 2.0):
        assert st.gauss_seidel_rho(h, st.ZETA) > 1.0
    for h in (0.01, 0.1, 0.5):
        assert st.gauss_seidel_rho(h, st.ZETA) - 1.0 == pytest.approx(h * h / 4, rel=0.15)


def test_coupling_limit_monolithic_matches_theory():
    rows = st.coupling_gains(kps=(1e-2, 1.0, 1e6), fmu=None, n_steps=200, iters=8)
    _assert_rows(rows)
    limits = [r.value for r in rows if r.measured.startswith("ω_c dt*")]
    assert len(limits) == 3
    assert np.ptp(limits) < 1e-9       # the limit scales exactly with 1/omega_c


# ------------------------------------------------------------------ scales, large steps
def test_scale_invariance():
    _assert_rows(st.scale_invariance(fmu=None))


def test_step_larger_than_the_forcing_period():
    # long enough for the unstable midpoint runs (omega_max*dt = 3, 7) to overflow: over 500 s
    # they end near 1e138 while still finite and are returned without an error (see the
    rows = st.large_step(dts=(3.0, 7.0), t_end=2000.0)
    _assert_rows(rows)
    mids = [r for r in rows if r.method == "midpoint" and r.case.startswith("paper")]
    assert all(r.outcome == "SimulationDiverged" for r in mids)   # omega_max*dt = 3, 7 > 2


@settings(max_examples=40, deadline=None)
@given(n=hst.integers(1, 6), scale=hst.floats(1e-3, 50.0), seed=hst.integers(0, 2**32 - 1))
def test_our_matrix_exponential_is_scipys(n, scale, seed):
    """core.exchange.expm (numpy only: the master's stability bound with the systems' own stiffness
    runs without scipy, a test extra) against scipy.linalg.expm."""
    import scipy.linalg as sl

    from fmu_sync.core.exchange import expm
    A = np.random.default_rng(seed).normal(size=(n, n)) * scale
    ref = sl.expm(A)
    assert np.max(np.abs(expm(A) - ref)) <= 1e-11 * max(1.0, np.max(np.abs(ref)))


def test_the_held_flow_map_needs_no_scipy():
    """The numba-range smoke (0.7.0 on numba 0.64) found the master importing scipy for the bound."""
    import subprocess
    import sys
    code = ("import sys; sys.modules['scipy'] = None\n"
            "import numpy as np\n"
            "from fmu_sync.core.exchange import hold_map_radius\n"
            "r = hold_map_radius(np.eye(1) * 2.0, np.eye(1) * 0.2, 0.1, 'foh', 'implicit', own=(np.eye(1), np.eye(1) * 0.1))\n"
            "print(r)")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and 0.0 < float(p.stdout) < 1.0, p.stderr
