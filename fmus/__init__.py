"""FMI 2.0 / 3.0 co-simulation slaves (docs/design.md §4.3): Python slaves behind our own C binary.

* :mod:`.contract` — the FMU contract: variable names, the model registry (one
  ``FmuModel`` per model: ``ImpactOscillator`` 1-DOF, ``MechanicalSystem2`` 2-DOF with
  full M, K, C and an oblique wall), and the conversion between a core system and the
  FMU's values (everything that crosses the FMI boundary is named there and nowhere else),
* :mod:`.slave` — ``MechanicalSlave(model)``, the one slave of every model (interface,
  validation, FMU state format),
* :mod:`.runtime` — the Python object behind one FMU instance (called by the binary),
* :mod:`.stepper` — the hot path: a numba cfunc the binary calls per doStep,
* :mod:`.boot` — the FMU's boot script (environment check, code unpacking),
* ``c/fmu_sync_fmi2.c`` — the FMI 2.0 glue (state table, statuses), and
  ``c/fmu_sync_runtime.c`` — the instance runtime (Python embedding, the
  communication step; API in ``c/fmu_sync_runtime.h``): the binary, compiled at export.

Build the FMUs with :func:`fmu_sync.export.export_fmu`. This package and its
modules import each other relatively: an FMU carries those its runtime, stepper and
slave import (with the core modules they import) under a package name of its own. Importing this package imports nothing heavy.
"""
