# long module: the one compiled exchange loop, its strategies (Jacobi, Gauss-Seidel, event-aware retake, implicit) beside the inlined helpers they share
"""The master's exchange loop, compiled (docs/design.md §4.4).

fmpy loads the FMU (extract, instantiate, initialise, free, logger); this
module takes over from there. :func:`fmi_functions` reads the FMI 2.0 C
function pointers of every instance from fmpy's loaded library and
:func:`exchange_chunk` (numba nopython, ``cache=True``) runs a chunk of
communication steps calling them directly: per step the coupling law (the
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
moved) and :func:`implicit_step` (rolled back until it converges; returns False with
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

import ctypes
import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from .core.checks import run_steps
from .core.coupling import chain_work
from .core.distance import BRANCH_E
from .core.network import edge_arrays, network_forces, node_force
from .core.kernels import depends_on_core
from .cosim_newton import OMEGA0, newton_update, newton_work, secants, step_start
from .fmus import contract
from .fmus.contract import INPUT_BOUND

depends_on_core(__file__)   # its cache follows the core's edits (it compiles network_forces in)

__all__ = ["CALLS", "fmi_functions", "exchange_chunk", "DONE", "SLAVE_FAILED", "FORCE_BOUND",
           "STATE_DIVERGED", "DISTANCE_DIVERGED", "NOT_CONVERGED", "IMPLICIT_TOL", "IMPLICIT_MAX_ITERATIONS",
           "implicit_work", "loop_arguments", "implicit_info", "not_converged"]

#: The FMI 2.0 functions the loop calls, in the column order of ``fmi_functions``.
CALLS = ("fmi2SetReal", "fmi2SetRealInputDerivatives", "fmi2DoStep", "fmi2GetReal", "fmi2GetInteger",
         "fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate")
SET_REAL, SET_DER, DO_STEP, GET_REAL, GET_INT, GET_STATE, SET_STATE, FREE_STATE = range(len(CALLS))

# outcome codes of a chunk (FAIL[0])
DONE, SLAVE_FAILED, FORCE_BOUND, STATE_DIVERGED, DISTANCE_DIVERGED, NOT_CONVERGED = range(6)
# ctl: the loop's integer state between chunks (FRESH: tau already holds the Jacobi
# forces at the current states, computed with the record's distances; ZERO_STEPS: delayed
# orders, the steps still to run before the forces transferred for the next step are computed)
ROW, RETAKES, HIST_VALID, FRESH, ZERO_STEPS = range(5)
CTL = 5
# ptr: addresses of the arrays the FMI calls read or write (taken once, in Python)
P_VR_OUT, P_VR_TAU, P_VR_IMP, P_ORDER, P_TAU, P_BUF, P_SLOPE, P_IBUF, P_SAVED = range(9)
# flags: the run's settings (STEPS: the run's communication steps; PIECES, PIECES_LAST: the
# event-aware retake's pieces of a step of length H and of the last step)
# IMPLICIT: the implicit exchange; MAX_ITER: its cap of FMU steps per communication step)
GAUSS_SEIDEL, FOH, EVENT_AWARE, NEED_D, COUPLED, RECORD_EVERY, PIECES, DELAY, STEPS, PIECES_LAST, IMPLICIT, \
    MAX_ITER = range(12)
FLAGS = 12
#: The implicit exchange's defaults: a step has converged when every force differs from the law at
#: the step's end states by at most IMPLICIT_TOL times the force scale (:func:`_scale`); at most
#: IMPLICIT_MAX_ITERATIONS FMU steps per communication step, else the run fails (NOT_CONVERGED).
IMPLICIT_TOL = 1e-9
IMPLICIT_MAX_ITERATIONS = 30
#: The switching laws' branch within a step of the implicit exchange (docs/design.md §4.4): decided
#: at the first iterate's end states and held for the others; a step converged on a branch that is
#: not the law's own at its end states is iterated on once more with the branch decided again there
#: (at most REDECIDE times), then accepted on the branch it converged on. A step not converged after
#: half its cap of FMU steps holds branch E from there (the PD law, linear in the end states).
REDECIDE = 1
#: the trust region of the implicit exchange's iterates: no FMU is given a force beyond this
#: fraction of its input bound (an iterate outside it is moved to its edge; the law's own force at
#: the step's start, inside the bound, stays inside: issue 44 item 7)
TRUST = 0.5
# flags[DELAY]: the exchange order of another master (docs/ssp.md), zero-order hold only.
# DELAYED (libcosim): step k is held at the forces of the states x_{k-1} (step 0 at x_0's);
# DELAYED_ZERO (fmpy's simulate_ssp): every connection starts at 0, steps 0 and 1 run
# without forces, step k >= 2 at the forces of x_{k-1}
NOT_DELAYED, DELAYED, DELAYED_ZERO = range(3)
WARNING = 1

#: the core's network_forces inlined into the loop (numba IR inlining: its own source and
#: arithmetic, bit for bit): called, it takes its ~20 arrays through the stack every step,
#: a third of the loop's own time. Never compiled on its own, so not cached itself: it is
#: compiled into exchange_chunk, which is.
_forces_inline = njit(inline="always")(network_forces.py_func)


def fmi_functions(dll, optional=("fmi2SetRealInputDerivatives", "fmi2GetFMUstate", "fmi2SetFMUstate",
                                 "fmi2FreeFMUstate")) -> np.ndarray:
    """The addresses of :data:`CALLS` in a loaded FMU library (0 for an optional function
    the library does not export; the master only calls those its run needs)."""
    out = np.zeros(len(CALLS), dtype=np.int64)
    for k, name in enumerate(CALLS):
        try:
            out[k] = ctypes.cast(getattr(dll, name), ctypes.c_void_p).value or 0
        except AttributeError:
            if name not in optional:
                raise ValueError(f"the FMU's binary does not export {name}, which the master calls") from None
    return out


def loop_arguments(m) -> None:
    """What :func:`exchange_chunk` takes for the run of a :class:`fmu_sync.master.NetworkMaster`
    ``m`` (set up, its instances started): every instance's FMI function addresses and component
    handle (a function its settings need but its binary lacks: ValueError), the value references,
    the settings (``flags``) and the loop's state between chunks, as ``m.loop_args`` and
    ``m.loop_state`` (the arrays the loop writes also as attributes of ``m``)."""
    model, N, n = m.model, m.N, m.model.n
    m.fn = np.stack([fmi_functions(s.fmu.dll) for s in m.slaves])
    rollback = "event_aware=True" if m.event_aware else "exchange='implicit'" if m.implicit else None
    needed = (["fmi2SetRealInputDerivatives"] if m.hold == "foh" else []) + (
        ["fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate"] if rollback else [])
    for name in needed:
        if not np.all(m.fn[:, CALLS.index(name)]):
            why = "hold='foh'" if "Derivatives" in name else rollback
            raise ValueError(f"{m.fmu}: its binary does not export {name}, which {why} needs")
    m.comp = np.array([s.fmu.component or 0 for s in m.slaves], dtype=np.int64)
    ref = (lambda names: np.array([m.slaves[0].variables[v].valueReference for v in names], dtype=np.uint32))
    m.vr_out, m.vr_tau, m.vr_imp = ref(model.q + model.u), ref(model.tau), ref([contract.IMPACTS])
    E2, W2 = edge_arrays(m.A, m.edges)
    flags = np.zeros(FLAGS, dtype=np.int64)
    flags[[GAUSS_SEIDEL, FOH, EVENT_AWARE, NEED_D, COUPLED]] = [
        m.method == "gauss-seidel", m.hold == "foh", m.event_aware, m.need_d, m.coupled]
    flags[RECORD_EVERY] = m.record_every
    flags[DELAY] = m.DELAY.get(m.method, NOT_DELAYED)
    flags[STEPS] = m.n_steps   # the last one of length grid.dt_last, ending at grid.t_end
    flags[IMPLICIT], flags[MAX_ITER] = m.implicit, IMPLICIT_MAX_ITERATIONS
    pieces = (lambda h: max(1, run_steps(h, m.H_min).steps) if m.event_aware else 1)
    flags[PIECES], flags[PIECES_LAST] = pieces(m.H), pieces(m.grid.dt_last)
    z = (lambda: np.zeros((N, n)))
    m.q, m.u, m.tau = z(), z(), z()
    m.imp, m.ctl = np.zeros(N, dtype=np.int64), np.zeros(CTL, dtype=np.int64)
    E = len(m.edges)
    work = chain_work(n)
    w = (np.zeros(n), np.zeros(n), *work, np.zeros(E), np.zeros(E, dtype=np.int64), np.zeros(E),
         np.zeros(2 * n), np.zeros(n))
    ibuf = np.zeros(1, dtype=np.int32)
    m.iw = implicit_work(N, n, len(m.edges), m.n_steps if m.implicit else 0, ibuf=ibuf,
                         Minv=getattr(m, "Minv_nodes", None))
    keep = (z(), z(), z(), np.zeros(2), z(), np.zeros(N, dtype=np.int64), ibuf, m.iw)
    m.FAIL, m.fail_t = np.zeros(4, dtype=np.int64), np.zeros(1)
    saved = np.zeros(N, dtype=np.int64)
    # the arrays the FMI calls read or write, by address (P_*); they live as long as the run
    m.held = (m.vr_out, m.vr_tau, m.vr_imp, np.ones(n, dtype=np.int32), m.tau, w[9], w[10], keep[6], saved)
    ptr = np.array([a.ctypes.data for a in m.held], dtype=np.int64)
    m.loop_args = (ptr, m.fn, m.comp, m.laws, m.geo, m.Kp_m, m.Kd_m, E2, W2, flags, m.hp, float(m.H),
                   float(m.grid.dt_last), float(m.grid.t_end))
    m.loop_state = (m.q, m.u, m.tau, z(), z(), np.zeros(1), m.imp, m.ctl, saved, keep, m.T, m.Qr, m.Ur, m.TAU, m.D,
                    m.BR, m.EU, w, m.FAIL, m.fail_t)


def implicit_info(iw) -> dict:
    """``info`` of an implicit run: ``iterations`` (FMU steps per communication step taken, int64),
    ``residuals`` (each one's final max |law(end states) - end force|), ``exchange_tol``,
    ``off_branch`` (per step, the edges whose end force was accepted on a branch other than the
    switching law's own at the end states: the law's branch changed within the step, §4.4); {} for
    an explicit run (``iw`` None or without per-step arrays)."""
    if iw is None or iw[-3].size == 0:
        return {}
    done = int(np.count_nonzero(iw[-3]))
    return dict(iterations=iw[-3][:done].copy(), residuals=iw[-2][:done].copy(), exchange_tol=float(iw[-1][0]),
                off_branch=iw[-4][:done].copy())


def not_converged(iw, t: float, H: float, steps: int) -> str:
    """The message of a step from ``t`` that did not converge after ``steps`` FMU steps."""
    res = float(iw[-2][np.count_nonzero(iw[-3]) - 1])
    return (f"the implicit exchange did not converge over the step from t = {t:.6g} (H = {H:g}): after "
            f"{steps} FMU steps the end force still differs from the law at the end states by {res:.3g} "
            f"(tolerance {float(iw[-1][0]):g} times the force scale); the step is not accepted and the "
            f"record ends at its start: lower H")


def implicit_work(N: int, n: int, E: int, steps: int, tol: float = IMPLICIT_TOL, ibuf=None, Minv=None):
    """The implicit exchange's arrays (``keep[7]`` of :func:`exchange_chunk`, unpacked in
    :func:`implicit_step`): ``ta, te, g, r, rp, gp`` (N, n); the block quasi-Newton's work ``nw``
    (:func:`fmu_sync.cosim_newton.newton_work`; ``ibuf`` the loop's impact-counter buffer at
    ``ptr[P_IBUF]``, ``Minv`` (N, n, n) each FMU's M^-1 or None); ``bh`` (E,) the branches held (``E`` edges); ``offb`` (steps,), ``iters``
    (steps,) int64 and ``resid`` (steps,) per communication step; ``tolv`` (1,) the tolerance.
    ``steps`` = 0 for an explicit run (nothing per step)."""
    z = (lambda: np.zeros((N, n)))
    ibuf = np.zeros(1, dtype=np.int32) if ibuf is None else ibuf
    nw = newton_work(N, n, ibuf, Minv) if steps else newton_work(1, n, ibuf)
    return (z(), z(), z(), z(), z(), z(), nw, np.zeros(E, dtype=np.int64), np.zeros(steps, dtype=np.int64),
            np.zeros(steps, dtype=np.int64), np.full(steps, np.nan), np.array([float(tol)]))


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
    :func:`exchange_chunk`), never returned or stored."""
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
    no_prior = 0 if flags[EVENT_AWARE] else 1
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


@njit(cache=True, inline="always")
def _scale(g, ta, q, u, Kp, Kd):
    """The force scale of the implicit exchange's tolerance: the largest force at either end of
    the step plus the largest law terms Kp q and Kd u could carry (round-off of the law)."""
    fmax = 0.0
    xq = 0.0
    xu = 0.0
    for i in range(g.shape[0]):
        for c in range(g.shape[1]):
            fmax = max(fmax, abs(g[i, c]), abs(ta[i, c]))
            xq = max(xq, abs(q[i, c]))
            xu = max(xu, abs(u[i, c]))
    kp = 0.0
    kd = 0.0
    for a in range(Kp.shape[0]):
        for b in range(Kp.shape[1]):
            kp = max(kp, abs(Kp[a, b]))
            kd = max(kd, abs(Kd[a, b]))
    return fmax + kp * xq + kd * xu


@njit(cache=True, inline="always")
def _residual(g, te, r):
    """r = g - te; returns max |r| (inf if an entry is not finite)."""
    rmax = 0.0
    for i in range(g.shape[0]):
        for c in range(g.shape[1]):
            r[i, c] = g[i, c] - te[i, c]
            rmax = max(rmax, abs(r[i, c])) if math.isfinite(r[i, c]) else math.inf
    return rmax


@njit(cache=True, inline="always")
def _dot(a, b):
    s = 0.0
    for i in range(a.shape[0]):
        for c in range(a.shape[1]):
            s += a[i, c] * b[i, c]
    return s


@njit(cache=True, inline="always")
def _trust(te):
    """Every iterate inside the trust region: each force component clipped to +-TRUST * INPUT_BOUND
    (a box: the quasi-Newton secants stay exact, since they are built from the forces applied)."""
    b = TRUST * INPUT_BOUND
    for i in range(te.shape[0]):
        for c in range(te.shape[1]):
            if te[i, c] > b:
                te[i, c] = b
            elif te[i, c] < -b:
                te[i, c] = -b


@njit(cache=True)
def implicit_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, t, h, k, q, u, tau, hist_tau, hist, ctl,
                   saved, qs, us, iw, w, FAIL, fail_t, hp):
    """The implicit exchange over [t, t + h] (docs/design.md §4.4): the force over the step is the
    line from ``ta`` (the law at the states at t) to ``te`` (first-order hold: value and input
    derivative) or their mean held (zero-order hold); ``te`` is iterated until it equals the law
    at the states the step ends in, to :data:`IMPLICIT_TOL` (``iw[-1][0]``) times :func:`_scale`.
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
    imp0, impc, ibuf = nw[5], nw[6], nw[8]
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
    _trust(te)
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
        rmax = _residual(g, te, r)
        target = tolv[0] * _scale(g, ta, q, u, Kp, Kd)
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
            rmax = _residual(g, te, r)
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
                rmax = _residual(g, te, r)
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
                    omega = -omega * (_dot(rp, r) - _dot(rp, rp)) / dr
            copy_rows(r, rp)
            for i in range(N):
                for c in range(n):
                    te[i, c] += omega * r[i, c]
        else:
            newton_update(nw, te, r, rmax, 0.1 * target, g, q, u, laws, geo, Kp, Kd, E2, W2, w, hp, t + h)
        fresh = False
        _trust(te)
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


@njit(cache=True)
def exchange_chunk(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, H, H_last, t_last, k0, k1, q, u,
                   tau, tau_next, hist_tau, hist, imp, ctl, saved, keep, T, Qr, Ur, TAU, D, BR, EU, w, FAIL, fail_t):
    """Communication steps ``k0 .. k1 - 1`` (time ``k H``); ``k0 = -1`` first reads the start
    states and impact counters and records row 0.

    The run ends exactly at ``t_last`` (docs/design.md §2.3): its last step
    ``k = flags[STEPS] - 1`` has the length ``H_last`` (``t_end - k H``; ``H`` itself, bit for
    bit, when t_end is a multiple of H) and ends at ``t_last``; the final state is always
    recorded (also when ``flags[RECORD_EVERY]`` does not divide the steps).

    ``ptr`` (:data:`P_VR_OUT` ...) the addresses of the arrays the FMI calls read or write:
    the value references of q, u (2n,), of tau (n,) and of the impact counter (1,), the
    derivative orders (n,) int32 ones, ``tau``, ``w[9]`` (2n,) and ``w[10]`` (n,) (outputs
    and slopes), ``keep[6]`` (1,) int32, ``saved``; ``fn`` (N, len(CALLS)) function
    addresses, ``comp`` (N,) component handles. ``flags`` (:data:`GAUSS_SEIDEL` ...); ``q, u, tau``
    (N, n) the current states and inputs; ``tau_next`` (N, n) the delayed orders' forces
    for the next step; ``hist_tau``, ``hist`` (time) the first-order
    hold's history; ``imp`` (N,); ``ctl`` (row, retakes, history valid); ``saved`` (N,) FMU
    state handles; ``keep``: copies for the retake (q, u, hist_tau, hist, ctl) and ``keep[7]`` the
    implicit exchange's work (:func:`implicit_work`; its per-step iterations and residuals). The record
    arrays are preallocated for the whole run. Returns the outcome code (also ``FAIL[0]``)
    and the last step done."""
    (ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, q, u, tau, tau_next, hist_tau, hist, imp, ctl, saved, keep,
     T, Qr, Ur, TAU, D, BR, EU, w, FAIL, fail_t) = unmanaged((ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, hp, q,
                                                              u, tau, tau_next, hist_tau, hist, imp, ctl, saved, keep,
                                                              T, Qr, Ur, TAU, D, BR, EU, w, FAIL, fail_t))
    N = q.shape[0]
    need_d = flags[NEED_D] != 0
    jacobi = flags[GAUSS_SEIDEL] == 0 and flags[DELAY] == NOT_DELAYED   # the record may compute tau
    qs, us, hts, hs, scratch, imp_new, ibuf, iw = keep
    FAIL[0] = DONE
    if k0 < 0:
        for i in range(N):
            if _read(ptr, fn, comp, i, w[9], q, u, FAIL, fail_t, 0.0):
                return FAIL[0], 0
        if read_impacts(ptr, fn, comp, ibuf, imp, FAIL, fail_t, 0.0):
            return FAIL[0], 0
        if flags[COUPLED]:
            network_forces(laws, geo, Kp, Kd, E2, W2, q, u, tau, w[0], w[1], w[2], w[3], w[4], w[5], False,
                           w[6], w[7], w[8], hp, 0.0)
        if flags[DELAY] == DELAYED_ZERO:   # the first two steps are held at 0
            for i in range(N):
                for c in range(q.shape[1]):
                    tau[i, c] = 0.0
            ctl[ZERO_STEPS] = 1
        if flags[DELAY]:
            copy_rows(tau, tau_next)
        record_row(0, 0.0, q, u, tau, laws, geo, Kp, Kd, E2, W2, need_d, jacobi, ctl, T, Qr, Ur, TAU, D, BR, EU, scratch,
                w, hp)
        ctl[ROW] = 1
        k0 = 0
    every = flags[RECORD_EVERY]
    last = flags[STEPS] - 1
    for k in range(k0, k1):
        t = k * H
        h = H
        t_next = (k + 1) * H
        pieces = flags[PIECES]
        if k == last:   # the last step lands on t_end
            h = H_last
            t_next = t_last
            pieces = flags[PIECES_LAST]
        if flags[IMPLICIT]:
            if implicit_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, t, h, k, q, u, tau, hist_tau, hist,
                              ctl, saved, qs, us, iw, w, FAIL, fail_t, hp):
                return FAIL[0], k
            if read_impacts(ptr, fn, comp, ibuf, imp_new, FAIL, fail_t, t + h):
                return FAIL[0], k
        else:
            if flags[EVENT_AWARE]:
                if fmu_states(ptr, fn, comp, GET_STATE, saved, FAIL, fail_t, t):
                    return FAIL[0], k
                copy_rows(q, qs)
                copy_rows(u, us)
                copy_rows(hist_tau, hts)
                hs[0] = hist[0]
                hs[1] = ctl[HIST_VALID]
            if exchange_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, t, h, q, u, tau,
                         tau_next, hist_tau, hist, ctl, w, FAIL, fail_t, hp):
                return FAIL[0], k
            if read_impacts(ptr, fn, comp, ibuf, imp_new, FAIL, fail_t, t + h):
                return FAIL[0], k
            if flags[EVENT_AWARE]:
                moved = False
                for i in range(N):
                    if imp_new[i] != imp[i]:
                        moved = True
                if moved:  # restore every instance to t and retake [t, t + h] in pieces of about H_min
                    copy_rows(hts, hist_tau)
                    hist[0] = hs[0]
                    ctl[HIST_VALID] = np.int64(hs[1])
                    ctl[RETAKES] += 1
                    if fmu_states(ptr, fn, comp, SET_STATE, saved, FAIL, fail_t, t):
                        return FAIL[0], k
                    copy_rows(qs, q)
                    copy_rows(us, u)
                    for p in range(pieces):
                        tp = t + p * (h / pieces)
                        hpc = (t + h) - tp if p == pieces - 1 else h / pieces
                        if exchange_step(ptr, fn, comp, laws, geo, Kp, Kd, E2, W2, flags, tp, hpc, q,
                                     u, tau, tau_next, hist_tau, hist, ctl, w, FAIL, fail_t, hp):
                            return FAIL[0], k
                    if read_impacts(ptr, fn, comp, ibuf, imp_new, FAIL, fail_t, t + h):
                        return FAIL[0], k
                if fmu_states(ptr, fn, comp, FREE_STATE, saved, FAIL, fail_t, t + h):
                    return FAIL[0], k
        for i in range(N):
            imp[i] = imp_new[i]
        for i in range(N):
            for c in range(q.shape[1]):
                if not (math.isfinite(q[i, c]) and math.isfinite(u[i, c])):
                    fail_at(FAIL, fail_t, STATE_DIVERGED, -1, -1, 0, t_next)
                    return FAIL[0], k
        if (k + 1) % every == 0 or k == last:   # the final state is always a row
            row = ctl[ROW]
            if not record_row(row, t_next, q, u, tau, laws, geo, Kp, Kd, E2, W2, need_d, jacobi, ctl, T, Qr, Ur, TAU, D,
                           BR, EU, scratch, w, hp):
                fail_at(FAIL, fail_t, DISTANCE_DIVERGED, -1, -1, 0, t_next)
                return FAIL[0], k
            ctl[ROW] = row + 1
    return DONE, k1
