"""One loop for coupled systems (core/loop.py, docs/design.md §2.3): the pair is the 2-node
network, the 1-DOF path inside the loop is the general step bit for bit."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba.core.registry import CPUDispatcher

from fmu_sync.core import ImpactOscillator, MechanicalSystem, moreau
from fmu_sync.core import batch, loop, network, pair
from fmu_sync.core.network import simulate_network
from fmu_sync.core.pair import simulate_pair

PAIR_GRAPH = [[0.0, 1.0], [1.0, 0.0]]


def _system(n, k):
    if n == 1:
        return ImpactOscillator(m=1.0, k=k, c=0.05, f0=0.2, F=0.5, Omega=2.5, e=0.85)
    K = np.array([[2.0 * k, -1.0], [-1.0, 2.0]])
    return MechanicalSystem(M=np.diag([1.0, 2.0]), K=K, C=0.05 * K, w=np.array([1.0, 0.0]), g0=0.3, e=0.8,
                            f0=np.array([0.1, 0.0]), forcing=[(np.array([0.5, 0.2]), 1.7, 0.3)], B=np.eye(2))


@settings(max_examples=12, deadline=None)
@given(n=st.sampled_from([1, 2]), law=st.sampled_from([None, "euclidean", "switching"]),
       scheme=st.sampled_from(["midpoint", "theta"]), k2=st.sampled_from([1.0, 1.4]),
       kp=st.floats(0.2, 2.0), every=st.integers(1, 9), t_end=st.floats(0.5, 3.0),
       x=st.lists(st.floats(0.05, 0.8), min_size=4, max_size=4))
def test_pair_is_the_two_node_network_bitwise(n, law, scheme, k2, kp, every, t_end, x):
    """simulate_pair and simulate_network on the pair graph: the same numbers, bit for bit
    (identical or different systems, both schemes, a shortened last step)."""
    systems = (_system(n, 1.0), _system(n, k2))
    x1 = (np.full(n, x[0]), np.full(n, x[1] - 0.4))
    x2 = (np.full(n, x[2]), np.full(n, x[3] - 0.4))
    kw = dict(Kp=kp, Kd=0.3, scheme=scheme, theta=0.6, record_every=every)
    p = simulate_pair(systems, x1, x2, t_end, 1e-3, coupling=law, **kw)
    net = simulate_network(systems, [x1, x2], PAIR_GRAPH, t_end, 1e-3, coupling=law, **kw)
    assert np.array_equal(p.t, net.t)
    for name, i in (("q", 0), ("u", 1)):
        assert np.array_equal(getattr(p, name + "1"), getattr(net, name)[:, 0])
        assert np.array_equal(getattr(p, name + "2"), getattr(net, name)[:, 1])
    assert np.array_equal(p.tau1, net.tau[:, 0]) and np.array_equal(p.tau2, net.tau[:, 1])
    assert np.array_equal(p.d, net.d[:, 0]) and np.array_equal(p.euclidean, net.euclidean[:, 0])
    assert [p.impacts1, p.impacts2] == net.impacts


@pytest.mark.parametrize("scheme", ["midpoint", "theta"])
def test_the_loops_1dof_path_is_the_general_single_system_step(scheme):
    """Uncoupled 1-DOF nodes of a network (the loop's float path) against the single-system
    general n-DOF kernel, node by node, bit for bit."""
    s = _system(1, 1.0)
    states = [(1.0, 0.0), (0.2, 0.5), (0.6, -0.3)]
    net = simulate_network(s, states, network.ring(3), 4.0, 1e-3, coupling=None, scheme=scheme, theta=0.7,
                           record_distance=False)
    sa = s.arrays()
    code = moreau.SCHEMES[scheme]
    for i, x in enumerate(states):
        rows = net.t.size
        rec = (np.empty(rows), np.empty((rows, 1)), np.empty((rows, 1)), np.empty(rows))
        moreau.integrate(sa, np.array([x[0]]), np.array([x[1]]), 0.0, 1e-3, rows - 1, np.zeros(1), code, 0.7, 1,
                         *rec, False, 0.0)
        assert np.array_equal(rec[1], net.q[:, i]) and np.array_equal(rec[2], net.u[:, i])
        assert net.impacts[i] > 0


def test_no_second_coupled_loop():
    """pair, network and batch compile no step loop of their own: the loop is loop.integrate_network
    (batch keeps its parallel driver and the per-run call into the loop)."""
    def compiled(mod):
        return sorted(k for k, v in vars(mod).items() if isinstance(v, CPUDispatcher) and v.__module__ == mod.__name__)
    assert compiled(pair) == [] and compiled(network) == []
    assert set(compiled(batch)) <= {"run_block", "_pair1", "_node1", "_geo", "_finish_metrics",
                                    "metrics_from_records"}
    assert "integrate_network" in batch._pair1.py_func.__code__.co_names
    assert "integrate_network" in compiled(loop)


def test_the_compiled_loops_never_call_into_python():
    """A kernel that boxes an array it made calls numba's unpickler (Python) on return; a
    pending Ctrl-C or SIGTERM is then raised inside numba's runtime (a SystemError or a
    crash, not a clean KeyboardInterrupt). The loops take their output arrays from the caller."""
    import sys
    from fmu_sync.core import ImpactOscillator, ring, simulate, simulate_network, simulate_pair
    s = ImpactOscillator(m=1.0, k=1.0, c=0.1, F=0.5, Omega=1.3, e=0.8)
    runs = [lambda: simulate_pair(s, (0.5, 0.0), (0.8, 0.1), 2.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5),
            lambda: simulate_network(s, [(0.5, 0.0), (0.8, 0.1), (0.2, 0.3)], ring(3), 2.0, 1e-3, Kp=1.0, Kd=0.5),
            lambda: simulate(s, (0.5, 0.0), 2.0, 1e-3)]
    for run in runs:
        run()                                   # compiled (or loaded from the cache)
    calls = []

    def profile(frame, event, arg):
        if event == "call" and frame.f_code.co_name == "_numba_unpickle":
            calls.append(frame.f_back.f_code.co_filename + f":{frame.f_back.f_lineno}")
    sys.setprofile(profile)
    try:
        for run in runs:
            run()
    finally:
        sys.setprofile(None)
    assert not calls, calls
