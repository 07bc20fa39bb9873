"""Runs end exactly at t_end, the final state is the last record, and the API refuses
what cannot be held or measured (issue 16, runs): docs/design.md §5.1."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fmu_sync.core import ImpactOscillator, MechanicalSystem, quotient_distance, simulate, simulate_network, \
    simulate_pair
from fmu_sync.core import checks
from fmu_sync.core.checks import InadmissibleState, RecordTooLarge, record_rows, run_steps
from fmu_sync.core.moreau import SCHEMES, advance
from fmu_sync.core.network import ring

OSC = ImpactOscillator(m=1.0, k=4.0, c=0.1, e=0.7, F=0.5, Omega=1.3, f0=-0.2)
SYS2 = MechanicalSystem(M=np.eye(2), K=np.array([[2.0, -1.0], [-1.0, 2.0]]), C=0.05 * np.eye(2), w=[1.0, 0.5],
                        e=0.8, f0=[-0.1, 0.0])


# ------------------------------------------------------------------ the step grid
@settings(max_examples=300, deadline=None)
@given(st.floats(1e-4, 1.0), st.integers(0, 10_000), st.floats(0.0, 1.0))
def test_step_grid_ends_at_t_end(dt, k, frac):
    """steps of dt and one shortened last step add up to t_end; a multiple of dt has none."""
    t_end = (k + frac) * dt
    g = run_steps(t_end, dt)
    full = g.steps - 1 if g.short else g.steps
    if g.short:
        assert 0.0 < g.dt_last < dt * (1 + 1e-9)
        assert (full * dt) + g.dt_last == pytest.approx(t_end, rel=1e-15, abs=1e-300)
    else:
        assert g.dt_last == dt
        assert abs(g.steps * dt - t_end) <= 1e-9 * dt + 1e-15 * t_end


def test_multiple_of_the_step_has_no_short_step():
    assert run_steps(10.0, 1e-3) == (1e-3, 10_000, 1e-3, 10_000 * 1e-3)
    assert run_steps(1.0, 0.3).steps == 4 and run_steps(1.0, 0.3).dt_last == pytest.approx(0.1)
    assert record_rows(3334, 7) == 478 and record_rows(10, 5) == 3 and record_rows(0, 3) == 1


# ------------------------------------------------------------------ single system
@pytest.mark.parametrize("scheme", ["midpoint", "theta"])
@pytest.mark.parametrize("system, x0", [(OSC, (1.0, 0.0)), (SYS2, ([1.0, 0.5], [0.0, 0.0]))])
def test_simulate_ends_at_t_end_on_the_advance_arithmetic(scheme, system, x0):
    """simulate(t_end=1, dt=0.3): rows 0, .3, .6, .9, 1; the final state is advance()'s
    (the FMU's communication step, whose last internal step is shortened the same way)."""
    r = simulate(system, x0, t_end=1.0, dt=0.3, scheme=scheme, theta=0.6, phasor=False)
    assert r.t.tolist() == pytest.approx([0.0, 0.3, 0.6, 0.9, 1.0], abs=1e-15) and r.t[-1] == 1.0
    q, u = (np.array(v, dtype=float).reshape(-1) for v in x0)
    status, P, _ = advance(system.arrays(), q, u, 0.0, 1.0, 0.3, np.zeros(system.n_inputs), SCHEMES[scheme], 0.6,
                           None, False)
    assert status == 0
    assert np.array_equal(r.q[-1], q) and np.array_equal(r.u[-1], u)


@pytest.mark.parametrize("phasor", [True, False])
def test_record_every_not_dividing_keeps_the_final_state(phasor):
    """t_end = 10, dt = 0.003, record_every = 7 (issue 16): the last record is at 10, and the
    rows before it are those of the run recorded at every step (same arithmetic)."""
    r = simulate(OSC, (1.0, 0.0), t_end=10.0, dt=0.003, record_every=7, phasor=phasor)
    every = simulate(OSC, (1.0, 0.0), t_end=10.0, dt=0.003, record_every=1, phasor=phasor)
    assert r.t[-1] == 10.0 and every.t[-1] == 10.0
    assert r.t.size == record_rows(3334, 7)
    assert np.array_equal(r.q[-1], every.q[-1]) and np.array_equal(r.u[-1], every.u[-1])
    if not phasor:   # the phasor re-synchronises on record blocks: within 1e-13, not bitwise
        assert np.array_equal(r.q[:-1], every.q[:-1:7])
    else:
        assert np.allclose(r.q[:-1], every.q[:-1:7], rtol=0, atol=1e-11)
    # the percussion of the last, shorter record interval is the sum over its steps
    assert r.percussion[-1] == pytest.approx(every.percussion[-(3334 - 7 * (3334 // 7)):].sum(), abs=1e-12)


@pytest.mark.parametrize("scheme", ["midpoint", "theta"])
def test_multiple_of_the_step_is_a_prefix_of_a_longer_run_bitwise(scheme):
    """Where t_end is a multiple of dt nothing changes: the run is bit for bit the prefix
    of a longer run (no extra step, no extra row), and so is a shortened run's."""
    short = simulate(OSC, (1.0, 0.0), t_end=5.0, dt=1e-3, scheme=scheme, theta=0.6, record_every=10)
    long = simulate(OSC, (1.0, 0.0), t_end=7.0, dt=1e-3, scheme=scheme, theta=0.6, record_every=10)
    odd = simulate(OSC, (1.0, 0.0), t_end=5.0037, dt=1e-3, scheme=scheme, theta=0.6, record_every=10)
    k = short.t.size
    assert k == 501 and short.t[-1] == 5.0
    for a in ("t", "q", "u", "percussion"):
        assert np.array_equal(getattr(short, a), getattr(long, a)[:k])
        assert np.array_equal(getattr(short, a), getattr(odd, a)[:k])
    assert odd.t[-1] == 5.0037 and odd.t.size == k + 1


def test_exact_solver_samples_t_end():
    r = simulate(OSC, (1.0, 0.0), t_end=1.0, dt=0.3, scheme="exact")
    assert r.t.tolist() == pytest.approx([0.0, 0.3, 0.6, 0.9, 1.0]) and r.t[-1] == 1.0
    ref = simulate(OSC, (1.0, 0.0), t_end=1.0, dt=0.1, scheme="exact")
    assert r.q[-1, 0] == pytest.approx(ref.q[-1, 0], abs=1e-12)


# ------------------------------------------------------------------ pair and network
@pytest.mark.parametrize("scheme", ["midpoint", "theta"])
@pytest.mark.parametrize("system", [OSC, SYS2])
def test_pair_ends_at_t_end_and_equals_the_fine_grid_run(scheme, system):
    """The shortened last step of a pair: held forces from the states at its start; the
    whole run equals a run with a step that divides t_end where the two grids agree, and
    the final state is the one of the same steps taken one by one (record_every=1)."""
    n = system.n
    x1 = (np.full(n, 1.0), np.zeros(n))
    x2 = (np.full(n, 0.4), np.full(n, 0.2))
    kw = dict(coupling="switching", Kp=1.0, Kd=0.5, scheme=scheme, theta=0.6)
    r = simulate_pair(system, x1, x2, t_end=2.0005, dt=1e-3, record_every=7, **kw)
    one = simulate_pair(system, x1, x2, t_end=2.0005, dt=1e-3, record_every=1, **kw)
    assert r.t[-1] == 2.0005 and one.t[-1] == 2.0005 and r.t[-2] == pytest.approx(1.995)
    assert r.t.size == record_rows(2001, 7) and one.t.size == 2002
    for a in ("q1", "u1", "q2", "u2", "d"):
        assert np.array_equal(getattr(r, a)[-1], getattr(one, a)[-1])
        assert np.array_equal(getattr(r, a)[:-1], getattr(one, a)[:-1:7])
    # the forces held over the last (shortened) step are those at its start
    assert np.array_equal(r.tau1[-1], one.tau1[-1])
    plain = simulate_pair(system, x1, x2, t_end=2.0, dt=1e-3, record_every=1, **kw)
    for a in ("t", "q1", "u1", "q2", "u2", "tau1", "tau2", "d"):
        assert np.array_equal(getattr(plain, a), getattr(one, a)[:-1])


def test_pair_chunked_streamed_and_progress_runs_are_the_same():
    kw = dict(coupling="switching", Kp=1.0, Kd=0.5, record_every=3)
    ref = simulate_pair(OSC, (1.0, 0.0), (0.3, 0.1), 3.0001, 1e-3, **kw)
    prog = simulate_pair(OSC, (1.0, 0.0), (0.3, 0.1), 3.0001, 1e-3, progress=lambda f: None, **kw)
    chunks = []
    last = simulate_pair(OSC, (1.0, 0.0), (0.3, 0.1), 3.0001, 1e-3, sink=chunks.append, chunk_rows=50, **kw)
    t = np.concatenate([c.t for c in chunks])
    q1 = np.concatenate([c.q1 for c in chunks])
    assert ref.t[-1] == 3.0001 and np.array_equal(t, ref.t) and np.array_equal(q1, ref.q1)
    assert np.array_equal(prog.q1, ref.q1) and np.array_equal(prog.t, ref.t)
    assert last.t[-1] == 3.0001 and last.info["rows"] == ref.t.size


@pytest.mark.parametrize("scheme", ["midpoint", "theta"])
def test_network_ends_at_t_end(scheme):
    states = [(1.0, 0.0), (0.5, 0.1), (0.2, -0.1)]
    kw = dict(coupling="switching", Kp=1.0, Kd=0.5, scheme=scheme, theta=0.6)
    r = simulate_network(OSC, states, ring(3), t_end=1.0, dt=0.3, **kw)
    assert r.t.tolist() == pytest.approx([0.0, 0.3, 0.6, 0.9, 1.0]) and r.t[-1] == 1.0
    # a 2-node network is the pair
    p = simulate_pair(OSC, states[0], states[1], t_end=1.0, dt=0.3, **kw)
    net2 = simulate_network(OSC, states[:2], [[0, 1], [1, 0]], t_end=1.0, dt=0.3, **kw)
    assert np.allclose(net2.q[:, 0, 0], p.q1[:, 0], rtol=0, atol=1e-13)
    assert np.allclose(net2.q[:, 1, 0], p.q2[:, 0], rtol=0, atol=1e-13) and net2.t[-1] == p.t[-1] == 1.0
    every = simulate_network(OSC, states, ring(3), t_end=10.0, dt=0.003, record_every=7, **kw)
    assert every.t[-1] == 10.0


# ------------------------------------------------------------------ API refusals
def test_api_refuses_an_oversized_record_before_allocating():
    """simulate_pair(t_end=1e6, dt=1e-6) raised numpy's MemoryError: now a ValueError
    naming the size, raised before anything is allocated (no MemoryError possible)."""
    with pytest.raises(RecordTooLarge, match=r"1e\+12 rows x 10 values = 7.451e\+04 GiB"):
        simulate_pair(OSC, (1.0, 0.0), (0.5, 0.0), t_end=1e6, dt=1e-6, coupling="switching", Kp=1, Kd=1)
    with pytest.raises(ValueError, match="rows"):
        simulate(OSC, (1.0, 0.0), t_end=1e6, dt=1e-7)
    with pytest.raises(ValueError, match="rows"):
        simulate_network(OSC, [(1, 0), (0.5, 0)], [[0, 1], [1, 0]], t_end=1e6, dt=1e-7, coupling=None)
    with pytest.raises(ValueError, match="rows"):
        simulate(OSC, (1.0, 0.0), t_end=1e6, dt=1e-7, scheme="exact")
    # the same run streamed to a sink, or recorded sparsely, is not refused
    r = simulate_pair(OSC, (1.0, 0.0), (0.5, 0.0), t_end=1.0, dt=1e-6, record_every=100_000)
    assert r.t[-1] == 1.0 and r.t.size == 11


def test_record_budget_is_the_machine_memory(monkeypatch):
    monkeypatch.setattr(checks, "record_budget", lambda: 100)
    with pytest.raises(RecordTooLarge, match="11 rows x 4 values"):
        simulate(OSC, (1.0, 0.0), t_end=1.0, dt=0.1)   # 11 rows x 4 values x 8 B = 352 B > 100 B
    assert simulate(OSC, (1.0, 0.0), t_end=0.2, dt=0.1).t.size == 3   # 96 B


def test_distance_refuses_inadmissible_states():
    with pytest.raises(InadmissibleState, match=r"x1 is not an admissible state: g\(q\) .* = -1 < 0"):
        quotient_distance(OSC, (-1.0, 0.0), (1.0, 0.0))
    with pytest.raises(ValueError, match="x2 is not an admissible state"):
        quotient_distance(SYS2, ([0.0, 0.0], [0.0, 0.0]), ([-1.0, 0.5], [0.0, 0.0]))
    # on the wall up to round-off is admissible: the distance is continuous there
    assert quotient_distance(OSC, (-1e-12, 0.0), (1.0, 0.0)) == pytest.approx(1.0, abs=1e-11)
    assert quotient_distance(OSC, (0.0, -1.0), (0.0, 0.7)) == 0.0


@settings(max_examples=200, deadline=None)
@given(st.floats(-10, 10), st.floats(-10, 10), st.floats(-5, 5))
def test_distance_admissibility_is_the_sign_of_the_gap(q1, q2, u):
    g = min(q1, q2)
    if g < -checks.GAP_TOL * max(1.0, abs(q1), abs(q2)):
        with pytest.raises(InadmissibleState):
            quotient_distance(OSC, (q1, u), (q2, -u))
    else:
        assert quotient_distance(OSC, (q1, u), (q2, -u)) >= 0.0


# ------------------------------------------------------------------ co-simulation
@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    from builtin_scenes import FORCED_PAIR
    from fmu_sync.export import export_fmu
    return export_fmu("impact-oscillator", tmp_path_factory.mktemp("fmu") / "osc.fmu",
                      {**FORCED_PAIR, "solver.dt": 1e-3, "solver.scheme": "midpoint"})   # the explicit exchange's core


def test_cosimulation_ends_at_t_end_with_the_core_numbers(fmu):
    """The master's last communication step is shortened (the slave's doStep shortens its
    own internal step the same way): with H = dt it is the core pair to round-off."""
    from builtin_scenes import FORCED_GAINS, FORCED_PAIR, FORCED_X1, FORCED_X2
    from fmu_sync.master import cosimulate
    system = ImpactOscillator(**FORCED_PAIR)
    kw = dict(coupling="switching", record_every=7, **FORCED_GAINS)
    core = simulate_pair(system, FORCED_X1, FORCED_X2, 3.0005, 1e-3, scheme="midpoint", **kw)
    cos = cosimulate(fmu, FORCED_X1, FORCED_X2, 3.0005, 1e-3, **kw)
    assert cos.error is None and cos.t[-1] == core.t[-1] == 3.0005
    assert np.array_equal(cos.t, core.t)
    assert np.max(np.abs(cos.q1 - core.q1)) < 1e-9 and np.max(np.abs(cos.d - core.d)) < 1e-9
    coarse = cosimulate(fmu, FORCED_X1, FORCED_X2, 1.0, 0.3, **FORCED_GAINS)
    assert coarse.t.tolist() == pytest.approx([0.0, 0.3, 0.6, 0.9, 1.0]) and coarse.t[-1] == 1.0
