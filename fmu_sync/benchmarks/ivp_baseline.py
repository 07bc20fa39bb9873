"""The solve_ivp baseline of the work-precision benchmark: the impact oscillator (and an
n-DOF system, :func:`ivp_impacts_nd`) as most Python users would write it with scipy
(terminal impact event and restart)."""
from __future__ import annotations

import math

import numpy as np

__all__ = ["ivp_impacts", "ivp_impacts_nd"]


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
