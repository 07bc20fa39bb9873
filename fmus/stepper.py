"""The FMU's hot path: one numba ``cfunc`` that the C binary calls per fmi2DoStep.

    int32 step(double *x, double *work, double t, double H)

``x`` is the FMU's variable array (indexed by value reference), ``work`` the
instance's work array: a header (the H_* slots, shared with
``fmus/c/fmu_sync_runtime.h``: FSR_H_*) followed by the system's arrays as the core's
kernels take them (:class:`fmu_sync.core.model.SystemArrays`, packed by
:func:`pack`). The cfunc rebuilds the ``SystemArrays`` as views of ``work``,
makes exactly one call to the core's :func:`fmu_sync.core.moreau.advance_in`
(``advance`` in the work array's scratch, nothing allocated)
(all internal steps; the input held, or with the first-order hold
``tau + taudot (t - t_c)`` when the master set input derivatives) -- or, with
``solver.scheme = exact`` (1-DOF), one call to the core's exact communication
step :func:`fmu_sync.core.exact.exact_step` (closed-form flow, impacts,
completed accumulations and persistent contact; tau constant over the step) --
and writes q, u, gap, energy, impacts and percussion into ``x``. It returns
one of the ``R_*`` codes: 0 done; after rolling the step back, 1 when the state
(or an output) became non-finite or left the state bound (``|q|, |u| <=
contract.STATE_BOUND``), 3 when the exact solver met more than its work guard
``EXACT_MAX_EVENTS`` events in the step, 4 when it could not decide a contact;
or 2 (nothing done) when the exact scheme is given a non-zero input derivative. ``H == 0`` only recomputes
gap and energy (used after a restore, so that the outputs are the very same
numbers).

FMI 3.0 early return (the header's ``H_MODE``, set by ``fmu_sync_fmi3.c``): with
MODE_EARLY the step stops at the first impact inside ``(t, t + H)`` -- the exact
scheme at the impact instant (``core.exact.exact_step_early``), a Moreau scheme at
the end of the first internal step with a positive percussion (the step is redone
internal step by internal step with ``advance_in``'s own time and last-step
rules) -- and writes the time reached into ``H_REACHED``. MODE_EARLY_EVENT stops
the exact scheme just before the impact (the left limit) and keeps the impact
pending (``H_PEND_U``, ``H_PEND_P``) until a call in MODE_APPLY_EVENT
(fmi3UpdateDiscreteStates) applies it.

Work array: the header (H_* slots), the system (:func:`pack`), a save area of
2n slots, the exact model (``core.exact.exact_model``, 1-DOF only, at
``H_IEXACT``) and, last, the m input derivatives (at ``H_ITAUDOT``: set by the
binary's fmi2SetRealInputDerivatives, consumed by the next doStep). The exact
run's velocity scale ``vref`` lives in ``H_VREF`` (part of the FMU state).

No Python object is touched: the binary calls it without the GIL. Compiled with
``cache=True``; its source path is stable because the FMU's code is unpacked to
a per-user cache folder keyed on its content (see ``boot.py``).
"""
from __future__ import annotations

import math

import numpy as np
from ..core.jit import carray, cfunc, njit

from ..core.exact_step import NT as _EXACT_NT
from ..core.exact_step import STEP_OK, STEP_TOO_MANY_EVENTS, exact_step_early
from ..core.model import SystemArrays
from ..core.moreau import MIDPOINT, OK, THETA, TRAPEZOID, advance_in, substeps
from .contract import SCHEME_EXACT as EXACT
from .contract import STATE_BOUND
from .workarray import mat, put, put_wall, wall

__all__ = ["step", "STEP_SIGNATURE", "pack", "work_size", "H_LEN", "H_VERSION", "H_TIME", "H_PHASE", "H_DT",
           "H_CONFIGURED", "WORK_VERSION", "H_FEEDTHROUGH", "H_VREF", "H_ITAUDOT", "H_IEXACT", "H_MAXEV", "H_BOUND",
           "EXACT", "exact_size", "law_params",
           "EXACT_MAX_EVENTS", "R_OK", "R_ROLLED_BACK", "R_EXACT_TAUDOT", "R_EXACT_EVENTS", "R_EXACT_STALL",
           "R_INADMISSIBLE",
           "H_MODE", "H_REACHED", "H_PEND_U", "H_PEND_P", "H_ICOUNT", "MODE_FULL", "MODE_EARLY",
           "MODE_EARLY_EVENT", "MODE_APPLY_EVENT"]

# --- header slots (those the C binary reads are written into fmu_sync_constants.h at export)
H_LEN, H_VERSION, H_TIME, H_PHASE, H_DT, H_CONFIGURED = 0, 1, 2, 3, 4, 5
H_N, H_M, H_NF, H_SCHEME, H_THETA, H_NX = 6, 7, 8, 9, 10, 11
H_IQ, H_IU, H_ITAU, H_IGAP, H_IENERGY, H_IIMPACTS, H_IPERC = 12, 13, 14, 15, 16, 17, 18
# (read by the C binary too: H_M, H_SCHEME, H_ITAU, H_ITAUDOT, H_FEEDTHROUGH, H_MAXEV, H_BOUND)
H_VREF, H_ITAUDOT, H_IEXACT = 19, 20, 21
#: read by the C binary: != 0 when the outputs depend directly on the inputs (0 here; the coupling FMU)
H_FEEDTHROUGH = 22
H_MAXEV, H_BOUND = 23, 24
# FMI 3.0 (read and written by fmu_sync_fmi3.c): the step mode (MODE_*), the time a
# step reached (t + H or an early return), the pending impact of an early return in
# event mode (post-impact velocity, its percussion; H_PEND_P > 0 while pending), and
# the offset of the per-slot FMI 3.0 variable sizes (runtime.FMUInstance)
H_MODE, H_REACHED, H_PEND_U, H_PEND_P, H_ICOUNT = 25, 26, 27, 28, 29
H_DATA = 30
#: the one version of what the binary and the Python side share (work array header,
#: layout, codes): fmu_sync_constants.h, generated at export, carries it
WORK_VERSION = 6   # 5: the native stepper (no stepper in the layout); 6: + the coupling's admissibility memory
#: work guard of the exact scheme: most events (impacts, contact changes, flow
#: pieces) in one doStep; more makes the step fail (rolled back, fmi2Error) in
#: well under a second instead of running for minutes (H = 1e9)
EXACT_MAX_EVENTS = 100_000
#: return codes of :func:`step` (read by fmus/c/fmu_sync_runtime.c)
R_OK, R_ROLLED_BACK, R_EXACT_TAUDOT, R_EXACT_EVENTS, R_EXACT_STALL = 0, 1, 2, 3, 4
#: return code of the coupling FMU's stepper (fmus/coupling_stepper.py): outputs computed, but an
#: input state lies inside the wall beyond the Moreau penetration (core.checks.penetration_bound)
R_INADMISSIBLE = 5
#: step modes (H_MODE): to the end of the step (FMI 2.0; FMI 3.0 without early return);
#: stop at the first impact with the impact handled (early return, no event mode); stop
#: at the first impact before it (early return in event mode: the exact scheme keeps the
#: impact pending for fmi3UpdateDiscreteStates); apply the pending impact (H ignored)
MODE_FULL, MODE_EARLY, MODE_EARLY_EVENT, MODE_APPLY_EVENT = 0, 1, 2, 3


def exact_size(n: int, m: int, nf: int) -> int:
    """Slots of the packed exact model (``core.exact.exact_model``; 0 for n > 1)."""
    return 0 if n != 1 else 4 + 16 + _EXACT_NT + 4 + m + nf * (3 + 2 * _EXACT_NT)


@njit(cache=True, inline="always")
def _scratch(n, m, nf):
    """Slots of the Moreau step's scratch (``core.moreau.advance_in``)."""
    return 6 * n + n * n + 4 * nf + m


def work_size(n: int, m: int, nf: int, nx: int = 0, n_p: int = 0) -> int:
    """Length of the work array for n DOF, m inputs, nf harmonic forces (and the nx
    FMI 3.0 variable sizes, placed just before the m input derivatives; and the n_p
    parameters of a user force law, just before those: :func:`law_params`)."""
    system = H_DATA + 4 * n * n + n + nf * n + 2 * nf + n * m + n + 2 + n + 1
    return system + 2 * n + _scratch(n, m, nf) + exact_size(n, m, nf) + n_p + nx + m


#: the parameters of the stepper's force law in the work array (0: the built-in linear law; a
#: user law's stepper, :mod:`.law_stepper`, is compiled with its own)
N_P = 0
#: a user law's stepper (:mod:`.law_stepper`) runs ``solver.scheme = trapezoid`` with the law's trapezoid
#: copy of advance_in (``ForceLaw.kernels(trapezoid=True)``: the core's default, second order); the
#: built-in law's advance_in serves every scheme
LAW_TRAPEZOID = False
advance_in_trapezoid = advance_in


@njit(cache=True, inline="always")
def law_params(w, n_p):
    """The n_p parameters p of a user force law in the work array (just before the FMI 3.0
    variable sizes at ``H_ICOUNT``; packed by :func:`pack`)."""
    i = int(w[H_ICOUNT])
    return w[i - n_p:i]


def pack(work: np.ndarray, sa: SystemArrays, dt: float, scheme: int, theta: float, exact=None,
         p=None) -> None:
    """Write the system ``sa`` and the solver data into ``work`` (header slots
    H_N.. and the data part; the index slots are set by the runtime);
    ``exact``: the packed exact model (``core.exact.exact_model``) for the exact scheme;
    ``p``: a user force law's parameter array (:func:`law_params`)."""
    n, m = sa.B.shape
    nf = sa.Omega.shape[0]
    need = work_size(n, m, nf)
    if need > work.shape[0]:
        raise ValueError(f"work array of {work.shape[0]} slots, the system needs {need}")
    work[H_N], work[H_M], work[H_NF] = n, m, nf
    work[H_SCHEME], work[H_THETA], work[H_DT] = scheme, theta, dt
    work[H_MAXEV] = EXACT_MAX_EVENTS
    work[H_BOUND] = STATE_BOUND
    k = put(work, H_DATA, (sa.M, sa.Minv, sa.K, sa.C, sa.f0, sa.F, sa.Omega, sa.phi, sa.B))
    k = put_wall(work, k, sa.w, sa.g0, sa.e, sa.Minv_w, sa.W)
    k += 2 * n + _scratch(n, m, nf)   # the save area and the scratch
    work[H_IEXACT] = 0.0
    n_p = 0 if p is None else len(p)
    if n_p:
        i = int(work[H_ICOUNT])
        work[i - n_p:i] = p
    if exact is not None:
        if k + exact.size > int(work[H_ICOUNT]) - n_p:
            raise ValueError(f"the exact model needs {exact.size} slots, the work array has "
                             f"{int(work[H_ICOUNT]) - k}")
        work[k:k + exact.size] = exact
        work[H_IEXACT] = k


@njit(cache=True, inline="always")
def _unpack(w):
    n = int(w[H_N])
    m = int(w[H_M])
    nf = int(w[H_NF])
    k = H_DATA
    M = mat(w, k, n, n)
    k += n * n
    Minv = mat(w, k, n, n)
    k += n * n
    K = mat(w, k, n, n)
    k += n * n
    C = mat(w, k, n, n)
    k += n * n
    f0 = w[k:k + n]
    k += n
    F = mat(w, k, nf, n)
    k += nf * n
    Omega = w[k:k + nf]
    k += nf
    phi = w[k:k + nf]
    k += nf
    B = mat(w, k, n, m)
    k += n * m
    wv, g0, e, Minv_w, W, k = wall(w, k, n)
    sa = SystemArrays(M, Minv, K, C, f0, F, Omega, phi, B, wv, g0, e, Minv_w, W)
    return sa, k


@njit(cache=True, inline="always")
def _outputs(sa, q, u):
    """gap g(q) = w^T q + g0 and energy 1/2 u^T M u + 1/2 q^T K q - f0^T q."""
    n = q.shape[0]
    g = sa.g0
    for i in range(n):
        g += sa.w[i] * q[i]
    ek = 0.0
    ep = 0.0
    for i in range(n):
        for j in range(n):
            ek += u[i] * sa.M[i, j] * u[j]
            ep += q[i] * sa.K[i, j] * q[j]
    E = 0.5 * ek + 0.5 * ep
    for i in range(n):
        E -= sa.f0[i] * q[i]
    return g, E


@njit(cache=True, inline="always")
def _advance(sa, q, u, t, H, dt, tau, taudot, scheme, theta, s, w):
    """One communication step with a Moreau scheme; (status, percussion, impacts).

    ``scheme`` is the core's scheme code (``solver.scheme`` item -> code in
    ``MechanicalSlave.configure`` via ``core.checks.scheme_code``); ``taudot``
    the input slope (zeros: bit for bit the zero-order hold); ``s`` the scratch
    (:func:`_scratch` slots); ``w`` the work array (where a user force law's stepper,
    :mod:`.law_stepper`: this function with the law's ``advance_in`` and ``N_P``, reads its
    parameters). The exact scheme is dispatched in :func:`step`.
    The place for more schemes: a new item in ``contract.SCHEME_ITEMS`` and a
    branch here."""
    n = q.shape[0]
    nf = sa.Omega.shape[0]
    m = tau.shape[0]
    if scheme == MIDPOINT or scheme == THETA or scheme == TRAPEZOID:
        foh = False
        for j in range(m):
            if taudot[j] != 0.0:
                foh = True
        # scratch: y, hf, uf, Sinv_w, qe, hb (n each), Sinv (n*n), cv, sv, cr, sr (nf each), tk (m)
        k = 6 * n + n * n
        p = law_params(w, N_P) if N_P > 0 else sa.f0   # a user law's parameters (the built-in law: unused)
        y, hf, uf, Sinv, Sinv_w = s[0:n], s[n:2 * n], s[2 * n:3 * n], mat(s, 6 * n, n, n), s[3 * n:4 * n]
        cv, sv, cr, sr = s[k:k + nf], s[k + nf:k + 2 * nf], s[k + 2 * nf:k + 3 * nf], s[k + 3 * nf:k + 4 * nf]
        qe, hb, tk = s[4 * n:5 * n], s[5 * n:6 * n], s[k + 4 * nf:k + 4 * nf + m]
        if LAW_TRAPEZOID and scheme == TRAPEZOID:   # a user law's trapezoid copy (core/law_loops.py heun)
            return advance_in_trapezoid(sa, p, q, u, t, H, dt, tau, taudot, foh, scheme, theta, False,
                                        y, hf, uf, Sinv, Sinv_w, cv, sv, cr, sr, qe, hb, tk)
        return advance_in(sa, p, q, u, t, H, dt, tau, taudot, foh, scheme, theta, False,
                          y, hf, uf, Sinv, Sinv_w, cv, sv, cr, sr, qe, hb, tk)
    # further schemes dispatch here
    return -1, 0.0, 0


#: the C signature of every FMU stepper (fsr_stepper in fmus/c/fmu_sync_runtime.h): numba's
#: text form, so that the module imports without numba (core/jit.py)
STEP_SIGNATURE = "int32(CPointer(float64), CPointer(float64), float64, float64)"


@cfunc(STEP_SIGNATURE, cache=True, nopython=True)
def step(x_ptr, w_ptr, t, H):
    w = carray(w_ptr, (int(w_ptr[H_LEN]),))
    x = carray(x_ptr, (int(w[H_NX]),))
    sa, k = _unpack(w)
    n = int(w[H_N])
    m = int(w[H_M])
    iq = int(w[H_IQ])
    iu = int(w[H_IU])
    it = int(w[H_ITAU])
    q = x[iq:iq + n]
    u = x[iu:iu + n]
    tau = x[it:it + m]
    mode = int(w[H_MODE])
    if mode == MODE_APPLY_EVENT and w[H_PEND_P] > 0.0:    # the pending impact of an early return
        u[0] = w[H_PEND_U]
        x[int(w[H_IPERC])] = w[H_PEND_P]
        x[int(w[H_IIMPACTS])] += 1
        w[H_PEND_P] = 0.0
    if H == 0.0 or mode == MODE_APPLY_EVENT:
        g, E = _outputs(sa, q, u)
        x[int(w[H_IGAP])] = g
        x[int(w[H_IENERGY])] = E
        return R_OK
    save = w[k:k + 2 * n]
    itd = int(w[H_ITAUDOT])
    taudot = w[itd:itd + m]
    for i in range(n):
        save[i] = q[i]
        save[n + i] = u[i]
    scheme = int(w[H_SCHEME])
    early = mode == MODE_EARLY or mode == MODE_EARLY_EVENT
    t_stop = t + H
    pend_u = 0.0
    pend_p = 0.0
    if scheme == EXACT:
        for j in range(m):
            if taudot[j] != 0.0:
                return R_EXACT_TAUDOT
        ie = int(w[H_IEXACT])
        st, t_stop, q1, u1, um, P, Pi, hits, vref = exact_step_early(w[ie:], q[0], u[0], t, H, tau,
                                                                     w[H_VREF], early, int(w[H_MAXEV]))
        if st == STEP_TOO_MANY_EVENTS:
            return R_EXACT_EVENTS
        if st != STEP_OK:
            return R_EXACT_STALL
        q[0] = q1
        u[0] = u1
        if Pi > 0.0 and mode == MODE_EARLY_EVENT:   # stop before the impact: left limit
            u[0] = um
            pend_u = u1
            pend_p = Pi
            P = P - Pi
            hits -= 1
        status = OK
    else:
        sc = w[k + 2 * n:k + 2 * n + _scratch(n, m, int(w[H_NF]))]
        # the step over H (kk = -1); with an early return at a percussion, again internal step by
        # internal step from the start (the same arithmetic: advance_in's t and last-step rules) up to the
        # end of the first internal step with one (kk = 0 .. ks - 1). One call site: _advance, the
        # stepper's largest part, is inlined once (half the stepper's compile, docs/design.md §5.6)
        dt = w[H_DT]
        ks = 0
        kk = -1
        while True:
            tk = t
            hk = H
            if kk >= 0:
                tk = t + kk * dt
                hk = dt
                if kk == ks - 1:
                    hk = (t + H) - tk if kk > 0 else H
            status, P, hits = _advance(sa, q, u, tk, hk, dt, tau, taudot, scheme, w[H_THETA], sc, w)
            if kk < 0:
                if not (early and hits > 0 and status == OK):
                    break
                for i in range(n):
                    q[i] = save[i]
                    u[i] = save[n + i]
                ks = substeps(H, dt)
            elif status != OK or P > 0.0:
                if kk < ks - 1:
                    t_stop = tk + hk
                break
            kk += 1
            if kk == ks:
                break
        vref = w[H_VREF]
    g, E = _outputs(sa, q, u)
    bad = status != OK or not (math.isfinite(g) and math.isfinite(E))
    bound = w[H_BOUND]
    for i in range(n):
        if not (abs(q[i]) <= bound and abs(u[i]) <= bound):
            bad = True
    if bad:
        for i in range(n):
            q[i] = save[i]
            u[i] = save[n + i]
        return R_ROLLED_BACK
    w[H_VREF] = vref
    w[H_REACHED] = t_stop
    w[H_PEND_U] = pend_u
    w[H_PEND_P] = pend_p
    for j in range(m):
        taudot[j] = 0.0                       # consumed: it applied to this step only
    x[int(w[H_IPERC])] = P
    x[int(w[H_IIMPACTS])] += hits
    x[int(w[H_IGAP])] = g
    x[int(w[H_IENERGY])] = E
    return R_OK
