"""The FMU contract (docs/design.md §4.2): one registry, both directions of the
system <-> FMU values conversion, and a clear refusal of a foreign FMU."""
import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from fmu_sync import cosimulate, cosimulate_network
from fmu_sync.core import ImpactOscillator, MechanicalSystem
from fmu_sync.fmus import contract

FOREIGN = Path(__file__).parent / "foreign_fmu"


@pytest.fixture(scope="module")
def foreign_fmu(tmp_path_factory):
    """A small FMI 2.0 CS FMU that is not ours (tests/foreign_fmu), built with gcc."""
    if shutil.which("gcc") is None:  # pragma: no cover - CI has gcc
        pytest.fail("gcc is needed to build the foreign test FMU")
    d = tmp_path_factory.mktemp("foreign")
    so = d / "Spring.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O1", "-Wall", "-Werror", "-o", str(so),
                    str(FOREIGN / "spring.c")], check=True)
    fmu = d / "Spring.fmu"
    with zipfile.ZipFile(fmu, "w") as zf:
        zf.write(FOREIGN / "modelDescription.xml", "modelDescription.xml")
        zf.write(so, "binaries/linux64/Spring.so")
    return fmu


def test_the_foreign_fmu_is_a_working_fmu(foreign_fmu):
    """Independent check that the fixture is a valid FMU: fmpy runs it, and the
    symplectic Euler spring keeps x^2 + v^2/k close to its start value 1."""
    from fmpy import simulate_fmu
    r = simulate_fmu(str(foreign_fmu), stop_time=1.0, step_size=1e-3, output=["x", "v"])
    x, v = r["x"], r["v"]
    assert abs(x[-1] - np.cos(2.0)) < 5e-3
    assert np.max(np.abs(x**2 + v**2 / 4.0 - 1.0)) < 1e-2


@pytest.mark.parametrize("run", ["pair", "network"])
def test_foreign_fmu_is_refused_naming_the_missing_variables(foreign_fmu, run, monkeypatch):
    # the closest model is sought among the built-in models and the user models declared in this
    # process so far (another test file's exports): here the built-ins alone
    monkeypatch.setattr(contract, "DECLARED", {})
    with pytest.raises(contract.ContractError) as err:
        if run == "pair":
            cosimulate(foreign_fmu, (1.0, 0.0), (0.5, 0.0), 1.0, 0.01, coupling="switching", Kp=1.0)
        else:
            cosimulate_network(foreign_fmu, [(1.0, 0.0)] * 3, np.ones((3, 3)) - np.eye(3), 1.0, 0.01)
    msg = str(err.value)
    assert "'Spring' is not an fmu-sync mechanical model" in msg
    for name in ("q", "u", "tau", "q_start", "u_start", "impacts", "m", "e"):
        assert f" {name}," in msg or f" {name} (" in msg, name
    assert isinstance(err.value, ValueError) and not isinstance(err.value, AttributeError)


def test_identify_accepts_every_registered_model_and_names_what_is_missing():
    for m in contract.MODELS.values():
        assert contract.identify([v.name for v in m.declare()], m.identifier) is m
        assert set(m.required()) <= {v.name for v in m.declare()}
    names = [v.name for v in contract.MODELS["mechanical-system-2"].declare() if v.name != "g0"]
    with pytest.raises(contract.ContractError, match="lacks the variables g0 "):
        contract.identify(names, "x")


def test_identify_tells_two_declarations_of_one_interface_apart_by_the_fmus_key(monkeypatch):
    """The same model declared in two files of a session offers one interface (variables and identifier):
    in either order of registration, the key an FMU's build record names picks its own; a key whose
    interface the FMU does not offer is not taken."""
    from fmu_sync.core.registry import load_model
    decl = load_model("pendulum")
    for order in (("a.py:pendulum", "b.py:pendulum"), ("b.py:pendulum", "a.py:pendulum")):
        monkeypatch.setattr(contract, "DECLARED", {})
        fm = {key: contract.declared(decl, key) for key in order}
        names = [v.name for v in fm["a.py:pendulum"].declare()]
        ident = fm["a.py:pendulum"].identifier
        for key in order:
            assert contract.identify(names, ident, key) is fm[key]
        assert contract.identify(names, ident, "impact-oscillator") in fm.values()   # not its interface


def test_system_to_values_and_back_is_the_identity():
    io = contract.MODELS["impact-oscillator"]
    s = ImpactOscillator(m=2.0, k=3.0, c=0.1, f0=0.2, F=0.5, Omega=2.5, e=0.8, phi=0.3)
    back = io.system(io.values(s))
    for a in ("M", "K", "C", "f0", "w"):
        assert np.array_equal(getattr(back, a), getattr(s, a))
    assert (back.g0, back.e, back.forcing) == (s.g0, s.e, s.forcing)
    ms = contract.MODELS["mechanical-system-2"]
    s2 = MechanicalSystem(M=[[2.0, 0.3], [0.3, 1.0]], K=[[3, -1], [-1, 2]], C=[[0.1, 0], [0, 0.2]],
                          f0=[0.1, 0.2], w=[1.0, 0.5], g0=0.1, e=0.6, forcing=(([0.6, 0.1], 1.3, 0.2),))
    v = ms.values(s2)
    assert v["M[1,2]"] == 0.3 and v["w[2]"] == 0.5 and v["F[2]"] == 0.1
    back = ms.system({**{x.name: x.start for x in ms.declare()}, **v})
    for a in ("M", "K", "C", "f0", "w"):
        assert np.array_equal(getattr(back, a), getattr(s2, a))
    assert (back.g0, back.e, back.forcing) == (s2.g0, s2.e, s2.forcing)
    geo = ms.geometry_system(v)
    assert np.array_equal(geo.M, s2.M) and np.array_equal(geo.w, s2.w) and geo.e == s2.e
    assert not geo.K.any()


def test_values_refuse_what_the_fmu_cannot_represent():
    io = contract.MODELS["impact-oscillator"]
    wall = MechanicalSystem(M=[[1.0]], K=[[1.0]], C=[[0.0]], f0=[0.0], w=[2.0], e=0.5)
    with pytest.raises(contract.ContractError, match=r"wall g\(q\) = q \+ g0 \(w = 1\)"):
        io.values(wall)
    two = MechanicalSystem(M=[[1.0]], K=[[1.0]], C=[[0.0]], f0=[0.0], w=[1.0], e=0.5,
                           forcing=(([1.0], 1.0, 0.0), ([1.0], 2.0, 0.0)))
    with pytest.raises(contract.ContractError, match="one forcing term, the system has 2"):
        io.values(two)
    with pytest.raises(ValueError, match="no scheme 'rk4'"):
        io.solver_values(1e-3, "rk4")
    assert io.solver_values(1e-3, "exact") == {"solver.dt": 1e-3, "solver.scheme": 2}
    assert io.solver_values(1e-3, "theta", 0.7) == {"solver.dt": 1e-3, "solver.scheme": 1, "solver.theta": 0.7}


def test_contract_imports_only_the_core_numpy_and_the_standard_library():
    import ast
    import sys
    tree = ast.parse(Path(contract.__file__).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0:
            top = node.module.split(".")[0]
            assert node.module.startswith("fmu_sync.core") or top in sys.stdlib_module_names or top in (
                "numpy", "__future__"), node.module
        elif isinstance(node, ast.ImportFrom):
            # the FMU carries the contract with the core under a package name of its own:
            # the core is imported relatively (..core), nothing else is
            assert node.level == 2 and node.module.split(".")[0] == "core", \
                f"relative import in the contract: {node.module}"
        elif isinstance(node, ast.Import):
            for a in node.names:
                assert a.name.split(".")[0] in sys.stdlib_module_names or a.name == "numpy", a.name
