"""The impact map (docs/design.md §2.2, paper eq. 5), as a function of a system.

    Zbar(q, u-) = (q, Z(u-)),   Z(u-) = u- - (1+e) M^-1 w min(0, w^T u-) / W,   W = w^T M^-1 w

Z = (1+e) prox - e id of the M-metric projection onto {w^T u >= 0}: Newton's law
w^T u+ = -e w^T u- for an approaching state, the identity for a leaving one.
The compiled kernel is :func:`impact_map_kernel` (on a
:class:`~fmu_sync.core.distance.DistanceGeometry`); :func:`impact_map` is its
checked Python entry point.
"""
from __future__ import annotations

import numpy as np
from .jit import njit

from .distance import make_geometry
from .model import MechanicalSystem, as_state

__all__ = ["impact_map", "impact_map_kernel"]


@njit(cache=True, error_model="numpy")
def impact_map_kernel(geo, q, u, zq, zu):
    """Zbar(q, u) = (q, Z u) into (zq, zu) (valid for any u; identity if w^T u >= 0)."""
    wu = 0.0
    for i in range(q.shape[0]):
        wu += geo.w[i] * u[i]
    c = (1.0 + geo.e) * min(0.0, wu) / geo.W
    for i in range(q.shape[0]):
        zq[i] = q[i]
        zu[i] = u[i] - c * geo.Minv_w[i]




def impact_map(system: MechanicalSystem, q, u, atol: float = 1e-12):
    """Post-impact velocity ``u+ = Z(u-)`` at a contact configuration ``g(q) = 0``.

    ``q, u`` are floats (1-DOF) or arrays; returns a float (1-DOF) or an (n,)
    array. A state on the wall that is not approaching it (``w^T u >= 0``) is a
    fixed point. Raises ValueError if ``|g(q)| > atol`` (the impact map is
    defined on the wall only; off the wall there is no impact).
    """
    q, u = as_state(system, (q, u), "(q, u)")
    g = system.gap(q)
    if abs(g) > atol:
        raise ValueError(f"the impact map is defined at the wall g(q) = 0 only; got g(q) = {g:.6g} "
                         f"(tolerance {atol:g})")
    sa = system.arrays()
    geo = make_geometry(sa.M, sa.w, sa.g0, sa.e)
    zq, zu = np.empty_like(q), np.empty_like(u)
    impact_map_kernel(geo, q, u, zq, zu)
    return float(zu[0]) if system.n == 1 else zu
