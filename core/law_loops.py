"""The loops of a user force law (docs/design.md §2.8): templates, specialised per law.

A user law ``h(q, u, tau, t, p)`` (:class:`fmu_sync.core.forcelaw.ForceLaw`) is compiled into
its own copies of the functions below: :meth:`ForceLaw.kernels` copies each template with a
globals dict in which ``law_h`` is the law's numba function and ``law_force`` evaluates it
into an array (:func:`_force_array` or, for a law returning a float (n = 1),
:func:`_force_scalar`); the templates' calls to each other resolve to the law's copies. So
the law is called *from the compiled step* (inlined by numba into each loop: the same code
an exported stepper compiles in), nothing a scene does not need is computed (no harmonic
table, no linear forces of the built-in law), and each law's copies are cached on disk under
a key of the law (core/_cache.py, :class:`LawLocator`): the user's file content, the law's
name and form, and the core's own stamp.

The step is the one of :func:`fmu_sync.core.steps.step_h` with the state-independent force
replaced by the law at the scheme's force point::

    y   = h(q0 + a u0, u0, tau, t + a, p)                 a = dt/2 (midpoint), θ dt (theta)
    u1  = u0 + dt X y + X w P,   q1 = q0 + dt u0 + a dt X y + a X w P

with ``X = M^-1`` (midpoint) or ``S^-1``, ``S = M + a C_L + a² K_L`` (theta: the law's
declared linear part implicit, the rest explicit at the force point; no linear part: S = M).
For the linear law ``h = f - K q - C u`` this is exactly ``step_h``.

Nothing here is compiled as it stands: the module holds plain functions (the templates).
"""
from __future__ import annotations

import math

import numpy as np

from .coupling import BRANCH_NONE, UNCOUPLED
from .loop import network_forces, sample_d
from .model import SystemArrays
from .moreau import substeps
from .steps import DIVERGED, OK, THETA, flush, flush1, step_y, theta_matrices

#: the names of the templates, in the order they are specialised (each sees all the others)
TEMPLATES = ("_finite", "_iteration", "_node_arrays", "law_step", "law_step1", "_integrate1", "law_integrate",
             "law_advance", "law_network")

#: the templates numba inlines into their callers (no array arguments passed per step)
INLINED = ("law_force", "law_force1", "law_step", "law_step1", "_finite", "_node_arrays", "_iteration")

law_h = None       # the law's numba function, set in each specialised copy's globals
law_force = None   # _force_array or _force_scalar, ditto
law_force1 = None  # _force1_array or _force1_scalar, ditto


def _force_array(qe, u, tau, tf, p, y):
    """y = h(qe, u, tau, tf, p) for a law returning an (n,) array."""
    r = law_h(qe, u, tau, tf, p)
    for i in range(y.shape[0]):
        y[i] = r[i]


def _force_scalar(qe, u, tau, tf, p, y):
    """y[0] = h(qe, u, tau, tf, p) for a 1-DOF law returning a float."""
    y[0] = law_h(qe, u, tau, tf, p)


def _force1_array(qa, ua, ta, tf, p):
    """h[0] for a 1-DOF law returning an array."""
    return law_h(qa, ua, ta, tf, p)[0]


def _force1_scalar(qa, ua, ta, tf, p):
    """h for a 1-DOF law returning a float."""
    return law_h(qa, ua, ta, tf, p)


def law_step1(X, iw, WX, a, w, g0, e, q, u, tf, dt, p, qa, ua, ta):
    """:func:`law_step` for n = 1 on floats (the same arithmetic; ``qa, ua, ta``: the law's
    1-element argument arrays, ``ta`` holding tau). Returns (q, u, P, g)."""
    qa[0] = q + a * u
    ua[0] = u
    y = law_force1(qa, ua, ta, tf, p)
    g = g0
    g += w * (q + (0.5 * dt) * u)
    uf = u + (dt * X) * y
    qn = q + (dt * u + (a * (dt * X)) * y)
    P = 0.0
    if g <= 0.0:
        xi = w * uf + e * (w * u)
        if xi < 0.0:
            P = -xi / WX
            uf += iw * P
            qn = qn + (a * iw) * P
        return flush1(qn), flush1(uf), P, g
    return qn, uf, P, g


def law_step(sa, X, iw, WX, a, q, u, tau, t, dt, p, qe, y, uf):
    """One step of either scheme (module docstring), in place on (q, u); returns (P, g)."""
    n = q.shape[0]
    for i in range(n):
        qe[i] = q[i] + a * u[i]
    law_force(qe, u, tau, t + a, p, y)
    return step_y(sa, X, iw, WX, a, q, u, dt, y, uf)


def _finite(q, u):
    ok = True
    for i in range(q.shape[0]):
        if not (math.isfinite(q[i]) and math.isfinite(u[i])):
            ok = False
    return ok


def _iteration(sa, h, scheme, theta, Sinv, Sinv_w):
    """(X, iw, WX, a) of a step h: M^-1 (midpoint) or S^-1 (theta, S of the linear part)."""
    if scheme == THETA:
        WS = theta_matrices(sa, h, theta, Sinv, Sinv_w)
        return Sinv, Sinv_w, WS, theta * h
    return sa.Minv, sa.Minv_w, sa.W, 0.5 * h


def law_integrate(sa, p, q, u, t0, dt, n_steps, tau, scheme, theta, record_every, T, Qr, Ur, Pr, dt_last):
    """:func:`fmu_sync.core.moreau.integrate` for the law (same records, same returns); a
    1-DOF law runs :func:`_integrate1` instead (chosen when the law is specialised: only the
    loop a law needs is compiled)."""
    n = q.shape[0]
    qe = np.empty(n)
    y = np.empty(n)
    uf = np.empty(n)
    Sinv = np.empty((n, n))
    Sinv_w = np.empty(n)
    X, iw, WX, a = _iteration(sa, dt, scheme, theta, Sinv, Sinv_w)
    T[0] = t0
    Qr[0, :] = q
    Ur[0, :] = u
    Pr[0] = 0.0
    row = 1
    Psum = 0.0
    k = 0
    while k < n_steps:
        m = min(record_every, n_steps - k)
        for i in range(k, k + m):
            P, g = law_step(sa, X, iw, WX, a, q, u, tau, t0 + i * dt, dt, p, qe, y, uf)
            if g <= 0.0:
                flush(q, u)
            Psum += P
        k += m
        flush(q, u)
        if not _finite(q, u):
            return DIVERGED, k, row
        if m == record_every:
            T[row] = t0 + k * dt
            for i in range(n):
                Qr[row, i] = q[i]
                Ur[row, i] = u[i]
            Pr[row] = Psum
            Psum = 0.0
            row += 1
    partial = n_steps % record_every != 0
    if dt_last > 0.0:
        X, iw, WX, a = _iteration(sa, dt_last, scheme, theta, Sinv, Sinv_w)
        P, g = law_step(sa, X, iw, WX, a, q, u, tau, t0 + n_steps * dt, dt_last, p, qe, y, uf)
        Psum += P
        flush(q, u)
        if not _finite(q, u):
            return DIVERGED, n_steps, row
    if dt_last > 0.0 or partial:
        T[row] = t0 + n_steps * dt + dt_last
        for i in range(n):
            Qr[row, i] = q[i]
            Ur[row, i] = u[i]
        Pr[row] = Psum
        row += 1
    return OK, n_steps + (1 if dt_last > 0.0 else 0), row


def _integrate1(sa, p, q_, u_, t0, dt, n_steps, tau, scheme, theta, record_every, T, Qr, Ur, Pr, dt_last):
    """:func:`law_integrate` for n = 1: the state in floats (:func:`law_step1`)."""
    qa = np.empty(1)
    ua = np.empty(1)
    ta = np.empty(1)
    ta[0] = tau[0]
    Sinv = np.empty((1, 1))
    Sinv_w = np.empty(1)
    X, iw, WX, a = _iteration(sa, dt, scheme, theta, Sinv, Sinv_w)
    X0, iw0, w, g0, e = X[0, 0], iw[0], sa.w[0], sa.g0, sa.e
    q = q_[0]
    u = u_[0]
    T[0] = t0
    Qr[0, 0] = q
    Ur[0, 0] = u
    Pr[0] = 0.0
    row = 1
    Psum = 0.0
    k = 0
    while k < n_steps:
        m = min(record_every, n_steps - k)
        for i in range(k, k + m):
            q, u, P, g = law_step1(X0, iw0, WX, a, w, g0, e, q, u, (t0 + i * dt) + a, dt, p, qa, ua, ta)
            Psum += P
        k += m
        q = flush1(q)
        u = flush1(u)
        q_[0] = q
        u_[0] = u
        if not (math.isfinite(q) and math.isfinite(u)):
            return DIVERGED, k, row
        if m == record_every:
            T[row] = t0 + k * dt
            Qr[row, 0] = q
            Ur[row, 0] = u
            Pr[row] = Psum
            Psum = 0.0
            row += 1
    partial = n_steps % record_every != 0
    if dt_last > 0.0:
        X, iw, WX, a = _iteration(sa, dt_last, scheme, theta, Sinv, Sinv_w)
        q, u, P, g = law_step1(X[0, 0], iw[0], WX, a, w, g0, e, q, u, (t0 + n_steps * dt) + a, dt_last, p, qa,
                               ua, ta)
        Psum += P
        q = flush1(q)
        u = flush1(u)
        q_[0] = q
        u_[0] = u
        if not (math.isfinite(q) and math.isfinite(u)):
            return DIVERGED, n_steps, row
    if dt_last > 0.0 or partial:
        T[row] = t0 + n_steps * dt + dt_last
        Qr[row, 0] = q
        Ur[row, 0] = u
        Pr[row] = Psum
        row += 1
    return OK, n_steps + (1 if dt_last > 0.0 else 0), row


def law_advance(sa, p, q, u, t0, H, dt, tau, scheme, theta):
    """:func:`fmu_sync.core.moreau.advance` for the law (zero-order hold of tau): from t0 to
    t0 + H in steps dt, the last one ending exactly on t0 + H. Returns (status, P_sum, impacts)."""
    n = q.shape[0]
    qe = np.empty(n)
    y = np.empty(n)
    uf = np.empty(n)
    Sinv = np.empty((n, n))
    Sinv_w = np.empty(n)
    k_steps = substeps(H, dt)
    X, iw, WX, a = _iteration(sa, dt, scheme, theta, Sinv, Sinv_w)
    Psum = 0.0
    impacts = 0
    for k in range(k_steps):
        t = t0 + k * dt
        hk = dt
        if k == k_steps - 1:
            hk = (t0 + H) - t if k > 0 else H
            if hk != dt:
                X, iw, WX, a = _iteration(sa, hk, scheme, theta, Sinv, Sinv_w)
        P, g = law_step(sa, X, iw, WX, a, q, u, tau, t, hk, p, qe, y, uf)
        if g <= 0.0:
            flush(q, u)
        if P > 0.0:
            impacts += 1
            Psum += P
    flush(q, u)
    if not _finite(q, u):
        return DIVERGED, Psum, impacts
    return OK, Psum, impacts


def _node_arrays(sa, KL, CL, i):
    """The SystemArrays of node i: the common geometry, the node's linear part (theta's S)."""
    return SystemArrays(sa.M, sa.Minv, KL[i], CL[i], sa.f0, sa.F, sa.Omega, sa.phi, sa.B, sa.w, sa.g0, sa.e,
                        sa.Minv_w, sa.W)


def law_network(base, K, C, P, F, Omega, phi, geo, laws, E2, W2, Kp, Kd, q, u, t0, k0, dt,
                n_steps, scheme, theta, record_every, record_d, T, Qr, Ur, TAU, D, BR, EU, dt_last,
                dec, acc, bt, bd, st, imp, ep):
    """:func:`fmu_sync.core.loop.integrate_network` for the law: the same arguments (``K, C``
    (N, n, n) the nodes' linear parts, ``P`` (N, n_p) the nodes' parameters in the slot of f0;
    ``F, Omega, phi`` unused), the same records and returns."""
    N = q.shape[0]
    n = q.shape[1]
    E = E2.shape[0]
    qe = np.empty(n)
    y = np.empty(n)
    uf = np.empty(n)
    ua = np.empty(n)
    Sinv = np.zeros((N, n, n))
    Sinv_w = np.zeros((N, n))
    WS = np.zeros(N)
    tau = np.zeros((N, n))
    t1 = np.zeros(n)
    t2 = np.zeros(n)
    c1q = np.empty(n)
    c1u = np.empty(n)
    c2q = np.empty(n)
    c2u = np.empty(n)
    dk = np.full(E, np.nan)
    bk = np.full(E, BRANCH_NONE)
    ek = np.full(E, np.nan)
    imp[:] = 0
    ep[:] = 0
    last = np.full(N, -2, dtype=np.int64)
    v_imp = 0.0
    tau_max = 0.0
    coupled = False
    for k in range(E):
        if laws[k] != UNCOUPLED:
            coupled = True
    hk = dt
    for i in range(N):
        if scheme == THETA:
            WS[i] = theta_matrices(_node_arrays(base, K, C, i), hk, theta, Sinv[i], Sinv_w[i])
    row = 0
    countdown = 1
    total = n_steps + 1 if dt_last > 0.0 else n_steps
    k = 0
    while True:
        is_row = k == total
        countdown -= 1
        if countdown == 0:
            countdown = record_every
            is_row = True
        need_d = is_row and record_d
        if coupled or need_d:
            network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, need_d, dk, bk, ek)
        r = 0 if dec else row
        if k == 0 and k0 == 0:
            for i in range(N):
                for c in range(n):
                    TAU[0, i, c] = tau[i, c]
        if is_row:
            T[r] = t0 + (k0 + k) * dt if k <= n_steps else t0 + (k0 + n_steps) * dt + dt_last
            ok = True
            for i in range(N):
                for c in range(n):
                    x = q[i, c]
                    v = u[i, c]
                    Qr[r, i, c] = x
                    Ur[r, i, c] = v
                    q[i, c] = flush1(x)
                    u[i, c] = flush1(v)
                    if not (math.isfinite(x) and math.isfinite(v)):
                        ok = False
            if record_d:
                for e_ in range(E):
                    D[r, e_] = dk[e_]
                    BR[r, e_] = bk[e_]
                    EU[r, e_] = ek[e_]
                    if not math.isfinite(dk[e_]):
                        ok = False
            if not ok:
                return DIVERGED, k, row, v_imp, tau_max
            if dec:
                sample_d(acc, bt, bd, st, T[0], dk[0])
            row += 1
        if k == total:
            break
        if (countdown == 1 or k == total - 1) and not dec:
            for i in range(N):
                for c in range(n):
                    TAU[row, i, c] = tau[i, c]
        if dec:
            for i in range(N):
                for c in range(n):
                    if abs(tau[i, c]) > tau_max:
                        tau_max = abs(tau[i, c])
        t = t0 + (k0 + k) * dt
        if k == n_steps:   # the shortened last step
            hk = dt_last
            for i in range(N):
                if scheme == THETA:
                    WS[i] = theta_matrices(_node_arrays(base, K, C, i), hk, theta, Sinv[i], Sinv_w[i])
        for i in range(N):
            for c in range(n):
                ua[c] = u[i, c]
            if scheme == THETA:
                Pc, g = law_step(base, Sinv[i], Sinv_w[i], WS[i], theta * hk, q[i], u[i], tau[i], t, hk, P[i],
                                 qe, y, uf)
            else:
                Pc, g = law_step(base, base.Minv, base.Minv_w, base.W, 0.5 * hk, q[i], u[i], tau[i], t, hk, P[i],
                                 qe, y, uf)
            if g <= 0.0:
                flush(q[i], u[i])
            if Pc > 0.0:
                imp[i] += 1
                if last[i] != k - 1:
                    ep[i] += 1
                last[i] = k
                v = 0.0
                for a_ in range(n):
                    for b_ in range(n):
                        v += ua[a_] * geo.Q[a_, b_] * ua[b_]
                v = math.sqrt(max(v, 0.0))
                if v > v_imp:
                    v_imp = v
        k += 1
    return OK, total, row, v_imp, tau_max
