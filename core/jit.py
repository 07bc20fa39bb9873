"""The one place where the core (and the FMU's steppers) meet numba (docs/design.md §4.3).

Every compiled function of the core is decorated with :func:`njit` from here, and the
FMU's steppers take :func:`cfunc` and :func:`carray` from here. Two modes:

* **compiled** (``NUMBA`` true): the names are numba's own (``fmu_sync`` as installed);
* **plain Python** (``NUMBA`` false): the decorators return the function unchanged, so
  the same modules import and run with numpy alone. This is the mode of the code an
  FMU carries: the carried package's ``__init__`` sets ``PLAIN_PYTHON = True``
  (``fmu_sync.export``), so its configuration code runs as Python and nothing is ever
  compiled (nor numba imported) on the machine that runs the FMU -- its stepper is the
  native code compiled at export into the FMU's binary. Without numba at all, the mode
  is plain Python as well.
"""
from __future__ import annotations

import sys

__all__ = ["NUMBA", "njit", "cfunc", "carray", "LAW_KEY"]

#: the global of a user force law's specialised kernels (core/forcelaw.py, fmus/law_stepper.py) that holds
#: the law's key, read by the cache locator (core/_cache.py)
LAW_KEY = "__fmu_sync_law_key__"


def _plain_requested() -> bool:
    top = sys.modules.get(__name__.split(".")[0])
    return bool(getattr(top, "PLAIN_PYTHON", False))


NUMBA = False
if not _plain_requested():
    try:
        from numba import carray, cfunc  # noqa: F401
        from numba import njit as _numba_njit
        from numba.core import types as _types
        from numba.core.registry import CPUDispatcher as _CPUDispatcher
        NUMBA = True
    except ImportError:
        pass

if NUMBA:
    class ValueDispatcher(_CPUDispatcher):
        """numba's dispatcher, typed by value when compiled code calls it: an argument that is a
        constant there (``True``, ``0``, a tuple holding one) counts as its type (bool, int64), not as
        a literal of its own. numba would compile the kernel once more for each such literal: the
        core's kernels are called with ``need_d=True`` here and a variable there, ``k0=0`` here and
        ``k`` there, and compiled up to seven times each in the test suite (docs/design.md §5.6).
        The values and the arithmetic are the same; only fewer copies are compiled."""

        def get_call_template(self, args, kws):
            return super().get_call_template(tuple(_types.unliteral(a) for a in args),
                                             {k: _types.unliteral(v) for k, v in kws.items()})

    def _by_value(dispatcher):
        if type(dispatcher) is _CPUDispatcher:
            dispatcher.__class__ = ValueDispatcher
        return dispatcher

    def njit(*args, **options):
        """numba's ``njit``, its dispatcher a :class:`ValueDispatcher`."""
        if len(args) == 1 and callable(args[0]) and not options:
            return _by_value(_numba_njit(args[0]))
        decorate = _numba_njit(*args, **options)
        return lambda func: _by_value(decorate(func))

if not NUMBA:
    def njit(*args, **options):
        """``@njit`` or ``@njit(**options)``: the function itself."""
        if len(args) == 1 and callable(args[0]) and not options:
            return args[0]
        return lambda func: func

    def cfunc(signature, **options):
        """``@cfunc(signature, ...)``: the Python function itself (its compiled form is the
        FMU binary's native code)."""
        return lambda func: func

    def carray(ptr, shape, dtype=None):
        raise RuntimeError("carray needs numba: a cfunc body runs only as compiled code")
