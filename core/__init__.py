"""fmu_sync.core — the standalone numba engine (no FMI code here)."""
from .model import MechanicalSystem, ImpactOscillator, SystemArrays
from .simulate import simulate, SimulationResult, SimulationDiverged
