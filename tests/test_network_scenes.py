"""Networks and non-identical systems in scenes and the CLI: the [network] table, the
built-in ring-8 (synchronizes under the switching law, core and co-simulated) and
mismatched-pair (bounded d, its ultimate bound) scenes."""
import json
import math

import numpy as np
import pytest

from fmu_sync import SceneError, load_scene, run_scene
from fmu_sync.core import ImpactOscillator, ring, simulate_network, simulate_pair
from fmu_sync.core.network import edges_of

from test_cli import run_cli


def write(tmp_path, text, name="net.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


NET = """description = "net"
[system]
model = "impact-oscillator"
k = 1.0
f0 = 0.2
F = 0.5
Omega = 2.5
e = 0.9
[network]
graph = "ring"
states = [[1.0, 0.0], [0.2, 0.5], [0.6, -0.3], [0.9, 0.4]]
[coupling]
law = "switching"
Kp = 1.0
Kd = 0.5
[run]
t_end = 2.0
"""


def test_ring8_scene_is_a_ring_of_8():
    (v,) = load_scene("ring-8").variants
    spec = v.network
    assert spec.N == 8 and spec.graph == "ring"
    assert np.array_equal(spec.A, ring(8)) and len(edges_of(spec.A)) == 8
    assert all(s is v.system for s in spec.systems) and v.law == "switching"


def test_ring8_core_synchronizes_from_the_scene(tmp_path):
    sr = run_scene("ring-8", tmp_path)
    (run,) = sr.runs
    r, m = run.result, run.metrics
    assert r.d.shape[1] == 8 and m["kind"] == "network" and m["N"] == 8
    assert m["final_d"] < 1e-8 and np.isfinite(m["t_sync"]) and m["t_sync"] < 0.9 * m["t_end"]
    assert m["rate"] > 0 and m["rate_resolved"] and m["rate_err"] < 0.2 * m["rate"]
    # issue 25: within 15 % of an independent estimate, the average decay of the running maximum of
    # max d from the end between 1e-2 and 1e-12 of its maximum (measured: 0.5587 against 0.549)
    env = np.maximum.accumulate(r.d_max[::-1])[::-1]
    t_a, t_b = r.t[np.argmax(env <= 1e-2 * env[0])], r.t[np.argmax(env <= 1e-12 * env[0])]
    assert env[-1] <= 1e-12 * env[0] and m["rate"] == pytest.approx(math.log(1e10) / (t_b - t_a), rel=0.15)
    # the scene runs exactly simulate_network with the scene's numbers (an independent call)
    cfg = run.variant.cfg
    ref = simulate_network(run.variant.system, list(run.variant.network.states), ring(8), cfg["run.t_end"],
                           cfg["solver.dt"], coupling="switching", Kp=cfg["coupling.Kp"], Kd=cfg["coupling.Kd"],
                           record_every=cfg["run.record_every"], scheme=cfg["solver.scheme"])
    assert np.array_equal(ref.d, r.d)
    for name in ("ring-8.csv", "ring-8.npz", "ring-8-distance.png", "ring-8-positions.png", "summary.md"):
        assert (tmp_path / name).stat().st_size > 0, name
    npz = np.load(tmp_path / "ring-8.npz")
    assert npz["q"].shape == (len(r.t), 8) and np.array_equal(npz["d_max"], r.d_max)


def test_ring8_cosim_reproduces_the_core_at_H_equal_dt(tmp_path):
    # the scene's default scheme (the trapezoid: the coupling inside the step) in both modes: the
    # implicit exchange at H = solver.dt reproduces it (issue 40.5; measured 1.3e-14)
    over = {"run.t_end": 1.5, "run.record_every": 1}   # run.H only where it does something (issue 44.4)
    core = run_scene("ring-8", tmp_path / "core", overrides=over, plots=False).runs[0].result
    co = run_scene("ring-8", tmp_path / "co", overrides={**over, "run.mode": "cosim", "run.H": 1e-3,
                                                         "run.exchange": "implicit"}, plots=False).runs[0].result
    assert co.d.shape == core.d.shape
    assert np.max(np.abs(co.d - core.d)) < 1e-9 and np.max(np.abs(co.q - core.q)) < 1e-9


def test_ring8_from_the_cli_in_both_modes(tmp_path):
    for mode in ("core", "cosim"):
        out = run_cli(["run", "ring-8", "--set", f"run.mode={mode}", "-o", str(tmp_path / mode), "--format", "npz"],
                      tmp_path, timeout=600)
        assert out.returncode == 0, out.stderr
        line = next(l for l in out.stdout.splitlines() if l.startswith("ring-8"))
        assert "not within" not in line
        d_max = np.load(tmp_path / mode / "ring-8.npz")["d_max"]
        assert d_max[-1] < 1e-6 and d_max[0] > 0.1


def test_mismatched_pair_bounded_with_ultimate_bound(tmp_path):
    sr = run_scene("mismatched-pair", tmp_path, overrides={"run.t_end": 60.0}, plots=False)
    unc, sw = (r.metrics for r in sr.runs)
    assert sr.runs[1].variant.network.systems[1].K[0, 0] == pytest.approx(1.05)
    assert 1e-4 < sw["bound"] < 0.1 and sw["bound"] < 0.2 * unc["bound"]
    # the same pair through simulate_pair (an independent driver): the same bound
    osc = ImpactOscillator(m=1, k=1, c=0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
    stiff = ImpactOscillator(m=1, k=1.05, c=0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
    p = simulate_pair((osc, stiff), (1.0, 0.0), (0.2, 0.5), 60.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5,
                      record_every=10, scheme=sr.runs[1].variant.cfg["solver.scheme"])
    assert sw["bound"] == pytest.approx(p.bound, rel=1e-9)
    text = (tmp_path / "summary.md").read_text()
    assert "ultimate bound" in text


def test_mismatched_pair_cosim_takes_each_instance_its_parameters(tmp_path):
    over = {"run.t_end": 2.0, "run.record_every": 1}
    core = run_scene("mismatched-pair", tmp_path / "a", overrides=over, variants=["switching"], plots=False)
    co = run_scene("mismatched-pair", tmp_path / "b", overrides={**over, "run.mode": "cosim", "run.H": 1e-3,
                                                                 "run.exchange": "implicit"},   # as the default core
                   variants=["switching"], plots=False)
    a, b = core.runs[0].result, co.runs[0].result
    assert np.max(np.abs(a.q - b.q)) < 1e-9
    same = run_scene("mismatched-pair", tmp_path / "c", overrides={**over, "network.nodes": [{}, {}]},
                     variants=["switching"], plots=False).runs[0].result
    assert np.max(np.abs(same.q[:, 1] - a.q[:, 1])) > 1e-6      # node 2's k = 1.05 matters


@pytest.mark.parametrize("edit,needle", [
    (lambda t: t.replace('graph = "ring"', 'graph = "torus"'), "network.graph"),
    (lambda t: t.replace('graph = "ring"', 'graph = "ring"\nnodes = [{}, {e = 0.5}, {}, {}]'),
     r"the switching law is refused: the quotient distance needs one impact map .*e differs: node 1 has e = "),
    (lambda t: t.replace('graph = "ring"', 'graph = "ring"\nnodes = [{}, {}]'), "has 2 tables for 4 nodes"),
    (lambda t: t.replace('graph = "ring"', 'graph = "ring"\nlaws = ["switching"]'), "1 laws for 4 edges"),
    (lambda t: t.replace('graph = "ring"', 'graph = "ring"\nN = 5'), "differs from the number of start states"),
    (lambda t: t.replace('graph = "ring"', 'graph = [[0, 1], [1, 0]]'), "is 2 x 2, there are 4 start states"),
    (lambda t: t.replace("[network]", "[initial]\nx1 = [1.0, 0.0]\n[network]"), "network.states"),
    (lambda t: t.replace('graph = "ring"\n', ""), "needs network.graph"),
    (lambda t: t.replace("[1.0, 0.0], [0.2, 0.5]", "[-1.0, 0.0], [0.2, 0.5]"), "violates the wall"),
])
def test_network_scene_errors_name_the_key(tmp_path, edit, needle):
    with pytest.raises(SceneError, match=needle):
        load_scene(write(tmp_path, edit(NET)))


def test_star_and_matrix_graphs_and_laws_per_edge(tmp_path):
    text = NET.replace('graph = "ring"', 'graph = "star"\ncenter = 2')
    (v,) = load_scene(write(tmp_path, text)).variants
    assert v.network.A[1].sum() == 3 and v.network.A[0, 2] == 0
    A = [[0, 1, 0, 0], [1, 0, 2, 0], [0, 2, 0, 1], [0, 0, 1, 0]]
    text = NET.replace('graph = "ring"', f'graph = {json.dumps(A)}\nlaws = ["switching", "euclidean", "none"]')
    sr = run_scene(load_scene(write(tmp_path, text, "m.toml")), tmp_path / "o", plots=False)
    r = sr.runs[0].result
    assert r.edges == [(0, 1), (1, 2), (2, 3)]
    assert np.all(r.tau[1:, 3] == 0.0)          # node 4 sits on the uncoupled edge only
    assert sr.runs[0].metrics["coupling"].endswith("(per edge)")
