"""The exact solver's communication step (docs/design.md §2.3, §4.3): the 1-DOF
event-driven solution over one step ``[t, t + H]`` with the input constant over it,
as the FMU slave's internal solver (``solver.scheme = exact``) and, with
``early``, stopping at the first impact (an FMI 3.0 early return).

Plain arrays and floats only, so that the FMU's compiled stepper (numba) calls it:
the system is packed once into one float64 array (:func:`exact_model`).
"""
from __future__ import annotations

import numpy as np
from .jit import njit

from .exact_flow import EPS, NPRM, NT, P_F0, P_S0, flow_model
from .exact_run import IMPACT_EV, run_events, sample, vref_start
from .model import MechanicalSystem

__all__ = ["NT", "exact_model", "exact_step", "exact_step_early", "STEP_OK", "STEP_TOO_MANY_EVENTS",
           "STEP_NO_PROGRESS"]

#: layout of the packed model (:func:`exact_model`)
_M_NH, _M_NIN, _M_W, _M_G0, _M_PRM = 0, 1, 2, 3, 4
_M_RC = _M_PRM + NPRM
_M_ROOTS = _M_RC + NT
_M_SB = _M_ROOTS + 4

#: exact_step status codes
STEP_OK, STEP_TOO_MANY_EVENTS, STEP_NO_PROGRESS = 0, 1, 2


def exact_model(system: MechanicalSystem) -> np.ndarray:
    """The 1-DOF system packed into one float64 array for :func:`exact_step`.

    Layout: ``[nh, n_inputs, w, g0, prm (16), rc (28), roots (re, im, re, im), sB (n_inputs),
    then per harmonic term j < nh: s_j, Omega_j, phi_j, Yc series (28), Ys series (28)]``
    with ``prm`` for ``tau = 0`` and ``sB = w B / m`` (the gap acceleration per
    unit input). Raises ValueError for n != 1.
    """
    md = flow_model(system, np.zeros(system.n_inputs))
    sa = system.arrays()
    nh = md.hs.size
    sB = md.w * sa.B[0, :] / float(sa.M[0, 0])
    parts = [np.array([nh, system.n_inputs, md.w, md.g0], dtype=np.float64), md.prm, md.rc,
             np.array([md.roots[0].real, md.roots[0].imag, md.roots[1].real, md.roots[1].imag]),
             sB.astype(np.float64)]
    for j in range(nh):
        parts += [np.array([md.hs[j], md.hO[j], md.hph[j]]), md.hcc[j], md.hcs[j]]
    return np.ascontiguousarray(np.concatenate(parts))


@njit(cache=True)
def _unpack(model, tau):
    nh = int(model[_M_NH])
    nin = int(model[_M_NIN])
    w = model[_M_W]
    g0w = model[_M_G0]
    prm = model[_M_PRM:_M_PRM + NPRM].copy()
    rc = model[_M_RC:_M_RC + NT].copy()
    roots = np.empty(2, dtype=np.complex128)
    roots[0] = complex(model[_M_ROOTS], model[_M_ROOTS + 1])
    roots[1] = complex(model[_M_ROOTS + 2], model[_M_ROOTS + 3])
    s0 = prm[P_S0]
    for j in range(nin):
        s0 += model[_M_SB + j] * tau[j]
    off = _M_SB + nin
    hs = np.empty(nh)
    hO = np.empty(nh)
    hph = np.empty(nh)
    hcc = np.empty((nh, NT))
    hcs = np.empty((nh, NT))
    F0 = abs(s0)
    for j in range(nh):
        b = off + j * (3 + 2 * NT)
        hs[j] = model[b]
        hO[j] = model[b + 1]
        hph[j] = model[b + 2]
        for k in range(NT):
            hcc[j, k] = model[b + 3 + k]
            hcs[j, k] = model[b + 3 + NT + k]
        F0 += abs(hs[j])
    prm[P_S0] = s0
    prm[P_F0] = F0
    return prm, rc, roots, hs, hO, hph, hcc, hcs, w, g0w


@njit(cache=True)
def exact_step(model, q, u, t, H, tau, vref, max_events=1_000_000, zeno_ttol=1e-12,
               zeno_vtol=1e-10, cutoff_vtol=1e-6):
    """Advance the 1-DOF state exactly over one communication step ``[t, t + H]``
    with the input ``tau`` (array, length m) constant over it.

    ``model``: :func:`exact_model` of the system; ``q, u, t, H``: floats. The
    flow between events is the closed form, impacts are located by the certified
    root search, accumulations are completed and followed by persistent contact
    with release when the contact force changes sign -- exactly as
    :func:`simulate_exact`, which this step reproduces when chained (same
    ``vref``). ``vref`` is the run's velocity scale for the Zeno criteria: pass
    0.0 on the first step and the returned value on the next one (it is part of
    the slave's state). Returns ``(status, q, u, percussion, impacts, vref)``:
    the state at ``t + H`` (post-impact if an impact falls on ``t + H``), the
    wall impulse over ``(t, t + H]`` (impacts, completed accumulations and the
    persistent contact force), the number of individually resolved impacts, and
    status STEP_OK, STEP_TOO_MANY_EVENTS (more than ``max_events`` events in the
    step) or STEP_NO_PROGRESS (undecidable contact; the state is unchanged then).
    """
    st, _, q1, u1, _, P, _, hits, vref = exact_step_early(
        model, q, u, t, H, tau, vref, False, max_events, zeno_ttol, zeno_vtol, cutoff_vtol)
    return st, q1, u1, P, hits, vref


@njit(cache=True)
def exact_step_early(model, q, u, t, H, tau, vref, early, max_events=1_000_000, zeno_ttol=1e-12,
                     zeno_vtol=1e-10, cutoff_vtol=1e-6):
    """:func:`exact_step` that, with ``early``, stops at the first impact inside
    ``(t, t + H)`` (an FMI 3.0 early return).

    Returns ``(status, t_stop, q, u, u_minus, percussion, p_impact, impacts, vref)``:
    ``t_stop`` is ``t + H`` or the impact instant; ``q, u`` the state there
    (post-impact), ``u_minus`` the velocity just before the stop (the pre-impact
    velocity of an early stop, else ``u``), ``percussion`` the wall impulse over
    ``(t, t_stop]`` including the impact's ``p_impact``, ``vref`` the run's
    velocity scale at ``t_stop``. Continuing from ``(t_stop, q, u, vref)`` runs
    the same closed-form segments as one step over the whole interval (an
    impact that completes an accumulation is then resolved from the post-impact
    state instead)."""
    prm, rc, roots, hs, hO, hph, hcc, hcs, w, g0w = _unpack(model, tau)
    g = w * q + g0w
    if g != 0.0 and abs(g) <= 4.0 * EPS * (abs(w * q) + abs(g0w)):
        g = 0.0                      # on the wall within the round-off of q = (0 - g0)/w
    if g < 0.0:
        g = 0.0
    v = w * u
    vref_in = vref
    status, segs, nseg, evs, nev, grz, ngr, vref = run_events(
        prm, rc, roots, hs, hO, hph, hcc, hcs, t, g, v, t + H, max_events, zeno_ttol,
        zeno_vtol, cutoff_vtol, vref)
    if status != 0:
        return status, t, q, u, u, 0.0, 0.0, 0, vref
    t_stop = t + H
    first = -1
    if early:
        for i in range(nev):
            if evs[i, 1] == IMPACT_EV and t < evs[i, 0]:
                if evs[i, 0] < t_stop:
                    first = i
                break
    if first >= 0:
        t_stop = evs[first, 0]
        vref = vref_start(prm, g, v, vref_in)
        for i in range(first + 1):
            if evs[i, 1] == IMPACT_EV:
                vref = max(vref, -evs[i, 2])
    T = np.empty(2)
    T[0] = t
    T[1] = t_stop
    Q = np.empty(2)
    U = np.empty(2)
    P = np.zeros(2)
    sample(T, segs, nseg, evs, nev, prm, rc, roots, hs, hO, hph, hcc, hcs, w, g0w, Q, U, P, True)
    impacts = 0
    for i in range(nev):
        if evs[i, 1] == IMPACT_EV and t < evs[i, 0] <= t_stop:
            impacts += 1
    if first >= 0:
        return STEP_OK, t_stop, Q[1], U[1], evs[first, 2] / w, P[1], evs[first, 3], impacts, vref
    return STEP_OK, t_stop, Q[1], U[1], U[1], P[1], 0.0, impacts, vref
