"""Independent high-accuracy reference for n-DOF impacting systems (tests only):
scipy DOP853 (rtol 1e-13) with event restarts at g = 0, the impact map, and, for
accumulations, a velocity cut-off followed by the constrained (contact) ODE with
an event on the contact force lambda = 0 (release). Events are detected at
step ends only: a shallow dip below the wall needs ``max_step`` below its width."""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp


def reference(system, x0, t_eval, tau=None, taudot=None, t_c=0.0, v_cut=1e-6, rtol=1e-13,
              max_step=np.inf):
    sa = system.arrays()
    n = system.n
    Minv, K, C, w, g0, e, W = sa.Minv, sa.K, sa.C, sa.w, sa.g0, sa.e, sa.W
    iw = sa.Minv_w
    tau = np.zeros(system.n_inputs) if tau is None else np.asarray(tau, float)
    taudot = np.zeros(system.n_inputs) if taudot is None else np.asarray(taudot, float)

    def h(t, q, u):
        f = sa.f0 + sa.B @ (tau + taudot * (t - t_c)) - K @ q - C @ u
        for F, Om, ph in zip(sa.F, sa.Omega, sa.phi):
            f = f + F * np.cos(Om * t + ph)
        return f

    def free(t, y):
        q, u = y[:n], y[n:]
        return np.concatenate([u, Minv @ h(t, q, u)])

    def lam(t, y):
        q, u = y[:n], y[n:]
        return -(w @ (Minv @ h(t, q, u))) / W

    def contact(t, y):
        q, u = y[:n], y[n:]
        a = Minv @ h(t, q, u)
        a = a - iw * (w @ a) / W
        return np.concatenate([u, a])

    def gap(t, y):
        return w @ y[:n] + g0
    gap.terminal, gap.direction = True, -1

    def release(t, y):
        return lam(t, y)
    release.terminal, release.direction = True, -1

    t = float(t_eval[0])
    y = np.concatenate([np.atleast_1d(np.asarray(x0[0], float)), np.atleast_1d(np.asarray(x0[1], float))])
    out = np.empty((t_eval.size, 2 * n))
    filled = 0
    mode = "free"
    log = []
    for _ in range(100000):
        te = t_eval[(t_eval > t) if filled else (t_eval >= t)]
        if mode == "free":
            sol = solve_ivp(free, (t, t_eval[-1]), y, method="DOP853", rtol=rtol, atol=1e-15, max_step=max_step,
                            events=gap, t_eval=te if te.size else [t_eval[-1]])
        else:
            sol = solve_ivp(contact, (t, t_eval[-1]), y, method="DOP853", rtol=rtol, atol=1e-15, max_step=max_step,
                            events=release, t_eval=te if te.size else [t_eval[-1]])
        assert sol.status >= 0, (sol.message, t, mode, log[-3:])
        if te.size:
            k = np.asarray(sol.y).reshape(2 * n, -1).shape[1]
            out[filled:filled + k] = np.asarray(sol.y).reshape(2 * n, -1).T
            filled += k
        if sol.status != 1:
            break
        t = float(sol.t_events[0][0])
        y = sol.y_events[0][0].copy()
        if mode == "free":
            vm = w @ y[n:]
            if vm >= 0.0:        # round-off crossing at a restart: no impact (see the re-arm below)
                continue
            y[n:] = y[n:] - (1 + e) * iw * vm / W
            log.append(("impact", t, vm))
            vp = -e * vm
            if vp < v_cut and lam(t, y) > 0:
                y[n:] = y[n:] - iw * (w @ y[n:]) / W
                mode = "contact"
                log.append(("contact", t))
            elif vp > 0:
                # re-arm the event only after a quarter of the coming flight (2 v+ / |a_w|):
                # near the wall g is at round-off level and the event would fire again at once
                aw = w @ (Minv @ h(t, y[:n], y[n:]))
                hop = min(0.5 * vp / max(-aw, 1e-300), 1e-3) if aw < 0 else 1e-9
                te = t_eval[(t_eval > t) & (t_eval <= t + hop)]
                sol = solve_ivp(free, (t, t + hop), y, method="DOP853", rtol=rtol, atol=1e-15,
                                t_eval=np.concatenate([te, [t + hop]]))
                k = te.size
                out[filled:filled + k] = sol.y[:, :k].T
                filled += k
                t, y = t + hop, sol.y[:, -1].copy()
        else:
            mode = "free"
            log.append(("release", t))
    assert filled == t_eval.size, (filled, t_eval.size, t, mode, log[-5:])
    return out, log
