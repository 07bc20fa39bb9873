"""FMI 2.0 co-simulation slaves (docs/design.md §4.3), written with pythonfmu.

* :mod:`.contract` — the FMU contract: variable names, the model registry, and
  the conversion between a core system and the FMU's values (everything that
  crosses the FMI boundary is named there and nowhere else),
* :mod:`.impact_oscillator` — ``ImpactOscillator`` (1-DOF),
* :mod:`.mechanical_system2` — ``MechanicalSystem2`` (2-DOF, full M, K, C, oblique wall),
* :mod:`.slave` — what both share (interface, errors, FMU state, one core call per doStep),
* :mod:`._export_lib` — workarounds for two memory bugs of pythonfmu 0.7.0's export library.

Build the FMUs with :func:`fmu_sync.export.export_fmu`. Importing this package
imports nothing heavy (the FMU entry-point script imports it first).
"""
