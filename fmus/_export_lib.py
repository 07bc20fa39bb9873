"""Workarounds for two memory bugs of pythonfmu 0.7.0's export library.

Our FMU binary is pythonfmu's ``libpythonfmu-export.so`` (no sources shipped;
read from the PythonFMU repository and confirmed with valgrind and refcounts).

1. Instance creation drops a reference it never took (``findClass``):
   on every ``fmi2Instantiate`` it imports the slave module, re-executes the
   module's source with the module's ``__dict__`` as globals, and then calls
   ``Py_DECREF`` on that dict, which ``PyModule_GetDict`` returned *borrowed*.
   Each instantiation thus steals one reference from the module's globals. A
   slave module whose functions hold references to its globals hides this for a
   while; our two-line entry-point script has none, so the second
   ``fmi2Instantiate`` in a process failed ("module has no attribute
   'ImpactOscillator'") or corrupted the heap ("corrupted double-linked list"):
   no master could run two instances. Fix: :func:`hold_module_globals`, called at
   the top of the entry-point script, i.e. on every (re-)execution, adds the
   reference that the library will drop.

2. Process exit writes into freed memory (pythonfmu issue #228):
   the library keeps its interpreter guard in a namespace-scope
   ``static std::shared_ptr<PyState> pyState`` and *also* resets that pointer
   from an ``__attribute__((destructor))`` function (``finalizePythonInterpreter``).
   The library has ``STB_GNU_UNIQUE`` symbols, so ``dlclose`` never unloads it
   (fmpy's ``freeLibrary`` is a no-op) and both run at process exit, in this order:

   a. ``exit()`` runs the C++ static destructors (``__cxa_atexit``): the
      shared_ptr is destroyed and its 128-byte control block freed;
   b. ``_dl_fini`` runs the library destructor, which assigns ``nullptr`` to the
      destroyed shared_ptr and decrements a counter inside the freed block
      (valgrind: "Invalid read of size 4 in finalizePythonInterpreter ... inside
      a block of size 128 free'd ... alloc'd in pythonfmu::createInstance").

   When glibc has put that chunk in the unsorted bin the write lands on its
   ``bk`` pointer, and the next ``free`` of an exit handler (here libgfortran's,
   loaded by numba through scipy) aborts with "corrupted double-linked list":
   46 of 50 fresh fmpy processes with numba loaded. Fix: while the interpreter
   is still fully alive (a Python ``atexit`` handler runs before ``exit()``),
   call the library's exported ``finalizePythonInterpreter()`` ourselves. It
   releases the guard through the live shared_ptr (under a Python host its
   destructor only joins an already finished thread) and leaves an empty pointer,
   so (a) and (b) touch no freed memory. After the fix: 0 crashes in hundreds of
   fresh processes, and valgrind reports no invalid access in the library.

   Only for hosts where Python owns the interpreter (fmpy, libcosimpy, any
   Python program): the handler runs in the process's main thread. In a C host
   the library initialises Python itself and finalises it from its own worker
   thread; there the handler does nothing (that host's exit is out of reach).
"""
from __future__ import annotations

import atexit
import ctypes
import os
import sys
import threading

__all__ = ["hold_module_globals", "register_export_library", "finalize_export_libraries"]

#: library path -> (CDLL handle, finalizePythonInterpreter function)
_LIBRARIES: dict[str, tuple] = {}
_LOCK = threading.Lock()
_REGISTERED = False


def hold_module_globals(module_globals: dict) -> None:
    """Add the reference to ``module_globals`` that the export library's
    instance creation will drop (bug 1 above). Call it from the module level of
    the FMU's entry-point script: the library re-executes that script on every
    fmi2Instantiate and then decrements its globals' reference count once.
    Over-counting only keeps a tiny dict alive until exit."""
    ctypes.pythonapi.Py_IncRef(ctypes.py_object(module_globals))


def _library_path(resources: str, model_identifier: str) -> str | None:
    if not sys.platform.startswith("linux"):
        return None
    res = resources
    if res.startswith("file://"):
        res = res[len("file://"):]
    res = os.path.abspath(res.rstrip("/"))
    return os.path.join(os.path.dirname(res), "binaries", "linux64", model_identifier + ".so")


def register_export_library(resources: str | None, model_identifier: str) -> bool:
    """Remember the export library of the FMU unpacked around ``resources`` so
    that :func:`finalize_export_libraries` releases it before exit.

    Opens the library with ``RTLD_NOLOAD``: it only finds a library the host has
    already loaded (never loads anything). Returns True if registered. Never raises.
    """
    global _REGISTERED
    try:
        if not resources:
            return False
        path = _library_path(resources, model_identifier)
        if path is None:
            return False
        with _LOCK:
            if path in _LIBRARIES:
                return True
            try:
                handle = ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_LAZY)
            except OSError:
                return False  # not loaded by this process (e.g. the export-time instance)
            fn = getattr(handle, "finalizePythonInterpreter", None)
            if fn is None:
                return False
            fn.restype = None
            fn.argtypes = []
            _LIBRARIES[path] = (handle, fn)
            if not _REGISTERED:
                atexit.register(finalize_export_libraries)
                _REGISTERED = True
        return True
    except Exception:  # pragma: no cover - never let bookkeeping break instantiate
        return False


def finalize_export_libraries() -> int:
    """Release the interpreter guard of every registered export library now.

    Called automatically at interpreter exit; safe to call earlier once all
    instances are freed (a later ``fmi2Instantiate`` simply creates a new guard).
    Returns the number of libraries released.
    """
    if threading.get_native_id() != os.getpid():
        # Finalisation is running in the library's own worker thread (C host):
        # resetting the guard from inside its own destructor would recurse.
        return 0
    with _LOCK:
        items = list(_LIBRARIES.values())
        _LIBRARIES.clear()
    for _handle, fn in items:
        fn()
    return len(items)
