"""The FMU's stepper as native code (docs/design.md §4.3, fmu_sync/native.py).

* the native FMU's numbers equal, bit for bit, numba's own compiled stepper driving the
  same instance (the path every FMU took before the stepper was compiled at export):
  the mechanical FMU's schemes (midpoint, theta, exact: the allocating one), 2 DOF,
  FMI 3.0 and the coupling FMU, with inputs that change every step;
* the FMU runs with numba (and llvmlite) impossible to import, and never imports numba;
* the export fails, clearly, when the stepper cannot be made native code.

FMUs are loaded in child processes only (``python tests/test_fmu_native.py SCENARIO ARGS OUT``).
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path


# =============================================================== child side
def _slave(path, d):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    from fmpy.fmi3 import FMU3Slave
    md = read_model_description(path)
    unz = extract(path, d)
    if md.fmiVersion.startswith("3"):
        s = FMU3Slave(guid=md.guid, unzipDirectory=unz, modelIdentifier=md.coSimulation.modelIdentifier)
        s.instantiate()
        s.enterInitializationMode(startTime=0.0)
    else:
        s = FMU2Slave(guid=md.guid, unzipDirectory=unz, modelIdentifier=md.coSimulation.modelIdentifier)
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
    s.exitInitializationMode()
    return md, unz, s


def _flat(md):
    """(input vrs, real output vrs, integer output vrs) of a model description (FMI 2.0 or 3.0 scalars)."""
    ins, reals, ints = [], [], []
    for v in md.modelVariables:
        if v.causality == "input":
            ins.append(v.valueReference)
        elif v.causality == "output":
            (ints if v.type in ("Integer", "Int64") else reals).append(v.valueReference)
    return ins, reals, ints


def scenario_compare(a):
    """Step the FMU (native stepper) and the same kind of instance driven by numba's compiled
    stepper in this process, with the same random inputs; every output after every step."""
    import numpy as np

    from fmu_sync.export import stepper_cfunc
    from fmu_sync.fmus import coupling_runtime, runtime
    from fmu_sync.fmus import stepper as S
    out = {}
    for key, path in a["fmus"].items():
        md, unz, s = _slave(path, tempfile.mkdtemp(dir=a["tmp"]))
        fmi3 = md.fmiVersion.startswith("3")
        res = os.path.join(unz, "resources")
        build = json.loads(Path(res, "fmu_sync_build.json").read_text())
        create = coupling_runtime.create if build["model"] == "coupling" else runtime.create
        reply, inst = create(res, build["model"], float(build["max_substeps"]), 3 if fmi3 else 2,
                             stepper_cfunc(build["model"]).address)
        assert inst is not None, reply
        assert inst.exit_initialization() == ""
        ins, reals, ints = _flat(md)
        rng = np.random.default_rng(7)
        H, mism, n = a["H"], 0, 0
        for k in range(a["steps"]):
            tau = rng.uniform(-a["amp"], a["amp"], len(ins))
            t = k * H
            if fmi3:
                s.setFloat64(ins, list(tau))
                s.doStep(t, H)
                got = list(s.getFloat64(reals)) + [float(v) for v in s.getInt64(ints)]
            else:
                s.setReal(ins, list(tau))
                s.doStep(t, H)
                got = list(s.getReal(reals)) + [float(v) for v in s.getInteger(ints)]
            inst.x[ins] = tau
            now = float(inst.work[S.H_TIME])              # as fsr_step: the slave's own time
            # random inputs of the coupling FMU put systems inside the wall: R_INADMISSIBLE (outputs
            # computed, fmi2Warning) is a completed step too
            assert inst._step(inst.x.ctypes.data, inst.work.ctypes.data, now, H) in (0, S.R_INADMISSIBLE)
            inst.work[S.H_TIME] = now + H
            want = [float(inst.x[i]) for i in reals + ints]
            n += len(want)
            mism += sum(np.float64(g).tobytes() != np.float64(w).tobytes() for g, w in zip(got, want))
        s.terminate()
        s.freeInstance()
        out[key] = {"values": n, "mismatches": int(mism), "last": got}
    return out


def scenario_no_numba(a):
    """numba and llvmlite impossible to import: the FMU still runs (its code is plain Python)."""
    if a["block"]:
        sys.modules["numba"] = None
        sys.modules["llvmlite"] = None
    from fmpy import simulate_fmu
    r = simulate_fmu(a["fmu"], stop_time=1.0, output_interval=0.01, output=["q", "u", "impacts"])
    return {"q": r["q"].tolist(), "u": r["u"].tolist(), "numba_imported": "numba" in sys.modules
            and sys.modules["numba"] is not None}


def _child_main(argv):
    name, args_path, out_path = argv
    args = json.loads(Path(args_path).read_text())
    Path(out_path).write_text(json.dumps(globals()[f"scenario_{name}"](args)))


if __name__ == "__main__":      # a child: the parent side's imports (numba among them) stay out
    _child_main(sys.argv[1:])
    sys.exit(0)

# =============================================================== parent side
import pytest  # noqa: E402

from fmu_sync import native  # noqa: E402
from fmu_sync.export import export_coupling, export_fmu  # noqa: E402


def _child(name, args, tmp, timeout=600, env=None):
    a, o = tmp / f"{name}.args.json", tmp / f"{name}.{len(list(tmp.iterdir()))}.out.json"
    a.write_text(json.dumps(args))
    p = subprocess.run([sys.executable, __file__, name, str(a), str(o)], capture_output=True, text=True,
                       timeout=timeout, env=None if env is None else {**os.environ, **env})
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(o.read_text())


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, shared_fmu):
    tmp = tmp_path_factory.mktemp("native")
    return tmp, {
        "midpoint": str(shared_fmu("impact-oscillator")),
        "theta": str(export_fmu("impact-oscillator", tmp / "io_theta.fmu",
                                {"solver.scheme": "theta", "solver.theta": 0.75, "e": 0.6})),
        "exact": str(export_fmu("impact-oscillator", tmp / "io_exact.fmu",
                                {"solver.scheme": "exact", "k": 0.0, "f0": -9.81, "F": 0.0, "e": 0.8})),
        "ms2": str(shared_fmu("mechanical-system-2")),
        "fmi3": str(shared_fmu("impact-oscillator", 3)),
        "coupling": str(shared_fmu("coupling")),
    }


@pytest.mark.parametrize("variant", ["the CPU's", "baseline"])
def test_native_stepper_equals_numba_stepper_bit_for_bit(fmus, variant):
    """Both compiled variants (x86-64-v3 where the CPU has AVX2, and the baseline every x86-64
    runs, forced by FMU_SYNC_NATIVE_BASELINE) give numba's numbers."""
    tmp, paths = fmus
    env = {"FMU_SYNC_NATIVE_BASELINE": "1"} if variant == "baseline" else None
    r = _child("compare", {"fmus": paths, "tmp": str(tmp), "H": 0.01, "steps": 400, "amp": 0.3}, tmp, env=env)
    for key in paths:
        assert r[key]["values"] >= 400 * 3, key
        assert r[key]["mismatches"] == 0, (key, r[key])
    assert r["exact"]["last"] != r["midpoint"]["last"]


def test_fmu_runs_without_numba_and_never_imports_it(fmus):
    tmp, paths = fmus
    blocked = _child("no_numba", {"fmu": paths["midpoint"], "block": True}, tmp)
    free = _child("no_numba", {"fmu": paths["midpoint"], "block": False}, tmp)
    assert blocked["q"] == free["q"] and blocked["u"] == free["u"] and len(free["q"]) == 101
    assert not free["numba_imported"]


def test_binary_carries_the_stepper_and_binds_libm_to_the_oldest_glibc(fmus):
    import zipfile
    tmp, paths = fmus
    with zipfile.ZipFile(paths["exact"]) as zf:
        so = tmp / "exact.so"
        so.write_bytes(zf.read(next(n for n in zf.namelist() if n.endswith(".so"))))
        build = json.loads(zf.read("resources/fmu_sync_build.json"))
    assert build["native_stepper"]["cpu"] == ["x86-64", "x86-64-v3"] and "numba" not in build["built_with"]
    dyn = subprocess.run(["objdump", "-T", str(so)], capture_output=True, text=True, check=True).stdout
    libm = {m.group(2): m.group(1) for m in re.finditer(r"\((GLIBC_[\d.]+)\)\s+(\w+)$", dyn, re.M)}
    for f in ("exp", "cos", "sin", "expm1"):       # the exact flow's functions
        assert libm.get(f) == "GLIBC_2.2.5", (f, libm.get(f))
    assert "fsr_native_step" not in dyn and "fsrx_" not in dyn      # internal to the binary


def test_every_runtime_symbol_is_provided_by_the_c_support():
    import fmu_sync.fmus
    src = (Path(fmu_sync.fmus.__file__).parent / "c" / "fmu_sync_native.c").read_text()
    defined = set(re.findall(r"\bfsrx_(\w+)", src)) | set(re.findall(r"(?:FLAGGED|QUIET)\((\w+)\)", src))
    assert native.RUNTIME <= defined, sorted(native.RUNTIME - defined)


def test_pyproject_pins_the_tested_numba_and_llvmlite_in_the_export_extra_only():
    """Issue 41: the export extra's ranges are the ranges the emission was tested with
    (native.TESTED); the package itself allows older numba (a user's is kept), and the test extra
    installs the export's, so CI runs the newest tested. The base bound stops at the next major:
    that bound makes pip (>= 25.1) resolve numba before FMPy and keep an installed numba 0.60."""
    BASE_LOW = {"numba": "0.60", "llvmlite": "0.43"}
    import tomllib
    project = tomllib.loads((Path(native.__file__).parents[1] / "pyproject.toml").read_text())["project"]
    extra = project["optional-dependencies"]["export"]
    for dist, (lo, hi) in native.TESTED.items():
        spec = next(d for d in extra if re.match(rf"{dist}\b", d))
        assert spec == f"{dist}>={lo[0]}.{lo[1]},<{hi[0]}.{hi[1] + 1}", spec
        base = next(d for d in project["dependencies"] if re.match(rf"{dist}\b", d))
        assert base == f"{dist}>={BASE_LOW[dist]},<1", base   # no pin of the tested minor for everything
    assert "fmu-sync[export]" in project["optional-dependencies"]["test"]
    native.check_versions()     # the installed ones are in range


@pytest.mark.parametrize("how", ["api", "cli", "coupling", "scene"])
def test_export_outside_the_tested_numba_refuses_in_one_line_before_any_work(monkeypatch, tmp_path, capsys, how):
    """Issue 41 item 2: the numba found, the versions the export supports, how to get them; no
    traceback, nothing written (the output file, the scene's folder)."""
    from fmu_sync.cli import main
    from fmu_sync.export import export_coupling
    from fmu_sync.scenes.running import run_scene
    monkeypatch.setitem(native.TESTED, "numba", ((0, 1), (0, 2)))
    import numba
    want = rf"numba 0\.1\.x-0\.2\.x.*this environment has numba {re.escape(numba.__version__)}.*fmu-sync\[export\]"
    if how == "cli":
        assert main(["export", "impact-oscillator", "-o", str(tmp_path / "io.fmu")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and re.search(want, err[0]) and "Traceback" not in err[0], err
    else:
        call = {"api": lambda: export_fmu("impact-oscillator", tmp_path / "io.fmu"),
                "coupling": lambda: export_coupling(tmp_path / "io.fmu"),
                "scene": lambda: run_scene("forced-pair", tmp_path / "out", overrides={"run.mode": "cosim"})}[how]
        with pytest.raises(native.ExportNeedsNumba, match=want):
            call()
    assert not (tmp_path / "io.fmu").exists() and not (tmp_path / "out").exists()


def test_export_fails_naming_a_symbol_the_binary_cannot_provide(tmp_path):
    """A stepper that calls into Python (print) cannot be made native: the export names the symbol."""
    from numba import cfunc

    @cfunc("int32(CPointer(float64), CPointer(float64), float64, float64)", nopython=True)
    def printing(x, w, t, H):
        print(t)
        return 0

    with pytest.raises(native.NativeCodeError, match=r"calls .*Py\w+.*numba feature outside"):
        native.stepper_object(printing, tmp_path / "s.o")
    with pytest.raises(native.NativeCodeError, match="PyObject_Print"):
        native.link_names(["cos", "PyObject_Print"])
    assert native.link_names(["cos", "NRT_Free"]) == {"cos": "cos@GLIBC_2.2.5", "NRT_Free": "fsrx_NRT_Free"}


def test_export_fails_for_an_address_of_the_exporting_process(tmp_path):
    """A ctypes function called from the stepper is an address valid only in this process."""
    import ctypes
    import ctypes.util

    from numba import cfunc
    libm = ctypes.CDLL(ctypes.util.find_library("m"))
    c_cos = libm.cos
    c_cos.restype, c_cos.argtypes = ctypes.c_double, [ctypes.c_double]

    @cfunc("int32(CPointer(float64), CPointer(float64), float64, float64)", nopython=True)
    def through_ctypes(x, w, t, H):
        w[0] = c_cos(t)
        return 0

    with pytest.raises(native.NativeCodeError, match="address of this process"):
        native.stepper_object(through_ctypes, tmp_path / "s.o")


def test_cli_export_reports_native_failure(monkeypatch, tmp_path, capsys):
    from fmu_sync.export import main_export
    monkeypatch.setitem(native.TESTED, "llvmlite", ((0, 1), (0, 2)))
    assert main_export(["impact-oscillator", "-o", str(tmp_path / "x.fmu")]) == 2
    assert "llvmlite" in capsys.readouterr().err



def test_the_stepper_is_emitted_once_per_machine_and_the_fmu_is_the_same_bit_for_bit(monkeypatch, tmp_path):
    """The native objects are cached on disk (native.cached_object) for the next process: a cached
    FMU is byte for byte the one emitted afresh."""
    folder = tmp_path / "cache"
    folder.mkdir()
    monkeypatch.setattr(native, "cache_dir", lambda: folder)
    emitted, emit = [], native._emit
    monkeypatch.setattr(native, "_emit", lambda *a: emitted.append(a[3]) or emit(*a))
    every = [cpu for cpu, _ in native.VARIANTS]

    def new_process(name):
        monkeypatch.setattr(native, "_OBJECTS", {})
        return export_coupling(tmp_path / name).read_bytes()

    a = new_process("a.fmu")
    assert emitted == every
    assert {f"fmu_sync.fmus.coupling_stepper.step-{entry}.o" for _, entry in native.VARIANTS} <= {
        p.name for p in folder.iterdir()}
    assert new_process("b.fmu") == a and emitted == every


def test_the_object_cache_keeps_one_entry_per_key(monkeypatch, tmp_path):
    """In the process, then on disk; an entry of another key (a changed stepper, llvmlite, native.py)
    is made again and replaced; no writable cache folder only means no disk cache."""
    monkeypatch.setattr(native, "cache_dir", lambda: tmp_path)
    monkeypatch.setattr(native, "_OBJECTS", {})
    made = []

    def make(code):
        return lambda: made.append(code) or code

    k1, k2 = "1" * 64, "2" * 64
    assert native.cached_object(k1, "s.o", make(b"one")) == b"one" and made == [b"one"]
    assert native.cached_object(k1, "s.o", make(b"not made")) == b"one" and made == [b"one"]
    assert (tmp_path / "s.o").read_bytes() == k1.encode() + b"one"
    monkeypatch.setattr(native, "_OBJECTS", {})
    assert native.cached_object(k1, "s.o", make(b"not made")) == b"one" and made == [b"one"]
    assert native.cached_object(k2, "s.o", make(b"two")) == b"two" and made == [b"one", b"two"]
    assert (tmp_path / "s.o").read_bytes() == k2.encode() + b"two"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.o"]       # no temporary left behind
    monkeypatch.setattr(native, "cache_dir", lambda: None)
    monkeypatch.setattr(native, "_OBJECTS", {})
    assert native.cached_object(k2, "s.o", make(b"three")) == b"three" and made[-1] == b"three"


def test_the_c_sources_are_compiled_again_only_when_their_text_changes(monkeypatch, tmp_path):
    """native.c_objects: keyed by the preprocessed source; fmu_sync_python.c does not use the boot
    module's name, fmu_sync_runtime.c does."""
    from fmu_sync import export as E, package_files
    from fmu_sync.export import binary
    (tmp_path / "cache").mkdir()
    monkeypatch.setattr(native, "cache_dir", lambda: tmp_path / "cache")
    monkeypatch.setattr(native, "_OBJECTS", {})
    compiled, run = [], subprocess.run

    def spy(cmd, *a, **k):
        if "-c" in cmd:
            compiled.append(Path(cmd[cmd.index("-c") + 1]).name)
        return run(cmd, *a, **k)

    monkeypatch.setattr(native.subprocess, "run", spy)
    srcs = [str(package_files.path(f"fmus/c/{f}")) for f in ("fmu_sync_runtime.c", "fmu_sync_python.c")]

    def build(boot):
        d = tmp_path / f"inc{len(list(tmp_path.iterdir()))}"
        d.mkdir()
        (d / binary.CONSTANTS_H).write_bytes(E.constants_header("{guid}", boot))
        return [p.read_bytes() for p in native.c_objects("gcc", ["-O2", "-fPIC"], srcs, d)]

    a = build("boot_a")
    assert compiled == ["fmu_sync_runtime.c", "fmu_sync_python.c"]
    assert build("boot_a") == a and len(compiled) == 2
    b = build("boot_b")
    assert compiled[2:] == ["fmu_sync_runtime.c"] and b[1] == a[1] and b[0] != a[0]
