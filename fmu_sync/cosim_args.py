"""The compiled loop's arguments by name, and their one builder (docs/design.md §4.4).

:func:`loop_arguments` makes what :func:`fmu_sync.cosim_loop.loop_start` and the one driver
:func:`fmu_sync.cosim_driver.drive` take for a run of a
:class:`fmu_sync.master.NetworkMaster`: :class:`LoopArgs` (what a run does not change),
:class:`LoopState` (the state between chunks and the record) with its :class:`Keep` (a rolled-back
step's copies), :class:`Work` (scratch) and :class:`ImplicitWork` (the implicit exchange's arrays);
the flags filled by name (:func:`named_flags`, the strategies' own from the registry
:mod:`fmu_sync.strategies`) and ``ptr``, the addresses of :class:`fmu_sync.cosim_loop.Held`'s
fields in their order. The kernels unpack these named tuples (numba types them by their fields);
the layouts the kernels index by integer (``ptr``'s slots, ``flags``) stay in
:mod:`fmu_sync.cosim_loop`, whose cached kernels they are compiled into.
"""
from __future__ import annotations

import ctypes
from typing import NamedTuple

import numpy as np

from .core.checks import run_steps
from .core.coupling import chain_work
from .core.network import edge_arrays
from . import cosim_loop
from .cosim_loop import CALLS, CTL, FLAG_NAMES, IMPLICIT_TOL, Held
from .cosim_newton import NewtonWork, newton_work
from .fmus import contract
from .strategies import flags_of

__all__ = ["Work", "ImplicitWork", "Keep", "LoopArgs", "LoopState", "fmi_functions", "named_flags",
           "loop_arguments", "implicit_info", "not_converged", "implicit_work", "with_room"]


class Work(NamedTuple):
    """The loop's scratch arrays: the law's chain work (t1 .. c2u, :func:`fmu_sync.core.coupling.chain_work`),
    each edge's distance, branch and Euclidean distance (E,), the outputs' buffer (2n,) and the slope (n,)."""
    t1: np.ndarray
    t2: np.ndarray
    c1q: np.ndarray
    c1u: np.ndarray
    c2q: np.ndarray
    c2u: np.ndarray
    dk: np.ndarray
    bk: np.ndarray
    ek: np.ndarray
    buf: np.ndarray
    slope: np.ndarray


class ImplicitWork(NamedTuple):
    """The implicit exchange's arrays (:func:`implicit_work`): ``ta, te, g, r, rp, gp`` (N, n); the
    block quasi-Newton's work ``nw``; ``bh`` (E,) the branches held; per accepted step ``offb``,
    ``iters`` (int64) and ``resid``; ``tolv`` (1,) the tolerance."""
    ta: np.ndarray
    te: np.ndarray
    g: np.ndarray
    r: np.ndarray
    rp: np.ndarray
    gp: np.ndarray
    nw: NewtonWork
    bh: np.ndarray
    offb: np.ndarray
    iters: np.ndarray
    resid: np.ndarray
    tolv: np.ndarray


class Keep(NamedTuple):
    """The copies a rolled-back step restores (states, input history, its time and validity in
    ``hs``), the record's scratch forces, the new impact counters, the impact-counter buffer and
    the implicit exchange's work."""
    qs: np.ndarray
    us: np.ndarray
    hts: np.ndarray
    hs: np.ndarray
    scratch: np.ndarray
    imp_new: np.ndarray
    ibuf: np.ndarray
    iw: ImplicitWork


class LoopArgs(NamedTuple):
    """What the kernels take that a run does not change (the first arguments of :func:`fmu_sync.cosim_driver.drive`)."""
    ptr: np.ndarray
    fn: np.ndarray
    comp: np.ndarray
    laws: np.ndarray
    geo: tuple
    Kp: np.ndarray
    Kd: np.ndarray
    E2: np.ndarray
    W2: np.ndarray
    flags: np.ndarray
    hp: np.ndarray
    H: float
    H_last: float
    t_last: float


class LoopState(NamedTuple):
    """The loop's state between chunks and its record (the last arguments of :func:`fmu_sync.cosim_driver.drive`)."""
    q: np.ndarray
    u: np.ndarray
    tau: np.ndarray
    tau_next: np.ndarray
    hist_tau: np.ndarray
    hist: np.ndarray
    imp: np.ndarray
    ctl: np.ndarray
    saved: np.ndarray
    keep: Keep
    T: np.ndarray
    Qr: np.ndarray
    Ur: np.ndarray
    TAU: np.ndarray
    D: np.ndarray
    BR: np.ndarray
    EU: np.ndarray
    w: Work
    FAIL: np.ndarray
    fail_t: np.ndarray


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


def named_flags(**values) -> np.ndarray:
    """The loop's ``flags`` array from its values by name (:data:`FLAG_NAMES`; unnamed ones 0)."""
    unknown = sorted(set(values) - set(FLAG_NAMES))
    if unknown:
        raise ValueError(f"unknown loop flag {unknown[0]!r} (the loop's flags: {', '.join(FLAG_NAMES)})")
    return np.array([int(values.get(k, 0)) for k in FLAG_NAMES], dtype=np.int64)


def loop_arguments(m) -> None:
    """What :func:`fmu_sync.cosim_driver.drive` takes for the run of a :class:`fmu_sync.master.NetworkMaster`
    ``m`` (set up, its instances started): every instance's FMI function addresses and component
    handle (a function its settings need but its binary lacks: ValueError), the value references,
    the settings (``flags``) and the loop's state between chunks, as ``m.loop_args`` and
    ``m.loop_state`` (the arrays the loop writes also as attributes of ``m``)."""
    model, N, n = m.model, m.N, m.model.n
    m.fn = np.stack([fmi_functions(s.fmu.dll) for s in m.slaves])
    rollback = next((st.selected_by for st in m.strategies if st.rollback), None)
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
    pieces = (lambda h: max(1, run_steps(h, m.H_min).steps) if m.event_aware else 1)
    flags = named_flags(foh=m.hold == "foh", need_d=m.need_d, coupled=m.coupled, record_every=m.record_every,
                        steps=m.n_steps,   # the last one of length grid.dt_last, ending at grid.t_end
                        max_iter=cosim_loop.IMPLICIT_MAX_ITERATIONS, pieces=pieces(m.H), pieces_last=pieces(m.grid.dt_last),
                        **flags_of(m.strategies))   # the strategies' own: gauss_seidel, delay, implicit, event_aware
    z = (lambda: np.zeros((N, n)))
    m.q, m.u, m.tau = z(), z(), z()
    m.imp, m.ctl = np.zeros(N, dtype=np.int64), np.zeros(CTL, dtype=np.int64)
    E = len(m.edges)
    w = Work(np.zeros(n), np.zeros(n), *chain_work(n), np.zeros(E), np.zeros(E, dtype=np.int64), np.zeros(E),
             np.zeros(2 * n), np.zeros(n))
    ibuf = np.zeros(1, dtype=np.int32)
    m.iw = implicit_work(N, n, len(m.edges), m.n_steps if m.implicit else 0, ibuf=ibuf,
                         Minv=getattr(m, "Minv_nodes", None))
    keep = Keep(z(), z(), z(), np.zeros(2), z(), np.zeros(N, dtype=np.int64), ibuf, m.iw)
    m.FAIL, m.fail_t = np.zeros(4, dtype=np.int64), np.zeros(1)
    saved = np.zeros(N, dtype=np.int64)
    m.held = Held(m.vr_out, m.vr_tau, m.vr_imp, np.ones(n, dtype=np.int32), m.tau, w.buf, w.slope, keep.ibuf, saved)
    ptr = np.array([a.ctypes.data for a in m.held], dtype=np.int64)
    m.loop_args = LoopArgs(ptr, m.fn, m.comp, m.laws, m.geo, m.Kp_m, m.Kd_m, E2, W2, flags, m.hp, float(m.H),
                           float(m.grid.dt_last), float(m.grid.t_end))
    m.loop_state = LoopState(m.q, m.u, m.tau, z(), z(), np.zeros(1), m.imp, m.ctl, saved, keep, m.T, m.Qr, m.Ur,
                             m.TAU, m.D, m.BR, m.EU, w, m.FAIL, m.fail_t)


def implicit_info(iw) -> dict:
    """``info`` of an implicit run: ``iterations`` (FMU steps per communication step taken, int64),
    ``residuals`` (each one's final max |law(end states) - end force|), ``exchange_tol``,
    ``off_branch`` (per step, the edges whose end force was accepted on a branch other than the
    switching law's own at the end states: the law's branch changed within the step, §4.4); {} for
    an explicit run (``iw`` None or without per-step arrays)."""
    if iw is None or iw.iters.size == 0:
        return {}
    done = int(np.count_nonzero(iw.iters))
    return dict(iterations=iw.iters[:done].copy(), residuals=iw.resid[:done].copy(), exchange_tol=float(iw.tolv[0]),
                off_branch=iw.offb[:done].copy())


def not_converged(iw, t: float, H: float, steps: int) -> str:
    """The message of a step from ``t`` that did not converge after ``steps`` FMU steps."""
    res = float(iw.resid[np.count_nonzero(iw.iters) - 1])
    return (f"the implicit exchange did not converge over the step from t = {t:.6g} (H = {H:g}): after "
            f"{steps} FMU steps the end force still differs from the law at the end states by {res:.3g} "
            f"(tolerance {float(iw.tolv[0]):g} times the force scale); the step is not accepted and the "
            f"record ends at its start: lower H")


def implicit_work(N: int, n: int, E: int, steps: int, tol: float = IMPLICIT_TOL, ibuf=None, Minv=None):
    """The implicit exchange's arrays (:class:`ImplicitWork`, ``keep.iw`` of :func:`fmu_sync.cosim_driver.drive`, unpacked in
    :func:`implicit_step`): ``ta, te, g, r, rp, gp`` (N, n); the block quasi-Newton's work ``nw``
    (:func:`fmu_sync.cosim_newton.newton_work`; ``ibuf`` the loop's impact-counter buffer at
    ``ptr[P_IBUF]``, ``Minv`` (N, n, n) each FMU's M^-1 or None); ``bh`` (E,) the branches held (``E`` edges); ``offb`` (steps,), ``iters``
    (steps,) int64 and ``resid`` (steps,) per communication step; ``tolv`` (1,) the tolerance.
    ``steps`` = 0 for an explicit run (nothing per step)."""
    z = (lambda: np.zeros((N, n)))
    ibuf = np.zeros(1, dtype=np.int32) if ibuf is None else ibuf
    nw = newton_work(N, n, ibuf, Minv) if steps else newton_work(1, n, ibuf)
    return ImplicitWork(z(), z(), z(), z(), z(), z(), nw, np.zeros(E, dtype=np.int64), np.zeros(steps, dtype=np.int64),
                        np.zeros(steps, dtype=np.int64), np.full(steps, np.nan), np.array([float(tol)]))


def with_room(iw: ImplicitWork, cap: int) -> ImplicitWork:
    """``iw`` whose per-step arrays (``offb``, ``iters``, ``resid``) hold ``cap`` steps, the
    steps so far kept (the tolerance controller grows them with its record)."""
    def grown(a, fill):
        b = np.full(cap, fill, dtype=a.dtype)
        b[:min(cap, a.size)] = a[:cap]
        return b
    return iw._replace(offb=grown(iw.offb, 0), iters=grown(iw.iters, 0), resid=grown(iw.resid, np.nan))
