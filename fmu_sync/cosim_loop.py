"""The master's exchange loop, compiled (docs/design.md §4.4).

fmpy loads the FMU (extract, instantiate, initialise, free, logger); this
module takes over from there. :func:`fmu_sync.cosim_args.fmi_functions` reads the FMI 2.0 C
function pointers of every instance from fmpy's loaded library and
:func:`loop_start` and :func:`take_step` (numba nopython, ``cache=True``; the one driver
that walks the run's time is :func:`fmu_sync.cosim_driver.drive`) call them directly: per step the coupling law (the
core's :func:`fmu_sync.core.network.network_forces` / ``node_force``, which call
:func:`fmu_sync.core.pair.coupling_step`), the input bound check, fmi2SetReal
(+ fmi2SetRealInputDerivatives for the first-order hold), fmi2DoStep,
fmi2GetReal of the outputs, fmi2GetInteger of the impact counters, the
event-aware retake (fmi2GetFMUstate / SetFMUstate / FreeFMUstate), the
divergence checks and the record. Jacobi and Gauss–Seidel, ZOH and FOH, pairs
and networks, the other masters' delayed orders (``DELAY``: libcosim's and
fmpy's SSP runner, docs/ssp.md) and the implicit exchange (``IMPLICIT``: each step
iterated with FMU-state rollback until the forces agree with the states at its end,
accelerated by a quasi-Newton step per FMU composed with the law's exact Jacobian,
:mod:`fmu_sync.cosim_newton`, :func:`implicit_step`) are one loop.

The exchange strategies are the branches of one primitive, "take the step [t, t + h]
from the current states": :func:`exchange_step` (Jacobi, Gauss–Seidel, delayed; explicit,
never rolled back), the event-aware retake around it (rolled back if an impact counter
moved; the two are :func:`take_step`) and :func:`implicit_step` (rolled back until it converges; returns False with
``FAIL = NOT_CONVERGED`` otherwise, the slaves restored to t, so a step-size
controller can retake it shorter).

Every call's status is checked: a status worse than fmi2Warning ends the chunk
and hands back the failure (``FAIL``: code, instance, call, status; time in
``fail_t``), from which the master raises its ``SlaveError``.

Function pointers are called through :func:`fmi_call`, a numba intrinsic that
casts an integer address to a C function of the argument types (pointers as
int64, ``double`` as float64, ``fmi2Boolean``/``fmi2Status`` as int32).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from .core.distance import BRANCH_E
from .core.network import network_forces, node_force
from .core.kernels import depends_on_core
from .cosim_newton import (OMEGA0, TRUST, dot_rows, force_scale, newton_update, residual_max,  # noqa: F401
                           secants, step_start, trust_clip)
from .fmus.contract import INPUT_BOUND
from .strategies import DELAYED, DELAYED_ZERO, NOT_DELAYED

depends_on_core(__file__)   # its cache follows the core's edits (it compiles network_forces in)

__all__ = ["CALLS", "loop_start", "take_step", "DONE", "SLAVE_FAILED", "FORCE_BOUND", "STATE_DIVERGED", "DISTANCE_DIVERGED",
           "NOT_CONVERGED", "FULL", "NO_ROOM", "Held", "FLAG_NAMES", "IMPLICIT_TOL", "IMPLICIT_MAX_ITERATIONS"]

#: The FMI 2.0 functions the loop calls, in the column order of ``fmi_functions``.
CALLS = ("fmi2SetReal", "fmi2SetRealInputDerivatives", "fmi2DoStep", "fmi2GetReal", "fmi2GetInteger",
         "fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate")
SET_REAL, SET_DER, DO_STEP, GET_REAL, GET_INT, GET_STATE, SET_STATE, FREE_STATE = range(len(CALLS))

# outcome codes of a chunk (FAIL[0]); FULL: the tolerance controller's record is full (grow it, go on);
# NO_ROOM: a per-step array would be written past its end (the bounds check of the builder's sizes)
DONE, SLAVE_FAILED, FORCE_BOUND, STATE_DIVERGED, DISTANCE_DIVERGED, NOT_CONVERGED, FULL, NO_ROOM = range(8)
# ctl: the loop's integer state between chunks (FRESH: tau already holds the Jacobi
# forces at the current states, computed with the record's distances; ZERO_STEPS: delayed
# orders, the steps still to run before the forces transferred for the next step are computed)
ROW, RETAKES, HIST_VALID, FRESH, ZERO_STEPS = range(5)
CTL = 5


class Held(NamedTuple):
    """The arrays the FMI calls read or write, by address (``ptr``, taken once in Python; they
    live as long as the run): value references of q, u (2n,), of tau (n,), of the impact counter
    (1,); the derivative orders (n,) int32 ones; ``tau`` (N, n); the outputs' buffer (2n,); the
    slope (n,); the impact-counter buffer (1,) int32; the FMU-state handles (N,)."""
    vr_out: np.ndarray
    vr_tau: np.ndarray
    vr_imp: np.ndarray
    order: np.ndarray
    tau: np.ndarray
    buf: np.ndarray
    slope: np.ndarray
    ibuf: np.ndarray
    saved: np.ndarray


# ptr's slots (the kernels read ptr[P_*]): the fields of Held, in its order
P_VR_OUT, P_VR_TAU, P_VR_IMP, P_ORDER, P_TAU, P_BUF, P_SLOPE, P_IBUF, P_SAVED = (
    Held._fields.index(f) for f in ("vr_out", "vr_tau", "vr_imp", "order", "tau", "buf", "slope", "ibuf", "saved"))


# flags: the run's settings (STEPS: the run's communication steps; PIECES, PIECES_LAST: the
# event-aware retake's pieces of a step of length H and of the last step)
# IMPLICIT: the implicit exchange; MAX_ITER: its cap of FMU steps per communication step)
#: the flags by name (the builder, :func:`fmu_sync.cosim_args.loop_arguments`, fills them by name; the kernels read them by index)
FLAG_NAMES = ("gauss_seidel", "foh", "event_aware", "need_d", "coupled", "record_every", "pieces", "delay", "steps",
              "pieces_last", "implicit", "max_iter", "tol")
GAUSS_SEIDEL, FOH, EVENT_AWARE, NEED_D, COUPLED, RECORD_EVERY, PIECES, DELAY, STEPS, PIECES_LAST, IMPLICIT, \
    MAX_ITER, TOL = range(len(FLAG_NAMES))
FLAGS = len(FLAG_NAMES)
#: The implicit exchange's defaults: a step has converged when every force differs from the law at
#: the step's end states by at most IMPLICIT_TOL times the force scale (:func:`force_scale`); at most
#: IMPLICIT_MAX_ITERATIONS FMU steps per communication step, else the run fails (NOT_CONVERGED).
IMPLICIT_TOL = 1e-9
IMPLICIT_MAX_ITERATIONS = 30
#: The switching laws' branch within a step of the implicit exchange (docs/design.md §4.4): decided
#: at the first iterate's end states and held for the others; a step converged on a branch that is
#: not the law's own at its end states is iterated on once more with the branch decided again there
#: (at most REDECIDE times), then accepted on the branch it converged on. A step not converged after
#: half its cap of FMU steps holds branch E from there (the PD law, linear in the end states).
REDECIDE = 1
# flags[DELAY]: the exchange order of another master (docs/ssp.md), zero-order hold only.
# DELAYED (libcosim): step k is held at the forces of the states x_{k-1} (step 0 at x_0's);
# DELAYED_ZERO (fmpy's simulate_ssp): every connection starts at 0, steps 0 and 1 run
# without forces, step k >= 2 at the forces of x_{k-1}
# (the codes are the registry's, fmu_sync.strategies)
WARNING = 1

#: the core's network_forces inlined into the loop (numba IR inlining: its own source and
#: arithmetic, bit for bit): called, it takes its ~20 arrays through the stack every step,
#: a third of the loop's own time. Never compiled on its own, so not cached itself: it is
#: compiled into the kernels that call it, which are.
_forces_inline = njit(inline="always")(network_forces.py_func)


@intrinsic
def fmi_call(typingctx, fn, args):
    """``fn(*args)`` for an integer function address ``fn``; returns the C ``int`` result."""
    if not isinstance(fn, types.Integer) or not isinstance(args, types.BaseTuple):
        return None
    sig = types.int32(fn, args)

    def codegen(context, builder, signature, llargs):
        address, tup = llargs
        tys = signature.args[1]
        values = [builder.extract_value(tup, i) for i in range(len(tys))]
        fnty = ir.FunctionType(ir.IntType(32), [context.get_value_type(t) for t in tys])
        return builder.call(builder.inttoptr(address, fnty.as_pointer()), values)

    return sig, codegen


def _unmanaged_value(context, builder, ty, value):
    """``value`` of type ``ty`` with every array's meminfo and parent set to NULL (tuples recursively)."""
    if isinstance(ty, types.Array):
        ary = cgutils.create_struct_proxy(ty)(context, builder, value=value)
        ary.meminfo = cgutils.get_null_value(ary.meminfo.type)
        ary.parent = cgutils.get_null_value(ary.parent.type)
        return ary._getvalue()
    if isinstance(ty, types.BaseTuple):
        for j, t in enumerate(ty.types):
            item = _unmanaged_value(context, builder, t, builder.extract_value(value, j))
            value = builder.insert_value(value, item, j)
    return value


@intrinsic
def unmanaged(typingctx, x):
    """``x`` (an array, or a tuple of arrays and scalars) as views that numba's runtime does not
    track (NULL meminfo): passing them on costs no reference counting (an atomic
    increment and decrement per array per call otherwise, most of the loop's time). Only
    for arrays the caller keeps alive for the whole call (the arguments of
    :func:`loop_start`, :func:`fmu_sync.cosim_driver.drive`), never returned or stored."""
    def codegen(context, builder, signature, llargs):
        return _unmanaged_value(context, builder, signature.args[0], llargs[0])

    return x(x), codegen


@njit(cache=True, inline="always")
def copy_rows(a, b):
    """b[:, :] = a, element by element (no array views: no reference counting in the loop)."""
    for i in range(a.shape[0]):
        for c in range(a.shape[1]):
            b[i, c] = a[i, c]


@njit(cache=True, inline="always")
def fail_at(FAIL, fail_t, code, i, call, status, t):
    FAIL[0] = code
    FAIL[1] = i
    FAIL[2] = call
    FAIL[3] = status
    fail_t[0] = t
    return True


@njit(cache=True, inline="always")
def _read(ptr, fn, comp, i, buf, q, u, FAIL, fail_t, t):
    """fmi2GetReal of q_i, u_i (one call, 2n references) into q[i], u[i]."""
    n = q.shape[1]
    st = fmi_call(fn[i, GET_REAL], (comp[i], ptr[P_VR_OUT], np.int64(2 * n), ptr[P_BUF]))
    if st > WARNING:
        return fail_at(FAIL, fail_t, SLAVE_FAILED, i, GET_REAL, st, t)
    for c in range(n):
        q[i, c] = buf[c]
        u[i, c] = buf[n + c]
    return False


@njit(cache=True, inline="always")
def read_impacts(ptr, fn, comp, ibuf, imp, FAIL, fail_t, t):
    """fmi2GetInteger of every instance's impact counter into imp."""
    for i in range(comp.shape[0]):
        st = fmi_call(fn[i, GET_INT], (comp[i], ptr[P_VR_IMP], np.int64(1), ptr[P_IBUF]))
        if st > WARNING:
            return fail_at(FAIL, fail_t, SLAVE_FAILED, i, GET_INT, st, t)
        imp[i] = ibuf[0]
    return False


@njit(cache=True, inline="always")
def _give(ptr, fn, comp, i, t, h, foh, no_prior, tau, hist_tau, hist_t, hist_valid, slope, FAIL,
          fail_t):
    """Instance i: for the first-order hold the slope from the inputs at the last
    communication point (0 on the first step), then :func:`_put`."""
    if foh:
        for c in range(tau.shape[1]):
            slope[c] = (tau[i, c] - hist_tau[i, c]) / (t - hist_t) if hist_valid and t > hist_t else 0.0
    return _put(ptr, fn, comp, i, t, h, foh, no_prior, tau, FAIL, fail_t)


@njit(cache=True, inline="always")
def _put(ptr, fn, comp, i, t, h, foh, no_prior, tau, FAIL, fail_t):
    """Instance i: the input bound check, fmi2SetReal(tau_i), for the first-order hold
    fmi2SetRealInputDerivatives of the slope in ``ptr[P_SLOPE]`` (after the value: setting
    an input resets its derivative), then fmi2DoStep(t, h)."""
    n = tau.shape[1]
    for c in range(n):
        if not abs(tau[i, c]) <= INPUT_BOUND:   # also catches NaN
            return fail_at(FAIL, fail_t, FORCE_BOUND, i, -1, 3, t)
    st = fmi_call(fn[i, SET_REAL], (comp[i], ptr[P_VR_TAU], np.int64(n), ptr[P_TAU] + 8 * n * i))
    if st > WARNING:
        return fail_at(FAIL, fail_t, SLAVE_FAILED, i, SET_REAL, st, t)
    if foh:
        st = fmi_call(fn[i, SET_DER], (comp[i], ptr[P_VR_TAU], np.int64(n), ptr[P_ORDER],
                                       ptr[P_SLOPE]))
        if st > WARNING:
            return fail_at(FAIL, fail_t, SLAVE_FAILED, i, SET_DER, st, t)
    st = fmi_call(fn[i, DO_STEP], (comp[i], t, h, np.int32(no_prior)))
    if st > WARNING:
        return fail_at(FAIL, fail_t, SLAVE_FAILED, i, DO_STEP, st, t)
    return False


@njit(cache=True, inline="always")
def exchange_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, t, h, q, u, tau, tau_next, hist_tau,
              hist, ctl, w, FAIL, fail_t, hp):
    """One exchange over [t, t + h]: Jacobi (every input from the same states, then all
    step), Gauss–Seidel (in index order, each input from the newest states) or delayed
    (as Jacobi, but every instance steps with the forces transferred after the previous
    step, ``tau_next``, which then become those of the current states); then the inputs
    become the first-order hold's history. ``w``: the scratch arrays."""
    t1, t2, c1q, c1u, c2q, c2u, dk, bk, ek, buf, slope = w
    N = q.shape[0]
    fresh = ctl[FRESH]
    ctl[FRESH] = 0
    foh = flags[FOH] != 0
    no_prior = 0 if flags[EVENT_AWARE] or flags[TOL] else 1   # a state may be set back
    if flags[GAUSS_SEIDEL]:
        for i in range(N):
            node_force(i, laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, hp, t)
            if _give(ptr, fn, comp, i, t, h, foh, no_prior, tau, hist_tau, hist[0], ctl[HIST_VALID],
                     slope, FAIL, fail_t):
                return True
            if _read(ptr, fn, comp, i, buf, q, u, FAIL, fail_t, t + h):
                return True
    else:
        if flags[DELAY]:
            copy_rows(tau_next, tau)
            if ctl[ZERO_STEPS] > 0:   # fmpy: the connections still hold their start value 0
                ctl[ZERO_STEPS] -= 1
            else:
                network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau_next, t1, t2, c1q, c1u, c2q, c2u, False, dk, bk,
                               ek, hp, t)
        elif fresh == 0:
            _forces_inline(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, False, dk, bk, ek, hp, t)
        for i in range(N):
            for c in range(tau.shape[1]):
                if not abs(tau[i, c]) <= INPUT_BOUND:
                    return fail_at(FAIL, fail_t, FORCE_BOUND, i, -1, 3, t)
        for i in range(N):
            if _give(ptr, fn, comp, i, t, h, foh, no_prior, tau, hist_tau, hist[0], ctl[HIST_VALID],
                     slope, FAIL, fail_t):
                return True
        for i in range(N):
            if _read(ptr, fn, comp, i, buf, q, u, FAIL, fail_t, t + h):
                return True
    copy_rows(tau, hist_tau)
    hist[0] = t
    ctl[HIST_VALID] = 1
    return False


@njit(cache=True, inline="always")
def fmu_states(ptr, fn, comp, call, saved, FAIL, fail_t, t):
    """Every instance's FMU state: saved (``call`` GET_STATE, a new copy), restored (SET_STATE)
    or freed (FREE_STATE) through the handles ``saved`` (at ``ptr[P_SAVED]``)."""
    for i in range(comp.shape[0]):
        if call == SET_STATE:
            st = fmi_call(fn[i, SET_STATE], (comp[i], saved[i]))
        else:
            if call == GET_STATE:
                saved[i] = 0
            st = fmi_call(fn[i, call], (comp[i], ptr[P_SAVED] + 8 * i))
        if st > WARNING:
            return fail_at(FAIL, fail_t, SLAVE_FAILED, i, call, st, t)
    return False


@njit(cache=True)
def implicit_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, t, h, k, q, u, tau, hist_tau, hist, ctl,
                   saved, qs, us, iw, w, FAIL, fail_t, hp):
    """The implicit exchange over [t, t + h] (docs/design.md §4.4): the force over the step is the
    line from ``ta`` (the law at the states at t) to ``te`` (first-order hold: value and input
    derivative) or their mean held (zero-order hold); ``te`` is iterated until it equals the law
    at the states the step ends in, to :data:`IMPLICIT_TOL` (``iw.tolv[0]``) times :func:`force_scale`.
    The first iterate is the explicit first-order hold's extrapolation; between iterates every
    instance is restored to t (fmi2SetFMUstate) and ``te`` updated by the block quasi-Newton step
    of :mod:`fmu_sync.cosim_newton` (each FMU's secant, reset when its impact count within the step
    moves or h changes, composed with the law's Jacobian; the impact counters are read after every
    iterate). The switching laws' branch (per edge) is decided
    at the first iterate's end states and held (``bh``) for the others, so that the law is a smooth
    function of the end states; a step converged on a branch that is not the law's own at its end
    states is iterated on with the branch decided again there (:data:`REDECIDE` times), then
    accepted (``offb[k]``: the edges accepted off their own branch); one not converged after half
    of ``flags[MAX_ITER]`` holds branch E from there (where a system's end state sits at its chain
    end, as in an impact within the step, the law's pull on a jump branch flips direction: no fixed
    point) and the update is a damped fixed point (relaxation OMEGA0, then Aitken's). ``iters[k]``: FMU steps taken,
    ``resid[k]``: the last residual's max norm.
    Not converged within ``flags[MAX_ITER]`` FMU steps: the instances are restored to t, ``FAIL``
    = NOT_CONVERGED, returns True (a caller with a step-size control may retake it shorter)."""
    t1, t2, c1q, c1u, c2q, c2u, dk, bk, ek, buf, slope = w
    ta, te, g, r, rp, gp, nw, bh, offb, iters, resid, tolv = iw
    if k >= iters.shape[0]:   # the per-step arrays hold the steps the builder sized them for: never past
        return fail_at(FAIL, fail_t, NO_ROOM, -1, k, iters.shape[0], t)
    imp0, impc, ibuf = nw.imp0, nw.impc, nw.ibuf
    N = q.shape[0]
    n = q.shape[1]
    foh = flags[FOH] != 0
    if ctl[FRESH] == 0:
        network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, False, dk, bk, ek, hp, t)
    ctl[FRESH] = 0
    extrapolate = ctl[HIST_VALID] != 0 and t > hist[0]
    for i in range(N):
        for c in range(n):
            ta[i, c] = tau[i, c]
            te[i, c] = ta[i, c] + h * (ta[i, c] - hist_tau[i, c]) / (t - hist[0]) if extrapolate else ta[i, c]
    trust_clip(te)
    if fmu_states(ptr, fn, comp, GET_STATE, saved, FAIL, fail_t, t):
        return True
    if read_impacts(ptr, fn, comp, ibuf, imp0, FAIL, fail_t, t):
        return True
    step_start(nw, h, foh)
    copy_rows(q, qs)
    copy_rows(u, us)
    it = 0
    rmax = math.inf
    converged = False
    omega = OMEGA0
    redecide = REDECIDE
    damped = False   # the fallback: a fixed point relaxed by Aitken's rule
    fresh = False   # the law changed branch at the last iterate: no Aitken across it
    while True:
        for i in range(N):
            for c in range(n):
                if foh:
                    tau[i, c] = ta[i, c]
                    slope[c] = (te[i, c] - ta[i, c]) / h
                else:
                    tau[i, c] = 0.5 * (ta[i, c] + te[i, c])
            if _put(ptr, fn, comp, i, t, h, foh, 0, tau, FAIL, fail_t):
                return True
        it += 1
        for i in range(N):
            if _read(ptr, fn, comp, i, buf, q, u, FAIL, fail_t, t + h):
                return True
        if read_impacts(ptr, fn, comp, ibuf, impc, FAIL, fail_t, t + h):
            return True
        secants(nw, te, q, u, it)
        # the law at the end states: on its own branch at the first iterate, on the branch held in
        # bk (decided there) at the others
        network_forces(laws, geo, Kp, Kd, E2, W2, q, u, g, t1, t2, c1q, c1u, c2q, c2u, False, dk, bk, ek, hp, t + h,
                       it > 1)
        rmax = residual_max(g, te, r)
        target = tolv[0] * force_scale(g, ta, q, u, Kp, Kd)
        if rmax <= target:
            for e_ in range(bk.shape[0]):
                bh[e_] = bk[e_]
            # the law's own branch at the end states (into bk; its forces into rp, free until the update)
            network_forces(laws, geo, Kp, Kd, E2, W2, q, u, rp, t1, t2, c1q, c1u, c2q, c2u, False, dk, bk, ek, hp,
                           t + h)
            off = 0
            for e_ in range(bk.shape[0]):
                if bk[e_] != bh[e_]:
                    off += 1
            if off == 0 or redecide == 0:
                offb[k] = off
                converged = True
                break
            redecide -= 1   # held from here on: the branch decided at these end states
            copy_rows(rp, g)
            rmax = residual_max(g, te, r)
            fresh = True
        if it >= flags[MAX_ITER] or not math.isfinite(rmax):
            break
        if it == flags[MAX_ITER] // 2 and it > 1:   # hold branch E from here; a damped fixed point
            for e_ in range(bk.shape[0]):
                if bk[e_] > BRANCH_E:
                    bk[e_] = BRANCH_E
                    fresh = True
            if fresh:
                network_forces(laws, geo, Kp, Kd, E2, W2, q, u, g, t1, t2, c1q, c1u, c2q, c2u, False, dk, bk, ek,
                               hp, t + h, True)
                rmax = residual_max(g, te, r)
                redecide = 0
            damped = True
            omega = OMEGA0
            fresh = True
        if damped:
            if not fresh:   # Aitken's relaxation from the last two residuals
                dr = 0.0
                for i in range(N):
                    for c in range(n):
                        dr += (r[i, c] - rp[i, c]) * (r[i, c] - rp[i, c])
                if dr > 0.0:
                    omega = -omega * (dot_rows(rp, r) - dot_rows(rp, rp)) / dr
            copy_rows(r, rp)
            for i in range(N):
                for c in range(n):
                    te[i, c] += omega * r[i, c]
        else:
            newton_update(nw, te, r, rmax, 0.1 * target, g, q, u, laws, geo, Kp, Kd, E2, W2, w, hp, t + h)
        fresh = False
        trust_clip(te)
        if fmu_states(ptr, fn, comp, SET_STATE, saved, FAIL, fail_t, t):
            return True
        copy_rows(qs, q)
        copy_rows(us, u)
    iters[k] = it
    resid[k] = rmax
    if not converged:   # back to t, then fail: never accepted
        if fmu_states(ptr, fn, comp, SET_STATE, saved, FAIL, fail_t, t):
            return True
        copy_rows(qs, q)
        copy_rows(us, u)
    if fmu_states(ptr, fn, comp, FREE_STATE, saved, FAIL, fail_t, t + h):
        return True
    copy_rows(ta, tau)   # the record's input held over the step: its value at t (as the first-order hold's)
    if not converged:
        return fail_at(FAIL, fail_t, NOT_CONVERGED, -1, it, 0, t)
    copy_rows(ta, hist_tau)
    hist[0] = t
    ctl[HIST_VALID] = 1
    return False


@njit(cache=True, inline="always")
def record_row(row, t, q, u, tau, laws, geo, Kp, Kd, E2, W2, need_d, jacobi, ctl, T, Qr, Ur, TAU, D, BR, EU, scratch,
            w, hp):
    """Row ``row`` at time t: the states, the inputs held over the step that ended here, and
    each edge's distance (returns False if a distance is not finite). Jacobi: the forces
    of the next step come with the distances (the same states), into ``tau`` (FRESH)."""
    t1, t2, c1q, c1u, c2q, c2u, dk, bk, ek, buf, slope = w
    T[row] = t
    for i in range(q.shape[0]):
        for c in range(q.shape[1]):
            Qr[row, i, c] = q[i, c]
            Ur[row, i, c] = u[i, c]
            TAU[row, i, c] = tau[i, c]
    if not need_d:
        return True
    dist = D.shape[1] == E2.shape[0]   # D without columns: the Euclidean error alone (no common geometry)
    if jacobi:
        _forces_inline(laws, geo, Kp, Kd, E2, W2, q, u, tau, t1, t2, c1q, c1u, c2q, c2u, dist, dk, bk, ek, hp, t)
        ctl[FRESH] = 1
    else:
        network_forces(laws, geo, Kp, Kd, E2, W2, q, u, scratch, t1, t2, c1q, c1u, c2q, c2u, dist, dk, bk, ek, hp, t)
    ok = True
    for e_ in range(E2.shape[0]):
        EU[row, e_] = ek[e_]
        if dist:
            D[row, e_] = dk[e_]
            BR[row, e_] = bk[e_]
        if not math.isfinite(dk[e_] if dist else ek[e_]):
            ok = False
    return ok


@njit(cache=True, inline="always")
def take_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, t, h, k, pieces, retake, q, u, tau, tau_next,
              hist_tau, hist, imp, ctl, saved, keep, w, FAIL, fail_t):
    """The run's step over [t, t + h] by its strategy: the implicit exchange (:func:`implicit_step`,
    its per-step arrays at ``k``) or :func:`exchange_step`, with ``retake`` the event-aware retake
    (every instance saved before; if an impact counter moved, restored and the step retaken in
    ``pieces``); then the impact counters into ``keep.imp_new``. True on a failure (``FAIL``)."""
    qs, us, hts, hs, scratch, imp_new, ibuf, iw = keep
    if flags[IMPLICIT]:
        if implicit_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, t, h, k, q, u, tau, hist_tau, hist,
                         ctl, saved, qs, us, iw, w, FAIL, fail_t, hp):
            return True
        return read_impacts(ptr, fn, comp, ibuf, imp_new, FAIL, fail_t, t + h)
    if retake:
        if fmu_states(ptr, fn, comp, GET_STATE, saved, FAIL, fail_t, t):
            return True
        copy_rows(q, qs)
        copy_rows(u, us)
        copy_rows(hist_tau, hts)
        hs[0] = hist[0]
        hs[1] = ctl[HIST_VALID]
    # the exchange over [t, t + h] (p = -1) and, with the retake, if an impact counter moved: every
    # instance restored to t and [t, t + h] again in pieces of about H_min (p = 0 .. pieces - 1). One call
    # site: exchange_step, with the coupling forces inlined, is compiled into the driver once
    # (docs/design.md §5.6)
    p = -1
    tp = t
    hpc = h
    while True:
        if exchange_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, tp, hpc, q, u, tau, tau_next, hist_tau,
                         hist, ctl, w, FAIL, fail_t, hp):
            return True
        if p < 0:
            if read_impacts(ptr, fn, comp, ibuf, imp_new, FAIL, fail_t, t + h):
                return True
            if not retake:
                return False
            moved = False
            for i in range(q.shape[0]):
                if imp_new[i] != imp[i]:
                    moved = True
            if not moved:
                break
            copy_rows(hts, hist_tau)
            hist[0] = hs[0]
            ctl[HIST_VALID] = np.int64(hs[1])
            ctl[RETAKES] += 1
            if fmu_states(ptr, fn, comp, SET_STATE, saved, FAIL, fail_t, t):
                return True
            copy_rows(qs, q)
            copy_rows(us, u)
        p += 1
        if p == pieces:
            if read_impacts(ptr, fn, comp, ibuf, imp_new, FAIL, fail_t, t + h):
                return True
            break
        tp = t + p * (h / pieces)
        hpc = (t + h) - tp if p == pieces - 1 else h / pieces
    return fmu_states(ptr, fn, comp, FREE_STATE, saved, FAIL, fail_t, t + h)


@njit(cache=True)
def loop_start(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, H, H_last, t_last, q, u, tau, tau_next,
               hist_tau, hist, imp, ctl, saved, keep, T, Qr, Ur, TAU, D, BR, EU, w, FAIL, fail_t):
    """The run's start (the arguments of :class:`fmu_sync.cosim_args.LoopArgs` and
    :class:`fmu_sync.cosim_args.LoopState`): the start states and impact counters read, the forces
    at them (the delayed orders' buffer ``tau_next``; 0 for ``delayed-zero``), row 0 recorded.
    The steps are the driver's (:func:`fmu_sync.cosim_driver.drive`). Returns the outcome code.

    ``ptr`` (:data:`P_VR_OUT` ...) the addresses of :class:`Held`'s arrays, which the FMI calls
    read or write; ``fn`` (N, len(CALLS)) function addresses, ``comp`` (N,) component handles;
    ``flags`` (:data:`FLAG_NAMES`); ``q, u, tau`` (N, n) the current states and inputs;
    ``hist_tau``, ``hist`` the first-order hold's history; ``imp`` (N,); ``ctl`` (row, retakes,
    history valid, fresh, zero steps); ``saved`` (N,) FMU state handles; ``keep``: a rolled-back
    step's copies and the implicit exchange's work."""
    (ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, q, u, tau, tau_next, hist_tau, hist, imp, ctl, saved, keep,
     T, Qr, Ur, TAU, D, BR, EU, w, FAIL, fail_t) = unmanaged((ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, q,
                                                              u, tau, tau_next, hist_tau, hist, imp, ctl, saved, keep,
                                                              T, Qr, Ur, TAU, D, BR, EU, w, FAIL, fail_t))
    N = q.shape[0]
    jacobi = flags[GAUSS_SEIDEL] == 0 and flags[DELAY] == NOT_DELAYED   # the record may compute tau
    FAIL[0] = DONE
    for i in range(N):
        if _read(ptr, fn, comp, i, w.buf, q, u, FAIL, fail_t, 0.0):
            return FAIL[0]
    if read_impacts(ptr, fn, comp, keep.ibuf, imp, FAIL, fail_t, 0.0):
        return FAIL[0]
    if flags[COUPLED]:
        network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, w.t1, w.t2, w.c1q, w.c1u, w.c2q, w.c2u, False,
                       w.dk, w.bk, w.ek, hp, 0.0)
    if flags[DELAY] == DELAYED_ZERO:   # the first two steps are held at 0
        for i in range(N):
            for c in range(q.shape[1]):
                tau[i, c] = 0.0
        ctl[ZERO_STEPS] = 1
    if flags[DELAY]:
        copy_rows(tau, tau_next)
    record_row(0, 0.0, q, u, tau, laws, geo, Kp, Kd, E2, W2, flags[NEED_D] != 0, jacobi, ctl, T, Qr, Ur, TAU, D, BR, EU,
               keep.scratch, w, hp)
    ctl[ROW] = 1
    return DONE
