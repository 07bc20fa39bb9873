"""The FMU's boot in the environments users have (issue 35 item 7): a patch-level Python difference
is no warning, the missing-numpy advice works where pip is absent, a broken numpy is named as such,
and the code cache never creates a home folder that is not there. Each case runs fmus/boot.py (the
standard library only, as the binary imports it) in a fresh interpreter with the environment set up
for it."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import venv
from pathlib import Path

import pytest

BOOT = Path(__file__).resolve().parents[1] / "fmus" / "boot.py"
LOAD = ("import importlib.util, json, sys\n"
        f"spec = importlib.util.spec_from_file_location('boot', {str(BOOT)!r})\n"
        "boot = importlib.util.module_from_spec(spec); spec.loader.exec_module(boot)\n")


def _boot(code: str, python: str = sys.executable, env: dict | None = None, drop=()) -> object:
    """Run ``code`` after loading boot.py as ``boot`` in a fresh ``python``; its last printed line, as JSON."""
    e = {k: v for k, v in os.environ.items() if k not in drop}
    e.update(env or {})
    p = subprocess.run([python, "-c", LOAD + code], capture_output=True, text=True, env=e, timeout=120)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_a_patch_level_python_difference_is_no_warning():
    """The ABI is per minor version: 3.11.7 built, 3.11.2 running is no warning; another minor version is."""
    import numpy
    major, minor, patch = sys.version_info[:3]
    for built, warned in ((f"{major}.{minor}.{patch + 5}", False), (f"{major}.{minor}.0", False),
                          (f"{major}.{minor + 1}.{patch}", True)):
        msgs = _boot(f"print(json.dumps(boot.check_runtime({{'python': {built!r}, 'numpy': {numpy.__version__!r}}})))")
        assert any("running on Python" in m for m in msgs) == warned, (built, msgs)
        assert not any(m.startswith("E:") for m in msgs)


def test_the_missing_numpy_advice_bootstraps_pip_where_it_is_absent(tmp_path):
    """A venv made without pip: the advice starts with ``-m ensurepip`` (pip's own bootstrap, offline),
    and that first command does give the interpreter pip."""
    env_dir = tmp_path / "no-pip"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = str(env_dir / "bin" / "python")
    msgs = _boot("print(json.dumps(boot.check_runtime({'python': '3', 'numpy': '2.0'}, requires={'numpy': '>=1.24'})))",
                 python=python, drop=("PYTHONPATH",))
    err = [m for m in msgs if m.startswith("E:")]
    assert len(err) == 1 and "lacks numpy" in err[0], msgs
    want = f"{python} -m ensurepip && {python} -m pip install 'numpy>=1.24'"
    assert want in err[0], err[0]
    assert subprocess.run([python, "-m", "pip", "--version"], capture_output=True).returncode != 0
    bootstrap = subprocess.run([python, "-m", "ensurepip"], capture_output=True, text=True, timeout=300)
    assert bootstrap.returncode == 0, bootstrap.stderr
    assert subprocess.run([python, "-m", "pip", "--version"], capture_output=True).returncode == 0


def test_a_broken_numpy_is_named_as_such(tmp_path):
    """A numpy whose import raises AttributeError (a damaged or mismatched installation): one error
    naming numpy as broken, the exception and the reinstall command; no traceback."""
    fake = tmp_path / "site" / "numpy"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("import sys\nraise AttributeError(\"module 'numpy.core' has no attribute "
                                      "'multiarray'\")\n")
    msgs = _boot("print(json.dumps(boot.check_runtime({'python': '3', 'numpy': '2.0'}, requires={'numpy': '>=1.24'})))",
                 env={"PYTHONPATH": str(tmp_path / "site")})
    err = [m for m in msgs if m.startswith("E:")]
    assert len(err) == 1, msgs
    assert "numpy in the Python environment" in err[0] and "is broken: importing it raises AttributeError: " \
        "module 'numpy.core' has no attribute 'multiarray'" in err[0]
    assert "-m pip install --force-reinstall 'numpy>=1.24'" in err[0] and "Traceback" not in err[0]


@pytest.mark.parametrize("home", ["missing", ""])
def test_the_cache_never_creates_a_home_that_is_not_there(tmp_path, home):
    """HOME naming no folder, or empty: ~/.cache is not used (nothing created there, nor '.cache' under
    the file-system root); the cache falls back to TMPDIR as for an unwritable home, and with no
    folder left the message says why HOME was not used."""
    home_dir = str(tmp_path / "gone" / "home") if home == "missing" else ""
    env = {"HOME": home_dir, "TMPDIR": str(tmp_path / "tmp")}
    (tmp_path / "tmp").mkdir()
    drop = ("FMU_SYNC_CACHE", "XDG_CACHE_HOME")
    got = _boot("print(json.dumps([boot._cache_candidates(), boot.cache_root()]))", env=env, drop=drop)
    folders = [f for _, f in got[0]]
    assert not any(f.startswith("/.cache") or ".cache" in f for f in folders), folders
    assert got[1] == str(tmp_path / "tmp" / f"fmu-sync-{os.getuid()}")
    assert not (tmp_path / "gone").exists()
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    code = ("boot.TMP_DIRS = ()\ntry:\n    boot.cache_root()\nexcept boot.SetupError as exc:\n"
            "    print(json.dumps(str(exc)))\n")
    text = _boot(code, env={**env, "TMPDIR": str(blocker / "tmp")}, drop=drop)
    assert "Set FMU_SYNC_CACHE" in text
    assert ("does not exist (not created)" if home else "HOME is empty") in text, text
    assert not (tmp_path / "gone").exists()
