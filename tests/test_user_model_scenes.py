"""Scenes of a declared model (issue 27): a user's model file in co-simulation (its FMU exported
once per scene run, the master agreeing with the core to round-off at H = dt), the units the
declaration states (q in rad) in the FMU, the records, the plots and the summary, and
``fmu-sync scenes --show``. One export for the module (the user's pendulum)."""
import json
import time
import zipfile
from xml.etree import ElementTree as ET

import numpy as np
import pytest

import fmu_sync
from fmu_sync import report
from fmu_sync.cli import main
from fmu_sync.core import IMPACT_OSCILLATOR, ImpactOscillator, simulate_pair
from fmu_sync.core.examples import DUFFING, PENDULUM, DuffingOscillator, Pendulum
from fmu_sync.core.registry import load_model
from fmu_sync.core.views import figure
from fmu_sync.fmus import contract
from fmu_sync.scenes.running import run_scene

from _user_files import SCENE_PENDULUM as PENDULUM_FILE

SCENE = '''description = "two user pendulums (tests/test_user_model_scenes.py)"

[system]
model = "models/my_pendulum.py:pendulum"
l = 0.8
c = 0.1
q_w = 0.25
e = 0.75

[initial]
x1 = [-0.6, 0.0]
x2 = [-0.1, 1.2]

[coupling]
law = "switching"
Kp = 5.0
Kd = 1.0

[solver]
scheme = "midpoint"
dt = 1e-3

[run]
t_end = 1.5
H = 1e-3

[plot]
plots = ["positions", "phase", "forces"]

[[runs]]
name = "switching"

[[runs]]
name = "uncoupled"
coupling.law = "none"
'''


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The scene in both modes (the user's file found from the scene's folder): the cosim run's
    export counted and timed, the plots' axis labels kept."""
    import fmu_sync.export
    import fmu_sync.plots
    tmp = tmp_path_factory.mktemp("user-scene")
    (tmp / "models").mkdir()
    (tmp / "models" / "my_pendulum.py").write_text(PENDULUM_FILE)
    (tmp / "pendulum-scene.toml").write_text(SCENE)
    exports, labels = [], {}
    real_export, real_save = fmu_sync.export.export_fmu, fmu_sync.plots._save

    def export(*a, **k):
        t0 = time.perf_counter()
        out = real_export(*a, **k)
        exports.append((a, time.perf_counter() - t0))
        return out

    def save(fig, path):
        labels[path.name] = [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes]
        return real_save(fig, path)

    # a decoy: the same model in another file of the session (the same variables and identifier),
    # registered after the scene's own whenever that is registered (a serial run of the suite met
    # it: another module's pendulum); the FMU's build record tells them apart
    (tmp / "models" / "my_pend.py").write_text(PENDULUM_FILE)
    saved = contract.DECLARED.pop("my_pend.py:pendulum", None)   # another module's, put back after
    decoy_decl = load_model(f"{tmp / 'models' / 'my_pend.py'}:pendulum")
    real_declared = contract.declared

    def declared(decl, key=None):
        fm = real_declared(decl, key)
        if key != "my_pend.py:pendulum":
            contract.DECLARED.pop("my_pend.py:pendulum", None)
            real_declared(decoy_decl, "my_pend.py:pendulum")
        return fm
    try:
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(fmu_sync.export, "export_fmu", export)
            mp.setattr(fmu_sync.plots, "_save", save)
            mp.setattr(contract, "declared", declared)
            cosim = run_scene(tmp / "pendulum-scene.toml", tmp / "cosim", {"run.mode": "cosim"})
    finally:
        contract.DECLARED.pop("my_pend.py:pendulum", None)
        if saved is not None:
            contract.DECLARED["my_pend.py:pendulum"] = saved
    core = run_scene(tmp / "pendulum-scene.toml", tmp / "core", plots=False)
    print(f"\nexport of the user's pendulum FMU in the scene run: {[round(s, 1) for _, s in exports]} s")
    return dict(tmp=tmp, cosim=cosim, core=core, exports=exports, labels=labels)


def _description(fmu):
    with zipfile.ZipFile(fmu) as zf:
        return ET.fromstring(zf.read("modelDescription.xml"))


def test_cosim_scene_of_a_user_file_agrees_with_the_core_at_H_equal_dt(runs):
    """Both variants co-simulate the user's FMU (exported once for the scene run, by its file)
    and agree with the core's simulate_pair to round-off: one internal step per exchange. (The
    scene names the midpoint, which the explicit exchange at H = dt reproduces; under the default
    the coupled user-law pair's core and implicit co-simulation differed, q by 3e-3 and u by 3.0
    after 1.5 s, an impact one step apart: reported in issue 40's branch i40-scenes.)"""
    assert len(runs["exports"]) == 1 and str(runs["exports"][0][0][0]).endswith("my_pendulum.py:pendulum")
    assert [f.name for f in runs["cosim"].out_dir.glob("*.fmu")] == ["ScenePendulum.fmu"]
    worst = 0.0
    for c, k in zip(runs["cosim"].runs, runs["core"].runs):
        assert c.result.info["mode"] == "cosim" and not c.metrics.get("error")
        assert c.result.q1.shape == k.result.q1.shape and c.result.impacts1 > 0
        for name in ("q1", "q2", "u1", "u2", "tau1", "tau2"):
            worst = max(worst, float(np.max(np.abs(getattr(c.result, name) - getattr(k.result, name)))))
    print(f"max |cosim - core| over q, u, tau of both variants: {worst:.3g}")
    assert worst <= 1e-12
    sw, unc = (r.result for r in runs["cosim"].runs)
    assert sw.d[-1] < 0.5 * sw.d[0] and np.max(np.abs(unc.tau1)) == 0.0


def test_the_declared_units_reach_the_fmu(runs):
    """q in rad (u in rad/s, tau in N.m) from the one declaration: the FMU's variables and
    UnitDefinitions; the built-in pendulum's FMU interface says rad, Duffing's m."""
    root = _description(next(runs["cosim"].out_dir.glob("*.fmu")))
    unit = {v.get("name"): v[0].get("unit") for v in root.iter("ScalarVariable")}
    assert (unit["q"], unit["u"], unit["tau"], unit["gap"], unit["q_start"], unit["u_start"]) == \
        ("rad", "rad/s", "N.m", "rad", "rad", "rad/s")
    assert unit["percussion"] == "N.m.s"
    defs = {u.get("name"): u[0].attrib for u in root.iter("Unit")}
    assert defs["rad/s"] == {"rad": "1", "s": "-1"} and defs["N.m"] == {"kg": "1", "m": "2", "s": "-2"}
    assert "m/s" not in defs   # no unit the FMU does not use
    for decl, q in ((PENDULUM, "rad"), (DUFFING, "m")):
        declared = {v.name: v.unit for v in contract.declared(decl).declare()}
        assert declared["q"] == q and declared["u"] == f"{q}/s"


def test_the_declared_units_reach_the_records_plots_and_summary(runs):
    for sr in (runs["cosim"], runs["core"]):
        out = sr.out_dir
        header = (out / "switching.csv").read_text().splitlines()[0]
        assert header.startswith("t [s],q1 [rad],u1 [rad/s],q2 [rad],u2 [rad/s],tau1 [N.m],tau2 [N.m]")
        meta = json.loads(str(np.load(out / "switching.npz")["meta"]))
        assert meta["units"]["q"] == "rad" and meta["info"]["units"] == {"q": "rad", "u": "rad/s", "tau": "N.m"}
        summary = (out / "summary.md").read_text()
        assert "| units | `q [rad], u [rad/s], tau [N.m]` |" in summary and "max\\|tau\\| [N.m]" in summary
        for f in ("switching.csv", "switching.npz"):      # read back with its units
            assert fmu_sync.load(out / f).info["units"]["u"] == "rad/s"
    labels = runs["labels"]
    assert labels["switching-positions.png"][0][1] == "position q [rad]"   # q itself, the wall drawn at q = q_w
    assert labels["switching-phase.png"][0] == ("position q [rad]", "velocity u [rad/s]")
    assert "[N.m]" in labels["switching-forces.png"][0][1]
    loaded = fmu_sync.load(runs["cosim"].out_dir / "switching.csv")
    assert figure(loaded).axes[0].get_ylabel() == "position q [rad]"
    assert runs["cosim"].runs[0].result.to_xarray()["u"].attrs["units"] == "rad/s"


def test_a_model_that_declares_no_units_keeps_m(tmp_path):
    """A model that declares no units (the linear built-ins; Duffing's FMU above): m, m/s, N, and
    no units entry in the record."""
    assert IMPACT_OSCILLATOR.units == {"q": "m", "u": "m/s", "tau": "N"} and DUFFING.units["q"] == "m"
    r = simulate_pair(ImpactOscillator(k=1.0, e=0.8), ([0.1], [0.0]), ([0.3], [0.0]), 0.05, 1e-3,
                      coupling="switching", Kp=1.0, Kd=0.5)
    files = report.write_data(r, tmp_path / "d", ("csv",))
    assert files[0].read_text().startswith("t [s],q1 [m],u1 [m/s],q2 [m],u2 [m/s],tau1 [N],tau2 [N]")
    assert "units" not in fmu_sync.load(files[0]).info


def test_scenes_show_prints_the_model_its_parameters_and_units(runs, capsys):
    assert main(["scenes", "--show", str(runs["tmp"] / "pendulum-scene.toml")]) == 0
    text = capsys.readouterr().out
    assert "# units: q [rad], u [rad/s], tau [N.m]" in text
    assert "#   q_w [rad]: wall angle" in text and "#   c [N.m.s/rad]: damping at the pivot" in text
    assert "l = 0.8" in text and 'model = "' in text and "my_pendulum.py:pendulum" in text
    assert main(["scenes", "--show", "pendulum"]) == 0
    assert "# units: q [rad], u [rad/s], tau [N.m]" in capsys.readouterr().out


def test_sync_rate_in_cosim_refuses_a_force_law_system_naming_the_way():
    """A system with a force law cannot give the FMU's parameters (its declaration has them):
    refused before anything is exported, naming the law and the scene route; the contract
    never maps it onto the linear FMU's parameters."""
    with pytest.raises(ValueError, match=r"force law 'pendulum'.*--set run.mode=cosim --starts"):
        fmu_sync.sync_rate(Pendulum(), "switching", 3, x1=([-0.5], [0.0]), x2=([-0.1], [1.0]), t_end=1.0,
                           dt=1e-3, mode="cosim", H=1e-2)
    with pytest.raises(contract.ContractError, match="force law 'duffing'"):
        contract.MODELS["impact-oscillator"].values(DuffingOscillator(g0=0.5))


def test_a_network_node_starts_its_fmu_instance_with_its_own_values(runs):
    """A network of the user's pendulums: each instance's start values are the scene's [system]
    values with the node's table laid over them (the declaration has no inverse of a system)."""
    from fmu_sync.scenes.loading import load_scene
    from fmu_sync.scenes.running import fmu_start_values
    net = runs["tmp"] / "net.toml"
    net.write_text(SCENE.split("[initial]")[0].replace("models/", str(runs["tmp"] / "models") + "/")
                   + '[network]\ngraph = "ring"\nstates = [[-0.6, 0.0], [-0.1, 1.2], [0.0, 0.0]]\n'
                   + 'nodes = [{}, {c = 0.2}, {g = 9.7}]\n\n[coupling]\nlaw = "switching"\nKp = 5.0\nKd = 1.0\n\n'
                   + '[run]\nt_end = 0.1\nmode = "cosim"\n')
    v = load_scene(net).variants[0]
    fmu = next(runs["cosim"].out_dir.glob("*.fmu"))
    starts = [fmu_start_values(fmu, v, s, t) for s, t in zip(v.network.systems, v.network.nodes)]
    assert [(x["c"], x["g"], x["l"], x["q_w"]) for x in starts] == \
        [(0.1, 9.81, 0.8, 0.25), (0.2, 9.81, 0.8, 0.25), (0.1, 9.7, 0.8, 0.25)]
    assert all(x["solver.dt"] == 1e-3 for x in starts)


def test_a_cosim_scene_of_a_model_without_an_fmu_is_refused_at_load(tmp_path):
    """Refused when the scene is read, naming why: a declaration whose defaults make no system
    (a required q_w: its FMU, whose start values are the defaults, cannot be made)."""
    from fmu_sync.scenes.loading import load_scene
    from fmu_sync.scenes.schema import SceneError
    (tmp_path / "m.py").write_text(PENDULUM_FILE.replace('Param("q_w", 0.3,', 'Param("q_w", None,'))
    (tmp_path / "s.toml").write_text(SCENE.replace("models/my_pendulum.py", "m.py"))
    assert load_scene(tmp_path / "s.toml").variants[0].mode == "core"
    with pytest.raises(SceneError, match=r"run.mode = \"cosim\": the FMU of .*m.py:pendulum cannot be made: .*q_w"):
        load_scene(tmp_path / "s.toml", {"run.mode": "cosim"})
