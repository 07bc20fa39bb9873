"""Sweeps: the compiled many-pair engine against single runs, failures as rows, resume, files."""
import json

import numpy as np
import pytest
from builtin_scenes import FORCED_PAIR, FORCED_X1, FORCED_X2

from fmu_sync.core import ImpactOscillator, simulate
from fmu_sync.core.pair import simulate_pair
from fmu_sync.core.steps import DEFAULT_SCHEME
from fmu_sync.report import contact_starts
from fmu_sync.sweeps import SweepSpecError, sweep
from fmu_sync.sweeps.spec import sample_runs
from fmu_sync.sweeps.store import read_dataset

xr = pytest.importorskip("xarray")

FORCED = FORCED_PAIR          # the forced-pair scene's system, read from its TOML
X1, X2 = FORCED_X1, FORCED_X2
SCENE = "forced-pair"
EVERY = 10            # run.record_every of the scene: the metrics' sample grid (checked below)


@pytest.fixture(scope="module")
def gain_map():
    """The 41 x 41 gain map of the coupled pair on the embedded engine (short runs)."""
    return sweep(SCENE, variant="switching", grid={"coupling.Kp": "logspace(-2, 2, 41)",
                                                   "coupling.Kd": "logspace(-2, 2, 41)"},
                 overrides={"run.t_end": 3.0}, quiet=True)


def _single(Kp, Kd, t_end=3.0, dt=1e-3, coupling="switching", every=EVERY, x1=X1, x2=X2, **kw):
    s = ImpactOscillator(**{**FORCED, **kw.pop("system", {})})
    kw.setdefault("scheme", DEFAULT_SCHEME)   # the scenes' default solver.scheme (the core's), which the sweeps run
    return simulate_pair(s, x1, x2, t_end, dt, coupling=coupling, Kp=Kp, Kd=Kd, record_every=every,
                         allow_unstable=kw.pop("allow_unstable", True), **kw)


def _same(ds_run, r):
    """Final state, distances, t_sync and impact counts equal bit for bit."""
    assert ds_run["status"] == 0
    for name, arr in (("q1", r.q1), ("u1", r.u1), ("q2", r.q2), ("u2", r.u2)):
        assert float(ds_run[name]) == arr[-1, 0], name
    assert float(ds_run["d_final"]) == r.d[-1]
    assert float(ds_run["d_max"]) == np.max(r.d)
    assert float(ds_run["d0"]) == r.d[0]
    assert float(ds_run["t_sync"]) == r.time_to_sync(1e-6)
    assert int(ds_run["impacts1"]) == r.impacts1 and int(ds_run["impacts2"]) == r.impacts2


def test_gain_map_41x41_equals_single_simulate_pair_runs_bitwise(gain_map):
    from fmu_sync import load_scene
    assert load_scene(SCENE).variant("switching").cfg["run.record_every"] == EVERY
    ds = gain_map
    assert ds["status"].shape == (41, 41)
    assert list(ds.dims) == ["coupling.Kp", "coupling.Kd"]
    assert ds.attrs["compiled_runs"] == 41 * 41 and ds.attrs["computed_runs"] == 41 * 41
    rng = np.random.default_rng(3)
    picks = [(0, 0), (40, 40), (40, 0), (0, 40), (20, 20)] + [tuple(rng.integers(0, 41, 2)) for _ in range(5)]
    for i, j in picks:
        run = ds.isel({"coupling.Kp": i, "coupling.Kd": j})
        _same(run, _single(float(run["coupling.Kp"]), float(run["coupling.Kd"])))


def test_max_tau_over_every_step_equals_the_recorded_forces():
    ds = sweep(SCENE, variant="switching", grid={"coupling.Kp": [0.5, 30.0], "coupling.Kd": [0.05, 2.0]},
               overrides={"run.t_end": 2.0, "run.record_every": 1}, quiet=True)
    for i, kp in enumerate([0.5, 30.0]):
        for j, kd in enumerate([0.05, 2.0]):
            r = _single(kp, kd, t_end=2.0, every=1)
            run = ds.isel({"coupling.Kp": i, "coupling.Kd": j})
            _same(run, r)
            assert float(run["tau_max"]) == max(np.max(np.abs(r.tau1)), np.max(np.abs(r.tau2)))


@pytest.mark.parametrize("law,scheme", [("euclidean", "midpoint"), ("switching", "theta"), ("none", "midpoint"),
                                        ("euclidean", "trapezoid"), ("none", "trapezoid")])
def test_other_laws_and_theta_scheme_equal_single_runs(law, scheme):
    ds = sweep(SCENE, variant="switching", grid={"coupling.Kd": [0.1, 1.0], "system.e": [0.5, 0.95]},
               overrides={"run.t_end": 2.0, "coupling.law": law, "solver.scheme": scheme,
                          "solver.theta": 0.7}, quiet=True)
    for i, kd in enumerate([0.1, 1.0]):
        for j, e in enumerate([0.5, 0.95]):
            r = _single(1.0, kd, t_end=2.0, coupling=None if law == "none" else law, scheme=scheme,
                        theta=0.7, system=dict(e=e))
            _same(ds.isel({"coupling.Kd": i, "system.e": j}), r)


def test_start_state_sweep_equals_single_runs_and_refuses_states_behind_the_wall():
    ds = sweep(SCENE, variant="switching", grid={"initial.q2": [-0.5, 0.0, 2.0], "initial.u2": [-1.0, 1.5]},
               overrides={"run.t_end": 2.0}, quiet=True)
    st = ds["status"].values
    assert (st[0] == 2).all() and (st[1:] == 0).all()
    assert "x2 violates the constraint" in ds["reason"].values[0, 0]
    assert ds["reason"].values[1, 0] == ""
    for i, q in ((1, 0.0), (2, 2.0)):
        for j, u in enumerate([-1.0, 1.5]):
            _same(ds.isel({"initial.q2": i, "initial.u2": j}), _single(1.0, 0.5, t_end=2.0, x2=(q, u)))


def test_contact_episodes_equal_those_of_single_runs():
    # uncoupled: each system is a single run; its per-step percussions give the episodes
    ds = sweep(SCENE, variant="uncoupled", grid={"system.e": [0.0, 0.6]},
               overrides={"run.t_end": 20.0}, quiet=True)
    for j, e in enumerate([0.0, 0.6]):
        s = ImpactOscillator(**{**FORCED, "e": e})
        for x, name in ((X1, "episodes1"), (X2, "episodes2")):
            r = simulate(s, x, 20.0, 1e-3, phasor=False)   # the pair loop takes cos per step
            assert int(ds[name].values[j]) == contact_starts(r.percussion).size > 0
            assert int(ds["impacts" + name[-1]].values[j]) == r.impacts


def test_decay_rate_bound_and_t_fit_are_the_metrics_of_the_recorded_distance():
    # 8 s: 801 samples, kept whole by the 1024-sample recorder -> the same numbers as the metrics
    # of the full record; 40 s: 4001 samples, decimated -> the same rate within its uncertainty
    for t_end, exact in ((8.0, True), (40.0, False)):
        ds = sweep(SCENE, variant="switching", grid={"coupling.Kp": [1.0, 10.0]},
                   overrides={"run.t_end": t_end, "coupling.Kd": 2.0}, quiet=True)
        for i, kp in enumerate([1.0, 10.0]):
            m = _single(kp, 2.0, t_end=t_end).sync()
            rate = float(ds["decay_rate"][i])
            assert float(ds["t_sync"][i]) == m.t_sync
            # the cell's verdict is the record's (8 s, Kp = 1: d has not fallen two decades yet)
            assert int(ds["rate_code"][i]) == m.code and bool(ds["rate_resolved"][i]) == m.resolved
            assert (ds["rate_reason"].values[i] == "") == m.resolved
            assert m.resolved or (t_end, kp) == (8.0, 1.0)
            if exact:
                assert rate == m.rate or (np.isnan(rate) and np.isnan(m.rate))
                assert float(ds["decay_rate_err"][i]) == m.rate_err or np.isnan(m.rate_err)
                assert float(ds["t_fit"][i]) == m.t_fit or np.isnan(m.t_fit)
                assert float(ds["bound"][i]) == m.bound
            else:
                assert abs(rate - m.rate) < 0.05 * m.rate + 3 * m.rate_err
                assert float(ds["bound"][i]) == m.bound


def test_diverging_runs_finish_as_rows_with_their_reason():
    # Kd dt / m > 1: the explicitly held damping force overshoots -> diverges (the midpoint named: it
    # holds the coupling over the step; the default, checked last, has it inside the step)
    over = {"run.t_end": 50.0, "solver.dt": 2e-2}
    ds = sweep(SCENE, variant="switching", grid={"coupling.Kd": [0.5, 80.0, 200.0]},
               overrides={**over, "solver.scheme": "midpoint"}, quiet=True)
    st = ds["status"].values
    assert st.tolist() == [0, 1, 1]
    assert bool(ds["synchronized"][0]) and not ds["synchronized"][1:].any()
    for k in (1, 2):
        reason = ds["reason"].values[k]
        assert "became non-finite" in reason and "dt = 0.02" in reason
        assert 0 < float(ds["t_stop"][k]) < 50.0
        assert np.isinf(float(ds["t_sync"][k]))
        with pytest.raises(Exception, match="non-finite"):
            _single(1.0, float(ds["coupling.Kd"][k]), t_end=50.0, dt=2e-2, scheme="midpoint")
        # the core's own check refuses it up front; the sweep runs it and flags it
        assert float(ds["exchange_stable"][k]) == 0.0
    assert float(ds["exchange_stable"][0]) == 1.0
    with pytest.raises(ValueError, match="unstable"):
        _single(1.0, 80.0, t_end=1.0, dt=2e-2, allow_unstable=False, scheme="midpoint")
    # the default: the same gains run, the exchange stable (A-stable), d synchronized, as simulate_pair
    ds = sweep(SCENE, variant="switching", grid={"coupling.Kd": [80.0, 200.0]}, overrides=over, quiet=True)
    assert ds["status"].values.tolist() == [0, 0] and ds["exchange_stable"].values.tolist() == [1.0, 1.0]
    for k, kd in enumerate([80.0, 200.0]):
        _same(ds.isel({"coupling.Kd": k}), _single(1.0, kd, t_end=50.0, dt=2e-2, allow_unstable=False))


def test_refused_step_is_a_row_not_an_error():
    # the midpoint named: its stability limit omega_max*dt < 2 refuses dt = 2.5 (θ = ½ has none)
    ds = sweep(SCENE, variant="switching", grid={"solver.dt": [1e-3, 2.5]},
               overrides={"run.t_end": 5.0, "solver.scheme": "midpoint"}, quiet=True)
    assert ds["status"].values.tolist() == [0, 2]
    assert "omega_max*dt >= 2" in ds["reason"].values[1]


def test_resume_after_interrupt_recomputes_only_missing_chunks(tmp_path):
    kw = dict(variant="switching", grid={"coupling.Kp": "logspace(-1, 1, 6)", "coupling.Kd": [0.3, 1.0, 3.0]},
              overrides={"run.t_end": 2.0}, chunk_size=4, plots=False, quiet=True)   # 18 runs, 5 chunks
    seen = []

    def interrupt(done, total, failed):
        seen.append(done)
        if done >= 8:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sweep(SCENE, out=tmp_path, progress=interrupt, **kw)
    assert seen[-1] == 8 and not (tmp_path / "sweep.nc").exists()
    ds = sweep(SCENE, out=tmp_path, **kw)
    assert ds.attrs["reused_runs"] == 8 and ds.attrs["computed_runs"] == 10
    ref = sweep(SCENE, **kw)
    for v in ("q1", "u1", "d_final", "d_max", "t_sync", "decay_rate", "status"):
        np.testing.assert_array_equal(ds[v].values, ref[v].values)
    again = sweep(SCENE, out=tmp_path, **kw)       # finished: nothing recomputed
    assert again.attrs["computed_runs"] == 0
    np.testing.assert_array_equal(again["d_final"].values, ref["d_final"].values)
    with pytest.raises(FileExistsError, match="different sweep"):
        sweep(SCENE, out=tmp_path, **{**kw, "overrides": {"run.t_end": 1.0}})


def test_netcdf_file_holds_labelled_arrays_scene_and_versions(tmp_path):
    ds = sweep(SCENE, variant="switching", grid={"coupling.Kp": [0.1, 1.0], "solver.dt": [1e-3, 2.5]},
               overrides={"run.t_end": 1.0}, out=tmp_path, plots=False, quiet=True)
    back = read_dataset(tmp_path / "sweep.nc")
    assert list(back.dims) == ["coupling.Kp", "solver.dt"]
    np.testing.assert_array_equal(back["coupling.Kp"].values, [0.1, 1.0])
    for v in ("d_final", "t_sync", "status", "synchronized"):
        np.testing.assert_array_equal(back[v].values, ds[v].values)
    assert back["reason"].values.tolist() == ds["reason"].values.tolist()
    assert "[system]" in back.attrs["scene_toml"] and back.attrs["scene"] == SCENE
    versions = json.loads(back.attrs["versions"])
    assert {"fmu_sync", "numba", "numpy", "xarray"} <= set(versions)


def test_random_and_latin_hypercube_samples_are_seeded_runs_with_parameter_coordinates():
    keys, runs = sample_runs({"coupling.Kp": "loguniform(0.01, 100)", "system.e": "uniform(0.5, 1)"},
                             50, "lhs", seed=7)
    e = np.array([r["system.e"] for r in runs])
    kp = np.array([r["coupling.Kp"] for r in runs])
    # one draw in each of the 50 strata of each parameter
    assert sorted(np.floor((e - 0.5) / 0.5 * 50).astype(int).tolist()) == list(range(50))
    assert sorted(np.floor(np.log(kp / 0.01) / np.log(1e4) * 50).astype(int).tolist()) == list(range(50))
    assert sample_runs({"system.e": "uniform(0.5, 1)"}, 5, "random", 1)[1] == \
        sample_runs({"system.e": "uniform(0.5, 1)"}, 5, "random", 1)[1]
    ds = sweep(SCENE, variant="switching", sample={"coupling.Kp": "loguniform(0.1, 10)",
                                                   "system.e": "uniform(0.5, 1)"},
               n=12, method="lhs", seed=7, overrides={"run.t_end": 2.0}, quiet=True)
    assert list(ds.dims) == ["run"] and ds.sizes["run"] == 12
    r = ds.isel(run=5)
    _same(r, _single(float(r["coupling.Kp"]), 0.5, t_end=2.0, system=dict(e=float(r["system.e"]))))


@pytest.mark.parametrize("kw,match", [
    (dict(grid={"coupling.Kp": [-1.0, 1.0]}), r"coupling.Kp = -1.0.*>= 0"),
    (dict(grid={"coupling.Kp": "logspace(1, 2)"}), r"expected 3 numbers"),
    (dict(grid={"coupling.Kp": "geomspace(1, 2, 3)"}), r"unknown function 'geomspace'"),
    (dict(grid={"Kp": [1.0]}), r"not a scene key"),
    (dict(grid={"coupling.Kq": [1.0]}), r"unknown key .*coupling.Kq.*allowed keys in \[coupling\]"),
    (dict(sample={"coupling.Kp": "loguniform(0, 1)"}, n=4, method="lhs"), r"a > 0"),
])
def test_bad_sweep_specs_are_refused_with_the_offending_value(kw, match):
    with pytest.raises(SweepSpecError, match=match):
        sweep(SCENE, variant="switching", quiet=True, **kw)


def test_a_scene_with_variants_needs_one_chosen():
    with pytest.raises(SweepSpecError, match="uncoupled, euclidean, switching"):
        sweep(SCENE, grid={"coupling.Kp": [1.0]}, quiet=True)
    ds = sweep(SCENE, grid={"variant": ["uncoupled", "switching"]}, overrides={"run.t_end": 40.0}, quiet=True)
    assert ds["synchronized"].values.tolist() == [False, True]


def test_maps_are_written(tmp_path):
    from fmu_sync.sweeps.plots import zoh_margin
    sweep("gain-map", grid={"coupling.Kp": "logspace(-2, 2, 6)", "coupling.Kd": "logspace(-2, 2, 6)"},
          overrides={"run.t_end": 20.0}, out=tmp_path / "map", quiet=True)
    sweep("basin", grid={"initial.q2": "linspace(-0.5, 2, 4)", "initial.u2": "linspace(-1, 1, 3)"},
          overrides={"run.t_end": 5.0}, out=tmp_path / "basin", quiet=True)
    sweep(SCENE, variant="switching", grid={"system.e": [0.5, 0.9]}, overrides={"run.t_end": 5.0},
          out=tmp_path / "line", quiet=True)
    assert (tmp_path / "line" / "line.png").stat().st_size > 15_000
    assert (tmp_path / "map" / "map.png").stat().st_size > 20_000
    assert (tmp_path / "basin" / "basin.png").stat().st_size > 15_000
    # the ZOH limit of stability.py: zeta <= 1/2 -> Kp h < 2 Kd; zeta >= 1/2 -> Kd h < m
    assert zoh_margin(1.0, 0.01, 0.02, 1.0) > 1 > zoh_margin(1.0, 0.011, 0.02, 1.0)
    assert zoh_margin(1.0, 49.0, 0.02, 1.0) < 1 < zoh_margin(1.0, 51.0, 0.02, 1.0)
    # the line drawn is the core's own stability check of the held exchange
    from fmu_sync.core.exchange import exchange_limit
    rng = np.random.default_rng(5)
    for kp, kd, h, m in zip(10 ** rng.uniform(-2, 2, 40), 10 ** rng.uniform(-2, 2, 40),
                            10 ** rng.uniform(-3, -1, 40), rng.uniform(0.5, 2, 40)):
        assert (zoh_margin(kp, kd, h, m) < 1) == exchange_limit([[m]], kp, kd, h).stable


def test_cli_sweep_writes_netcdf_and_map(tmp_path, capsys):
    from fmu_sync.cli import main
    out = tmp_path / "s"
    code = main(["sweep", "forced-pair", "--variant", "switching", "--grid", "coupling.Kp=logspace(-1,1,3)",
                 "--grid", "coupling.Kd=[0.2, 1.0]", "--set", "run.t_end=3", "-o", str(out), "--quiet"])
    assert code == 0
    text = capsys.readouterr().out
    assert "6 runs (6 computed" in text and "map.png" in text
    assert read_dataset(out / "sweep.nc")["status"].shape == (3, 2)
    assert main(["sweep", "forced-pair", "--grid", "coupling.Kp=-1", "--variant", "switching",
                 "-o", str(tmp_path / "bad"), "--quiet"]) == 2
    assert "coupling.Kp = -1" in capsys.readouterr().err


@pytest.mark.slow
def test_cosimulated_sweep_runs_in_worker_processes_and_equals_single_cosimulations(tmp_path):
    from fmu_sync.scenes.loading import load_scene
    from fmu_sync.scenes.running import export_for, run_variant
    over = {"run.t_end": 4.0, "run.mode": "cosim", "run.record_every": 1}
    ds = sweep(SCENE, variant="switching", grid={"coupling.Kp": [0.5, 2.0], "run.H": [1e-2]},
               overrides=over, workers=2, quiet=True)
    assert ds.attrs["process_runs"] == 2 and ds.attrs["compiled_runs"] == 0
    sc = load_scene(SCENE, over, ["switching"])
    fmu = export_for(sc.variants[0], tmp_path)
    for i, kp in enumerate([0.5, 2.0]):
        v = load_scene(SCENE, {**over, "coupling.Kp": kp, "run.H": 1e-2}, ["switching"]).variants[0]
        r = run_variant(v, fmu)
        run = ds.isel({"coupling.Kp": i, "run.H": 0})
        assert int(run["status"]) == 0
        assert float(run["d_final"]) == r.d[-1] and float(run["d_max"]) == np.max(r.d)
        assert float(run["q1"]) == r.q1[-1, 0] and float(run["u2"]) == r.u2[-1, 0]
        assert float(run["t_sync"]) == r.time_to_sync(1e-6)
        assert int(run["impacts1"]) == r.impacts1
        assert float(run["tau_max"]) == max(np.max(np.abs(r.tau1)), np.max(np.abs(r.tau2)))
    # Kp = 50, Kd = 0, H = 0.5 s: the held exchange is unstable; the master refuses it up front
    bad = sweep(SCENE, variant="switching", grid={"coupling.Kp": [50.0]},
                overrides={**over, "run.H": 0.5, "run.t_end": 400.0, "coupling.Kd": 0.0}, workers=1, quiet=True)
    assert int(bad["status"][0]) == 2 and "unstable" in bad["reason"].values[0]
    assert float(bad["exchange_stable"][0]) == 0.0


def test_two_dof_core_pairs_run_in_worker_processes_and_equal_single_runs():
    from fmu_sync.scenes.loading import load_scene
    from fmu_sync.scenes.running import run_variant
    ds = sweep("two-dof", grid={"coupling.Kp": [0.5, 2.0]}, overrides={"run.t_end": 3.0}, workers=2, quiet=True)
    assert ds.attrs["process_runs"] == 2 and ds.attrs["compiled_runs"] == 0
    for i, kp in enumerate([0.5, 2.0]):
        r = run_variant(load_scene("two-dof", {"run.t_end": 3.0, "coupling.Kp": kp}).variants[0])
        run = ds.isel({"coupling.Kp": i})
        assert int(run["status"]) == 0
        assert float(run["d_final"]) == r.d[-1] and float(run["d_max"]) == np.max(r.d)
        assert float(run["q1"]) == r.q1[-1, 0] and float(run["t_sync"]) == r.time_to_sync(1e-6)
        assert int(run["impacts1"]) == r.impacts1 and int(run["impacts2"]) == r.impacts2


def test_mismatched_second_system_uncoupled_equals_two_single_runs():
    # system2.* lays keys over system 2 only; uncoupled, each system is a single run of its own
    ds = sweep(SCENE, variant="uncoupled", grid={"system2.k": [0.5, 1.0, 2.0], "system2.f0": [0.2, 0.35]},
               overrides={"run.t_end": 10.0}, quiet=True)
    r1 = simulate(ImpactOscillator(**FORCED), X1, 10.0, 1e-3, phasor=False)   # cos per step, as the pair loop
    for i, k in enumerate([0.5, 1.0, 2.0]):
        for j, f0 in enumerate([0.2, 0.35]):
            run = ds.isel({"system2.k": i, "system2.f0": j})
            r2 = simulate(ImpactOscillator(**{**FORCED, "k": k, "f0": f0}), X2, 10.0, 1e-3, phasor=False)
            assert float(run["q1"]) == r1.q[-1, 0] and float(run["u1"]) == r1.u[-1, 0]
            assert float(run["q2"]) == r2.q[-1, 0] and float(run["u2"]) == r2.u[-1, 0]
            assert int(run["impacts2"]) == r2.impacts
    # coupled, a mismatch leaves a residual: practical synchronization, a positive ultimate bound
    c = sweep(SCENE, variant="switching", grid={"system2.f0": [0.2, 0.3]}, overrides={"run.t_end": 60.0},
              quiet=True)
    assert bool(c["synchronized"][0]) and not bool(c["synchronized"][1])
    assert 0 < float(c["bound"][1]) < 0.1 * float(c["d0"][1])
    # ... bit for bit the non-identical pair of simulate_pair((system1, system2), ...)
    s1, s2 = ImpactOscillator(**FORCED), ImpactOscillator(**{**FORCED, "f0": 0.3})
    r = simulate_pair((s1, s2), X1, X2, 60.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5, record_every=EVERY)
    _same(c.isel({"system2.f0": 1}), r)
    with pytest.raises(SweepSpecError, match=r"the switching law is refused: the quotient distance needs one impact map .*e differs: system 1 has e = 0.9, "
                                             r"system 2 has e = 0.5"):
        sweep(SCENE, variant="switching", grid={"system2.e": [0.5]}, quiet=True)


def test_progress_shows_runs_failures_and_time_left():
    import io
    import time

    from fmu_sync.sweeps import SweepProgress
    buf = io.StringIO()
    bar = SweepProgress("sweep x", stream=buf, force=True)
    bar(0, 100, 0)
    time.sleep(0.02)
    bar(50, 100, 3)
    bar(100, 100, 4)
    text = buf.getvalue()
    assert "0/100 runs, 0 failed" in text
    assert "50/100 runs, 3 failed" in text and "ETA" in text.splitlines()[1]
    assert "100/100 runs, 4 failed" in text


def _average_decay(t, d, hi=1e-2):
    """The independent estimate of issue 25: the average decay of the running maximum of d from
    the end between ``hi`` max d and the lower of 1e-8 max d and a decade above the lowest level it
    reaches (NaN if that is not two decades below ``hi``)."""
    env = np.maximum.accumulate(np.asarray(d)[::-1])[::-1]
    lo = max(1e-8, 10.0 ** (np.floor(np.log10(max(env[-1], 1e-300) / env[0])) + 1))
    if lo > 1e-2 * hi:
        return float("nan")
    return np.log(hi / lo) / (t[np.argmax(env <= lo * env[0])] - t[np.argmax(env <= hi * env[0])])


def test_gain_map_cells_carry_a_rate_that_matches_their_own_average_decay():
    # issue 25: the forced pair's 6 x 6 gain map over Kp, Kd in [0.1, 10] at the sweep scene's own dt
    # (2e-2, 60 s): most synchronized cells carry a resolved rate (flag and reason in every cell),
    # each within 30 % of the same run's average decay of d from 1e-2 max d down to 1e-8 max d (or a
    # decade above the lowest level it reaches; measured under the default, the trapezoid: 20 of 20
    # resolved, 19 within 8 %, the worst 26.5 % at Kp = 10, Kd = 0.25, light damping, where d's
    # oscillation makes single decades uneven; the midpoint's map: 22 resolved, the worst 24 %)
    from fmu_sync.sweeps import load_sweep_scene
    dt = load_sweep_scene("gain-map")["overrides"]["solver.dt"]
    grid = {"coupling.Kp": "logspace(-1, 1, 6)", "coupling.Kd": "logspace(-1, 1, 6)"}
    ds = sweep(SCENE, variant="switching", grid=grid, overrides={"run.t_end": 60.0, "solver.dt": dt}, quiet=True)
    sync = ds["synchronized"].values
    resolved = ds["rate_resolved"].values
    assert sync.sum() >= 12 and (resolved & sync).sum() >= 0.8 * sync.sum()
    reasons = ds["rate_reason"].values
    assert all((r == "") == bool(ok) for r, ok in zip(reasons.ravel(), resolved.ravel()))
    checked = 0
    for i, kp in enumerate(ds["coupling.Kp"].values):
        for j, kd in enumerate(ds["coupling.Kd"].values):
            if not resolved[i, j]:
                continue
            r = _single(float(kp), float(kd), t_end=60.0, dt=dt)
            ref = _average_decay(r.t, r.d)
            if np.isfinite(ref):
                checked += 1
                assert float(ds["decay_rate"][i, j]) == pytest.approx(ref, rel=0.3), (kp, kd)
    assert checked >= 0.8 * resolved.sum()


def _captured(monkeypatch):
    """The figures the sweep plots save (fmu_sync.sweeps.plots.save_figure), kept for inspection."""
    import fmu_sync.sweeps.plots as SP
    figs = []
    real = SP.save_figure

    def keep(fig, path, dpi):
        figs.append(fig)
        return real(fig, path, dpi)
    monkeypatch.setattr(SP, "save_figure", keep)
    return SP, figs


def test_samples_plot_draws_every_sample_and_counts_each_kind(tmp_path, monkeypatch):
    """An LHS sample whose rates are finite but not resolved (issue 28: 213 samples with Kp in
    [0.03, 0.08] had finite rates in sweep.nc and were not drawn, unsaid): every sample is drawn,
    the legend counts each kind."""
    import xarray as xr
    SP, figs = _captured(monkeypatch)
    rng = np.random.default_rng(28)
    n = 60
    Kp, e = 10 ** rng.uniform(-2, 2, n), rng.uniform(0.5, 1.0, n)
    rate = rng.uniform(0.2, 1.0, n)
    err = np.where(Kp < 0.1, 0.5 * rate, 0.01 * rate)            # unresolved below Kp = 0.1
    status = np.zeros(n, dtype=np.int8)
    status[:3], status[3:5] = 1, 2
    rate[5:9] = np.nan                                             # no rate at all
    ds = xr.Dataset({"status": ("run", status), "decay_rate": ("run", rate), "decay_rate_err": ("run", err),
                     "rate_resolved": ("run", np.isfinite(rate) & (Kp >= 0.1)),
                     "synchronized": ("run", np.isfinite(rate))},
                    coords={"run": np.arange(n), "coupling.Kp": ("run", Kp), "system.e": ("run", e)},
                    attrs={"method": "lhs", "scene": "forced-pair"})
    SP.scatter(ds, "coupling.Kp", "system.e", tmp_path / "samples.png")
    ax = figs[-1].axes[0]
    drawn = sum(len(c.get_offsets()) for c in ax.collections)
    assert drawn == n
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    loose = int(((status == 0) & np.isfinite(rate) & (Kp < 0.1)).sum())
    assert loose > 0 and f"decay rate not resolved, open ({loose})" in labels, labels
    assert "no decay rate (4)" in labels and "diverged (3)" in labels and "refused (2)" in labels


def test_basin_colours_without_a_rate_are_told_apart(tmp_path, monkeypatch):
    """basin.png: the cells without a colour-scale value (not synchronized; synchronized, no rate;
    diverged; refused) in colours far apart (issue 28: two greys), the legend off the map."""
    import xarray as xr
    from matplotlib.colors import to_rgb
    SP, figs = _captured(monkeypatch)
    q, u = np.linspace(0, 3, 6), np.linspace(-3, 3, 6)
    status = np.zeros((6, 6), dtype=np.int8)
    status[0, 0], status[0, 1] = 1, 2
    rate = np.full((6, 6), 0.5)
    rate[1, :3] = np.nan
    sync = np.ones((6, 6), dtype=bool)
    sync[2, :3] = False
    rate[2, :3] = np.nan
    dims = ("initial.q2", "initial.u2")
    ds = xr.Dataset({"status": (dims, status), "decay_rate": (dims, rate), "decay_rate_err": (dims, 0.01 * rate),
                     "rate_resolved": (dims, np.isfinite(rate)), "synchronized": (dims, sync)}, coords={"initial.q2": q, "initial.u2": u},
                    attrs={"scene": "forced-pair"})
    SP.basin(ds, *dims, tmp_path / "basin.png")
    fig = figs[-1]
    ax = fig.axes[0]
    leg = ax.get_legend()
    colours = {t.get_text(): np.array(to_rgb(h.get_facecolor())) for t, h in zip(leg.get_texts(), leg.legend_handles)}
    assert len(colours) == 4, colours
    names = list(colours)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert np.abs(colours[a] - colours[b]).sum() > 0.45, (a, b, colours[a], colours[b])
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    canvas = FigureCanvasAgg(fig)      # pyplot closed it: draw it on a canvas of its own
    canvas.draw()
    R = canvas.get_renderer()
    assert not leg.get_window_extent(R).overlaps(ax.get_window_extent(R))


def test_sweep_axes_carry_the_units_of_the_scene_and_its_model(tmp_path, monkeypatch):
    """Issue 36: a line plot's axis "system.k12" had no unit. The unit of a swept key comes from
    the model's declaration ([system] keys, the initial state's q and u) or the scene schema."""
    from pathlib import Path

    import fmu_sync.scenes
    from fmu_sync.core.registry import load_model
    SP, figs = _captured(monkeypatch)
    pend, osc = load_model("pendulum"), load_model("impact-oscillator")
    assert SP.axis_label("system.l", pend) == "system.l [m]"
    assert SP.axis_label("initial.q1", pend) == "$q_1(0)$ [rad]"
    assert SP.axis_label("initial.u2", pend) == "$u_2(0)$ [rad/s]"
    assert SP.axis_label("initial.q1", osc) == "$q_1(0)$ [m]" and SP.axis_label("system.k", osc) == "system.k [N/m]"
    assert SP.axis_label("coupling.Kp") == "$K_p$ [N/m]" and SP.axis_label("run.H") == "H [s]"
    assert SP.axis_label("system.e", pend) == "restitution e"          # dimensionless: no unit
    l = np.array([0.5, 1.0, 1.5])
    ds = xr.Dataset({"status": ("system.l", np.zeros(3, dtype=np.int8)), "decay_rate": ("system.l", [0.3, 0.2, 0.1]),
                     "decay_rate_err": ("system.l", [0.01] * 3), "rate_resolved": ("system.l", [True] * 3),
                     "synchronized": ("system.l", [True] * 3), "t_sync": ("system.l", [5.0, 7.0, 9.0])},
                    coords={"system.l": l},
                    attrs={"scene": "pendulum",
                           "scene_file": str(Path(fmu_sync.scenes.__file__).parent / "pendulum.toml")})
    SP.line_plot(ds, "system.l", tmp_path / "line.png")
    assert [ax.get_xlabel() for ax in figs[-1].axes] == ["system.l [m]"] * 2


@pytest.mark.parametrize("scheme,drawn", [("midpoint", True), (DEFAULT_SCHEME, False)])
def test_the_gain_map_draws_the_zoh_limit_only_where_the_core_holds_the_coupling(tmp_path, monkeypatch, scheme,
                                                                                   drawn):
    # the midpoint holds the forces over dt (its limit Kd dt / m = 1 lies inside the map: Kd = 50 at
    # dt = 0.02); the default solves the coupling inside the step: no held exchange, no line
    SP, figs = _captured(monkeypatch)
    ds = sweep(SCENE, variant="switching", grid={"coupling.Kp": [0.1, 1.0, 10.0], "coupling.Kd": [1.0, 20.0, 100.0]},
               overrides={"run.t_end": 1.0, "solver.dt": 2e-2, "solver.scheme": scheme}, out=tmp_path, quiet=True)
    assert (ds["exchange_stable"].values == 1.0).all() != drawn
    legends = [lg for f in figs for lg in [*f.legends, *(ax.get_legend() for ax in f.axes)] if lg is not None]
    labels = [t.get_text() for lg in legends for t in lg.get_texts()]
    assert any("ZOH limit" in s for s in labels) == drawn, labels


def test_any_thread_count_gives_the_same_rows_bit_for_bit():
    """The compiled chunk on 1 and on 3 threads (each taking the next block of runs: core/batch.run_pairs1):
    the same dataset bit for bit, and no thread left running."""
    import threading
    grid = {"coupling.Kp": "logspace(-1, 1, 5)", "coupling.Kd": "logspace(-1, 1, 5)"}
    before = threading.active_count()
    a, b = (sweep(SCENE, variant="switching", grid=grid, overrides={"run.t_end": 1.0}, quiet=True, threads=t)
            for t in (1, 3))
    assert threading.active_count() == before
    for name in a.data_vars:
        x, y = a[name].values, b[name].values
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name


def test_an_error_in_one_block_ends_the_call_with_it_and_no_thread_left(monkeypatch):
    """A block that raises (here the third; a Ctrl-C the same) is raised in the caller's thread once
    every thread has finished its own block; no block is started after it."""
    import threading
    from fmu_sync.core import batch
    real, started = batch.run_block, []

    def block(lo, hi, *args):
        started.append(lo)
        if len(started) == 3:
            raise RuntimeError(f"block at run {lo} failed")
        return real(lo, hi, *args)
    monkeypatch.setattr(batch, "run_block", block)
    grid = {"coupling.Kp": "logspace(-1, 1, 8)", "coupling.Kd": "logspace(-1, 1, 8)"}
    before = threading.active_count()
    with pytest.raises(RuntimeError, match="block at run"):
        sweep(SCENE, variant="switching", grid=grid, overrides={"run.t_end": 0.5}, quiet=True, threads=2)
    assert threading.active_count() == before
    assert len(started) < 2 * batch.BLOCKS_PER_THREAD   # the blocks left were not started
