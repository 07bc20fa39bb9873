"""Co-simulation master (docs/design.md §4.4): two (or N) FMU instances coupled
through the coupling law of the core, driven by fmpy's ``FMU2Slave``.

The master holds no model data of its own: the FMU contract
(:mod:`fmu_sync.fmus.contract`) names the variables, and the mass matrix, the
wall (w, g0) and the restitution e it needs for the quotient distance are read
from the FMU's parameters. The coupling forces and the distance are computed by
the core's compiled :func:`fmu_sync.core.pair.coupling_step` — the same function
the monolithic :func:`fmu_sync.core.simulate_pair` calls every step. With ``H``
equal to the slaves' internal step the two runs agree to round-off.

Structure (after fmpy's ``simulate_fmu``): :class:`FmuInstance` is a thin,
status-checked wrapper of one instance; :class:`NetworkMaster` holds one run,
with one method per exchange strategy (``step_jacobi``, ``step_gauss_seidel``;
a new strategy is one more ``step_<name>`` method), the event-aware retake and
the recording as methods; :func:`cosimulate_network` and :func:`cosimulate`
are the plain functional entry points.

Failure convention (docs/design.md §5.1): bad arguments or a foreign FMU raise
a ValueError before any instance is created; a slave that fails mid-run raises
:class:`SlaveError` (a :class:`fmu_sync.core.RunFailed`) whose ``partial``
holds everything recorded up to the failure.
"""
from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .core.checks import check_run, check_start, check_step, coupling_omega
from .core.coupling import chain_work, gain_matrix
from .core.distance import geometry
from .core.errors import RunFailed
from .core.model import MechanicalSystem, as_state
from .core.pair import LAWS, coupling_step
from .core.result import PairResult, RunStatus
from .fmus import contract

__all__ = ["cosimulate", "cosimulate_network", "NetworkMaster", "NetworkResult", "SlaveError", "FmuInstance",
           "fmu_model", "system_from_fmu"]

STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")


class SlaveError(RunFailed):
    """A slave answered an FMI call with a status worse than fmi2Warning."""

    def __init__(self, slave: str, t: float, call: str, status: int, log: list[str]):
        reason = log[-1] if log else "no message logged"
        label = STATUS[status] if 0 <= status < len(STATUS) else str(status)
        super().__init__(f"slave {slave!r} failed at t = {t:.6g}: {call} returned fmi2{label}: {reason}")
        self.slave, self.t, self.call, self.status, self.log = slave, t, call, status, list(log)


class FmuInstance:
    """One FMU instance as the master uses it: the status-returning
    :class:`fmu_sync.fmi_bridge.FMUHost`, with every status worse than
    fmi2Warning turned into a :class:`SlaveError` naming the instance, the time
    and the FMU's logged reason."""

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


def fmu_model(md):
    """The contract's model of an FMU (from its model description); a foreign FMU
    raises :class:`fmu_sync.fmus.contract.ContractError` naming the missing variables."""
    return contract.identify([v.name for v in md.modelVariables], md.modelName)


def system_from_fmu(instance: FmuInstance, model=None) -> MechanicalSystem:
    """The geometry the distance needs (M, w, g0, e), read from the FMU's parameters
    named by the FMU contract (K = C = f0 = 0: only M, w, g0 and e enter the
    distance and the coupling)."""
    model = model or fmu_model(instance.host.md)
    return model.geometry_system(dict(zip(model.geometry, instance.get(list(model.geometry)))))


@dataclass
class NetworkResult(RunStatus):
    """Sampled co-simulation of N coupled instances on a weighted graph.

    ``q, u, tau``: (rows, N, n); ``edges``: the coupled pairs (i, j), i < j;
    ``d, euclidean`` (rows, n_edges) and ``branch`` (rows, n_edges) per edge;
    ``V = 1/2 sum_edges a_ij d_ij^2`` (rows,) with a_ij the mean of the two
    directed weights; ``impacts`` (N,). ``error`` names a failed slave (only on
    the ``partial`` result of a :class:`SlaveError`).
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


class NetworkMaster:
    """One co-simulation run of N instances of one FMU coupled on a weighted graph.

    The constructor checks every argument (ValueError) and identifies the FMU
    through the contract; :meth:`run` creates the instances, runs and frees them.
    Exchange strategies are the methods ``step_<method>`` (``method`` with ``-``
    read as ``_``): each takes one communication step ``[t, t + h]`` from the
    states ``x`` and returns the new states.
    """

    METHODS = ("jacobi", "gauss-seidel")

    def __init__(self, fmu, states, A, t_end: float, H: float, coupling: str | None = "switching",
                 Kp=0.0, Kd=0.0, Q=None, method: str = "jacobi", record_every: int = 1,
                 event_aware: bool = False, H_min: float | None = None, start_values: dict | None = None,
                 record_distance: bool = True):
        H, n_steps, record_every = check_run(t_end, H, record_every, dt_name="H")
        if coupling not in LAWS:
            raise ValueError(f"coupling must be one of {list(LAWS)}, got {coupling!r}")
        if method not in self.METHODS:
            raise ValueError(f"method must be {' or '.join(repr(m) for m in self.METHODS)}, got {method!r}")
        if event_aware:
            H_min = H / 16 if H_min is None else check_step(H_min, "H_min")
            if H_min > H:
                raise ValueError(f"H_min must not exceed H = {H}, got {H_min}")
        if n_steps < 1:
            raise ValueError(f"t_end = {t_end} is shorter than one communication step H = {H}")
        self.states = list(states)
        self.N = N = len(self.states)
        if N < 2:
            raise ValueError(f"a network needs at least 2 states, got {N}")
        self.A = _weights(A, N)
        self.edges = [(i, j) for i in range(N) for j in range(i + 1, N)
                      if self.A[i, j] > 0.0 or self.A[j, i] > 0.0]
        self.fmu = str(fmu)
        if not Path(self.fmu).is_file():
            raise FileNotFoundError(f"FMU not found: {self.fmu}")
        from fmpy import read_model_description
        self.md = read_model_description(self.fmu)
        self.model = fmu_model(self.md)  # a foreign FMU fails here, naming what it lacks
        self.H, self.n_steps, self.record_every = H, n_steps, record_every
        self.coupling, self.law = coupling, LAWS[coupling]
        self.Kp, self.Kd, self.Q = Kp, Kd, Q
        self.method, self.exchange = method, getattr(self, "step_" + method.replace("-", "_"))
        self.event_aware, self.H_min = event_aware, H_min
        self.start_values = dict(start_values or {})
        self.need_d = record_distance or self.law != LAWS[None]
        self.slaves: list[FmuInstance] = []
        self.retakes = 0

    # ------------------------------------------------------------ set-up
    def _start(self, unzipdir: str) -> None:
        model, N = self.model, self.N
        for i in range(N):
            self.slaves.append(FmuInstance(unzipdir, self.md, f"system{i + 1}"))
        for s in self.slaves:
            s.set(self.start_values)
        self.system = system = system_from_fmu(self.slaves[0], model)
        for i, (s, x) in enumerate(zip(self.slaves, self.states)):
            label = f"x{i + 1}"
            q0, u0 = as_state(system, x, label)
            check_start(system, q0, label)
            s.initialize(0.0, model.state_values(q0, u0))
        n = model.n
        self.geo = geometry(system, self.Q)
        self.Kp_m, self.Kd_m = gain_matrix(self.Kp, n, "Kp"), gain_matrix(self.Kd, n, "Kd")
        E, rows = len(self.edges), self.n_steps // self.record_every + 1
        self.T = np.full(rows, np.nan)
        self.Qr, self.Ur, self.TAU = (np.full((rows, N, n), np.nan) for _ in range(3))
        self.D, self.EU = np.full((rows, E), np.nan), np.full((rows, E), np.nan)
        self.BR = np.full((rows, E), -1, dtype=np.int64)
        self.tau = np.zeros((N, n))
        self.t1, self.t2 = np.zeros(n), np.zeros(n)
        self.work = chain_work(n)

    def read(self, s: FmuInstance) -> list:
        v = s.get(self.model.q + self.model.u)
        n = self.model.n
        return [v[:n].copy(), v[n:].copy()]

    # ------------------------------------------------------------ coupling
    def pair(self, i: int, j: int, x, want_d: bool):
        """The pairwise law on edge (i, j) at states x: fills t1 (on i), t2 (on j)."""
        return coupling_step(self.law, self.geo, self.Kp_m, self.Kd_m, x[i][0], x[i][1], x[j][0], x[j][1],
                             self.t1, self.t2, *self.work, want_d)

    def input_of(self, i: int, x) -> None:
        """tau_i = sum_j a_ij tau_i^(j) at states x (one node at a time)."""
        A, tau = self.A, self.tau
        tau[i] = 0.0
        for a, b in self.edges:
            if i == a and A[a, b] > 0.0:
                self.pair(a, b, x, False)
                tau[i] += A[a, b] * self.t1
            elif i == b and A[b, a] > 0.0:
                self.pair(a, b, x, False)
                tau[i] += A[b, a] * self.t2

    def inputs(self, x) -> None:
        """tau_i for every i at states x: each edge's law evaluated once."""
        A, tau = self.A, self.tau
        tau[:] = 0.0
        for a, b in self.edges:
            self.pair(a, b, x, False)
            if A[a, b] > 0.0:
                tau[a] += A[a, b] * self.t1
            if A[b, a] > 0.0:
                tau[b] += A[b, a] * self.t2

    def check_forces(self, i: int, t: float, h: float) -> None:
        if not np.all(np.isfinite(self.tau[i])):
            wc = coupling_omega(self.system, self.Kp_m) * h
            raise SlaveError(f"system{i + 1}", t, "coupling", 3, [
                f"its coupling force became non-finite ({self.tau[i].tolist()}): the explicit "
                f"exchange is unstable for these gains and this step (coupling omega_c*H = "
                f"{wc:.3g}; stable only below min(4 zeta, 1/zeta) <= 2): lower Kp or H, or add Kd"])

    def _give(self, i: int, s: FmuInstance, t: float, h: float) -> None:
        s.set(dict(zip(self.model.tau, self.tau[i])))
        s.do_step(t, h)

    # ------------------------------------------------------------ exchange strategies
    def step_jacobi(self, t: float, h: float, x) -> list:
        """Every instance gets its input from the same states x, then all step."""
        self.inputs(x)
        for i in range(self.N):
            self.check_forces(i, t, h)
        for i, s in enumerate(self.slaves):
            self._give(i, s, t, h)
        return [self.read(s) for s in self.slaves]

    def step_gauss_seidel(self, t: float, h: float, x) -> list:
        """Instances step in index order, each input from the newest states of the others."""
        x = [list(xi) for xi in x]
        for i, s in enumerate(self.slaves):
            self.input_of(i, x)
            self.check_forces(i, t, h)
            self._give(i, s, t, h)
            x[i] = self.read(s)
        return x

    def communication_step(self, t: float, x, impacts: list) -> tuple[list, list]:
        """One step of length H from t; event-aware: retaken in pieces of H_min if an
        impact counter moved. Returns (new states, impact counters)."""
        if not self.event_aware:
            new = self.exchange(t, self.H, x)
            return new, [s.get_integer(contract.IMPACTS) for s in self.slaves]
        saved = [s.save() for s in self.slaves]
        new = self.exchange(t, self.H, x)
        now = [s.get_integer(contract.IMPACTS) for s in self.slaves]
        if now != impacts:
            new, now = self.retake(t, x, saved)
        for s, st in zip(self.slaves, saved):
            s.free_state(st)
        return new, now

    def retake(self, t: float, x, saved) -> tuple[list, list]:
        """Restore every instance to t and retake [t, t + H] in pieces of about H_min."""
        H = self.H
        self.retakes += 1
        for s, st in zip(self.slaves, saved):
            s.restore(st, t)
        pieces = max(1, int(math.ceil(H / self.H_min - 1e-9)))
        new = x
        for p in range(pieces):
            tp = t + p * (H / pieces)
            hp = (t + H) - tp if p == pieces - 1 else H / pieces
            new = self.exchange(tp, hp, new)
        return new, [s.get_integer(contract.IMPACTS) for s in self.slaves]

    # ------------------------------------------------------------ recording
    def record(self, row: int, t: float, x, held) -> None:
        self.T[row] = t
        for i in range(self.N):
            self.Qr[row, i], self.Ur[row, i] = x[i]
        self.TAU[row] = held
        if self.need_d:
            for k, (i, j) in enumerate(self.edges):
                self.D[row, k], self.BR[row, k], self.EU[row, k] = self.pair(i, j, x, True)

    def result(self, rows: int, impacts: list, error: str | None) -> NetworkResult:
        sl, need_d, A = slice(0, rows), self.need_d, self.A
        V = None
        if need_d:
            a_sym = np.array([0.5 * (A[i, j] + A[j, i]) for i, j in self.edges])
            V = 0.5 * (self.D[sl] ** 2) @ a_sym
        return NetworkResult(
            self.T[sl], self.Qr[sl], self.Ur[sl], self.TAU[sl], self.edges,
            self.D[sl] if need_d else None, self.BR[sl] if need_d else None,
            self.EU[sl] if need_d else None, V, impacts=impacts,
            info=dict(mode="cosim", H=self.H, method=self.method, event_aware=self.event_aware,
                      H_min=self.H_min if self.event_aware else None, retaken_steps=self.retakes,
                      fmu=self.fmu, steps=self.n_steps, coupling=self.coupling),
            error=error)

    # ------------------------------------------------------------ the run
    def run(self, progress=None) -> NetworkResult:
        """Run to t_end; raises :class:`SlaveError` (``partial``: the record so far) if a slave fails."""
        from fmpy import extract
        unzipdir = extract(self.fmu)  # one unpacked copy shared by all instances, removed at the end
        failure = None
        try:
            self._start(unzipdir)
            x = [self.read(s) for s in self.slaves]
            if self.law != LAWS[None]:
                self.inputs(x)
            self.record(0, 0.0, x, self.tau)
            row = 1
            imp = [s.get_integer(contract.IMPACTS) for s in self.slaves]
            n_steps, H = self.n_steps, self.H
            report_every = max(1, n_steps // 200)
            for k in range(n_steps):
                try:
                    x, imp = self.communication_step(k * H, x, imp)
                except SlaveError as ex:
                    failure = ex
                    break
                if (k + 1) % self.record_every == 0:
                    self.record(row, (k + 1) * H, x, self.tau.copy())
                    row += 1
                if progress is not None and (k + 1) % report_every == 0:
                    progress((k + 1) / n_steps)
            if progress is not None:
                progress(1.0)
        finally:
            for s in self.slaves:
                s.close()
            shutil.rmtree(unzipdir, ignore_errors=True)
        res = self.result(row, imp, None if failure is None else str(failure))
        if failure is not None:
            failure.partial = res
            raise failure
        return res


def cosimulate_network(fmu, states, A, t_end: float, H: float, coupling: str | None = "switching",
                       Kp=0.0, Kd=0.0, Q=None, method: str = "jacobi", record_every: int = 1,
                       event_aware: bool = False, H_min: float | None = None,
                       start_values: dict | None = None, progress=None,
                       record_distance: bool = True) -> NetworkResult:
    """Co-simulate N instances of ``fmu`` coupled on a weighted graph (docs/design.md §2.5, §4.4).

    ``states``: N start states (q, u); ``A``: N×N weights a_ij >= 0 (zero
    diagonal); system i receives ``tau_i = sum_j a_ij tau_i^(j)``, with
    ``tau_i^(j)`` the force of the pairwise law (``coupling``, gains ``Kp``,
    ``Kd``, norm weight ``Q``) on i in the pair (i, j). Other arguments as
    :func:`cosimulate`; Gauss–Seidel updates the instances in index order, each
    one's input computed from the newest states of the others.
    """
    return NetworkMaster(fmu, states, A, t_end, H, coupling, Kp, Kd, Q, method, record_every, event_aware,
                         H_min, start_values, record_distance).run(progress)


def _pair_result(r: NetworkResult, coupling) -> PairResult:
    d = r.d is not None
    return PairResult(r.t, r.q[:, 0], r.u[:, 0], r.q[:, 1], r.u[:, 1], r.tau[:, 0], r.tau[:, 1],
                      r.d[:, 0] if d else None, r.branch[:, 0] if d else None,
                      r.euclidean[:, 0] if d else None, impacts1=r.impacts[0], impacts2=r.impacts[1],
                      coupling=coupling, info=r.info, error=r.error)


def cosimulate(fmu, x1, x2, t_end: float, H: float, coupling: str | None = None, Kp=0.0, Kd=0.0,
               Q=None, method: str = "jacobi", record_every: int = 1, event_aware: bool = False,
               H_min: float | None = None, start_values: dict | None = None, progress=None,
               record_distance: bool = True) -> PairResult:
    """Co-simulate two instances of ``fmu`` coupled by ``coupling`` (docs/design.md §2.5, §4.4).

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

    Returns a :class:`PairResult`. Bad arguments, or an FMU that does not follow
    the FMU contract, raise a ValueError naming what is wrong. If a slave fails,
    the run stops there and raises :class:`SlaveError`; its ``partial`` is the
    :class:`PairResult` recorded up to the failure, whose ``error`` names the
    slave, the time and the reason. (The pair is the two-node graph of
    :func:`cosimulate_network`.)
    """
    try:
        r = cosimulate_network(fmu, [x1, x2], [[0.0, 1.0], [1.0, 0.0]], t_end, H, coupling, Kp, Kd, Q,
                               method, record_every, event_aware, H_min, start_values, progress,
                               record_distance)
    except SlaveError as exc:
        exc.partial = _pair_result(exc.partial, coupling)
        raise
    return _pair_result(r, coupling)
