"""Networks of systems that differ in M, w, g0 and e (issue 42): they run where the coupling law
allows it (Euclidean, uncoupled), checked against scipy's DOP853; the quotient laws refuse them
before the first step, naming the quantity, the systems, their values and the reason."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from fmu_sync.core.model import ImpactOscillator
from fmu_sync.core.network import ring, simulate_network
from fmu_sync.core.pair import simulate_pair

# the ring of issue 42: masses 1, 2, 0.5; k = 1, c = 0, f0 = 0.2, F = 0.5, Omega = 2.5, the wall far away
MASSES = (1.0, 2.0, 0.5)
X = [(1.0, 0.0), (-0.5, 0.3), (0.2, -0.4)]
KP, KD = 200.0, 1.0
T_END = 4.0


def oscillator(m, **kw):
    return ImpactOscillator(**{**dict(m=m, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, g0=100.0), **kw})


def dop853(masses, A, x, t_end, Kp=KP, Kd=KD):
    """The smooth reference (no contact: the wall is 100 away): the linear ODE by DOP853."""
    m, N = np.asarray(masses), len(masses)

    def rhs(t, y):
        q, u = y[:N], y[N:]
        tau = np.array([sum(A[i, j] * (-Kp * (q[i] - q[j]) - Kd * (u[i] - u[j])) for j in range(N))
                        for i in range(N)])
        return np.concatenate([u, (0.2 + 0.5 * np.cos(2.5 * t) - q + tau) / m])
    y0 = np.array([p[0] for p in x] + [p[1] for p in x])
    return solve_ivp(rhs, (0.0, t_end), y0, method="DOP853", rtol=1e-10, atol=1e-12, dense_output=True).sol


def test_core_ring_of_unequal_masses_follows_dop853_and_records_the_euclidean_error():
    A = ring(3)
    r = simulate_network([oscillator(m) for m in MASSES], X, A, T_END, 1e-3, coupling="euclidean", Kp=KP, Kd=KD,
                         record_every=10)
    ref = dop853(MASSES, A, X, T_END)(r.t)
    assert np.max(np.abs(r.q[:, :, 0] - ref[:3].T)) < 0.05
    # no common geometry: no d, no V; the Euclidean error in the law's norm, named
    assert r.d is None and r.V is None and r.info["error"] == "euclidean" and not r.info["common_geometry"]
    Q = np.asarray(r.info["Q"], dtype=float).reshape(-1)[0]
    Mbar = np.mean(MASSES)
    dq, du = r.q[:, 0, 0] - r.q[:, 1, 0], r.u[:, 0, 0] - r.u[:, 1, 0]
    np.testing.assert_allclose(r.euclidean[:, 0], np.sqrt(Q * dq ** 2 + Mbar * du ** 2), rtol=1e-12, atol=1e-14)
    # the summary names the measure: the Euclidean error, its final value and decay (no d, no V)
    from fmu_sync import report
    m = report.metrics(r)
    assert m["measure"] == "Euclidean error" and m["final_d"] is None
    assert m["final_euclidean"] == pytest.approx(np.max(r.euclidean[-1]))
    cols, _ = report.record_columns(r)
    assert [c for c, _ in cols] == ["t", "q", "u", "tau", "euclidean"]
    # the implicit exchange (scheme trapezoid) is closer still
    t = simulate_network([oscillator(m) for m in MASSES], X, A, T_END, 1e-3, coupling="euclidean", Kp=KP, Kd=KD,
                         record_every=10, scheme="trapezoid")
    assert np.max(np.abs(t.q[:, :, 0] - ref[:3].T)) < 2e-3


def test_a_pair_of_unequal_masses_and_walls_under_the_euclidean_law():
    s1, s2 = oscillator(1.0, g0=100.0, e=0.9), oscillator(3.0, g0=50.0, e=0.2)
    r = simulate_pair([s1, s2], X[0], X[1], T_END, 1e-3, coupling="euclidean", Kp=KP, Kd=KD,
                      record_distance=False)
    ref = dop853((1.0, 3.0), np.array([[0.0, 1.0], [1.0, 0.0]]), X[:2], T_END)(r.t)
    assert max(np.max(np.abs(r.q1[:, 0] - ref[0])), np.max(np.abs(r.q2[:, 0] - ref[1]))) < 0.05
    with pytest.raises(ValueError, match=r"the distance record is refused: the quotient distance needs one impact "
                       r"map .* M differs: system 1 has M = \[\[1.0\]\], system 2 has M = \[\[3.0\]\]"):
        simulate_pair([s1, s2], X[0], X[1], 1.0, 1e-3, coupling="euclidean", Kp=KP, Kd=KD)


@pytest.mark.parametrize("law", ["switching", "switching-compensated"])
@pytest.mark.parametrize("key,values", [("M", (1.0, 2.0, 0.5)), ("g0", (100.0, 100.0, 3.0)),
                                        ("e", (0.5, 0.9, 0.5))])
def test_quotient_laws_refuse_systems_without_one_impact_map(law, key, values):
    kw = {"M": "m"}.get(key, key)
    nodes = [oscillator(**{"m": 1.0, kw: v}) if kw != "m" else oscillator(v) for v in values]
    shown = [[[v]] if key == "M" else v for v in values]
    msg = (rf"the {law} law is refused: the quotient distance needs one impact map \(equal M, w, g0 and e\), and "
           rf"{key} differs: " + ", ".join(rf"node {i + 1} has {key} = {np.asarray(v).tolist()}"
                                           for i, v in enumerate(shown)).replace("[", r"\[").replace("]", r"\]"))
    with pytest.raises(ValueError, match=msg):
        simulate_network(nodes, X, ring(3), 1.0, 1e-3, coupling=law, Kp=1.0, Kd=1.0)
    with pytest.raises(ValueError, match=r"the distance record is refused"):
        simulate_network(nodes, X, ring(3), 1.0, 1e-3, coupling="euclidean", Kp=1.0, Kd=1.0, record_distance=True)
    r = simulate_network(nodes, X, ring(3), 0.1, 1e-3, coupling="none")   # uncoupled: runs, the error recorded
    assert r.d is None and r.euclidean.shape == (r.t.size, 3)


def test_equal_systems_keep_the_quotient_distance():
    r = simulate_network([oscillator(1.0)] * 3, X, ring(3), 0.5, 1e-3, coupling="euclidean", Kp=KP, Kd=KD)
    assert r.d is not None and r.V is not None and r.info["common_geometry"] and "error" not in r.info


def test_master_ring_of_unequal_masses_follows_dop853(shared_fmu):
    from fmu_sync.master import cosimulate_network
    fmu = shared_fmu()
    A = ring(3)
    sv = [dict(m=m, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, g0=100.0) for m in MASSES]
    r = cosimulate_network(fmu, X, A, T_END, 0.01, coupling="euclidean", Kp=KP, Kd=KD, start_values=sv,
                           exchange="implicit")
    ref = dop853(MASSES, A, X, T_END)(r.t)
    assert np.max(np.abs(r.q[:, :, 0] - ref[:3].T)) < 0.05
    assert r.d is None and r.V is None and r.info["error"] == "euclidean" and r.euclidean.shape == (r.t.size, 3)
    with pytest.raises(ValueError, match=r"the switching law is refused: the quotient distance needs one impact map "
                       r".*M differs: instance 1 has M = \[\[1.0\]\], instance 2 has M = \[\[2.0\]\]"):
        cosimulate_network(fmu, X, A, 1.0, 0.01, coupling="switching", Kp=1.0, Kd=1.0, start_values=sv)


SCENE = """description = "ring of unequal masses"
[system]
model = "impact-oscillator"
m = 1.0
k = 1.0
f0 = 0.2
F = 0.5
Omega = 2.5
g0 = 100.0
e = 0.5
[network]
graph = "ring"
states = [[1.0, 0.0], [-0.5, 0.3], [0.2, -0.4]]
nodes = [{}, {m = 2.0}, {m = 0.5}]
[coupling]
law = "euclidean"
Kp = 200.0
Kd = 1.0
[solver]
dt = 1e-3
[run]
t_end = 2.0
record_every = 10
[record]
distance = true
"""


def test_a_scene_gives_per_node_masses_and_its_summary_names_the_euclidean_error(tmp_path):
    from fmu_sync.scenes.loading import load_scene
    from fmu_sync.scenes.running import run_scene
    from fmu_sync.scenes.schema import SceneError
    path = tmp_path / "mixed.toml"
    path.write_text(SCENE)
    (v,) = load_scene(path).variants
    assert [float(s.M[0, 0]) for s in v.network.systems] == list(MASSES)
    sr = run_scene(path, tmp_path / "out", plots=False)
    r = sr.runs[0].result
    ref = dop853(MASSES, ring(3), X, 2.0)(r.t)
    assert r.d is None and np.max(np.abs(r.q[:, :, 0] - ref[:3].T)) < 0.05
    text = next((tmp_path / "out").rglob("summary.md")).read_text()
    assert "no common impact geometry" in text and "Euclidean error" in text
    from fmu_sync.results import load     # the record carries the Euclidean error and reads it back
    files = sorted(f for f in (tmp_path / "out").rglob("*") if f.suffix in (".csv", ".npz"))
    assert {f.suffix for f in files} == {".csv", ".npz"}, files
    for f in files:
        back = load(f)
        assert back.d is None and back.euclidean is not None, f
        np.testing.assert_allclose(back.euclidean.reshape(np.shape(r.euclidean)), r.euclidean, rtol=1e-12, atol=1e-12)
    path.write_text(SCENE.replace('law = "euclidean"', 'law = "switching"'))
    with pytest.raises(SceneError, match=r"the switching law is refused: the quotient distance needs one impact map"
                       r" .*M differs: node 1 has M = \[\[1.0\]\], node 2 has M = \[\[2.0\]\]"):
        load_scene(path)


def test_a_sweep_over_the_mass_ratio_runs_and_equals_simulate_pair():
    from builtin_scenes import FORCED_PAIR, FORCED_X1, FORCED_X2
    from fmu_sync.sweeps import sweep
    ratios = [0.5, 1.0, 3.0]
    ds = sweep("forced-pair", variant="euclidean", grid={"system2.m": ratios}, overrides={"run.t_end": 3.0},
               quiet=True)
    for i, m2 in enumerate(ratios):
        run = ds.isel({"system2.m": i})
        assert int(run["status"]) == 0
        assert float(run["measure"]) == (0.0 if m2 == 1.0 else 1.0)   # d, or the Euclidean error, named
        s1, s2 = ImpactOscillator(**FORCED_PAIR), ImpactOscillator(**{**FORCED_PAIR, "m": m2})
        p = simulate_pair((s1, s2), FORCED_X1, FORCED_X2, 3.0, 1e-3, coupling="euclidean", Kp=1.0, Kd=0.5,
                          record_distance=m2 == 1.0, record_every=10)   # the scenes' scheme: the core's default
        assert float(run["q2"]) == p.q2[-1, 0] and float(run["u2"]) == p.u2[-1, 0]
        assert float(run["q1"]) == p.q1[-1, 0] and int(run["impacts2"]) == p.impacts2


def test_an_ssp_package_carries_per_node_masses_and_runs_in_our_master(tmp_path):
    from fmu_sync.ssp.reader import read_ssp
    from fmu_sync.ssp.runner import run_ssp
    from fmu_sync.ssp.writer import write_ssp
    scene = tmp_path / "mixed.toml"
    scene.write_text(SCENE)
    pkg = write_ssp(scene, tmp_path / "mixed.ssp")
    params = read_ssp(pkg).parameters
    assert [params[f"system{i + 1}"]["m"] for i in range(3)] == list(MASSES)
    r = run_ssp(pkg, t_end=1.0, H=0.001)
    ref = dop853(MASSES, ring(3), X, 1.0)(r.t)
    assert np.max(np.abs(r.q[:, :, 0] - ref[:3].T)) < 0.05
    assert r.d is None and r.info["error"] == "euclidean"
