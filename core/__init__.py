"""fmu_sync.core — the standalone numba engine (no FMI code here).

Model (:mod:`.model`), Moreau schemes (:mod:`.moreau`), exact solver
(:mod:`.exact`), quotient distance (:mod:`.distance`), coupling laws
(:mod:`.coupling`), the monolithic pair (:mod:`.pair`) and the shared result
(:mod:`.result`). Kernels compile lazily, on first use.
"""
from . import _cache  # noqa: F401  (first: every core kernel's cache is keyed on the whole core)
from .model import ImpactOscillator, MechanicalSystem, SystemArrays
from .impact import impact_map
from .simulate import SimulationDiverged, SimulationResult, simulate

__all__ = ["ImpactOscillator", "MechanicalSystem", "SystemArrays", "impact_map", "simulate",
           "SimulationResult", "SimulationDiverged"]
