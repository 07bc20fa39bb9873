"""Stability report (`fmu-sync report stability`): stiff and extreme cases, each row with a stated pass/fail criterion.

Groups (each a function returning :class:`Row` objects, so that the tests can run the cheap
ones directly):

* :func:`stiff_wall` — k = 1e8 spring behind the wall (omega_max = 1e4), midpoint and
  θ = 0.5 / 1 for dt from 1e-6 to 1e-2. Criterion: the run stays inside the energy bound
  of the initial state (×2 margin), or raises ``SimulationDiverged`` naming dt and
  omega_max·dt. Returning data outside the bound is a failure ("silently wrong data").
* :func:`restitution_limits` — e = 1 (bouncing ball, no forcing/damping: energy drift over
  1e4 impacts; forced elastic oscillator: bounded, impact count vs exact) and e = 0
  (plastic oscillator over 1e4 impacts: every impact ends with u = 0 exactly).
* :func:`zeno_rest_times` — bouncing ball, e = 0.1 … 0.95: rest-time error vs the closed form
  t_inf = t1 + 2 e v1/(g(1-e)); bound 20 dt/(1-e) for Moreau (each resolved bounce shifts by
  O(dt); bounces whose flight is shorter than ~10 dt are lost in the O(dt) penetration, and
  the remaining Zeno tail lasts ~10 dt/(1-e)); 1e-12 t_inf for the exact solver.
* :func:`grazing` — the grazing orbit: position error vs exact, spurious low-speed impacts.
* :func:`coupling_gains` — two unit masses coupled by PD gains (Kp, Kd = ζ√(2Kp), ζ = 0.354
  as in the forced pair), Kp = 1e-2 … 1e6: stability limit of the explicit (zero-order-hold)
  exchange, monolithic (dt) and co-simulated (H, Jacobi and Gauss–Seidel), against the exact
  limit of the ZOH map, h* = ω_c H* = min(4ζ, 1/ζ) (≤ 2, = 2 at ζ = ½), ω_c = sqrt(2 Kp/m).
* :func:`scale_invariance` — the same runs with states scaled by 1e-9 and 1e6.
* :func:`large_step` — dt larger than the forcing period.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .stability_base import G, ZETA, Row, div_ok, fmt3, osc  # noqa: F401
from .stability_coupling import coupling_gains, gauss_seidel_rho, zoh_limit, zoh_rho  # noqa: F401
from .stability_report import grouped_tables, summary, table, write_csv  # noqa: F401

__all__ = ["Row", "stiff_wall", "restitution_limits", "zeno_rest_times", "grazing", "coupling_gains",
           "scale_invariance", "large_step", "zoh_limit", "zoh_rho", "gauss_seidel_rho", "run", "write_csv",
           "table"]


# ===================================================================== stiff wall
STIFF = dict(m=1.0, k=1e8, c=0.0, f0=-1.0, e=0.5)
STIFF_X0 = (1e-6, 0.0)
STIFF_DTS = (1e-6, 1e-5, 1e-4, 2e-4, 1e-3, 1e-2)


def _stiff_bounds():
    """Energy bound of the stiff wall from x0: |q| <= q_b, |u| <= u_b (no forcing, e <= 1, c = 0)."""
    m, k, f0 = STIFF["m"], STIFF["k"], STIFF["f0"]
    q0, u0 = STIFF_X0
    E0 = 0.5 * m * u0 ** 2 + 0.5 * k * q0 ** 2 - f0 * q0
    # 1/2 k q^2 - f0 q = E0: roots
    disc = math.sqrt(f0 ** 2 + 2.0 * k * E0)
    q_b = max(abs((f0 + disc) / k), abs((f0 - disc) / k))
    Emin = -f0 ** 2 / (2.0 * k)
    u_b = math.sqrt(2.0 * (E0 - Emin) / m)
    return q_b, u_b


def stiff_wall(dts=STIFF_DTS, t_end: float = 0.2, schemes=(("midpoint", "midpoint", 0.5),
                                                              ("theta0.5", "theta", 0.5),
                                                              ("theta1", "theta", 1.0))) -> list[Row]:
    from fmu_sync.core import simulate
    from fmu_sync.core import exact_events
    from fmu_sync.core import SimulationDiverged, UnstableScheme
    s = osc(**STIFF)
    wmax = s.omega_max()
    q_b, u_b = _stiff_bounds()
    ev = exact_events(s, STIFF_X0, t_end)
    crit = (f"|q| <= {fmt3(2 * q_b)} and |u| <= {fmt3(2 * u_b)} (2x the energy bound of x0), "
            "or SimulationDiverged naming dt and omega_max*dt")
    rows = []
    for label, scheme, theta in schemes:
        for dt in dts:
            t0 = time.perf_counter()
            setting = f"dt={dt:g} (omega_max*dt={wmax * dt:.3g})"
            try:
                r = simulate(s, STIFF_X0, t_end, dt, scheme=scheme, theta=theta,
                             record_every=max(1, int(round(1e-5 / dt))))
            except (SimulationDiverged, UnstableScheme) as ex:   # diverged, or refused up front
                ok = div_ok(str(ex))
                rows.append(Row("stiff-wall", "k=1e8, f0=-1, e=0.5, x0=(1e-6,0)", label, setting,
                                "SimulationDiverged", str(ex).split(" The ")[0], crit, ok,
                                time.perf_counter() - t0))
                continue
            sec = time.perf_counter() - t0
            q, u = r.q[:, 0], r.u[:, 0]
            finite = bool(np.all(np.isfinite(q)) and np.all(np.isfinite(u)))
            qm, um = float(np.max(np.abs(q))), float(np.max(np.abs(u)))
            ok = finite and qm <= 2 * q_b and um <= 2 * u_b
            qe, _ = ev.state(r.t)
            err = float(np.max(np.abs(q - qe))) if finite else math.nan
            outcome = "bounded" if ok else ("NaN returned" if not finite else
                                            "returned data outside the bound, no error raised")
            rows.append(Row("stiff-wall", "k=1e8, f0=-1, e=0.5, x0=(1e-6,0)", label, setting, outcome,
                            f"max|q|={fmt3(qm)}, max|u|={fmt3(um)}, max|q-q_exact|={fmt3(err)}", crit, ok, sec,
                            value=max(qm / q_b, um / u_b)))
    return rows


# ===================================================================== e = 0 and e = 1
def _onsets(P):
    c = np.asarray(P) > 0.0
    return np.nonzero(c[1:] & ~c[:-1])[0] + 1


def _chunks(system, x0, t_end, dt, chunk=1_000_000):
    """Midpoint run recorded at every step, in chunks (bounded memory).

    Uses the core's compiled loop directly (``kernels_for``): ``simulate`` cannot be
    restarted from a Moreau state that ends in contact, whose O(dt) penetration g < 0 it
    rejects as an initial state. Yields (t, u, q, percussion) per chunk; row 0 of each
    chunk is the last row of the previous one.
    """
    from fmu_sync.core.kernels import DIVERGED, MIDPOINT, kernels_for
    from fmu_sync.core import SimulationDiverged
    from fmu_sync.core.checks import divergence_message
    sa = system.arrays()
    kern = kernels_for(sa)
    q = np.array([x0[0]], dtype=float)
    u = np.array([x0[1]], dtype=float)
    tau = np.zeros(1)
    steps = int(math.floor(t_end / dt + 1e-9))
    done = 0
    while done < steps:
        k = min(chunk, steps - done)
        T = np.empty(k + 1)
        Q = np.empty((k + 1, 1))
        U = np.empty((k + 1, 1))
        P = np.empty(k + 1)
        status, _, _ = kern(sa, q, u, done * dt, dt, k, tau, MIDPOINT, 0.5, 1, T, Q, U, P, False, 0.0)
        if status == DIVERGED:
            raise SimulationDiverged(divergence_message(system, "midpoint", dt, (done + k) * dt))
        done += k
        yield T, U[:, 0], Q[:, 0], P


def restitution_limits(n_impacts: int = 10_000, dt: float = 1e-3) -> list[Row]:
    from fmu_sync.core import simulate
    from fmu_sync.core import exact_events
    rows = []

    # --- e = 1, bouncing ball (no forcing, no damping): energy conserved?
    q0 = 1.0
    period = 2.0 * math.sqrt(2.0 * q0 / G)
    T = (n_impacts + 0.5) * period
    for label, scheme, theta in (("midpoint", "midpoint", 0.5), ("theta0.5", "theta", 0.5),
                                 ("theta1", "theta", 1.0)):
        s = osc(m=1.0, k=0.0, c=0.0, f0=-G, e=1.0)
        t0 = time.perf_counter()
        r = simulate(s, (q0, 0.0), T, dt, scheme=scheme, theta=theta, record_every=10)
        sec = time.perf_counter() - t0
        E = 0.5 * r.u[:, 0] ** 2 + G * r.q[:, 0]
        fluct = float(np.max(np.abs(E - E[0])) / E[0])
        w = max(1, E.size // 10)
        drift = float(abs(np.median(E[-w:]) - np.median(E[:w])) / E[0])
        n = _onsets(r.percussion).size
        ev = exact_events(s, (q0, 0.0), T)
        ok = drift <= 1e-9 and abs(n - ev.n_impacts) <= 0.01 * ev.n_impacts
        rows.append(Row("restitution", "e=1 bouncing ball (no forcing, no damping)", label,
                        f"dt={dt:g}, T={T:.0f} s", "no energy drift" if drift <= 1e-9 else "energy drifts",
                        f"impacts {n} (exact {ev.n_impacts}), secular drift {drift:.1e}, "
                        f"max|E-E0|/E0 {fluct:.1e}",
                        "secular energy drift (median of E over the last vs the first 10 % of the run) "
                        "<= 1e-9 E0, impact count within 1 % of exact", ok, sec, value=drift))

    # --- e = 1, forced elastic oscillator (the built-in "elastic" scene): bounded, impact count
    s = osc(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=1.0)
    ev_probe = exact_events(s, (1.0, 0.0), 2000.0)
    rate = max(ev_probe.n_impacts, 1) / 2000.0
    T = n_impacts / rate
    ev = exact_events(s, (1.0, 0.0), T)
    qmax_ex = float(np.max(np.abs(ev.state(np.linspace(0, T, 200_001))[0])))
    t0 = time.perf_counter()
    r = simulate(s, (1.0, 0.0), T, dt, record_every=10, scheme="midpoint")
    sec = time.perf_counter() - t0
    n = _onsets(r.percussion).size
    qm = float(np.max(np.abs(r.q)))
    ok = qm <= 2 * qmax_ex and abs(n - ev.n_impacts) <= 0.02 * ev.n_impacts
    rows.append(Row("restitution", "e=1 forced (elastic scene)", "midpoint", f"dt={dt:g}, T={T:.0f} s",
                    "bounded" if qm <= 2 * qmax_ex else "unbounded",
                    f"impacts {n} (exact {ev.n_impacts}), max|q|={fmt3(qm)} (exact {fmt3(qmax_ex)})",
                    "max|q| <= 2x exact and impact count within 2 % of exact", ok, sec, value=n / ev.n_impacts))

    # --- e = 0, plastic oscillator (the built-in "plastic" scene): no rebound, 1e4 impacts
    s = osc(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.0)
    ev_probe = exact_events(s, (1.0, 0.0), 2000.0)
    rate = max(ev_probe.n_impacts, 1) / 2000.0
    T = n_impacts / rate
    ev = exact_events(s, (1.0, 0.0), T)
    t0 = time.perf_counter()
    n = 0
    rebound = 0.0
    qmin, qmax = math.inf, -math.inf
    prevP = 0.0
    for Tc, Uc, Qc, Pc in _chunks(s, (1.0, 0.0), T, dt):
        P = Pc.copy()
        P[0] = prevP                 # row 0 repeats the previous chunk's last state
        on = _onsets(P)
        n += on.size
        if on.size:
            rebound = max(rebound, float(np.max(np.abs(Uc[on]))))
        qmin = min(qmin, float(Qc.min()))
        qmax = max(qmax, float(Qc.max()))
        prevP = float(Pc[-1])
    sec = time.perf_counter() - t0
    ok = rebound == 0.0 and abs(n - ev.n_impacts) <= 0.01 * ev.n_impacts and qmax <= 2.0
    rows.append(Row("restitution", "e=0 forced (plastic scene)", "midpoint", f"dt={dt:g}, T={T:.0f} s",
                    "no rebound" if rebound == 0.0 else "rebound",
                    f"impacts {n} (exact {ev.n_impacts}), max|u| after impact step={rebound:.1e}, "
                    f"min q={qmin:.2e} (penetration), max q={fmt3(qmax)}",
                    "u = 0 exactly after every impact step, impact count within 1 % of exact, bounded",
                    ok, sec, value=n / max(ev.n_impacts, 1)))
    return rows


# ===================================================================== Zeno
ZENO_ES = (0.1, 0.3, 0.5, 0.7, 0.8, 0.9, 0.95)


def zeno_rest_times(es=ZENO_ES, dts=(1e-3, 1e-4), q0: float = 1.0) -> list[Row]:
    from fmu_sync.core import simulate
    from fmu_sync.core import exact_events
    from .work_precision_cases import closed_form_rest_time, rest_time_of
    rows = []
    for e in es:
        p = dict(m=1.0, k=0.0, c=0.0, f0=-G, e=e)
        t_inf = closed_form_rest_time(p, q0)
        s = osc(**p)
        T = t_inf + 1.0
        t0 = time.perf_counter()
        ev = exact_events(s, (q0, 0.0), T)
        sec = time.perf_counter() - t0
        te = float(ev.zeno_times[0]) if ev.zeno_times.size else math.nan
        err = abs(te - t_inf)
        rows.append(Row("zeno", f"bouncing ball e={e:g} (t_inf={t_inf:.4f} s)", "exact", "-",
                        "accumulation completed" if math.isfinite(te) else "no accumulation point",
                        f"|t_rest - t_inf| = {err:.1e} s ({ev.n_impacts} impacts resolved)",
                        "|t_rest - t_inf| <= 1e-12 t_inf", err <= 1e-12 * t_inf, sec, value=err))
        v_tol = 1e-6 * math.sqrt(2 * G * q0)
        for dt in dts:
            t0 = time.perf_counter()
            r = simulate(s, (q0, 0.0), T, dt, scheme="midpoint")
            sec = time.perf_counter() - t0
            tr = rest_time_of(r.t, r.u[:, 0], v_tol)
            err = abs(tr - t_inf)
            bound = 20.0 * dt / (1.0 - e)
            rows.append(Row("zeno", f"bouncing ball e={e:g} (t_inf={t_inf:.4f} s)", "midpoint", f"dt={dt:g}",
                            "rests" if math.isfinite(tr) else "never rests",
                            f"|t_rest - t_inf| = {err:.2e} s = {err / dt:.1f} dt",
                            f"<= 20 dt/(1-e) = {bound:.2e} s", bool(err <= bound), sec, value=err / dt))
    return rows


# ===================================================================== grazing
GRAZING = dict(m=1.0, k=1.0, c=0.0, f0=0.4, F=0.3, Omega=0.5, e=0.8)


def grazing(dts=(1e-3, 1e-4), t_end: float = 60.0) -> list[Row]:
    from fmu_sync.core import simulate
    from fmu_sync.core import exact_events
    s = osc(**GRAZING)
    x0 = (0.8, 0.0)
    t0 = time.perf_counter()
    ev = exact_events(s, x0, t_end)
    sec = time.perf_counter() - t0
    expect = int(math.floor((t_end - 2 * math.pi) / (4 * math.pi))) + 1 if t_end >= 2 * math.pi else 0
    rows = [Row("grazing", "grazing orbit q = 0.4 + 0.4 cos(t/2)", "exact", f"T={t_end:g} s",
                f"{ev.graze_times.size} grazings, {ev.n_impacts} impacts",
                "graze times " + ", ".join(f"{t:.4f}" for t in ev.graze_times[:5]),
                f"0 impacts and {expect} grazings (at 2π + 4πk)",
                ev.n_impacts == 0 and ev.graze_times.size == expect, sec, value=ev.graze_times.size)]
    v_ref = 0.2                  # max speed on the orbit (0.4 * 0.5)
    a_ref = 1.5                  # bound of the free acceleration |-q + 0.4 + 0.3 cos| on the orbit
    for label, scheme, theta in (("midpoint", "midpoint", 0.5), ("theta0.5", "theta", 0.5),
                                 ("theta1", "theta", 1.0)):
        for dt in dts:
            t0 = time.perf_counter()
            r = simulate(s, x0, t_end, dt, scheme=scheme, theta=theta)
            sec = time.perf_counter() - t0
            qe, _ = ev.state(r.t)
            err = float(np.max(np.abs(r.q[:, 0] - qe)))
            pmax = float(r.percussion.max())
            n = _onsets(r.percussion).size
            ok = err <= 5 * v_ref * dt and pmax <= (1 + s.e) * s.M[0, 0] * a_ref * dt
            rows.append(Row("grazing", "grazing orbit q = 0.4 + 0.4 cos(t/2)", label, f"dt={dt:g}",
                            f"{n} spurious impacts" if n else "no impact",
                            f"max|q-q_exact|={err:.2e}, max percussion={pmax:.1e}",
                            f"error <= 5 v_ref dt = {5 * v_ref * dt:.1e}, percussion <= (1+e) m a_max dt "
                            f"= {(1 + s.e) * a_ref * dt:.1e}", ok, sec, value=err))
    return rows




# ===================================================================== scale invariance
SCALES = (1e-9, 1.0, 1e6)


def scale_invariance(scales=SCALES, dt: float = 1e-3, fmu=None, tol: float = 1e-6) -> list[Row]:
    """Relative errors of runs whose states (and forces) are scaled by s: must not depend on s."""
    from fmu_sync.core import simulate
    from fmu_sync.core import exact_events, simulate_exact
    from fmu_sync.core import simulate_pair
    from .work_precision_cases import closed_form_rest_time, rest_time_of

    def ball(sc):
        return dict(m=1.0, k=0.0, c=0.0, f0=-G * sc, e=0.8), (sc, 0.0), 5.0

    def forced_pair(sc):
        return dict(m=1.0, k=1.0, c=0.0, f0=0.2 * sc, F=0.5 * sc, Omega=2.5, e=0.9), (sc, 0.0), 20.0

    cases = {}
    for sc in scales:
        out = {}
        p, x0, T = ball(sc)
        s = osc(**p)
        ev = exact_events(s, x0, T)
        r = simulate(s, x0, T, dt, scheme="midpoint")
        qe, _ = ev.state(r.t)
        out[("bouncing ball", "midpoint", "max|q-q_exact|/s")] = float(np.max(np.abs(r.q[:, 0] - qe))) / sc
        t_inf = closed_form_rest_time(dict(p, f0=-G, m=1.0), 1.0)      # time scale is unchanged
        out[("bouncing ball", "midpoint", "|t_rest - t_inf| (s)")] = abs(rest_time_of(r.t, r.u[:, 0], 1e-6 * math.sqrt(2 * G) * sc)
                                                       - t_inf)
        out[("bouncing ball", "exact", "|t_rest - t_inf|/t_inf")] = abs(float(ev.zeno_times[0]) - t_inf) / t_inf
        p, x0, T = forced_pair(sc)
        s = osc(**p)
        ev = exact_events(s, x0, T)
        for label, scheme, theta in (("midpoint", "midpoint", 0.5), ("theta1", "theta", 1.0)):
            r = simulate(s, x0, T, dt, scheme=scheme, theta=theta)
            qe, _ = ev.state(r.t)
            out[("forced pair", label, "max|q-q_exact|/s")] = float(np.max(np.abs(r.q[:, 0] - qe))) / sc
        rx = simulate_exact(s, x0, T, dt)
        out[("forced pair", "exact", "q(T)/s")] = float(rx.q[-1, 0]) / sc
        rp = simulate_pair(s, x0, (0.2 * sc, 0.5 * sc), 10.0, dt, coupling="switching", Kp=1.0, Kd=0.5,
                           record_every=10, scheme="midpoint")
        out[("forced pair, coupled pair (switching)", "simulate_pair midpoint", "max d/s, d(T)/s")] = (float(np.max(rp.d)) / sc, float(rp.d[-1]) / sc)
        if fmu is not None:
            from fmu_sync import SlaveError, cosimulate
            from fmu_sync.fmus.contract import MODELS
            io = MODELS["impact-oscillator"]
            sv = {**io.values(s), **io.solver_values(dt)}
            try:
                rc = cosimulate(fmu, x0, (0.2 * sc, 0.5 * sc), 10.0, 0.01, coupling="switching", Kp=1.0,
                                Kd=0.5, start_values=sv, record_every=10)
            except SlaveError as exc:
                rc = exc.partial
            out[("forced pair, coupled pair (switching)", "co-simulation H=0.01", "max d/s, d(T)/s")] = (
                (float(np.max(rc.d)) / sc, float(rc.d[-1]) / sc) if not rc.error else (math.nan, math.nan))
        cases[sc] = out
    rows = []
    ref = cases[1.0] if 1.0 in cases else cases[scales[0]]
    for key in ref:
        for sc in scales:
            if sc == 1.0:
                continue
            a, b = cases[sc][key], ref[key]
            a = np.atleast_1d(np.asarray(a, dtype=float))
            b = np.atleast_1d(np.asarray(b, dtype=float))
            if key[2] == "|t_rest - t_inf|/t_inf":
                dev = float(np.max(a))
                ok = dev <= 1e-12
                crit = "|t_rest - t_inf| / t_inf <= 1e-12 at every scale"
            else:
                dev = float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300)))
                ok = bool(np.all(np.isfinite(a))) and dev <= tol
                crit = f"relative deviation from the s = 1 value <= {tol:g}"
            rows.append(Row("scale", key[0], key[1], f"s={sc:g}: {key[2]}",
                            "scale-invariant" if ok else "depends on scale",
                            f"value {', '.join(f'{x:.6g}' for x in a)} (s=1: {', '.join(f'{x:.6g}' for x in b)}), "
                            f"deviation {dev:.1e}", crit, ok, value=dev))
    return rows


# ===================================================================== large steps
def large_step(dts=(1.0, 3.0, 7.0), t_end: float = 2000.0) -> list[Row]:
    """dt larger than the forcing period: bounded (no secular growth) or SimulationDiverged."""
    from fmu_sync.core import simulate
    from fmu_sync.core import exact_events
    from fmu_sync.core import SimulationDiverged, UnstableScheme
    rows = []
    for name, p, x0 in (("forced-pair (period 2.51 s, omega_max = 1)",
                         dict(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9), (1.0, 0.0)),
                        ("zeno-table (period 2.09 s, k = 0)",
                         dict(m=1.0, k=0.0, c=0.0, f0=-1.0, F=2.0, Omega=3.0, e=0.5), (0.0, 0.0))):
        s = osc(**p)
        ev = exact_events(s, x0, t_end)
        qex = float(np.max(np.abs(ev.state(np.linspace(0.0, t_end, 400_001))[0])))
        period = 2 * math.pi / p["Omega"]
        for label, scheme, theta in (("midpoint", "midpoint", 0.5), ("theta0.5", "theta", 0.5),
                                     ("theta1", "theta", 1.0)):
            for dt in dts:
                setting = f"dt={dt:g} = {dt / period:.2f} forcing periods (omega_max*dt={s.omega_max() * dt:.3g})"
                crit = ("finite, no secular growth (max|q| over the 2nd half <= 2x the 1st half), "
                        "or SimulationDiverged naming dt and omega_max*dt; accuracy not expected")
                t0 = time.perf_counter()
                try:
                    r = simulate(s, x0, t_end, dt, scheme=scheme, theta=theta)
                except (SimulationDiverged, UnstableScheme) as ex:
                    rows.append(Row("large-dt", name, label, setting, "SimulationDiverged",
                                    str(ex).split(" The ")[0], crit, div_ok(str(ex)), time.perf_counter() - t0))
                    continue
                sec = time.perf_counter() - t0
                q = r.q[:, 0]
                h = q.size // 2
                finite = bool(np.all(np.isfinite(q)))
                a1, a2 = float(np.max(np.abs(q[:h]))), float(np.max(np.abs(q[h:])))
                ok = finite and a2 <= 2 * a1
                qe, _ = ev.state(r.t)
                rows.append(Row("large-dt", name, label, setting, "bounded" if ok else "grows",
                                f"max|q| {fmt3(max(a1, a2))} (exact {fmt3(qex)}), max|q-q_exact| "
                                f"{fmt3(float(np.max(np.abs(q - qe))))}: aliased forcing, no warning given",
                                crit, ok, sec, value=max(a1, a2) / qex))
    return rows


# ===================================================================== report
def run(quick: bool = False, fmu=None, progress=None, smoke: bool = False):
    """All groups; returns (rows, markdown)."""
    t_start = time.perf_counter()
    if smoke:
        plan = [
            ("stiff wall", lambda: stiff_wall(dts=(1e-5, 1e-3, 1e-2), t_end=0.02)),
            ("e = 0 / e = 1", lambda: restitution_limits(n_impacts=200)),
            ("Zeno", lambda: zeno_rest_times(es=(0.5, 0.9), dts=(1e-3,))),
            ("grazing", lambda: grazing(dts=(1e-3,), t_end=20.0)),
            ("coupling gains", lambda: coupling_gains(kps=(1.0,), fmu=fmu, methods=("jacobi",), n_steps=200,
                                                      iters=6, tol=0.05, divergence_check=False)),
            ("scales", lambda: scale_invariance(fmu=None)),
            ("large dt", lambda: large_step(dts=(3.0,), t_end=200.0)),
        ]
    else:
        plan = [
            ("stiff wall", lambda: stiff_wall()),
            ("e = 0 / e = 1", lambda: restitution_limits(n_impacts=10_000)),
            ("Zeno", lambda: zeno_rest_times()),
            ("grazing", lambda: grazing()),
            ("coupling gains", lambda: coupling_gains(
                fmu=fmu, cosim_kps=(1e-2, 1.0, 1e6) if quick else None,
                methods=("jacobi", "gauss-seidel"),
                n_steps=200 if quick else 400, iters=8 if quick else 10)),
            ("scales", lambda: scale_invariance(fmu=fmu)),
            ("large dt", lambda: large_step(t_end=2000.0 if quick else 20000.0)),
        ]
    rows = []
    for i, (name, fn) in enumerate(plan):
        rows += fn()
        if progress is not None:
            progress((i + 1) / len(plan))
    seconds = time.perf_counter() - t_start
    mode = "smoke" if smoke else ("quick" if quick else "full")
    md = ["## Stability on stiff and extreme cases", "", f"Mode {mode}, {seconds:.0f} s.", "",
          "Every row states its criterion; a divergence must be reported as an error "
          "(`SimulationDiverged` in the core, `SlaveError` with the partial record in co-simulation), never returned as data.",
          "", "### Findings", ""] + summary(rows) + ["", grouped_tables(rows), ""]
    return rows, "\n".join(md) + "\n"
