"""The run plan (docs/design.md §5.1.1): every check of a run, made once, into one object.

:func:`plan_run` takes what a run is made of (its systems, start states, end time, step,
scheme, the hold of the coupling exchange, graph, laws and gains, the record) and checks it
in one fixed order:

1. systems: one per start state, one compiled loop (n, the force law); a common impact geometry
   (M, w, g0, e) only for a quotient law or the distance record (:data:`ONE_IMPACT_MAP`);
2. the step grid (:func:`.checks.check_run`: a positive step, a finite end, ``record_every``);
3. the scheme (:func:`.checks.scheme_code`) and its limit for each system's internal step
   (:func:`.checks.check_stable`, :class:`~.errors.UnstableScheme`);
4. the start states (:func:`.model.as_state`, :func:`.checks.check_start`,
   :class:`~.checks.InadmissibleState`);
5. coupled runs: forces through B = I, the gains, and the held exchange at the exchange
   step for the hold in use (:func:`held_exchange`, :class:`~.exchange.UnstableExchange`);
6. the record budget (:func:`.checks.check_record_size`, :class:`~.checks.RecordTooLarge`).

A refusal raises a :class:`~.errors.RunRefused` subclass of its own type (all ValueErrors); a
malformed argument a plain ValueError. The result, :class:`RunPlan`, carries what the drivers
need: the checked systems and states, the grid, the scheme code, the record rows, the gain
matrices and the exchange verdict. ``simulate``, ``simulate_pair``, ``simulate_network``, the
batch sweeps, the scene preflight, the co-simulation master and the FMU slave (single-system
part) all make their checks through it: no second copy of a run check exists.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import refuse_nonlinear  # noqa: F401 (re-exported: a run check)
from .checks import RunSteps, check_record_size, check_run, check_stable, check_start, check_step, record_rows, \
    scheme_code
from .errors import UnstableScheme
from .exchange import ExchangeLimit, check_exchange
from .model import MechanicalSystem, as_state

__all__ = ["RunPlan", "plan_run", "refuse_nonlinear", "held_exchange", "check_common_geometry", "check_one_loop",
           "geometry_difference", "ONE_IMPACT_MAP", "critical_system", "network_geometry", "as_systems", "weights",
           "edges_of", "coupled_weights"]


# ------------------------------------------------------------------ systems and graphs
def as_systems(system, count: int, what: str = "system") -> list:
    """One MechanicalSystem for all, or a sequence of ``count`` of them."""
    if isinstance(system, MechanicalSystem):
        return [system] * count
    try:
        systems = list(system)
    except TypeError:
        raise ValueError(f"{what} must be a MechanicalSystem or a sequence of {count}, "
                         f"got {system!r}") from None
    if len(systems) != count or not all(isinstance(s, MechanicalSystem) for s in systems):
        raise ValueError(f"{what} must be a MechanicalSystem or a sequence of {count} MechanicalSystem "
                         f"objects, got {len(systems)} item(s) of types "
                         f"{sorted({type(s).__name__ for s in systems})}")
    return systems


def check_one_loop(systems, names=None) -> None:
    """Coupled systems run in one compiled loop: the same number of degrees of freedom and one
    force law (its parameters, and M, K, C, w, g0, e, forcing, may differ per system)."""
    systems = list(systems)
    names = names or [f"system {i + 1}" for i in range(len(systems))]
    a = systems[0]
    for name, b in zip(names[1:], systems[1:]):
        if b.n != a.n:
            raise ValueError(f"coupled systems must have the same number of degrees of freedom: "
                             f"{names[0]} has n = {a.n}, {name} has n = {b.n}")
        if b.force is not a.force:   # one compiled loop: one law (its parameters may differ per system)
            what = [s.force.name if s.force is not None else "the built-in linear law" for s in (a, b)]
            raise ValueError(f"coupled systems must share one force law (its parameters may differ): "
                             f"{names[0]} has {what[0]}, {name} has {what[1]}")


#: The reason of a refused quotient law or distance record (docs/design.md §2.5.3).
ONE_IMPACT_MAP = "the quotient distance needs one impact map"


def geometry_difference(systems) -> str | None:
    """The first of M, w, g0, e in which the systems differ (None: they share one impact map)."""
    a = systems[0]
    for key in ("M", "w", "g0", "e"):
        if any(not np.array_equal(getattr(a, key), getattr(b, key)) for b in systems[1:]):
            return key
    return None


def check_common_geometry(systems, names=None, what: str = "the quotient distance") -> None:
    """The quotient distance identifies states through one impact map: the systems must
    share M, w, g0 and e (stiffness, damping, offset force and forcing may differ). Raises
    ValueError naming the quantity that differs, every system's value and the reason;
    ``what``: what needs it (a law, the distance record)."""
    systems = list(systems)
    names = names or [f"system {i + 1}" for i in range(len(systems))]
    check_one_loop(systems, names)
    key = geometry_difference(systems)
    if key is not None:
        fmt = (lambda v: np.asarray(v).tolist())
        values = ", ".join(f"{nm} has {key} = {fmt(getattr(s, key))}" for nm, s in zip(names, systems))
        raise ValueError(f"{what} is refused: {ONE_IMPACT_MAP} (equal M, w, g0 and e), and {key} differs: "
                         f"{values}. Systems that differ run with coupling='euclidean' or 'none' and "
                         f"record_distance=False (the record then carries the Euclidean error)")


def weights(A, N: int | None = None) -> np.ndarray:
    """Validated N x N weights: finite, >= 0, zero diagonal."""
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


def edges_of(A) -> list:
    """The coupled pairs (i, j), i < j, in lexicographic order (the record's columns)."""
    N = A.shape[0]
    return [(i, j) for i in range(N) for j in range(i + 1, N) if A[i, j] > 0.0 or A[j, i] > 0.0]


def coupled_weights(A, edges, laws) -> np.ndarray:
    """``A`` without the edges whose law is "none" (they carry no force): the graph whose
    Laplacian sets the stability limit of the exchange."""
    from .coupling import UNCOUPLED   # coupled runs only: a single system's plan (the FMU slave) needs no law
    Ac = np.array(A, dtype=np.float64)
    for (i, j), law in zip(edges, laws):
        if law == UNCOUPLED:
            Ac[i, j] = Ac[j, i] = 0.0
    return Ac


def held_exchange(M, Kp, Kd, step: float, A=None, laws=None, hold: str = "zoh", allow_unstable: bool = False,
                  step_name: str = "H", exchange: str = "explicit", own=None):
    """The one check of the held coupling exchange of a run (docs/design.md §2.6), step 5 of
    :func:`plan_run`: gains as n x n matrices, the weights of the edges whose law carries a
    force (``laws``: one code per edge of ``A``, default all coupled; ``A`` default the pair),
    the hold in use (``"zoh"``; the master's ``"foh"``) and the exchange (``"explicit"``; the
    master's ``"implicit"``; ``own``: the systems' own ``(K, C)`` where the systems integrate them
    inside the step, :func:`fmu_sync.core.exchange.exchange_limit`). Returns ``(Kp, Kd, A_coupled,
    limit)``; ``limit`` is None when no edge is coupled; refused with ``UnstableExchange``
    (a ValueError) unless ``allow_unstable``."""
    from .coupling import SWITCHING, UNCOUPLED, gain_matrix   # coupled runs only (see coupled_weights)
    n = np.atleast_2d(np.asarray(M, dtype=np.float64)).shape[0]
    Kp_m, Kd_m = gain_matrix(Kp, n, "Kp"), gain_matrix(Kd, n, "Kd")
    A = weights([[0.0, 1.0], [1.0, 0.0]] if A is None else A)
    edges = edges_of(A)
    laws = np.full(len(edges), SWITCHING, dtype=np.int64) if laws is None else np.asarray(laws)
    Ac = coupled_weights(A, edges, laws)
    if not np.any(laws != UNCOUPLED):
        return Kp_m, Kd_m, Ac, None
    return Kp_m, Kd_m, Ac, check_exchange(M, Kp_m, Kd_m, step, A=Ac, allow_unstable=allow_unstable,
                                          step_name=step_name, hold=hold, exchange=exchange, own=own)


def coupling_exchange(scheme, systems) -> str:
    """The exchange of the core's coupled loop (:func:`.loop.integrate_network`) for ``scheme``:
    ``"implicit"`` (the coupling inside the step, its trapezoid: A-stable, docs/design.md §2.6)
    for ``scheme="trapezoid"`` (n = 1: core/loop.py; n > 1: core/loop_implicit.py), else the
    zero-order hold of the start forces."""
    return "implicit" if scheme == "trapezoid" else "explicit"


# ------------------------------------------------------------------ the plan
@dataclass(frozen=True, eq=False)
class RunPlan:
    """A checked run (:func:`plan_run`). ``q``, ``u``: the start states, (N, n);
    ``grid``: the step grid (None for a slave, which has no end time); ``rows``: record
    rows (0 without a record); ``code``/``theta``: the scheme of the kernels (``code``
    None for the exact solver or per-system schemes); ``dts``: each system's internal
    step; ``H``: the exchange step (the step itself in the core); ``Kp``, ``Kd``: gain
    matrices and ``A_coupled`` the graph of the coupled edges (None for one system);
    ``coupled``: some edge's law carries a force;
    ``limit``: the exchange verdict (:class:`~.exchange.ExchangeLimit`, None uncoupled)."""

    systems: tuple
    q: np.ndarray
    u: np.ndarray
    grid: RunSteps | None
    record_every: int
    rows: int
    schemes: tuple
    code: int | None
    theta: float
    dts: tuple
    H: float
    hold: str
    laws: np.ndarray | None = None
    coupled: bool = False
    Kp: np.ndarray | None = None
    Kd: np.ndarray | None = None
    A_coupled: np.ndarray | None = None
    limit: ExchangeLimit | None = None

    @property
    def dt(self) -> float:
        """The step of the grid (the core's dt, the master's H)."""
        return self.grid.dt if self.grid is not None else self.dts[0]

    @property
    def whole_steps(self) -> int:
        """Steps of full length (the kernels' ``n_steps``); then the shortened one, if any."""
        return self.grid.steps - 1 if self.grid.short else self.grid.steps

    @property
    def dt_last(self) -> float:
        """The kernels' ``dt_last`` argument: the shortened last step, 0.0 when there is none."""
        return self.grid.dt_last if self.grid.short else 0.0


def network_geometry(systems, Q):
    """``(geo, shared)``: the distance geometry of the run and whether the systems share one impact
    map (M, w, g0, e). Without one, ``geo`` serves the Euclidean error alone, in the norm
    ``P = diag(Q, M_mean)`` (M_mean the mean of the nodes' M; docs/design.md §2.5.3): no quotient
    distance is computed against it."""
    from .distance import geometry, make_geometry
    shared = geometry_difference(systems) is None
    s0 = systems[0]
    if shared:
        return geometry(s0, Q), True
    M = np.mean([np.atleast_2d(s.M) for s in systems], axis=0)
    return make_geometry(M, s0.w, s0.g0, s0.e, Q), False


def critical_system(systems):
    """The system whose mass matrix has the smallest eigenvalue: for systems that differ in M, the
    held exchange is checked with it (the largest coupling frequency, the conservative limit; for
    equal M it is the first system)."""
    low = [float(np.linalg.eigvalsh(np.atleast_2d(np.asarray(s.M, dtype=np.float64))).min()) for s in systems]
    return systems[int(np.argmin(low))]


def _edge_laws(A, N: int, laws) -> np.ndarray:
    """The law code of every edge: ``laws``, or the switching law on every edge of ``A`` (default:
    the pair)."""
    from .coupling import SWITCHING   # coupled runs only (see coupled_weights)
    if laws is None:
        return np.full(1 if A is None else len(edges_of(weights(A, N))), SWITCHING, dtype=np.int64)
    return np.atleast_1d(np.asarray(laws, dtype=np.int64))


def _check_geometry(systems, laws, A, N, distance, names) -> None:
    """Step 1 of :func:`plan_run`: one impact map where a quotient law or the distance record needs it."""
    if geometry_difference(systems) is None:
        return
    from .coupling import LAW_NAMES, QUOTIENT_LAWS   # coupled runs only (see coupled_weights)
    quotient = [c for c in _edge_laws(A, N, laws) if c in QUOTIENT_LAWS]
    if quotient:
        check_common_geometry(systems, names, f"the {LAW_NAMES[int(quotient[0])]} law")
    if distance:
        check_common_geometry(systems, names, "the distance record")


def _per_system(value, N: int, what: str) -> tuple:
    if isinstance(value, (str, float, int)) or value is None:
        return (value,) * N
    out = tuple(value)
    if len(out) != N:
        raise ValueError(f"{what} per system needs {N} entries, got {len(out)}")
    return out


def _schemes(systems, scheme, theta, dt, step, exact, allow_unstable, system_names):
    """Step 3 of :func:`plan_run`: each system's scheme and internal step, the kernels' scheme code
    (None for per-system schemes) and each scheme's limit; ``(schemes, dts, code, theta)``."""
    N = len(systems)
    schemes = _per_system(scheme, N, "scheme")
    dts = tuple(step if d is None else check_step(d, "dt") for d in _per_system(dt, N, "dt"))
    if "exact" in schemes:
        for s in systems:
            refuse_nonlinear(s)
    code = None
    for s in dict.fromkeys(schemes):
        if s is not None and not (exact and s == "exact"):
            c, theta = scheme_code(s, theta)
            code = c if len(set(schemes)) == 1 else None
    if not allow_unstable:
        seen = set()
        for i, (s, sch, d) in enumerate(zip(systems, schemes, dts)):
            if sch not in (None, "exact") and (id(s), sch, d) not in seen:
                try:
                    check_stable(s, sch, d)
                except UnstableScheme as exc:
                    if system_names is None:
                        raise
                    raise UnstableScheme(f"{system_names[i]}: {exc}") from None
                seen.add((id(s), sch, d))
    return schemes, dts, code, theta


def _coupling(systems, A, laws, Kp, Kd, step, hold, allow_unstable, step_name, exchange, cosim):
    """Step 5 of :func:`plan_run`: forces through B = I, the laws per edge, the held exchange checked
    with the lightest system (:func:`critical_system`); ``(laws, coupled, held_exchange(...))``."""
    from .coupling import COMPENSATED, UNCOUPLED   # coupled runs only (see coupled_weights)
    from .compensation import check_compensated
    n = systems[0].n
    for s in systems:
        if s.n_inputs != n or not np.array_equal(s.B, np.eye(n)):
            raise ValueError(f"coupled systems take the forces through B = I (tau has n = {n} entries); "
                             f"got B of shape {s.B.shape}")
    laws_a = _edge_laws(A, len(systems), laws)
    if np.any(laws_a == COMPENSATED):
        check_compensated(n, systems[0].force)
    sc = critical_system(systems)   # the lightest node sets the exchange's limit (docs/design.md §2.5.3)
    own = (sc.K, sc.C) if cosim else None   # a co-simulation: the slaves integrate K, C inside H
    return laws_a, bool(np.any(laws_a != UNCOUPLED)), held_exchange(sc.M, Kp, Kd, step, A, laws_a, hold,
                                                                     allow_unstable, step_name, exchange, own)


def plan_run(systems, starts, t_end, step, *, scheme="midpoint", theta: float = 0.5, dt=None,
             hold: str = "zoh", exchange: str = "explicit", A=None, laws=None, Kp=0.0, Kd=0.0,
             record_every: int = 1,
             t0: float = 0.0, record_values: int | None = None, record_what: str = "the record",
             record_hint: str = "", allow_unstable: bool = False,
             step_name: str = "dt", state_names=None, system_names=None, exact: bool = False,
             distance: bool = True) -> RunPlan:
    """Check a run once, in the order of the module docstring, and return its :class:`RunPlan`.

    ``systems``: one :class:`MechanicalSystem` for every start state or one per state;
    ``starts``: the start states ``(q, u)`` (one: a single system; two or more: coupled);
    ``t_end``: the end time (None: no grid, the FMU slave); ``step``: the grid's step (the
    core's ``dt``; the master's ``H``, with ``step_name="H"``); ``scheme``/``dt``: each
    system's scheme and internal step (one for all or one per system; ``dt`` default
    ``step``; ``None``: not checked; ``"exact"``, accepted where the caller offers it,
    ``exact=True``: no limit); ``hold``: the hold of the exchange; ``exchange``: explicit or
    implicit (the master's ``exchange="implicit"``);
    ``A`` (default: the pair), ``laws`` (law codes per edge, default all switching),
    ``Kp``, ``Kd``: the coupling (coupled runs only); ``record_values``: float64 values per
    record row (None: the caller keeps no record, or checks it elsewhere);
    ``allow_unstable``: skip the scheme limit and run an unstable exchange (its verdict
    is still in ``limit``);
    ``state_names``/``system_names``: how messages name the states (``x1``, ... or ``x0``)
    and the systems (default ``system 1``, ...; a scheme refusal then names none);
    ``distance``: the run records the quotient distance (then, as for a quotient law, the systems
    must share one impact map; otherwise they may differ in M, w, g0 and e).
    """
    starts = list(starts)
    N = len(starts)
    if N < 1:
        raise ValueError("a run needs at least one start state")
    systems = as_systems(systems, N)
    if N > 1:                                                           # 1. systems
        check_one_loop(systems, system_names)
        _check_geometry(systems, laws, A, N, distance, system_names)
    s0 = systems[0]
    if t_end is None:                                                   # 2. the grid
        grid, rows = None, 0
        step = check_step(step, step_name)
        record_every = int(record_every)
    else:
        grid, record_every = check_run(t_end, step, record_every, t0, dt_name=step_name)
        step = grid.dt
        rows = record_rows(grid.steps, record_every)
    schemes, dts, code, theta = _schemes(systems, scheme, theta, dt, step, exact, allow_unstable,
                                         system_names)                 # 3. scheme and its limit
    names = state_names or ([f"x{i + 1}" for i in range(N)] if N > 1 else ["x0"])
    q = np.zeros((N, s0.n))                                             # 4. start states
    u = np.zeros((N, s0.n))
    for i, (s, x) in enumerate(zip(systems, starts)):
        q[i], u[i] = as_state(s, x, names[i])
        check_start(s, q[i], names[i])
        if s.force is not None:   # compilable, the right shape, finite at the start (LawRefused)
            s.force.check(s.p, q[i], u[i], t=float(t0) if t_end is not None else 0.0, where=f"{names[i]}:")
    laws_a = Kp_m = Kd_m = Ac = limit = None
    coupled = False
    if N > 1:                                                           # 5. the coupling
        laws_a, coupled, (Kp_m, Kd_m, Ac, limit) = _coupling(systems, A, laws, Kp, Kd, step, hold, allow_unstable,
                                                             step_name, exchange, dt is not None)
    if record_values is not None and grid is not None:                  # 6. the record budget
        check_record_size(rows, int(record_values), record_what, record_hint)
    return RunPlan(tuple(systems), q, u, grid, record_every, rows, schemes, code, float(theta), dts, step, hold,
                   laws_a, coupled, Kp_m, Kd_m, Ac, limit)
