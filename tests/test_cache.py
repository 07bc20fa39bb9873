"""Every core kernel's numba cache is keyed on the whole core package.

numba stamps a cache entry with the hash of the defining file only; a kernel
that inlines code of another core module would otherwise run stale code after
that module changed (seen while developing distance.py/coupling.py).
"""
import importlib
import pkgutil

from numba.core.registry import CPUDispatcher

import fmu_sync.core as core
from fmu_sync.core import _cache


def _dispatchers():
    for mod in pkgutil.iter_modules(core.__path__):
        m = importlib.import_module(f"fmu_sync.core.{mod.name}")
        for name, obj in vars(m).items():
            if isinstance(obj, CPUDispatcher) and obj.__module__ == m.__name__:
                yield f"{m.__name__}.{name}", obj


def test_every_core_kernel_uses_the_package_wide_stamp():
    seen = 0
    for name, disp in _dispatchers():
        cache = disp._cache
        assert hasattr(cache, "_impl"), f"{name} is not cached (cache=True missing)"
        loc = cache._impl.locator
        assert isinstance(loc, _cache._CoreStamp), f"{name}: {type(loc).__name__}"
        assert loc.get_source_stamp() == _cache.core_stamp()
        seen += 1
    assert seen > 20


def test_stamp_covers_every_core_module(tmp_path, monkeypatch):
    # the stamp changes when any core file changes: hash a copy, edit one file, hash again
    import shutil
    copy = tmp_path / "core"
    shutil.copytree(_cache.CORE_DIR, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(_cache, "CORE_DIR", str(copy))
    monkeypatch.setattr(_cache, "_stamp", None)
    before = _cache.core_stamp()
    monkeypatch.setattr(_cache, "_stamp", None)
    with open(copy / "distance.py", "a") as f:
        f.write("\n# edited\n")
    assert _cache.core_stamp() != before


def test_the_master_loop_cache_follows_core_edits():
    """fmu_sync/cosim_loop.py compiles the core's force assembly into its loop: its cached
    kernels are stamped with the core's stamp beside their own, so a core edit recompiles them"""
    from fmu_sync import cosim_driver, cosim_loop
    for kernel in (cosim_loop.loop_start, cosim_driver.drive):   # the start and the one driver (issue 43)
        stamp = kernel._cache._impl.locator.get_source_stamp()
        assert isinstance(stamp, tuple) and stamp[0] == _cache.core_stamp() and stamp[1] != _cache.core_stamp()


def test_the_drivers_cache_follows_an_edit_of_the_step_it_inlines(tmp_path, monkeypatch):
    """The master's driver (cosim_driver.py) inlines cosim_loop's step: its stamp is that of every file of its
    folder, so an edit of cosim_loop.py alone recompiles it (0.11.0 stamped the driver's own file only and
    loaded the driver with the old step). Checked on a copy of the folder: one file edited, the stamp changes."""
    import os
    import shutil
    from fmu_sync import cosim_driver
    folder = os.path.dirname(os.path.abspath(cosim_driver.__file__))
    assert cosim_driver.drive._cache._impl.locator.get_source_stamp()[1] == _cache.folder_stamp(folder)
    copy = tmp_path / "fmu_sync"
    copy.mkdir()
    for name in os.listdir(folder):
        if name.endswith(".py"):
            shutil.copy(os.path.join(folder, name), copy / name)
    before = _cache.folder_stamp(str(copy))
    assert before == _cache.folder_stamp(folder)
    monkeypatch.setattr(_cache, "_folders", {})
    with open(copy / "cosim_loop.py", "a") as f:
        f.write("\n# edited\n")
    assert _cache.folder_stamp(str(copy)) != before


_VERSIONED = r"""
import pickle, sys
import numpy as np
from fmu_sync.core.impact import impact_map_kernel as k
from fmu_sync.core.model import ImpactOscillator
from fmu_sync.core.distance import geometry
geo = geometry(ImpactOscillator(m=1, k=1, e=0.9), 1.0)
q, u, zq, zu = np.zeros(1), np.array([-1.0]), np.zeros(1), np.zeros(1)
k(geo, q, u, zq, zu)
index = k._cache._cache_file._index_path
if sys.argv[1] == "other":     # the index as another numba would have left it
    with open(index, "rb") as f:
        pickle.load(f)
        rest = f.read()
    with open(index, "wb") as f:
        pickle.dump("0.59.1", f, protocol=-1)
        f.write(rest)
with open(index, "rb") as f:
    print(pickle.load(f), k.stats.cache_hits.get(k.signatures[0], 0), len(k.stats.cache_misses))
"""


def test_a_kernel_cached_by_another_numba_is_never_loaded(tmp_path):
    """Issue 41 item 4: numba's own keying suffices. Its cache index starts with the numba version
    that wrote it, and an index of another version is read as empty (numba/core/caching.py,
    IndexDataCacheFile._load_index); our locators (core/_cache.py) change the folder and the
    source stamp, not that file. A kernel cached, its index relabelled as numba 0.59.1's, is
    compiled again (a miss, no hit) and the index rewritten under this numba's version."""
    import os
    import subprocess
    import sys

    import numba
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    run = (lambda *a: subprocess.run([sys.executable, "-c", _VERSIONED, *a], env=env, capture_output=True,
                                     text=True, timeout=300))
    first = run("other")
    assert first.returncode == 0, first.stderr
    assert first.stdout.split()[0] == "0.59.1"
    again = run("same")
    assert again.returncode == 0, again.stderr
    version, hits, misses = again.stdout.split()
    assert version == numba.__version__ and int(hits) == 0 and int(misses) >= 1, again.stdout
    third = run("same")     # and this numba's own entry is then loaded
    assert third.stdout.split()[1] != "0", third.stdout


def test_a_core_kernel_called_with_a_constant_and_with_a_variable_compiles_once():
    """core.jit's njit types a call from compiled code by value (ValueDispatcher): ``k(x, True)`` and
    ``k(x, flag)`` reach one compiled k, not one per literal (numba's own dispatcher compiles
    ``Literal[bool](True)`` apart: the core's kernels compiled up to seven times in the suite)."""
    from fmu_sync.core.jit import ValueDispatcher, njit

    @njit
    def k(x, flag, shift):
        return x + shift if flag else x

    @njit
    def with_constants(x):
        return k(x, True, 0) + k(x, False, 1)

    @njit
    def with_values(x, flag, shift):
        return k(x, flag, shift)

    assert isinstance(k, ValueDispatcher) and isinstance(k, CPUDispatcher)
    assert with_constants(1.0) == 2.0 and with_values(1.0, True, 2) == 3.0
    assert len(k.signatures) == 1, k.signatures
