"""The coupling FMU's interface and slave (docs/design.md §4.8, docs/ssp.md).

The coupling of N systems on a graph as an FMI 2.0 co-simulation FMU of its
own, so that a master that is not ours (libcosim, fmpy's SSP runner) can run
the coupled system as a package of FMUs (:mod:`fmu_sync.ssp`):

* inputs: the states of the N systems, ``q[i]``, ``u[i]`` (n = 1) or
  ``q[i,k]``, ``u[i,k]`` (n > 1), i = 1..N;
* outputs: the force on each system ``tau[i]`` / ``tau[i,k]`` and, per edge
  e = 1..E (the graph's edges (i, j), i < j, in the order of
  :func:`fmu_sync.core.network.edges_of`), the quotient distance ``d[e]``,
  ``V[e] = 1/2 (a_ij + a_ji)/2 d^2``, the branch code ``branch[e]`` (0 E,
  1 J12, 2 J21, 3 J2) and the Euclidean error ``euclidean[e]``; every output
  depends directly on every input (ModelStructure) and is computed from the
  current inputs whenever it is read;
* parameters: ``law[e]`` (enumeration ``fmu_sync.Law``: switching, euclidean,
  none, switching-compensated), the weights ``a[i,j]`` and ``a[j,i]`` of each edge, the gains ``Kp``,
  ``Kd`` and the metric ``Q`` (n x n for n > 1), the impact geometry ``M``,
  ``w``, ``g0``, ``e`` (which must equal the systems') and, for n = 1, each system's
  force law h, ``k[i]``, ``c[i]``, ``f0[i]``, ``F[i]``, ``Omega[i]``, ``phi[i]``
  (:func:`force_vars`: the 1-DOF mechanical FMU's own declaration of them, which the
  compensated law evaluates at the chain ends, docs/design.md §2.5.2; they must equal
  the systems').

The structure (N, n and the edges) is fixed at export (:class:`CouplingSpec`,
stored in the FMU's start file); the values are parameters. The numbers come
from one compiled call per evaluation of the core's
:func:`fmu_sync.core.network.network_forces` (:mod:`.coupling_stepper`).
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np

from ..core.compensation import check_compensated, force_table
from ..core.coupling import COMPENSATED, gain_matrix
from ..core.declaration import DEFAULT_UNITS
from ..core.distance import make_geometry
from ..core.pair import stack_nodes
from .contract import INPUT_BOUND, LAW_ITEMS, LAW_TYPE, POSITIVE_MIN, Var, matrix, model
from .slave import Slave

__all__ = ["CouplingSpec", "CouplingSlave", "node_names", "edge_names", "MODEL",
           "IDENTIFIER", "BRANCH_CODES", "SYSTEM_MODEL", "force_names", "force_vars"]

MODEL = "coupling"
IDENTIFIER = "SyncCoupling"
#: values of the branch[e] output (fmu_sync.core.distance's codes; -1: no distance computed)
BRANCH_CODES = "0 = E, 1 = J12, 2 = J21, 3 = J2"
#: the mechanical FMU (fmus/contract.py's registry) whose force law h the compensated law evaluates
SYSTEM_MODEL = "impact-oscillator"


def force_names() -> tuple:
    """The parameters of the systems' force law h: :data:`SYSTEM_MODEL`'s declared parameters
    other than its impact geometry (k, c, f0, F, Omega, phi)."""
    decl = model(SYSTEM_MODEL).declaration
    return tuple(name for name in decl.names if name not in decl.geometry)


def force_vars(N: int) -> list[Var]:
    """The coupling FMU's copy of each system's force-law parameters, ``k[i]`` .. ``phi[i]``:
    the mechanical FMU's own variables (unit, range, start) renamed per system."""
    own = {v.name: v for v in model(SYSTEM_MODEL).declare()}
    return [replace(own[name], name=f"{name}[{i + 1}]",
                    description=f"{own[name].description}: system {i + 1}'s force law h, evaluated by "
                                f"law switching-compensated (must equal the system's {name})")
            for i in range(N) for name in force_names()]


@dataclass(frozen=True)
class CouplingSpec:
    """The structure of a coupling FMU: N nodes of n DOF and the coupled edges (0-based i < j);
    ``units``: the systems' units of q, u and tau (``(("q", "rad"), ...)``; empty: m, m/s, N), which
    its inputs, its outputs tau and its gains take (an importer such as OMSimulator refuses a
    connection between variables of different units)."""

    N: int
    n: int
    edges: tuple
    units: tuple = ()

    def unit(self, key: str) -> str:
        """The unit of ``q``, ``u`` or ``tau``."""
        return dict(self.units).get(key, DEFAULT_UNITS[key])

    def __post_init__(self):
        if self.units:
            from .slave import unit_exponents
            if set(dict(self.units)) != set(DEFAULT_UNITS):
                raise ValueError(f"units must name q, u and tau, got {dict(self.units)!r}")
            for key, unit in self.units:
                unit_exponents(unit)      # ValueError naming a unit it cannot read
        if not (isinstance(self.N, int) and self.N >= 2):
            raise ValueError(f"a coupling FMU couples N >= 2 systems, got N = {self.N!r}")
        if not (isinstance(self.n, int) and self.n >= 1):
            raise ValueError(f"n (degrees of freedom) must be an integer >= 1, got {self.n!r}")
        if not self.edges:
            raise ValueError("a coupling FMU needs at least one edge")
        for e in self.edges:
            i, j = e
            if not (0 <= i < j < self.N):
                raise ValueError(f"edge {e} must be (i, j) with 0 <= i < j < N = {self.N}")
        if len(set(self.edges)) != len(self.edges):
            raise ValueError(f"edges must be distinct, got {list(self.edges)}")

    @classmethod
    def from_weights(cls, A, n: int = 1, units: dict | None = None) -> "CouplingSpec":
        from ..core.network import edges_of, weights
        a = weights(A)
        return cls(a.shape[0], int(n), tuple(tuple(int(x) for x in e) for e in edges_of(a)), _units(units))

    def as_dict(self) -> dict:
        out = {"N": self.N, "n": self.n, "edges": [list(e) for e in self.edges]}
        if self.units:      # the default units are not written (an FMU without units is in m, m/s, N)
            out["units"] = dict(self.units)
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "CouplingSpec":
        return cls(int(d["N"]), int(d["n"]), tuple(tuple(int(x) for x in e) for e in d["edges"]),
                   _units(d.get("units")))


def _units(units: dict | None) -> tuple:
    """The units of q, u, tau as :attr:`CouplingSpec.units` (empty for the default m, m/s, N)."""
    if not units or dict(units) == DEFAULT_UNITS:
        return ()
    return tuple(sorted(dict(units).items()))


def node_names(base: str, i: int, n: int) -> list[str]:
    """Names of node i's (0-based) n components of ``base``: ``q[i+1]`` or ``q[i+1,k]``."""
    return [f"{base}[{i + 1}]"] if n == 1 else [f"{base}[{i + 1},{k + 1}]" for k in range(n)]


def edge_names(base: str, E: int) -> list[str]:
    return [f"{base}[{e + 1}]" for e in range(E)]


def _param(name, unit, description, start, min=None, max=None):
    return Var(name, "Real", "parameter", "fixed", description, initial="exact", unit=unit,
               min=min, max=max, start=start)


def _square(sym, unit, what, n, start_diag, diag_min):
    if n == 1:
        return [_param(sym, unit, what, start_diag, min=diag_min)]
    return [_param(name, unit, f"{what}, row {k // n + 1}, column {k % n + 1}",
                   start_diag if k // n == k % n else 0.0, min=diag_min if k // n == k % n else None)
            for k, name in enumerate(matrix(sym, n))]


def declare(spec: CouplingSpec) -> list[Var]:
    """The interface of a coupling FMU, in value-reference order."""
    N, n, E = spec.N, spec.n, len(spec.edges)
    uq, uu, ut = spec.unit("q"), spec.unit("u"), spec.unit("tau")
    own = bool(spec.units)        # the systems' own units: the gains' follow (tau per q, ...)
    inputs = []
    for base, unit, what in (("q", uq, "Position"), ("u", uu, "Velocity")):
        for i in range(N):
            inputs += [Var(name, "Real", "input", "continuous", f"{what} of system {i + 1}"
                           + ("" if n == 1 else f", coordinate {k + 1}"), unit=unit, start=0.0,
                           min=-INPUT_BOUND, max=INPUT_BOUND) for k, name in enumerate(node_names(base, i, n))]
    ins = tuple(v.name for v in inputs)
    params = ([Var(name, "Enumeration", "parameter", "fixed",
                   f"Coupling law of edge {e + 1} = (system {spec.edges[e][0] + 1}, system {spec.edges[e][1] + 1})",
                   initial="exact", start=0, declared_type=LAW_TYPE) for e, name in enumerate(edge_names("law", E))])
    for (i, j) in spec.edges:
        for a, b in ((i, j), (j, i)):
            params.append(_param(f"a[{a + 1},{b + 1}]", "1", f"Weight a_ij of the force on system {a + 1} "
                                 f"from its edge with system {b + 1} (>= 0)", 1.0, min=0.0))
    stiff = f"{ut}/{uq}" if own else "N/m"
    params += (_square("Kp", stiff, "Proportional gain Kp", n, 1.0, 0.0)
               + _square("Kd", f"{ut}.s/{uq}" if own else "N.s/m", "Derivative gain Kd", n, 0.5, 0.0)
               + _square("Q", stiff, "Position weight Q of the norm ||x||^2 = q^T Q q + u^T M u (SPD)", n, 1.0,
                         POSITIVE_MIN)
               + _square("M", f"{ut}.s2/{uq}" if own else "kg", "Mass matrix M of the systems (SPD; must equal "
                         "theirs)", n, 1.0, POSITIVE_MIN)
               + ([_param("w", "1", "Wall normal w in g(q) = w^T q + g0 (must equal the systems')", 1.0)]
                  if n == 1 else [_param(f"w[{k + 1}]", "1", f"Wall normal w, component {k + 1} (must equal "
                                         f"the systems')", 1.0 if k == 0 else 0.0) for k in range(n)])
               + [_param("g0", uq, "Wall offset g0 in g(q) = w^T q + g0 (must equal the systems')", 0.0),
                  _param("e", "1", "Newton restitution coefficient (must equal the systems')", 0.9, min=0.0,
                         max=1.0)])
    if n == 1:   # the compensated law's h (1-DOF only: check_compensated)
        params += force_vars(N)
    pnames = tuple(v.name for v in params)
    outs = []
    for i in range(N):
        outs += [Var(name, "Real", "output", "continuous", f"Coupling force on system {i + 1}"
                     + ("" if n == 1 else f", coordinate {k + 1}") + " (B = I)", initial="calculated", unit=ut,
                     depends=ins, initial_depends=ins + pnames) for k, name in enumerate(node_names("tau", i, n))]
    for base, typ, unit, what in (
            ("d", "Real", None, "Quotient distance d of edge {e} (sqrt(J): the norm ||.||_P with Q in N/m)"),
            ("V", "Real", "J", "V = 1/2 (a_ij + a_ji)/2 d^2 of edge {e} (its share of the Lyapunov function)"),
            ("euclidean", "Real", None, "Euclidean error ||x_i - x_j||_P of edge {e} (sqrt(J))"),
            ("branch", "Integer", None, "Branch of the quotient distance of edge {e} (" + BRANCH_CODES + ")")):
        outs += [Var(name, typ, "output", "continuous" if typ == "Real" else "discrete",
                     what.format(e=e + 1), initial="calculated", unit=unit, depends=ins,
                     initial_depends=ins + pnames) for e, name in enumerate(edge_names(base, len(spec.edges)))]
    return inputs + outs + params


class CouplingConfiguration:
    """A validated parameter set: laws, weights, gains and the distance geometry."""

    def __init__(self, laws, W2, Kp, Kd, geo, hp):
        self.laws, self.W2, self.Kp, self.Kd, self.geo, self.hp = laws, W2, Kp, Kd, geo, hp


@contextmanager
def _overflow(what: str):
    """numpy's floating-point errors (overflow, invalid, division by zero) raised inside, refused
    as a ValueError naming ``what`` (the parameters that were being combined), never printed."""
    try:
        with np.errstate(over="raise", invalid="raise", divide="raise", under="ignore"):
            yield
    except FloatingPointError as exc:
        raise ValueError(f"{what}: computing with these values overflows the float range ({exc}); "
                         f"use values of a physical magnitude") from None


class CouplingSlave(Slave):
    """The slave of the coupling FMU of one structure: ``CouplingSlave(spec)``."""

    MODEL = MODEL
    MODEL_IDENTIFIER = IDENTIFIER

    def __init__(self, spec: CouplingSpec):
        self.SPEC = spec
        self.N = spec.n
        edges = ", ".join(f"({i + 1},{j + 1})" for i, j in spec.edges)
        self.DESCRIPTION = (
            f"Synchronizing coupling of {spec.N} mechanical systems with {spec.n} degree(s) of freedom on "
            f"the edges {edges}: forces tau_i = sum_j a_ij tau_i^(j) of the switching quotient, compensated "
            f"switching or Euclidean PD law per edge, quotient distance d and V per edge (fmu-sync core)")

    def declare(self) -> list[Var]:
        return declare(self.SPEC)

    def _square(self, p: dict, sym: str):
        n = self.SPEC.n
        if n == 1:
            return np.array([[p[sym]]], dtype=np.float64)
        return np.array([p[k] for k in matrix(sym, n)], dtype=np.float64).reshape(n, n)

    def configure(self, p: dict) -> CouplingConfiguration:
        """Validate a complete parameter set; raises ValueError naming what is wrong: a value out of
        its range, an arithmetic overflow (numpy's floating-point errors raise here and are refused
        naming the parameters, never printed as warnings on the host's stderr) and forces beyond
        what the systems accept (:meth:`check_force_bound`)."""
        spec = self.SPEC
        n, E = spec.n, len(spec.edges)
        codes = {v for _, v, _ in LAW_ITEMS}
        laws = np.array([p[k] for k in edge_names("law", E)], dtype=np.int64)
        for k, c in enumerate(laws):
            if int(c) not in codes:
                raise ValueError(f"law[{k + 1}] must be one of {sorted(codes)}, got {c}")
        W2 = np.array([[p[f"a[{i + 1},{j + 1}]"], p[f"a[{j + 1},{i + 1}]"]] for i, j in spec.edges],
                      dtype=np.float64).reshape(E, 2)
        if not (np.all(np.isfinite(W2)) and np.all(W2 >= 0.0)):
            raise ValueError(f"the weights a[i,j] must be finite and >= 0, got {W2.tolist()}")
        w = [p["w"]] if n == 1 else [p[f"w[{k + 1}]"] for k in range(n)]
        with _overflow("Kp"):
            Kp = gain_matrix(self._square(p, "Kp"), n, "Kp")
        with _overflow("Kd"):
            Kd = gain_matrix(self._square(p, "Kd"), n, "Kd")
        with _overflow("the impact geometry M, w, g0, e and the metric Q"):
            geo = make_geometry(self._square(p, "M"), w, p["g0"], p["e"], self._square(p, "Q"))
        if np.any(laws == COMPENSATED):
            check_compensated(n)
        with _overflow("the force laws k[i], c[i], f0[i], F[i], Omega[i], phi[i]"):
            hp = self.force_table(p)
        self.check_force_bound(p, laws, W2, Kp, Kd)
        return CouplingConfiguration(laws, W2, Kp, Kd, geo, hp)

    def check_force_bound(self, p: dict, laws, W2, Kp, Kd) -> None:
        """The coupling's forces must stay within what the systems accept as their input tau,
        |tau| <= INPUT_BOUND (contract.INPUT_BOUND): refused (ValueError naming the parameters) when the
        force on a system at a unit state difference (1 in every coordinate of q and u) could exceed it,
        ``sum_j a_ij (2 |Kp| + 2 |Kd| + |h_i|)`` (|.| the largest row sum; 2: the compensated law's
        whole relative gain; ``|h_i| = |k[i]| + |c[i]| + |f0[i]| + |F[i]|`` on a switching-compensated
        edge, the force law it cancels). During a run, inputs that make a force exceed the bound
        make the call fail (the stepper's check, :mod:`.coupling_stepper`)."""
        with np.errstate(over="ignore"):     # an overflowing sum is inf: refused below
            gains = 2.0 * float(np.max(np.sum(np.abs(Kp), axis=1))) + 2.0 * float(np.max(np.sum(np.abs(Kd), axis=1)))
        h_names = ("k", "c", "f0", "F")
        total, terms = [0.0] * self.SPEC.N, [[] for _ in range(self.SPEC.N)]
        for (i, j), law, (aij, aji) in zip(self.SPEC.edges, laws, W2):
            for node, other, a in ((i, j, aij), (j, i, aji)):
                h, said = 0.0, f"a[{node + 1},{other + 1}] = {float(a):g}"
                if int(law) == COMPENSATED:
                    h = sum(abs(p[f"{x}[{node + 1}]"]) for x in h_names)
                    said += ", its force law k, c, f0, F = " + ", ".join(f"{p[f'{x}[{node + 1}]']:g}" for x in h_names)
                total[node] += float(a) * (gains + h)
                terms[node].append(said)
        gain = ", ".join(f"{k} = {float(v[0, 0]):g}" if self.SPEC.n == 1 else f"{k} = {v.tolist()}"
                         for k, v in (("Kp", Kp), ("Kd", Kd)))
        for node, f in enumerate(total):
            if not f <= INPUT_BOUND:
                raise ValueError(
                    f"the coupling force on system {node + 1} at a unit state difference (1 in every coordinate "
                    f"of q and u) reaches {f:.3g} (sum_j a_ij (2 |Kp| + 2 |Kd| + |h_i|) with {gain}, "
                    f"{'; '.join(terms[node])}), beyond |tau| <= {INPUT_BOUND:g}, what the systems accept as "
                    f"their input tau (contract.INPUT_BOUND): lower the gains, the weights or the force law")

    def force_table(self, p: dict) -> np.ndarray:
        """The systems' force laws as the core's table (:func:`fmu_sync.core.compensation.force_table`,
        the table the master builds from its systems): each system made by the mechanical FMU's
        declaration from its ``k[i]`` .. ``phi[i]`` (an empty (N, 3) table for n > 1)."""
        N = self.SPEC.N
        if self.SPEC.n > 1:
            return np.zeros((N, 3))
        fm = model(SYSTEM_MODEL)
        base = {v.name: v.start for v in fm.declare() if v.causality == "parameter"}
        systems = []
        for i in range(N):
            own = {name: p[f"{name}[{i + 1}]"] for name in force_names()}
            try:
                systems.append(fm.system({**base, **own}))
            except ValueError as exc:
                raise ValueError(f"the force law of system {i + 1} ({', '.join(f'{k}[{i + 1}]' for k in own)}): "
                                 f"{exc}") from None
        return force_table(*stack_nodes(*systems)[1:])

    def input_names(self) -> list[str]:
        return [v.name for v in self.declare() if v.causality == "input"]
