"""The stepper of a user force law's FMU, made at export (docs/user-model.md "Export").

The FMU of a model declaration with a force law (:func:`.contract.declared`) runs the one
stepper of :mod:`.stepper` -- the same work array, outputs, rollback, early return and
return codes -- with its Moreau communication step replaced by the law's: the law's own
copy of :func:`fmu_sync.core.law_loops.law_advance` (:meth:`ForceLaw.kernels`, the law
inlined into it), with the law's parameters read from the work array
(:func:`.stepper.law_params`, packed by the slave). :func:`law_stepper` compiles that copy
as a numba cfunc; :func:`fmu_sync.native.stepper_object` turns it into the FMU binary's
native code, so the law runs on the target as compiled code, without numba.

A first-order hold of the input (fmi2SetRealInputDerivatives) holds, in each internal
step, the input at the step's force point ``t_k + a`` (a = dt/2 midpoint, θ dt theta).

Only the export imports this module (it needs numba); an FMU does not carry it.
"""
from __future__ import annotations

import types as pytypes

from numba import cfunc, njit

from ..core.moreau import THETA, substeps
from ..core.steps import OK
from . import stepper as S

__all__ = ["law_stepper"]

_STEPPERS: dict = {}   # law key (or id) -> cfunc, one compilation per process


def law_stepper(law):
    """The numba cfunc (:data:`.stepper.STEP_SIGNATURE`) stepping the FMU of force law ``law``."""
    key = law.key or id(law)
    if key in _STEPPERS:
        return _STEPPERS[key]
    advance = law.kernels().advance
    n_p = len(law.params)

    @njit(inline="always")
    def _advance(sa, q, u, t, H, dt, tau, taudot, scheme, theta, s, w):
        p = S.law_params(w, n_p)
        m = tau.shape[0]
        foh = False
        for j in range(m):
            if taudot[j] != 0.0:
                foh = True
        if not foh:
            return advance(sa, p, q, u, t, H, dt, tau, scheme, theta)
        tk = s[0:m]                # the scratch (advance() needs none of it)
        ks = substeps(H, dt)
        Psum = 0.0
        hits = 0
        for k in range(ks):
            t0 = t + k * dt
            hk = dt
            if k == ks - 1:
                hk = (t + H) - t0 if k > 0 else H
            a = theta * hk if scheme == THETA else 0.5 * hk
            for j in range(m):
                tk[j] = tau[j] + taudot[j] * ((t0 + a) - t)
            st, P, i = advance(sa, p, q, u, t0, hk, hk, tk, scheme, theta)
            Psum += P
            hits += i
            if st != OK:
                return st, Psum, hits
        return OK, Psum, hits

    py = S.step._pyfunc
    g = dict(vars(S))
    g["_advance"] = _advance
    f = pytypes.FunctionType(py.__code__, g, "step", py.__defaults__, py.__closure__)
    f.__qualname__ = f"step_{law.name}"
    c = cfunc(S.STEP_SIGNATURE, nopython=True)(f)
    _STEPPERS[key] = c
    return c
