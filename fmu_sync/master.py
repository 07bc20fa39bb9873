"""Co-simulation master (docs/design.md §4.4): two (or N) FMU instances coupled
through the coupling law of the core, driven by fmpy's ``FMU2Slave``.

The master holds no model data of its own: the FMU contract (:mod:`fmu_sync.fmus.contract`) names
the variables, and the mass matrix, the wall (w, g0), the restitution e and the stiffness (for the
default position weight, §2.5.1) are read from the FMU's parameters. The coupling forces and the
distance are computed by the core's compiled :func:`fmu_sync.core.pair.coupling_step` — the same
function the monolithic :func:`fmu_sync.core.simulate_pair` calls every step. With ``H`` equal to
the slaves' internal step the two runs agree to round-off.

Structure: each instance is one host (:class:`FmuInstance`, the
:class:`fmu_sync.fmi_bridge.FMUHost` of its FMI version made with ``raises=True``:
fmpy loads, initialises and frees it, and a failed call raises :class:`SlaveError`
at the call); :class:`NetworkMaster` holds one
run: it checks the arguments, sets the instances up and hands their FMI C function
pointers and component handles to the compiled exchange loop
(:mod:`fmu_sync.cosim_loop`), which runs the communication steps in chunks
(Jacobi or Gauss–Seidel, zero- or first-order hold, the event-aware retake, the
record); :func:`cosimulate_network` and :func:`cosimulate` are the plain
functional entry points.

Failure convention (docs/design.md §5.1): bad arguments or a foreign FMU raise
a ValueError before any instance is created; an exchange known to be unstable
(the run plan, :func:`fmu_sync.core.plan.plan_run`) or instances with different
impact geometries (M, w, g0, e) raise a ValueError before the first step; a
slave that fails mid-run raises :class:`SlaveError` and a run whose states or
distances become non-finite raises :class:`fmu_sync.core.SimulationDiverged`
(both :class:`fmu_sync.core.RunFailed`) whose ``partial`` holds everything
recorded up to the failure (finite rows only).
"""
from __future__ import annotations

import contextlib
import functools
import math
import shutil
from pathlib import Path

import numpy as np

from .core.checks import TIME_TOL, check_record_size, check_run, check_step, record_rows, steps_in
from .core.compensation import force_table
from .core.coupling import QUOTIENT_LAWS, law_metric, metric_info
from .core.errors import ExchangeNotConverged, RunFailed, SimulationDiverged, UnstableScheme
from .core.exchange import exchange_limit
from .core.model import MechanicalSystem
from .core.network import edge_laws, edges_of, geometry_info, network_geometry, weights
from .core.pair import LAWS, stack_nodes
from .core.plan import RunPlan, critical_system, plan_run
from .core.result import NetworkResult, PairResult
from .core.views import units_info
from .fmi3_bridge import element_names, open_host
from .fmi_bridge import FMUHost, SlaveError
from .fmus import contract
from . import cosim_adaptive as ad
from . import cosim_args as args
from . import cosim_loop as loop
from .cosim_driver import drive
from .cosim_loop import CALLS
from .hold import check_hold, check_schemes
from . import strategies
from .instance_pool import give_back, keep_instances, kept_key, take
from .run_guard import GrowthGuard, floor_error, tolerance_verdict

__all__ = ["cosimulate", "cosimulate_network", "keep_instances", "NetworkMaster", "AdaptiveMaster", "check_tol", "NetworkResult", "SlaveError", "FmuInstance",
           "fmu_model", "system_from_fmu", "pair_result"]

#: Communication steps per compiled chunk when no progress is reported (Ctrl-C is honoured between chunks).
CHUNK_STEPS = 4096
#: One FMU instance as the master uses it: the host of its FMI version whose failed calls raise
#: :class:`SlaveError` (naming the instance, the time, the FMI call, the status and the FMU's
#: logged reason); :func:`open_instance` makes one.
FmuInstance = FMUHost


def open_instance(unzipdir: str, md, name: str, early_return: bool = False) -> FmuInstance:
    """The master's instance ``name`` of an unpacked FMU (FMI 2.0, or FMI 3.0 with early return
    and event mode if ``early_return``): failed calls raise :class:`SlaveError`."""
    return open_host(unzipdir, md, name, early_return, raises=True)


@functools.lru_cache(maxsize=16)
def _read_description(path: str, stamp: tuple):
    from fmpy import read_model_description
    return read_model_description(path)


def model_description(fmu: str):
    """fmpy's model description of an .fmu or an unpacked FMU folder, parsed once per process
    for a file that has not changed (many runs of one FMU in a sweep worker)."""
    f = Path(fmu) / "modelDescription.xml" if Path(fmu).is_dir() else Path(fmu)
    st = f.stat()
    return _read_description(str(fmu), (st.st_mtime_ns, st.st_size))


def fmu_model(md, fmu: str | None = None):
    """The contract's model of an FMU (from its model description); a foreign FMU
    raises :class:`fmu_sync.fmus.contract.ContractError` naming the missing variables.
    The FMU of a model declaration with a force law not registered in this process is
    registered from the declaration its build record names (``fmu``: the .fmu or its folder;
    :func:`fmu_sync.user_export.declaration_of`)."""
    from .user_export import built_key, register_from
    key = None if fmu is None else built_key(fmu)   # two declarations of one interface: the FMU's own
    try:
        return contract.identify(element_names(md), md.modelName, key)
    except contract.ContractError:
        if fmu is None:
            raise
        if not register_from(fmu):
            raise
        return contract.identify(element_names(md), md.modelName, key)


def system_from_fmu(instance: FmuInstance, model=None) -> MechanicalSystem:
    """The geometry the distance needs (M, w, g0, e), read from the FMU's parameters
    named by the FMU contract (K = C = f0 = 0: only M, w, g0 and e enter the
    distance and the coupling)."""
    model = model or fmu_model(instance.md)
    return model.geometry_system(dict(zip(model.geometry, instance.get(list(model.geometry)))))


class NetworkMaster:
    """One co-simulation run of N instances of one FMU coupled on a weighted graph.

    The constructor checks every argument (ValueError) and identifies the FMU
    through the contract; :meth:`run` creates the instances, runs and frees them.
    Its exchange strategies (``self.strategies``) are entries of the registry
    :mod:`fmu_sync.strategies`, selected and checked there from ``method``, ``exchange``,
    ``tol``, ``event_aware`` and ``hold``; the ones compiled are flags of the loop
    (:mod:`fmu_sync.cosim_loop`).
    """

    METHODS = strategies.METHODS
    tol = None             # the tolerance of an AdaptiveMaster (set before this constructor runs)
    EARLY_RETURN = False   # FMI 3.0 instances with early return and event mode (fmu_sync.early_return)

    def __init__(self, fmu, states, A, t_end: float, H: float, coupling: str | None = "switching",
                 Kp=0.0, Kd=0.0, Q=None, method: str = "jacobi", record_every: int = 1,
                 event_aware: bool = False, H_min: float | None = None, start_values=None,
                 record_distance: bool | None = None, allow_unstable: bool = False, hold: str = "zoh",
                 exchange: str = "explicit"):
        grid, record_every = check_run(t_end, H, record_every, dt_name="H")   # ends at t_end (grid.dt_last)
        H, n_steps = grid.dt, grid.steps
        self.strategies = strategies.select(method, exchange, self.tol, event_aware, hold)
        self.exchange_kind = exchange
        if event_aware:
            H_min = H / 16 if H_min is None else check_step(H_min, "H_min")
            if H_min > H:
                raise ValueError(f"H_min must not exceed H = {H}, got {H_min}")
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
        self.unpacked = Path(self.fmu).is_dir()   # an unpacked FMU: used in place, kept
        if not (Path(self.fmu).is_file() or (self.unpacked and (Path(self.fmu) / "modelDescription.xml").is_file())):
            raise FileNotFoundError(f"FMU not found: {self.fmu} (an .fmu file or an unpacked FMU folder "
                                    f"with its modelDescription.xml)")
        self.md = model_description(self.fmu)
        strategies.check_fmu(self.strategies, self.md, self.fmu)   # FMI version, state access
        self.model = fmu_model(self.md, self.fmu)  # a foreign FMU fails here, naming what it lacks
        self.hold = check_hold(hold, self.md, self.fmu)
        self.record_values = 1 + 3 * N * self.model.n + 3 * len(self.edges)
        check_record_size(record_rows(n_steps, record_every), self.record_values,
                          "the record of the co-simulation")   # the plan's step 6, before any instance exists
        self.H, self.n_steps, self.record_every, self.grid, self.t_end = H, n_steps, record_every, grid, t_end
        self.coupling = coupling
        self.allow_unstable = bool(allow_unstable)
        self.limit = None
        self.Kp, self.Kd, self.Q = Kp, Kd, Q
        self.method = method
        self.event_aware, self.H_min = event_aware, H_min
        self.need_d = record_distance is not False or self.coupled
        self.record_distance = record_distance   # True: the quotient distance, refused without one impact map
        self.slaves: list[FmuInstance] = []
        self.retakes = 0

    # ------------------------------------------------------------ set-up
    def _start(self, unzipdir: str) -> None:
        model, N = self.model, self.N
        for i in range(N):
            kept = take(self._kept_key(unzipdir, i))
            self.slaves.append(kept or open_instance(unzipdir, self.md, f"system{i + 1}", self.EARLY_RETURN))
        for s, sv in zip(self.slaves, self.start_values):
            s.enter_initialization(0.0)   # FMI 2.0: variables are readable from initialization mode on
            s.set(sv)
        schemes = [contract.scheme_name(s.get_integer(contract.SOLVER_SCHEME)) for s in self.slaves]
        check_schemes(self.hold, schemes)
        names = [v.name for v in model.declare() if v.causality == "parameter" and v.type == "Real"]
        values = [dict(zip(names, s.get(names))) for s in self.slaves]   # what each instance runs with
        plan = self.plan(values, schemes)   # every check of the run, once (docs/design.md §5.1.1)
        crit = plan.systems.index(critical_system(plan.systems))   # the lightest instance (core/plan.py)
        self.system = system_from_fmu(self.slaves[crit], model)
        for s, q0, u0 in zip(self.slaves, plan.q, plan.u):
            s.exit_initialization(model.state_values(q0, u0))
        n = model.n
        self.Kp_m, self.Kd_m, self.A_coupled, self.limit = plan.Kp, plan.Kd, plan.A_coupled, plan.limit
        self.guard = GrowthGuard(plan.systems[0], self.Kp_m, self.A_coupled, self.edges, plan.q, plan.u,
                                 "" if self.limit is None else f" ({self.limit.message()})")
        self.metric = law_metric(self.Q, [s.K for s in plan.systems], self.Kp_m,
                                 self.A_coupled if self.coupled else None, coupled=self.coupled,
                                 stiffness=plan.systems[0].metric_source)   # a user force law: "linearized"
        self.geo, self.shared = network_geometry(plan.systems, self.metric.Q)   # per-instance M, w, g0, e
        self.dist = self.need_d and (self.shared or bool(np.any(np.isin(self.laws, QUOTIENT_LAWS))))
        self.hp = force_table(*stack_nodes(*plan.systems)[1:])   # each instance's h (the compensated law)
        # each instance's M^-1: the implicit exchange's prior of an FMU's response to its input
        self.Minv_nodes = np.stack([np.linalg.inv(np.atleast_2d(np.asarray(s.M, dtype=float))) for s in plan.systems])
        E, rows = len(self.edges), record_rows(self.n_steps, self.record_every)
        self.T = np.full(rows, np.nan)
        self.Qr, self.Ur, self.TAU = (np.full((rows, N, n), np.nan) for _ in range(3))
        Ed = E if self.dist else 0   # without one impact map: the Euclidean error alone (docs/design.md §2.5.3)
        self.D, self.EU = np.full((rows, Ed), np.nan), np.full((rows, E), np.nan)
        self.BR = np.full((rows, Ed), -1, dtype=np.int64)

    def plan(self, values: list, schemes: list) -> RunPlan:
        """The run plan (:func:`fmu_sync.core.plan.plan_run`) of this co-simulation from what the
        instances report: ``values``, each instance's Real parameters (its system, its internal
        step ``solver.dt``), ``schemes``, each one's scheme name: the common geometry, each
        instance's scheme limit, the start states, the held exchange at H for the hold in use,
        the record. The scene preflight makes the same plan from the scene's values."""
        N = self.N
        systems = [self.model.system(v) for v in values]
        try:
            return plan_run(systems, self.states, self.t_end, self.H, scheme=schemes,
                            dt=[v[contract.SOLVER_DT] for v in values], hold=self.hold, exchange=self.exchange_kind,
                            A=self.A, laws=self.laws,
                            Kp=self.Kp, Kd=self.Kd, record_every=self.record_every, step_name="H", exact=True,
                            allow_unstable=self.allow_unstable, record_values=self.record_values,
                            distance=self.record_distance is True,
                            record_what="the record of the co-simulation",
                            system_names=[f"instance {i + 1}" for i in range(N)])
        except UnstableScheme as exc:
            raise UnstableScheme(f"refused before the first step: {exc} (allow_unstable=True runs anyway)") from None

    def result(self, rows: int, impacts: list, error: str | None) -> NetworkResult:
        sl, need_d, dist, A = slice(0, rows), self.need_d, self.dist, self.A
        V = None
        if dist:
            a_sym = np.array([0.5 * (A[i, j] + A[j, i]) for i, j in self.edges])
            with np.errstate(over="ignore"):  # a failed run may end on huge (finite) d
                V = 0.5 * (self.D[sl] ** 2) @ a_sym
        return NetworkResult(
            self.T[sl], self.Qr[sl], self.Ur[sl], self.TAU[sl], self.edges,
            self.D[sl] if dist else None, self.BR[sl] if dist else None,
            self.EU[sl] if need_d else None, V, impacts=impacts,
            info=dict(mode="cosim", H=self.H, method=self.method,
                      strategies=[st.name for st in self.strategies], event_aware=self.event_aware, fmu=self.fmu,
                      H_min=self.H_min if self.event_aware else None, retaken_steps=self.retakes,
                      steps=self.n_steps, coupling=self.coupling, hold=self.hold, exchange=self.exchange_kind,
                      **args.implicit_info(getattr(self, "iw", None)), **metric_info(self.metric, self.geo),
                      **geometry_info(self.shared, need_d and not dist),
                      **units_info(self.model.declaration),
                      **({} if self.limit is None else dict(
                          omega_c_H=self.limit.h, exchange_bound=self.limit.bound,
                          zeta=self.limit.zeta, H_max=self.limit.H_max))),
            error=error)

    @property
    def implicit(self) -> bool:
        return self.exchange_kind == "implicit"

    def diverged(self, t: float, what: str) -> SimulationDiverged:
        hint = f" ({self.limit.message()})" if self.limit is not None else ""
        return SimulationDiverged(
            f"the co-simulation diverged: {what} became non-finite at t = {t:.6g}; the run stopped "
            f"there and the record ends at the last finite row{hint}")

    # ------------------------------------------------------------ the run
    def _loop_arrays(self) -> None:
        """What the compiled driver takes (:func:`fmu_sync.cosim_args.loop_arguments`), and the tolerance
        controller's arrays, idle without tol (:class:`AdaptiveMaster` makes them live)."""
        args.loop_arguments(self)
        N, n = self.N, self.model.n
        self.norm = tuple(np.eye(n) for _ in range(3))
        self.ad, self.ast, self.actl = ad.controller_arrays(0.0, self.grid.t_end, self.H, self.H, self.H)
        self.mine = np.zeros(N, dtype=np.int64)   # the controller's FMU-state handles
        self.pmine = self.loop_args.ptr.copy()
        self.pmine[loop.P_SAVED] = self.mine.ctypes.data
        self.extra = ad.Extra(np.zeros((N, n)), np.zeros((N, n)), np.zeros(n), np.zeros(n), self.mine, self.pmine)
        self.HS, self.ES = np.zeros(0), np.zeros(0)

    def _drive(self, budget: int) -> int:
        """Up to ``budget`` tries of a step in the one compiled driver; returns its outcome code."""
        a, s = self.loop_args, self.loop_state
        return int(drive(a.ptr, a.fn, a.comp, a.laws, a.geo, a.Kp, a.Kd, a.E2, a.W2, a.flags, a.hp, a.H, a.H_last,
                         a.t_last, self.ad, self.norm, budget, s.q, s.u, s.tau, s.tau_next, s.hist_tau, s.hist, s.imp,
                         s.ctl, s.saved, s.keep, self.extra, self.ast, self.actl, self.T, self.Qr, self.Ur, self.TAU,
                         self.D, self.BR, self.EU, self.HS, self.ES, s.w, s.FAIL, s.fail_t))

    def _walk(self, progress) -> RunFailed | None:
        """The run from its start to t_end in the driver, in chunks (``progress(fraction)`` and
        Ctrl-C between them); the failure that ended it, or None."""
        code = int(loop.loop_start(*self.loop_args, *self.loop_state))   # states, impact counters, row 0
        if code != loop.DONE:
            raise self._failure(code)
        budget = self._budget(progress)
        while True:
            code = self._drive(budget)
            if code == loop.FULL:
                self._grow()
                continue
            failure = self._failure(code) if code != loop.DONE else self.grew()
            if failure is not None:
                return failure
            c = ad.controller_state(self.ast, self.actl)
            if progress is not None:
                progress(self._fraction(c))
            if c["done"]:
                return None

    def _budget(self, progress) -> int:
        return max(1, self.n_steps // 200) if progress is not None else CHUNK_STEPS

    def _fraction(self, c: dict) -> float:
        return c["steps"] / self.n_steps

    def _grow(self) -> None:
        raise AssertionError("a fixed-step record is sized for the whole run")

    def grew(self):
        """The growth guard's failure (:mod:`fmu_sync.run_guard`) at the last recorded row, or None."""
        row = int(self.ctl[loop.ROW]) - 1
        return self.guard.check(self.loop_state.q, self.loop_state.u, float(self.T[max(row, 0)]))

    def force_bound(self, i: int, t: float) -> SlaveError:
        """Instance i's coupling force ``self.tau[i]`` is non-finite or above the FMU's input bound."""
        lim = self.limit or exchange_limit(self.system.M, self.Kp_m, self.Kd_m, self.H, self.A_coupled,
                                           hold=self.hold, exchange=self.exchange_kind)
        what = (f"its coupling force became non-finite or exceeds the FMU's input bound {contract.INPUT_BOUND:g} "
                f"({self.tau[i].tolist()})")
        if self.exchange_kind == "explicit" and not lim.stable:
            why = (f"the explicit exchange is unstable for these gains and this step ({lim.message()}): lower Kp "
                   f"or H, add Kd, or use exchange='implicit'")
        else:   # a stable exchange: the law itself asks for forces the FMU does not take
            why = (f"the {self.exchange_kind} exchange is stable at this step, but the law's force at these states "
                   f"(Kp |q_i - q_j| + Kd |u_i - u_j| summed over the edges) is beyond what the FMU accepts: "
                   f"lower Kp and Kd, or start the systems closer")
        return SlaveError(f"system{i + 1}", t, "coupling", 3, [f"{what}: {why}"])

    def _failure(self, code: int) -> RunFailed:
        """The exception of a chunk that ended early (the loop's FAIL record)."""
        _, i, call, status = (int(v) for v in self.FAIL)
        t = float(self.fail_t[0])
        if code == loop.SLAVE_FAILED:
            s = self.slaves[i]
            if status >= 4:   # fmi2Fatal: no call but freeing it any more
                s.dead = True
            return s.failure(CALLS[call], status, t)
        if code == loop.FORCE_BOUND:
            return self.force_bound(i, t)
        if code == loop.NOT_CONVERGED:
            return ExchangeNotConverged(args.not_converged(self.iw, t, self.H, call))
        if code == loop.NO_ROOM:   # a bug of the builder's sizes, caught before any write past an end
            return RunFailed(f"the implicit exchange's per-step arrays hold {status} steps, step {call} at t = {t:.6g} "
                             f"needs more (fmu_sync.cosim_args.implicit_work sized them): the run stopped there")
        return self.diverged(t, "a state" if code == loop.STATE_DIVERGED else "a distance")

    def run(self, progress=None) -> NetworkResult:
        """Run to t_end; raises :class:`SlaveError` if a slave fails and
        :class:`SimulationDiverged` if a state or distance becomes non-finite
        (``partial``: the finite record so far). The compiled loop runs in chunks
        of steps, so ``progress(fraction)`` is called and Ctrl-C is honoured between them."""
        with self.instances() as unzipdir:
            self._start(unzipdir)
            self._loop_arrays()
            failure = self._walk(progress)
            if progress is not None and failure is None:
                progress(1.0)
        self.retakes = int(self.ctl[loop.RETAKES])
        return self.finish(int(self.ctl[loop.ROW]), [int(v) for v in self.imp], failure)

    @contextlib.contextmanager
    def instances(self):
        """The unpacked FMU folder for the instances; at the end every instance is freed and
        the copy removed (one unpacked copy shared by all instances; an unpacked folder is kept)."""
        from fmpy import extract
        unzipdir = self.fmu if self.unpacked else extract(self.fmu)
        try:
            yield unzipdir
        finally:
            for i, s in enumerate(self.slaves):
                give_back(self._kept_key(unzipdir, i), s)   # kept for the next run, or freed
            if not self.unpacked:
                shutil.rmtree(unzipdir, ignore_errors=True)

    def _kept_key(self, unzipdir: str, i: int):
        """The key of instance i in the kept instances (None: not kept, :func:`keep_instances`)."""
        if self.md.fmiVersion != "2.0" or self.EARLY_RETURN:
            return None
        return kept_key(unzipdir, self.md.guid, f"system{i + 1}")

    def finish(self, rows: int, impacts: list, failure: RunFailed | None) -> NetworkResult:
        """The result of ``rows`` recorded rows; a failure is raised with it as ``partial``."""
        res = self.result(rows, impacts, None if failure is None else str(failure))
        if failure is not None:
            failure.partial = res
            raise failure
        return res


def cosimulate_network(fmu, states, A, t_end: float, H: float, coupling: str | None = "switching",
                       Kp=0.0, Kd=0.0, Q=None, method: str = "jacobi", record_every: int = 1,
                       event_aware: bool = False, H_min: float | None = None,
                       start_values=None, progress=None,
                       record_distance: bool | None = None, allow_unstable: bool = False, hold: str = "zoh",
                       exchange: str = "explicit", tol: float | None = None) -> NetworkResult:
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
    K, C, f0, forcing may differ, and M, w, g0, e unless a quotient law or
    ``record_distance=True`` needs one impact map; without one the record carries
    the Euclidean error, ``d`` and ``V`` None, docs/design.md §2.5.3).
    Before the first step (the run plan, :func:`fmu_sync.core.plan.plan_run`), the held exchange over ``H`` (
    ``UnstableExchange``) and each instance's internal midpoint step (omega_max*dt < 2,
    ``UnstableScheme``) are checked; both are ValueErrors, skipped with ``allow_unstable``.
    ``tol``: co-simulate to this tolerance (:class:`AdaptiveMaster`, docs/design.md §4.4.1).
    """
    args = (fmu, states, A, t_end, H, coupling, Kp, Kd, Q, method, record_every, event_aware, H_min, start_values,
            record_distance, allow_unstable, hold, exchange)
    master = strategies.master_of(strategies.select(method, exchange, tol, event_aware, hold))
    return master(*args, **({} if tol is None else {"tol": tol})).run(progress)


def pair_result(r: NetworkResult, coupling) -> PairResult:
    d = r.d is not None
    return PairResult(r.t, r.q[:, 0], r.u[:, 0], r.q[:, 1], r.u[:, 1], r.tau[:, 0], r.tau[:, 1],
                      r.d[:, 0] if d else None, r.branch[:, 0] if d else None,
                      r.euclidean[:, 0] if d else None, impacts1=r.impacts[0], impacts2=r.impacts[1],
                      coupling=coupling, info=r.info, error=r.error)


def cosimulate(fmu, x1, x2, t_end: float, H: float, coupling: str | None = None, Kp=0.0, Kd=0.0,
               Q=None, method: str = "jacobi", record_every: int = 1, event_aware: bool = False,
               H_min: float | None = None, start_values=None, progress=None,
               record_distance: bool | None = None, allow_unstable: bool = False, hold: str = "zoh",
               exchange: str = "explicit", tol: float | None = None) -> PairResult:
    """Co-simulate two instances of ``fmu`` coupled by ``coupling`` (docs/design.md §2.5, §4.4).

    Parameters
    ----------
    fmu : path to the .fmu (an fmu-sync mechanical model, see ``fmu-sync export``), or to an
        unpacked FMU folder (used in place and kept: a sweep worker unpacks once for all its runs).
    x1, x2 : start states (q, u) of the two instances (set as ``q_start``/``u_start``).
    t_end, H : stop time (reached exactly: the last step shortened) and communication step.
    coupling : None, ``"switching"`` (quotient coupling), ``"switching-compensated"`` (1-DOF, V
        non-increasing on every branch, docs/design.md §2.5.2) or ``"euclidean"`` (PD baseline).
    Kp, Kd : gains (scalars or n×n).  Q : position weight of the norm (default: ``energy_metric``).
    method : the exchange order, an order of the registry :mod:`fmu_sync.strategies`
        (docs/cosim-strategies.md): ``"jacobi"`` (both slaves get inputs computed from the same
        states), ``"gauss-seidel"`` (slave 2's input uses slave 1's updated state), ``"delayed"``
        / ``"delayed-zero"`` (libcosim's / fmpy's SSP runner's order, docs/ssp.md) or
        ``"early-return"`` (an FMI 3.0 FMU: the forces exchanged at every impact, docs/fmi3.md).
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
    exchange : ``"explicit"`` (the forces from the states at the step's start, extrapolated by the
        hold) or ``"implicit"`` (each step iterated with FMU-state rollback until the forces agree
        with the states at its end: the line between the two ends with ``hold="foh"``, their mean
        held with ``"zoh"``; needs ``canGetAndSetFMUstate``; ``info["iterations"]``: FMU steps per
        communication step; the switching laws' branch is held within a step, ``info["off_branch"]``
        counting per step the edges accepted off the law's own branch; a step that does not converge
        raises ``ExchangeNotConverged``, docs/design.md §4.4).
    tol : co-simulate to this tolerance (docs/design.md §4.4.1): ``H`` is then the first and
        largest step; each step's local coupling error is estimated, a step over its share
        ``tol h / t_end`` is rolled back (FMU state) and retaken shorter, steps are whole
        multiples of the slaves' solver.dt (the floor). tol and ``info["error_estimate"]``
        are in q's unit (``info["error_norm"]``); ``info`` also holds ``steps``, ``rejected``
        and ``step_lengths`` (the accepted steps' lengths; ``H`` stays the nominal step). Needs an FMU that can get and set its state.
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
                               record_distance, allow_unstable, hold, exchange, tol)
    except RunFailed as exc:
        if exc.partial is not None:  # None: refused before the first step
            exc.partial = pair_result(exc.partial, coupling)
        raise
    return pair_result(r, coupling)


# Co-simulation to a tolerance (docs/design.md §4.4.1)
# Co-simulation to a tolerance (docs/design.md §4.4.1): AdaptiveMaster is the NetworkMaster run whose communication step is chosen by the compiled
# controller of :mod:`fmu_sync.cosim_adaptive`; ``cosimulate(..., tol=T)`` and
# ``cosimulate_network(..., tol=T)`` make it.
#
# What the result carries (``info``): ``steps`` (accepted communication steps), ``rejected``
# (steps rolled back and retaken shorter), ``step_lengths`` (the accepted steps' lengths, an
# array, one per step), ``H`` and ``H_first`` (the first and largest step, the nominal H as in every mode), ``step_unit`` (the floor: the slaves'
# solver.dt), ``tol``, ``error_estimate`` (the estimated global error: the sum of the accepted
# steps' local estimates and the slaves' own error at solver.dt ``floor_error``, in q's unit like
# tol), ``tol_met`` (bool) and ``tol_not_met`` (why not), ``floor_steps`` (steps accepted at the floor
# although their estimate exceeded their share: an impact accumulation, for example) and
# ``error_norm`` (the norm, in words). The record has a row every ``record_every`` accepted
# steps and the final state.

#: what tol and info["error_estimate"] measure (docs/design.md §4.4.1)
ERROR_NORM = ("q's unit: per node the state error (dq, du) in the law's metric, sqrt(dq' Q dq + du' M du) / "
              "sqrt(lambda_min(Q)) (one degree of freedom: sqrt(dq^2 + du^2 m/Q)), summed over the accepted "
              "steps, largest over the nodes")


def check_tol(tol) -> float:
    """``tol``: a finite number > 0 (ValueError otherwise)."""
    if isinstance(tol, bool) or not isinstance(tol, (int, float, np.floating, np.integer)) or not (
            math.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a finite number > 0 (the co-simulation's error tolerance, in q's unit), "
                         f"got {tol!r}")
    return float(tol)


class AdaptiveMaster(NetworkMaster):
    """A co-simulation run to the tolerance ``tol``: ``H`` is the first and largest step."""

    def __init__(self, *args, tol, **kwargs):
        self.tol = check_tol(tol)
        super().__init__(*args, **kwargs)   # the registry's checks of tol (fmu_sync.strategies)
        self.steps = self.rejected = self.forced = 0
        self.estimate = 0.0

    def plan(self, values, schemes):
        plan = super().plan(values, schemes)
        self.guard_start = (plan.q, plan.u)
        self.unit = max(plan.dts)   # the floor of the step: the slaves' own solver.dt
        if self.H < self.unit * (1 - TIME_TOL):
            raise ValueError(f"tol: H = {self.H:g} is below the slaves' solver.dt = {self.unit:g}, the "
                             f"smallest communication step with tol; H (the first and largest step) must be "
                             f">= solver.dt")
        return plan

    def _loop_arrays(self) -> None:
        super()._loop_arrays()   # with the registry's flags of tol and the state calls it needs
        n = self.model.n
        M = np.atleast_2d(np.asarray(self.system.M, dtype=np.float64))
        Q = np.asarray(self.metric.Q, dtype=np.float64)
        Q = Q * np.eye(n) if Q.ndim == 0 else np.atleast_2d(Q)
        lam = float(np.linalg.eigvalsh(0.5 * (Q + Q.T)).min())
        self.norm = (np.linalg.inv(M), Q / lam, M / lam)
        self.ad, self.ast, self.actl = ad.controller_arrays(self.tol, self.grid.t_end, self.unit, self.H,
                                                            self.unit * max(1, steps_in(self.H, self.unit)[0]))
        cap = 2 * self.n_steps + 16
        self.HS, self.ES = np.full(cap, np.nan), np.full(cap, np.nan)
        self._implicit_room(cap)

    def _implicit_room(self, cap: int) -> None:
        """The implicit exchange's per-step arrays (:func:`fmu_sync.cosim_args.with_room`) for ``cap``
        accepted steps, in the loop's state by name."""
        if not self.implicit:
            return
        self.iw = args.with_room(self.iw, cap)
        s = self.loop_state
        self.loop_state = s._replace(keep=s.keep._replace(iw=self.iw))

    def _grow(self) -> None:
        """Twice the room for rows and steps (the number of steps is not known in advance)."""
        def grow(a, fill):
            b = np.full((2 * a.shape[0],) + a.shape[1:], fill, dtype=a.dtype)
            b[:a.shape[0]] = a
            return b
        self.T, self.Qr, self.Ur, self.TAU, self.D, self.EU = (
            grow(a, np.nan) for a in (self.T, self.Qr, self.Ur, self.TAU, self.D, self.EU))
        self.BR = grow(self.BR, -1)
        self.HS, self.ES = grow(self.HS, np.nan), grow(self.ES, np.nan)
        self._implicit_room(self.HS.size)

    def _budget(self, progress) -> int:
        return 256 if progress is not None else CHUNK_STEPS

    def _fraction(self, c: dict) -> float:
        return min(1.0, c["t"] / self.grid.t_end)

    def run(self, progress=None):
        with self.instances() as unzipdir:
            self._start(unzipdir)
            self._loop_arrays()
            try:
                failure = self._walk(progress)
            finally:
                ad.free_states(self.pmine, self.fn, self.comp, self.mine, np.zeros(4, dtype=np.int64), np.zeros(1))
        c = ad.controller_state(self.ast, self.actl)
        self.steps, self.rejected, self.forced, self.estimate = c["steps"], c["rejected"], c["floor_steps"], \
            c["error_estimate"]
        if failure is None:
            self.verdict(sum(int(v) for v in self.imp))
        return self.finish(int(self.ctl[loop.ROW]), [int(v) for v in self.imp], failure)

    def verdict(self, impacts: int) -> None:
        """The slaves' own error at the floor added to the estimate, and whether the run met tol
        (:func:`fmu_sync.run_guard.tolerance_verdict`, a ToleranceNotMet warning when not)."""
        omega = 0.0 if self.limit is None else math.sqrt(self.limit.omega_c ** 2 + self.limit.own)
        q, u = self.guard_start
        amp = float(np.max(np.abs(q)) + (np.max(np.abs(u)) / omega if omega > 0 else 0.0))
        self.floor = floor_error(omega, self.unit, self.grid.t_end, amp)
        self.estimate += self.floor
        self.tol_met, self.tol_not_met = tolerance_verdict(self.tol, self.estimate, self.floor, self.forced,
                                                           self.unit, self.hold, impacts)

    def result(self, rows, impacts, error):
        res = super().result(rows, impacts, error)
        res.info.update(tol=self.tol, steps=self.steps, rejected=self.rejected, step_lengths=self.HS[:self.steps].copy(),
                        H_first=self.H, step_unit=self.unit, error_estimate=self.estimate,
                        floor_steps=self.forced, error_norm=ERROR_NORM, floor_error=getattr(self, "floor", None),
                        tol_met=getattr(self, "tol_met", False), tol_not_met=getattr(self, "tol_not_met", error))
        return res
