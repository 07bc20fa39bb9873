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
from .core.result import NetworkResult, PairResult

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


def cosimulate_network(fmu, states, A, t_end: float, H: float, coupling: str | None = "switching",
                       Kp=0.0, Kd=0.0, Q=None, method: str = "jacobi", record_every: int = 1,
                       event_aware: bool = False, H_min: float | None = None,
                       start_values=None, progress=None,
                       record_distance: bool = True, allow_unstable: bool = False) -> NetworkResult:
    """Co-simulate N instances of ``fmu`` coupled on a weighted graph (SPEC §5, §8).

    ``states``: N start states (q, u); ``A``: N×N weights a_ij >= 0 (zero
    diagonal); system i receives ``tau_i = sum_j a_ij tau_i^(j)``, with
    ``tau_i^(j)`` the force of the pairwise law (``coupling``, gains ``Kp``,
    ``Kd``, norm weight ``Q``) on i in the pair (i, j); ``coupling`` is one law
    name for every edge or a sequence of names, one per edge in the order of
    ``result.edges`` (:func:`fmu_sync.core.network.edges_of`). The monolithic
    reference is :func:`fmu_sync.core.network.simulate_network` (reproduced to
    round-off at H = dt with Jacobi). Other arguments as
    :func:`cosimulate`; Gauss–Seidel updates the instances in index order, each
    one's input computed from the newest states of the others.
    ``start_values``: one dict of parameter start values for every instance, or
    a sequence of N dicts (or None), one per instance (non-identical systems:
    K, C, f0, forcing may differ; M, w, g0 and e must not).
    The stability of the held exchange over ``H`` is checked before the first
    step by :func:`fmu_sync.core.exchange.check_exchange` (refused with
    ``UnstableExchange``, a ValueError, unless ``allow_unstable``). A run whose
    states or distances become non-finite stops there: ``result.error`` says
    so and the record ends at the last finite row.
    """
    from fmpy import extract, read_model_description

    from .core.coupling import chain_work, gain_matrix
    from .core.distance import geometry
    from .core.exchange import check_exchange, exchange_limit
    from .core.network import coupled_weights, edge_laws, edges_of, weights
    from .core.pair import LAWS, check_common_geometry, coupling_step

    H = _check_positive("H", H)
    t_end = float(t_end)
    if not (math.isfinite(t_end) and t_end > 0.0):
        raise ValueError(f"t_end must be a positive finite time, got {t_end}")
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
    A = weights(A, N)
    edges = edges_of(A)
    laws = edge_laws(coupling, edges)
    coupled = bool(np.any(laws != LAWS[None]))
    if start_values is None or isinstance(start_values, dict):
        per_instance = [dict(start_values or {})] * N
    else:
        per_instance = [dict(v or {}) for v in start_values]
        if len(per_instance) != N:
            raise ValueError(f"start_values must be one dict or a sequence of N = {N} dicts (one per "
                             f"instance), got {len(per_instance)}")

    fmu = str(fmu)
    if not Path(fmu).is_file():
        raise FileNotFoundError(f"FMU not found: {fmu}")
    md = read_model_description(fmu)
    unzipdir = extract(fmu)  # one unpacked copy shared by all instances, removed at the end
    slaves: list[Slave] = []
    try:
        for i in range(N):
            slaves.append(Slave(unzipdir, md, f"system{i + 1}"))
        n = _dofs(slaves[0])
        qn, un, taun = (_names(slaves[0], b, n) for b in ("q", "u", "tau"))
        for s, sv in zip(slaves, per_instance):
            s.set(sv)
        systems = [system_from_fmu(s) for s in slaves]
        check_common_geometry(systems, [f"instance {i + 1}" for i in range(N)])
        system = systems[0]
        Kp_m, Kd_m = gain_matrix(Kp, n, "Kp"), gain_matrix(Kd, n, "Kd")
        limit = None
        if coupled:
            limit = check_exchange(system.M, Kp_m, Kd_m, H, A=coupled_weights(A, edges, laws),
                                   allow_unstable=allow_unstable)
        for i, (s, x) in enumerate(zip(slaves, states)):
            label = f"x{i + 1}"
            q0, u0 = as_state(system, x, label)
            if system.gap(q0) < 0.0:
                raise ValueError(f"{label} violates the constraint: g(q) = {system.gap(q0):.6g} < 0 "
                                 f"(need g >= 0)")
            start = dict(zip(_names(s, "q_start", n) + _names(s, "u_start", n), list(q0) + list(u0)))
            s.initialize(0.0, start)
        need_d = bool(record_distance) or coupled
        geo = geometry(system, Q)
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

        def pair(k, x, want_d):
            """The pairwise law of edge k = (i, j) at states x: fills t1 (on i), t2 (on j)."""
            i, j = edges[k]
            return coupling_step(laws[k], geo, Kp_m, Kd_m, x[i][0], x[i][1], x[j][0], x[j][1], t1, t2,
                                 *work, want_d)

        def input_of(i, x):
            """tau_i = sum_j a_ij tau_i^(j) at states x (Gauss-Seidel: one node at a time)."""
            tau[i] = 0.0
            for k, (a, b) in enumerate(edges):
                if i == a and A[a, b] > 0.0:
                    pair(k, x, False)
                    tau[i] += A[a, b] * t1
                elif i == b and A[b, a] > 0.0:
                    pair(k, x, False)
                    tau[i] += A[b, a] * t2

        def inputs(x):
            """tau_i for every i at states x (Jacobi): each edge's law evaluated once."""
            tau[:] = 0.0
            for k, (a, b) in enumerate(edges):
                pair(k, x, False)
                if A[a, b] > 0.0:
                    tau[a] += A[a, b] * t1
                if A[b, a] > 0.0:
                    tau[b] += A[b, a] * t2

        def check_forces(i, t, h):
            if not np.all(np.isfinite(tau[i])):
                lim = exchange_limit(system.M, Kp_m, Kd_m, h, coupled_weights(A, edges, laws))
                raise SlaveError(f"system{i + 1}", t, "coupling", 3, [
                    f"its coupling force became non-finite ({tau[i].tolist()}): the explicit "
                    f"exchange is unstable for these gains and this step ({lim.message()}): lower "
                    f"Kp or H, or add Kd"])

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
                    D[row, k], BR[row, k], EU[row, k] = pair(k, x, True)

        def diverged(t, what):
            hint = f" ({limit.message()})" if limit is not None else ""
            return (f"the co-simulation diverged: {what} became non-finite at t = {t:.6g}; the run "
                    f"stopped there and the record ends at the last finite row{hint}")

        x = [read(s) for s in slaves]
        if coupled:
            inputs(x)
        record(0, 0.0, x, tau)
        row, error, retakes = 1, None, 0
        imp = [s.get_integer("impacts") for s in slaves]
        report_every = max(1, n_steps // 200)
        for k in range(n_steps):
            t = k * H
            try:
                if event_aware:
                    saved = [s.save() for s in slaves]
                new = exchange(t, H, x)
                now = [s.get_integer("impacts") for s in slaves]
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
                        now = [s.get_integer("impacts") for s in slaves]
                    for s, st in zip(slaves, saved):
                        s.free_state(st)
                imp = now
                x = new
            except SlaveError as ex:
                error = str(ex)
                break
            if not all(np.all(np.isfinite(xi[0])) and np.all(np.isfinite(xi[1])) for xi in x):
                error = diverged((k + 1) * H, "a state")
                break
            if (k + 1) % record_every == 0:
                record(row, (k + 1) * H, x, tau.copy())
                if need_d and not np.all(np.isfinite(D[row])):
                    error = diverged((k + 1) * H, "a distance")
                    break
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
        with np.errstate(over="ignore"):  # a failed run may end on huge (finite) d
            V = 0.5 * (D[sl] ** 2) @ a_sym
    return NetworkResult(T[sl], Qr[sl], Ur[sl], TAU[sl], edges,
                         D[sl] if need_d else None, BR[sl] if need_d else None,
                         EU[sl] if need_d else None, V, impacts=imp,
                         info=dict(mode="cosim", H=H, method=method, event_aware=event_aware,
                                   H_min=H_min if event_aware else None, retaken_steps=retakes,
                                   fmu=fmu, steps=n_steps, coupling=coupling,
                                   **({} if limit is None else dict(
                                       omega_c_H=limit.h, exchange_bound=limit.bound,
                                       zeta=limit.zeta, H_max=limit.H_max))),
                         error=error)


def cosimulate(fmu, x1, x2, t_end: float, H: float, coupling: str | None = None, Kp=0.0, Kd=0.0,
               Q=None, method: str = "jacobi", record_every: int = 1, event_aware: bool = False,
               H_min: float | None = None, start_values=None, progress=None,
               record_distance: bool = True, allow_unstable: bool = False) -> PairResult:
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
    start_values : extra parameter start values, one dict for both instances (e.g.
        ``{"e": 0.8}``) or a pair of dicts, one per instance (non-identical systems,
        e.g. ``[{}, {"k": 1.05}]``; M, w, g0 and e must agree).
    allow_unstable : run even if the held exchange is unstable at ``H`` (by default
        refused before the first step with ``UnstableExchange``, a ValueError).
    progress : callable ``progress(fraction)`` or None.

    Returns a :class:`PairResult`. If a slave fails, the run stops there: the
    result holds everything recorded up to the failure and ``result.error`` names
    the slave, the time and the reason. (The pair is the two-node graph of
    :func:`cosimulate_network`.)
    """
    r = cosimulate_network(fmu, [x1, x2], [[0.0, 1.0], [1.0, 0.0]], t_end, H, coupling, Kp, Kd, Q,
                           method, record_every, event_aware, H_min, start_values, progress,
                           record_distance, allow_unstable)
    d = r.d is not None
    return PairResult(r.t, r.q[:, 0], r.u[:, 0], r.q[:, 1], r.u[:, 1], r.tau[:, 0], r.tau[:, 1],
                      r.d[:, 0] if d else None, r.branch[:, 0] if d else None,
                      r.euclidean[:, 0] if d else None, impacts1=r.impacts[0], impacts2=r.impacts[1],
                      coupling=coupling, info=r.info, error=r.error)
