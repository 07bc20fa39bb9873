"""Independent reference for a 1-DOF user force law (tests only): scipy DOP853 (rtol 1e-12)
of ``M q'' = h(q, q', 0, t, p) + sum_j F_j cos(Omega_j t + phi_j)`` (the law's declared forcing) with a terminal event at g(q) = 0 and a restart after
Newton's impact law u+ = -e u-. The law is evaluated by its plain Python function (not the
compiled loops). Scenarios must impact transversally (no accumulation, no contact phase)."""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp


def reference(system, x0, t_end, rtol=1e-12, max_impacts=10000):
    """``(q, u, impacts)`` at ``t_end`` from ``x0 = (q0, u0)`` at t = 0."""
    law, p = system.force, system.p
    M, w, g0, e = float(system.M[0, 0]), float(system.w[0]), float(system.g0), float(system.e)
    zero = np.zeros(1)
    terms = [(F[0], Om, ph) for F, Om, ph in law.forcing_terms(p)]   # the law's declared forcing

    def f(t, y):
        h = float(np.ravel(law.py_func(np.array([y[0]]), np.array([y[1]]), zero, t, p))[0])
        return [y[1], (h + sum(F * np.cos(Om * t + ph) for F, Om, ph in terms)) / M]

    def gap(t, y):
        return w * y[0] + g0
    gap.terminal, gap.direction = True, -1

    t, y, impacts = 0.0, np.array([float(x0[0]), float(x0[1])]), 0
    while t < t_end:
        sol = solve_ivp(f, (t, t_end), y, method="DOP853", rtol=rtol, atol=1e-14, events=gap)
        t, y = sol.t[-1], sol.y[:, -1].copy()
        if sol.status == 1:   # impact: Newton's law along w
            y[1] = -e * y[1]
            impacts += 1
            if impacts > max_impacts:
                raise RuntimeError("reference: too many impacts (accumulation?)")
    return y[0], y[1], impacts
