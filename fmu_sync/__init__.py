"""fmu-sync: controlled synchronization of mechanical systems with a unilateral constraint.

The component-level API (the core's own API is :mod:`fmu_sync.core`):

* :func:`cosimulate`, :func:`cosimulate_network` — the co-simulation master
  (:class:`SlaveError` when a slave fails; :class:`NetworkResult`);
* :func:`export_fmu` — build an FMI 2.0 co-simulation FMU of a registered model;
* :func:`load_scene`, :func:`run_scene`, :func:`convergence`, :func:`list_scenes`, :func:`run_demo` — scenes
  (:class:`SceneError` for a bad scene);
* :func:`sweep` — families of pair runs (gain maps, basins, samples) as an xarray Dataset,
  on all cores or a Dask cluster (:mod:`fmu_sync.sweeps`);
* :func:`sync_rate` — the decay rate of d over start states (median and interquartile
  range), in the core or in co-simulation (:mod:`fmu_sync.ensemble`);
* :func:`load` — a saved run (``.npz``, ``.csv``, ``.nc``) back into its result object, a
  sweep's ``.nc`` into its Dataset; :func:`redraw` — a finished run's plots again
  (``fmu-sync plot DIR``; docs/results.md);
* ``__version__`` (single source: pyproject.toml, through the installed package's metadata).

The names load on first use (PEP 562), so ``import fmu_sync`` imports neither
fmpy nor the FMU export, and a core-only run never loads the master.
"""
from importlib import import_module
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _metadata_version


def _version() -> str:
    """The installed distribution's version (its metadata, written from pyproject.toml at install;
    after a version bump in a checkout, ``pip install -e .`` again); "0+unknown" where fmu-sync is
    not installed."""
    try:
        return _metadata_version("fmu-sync")
    except PackageNotFoundError:  # pragma: no cover - imported without being installed
        return "0+unknown"


__version__ = _version()

#: public name -> module that defines it
_API = {
    "cosimulate": "master", "cosimulate_network": "master", "NetworkResult": "master", "SlaveError": "master",
    "export_fmu": "export",
    "load_scene": "scenes.loading", "list_scenes": "scenes.loading", "Scene": "scenes.schema",
    "SceneError": "scenes.schema", "run_scene": "scenes.running",
    "convergence": "scenes.convergence", "run_demo": "scenes.demo",
    "sweep": "sweeps",
    "load": "results", "redraw": "results",
    "sync_rate": "ensemble",
    "ToleranceNotMet": "core.errors",
}

__all__ = ["__version__", *_API]


def __getattr__(name):
    if name in _API:
        value = getattr(import_module(f"{__name__}.{_API[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_API))
