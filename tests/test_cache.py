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
    from fmu_sync import cosim_loop
    stamp = cosim_loop.exchange_chunk._cache._impl.locator.get_source_stamp()
    assert isinstance(stamp, tuple) and stamp[0] == _cache.core_stamp() and stamp[1] != _cache.core_stamp()
