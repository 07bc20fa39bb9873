"""The start of the event-time refinement shared by the exact solvers
(:mod:`.exact`, 1-DOF compiled; :mod:`.exact_nd`, n-DOF), docs/design.md §2.3."""
from __future__ import annotations

import math

from .jit import njit

__all__ = ["taylor_start"]


@njit(cache=True)
def taylor_start(lo, hi, flo, fplo, fpplo):
    """First iterate for a root of F in the bracket (lo, hi), F(lo) = flo.

    The first positive root s of the quadratic Taylor model of F at lo,
    flo + fplo s + fpplo s^2 / 2 (computed without cancellation), so that roots
    many orders of magnitude closer to lo than hi are found at once; lo + s if it
    lies inside the bracket, otherwise the bracket's midpoint.
    """
    sig = -1.0
    A = 0.5 * fpplo
    if A == 0.0:
        if fplo != 0.0:
            sig = -flo / fplo
    else:
        disc = fplo * fplo - 4.0 * A * flo
        if disc >= 0.0:
            q = -0.5 * (fplo + math.copysign(math.sqrt(disc), fplo))
            r1 = q / A
            r2 = flo / q if q != 0.0 else -1.0
            if r1 > 0.0 and (r2 <= 0.0 or r1 < r2):
                sig = r1
            elif r2 > 0.0:
                sig = r2
    x = lo + sig
    if not (lo < x < hi):
        x = 0.5 * (lo + hi)
    return x
