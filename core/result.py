"""The results of a run (docs/design.md §5.2).

:class:`SimulationResult` (one system), :class:`PairResult` (two coupled
systems: the monolithic pair and the co-simulation master, same fields, so
reports and plots take either) and :class:`NetworkResult` (N systems on a
graph: the monolithic network and the co-simulated one). A result attached to a
:class:`~fmu_sync.core.errors.RunFailed` as ``partial`` has ``error`` set:
``success`` is then False and ``message`` names what happened.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .distance import BRANCH_NAMES
from .metrics import SyncMetrics, sync_metrics

__all__ = ["RunStatus", "SimulationResult", "PairResult", "NetworkResult", "BRANCH_NAMES", "concat_pairs"]


class RunStatus:
    """``success`` / ``message`` of a result from its ``error`` field (None: it ran to the end),
    and the views every result has (:mod:`fmu_sync.core.views`): a short repr,
    :meth:`to_xarray`, :meth:`to_dataframe` and :meth:`plot`; for coupled runs the position weight
    of the distance (``info["metric"]``, ``info["Q"]``)."""

    error: str | None

    def __repr__(self) -> str:
        from .views import short_repr
        return short_repr(self)

    def to_xarray(self, settings: dict | None = None):
        """An xarray Dataset: coordinate ``t``, dimensions ``node``/``dof``/``edge``, ``units`` and
        ``long_name`` on every variable, the run's settings as attributes (needs xarray)."""
        from .views import to_xarray
        return to_xarray(self, settings)

    def to_dataframe(self):
        """A pandas DataFrame with the CSV's columns (``t [s]``, ``q1 [m]``, ``d[1-2]``, ...)."""
        from .views import to_dataframe
        return to_dataframe(self)

    def plot(self):
        """A quick-look matplotlib Figure (positions; d and the Euclidean error when recorded).
        The files' plots: ``fmu-sync plot DIR`` (:mod:`fmu_sync.plots`)."""
        from .views import figure
        return figure(self)

    @property
    def metric(self) -> str | None:
        """How the distance's position weight Q was chosen: "energy" (the law's own metric,
        V = d^2/2 the energy of the relative motion), "user" (an explicit Q: V is then not a
        Lyapunov function of the law) or "identity" (uncoupled, no energy norm); None if no
        distance was computed (docs/design.md §2.5.1)."""
        return getattr(self, "info", {}).get("metric")

    @property
    def Q(self) -> np.ndarray | None:
        """The position weight of the distance ``||x||_P^2 = q^T Q q + u^T M u`` used by the run."""
        Q = getattr(self, "info", {}).get("Q")
        return None if Q is None else np.asarray(Q)

    @property
    def success(self) -> bool:
        return self.error is None

    @property
    def message(self) -> str:
        return "the run reached its end" if self.error is None else self.error


@dataclass(repr=False)
class SimulationResult(RunStatus):
    """Sampled trajectory. ``percussion[i]`` is the impulse (N s) applied over the
    steps that end at ``t[i]`` (one step for ``record_every=1``). The exact
    solver also attaches its events (:class:`fmu_sync.core.exact.ExactEvents`)."""

    t: np.ndarray
    q: np.ndarray
    u: np.ndarray
    percussion: np.ndarray
    scheme: str
    dt: float
    events: object = None
    error: str | None = None

    @property
    def impacts(self) -> int:
        """Number of records with a positive percussion."""
        return int(np.count_nonzero(self.percussion > 0.0))


@dataclass(repr=False)
class PairResult(RunStatus):
    """Sampled run of two coupled systems.

    Arrays have one row per record: ``t`` (N,), ``q1, u1, q2, u2`` (N, n),
    ``tau1, tau2`` (N, m) — the coupling forces held over the step that ends at
    ``t[i]`` (row 0: the forces at the start) — and, when the distance was
    computed, ``d`` (N,), ``branch`` (N,) int codes into :data:`BRANCH_NAMES`,
    ``V = d**2 / 2`` and ``euclidean = ||x1 - x2||_P``. ``impacts1/2`` count
    steps (or communication steps) with a positive percussion.
    ``d``/``branch``/``V``/``euclidean`` are ``None`` when nothing asked for
    the distance (no coupling that needs it and ``record_distance=False``).
    """

    t: np.ndarray
    q1: np.ndarray
    u1: np.ndarray
    q2: np.ndarray
    u2: np.ndarray
    tau1: np.ndarray
    tau2: np.ndarray
    d: np.ndarray | None
    branch: np.ndarray | None
    euclidean: np.ndarray | None
    impacts1: int = 0
    impacts2: int = 0
    coupling: str | None = None
    info: dict = field(default_factory=dict)
    error: str | None = None

    @property
    def V(self) -> np.ndarray | None:
        """V = d^2 / 2: a Lyapunov function of the law when :attr:`metric` is "energy"
        (docs/design.md §2.5.1)."""
        return None if self.d is None else 0.5 * self.d**2

    @property
    def branch_names(self) -> list[str] | None:
        from .views import branch_label
        return None if self.branch is None else [branch_label(b) for b in self.branch]

    def sync(self, threshold: float = 1e-6, threshold_rel: float | None = None, **window) -> SyncMetrics:
        """Synchronization metrics of d (:mod:`fmu_sync.core.metrics`): decay rate of its
        envelope (median of the per-decade rates over the decades d falls through) with its
        spread, whether it is resolved and why not, the window, ``t_sync`` (time after which
        d < threshold, or < ``threshold_rel * d0``), ``t_fit``, and the ultimate bound (max d
        over the last 20 % of the run). ``window``: ``hi``, ``lo``, ``floor_abs``, ``tail`` of
        :func:`sync_metrics`. For a forced impacting pair one start state's rate is a sample:
        :func:`fmu_sync.core.sync_rate` gives the statistic over start states."""
        if self.d is None:
            raise ValueError("this run did not record the distance d")
        return sync_metrics(self.t, self.d, threshold, threshold_rel=threshold_rel, **window)

    @property
    def rate(self) -> float:
        """Decay rate of the envelope of d (1/s), default window; see :meth:`sync`."""
        return self.sync().rate

    @property
    def rate_err(self) -> float:
        """Uncertainty of :attr:`rate`: the spread of its per-decade rates."""
        return self.sync().rate_err

    @property
    def t_sync(self) -> float:
        """Time after which d stays below 1e-6 (inf: never); see :meth:`sync`."""
        return self.sync().t_sync

    @property
    def bound(self) -> float:
        """Ultimate bound of d: max d over the last 20 % of the run (practical synchronization)."""
        return self.sync().bound

    def time_to_sync(self, threshold: float = 1e-6) -> float:
        """First time after which d stays below ``threshold`` (inf if never)."""
        if self.d is None:
            raise ValueError("this run did not record the distance d")
        above = np.nonzero(~(self.d < threshold))[0]
        if above.size == 0:
            return float(self.t[0])
        if above[-1] == self.d.size - 1:
            return float("inf")
        return float(self.t[above[-1] + 1])

    def to_npz(self, path) -> None:
        data = {k: v for k, v in self.__dict__.items() if isinstance(v, np.ndarray)}
        if self.d is not None:
            data["V"] = self.V
        np.savez_compressed(path, **data)

    def to_csv(self, path) -> None:
        """Tidy CSV as ``fmu-sync run`` writes it: one row per record, one column per scalar
        component, names with units, branches by name, shortest round-trip numbers."""
        from .views import column_headers, csv_lines, layout, record_arrays
        lay, arrays = layout(self), record_arrays(self)
        names = [h for k, a in arrays for h in column_headers(k, a.shape[1], lay)]
        block = np.column_stack([a.astype(np.float64) for _, a in arrays])
        branch = [i for i, h in enumerate(names) if h.startswith("branch")]
        with open(path, "w", encoding="ascii", newline="\n") as fh:
            fh.write(",".join(names) + "\n")
            fh.writelines(csv_lines(block, branch))


@dataclass(repr=False)
class NetworkResult(RunStatus):
    """Sampled run of N coupled systems on a weighted graph: the co-simulated network
    (:func:`fmu_sync.master.cosimulate_network`) and its monolithic reference
    (:func:`fmu_sync.core.network.simulate_network`).

    ``q, u, tau``: (rows, N, n) (``tau`` row i: the forces held over the step
    that ends at ``t[i]``, row 0 the forces at the start); ``edges``: the
    coupled pairs (i, j), i < j;
    ``d, euclidean`` (rows, n_edges) and ``branch`` (rows, n_edges) per edge;
    ``V = 1/2 sum_edges a_ij d_ij^2`` (rows,) with a_ij the mean of the two
    directed weights; ``impacts`` (N,) counts steps (communication steps) with
    a positive percussion. ``error`` names the failure (a slave, a divergence;
    only on the ``partial`` result of a :class:`~fmu_sync.core.errors.RunFailed`).
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

    @property
    def d_max(self) -> np.ndarray | None:
        """max over the edges of the pairwise distances, per row (rows,)."""
        return None if self.d is None else np.max(self.d, axis=1)

    def sync(self, threshold: float = 1e-6, threshold_rel: float | None = None, **window) -> SyncMetrics:
        """:func:`fmu_sync.core.metrics.sync_metrics` of :attr:`d_max` (the network is
        synchronized when its largest pairwise distance is); the window as in
        :meth:`PairResult.sync`."""
        if self.d is None:
            raise ValueError("this run did not record the distances d")
        return sync_metrics(self.t, self.d_max, threshold, threshold_rel=threshold_rel, **window)


def concat_pairs(parts) -> PairResult:
    """Consecutive pair results as one (the last one's counts and error, the first one's info)."""
    first, last = parts[0], parts[-1]
    cols = ("t", "q1", "u1", "q2", "u2", "tau1", "tau2", "d", "branch", "euclidean")
    g = lambda k: None if getattr(first, k) is None else np.concatenate([getattr(p, k) for p in parts])  # noqa: E731
    return PairResult(*(g(k) for k in cols), impacts1=last.impacts1, impacts2=last.impacts2,
                      coupling=first.coupling, info=dict(first.info), error=last.error)
