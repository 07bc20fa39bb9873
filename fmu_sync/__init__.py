"""fmu-sync: controlled synchronization of mechanical systems with a unilateral constraint.

The component-level API (the core's own API is :mod:`fmu_sync.core`):

* :func:`cosimulate`, :func:`cosimulate_network` — the co-simulation master;
* :func:`export_fmu` — build an FMI 2.0 co-simulation FMU of a registered model;
* :func:`load_scene`, :func:`run_scene`, :func:`list_scenes`, :func:`run_demo` — scenes;
* ``__version__``.

Importing this package imports no FMI library (fmpy loads on the first co-simulation).
"""
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _metadata_version

try:
    __version__ = _metadata_version("fmu-sync")
except PackageNotFoundError:  # pragma: no cover - a source tree that was never installed
    __version__ = "0+unknown"

from .export import export_fmu  # noqa: E402
from .master import NetworkResult, SlaveError, cosimulate, cosimulate_network  # noqa: E402
from .scene import Scene, SceneError, list_scenes, load_scene, run_demo, run_scene  # noqa: E402

__all__ = ["__version__", "cosimulate", "cosimulate_network", "NetworkResult", "SlaveError", "export_fmu",
           "load_scene", "run_scene", "list_scenes", "run_demo", "Scene", "SceneError"]
