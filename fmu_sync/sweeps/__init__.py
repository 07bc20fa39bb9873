"""Sweeps: families of coupled-pair runs as labelled arrays (gain maps, basins, ...).

    import fmu_sync
    ds = fmu_sync.sweep("forced-pair", variant="switching",
                        grid={"coupling.Kp": "logspace(-2, 2, 41)", "coupling.Kd": "logspace(-2, 2, 41)"},
                        out="gain-map")
    ds["decay_rate"].sel({"coupling.Kd": 0.5}, method="nearest")

Every run is the scene's pair with the swept parameters laid over it; per run
the sweep keeps numbers, not trajectories (see :data:`store.VARIABLES`): status
and reason (a diverged or refused run is a row, never a lost sweep),
synchronized, t_sync, decay rate, d at start / end / max, max |tau|, impacts,
contact episodes, final state.

Engines (the user's call does not change):

* default, core-mode 1-DOF pairs: chunks of runs, each chunk ONE compiled call
  (:func:`fmu_sync.core.batch.run_pairs1`: one thread per core, each taking the next
  block of runs, compiled without the GIL; O(1) memory per run); bit-identical to single
  ``simulate_pair`` runs;
* co-simulated runs (and core pairs with n > 1): worker processes, one run at
  a time each (an FMU instance belongs to its process);
* ``client=`` (a ``dask.distributed.Client``) or ``scheduler="tcp://host:8786"``:
  the same chunks as tasks on a Dask cluster.

With ``out=DIR`` the result is written to ``DIR/sweep.nc`` (NetCDF), the maps
to ``DIR/*.png``; an interrupted sweep restarted with the same arguments and
``DIR`` resumes from its finished chunks.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from .budget import DEFAULT_MAX_RUNS, DEFAULT_MAX_TIME, SweepEstimate, check_sweep_budget, estimate_sweep, grid_size
from .spec import SweepSpecError, grid_runs, sample_runs

__all__ = ["sweep", "SweepSpecError", "SweepTaskError", "SweepExists", "SweepInterrupted", "SweepProgress", "load_sweep_scene", "list_sweep_scenes",
           "SWEEP_SCENE_DIR"]

SWEEP_SCENE_DIR = Path(__file__).resolve().parent / "scenes"


class SweepTaskError(RuntimeError):
    """A task could not run at all (not a failed run: those are rows). Finished chunks are kept."""


class SweepInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM during a sweep: the message says what was kept and how to resume."""


class SweepExists(FileExistsError):
    """The output folder holds a different sweep (finished or unfinished)."""


def _remove_if_empty(path, created: bool) -> None:
    """Remove a folder this sweep created if nothing is in it (nothing left behind)."""
    if created and path is not None and path.is_dir() and not any(path.iterdir()):
        path.rmdir()


def _check_time(scene, variant, keys, runs, max_memory, max_time, max_runs, threads, workers) -> None:
    """The time estimate of the sweep (the scene variant's steps per run), refused above max_time."""
    v = next((x for x in scene.variants if x.name == variant), scene.variants[0])
    swept = {k: [r[k] for r in runs] for k in ("run.t_end", "solver.dt", "run.H") if k in keys}
    compiled = v.mode == "core" and v.system.n == 1
    est = estimate_sweep(len(runs), v.cfg, swept, compiled, threads or _default_threads(),
                         workers or os.cpu_count() or 1)
    check_sweep_budget(est, max_memory, max_time, max_runs)


# ------------------------------------------------------------------ progress
class SweepProgress:
    """Progress of a sweep on stderr: runs done, failures, runs/s and ETA.

    Terminal: one line redrawn in place; otherwise a line every 10 %. Silenced
    like :class:`fmu_sync.progress.Progress` (``quiet``, ``CI``, ``FMU_SYNC_PROGRESS``).
    """

    def __init__(self, label: str = "sweep", stream=None, force: bool | None = None, width: int = 24):
        from ..progress import Progress
        self._p = Progress(label, stream=stream, force=force, width=width)
        self.label = label
        self.width = width
        self._start = time.monotonic()
        self._base = None
        self.line = ""

    def __call__(self, done: int, total: int, failed: int = 0, new: int | None = None) -> None:
        p = self._p
        if self._base is None:
            self._base = done
        now = time.monotonic()
        elapsed = now - self._start
        ran = done - self._base
        rate = ran / elapsed if elapsed > 0 and ran > 0 else 0.0
        eta = f", ETA {(total - done) / rate:.0f} s" if rate > 0 and done < total else ""
        f = done / total if total else 1.0
        filled = int(round(f * self.width))
        self.line = (f"{self.label} [{'#' * filled}{'.' * (self.width - filled)}] {done}/{total} runs, "
                     f"{failed} failed" + (f", {rate:.3g} runs/s" if rate else "") + eta)
        p.show(f, self.line)

    def close(self):
        self._p.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


# ------------------------------------------------------------------ sweep scenes
def list_sweep_scenes() -> list[tuple[str, str]]:
    """``(name, description)`` of the built-in sweep scenes."""
    import tomllib
    out = []
    for p in sorted(SWEEP_SCENE_DIR.glob("*.toml")):
        with open(p, "rb") as fh:
            out.append((p.stem, str(tomllib.load(fh).get("description", "")).strip()))
    return out


_SWEEP_KEYS = {"description", "scene", "variant", "set", "grid", "sample", "n", "method", "seed", "plot"}


def load_sweep_scene(name_or_path) -> dict | None:
    """A sweep scene (built-in name or ``.toml`` path holding a ``grid`` or ``sample`` table):
    a dict of :func:`sweep` arguments, or None if it is an ordinary scene."""
    import tomllib
    p = Path(name_or_path)
    if not (p.suffix == ".toml" and p.is_file()):
        p = SWEEP_SCENE_DIR / f"{name_or_path}.toml"
        if not p.is_file():
            return None
    with open(p, "rb") as fh:
        data = tomllib.load(fh)
    if "grid" not in data and "sample" not in data:
        return None
    bad = set(data) - _SWEEP_KEYS
    if bad:
        raise SweepSpecError(f"{p.name}: unknown keys {sorted(bad)} in a sweep scene; allowed: "
                             f"{', '.join(sorted(_SWEEP_KEYS))}")
    if "scene" not in data:
        raise SweepSpecError(f"{p.name}: a sweep scene names its scene (scene = \"NAME\" or a path)")
    scene = data["scene"]
    if not Path(scene).is_absolute() and (p.parent / scene).is_file():
        scene = str(p.parent / scene)
    method = data.get("method", "grid" if "grid" in data else "lhs")
    return dict(name=p.stem, scene=scene, variant=data.get("variant"), overrides=dict(data.get("set", {})),
                grid=data.get("grid"), sample=data.get("sample"), n=data.get("n"), method=method,
                seed=data.get("seed", 0), plot=data.get("plot", {}), description=data.get("description", ""))


# ------------------------------------------------------------------ helpers
def _versions() -> dict:
    out = {"python": platform.python_version()}
    for mod in ("fmu_sync", "numpy", "numba", "xarray", "dask", "distributed", "fmpy"):
        try:
            out[mod] = __import__(mod).__version__
        except Exception:
            out[mod] = "n/a"
    return out


def _fingerprint(scene, variant, keys, runs, method, seed, threshold, chunk) -> str:
    h = hashlib.sha256()
    h.update(Path(scene.path).read_bytes())
    h.update(json.dumps(dict(overrides=scene.overrides, variant=variant, keys=keys, method=method, seed=seed,
                             threshold=threshold, chunk=chunk), sort_keys=True, default=repr).encode())
    h.update(json.dumps(runs, sort_keys=True, default=repr).encode())
    h.update(json.dumps(_versions(), sort_keys=True).encode())
    return h.hexdigest()


def _default_threads() -> int:
    import numba
    return int(numba.config.NUMBA_NUM_THREADS)


def _tasks(prep, threshold, chunk_size, threads, py_chunk):
    """``[(chunk id, kind, payload, run count)]`` in run order."""
    from .engine import compiled_payload
    tasks = []
    comp = prep.compiled
    for j in range(0, comp.size, chunk_size):
        idx = comp[j:j + chunk_size]
        tasks.append((f"c{j // chunk_size:05d}", "compiled", compiled_payload(prep, idx, threshold), idx.size))
    py = prep.python
    for j in range(0, py.size, py_chunk):
        idx = py[j:j + py_chunk]
        items = [(int(i),) + prep.python_items[int(i)] for i in idx]
        tasks.append((f"p{j // py_chunk:05d}", "python", items, idx.size))
    return tasks


def _run_task(kind, payload, threshold, threads=None):
    from .engine import run_compiled_chunk, run_python_chunk
    if kind == "compiled":
        idx, rows = run_compiled_chunk(payload, threads)
        return idx, rows, None
    return run_python_chunk(payload, threshold)


def _dask_task(kind, payload, threshold):
    """A Dask task: the same call, numba threads = the worker's threads."""
    return _run_task(kind, payload, threshold, None)


# ------------------------------------------------------------------ the API
def sweep(scene, grid: dict | None = None, *, sample: dict | None = None, n: int | None = None,
          method: str | None = None, seed: int = 0, variant: str | None = None, overrides: dict | None = None,
          out=None, client=None, scheduler: str | None = None, workers: int | None = None,
          threads: int | None = None, chunk_size: int | None = None, threshold: float | None = None,
          progress=None, plots: bool = True, overwrite: bool = False, quiet: bool = False,
          max_memory: float | None = None, max_time: float | None = DEFAULT_MAX_TIME,
          max_runs: int = DEFAULT_MAX_RUNS):
    """Run a family of coupled-pair runs; return an ``xarray.Dataset`` of per-run metrics.

    Parameters
    ----------
    scene : built-in scene name, ``.toml`` path or :class:`fmu_sync.Scene`
        (a built-in *sweep* scene name, e.g. ``"gain-map"``, brings its own grid).
    grid : ``{parameter: values}`` -- a full grid; values as in :mod:`.spec`
        (``"logspace(-2, 2, 41)"``, ``"linspace(0, 1, 11)"``, a list, an array).
    sample, n, method, seed : ``{parameter: "uniform(a, b)" | "loguniform(a, b)" | list}``
        drawn ``n`` times, ``method="random"`` or ``"lhs"`` (Latin hypercube), seeded.
    variant : the scene variant to sweep (scenes with several ``[[runs]]``), or sweep ``"variant"``.
    overrides : scene keys set for every run (``{"run.t_end": 50}``).
    out : output folder: ``sweep.nc`` and maps; enables resuming.
    client, scheduler : a ``dask.distributed.Client`` or a scheduler address: run the chunks there.
    workers : worker processes for co-simulated runs (default: cores).
    threads : numba threads of the embedded engine (default: one per core).
    chunk_size : runs per compiled call / Dask task (default: ~50 chunks, >= 32 runs per thread).
    threshold : d below it counts as synchronized (default ``fmu_sync.report.SYNC_THRESHOLD``).
    progress : callable ``progress(done, total, failed)`` (default: a :class:`SweepProgress` bar
        unless ``quiet``).
    max_memory, max_time, max_runs : the budget (bytes, default ``fmu_sync.output.DEFAULT_MAX_MEMORY``;
        seconds, None for no limit; runs): a sweep estimated above it is refused before anything is
        built, run or written (:class:`fmu_sync.sweeps.budget.SweepTooLarge`, a ValueError).

    Nothing is written before the sweep is known to be valid; a refused sweep leaves no folder
    behind. An interrupted sweep keeps its finished chunks in ``out/.partial`` for resuming.
    """
    from ..output import DEFAULT_MAX_MEMORY
    from ..report import SYNC_THRESHOLD
    from . import store
    from .engine import prepare

    scene, grid, sample, n, method, seed, variant, plot_axes, sweep_name = _resolve_scene(
        scene, grid, sample, n, method, seed, variant, overrides)
    threshold = SYNC_THRESHOLD if threshold is None else float(threshold)
    method = method or ("grid" if grid else "lhs")
    max_memory = DEFAULT_MAX_MEMORY if max_memory is None else float(max_memory)
    keys, axes, runs = _runs(grid, sample, n, method, seed, max_memory, max_runs)
    variant = _variant(scene, variant, keys)
    if plot_axes and not all(plot_axes.get(a) in keys for a in ("x", "y")):
        plot_axes = {}   # the sweep scene's grid was replaced: the maps follow the swept keys
    _check_time(scene, variant, keys, runs, max_memory, max_time, max_runs, threads, workers)
    out_dir = _out_dir(out)
    own_client = client is None and scheduler is not None
    if own_client:
        client = _client(scheduler)
    threads = threads or _default_threads()
    R = len(runs)
    chunk = chunk_size or max(32 * threads if client is None else 8, math.ceil(R / 50))
    fp = _fingerprint(scene, variant, keys, runs, method, seed, threshold, chunk)
    attrs = _attrs(scene, sweep_name, variant, keys, method, seed, grid, sample, threshold, fp)
    if out_dir is not None and (out_dir / store.RESULT_FILE).exists() and not overwrite:
        return _finished_sweep(out_dir / store.RESULT_FILE, fp)

    prep = prepare(scene, runs, variant)   # every run checked: nothing is written before this
    st, created = _chunk_store(out_dir, fp, overwrite)
    tasks = _tasks(prep, threshold, chunk, threads, 1 if client is not None else 2)
    own_bar = progress is None and not quiet
    bar = SweepProgress(f"sweep {scene.name}") if own_bar else progress
    table, reasons, computed, reused = _execute(prep, tasks, st, client, threshold, threads, workers,
                                                 fp, bar, R, out_dir, created, own_bar, own_client)
    attrs.update(engine="dask" if client is not None else "embedded", computed_runs=int(computed),
                 reused_runs=int(reused), compiled_runs=int(prep.compiled.size),
                 process_runs=int(prep.python.size))
    ds = store.to_dataset(table, reasons, keys, axes, runs, attrs)
    if out_dir is not None:
        store.write_dataset(ds, out_dir / store.RESULT_FILE)
        st.clear()
        if plots:
            from .plots import sweep_plots
            ds.attrs["plots"] = json.dumps([p.name for p in sweep_plots(ds, out_dir, plot_axes)])
    return ds


def _out_dir(out):
    """The output folder as a Path, checked before anything runs (None: nothing written)."""
    if out is None:
        return None
    from ..output import check_out_dir
    check_out_dir(Path(out))
    return Path(out)


def _chunk_store(out_dir, fp, overwrite):
    """(the chunk store of ``out_dir``, whether the folder was made here); SweepExists when it
    holds a different unfinished sweep (a folder made here is removed again)."""
    from . import store
    created = out_dir is not None and not out_dir.exists()
    try:
        if out_dir is not None:
            out_dir.mkdir(parents=True, exist_ok=True)
        return store.ChunkStore(out_dir, fp, overwrite=overwrite), created
    except FileExistsError as exc:
        _remove_if_empty(out_dir, created)
        raise SweepExists(str(exc)) from None


def _resolve_scene(scene, grid, sample, n, method, seed, variant, overrides):
    """The scene (a :class:`Scene`, overrides laid over it) and the sweep's arguments, a built-in
    sweep scene's own filling those the call leaves out; also its plot axes and name."""
    from ..scenes.loading import Scene, load_scene
    plot_axes, sweep_name = {}, ""
    if not isinstance(scene, Scene):
        spec = load_sweep_scene(scene)
        if spec is not None:
            grid = grid if grid is not None else spec["grid"]
            sample = sample if sample is not None else spec["sample"]
            n = n if n is not None else spec["n"]
            method = method or spec["method"]
            seed = seed if seed else spec["seed"]
            variant = variant or spec["variant"]
            overrides = {**spec["overrides"], **(overrides or {})}
            plot_axes = spec["plot"]
            sweep_name = spec["name"]
            scene = spec["scene"]
    if isinstance(scene, Scene):
        if overrides:
            scene = scene.with_overrides(overrides)
    else:
        scene = load_scene(scene, overrides)
    return scene, grid, sample, n, method, seed, variant, plot_axes, sweep_name


def _runs(grid, sample, n, method, seed, max_memory, max_runs):
    """(keys, axes, runs) of a grid or a sample, the run count and memory checked before any value
    is built (``logspace(-1, 1, 1e9)`` allocates nothing); ``axes`` is None for a sample."""
    if method == "grid":
        if not grid or sample:
            raise SweepSpecError("a grid sweep needs grid={parameter: values} (and no sample)")
        check_sweep_budget(SweepEstimate(grid_size(grid)), max_memory, None, max_runs)
        return grid_runs(grid)
    if not sample or grid:
        raise SweepSpecError(f"a {method} sweep needs sample={{parameter: distribution}} and n "
                             "(and no grid)")
    if n is None:
        raise SweepSpecError(f"a {method} sweep needs the number of runs n")
    if isinstance(n, (int, float)) and not isinstance(n, bool) and n >= 1:
        check_sweep_budget(SweepEstimate(int(n)), max_memory, None, max_runs)
    keys, runs = sample_runs(sample, n, method, seed)
    return keys, None, runs


def _variant(scene, variant, keys):
    """The variant swept: the one asked for, the scene's only one, or None when swept over."""
    if variant is None and "variant" not in keys:
        if len(scene.variants) > 1:
            raise SweepSpecError(f"scene {scene.name!r} has variants "
                                 f"{', '.join(v.name for v in scene.variants)}: "
                                 "choose one (variant=NAME, --variant NAME) or sweep over variant")
        variant = scene.variants[0].name
    return variant


def _client(scheduler):
    try:
        from distributed import Client
    except ImportError:
        raise ImportError("--scheduler needs dask.distributed: pip install 'fmu-sync[sweep]'") from None
    return Client(scheduler)


def _attrs(scene, sweep_name, variant, keys, method, seed, grid, sample, threshold, fp) -> dict:
    """The dataset's attributes known before the runs (what was swept, how, with which versions)."""
    return dict(sweep_scene=sweep_name, scene=scene.name, scene_file=str(scene.path),
                scene_toml=Path(scene.path).read_text(),
                variant=str(variant or ""), overrides=json.dumps(scene.overrides, default=repr),
                swept=json.dumps(keys), method=method, seed=int(seed) if method != "grid" else -1,
                spec=json.dumps(grid if method == "grid" else sample, default=repr),
                threshold=threshold, fingerprint=fp,
                versions=json.dumps(_versions()), created=time.strftime("%Y-%m-%dT%H:%M:%S%z"))


def _finished_sweep(final: Path, fp: str):
    """The finished sweep in ``final`` when it is this one (nothing computed), else SweepExists."""
    from . import store
    old = store.read_dataset(final)
    if old.attrs.get("fingerprint") == fp:
        old.attrs["computed_runs"] = 0
        old.attrs["already_complete"] = 1
        return old
    raise SweepExists(f"{final} holds a different sweep: use another output folder or "
                      "overwrite=True (--overwrite)")


def _execute(prep, tasks, st, client, threshold, threads, workers, fp, bar, R, out_dir, created,
             own_bar, own_client):
    """Run the tasks not in the chunk store ``st`` (reusing those that are), saving each finished
    chunk; returns (table, reasons, computed runs, reused runs). An interrupt says what was kept."""
    from ..core.batch import COL, DIVERGED, OK
    from .engine import divergence_reason
    done_ids = st.done()
    table = prep.out.copy()
    reasons = list(prep.reasons)

    def absorb(idx, rows, rs):
        table[idx] = rows
        if rs is not None:
            for i, r in zip(idx, rs):
                reasons[int(i)] = r

    reused_failed = 0
    for cid, kind, payload, cnt in tasks:
        if cid in done_ids:
            idx, rows, rs = st.load(cid)
            absorb(idx, rows, rs)
            reused_failed += int(np.sum(np.asarray(rows)[:, COL["status"]] != OK))
    todo = [t for t in tasks if t[0] not in done_ids]
    reused = sum(t[3] for t in tasks if t[0] in done_ids)
    counted = {"done": reused, "failed": reused_failed}

    def finished(cid, idx, rows, rs):
        if rs is None:   # compiled chunk: reasons of diverged / refused runs
            rs = []
            for i, row in zip(idx, rows):
                if row[COL["status"]] == DIVERGED:
                    rs.append(divergence_reason(prep, int(i), float(row[COL["t_stop"]])))
                else:
                    rs.append(prep.reasons[int(i)])
        st.save(cid, idx, rows, rs)
        absorb(idx, rows, rs)
        counted["done"] += len(idx)
        counted["failed"] += int(np.sum(np.asarray(rows)[:, COL["status"]] != OK))
        if bar is not None:
            bar(counted["done"], R, counted["failed"])

    try:
        if bar is not None:
            bar(counted["done"], R, counted["failed"])
        if client is not None:
            computed = _run_dask(client, todo, threshold, fp, finished)
        else:
            computed = _run_local(todo, threshold, threads, workers, finished)
    except KeyboardInterrupt:
        _interrupted(counted["done"], R, out_dir, st, created)
    except BaseException:
        if out_dir is not None and counted["done"] == 0:
            st.clear()
            _remove_if_empty(out_dir, created)
        raise
    finally:
        if own_bar:
            bar.close()
        if own_client:
            client.close()
    return table, reasons, computed, reused


def _interrupted(kept, R, out_dir, st, created):
    """Raise SweepInterrupted saying what was kept (``kept`` of ``R`` runs) and how to resume."""
    if out_dir is None:
        raise SweepInterrupted(f"sweep interrupted: {kept} of {R} runs had finished; nothing was "
                               "written (no output folder)") from None
    if kept == 0:
        st.clear()
        _remove_if_empty(out_dir, created)
        raise SweepInterrupted("sweep interrupted before any chunk finished: nothing kept") from None
    raise SweepInterrupted(f"sweep interrupted: {kept} of {R} runs kept in {out_dir / '.partial'}; "
                           f"rerun the same command to resume from them") from None


def _run_local(todo, threshold, threads, workers, finished) -> int:
    computed = 0
    comp = [t for t in todo if t[1] == "compiled"]
    py = [t for t in todo if t[1] == "python"]
    pool = None
    futs = {}
    if py:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        pool = ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1,
                                   mp_context=multiprocessing.get_context("spawn"))
        from .engine import run_python_chunk
        futs = {pool.submit(run_python_chunk, t[2], threshold): t for t in py}
    try:
        for cid, kind, payload, cnt in comp:
            idx, rows, rs = _run_task(kind, payload, threshold, threads)
            finished(cid, idx, rows, rs)
            computed += cnt
        if futs:
            from concurrent.futures import as_completed
            for f in as_completed(futs):
                cid, kind, payload, cnt = futs[f]
                finished(cid, *f.result())
                computed += cnt
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
    return computed


def _run_dask(client, todo, threshold, fp, finished) -> int:
    from distributed import as_completed
    if not todo:
        return 0
    futures = {}
    for cid, kind, payload, cnt in todo:
        f = client.submit(_dask_task, kind, payload, threshold, key=f"fmu-sync-sweep-{fp[:16]}-{cid}",
                          pure=False, retries=2)
        futures[f] = (cid, cnt)
    computed = 0
    seen = set()
    try:
        for f in as_completed(list(futures)):
            cid, cnt = futures[f]
            if cid in seen:     # never count a chunk twice
                continue
            try:
                idx, rows, rs = f.result()
            except Exception as exc:
                raise SweepTaskError(
                    f"sweep task {cid} failed on the Dask cluster: {type(exc).__name__}: {exc}. Scheduler and "
                    "workers must run the same Python environment with fmu-sync installed (pip install "
                    "'fmu-sync[sweep]'; start them with that environment's `dask scheduler` / `dask worker`). "
                    "Finished chunks are kept: rerun with the same output folder to resume.") from exc
            seen.add(cid)
            finished(cid, idx, rows, rs)
            computed += cnt
    finally:
        for f in futures:
            f.release()
    return computed
