"""Co-simulation master against the monolithic core (docs/design.md §4.4)."""
import numpy as np
import pytest

from fmu_sync.core import ImpactOscillator
from fmu_sync.core.pair import simulate_pair
from fmu_sync.master import cosimulate

from builtin_scenes import FORCED_GAINS as GAINS
from builtin_scenes import FORCED_PAIR as PAPER
from builtin_scenes import FORCED_X1 as X1
from builtin_scenes import FORCED_X2 as X2


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    from fmu_sync.export import export_fmu
    start = dict(PAPER)
    start["solver.dt"] = 1e-3
    start["solver.scheme"] = "midpoint"   # the explicit exchange reproduces the midpoint core (named on both sides)
    return export_fmu("impact-oscillator", tmp_path_factory.mktemp("fmu") / "osc.fmu", start)


@pytest.fixture(scope="module")
def system():
    return ImpactOscillator(**PAPER)


def test_cosim_with_H_equal_dt_reproduces_the_monolithic_run(fmu, system):
    core = simulate_pair(system, X1, X2, 30.0, 1e-3, coupling="switching", **GAINS, scheme="midpoint")
    cos = cosimulate(fmu, X1, X2, 30.0, 1e-3, coupling="switching", **GAINS)
    assert cos.error is None
    assert np.array_equal(cos.t, core.t)
    assert core.impacts1 > 5
    assert np.max(np.abs(cos.d - core.d)) < 1e-9
    assert np.max(np.abs(cos.q1 - core.q1)) < 1e-9
    assert np.array_equal(cos.branch, core.branch)
    assert (cos.impacts1, cos.impacts2) == (core.impacts1, core.impacts2)


def test_larger_H_error_is_reported_and_sync_still_happens(fmu, system):
    core = simulate_pair(system, X1, X2, 100.0, 1e-3, coupling="switching", record_every=10, **GAINS, scheme="midpoint")
    cos = cosimulate(fmu, X1, X2, 100.0, 1e-2, coupling="switching", **GAINS)
    err = np.max(np.abs(cos.d - core.d))
    # a zero-order hold over 10 internal steps is a real (first-order) error, not round-off
    assert 1e-6 < err < 0.1
    assert cos.time_to_sync(1e-6) < 100.0


def test_uncoupled_cosim_does_not_synchronize(fmu):
    cos = cosimulate(fmu, X1, X2, 100.0, 1e-2, coupling=None)
    assert np.min(cos.d[cos.t > 50]) > 1e-2
    assert np.all(cos.tau1 == 0.0)


def test_gauss_seidel_leaves_an_order_H_residual(fmu):
    # Gauss-Seidel hands system 2 the state of system 1 at t + H: system 2 then tracks
    # system 1 with a time lead of H, so d settles at O(H |x'|) instead of 0
    res = {}
    for H in (1e-2, 5e-3):
        cos = cosimulate(fmu, X1, X2, 100.0, H, coupling="switching", method="gauss-seidel",
                         **GAINS)
        res[H] = np.max(cos.d[cos.t > 80])
    assert res[1e-2] < 0.05
    # measured 6.2e-3 at H = 1e-2 and 4.2e-3 at H = 5e-3: it shrinks with H
    assert res[5e-3] < 0.8 * res[1e-2]


def test_event_aware_stepping_repairs_the_euclidean_law(fmu, system):
    # The Euclidean PD law reacts to the error peak at an impact mismatch; holding that
    # force over a whole communication step kicks the pair apart. Retaking impact steps
    # in pieces of H_min lets the coupling see the impact (measured: max |d - d_core|
    # 9.6e-3 -> 4.4e-3, time to d < 1e-6: 43.0 s -> 26.6 s vs 26.1 s in the core).
    core = simulate_pair(system, X1, X2, 60.0, 1e-3, coupling="euclidean", record_every=10, **GAINS, scheme="midpoint")
    plain = cosimulate(fmu, X1, X2, 60.0, 1e-2, coupling="euclidean", **GAINS)
    aware = cosimulate(fmu, X1, X2, 60.0, 1e-2, coupling="euclidean", event_aware=True,
                       H_min=1e-3, **GAINS)
    assert aware.info["retaken_steps"] > 0 and plain.info["retaken_steps"] == 0
    err_plain = np.max(np.abs(plain.d - core.d))
    err_aware = np.max(np.abs(aware.d - core.d))
    assert err_aware < 0.7 * err_plain
    t_core = core.time_to_sync(1e-6)
    assert abs(aware.time_to_sync(1e-6) - t_core) < abs(plain.time_to_sync(1e-6) - t_core)


def test_unstable_exchange_is_refused_before_the_first_step(fmu):
    from fmu_sync.core.exchange import UnstableExchange
    # the case: Kp = 1e5, Kd = 150, H = 1e-2: omega_c*H = 4.47 > 1.342
    # the systems' own stiffness k = 1 in the map (issue 39.4); the named H is below the limit 0.003
    with pytest.raises(UnstableExchange, match=r"omega_c\*H = 4.472 against the limit 1.342 of the hold map "
                                               r"with the systems' own stiffness .*zeta = 0.3354"
                                               r".*largest stable H = 0.002999\b"):
        cosimulate(fmu, X1, X2, 5.0, 1e-2, coupling="switching", Kp=1e5, Kd=150)


def test_failing_slave_stops_the_run_with_a_complete_record(fmu):
    # an absurd gain (forced past the up-front refusal) makes the explicit exchange blow
    # up: the run stops, raising with the finite record so far (no NaN data passed on)
    from fmu_sync.core import RunFailed
    with pytest.raises(RunFailed) as err:
        cosimulate(fmu, X1, X2, 50.0, 1e-2, coupling="euclidean", Kp=1e9, Kd=0.0, allow_unstable=True)
    res = err.value.partial
    assert res.error is not None and res.error == str(err.value) and not res.success
    # the states diverge, or first the coupling force leaves the FMU's documented input bound
    assert "non-finite at t = " in res.error or "exceeds the FMU's input bound 1e+12" in res.error
    assert "omega_c*H = 447" in res.error
    assert np.all(np.isfinite(res.d))
    assert res.t.size > 1 and res.t[-1] < 50.0
    assert np.all(np.isfinite(res.t)) and np.all(np.isfinite(res.q1))


@pytest.mark.parametrize("kwargs, match", [
    (dict(H=0.0), "H must be a positive finite step, got 0.0"),
    (dict(coupling="magnetic"), "coupling must be one of"),
    (dict(method="newton"), "method must be 'jacobi', 'gauss-seidel', .* or 'early-return', got 'newton'"),
    (dict(x1=(-1.0, 0.0)), "x1"),
])
def test_bad_master_input(fmu, kwargs, match):
    args = dict(x1=X1, x2=X2, t_end=1.0, H=1e-2)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        cosimulate(fmu, **args)


# ------------------------------------------------------------ N instances on a graph
def test_network_disconnected_node_runs_alone_and_pair_matches(fmu, system):
    from fmu_sync.core import simulate
    from fmu_sync.master import cosimulate_network
    x3 = (0.6, -0.2)
    A = [[0, 1, 0], [1, 0, 0], [0, 0, 0]]  # node 3 is not coupled
    net = cosimulate_network(fmu, [X1, X2, x3], A, 20.0, 1e-2, coupling="switching", **GAINS)
    assert net.error is None and net.edges == [(0, 1)]
    alone = simulate(system, x3, 20.0, 1e-3, record_every=10, scheme="midpoint")
    assert np.max(np.abs(net.q[:, 2, 0] - alone.q[:, 0])) < 1e-12
    pair = cosimulate(fmu, X1, X2, 20.0, 1e-2, coupling="switching", **GAINS)
    assert np.array_equal(net.q[:, 0], pair.q1) and np.array_equal(net.d[:, 0], pair.d)


def test_network_ring_synchronizes(fmu):
    from fmu_sync.master import cosimulate_network
    A = [[0, 1, 1], [1, 0, 1], [1, 1, 0]]
    net = cosimulate_network(fmu, [X1, X2, (0.6, -0.2)], A, 100.0, 1e-2, coupling="switching", **GAINS)
    assert len(net.edges) == 3
    assert np.max(net.d[-1]) < 1e-6
    assert net.V[-1] == pytest.approx(0.5 * np.sum(net.d[-1] ** 2))


@pytest.mark.parametrize("A, match", [
    ([[0, 1], [1, 0]], r"N = number of states \(3\)"),
    ([[0, -1, 0], [1, 0, 0], [0, 0, 0]], "finite weights >= 0"),
    ([[1, 1, 0], [1, 0, 0], [0, 0, 0]], "zero diagonal"),
])
def test_network_rejects_bad_weights(fmu, A, match):
    from fmu_sync.master import cosimulate_network
    with pytest.raises(ValueError, match=match):
        cosimulate_network(fmu, [X1, X2, X1], A, 1.0, 1e-2)


# ------------------------------------------------------------ non-identical instances
def test_mismatched_pair_cosim_reproduces_the_core(fmu, system):
    # 5 % stiffness mismatch through per-instance start values: d stays bounded, not 0
    other = ImpactOscillator(**{**PAPER, "k": 1.05})
    core = simulate_pair((system, other), X1, X2, 60.0, 1e-3, coupling="switching", **GAINS, scheme="midpoint")
    cos = cosimulate(fmu, X1, X2, 60.0, 1e-3, coupling="switching", start_values=[{}, {"k": 1.05}],
                     **GAINS)
    assert cos.success
    assert np.max(np.abs(cos.d - core.d)) < 1e-9
    assert np.max(np.abs(cos.q2 - core.q2)) < 1e-9
    m = cos.sync(1e-6)
    assert m.t_sync == np.inf and 1e-4 < m.bound < 0.05 * np.max(cos.d)
    assert m.bound == pytest.approx(core.bound, rel=1e-6)


@pytest.mark.parametrize("values, match", [
    ([{}, {"m": 1.1}], r"M differs: instance 1 has M = \[\[1.0\]\], instance 2 has M = \[\[1.1\]\]"),
    ([{"e": 0.5}, {}], r"e differs: instance 1 has e = 0.5, instance 2 has e = 0.9"),
    ([{}], r"a sequence of N = 2 dicts"),
])
def test_mismatched_instances_are_refused(fmu, values, match):
    with pytest.raises(ValueError, match=match):
        cosimulate(fmu, X1, X2, 1.0, 1e-2, coupling="switching", start_values=values, **GAINS)


# ------------------------------------------------------------ network against the core
RING_X = [(0.2 + 0.9 * (i % 3) / 2, 0.5 * np.sin(1.7 * i)) for i in range(8)]


def test_ring_of_8_cosim_reproduces_the_core_network_and_synchronizes(fmu, system):
    from fmu_sync.core.network import ring, simulate_network
    from fmu_sync.master import cosimulate_network
    kw = dict(coupling="switching", Kp=4.0, Kd=2.0)
    core = simulate_network(system, RING_X, ring(8), 40.0, 1e-2, **kw, scheme="midpoint")
    cos = cosimulate_network(fmu, RING_X, ring(8), 40.0, 1e-2, start_values={"solver.dt": 1e-2}, **kw)
    assert cos.success and cos.edges == core.edges
    assert np.array_equal(cos.t, core.t)
    assert np.max(np.abs(cos.q - core.q)) < 1e-9 and np.max(np.abs(cos.d - core.d)) < 1e-9
    assert np.array_equal(cos.branch, core.branch) and cos.impacts == core.impacts
    assert np.max(np.abs(cos.tau - core.tau)) < 1e-9        # row 0 included: forces at the start
    assert cos.sync(1e-6).t_sync < 40.0 and cos.d_max[-1] < 1e-7


def test_mismatched_network_with_mixed_laws_cosim_reproduces_the_core(fmu):
    from fmu_sync.core.network import simulate_network, star
    from fmu_sync.master import cosimulate_network
    ks = [1.0, 1.05, 0.95, 1.02]
    nodes = [ImpactOscillator(**{**PAPER, "k": k}) for k in ks]
    laws = ["switching", "euclidean", "switching"]          # star edges (0,1), (0,2), (0,3)
    A = star(4)
    A[0, 1] = 0.5                                            # directed weights differ on one edge
    core = simulate_network(nodes, RING_X[:4], A, 20.0, 1e-2, coupling=laws, Kp=2.0, Kd=1.0, scheme="midpoint")
    cos = cosimulate_network(fmu, RING_X[:4], A, 20.0, 1e-2, coupling=laws, Kp=2.0, Kd=1.0,
                             start_values=[{"solver.dt": 1e-2, "k": k} for k in ks])
    assert cos.success
    assert np.max(np.abs(cos.q - core.q)) < 1e-9 and np.max(np.abs(cos.d - core.d)) < 1e-9
    assert np.isfinite(cos.sync().bound) and cos.sync().t_sync == np.inf


def test_an_instance_whose_midpoint_step_diverges_is_refused_before_the_first_step(fmu):
    from fmu_sync.core import UnstableScheme
    # instance 2 gets k = 1e8 with the FMU's dt = 1e-3: omega_max*dt = 10 >= 2
    with pytest.raises(UnstableScheme, match=r"refused before the first step: instance 2: the "
                                                 r"explicit midpoint scheme diverges .*omega_max\*dt = 10"
                                                 ) as err:
        cosimulate(fmu, X1, X2, 1.0, 1e-3, coupling="switching", start_values=[{}, {"k": 1e8}], **GAINS)
    assert isinstance(err.value, ValueError)                # a refusal: nothing ran
