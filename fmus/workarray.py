"""The work arrays' packing and unpacking, shared by the FMU's steppers
(:mod:`fmus.stepper`, :mod:`fmus.coupling_stepper`).

A work array holds a header and then the model's arrays back to back, flat.
:func:`put` writes them (Python, once per configuration); :func:`mat` reads a
matrix back as a 2-D view at an offset (numba, every doStep). ``mat`` builds the
view directly (data pointer, shape, strides) instead of slicing and reshaping:
``reshape`` calls numba's C helper ``numba_attempt_nocopy_reshape`` each time,
a measurable part of a doStep of a small system (docs/design.md, the FMU's hot path).
"""
from __future__ import annotations

import numpy as np
from ..core.jit import NUMBA, njit

__all__ = ["put", "mat", "put_wall", "wall"]


def put(work: np.ndarray, k: int, arrays) -> int:
    """Write ``arrays`` flat (C order, float64) into ``work`` from slot ``k`` on; returns the slot after them."""
    for a in arrays:
        flat = np.ascontiguousarray(a, dtype=np.float64).reshape(-1)
        work[k:k + flat.size] = flat
        k += flat.size
    return k


def put_wall(work: np.ndarray, k: int, w, g0: float, e: float, Minv_w, W: float) -> int:
    """Write the wall block (w, g0, e, M^-1 w, W = w^T M^-1 w) from slot ``k`` on, the layout
    :func:`wall` reads; returns the slot after it."""
    n = len(w)
    work[k:k + n] = w
    work[k + n], work[k + n + 1] = g0, e
    k += n + 2
    work[k:k + n] = Minv_w
    work[k + n] = W
    return k + n + 1


@njit(cache=True, inline="always")
def wall(w, k, n):
    """The wall block :func:`put_wall` wrote at slot ``k`` (n DOF): views of w and M^-1 w,
    g0, e, W, and the slot after the block."""
    return w[k:k + n], w[k + n], w[k + n + 1], w[k + n + 2:k + 2 * n + 2], w[k + 2 * n + 2], k + 2 * n + 3


def _mat_python(w, k, r, c):
    """:func:`mat` as plain Python (the carried code's mode, core/jit.py): the same view."""
    return w[k:k + r * c].reshape((r, c))


if not NUMBA:
    mat = _mat_python
else:
    from numba import types
    from numba.core.imputils import impl_ret_borrowed
    from numba.extending import intrinsic
    from numba.np.arrayobj import make_array, populate_array

    @intrinsic
    def mat(typingctx, w, k, r, c):
        """``w[k:k + r * c].reshape((r, c))`` for a 1-D C-contiguous ``w``, as a view (same
        owner as ``w``) made without the reshape helper call; the caller guarantees
        ``k + r * c <= len(w)`` (the packed layout)."""
        if not (isinstance(w, types.Array) and w.ndim == 1 and w.layout == "C"
                and all(isinstance(a, types.Integer) for a in (k, r, c))):
            return None
        ret = types.Array(w.dtype, 2, "C")

        def codegen(context, builder, signature, args):
            wv, kv, rv, cv = args
            src = make_array(signature.args[0])(context, builder, wv)
            out = make_array(ret)(context, builder)
            kv, rv, cv = (context.cast(builder, v, t, types.intp) for v, t in zip((kv, rv, cv), signature.args[1:]))
            itemsize = context.get_constant(types.intp, context.get_abi_sizeof(context.get_data_type(w.dtype)))
            populate_array(out, data=builder.gep(src.data, [kv]), shape=[rv, cv],
                           strides=[builder.mul(cv, itemsize), itemsize], itemsize=itemsize,
                           meminfo=src.meminfo, parent=src.parent)
            return impl_ret_borrowed(context, builder, ret, out._getvalue())

        return ret(w, k, r, c), codegen
