"""numba cache keys for the core: one stamp for the whole package.

numba (0.68) stamps a cached kernel with the hash of the *file that defines
it*. Our kernels inline or call kernels of other core modules (``pair`` calls
``coupling``, which calls ``distance``; the FMU stepper calls ``moreau``), so an
edit of ``distance.py`` would leave the cached ``pair``/``coupling`` kernels
silently running the old code. This module registers cache locators, used for
files of this package only, whose source stamp is the hash of *all* core
modules: any change of the core invalidates every core kernel's cache, and
nothing else changes (same cache folders, same rules for NUMBA_CACHE_DIR and
for read-only installs).
"""
from __future__ import annotations

import hashlib
import os
import weakref

from numba.core import caching

from .jit import LAW_KEY  # noqa: F401 (the law's key global, defined in core/jit.py)

__all__ = ["install", "core_stamp", "folder_stamp", "depends_on_core", "law_function", "CORE_DIR"]

CORE_DIR = os.path.dirname(os.path.abspath(__file__))
_stamp: bytes | None = None


def _hash_folder(folder: str) -> bytes:
    """sha256 over the names and contents of every ``*.py`` file of ``folder``."""
    h = hashlib.sha256()
    for name in sorted(os.listdir(folder)):
        if name.endswith(".py"):
            h.update(name.encode())
            with open(os.path.join(folder, name), "rb") as f:
                h.update(f.read())
    return h.digest()


def core_stamp() -> bytes:
    """sha256 over the names and contents of every ``*.py`` file of the core."""
    global _stamp
    if _stamp is None:
        _stamp = _hash_folder(CORE_DIR)
    return _stamp


_folders: dict = {}


def folder_stamp(folder: str) -> bytes:
    """:func:`core_stamp` of another folder (a dependent file's, :func:`depends_on_core`), once per process."""
    folder = os.path.abspath(folder)
    if folder not in _folders:
        _folders[folder] = _hash_folder(folder)
    return _folders[folder]


#: files outside the core whose kernels compile core kernels into themselves (registered
#: with :func:`depends_on_core` before their first ``@njit(cache=True)``): path -> whether their
#: folder's other files count too
_DEPENDENTS: dict = {}


def depends_on_core(py_file: str, neighbours: bool = False) -> None:
    """Stamp the cached kernels of ``py_file`` with the core's stamp and the file's own: an edit of
    the core then recompiles them too (fmu_sync/cosim_loop.py compiles the core's force assembly into
    its loop; a user's force law, core/forcelaw.py). ``neighbours``: the stamp of every ``*.py`` of
    the file's folder instead of the file's own, for kernels that inline kernels of the files beside
    them (the master's driver in cosim_driver.py inlines cosim_loop's step: with its own file's stamp
    alone, an edit of cosim_loop.py left the cached driver running the old step)."""
    _DEPENDENTS[os.path.abspath(py_file)] = neighbours


#: a user force law's own h (its Python function) -> the law's key, registered with
#: :func:`law_function` before h's ``@njit(cache=True)``
_LAW_FUNCS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def law_function(py_func, key: str) -> None:
    """Stamp the cached h of a force law with the law's key as well as its file's stamp (the
    key in the disambiguator too): h's own compiled code calls the helpers it reads, and a
    helper in another file is in the key (core/law_key.py), not in the stamp of h's file that
    numba gives it. Unlike the law's copies of the loops, h's own entry is not shared between
    files: numba's entry names h's module, and a user file's module name follows its content."""
    _LAW_FUNCS[py_func] = key



class _CoreStamp:
    """The locator of every kernel built on the core, three kinds told apart by one key:

    * a core file's kernel: the package-wide stamp;
    * a kernel of a registered dependent file (:func:`depends_on_core`): the core's stamp and
      the file's own, or its folder's (:func:`folder_stamp`);
    * a user force law's copy of the core's loop templates (its globals carry :data:`LAW_KEY`,
      core/forcelaw.py), and the law's h itself (:func:`law_function`): its own index file per
      law (the key in the disambiguator) and the stamp ``(core stamp, key)`` (the hash of what
      numba compiles of h, core/law_key.py), so an edit of either recompiles and two laws share
      an entry only when h is the same code."""

    _law_key = None
    _law_h = False   # the law's h itself (law_function), not a copy of the loops

    def get_source_stamp(self):
        if self._law_key is not None:   # h itself: its file's stamp too (numba's entry names h's module,
            # whose name follows the file's content: core/registry.py), cheap to compile again
            return (core_stamp(), super().get_source_stamp(), self._law_key) if self._law_h \
                else (core_stamp(), self._law_key)
        path = os.path.abspath(self._py_file)
        if path in _DEPENDENTS:
            own = folder_stamp(os.path.dirname(path)) if _DEPENDENTS[path] else super().get_source_stamp()
            return (core_stamp(), own)
        return core_stamp()

    def get_disambiguator(self):
        d = super().get_disambiguator()
        return d if self._law_key is None else f"{d}_{self._law_key[:20]}"

    @classmethod
    def from_function(cls, py_func, py_file):
        key = getattr(py_func, "__globals__", {}).get(LAW_KEY)
        law_h = key is None and py_func in _LAW_FUNCS
        key = _LAW_FUNCS[py_func] if law_h else key
        path = os.path.abspath(py_file)
        if key is None and os.path.dirname(path) != CORE_DIR and path not in _DEPENDENTS:
            return None
        self = super().from_function(py_func, py_file)
        if self is not None:
            self._law_key, self._law_h = key, law_h
        return self


def _locator(name: str):
    """numba's locator class ``name``: public from numba 0.62 on, ``_name`` before (0.60, 0.61)."""
    return getattr(caching, name, None) or getattr(caching, "_" + name)


class CoreUserProvidedLocator(_CoreStamp, _locator("UserProvidedCacheLocator")):
    """NUMBA_CACHE_DIR set: the user's folder, package-wide stamp."""


class CoreInTreeLocator(_CoreStamp, _locator("InTreeCacheLocator")):
    """``core/__pycache__``, package-wide stamp."""


class CoreUserWideLocator(_CoreStamp, _locator("UserWideCacheLocator")):
    """Read-only install: the user-wide cache folder, package-wide stamp."""


def install() -> None:
    """Put the core locators first, in numba's own order of preference."""
    classes = caching.CacheImpl._locator_classes
    for cls in (CoreUserWideLocator, CoreInTreeLocator, CoreUserProvidedLocator):
        if cls not in classes:
            classes.insert(0, cls)


install()
