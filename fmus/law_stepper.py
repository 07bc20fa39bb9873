"""The stepper of a user force law's FMU, made at export (docs/user-model.md "Export").

The FMU of a model declaration with a force law (:func:`.contract.declared`) runs the one
stepper of :mod:`.stepper` -- the same work array, outputs, rollback, early return, return
codes and the same communication step :func:`.stepper._advance` -- compiled with the law's
copy of the core's :func:`fmu_sync.core.moreau.advance_in` (:meth:`ForceLaw.kernels`: the
one loop template with the law's force inlined) and the law's parameter count ``N_P`` (its
parameters read from the work array, :func:`.stepper.law_params`, packed by the slave).
So the zero-order and the first-order hold of the input (fmi2SetRealInputDerivatives: the
input at each internal step's force point ``t_k + a``) are the core's own, bit for bit
``law.kernels().advance``. :func:`law_stepper` compiles it as a numba cfunc;
:func:`fmu_sync.native.stepper_object` turns it into the FMU binary's native code, so the law
runs on the target as compiled code, without numba.

The cfunc is cached on disk as the built-in stepper is (numba ``cache=True``), under
:func:`stepper_key`: everything it is made from -- the law's key (what numba compiles of h,
core/law_key.py, h's name and the law's form), what the stepper compiles in beside h (``N_P``,
whether it carries the corrected copy, the law's name), the source of this package's modules,
the numba, llvmlite and Python versions -- and the core's stamp, which the cache locator adds
(core/_cache.py); numba's index adds the target (CPU and triple). So a second export of the
same law compiles nothing (minutes of numba under load, otherwise); an edit of h or of what
it reads, of the core or of the stepper compiles again.

Only the export imports this module (it needs numba); an FMU does not carry it.
"""
from __future__ import annotations

import hashlib
import os
import sys
import types as pytypes

import llvmlite
import numba
from numba import njit
from numba.core import sigutils
from numba.core.ccallback import CFunc

from ..core.jit import LAW_KEY
from . import stepper as S

__all__ = ["law_stepper", "stepper_key", "compiled"]

_STEPPERS: dict = {}   # stepper key (or the law's id) -> cfunc, one compilation per process
#: the laws whose stepper this process compiled (a cache hit compiles none), by name
_COMPILED: list = []


def compiled() -> tuple:
    """The names of the laws whose FMU stepper this process compiled rather than loaded from
    the cache, in order."""
    return tuple(_COMPILED)


def _package_source() -> bytes:
    """The names and contents of this package's ``*.py`` files (what the stepper is made of
    besides the core, whose stamp the cache locator adds)."""
    folder = os.path.dirname(os.path.abspath(__file__))
    h = hashlib.sha256()
    for name in sorted(os.listdir(folder)):
        if name.endswith(".py"):
            h.update(name.encode() + b"\0")
            with open(os.path.join(folder, name), "rb") as f:
                h.update(hashlib.sha256(f.read()).digest())
    return h.digest()


def stepper_key(law) -> str | None:
    """The cache key of the FMU stepper of force law ``law`` (hex sha256): its
    :attr:`~fmu_sync.core.ForceLaw.key` (what numba compiles of h, h's name, n and form), what the
    stepper compiles in beside it (the parameter count, whether the law runs the trapezoid's corrected
    copy, the law's name),
    this package's source and the numba, llvmlite and Python versions; None for a law without
    a source file (no cache: it compiles in each process)."""
    if law.key is None:
        return None
    h = hashlib.sha256(law.key.encode())
    # what the stepper compiles in beside h's code (law.key): its parameter count, whether it carries the
    # trapezoid's corrected copy, its name (two laws with the same h may differ in these)
    h.update(f"|N_P {len(law.params)}|corrected {not law.linear_in_u}|name {law.name}".encode())
    h.update(_package_source())
    h.update(f"numba {numba.__version__}|llvmlite {llvmlite.__version__}|python {sys.version}".encode())
    return h.hexdigest()


class _LawCFunc(CFunc):
    """numba's cfunc, which tells ``on_compile`` when it compiles (a cache miss)."""

    on_compile = None
    law_name = ""

    def _compile_uncached(self):
        if self.on_compile is not None:
            self.on_compile(self.law_name)
        _COMPILED.append(self.law_name)
        return super()._compile_uncached()


def law_stepper(law, on_compile=None):
    """The numba cfunc (:data:`.stepper.STEP_SIGNATURE`) stepping the FMU of force law ``law``:
    loaded from the cache (:func:`stepper_key`) or compiled; ``on_compile(name)`` is called
    before it compiles (the export's progress line)."""
    cache_key = stepper_key(law)
    key = cache_key or id(law)
    if key in _STEPPERS:
        return _STEPPERS[key]
    plain, trapezoid = law.kernels(), law.kernels(trapezoid=True)   # one copy when the law needs no correction
    g = dict(vars(S), advance_in=plain.advance_in, N_P=len(law.params), LAW_TRAPEZOID=trapezoid is not plain,
             advance_in_trapezoid=trapezoid.advance_in)
    if cache_key is not None:    # the cache locator's key of this copy (core/_cache.py)
        g[LAW_KEY] = cache_key
    for name, fn in (("_advance", S._advance.py_func), ("step", S.step._pyfunc)):
        f = pytypes.FunctionType(fn.__code__, g, name, fn.__defaults__, fn.__closure__)
        f.__qualname__ = f"{name}_{law.name}"
        g[name] = f
    g["_advance"] = njit(inline="always")(g["_advance"])
    c = _LawCFunc(g["step"], sigutils.normalize_signature(S.STEP_SIGNATURE), locals={},
                  options={"nopython": True})
    c.on_compile, c.law_name = on_compile, law.name
    if cache_key is not None:
        try:
            c.enable_caching()
        except RuntimeError:   # numba finds no cache folder it can write: compiled in this process only
            pass
    c.compile()
    _STEPPERS[key] = c
    return c
