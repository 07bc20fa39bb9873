"""Turning a sweep into tasks and running them: compiled chunks, worker processes, Dask.

* **compiled chunks** -- core-mode 1-DOF pairs: the inputs of a chunk of runs
  are packed into arrays (:class:`Prepared`) and run by one call of
  :func:`fmu_sync.core.batch.run_pairs1` (one thread per core, blocks of runs compiled without the GIL).
* **per-run chunks** -- co-simulated runs (FMU instances belong to a process)
  and core pairs with n > 1: each run is loaded from the scene and run by
  :func:`fmu_sync.scenes.variant.run_variant` in a worker process; only its metrics
  come back (:func:`fmu_sync.core.batch.metrics_from_records`).

Both kinds of task are plain functions of picklable payloads, so the same
tasks run in this process (compiled), in a local process pool (per-run) or on
a Dask cluster (both).
"""
from __future__ import annotations

import atexit
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field

import numpy as np

from ..core import batch
from ..core.batch import COL, COLUMNS, DIVERGED, OK, REFUSED
from ..core.coupling import QUOTIENT_LAW_NAMES, law_metric
from ..core.steps import SCHEMES
from .spec import STATE_ALIASES, SweepSpecError

__all__ = ["Prepared", "prepare", "compiled_payload", "run_compiled_chunk", "run_python_chunk",
           "PER_RUN_KEYS"]

#: Parameters that vary per run inside one compiled call (no new system needed).
SYSTEM2 = "system2."
INT_ARRAYS = ("law", "scheme", "group1", "group2", "n_steps", "every")
PER_RUN_KEYS = ("coupling.Kp", "coupling.Kd", "solver.dt", "solver.theta", "run.t_end", "initial.x1",
                "initial.x2") + tuple(STATE_ALIASES)
_VALIDATED = ("coupling.Kp", "coupling.Kd", "solver.dt", "solver.theta", "run.t_end")


@dataclass
class Prepared:
    """The runs of a sweep, ready for the engines.

    ``compiled`` (indices of runs that go through the compiled kernel) with
    their per-run arrays ``arrays`` (each of length R, indexed by run) and the
    system tables ``tables``; ``python`` (indices of runs made one by one)
    with ``python_items[i] = (scene path, overrides, variant)``;
    ``out`` (R, len(COLUMNS)) holds REFUSED rows already, with ``reasons``.
    """

    R: int
    compiled: np.ndarray
    python: np.ndarray
    arrays: dict
    tables: dict
    python_items: dict
    out: np.ndarray
    reasons: list
    systems: dict = field(default_factory=dict)     # group index -> the scene Variant of system 1
    groups: np.ndarray | None = None                # group index of each run


def _law(name) -> int:
    from ..core.pair import LAWS
    return LAWS[None if name == "none" else name]


def _state_with(run: dict, base, which: str):
    """Start state ``which`` ("x1"/"x2") of a run: the scene's, replaced or patched by the run."""
    key = f"initial.{which}"
    if key in run:
        v = run[key]
        q, u = (v[0], v[1])
        q = q[0] if isinstance(q, list) else q
        u = u[0] if isinstance(u, list) else u
    else:
        q, u = base
    q, u = float(q), float(u)
    for alias, (target, idx) in STATE_ALIASES.items():
        if target == key and alias in run:
            if idx == 0:
                q = float(run[alias])
            else:
                u = float(run[alias])
    return q, u


def _scene_overrides(run: dict, variant) -> dict:
    """A run's parameters as scene overrides (aliases folded into initial.x1 / x2)."""
    out = {k: v for k, v in run.items() if k not in STATE_ALIASES and k != "variant"}
    for which in ("x1", "x2"):
        if any(STATE_ALIASES[a][0] == f"initial.{which}" for a in run if a in STATE_ALIASES):
            base = getattr(variant, which)
            q, u = _state_with(run, base, which)
            out[f"initial.{which}"] = [q, u]
    return out


def _validate_values(scene, variant_name, key, values):
    """Check per-run values against the scene's own rules (each distinct value, or the
    extremes of a large sample); raise :class:`SweepSpecError` naming the parameter."""
    from ..scenes.loading import load_scene
    from ..scenes.schema import SceneError
    vals = list({repr(v): v for v in values}.values())
    if len(vals) > 256 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals):
        vals = [min(vals), max(vals)]   # the scene's checks on numbers are ranges
    for v in vals:
        try:
            load_scene(scene.path, {**scene.overrides, key: v}, [variant_name])
        except SceneError as exc:
            raise SweepSpecError(f"sweep parameter {key} = {v!r}: {exc}") from None


def prepare(scene, runs: list[dict], variant_name: str | None) -> Prepared:
    """Resolve every run against the scene: system groups, per-run inputs, refusals."""
    R = len(runs)
    out = batch.empty_out(R)
    reasons = [""] * R
    _check_values(scene, runs, variant_name)
    variants, group = _groups(scene, runs, variant_name)
    comp = np.array([_compiled_ok(variants[g]) for g in group], dtype=bool) if R else np.zeros(0, bool)
    rows, group2, second = _second_systems(scene, runs, variants, group, comp)
    arrays = {name: np.zeros(R, dtype=np.int64 if name in INT_ARRAYS else np.float64)
              for name in ("law", "scheme", "theta", "group1", "group2", "kp", "kd", "q1", "u1", "q2", "u2",
                           "dt", "n_steps", "dt_last", "every", "qw")}
    python_items = {}
    cache = {}
    for i, r in enumerate(runs):
        v = variants[group[i]]
        if not comp[i]:
            over = {**scene.overrides, **_scene_overrides(r, v)}
            for k, val in r.items():
                if k not in PER_RUN_KEYS and k != "variant":
                    over[k] = val
            python_items[i] = (str(scene.path), over, v.name)
            continue
        why = _fill_run(arrays, i, r, v, group[i], group2[i], rows[group2[i]], out, cache)
        if why:
            out[i, COL["status"]] = REFUSED
            out[i, COL["steps"]] = 0
            out[i, COL["t_stop"]] = 0.0
            reasons[i] = why
    return Prepared(R, np.nonzero(comp)[0], np.nonzero(~comp)[0], arrays, _tables(rows, variants, second),
                    python_items, out, reasons, {g: v for g, v in enumerate(variants)}, group)


def _check_values(scene, runs, variant_name):
    """Per-run values: the scene's own rules (for the keys it checks) or finite numbers."""
    for k in sorted({k for r in runs for k in r}):
        if k in _VALIDATED:
            _validate_values(scene, (variant_name or runs[0].get("variant")), k, [r[k] for r in runs])
        elif k in PER_RUN_KEYS:
            for r in runs:
                v = r[k]
                flat = v if k in STATE_ALIASES else np.ravel(np.array(v, dtype=object))
                try:
                    ok = all(math.isfinite(float(x)) for x in np.ravel(flat))
                except (TypeError, ValueError):
                    ok = False
                if not ok:
                    raise SweepSpecError(f"sweep parameter {k} = {v!r}: not finite numbers")


def _groups(scene, runs, variant_name):
    """(variants, group): the scene variant of each distinct set of system-1 parameters, loaded
    once, and the group index of each run; a single system or an unchosen variant is refused."""
    from ..scenes.loading import load_scene
    from ..scenes.schema import SceneError
    group_of = {}
    variants = []
    group = np.zeros(len(runs), dtype=np.int64)
    for i, r in enumerate(runs):
        gk = _group_key(r, system2=False)
        if gk not in group_of:
            vname = r.get("variant", variant_name)
            over = _group_overrides(r)
            try:
                sc = load_scene(scene.path, {**scene.overrides, **over}, [vname] if vname else None)
            except SceneError as exc:
                raise SweepSpecError(f"sweep parameters {dict(over)}: {exc}") from None
            if len(sc.variants) != 1:
                raise SweepSpecError(f"scene {scene.name!r} has {len(sc.variants)} variants "
                                     f"({', '.join(v.name for v in sc.variants)}): choose one "
                                     "(variant=... / --variant NAME) or sweep over `variant`")
            v = sc.variants[0]
            if not v.pair:
                raise SweepSpecError(f"scene {scene.name!r}, variant {v.name!r} is a single system: "
                                     "sweeps run coupled pairs (give the scene an initial.x2)")
            group_of[gk] = len(variants)
            variants.append(v)
        group[i] = group_of[gk]
    return variants, group


def _compiled_ok(v) -> bool:
    """Whether a variant's runs go through the compiled kernel."""
    s = v.system
    # a user force law runs run by run (simulate_pair runs the law's own loop; the batch kernel
    # carries the built-in linear law only)
    return (v.mode == "core" and s.force is None and s.n == 1 and s.n_inputs == 1 and float(s.B[0, 0]) == 1.0
            and v.cfg["solver.scheme"] in SCHEMES)   # the core's Moreau schemes (not "exact")


def _second_systems(scene, runs, variants, group, comp):
    """System 2 where it differs (system2.* parameters): (table rows: the groups' systems, then
    the distinct second systems; each run's system-2 row; {(group, system2 keys): row})."""
    rows = [v.system for v in variants]
    group2 = group.copy()
    second = {}
    for i, r in enumerate(runs):
        s2 = {k: v for k, v in r.items() if k.startswith(SYSTEM2)}
        if not s2:
            continue
        v = variants[group[i]]
        if not comp[i]:
            raise SweepSpecError(f"{', '.join(s2)}: a second system that differs from the first runs in the "
                                 "compiled core engine only (1-DOF pairs, run.mode = core); this run is "
                                 f"{v.mode} with n = {v.system.n}")
        key = (group[i], tuple(sorted((k, repr(x)) for k, x in s2.items())))
        if key not in second:
            second[key] = len(rows)
            rows.append(_system2(scene, v, r, s2))
        group2[i] = second[key]
    return rows, group2, second


def _tables(rows, variants, second) -> dict:
    """The system tables of the compiled kernel (rows of systems that run compiled)."""
    from ..core.distance import geometry
    G = len(rows)
    nf_max = max([len(s.arrays().Omega) for s in rows] + [1])
    sys_rows = np.zeros((G, len(batch.GROUP_FIELDS)))
    geo_rows = np.zeros((G, len(batch.GEO_FIELDS)))
    F = np.zeros((G, nf_max))
    Om = np.zeros((G, nf_max))
    ph = np.zeros((G, nf_max))
    nf = np.zeros(G, dtype=np.int64)
    owner = {g: g for g in range(len(variants))}
    owner.update({g2: g1 for (g1, _), g2 in second.items()})
    for g, s in enumerate(rows):
        v = variants[owner[g]]
        if not _compiled_ok(v):
            continue
        sr, gr, f_, o_, p_ = batch.group_row(s, geometry(s, v.Q))
        sys_rows[g], geo_rows[g] = sr, gr
        nf[g] = len(o_)
        F[g, :nf[g]], Om[g, :nf[g]], ph[g, :nf[g]] = f_, o_, p_
    return dict(sys_rows=sys_rows, geo_rows=geo_rows, F=F, Omega=Om, phi=ph, nf=nf)


def _fill_run(a, i, r, v, g1, g2, system2, out, cache) -> str:
    """Write compiled run ``i``'s inputs into the arrays ``a`` (and its exchange verdict into
    ``out``); return why it cannot start, or ''."""
    from ..core.checks import run_steps
    cfg = v.cfg
    kp = _scalar_gain(r.get("coupling.Kp", v.Kp))
    kd = _scalar_gain(r.get("coupling.Kd", v.Kd))
    dt = float(r.get("solver.dt", cfg["solver.dt"]))
    theta = float(r.get("solver.theta", cfg["solver.theta"]))
    t_end = float(r.get("run.t_end", cfg["run.t_end"]))
    q1, u1 = _state_with(r, v.x1, "x1")
    q2, u2 = _state_with(r, v.x2, "x2")
    a["law"][i] = _law(v.law)
    a["group1"][i], a["group2"][i], a["kp"][i], a["kd"][i] = g1, g2, kp, kd
    a["q1"][i], a["u1"][i], a["q2"][i], a["u2"][i], a["dt"][i] = q1, u1, q2, u2, dt
    grid = run_steps(t_end, dt)   # whole steps, then the shortened last one (ends at t_end)
    a["n_steps"][i] = grid.steps - 1 if grid.short else grid.steps
    a["dt_last"][i] = grid.dt_last if grid.short else 0.0
    a["qw"][i] = _run_metric(v, system2, kp)
    a["every"][i] = cfg["run.record_every"]
    out[i, COL["exchange_stable"]] = _exchange_stable(v, kp, kd, dt, cache)
    why, plan = _refusal(v, system2, (q1, u1), (q2, u2), t_end, dt, theta)
    # the kernel's scheme code and theta as the run plan makes them (the trapezoid's theta is 1/2
    # whatever solver.theta says, as in simulate_pair); a refused run is not run
    ran = plan is not None and plan.code is not None
    a["scheme"][i] = plan.code if ran else SCHEMES[cfg["solver.scheme"]]
    a["theta"][i] = plan.theta if ran else theta
    if not why and not math.isfinite(a["qw"][i]) and v.law not in (None, "none"):
        why = f"no energy metric: k + 2 Kp = {v.system.K[0, 0] + 2 * kp:.6g} is not > 0 (set coupling.Q)"
    return why


def _run_metric(v, system2, kp) -> float:
    """Q of a compiled run's distance: the variant's explicit Q, else the law's own metric
    (docs/design.md §2.5.1); NaN when the run cannot have one (it is then refused or uncoupled)."""
    coupled = v.law not in (None, "none")
    try:
        return float(law_metric(v.Q, [v.system.K, system2.K], kp, coupled=coupled).Q[0, 0])
    except ValueError:
        return float("nan")


def _refusal(v, system2, x1, x2, t_end, dt, theta):
    """``(why, plan)``: why a run cannot start (or '') and its run plan (None if refused), the plan
    of simulate_pair (:func:`fmu_sync.core.plan.plan_run`: systems, grid, scheme and its limit,
    start states); the exchange is not refused (the sweep runs it either way,
    :func:`_exchange_stable` records its verdict)."""
    from ..core.coupling import UNCOUPLED
    from ..core.plan import plan_run
    try:
        plan = plan_run((v.system, system2), (x1, x2), t_end, dt, scheme=v.cfg["solver.scheme"], theta=theta,
                        laws=[UNCOUPLED], distance=False)   # one impact map: a quotient law's rule, in _system2
    except ValueError as exc:
        return str(exc), None
    return "", plan


def _exchange_stable(v, kp, kd, dt, cache) -> float:
    """1.0 if the coupling is stable at this step (the run plan's exchange check,
    :func:`fmu_sync.core.plan.held_exchange`, with the exchange of the scheme's loop:
    :func:`fmu_sync.core.plan.coupling_exchange`), else 0.0. The sweep runs either way
    (as ``simulate_pair(..., allow_unstable=True)``)."""
    from ..core.plan import coupling_exchange, held_exchange
    if v.law == "none":
        return 1.0
    exchange = coupling_exchange(v.cfg["solver.scheme"], [v.system])
    key = (float(v.system.M[0, 0]), kp, kd, dt, exchange)
    if key not in cache:
        lim = held_exchange(v.system.M, kp, kd, dt, allow_unstable=True, step_name="dt", exchange=exchange)[3]
        cache[key] = 1.0 if lim.stable else 0.0
    return cache[key]


def _scalar_gain(K) -> float:
    """A 1-DOF gain: a number or a 1 x 1 matrix."""
    return float(np.asarray(K, dtype=float).ravel()[0])


def _group_key(r: dict, system2: bool):
    return tuple(sorted((k, repr(v)) for k, v in r.items()
                        if k not in PER_RUN_KEYS and (system2 or not k.startswith(SYSTEM2))))


def _group_overrides(r: dict) -> dict:
    return {k: v for k, v in r.items() if k not in PER_RUN_KEYS and k != "variant" and not k.startswith(SYSTEM2)}


def _system2(scene, v, r, s2: dict):
    """System 2 of a run: system 1 with the ``system2.*`` keys laid over it (through the scene's
    own checks); under a quotient law it must share the impact geometry (M, w, g0, e) with system 1."""
    from ..scenes.loading import load_scene
    from ..scenes.schema import SceneError
    over = {**scene.overrides, **_group_overrides(r), **{"system." + k[len(SYSTEM2):]: x for k, x in s2.items()}}
    try:
        sys2 = load_scene(scene.path, over, [v.name]).variants[0].system
    except SceneError as exc:
        raise SweepSpecError(f"sweep parameters {s2}: {exc}") from None
    if v.law in QUOTIENT_LAW_NAMES:   # a quotient law needs one impact map (core/plan.py)
        from ..core.plan import check_common_geometry
        try:
            check_common_geometry([v.system, sys2], ["system 1", "system 2"], f"the {v.law} law")
        except ValueError as exc:
            raise SweepSpecError(f"sweep parameters {s2}: {exc}") from None
    return sys2   # otherwise M, w, g0, e may differ: the runs measure the Euclidean error (core/batch.py)


def divergence_reason(prep: Prepared, i: int, t_stop: float) -> str:
    """The message simulate_pair would raise for a compiled run that diverged."""
    from ..core.coupling import gain_matrix
    from ..core.checks import divergence_message
    v = prep.systems[int(prep.groups[i])]
    a = prep.arrays
    law = int(a["law"][i])
    from ..core.coupling import UNCOUPLED
    return divergence_message(v.system, v.cfg["solver.scheme"], float(a["dt"][i]), t_stop,
                              what="a coupled state",
                              Kp=gain_matrix(float(a["kp"][i]), 1, "Kp") if law != UNCOUPLED else None)


# ------------------------------------------------------------------ tasks
def compiled_payload(prep: Prepared, idx: np.ndarray, threshold: float) -> dict:
    """Everything one compiled chunk needs (runs ``idx``), with only the groups it uses."""
    a = prep.arrays
    n = len(idx)
    used, local = np.unique(np.concatenate((a["group1"][idx], a["group2"][idx])), return_inverse=True)
    t = prep.tables
    return dict(idx=np.asarray(idx, dtype=np.int64), threshold=float(threshold),
                out=prep.out[idx].copy(),
                runs={k: a[k][idx].copy() for k in a if not k.startswith("group")},
                group1=local[:n].astype(np.int64), group2=local[n:].astype(np.int64),
                tables={k: t[k][used].copy() for k in t})


def _worker_threads():
    """Threads of the Dask worker running this task (None outside Dask)."""
    try:
        from distributed import get_worker
        return int(get_worker().state.nthreads)
    except Exception:
        return None


def run_compiled_chunk(payload: dict, threads: int | None = None):
    """One compiled call over the chunk's runs; returns ``(idx, out rows)``.

    ``threads``: threads for the call (default: all cores, or the
    thread count of the Dask worker it runs on)."""
    threads = threads or _worker_threads()
    r, t = payload["runs"], payload["tables"]
    out = payload["out"].copy()
    batch.run_pairs1(r["law"], r["scheme"], r["theta"], t["sys_rows"], t["geo_rows"], t["F"], t["Omega"],
                     t["phi"], t["nf"], payload["group1"], payload["group2"], r["kp"], r["kd"], r["q1"], r["u1"],
                     r["q2"], r["u2"],
                     r["dt"], r["n_steps"], r["dt_last"], r["every"], payload["threshold"], out, r["qw"],
                     threads=threads)
    return payload["idx"], out


_FMUS: dict = {}


def _fmu_for(variant):
    """The FMU of the variant's model, exported and unpacked once per process: every
    co-simulated run of the worker instantiates its FMU instances from that one folder
    (the master's compiled loop then drives them; nothing is unpacked per run)."""
    from fmpy import extract

    from ..scenes.running import export_for
    key = (variant.cfg["system.model"], variant.system.n)
    if key not in _FMUS:
        d = tempfile.mkdtemp(prefix=f"fmu-sync-sweep-{os.getpid()}-")
        atexit.register(shutil.rmtree, d, True)
        _FMUS[key] = extract(str(export_for(variant, d)), unzipdir=os.path.join(d, "unpacked"))
        from ..instance_pool import keep_instances
        keep_instances(_FMUS[key])   # its instances are reset and reused run after run
    return _FMUS[key]


def _one_python_run(path, overrides, vname, threshold):
    from ..core import RunFailed, RunRefused, UnstableExchange
    from ..scenes.loading import load_scene
    from ..scenes.running import run_variant
    from ..scenes.schema import SceneError
    row = np.full(len(COLUMNS), np.nan)
    try:
        v = load_scene(path, overrides, [vname]).variants[0]
    except SceneError as exc:
        row[COL["status"]], row[COL["steps"]], row[COL["t_stop"]] = REFUSED, 0, 0.0
        return row, str(exc)
    reason = ""
    try:
        res = run_variant(v, _fmu_for(v) if v.mode == "cosim" else None)
    except RunRefused as exc:   # refused up front by the run plan (core or master)
        row[COL["status"]], row[COL["steps"]], row[COL["t_stop"]] = REFUSED, 0, 0.0
        if isinstance(exc, UnstableExchange):
            row[COL["exchange_stable"]] = 0.0
        return row, str(exc)
    except RunFailed as exc:
        res = getattr(exc, "partial", None)
        reason = str(exc)
        if res is None:  # refused before the first step
            row[COL["status"]], row[COL["steps"]], row[COL["t_stop"]] = REFUSED, 0, 0.0
            return row, reason
    if res.error and not reason:
        reason = res.error
    t = np.asarray(res.t, dtype=float)
    euclid = res.d is None and getattr(res, "euclidean", None) is not None   # no common impact geometry
    row[COL["measure"]] = batch.MEASURE_EUCLIDEAN if euclid else batch.MEASURE_D
    d = np.asarray(res.d if res.d is not None else (np.asarray(res.euclidean).reshape(t.size, -1)[:, 0] if euclid
                                                     else np.full(t.size, np.nan)), dtype=float)
    n_ok = t.size
    finite = np.isfinite(d) & np.all(np.isfinite(res.q1), axis=1) & np.all(np.isfinite(res.q2), axis=1)
    if not finite.all():
        n_ok = int(np.argmin(finite))
    tau1 = np.ascontiguousarray(np.asarray(res.tau1, dtype=float).reshape(t.size, -1))
    tau2 = np.ascontiguousarray(np.asarray(res.tau2, dtype=float).reshape(t.size, -1))
    batch.metrics_from_records(t, d, tau1, tau2, n_ok, threshold, float(v.cfg["run.t_end"]), row)
    failed = bool(reason) or n_ok < t.size
    row[COL["status"]] = DIVERGED if failed else OK
    last = max(n_ok - 1, 0)
    row[COL["t_stop"]] = float(t[last]) if t.size else 0.0
    row[COL["steps"]] = int(res.info.get("steps", 0)) if not failed else np.nan
    for name, arr in (("q1", res.q1), ("u1", res.u1), ("q2", res.q2), ("u2", res.u2)):
        row[COL[name]] = float(np.asarray(arr)[last].ravel()[0]) if t.size else np.nan
    row[COL["impacts1"]], row[COL["impacts2"]] = res.impacts1, res.impacts2
    row[COL["exchange_stable"]] = 1.0   # it ran: the core's / master's check let it
    if failed and not reason:
        reason = f"non-finite state or distance at t = {row[COL['t_stop']]:.6g}"
    return row, reason


def run_python_chunk(items: list, threshold: float):
    """Runs made one by one (co-simulated, or core pairs with n > 1): ``(idx, rows, reasons)``.
    ``items``: ``(run index, scene path, overrides, variant)``."""
    idx = np.array([it[0] for it in items], dtype=np.int64)
    rows = np.full((len(items), len(COLUMNS)), np.nan)
    reasons = []
    for j, (_, path, over, vname) in enumerate(items):
        try:
            rows[j], why = _one_python_run(path, over, vname, threshold)
        except Exception as exc:  # a failed run is a row with its reason, never a lost sweep
            rows[j, COL["status"]] = DIVERGED
            why = f"{type(exc).__name__}: {exc}"
        reasons.append(why)
    return idx, rows, reasons
