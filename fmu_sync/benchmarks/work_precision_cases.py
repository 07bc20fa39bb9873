"""Work-precision cases: the scenes (loaded from the built-in TOML files), the methods,
their step ladders and the timed measurement (:func:`measure`)."""
from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .ivp_baseline import ivp_impacts, ivp_impacts_nd

__all__ = ["SCENES", "Case", "Point", "WorkPrecision", "METHOD_DOC", "LADDERS", "measure", "horizon",
           "rest_time_of", "closed_form_rest_time", "pair_metrics", "dop853_pair"]


G = 9.81
V_REST_REL = 1e-6        # rest detection: |u| <= V_REST_REL * v1
PAIR_GRID = 0.01         # d is compared on this grid (s)
PAIR_REF_SCHEME = "trapezoid"   # the impacting pair's fine reference run (the core's default)

METHOD_DOC = {
    "midpoint": "Moreau midpoint (core), step = dt",
    "theta0.5": "Moreau–Jean θ = 0.5 (core), step = dt",
    "theta1": "Moreau–Jean θ = 1 (core), step = dt",
    "trapezoid": "trapezoid (core): Moreau–Jean θ = 0.5 with, in a pair, the coupling inside the step "
                 "(its trapezoid, docs/design.md §2.3); step = dt",
    "exact": "exact event-driven solver (core/exact.py, n-DOF: core/exact_nd.py), output every 1 ms; "
             "it is the reference, so its own error is 0 except against a closed form (tests check it "
             "against DOP853 to 1e-12 (1-DOF) and 1e-10 (two-dof))",
    "solve_ivp": "scipy solve_ivp RK45 + terminal impact event, restart with the impact map, Zeno guard; "
                 "step = rtol (atol = 1e-3 rtol)",
    "cosim": "co-simulation: FMU + master (fmpy, Jacobi), slave dt = H; step = H",
    "cosim-ea": "co-simulation, event-aware (impact steps retaken in H/16 pieces), slave dt = H",
    "cosim-fine": "co-simulation with slave dt = 1e-4 (coupled pair: coupling error only); step = H",
    "cosim-fine-ea": "same, event-aware",
    "cosim-fine-implicit": "same, exchange='implicit' (iterated to the step's end states, hold='foh')",
}
CORE_SCHEMES = (("midpoint", "midpoint", 0.5), ("theta0.5", "theta", 0.5), ("theta1", "theta", 1.0),
                ("trapezoid", "trapezoid", 0.5))


# ------------------------------------------------------------------ scenes
@dataclass(frozen=True)
class Case:
    name: str
    params: dict                  # ImpactOscillator keyword arguments
    x0: tuple
    t_end: float
    t_end_quick: float
    metrics: tuple = ("max_q",)
    pair: dict | None = None      # coupled pair for the "d" metric: x2, Kp, Kd
    system: object = None         # n-DOF scene: its MechanicalSystem (params unused)
    fmu: bool = True              # the 1-DOF FMU applies (co-simulation runs)
    smooth: bool = False          # no impacts: the pair's truth is DOP853 (metric "q"), not a fine run ("d")

    def horizon(self, quick: bool) -> float:
        return self.t_end_quick if quick else self.t_end


_PARAMS = ("m", "k", "c", "f0", "F", "Omega", "e")


def _builtin(name: str, t_end: float, t_end_quick: float, metrics=("max_q",), pair: str | None = None) -> Case:
    """A benchmark case from the built-in scene ``name`` (its system, x1 and, for the
    "d" metric, the coupled variant ``pair``'s x2, Kp, Kd): the TOML files are the only
    place the scenes' numbers are written."""
    from fmu_sync import load_scene
    scene = load_scene(name)
    v = scene.variant(pair) if pair else scene.variants[0]
    params = {k: v.cfg[f"system.{k}"] for k in _PARAMS}
    coupled = dict(x2=v.x2, Kp=v.Kp, Kd=v.Kd) if pair else None
    return Case(name, params, v.x1, t_end, t_end_quick, metrics=metrics, pair=coupled)


def _builtin_nd(name: str, t_end: float, t_end_quick: float) -> Case:
    """An n-DOF benchmark case (its system and x1) from the built-in scene ``name``."""
    from fmu_sync import load_scene
    v = load_scene(name).variants[0]
    return Case(name, {}, v.x1, t_end, t_end_quick, system=v.system, fmu=False)


#: the issue-40 damped forced oscillator (m = 1, k = 1, c = 0.1, F = 0.5, Omega = 2.5), the wall far away: the
#: smooth case (truth: the exact solver alone, DOP853 coupled with Kp = 1, Kd = 0.5)
DAMPED = dict(m=1.0, k=1.0, c=0.1, f0=0.0, F=0.5, Omega=2.5, e=0.9, g0=100.0)
SMOOTH_PAIR = dict(x2=(-0.2, 0.4), Kp=1.0, Kd=0.5)

SCENES = (
    Case("damped-pair", DAMPED, (0.3, 0.0), 20.0, 10.0, pair=SMOOTH_PAIR, fmu=False, smooth=True),
    _builtin("bouncing-ball", 5.0, 5.0, metrics=("rest_time", "max_q")),
    _builtin("forced-pair", 20.0, 10.0, pair="switching"),
    _builtin("zeno-table", 20.0, 10.0),
    _builtin("grazing", 60.0, 20.0),
    _builtin_nd("two-dof", 60.0, 20.0),
)


def closed_form_rest_time(params: dict, q0: float) -> float:
    """Bouncing ball dropped from rest at q0: t_inf = t1 + 2 e v1 / (g (1 - e))."""
    g = -params["f0"] / params["m"]
    e = params["e"]
    t1 = math.sqrt(2.0 * q0 / g)
    v1 = g * t1
    return t1 + 2.0 * e * v1 / (g * (1.0 - e))


def rest_time_of(t, u, v_tol: float) -> float:
    """First output time after which |u| <= v_tol for good (nan if it never rests)."""
    u = np.abs(np.asarray(u, dtype=float).reshape(-1))
    t = np.asarray(t, dtype=float).reshape(-1)
    big = np.nonzero(~(u <= v_tol))[0]
    if big.size == 0:
        return float(t[0])
    if big[-1] + 1 >= t.size:
        return math.nan
    return float(t[big[-1] + 1])


# ------------------------------------------------------------------ results
@dataclass
class Point:
    method: str
    scene: str
    metric: str
    step: float
    error: float
    seconds: float
    repeats: int
    spread: float
    reference: str
    note: str = ""

    CSV_FIELDS = ("method", "scene", "metric", "step", "error", "seconds", "repeats", "spread",
                  "reference", "note")

    def row(self) -> list:
        return [self.method, self.scene, self.metric, f"{self.step:.6g}", f"{self.error:.6g}",
                f"{self.seconds:.6g}", self.repeats, f"{self.spread:.3g}", self.reference, self.note]


@dataclass
class _Config:
    method: str
    scene: Case
    step: float
    fn: Callable
    metrics: tuple
    kind: str = "single"         # "single" or "pair"
    times: list = field(default_factory=list)
    errors: dict = field(default_factory=dict)
    note: str = ""
    failed: bool = False


@dataclass
class WorkPrecision:
    points: list
    markdown: str
    findings: dict
    quick: bool
    seconds: float


# ------------------------------------------------------------------ runners
def _system(scene: Case):
    from fmu_sync.core import ImpactOscillator
    if scene.system is not None:
        return scene.system
    return ImpactOscillator(**scene.params)


def _fmu_starts(scene: Case, slave_dt: float) -> dict:
    from fmu_sync.fmus.contract import MODELS  # the FMU's values, as the contract names them
    io = MODELS["impact-oscillator"]
    return {**io.values(_system(scene)), **io.solver_values(float(slave_dt))}


def _rec_every(step: float, grid: float) -> int:
    return max(1, int(round(grid / step))) if step < grid else 1


def _core_single(scene, T, scheme, theta, dt, fine):
    from fmu_sync.core import simulate
    system = _system(scene)
    rec = 1 if fine else _rec_every(dt, 1e-3)

    def fn():
        r = simulate(system, scene.x0, T, dt, scheme=scheme, theta=theta, record_every=rec)
        return (r.t, r.q, r.u, None) if system.n > 1 else (r.t, r.q[:, 0], r.u[:, 0], None)
    return fn


def _exact_single(scene, T):
    from fmu_sync.core import simulate_exact
    system = _system(scene)

    def fn():
        r = simulate_exact(system, scene.x0, T, 1e-3)
        if system.n > 1:
            return r.t, r.q, r.u, None
        ev = r.events
        rest = float(ev.zeno_times[0]) if ev.zeno_times.size else None
        return r.t, r.q[:, 0], r.u[:, 0], rest
    return fn


def _ivp_single(scene, T, rtol):
    n = int(round(T / 1e-3))
    grid = np.arange(n + 1) * 1e-3
    if scene.system is not None:
        system = scene.system

        def fn_nd():
            Q, U, _ = ivp_impacts_nd(system, scene.x0, T, grid, rtol)
            return grid, Q, U, None
        return fn_nd

    def fn():
        Q, U, _, rest = ivp_impacts(scene.params, scene.x0, T, grid, rtol)
        return grid, Q, U, rest
    return fn


def _cosim_single(scene, T, H, ea, fmu):
    from fmu_sync import cosimulate
    sv = _fmu_starts(scene, H)

    def fn():
        r = cosimulate(fmu, scene.x0, scene.x0, T, H, coupling=None, event_aware=ea,
                       start_values=sv, record_distance=False)
        return r.t, r.q1[:, 0], r.u1[:, 0], None
    return fn


def _core_pair(scene, T, scheme, theta, dt):
    from fmu_sync.core import simulate_pair
    system = _system(scene)
    p = scene.pair
    rec = _rec_every(dt, PAIR_GRID)

    def fn():
        r = simulate_pair(system, scene.x0, p["x2"], T, dt, coupling="switching", Kp=p["Kp"], Kd=p["Kd"],
                          scheme=scheme, theta=theta, record_every=rec)
        return r.t, r.d, r.q1[:, 0], r.q2[:, 0]
    return fn


def pair_metrics(scene: Case) -> tuple:
    """The pair's metrics: ``q`` (max |q_i - q_i,DOP853| over both systems) for a smooth pair, else ``d``."""
    return ("q",) if scene.smooth else ("d",)


def dop853_pair(scene: Case, t):
    """The smooth pair by DOP853 (rtol = atol = 1e-12) at the times ``t``: (q1, q2). Far from the wall the
    switching law is on branch E, the PD law tau_1 = -Kp (q1 - q2) - Kd (u1 - u2) = -tau_2."""
    from scipy.integrate import solve_ivp
    p, s = scene.pair, _system(scene)
    m, k, c, f0 = (float(x) for x in (s.M[0, 0], s.K[0, 0], s.C[0, 0], s.f0[0]))
    (F, Om, ph), = ((float(np.ravel(a)[0]), float(b), float(c_)) for a, b, c_ in s.forcing)

    def rhs(t_, z):
        q1, u1, q2, u2 = z
        tau = -p["Kp"] * (q1 - q2) - p["Kd"] * (u1 - u2)
        f = f0 + F * math.cos(Om * t_ + ph)
        return [u1, (f - k * q1 - c * u1 + tau) / m, u2, (f - k * q2 - c * u2 - tau) / m]
    z0 = [*scene.x0, *p["x2"]]
    r = solve_ivp(rhs, (0.0, float(t[-1])), z0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t)
    return r.y[0], r.y[2]


def _cosim_pair(scene, T, H, ea, slave_dt, fmu, implicit=False):
    from fmu_sync import cosimulate
    p = scene.pair
    sv = _fmu_starts(scene, slave_dt)
    rec = _rec_every(H, PAIR_GRID)
    exchange = dict(exchange="implicit", hold="foh") if implicit else {}

    def fn():
        r = cosimulate(fmu, scene.x0, p["x2"], T, H, coupling="switching", Kp=p["Kp"], Kd=p["Kd"],
                       event_aware=ea, start_values=sv, record_every=rec, **exchange)
        return r.t, r.d
    return fn


# ------------------------------------------------------------------ ladders
LADDERS = {
    "full": dict(dt=(1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5),
                 rtol=(1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10),
                 H=(0.05, 0.02, 0.01, 0.005, 0.002, 0.001),
                 dt_ref_pair=1e-6, repeats=5, budget=10.0, min_time=0.02),
    "quick": dict(dt=(1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5),
                  rtol=(1e-3, 1e-5, 1e-7, 1e-9),
                  H=(0.05, 0.02, 0.01, 0.005),
                  dt_ref_pair=1e-5, repeats=3, budget=0.6, min_time=0.01),
    "smoke": dict(dt=(1e-2, 1e-3), rtol=(1e-4,), H=(0.05,), dt_ref_pair=1e-4, repeats=1, budget=0.0,
                  min_time=0.0),
}


def horizon(scene: Case, mode: str) -> float:
    """Run length of a scene in a mode (smoke: at most 5 s)."""
    if mode == "smoke":
        return min(scene.t_end_quick, 5.0)
    return scene.horizon(mode == "quick")


def _configs(mode: str, fmu, scenes=SCENES):
    lad = LADDERS[mode]
    cfgs = []
    for sc in scenes:
        T = horizon(sc, mode)
        fine = "rest_time" in sc.metrics
        for label, scheme, theta in CORE_SCHEMES:
            for dt in lad["dt"]:
                cfgs.append(_Config(label, sc, dt, _core_single(sc, T, scheme, theta, dt, fine), sc.metrics))
        cfgs.append(_Config("exact", sc, 1e-3, _exact_single(sc, T), sc.metrics))
        for rtol in lad["rtol"]:
            cfgs.append(_Config("solve_ivp", sc, rtol, _ivp_single(sc, T, rtol), sc.metrics))
        if fmu is not None and sc.fmu:
            for H in lad["H"]:
                for ea in (False, True):
                    cfgs.append(_Config("cosim-ea" if ea else "cosim", sc, H,
                                        _cosim_single(sc, T, H, ea, fmu), sc.metrics))
        if sc.pair is not None:
            for label, scheme, theta in CORE_SCHEMES:
                for dt in lad["dt"]:
                    if dt >= 10 * lad["dt_ref_pair"] - 1e-15 or sc.smooth:
                        cfgs.append(_Config(label, sc, dt, _core_pair(sc, T, scheme, theta, dt), pair_metrics(sc),
                                            "pair"))
            if fmu is not None:
                for H in lad["H"]:
                    for ea in (False, True):
                        cfgs.append(_Config("cosim-ea" if ea else "cosim", sc, H,
                                            _cosim_pair(sc, T, H, ea, H, fmu), ("d",), "pair"))
                        if H > 1e-4:
                            cfgs.append(_Config("cosim-fine-ea" if ea else "cosim-fine", sc, H,
                                                _cosim_pair(sc, T, H, ea, 1e-4, fmu), ("d",), "pair"))
                    if H > 1e-4:
                        cfgs.append(_Config("cosim-fine-implicit", sc, H, _cosim_pair(sc, T, H, False, 1e-4, fmu, True),
                                            ("d",), "pair"))
    return cfgs


# ------------------------------------------------------------------ references and errors
@dataclass
class _Reference:
    events: object = None           # ExactEvents over the horizon
    t_inf: float | None = None      # closed-form rest time
    v_tol: float = 0.0
    d_t: np.ndarray | None = None   # pair reference on the PAIR_GRID
    d: np.ndarray | None = None
    d_label: str = ""
    q_pair: tuple | None = None     # smooth pair: DOP853's (q1, q2) on the PAIR_GRID


def _references(cfgs, mode):
    from fmu_sync.core import exact_events
    from fmu_sync.core import simulate_pair
    refs = {}
    dt_ref = LADDERS[mode]["dt_ref_pair"]
    for sc in {c.scene.name: c.scene for c in cfgs}.values():
        T = horizon(sc, mode)
        ref = _Reference()
        system = _system(sc)
        ref.events = exact_events(system, sc.x0, T)
        if "rest_time" in sc.metrics:
            ref.t_inf = closed_form_rest_time(sc.params, sc.x0[0])
            ref.v_tol = V_REST_REL * math.sqrt(2.0 * G * sc.x0[0])
        if sc.smooth:
            ref.q_pair = dop853_pair(sc, np.arange(int(round(T / PAIR_GRID)) + 1) * PAIR_GRID)
        elif sc.pair is not None:
            p = sc.pair
            r = simulate_pair(_system(sc), sc.x0, p["x2"], T, dt_ref, coupling="switching", Kp=p["Kp"],
                              Kd=p["Kd"], record_every=_rec_every(dt_ref, PAIR_GRID), scheme=PAIR_REF_SCHEME)
            ref.d_t, ref.d = r.t, r.d
            ref.d_label = f"simulate_pair {PAIR_REF_SCHEME} dt={dt_ref:g}"
        refs[sc.name] = ref
    return refs


def _evaluate(cfg: _Config, out, ref: _Reference) -> dict:
    if cfg.kind == "pair":
        t, d = out[:2]
        idx = np.rint(np.asarray(t) / PAIR_GRID).astype(int)
        if ref.q_pair is not None:
            ok = idx < ref.q_pair[0].size
            return {"q": float(max(np.max(np.abs(np.asarray(q)[ok] - qr[idx[ok]])) for q, qr in zip(out[2:], ref.q_pair)))}
        ok = idx < ref.d.size
        return {"d": float(np.max(np.abs(np.asarray(d)[ok] - ref.d[idx[ok]])))}
    t, q, u, rest = out
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    errs = {}
    if "max_q" in cfg.metrics:
        if cfg.method == "exact":
            errs["max_q"] = 0.0
        else:
            inside = t <= ref.events.t_end
            qe, _ = ref.events.state(t[inside])
            if not np.all(np.isfinite(q[inside])):
                errs["max_q"] = math.nan
            else:
                errs["max_q"] = float(np.max(np.abs(q[inside] - qe.reshape(q[inside].shape))))
    if "rest_time" in cfg.metrics:
        tr = rest if rest is not None else rest_time_of(t, u, ref.v_tol)
        errs["rest_time"] = abs(tr - ref.t_inf) if math.isfinite(tr) else math.nan
        if not math.isfinite(tr):
            errs["rest_time_note"] = "never comes to rest within the horizon"
    return errs


def _reference_label(cfg: _Config, metric: str, ref: _Reference) -> str:
    if metric == "d":
        return ref.d_label
    if metric == "q":
        return "DOP853 rtol=atol=1e-12"
    if metric == "rest_time":
        return "closed form t_inf"
    return "exact (core/exact_nd.py)" if cfg.scene.system is not None else "exact (core/exact.py)"


# ------------------------------------------------------------------ measurement loop
def _warm_up(cfgs, progress=None):
    """One short run of each kind so that no timing includes compilation / cache loading."""
    seen = set()
    for c in cfgs:
        key = (c.method, c.kind, c.scene.system is not None)   # n-DOF kernels compile apart
        if key in seen:
            continue
        seen.add(key)
        try:
            c.fn()
        except Exception:
            pass


def _timed(fn, min_time: float):
    """(seconds per call, output of the first call). Calls faster than ``min_time`` are repeated
    back to back until ``min_time`` is spent and averaged (one timer read per call is too coarse
    and too noisy for sub-millisecond runs)."""
    t0 = time.perf_counter()
    out = fn()
    sec = time.perf_counter() - t0
    if sec >= min_time or min_time <= 0:
        return sec, out
    n = min(1000, max(1, int(math.ceil(min_time / max(sec, 1e-7)))))
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n, out


def measure(mode: str = "quick", fmu=None, progress=None, scenes=SCENES) -> list[Point]:
    lad = LADDERS[mode]
    cfgs = _configs(mode, fmu, scenes)
    refs = _references(cfgs, mode)
    _warm_up(cfgs)
    total = len(cfgs) * lad["repeats"]
    done = 0
    for rep in range(lad["repeats"]):
        for c in cfgs:
            done += 1
            if progress is not None:
                progress(done / total)
            if c.failed or (rep > 0 and sum(c.times) > lad["budget"]):
                continue
            try:
                sec, out = _timed(c.fn, lad["min_time"])
                c.times.append(sec)
            except Exception as ex:  # reported in the table, never silently dropped
                c.failed = True
                c.note = f"{type(ex).__name__}: {str(ex).splitlines()[0][:160]}"
                continue
            if rep == 0:
                try:
                    c.errors = _evaluate(c, out, refs[c.scene.name])
                except Exception as ex:
                    c.note = f"evaluation failed: {type(ex).__name__}: {ex}"
            del out
    points = []
    for c in cfgs:
        med = statistics.median(c.times) if c.times else math.nan
        spread = (max(c.times) - min(c.times)) / med if len(c.times) > 1 and med > 0 else 0.0
        for metric in c.metrics:
            err = c.errors.get(metric, math.nan)
            note = c.note or c.errors.get(f"{metric}_note", "")
            if c.method == "exact" and metric != "rest_time" and not c.failed:
                note = note or "reference itself: error 0 by definition"
            points.append(Point(c.method, c.scene.name, metric, c.step, err, med, len(c.times), spread,
                                _reference_label(c, metric, refs[c.scene.name]), note))
    return points
