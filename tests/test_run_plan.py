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
    # the registered models and the built-in pendulum scene's declared model (a force law's FMU)
    return {key: export_fmu(key, d / f"{key}.fmu", None) for key in (*contract.MODELS, "pendulum")}


def _variants():
    for name, _ in list_scenes():
        for v in load_scene(name).variants:
            yield name, v.name


def _laws(v):
    spec = v.network
    if spec is not None and spec.laws is not None:
        return [None if x == "none" else x for x in spec.laws]
    return None if v.law == "none" else v.law


def _refusal(run):
    """The type of the refusal ``run()`` raises before its first step, or None if it runs
    (a run that then fails mid-way, RunFailed, ran)."""
    try:
        run()
    except RunRefused as exc:
        return type(exc)
    except RunFailed:
        pass
    return None


def _master_verdict(fmus, v):
    """The master's own decision: a NetworkMaster for the variant, its plan from the values
    each instance would report (the declared defaults with the scene's start values)."""
    from fmu_sync.master import NetworkMaster
    from fmu_sync.scenes.variant import fmu_start_values
    from fmu_sync.user_export import fmu_model_of
    model = fmu_model_of(v.cfg["system.model"], v.system.n)
    fmu = fmus[model.key]
    states = list(v.network.states) if v.is_network else [v.x1, v.x2]
    systems = list(v.network.systems) if v.is_network else [v.system, v.system]
    A = v.network.A if v.is_network else [[0.0, 1.0], [1.0, 0.0]]
    cfg = v.cfg
    real = {x.name: x.start for x in model.declare() if x.causality == "parameter" and x.type == "Real"}
    values = [{**real, **{k: val for k, val in fmu_start_values(fmu, v, s).items() if k in real}} for s in systems]

    def run():
        m = NetworkMaster(fmu, states, A, cfg["run.t_end"], cfg["run.H"], _laws(v), v.Kp, v.Kd,
                          record_every=cfg["run.record_every"], hold=cfg["run.hold"],
                          allow_unstable=cfg["run.allow_unstable"])
        m.plan(values, [cfg["solver.scheme"]] * len(states))
    return _refusal(run)


def _cases():
    """Every built-in variant, in the core (zero-order hold at solver.dt) and, coupled, in
    co-simulation with either hold (at run.H), at steps on both sides of the exchange limit
    of the hold in use and beyond the midpoint limit, and once with run.allow_unstable."""
    for scene, vname in _variants():
        base = load_scene(scene, None, [vname]).variants[0]
        if base.system.omega_max() > 0.0:   # beyond the midpoint limit (a free ball has none)
            wdt = 2.0 / base.system.omega_max()
            yield scene, vname, {"solver.scheme": "midpoint", "solver.dt": 1.05 * wdt}
        if not base.pair:
            yield scene, vname, {}
            continue
        A = base.network.A if base.is_network else None
        laws = edge_laws(_laws(base), edges_of(A) if A is not None else [(0, 1)])
        for mode, hold in (("core", "zoh"), ("cosim", "zoh"), ("cosim", "foh")):
            lim = held_exchange(base.system.M, base.Kp, base.Kd, 1.0, A, laws, hold=hold, allow_unstable=True)[3]
            steps = [0.5, 0.97, 1.03, 2.0] if lim is not None and math.isfinite(lim.H_max) else [float("nan")]
            for f in steps:
                over = {"run.mode": mode, **({"run.hold": hold} if mode == "cosim" else {})}   # issue 44.4
                if math.isfinite(f):
                    over["solver.dt" if mode == "core" else "run.H"] = f * lim.H_max
                yield scene, vname, over
                if f == 2.0:
                    yield scene, vname, {**over, "run.allow_unstable": True}


def test_plan_preflight_core_and_master_agree_on_every_scene(fmus):
    """One run plan (issue 17): for every case of :func:`_cases`, the scene preflight, the
    core driver (run for three steps) and the master's set-up decide alike: the same refusal
    type, or a run. A second copy of any run check that disagrees on a built-in scene fails here."""
    from fmu_sync.scenes.running import plan_variant, run_variant
    seen = {"core": 0, "cosim": 0}
    kinds = set()
    for scene, vname, over in _cases():
        try:
            v = load_scene(scene, over, [vname]).variants[0]
            dt = v.cfg["solver.dt"] if v.mode == "core" or not v.pair else v.cfg["run.H"]
            v = load_scene(scene, {**over, "run.t_end": 3 * dt}, [vname]).variants[0]
        except SceneError:
            continue
        plan = _refusal(lambda: plan_variant(v))
        assert _refusal(lambda: preflight(v, scene)) is plan, (scene, vname, over)
        if v.pair and v.mode == "cosim":
            other = _master_verdict(fmus, v)
        else:
            other = _refusal(lambda: run_variant(v, None, None, scene))
        assert other is plan, (scene, vname, over, plan, other)
        seen[v.mode if v.pair else "core"] += 1
        kinds.add(plan)
    assert seen["core"] >= 30 and seen["cosim"] >= 40, seen
    assert {None, UnstableScheme, UnstableExchange} <= kinds


def test_no_second_copy_of_a_run_check():
    """The run checks are called by the run plan only (core/plan.py), and by their own
    definitions: a module that calls one directly is a second copy of the plan."""
    import ast
    from pathlib import Path
    import fmu_sync
    import fmu_sync.core
    import fmu_sync.fmus
    checks = {"check_stable", "check_start", "check_exchange", "held_exchange", "check_run", "scheme_code",
              "check_common_geometry", "gap"}
    allowed = {
        "core/plan.py": checks,
        "core/checks.py": {"gap"},          # check_start itself
        # other rules: the impact map's domain (on the wall), the gap output, an FMU state's penetration bound
        "core/impact.py": {"gap"}, "fmus/runtime.py": {"gap"}, "fmus/slave.py": {"gap"},
        "core/exchange.py": set(),
        # the exact solvers' one entry (exact_events has no step grid, so no plan): the plan's own
        # start check, and simulate_exact's grid and record
        "core/exact.py": {"check_run", "check_start"},
        "core/model.py": {"gap"},
        # the master refuses a record too large before any instance exists (the plan's step 6)
        "fmu_sync/master.py": {"check_run"},
        # a sweep records the exchange's verdict (it runs either way)
        # ... and refuses a quotient law's system 2 without one impact map (its grid key named)
        "fmu_sync/sweeps/engine.py": {"held_exchange", "check_common_geometry"},
        # a scene's state key, and a quotient law's [network] nodes without one impact map, named where read
        "fmu_sync/scenes/loading.py": {"check_start", "check_common_geometry"},
        "fmu_sync/ssp/runner.py": {"check_common_geometry"},   # an SSP package's components, read, not run
    }
    found = []
    paths = [(Path(pkg.__file__).parent, path) for pkg in (fmu_sync, fmu_sync.core, fmu_sync.fmus)
             for path in sorted(Path(pkg.__file__).parent.glob("*.py" if pkg is fmu_sync else "**/*.py"))]
    paths += [(Path(fmu_sync.__file__).parent, p) for p in sorted(Path(fmu_sync.__file__).parent.glob("*/**/*.py"))]
    for base, path in paths:
        rel = f"{base.name}/{path.relative_to(base).as_posix()}"
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                f = node.func
                name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
                if name in checks and name not in allowed.get(rel, set()):
                    found.append(f"{rel}:{node.lineno} calls {name}")
            if isinstance(node, ast.Compare) and rel != "core/checks.py":   # the midpoint limit written out
                src = ast.unparse(node)
                if "omega_max()" in src and "2" in src:
                    found.append(f"{rel}:{node.lineno}: {src}")
    assert not found, found


def test_every_refusal_has_its_own_type():
    import fmu_sync.core as core
    types = [core.UnstableScheme, core.UnstableExchange, core.InadmissibleState, core.RecordTooLarge]
    assert len(set(types)) == len(types)
    for t in types:
        assert issubclass(t, core.RunRefused) and issubclass(t, ValueError) and not issubclass(t, RunFailed)
        assert t.__name__ in core.__all__
    assert RunRefused is core.RunRefused   # the scenes' refusal is the core's


def test_a_start_inside_the_wall_is_refused_alike_everywhere():
    from fmu_sync.core import InadmissibleState, plan_run, simulate_network, ring
    from fmu_sync.fmus.slave import MechanicalSlave
    model = contract.MODELS["impact-oscillator"]
    slave = MechanicalSlave(model)   # the FMU's own validation (configure)
    params = {**{v.name: v.start for v in model.declare() if v.start is not None}, "q_start": -0.1}
    s = ImpactOscillator(m=1, k=1, e=0.5)
    bad, ok = (-0.1, 0.0), (1.0, 0.0)
    for run in (lambda: simulate(s, bad, 1.0, 1e-3),
                lambda: simulate(s, bad, 1.0, 1e-2, scheme="exact"),
                lambda: simulate_pair(s, ok, bad, 1.0, 1e-3),
                lambda: simulate_network(s, [ok, ok, bad], ring(3), 1.0, 1e-3),
                lambda: plan_run(s, [bad], None, 1e-3),
                lambda: slave.configure(params)):
        with pytest.raises(InadmissibleState, match="violates the constraint: g"):
            run()


def test_the_plan_carries_what_the_drivers_need():
    from fmu_sync.core import plan_run
    s = ImpactOscillator(m=1, k=1, e=0.5)
    p = plan_run(s, [(1.0, 0.0), (0.5, 0.2)], 1.0, 0.3, scheme="theta", theta=0.7, laws=[1], Kp=2.0, Kd=1.0,
                 record_every=2, record_values=5)
    assert (p.grid.steps, p.whole_steps, p.rows) == (4, 3, 3) and p.dt_last == pytest.approx(0.1)
    assert p.code is not None and p.theta == 0.7 and p.coupled
    assert p.q.tolist() == [[1.0], [0.5]] and p.u.tolist() == [[0.0], [0.2]]
    assert p.Kp.tolist() == [[2.0]] and p.limit.stable and p.limit.hold == "zoh"
    with pytest.raises(UnstableExchange):   # the same run at the first-order hold's H, beyond its bound
        plan_run(s, [(1.0, 0.0), (0.5, 0.2)], 10.0, 1.2 * p.limit.H_max, laws=[1], Kp=2.0, Kd=1.0, hold="foh",
                 step_name="H")


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
        simulate(stiff, (1e-6, 0.0), 1.0, 1e-3, scheme="midpoint")
    assert isinstance(err.value, ValueError) and not isinstance(err.value, RunFailed)
    with pytest.raises(UnstableExchange):
        simulate_pair(ImpactOscillator(), (1.0, 0.0), (0.5, 0.0), 1.0, 0.5, coupling="euclidean", Kp=100.0,
                      scheme="midpoint")


def test_the_cli_tells_a_refusal_from_a_failure_by_type(tmp_path, capsys):
    # refused up front (exit 2), whatever the message says; no folder
    assert main(["run", "stiff-wall", "--quiet", "--set", "solver.scheme=midpoint", "-o", str(tmp_path / "s")]) == 2
    assert "omega_max*dt" in capsys.readouterr().err and not (tmp_path / "s").exists()
    from fmu_sync import cli
    assert not hasattr(cli, "_refused_up_front")   # no message matching left in the CLI


def test_no_caller_tells_errors_apart_by_their_text():
    """Refusals and failures are told apart by type: no comparison, prefix test or regex on an
    exception's text in the command line, the scenes, the sweeps or the master."""
    import ast
    from pathlib import Path
    import fmu_sync
    root = Path(fmu_sync.__file__).parent
    paths = [root / "cli.py", root / "master.py", *sorted((root / "scenes").glob("*.py")),
             *sorted((root / "sweeps").glob("*.py"))]
    text = ("str(exc", "str(e)", "str(err", ".args")
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare):
                parts = [node.left, *node.comparators]
            elif isinstance(node, ast.Call) and isinstance(node.func, (ast.Attribute, ast.Name)) and \
                    getattr(node.func, "attr", getattr(node.func, "id", "")) in (
                        "startswith", "endswith", "find", "search", "match", "fullmatch", "findall"):
                parts = [getattr(node.func, "value", node.func), *node.args]
            else:
                continue
            if any(t in ast.unparse(p) for p in parts for t in text):
                found.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    assert not found, found


def test_a_step_as_long_as_the_run_is_refused_in_core_and_cosim(tmp_path, capsys):
    """``fmu-sync run bouncing-ball --set solver.dt=10 --set run.t_end=1`` ran one step and ended at
    q = -3.9 m, exit 0 (issue 28). The run plan's one rule (dt < t_end - t0) refuses it in the core,
    the pair and the master's plan (step H) alike, naming the step and the run's length."""
    from fmu_sync.core import StepTooLarge
    from fmu_sync.core.plan import plan_run
    ball = ImpactOscillator(m=1.0, k=0.0, c=0.0, f0=-9.81, e=0.8)
    for dt in (10.0, 1.0):
        with pytest.raises(StepTooLarge, match=rf"dt = {dt:g} s is not shorter than the run \(t_end - t0 = 1 s\)"):
            simulate(ball, (1.0, 0.0), 1.0, dt)
    with pytest.raises(StepTooLarge):
        simulate_pair(ball, (1.0, 0.0), (0.5, 0.0), 2.0, 2.0, coupling="switching", Kp=1.0, Kd=0.5)
    with pytest.raises(StepTooLarge, match=r"H = 5 s is not shorter"):
        plan_run(ball, [(1.0, 0.0), (0.5, 0.0)], 5.0, 5.0, dt=1e-3, step_name="H", Kp=1.0, Kd=0.5)
    assert simulate(ball, (1.0, 0.0), 1.0, 0.1).q.min() > -0.1 * 9.81   # resolved: O(dt |u|)
    assert main(["run", "bouncing-ball", "--set", "solver.dt=10", "--set", "run.t_end=1", "-o",
                 str(tmp_path / "bb"), "--quiet"]) == 2
    assert "dt = 10 s is not shorter than the run" in capsys.readouterr().err
    assert not (tmp_path / "bb").exists()
