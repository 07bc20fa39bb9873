"""A user force law's part of the loops (docs/design.md §2.8): its force, specialised per law.

The loops of one system are the built-in law's own (:mod:`.moreau`: ``integrate_with``,
``integrate1_with``, ``advance_with``, ``advance_in``, the templates of
:data:`fmu_sync.core.moreau.TEMPLATES`) with the force evaluation as their one injected part:
:func:`fmu_sync.core.moreau.force` (n-DOF) and :func:`~fmu_sync.core.moreau.force1` (1-DOF on
floats) for the built-in linear law, :func:`force` and :func:`force1` below for a user law
``h(q, u, tau, t, p)`` (:class:`fmu_sync.core.forcelaw.ForceLaw`). :meth:`ForceLaw.kernels`
copies the templates with globals in which ``force``, ``force1`` are the law's, whose
``law_h`` is the law's numba function (inlined by numba into each loop: the same code an
exported stepper compiles in); each law's copies are cached on disk under a key of the law
(core/_cache.py): the user's file content, the law's name and form, and the core's own stamp.

The step is :func:`fmu_sync.core.steps.step_y` after the force at the scheme's force point::

    y   = h(q0 + a u0, u0, tau, t + a, p) + sum_j F_j cos(Omega_j (t + a) + phi_j)
    u1  = u0 + dt X y + X w P,   q1 = q0 + dt u0 + a dt X y + a X w P

with ``a = dt/2`` (midpoint) or θ dt (theta), ``X = M^-1`` (midpoint) or ``S^-1``,
``S = M + a C_L + a² K_L`` (theta: the law's declared linear part implicit, the rest explicit
at the force point; no linear part: S = M). The harmonic terms are the law's declared
``forcing`` (``ForceLaw(forcing=...)``), evaluated by the loops' own cos or phasor path
(:mod:`.harmonic`) as for the built-in law. For the linear law ``h = f - K q - C u`` this is
the built-in step.

:func:`law_network` is the coupled loop of N systems of one law (:func:`fmu_sync.core.loop.
integrate_network`'s arguments and records). Nothing here is compiled as it stands.
"""
from __future__ import annotations

import math

import numpy as np

from .coupling import BRANCH_NONE, UNCOUPLED
from .harmonic import hsum_cos
from .loop import network_forces, sample_d
from .model import SystemArrays
from .steps import DIVERGED, OK, THETA, flush, flush1, step_y, theta_matrices

#: the law's own functions (plain, specialised per law by :meth:`ForceLaw.kernels`) and their
#: numba ``inline`` option; the loops themselves are the built-in law's templates
#: (:data:`fmu_sync.core.moreau.TEMPLATES`), specialised with this ``force``, ``force1``
OWN = {"law_into": "always", "law_h1": "always", "force": "always", "force1": "always", "_node_arrays": "always",
       "law_network": "never"}

law_h = None      # the law's numba function, set in each specialised copy's globals
law_into = None   # _h_array or _h_scalar, ditto
law_h1 = None     # _h1_array or _h1_scalar, ditto


def _h_array(qe, u, tau, tf, p, y):
    """y = h(qe, u, tau, tf, p) for a law returning an (n,) array."""
    r = law_h(qe, u, tau, tf, p)
    for i in range(y.shape[0]):
        y[i] = r[i]


def _h_scalar(qe, u, tau, tf, p, y):
    """y[0] = h(qe, u, tau, tf, p) for a 1-DOF law returning a float."""
    y[0] = law_h(qe, u, tau, tf, p)


def _h1_array(qa, ua, ta, tf, p):
    """h[0] for a 1-DOF law returning an array."""
    return law_h(qa, ua, ta, tf, p)[0]


def _h1_scalar(qa, ua, ta, tf, p):
    """h for a 1-DOF law returning a float."""
    return law_h(qa, ua, ta, tf, p)


def force(sa, p, q, u, tau, hb, hf, tf, a, y, qe):
    """The law's force at the step's force point, into y (the loops' ``force``,
    :func:`fmu_sync.core.moreau.force`'s signature): ``y = h(q + a u, u, tau, tf, p) + hf``,
    ``hf`` the law's declared harmonic forcing at ``tf`` (cos or phasor path); ``hb`` unused."""
    n = q.shape[0]
    for i in range(n):
        qe[i] = q[i] + a * u[i]
    law_into(qe, u, tau, tf, p, y)
    for i in range(n):
        y[i] += hf[i]


def force1(c, p, q, u, tau, hb, fc, tf, a, qa, ua, ta):
    """:func:`force` for n = 1 on floats (:func:`fmu_sync.core.moreau.force1`'s signature;
    ``qa, ua, ta``: the law's 1-element argument arrays)."""
    qa[0] = q + a * u
    ua[0] = u
    ta[0] = tau
    return law_h1(qa, ua, ta, tf, p) + fc


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
    hf = np.empty(n)
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
    hp = np.zeros((N, 3))   # no built-in force table: the plan refuses 'switching-compensated' with a law
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
            network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, need_d, dk, bk, ek,
                           hp, t0 + (k0 + k) * dt)
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
        a = theta * hk if scheme == THETA else 0.5 * hk
        for i in range(N):
            for c in range(n):
                ua[c] = u[i, c]
            hsum_cos(F[i], Omega[i], phi[i], t + a, hf)
            force(base, P[i], q[i], u[i], tau[i], hf, hf, t + a, a, y, qe)
            if scheme == THETA:
                Pc, g = step_y(base, Sinv[i], Sinv_w[i], WS[i], a, q[i], u[i], hk, y, uf)
            else:
                Pc, g = step_y(base, base.Minv, base.Minv_w, base.W, a, q[i], u[i], hk, y, uf)
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
