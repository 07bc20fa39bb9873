"""Scene schema (docs/design.md §4.5): every key of a scene file, its checker,
default and unit, and the validated :class:`Variant` one run is made of.

The file format itself is documented in :mod:`fmu_sync.scenes` and in the
comments of ``forced-pair.toml``.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np

from ..core import MechanicalSystem
from ..core.coupling import LAWS as COUPLING_LAWS
from ..core.steps import DEFAULT_SCHEME, SCHEMES as CORE_SCHEMES
from ..core.exchange import EXCHANGES, HOLDS
from ..strategies import FMI2_METHODS
from ..core.declaration import POSITIVE_MIN, Model, Param
from ..core.registry import builtin_models

__all__ = ["SceneError", "Key", "Variant", "PLOTS", "DEFAULT_OUT", "KEYS", "SYSTEM_KEYS", "BadValue", "REQUIRED",
           "MODELS", "LAWS", "SCHEMES", "MOREAU_SCHEMES", "MODES", "METHODS", "TABLES", "VARIANT_TABLES",
           "SINGLE_PLOTS", "DISTANCE_PLOTS", "plots_for", "system_keys", "NAME_RE", "show_value", "choice", "GRAPHS", "NETWORK_PLOTS", "NetworkSpec"]

#: the built-in models' names (a scene may also name a user model "path/to/model.py:name")
BUILTIN_MODELS = builtin_models()
MODELS = tuple(BUILTIN_MODELS)
#: the scenes' coupling.law values: the core's coupling laws, "none" first
LAWS = ("none",) + tuple(k for k in COUPLING_LAWS if k != "none")
#: the scenes' solver.scheme values: the core's Moreau schemes (core.steps, its default first), then the
#: exact event-driven solver of single 1-DOF systems
MOREAU_SCHEMES = (DEFAULT_SCHEME,) + tuple(k for k in CORE_SCHEMES if k != DEFAULT_SCHEME)
SCHEMES = MOREAU_SCHEMES + ("exact",)
MODES = ("core", "cosim")
#: the master's exchange orders a scene's FMI 2.0 FMU runs with, and its input holds: the strategy
#: registry's (fmu_sync.strategies, docs/cosim-strategies.md)
METHODS = FMI2_METHODS
PLOTS = ("positions", "distance", "impact-zoom", "lyapunov", "forces", "phase")
SINGLE_PLOTS = ("positions", "phase")
DISTANCE_PLOTS = ("distance", "impact-zoom", "lyapunov")
TABLES = ("system", "initial", "network", "coupling", "solver", "run", "record", "plot")
VARIANT_TABLES = ("system", "initial", "network", "coupling", "solver", "run", "record")
GRAPHS = ("ring", "path", "star", "all-to-all")
#: plots of a network run (N systems on a graph)
NETWORK_PLOTS = ("positions", "distance", "lyapunov")
DEFAULT_OUT = Path("fmu-sync-out")


def plots_for(pair: bool, distance: bool, network: bool) -> list[str]:
    """The plots drawn for a run: all of :data:`PLOTS` for a pair with d; a single system
    :data:`SINGLE_PLOTS`; without d no :data:`DISTANCE_PLOTS`; a network :data:`NETWORK_PLOTS`."""
    return [p for p in PLOTS if (pair or p in SINGLE_PLOTS) and (distance or p not in DISTANCE_PLOTS)
            and (not network or p in NETWORK_PLOTS)]
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


class SceneError(ValueError):
    """A scene file (or an override) is invalid; the message names file, key and value."""


# ---------------------------------------------------------------- key checkers
class BadValue(Exception):
    def __init__(self, problem: str, allowed: str):
        super().__init__(problem)
        self.problem, self.allowed = problem, allowed


REQUIRED = object()


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _number(gt=None, ge=None, le=None):
    parts = []
    if gt is not None:
        parts.append(f"> {gt:g}")
    if ge is not None:
        parts.append(f">= {ge:g}")
    if le is not None:
        parts.append(f"<= {le:g}")
    allowed = "a finite real number" + (" " + " and ".join(parts) if parts else "")
    if ge is not None and le is not None:
        allowed = f"a real number in [{ge:g}, {le:g}]"

    def check(v):
        if not _is_num(v):
            raise BadValue(f"is a {type(v).__name__}, not a number", allowed)
        x = float(v)
        if not math.isfinite(x) or (gt is not None and not x > gt) or (ge is not None and not x >= ge) \
                or (le is not None and not x <= le):
            raise BadValue("is out of range", allowed)
        return x
    return check


def _integer(ge=1):
    allowed = f"an integer >= {ge}"

    def check(v):
        if isinstance(v, bool) or not isinstance(v, int):
            raise BadValue(f"is a {type(v).__name__}, not an integer", allowed)
        if v < ge:
            raise BadValue("is out of range", allowed)
        return v
    return check


def _boolean(v):
    if not isinstance(v, bool):
        raise BadValue(f"is a {type(v).__name__}, not a boolean", "true or false")
    return v


def choice(*options):
    allowed = "one of " + ", ".join(f'"{o}"' for o in options)

    def check(v):
        if not isinstance(v, str):
            raise BadValue(f"is a {type(v).__name__}, not a string", allowed)
        if v not in options:
            raise BadValue("is not allowed", allowed)
        return v
    return check


def _text(v):
    if not isinstance(v, str):
        raise BadValue(f"is a {type(v).__name__}, not a string", "a string")
    return v


def _vector(v):
    allowed = "a list of finite numbers, e.g. [1.0, 0.5]"
    if not isinstance(v, list) or not v or not all(_is_num(x) and math.isfinite(x) for x in v):
        raise BadValue("is not a list of numbers", allowed)
    return [float(x) for x in v]


def _matrix(v):
    allowed = "a square matrix as a list of rows of finite numbers, e.g. [[2.0, 0.5], [0.5, 1.0]]"
    if not isinstance(v, list) or not v or not all(isinstance(r, list) for r in v):
        raise BadValue("is not a list of rows", allowed)
    if not all(_is_num(x) and math.isfinite(x) for r in v for x in r):
        raise BadValue("has entries that are not finite numbers", allowed)
    if any(len(r) != len(v) for r in v):
        raise BadValue("is not square", allowed)
    return [[float(x) for x in r] for r in v]


def _gain(v):
    """A number >= 0 or a matrix (scalar gains multiply the identity)."""
    if _is_num(v):
        return _number(ge=0)(v)
    try:
        return _matrix(v)
    except BadValue:
        raise BadValue("is neither a number nor a matrix", "a number >= 0 or an n x n matrix") from None


def _weight(v):
    if v == "energy":   # the default, said explicitly (docs/design.md §2.5.1)
        return None
    if _is_num(v):
        return _number(gt=0)(v)
    try:
        return _matrix(v)
    except BadValue:
        raise BadValue("is neither \"energy\", a number nor a matrix",
                   "\"energy\" (the default), a number > 0 or a symmetric positive definite n x n matrix") from None


def _state(v):
    allowed = "[q, u] (1-DOF) or [[q1, .., qn], [u1, .., un]]"
    if not isinstance(v, list) or len(v) != 2:
        raise BadValue("is not a pair [q, u]", allowed)
    if all(_is_num(x) for x in v):
        out = [[float(v[0])], [float(v[1])]]
    elif all(isinstance(x, list) and x and all(_is_num(y) for y in x) for x in v):
        out = [[float(y) for y in x] for x in v]
    else:
        raise BadValue("is not a pair [q, u] of numbers or of lists of numbers", allowed)
    if len(out[0]) != len(out[1]) or not all(math.isfinite(y) for x in out for y in x):
        raise BadValue("must hold q and u of equal length, all finite", allowed)
    return out


def _plots(v):
    allowed = "a list of distinct names from " + ", ".join(f'"{p}"' for p in PLOTS)
    if not isinstance(v, list) or not all(isinstance(p, str) for p in v):
        raise BadValue("is not a list of strings", allowed)
    bad = [p for p in v if p not in PLOTS]
    if bad or len(set(v)) != len(v):
        raise BadValue(f"has unknown or repeated entries {bad or v}", allowed)
    return list(v)


def _formats(v):
    allowed = 'a list of data formats from "csv", "npz", "nc" (may be empty)'
    if not isinstance(v, list) or not all(isinstance(f, str) for f in v):
        raise BadValue("is not a list of strings", allowed)
    if any(f not in ("csv", "npz", "nc") for f in v) or len(set(v)) != len(v):
        raise BadValue("has unknown or repeated entries", allowed)
    return list(v)


def _graph(v):
    allowed = ('one of "ring", "path", "star", "all-to-all", or an N x N matrix of weights >= 0 '
               "with a zero diagonal")
    if isinstance(v, str):
        if v not in GRAPHS:
            raise BadValue("is not a known graph", allowed)
        return v
    try:
        a = _matrix(v)
    except BadValue:
        raise BadValue("is neither a graph name nor a square matrix", allowed) from None
    if len(a) < 2 or any(x < 0 for r in a for x in r) or any(a[i][i] != 0 for i in range(len(a))):
        raise BadValue("is not a weight matrix (N >= 2, weights >= 0, zero diagonal)", allowed)
    return a


def _states(v):
    allowed = "a list of N start states [q, u] (n > 1: [[q1, .., qn], [u1, .., un]])"
    if not isinstance(v, list) or len(v) < 2:
        raise BadValue("is not a list of at least 2 states", allowed)
    out = []
    for k, x in enumerate(v):
        try:
            out.append(_state(x))
        except BadValue as b:
            raise BadValue(f"has a state {k + 1} that {b.problem}", allowed) from None
    return out


def _nodes(v):
    allowed = ("a list of N tables of [system] keys that differ per node, e.g. [{}, {k = 1.05}, {m = 2.0}] "
               "(M, w, g0 and e only under the Euclidean law or none: a quotient law needs one impact map)")
    if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
        raise BadValue("is not a list of tables", allowed)
    for t in v:
        if "model" in t:
            raise BadValue("sets model per node; every node runs the scene's model", allowed)
    return [dict(t) for t in v]


def _laws(v):
    allowed = "a list with one law per edge, each one of " + ", ".join(f'"{x}"' for x in LAWS)
    if not isinstance(v, list) or not all(isinstance(x, str) and x in LAWS for x in v):
        raise BadValue("is not a list of law names", allowed)
    return list(v)


def _forcing(v):
    allowed = "a list of tables {F = [..n numbers..], Omega = <rad/s>, phi = <rad, default 0>}"
    if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
        raise BadValue("is not a list of tables", allowed)
    out = []
    for t in v:
        extra = set(t) - {"F", "Omega", "phi"}
        if extra or "F" not in t or "Omega" not in t:
            raise BadValue(f"has a term with keys {sorted(t)}", allowed)
        try:
            out.append((_vector(t["F"]), _number()(t["Omega"]), _number()(t.get("phi", 0.0))))
        except BadValue as b:
            raise BadValue(f"has a term {t} whose value {b.problem}", allowed) from None
    return out


class Key(NamedTuple):
    """One scene key: its checker, default (:data:`REQUIRED`: none), meaning and unit (SI)."""

    check: Callable
    default: Any
    doc: str
    unit: str = ""


def _key(check, default=REQUIRED, doc="", unit=""):
    return Key(check, default, doc, unit)


def model_name(v):
    allowed = "one of " + ", ".join(f'"{m}"' for m in MODELS) + ', or "path/to/model.py:name" (a user model)'
    if not isinstance(v, str):
        raise BadValue(f"is a {type(v).__name__}, not a string", allowed)
    path, sep, name = v.rpartition(":")
    if v not in MODELS and not (sep and path.endswith(".py") and name.isidentifier()):
        raise BadValue("is not allowed", allowed)
    return v


def _param_check(p: Param):
    """The scene checker of a declared parameter (docs/design.md §2.1.1): its shape and range."""
    if p.shape == ("n",):
        return _vector
    if p.shape == ("n", "n"):
        return _matrix
    if p.shape == ("terms",):
        return _forcing
    positive = p.min == POSITIVE_MIN
    return _number(gt=0 if positive else None, ge=None if positive else p.min, le=p.max)


def system_keys(model: Model) -> dict:
    """The ``[system]`` keys of a model, from its declaration: ``model`` and one key per parameter
    (checker, default, unit and meaning as declared; a vector/matrix without default: zero)."""
    keys = {"model": _key(model_name, doc="the system: a built-in model or a user model 'path/to/model.py:name'")}
    for p in model.params:
        default = REQUIRED if p.required else list(p.default) if isinstance(p.default, tuple) else p.default
        keys[p.name] = _key(_param_check(p), default, p.description, "" if p.unit == "1" else p.unit)
    return keys


#: the built-in models' [system] keys (a user model's: :func:`system_keys` of its declaration)
SYSTEM_KEYS = {name: system_keys(m) for name, m in BUILTIN_MODELS.items()}
KEYS = {
    "initial": {"x1": _key(_state, None, "start state [q, u] of system 1 (required unless a network)", "m, m/s"),
                "x2": _key(_state, None, "start state of system 2 (leave out: a single system)", "m, m/s")},
    "network": {"graph": _key(_graph, None, "the coupling graph (instead of [initial]: a network)"),
                "N": _key(_integer(2), None, "number of nodes (optional check: = len(states))"),
                "weight": _key(_number(gt=0), 1.0, "edge weight a_ij of a named graph"),
                "center": _key(_integer(1), 1, "the hub of a star (node number)"),
                "states": _key(_states, None, "one start state per node", "m, m/s"),
                "nodes": _key(_nodes, None, "[system] keys that differ per node"),
                "laws": _key(_laws, None, "one coupling law per edge, edges in the order (1,2), (1,3), .., (2,3), ..")},
    "coupling": {"law": _key(choice(*LAWS), "none", "coupling law"),
                 "Kp": _key(_gain, 0.0, "position gain (a number multiplies the identity)", "N/m"),
                 "Kd": _key(_gain, 0.0, "velocity gain", "N s/m"),
                 "Q": _key(_weight, None, "position weight of the state norm (default identity)")},
    "solver": {"scheme": _key(choice(*SCHEMES), DEFAULT_SCHEME, "time-stepping scheme (default: the core's; "
                                                                  "exact: single 1-DOF systems)"),
               "dt": _key(_number(gt=0), 1e-3, "internal step (also the FMU's internal step)", "s"),
               "theta": _key(_number(ge=0.5, le=1), 0.5, "theta of the theta scheme")},
    "run": {"t_end": _key(_number(gt=0), doc="simulated time", unit="s"),
            "mode": _key(choice(*MODES), "core", "monolithic core run, or FMUs driven by the master"),
            "H": _key(_number(gt=0), 1e-2, "communication step of the master (cosim)", "s"),
            "H_min": _key(_number(gt=0), None, "smallest retaken step with event_aware (cosim)", "s"),
            "method": _key(choice(*METHODS), "jacobi", "exchange strategy of the master (cosim)"),
            "event_aware": _key(_boolean, False, "retake a communication step that contains an impact (cosim)"),
            "hold": _key(choice(*HOLDS), "zoh", "input hold over a communication step (cosim)"),
            "exchange": _key(choice(*EXCHANGES), "explicit", "forces from the step's start, or iterated to its "
                             "end states with FMU-state rollback (cosim)"),
            "tol": _key(_number(gt=0), None, "co-simulate to this error tolerance (q's unit): H is then the first and "
                        "largest step, each step's coupling error estimated and a step over its share retaken "
                        "shorter (cosim; docs/design.md §4.4.1)"),
            "record_every": _key(_integer(1), 1, ("record every k steps of solver.dt in both modes (cosim: at the nearest whole number of "
                                                                 "run.H steps, at least one); the summary's metrics use every step")),
            "allow_unstable": _key(_boolean, False, "run even if the held coupling exchange is unstable at this step")},
    "record": {"distance": _key(_boolean, None, "compute d, branch, V and the Euclidean error (pairs and "
                                "networks: default true)"),
               "formats": _key(_formats, ["csv", "npz"], "data files to write (CLI: --format)")},
    "plot": {"plots": _key(_plots, None, "plots to draw (default: every plot that fits the runs)"),
             "compare": _key(_boolean, None, "d(t) of all variants on one plot (default: with 2 or more "
                             "variants that record d)")},
}


#: the keys only the co-simulation master reads: set where every run is in the core, they do nothing
COSIM_KEYS = ("run.H", "run.H_min", "run.method", "run.event_aware", "run.hold", "run.exchange", "run.tol")


def show_value(v) -> str:
    s = repr(v) if not isinstance(v, str) else f'"{v}"'
    return s if len(s) <= 80 else s[:77] + "..."



# ---------------------------------------------------------------- data classes
@dataclass(frozen=True)
class NetworkSpec:
    """A network scene's graph and nodes: weights ``A`` (N x N), the node systems
    (equal M, w, g0, e), their start states, the per-node parameter tables as
    written (for the FMU's start values) and the law of each edge (None: ``coupling.law``)."""

    A: np.ndarray
    graph: str
    systems: tuple
    states: tuple
    nodes: tuple
    laws: tuple | None = None

    @property
    def N(self) -> int:
        return len(self.states)




@dataclass(frozen=True)
class Variant:
    """One run of a scene: validated settings (``cfg``, dotted keys, defaults filled) and the system."""

    name: str
    description: str
    cfg: dict
    system: MechanicalSystem
    x1: tuple
    x2: tuple | None
    Kp: Any = 0.0
    Kd: Any = 0.0
    Q: np.ndarray | None = None
    network: Any = None          #: :class:`NetworkSpec` of a network scene (N systems on a graph)

    @property
    def pair(self) -> bool:
        """Two or more coupled systems (a pair or a network)."""
        return self.x2 is not None or self.network is not None

    @property
    def is_network(self) -> bool:
        return self.network is not None

    @property
    def law(self) -> str:
        return self.cfg["coupling.law"]

    @property
    def mode(self) -> str:
        return self.cfg["run.mode"]

    @property
    def has_distance(self) -> bool:
        """Whether the run computes d: recorded, or needed by the coupling law."""
        return self.pair and (self.cfg["record.distance"] or self.law == "switching")


