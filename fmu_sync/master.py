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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .core.model import MechanicalSystem, as_state
from .core.result import PairResult
from .fmus import contract

__all__ = ["cosimulate", "cosimulate_network", "NetworkResult", "SlaveError", "Slave", "system_from_fmu"]

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
        self.enter_initialization(t0)
        self.exit_initialization(start_values)

    def enter_initialization(self, t0: float) -> None:
        """setupExperiment + enterInitializationMode: parameters are readable from here on."""
        self.t = t0
        self._check("initialization", self.host.enter_initialization(t0))

    def exit_initialization(self, start_values: dict) -> None:
        self._check("initialization", self.host.exit_initialization(start_values))

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


def fmu_model(md):
    """The contract's model of an FMU (from its model description); a foreign FMU
    raises :class:`fmu_sync.fmus.contract.ContractError` naming the missing variables."""
    return contract.identify([v.name for v in md.modelVariables], md.modelName)


def system_from_fmu(slave: Slave, model=None) -> MechanicalSystem:
    """The geometry the distance needs (M, w, g0, e), read from the FMU's parameters
    named by the FMU contract (K = C = f0 = 0: only M, w, g0 and e enter the
    distance and the coupling)."""
    model = model or fmu_model(slave.host.md)
    return model.geometry_system(dict(zip(model.geometry, slave.get(list(model.geometry)))))


def _check_positive(name, value):
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a positive finite number, got {value}")
    return value


@dataclass
class NetworkResult:
    """Sampled co-simulation of N coupled instances on a weighted graph.

    ``q, u, tau``: (rows, N, n); ``edges``: the coupled pairs (i, j), i < j;
    ``d, euclidean`` (rows, n_edges) and ``branch`` (rows, n_edges) per edge;
    ``V = 1/2 sum_edges a_ij d_ij^2`` (rows,) with a_ij the mean of the two
    directed weights; ``impacts`` (N,). ``error`` names a failed slave, if any.
    """

    t: np.ndarray
    q: np.ndarray
    u: np.ndarray
    tau: np.ndarray
    edges: list
    d: np.ndarray | None
    branch: np.ndarray | None
    euclidean: np.ndarray | None
    V: np.ndarray | None
    impacts: list
    info: dict = field(default_factory=dict)
    error: str | None = None


def _weights(A, N: int | None) -> np.ndarray:
    try:
        a = np.array(A, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"A must be an N x N matrix of weights, got {A!r}") from None
    if a.ndim != 2 or a.shape[0] != a.shape[1] or (N is not None and a.shape[0] != N):
        raise ValueError(f"A must be a square N x N weight matrix with N = number of states "
                         f"({N}), got shape {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < 0.0):
        raise ValueError(f"A must hold finite weights >= 0, got {a.tolist()}")
    if np.any(np.diag(a) != 0.0):
        raise ValueError(f"A must have a zero diagonal (no self-coupling), got {np.diag(a).tolist()}")
    return a


def cosimulate_network(fmu, states, A, t_end: float, H: float, coupling: str | None = "switching",
                       Kp=0.0, Kd=0.0, Q=None, method: str = "jacobi", record_every: int = 1,
                       event_aware: bool = False, H_min: float | None = None,
                       start_values: dict | None = None, progress=None,
                       record_distance: bool = True) -> NetworkResult:
    """Co-simulate N instances of ``fmu`` coupled on a weighted graph (SPEC §5, §8).

    ``states``: N start states (q, u); ``A``: N×N weights a_ij >= 0 (zero
    diagonal); system i receives ``tau_i = sum_j a_ij tau_i^(j)``, with
    ``tau_i^(j)`` the force of the pairwise law (``coupling``, gains ``Kp``,
    ``Kd``, norm weight ``Q``) on i in the pair (i, j). Other arguments as
    :func:`cosimulate`; Gauss–Seidel updates the instances in index order, each
    one's input computed from the newest states of the others.
    """
    from fmpy import extract, read_model_description

    from .core.coupling import chain_work, gain_matrix
    from .core.distance import geometry
    from .core.pair import LAWS, coupling_step
    from .core.simulate import coupling_omega

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
    states = list(states)
    N = len(states)
    if N < 2:
        raise ValueError(f"a network needs at least 2 states, got {N}")
    A = _weights(A, N)
    edges = [(i, j) for i in range(N) for j in range(i + 1, N) if A[i, j] > 0.0 or A[j, i] > 0.0]

    fmu = str(fmu)
    if not Path(fmu).is_file():
        raise FileNotFoundError(f"FMU not found: {fmu}")
    md = read_model_description(fmu)
    model = fmu_model(md)  # a foreign FMU fails here, naming what it lacks
    unzipdir = extract(fmu)  # one unpacked copy shared by all instances, removed at the end
    slaves: list[Slave] = []
    law = LAWS[coupling]
    try:
        for i in range(N):
            slaves.append(Slave(unzipdir, md, f"system{i + 1}"))
        n = model.n
        qn, un, taun = model.q, model.u, model.tau
        for s in slaves:
            s.enter_initialization(0.0)   # FMI 2.0: variables are readable from initialization mode on
            s.set(dict(start_values or {}))
        system = system_from_fmu(slaves[0], model)
        for i, (s, x) in enumerate(zip(slaves, states)):
            label = f"x{i + 1}"
            q0, u0 = as_state(system, x, label)
            if system.gap(q0) < 0.0:
                raise ValueError(f"{label} violates the constraint: g(q) = {system.gap(q0):.6g} < 0 "
                                 f"(need g >= 0)")
            s.exit_initialization(model.state_values(q0, u0))
        need_d = record_distance or law != LAWS[None]
        geo = geometry(system, Q)
        Kp_m, Kd_m = gain_matrix(Kp, n, "Kp"), gain_matrix(Kd, n, "Kd")
        E = len(edges)
        rows = n_steps // record_every + 1
        T = np.full(rows, np.nan)
        Qr, Ur, TAU = (np.full((rows, N, n), np.nan) for _ in range(3))
        D, EU = np.full((rows, E), np.nan), np.full((rows, E), np.nan)
        BR = np.full((rows, E), -1, dtype=np.int64)
        tau = np.zeros((N, n))
        t1, t2 = np.zeros(n), np.zeros(n)
        work = chain_work(n)

        def read(s):
            v = s.get(qn + un)
            return [v[:n].copy(), v[n:].copy()]

        def pair(i, j, x, want_d):
            """The pairwise law on edge (i, j) at states x: fills t1 (on i), t2 (on j)."""
            return coupling_step(law, geo, Kp_m, Kd_m, x[i][0], x[i][1], x[j][0], x[j][1], t1, t2,
                                 *work, want_d)

        def input_of(i, x):
            """tau_i = sum_j a_ij tau_i^(j) at states x (Gauss-Seidel: one node at a time)."""
            tau[i] = 0.0
            for a, b in edges:
                if i == a and A[a, b] > 0.0:
                    pair(a, b, x, False)
                    tau[i] += A[a, b] * t1
                elif i == b and A[b, a] > 0.0:
                    pair(a, b, x, False)
                    tau[i] += A[b, a] * t2

        def inputs(x):
            """tau_i for every i at states x (Jacobi): each edge's law evaluated once."""
            tau[:] = 0.0
            for a, b in edges:
                pair(a, b, x, False)
                if A[a, b] > 0.0:
                    tau[a] += A[a, b] * t1
                if A[b, a] > 0.0:
                    tau[b] += A[b, a] * t2

        def check_forces(i, t, h):
            if not np.all(np.abs(tau[i]) <= contract.INPUT_BOUND):   # also catches NaN
                wc = coupling_omega(system, Kp_m) * h
                raise SlaveError(f"system{i + 1}", t, "coupling", 3, [
                    f"its coupling force became non-finite or exceeds the FMU's input bound "
                    f"{contract.INPUT_BOUND:g} ({tau[i].tolist()}): the explicit "
                    f"exchange is unstable for these gains and this step (coupling omega_c*H = "
                    f"{wc:.3g}; stable only below min(4 zeta, 1/zeta) <= 2): lower Kp or H, or add Kd"])

        def exchange(t, h, x):
            """One communication step of length h from t; returns the new states."""
            x = [list(xi) for xi in x]
            if method == "jacobi":
                inputs(x)
                for i in range(N):
                    check_forces(i, t, h)
                for i, s in enumerate(slaves):
                    s.set(dict(zip(taun, tau[i])))
                    s.do_step(t, h)
                return [read(s) for s in slaves]
            for i, s in enumerate(slaves):  # Gauss-Seidel: newest states of the others
                input_of(i, x)
                check_forces(i, t, h)
                s.set(dict(zip(taun, tau[i])))
                s.do_step(t, h)
                x[i] = read(s)
            return x

        def record(row, t, x, held):
            T[row] = t
            for i in range(N):
                Qr[row, i], Ur[row, i] = x[i]
            TAU[row] = held
            if need_d:
                for k, (i, j) in enumerate(edges):
                    D[row, k], BR[row, k], EU[row, k] = pair(i, j, x, True)

        x = [read(s) for s in slaves]
        if law != LAWS[None]:
            inputs(x)
        record(0, 0.0, x, tau)
        row, error, retakes = 1, None, 0
        imp = [s.get_integer(contract.IMPACTS) for s in slaves]
        report_every = max(1, n_steps // 200)
        for k in range(n_steps):
            t = k * H
            try:
                if event_aware:
                    saved = [s.save() for s in slaves]
                new = exchange(t, H, x)
                now = [s.get_integer(contract.IMPACTS) for s in slaves]
                if event_aware:
                    if now != imp:
                        retakes += 1
                        for s, st in zip(slaves, saved):
                            s.restore(st, t)
                        pieces = max(1, int(math.ceil(H / H_min - 1e-9)))
                        new = x
                        for p in range(pieces):
                            tp = t + p * (H / pieces)
                            hp = (t + H) - tp if p == pieces - 1 else H / pieces
                            new = exchange(tp, hp, new)
                        now = [s.get_integer(contract.IMPACTS) for s in slaves]
                    for s, st in zip(slaves, saved):
                        s.free_state(st)
                imp = now
                x = new
            except SlaveError as ex:
                error = str(ex)
                break
            if (k + 1) % record_every == 0:
                record(row, (k + 1) * H, x, tau.copy())
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
    V = None
    if need_d:
        a_sym = np.array([0.5 * (A[i, j] + A[j, i]) for i, j in edges])
        V = 0.5 * (D[sl] ** 2) @ a_sym
    return NetworkResult(T[sl], Qr[sl], Ur[sl], TAU[sl], edges,
                         D[sl] if need_d else None, BR[sl] if need_d else None,
                         EU[sl] if need_d else None, V, impacts=imp,
                         info=dict(mode="cosim", H=H, method=method, event_aware=event_aware,
                                   H_min=H_min if event_aware else None, retaken_steps=retakes,
                                   fmu=fmu, steps=n_steps, coupling=coupling),
                         error=error)


def cosimulate(fmu, x1, x2, t_end: float, H: float, coupling: str | None = None, Kp=0.0, Kd=0.0,
               Q=None, method: str = "jacobi", record_every: int = 1, event_aware: bool = False,
               H_min: float | None = None, start_values: dict | None = None, progress=None,
               record_distance: bool = True) -> PairResult:
    """Co-simulate two instances of ``fmu`` coupled by ``coupling`` (SPEC §5, §8).

    Parameters
    ----------
    fmu : path to the .fmu (an fmu-sync mechanical model, see ``fmu-sync export``).
    x1, x2 : start states (q, u) of the two instances (set as ``q_start``/``u_start``).
    t_end, H : stop time and communication step; the run makes ``floor(t_end/H)`` steps.
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
    the slave, the time and the reason. (The pair is the two-node graph of
    :func:`cosimulate_network`.)
    """
    r = cosimulate_network(fmu, [x1, x2], [[0.0, 1.0], [1.0, 0.0]], t_end, H, coupling, Kp, Kd, Q,
                           method, record_every, event_aware, H_min, start_values, progress,
                           record_distance)
    d = r.d is not None
    return PairResult(r.t, r.q[:, 0], r.u[:, 0], r.q[:, 1], r.u[:, 1], r.tau[:, 0], r.tau[:, 1],
                      r.d[:, 0] if d else None, r.branch[:, 0] if d else None,
                      r.euclidean[:, 0] if d else None, impacts1=r.impacts[0], impacts2=r.impacts[1],
                      coupling=coupling, info=r.info, error=r.error)
