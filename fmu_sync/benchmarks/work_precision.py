"""Work–precision: error against run time for every solver on the built-in scenes (SPEC §9).

Methods (``method`` column of ``work_precision.csv``; ``step`` is the method's own knob):

============== ===============================================================  ==========
method         what runs                                                        step
============== ===============================================================  ==========
midpoint       core ``simulate`` / ``simulate_pair``, Moreau midpoint           dt
theta0.5       core, Moreau–Jean θ = 0.5                                        dt
theta1         core, Moreau–Jean θ = 1                                          dt
exact          core/exact.py (1-DOF) or core/exact_nd.py (n-DOF), event-driven  (1e-3)
               closed form, sampled every 1 ms
solve_ivp      ``scipy.integrate.solve_ivp`` RK45 with a terminal g = 0 event,  rtol
               restart with the impact map, Zeno guard (see :func:`ivp_impacts`,
               :func:`ivp_impacts_nd`)
cosim          FMU + master (fmpy), Jacobi, slave's internal dt = H             H
cosim-ea       same, ``event_aware=True`` (impact steps retaken in H/16)        H
cosim-fine     coupled pair only: slave dt = 1e-4 (coupling error alone)        H
cosim-fine-ea  same, event-aware                                                H
============== ===============================================================  ==========

Errors (``metric`` column), all absolute, SI units:

* ``max_q``: max over the method's output times (and coordinates) of |q - q_exact(t)|
  (exact: core/exact.py, or core/exact_nd.py for the two-dof scene, evaluated at the same
  times);
* ``rest_time`` (bouncing ball): |t_rest - t_inf|, ``t_inf = t1 + 2 e v1 / (g (1 - e))`` in
  closed form; t_rest is the first output time after which |u| <= 1e-6 v1 for good (the
  exact solver and solve_ivp report theirs directly);
* ``d`` (paper example, coupled pair, switching coupling Kp = 1, Kd = 0.5): max over a
  10 ms grid of |d - d_ref|, the reference being ``simulate_pair`` (midpoint) at a much finer
  dt — the exact solver does not apply to a coupled pair (the coupling force depends on
  both states), so this reference is labelled in the ``reference`` column.

Timing: every configuration is warmed up (compiled / cache loaded, FMU instantiated once)
before it is timed; repeats are interleaved (all configurations once, then again), the
figure is the median and ``spread`` = (max - min) / median of the repeats. Long runs are
repeated fewer times (``repeats`` column). Error evaluation is never timed.
"""
from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

__all__ = ["SCENES", "Scene", "Point", "WorkPrecision", "run", "ivp_impacts", "METHOD_DOC",
           "measured_order", "rest_time_of", "closed_form_rest_time"]

G = 9.81
V_REST_REL = 1e-6        # rest detection: |u| <= V_REST_REL * v1
PAIR_GRID = 0.01         # d is compared on this grid (s)

METHOD_DOC = {
    "midpoint": "Moreau midpoint (core), step = dt",
    "theta0.5": "Moreau–Jean θ = 0.5 (core), step = dt",
    "theta1": "Moreau–Jean θ = 1 (core), step = dt",
    "exact": "exact event-driven solver (core/exact.py, n-DOF: core/exact_nd.py), output every 1 ms; "
             "it is the reference, so its own error is 0 except against a closed form (tests check it "
             "against DOP853 to 1e-12 (1-DOF) and 1e-10 (two-dof))",
    "solve_ivp": "scipy solve_ivp RK45 + terminal impact event, restart with the impact map, Zeno guard; "
                 "step = rtol (atol = 1e-3 rtol)",
    "cosim": "co-simulation: FMU + master (fmpy, Jacobi), slave dt = H; step = H",
    "cosim-ea": "co-simulation, event-aware (impact steps retaken in H/16 pieces), slave dt = H",
    "cosim-fine": "co-simulation with slave dt = 1e-4 (coupled pair: coupling error only); step = H",
    "cosim-fine-ea": "same, event-aware",
}
CORE_SCHEMES = (("midpoint", "midpoint", 0.5), ("theta0.5", "theta", 0.5), ("theta1", "theta", 1.0))


# ------------------------------------------------------------------ scenes
@dataclass(frozen=True)
class Scene:
    name: str
    params: dict                  # ImpactOscillator keyword arguments
    x0: tuple
    t_end: float
    t_end_quick: float
    metrics: tuple = ("max_q",)
    pair: dict | None = None      # coupled pair for the "d" metric: x2, Kp, Kd
    system_kw: dict | None = None  # MechanicalSystem keyword arguments (n-DOF scene; params unused)
    fmu: bool = True              # the 1-DOF FMU applies (co-simulation runs)

    def horizon(self, quick: bool) -> float:
        return self.t_end_quick if quick else self.t_end


SCENES = (
    Scene("bouncing-ball", dict(m=1.0, k=0.0, c=0.0, f0=-G, F=0.0, Omega=0.0, e=0.8), (1.0, 0.0),
          5.0, 5.0, metrics=("rest_time", "max_q")),
    Scene("paper-example", dict(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9), (1.0, 0.0),
          20.0, 10.0, metrics=("max_q",), pair=dict(x2=(0.2, 0.5), Kp=1.0, Kd=0.5)),
    Scene("zeno-table", dict(m=1.0, k=0.0, c=0.0, f0=-1.0, F=2.0, Omega=3.0, e=0.5), (0.0, 0.0),
          20.0, 10.0),
    Scene("grazing", dict(m=1.0, k=1.0, c=0.0, f0=0.4, F=0.3, Omega=0.5, e=0.8), (0.8, 0.0),
          60.0, 20.0),
    # fmu_sync/scenes/two-dof.toml, system x1
    Scene("two-dof", {}, ((0.6, 0.2), (0.0, 0.0)), 60.0, 20.0, fmu=False,
          system_kw=dict(M=[[2.0, 0.5], [0.5, 1.0]], K=[[3.0, -1.0], [-1.0, 2.0]], C=[[0.02, 0.0], [0.0, 0.02]],
                         f0=[0.1, 0.2], w=[1.0, 0.5], g0=0.0, e=0.7, forcing=[([0.6, 0.0], 1.3, 0.0)])),
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


# ------------------------------------------------------------------ solve_ivp baseline
def ivp_impacts(params: dict, x0, t_end: float, grid, rtol: float, method: str = "RK45",
                v_rest: float = 1e-6, t_min: float = 1e-9, max_impacts: int = 100_000):
    """The impact oscillator the way most Python users write it with scipy.

    Integrate ``m q'' + c q' + k q = f0 + F cos(Omega t)`` with ``solve_ivp`` until the
    terminal event ``q = 0`` (direction -1), apply ``u -> -e u`` and restart. Zeno guard:
    a post-impact speed below ``v_rest`` or two impacts closer than ``t_min`` put the
    mass at rest on the wall (q = u = 0) until the free force at the wall turns positive
    (a second event), then free flight resumes; more than ``max_impacts`` impacts raise.
    Returns ``(q, u, impacts, rest_time)`` with q, u sampled on ``grid`` (t_eval).
    """
    from scipy.integrate import solve_ivp

    m, k, c, f0 = (float(params[n]) for n in ("m", "k", "c", "f0"))
    F, Om, e = float(params.get("F", 0.0)), float(params.get("Omega", 0.0)), float(params["e"])
    atol = rtol * 1e-3
    grid = np.asarray(grid, dtype=float)

    def rhs(t, y):
        return [y[1], (f0 + F * math.cos(Om * t) - k * y[0] - c * y[1]) / m]

    def hit(t, y):
        return y[0]

    hit.terminal = True
    hit.direction = -1

    def push(t, y):                      # free force on the mass resting at q = 0, u = 0
        return f0 + F * math.cos(Om * t)

    push.terminal = True
    push.direction = 1

    Q = np.full(grid.size, np.nan)
    U = np.full(grid.size, np.nan)
    t, y = 0.0, np.array(x0, dtype=float)
    impacts, t_last, rest = 0, -math.inf, None
    while t < t_end:
        a = int(np.searchsorted(grid, t, side="left"))
        b = int(np.searchsorted(grid, t_end, side="right"))
        sol = solve_ivp(rhs, (t, t_end), y, method=method, rtol=rtol, atol=atol, events=hit,
                        t_eval=grid[a:b])
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed at t = {t:.6g}: {sol.message}")
        n = np.asarray(sol.t).size
        if n:
            Q[a:a + n] = sol.y[0]
            U[a:a + n] = sol.y[1]
        if sol.status != 1:
            break
        te, um = float(sol.t_events[0][0]), float(sol.y_events[0][0][1])
        impacts += 1
        if impacts > max_impacts:
            raise RuntimeError(f"solve_ivp baseline: more than {max_impacts} impacts (Zeno guard failed)")
        up = -e * um
        if up < v_rest or te - t_last < t_min:
            if rest is None:
                rest = te
            if push(te, None) > 0.0:
                t, y, t_last = te, np.zeros(2), te
                continue
            s2 = solve_ivp(lambda s, z: [0.0], (te, t_end), [0.0], events=push, rtol=1e-10, atol=1e-12,
                           max_step=(math.pi / (4.0 * Om)) if Om > 0.0 else np.inf)
            tr = float(s2.t_events[0][0]) if s2.status == 1 else t_end
            i0 = int(np.searchsorted(grid, te, side="right"))
            i1 = int(np.searchsorted(grid, tr, side="right"))
            Q[i0:i1] = 0.0
            U[i0:i1] = 0.0
            if s2.status != 1:
                break
            t, y, t_last = tr, np.zeros(2), tr
        else:
            t, y, t_last = te, np.array([0.0, up]), te
    return Q, U, impacts, rest


def ivp_impacts_nd(system, x0, t_end: float, grid, rtol: float, method: str = "RK45",
                   v_rest: float = 1e-6, t_min: float = 1e-9, max_impacts: int = 100_000):
    """:func:`ivp_impacts` for an n-DOF MechanicalSystem: terminal event g(q) = 0, impact map
    ``u -> u - (1+e) M^-1 w (w^T u)/W``, Zeno guard (post-impact normal speed below ``v_rest``
    or impacts closer than ``t_min``: the normal velocity is removed and the projected
    (sliding) dynamics run until the contact force turns negative). Returns (Q, U, impacts)
    sampled on ``grid``."""
    from scipy.integrate import solve_ivp

    sa = system.arrays()
    n = system.n
    Minv, w, W, iw, e = sa.Minv, sa.w, sa.W, sa.Minv_w, sa.e
    atol = rtol * 1e-3
    grid = np.asarray(grid, dtype=float)

    def h(t, q, u):
        f = sa.f0 - sa.K @ q - sa.C @ u
        for F, Om, ph in zip(sa.F, sa.Omega, sa.phi):
            f = f + F * math.cos(Om * t + ph)
        return f

    def free(t, y):
        return np.concatenate([y[n:], Minv @ h(t, y[:n], y[n:])])

    def slide(t, y):
        a = Minv @ h(t, y[:n], y[n:])
        return np.concatenate([y[n:], a - iw * (w @ a) / W])

    def hit(t, y):
        return w @ y[:n] + sa.g0
    hit.terminal, hit.direction = True, -1

    def release(t, y):
        return -(w @ (Minv @ h(t, y[:n], y[n:])))
    release.terminal, release.direction = True, -1

    Q = np.full((grid.size, n), np.nan)
    U = np.full((grid.size, n), np.nan)
    t = 0.0
    y = np.concatenate([np.asarray(x0[0], float), np.asarray(x0[1], float)])
    impacts, t_last, mode = 0, -math.inf, "free"
    while t < t_end:
        a = int(np.searchsorted(grid, t, side="left"))
        b = int(np.searchsorted(grid, t_end, side="right"))
        sol = solve_ivp(free if mode == "free" else slide, (t, t_end), y, method=method, rtol=rtol,
                        atol=atol, events=hit if mode == "free" else release, t_eval=grid[a:b])
        if not sol.success:
            raise RuntimeError(f"solve_ivp failed at t = {t:.6g}: {sol.message}")
        k = np.asarray(sol.t).size
        if k:
            Q[a:a + k] = sol.y[:n].T
            U[a:a + k] = sol.y[n:].T
        if sol.status != 1:
            break
        te, ye = float(sol.t_events[0][0]), sol.y_events[0][0].copy()
        if mode == "slide":
            t, y, mode = te, ye, "free"
            continue
        vm = float(w @ ye[n:])
        if vm >= 0.0:             # round-off crossing right after a restart
            t, y = te + t_min, ye
            continue
        impacts += 1
        if impacts > max_impacts:
            raise RuntimeError(f"solve_ivp baseline: more than {max_impacts} impacts (Zeno guard failed)")
        ye[n:] = ye[n:] - (1.0 + e) * iw * vm / W
        if -e * vm < v_rest or te - t_last < t_min:
            ye[n:] = ye[n:] - iw * (w @ ye[n:]) / W
            mode = "slide"
        t, y, t_last = te, ye, te
    return Q, U, impacts


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
    scene: Scene
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
def _system(scene: Scene):
    from fmu_sync.core import ImpactOscillator, MechanicalSystem
    if scene.system_kw is not None:
        return MechanicalSystem(**scene.system_kw)
    return ImpactOscillator(**scene.params)


def _fmu_starts(scene: Scene, slave_dt: float) -> dict:
    p = scene.params
    out = {n: float(p.get(n, 0.0)) for n in ("m", "k", "c", "f0", "F", "Omega", "e")}
    out["phi"] = 0.0
    out["solver.dt"] = float(slave_dt)
    return out


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
    system = _system(scene)
    if system.n > 1:
        from fmu_sync.core.exact_nd import simulate_exact_nd

        def fn_nd():
            r = simulate_exact_nd(system, scene.x0, T, 1e-3)
            return r.t, r.q, r.u, None
        return fn_nd
    from fmu_sync.core.exact import simulate_exact

    def fn():
        r, ev = simulate_exact(system, scene.x0, T, 1e-3, return_events=True)
        rest = float(ev.zeno_times[0]) if ev.zeno_times.size else None
        return r.t, r.q[:, 0], r.u[:, 0], rest
    return fn


def _ivp_single(scene, T, rtol):
    n = int(round(T / 1e-3))
    grid = np.arange(n + 1) * 1e-3
    if scene.system_kw is not None:
        system = _system(scene)

        def fn_nd():
            Q, U, _ = ivp_impacts_nd(system, scene.x0, T, grid, rtol)
            return grid, Q, U, None
        return fn_nd

    def fn():
        Q, U, _, rest = ivp_impacts(scene.params, scene.x0, T, grid, rtol)
        return grid, Q, U, rest
    return fn


def _cosim_single(scene, T, H, ea, fmu):
    from fmu_sync.master import cosimulate
    sv = _fmu_starts(scene, H)

    def fn():
        r = cosimulate(fmu, scene.x0, scene.x0, T, H, coupling=None, event_aware=ea,
                       start_values=sv, record_distance=False)
        if r.error:
            raise RuntimeError(r.error)
        return r.t, r.q1[:, 0], r.u1[:, 0], None
    return fn


def _core_pair(scene, T, scheme, theta, dt):
    from fmu_sync.core.pair import simulate_pair
    system = _system(scene)
    p = scene.pair
    rec = _rec_every(dt, PAIR_GRID)

    def fn():
        r = simulate_pair(system, scene.x0, p["x2"], T, dt, coupling="switching", Kp=p["Kp"], Kd=p["Kd"],
                          scheme=scheme, theta=theta, record_every=rec)
        return r.t, r.d
    return fn


def _cosim_pair(scene, T, H, ea, slave_dt, fmu):
    from fmu_sync.master import cosimulate
    p = scene.pair
    sv = _fmu_starts(scene, slave_dt)
    rec = _rec_every(H, PAIR_GRID)

    def fn():
        r = cosimulate(fmu, scene.x0, p["x2"], T, H, coupling="switching", Kp=p["Kp"], Kd=p["Kd"],
                       event_aware=ea, start_values=sv, record_every=rec)
        if r.error:
            raise RuntimeError(r.error)
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


def horizon(scene: Scene, mode: str) -> float:
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
                    if dt >= 10 * lad["dt_ref_pair"] - 1e-15:
                        cfgs.append(_Config(label, sc, dt, _core_pair(sc, T, scheme, theta, dt), ("d",), "pair"))
            if fmu is not None:
                for H in lad["H"]:
                    for ea in (False, True):
                        cfgs.append(_Config("cosim-ea" if ea else "cosim", sc, H,
                                            _cosim_pair(sc, T, H, ea, H, fmu), ("d",), "pair"))
                        if H > 1e-4:
                            cfgs.append(_Config("cosim-fine-ea" if ea else "cosim-fine", sc, H,
                                                _cosim_pair(sc, T, H, ea, 1e-4, fmu), ("d",), "pair"))
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


def _references(cfgs, mode):
    from fmu_sync.core.exact import exact_events
    from fmu_sync.core.pair import simulate_pair
    refs = {}
    dt_ref = LADDERS[mode]["dt_ref_pair"]
    for sc in {c.scene.name: c.scene for c in cfgs}.values():
        T = horizon(sc, mode)
        ref = _Reference()
        system = _system(sc)
        if system.n > 1:
            from fmu_sync.core.exact_nd import exact_events_nd
            ref.events = exact_events_nd(system, sc.x0, T)[0]
        else:
            ref.events = exact_events(system, sc.x0, T)
        if "rest_time" in sc.metrics:
            ref.t_inf = closed_form_rest_time(sc.params, sc.x0[0])
            ref.v_tol = V_REST_REL * math.sqrt(2.0 * G * sc.x0[0])
        if sc.pair is not None:
            p = sc.pair
            r = simulate_pair(_system(sc), sc.x0, p["x2"], T, dt_ref, coupling="switching", Kp=p["Kp"],
                              Kd=p["Kd"], record_every=_rec_every(dt_ref, PAIR_GRID))
            ref.d_t, ref.d = r.t, r.d
            ref.d_label = f"simulate_pair midpoint dt={dt_ref:g}"
        refs[sc.name] = ref
    return refs


def _evaluate(cfg: _Config, out, ref: _Reference) -> dict:
    if cfg.kind == "pair":
        t, d = out
        idx = np.rint(np.asarray(t) / PAIR_GRID).astype(int)
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
    if metric == "rest_time":
        return "closed form t_inf"
    return "exact (core/exact_nd.py)" if cfg.scene.system_kw is not None else "exact (core/exact.py)"


# ------------------------------------------------------------------ measurement loop
def _warm_up(cfgs, progress=None):
    """One short run of each kind so that no timing includes compilation / cache loading."""
    seen = set()
    for c in cfgs:
        key = (c.method, c.kind, c.scene.system_kw is not None)   # n-DOF kernels compile apart
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


# ------------------------------------------------------------------ analysis
def _curve(points, scene, metric, method):
    pts = [p for p in points if p.scene == scene and p.metric == metric and p.method == method
           and math.isfinite(p.error) and math.isfinite(p.seconds)]
    return sorted(pts, key=lambda p: p.step)


def measured_order(points, scene, metric, method="midpoint", min_step=0.0, floor=0.0):
    """Least-squares slope of log(error) vs log(step) (points with error > floor, step >= min_step)."""
    pts = [p for p in _curve(points, scene, metric, method) if p.error > floor and p.step >= min_step]
    if len(pts) < 3:
        return math.nan, pts
    x = np.log10([p.step for p in pts])
    y = np.log10([p.error for p in pts])
    return float(np.polyfit(x, y, 1)[0]), pts


def slope_stderr(pts) -> float:
    """Standard error of the least-squares slope (scatter of the points about the line)."""
    if len(pts) < 4:
        return math.nan
    x = np.log10([p.step for p in pts])
    y = np.log10([p.error for p in pts])
    _, cov = np.polyfit(x, y, 1, cov=True)
    return float(math.sqrt(cov[0, 0]))


def _interp_loglog(xs, ys, x):
    """Piecewise-linear interpolation in log-log (xs increasing); nan outside."""
    lx, ly = np.log10(xs), np.log10(ys)
    v = math.log10(x)
    if v < lx[0] or v > lx[-1]:
        return math.nan
    return 10 ** float(np.interp(v, lx, ly))


def _pareto(c):
    """(errors, seconds) of the Pareto front, by increasing error."""
    # Pareto front: walking to larger errors, keep a run only if it is cheaper than every
    # run with a smaller error (dominated runs say nothing about the attainable cost)
    c = sorted(c, key=lambda p: (p.error, p.seconds))
    keep, best = [], math.inf
    for p in c:
        if p.seconds < best:
            keep.append(p)
            best = p.seconds
    return np.array([p.error for p in keep]), np.array([p.seconds for p in keep])


def cost_crossover(points, scene, metric, a, b):
    """Error level below which method ``a`` becomes cheaper (or dearer) than ``b``.

    The Pareto fronts seconds(error) of both methods are interpolated in log-log on their
    common error range; returns a dict: crossing error (or None), which method is cheaper at
    the small- and the large-error end and by how much, the common range.
    """
    ca = [p for p in _curve(points, scene, metric, a) if p.error > 0]
    cb = [p for p in _curve(points, scene, metric, b) if p.error > 0]
    if len(ca) < 2 or len(cb) < 2:
        return None
    ea, sa = _pareto(ca)
    eb, sb = _pareto(cb)
    if len(ea) < 2 or len(eb) < 2:
        return dict(overlap=False, a_range=(ea[0], ea[-1]), b_range=(eb[0], eb[-1]))
    lo, hi = max(ea[0], eb[0]), min(ea[-1], eb[-1])
    if not lo < hi:
        return dict(overlap=False, a_range=(ea[0], ea[-1]), b_range=(eb[0], eb[-1]))
    grid = np.logspace(math.log10(lo), math.log10(hi), 200)
    ra = np.array([_interp_loglog(ea, sa, g) for g in grid])
    rb = np.array([_interp_loglog(eb, sb, g) for g in grid])
    diff = np.log10(ra) - np.log10(rb)
    s = np.sign(diff)
    crossings = [float(grid[i]) for i in range(len(grid) - 1) if s[i] != 0 and s[i + 1] != 0 and s[i] != s[i + 1]]
    cross = crossings[0] if len(crossings) == 1 else None
    return dict(overlap=True, crossing=cross, crossings=crossings, range=(lo, hi),
                cheaper_coarse=a if diff[-1] < 0 else b, cheaper_fine=a if diff[0] < 0 else b,
                ratio_coarse=float(10 ** -diff[-1]), ratio_fine=float(10 ** -diff[0]))


def midpoint_vs_exact(points, scene, metric):
    """dt below which the midpoint run costs more than the exact solver (log-log interpolation)."""
    mid = _curve(points, scene, metric, "midpoint")
    ex = [p for p in points if p.scene == scene and p.metric == metric and p.method == "exact"
          and math.isfinite(p.seconds)]
    if not mid or not ex:
        return None
    tx = ex[0].seconds
    steps = np.array([p.step for p in mid])          # increasing: fine -> coarse
    secs = np.array([p.seconds for p in mid])
    errs = np.array([p.error for p in mid])
    if np.all(secs <= tx):
        return dict(dt=None, exact_seconds=tx, note="the midpoint is cheaper than the exact solver over "
                    f"the whole ladder (dt >= {steps[0]:g})")
    if np.all(secs > tx):
        return dict(dt=None, exact_seconds=tx, note="the exact solver is cheaper than every midpoint run "
                    f"(dt <= {steps[-1]:g})")
    for i in range(len(steps) - 2, -1, -1):           # coarsest crossing
        if (secs[i] > tx) != (secs[i + 1] > tx):
            x = np.interp(math.log10(tx), sorted([math.log10(secs[i]), math.log10(secs[i + 1])]),
                          [math.log10(steps[i + 1]), math.log10(steps[i])]
                          if secs[i] > secs[i + 1] else [math.log10(steps[i]), math.log10(steps[i + 1])])
            dt = 10 ** float(x)
            e0, e1 = errs[i], errs[i + 1]
            err = (_interp_loglog(steps[i:i + 2], np.maximum([e0, e1], 1e-300), dt)
                   if e0 > 0 and e1 > 0 else math.nan)
            return dict(dt=dt, err=err, exact_seconds=tx)
    return None


#: error levels of the "best method vs solve_ivp" comparison
LEVELS = tuple(10.0 ** -k for k in range(2, 11))
#: the project's own methods (single system)
OWN_METHODS = ("midpoint", "theta0.5", "theta1", "exact")
#: verified accuracy of the exact solvers against DOP853 (tests/test_exact.py: 1e-12 on the
#: 1-DOF closed forms; tests/test_exact_nd.py: 1e-10 asserted on the two-dof scene)
EXACT_VERIFIED = {1: 1e-12, 2: 1e-10}


def best_vs_ivp(points, scene, metric, n_dof=1):
    """At each error level 1e-2..1e-10: the cheapest run of the project's own methods with
    error <= level (the exact solver counts with its verified accuracy where its error is the
    reference's 0) against the cheapest solve_ivp run with error <= level.

    Returns rows (level, own method, own seconds, solve_ivp seconds or nan, ok) with ok =
    own <= solve_ivp (True where solve_ivp never reaches the level)."""
    rows = []
    pts = [p for p in points if p.scene == scene and p.metric == metric and math.isfinite(p.seconds)]
    for lev in LEVELS:
        own = []
        for p in pts:
            if p.method not in OWN_METHODS or not math.isfinite(p.error):
                continue
            err = p.error
            if p.method == "exact" and err == 0.0:
                err = EXACT_VERIFIED.get(n_dof, EXACT_VERIFIED[2])
            if err <= lev:
                own.append((p.seconds, p.method, p.step))
        ivp = [p.seconds for p in pts if p.method == "solve_ivp" and math.isfinite(p.error) and p.error <= lev]
        best = min(own) if own else (math.nan, "none", math.nan)
        tivp = min(ivp) if ivp else math.nan
        ok = (not math.isnan(best[0])) and (math.isnan(tivp) or best[0] <= tivp)
        rows.append((lev, best[1], best[2], best[0], tivp, ok))
    return rows


def cosim_h_dependence(points, scene, metric):
    """Slope of log error vs log H for each co-simulation variant and the event-aware gain."""
    out = {}
    for m in ("cosim", "cosim-ea", "cosim-fine", "cosim-fine-ea"):
        slope, pts = measured_order(points, scene, metric, m)
        if pts:
            out[m] = dict(slope=slope, errors={p.step: p.error for p in pts},
                          seconds={p.step: p.seconds for p in pts})
    return out


# ------------------------------------------------------------------ report
def _fmt(x, digits=3):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    if x == 0:
        return "0"
    return f"{x:.{digits}g}"


def table(points, scene, metric) -> str:
    pts = [p for p in points if p.scene == scene and p.metric == metric]
    order = list(METHOD_DOC)
    pts.sort(key=lambda p: (order.index(p.method) if p.method in order else 99, -p.step))
    base = [p for p in pts if p.method == "midpoint" and abs(p.step - 1e-3) < 1e-12]
    b = base[0].seconds if base and math.isfinite(base[0].seconds) else math.nan
    lines = [f"| method | step | error | seconds (median) | repeats | spread | cost / midpoint dt=1e-3 |",
             "|---|---|---|---|---|---|---|"]
    for p in pts:
        err = _fmt(p.error) if not p.note or p.method == "exact" else f"{_fmt(p.error)} ({p.note})"
        lines.append(f"| {p.method} | {p.step:.3g} | {err} | {_fmt(p.seconds)} | {p.repeats} | "
                     f"{p.spread:.2f} | {_fmt(p.seconds / b) if math.isfinite(b) else 'n/a'} |")
    return "\n".join(lines)


def _crossover_line(points, scene, metric, a, b, findings) -> str | None:
    cx = cost_crossover(points, scene, metric, a, b)
    if cx is None:
        return None
    findings.setdefault("crossover", {})[f"{scene}/{metric}: {a} vs {b}"] = cx
    head = f"- **{a} vs {b}, {scene} / {metric}**: "
    if not cx["overlap"]:
        return (head + f"error ranges do not overlap ({a} {_fmt(cx['a_range'][0])}–{_fmt(cx['a_range'][1])}, "
                f"{b} {_fmt(cx['b_range'][0])}–{_fmt(cx['b_range'][1])}).")
    if len(cx["crossings"]) > 1:
        return (head + f"the cost curves cross {len(cx['crossings'])} times on {_fmt(cx['range'][0])}–"
                f"{_fmt(cx['range'][1])} (differences within the timing noise, largest ×"
                f"{_fmt(max(cx['ratio_fine'], 1 / cx['ratio_fine'], cx['ratio_coarse'], 1 / cx['ratio_coarse']), 2)}"
                " at the ends): no clear winner.")
    if cx["crossing"] is not None:
        return (head + f"equal cost at error ≈ {_fmt(cx['crossing'])} (crossover); {cx['cheaper_coarse']} is "
                f"cheaper for larger errors, {cx['cheaper_fine']} for smaller.")
    f = max(cx["ratio_fine"], 1 / cx["ratio_fine"])
    c = max(cx["ratio_coarse"], 1 / cx["ratio_coarse"])
    return (head + f"no crossover on the common error range {_fmt(cx['range'][0])}–{_fmt(cx['range'][1])}: "
            f"{cx['cheaper_fine']} is cheaper for the same error throughout (×{_fmt(f, 2)} at the small-error "
            f"end, ×{_fmt(c, 2)} at the large-error end).")


def _interpretations(points, findings, mode) -> list[str]:
    lad = LADDERS[mode]
    out = []
    # measured orders of the midpoint
    for scene, metric, kw in (("bouncing-ball", "rest_time", {}), ("bouncing-ball", "max_q", {}),
                              ("paper-example", "max_q", {}),
                              ("paper-example", "d", dict(min_step=10 * lad["dt_ref_pair"])),
                              ("zeno-table", "max_q", {}), ("grazing", "max_q", {}),
                              ("two-dof", "max_q", {})):
        slope, pts = measured_order(points, scene, metric, "midpoint", **kw)
        if pts:
            findings.setdefault("order", {})[f"{scene}/{metric}"] = slope
            out.append(f"- **Measured order, midpoint, {scene} / {metric}**: slope of log error vs log dt = "
                       f"{_fmt(slope)} ± {_fmt(slope_stderr(pts), 2)} (least squares, dt {pts[0].step:g}–"
                       f"{pts[-1].step:g}, {len(pts)} points).")
    # exact vs midpoint, solve_ivp vs midpoint
    for scene, metric in (("bouncing-ball", "max_q"), ("paper-example", "max_q"), ("zeno-table", "max_q"),
                          ("grazing", "max_q"), ("two-dof", "max_q")):
        mx = midpoint_vs_exact(points, scene, metric)
        if mx is not None:
            findings.setdefault("exact_crossover", {})[scene] = mx
            if mx.get("dt") is not None:
                out.append(f"- **Crossover midpoint / exact, {scene}**: the exact solver ({_fmt(mx['exact_seconds'])} s) "
                           f"is cheaper than a midpoint run with dt < {_fmt(mx['dt'])} s (midpoint error there "
                           f"≈ {_fmt(mx['err'])}).")
            else:
                out.append(f"- **Midpoint / exact, {scene}**: {mx['note']} (exact: {_fmt(mx['exact_seconds'])} s).")
        line = _crossover_line(points, scene, metric, "midpoint", "solve_ivp", findings)
        if line:
            out.append(line)
    # the project's best method against solve_ivp at every error level
    for sc in SCENES:
        n_dof = 2 if sc.system_kw is not None else 1
        for metric in sc.metrics:
            rows = best_vs_ivp(points, sc.name, metric, n_dof)
            if not any(math.isfinite(r[3]) for r in rows):
                continue
            findings.setdefault("best_vs_ivp", {})[f"{sc.name}/{metric}"] = rows
            bad = [r for r in rows if not r[5]]
            cells = ", ".join(f"{_fmt(r[0], 1)}: {r[1]} {_fmt(r[3], 2)} s vs "
                              f"{_fmt(r[4], 2) + ' s' if math.isfinite(r[4]) else 'not reached'}"
                              for r in rows)
            verdict = ("at least as cheap as solve_ivp at every level" if not bad else
                       "NOT cheaper at " + ", ".join(_fmt(r[0], 1) for r in bad))
            out.append(f"- **Best own method vs solve_ivp, {sc.name} / {metric}**: {verdict} "
                       f"(level: cheapest own run with error ≤ level vs cheapest solve_ivp run; {cells}).")
        if sc.pair is not None:
            out.append(f"- **Best own method vs solve_ivp, {sc.name} / d**: solve_ivp is not run on the "
                       "coupled pair (no baseline): no comparison.")
    # co-simulation vs H
    for scene, metric in (("paper-example", "d"), ("bouncing-ball", "rest_time"), ("bouncing-ball", "max_q"),
                          ("paper-example", "max_q")):
        dep = cosim_h_dependence(points, scene, metric)
        if not dep:
            continue
        findings.setdefault("cosim", {})[f"{scene}/{metric}"] = dep
        parts = [f"{m}: slope {_fmt(v['slope'], 2)}" for m, v in dep.items()]
        line = f"- **Co-simulation error vs H, {scene} / {metric}**: " + ", ".join(parts)
        if "cosim" in dep and "cosim-ea" in dep:
            ratios = [dep["cosim"]["errors"][h] / dep["cosim-ea"]["errors"][h]
                      for h in dep["cosim"]["errors"] if h in dep["cosim-ea"]["errors"]
                      and dep["cosim-ea"]["errors"][h] > 0]
            costs = [dep["cosim-ea"]["seconds"][h] / dep["cosim"]["seconds"][h]
                     for h in dep["cosim"]["seconds"] if h in dep["cosim-ea"]["seconds"]]
            if ratios:
                line += (f"; event-aware changes the error by ×{_fmt(1 / statistics.median(ratios), 2)} "
                         f"(median over H, range ×{_fmt(1 / max(ratios), 2)}–×{_fmt(1 / min(ratios), 2)}) "
                         f"at ×{_fmt(statistics.median(costs), 2)} the cost")
        out.append(line + ".")
        for a, b in (("cosim-ea", "cosim"), ("cosim-fine", "cosim"), ("cosim-fine-ea", "cosim-ea")):
            if a in dep and b in dep:
                cl = _crossover_line(points, scene, metric, a, b, findings)
                if cl:
                    out.append(cl)
    # cost of the FMU path
    ratios = []
    for scene in {p.scene for p in points}:
        for p in points:
            if p.scene == scene and p.method == "cosim" and p.metric != "d":
                m = [q for q in points if q.scene == scene and q.metric == p.metric and q.method == "midpoint"
                     and abs(q.step - p.step) < 1e-12]
                if m and m[0].seconds > 0:
                    ratios.append(p.seconds / m[0].seconds)
    if ratios:
        findings["cosim_over_core"] = statistics.median(ratios)
        out.append(f"- **FMU overhead**: an uncoupled co-simulation with slave dt = H gives the same numbers as "
                   f"the core midpoint at dt = H, at ×{_fmt(statistics.median(ratios), 2)} the run time "
                   f"(median over scenes and H; two FMU instances, one master exchange per step).")
    return out


def report(points, mode, seconds) -> tuple[str, dict]:
    findings: dict = {}
    lad = LADDERS[mode]
    lines = [f"## Work–precision ({mode}: medians of up to {lad['repeats']} interleaved repeats, "
             f"{seconds:.0f} s)", ""]
    lines.append("Methods: " + "; ".join(f"`{k}` = {v}" for k, v in METHOD_DOC.items()) + ".")
    lines.append("")
    lines.append("Errors: `max_q` = max |q − q_exact| over the run's output times (exact = core/exact.py, "
                 "core/exact_nd.py for two-dof); "
                 "`rest_time` = |t_rest − t_inf| with t_inf in closed form; `d` = max |d − d_ref| of the "
                 "coupled pair (switching coupling, Kp = 1, Kd = 0.5) on a 10 ms grid, d_ref from "
                 f"`simulate_pair` at dt = {lad['dt_ref_pair']:g} (the exact solver does not apply to a "
                 "coupled pair). Horizons: " + ", ".join(
                     f"{s.name} {horizon(s, mode):g} s"
                     for s in SCENES) + ".")
    lines.append("")
    lines.append("### Findings")
    lines.append("")
    lines += _interpretations(points, findings, mode)
    lines.append("")
    for scene in SCENES:
        for metric in scene.metrics + (("d",) if scene.pair else ()):
            if not any(p.scene == scene.name and p.metric == metric for p in points):
                continue
            lines.append(f"### {scene.name} — {metric}")
            lines.append("")
            lines.append(table(points, scene.name, metric))
            lines.append("")
    return "\n".join(lines) + "\n", findings


def write_csv(points, path) -> None:
    import csv
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(Point.CSV_FIELDS)
        for p in points:
            w.writerow(p.row())


def run(quick: bool = False, fmu=None, progress=None, smoke: bool = False) -> WorkPrecision:
    """Measure every configuration; return the points, the markdown section and the findings."""
    mode = "smoke" if smoke else ("quick" if quick else "full")
    t0 = time.perf_counter()
    points = measure(mode, fmu=fmu, progress=progress)
    seconds = time.perf_counter() - t0
    md, findings = report(points, mode, seconds)
    return WorkPrecision(points, md, findings, quick, seconds)
