"""The compiled kernels, as a documented public entry point (docs/design.md §4.1).

For benchmarks and for users who write their own compiled loops: the functions
here are the very kernels :func:`~fmu_sync.core.simulate`,
:func:`~fmu_sync.core.simulate_pair` and the FMU slave run (nothing is wrapped
or copied). They take the packed arrays of :meth:`MechanicalSystem.arrays` and
the geometry of :func:`make_geometry`, perform no argument checks, and return
status codes instead of raising. Prefer the checked entry points of
:mod:`fmu_sync.core` unless you need the raw loop.

* time stepping: :func:`kernels_for` (the fixed-step loop of a system),
  :func:`advance` (one communication step of internal steps), status codes
  ``OK``/``DIVERGED``, scheme codes ``MIDPOINT``/``THETA``;
* distance: :func:`make_geometry`, :func:`distance_kernel`, :func:`distance_value`,
  :func:`distance1` (1-DOF floats), :func:`distance_kernel_unpruned` (no lower-bound
  pruning: the reference of the pruning benchmark), :func:`core_2d` (planar core);
* coupling: :func:`coupling_kernel`, :func:`coupling_kernel1`, :func:`gain_matrix`,
  law codes ``SWITCHING``/``EUCLIDEAN``/``UNCOUPLED``;
* :func:`impact_map_kernel`;
* the exact communication step of a 1-DOF slave: :func:`exact_model` (pack a system),
  :func:`exact_step` (compiled; one step [t, t + H] with constant tau), status ``STEP_OK``.
"""
from .coupling import EUCLIDEAN, SWITCHING, UNCOUPLED, coupling_kernel, coupling_kernel1, gain_matrix
from .distance import (core_2d, distance1, distance_kernel, distance_kernel_unpruned, distance_value,
                       make_geometry)
from .impact import impact_map_kernel
from .exact_step import STEP_OK, exact_model, exact_step
from .moreau import DIVERGED, MIDPOINT, OK, THETA, advance, kernels_for
from ._cache import depends_on_core   # a custom loop compiling core kernels in registers its file

__all__ = ["depends_on_core", "kernels_for", "advance", "OK", "DIVERGED", "MIDPOINT", "THETA", "make_geometry", "distance_kernel",
           "distance_value", "distance1", "distance_kernel_unpruned", "core_2d", "coupling_kernel",
           "coupling_kernel1", "gain_matrix", "SWITCHING", "EUCLIDEAN", "UNCOUPLED", "impact_map_kernel",
           "exact_model", "exact_step", "STEP_OK"]
