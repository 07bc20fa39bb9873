"""The solve_ivp baseline of the work-precision benchmark: the impact oscillator as most
Python users would write it with scipy (terminal impact event and restart)."""
from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

__all__ = ["ivp_impacts"]


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
