"""Co-simulation master (SPEC §8): two (or N) FMU instances coupled through the
coupling law of the core, driven by fmpy's ``FMU2Slave``.

The master holds no model data of its own: the mass matrix, the wall (w, g0)
and the restitution e it needs for the quotient distance are read from the
FMU's parameters, and the coupling forces and the distance are computed by the
core's compiled :func:`fmu_sync.core.pair.coupling_step` — the same function
the monolithic :func:`fmu_sync.core.pair.simulate_pair` calls every step.
With ``H`` equal to the slaves' internal step the two runs agree to round-off.

Structure (after fmpy's ``simulate_fmu``): :class:`Slave` is a thin,
status-checked wrapper of one instance; :func:`cosimulate` is the plain
functional entry point.
"""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np

from .core.model import MechanicalSystem, as_state
from .core.result import PairResult

__all__ = ["cosimulate", "SlaveError", "Slave", "system_from_fmu"]

STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")


class SlaveError(RuntimeError):
    """A slave answered an FMI call with a status worse than fmi2Warning."""

    def __init__(self, slave: str, t: float, call: str, status: int, log: list[str]):
        reason = log[-1] if log else "no message logged"
        label = STATUS[status] if 0 <= status < len(STATUS) else str(status)
        super().__init__(f"slave {slave!r} failed at t = {t:.6g}: {call} returned fmi2{label}: {reason}")
        self.slave, self.t, self.call, self.status, self.log = slave, t, call, status, list(log)


class Slave:
    """One FMU instance as the master uses it: the status-returning
    :class:`fmu_sync.fmi_bridge.FMUHost`, with every status worse than
    fmi2Warning turned into a :class:`SlaveError` naming the slave, the time and
    the FMU's logged reason."""

    def __init__(self, unzipdir: str, md, name: str):
        from .fmi_bridge import FMUHost
        self.name = name
        self.t = 0.0
        self.host = FMUHost(unzipdir, instance_name=name, model_description=md)
        self.vr = self.host.variables

    def _check(self, call: str, status: int):
        if status > 1:
            raise SlaveError(self.name, self.t, call, status,
                             self.host.errors(min_status=1) or [m for _, _, m in self.host.messages])

    def get(self, names) -> np.ndarray:
        values = self.host.get(names)
        self._check("fmi2GetReal", self.host.last_status)
        return np.array(values, dtype=np.float64)

    def get_integer(self, name: str) -> int:
        value = self.host.get([name])[0]
        self._check("fmi2GetInteger", self.host.last_status)
        return int(value)

    def set(self, values: dict) -> None:
        self._check("fmi2SetReal", self.host.set(values))

    def initialize(self, t0: float, start_values: dict) -> None:
        self.t = t0
        self._check("initialization", self.host.initialize(t0, start_values))

    def do_step(self, t: float, h: float) -> None:
        self.t = t
        self._check("fmi2DoStep", self.host.do_step(t, h))
        self.t = t + h

    def save(self):
        status, state = self.host.get_state()
        self._check("fmi2GetFMUstate", status)
        return state

    def restore(self, state, t: float) -> None:
        self._check("fmi2SetFMUstate", self.host.set_state(state))
        self.t = t

    def free_state(self, state) -> None:
        self._check("fmi2FreeFMUstate", self.host.free_state(state))

    def close(self) -> None:
        self.host.close()


def _names(slave: Slave, base: str, n: int) -> list[str]:
    if n == 1 and base in slave.vr:
        return [base]
    return [f"{base}[{i + 1}]" for i in range(n)]


def _dofs(slave: Slave) -> int:
    if "q" in slave.vr:
        return 1
    n = 0
    while f"q[{n + 1}]" in slave.vr:
        n += 1
    if n == 0:
        raise KeyError(f"FMU {slave.md.modelName!r} has no output 'q' or 'q[1]': not an fmu-sync mechanical model")
    return n


def system_from_fmu(slave: Slave) -> MechanicalSystem:
    """The geometry the distance needs (M, w, g0, e), read from the FMU's parameters.

    The 1-DOF impact oscillator exposes ``m`` (and, if present, ``w``/``g0``;
    its wall is q >= 0 otherwise); n-DOF models expose ``M[i,j]``, ``w[i]``, ``g0``.
    Only M, w, g0 and e enter the distance and the coupling, so K, C, f0 are zero here.
    """
    n = _dofs(slave)
    if n == 1 and "m" in slave.vr:
        M = slave.get(["m"]).reshape(1, 1)
    else:
        M = slave.get([f"M[{i + 1},{j + 1}]" for i in range(n) for j in range(n)]).reshape(n, n)
    if n == 1 and "w" in slave.vr:
        w = slave.get(["w"])
    elif f"w[1]" in slave.vr:
        w = slave.get(_names(slave, "w", n))
    else:
        w = np.ones(1)
    g0 = float(slave.get(["g0"])[0]) if "g0" in slave.vr else 0.0
    e = float(slave.get(["e"])[0])
    z = np.zeros((n, n))
    return MechanicalSystem(M=M, K=z, C=z, f0=np.zeros(n), w=w, g0=g0, e=e)


def _check_positive(name, value):
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a positive finite number, got {value}")
    return value


def cosimulate(fmu, x1, x2, t_end: float, H: float, coupling: str | None = None, Kp=0.0, Kd=0.0,
               Q=None, method: str = "jacobi", record_every: int = 1, event_aware: bool = False,
               H_min: float | None = None, start_values: dict | None = None, progress=None,
               record_distance: bool = True) -> PairResult:
    """Co-simulate two instances of ``fmu`` coupled by ``coupling`` (SPEC §5, §8).

    Parameters
    ----------
    fmu : path to the .fmu (an fmu-sync mechanical model, see ``fmu-sync export``).
    x1, x2 : start states (q, u) of the two instances (set as ``q_start``/``u_start``).
    t_end, H : stop time and communication step; the run makes ``round(t_end/H)`` steps.
    coupling : None, ``"switching"`` (quotient coupling) or ``"euclidean"`` (PD baseline).
    Kp, Kd : gains (scalars or n×n).  Q : position weight of the norm (default identity).
    method : ``"jacobi"`` (both slaves get inputs computed from the same states) or
        ``"gauss-seidel"`` (slave 2's input uses slave 1's updated state).
    record_every : keep every k-th communication point.
    event_aware : when a slave's impact counter moves during a step, restore both
        slaves and retake the step in pieces of ``H_min`` (default ``H/16``) so the
        coupling sees the impact.
    start_values : extra parameter start values for both instances (e.g. ``{"e": 0.8}``).
    progress : callable ``progress(fraction)`` or None.

    Returns a :class:`PairResult`. If a slave fails, the run stops there: the
    result holds everything recorded up to the failure and ``result.error`` names
    the slave, the time and the reason.
    """
    from fmpy import extract, read_model_description

    from .core.coupling import chain_work, gain_matrix
    from .core.distance import geometry
    from .core.pair import LAWS, coupling_step

    H = _check_positive("H", H)
    t_end = float(t_end)
    if not (math.isfinite(t_end) and t_end > 0.0):
        raise ValueError(f"t_end must be a positive finite time, got {t_end}")
    if coupling not in LAWS:
        raise ValueError(f"coupling must be one of {list(LAWS)}, got {coupling!r}")
    if method not in ("jacobi", "gauss-seidel"):
        raise ValueError(f"method must be 'jacobi' or 'gauss-seidel', got {method!r}")
    record_every = int(record_every)
    if record_every < 1:
        raise ValueError(f"record_every must be >= 1, got {record_every}")
    if event_aware:
        H_min = H / 16 if H_min is None else _check_positive("H_min", H_min)
        if H_min > H:
            raise ValueError(f"H_min must not exceed H = {H}, got {H_min}")
    n_steps = int(math.floor(t_end / H + 1e-9))
    if n_steps < 1:
        raise ValueError(f"t_end = {t_end} is shorter than one communication step H = {H}")

    fmu = str(fmu)
    if not Path(fmu).is_file():
        raise FileNotFoundError(f"FMU not found: {fmu}")
    md = read_model_description(fmu)
    unzipdir = extract(fmu)  # one unpacked copy shared by both instances, removed at the end
    slaves: list[Slave] = []
    law = LAWS[coupling]
    try:
        for i in range(2):
            slaves.append(Slave(unzipdir, md, f"system{i + 1}"))
        s1, s2 = slaves
        n = _dofs(s1)
        qn, un, taun = _names(s1, "q", n), _names(s1, "u", n), _names(s1, "tau", n)
        extra = dict(start_values or {})
        for s in slaves:
            s.set(extra)
        system = system_from_fmu(s1)
        for s, x, label in ((s1, x1, "x1"), (s2, x2, "x2")):
            q0, u0 = as_state(system, x, label)
            if system.gap(q0) < 0.0:
                raise ValueError(f"{label} violates the constraint: g(q) = {system.gap(q0):.6g} < 0 "
                                 f"(need g >= 0)")
            start = dict(zip(_names(s, "q_start", n) + _names(s, "u_start", n), list(q0) + list(u0)))
            s.initialize(0.0, start)
        system = system_from_fmu(s1)
        need_d = record_distance or law != LAWS[None]
        geo = geometry(system, Q)
        Kp_m, Kd_m = gain_matrix(Kp, n, "Kp"), gain_matrix(Kd, n, "Kd")

        rows = n_steps // record_every + 1
        T = np.full(rows, np.nan)
        Q1, U1, Q2, U2 = (np.full((rows, n), np.nan) for _ in range(4))
        TAU1, TAU2 = np.full((rows, n), np.nan), np.full((rows, n), np.nan)
        D, BR, EU = np.full(rows, np.nan), np.zeros(rows, dtype=np.int64), np.full(rows, np.nan)
        tau1, tau2 = np.zeros(n), np.zeros(n)
        work = chain_work(n)

        def read(s):
            v = s.get(qn + un)
            return v[:n].copy(), v[n:].copy()

        def forces(q1, u1, q2, u2):
            return coupling_step(law, geo, Kp_m, Kd_m, q1, u1, q2, u2, tau1, tau2, *work, need_d)

        def record(row, t, q1, u1, q2, u2, dbe):
            T[row] = t
            Q1[row], U1[row], Q2[row], U2[row] = q1, u1, q2, u2
            TAU1[row], TAU2[row] = tau1, tau2
            if need_d:
                D[row], BR[row], EU[row] = dbe

        def exchange(t, h, q1, u1, q2, u2):
            """One communication step of length h from t; returns the new states."""
            forces(q1, u1, q2, u2)
            s1.set(dict(zip(taun, tau1)))
            if method == "jacobi":
                s2.set(dict(zip(taun, tau2)))
                s1.do_step(t, h)
                s2.do_step(t, h)
                return read(s1) + read(s2)
            s1.do_step(t, h)
            q1n, u1n = read(s1)
            t1_hold = tau1.copy()
            forces(q1n, u1n, q2, u2)
            tau1[:] = t1_hold
            s2.set(dict(zip(taun, tau2)))
            s2.do_step(t, h)
            return (q1n, u1n) + read(s2)

        q1, u1 = read(s1)
        q2, u2 = read(s2)
        dbe = forces(q1, u1, q2, u2) if need_d else None
        record(0, 0.0, q1, u1, q2, u2, dbe)
        row, error, retakes = 1, None, 0
        imp = [s1.get_integer("impacts"), s2.get_integer("impacts")]
        report_every = max(1, n_steps // 200)
        for k in range(n_steps):
            t = k * H
            try:
                if event_aware:
                    states = [s.save() for s in slaves]
                new = exchange(t, H, q1, u1, q2, u2)
                now = [s1.get_integer("impacts"), s2.get_integer("impacts")]
                if event_aware:
                    if now != imp:
                        retakes += 1
                        for s, st in zip(slaves, states):
                            s.restore(st, t)
                        pieces = max(1, int(math.ceil(H / H_min - 1e-9)))
                        new = (q1, u1, q2, u2)
                        for j in range(pieces):
                            tj = t + j * (H / pieces)
                            hj = (t + H) - tj if j == pieces - 1 else H / pieces
                            new = exchange(tj, hj, *new)
                        now = [s1.get_integer("impacts"), s2.get_integer("impacts")]
                    for s, st in zip(slaves, states):
                        s.free_state(st)
                imp = now
                q1, u1, q2, u2 = new
            except SlaveError as ex:
                error = str(ex)
                break
            if (k + 1) % record_every == 0:
                tnext = (k + 1) * H
                dbe = None
                if need_d:
                    held = tau1.copy(), tau2.copy()
                    dbe = forces(q1, u1, q2, u2)
                    tau1[:], tau2[:] = held
                record(row, tnext, q1, u1, q2, u2, dbe)
                row += 1
            if progress is not None and (k + 1) % report_every == 0:
                progress((k + 1) / n_steps)
        if progress is not None:
            progress(1.0)
    finally:
        for s in slaves:
            s.close()
        shutil.rmtree(unzipdir, ignore_errors=True)

    sl = slice(0, row)
    res = PairResult(T[sl], Q1[sl], U1[sl], Q2[sl], U2[sl], TAU1[sl], TAU2[sl],
                     D[sl] if need_d else None, BR[sl] if need_d else None, EU[sl] if need_d else None,
                     impacts1=imp[0], impacts2=imp[1], coupling=coupling,
                     info=dict(mode="cosim", H=H, method=method, event_aware=event_aware,
                               H_min=H_min if event_aware else None, retaken_steps=retakes,
                               fmu=fmu, steps=n_steps),
                     error=error)
    return res
