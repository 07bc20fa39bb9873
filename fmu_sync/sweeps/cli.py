"""``fmu-sync sweep``: the command line of :func:`fmu_sync.sweeps.sweep`."""
from __future__ import annotations

import time
from pathlib import Path

__all__ = ["add_parser", "run"]

HELP = """\
examples:
  fmu-sync sweep gain-map -o out/gain-map                      (built-in sweep scene: 41 x 41 Kp, Kd)
  fmu-sync sweep forced-pair --variant switching \\
      --grid coupling.Kp='logspace(-2,2,41)' --grid coupling.Kd='logspace(-2,2,41)' -o out/map
  fmu-sync sweep basin -o out/basin                             (basin over the start state of system 2)
  fmu-sync sweep forced-pair --variant switching --method lhs --n 500 --seed 1 \\
      --sample coupling.Kp='loguniform(0.01,100)' --sample system.e='uniform(0.5,1)'
  fmu-sync sweep gain-map --scheduler tcp://HOST:8786          (chunks as tasks on a Dask cluster)

parameters: any scene key (coupling.Kp, coupling.Kd, system.e, solver.dt, run.H, coupling.law, ...),
variant, or a 1-DOF start-state component initial.q1 / initial.u1 / initial.q2 / initial.u2.
"""


def add_parser(sub):
    from argparse import RawDescriptionHelpFormatter
    s = sub.add_parser("sweep", help="run a family of pair runs (gain map, basin, samples) -> NetCDF + maps",
                       epilog=HELP, formatter_class=RawDescriptionHelpFormatter)
    s.add_argument("scene", nargs="?", help="scene or sweep scene (built-in name or .toml path)")
    s.add_argument("--grid", action="append", default=[], metavar="KEY=VALUES",
                   help="grid axis: linspace(a,b,n), logspace(a,b,n) or [v1,v2,...] (repeatable)")
    s.add_argument("--sample", action="append", default=[], metavar="KEY=DIST",
                   help="sampled parameter: uniform(a,b), loguniform(a,b) or [v1,...] (with --n)")
    s.add_argument("--method", choices=("grid", "random", "lhs"), default=None,
                   help="full grid (default with --grid), random or Latin hypercube (default with --sample)")
    s.add_argument("--n", type=int, default=None, help="number of sampled runs")
    s.add_argument("--seed", type=int, default=0, help="seed of the sample (default 0)")
    s.add_argument("--variant", default=None, help="scene variant to sweep")
    s.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="scene key for every run, e.g. --set run.t_end=50")
    s.add_argument("-o", "--out", type=Path, default=None,
                   help="output folder (default ./fmu-sync-out/sweep-<scene>); rerun to resume")
    s.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler address (tcp://host:8786): run the chunks on that cluster")
    s.add_argument("--workers", type=int, default=None, help="worker processes for co-simulated runs")
    s.add_argument("--threads", type=int, default=None, help="threads of the compiled engine (default: cores)")
    s.add_argument("--chunk", type=int, default=None, help="runs per compiled call / Dask task")
    s.add_argument("--overwrite", action="store_true", help="discard a different sweep found in the output")
    s.add_argument("--max-memory", default=None, metavar="SIZE",
                   help="memory budget of the sweep, e.g. 4GB (default 2GB); a larger sweep is refused before it runs")
    s.add_argument("--max-time", type=float, default=None, metavar="SECONDS",
                   help="estimated run-time budget (default 86400 s); a sweep estimated longer is refused")
    s.add_argument("--no-plots", action="store_true", help="write sweep.nc only")
    s.add_argument("--quiet", action="store_true", help="no progress display")
    s.add_argument("--list", action="store_true", help="list the built-in sweep scenes")
    return s


def _pairs(items, what):
    from .spec import SweepSpecError
    out = {}
    for text in items:
        if "=" not in text:
            raise SweepSpecError(f"{what} {text!r}: expected KEY=VALUES, e.g. coupling.Kp=logspace(-2,2,41)")
        k, v = text.split("=", 1)
        k = k.strip()
        if k in out:
            raise SweepSpecError(f"{what} {k} is given twice ({out[k]!r} and {v.strip()!r}): give each key once")
        out[k] = v.strip()
    return out


def _short(reason: str, width: int = 90) -> str:
    """The first clause of a reason, cut at a word boundary (never mid-word)."""
    head = reason.split(": ")[0].strip()
    if len(head) <= width:
        return head
    cut = head[:width].rsplit(" ", 1)[0]
    return cut.rstrip(",;") + " ..."


def run(args) -> int:
    import numpy as np

    from ..output import parse_size
    from ..scenes.loading import parse_override
    from .budget import DEFAULT_MAX_TIME
    from . import SweepTaskError, list_sweep_scenes, load_sweep_scene, sweep
    if args.list or not args.scene:
        rows = list_sweep_scenes()
        w = max(len(n) for n, _ in rows)
        for name, desc in rows:
            print(f"{name.ljust(w)}  {desc}")
        print("\nrun one with `fmu-sync sweep NAME`; any scene takes --grid/--sample (see --help).")
        return 0
    spec = load_sweep_scene(args.scene)
    name = spec["name"] if spec else Path(args.scene).stem
    out = args.out or Path("fmu-sync-out") / f"sweep-{name}"
    grid = _pairs(args.grid, "--grid") or None
    sample = _pairs(args.sample, "--sample") or None
    max_memory = parse_size(args.max_memory) if args.max_memory is not None else None
    max_time = DEFAULT_MAX_TIME if args.max_time is None else args.max_time
    if not max_time > 0:
        raise ValueError(f"--max-time must be a positive number of seconds, got {args.max_time}")
    t0 = time.perf_counter()
    try:
        ds = sweep(args.scene, grid=grid, sample=sample, n=args.n, method=args.method, seed=args.seed,
                   variant=args.variant, overrides=dict(parse_override(s) for s in args.overrides) or None,
                   out=out, scheduler=args.scheduler, workers=args.workers, threads=args.threads,
                   chunk_size=args.chunk, plots=not args.no_plots, overwrite=args.overwrite, quiet=args.quiet,
                   max_memory=max_memory, max_time=max_time)
    except SweepTaskError as exc:
        import sys
        print(f"fmu-sync: error: {exc}", file=sys.stderr)
        return 2
    sec = time.perf_counter() - t0
    st = ds["status"].values.ravel()
    n = st.size
    print(f"\nsweep {name}: {n} runs ({ds.attrs.get('computed_runs', 0)} computed, "
          f"{ds.attrs.get('reused_runs', 0)} from an earlier start) in {sec:.1f} s, engine "
          f"{ds.attrs.get('engine', '?')}")
    print(f"  synchronized: {int(ds['synchronized'].values.sum())}, not synchronized: "
          f"{int(((st == 0) & ~ds['synchronized'].values.ravel()).sum())}, diverged: {int((st == 1).sum())}, "
          f"refused: {int((st == 2).sum())}")
    reasons = [_short(str(r)) for r, s in zip(ds["reason"].values.ravel(), st) if s != 0]
    if reasons:
        u, c = np.unique(reasons, return_counts=True)
        for k in np.argsort(-c)[:3]:
            print(f"  {c[k]} x {u[k]}")
    if ds.attrs.get("already_complete"):
        print(f"already complete in {out}/sweep.nc: nothing recomputed, nothing written "
              "(--overwrite to run it again)")
        return 0
    plots = ds.attrs.get("plots", "[]")
    print(f"written to {out}/ (sweep.nc{', ' + plots.strip('[]').replace(chr(34), '') if plots != '[]' else ''})")
    return 0
