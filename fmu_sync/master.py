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
a ValueError before any instance is created; an exchange known to be unstable
(:func:`fmu_sync.core.exchange.check_exchange`) or instances with different
impact geometries (M, w, g0, e) raise a ValueError before the first step; a
slave that fails mid-run raises :class:`SlaveError` and a run whose states or
distances become non-finite raises :class:`fmu_sync.core.SimulationDiverged`
(both :class:`fmu_sync.core.RunFailed`) whose ``partial`` holds everything
recorded up to the failure (finite rows only).
"""
from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np

from .core.checks import check_run, check_start, check_step
from .core.coupling import chain_work, gain_matrix
from .core.distance import geometry
from .core.errors import RunFailed, SimulationDiverged
from .core.exchange import check_exchange, exchange_limit
from .core.model import MechanicalSystem, as_state
from .core.network import coupled_weights, edge_laws, edges_of, weights
from .core.pair import LAWS, check_common_geometry, coupling_step
from .core.result import NetworkResult, PairResult
from .fmi3_bridge import element_names, open_host
from .fmus import contract
from .hold import InputHistory, check_hold, check_schemes

__all__ = ["cosimulate", "cosimulate_network", "NetworkMaster", "NetworkResult", "SlaveError", "FmuInstance",
           "fmu_model", "system_from_fmu", "pair_result"]

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

    def __init__(self, unzipdir: str, md, name: str, early_return: bool = False):
        self.name, self.t = name, 0.0
        self.host = open_host(unzipdir, md, name, early_return)   # FMI 2.0 or FMI 3.0
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
        """setupExperiment + enterInitializationMode: variables are readable from here on (FMI 2.0)."""
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
    return contract.identify(element_names(md), md.modelName)


def system_from_fmu(instance: FmuInstance, model=None) -> MechanicalSystem:
    """The geometry the distance needs (M, w, g0, e), read from the FMU's parameters
    named by the FMU contract (K = C = f0 = 0: only M, w, g0 and e enter the
    distance and the coupling)."""
    model = model or fmu_model(instance.host.md)
    return model.geometry_system(dict(zip(model.geometry, instance.get(list(model.geometry)))))


class NetworkMaster:
    """One co-simulation run of N instances of one FMU coupled on a weighted graph.

    The constructor checks every argument (ValueError) and identifies the FMU
    through the contract; :meth:`run` creates the instances, runs and frees them.
    Exchange strategies are the methods ``step_<method>`` (``method`` with ``-``
    read as ``_``): each takes one communication step ``[t, t + h]`` from the
    states ``x`` and returns the new states.
    """

    METHODS = ("jacobi", "gauss-seidel")
    EARLY_RETURN = False   # FMI 3.0 instances with early return and event mode (fmu_sync.early_return)

    def __init__(self, fmu, states, A, t_end: float, H: float, coupling: str | None = "switching",
                 Kp=0.0, Kd=0.0, Q=None, method: str = "jacobi", record_every: int = 1,
                 event_aware: bool = False, H_min: float | None = None, start_values=None,
                 record_distance: bool = True, allow_unstable: bool = False, hold: str = "zoh"):
        H, n_steps, record_every = check_run(t_end, H, record_every, dt_name="H")
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
        self.A = weights(A, N)
        self.edges = edges_of(self.A)
        self.laws = edge_laws(coupling, self.edges)  # one law per edge
        self.coupled = bool(np.any(self.laws != LAWS[None]))
        if start_values is None or isinstance(start_values, dict):
            self.start_values = [dict(start_values or {})] * N
        else:
            self.start_values = [dict(v or {}) for v in start_values]
            if len(self.start_values) != N:
                raise ValueError(f"start_values must be one dict or a sequence of N = {N} dicts (one "
                                 f"per instance), got {len(self.start_values)}")
        self.fmu = str(fmu)
        if not Path(self.fmu).is_file():
            raise FileNotFoundError(f"FMU not found: {self.fmu}")
        from fmpy import read_model_description
        self.md = read_model_description(self.fmu)
        self.model = fmu_model(self.md)  # a foreign FMU fails here, naming what it lacks
        self.hold = check_hold(hold, self.md, self.fmu)
        self.H, self.n_steps, self.record_every = H, n_steps, record_every
        self.coupling = coupling
        self.allow_unstable = bool(allow_unstable)
        self.limit = None
        self.Kp, self.Kd, self.Q = Kp, Kd, Q
        self.method, self.exchange = method, getattr(self, "step_" + method.replace("-", "_"))
        self.event_aware, self.H_min = event_aware, H_min
        self.need_d = bool(record_distance) or self.coupled
        self.slaves: list[FmuInstance] = []
        self.retakes = 0

    # ------------------------------------------------------------ set-up
    def _start(self, unzipdir: str) -> None:
        model, N = self.model, self.N
        for i in range(N):
            self.slaves.append(FmuInstance(unzipdir, self.md, f"system{i + 1}", self.EARLY_RETURN))
        for s, sv in zip(self.slaves, self.start_values):
            s.enter_initialization(0.0)   # FMI 2.0: variables are readable from initialization mode on
            s.set(sv)
        check_schemes(self.hold, [contract.scheme_name(s.get_integer(contract.SOLVER_SCHEME)) for s in self.slaves])
        systems = [system_from_fmu(s, model) for s in self.slaves]
        check_common_geometry(systems, [f"instance {i + 1}" for i in range(N)])
        self.system = system = systems[0]
        if not self.allow_unstable:
            self._check_internal_steps()
        for i, (s, x) in enumerate(zip(self.slaves, self.states)):
            label = f"x{i + 1}"
            q0, u0 = as_state(system, x, label)
            check_start(system, q0, label)
            s.exit_initialization(model.state_values(q0, u0))
        n = model.n
        self.geo = geometry(system, self.Q)
        self.Kp_m, self.Kd_m = gain_matrix(self.Kp, n, "Kp"), gain_matrix(self.Kd, n, "Kd")
        self.A_coupled = coupled_weights(self.A, self.edges, self.laws)
        if self.coupled:  # before the first step: the held exchange must be stable at H
            self.limit = check_exchange(system.M, self.Kp_m, self.Kd_m, self.H, A=self.A_coupled,
                                        allow_unstable=self.allow_unstable, hold=self.hold)
        E, rows = len(self.edges), self.n_steps // self.record_every + 1
        self.T = np.full(rows, np.nan)
        self.Qr, self.Ur, self.TAU = (np.full((rows, N, n), np.nan) for _ in range(3))
        self.D, self.EU = np.full((rows, E), np.nan), np.full((rows, E), np.nan)
        self.BR = np.full((rows, E), -1, dtype=np.int64)
        self.tau = np.zeros((N, n))
        self.history = InputHistory(N, n)
        self.t1, self.t2 = np.zeros(n), np.zeros(n)
        self.work = chain_work(n)

    def _check_internal_steps(self) -> None:
        """Before the first step: each instance's own scheme limit (the explicit midpoint
        needs omega_max*dt < 2 for its internal step dt), from its parameter values, with
        the core's check; the slave would refuse its first doStep otherwise."""
        from .core.checks import check_stable
        names = [v.name for v in self.model.declare() if v.causality == "parameter" and v.type == "Real"]
        for i, s in enumerate(self.slaves):
            values = dict(zip(names, s.get(names)))
            scheme = contract.scheme_name(s.get_integer(contract.SOLVER_SCHEME))
            if scheme is None:
                continue
            try:
                check_stable(self.model.system(values), scheme, values[contract.SOLVER_DT])
            except SimulationDiverged as exc:
                raise SimulationDiverged(f"refused before the first step: instance {i + 1}: {exc} "
                                         f"(allow_unstable=True runs anyway)") from None

    def read(self, s: FmuInstance) -> list:
        v = s.get(self.model.q + self.model.u)
        n = self.model.n
        return [v[:n].copy(), v[n:].copy()]

    # ------------------------------------------------------------ coupling
    def pair(self, k: int, x, want_d: bool):
        """The pairwise law of edge k = (i, j) at states x: fills t1 (on i), t2 (on j)."""
        i, j = self.edges[k]
        return coupling_step(self.laws[k], self.geo, self.Kp_m, self.Kd_m, x[i][0], x[i][1], x[j][0],
                             x[j][1], self.t1, self.t2, *self.work, want_d)

    def input_of(self, i: int, x) -> None:
        """tau_i = sum_j a_ij tau_i^(j) at states x (one node at a time)."""
        A, tau = self.A, self.tau
        tau[i] = 0.0
        for k, (a, b) in enumerate(self.edges):
            if i == a and A[a, b] > 0.0:
                self.pair(k, x, False)
                tau[i] += A[a, b] * self.t1
            elif i == b and A[b, a] > 0.0:
                self.pair(k, x, False)
                tau[i] += A[b, a] * self.t2

    def inputs(self, x) -> None:
        """tau_i for every i at states x: each edge's law evaluated once."""
        A, tau = self.A, self.tau
        tau[:] = 0.0
        for k, (a, b) in enumerate(self.edges):
            self.pair(k, x, False)
            if A[a, b] > 0.0:
                tau[a] += A[a, b] * self.t1
            if A[b, a] > 0.0:
                tau[b] += A[b, a] * self.t2

    def check_forces(self, i: int, t: float, h: float) -> None:
        if not np.all(np.abs(self.tau[i]) <= contract.INPUT_BOUND):   # also catches NaN
            lim = exchange_limit(self.system.M, self.Kp_m, self.Kd_m, h, self.A_coupled, hold=self.hold)
            raise SlaveError(f"system{i + 1}", t, "coupling", 3, [
                f"its coupling force became non-finite or exceeds the FMU's input bound "
                f"{contract.INPUT_BOUND:g} ({self.tau[i].tolist()}): the explicit "
                f"exchange is unstable for these gains and this step ({lim.message()}): lower "
                f"Kp or H, or add Kd"])

    def _give(self, i: int, s: FmuInstance, t: float, h: float) -> None:
        s.set(dict(zip(self.model.tau, self.tau[i])))
        if self.hold == "foh":   # after the value (setting an input resets its derivative); fmu_sync.hold
            s._check("fmi2SetRealInputDerivatives", s.host.set_input_derivatives(
                dict(zip(self.model.tau, self.history.slope(i, self.tau[i], t)))))
        s.do_step(t, h)

    # ------------------------------------------------------------ exchange strategies
    def step_jacobi(self, t: float, h: float, x) -> list:
        """Every instance gets its input from the same states x, then all step."""
        self.inputs(x)
        for i in range(self.N):
            self.check_forces(i, t, h)
        for i, s in enumerate(self.slaves):
            self._give(i, s, t, h)
        self.history.remember(self.tau, t)
        return [self.read(s) for s in self.slaves]

    def step_gauss_seidel(self, t: float, h: float, x) -> list:
        """Instances step in index order, each input from the newest states of the others."""
        x = [list(xi) for xi in x]
        for i, s in enumerate(self.slaves):
            self.input_of(i, x)
            self.check_forces(i, t, h)
            self._give(i, s, t, h)
            x[i] = self.read(s)
        self.history.remember(self.tau, t)
        return x

    def communication_step(self, t: float, x, impacts: list) -> tuple[list, list]:
        """One step of length H from t; event-aware: retaken in pieces of H_min if an
        impact counter moved. Returns (new states, impact counters)."""
        if not self.event_aware:
            new = self.exchange(t, self.H, x)
            return new, [s.get_integer(contract.IMPACTS) for s in self.slaves]
        saved, history = [s.save() for s in self.slaves], self.history.save()
        new = self.exchange(t, self.H, x)
        now = [s.get_integer(contract.IMPACTS) for s in self.slaves]
        if now != impacts:
            self.history.restore(history)
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
            for k in range(len(self.edges)):
                self.D[row, k], self.BR[row, k], self.EU[row, k] = self.pair(k, x, True)

    def result(self, rows: int, impacts: list, error: str | None) -> NetworkResult:
        sl, need_d, A = slice(0, rows), self.need_d, self.A
        V = None
        if need_d:
            a_sym = np.array([0.5 * (A[i, j] + A[j, i]) for i, j in self.edges])
            with np.errstate(over="ignore"):  # a failed run may end on huge (finite) d
                V = 0.5 * (self.D[sl] ** 2) @ a_sym
        return NetworkResult(
            self.T[sl], self.Qr[sl], self.Ur[sl], self.TAU[sl], self.edges,
            self.D[sl] if need_d else None, self.BR[sl] if need_d else None,
            self.EU[sl] if need_d else None, V, impacts=impacts,
            info=dict(mode="cosim", H=self.H, method=self.method, event_aware=self.event_aware,
                      H_min=self.H_min if self.event_aware else None, retaken_steps=self.retakes,
                      fmu=self.fmu, steps=self.n_steps, coupling=self.coupling, hold=self.hold,
                      **({} if self.limit is None else dict(
                          omega_c_H=self.limit.h, exchange_bound=self.limit.bound,
                          zeta=self.limit.zeta, H_max=self.limit.H_max))),
            error=error)

    def diverged(self, t: float, what: str) -> SimulationDiverged:
        hint = f" ({self.limit.message()})" if self.limit is not None else ""
        return SimulationDiverged(
            f"the co-simulation diverged: {what} became non-finite at t = {t:.6g}; the run stopped "
            f"there and the record ends at the last finite row{hint}")

    # ------------------------------------------------------------ the run
    def run(self, progress=None) -> NetworkResult:
        """Run to t_end; raises :class:`SlaveError` if a slave fails and
        :class:`SimulationDiverged` if a state or distance becomes non-finite
        (``partial``: the finite record so far)."""
        from fmpy import extract
        unzipdir = extract(self.fmu)  # one unpacked copy shared by all instances, removed at the end
        failure = None
        try:
            self._start(unzipdir)
            x = [self.read(s) for s in self.slaves]
            if self.coupled:
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
                if not all(np.all(np.isfinite(xi[0])) and np.all(np.isfinite(xi[1])) for xi in x):
                    failure = self.diverged((k + 1) * H, "a state")
                    break
                if (k + 1) % self.record_every == 0:
                    self.record(row, (k + 1) * H, x, self.tau.copy())
                    if self.need_d and not np.all(np.isfinite(self.D[row])):
                        failure = self.diverged((k + 1) * H, "a distance")
                        break
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
                       start_values=None, progress=None,
                       record_distance: bool = True, allow_unstable: bool = False, hold: str = "zoh") -> NetworkResult:
    """Co-simulate N instances of ``fmu`` coupled on a weighted graph (docs/design.md §2.5, §4.4).

    ``states``: N start states (q, u); ``A``: N×N weights a_ij >= 0 (zero
    diagonal); system i receives ``tau_i = sum_j a_ij tau_i^(j)``, with
    ``tau_i^(j)`` the force of the pairwise law (``coupling``, gains ``Kp``,
    ``Kd``, norm weight ``Q``) on i in the pair (i, j); ``coupling`` is one law
    name for every edge or a sequence of names, one per edge in the order of
    ``result.edges`` (:func:`fmu_sync.core.network.edges_of`). The monolithic
    reference is :func:`fmu_sync.core.network.simulate_network` (reproduced to
    round-off at H = dt with Jacobi). Other arguments as :func:`cosimulate`;
    Gauss–Seidel updates the instances in index order, each one's input
    computed from the newest states of the others.
    ``start_values``: one dict of parameter start values for every instance, or
    a sequence of N dicts (or None), one per instance (non-identical systems:
    K, C, f0, forcing may differ; M, w, g0 and e must not).
    The stability of the held exchange over ``H`` is checked before the first
    step by :func:`fmu_sync.core.exchange.check_exchange` (refused with
    ``UnstableExchange``, a ValueError, unless ``allow_unstable``), and so is
    each instance's internal midpoint step (omega_max*dt < 2, refused with
    ``SimulationDiverged`` whose ``partial`` is None).
    """
    return NetworkMaster(fmu, states, A, t_end, H, coupling, Kp, Kd, Q, method, record_every, event_aware,
                         H_min, start_values, record_distance, allow_unstable, hold).run(progress)


def pair_result(r: NetworkResult, coupling) -> PairResult:
    d = r.d is not None
    return PairResult(r.t, r.q[:, 0], r.u[:, 0], r.q[:, 1], r.u[:, 1], r.tau[:, 0], r.tau[:, 1],
                      r.d[:, 0] if d else None, r.branch[:, 0] if d else None,
                      r.euclidean[:, 0] if d else None, impacts1=r.impacts[0], impacts2=r.impacts[1],
                      coupling=coupling, info=r.info, error=r.error)


def cosimulate(fmu, x1, x2, t_end: float, H: float, coupling: str | None = None, Kp=0.0, Kd=0.0,
               Q=None, method: str = "jacobi", record_every: int = 1, event_aware: bool = False,
               H_min: float | None = None, start_values=None, progress=None,
               record_distance: bool = True, allow_unstable: bool = False, hold: str = "zoh") -> PairResult:
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
    start_values : extra parameter start values, one dict for both instances (e.g.
        ``{"e": 0.8}``) or a pair of dicts, one per instance (non-identical systems,
        e.g. ``[{}, {"k": 1.05}]``; M, w, g0 and e must agree).
    allow_unstable : run even if the held exchange is unstable at ``H`` (by default
        refused before the first step with ``UnstableExchange``, a ValueError).
    hold : ``"zoh"`` (inputs held over a step) or ``"foh"`` (first-order hold, :mod:`fmu_sync.hold`).
    progress : callable ``progress(fraction)`` or None.

    Returns a :class:`PairResult`. Bad arguments, or an FMU that does not follow
    the FMU contract, raise a ValueError naming what is wrong. If a slave fails,
    the run stops there and raises :class:`SlaveError` (:class:`SimulationDiverged`
    if the states or distances become non-finite); its ``partial`` is the
    :class:`PairResult` recorded up to the failure, whose ``error`` names the
    slave, the time and the reason. (The pair is the two-node graph of
    :func:`cosimulate_network`.)
    """
    try:
        r = cosimulate_network(fmu, [x1, x2], [[0.0, 1.0], [1.0, 0.0]], t_end, H, coupling, Kp, Kd, Q,
                               method, record_every, event_aware, H_min, start_values, progress,
                               record_distance, allow_unstable, hold)
    except RunFailed as exc:
        if exc.partial is not None:  # None: refused before the first step
            exc.partial = pair_result(exc.partial, coupling)
        raise
    return pair_result(r, coupling)
