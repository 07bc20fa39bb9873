"""The README's demo (docs/design.md §4.5): the forced-pair scene co-simulated
three ways and compared with the monolithic core."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from ..ensemble import N_STARTS
from ..ensemble import markdown as ensemble_markdown
from ..ensemble import scene_ensembles
from ..progress import scaled
from .loading import load_scene
from .running import (RunRecord, SceneRun, check_export, error_notes, export_for, run_variant, settings_table, skipped_notes,
                      write_run)

__all__ = ["run_demo", "DEMO_OUT", "DEMO_VARIANTS", "DEMO_QUICK_T_END"]


# ---------------------------------------------------------------- the demo
DEMO_OUT = Path("fmu-sync-demo")
DEMO_VARIANTS = ("uncoupled", "euclidean", "switching")
#: --quick: long enough for every coupled run to reach d < 1e-6 (the core about 26 s and 29 s,
#: the Euclidean co-simulation about 43 s with the defaults).
DEMO_QUICK_T_END = 50.0


def run_demo(out_dir=None, quick: bool = False, progress: Callable | None = None,
             t_end: float | None = None, n_starts: int = N_STARTS) -> SceneRun:
    """The README's demo: forced-pair, co-simulated three ways and compared with the core.

    Exports the 1-DOF FMU into ``out_dir`` (default ``./fmu-sync-demo``), runs
    ``cosimulate`` (H = run.H) and ``simulate_pair`` (dt = solver.dt) for the
    uncoupled, Euclidean and switching variants, compares d on the common
    grid (max |d_cosim - d_core|) and writes data, plots and ``summary.md``.
    ``quick`` shortens the run to ``DEMO_QUICK_T_END`` (50 s); ``t_end`` sets it outright.
    The Euclidean and switching laws are then compared by their ensemble rate over ``n_starts``
    start states, in both modes (:mod:`fmu_sync.ensemble`; 0: not computed).
    """
    from .. import plots as P
    from .. import report

    out_dir = Path(out_dir) if out_dir is not None else DEMO_OUT
    base = {"run.t_end": t_end} if t_end is not None else {"run.t_end": DEMO_QUICK_T_END} if quick else {}
    scene = load_scene("forced-pair", base)
    v0 = scene.variant(DEMO_VARIANTS[0])
    H, dt = v0.cfg["run.H"], v0.cfg["solver.dt"]
    every = max(1, round(H / dt))
    cosim = load_scene("forced-pair", {**base, "run.mode": "cosim", "run.record_every": 1,
                                         "record.distance": True})
    check_export(cosim.variants)   # the demo exports an FMU: refused in one line before anything is written
    out_dir.mkdir(parents=True, exist_ok=True)
    core = load_scene("forced-pair", {**base, "run.mode": "core", "run.record_every": every,
                                        "record.distance": True})
    fmu_path = export_for(cosim.variant(DEMO_VARIANTS[0]), out_dir)
    files = [fmu_path]
    runs = []
    steps = 2 * len(DEMO_VARIANTS) + (4 if n_starts else 0)
    k = 0
    for name in DEMO_VARIANTS:
        for tag, sc, fmu in (("cosim", cosim, fmu_path), ("core", core, None)):
            v = sc.variant(name)
            result = run_variant(v, fmu, scaled(progress, k / steps, (k + 1) / steps), scene.name)
            k += 1
            run = RunRecord(f"{name}-{tag}", v, result, report.metrics(result, v.system))
            run.metrics.update(mode=tag, variant=name)
            write_run(run, out_dir, scene.plots if tag == "cosim" else (), "forced-pair",
                      formats=tuple(v.cfg["record.formats"]))
            runs.append(run)
        rc, rm = runs[-2], runs[-1]
        diff = report.max_abs_difference(rc.result, rm.result, "d")
        rc.metrics["d_vs_core"] = rm.metrics["d_vs_core"] = diff
    files += [f for r in runs for f in r.files]
    ens = scene_ensembles(runs, n_starts, out_dir, scaled(progress, k / steps, 1.0), scene.name,
                          fmu_path) if n_starts else []
    cos = {r.name.removesuffix("-cosim"): r.result for r in runs if r.name.endswith("-cosim")}
    files.append(P.compare_plot(cos, out_dir / "compare-distance.png",
                                title=f"forced-pair, co-simulation (H = {H:g} s): quotient distance d"))
    files.append(P.compare_plot(cos, out_dir / "compare-euclidean.png", quantity="euclidean",
                                title=f"forced-pair, co-simulation (H = {H:g} s): Euclidean error"))
    both = {f"{r.metrics['variant']} ({r.metrics['mode']})": r.result for r in runs}
    colors = {f"{r.metrics['variant']} ({r.metrics['mode']})": f"C{DEMO_VARIANTS.index(r.metrics['variant'])}"
              for r in runs}
    files.append(P.compare_plot(both, out_dir / "cosim-vs-core.png", colors=colors,
                                dashed=[k for k in both if k.endswith("(core)")],
                                title=f"forced-pair: d, co-simulation (H = {H:g} s) vs core (dt = {dt:g} s)"))
    sr = SceneRun(scene, out_dir, runs, files)
    sr.ensembles = ens
    note = (f"Co-simulation: the FMU `{fmu_path.name}`, two instances, communication step H = {H:g} s, "
            f"{v0.cfg['run.method']} exchange, coupling forces held over each H. Core: `simulate_pair` with "
            f"dt = {dt:g} s, forces held over each dt. max|d - d_core| compares the two runs' d on the "
            f"common time grid.")
    sr.summary = report.write_summary(out_dir / "summary.md", title="fmu-sync demo: forced pair",
                                      description=scene.description, rows=report.rows(runs, demo=True),
                                      settings=settings_table(scene, [r.variant for r in runs],
                                                              [r.name for r in runs]), files=files,
                                      base=out_dir, notes=[note] + error_notes(runs) + skipped_notes(runs) + report.run_notes(runs),
                                      sections=ensemble_markdown(ens, n_starts) if ens else ())
    return sr
