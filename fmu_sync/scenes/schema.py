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
from typing import Any

import numpy as np

from ..core import MechanicalSystem
from ..core.coupling import LAWS as COUPLING_LAWS

__all__ = ["SceneError", "Variant", "PLOTS", "DEFAULT_OUT", "KEYS", "SYSTEM_KEYS", "BadValue", "REQUIRED",
           "MODELS", "LAWS", "SCHEMES", "MODES", "METHODS", "TABLES", "VARIANT_TABLES", "SINGLE_PLOTS",
           "DISTANCE_PLOTS", "NAME_RE", "show_value", "choice"]

MODELS = ("impact-oscillator", "mechanical-system")
#: the scenes' coupling.law values: the core's coupling laws, "none" first
LAWS = ("none",) + tuple(k for k in COUPLING_LAWS if k != "none")
SCHEMES = ("midpoint", "theta", "exact")
MODES = ("core", "cosim")
METHODS = ("jacobi", "gauss-seidel")
#: the master's input hold over a communication step (fmu_sync.master.NetworkMaster.HOLDS)
HOLDS = ("zoh", "foh")
PLOTS = ("positions", "distance", "lyapunov", "forces", "phase")
SINGLE_PLOTS = ("positions", "phase")
DISTANCE_PLOTS = ("distance", "lyapunov")
TABLES = ("system", "initial", "coupling", "solver", "run", "record", "plot")
VARIANT_TABLES = ("system", "initial", "coupling", "solver", "run", "record")
DEFAULT_OUT = Path("fmu-sync-out")
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
    if _is_num(v):
        return _number(gt=0)(v)
    try:
        return _matrix(v)
    except BadValue:
        raise BadValue("is neither a number nor a matrix",
                   "a number > 0 or a symmetric positive definite n x n matrix") from None


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


def _key(check, default=REQUIRED, doc=""):
    return (check, default, doc)


_IO_KEYS = {
    "model": _key(choice(*MODELS)),
    "m": _key(_number(gt=0), 1.0, "mass, kg"),
    "k": _key(_number(ge=0), 0.0, "stiffness, N/m"),
    "c": _key(_number(ge=0), 0.0, "damping, N s/m"),
    "f0": _key(_number(), 0.0, "constant force, N"),
    "F": _key(_number(), 0.0, "forcing amplitude, N"),
    "Omega": _key(_number(), 0.0, "forcing frequency, rad/s"),
    "phi": _key(_number(), 0.0, "forcing phase, rad"),
    "e": _key(_number(ge=0, le=1), doc="restitution"),
}
_MS_KEYS = {
    "model": _key(choice(*MODELS)),
    "M": _key(_matrix, doc="mass matrix, SPD"),
    "K": _key(_matrix, None, "stiffness matrix"),
    "C": _key(_matrix, None, "damping matrix"),
    "f0": _key(_vector, None, "constant force"),
    "w": _key(_vector, doc="wall normal: g(q) = w.q + g0 >= 0"),
    "g0": _key(_number(), 0.0, "wall offset"),
    "e": _key(_number(ge=0, le=1), doc="restitution"),
    "forcing": _key(_forcing, [], "harmonic forces"),
}
SYSTEM_KEYS = {"impact-oscillator": _IO_KEYS, "mechanical-system": _MS_KEYS}
KEYS = {
    "initial": {"x1": _key(_state), "x2": _key(_state, None)},
    "coupling": {"law": _key(choice(*LAWS), "none"), "Kp": _key(_gain, 0.0), "Kd": _key(_gain, 0.0),
                 "Q": _key(_weight, None)},
    "solver": {"scheme": _key(choice(*SCHEMES), "midpoint"), "dt": _key(_number(gt=0), 1e-3),
               "theta": _key(_number(ge=0.5, le=1), 0.5)},
    "run": {"t_end": _key(_number(gt=0)), "mode": _key(choice(*MODES), "core"),
            "H": _key(_number(gt=0), 1e-2), "H_min": _key(_number(gt=0), None),
            "method": _key(choice(*METHODS), "jacobi"), "event_aware": _key(_boolean, False),
            "hold": _key(choice(*HOLDS), "zoh"),
            "record_every": _key(_integer(1), 1)},
    "record": {"distance": _key(_boolean, None)},
    "plot": {"plots": _key(_plots, None), "compare": _key(_boolean, None)},
}


def show_value(v) -> str:
    s = repr(v) if not isinstance(v, str) else f'"{v}"'
    return s if len(s) <= 80 else s[:77] + "..."



# ---------------------------------------------------------------- data classes
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

    @property
    def pair(self) -> bool:
        return self.x2 is not None

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


