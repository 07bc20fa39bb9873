"""FMI 2.0 co-simulation slaves (docs/design.md §4.3): Python slaves behind our own C binary.

* :mod:`.contract` — the FMU contract: variable names, the model registry, and
  the conversion between a core system and the FMU's values (everything that
  crosses the FMI boundary is named there and nowhere else),
* :mod:`.impact_oscillator` — ``ImpactOscillator`` (1-DOF),
* :mod:`.mechanical_system2` — ``MechanicalSystem2`` (2-DOF, full M, K, C, oblique wall),
* :mod:`.slave` — what both share (interface, validation, FMU state format),
* :mod:`.runtime` — the Python object behind one FMU instance (called by the binary),
* :mod:`.stepper` — the hot path: a numba cfunc the binary calls per doStep,
* :mod:`.boot` — the FMU's boot script (environment check, code unpacking),
* ``c/fmu_sync_fmi2.c`` — the FMI 2.0 glue (state table, statuses), and
  ``c/fmu_sync_runtime.c`` — the instance runtime (Python embedding, the
  communication step; API in ``c/fmu_sync_runtime.h``): the binary, compiled at export.

Build the FMUs with :func:`fmu_sync.export.export_fmu`. This package and its
modules import each other relatively: the FMU carries them (with the core) under
a package name of its own. Importing this package imports nothing heavy.
"""
