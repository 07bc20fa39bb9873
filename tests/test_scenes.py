"""Scenes (docs/design.md §4.5): the built-in files load, bad files fail loudly, overrides apply,
and running a scene builds only what it names."""
import re
import sys
import types

import numpy as np
import pytest

from fmu_sync.core import SimulationResult
from fmu_sync.core.result import PairResult
from fmu_sync.core.steps import DEFAULT_SCHEME, SCHEMES
from fmu_sync import SceneError, list_scenes, load_scene, run_scene
from fmu_sync.scenes.loading import parse_override
from fmu_sync.scenes import SCENE_DIR, builtin_names

BUILTIN_SCENES = {"forced-pair", "zeno-table", "grazing", "bouncing-ball", "stiff-wall", "plastic",
               "elastic", "two-dof"}


# ------------------------------------------------------------------ built-in scenes
def test_all_spec_scenes_are_built_in():
    assert BUILTIN_SCENES <= set(builtin_names())
    described = dict(list_scenes())
    assert all(described[n] for n in BUILTIN_SCENES), "every scene has a one-line description"


@pytest.mark.parametrize("name", builtin_names())
def test_builtin_scene_loads_and_validates(name):
    s = load_scene(name)
    assert s.name == name and s.path == SCENE_DIR / f"{name}.toml"
    assert s.variants and s.description
    for v in s.variants:
        assert v.cfg["run.t_end"] > 0 and v.cfg["solver.dt"] > 0
        assert 0.0 <= v.system.e <= 1.0
        starts = v.network.states if v.is_network else [x for x in (v.x1, v.x2) if x is not None]
        assert all(v.system.gap(np.atleast_1d(x[0])) >= 0 for x in starts)


def test_forced_pair_has_our_parameters():
    """The forced-pair scene holds the values the project chose (not the paper's: not available)."""
    s = load_scene("forced-pair")
    assert [v.name for v in s.variants] == ["uncoupled", "euclidean", "switching"]
    assert [v.law for v in s.variants] == ["none", "euclidean", "switching"]
    v = s.variant("switching")
    sy = v.system
    assert (sy.M[0, 0], sy.K[0, 0], sy.C[0, 0], sy.f0[0], sy.e) == (1.0, 1.0, 0.0, 0.2, 0.9)
    ((F, Omega, phi),) = sy.forcing
    assert np.allclose(F, [0.5]) and (Omega, phi) == (2.5, 0.0)
    assert v.x1 == (1.0, 0.0) and v.x2 == (0.2, 0.5)
    assert (v.Kp, v.Kd) == (1.0, 0.5)
    assert s.compare and all(v.has_distance for v in s.variants)


def test_limits_and_two_dof():
    assert load_scene("plastic").variants[0].system.e == 0.0
    assert load_scene("elastic").variants[0].system.e == 1.0
    v = load_scene("two-dof").variants[0]
    assert v.system.n == 2
    assert v.system.M[0, 1] != 0.0, "non-diagonal mass matrix"
    assert np.count_nonzero(v.system.w) == 2, "oblique wall"
    assert v.x1[0].shape == (2,) and v.x2[1].shape == (2,)
    s = load_scene("bouncing-ball")
    assert not s.variants[0].pair and not s.variants[0].has_distance
    assert set(s.plots) <= {"positions", "phase"}
    stiff = load_scene("stiff-wall").variants[0]
    assert stiff.system.omega_max() * stiff.cfg["solver.dt"] > 2 and stiff.cfg["solver.scheme"] == "theta"


def test_scenes_offer_the_core_schemes_and_run_its_default_in_both_modes(tmp_path):
    """One rule (issue 40.5): solver.scheme takes the core's scheme names (and "exact"), a scene
    without it runs the core's default, and a co-simulated scene hands that default to its FMUs."""
    from fmu_sync.fmus import contract
    from fmu_sync.scenes.variant import scene_values
    assert DEFAULT_SCHEME == "trapezoid"
    for name in SCHEMES:
        assert load_scene(write(tmp_path, BASE), {"solver.scheme": name}).variants[0].cfg["solver.scheme"] == name
    for mode in ("core", "cosim"):
        v = load_scene(write(tmp_path, BASE), {"run.mode": mode}).variants[0]
        assert v.cfg["solver.scheme"] == DEFAULT_SCHEME
    values = scene_values(contract.MODELS["impact-oscillator"], v)
    assert values[contract.SOLVER_SCHEME] == contract.scheme_value(DEFAULT_SCHEME) == SCHEMES[DEFAULT_SCHEME]
    with pytest.raises(SceneError, match=r'"trapezoid" or "midpoint" or "theta" for pairs'):
        load_scene(write(tmp_path, BASE), {"solver.scheme": "exact"})
    with pytest.raises(SceneError, match=r'one of "trapezoid", "midpoint", "theta", "exact"'):
        load_scene(write(tmp_path, BASE), {"solver.scheme": "euler"})
    # the built-in scenes that name no scheme run the default; stiff-wall names theta (it is about it)
    named = {n: load_scene(n).variants[0].cfg["solver.scheme"] for n, _ in list_scenes()}
    assert {n for n, sch in named.items() if sch != DEFAULT_SCHEME} == {"stiff-wall"}, named


# ------------------------------------------------------------------ strict validation
BASE = """
description = "test scene"
[system]
model = "impact-oscillator"
k = 1.0
e = 0.5
[initial]
x1 = [1.0, 0.0]
x2 = [0.5, 0.0]
[coupling]
law = "switching"
Kp = 1.0
[run]
t_end = 1.0
"""


def write(tmp_path, text, name="my-scene.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("old,new,key,value,allowed", [
    ("k = 1.0", "k = 1.0\nstiffness = 3", "system.stiffness", "3", "allowed keys in [system]"),
    ("Kp = 1.0", "Kp = 1.0\nKi = 0.1", "coupling.Ki", "0.1", "law, Kp, Kd, Q"),
    ("e = 0.5", 'e = "high"', "system.e", '"high"', "[0, 1]"),
    ("e = 0.5", "e = 1.5", "system.e", "1.5", "[0, 1]"),
    ('law = "switching"', 'law = "magnetic"', "coupling.law", '"magnetic"', '"none", "switching", "euclidean"'),
    ("t_end = 1.0", "t_end = -2.0", "run.t_end", "-2.0", "> 0"),
    ("t_end = 1.0", "t_end = 1.0\nrecord_every = 0", "run.record_every", "0", "integer >= 1"),
    ("t_end = 1.0", "t_end = 1.0\nrecord_every = 2.5", "run.record_every", "2.5", "integer >= 1"),
    ("t_end = 1.0", 't_end = 1.0\nmode = "fmu"', "run.mode", '"fmu"', '"core", "cosim"'),
    ("t_end = 1.0", "t_end = 1.0\nevent_aware = 1", "run.event_aware", "1", "true or false"),
    ("Kp = 1.0", "Kp = -1.0", "coupling.Kp", "-1.0", ">= 0"),
    ("x2 = [0.5, 0.0]", "x2 = [-0.5, 0.0]", "initial.x2", "[-0.5, 0.0]", "g(q) >= 0"),
    ("x2 = [0.5, 0.0]", "x2 = [0.5]", "initial.x2", "[0.5]", "[q, u]"),
    ('model = "impact-oscillator"', 'model = "rocket"', "system.model", '"rocket"', "impact-oscillator"),
    ("t_end = 1.0", "t_end = 1.0\n[solver]\ntheta = 0.2", "solver.theta", "0.2", "[0.5, 1]"),
    ("t_end = 1.0", 't_end = 1.0\n[plot]\nplots = ["positions", "spectrum"]', "plot.plots", "spectrum",
     '"positions"'),
])
def test_bad_scene_names_file_key_value_and_allowed(tmp_path, old, new, key, value, allowed):
    assert old in BASE
    p = write(tmp_path, BASE.replace(old, new, 1))
    with pytest.raises(SceneError) as info:
        load_scene(p)
    msg = str(info.value)
    assert "my-scene.toml" in msg and key in msg and value in msg and allowed in msg, msg
    assert "\n" not in msg


def test_structural_errors(tmp_path):
    cases = {
        BASE + "\n[physics]\ng = 9.81\n": ("physics", "allowed at the top"),
        BASE.replace("[run]\nt_end = 1.0\n", "[run]\n"): ("run.t_end", "missing"),
        BASE + '\n[[runs]]\nname = "a"\nplot.plots = ["positions"]\n': ("runs[1].plot.plots", "whole scene"),
        BASE + '\n[[runs]]\nname = "a"\n[[runs]]\nname = "a"\n': ('"a"', "unique"),
        BASE + '\n[[runs]]\nname = "has space"\n': ('"has space"', "names output files"),
        BASE + '\n[[runs]]\nname = "a"\ncoupling.lw = "none"\n': ("runs[1].coupling.lw", "allowed keys"),
        BASE.replace("x2 = [0.5, 0.0]\n", ""): ("coupling.law", "needs two systems"),
        BASE + "\n[record]\ndistance = false\n[plot]\nplots = [\"distance\"]\n"
             + '[[runs]]\nname = "free"\ncoupling.law = "none"\n': ("plot.plots", "computes none"),
        BASE.replace("[run]", "[solver]\nscheme = \"exact\"\n[run]"): ("solver.scheme", "single 1-DOF"),
        BASE + "nonsense here": ("my-scene.toml", "not valid TOML"),
        BASE.replace("k = 1.0", "k = 1.0\nM = [[1.0]]"): ("system.M", 'model = "impact-oscillator"'),
    }
    for text, (key, problem) in cases.items():
        with pytest.raises(SceneError) as info:
            load_scene(write(tmp_path, text))
        msg = str(info.value)
        assert "my-scene.toml" in msg and key in msg and problem in msg, msg


def test_variant_errors_name_the_variant_key(tmp_path):
    text = BASE + '\n[[runs]]\nname = "a"\n[[runs]]\nname = "b"\ncoupling.Kd = "soft"\n'
    with pytest.raises(SceneError, match=r'runs\[2\]\.coupling\.Kd = "soft".*allowed'):
        load_scene(write(tmp_path, text))


def test_two_dof_shapes_are_checked(tmp_path):
    text = (SCENE_DIR / "two-dof.toml").read_text()
    bad = text.replace("x2 = [[0.2, -0.1], [0.3, -0.2]]", "x2 = [0.2, 0.3]")
    with pytest.raises(SceneError, match=r"initial\.x2 = \[0\.2, 0\.3\].*n = 2"):
        load_scene(write(tmp_path, bad))
    bad = text.replace("Kp = 2.0", "Kp = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]")
    with pytest.raises(SceneError, match=r"coupling\.Kp.*3 x 3"):
        load_scene(write(tmp_path, bad))
    bad = text.replace("M = [[2.0, 0.5], [0.5, 1.0]]", "M = [[2.0, 0.5], [0.4, 1.0]]")
    with pytest.raises(SceneError, match=r"\[system\]: M must be symmetric"):
        load_scene(write(tmp_path, bad))


def test_missing_scene():
    with pytest.raises(SceneError, match="unknown scene 'nope'.*forced-pair"):
        load_scene("nope")
    with pytest.raises(FileNotFoundError, match="nope.toml"):
        load_scene("nope.toml")


# ------------------------------------------------------------------ overrides
def test_parse_override():
    assert parse_override("coupling.Kp=2") == ("coupling.Kp", 2)
    assert parse_override("run.t_end = 50.5") == ("run.t_end", 50.5)
    assert parse_override("run.event_aware=true") == ("run.event_aware", True)
    assert parse_override("solver.scheme=theta") == ("solver.scheme", "theta")
    assert parse_override('solver.scheme="theta"') == ("solver.scheme", "theta")
    assert parse_override("initial.x1=[0.5, -1]") == ("initial.x1", [0.5, -1])
    with pytest.raises(SceneError, match="key=value"):
        parse_override("coupling.Kp")


def test_overrides_apply_to_every_variant():
    s = load_scene("forced-pair", {"coupling.Kp": 2, "run.t_end": 5, "solver.scheme": "theta"})
    for v in s.variants:
        assert v.Kp == 2.0 and v.cfg["run.t_end"] == 5.0 and v.cfg["solver.scheme"] == "theta"
    # an override wins over what a variant sets
    s = load_scene("forced-pair", {"coupling.law": "euclidean"})
    assert {v.law for v in s.variants} == {"euclidean"}
    s2 = s.with_overrides({"run.t_end": 3.0})
    assert s2.variants[0].cfg["run.t_end"] == 3.0 and s2.variants[0].law == "euclidean"


def test_bad_override_names_the_set(tmp_path):
    with pytest.raises(SceneError, match=r"forced-pair\.toml: --set coupling\.Kp = -3: is out of range"):
        load_scene("forced-pair", {"coupling.Kp": -3})
    with pytest.raises(SceneError, match=r"unknown key --set run\.tend = 5"):
        load_scene("forced-pair", {"run.tend": 5})
    with pytest.raises(SceneError, match=r"--set t_end = 5: not a key"):
        load_scene("forced-pair", {"t_end": 5})


# ------------------------------------------------------------------ running
def test_single_system_scene_runs_simulate_only(tmp_path):
    out = tmp_path / "bb"
    sr = run_scene("bouncing-ball", out, overrides={"run.t_end": 1.5})
    (run,) = sr.runs
    assert isinstance(run.result, SimulationResult)
    assert run.metrics["impacts"] >= 2
    names = {p.name for p in out.iterdir()}
    assert {"summary.md", "bouncing-ball.csv", "bouncing-ball.npz", "bouncing-ball-positions.png",
            "bouncing-ball-phase.png"} <= names
    assert not list(tmp_path.rglob("*.fmu"))
    text = (out / "summary.md").read_text()
    assert "bouncing-ball" in text and "run.t_end" in text


def test_divergence_names_the_scene_and_step(tmp_path):
    text = BASE.replace("k = 1.0", "k = 1e8").replace("x2 = [0.5, 0.0]\n", "").replace(
        'law = "switching"\nKp = 1.0\n', "").replace("[run]", '[solver]\nscheme = "midpoint"\ndt = 1e-3\n[run]')
    # (the midpoint named: its stability limit omega_max*dt < 2 is what refuses; the default θ = ½ runs it)
    from fmu_sync.scenes.running import RunRefused
    # refused before the first step (a ValueError: bad input), nothing written
    with pytest.raises(RunRefused, match=r"scene 'stiff'.*refused before the first step.*dt = 0\.001.*"
                                         r"omega_max\*dt = 10"):
        run_scene(load_scene(write(tmp_path, text, "stiff.toml")), tmp_path / "o")
    assert not (tmp_path / "o").exists()


def _streamed(res, sink):
    """What simulate_pair(..., sink=...) does with a result: the rows to the sink, the last row back."""
    if sink is None:
        return res
    sink(res)
    last = lambda a: None if a is None else a[-1:]  # noqa: E731
    return PairResult(*(last(getattr(res, k)) for k in ("t", "q1", "u1", "q2", "u2", "tau1", "tau2", "d", "branch",
                                                        "euclidean")), coupling=res.coupling)


def _fake_pair_module(calls):
    """A stand-in for fmu_sync.core.pair that records its arguments (tests the plumbing only)."""
    def simulate_pair(system, x1, x2, t_end, dt, coupling=None, Kp=0.0, Kd=0.0, Q=None, scheme=DEFAULT_SCHEME,
                      theta=0.5, record_every=1, record_distance=True, progress=None, sink=None, chunk_rows=None):
        calls.append(dict(coupling=coupling, Kp=Kp, Kd=Kd, Q=Q, scheme=scheme, record_every=record_every,
                          record_distance=record_distance, t_end=t_end, dt=dt))
        t = np.linspace(0.0, t_end, 11)
        q1 = np.abs(np.cos(t))[:, None]
        z = np.zeros_like(q1)
        want_d = record_distance or coupling == "switching"
        d = np.exp(-t) if want_d else None
        if progress:
            progress(1.0)
        return _streamed(PairResult(t, q1, z, q1 + 0.1, z, z, z, d, np.zeros(11, int) if want_d else None,
                                    d, coupling=coupling), sink)
    return types.SimpleNamespace(simulate_pair=simulate_pair)


def test_pair_plumbing_without_distance(tmp_path, monkeypatch):
    """Uncoupled with record.distance = false: no distance asked for, none plotted, no FMU."""
    calls = []
    monkeypatch.setitem(sys.modules, "fmu_sync.core.pair", _fake_pair_module(calls))
    seen = []
    sr = run_scene("forced-pair", tmp_path, variants=["uncoupled"], progress=seen.append,
                   overrides={"record.distance": False, "plot.plots": ["positions", "forces", "phase"],
                              "plot.compare": False, "run.t_end": 1.0})
    # every step run (the metrics from all of them, issue 36), every run.record_every = 10th kept
    assert calls == [dict(coupling=None, Kp=1.0, Kd=0.5, Q=None, scheme=DEFAULT_SCHEME, record_every=1,
                          record_distance=False, t_end=1.0, dt=1e-3)]
    assert sr.runs[0].result.t.tolist() == pytest.approx([0.0, 1.0])
    assert seen and seen[-1] == 1.0
    assert sr.runs[0].metrics["t_sync"] is None
    names = {p.name for p in tmp_path.iterdir()}
    assert "uncoupled-positions.png" in names and "uncoupled-distance.png" not in names
    assert not any(n.endswith(".fmu") for n in names)
    # switching needs d even when not recorded: the law is still passed through
    calls.clear()
    run_scene("forced-pair", tmp_path, variants=["switching"], plots=False,
              overrides={"record.distance": False, "run.t_end": 1.0})
    assert calls[0]["coupling"] == "switching"


# ------------------------------------------------------------------ needs the lead's simulate_pair
# These run the real monolithic pair simulation (fmu_sync.core.pair, being written by the lead).
# They fail (ImportError) until it exists; they are meant to fail then, not to be skipped.
def test_forced_pair_core_runs(tmp_path):
    sr = run_scene("forced-pair", tmp_path, overrides={"run.t_end": 2.0}, variants=["uncoupled", "switching"])
    assert [r.name for r in sr.runs] == ["uncoupled", "switching"]
    for r in sr.runs:
        assert r.result.d is not None and np.all(np.isfinite(r.result.d))
        for p in ("positions", "distance", "lyapunov", "phase") + (("forces",) if r.name != "uncoupled" else ()):
            assert (tmp_path / f"{r.name}-{p}.png").stat().st_size > 5000
        assert (tmp_path / f"{r.name}.csv").stat().st_size > 0
    assert (tmp_path / "compare-distance.png").exists()
    assert not list(tmp_path.rglob("*.fmu"))
    assert sr.runs[0].metrics["peak_tau"] == 0.0 and sr.runs[1].metrics["peak_tau"] > 0.0
    # no coupling force: no forces plot, and the summary says why
    assert not (tmp_path / "uncoupled-forces.png").exists()
    assert "**uncoupled**: no forces plot: no coupling force" in sr.summary.read_text()


def test_two_dof_core_runs(tmp_path):
    sr = run_scene("two-dof", tmp_path, overrides={"run.t_end": 1.0})
    r = sr.runs[0].result
    assert r.q1.shape[1] == 2 and r.d is not None
    assert (tmp_path / "two-dof-positions.png").exists()


# ------------------------------------------------------------------ cosim plumbing with stand-ins
def _fake_cosim_modules(monkeypatch, calls):
    """Stand-ins for fmu_sync.export / fmu_sync.master / simulate_pair recording their arguments."""
    import fmu_sync.scenes.variant as scene_mod   # the variant layer calls fmu_start_values

    def export_fmu(model, path, start_values=None):
        calls.append(("export", model))
        path.write_bytes(b"fake fmu")
        return path

    def fake_result(t_end, step, coupling):
        t = np.arange(0.0, t_end + step / 2, step)
        q1 = np.abs(np.cos(t))[:, None]
        z = np.zeros_like(q1)
        d = np.exp(-t) if coupling else np.full(t.size, 0.5)
        return PairResult(t, q1, z, q1 + 0.1, z, -0.1 * d[:, None], 0.1 * d[:, None], d,
                          np.zeros(t.size, int), d + 0.1, coupling=coupling)

    def cosimulate(fmu_path, x1, x2, t_end, H, coupling=None, Kp=0.0, Kd=0.0, Q=None, method="jacobi",
                   record_every=1, event_aware=False, H_min=None, start_values=None, record_distance=True,
                   progress=None, hold="zoh", exchange="explicit", tol=None):
        calls.append(("cosim", coupling, H, method, record_every, event_aware, start_values, hold, exchange, tol))
        return fake_result(t_end, H * record_every, coupling)

    def simulate_pair(system, x1, x2, t_end, dt, coupling=None, record_every=1, progress=None, sink=None, **kw):
        calls.append(("core", coupling, dt, record_every))
        return _streamed(fake_result(t_end, dt * record_every, coupling), sink)

    monkeypatch.setitem(sys.modules, "fmu_sync.export", types.SimpleNamespace(export_fmu=export_fmu))
    monkeypatch.setitem(sys.modules, "fmu_sync.master", types.SimpleNamespace(cosimulate=cosimulate))
    monkeypatch.setitem(sys.modules, "fmu_sync.core.pair", types.SimpleNamespace(simulate_pair=simulate_pair))
    monkeypatch.setattr(scene_mod, "fmu_start_values", lambda fmu, v: {"e": v.system.e})


def test_cosim_scene_plumbing(tmp_path, monkeypatch):
    calls = []
    _fake_cosim_modules(monkeypatch, calls)
    sr = run_scene("forced-pair", tmp_path, plots=False,
                   overrides={"run.mode": "cosim", "run.t_end": 1.0, "run.method": "gauss-seidel"})
    assert calls[0] == ("export", "impact-oscillator")
    assert [c[0] for c in calls] == ["export", "cosim", "cosim", "cosim"], "one FMU for all variants"
    assert [c[1] for c in calls[1:]] == [None, "euclidean", "switching"]
    # every communication step run (the metrics from all of them); run.record_every = 10 steps of
    # solver.dt = 1 step of H kept
    assert all(c[2:6] == (1e-2, "gauss-seidel", 1, False) and c[6] == {"e": 0.9} for c in calls[1:])
    assert np.allclose(np.diff(sr.runs[0].result.t), 1e-2)
    assert len(list(tmp_path.glob("*.fmu"))) == 1 and len(sr.runs) == 3
    assert all(c[7] == "zoh" for c in calls[1:])
    calls.clear()
    run_scene("forced-pair", tmp_path / "foh", plots=False,
              overrides={"run.mode": "cosim", "run.t_end": 1.0, "run.hold": "foh"})
    assert [c[7] for c in calls if c[0] == "cosim"] == ["foh"] * 3     # scene key run.hold -> master
    assert [c[8] for c in calls if c[0] == "cosim"] == ["explicit"] * 3
    calls.clear()
    run_scene("forced-pair", tmp_path / "implicit", plots=False,
              overrides={"run.mode": "cosim", "run.t_end": 1.0, "run.exchange": "implicit"})
    assert [c[8] for c in calls if c[0] == "cosim"] == ["implicit"] * 3   # scene key run.exchange -> master
    assert [c[9] for c in calls if c[0] == "cosim"] == [None] * 3
    calls.clear()
    run_scene("forced-pair", tmp_path / "tol", plots=False,
              overrides={"run.mode": "cosim", "run.t_end": 1.0, "run.tol": 1e-3})
    assert [c[9] for c in calls if c[0] == "cosim"] == [1e-3] * 3   # scene key run.tol -> master


def test_demo_plumbing_with_stand_ins(tmp_path, monkeypatch):
    """run_demo against stand-ins of export/cosimulate/simulate_pair: what it runs and writes."""
    from fmu_sync import plots
    from fmu_sync import run_demo
    calls = []
    _fake_cosim_modules(monkeypatch, calls)

    def stub(result, path, **kw):   # the plots themselves are tested in test_plots.py
        path.write_bytes(b"png")
        return path
    monkeypatch.setattr(plots, "PLOTTERS", {k: stub for k in plots.PLOTTERS})
    monkeypatch.setattr(plots, "compare_plot", lambda results, path, **kw: stub(None, path))
    sr = run_demo(tmp_path, quick=True, n_starts=2)
    kinds = [c[0] for c in calls]
    # the six runs, then the ensemble rate of each coupled law in both modes (2 starts each, the
    # FMU already exported)
    assert kinds == ["export"] + ["cosim", "core"] * 3 + ["cosim"] * 2 + ["core"] * 2 + ["cosim"] * 2 + ["core"] * 2
    assert [c[1] for c in calls[7:]] == ["euclidean"] * 4 + ["switching"] * 4
    assert [(n, mode, e.n_starts, e.median) for n, mode, _, e in sr.ensembles] == [
        ("euclidean-cosim", "cosim", 2, pytest.approx(1.0)), ("euclidean-core", "core", 2, pytest.approx(1.0)),
        ("switching-cosim", "cosim", 2, pytest.approx(1.0)), ("switching-core", "core", 2, pytest.approx(1.0))]
    calls = calls[:7]
    cos = [c for c in calls if c[0] == "cosim"]
    core = [c for c in calls if c[0] == "core"]
    assert [c[1] for c in cos] == [None, "euclidean", "switching"] == [c[1] for c in core]
    assert all(c[2] == 1e-2 and c[4] == 1 for c in cos), "cosim records every communication step H"
    assert all(c[2] == 1e-3 and c[3] == 10 for c in core), "core records on the same grid"
    assert [r.metrics["d_vs_core"] for r in sr.runs] == [0.0] * 6   # identical stand-in data
    summary = (tmp_path / "summary.md").read_text()
    assert "| uncoupled | cosim |" in summary and "| switching | core |" in summary
    assert "## Ensemble decay rate" in summary and "| switching-core | core | switching | 1 [1, 1] | 2/2 |" in summary
    for name in ("compare-distance.png", "compare-euclidean.png", "cosim-vs-core.png",
                 "switching-cosim-distance.png", "euclidean-core.csv"):
        assert (tmp_path / name).stat().st_size > 0, name


def test_the_record_interval_is_said_as_a_time_core_and_cosim():
    """run.record_every counts steps of solver.dt in both modes (issue 36; issue 28: `--set
    run.mode=cosim` recorded every 0.1 s, unsaid): one scene records every 0.01 s in both, and the
    summary's settings and the data file's meta say the interval in seconds, with the steps."""
    from fmu_sync.scenes.loading import load_scene
    from fmu_sync.scenes.running import run_extra, settings_table
    rows = {}
    for mode in ("core", "cosim"):
        sc = load_scene("forced-pair", {"run.mode": mode}, ["switching"])
        rows[mode] = dict(settings_table(sc, sc.variants))["record interval"]
        assert run_extra(sc.variants[0], [], "t")["record_interval"] == pytest.approx(0.01)
    assert rows["core"] == "0.01 s (run.record_every = 10 steps of solver.dt = 0.001 s)"
    assert rows["cosim"] == ("0.01 s (run.record_every = 10 steps of solver.dt = 0.001 s; in co-simulation "
                             "every 1 step of run.H = 0.01 s)")


def test_a_cosim_key_that_would_do_nothing_is_refused_naming_key_and_mode(tmp_path):
    """Issue 44 item 4: ``--set run.tol=1e-4 --set run.exchange=implicit`` on a core-mode variant
    ran and exited 0 on 0.6.0; now the key is refused, naming it and the mode. With
    ``run.mode=cosim`` (or when another selected variant co-simulates) it is accepted."""
    for key, value in (("run.tol", 1e-4), ("run.exchange", "implicit"), ("run.hold", "foh"), ("run.H", 0.02)):
        with pytest.raises(SceneError, match=rf"--set {re.escape(key)} = .*does nothing here.*run.mode = 'core'"):
            load_scene("forced-pair", {key: value}, ["switching"])
        v = load_scene("forced-pair", {key: value, "run.mode": "cosim"}, ["switching"]).variants[0]
        assert v.cfg[key] == value
    scene = tmp_path / "s.toml"
    text = (SCENE_DIR / "forced-pair.toml").read_text()
    scene.write_text(text.replace('name = "switching"', 'name = "switching"\nrun.tol = 1e-4', 1))
    with pytest.raises(SceneError, match=r"runs\[\d\]\.run\.tol = 0\.0001: does nothing in variant 'switching'"):
        load_scene(scene)
    # the scene file's own [run] table may hold them for --set run.mode=cosim (forced-pair sets run.H)
    assert load_scene("forced-pair").variants[0].mode == "core"
