"""The ensemble decay rate in the core or in co-simulation (:func:`sync_rate`), and for a scene
variant (:func:`variant_sync_rate`: ``fmu-sync run SCENE --starts N``, the demo).

The statistic itself (start states, median and interquartile range) is the core's
:func:`fmu_sync.core.ensemble.sync_rate`; this module only supplies how one start runs.
"""
from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path
from typing import Callable

from .core.ensemble import N_STARTS, SPREAD, EnsembleRate
from .core.ensemble import sync_rate as core_sync_rate

__all__ = ["sync_rate", "variant_sync_rate", "EnsembleRate", "N_STARTS"]

MODES = ("core", "cosim")


def sync_rate(system, law: str | None = "switching", n_starts: int = N_STARTS, *, x1, x2, t_end: float, dt: float,
              Kp=0.0, Kd=0.0, mode: str = "core", H: float | None = None, fmu=None, seed: int = 0,
              spread: float = SPREAD, threshold: float = 1e-6, progress: Callable | None = None,
              **options) -> EnsembleRate:
    """The decay rate of d over ``n_starts`` start states around ``x1, x2`` (median and
    interquartile range; :func:`fmu_sync.core.ensemble.sync_rate`).

    ``mode="core"``: each start is ``simulate_pair`` at ``dt``. ``mode="cosim"``: each start is
    ``cosimulate`` of two instances of ``fmu`` (default: the registered model of the system,
    exported into a temporary folder) at communication step ``H``, the FMU's parameters set to
    ``system`` and its internal step to ``dt``. ``law`` is any coupling law's name; ``options`` go
    to the driver of each start (``Q``, ``record_every``, ``hold``, ...)."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    common = dict(x1=x1, x2=x2, t_end=t_end, dt=dt, Kp=Kp, Kd=Kd, seed=seed, spread=spread,
                  threshold=threshold, progress=progress)
    if mode == "core":
        return core_sync_rate(system, law, n_starts, **common, **options)
    if H is None or not H > 0:
        raise ValueError(f"mode = cosim needs a positive communication step H, got {H}")
    force = getattr(system, "force", None)
    if force is not None:
        raise ValueError(f"sync_rate(mode='cosim') builds the FMU's parameters from the system, which a system with "
                         f"the force law {force.name!r} cannot give (its model declaration has the parameters): run "
                         f"its scene in co-simulation with --starts N (fmu-sync run SCENE --set run.mode=cosim "
                         f"--starts {n_starts}, docs/user-model.md), or mode='core'")
    from .fmus import contract
    from .master import cosimulate
    model = contract.model_for("impact-oscillator" if system.n == 1 else "mechanical-system", system.n)
    if model is None:
        raise ValueError(f"no registered FMU model has n = {system.n} degrees of freedom")
    values = {**model.values(system), **model.solver_values(dt)}
    coupling = None if law in (None, "none") else law
    with tempfile.TemporaryDirectory(prefix="fmu-sync-ensemble-") as tmp:
        if fmu is None:
            from .export import export_fmu
            fmu = export_fmu(model.key, Path(tmp) / f"{model.key}.fmu", None)

        def run(a, b):
            return cosimulate(fmu, a, b, t_end, H, coupling=coupling, Kp=Kp, Kd=Kd, start_values=values, **options)
        return core_sync_rate(system, law, n_starts, run=run, **common)


def variant_sync_rate(variant, n_starts: int = N_STARTS, fmu_path=None, seed: int = 0,
                      progress: Callable | None = None, scene_name: str = "") -> EnsembleRate:
    """The ensemble rate of a coupled pair variant of a scene, run by the scene runner in its own
    mode (core, or co-simulation with ``fmu_path``) from ``n_starts`` start states around its
    own ``x1, x2`` (the first start is the variant itself)."""
    from .scenes.running import run_variant
    if not variant.pair or variant.is_network:
        raise ValueError(f"variant {variant.name!r}: an ensemble rate needs a coupled pair (not a single system "
                         "or a network)")
    cfg = variant.cfg

    def run(a, b):
        return run_variant(dataclasses.replace(variant, x1=a, x2=b), fmu_path, None, scene_name)
    return core_sync_rate(variant.system, variant.law, n_starts, x1=variant.x1, x2=variant.x2,
                          t_end=cfg["run.t_end"], dt=cfg["solver.dt"], seed=seed, run=run, progress=progress)


#: The ensemble table's header (summary.md, the demo, ``fmu-sync run --starts``).
HEADER = ("variant", "mode", "coupling", "ensemble decay rate [1/s]: median [IQR]", "starts resolved")


def table_rows(entries) -> list[list[str]]:
    """Rows of the ensemble table from ``(variant name, mode, law, EnsembleRate)`` entries."""
    return [[name, mode, law or "none",
             (f"{e.median:.3g} [{e.q25:.3g}, {e.q75:.3g}]" if e.n_resolved else "—"),
             f"{e.n_resolved}/{e.n_starts}"] for name, mode, law, e in entries]


def markdown(entries, n_starts: int) -> list[str]:
    """The ensemble section of a summary.md: its table and what it means."""
    from .report import md_table
    return ["## Ensemble decay rate", "",
            f"The decay rate of d over {n_starts} start states of each coupled variant (the variant's own "
            "first, the others drawn from the box its two start states span, widened by half its size on "
            "each side; seed 0): the median and the interquartile range of the resolved rates. For a forced "
            "impacting pair one start's rate is a sample of this distribution: compare laws by it.", ""] + \
        md_table(list(HEADER), table_rows(entries)) + [""]


def scene_ensembles(runs, n_starts: int, fmu_dir=None, progress: Callable | None = None,
                    scene_name: str = "", fmu_path=None) -> list:
    """``(name, mode, law, EnsembleRate)`` of every coupled pair variant among ``runs`` (records
    of a scene run that finished); co-simulated variants use ``fmu_path`` (the FMU the scene
    ran), else one exported into ``fmu_dir``."""
    from .progress import scaled
    from .scenes.running import export_for
    todo = [r for r in runs if not r.metrics.get("error") and r.variant.pair and not r.variant.is_network
            and r.variant.law != "none"]
    out = []
    for k, r in enumerate(todo):
        v = r.variant
        if v.mode == "cosim" and fmu_path is None:
            fmu_path = export_for(v, fmu_dir)
        fmu = fmu_path if v.mode == "cosim" else None
        e = variant_sync_rate(v, n_starts, fmu, progress=scaled(progress, k / len(todo), (k + 1) / len(todo)),
                              scene_name=scene_name)
        out.append((r.name, v.mode, v.law, e))
    return out


def add_to_summary(path, lines) -> None:
    """Insert the ensemble section into a written summary.md, before its settings."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    block = "\n".join(lines) + "\n"
    at = text.find("## Settings")
    text = text[:at] + block + text[at:] if at >= 0 else text + "\n" + block
    path.write_text(text, encoding="utf-8")


def print_table(entries, file=None) -> None:
    """The ensemble table on the terminal."""
    from .report import print_table as show
    print("\nensemble decay rate over start states (median [interquartile range])", file=file)
    show(list(HEADER), table_rows(entries), file=file)
