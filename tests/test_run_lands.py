"""Every run returns and ends at t_end exactly, with no step shorter than a round-off
(issue 39 item 5, docs/design.md §5.1): the one time rule ``core.checks.TIME_TOL``
(``steps_in``, ``lands``) in the run grid, the tolerance controller and the FMI 3.0
early-return master."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from fmu_sync.core.checks import TIME_TOL, lands, run_steps, steps_in
from fmu_sync.master import cosimulate

# the forced pair of issue 39 (switching law, impacts inside the run)
FORCED = dict(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
X1, X2 = (1.0, 0.0), (0.2, 0.5)
LAW = dict(coupling="switching", Kp=1.0, Kd=0.5)


# ------------------------------------------------------------------ the rule
@settings(max_examples=400, deadline=None)
@given(st.floats(1e-4, 1.0), st.integers(0, 100_000), st.floats(0.0, 1.0))
def test_run_grid_ends_at_t_end_itself(dt, k, frac):
    """run_steps' t_end is the t_end asked for, bit for bit; the last step is a whole step or
    longer than a round-off (never a step of TIME_TOL dt or less)."""
    t_end = (k + frac) * dt
    g = run_steps(t_end, dt)
    assert g.t_end == t_end
    assert g.dt_last == dt or g.dt_last > TIME_TOL * dt
    # the steps span t_end up to the round-off (a run of less than TIME_TOL dt takes no step)
    assert max(g.steps - 1, 0) * dt + (g.dt_last if g.steps else 0.0) == pytest.approx(
        t_end, rel=1e-12, abs=2 * TIME_TOL * dt)   # at most a round-off (TIME_TOL, as measured) apart


def test_the_issue_grids():
    """0.7 / 0.1 and 0.7 / 0.05 ended at 0.7000000000000001 on 0.6.0; 1.05 / 0.1 has a short step."""
    for t_end, dt, steps in ((0.7, 0.1, 7), (0.7, 0.05, 14), (0.3, 0.1, 3), (0.6, 1e-5, 60_000)):
        g = run_steps(t_end, dt)
        assert (g.t_end, g.steps, g.dt_last, g.short) == (t_end, steps, dt, False)
    g = run_steps(1.05, 0.1)
    assert g.steps == 11 and g.short and g.dt_last == pytest.approx(0.05) and g.t_end == 1.05


@settings(max_examples=300, deadline=None)
@given(st.floats(1e-6, 1.0), st.integers(1, 10_000), st.floats(-3.0, 3.0))
def test_lands_and_steps_in_share_the_round_off(unit, m, off):
    """A step that falls short of t_end by less than TIME_TOL unit lands, one short by more does
    not; steps_in counts a rest within TIME_TOL of a step (either side) as no step."""
    assume(abs(abs(off) - 1.0) > 0.05)
    t_end = m * unit
    miss = off * TIME_TOL * unit
    assert lands(t_end - unit - miss, unit, t_end, unit) == (off < 1.0)
    k, short = steps_in((m + 0.3 * off * TIME_TOL) * unit, unit)
    assert (k, short) == (m, False)
    k, short = steps_in((m + 2.0 * abs(off) * TIME_TOL + 1e-6) * unit, unit)
    assert (k, short) == (m, True)


# ------------------------------------------------------------------ the tolerance controller
@pytest.fixture(scope="module")
def fine_fmu(shared_fmu):
    return shared_fmu("impact-oscillator", 2, dict(FORCED, **{"solver.dt": 1e-5}))


def guarded():
    """A progress callback that fails the test when the run stops advancing (0.6.0 looped for
    ever at t = 0.59999 of t_end = 0.6: the test fails instead of hanging)."""
    seen = {"last": -1.0, "same": 0}

    def progress(f):
        seen["same"] = seen["same"] + 1 if f == seen["last"] else 0
        seen["last"] = f
        assert seen["same"] < 50, f"the run stopped advancing at {f} of t_end"
    return progress


def test_tolerance_run_at_the_floor_returns_at_t_end(fine_fmu):
    """The issue's hang: tol = 1e-12 (every step at the floor solver.dt = 1e-5), t_end = 0.6,
    implicit exchange. It returns, ends at 0.6 exactly, every step whole units (no round-off
    step, no unit stretched by one), and they add up to t_end."""
    r = cosimulate(fine_fmu, X1, X2, 0.6, 0.05, tol=1e-12, exchange="implicit", progress=guarded(), **LAW)
    H = r.info["step_lengths"]
    assert r.t[-1] == 0.6 and r.t[-2] < 0.6
    m = H / 1e-5
    assert np.all(np.abs(m - np.round(m)) <= TIME_TOL) and m.min() >= 1 - TIME_TOL, (m.min(), m.max())
    assert r.info["floor_steps"] > 1000   # the case is the floor's
    assert math.isclose(H.sum(), 0.6, rel_tol=1e-12)


def test_tolerance_run_ends_at_t_end_not_beside_it(shared_fmu):
    """t_end = 0.7, H = 0.05 (0.7 / 0.05 is 13.999999999999998 in floating point): the run ended at
    0.7000000000000001 on 0.6.0; now at 0.7, no step shorter than the unit but a real short rest."""
    fmu = shared_fmu("impact-oscillator", 2, dict(FORCED, **{"solver.dt": 1e-4}))
    for t_end in (0.7, 0.70005):
        r = cosimulate(fmu, X1, X2, t_end, 0.05, tol=1e-4, progress=guarded(), **LAW)
        H = r.info["step_lengths"]
        assert r.t[-1] == t_end
        assert H[:-1].min() >= 1e-4 * (1 - 1e-9)
        assert H[-1] > 1e-4 * TIME_TOL
        assert math.isclose(H.sum(), t_end, rel_tol=1e-12)


# ------------------------------------------------------------------ the FMI 3.0 early-return master
def test_early_return_master_ends_at_t_end_with_its_final_state(shared_fmu):
    """t_end = 1.05, H = 0.1: the record ended at 1.1 on 0.6.0. Now the last step is 0.05 and its
    state is the last row; uncoupled, the early stops change nothing, so the FMI 2.0 master's run
    of the same model (which lands on t_end) is the reference, to the FMU's round-off."""
    from fmu_sync.early_return import cosimulate_early_return
    fmu3 = shared_fmu("impact-oscillator", 3, dict(FORCED, **{"solver.dt": 1e-3}))
    fmu2 = shared_fmu("impact-oscillator", 2, dict(FORCED, **{"solver.dt": 1e-3}))
    for every in (1, 4):
        r3 = cosimulate_early_return(fmu3, X1, X2, 1.05, 0.1, record_every=every)
        r2 = cosimulate(fmu2, X1, X2, 1.05, 0.1, record_every=every)
        assert r3.t[-1] == 1.05 and len(r3.t) == len(r2.t)
        np.testing.assert_array_equal(r3.t, r2.t)
        assert np.max(np.abs(r3.q1 - r2.q1)) < 1e-12 and np.max(np.abs(r3.u2 - r2.u2)) < 1e-12


# ------------------------------------------------------------------ fixed-step runs: core and master
OSC = dict(m=1.0, k=1.0, c=0.0, e=0.9, f0=0.2, F=0.5, Omega=2.5)


@pytest.mark.parametrize("t_end, dt", [(0.7, 0.1), (0.3, 0.1), (0.7, 0.05), (1.05, 0.1)])
def test_core_runs_end_at_t_end_itself(t_end, dt):
    """simulate, simulate_pair (whole, with progress chunks, streamed) and simulate_network end at
    t_end bit for bit (0.6.0: 0.7000000000000001 for 0.7 / 0.1), the row before a step earlier."""
    from fmu_sync.core import ImpactOscillator, simulate, simulate_network, simulate_pair
    from fmu_sync.core.network import ring
    o = ImpactOscillator(**OSC)
    law = dict(coupling="euclidean", Kp=1.0, Kd=0.5)
    streamed = []
    runs = [simulate(o, X1, t_end, dt).t,
            simulate_pair(o, X1, X2, t_end, dt, **law).t,
            simulate_pair(o, X1, X2, t_end, dt, progress=lambda f: None, **law).t,
            simulate_network([o] * 3, [X1, X2, X1], ring(3), t_end, dt, **law).t,
            simulate_network([o] * 3, [X1, X2, X1], ring(3), t_end, dt, progress=lambda f: None, **law).t]
    simulate_pair(o, X1, X2, t_end, dt, sink=lambda r: streamed.append(r.t), chunk_rows=2, **law)
    runs.append(np.concatenate(streamed))
    for t in runs:
        assert t[-1] == t_end and 0 < t_end - t[-2] <= dt * (1 + 1e-9)


def test_master_runs_end_at_t_end_itself(shared_fmu):
    """cosimulate and cosimulate_network at t_end = 0.7, H = 0.05 (0.6.0: 0.7000000000000001)."""
    from fmu_sync.core.network import ring
    from fmu_sync.master import cosimulate_network
    fmu = shared_fmu("impact-oscillator", 2, dict(FORCED, **{"solver.dt": 1e-3}))
    r = cosimulate(fmu, X1, X2, 0.7, 0.05, **LAW)
    n = cosimulate_network(fmu, [X1, X2, X1], ring(3), 0.7, 0.05, coupling="euclidean", Kp=1.0, Kd=0.5)
    for t in (r.t, n.t):
        assert t[-1] == 0.7 and len(t) == 15


@pytest.mark.parametrize("mode", ["core", "cosim"])
def test_scene_runs_end_at_t_end_itself(tmp_path, mode):
    """A scene of run.t_end = 0.7 (run.H = 0.05 co-simulated): every variant's record ends at 0.7."""
    from fmu_sync import run_scene
    over = {"run.mode": mode, "run.t_end": 0.7}
    if mode == "cosim":
        over["run.H"] = 0.05
    sr = run_scene("forced-pair", tmp_path, plots=False, overrides=over, variants=["switching", "euclidean"])
    assert len(sr.runs) == 2
    for r in sr.runs:
        assert r.result.t[-1] == 0.7
