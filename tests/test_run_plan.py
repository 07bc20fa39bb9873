"""One check per rule (issue 17, item 1): the scene preflight and the co-simulation master
make the same exchange check for the hold in use, refusals have their own types."""
from __future__ import annotations

import math

import pytest

from fmu_sync.cli import main
from fmu_sync.core import ImpactOscillator, RunFailed, UnstableExchange, UnstableScheme, simulate, simulate_pair
from fmu_sync.core.network import edge_laws, edges_of, held_exchange
from fmu_sync.fmus import contract
from fmu_sync.scenes.loading import list_scenes, load_scene
from fmu_sync.scenes.running import RunRefused, preflight
from fmu_sync.scenes.schema import SceneError

FOH = ["run", "forced-pair", "--variant", "switching", "--set", "run.mode=cosim", "--set", "coupling.Kp=1800",
       "--set", "coupling.Kd=6", "--set", "run.H=0.01", "--set", "run.hold=foh", "--set", "run.t_end=5"]


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    from fmu_sync.export import export_fmu
    d = tmp_path_factory.mktemp("fmus")
    return {key: export_fmu(key, d / f"{key}.fmu", None) for key in tuple(contract.MODELS)}


def _coupled_variants():
    for name, _ in list_scenes():
        for v in load_scene(name).variants:
            if v.pair:
                yield name, v.name


def _laws(v):
    spec = v.network
    if spec is not None and spec.laws is not None:
        return [None if x == "none" else x for x in spec.laws]
    return None if v.law == "none" else v.law


@pytest.mark.parametrize("hold", ["zoh", "foh"])
def test_preflight_and_master_make_the_same_exchange_check_on_every_scene(fmus, hold):
    """For every coupled variant of every built-in scene, at steps around its limit for the
    hold in use: the scene preflight refuses exactly when the master's own set-up check does
    (with the geometry the master reads back from the FMU)."""
    from fmu_sync.master import NetworkMaster
    checked = 0
    for scene, vname in _coupled_variants():
        base = load_scene(scene, None, [vname]).variants[0]
        A = base.network.A if base.is_network else None
        laws = edge_laws(_laws(base), edges_of(A) if A is not None else [(0, 1)])
        lim = held_exchange(base.system.M, base.Kp, base.Kd, 1.0, A, laws, hold=hold, allow_unstable=True)[3]
        if lim is None or not math.isfinite(lim.H_max):
            continue
        for f in (0.5, 0.97, 1.03, 2.0):
            H = f * lim.H_max
            try:
                v = load_scene(scene, {"run.mode": "cosim", "run.H": H, "run.hold": hold}, [vname]).variants[0]
            except SceneError:
                continue
            try:
                preflight(v, scene)
                refused = False
            except RunRefused:
                refused = True
            model = contract.model_for(v.cfg["system.model"], v.system.n)
            states = list(v.network.states) if v.is_network else [v.x1, v.x2]
            A_run = v.network.A if v.is_network else [[0.0, 1.0], [1.0, 0.0]]
            m = NetworkMaster(fmus[model.key], states, A_run, 1.0, H, _laws(v), v.Kp, v.Kd, hold=hold)
            values = model.values(v.system)   # what the master reads back from the FMU's parameters
            geometry = model.geometry_system({k: values[k] for k in model.geometry})
            try:
                m.check_held_exchange(geometry)
                master_refused = False
            except UnstableExchange:
                master_refused = True
            assert refused == master_refused, (scene, vname, hold, f, H)
            checked += 1
    assert checked >= 20


def test_the_foh_scene_of_issue_17_runs(tmp_path, capsys):
    """Refused before ("omega_c*H = 0.6 against the zero-order-hold bound 0.4") although the
    first-order hold is stable there and the master runs it."""
    assert main(FOH + ["--quiet", "--no-plots", "--format", "npz", "-o", str(tmp_path / "foh")]) == 0
    zoh = [a if a != "run.hold=foh" else "run.hold=zoh" for a in FOH]
    assert main(zoh + ["--quiet", "-o", str(tmp_path / "zoh")]) == 2
    err = capsys.readouterr().err
    assert "zero-order" in err or "zoh" in err
    assert not (tmp_path / "zoh").exists()


def test_refusals_have_their_own_types():
    stiff = ImpactOscillator(m=1, k=1e8, f0=-1, e=0.5)
    with pytest.raises(UnstableScheme) as err:
        simulate(stiff, (1e-6, 0.0), 1.0, 1e-3)
    assert isinstance(err.value, ValueError) and not isinstance(err.value, RunFailed)
    with pytest.raises(UnstableExchange):
        simulate_pair(ImpactOscillator(), (1.0, 0.0), (0.5, 0.0), 1.0, 0.5, coupling="euclidean", Kp=100.0)


def test_the_cli_tells_a_refusal_from_a_failure_by_type(tmp_path, capsys):
    # refused up front (exit 2), whatever the message says; no folder
    assert main(["run", "stiff-wall", "--quiet", "--set", "solver.scheme=midpoint", "-o", str(tmp_path / "s")]) == 2
    assert "omega_max*dt" in capsys.readouterr().err and not (tmp_path / "s").exists()
    from fmu_sync import cli
    assert not hasattr(cli, "_refused_up_front")   # no message matching left in the CLI
