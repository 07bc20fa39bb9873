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
(core/_cache.py): what numba compiles of h (core/law_key.py), its name and form, and the core's own stamp.

The step is :func:`fmu_sync.core.steps.step_y` after the force at the scheme's force point::

    y   = h(q0 + a u0, u0, tau, t + a, p) + sum_j F_j cos(Omega_j (t + a) + phi_j)
    u1  = u0 + dt X y + X w P,   q1 = q0 + dt u0 + a dt X y + a X w P

with ``a = dt/2`` (midpoint) or θ dt (theta), ``X = M^-1`` (midpoint) or ``S^-1``,
``S = M + a C_L + a² K_L`` (theta: the law's declared linear part implicit, the rest explicit
at the force point; no linear part: S = M). The harmonic terms are the law's declared
``forcing`` (``ForceLaw(forcing=...)``), evaluated by the loops' own cos or phasor path
(:mod:`.harmonic`) as for the built-in law. For the linear law ``h = f - K q - C u`` this is
the built-in step.

The coupled loop of N systems (:func:`fmu_sync.core.loop.integrate_network`: pair, networks,
run-by-run sweeps) is a template the same way, its node force ``net_force``/``net_force1`` the
one injected part (:func:`net_force`, :func:`net_force1` below: the node's parameters ``P[i]``
in the slot of f0). Nothing here is compiled as it stands.
"""
from __future__ import annotations

import numpy as np

from .steps import inverse   # noqa: F401 (a global of the specialised copies: the n-DOF correction's S^-1)

#: the law's own functions (plain, specialised per law by :meth:`ForceLaw.kernels`) and their
#: numba ``inline`` option; the loops themselves are the built-in law's templates
#: (:data:`fmu_sync.core.moreau.TEMPLATES`, :data:`fmu_sync.core.loop.TEMPLATES`), specialised
#: with this ``force``, ``force1``, ``net_force``, ``net_force1``
OWN = {"law_into": "always", "law_h1": "always", "heun": "always", "force": "always", "force1": "always",
       "net_force": "always", "net_force1": "always"}

law_h = None      # the law's numba function, set in each specialised copy's globals
law_into = None   # _h_array or _h_scalar, ditto
law_h1 = None     # _h1_array or _h1_scalar, ditto
#: the trapezoid's copies (``ForceLaw.kernels(trapezoid=True)``): the explicit part of h corrected at the
#: step's middle velocity (:func:`heun`), a constant of each copy (numba prunes the branch elsewhere)
HEUN = False


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
    ``hf`` the law's declared harmonic forcing at ``tf`` (cos or phasor path); ``hb`` unused.
    The trapezoid's copies (:data:`HEUN`) correct it at the step's middle velocity (:func:`heun`)."""
    n = q.shape[0]
    for i in range(n):
        qe[i] = q[i] + a * u[i]
    law_into(qe, u, tau, tf, p, y)
    for i in range(n):
        y[i] += hf[i]
    if HEUN:
        heun(sa, p, u, tau, hf, tf, a, y, qe)


def heun(sa, p, u, tau, hf, tf, a, y, qe):
    """The trapezoid's second evaluation (n-DOF; docs/design.md §2.8.1): with ``y0`` (in y) the force
    at the step's start velocity u0, the middle velocity ``ub = u0 + a X y0`` (X = S^-1 of the step,
    ``a = dt/2``) and ``y = h(qe, ub, tau, tf, p) + hf + C_L (ub - u0)``: the law's declared linear
    part stays in S (its u0 value, as without the correction), the rest is taken at ub, which is
    u(t + dt/2) to O(dt^2): the force of the midpoint rule, so the step is second order."""
    n = u.shape[0]
    S = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            S[i, j] = sa.M[i, j] + a * sa.C[i, j] + a * a * sa.K[i, j]
    X = inverse(S)
    ub = np.empty(n)
    for i in range(n):
        s = u[i]
        for j in range(n):
            s += (a * X[i, j]) * y[j]
        ub[i] = s
    law_into(qe, ub, tau, tf, p, y)
    for i in range(n):
        c = hf[i]
        for j in range(n):
            c += sa.C[i, j] * (ub[j] - u[j])
        y[i] += c


def force1(c, p, q, u, tau, hb, fc, tf, a, qa, ua, ta):
    """:func:`force` for n = 1 on floats (:func:`fmu_sync.core.moreau.force1`'s signature;
    ``qa, ua, ta``: the law's 1-element argument arrays). The trapezoid's copies (:data:`HEUN`):
    :func:`heun` on floats, ``X = c[2] / dt`` (``c[2] = dt X``, ``a = dt/2``), ``C_L = c[1] - a c[0]``."""
    qa[0] = q + a * u
    ua[0] = u
    ta[0] = tau
    y = law_h1(qa, ua, ta, tf, p) + fc
    if HEUN:
        ub = u + 0.5 * (c[2] * y)
        ua[0] = ub
        y = law_h1(qa, ua, ta, tf, p) + (fc + (c[1] - a * c[0]) * (ub - u))
    return y


def net_force(sa, P, i, q, u, tau, hf, tf, a, y, qe):
    """Node i's force in the coupled loop (n > 1; :func:`fmu_sync.core.loop.net_force`'s
    signature): :func:`force` with the node's parameters ``P[i]``."""
    force(sa, P[i], q, u, tau, hf, hf, tf, a, y, qe)


def net_force1(cf, P, f01, i, q, u, tau, B0, fc, tf, a, qa, ua, ta):
    """:func:`net_force` for n = 1 on floats (:func:`fmu_sync.core.loop.net_force1`'s signature)."""
    return force1(cf, P[i], q, u, tau, fc, fc, tf, a, qa, ua, ta)


#: a 1-DOF law's copy of the coupled loop (:meth:`fmu_sync.core.forcelaw.ForceLaw.kernels`, n = 1) compiles
#: only what it runs: the n > 1 node steps of :mod:`.loop`, unreachable there (q has one column, the law's n),
#: are these stand-ins of the same signature and return type (a law's loop compiles in about 0.6 of the time
#: with the 1-DOF solves compiled once as calls, docs/design.md "The test suite")
N1_STANDINS = {"_step_node": "_n1_step_node", "_free_nodes": "_n1_free_nodes", "_solved_nodes": "_n1_solved_nodes"}


def _n1_step_node(base, K, C, f0, F, Omega, phi, i, q, u, tau, t, hk, scheme, theta, Sinv, Sinv_w, WS, y, hf, uf,
                  ua, qe):
    """:func:`fmu_sync.core.loop._step_node`'s stand-in in a 1-DOF law's loop (never called there)."""
    return 0.0


def _n1_free_nodes(base, K, C, f0, F, Omega, phi, q, u, tau, t, hk, theta, Sinv, y, hf, qe, ws):
    """:func:`fmu_sync.core.loop._free_nodes`'s stand-in in a 1-DOF law's loop (never called there)."""
    return None


def _n1_solved_nodes(base, K, C, f0, F, Omega, phi, q, u, tau, t, hk, theta, Sinv, Sinv_w, WS, y, hf, uf, qe, ws,
                     k, imp, ep, last, Q, zero, v_imp):
    """:func:`fmu_sync.core.loop._solved_nodes`'s stand-in in a 1-DOF law's loop (never called there)."""
    return v_imp
