"""One numba compile per kernel and signature for the whole test run, not one per xdist worker
(tests/conftest.py installs it in each worker; docs/design.md "The test suite").

On a cold cache (a fresh clone, CI) both workers meet the same big kernels (the master's driver,
the FMU steppers) at about the same time and each compiled them, for the same on-disk cache
entry. Here a top-level compile of a cached kernel (``@njit(cache=True)``, ``@cfunc(cache=True)``)
first takes a file lock named by the kernel and its signature, shared by the run's workers: the
first worker compiles and saves it; the other waits, then finds it in numba's cache and loads it.
Nothing of the compiled code changes (the same numba compile, the same cache), only who does it.
A compile nested in another (a kernel first met while typing its caller) takes its own lock too: the
sweep's kernel and the other worker's pair run both need the network loop, and each compiled it. Lock
order cannot cycle: a worker holds the locks of a chain of callers and waits for a callee's, and the
kernels' calls form no cycle (a kernel met again inside its own compile, by recursion, is not locked
again). Kernels without a disk cache are left as they are."""
from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import threading

_held = threading.local()   # the keys this thread holds the locks of (its chain of nested compiles)


@contextlib.contextmanager
def _locked(folder: str, key: str):
    path = os.path.join(folder, hashlib.sha1(key.encode()).hexdigest() + ".lock")
    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _guard(compile_, key_of):
    def compile(self, *args):
        key = key_of(self, *args)
        held = _held.__dict__.setdefault("keys", set())
        if key is None or key in held:
            return compile_(self, *args)
        held.add(key)
        try:
            with _locked(_FOLDER[0], key):
                return compile_(self, *args)
        finally:
            held.discard(key)
    return compile


_FOLDER: list = []


def _name(func) -> str:
    return f"{getattr(func, '__module__', '?')}.{getattr(func, '__qualname__', '?')}"


def _dispatcher_key(self, sig):
    from numba.core import sigutils
    from numba.core.caching import NullCache
    args = tuple(sigutils.normalize_signature(sig)[0])
    if isinstance(self._cache, NullCache) or args in self.overloads:
        return None
    return f"{_name(self.py_func)}|{args}"


def _cfunc_key(self):
    from numba.core.caching import NullCache
    return None if isinstance(self._cache, NullCache) else f"{_name(self._pyfunc)}|{self._sig}"


def install(folder: str) -> None:
    """Guard numba's compiles of cached kernels with file locks in ``folder`` (shared by the run's
    workers, one run's own)."""
    if _FOLDER:
        return
    os.makedirs(folder, exist_ok=True)
    _FOLDER.append(folder)
    from numba.core import ccallback, dispatcher
    dispatcher.Dispatcher.compile = _guard(dispatcher.Dispatcher.compile, _dispatcher_key)
    ccallback.CFunc.compile = _guard(ccallback.CFunc.compile, _cfunc_key)
