"""FMU export of a model declaration with a force law (docs/user-model.md "Export"): a user's
pendulum written in a file and the built-in Duffing oscillator; fmpy, the plain C host, the
fmu-sync master, and the export's refusals."""
import os
import subprocess
import sys
import zipfile
from xml.etree import ElementTree as ET

import numpy as np
import pytest

from fmu_sync import cosimulate
from fmu_sync.core import simulate
from fmu_sync.core.examples import DUFFING
from fmu_sync.core.registry import load_model
from fmu_sync.export import export_fmu, fmu_guid, main_export, resolve, target_requires

from _user_files import pendulum_file

PENDULUM_FILE = pendulum_file("my_pendulum", "my-pendulum", units=False)
X1, X2 = ([-0.6], [0.0]), ([-0.1], [1.2])


@pytest.fixture(scope="module")
def pend(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("user-model")
    src = tmp / "my_pendulum.py"
    src.write_text(PENDULUM_FILE)
    spec = f"{src}:pendulum"
    fmu = export_fmu(spec, tmp / "pendulum.fmu")
    return {"tmp": tmp, "src": src, "spec": spec, "fmu": fmu, "decl": load_model(spec)}


def _description(fmu):
    with zipfile.ZipFile(fmu) as zf:
        return ET.fromstring(zf.read("modelDescription.xml"))


def test_declared_parameters_are_fmu_parameters(pend):
    root = _description(pend["fmu"])
    assert root.get("modelName") == "MyPendulum"
    by = {v.get("name"): v for v in root.iter("ScalarVariable")}
    for name, unit, lo, start in (("m", "kg", "1e-09", "1.0"), ("g", "m/s2", "0.0", "9.81"),
                                  ("c", "N.m.s/rad", "0.0", "0.05"), ("q_w", "rad", None, "0.3"),
                                  ("e", "1", "0.0", "0.7")):
        real = by[name].find("Real")
        assert by[name].get("causality") == "parameter"
        assert (real.get("unit"), real.get("min"), real.get("start")) == (unit, lo, start), name
    assert by["e"].find("Real").get("max") == "1.0"
    units = {u.get("name"): u.find("BaseUnit").attrib for u in root.iter("Unit")}
    assert units["N.m.s/rad"] == {"kg": "1", "m": "2", "s": "-1", "rad": "-1"}
    # the default start lies inside (gap 1): q_start = w (1 - g0) = -0.7
    assert by["q_start"].find("Real").get("start") == "-0.7"
    # the target needs numpy only (the law runs as native code, the configuration as plain Python)
    key = resolve(pend["spec"])[0]
    assert set(target_requires(key)) == {"numpy"}
    from fmu_sync.fmus.contract import ContractError, model
    with pytest.raises(ContractError, match="no inverse"):   # a system does not give the declared values back
        model(key).values(pend["decl"]())


def test_guid_follows_the_user_code(pend, tmp_path):
    g1 = fmu_guid(pend["spec"])
    assert g1 == _description(pend["fmu"]).get("guid")
    other = tmp_path / "my_pendulum.py"
    other.write_text(PENDULUM_FILE.replace("- c * u[0]", "- c * u[0] * 1.0"))
    assert fmu_guid(f"{other}:pendulum") != g1


def test_fmpy_run_equals_the_core(pend):
    """q of the FMU in fmpy = the core's simulate to round-off, and bit for bit the law's own
    compiled communication step (the code compiled into the binary, here JIT-compiled for this
    CPU) called with fmpy's communication points: fmpy steps from t_k = k H by
    ``t_(k+1) - t_k`` (not H: ``(k+1) H - k H`` differs from H by round-off), which moves the
    end ``t_k + H_k`` of each step's shortened last internal step -- the round-off by which the
    FMU differed from ``advance(.., k H, H, ..)``."""
    from fmpy import simulate_fmu
    dt, H, T = 1e-3, 1e-2, 4.0
    r = simulate_fmu(str(pend["fmu"]), stop_time=T, output_interval=H, output=["q", "u", "impacts"],
                     start_values={"q_start": X1[0][0], "solver.dt": dt})
    system = pend["decl"]()
    c = simulate(system, X1, T, dt, record_every=10)
    assert r["impacts"][-1] >= 2 and len(r) == c.q.shape[0]
    assert np.max(np.abs(r["q"] - c.q[:, 0])) <= 1e-12
    adv = system.force.kernels().advance
    q, u, tau, out = np.array(X1[0]), np.array(X1[1]), np.zeros(1), [X1[0][0]]
    for k in range(len(r) - 1):
        adv(system.arrays(), system.p, q, u, k * H, (k + 1) * H - k * H, dt, tau, 3, 0.5)   # 3: trapezoid
        out.append(q[0])
    assert np.array_equal(r["q"], np.array(out))


@pytest.mark.parametrize("scheme", [0, 1, 3])
def test_the_fmu_step_is_the_laws_advance_bit_for_bit(pend, scheme):
    """The law's FMU steps with the law's own ``advance`` (fmus/law_stepper.py: the stepper's
    communication step with the law's ``advance_in``): zero-order and first-order hold of the
    input (fmi2SetRealInputDerivatives), both schemes, bit for bit."""
    from fmu_sync.fmi_bridge import FMUHost
    system = pend["decl"]()
    adv = system.force.kernels().advance
    host = FMUHost(pend["fmu"])
    try:
        name = next(v.name for v in host.md.modelVariables if v.causality == "input")
        host.initialize(0.0, {"q_start": X1[0][0], "solver.dt": 1e-3, "solver.scheme": scheme,
                              "solver.theta": 0.7 if scheme == 1 else 0.5})
        q, u, H = np.array(X1[0]), np.array(X1[1]), 0.05
        for k in range(40):
            tau, slope = np.array([0.3 * np.sin(k)]), np.array([2.0 * np.cos(k)]) if k % 2 else np.zeros(1)
            host.set({name: tau[0]})
            host.set_input_derivatives({name: slope[0]})
            assert host.do_step(k * H, H) == 0
            adv(system.arrays(), system.p, q, u, k * H, H, 1e-3, tau, scheme, 0.7 if scheme == 1 else 0.5, slope)
            assert host.get(["q", "u"]) == [q[0], u[0]], k
        assert host.get(["impacts"])[0] > 0
    finally:
        host.close()


def test_c_host_runs_it(pend, c_host):
    """The plain C host (no Python in the host, a clean environment) runs the user's FMU and
    reproduces fmpy's numbers."""
    from _children import unpack_fmu
    from fmpy import simulate_fmu
    from tests.test_fmu_c_host import _clean_env, _read_csv
    tmp = pend["tmp"]
    host = c_host
    unz = unpack_fmu(pend["fmu"], tmp / "unz")
    vr = {v.get("name"): v.get("valueReference") for v in _description(pend["fmu"]).iter("ScalarVariable")}
    out = tmp / "host.csv"
    p = subprocess.run([str(host), str(unz), "--stop", "3", "--step", "0.01", "--var", vr["q"], "--var", vr["u"],
                        "--out", str(out)], capture_output=True, text=True, timeout=300, env=_clean_env())
    assert p.returncode == 0, p.stdout + p.stderr[-2000:]
    rows = _read_csv(out)
    ref = simulate_fmu(str(pend["fmu"]), stop_time=3.0, output_interval=0.01, output=["q", "u"])
    assert np.max(np.abs(rows[:, 1] - ref["q"])) <= 1e-12
    assert np.ptp(rows[:, 1]) > 0.5


def test_two_instances_synchronize_under_the_switching_law(pend):
    r = cosimulate(str(pend["fmu"]), X1, X2, 20.0, 1e-2, coupling="switching", Kp=5.0, Kd=1.0)
    d = np.asarray(r.d)
    assert d[0] > 0.1 and np.max(np.abs(d[-100:])) < 1e-3 * d[0]
    unc = cosimulate(str(pend["fmu"]), X1, X2, 20.0, 1e-2, coupling=None)
    assert np.max(np.abs(np.asarray(unc.d)[-100:])) > 1e-2      # without the law they stay apart
    # the first-order hold (input derivatives: the law's step takes the input at each force point)
    foh = cosimulate(str(pend["fmu"]), X1, X2, 20.0, 1e-2, coupling="switching", Kp=5.0, Kd=1.0, hold="foh")
    d2 = np.asarray(foh.d)
    assert np.max(np.abs(d2[-100:])) < 1e-3 * d2[0] and not np.array_equal(d2, d)


def test_builtin_duffing_exports_and_runs(tmp_path):
    from fmpy import simulate_fmu
    fmu = export_fmu("duffing", tmp_path / "duffing.fmu", {"F": 0.5, "Omega": 1.3, "g0": 0.5, "c": 0.05,
                                                              "q_start": 0.5})
    r = simulate_fmu(str(fmu), stop_time=5.0, output_interval=0.01, output=["q", "impacts"])
    c = simulate(DUFFING(F=0.5, Omega=1.3, g0=0.5, c=0.05), ([0.5], [0.0]), 5.0, 1e-3, record_every=10)
    assert r["impacts"][-1] >= 1
    assert np.max(np.abs(r["q"] - c.q[:, 0])) <= 1e-12


def _refused(capsys, *argv):
    assert main_export(list(argv)) == 2
    return capsys.readouterr().err


def test_export_refusals_name_what_is_wrong(tmp_path, capsys):
    out = str(tmp_path / "x.fmu")
    err = _refused(capsys, str(tmp_path / "nope.py") + ":pendulum", "-o", out)
    assert "no file" in err and "nope.py" in err
    good = tmp_path / "m.py"
    good.write_text(PENDULUM_FILE)
    err = _refused(capsys, f"{good}:pendulm", "-o", out)
    assert "no Model named 'pendulm'" in err and "pendulum" in err
    bad = tmp_path / "bad.py"
    bad.write_text(PENDULUM_FILE.replace("return -m * g", "return {'a': object()} or -m * g"))
    err = _refused(capsys, f"{bad}:pendulum", "-o", out)
    assert "force law 'my_pendulum' is not numba-compilable" in err
    assert not os.path.exists(out)


def test_a_fresh_master_process_finds_the_declaration(pend):
    """cosimulate in a process that did not export: the declaration comes from the FMU's build record."""
    code = ("import sys, numpy as np\n"
            "from fmu_sync import cosimulate\n"
            f"r = cosimulate({str(pend['fmu'])!r}, ([-0.6], [0.0]), ([-0.1], [1.2]), 2.0, 1e-2, "
            "coupling='switching', Kp=5.0, Kd=1.0)\n"
            "print(float(np.asarray(r.d)[0]), float(np.asarray(r.d)[-1]))\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    d0, d1 = map(float, p.stdout.split()[-2:])
    assert d1 < d0


def test_carried_code_configures_without_numba(pend, tmp_path):
    """The FMU's carried code (the user's file included) imports and configures a parameter set
    with numba unimportable: the law's checks run as plain Python."""
    pkg = tmp_path / "fmu_sync_mtest"
    with zipfile.ZipFile(pend["fmu"]) as zf:
        for name in zf.namelist():
            if name.startswith("resources/fmu_sync_code/") and name.endswith(".py"):
                target = pkg / name[len("resources/fmu_sync_code/"):]
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(zf.read(name))
    code = ("import sys\n"
            "sys.modules['numba'] = None\n"
            f"sys.path.insert(0, {str(tmp_path)!r})\n"
            "import fmu_sync_mtest.user.runtime as rt\n"
            "from fmu_sync_mtest.fmus.slave import MechanicalSlave\n"
            "from fmu_sync_mtest.fmus.contract import model\n"
            "s = MechanicalSlave(model(rt.KEY))\n"
            "cfg = s.configure(s.start_parameters({'c': 0.2, 'q_start': -0.5}))\n"
            "print(type(cfg.system.force).__module__, cfg.system.p.tolist(), s.N_P)\n"
            "try:\n"
            "    s.configure(s.start_parameters({'q_start': 0.5}))\n"
            "except ValueError as exc:\n"
            "    print('refused:', exc)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    first, second = p.stdout.strip().splitlines()[-2:]
    assert first == "fmu_sync_mtest.core.forcelaw [1.0, 9.81, 0.5, 0.2] 4"
    assert second.startswith("refused:") and "q_start" in second


def test_the_carried_file_imports_the_carried_core_line_for_line():
    from fmu_sync.core.declaration import ModelError
    from fmu_sync.user_export import rewrite_imports
    src = (b"from fmu_sync.core import (ForceLaw,\n    Model)\n"
           b"from fmu_sync.core.examples import PENDULUM as P\nx = 1\n")
    out = rewrite_imports(src, "t.py").decode().splitlines()
    assert out == ["from ..core.forcelaw import ForceLaw; from ..core.declaration import Model", "",
                   "from ..core.examples import PENDULUM as P", "x = 1"]
    for bad, why in ((b"import fmu_sync\n", "cannot travel"), (b"from fmu_sync import cosimulate\n", "fmu_sync.master"),
                     (b"from fmu_sync.core import *\n", "name what you import")):
        with pytest.raises(ModelError, match=why):
            rewrite_imports(bad, "t.py")


TWO_TERMS_FILE = '''"""A user's oscillator with nt declared harmonic forcing terms (default 2)."""
from fmu_sync.core import ForceLaw, MechanicalSystem, Model, Param


def h(q, u, tau, t, p):
    return -p[0] * q[0] - 0.1 * u[0] + tau[0]


law = ForceLaw(h, n=1, name="two_terms",
               params=(Param("k", 1.0, "N/m", 0.0, None, "stiffness"),
                       Param("nt", 2.0, "1", 0.0, 3.0, "number of forcing terms")),
               forcing=lambda p: tuple((0.4 / (j + 1), 1.3 * (j + 1), 0.2 * j) for j in range(int(p[1]))))

model = Model("two-terms", "an oscillator forced by nt harmonic terms",
              params=(Param("g0", 0.5, "m", None, None, "wall offset"),
                      Param("e", 0.8, "1", 0.0, 1.0, "restitution")),
              force=law, geometry=("g0", "e"),
              system=lambda p: MechanicalSystem(M=[[1.0]], w=[1.0], g0=p.g0, e=p.e, force=law, params=p.of(law)))
'''


def test_a_law_with_two_forcing_terms_exports_runs_and_refuses_a_third(tmp_path):
    """The FMU's work array holds the forcing terms the law declares at its defaults (here 2;
    it held 1 before, and fmi2ExitInitializationMode was fmi2Fatal); a parameter set that makes
    more is refused with fmi2Error and the reason, not packed out of bounds."""
    from fmpy import simulate_fmu
    src = tmp_path / "two_terms.py"
    src.write_text(TWO_TERMS_FILE)
    spec = f"{src}:model"
    fmu = export_fmu(spec, tmp_path / "two.fmu")
    system = load_model(spec)()
    assert len(system.forcing) == 2
    x0, dt, H, T = ([0.2], [0.0]), 1e-3, 1e-2, 4.0
    r = simulate_fmu(str(fmu), stop_time=T, output_interval=H, output=["q", "impacts"],
                     start_values={"q_start": x0[0][0], "solver.dt": dt})
    c = simulate(system, x0, T, dt, record_every=10)
    assert r["impacts"][-1] >= 1 and len(r) == c.q.shape[0]
    assert np.max(np.abs(r["q"] - c.q[:, 0])) <= 1e-12
    with pytest.raises(Exception, match=r"fmi2ExitInitializationMode failed with status 3 \(error\)"):
        simulate_fmu(str(fmu), stop_time=0.1, output_interval=H, start_values={"nt": 3.0})


def test_a_second_export_of_the_file_compiles_nothing(pend, tmp_path, capsys):
    """Issue 36 item 4: the law's FMU stepper is cached on disk like the built-in one. This
    process's copy forgotten (as in a new process), a second export of the same file loads it
    from numba's cache: no compilation (the compile counter unchanged, a cache hit, no progress
    line) and the same FMU, byte for byte."""
    from fmu_sync.fmus import law_stepper as LS
    law = pend["decl"].force
    key = LS.stepper_key(law)
    assert key in LS._STEPPERS
    before = LS.compiled()
    del LS._STEPPERS[key]
    assert main_export([pend["spec"], "-o", str(tmp_path / "again.fmu")]) == 0
    assert LS.compiled() == before
    assert LS._STEPPERS[key].cache_hits == 1
    assert "compiling" not in capsys.readouterr().err
    assert (tmp_path / "again.fmu").read_bytes() == pend["fmu"].read_bytes()


def test_the_stepper_cache_key_follows_the_laws_code(pend, tmp_path):
    """The key changes with an edit of h (core/law_key.py: of what numba compiles of it) and with a
    parameter more (the stepper reads N_P of them: the law's key alone, which is h's, would hand it the
    other law's stepper), not with another edit of the rest of the file, nor with where the file lies."""
    from fmu_sync.fmus.law_stepper import stepper_key
    key = stepper_key(pend["decl"].force)
    moved = tmp_path / "elsewhere" / "my_pendulum.py"
    moved.parent.mkdir()
    moved.write_text(PENDULUM_FILE)
    appended = tmp_path / "my_pendulum.py"
    appended.write_text(PENDULUM_FILE + "\nUNUSED = 1\n")
    edited = tmp_path / "my_pendulum_edited.py"
    edited.write_text(PENDULUM_FILE.replace("- c * u[0]", "- c * u[0] * 1.0"))
    assert stepper_key(load_model(f"{moved}:pendulum").force) == key
    assert stepper_key(load_model(f"{appended}:pendulum").force) == key
    assert stepper_key(load_model(f"{edited}:pendulum").force) != key
    more = tmp_path / "my_pendulum_more.py"
    more.write_text(PENDULUM_FILE.replace('"damping at the pivot")),', '"damping at the pivot"),\n'
                                          '                       Param("spare", 0.0, "1", None, None, "unused")),'))
    law = load_model(f"{more}:pendulum").force
    assert len(law.params) == 5 and law.key == pend["decl"].force.key and stepper_key(law) != key
