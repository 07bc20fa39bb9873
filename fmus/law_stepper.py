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

Only the export imports this module (it needs numba); an FMU does not carry it.
"""
from __future__ import annotations

import types as pytypes

from numba import cfunc, njit

from . import stepper as S

__all__ = ["law_stepper"]

_STEPPERS: dict = {}   # law key (or id) -> cfunc, one compilation per process


def law_stepper(law):
    """The numba cfunc (:data:`.stepper.STEP_SIGNATURE`) stepping the FMU of force law ``law``."""
    key = law.key or id(law)
    if key in _STEPPERS:
        return _STEPPERS[key]
    g = dict(vars(S), advance_in=law.kernels().advance_in, N_P=len(law.params))
    for name, fn in (("_advance", S._advance.py_func), ("step", S.step._pyfunc)):
        f = pytypes.FunctionType(fn.__code__, g, name, fn.__defaults__, fn.__closure__)
        f.__qualname__ = f"{name}_{law.name}"
        g[name] = f
    g["_advance"] = njit(inline="always")(g["_advance"])
    c = cfunc(S.STEP_SIGNATURE, nopython=True)(g["step"])
    _STEPPERS[key] = c
    return c
