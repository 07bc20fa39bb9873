"""fmu_sync.core — the standalone numba engine (no FMI code here).

The public API of the core (everything a user of the standalone engine needs):

* models: :class:`MechanicalSystem`, :func:`ImpactOscillator`, and the one model declaration
  :class:`Model` / :class:`Param` (built-ins :data:`IMPACT_OSCILLATOR`, :data:`MECHANICAL_SYSTEM`;
  a user's ``"model.py:name"`` by :func:`load_model`); user force laws
  :class:`ForceLaw` (:func:`force_law`; built-in examples in
  :mod:`.examples`: the impacting pendulum and the Duffing oscillator);
* the impact map :func:`impact_map`;
* runs: :func:`simulate` (one system), :func:`simulate_pair` (two coupled systems,
  identical or not), :func:`simulate_network` (N systems on a graph: :func:`ring`,
  :func:`path`, :func:`star`, :func:`all_to_all`);
* synchronization metrics :func:`sync_metrics` (decay rate with its spread and
  whether it is resolved, t_sync, ultimate bound; :class:`SyncMetrics`), the rate over
  start states :func:`sync_rate` (median and interquartile range; :class:`EnsembleRate`), and the stability limit of the
  held coupling :func:`exchange_limit` (:class:`UnstableExchange` when refused);
* the quotient distance :func:`quotient_distance`, the coupling laws
  :func:`coupling_forces` and the laws' own position weight :func:`energy_metric`
  (Q = K + 2 Kp for a pair: V = d^2/2 is then the energy of the relative motion);
* the exact event-driven solver :func:`simulate_exact` / :func:`exact_events` (any n: the
  compiled closed form for n = 1, the matrix flow for n > 1; results :class:`ExactEvents`);
* results :class:`SimulationResult`, :class:`PairResult`, :class:`NetworkResult`, and the errors
  :class:`SimulationDiverged` (a run that failed; :class:`ForceLawFailed`: a user force law
  raised mid-run) and the refusals made before the first step,
  each of its own type, all :class:`RunRefused` (ValueErrors): :class:`UnstableScheme`,
  :class:`UnstableExchange`, :class:`InadmissibleState`, :class:`RecordTooLarge`;
* the run plan :func:`plan_run` (:class:`RunPlan`): every check of a run, made once
  (docs/design.md §5.1.1), the one the drivers, scenes, sweeps, master and slave use.

The raw compiled kernels (for benchmarks and custom loops) are in :mod:`.kernels`.
Where each concept lives: docs/design.md §3. Kernels compile lazily, on first use.
"""
from . import _cache  # noqa: F401  (first: every core kernel's cache is keyed on the whole core)
from .model import IMPACT_OSCILLATOR, MECHANICAL_SYSTEM, ImpactOscillator, MechanicalSystem, SystemArrays
from .declaration import Model, ModelError, Param
from .registry import load_model
from .impact import impact_map
from .errors import ForceLawFailed, RunFailed, RunRefused, SimulationDiverged, UnstableScheme
from .checks import InadmissibleState, RecordTooLarge, StepTooLarge
from .plan import RunPlan, plan_run
from .result import NetworkResult, PairResult, SimulationResult
from .single import simulate
from .distance import quotient_distance
from .coupling import coupling_forces, energy_metric
from .pair import simulate_pair
from .metrics import SyncMetrics, sync_metrics
from .ensemble import EnsembleRate, sync_rate
from .exchange import UnstableExchange, exchange_limit, hold_bound
from .network import all_to_all, path, ring, simulate_network, star
from .exact import ExactEvents, exact_events, simulate_exact
from .forcelaw import ForceLaw, force_law
from .errors import LawRefused

__all__ = ["Model", "Param", "ModelError", "load_model", "IMPACT_OSCILLATOR", "MECHANICAL_SYSTEM",
           "ImpactOscillator", "MechanicalSystem", "SystemArrays", "impact_map", "simulate", "simulate_pair",
           "quotient_distance", "coupling_forces", "energy_metric", "simulate_exact", "exact_events", "ExactEvents",
           "SimulationResult", "PairResult", "RunFailed", "ForceLawFailed",
           "SimulationDiverged", "NetworkResult", "simulate_network", "ring", "path", "star", "all_to_all",
           "sync_metrics", "SyncMetrics", "sync_rate", "EnsembleRate", "exchange_limit", "hold_bound", "UnstableExchange", "UnstableScheme",
           "RunRefused", "InadmissibleState", "RecordTooLarge", "StepTooLarge", "RunPlan", "plan_run", "ForceLaw", "force_law", "LawRefused"]
