"""The FMU on another machine (issue 26): exported here, run from the plain C test host
(tests/c/fmu_host.c) with ``env -i``, the exporting environment gone, an empty home (so an empty
cache folder) and PATH holding only a venv that sees nothing but the packages the FMU says it needs
(``requires`` of its build record), built without network from this machine's installed packages.
Also: what the target is told when its Python lacks numpy, or when no Python is found.

The target venv is made from this interpreter's base Python; set FMU_SYNC_TEST_TARGET_PYTHON to
another interpreter of the same minor version (e.g. Debian's /usr/bin/python3) for a different Python.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from _children import unpack_fmu
from test_fmu_c_host import VR_Q, VR_TAU, _fmpy_reference, _read_csv

TARGET_PYTHON = os.environ.get("FMU_SYNC_TEST_TARGET_PYTHON") or getattr(sys, "_base_executable", sys.executable)


def _distribution_closure(names):
    """The installed distributions ``names`` need (their non-extra requirements, recursively)."""
    seen, todo = {}, list(names)
    while todo:
        name = re.match(r"[A-Za-z0-9_.-]+", todo.pop()).group(0).lower().replace("_", "-")
        if name in seen:
            continue
        seen[name] = dist = metadata.distribution(name)
        todo += [r for r in dist.requires or [] if "extra ==" not in r]
    return seen


def _venv(path: Path, expose=()) -> Path:
    """A venv of TARGET_PYTHON, without pip, seeing only the distributions ``expose`` (and what they
    need) through one .pth file: symlinks to their installed top-level folders and metadata."""
    subprocess.run([TARGET_PYTHON, "-m", "venv", "--without-pip", str(path)], check=True, timeout=120,
                   capture_output=True)
    shown = path / "exposed"
    shown.mkdir()
    for dist in _distribution_closure(expose).values():
        for top in {f.parts[0] for f in dist.files or [] if f.parts[0] != ".."}:
            src = Path(dist.locate_file(top))
            if src.exists() and not (shown / top).exists():
                (shown / top).symlink_to(src)
    site = next(path.glob("lib/python3*/site-packages"))
    (site / "exposed.pth").write_text(f"{shown}\n")
    return path


@pytest.fixture(scope="module")
def travel(tmp_path_factory, shared_fmu, c_host):
    """An exported FMU whose recorded interpreter (an exporting venv) was removed, and the C host."""
    tmp = tmp_path_factory.mktemp("travel")
    fmu = shared_fmu("impact-oscillator")
    d = unpack_fmu(fmu, tmp / "io")
    build = json.loads((d / "resources" / "fmu_sync_build.json").read_text())
    gone = _venv(tmp / "exporting-venv")                  # existed at export, removed since
    record = d / "resources" / "fmu_sync_python.txt"
    record.write_text(re.sub(r"(?m)^program=.*$", f"program={gone}/bin/python", record.read_text()))
    subprocess.run(["rm", "-rf", str(gone)], check=True)
    return {"tmp": tmp, "fmu": fmu, "dir": d, "host": c_host, "build": build, "gone": gone}


def _run_empty_env(travel, path_dirs, *args, home=None, timeout=900):
    """The C host under ``env -i``: HOME (a fresh empty folder) and PATH only."""
    home = home or Path(travel["tmp"]) / f"home-{len(list(travel['tmp'].glob('home-*')))}"
    home.mkdir()
    cmd = ["env", "-i", f"HOME={home}", f"PATH={':'.join(map(str, path_dirs))}", str(travel["host"]),
           str(travel["dir"]), *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_runs_on_another_machine_with_only_what_it_says_it_needs(travel):
    """Exit 0 and q equal to fmpy's run on the exporting machine to 1e-12; the Python was found on
    PATH after the recorded one, gone, was passed over."""
    needs = travel["build"]["requires"]
    assert set(needs) == {"numpy"}                          # a Python+numpy-only venv: no numba, no LLVM
    target = _venv(travel["tmp"] / "target-venv", expose=needs)
    out = travel["tmp"] / "travel.csv"
    stop, H, tau = 2.0, 0.01, 0.05
    p = _run_empty_env(travel, [target / "bin"], "--stop", stop, "--step", H, "--set", f"{VR_TAU}={tau}",
                       "--var", VR_Q, "--out", out)
    assert p.returncode == 0, p.stdout + p.stderr[-3000:]
    chosen = [ln for ln in p.stderr.splitlines() if "Python chosen" in ln]
    assert chosen and f"{target}/bin/python3" in chosen[0] and "gone" in chosen[0], p.stderr[-2000:]
    got = _read_csv(out)
    ref = _fmpy_reference(travel["fmu"], travel["tmp"], stop, H, tau, names=("q",))
    assert got.shape == (len(ref["time"]), 2)
    assert np.max(np.abs(got[:, 1] - np.array(ref["q"]))) <= 1e-12
    assert np.ptp(got[:, 1]) > 0.1


def test_a_python_without_numpy_is_refused_with_the_command(travel):
    """PATH holds a venv without numpy: the instantiation fails (exit 3, within the time-out, no hang)
    with a message naming numpy, its minimum version and the command that installs it there."""
    bare = _venv(travel["tmp"] / "bare-venv")
    p = _run_empty_env(travel, [bare / "bin"], "--stop", 0.1, timeout=60)
    assert p.returncode == 3 and "instantiate NULL" in p.stdout, p.stdout + p.stderr
    err = " ".join(ln for ln in p.stderr.splitlines() if ln.startswith("LOG 3"))
    spec = travel["build"]["requires"]["numpy"]
    assert f"lacks numpy (the FMU needs numpy{spec}" in err, err
    assert re.search(re.escape(f"{bare}/bin/python3 -m pip install ") + r"('[^']+' )*" + re.escape(f"'numpy{spec}'"),
                     err), err
    assert f"{bare}/bin/python3 -m ensurepip && " in err, err     # the venv has no pip: bootstrapped first
    assert str(travel["gone"]) in err and "gone" in err         # what was tried, the recorded one gone


def test_no_python_at_all_names_what_was_tried_and_the_fix(travel):
    """No python3 on PATH and the recorded interpreter gone: exit 3 before any Python starts, the
    message names each place tried, numpy and a command for this platform."""
    empty = travel["tmp"] / "empty-bin"
    empty.mkdir()
    p = _run_empty_env(travel, [empty], "--stop", 0.1, timeout=60)
    assert p.returncode == 3 and "instantiate NULL" in p.stdout, p.stdout + p.stderr
    err = " ".join(ln for ln in p.stderr.splitlines() if ln.startswith("LOG 3"))
    assert "no Python to run this FMU" in err and "numpy" in err, err
    assert "FMU_SYNC_PYTHON: not set" in err and f"{travel['gone']}/bin/python: gone" in err, err
    assert f"python3 on PATH ({empty}): none" in err, err
    assert re.search(r"apt-get install \S*libpython3\S* python3-numpy|dnf install|--enable-shared", err), err


# --------------------------------------------------------------- what the target is told, unit by unit
@pytest.mark.parametrize("version, spec, ok", [
    ("1.24.0", ">=1.24", True), ("1.23.5", ">=1.24", False), ("2.4.6", ">=1.24", True),
    ("0.57.1", ">=0.59,<0.69", False), ("0.68.1", ">=0.59,<0.69", True), ("0.69.0", ">=0.59,<0.69", False),
    ("2.0.0rc1", ">=2.0", True), ("1.26", "==1.26.0", True), ("1.26.1", "!=1.26.1", False), ("3", "", True),
])
def test_version_ranges(version, spec, ok):
    from fmu_sync.fmus.boot import satisfies
    assert satisfies(version, spec) is ok


def test_pyproject_states_the_ranges_the_fmu_checks():
    """TARGET_REQUIRES (what an FMU's build record carries) and pyproject.toml's dependencies agree."""
    import tomllib
    from fmu_sync.export import TARGET_REQUIRES
    deps = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    spec = {re.match(r"[A-Za-z0-9_.-]+", d).group(0): set(d[len(re.match(r"[A-Za-z0-9_.-]+", d).group(0)):]
                                                       .replace(" ", "").split(","))
            for d in deps["dependencies"]}
    for dist, want in TARGET_REQUIRES.items():
        assert spec[dist] == set(want.split(",")), (dist, spec[dist], want)


def test_the_build_record_names_the_carried_imports():
    from fmu_sync.export import TARGET_REQUIRES, target_requires
    for model in ("impact-oscillator", "mechanical-system-2", "coupling"):
        needs = target_requires(model)
        assert "numpy" in needs and set(needs) <= set(TARGET_REQUIRES)
        assert "xarray" not in needs and "matplotlib" not in needs    # deferred imports of core/views.py


def test_export_refuses_a_numpy_outside_the_range(monkeypatch):
    import numpy
    from fmu_sync import export
    monkeypatch.setattr(numpy, "__version__", "1.21.6")
    with pytest.raises(RuntimeError, match=r"cannot export with numpy 1\.21\.6: .*numpy>=1\.24.*pip install"):
        export._runtime_versions()


def test_an_old_numpy_is_refused_with_the_command(monkeypatch):
    from fmu_sync.fmus import boot
    monkeypatch.setattr(boot, "_version", lambda dist: "1.21.6")
    msgs = boot.check_runtime({"numpy": "2.4.6"}, embedded=True, requires={"numpy": ">=1.24"})
    err = [m for m in msgs if m.startswith("E:")]
    assert len(err) == 1 and "has numpy 1.21.6 (needs numpy>=1.24)" in err[0], msgs
    assert f"{sys.executable} -m pip install 'numpy>=1.24'" in err[0]       # this interpreter is a venv's


def test_install_command_for_a_debian_system_python(monkeypatch, tmp_path):
    """A PEP 668 system Python on Debian/Ubuntu: the distribution's package, not pip."""
    from fmu_sync.fmus import boot
    import sysconfig
    (tmp_path / "EXTERNALLY-MANAGED").write_text("[externally-managed]\n")
    monkeypatch.setattr(sys, "prefix", sys.base_prefix)
    monkeypatch.setattr(sysconfig, "get_path", lambda name: str(tmp_path))
    monkeypatch.setattr(boot.os.path, "isfile", lambda p: p == str(tmp_path / "EXTERNALLY-MANAGED")
                        or p == "/etc/debian_version")
    assert boot.install_command({"numpy": ">=1.24"}) == "sudo apt-get install python3-numpy"


def test_a_python_without_its_shared_library_is_named(travel):
    """python3 on PATH whose installation has no libpython (a static build): it is named with what
    it lacks, and the advice is a shared build (this prefix is not the distribution's /usr)."""
    prefix = travel["tmp"] / "static-python"
    (prefix / "bin").mkdir(parents=True)
    real = prefix / "bin" / "python3.11"
    real.write_text("#!/bin/sh\nexit 1\n")
    real.chmod(0o755)
    (prefix / "bin" / "python3").symlink_to("python3.11")
    p = _run_empty_env(travel, [prefix / "bin"], "--stop", 0.1, timeout=60)
    assert p.returncode == 3 and "instantiate NULL" in p.stdout, p.stdout + p.stderr
    err = " ".join(ln for ln in p.stderr.splitlines() if ln.startswith("LOG 3"))
    assert (f"python3 on PATH {prefix}/bin/python3: Python 3.11 without its shared library "
            f"libpython3.11.so.1.0 (looked under {prefix}/lib) and without numpy") in err, err
    assert "--enable-shared" in err and "FMU_SYNC_PYTHON" in err, err
