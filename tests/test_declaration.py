"""The one model declaration (docs/design.md §2.1.1): a Model's parameters drive the core's
checks, the FMU's parameters and the scenes' [system] keys; a user model is the same kind of
object, named in a scene as "path/to/model.py:name"."""
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from fmu_sync import load_scene
from fmu_sync.core import (IMPACT_OSCILLATOR, MECHANICAL_SYSTEM, ImpactOscillator, Model, ModelError, Param,
                           load_model)
from fmu_sync.fmus import contract
from fmu_sync.scenes.schema import REQUIRED, SYSTEM_KEYS, SceneError
from test_scenes import write

USER_MODEL = '''
from fmu_sync.core import MechanicalSystem, Model, Param

def _system(p):
    # a mass on a spring hitting a stop at q = -gap0 (w = 1, g0 = gap0), in the user's coordinates
    return MechanicalSystem(M=[[p.m]], K=[[p.k]], C=[[p.c]], f0=[0.0], w=[1.0], g0=p.gap0, e=p.e)

stop = Model(
    name="spring-stop", description="mass on a spring against a stop",
    params=(Param("m", 2.0, "kg", 1e-9, None, "Mass"),
            Param("k", 50.0, "N/m", 0.0, None, "Spring stiffness"),
            Param("c", 0.1, "N.s/m", 0.0, None, "Damping"),
            Param("gap0", 0.05, "m", 0.0, 1.0, "Distance of the stop from the rest position"),
            Param("e", 0.7, "1", 0.0, 1.0, "Restitution")),
    system=_system, n=1, geometry=("m", "gap0", "e"))
'''


def _arrays_equal(a, b):
    for x, y in zip(a.arrays(), b.arrays()):
        assert np.array_equal(np.asarray(x), np.asarray(y))


def test_the_builtin_declarations_build_the_same_systems_bit_for_bit():
    kw = dict(m=2.0, k=50.0, c=0.1, f0=0.3, F=1.0, Omega=3.0, phi=0.2, e=0.7, g0=0.05)
    _arrays_equal(IMPACT_OSCILLATOR(**kw), ImpactOscillator(**kw))
    s = MECHANICAL_SYSTEM(M=[[2, 0.5], [0.5, 1]], w=[1, 0.5], e=0.7, forcing=[([0.6, 0.0], 1.3, 0.0)])
    assert not s.K.any() and not s.f0.any() and s.forcing == (((0.6, 0.0), 1.3, 0.0),) and s.n == 2


@pytest.mark.parametrize("kw, words", [
    (dict(m=0.0, e=0.5), ["impact-oscillator", "parameter m = 0.0", "> 0"]),
    (dict(e=1.5), ["parameter e = 1.5", "in [0, 1]"]),
    (dict(k=float("nan"), e=0.5), ["parameter k", "not finite"]),
    (dict(mass=1.0, e=0.5), ["no parameter mass", "m, k, c, f0, F, Omega, phi, e, g0"]),
    (dict(m=1.0), ["parameter e is required"]),
])
def test_values_outside_the_declaration_are_refused_naming_them(kw, words):
    with pytest.raises(ModelError) as err:
        IMPACT_OSCILLATOR(**kw)
    assert all(w in str(err.value) for w in words), str(err.value)


def test_a_declaration_is_checked_when_made():
    with pytest.raises(ModelError, match="declares the parameter.* m twice"):
        Model("x", "", (Param("m", 1.0), Param("m", 2.0)), system=lambda p: None)
    with pytest.raises(ModelError, match="geometry names undeclared parameters M"):
        Model("x", "", (Param("m", 1.0),), system=lambda p: None, geometry=("M",))


@pytest.mark.parametrize("key", list(contract.MODELS))
def test_the_fmu_parameters_are_the_declaration(key):
    fm = contract.MODELS[key]
    decl = fm.declaration
    params = {v.name: v for v in fm.declare() if v.causality == "parameter"}
    for p in decl.params:
        names = contract._flat_names(p, fm.n)
        assert all(x in params for x in names), (p.name, names)
        if p.shape == ():
            v = params[p.name]
            assert (v.unit, v.min, v.max, v.description) == (p.unit, p.min, p.max, p.description)
    assert set(fm.geometry) <= set(params)
    assert fm.family == decl.name


@pytest.mark.parametrize("name", list(SYSTEM_KEYS))
def test_the_scene_keys_are_the_declaration(name):
    decl = load_model(name)
    keys = SYSTEM_KEYS[name]
    assert list(keys) == ["model"] + [p.name for p in decl.params]
    for p in decl.params:
        key = keys[p.name]
        assert key.doc == p.description
        assert key.default is REQUIRED if p.required else key.default == (list(p.default) if isinstance(
            p.default, tuple) else p.default)


@pytest.fixture()
def user_scene(tmp_path):
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "stop.py").write_text(USER_MODEL)
    scene = write(tmp_path, textwrap.dedent('''
        description = "a user model"
        [system]
        model = "models/stop.py:stop"
        k = 40.0
        [initial]
        x1 = [0.2, 0.0]
        x2 = [0.1, 0.5]
        [coupling]
        law = "switching"
        Kp = 20.0
        Kd = 2.0
        [run]
        t_end = 2.0
        [solver]
        dt = 1e-3
        '''), "stop.toml")
    return scene


def test_a_user_model_runs_in_a_scene_with_its_declared_parameters(user_scene):
    v = load_scene(user_scene).variants[0]
    assert v.cfg["system.k"] == 40.0 and v.cfg["system.gap0"] == 0.05      # set, and the declared default
    assert v.system.g0 == 0.05 and v.system.K[0, 0] == 40.0 and v.system.M[0, 0] == 2.0
    assert v.cfg["system.model"].endswith("models/stop.py:stop")
    from fmu_sync.scenes.running import run_scene
    run_scene(user_scene, user_scene.parent / "out", plots=False)
    assert list((user_scene.parent / "out").rglob("*.csv"))


@pytest.mark.parametrize("text, words", [
    ('model = "models/stop.py:stop"\nmass = 1.0', ["unknown key system.mass", "m, k, c, gap0, e"]),
    ('model = "models/stop.py:stop"\ngap0 = 2.0', ["gap0 = 2.0", "[0, 1]"]),
    ('model = "models/none.py:stop"', ["system.model", "no file"]),
    ('model = "models/stop.py:pendulum"', ["no Model named 'pendulum'", "(it has stop)"]),
    ('model = "swing"', ["system.model", "path/to/model.py:name"]),
])
def test_a_bad_user_model_is_refused_naming_it(user_scene, text, words):
    src = user_scene.read_text().replace('model = "models/stop.py:stop"\nk = 40.0', text)
    user_scene.write_text(src)
    with pytest.raises(SceneError) as err:
        load_scene(user_scene)
    assert all(w in str(err.value) for w in words), str(err.value)


def test_scenes_show_prints_the_user_model_and_loads_back(user_scene, tmp_path):
    p = subprocess.run([sys.executable, "-m", "fmu_sync.cli", "scenes", "--show", str(user_scene)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert "# spring-stop: mass on a spring against a stop" in p.stdout
    assert "#   gap0 [m]: Distance of the stop from the rest position" in p.stdout
    assert "k = 40.0" in p.stdout and "gap0 = 0.05" in p.stdout
    again = tmp_path / "again.toml"
    again.write_text(p.stdout)
    cfg = lambda path: {k: x for k, x in load_scene(path).variants[0].cfg.items() if not k.startswith("plot.")}  # noqa: E731
    assert cfg(again) == cfg(user_scene)


def test_the_builtin_nonlinear_models_are_declarations_and_the_pendulum_scene_synchronizes():
    from fmu_sync.core import simulate_pair
    from fmu_sync.core.examples import DUFFING, PENDULUM, DuffingOscillator, Pendulum, pendulum_law
    assert set(pendulum_law.params) <= set(PENDULUM.params) and PENDULUM.n == 1
    _arrays_equal(PENDULUM(m=2.0, l=0.5, q_w=0.3, e=0.6), Pendulum(m=2.0, l=0.5, q_w=0.3, e=0.6))
    _arrays_equal(DUFFING(k3=2.0, g0=0.1, F=0.5), DuffingOscillator(k3=2.0, g0=0.1, F=0.5))
    with pytest.raises(ModelError, match=r"model 'pendulum': parameter l = -1.0 .*below"):
        PENDULUM(l=-1.0)
    v = load_scene("pendulum").variants[0]
    assert v.system.force is pendulum_law and v.system.g0 == v.cfg["system.q_w"] == 0.2
    r = simulate_pair(v.system, v.x1, v.x2, v.cfg["run.t_end"], v.cfg["solver.dt"], coupling=v.law, Kp=v.Kp, Kd=v.Kd)
    assert r.impacts1 > 3 and r.d[-1] < 1e-5 * r.d[0]
    # its FMU is the declaration's (issue 27; run in tests/test_user_model_scenes.py)
    assert load_scene("pendulum", {"run.mode": "cosim"}).variants[0].mode == "cosim"
