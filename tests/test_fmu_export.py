"""FMU export and modelDescription.xml (docs/design.md §4.3). Nothing here loads the FMU's
binary: the FMUs are run in child processes by tests/test_fmu_run.py."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import zipfile

import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from fmu_sync.export import MODELS, export_fmu, main_export

IDENT = {"impact-oscillator": "ImpactOscillator", "mechanical-system-2": "MechanicalSystem2"}


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("fmus")
    return {m: export_fmu(m, d / f"{IDENT[m]}.fmu") for m in MODELS}


def _md(path):
    return read_model_description(str(path), validate=True)


def _vars(path):
    return {v.name: v for v in _md(path).modelVariables}


@pytest.mark.parametrize("model", sorted(MODELS))
def test_schema_and_fmpy_validation(fmus, model):
    path = fmus[model]
    md = _md(path)  # raises on a schema or semantic problem
    assert md.fmiVersion == "2.0"
    assert md.coSimulation.modelIdentifier == IDENT[model]
    assert validate_fmu(str(path)) == []
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
    assert f"binaries/linux64/{IDENT[model]}.so" in names
    # the FMU carries its code (core + slave), its boot script and how it finds Python
    assert "resources/fmu_sync_code/core/moreau.py" in names
    assert "resources/fmu_sync_code/fmus/stepper.py" in names
    assert "resources/fmu_sync_code/fmus/contract.py" in names
    assert {"resources/fmu_sync_build.json", "resources/fmu_sync_python.txt"} <= names
    assert any(n.startswith("resources/fmu_sync_boot_") and n.endswith(".py") for n in names)


@pytest.mark.parametrize("model", sorted(MODELS))
def test_capabilities_are_declared(fmus, model):
    cs = _md(fmus[model]).coSimulation
    assert cs.canHandleVariableCommunicationStepSize
    assert cs.canGetAndSetFMUstate
    assert cs.canSerializeFMUstate
    assert cs.canInterpolateInputs                # first-order hold (fmi2SetRealInputDerivatives)
    assert not cs.providesDirectionalDerivative
    assert not cs.canBeInstantiatedOnlyOncePerProcess


@pytest.mark.parametrize("model", sorted(MODELS))
def test_every_variable_is_described_with_units(fmus, model):
    md = _md(fmus[model])
    units = {u.name: u for u in md.unitDefinitions}
    for v in md.modelVariables:
        assert v.description, v.name
        if v.type == "Real":
            assert v.unit in units, v.name
    base = {name: {k: getattr(u.baseUnit, k) for k in ("kg", "m", "s", "rad")} for name, u in units.items()}
    assert base["N"] == {"kg": 1, "m": 1, "s": -2, "rad": 0}
    assert base["N.s"] == {"kg": 1, "m": 1, "s": -1, "rad": 0}
    assert base["m/s"] == {"kg": 0, "m": 1, "s": -1, "rad": 0}
    assert base["J"] == {"kg": 1, "m": 2, "s": -2, "rad": 0}


def test_impact_oscillator_interface(fmus):
    v = _vars(fmus["impact-oscillator"])
    assert (v["tau"].causality, v["tau"].variability, v["tau"].unit) == ("input", "continuous", "N")
    for name, unit in (("q", "m"), ("u", "m/s"), ("gap", "m"), ("percussion", "N.s"), ("energy", "J")):
        assert v[name].causality == "output" and v[name].initial == "calculated" and v[name].unit == unit
    assert v["impacts"].type == "Integer" and v["impacts"].causality == "output"
    for name in ("m", "k", "c", "f0", "F", "Omega", "phi", "e", "q_start", "u_start",
                 "solver.dt", "solver.scheme", "solver.theta"):
        assert (v[name].causality, v[name].variability, v[name].initial) == ("parameter", "fixed", "exact")
        assert v[name].start is not None
    assert 0.0 < float(v["m"].min) < 1e-300
    assert 0.0 < float(v["solver.dt"].min) < 1e-300
    assert (float(v["e"].min), float(v["e"].max)) == (0.0, 1.0)
    assert (float(v["solver.theta"].min), float(v["solver.theta"].max)) == (0.5, 1.0)
    # the wall moves with g0 (g(q) = q + g0 >= 0): q_start's bounds are the state bound, the wall is
    # checked on the parameter set (configure: g(q_start) >= 0)
    assert (float(v["q_start"].min), float(v["q_start"].max)) == (-1e12, 1e12)
    assert v["solver.scheme"].type == "Enumeration"
    items = {i.name: int(i.value) for i in v["solver.scheme"].declaredType.items}
    assert items == {"midpoint": 0, "theta": 1, "exact": 2, "trapezoid": 3}     # the core's scheme codes
    assert int(v["solver.scheme"].start) == items["trapezoid"]                  # the core's default


def test_model_structure_dependencies(fmus):
    md = _md(fmus["impact-oscillator"])
    names = [v.name for v in md.modelVariables]
    assert [u.variable.name for u in md.outputs] == ["q", "u", "gap", "impacts", "percussion", "energy"]
    assert all(u.dependencies == [] for u in md.outputs)  # no direct feedthrough of tau
    init = {u.variable.name: sorted(d.name for d in u.dependencies) for u in md.initialUnknowns}
    assert init["q"] == ["q_start"] and init["u"] == ["u_start"]
    assert init["energy"] == sorted(["m", "k", "f0", "q_start", "u_start"])
    assert init["impacts"] == [] and init["percussion"] == []
    assert names.index("tau") < names.index("q")


def test_two_dof_interface(fmus):
    v = _vars(fmus["mechanical-system-2"])
    for name in ("M[1,1]", "M[1,2]", "M[2,1]", "M[2,2]", "K[1,2]", "C[2,2]", "w[1]", "w[2]", "g0", "e",
                 "q_start[1]", "u_start[2]", "f0[2]", "F[1]", "Omega", "phi"):
        assert v[name].causality == "parameter", name
    for name in ("tau[1]", "tau[2]"):
        assert v[name].causality == "input"
    for name in ("q[1]", "q[2]", "u[1]", "u[2]", "gap", "impacts", "percussion", "energy"):
        assert v[name].causality == "output"
    assert float(v["M[1,1]"].min) > 0.0 and v["M[1,2]"].min is None
    md = _md(fmus["mechanical-system-2"])
    init = {u.variable.name: {d.name for d in u.dependencies} for u in md.initialUnknowns}
    assert init["gap"] == {"w[1]", "w[2]", "g0", "q_start[1]", "q_start[2]"}


def test_start_values_reach_the_model_description(tmp_path):
    path = export_fmu("impact-oscillator", tmp_path / "io.fmu",
                      {"e": 0.5, "solver.scheme": "theta", "solver.dt": 1e-4, "q_start": 0.25, "tau": 0.1})
    v = _vars(path)
    assert float(v["e"].start) == 0.5
    assert int(v["solver.scheme"].start) == 1
    assert float(v["solver.dt"].start) == 1e-4
    assert float(v["q_start"].start) == 0.25
    assert float(v["tau"].start) == 0.1
    with zipfile.ZipFile(path) as zf:
        data = json.loads(zf.read("resources/fmu_sync_start.json"))
    # The slave reads the same values at instantiation: one source for both.
    for name, var in v.items():
        if var.start is not None:
            assert data["start"][name] == pytest.approx(float(var.start), rel=0, abs=0), name


def test_export_is_reproducible(tmp_path):
    a = export_fmu("mechanical-system-2", tmp_path / "a.fmu", {"M[1,2]": 0.3, "M[2,1]": 0.3})
    b = export_fmu("mechanical-system-2", tmp_path / "b.fmu", {"M[2,1]": 0.3, "M[1,2]": 0.3})
    assert a.read_bytes() == b.read_bytes()
    c = export_fmu("mechanical-system-2", tmp_path / "c.fmu")
    assert _md(a).guid != _md(c).guid


@pytest.mark.parametrize("model, values, message", [
    ("impact-oscillator", {"nonsense": 1.0}, "no variable 'nonsense'"),
    ("impact-oscillator", {"q": 1.0}, "q is an output"),
    ("impact-oscillator", {"e": 1.5}, "e"),
    ("impact-oscillator", {"m": 0.0}, "must be > 0"),
    ("impact-oscillator", {"solver.dt": -1e-3}, "must be > 0"),
    ("impact-oscillator", {"solver.theta": 0.2}, ">= 0.5"),
    ("impact-oscillator", {"solver.scheme": "euler"}, "midpoint, theta"),
    ("impact-oscillator", {"q_start": -0.1}, "q_start"),
    ("impact-oscillator", {"k": "abc"}, "real number"),
    ("mechanical-system-2", {"M[1,2]": 0.7}, "symmetric"),
    ("mechanical-system-2", {"q_start[1]": -1.0}, "q_start violates the constraint"),
    ("mechanical-system-2", {"w[1]": 0.0, "w[2]": 0.0}, "nonzero"),
])
def test_export_rejects_bad_start_values(tmp_path, model, values, message):
    with pytest.raises(ValueError, match=None) as exc:
        export_fmu(model, tmp_path / "bad.fmu", values)
    assert message in str(exc.value)
    assert not (tmp_path / "bad.fmu").exists()


def test_main_export(tmp_path, capsys):
    out = tmp_path / "sub" / "io.fmu"
    assert main_export(["impact-oscillator", "-o", str(out), "--set", "e=0.3",
                        "--set", "solver.scheme=theta"]) == 0
    v = _vars(out)
    assert float(v["e"].start) == 0.3 and int(v["solver.scheme"].start) == 1
    assert main_export(["mechanical-system-2", "-o", str(tmp_path / "m.fmu"), "--set", "M[1,2]=9"]) == 2
    assert "symmetric" in capsys.readouterr().err
    assert main_export(["impact-oscillator", "--set", "e"]) == 2
    assert main_export(["no-such-model"]) == 2      # a model is a key, a declaration or 'file.py:name'
    assert "model 'no-such-model' is neither a built-in model" in capsys.readouterr().err



def test_export_to_a_path_it_cannot_write_is_a_refusal_naming_it(tmp_path, capsys):
    """/sys/x.fmu (root cannot create files there either), a path under a file, a folder: exit 2,
    the message names the path asked for (not a temporary file), nothing is left behind."""
    (tmp_path / "file").write_text("x")
    (tmp_path / "dir.fmu").mkdir()
    for target in ("/sys/x.fmu", str(tmp_path / "file" / "x.fmu"), str(tmp_path / "dir.fmu")):
        assert main_export(["impact-oscillator", "-o", target]) == 2, target
        err = capsys.readouterr().err
        assert f"cannot write the FMU {target}:" in err and ".export-" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.fmu", "file"]

def test_slave_import_compiles_nothing():
    """The slave module imports the compiled kernel but compiles nothing."""
    code = textwrap.dedent("""
        import fmu_sync.fmus.slave, fmu_sync.fmus.runtime
        from fmu_sync.core import moreau
        print(len(moreau.advance.signatures), len(moreau.advance.overloads))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["0", "0"]


def test_fmu_carries_only_what_its_slave_and_stepper_import():
    """The carried code is the import closure of the runtime, stepper and slave (deferred imports
    included); nothing in it imports the host package fmu_sync."""
    import ast

    from fmu_sync import export
    files = dict(export.carried_files())
    # (core/network.py and core/pair.py come with the coupling FMU's stepper only: network_forces)
    for name in ("core/batch.py", "core/exact.py", "core/exact_nd.py", "core/kernels.py", "core/single.py",
                 "core/_cache.py", "core/network.py", "core/pair.py", "fmus/coupling.py",
                 "fmus/coupling_stepper.py"):   # (core/exact.py: the public entries; the FMU runs core/exact_step.py)
        assert name not in files, name
    for name in ("core/moreau.py", "core/exact_step.py", "core/model.py", "fmus/stepper.py", "fmus/runtime.py",
                 "fmus/slave.py", "fmus/contract.py"):
        assert name in files, name
    for rel, data in files.items():
        pkg = rel.split("/")[0] if "/" in rel else ""
        for node in ast.walk(ast.parse(data)):
            if isinstance(node, ast.Import):
                assert not any(a.name.startswith("fmu_sync") for a in node.names), rel
            elif isinstance(node, ast.ImportFrom):
                assert node.level or not (node.module or "").startswith("fmu_sync"), (rel, node.module)
                if node.level:      # every relative import resolves to a carried module
                    target = ([pkg] if node.level == 1 else []) + (node.module or "").split(".")
                    mods = ["/".join(target) + ".py"] if node.module and len(target) == 2 else \
                        [f"{target[0]}/{a.name}.py" for a in node.names]
                    assert all(m in files for m in mods), (rel, mods)


def test_changing_core_batch_leaves_the_guid_unchanged(monkeypatch):
    from fmu_sync import export, package_files
    guid = export.fmu_guid("impact-oscillator")
    read = package_files.read

    def edited(target):
        return lambda rel: read(rel) + (b"\n# edited\n" if rel == target else b"")
    for other in ("core/batch.py", "core/network.py", "core/pair.py", "fmus/coupling.py"):  # not carried
        monkeypatch.setattr(package_files, "read", edited(other))
        assert export.fmu_guid("impact-oscillator") == guid, other
    monkeypatch.setattr(package_files, "read", edited("core/moreau.py"))     # a module the FMU runs: a new GUID
    assert export.fmu_guid("impact-oscillator") != guid


def _closure(roots) -> set:
    """The core/fmus modules reachable from ``roots`` ("fmus/slave.py") through their imports,
    deferred ones included: the test's own walk (importlib's name resolution and finder)."""
    import ast
    import importlib.util
    from pathlib import Path

    seen, todo = set(), list(roots)
    while todo:
        rel = todo.pop()
        if rel in seen:
            continue
        seen.add(rel)
        here = "fmu_sync." + rel[:-3].replace("/", ".")
        for node in ast.walk(ast.parse(Path(importlib.util.find_spec(here).origin).read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                base = importlib.util.resolve_name("." * node.level + (node.module or ""), here.rsplit(".", 1)[0])
                for name in [base] + [f"{base}.{a.name}" for a in node.names]:
                    try:
                        spec = importlib.util.find_spec(name)
                    except ModuleNotFoundError:
                        spec = None
                    if spec is not None and spec.origin and not spec.origin.endswith("__init__.py"):
                        todo.append(name.split(".", 1)[1].replace(".", "/") + ".py")
    return seen


@pytest.mark.parametrize("model", sorted(MODELS))
def test_exported_fmu_carries_the_closure_of_its_own_slave_and_stepper(fmus, model):
    """An exported mechanical FMU's code is exactly the import closure of its runtime, stepper and
    slave (fmus/__init__.py and the two stub __init__ files beside): nothing of the coupling FMU."""
    with zipfile.ZipFile(fmus[model]) as zf:
        files = {n[len("resources/fmu_sync_code/"):] for n in zf.namelist()
                 if n.startswith("resources/fmu_sync_code/")}
    code = {n for n in files if "__pycache__" not in n}
    want = _closure(["fmus/runtime.py", "fmus/stepper.py", "fmus/slave.py"])
    assert code - {"__init__.py", "core/__init__.py", "fmus/__init__.py"} == want
    tag = sys.implementation.cache_tag          # and the bytecode of each module, nothing more
    assert files - code == {f"{os.path.dirname(n) + '/' if '/' in n else ''}__pycache__/"
                            f"{os.path.basename(n)[:-3]}.{tag}.pyc" for n in code}
    assert not {"fmus/coupling.py", "fmus/coupling_runtime.py", "fmus/coupling_stepper.py",
                "core/network.py", "core/pair.py", "core/batch.py"} & code


def test_the_carried_code_runs_without_fmu_sync(fmus):
    """The oscillator FMU's code, unpacked as its boot script does, makes an instance and steps it
    (the exact scheme too: its deferred imports) in a process where importing fmu_sync, numba or
    llvmlite fails; every module it loads is one the FMU carries. (The stepper here is a stand-in
    with the binary's signature: the real one is native code in the binary.)"""
    with zipfile.ZipFile(fmus["impact-oscillator"]) as zf:
        build = json.loads(zf.read("resources/fmu_sync_build.json"))
        code = {n[len("resources/fmu_sync_code/"):] for n in zf.namelist()
                if n.startswith("resources/fmu_sync_code/")}
        res = zf.extract
        import tempfile
        tmp = tempfile.mkdtemp(prefix="fmu-sync-carried-")
        for n in zf.namelist():
            if n.startswith("resources/"):
                res(n, tmp)
    script = textwrap.dedent(f"""
        import ctypes, importlib, json, sys
        class Block:
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in ("fmu_sync", "numba", "llvmlite"):
                    raise ImportError(name + " must not be imported by an FMU's code")
        calls = []
        stepper = ctypes.CFUNCTYPE(ctypes.c_int32, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double,
                                   ctypes.c_double)(lambda x, w, t, H: calls.append(H) or 0)
        sys.meta_path.insert(0, Block())
        resources = {tmp + '/resources'!r}
        sys.path.insert(0, resources)
        boot = importlib.import_module({build['package'].replace('fmu_sync_m', 'fmu_sync_boot_')!r})
        reply, inst = boot.instantiate(resources, "carried", {build['guid']!r}, 0,
                                       ctypes.cast(stepper, ctypes.c_void_p).value)
        assert inst is not None, reply
        assert inst.exit_initialization() == "", "exit"
        inst._step(inst.x.ctypes.data, inst.work.ctypes.data, 0.0, 0.1)
        inst.x[inst.index["solver.scheme"]] = 2
        assert inst.set_state(dict(inst.get_state(), phase="initialization")) == ""
        assert inst.exit_initialization() == "", "exit exact"
        assert calls == [0.0, 0.1, 0.0], calls
        pkg = {build['package']!r} + "."
        print(json.dumps(sorted(m[len(pkg):] for m in sys.modules if m.startswith(pkg))))
    """)
    try:
        out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    finally:
        import shutil
        shutil.rmtree(tmp, ignore_errors=True)
    assert out.returncode == 0, out.stderr[-3000:]
    loaded = {m.replace(".", "/") + ".py" for m in json.loads(out.stdout.splitlines()[-1])}
    assert {"fmus/runtime.py", "fmus/stepper.py", "fmus/slave.py", "core/exact_step.py"} <= loaded
    assert loaded - {"core.py", "fmus.py"} <= code


def test_one_scheme_numbering_and_generated_constants():
    """The FMU's enumeration values are the core's scheme codes (exact after them), and the
    binary's constants are generated from the Python definitions, not written in the C files."""
    import re
    from pathlib import Path

    from fmu_sync.core.moreau import SCHEMES
    from fmu_sync.export import constants_header
    from fmu_sync.fmus import contract, runtime, slave, stepper
    items = {name: value for name, value, _ in contract.SCHEME_ITEMS}
    # the FMU offers midpoint and theta (its theta = 1/2 is the core's trapezoid on a single system)
    # under the core's codes, exact after them; no core code is another FMU scheme's value
    offered = {k: v for k, v in SCHEMES.items() if k in items}
    assert {k: items[k] for k in offered} == offered and set(offered) >= {"midpoint", "theta"}
    assert items["exact"] == stepper.EXACT and not (set(SCHEMES.values()) - set(offered.values())) & set(items.values())
    h = dict(re.findall(r"#define (\w+) (.+)", constants_header("{x}", "boot").decode()))
    assert h["FSR_SCHEME_EXACT"] == str(stepper.EXACT) and h["FSR_SCHEME_THETA"] == str(SCHEMES["theta"])
    assert h["FSR_H_TIME"] == str(stepper.H_TIME) and h["FSR_H_ITAUDOT"] == str(stepper.H_ITAUDOT)
    assert h["FSR_VERSION"] == str(int(stepper.WORK_VERSION)) and h["FSR_STEP"] == str(slave.PHASES["step"])
    assert h["FSR_L_WORK"] == str(runtime.LAYOUT.index("work")) and "FSR_L_STEPPER" not in h
    assert h["FMU_SYNC_GUID"] == '"{x}"'
    c_dir = Path(slave.__file__).parent / "c"
    hand = "".join(p.read_text() for p in c_dir.glob("*.[ch]"))
    assert not re.search(r"#define (FSR_H_|FSR_SCHEME_|FSR_VERSION|FSR_L_)|FSR_H_\w+ = \d", hand)
