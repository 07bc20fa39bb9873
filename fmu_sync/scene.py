"""Scenes: what to simulate, how, and what to write out (SPEC §6).

A scene is a TOML file. Built-in scenes live in ``fmu_sync/scenes/``; any other
file can be given by path. Format (every key is checked; unknown keys, wrong
types and bad values raise :class:`SceneError` naming file, key and value)::

    description = "one line shown by `fmu-sync scenes`"

    [system]                    # the mechanical system (SPEC §1), SI units
    model = "impact-oscillator" # m q'' + c q' + k q = f0 + F cos(Omega t + phi) + tau, q >= 0
    m = 1.0                     # kg, > 0            (default 1)
    k = 1.0                     # N/m, >= 0          (default 0)
    c = 0.0                     # N s/m, >= 0        (default 0)
    f0 = 0.2                    # N                  (default 0)
    F = 0.5                     # N                  (default 0)
    Omega = 2.5                 # rad/s              (default 0)
    phi = 0.0                   # rad                (default 0)
    e = 0.9                     # restitution in [0, 1] (required)
    # or model = "mechanical-system" with
    #   M (n x n, required), K, C (n x n, default 0), f0 (n, default 0),
    #   w (n, required, nonzero), g0 (default 0), e (required),
    #   forcing = [{F = [..n..], Omega = 1.3, phi = 0.0}, ...]   (default none)

    [initial]
    x1 = [1.0, 0.0]             # [q, u]; for n > 1: [[q1, .., qn], [u1, .., un]]
    x2 = [0.2, 0.5]             # optional: without x2 the scene is a single system

    [coupling]                  # pair scenes only
    law = "switching"           # "none" | "switching" | "euclidean"   (default "none")
    Kp = 1.0                    # >= 0, number or n x n matrix         (default 0)
    Kd = 0.5                    # >= 0, number or n x n matrix         (default 0)
    Q = 1.0                     # position weight of the norm: number > 0 or SPD n x n (default identity)

    [solver]
    scheme = "midpoint"         # "midpoint" | "theta" | "exact" (exact: single 1-DOF systems)
    dt = 1e-3                   # internal step, s, > 0 (default 1e-3)
    theta = 0.5                 # in [0.5, 1], for scheme = "theta" (default 0.5)

    [run]
    t_end = 100.0               # s, > 0 (required)
    mode = "core"               # "core" (monolithic numba run) | "cosim" (FMU + master)
    H = 1e-2                    # communication step of the master, s, > 0 (cosim)
    H_min = 1e-4                # smallest retaken step with event_aware (optional)
    method = "jacobi"           # "jacobi" | "gauss-seidel" (cosim)
    event_aware = false         # cosim: retake steps that contain an impact
    record_every = 10           # keep every k-th step (core: steps dt; cosim: steps H)

    [record]
    distance = true             # compute d, branch, V, Euclidean error (pairs; default true)

    [plot]
    plots = ["positions", "distance", "lyapunov", "forces", "phase"]
    compare = true              # d(t) of all variants on one axis (default: when >= 2 variants)

    [[runs]]                    # optional variants; each one is a run of its own.
    name = "uncoupled"          # used in file names: letters, digits, - _ .
    description = "no coupling"
    coupling.law = "none"       # any key of [system] [initial] [coupling] [solver] [run] [record]

A scene without ``[[runs]]`` has one run named after the scene. Each variant is
the top-level tables with the variant's keys laid over them. ``--set`` style
overrides (``{"coupling.Kp": 2}``) replace a key everywhere, variants included.

Only what a scene names is built: a core scene never exports an FMU nor imports
fmpy/pythonfmu, a single system runs :func:`fmu_sync.core.simulate` (no master,
no distance), and the distance is computed only when recorded or needed by the
coupling law.
"""
from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .core import ImpactOscillator, MechanicalSystem, SimulationDiverged, simulate
from .fmus import contract
from .progress import scaled
from .scenes import SCENE_DIR, builtin_names

__all__ = ["SceneError", "Scene", "Variant", "RunRecord", "SceneRun", "load_scene", "list_scenes",
           "run_scene", "run_variant", "run_demo", "parse_override", "PLOTS", "DEFAULT_OUT"]

MODELS = ("impact-oscillator", "mechanical-system")
LAWS = ("none", "switching", "euclidean")
SCHEMES = ("midpoint", "theta", "exact")
MODES = ("core", "cosim")
METHODS = ("jacobi", "gauss-seidel")
PLOTS = ("positions", "distance", "lyapunov", "forces", "phase")
SINGLE_PLOTS = ("positions", "phase")
DISTANCE_PLOTS = ("distance", "lyapunov")
TABLES = ("system", "initial", "coupling", "solver", "run", "record", "plot")
VARIANT_TABLES = ("system", "initial", "coupling", "solver", "run", "record")
DEFAULT_OUT = Path("fmu-sync-out")
#: FMU model family per scene model (n = 1 / n = 2), see fmu_sync.export.export_fmu.
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


class SceneError(ValueError):
    """A scene file (or an override) is invalid; the message names file, key and value."""


# ---------------------------------------------------------------- key checkers
class _Bad(Exception):
    def __init__(self, problem: str, allowed: str):
        super().__init__(problem)
        self.problem, self.allowed = problem, allowed


_REQUIRED = object()


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
            raise _Bad(f"is a {type(v).__name__}, not a number", allowed)
        x = float(v)
        if not math.isfinite(x) or (gt is not None and not x > gt) or (ge is not None and not x >= ge) \
                or (le is not None and not x <= le):
            raise _Bad("is out of range", allowed)
        return x
    return check


def _integer(ge=1):
    allowed = f"an integer >= {ge}"

    def check(v):
        if isinstance(v, bool) or not isinstance(v, int):
            raise _Bad(f"is a {type(v).__name__}, not an integer", allowed)
        if v < ge:
            raise _Bad("is out of range", allowed)
        return v
    return check


def _boolean(v):
    if not isinstance(v, bool):
        raise _Bad(f"is a {type(v).__name__}, not a boolean", "true or false")
    return v


def _choice(*options):
    allowed = "one of " + ", ".join(f'"{o}"' for o in options)

    def check(v):
        if not isinstance(v, str):
            raise _Bad(f"is a {type(v).__name__}, not a string", allowed)
        if v not in options:
            raise _Bad("is not allowed", allowed)
        return v
    return check


def _text(v):
    if not isinstance(v, str):
        raise _Bad(f"is a {type(v).__name__}, not a string", "a string")
    return v


def _vector(v):
    allowed = "a list of finite numbers, e.g. [1.0, 0.5]"
    if not isinstance(v, list) or not v or not all(_is_num(x) and math.isfinite(x) for x in v):
        raise _Bad("is not a list of numbers", allowed)
    return [float(x) for x in v]


def _matrix(v):
    allowed = "a square matrix as a list of rows of finite numbers, e.g. [[2.0, 0.5], [0.5, 1.0]]"
    if not isinstance(v, list) or not v or not all(isinstance(r, list) for r in v):
        raise _Bad("is not a list of rows", allowed)
    if not all(_is_num(x) and math.isfinite(x) for r in v for x in r):
        raise _Bad("has entries that are not finite numbers", allowed)
    if any(len(r) != len(v) for r in v):
        raise _Bad("is not square", allowed)
    return [[float(x) for x in r] for r in v]


def _gain(v):
    """A number >= 0 or a matrix (scalar gains multiply the identity)."""
    if _is_num(v):
        return _number(ge=0)(v)
    try:
        return _matrix(v)
    except _Bad:
        raise _Bad("is neither a number nor a matrix", "a number >= 0 or an n x n matrix") from None


def _weight(v):
    if _is_num(v):
        return _number(gt=0)(v)
    try:
        return _matrix(v)
    except _Bad:
        raise _Bad("is neither a number nor a matrix",
                   "a number > 0 or a symmetric positive definite n x n matrix") from None


def _state(v):
    allowed = "[q, u] (1-DOF) or [[q1, .., qn], [u1, .., un]]"
    if not isinstance(v, list) or len(v) != 2:
        raise _Bad("is not a pair [q, u]", allowed)
    if all(_is_num(x) for x in v):
        out = [[float(v[0])], [float(v[1])]]
    elif all(isinstance(x, list) and x and all(_is_num(y) for y in x) for x in v):
        out = [[float(y) for y in x] for x in v]
    else:
        raise _Bad("is not a pair [q, u] of numbers or of lists of numbers", allowed)
    if len(out[0]) != len(out[1]) or not all(math.isfinite(y) for x in out for y in x):
        raise _Bad("must hold q and u of equal length, all finite", allowed)
    return out


def _plots(v):
    allowed = "a list of distinct names from " + ", ".join(f'"{p}"' for p in PLOTS)
    if not isinstance(v, list) or not all(isinstance(p, str) for p in v):
        raise _Bad("is not a list of strings", allowed)
    bad = [p for p in v if p not in PLOTS]
    if bad or len(set(v)) != len(v):
        raise _Bad(f"has unknown or repeated entries {bad or v}", allowed)
    return list(v)


def _forcing(v):
    allowed = "a list of tables {F = [..n numbers..], Omega = <rad/s>, phi = <rad, default 0>}"
    if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
        raise _Bad("is not a list of tables", allowed)
    out = []
    for t in v:
        extra = set(t) - {"F", "Omega", "phi"}
        if extra or "F" not in t or "Omega" not in t:
            raise _Bad(f"has a term with keys {sorted(t)}", allowed)
        try:
            out.append((_vector(t["F"]), _number()(t["Omega"]), _number()(t.get("phi", 0.0))))
        except _Bad as b:
            raise _Bad(f"has a term {t} whose value {b.problem}", allowed) from None
    return out


def _key(check, default=_REQUIRED, doc=""):
    return (check, default, doc)


_IO_KEYS = {
    "model": _key(_choice(*MODELS)),
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
    "model": _key(_choice(*MODELS)),
    "M": _key(_matrix, doc="mass matrix, SPD"),
    "K": _key(_matrix, None, "stiffness matrix"),
    "C": _key(_matrix, None, "damping matrix"),
    "f0": _key(_vector, None, "constant force"),
    "w": _key(_vector, doc="wall normal: g(q) = w.q + g0 >= 0"),
    "g0": _key(_number(), 0.0, "wall offset"),
    "e": _key(_number(ge=0, le=1), doc="restitution"),
    "forcing": _key(_forcing, [], "harmonic forces"),
}
_SYSTEM_KEYS = {"impact-oscillator": _IO_KEYS, "mechanical-system": _MS_KEYS}
_KEYS = {
    "initial": {"x1": _key(_state), "x2": _key(_state, None)},
    "coupling": {"law": _key(_choice(*LAWS), "none"), "Kp": _key(_gain, 0.0), "Kd": _key(_gain, 0.0),
                 "Q": _key(_weight, None)},
    "solver": {"scheme": _key(_choice(*SCHEMES), "midpoint"), "dt": _key(_number(gt=0), 1e-3),
               "theta": _key(_number(ge=0.5, le=1), 0.5)},
    "run": {"t_end": _key(_number(gt=0)), "mode": _key(_choice(*MODES), "core"),
            "H": _key(_number(gt=0), 1e-2), "H_min": _key(_number(gt=0), None),
            "method": _key(_choice(*METHODS), "jacobi"), "event_aware": _key(_boolean, False),
            "record_every": _key(_integer(1), 1)},
    "record": {"distance": _key(_boolean, None)},
    "plot": {"plots": _key(_plots, None), "compare": _key(_boolean, None)},
}


def _show(v) -> str:
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


@dataclass(frozen=True)
class Scene:
    name: str
    path: Path
    description: str
    variants: tuple
    plots: tuple
    compare: bool
    overrides: dict = field(default_factory=dict)

    def variant(self, name: str) -> Variant:
        for v in self.variants:
            if v.name == name:
                return v
        raise SceneError(f"{self.path.name}: no variant {name!r}; variants: "
                         + ", ".join(v.name for v in self.variants))

    def with_overrides(self, overrides: dict) -> "Scene":
        return load_scene(self.path, {**self.overrides, **overrides}, [v.name for v in self.variants])

    def select(self, names) -> "Scene":
        """The scene with only the named variants (re-validated)."""
        return load_scene(self.path, self.overrides, list(names))


@dataclass
class RunRecord:
    name: str
    variant: Variant
    result: Any                 # PairResult or SimulationResult
    metrics: dict
    files: list = field(default_factory=list)


@dataclass
class SceneRun:
    scene: Scene
    out_dir: Path
    runs: list
    files: list
    summary: Path | None = None


# ---------------------------------------------------------------- loading
def list_scenes() -> list[tuple[str, str]]:
    """``(name, one-line description)`` of every built-in scene."""
    out = []
    for name in builtin_names():
        path = SCENE_DIR / f"{name}.toml"
        try:
            with open(path, "rb") as fh:
                desc = tomllib.load(fh).get("description", "")
        except (OSError, tomllib.TOMLDecodeError) as exc:
            desc = f"(unreadable: {exc})"
        out.append((name, str(desc).strip().splitlines()[0] if desc else ""))
    return out


def _scene_path(name_or_path) -> Path:
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.parent != Path(".") or p.is_file():
        if not p.is_file():
            raise FileNotFoundError(f"scene file not found: {p}")
        return p
    builtin = SCENE_DIR / f"{name_or_path}.toml"
    if builtin.is_file():
        return builtin
    raise SceneError(f"unknown scene {str(name_or_path)!r}; built-in scenes: {', '.join(builtin_names())} "
                     "(or give the path of a .toml file)")


def parse_override(text: str) -> tuple[str, Any]:
    """``"coupling.Kp=2"`` -> ``("coupling.Kp", 2)``. Values are TOML (numbers, booleans,
    strings, arrays); a bare word that is not TOML is taken as a string (``scheme=theta``)."""
    if "=" not in text:
        raise SceneError(f"--set {text!r}: expected key=value, e.g. coupling.Kp=2")
    key, raw = (s.strip() for s in text.split("=", 1))
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value


def _flatten(data: dict, ctx: str, prefix: str = "") -> dict:
    """Tables -> dotted keys (one level; deeper structure stays a value and fails its check)."""
    flat = {}
    for k, v in data.items():
        if k in TABLES:
            if not isinstance(v, dict):
                raise SceneError(f"{ctx}: {prefix}{k} = {_show(v)}: must be a table [{k}]")
            for k2, v2 in v.items():
                flat[f"{k}.{k2}"] = v2
        else:
            flat[k] = v
    return flat


def load_scene(name_or_path, overrides: dict | None = None, variants=None) -> Scene:
    """Load and validate a scene (built-in name or path).

    ``overrides`` maps dotted keys to values (``{"coupling.Kp": 2}``); ``variants``
    (names) keeps only those variants, and only they are checked against [plot].
    """
    path = _scene_path(name_or_path)
    ctx = path.name
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{ctx}: not valid TOML: {exc}") from None
    overrides = dict(overrides or {})

    runs = data.pop("runs", None)
    base = _flatten(data, ctx)
    origin = {k: k for k in base}
    description = base.pop("description", "")
    if not isinstance(description, str):
        raise SceneError(f"{ctx}: description = {_show(description)}: is not a string; allowed: a string")
    for k in base:
        if "." not in k:
            raise SceneError(f"{ctx}: unknown key {k} = {_show(base[k])}; allowed at the top: "
                             f"description, [{'], ['.join(TABLES)}], [[runs]]")

    if runs is None:
        raw_variants = [({"name": path.stem, "description": ""}, {}, {})]
    else:
        if not isinstance(runs, list) or not runs or not all(isinstance(r, dict) for r in runs):
            raise SceneError(f"{ctx}: runs = {_show(runs)}: must be one or more [[runs]] tables")
        raw_variants = []
        for i, r in enumerate(runs):
            where = f"runs[{i + 1}]."
            r = dict(r)
            head = {"name": r.pop("name", None), "description": r.pop("description", "")}
            if not isinstance(head["name"], str) or not _NAME_RE.match(head["name"]):
                raise SceneError(f"{ctx}: {where}name = {_show(head['name'])}: missing or not a valid name; "
                                 "allowed: a string of letters, digits, '-', '_', '.' (it names output files)")
            if not isinstance(head["description"], str):
                raise SceneError(f"{ctx}: {where}description = {_show(head['description'])}: is not a string")
            flat = _flatten(r, ctx, where)
            for k, v in flat.items():
                if k.split(".")[0] not in VARIANT_TABLES:
                    raise SceneError(f"{ctx}: unknown key {where}{k} = {_show(v)}; a variant may set keys of "
                                     f"[{'], ['.join(VARIANT_TABLES)}] (plots are set for the whole scene)")
            raw_variants.append((head, flat, {k: where + k for k in flat}))
        names = [h["name"] for h, _, _ in raw_variants]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise SceneError(f"{ctx}: runs[].name = {_show(sorted(dup)[0])}: repeated; variant names must be unique")

    if variants:
        known = [h["name"] for h, _, _ in raw_variants]
        unknown = [n for n in variants if n not in known]
        if unknown:
            raise SceneError(f"{ctx}: no variant {unknown[0]!r}; variants: {', '.join(known)}")
        raw_variants = [rv for rv in raw_variants if rv[0]["name"] in variants]

    for key, value in overrides.items():
        table = key.split(".")[0]
        if key.count(".") != 1 or table not in TABLES:
            raise SceneError(f"{ctx}: --set {key} = {_show(value)}: not a key of the scene; allowed: "
                             f"dotted keys table.key with table one of {', '.join(TABLES)} (e.g. run.t_end=50)")
        base[key] = value
        origin[key] = f"--set {key}"
        for _, flat, orig in raw_variants:
            if key in flat:
                flat[key] = value
                orig[key] = f"--set {key}"

    built = []
    for head, flat, orig in raw_variants:
        merged = {**base, **flat}
        where = {**origin, **orig}
        cfg = _validate(merged, where, ctx)
        built.append(_build_variant(head["name"], head["description"], cfg, where, ctx, merged))

    plots, compare = _resolve_plots(origin, ctx, built)
    return Scene(name=path.stem, path=path, description=description, variants=tuple(built),
                 plots=tuple(plots), compare=compare, overrides=overrides)


def _validate(flat: dict, where: dict, ctx: str) -> dict:
    """Check every dotted key against the schema of its table; return them with defaults filled."""
    def fail(key, value, problem, allowed):
        raise SceneError(f"{ctx}: {where.get(key, key)} = {_show(value)}: {problem}; allowed: {allowed}")

    model = flat.get("system.model", _REQUIRED)
    if model is _REQUIRED:
        raise SceneError(f"{ctx}: system.model is missing; allowed: one of "
                         + ", ".join(f'"{m}"' for m in MODELS))
    try:
        _choice(*MODELS)(model)
    except _Bad as b:
        fail("system.model", model, b.problem, b.allowed)
    schema = {f"system.{k}": s for k, s in _SYSTEM_KEYS[model].items()}
    for table, keys in _KEYS.items():
        schema.update({f"{table}.{k}": s for k, s in keys.items()})

    cfg = {}
    for key, value in flat.items():
        if key not in schema:
            table = key.split(".")[0]
            known = [k.split(".", 1)[1] for k in schema if k.startswith(table + ".")]
            scope = f'[system] with model = "{model}"' if table == "system" else f"[{table}]"
            raise SceneError(f"{ctx}: unknown key {where.get(key, key)} = {_show(value)}; allowed keys in "
                             f"{scope}: {', '.join(known)}")
        try:
            cfg[key] = schema[key][0](value)
        except _Bad as b:
            fail(key, value, b.problem, b.allowed)
    for key, (check, default, _) in schema.items():
        if key not in cfg:
            if default is _REQUIRED:
                raise SceneError(f"{ctx}: {key} is missing (required)")
            cfg[key] = default
    return cfg


def _build_variant(name: str, description: str, cfg: dict, where: dict, ctx: str, raw: dict) -> Variant:
    def fail(key, value, problem, allowed=None):
        tail = f"; allowed: {allowed}" if allowed else ""
        value = raw.get(key, value)  # show the value as written
        raise SceneError(f"{ctx}: {where.get(key, key)} = {_show(value)}: {problem}{tail}")

    try:
        if cfg["system.model"] == "impact-oscillator":
            system = ImpactOscillator(m=cfg["system.m"], k=cfg["system.k"], c=cfg["system.c"],
                                      f0=cfg["system.f0"], F=cfg["system.F"], Omega=cfg["system.Omega"],
                                      phi=cfg["system.phi"], e=cfg["system.e"])
        else:
            M = np.array(cfg["system.M"])
            n = M.shape[0]
            zeros = np.zeros((n, n))
            system = MechanicalSystem(M=M, K=cfg["system.K"] if cfg["system.K"] is not None else zeros,
                                      C=cfg["system.C"] if cfg["system.C"] is not None else zeros,
                                      f0=cfg["system.f0"] if cfg["system.f0"] is not None else np.zeros(n),
                                      w=cfg["system.w"], g0=cfg["system.g0"], e=cfg["system.e"],
                                      forcing=tuple(cfg["system.forcing"]))
    except ValueError as exc:
        raise SceneError(f"{ctx}: [system]: {exc}") from None
    n = system.n

    def state(key):
        v = cfg[key]
        if v is None:
            return None
        if len(v[0]) != n:
            fail(key, v, f"has {len(v[0])} entries per q and u, the system has n = {n}",
                 "[q, u]" if n == 1 else f"[[{n} positions], [{n} velocities]]")
        q, u = np.array(v[0]), np.array(v[1])
        g = system.gap(q)
        if g < 0:
            fail(key, v, f"violates the wall: g(q) = {g:.6g} < 0", "states with g(q) >= 0")
        return (float(q[0]), float(u[0])) if n == 1 else (q, u)

    def square(key, v):
        a = np.array(v, dtype=float)
        if a.shape != (n, n):
            fail(key, v, f"is {a.shape[0]} x {a.shape[1]}, the system has n = {n}", f"a number or an {n} x {n} matrix")
        return a

    x1, x2 = state("initial.x1"), state("initial.x2")
    Kp, Kd, Q = cfg["coupling.Kp"], cfg["coupling.Kd"], cfg["coupling.Q"]
    if isinstance(Kp, list):
        Kp = square("coupling.Kp", Kp)
    if isinstance(Kd, list):
        Kd = square("coupling.Kd", Kd)
    if Q is not None:
        Q = Q * np.eye(n) if not isinstance(Q, list) else square("coupling.Q", Q)
        if not (np.allclose(Q, Q.T) and np.linalg.eigvalsh(Q)[0] > 0):
            fail("coupling.Q", cfg["coupling.Q"], "is not symmetric positive definite",
                 "a number > 0 or an SPD matrix")

    law, mode, scheme = cfg["coupling.law"], cfg["run.mode"], cfg["solver.scheme"]
    if x2 is None:
        if law != "none":
            fail("coupling.law", law, "a coupling needs two systems: this scene has no initial.x2",
                 '"none" for a single system, or add initial.x2')
        if mode != "core":
            fail("run.mode", mode, "a single system runs in the core (no master, no FMU)", '"core"')
        if cfg["record.distance"]:
            fail("record.distance", True, "a single system has no distance", "false (or add initial.x2)")
        cfg["record.distance"] = False
    else:
        if cfg["record.distance"] is None:
            cfg["record.distance"] = True
        if scheme == "exact":
            fail("solver.scheme", scheme, "the exact solver runs single 1-DOF systems only",
                 '"midpoint" or "theta" for pairs')
        if mode == "cosim" and contract.model_for(cfg["system.model"], n) is None:
            fail("run.mode", mode, f"there is no FMU for a {cfg['system.model']} with n = {n}",
                 '"core", or a model with an FMU: impact-oscillator, mechanical-system with n = 2')
    if scheme == "exact" and (n != 1):
        fail("solver.scheme", scheme, "the exact solver is for 1-DOF systems", '"midpoint" or "theta"')
    return Variant(name=name, description=description, cfg=cfg, system=system, x1=x1, x2=x2,
                   Kp=Kp, Kd=Kd, Q=Q)


def _resolve_plots(origin: dict, ctx: str, variants: list) -> tuple[list, bool]:
    """Scene-wide [plot] settings (already type-checked; variants cannot set them) against the variants."""
    plots, compare = variants[0].cfg["plot.plots"], variants[0].cfg["plot.compare"]
    pair = any(v.pair for v in variants)
    all_d = all(v.has_distance for v in variants)
    if plots is None:
        plots = [p for p in PLOTS if (pair or p in SINGLE_PLOTS) and (all_d or p not in DISTANCE_PLOTS)]
    for p in plots:
        for v in variants:
            if not v.pair and p not in SINGLE_PLOTS:
                raise SceneError(f"{ctx}: {origin.get('plot.plots', 'plot.plots')} = {_show(plots)}: "
                                 f'"{p}" needs two systems (variant {v.name!r} has no initial.x2); '
                                 f"allowed for a single system: {', '.join(SINGLE_PLOTS)}")
            if p in DISTANCE_PLOTS and not v.has_distance:
                raise SceneError(f"{ctx}: {origin.get('plot.plots', 'plot.plots')} = {_show(plots)}: "
                                 f'"{p}" needs the distance, but variant {v.name!r} computes none '
                                 f'(record.distance = false, coupling.law = "{v.law}"); '
                                 "set record.distance = true or drop the plot")
    if compare is None:
        compare = len(variants) > 1 and all_d
    elif compare and not all_d:
        raise SceneError(f"{ctx}: {origin.get('plot.compare', 'plot.compare')} = true: comparing d(t) needs "
                         "the distance in every variant; set record.distance = true or compare = false")
    return plots, compare


# ---------------------------------------------------------------- running
def _coupling_arg(law: str):
    return None if law == "none" else law


def fmu_start_values(fmu_path, variant: Variant) -> dict:
    """Start values for the FMU's parameters from the scene, as the FMU contract names them.

    The FMU must be the contract's model of the variant's system family
    (:func:`fmu_sync.fmus.contract.identify`); anything else raises :class:`SceneError`.
    """
    from fmpy import read_model_description  # cosim branch only

    cfg = variant.cfg
    name = Path(fmu_path).name
    try:
        md = read_model_description(str(fmu_path))
        model = contract.identify([v.name for v in md.modelVariables], md.modelName)
        want = contract.model_for(cfg["system.model"], variant.system.n)
        if model is not want:
            raise contract.ContractError(f"it is the {model.key} model, the scene needs "
                                         f"{want.key if want else 'a model the registry does not have'}")
        return {**model.values(variant.system),
                **model.solver_values(cfg["solver.dt"], cfg["solver.scheme"], cfg["solver.theta"])}
    except contract.ContractError as exc:
        raise SceneError(f"{name}: cannot take the scene's values: {exc}") from None
    except ValueError as exc:  # an unknown scheme
        raise SceneError(f"{name}: {exc}") from None


def export_for(variant: Variant, out_dir) -> Path:
    """Export the FMU of the variant's model family into ``out_dir`` (cosim only)."""
    from .export import export_fmu  # cosim branch only

    model = contract.model_for(variant.cfg["system.model"], variant.system.n).key
    return Path(export_fmu(model, Path(out_dir) / f"{model.replace('-', '_')}.fmu", None))


def run_variant(variant: Variant, fmu_path=None, progress: Callable | None = None, scene_name: str = ""):
    """Run one variant: ``simulate`` (single system), ``simulate_pair`` (core) or ``cosimulate``."""
    cfg = variant.cfg
    label = f"scene {scene_name!r}, variant {variant.name!r}" if scene_name else f"variant {variant.name!r}"
    try:
        if not variant.pair:
            result = simulate(variant.system, variant.x1, cfg["run.t_end"], cfg["solver.dt"],
                              scheme=cfg["solver.scheme"], theta=cfg["solver.theta"],
                              record_every=cfg["run.record_every"])
            if progress is not None:
                progress(1.0)
            return result
        if variant.mode == "core":
            from .core.pair import simulate_pair
            return simulate_pair(variant.system, variant.x1, variant.x2, cfg["run.t_end"], cfg["solver.dt"],
                                 coupling=_coupling_arg(variant.law), Kp=variant.Kp, Kd=variant.Kd, Q=variant.Q,
                                 scheme=cfg["solver.scheme"], theta=cfg["solver.theta"],
                                 record_every=cfg["run.record_every"],
                                 record_distance=bool(cfg["record.distance"]), progress=progress)
        from .master import cosimulate  # imports fmpy: cosim branch only
        if fmu_path is None:
            raise ValueError(f"{label}: mode = cosim needs an exported FMU (fmu_path)")
        return cosimulate(fmu_path, variant.x1, variant.x2, cfg["run.t_end"], cfg["run.H"],
                          coupling=_coupling_arg(variant.law), Kp=variant.Kp, Kd=variant.Kd, Q=variant.Q,
                          method=cfg["run.method"], record_every=cfg["run.record_every"],
                          event_aware=cfg["run.event_aware"], H_min=cfg["run.H_min"],
                          start_values=fmu_start_values(fmu_path, variant),
                          record_distance=bool(cfg["record.distance"]), progress=progress)
    except SimulationDiverged as exc:
        raise SimulationDiverged(f"{label}: {exc}") from None


def _write_run(run: RunRecord, out_dir: Path, plots, title: str) -> None:
    from . import report
    run.files += report.write_data(run.result, out_dir / run.name)
    if plots:
        from . import plots as P
        if run.name != title:
            title = f"{title}: {run.name}"
        for p in plots:
            run.files.append(P.PLOTTERS[p](run.result, out_dir / f"{run.name}-{p}.png",
                                           system=run.variant.system, title=title))


def run_scene(scene, out_dir=None, overrides: dict | None = None, progress: Callable | None = None,
              variants=None, plots: bool = True) -> SceneRun:
    """Run every (or the named) variant(s) of a scene and write data, plots and ``summary.md``.

    ``scene`` is a :class:`Scene` or a name/path for :func:`load_scene`. ``out_dir``
    defaults to ``./fmu-sync-out/<scene>``. ``progress(fraction)`` gets the overall
    fraction done. Returns a :class:`SceneRun`.
    """
    from . import report

    if not isinstance(scene, Scene):
        scene = load_scene(scene, overrides, variants)
    else:
        if overrides:
            scene = scene.with_overrides(overrides)
        if variants:
            scene = scene.select(variants)
    chosen = list(scene.variants)
    out_dir = Path(out_dir) if out_dir is not None else DEFAULT_OUT / scene.name
    out_dir.mkdir(parents=True, exist_ok=True)

    fmus = {}
    runs = []
    for i, v in enumerate(chosen):
        fmu_path = None
        if v.pair and v.mode == "cosim":
            model = (v.cfg["system.model"], v.system.n)
            if model not in fmus:
                fmus[model] = export_for(v, out_dir)
            fmu_path = fmus[model]
        result = run_variant(v, fmu_path, scaled(progress, i / len(chosen), (i + 1) / len(chosen)), scene.name)
        run = RunRecord(v.name, v, result, report.metrics(result, v.system))
        _write_run(run, out_dir, scene.plots if plots else (), scene.name)
        runs.append(run)

    files = list(fmus.values()) + [f for r in runs for f in r.files]
    if plots and scene.compare and len(runs) > 1 and all(r.variant.has_distance for r in runs):
        from . import plots as P
        files.append(P.compare_plot({r.name: r.result for r in runs}, out_dir / "compare-distance.png",
                                    title=scene.name))
    sr = SceneRun(scene, out_dir, runs, files)
    sr.summary = report.write_summary(out_dir / "summary.md", title=f"Scene `{scene.name}`",
                                      description=scene.description, rows=report.rows(runs),
                                      settings=_settings_table(scene, chosen), files=files, base=out_dir,
                                      notes=_error_notes(runs))
    return sr


_COSIM_KEYS = ("run.H", "run.H_min", "run.method", "run.event_aware")


def _relevant(key: str, variants) -> bool:
    """Settings worth listing: set (not None) and used by at least one variant."""
    for v in variants:
        if v.cfg.get(key) is None or key.startswith("plot."):
            continue
        if key.startswith("coupling.") and not v.pair:
            continue
        if key in _COSIM_KEYS and v.mode != "cosim":
            continue
        if key == "solver.theta" and v.cfg["solver.scheme"] != "theta":
            continue
        return True
    return False


def _error_notes(runs) -> list[str]:
    return [f"**{r.name} stopped early**: {r.metrics['error']}" for r in runs if r.metrics.get("error")]


def _settings_table(scene: Scene, variants) -> list[tuple[str, str]]:
    rows = [("scene file", str(scene.path))]
    if scene.overrides:
        rows.append(("overrides", ", ".join(f"{k}={v!r}" for k, v in scene.overrides.items())))
    keys = [k for k in variants[0].cfg if _relevant(k, variants)]
    for k in sorted(keys, key=lambda k: TABLES.index(k.split(".")[0])):
        values = {repr(v.cfg[k]) for v in variants}
        if len(values) == 1:
            rows.append((k, values.pop()))
        else:
            rows.append((k, "; ".join(f"{v.name}: {v.cfg[k]!r}" for v in variants)))
    return rows


# ---------------------------------------------------------------- the demo
DEMO_OUT = Path("fmu-sync-demo")
DEMO_VARIANTS = ("uncoupled", "euclidean", "switching")
#: --quick: long enough for the coupled runs to reach d < 1e-6 (about 26 s and 29 s with the defaults).
DEMO_QUICK_T_END = 40.0


def run_demo(out_dir=None, quick: bool = False, progress: Callable | None = None,
             t_end: float | None = None) -> SceneRun:
    """The README's demo: paper-example, co-simulated three ways and compared with the core.

    Exports the 1-DOF FMU into ``out_dir`` (default ``./fmu-sync-demo``), runs
    ``cosimulate`` (H = run.H) and ``simulate_pair`` (dt = solver.dt) for the
    uncoupled, Euclidean and switching variants, compares d on the common
    grid (max |d_cosim - d_core|) and writes data, plots and ``summary.md``.
    ``quick`` shortens the run to ``DEMO_QUICK_T_END`` (40 s); ``t_end`` sets it outright.
    """
    from . import plots as P
    from . import report

    out_dir = Path(out_dir) if out_dir is not None else DEMO_OUT
    out_dir.mkdir(parents=True, exist_ok=True)
    base = {"run.t_end": t_end} if t_end is not None else {"run.t_end": DEMO_QUICK_T_END} if quick else {}
    scene = load_scene("paper-example", base)
    v0 = scene.variant(DEMO_VARIANTS[0])
    H, dt = v0.cfg["run.H"], v0.cfg["solver.dt"]
    every = max(1, round(H / dt))
    cosim = load_scene("paper-example", {**base, "run.mode": "cosim", "run.record_every": 1,
                                         "record.distance": True})
    core = load_scene("paper-example", {**base, "run.mode": "core", "run.record_every": every,
                                        "record.distance": True})
    fmu_path = export_for(cosim.variant(DEMO_VARIANTS[0]), out_dir)
    files = [fmu_path]
    runs = []
    steps = 2 * len(DEMO_VARIANTS)
    k = 0
    for name in DEMO_VARIANTS:
        for tag, sc, fmu in (("cosim", cosim, fmu_path), ("core", core, None)):
            v = sc.variant(name)
            result = run_variant(v, fmu, scaled(progress, k / steps, (k + 1) / steps), scene.name)
            k += 1
            run = RunRecord(f"{name}-{tag}", v, result, report.metrics(result, v.system))
            run.metrics.update(mode=tag, variant=name)
            _write_run(run, out_dir, scene.plots if tag == "cosim" else (), "paper-example")
            runs.append(run)
        rc, rm = runs[-2], runs[-1]
        diff = report.max_abs_difference(rc.result, rm.result, "d")
        rc.metrics["d_vs_core"] = rm.metrics["d_vs_core"] = diff
    files += [f for r in runs for f in r.files]
    cos = {r.name.removesuffix("-cosim"): r.result for r in runs if r.name.endswith("-cosim")}
    files.append(P.compare_plot(cos, out_dir / "compare-distance.png",
                                title="paper-example (co-simulation): quotient distance d"))
    files.append(P.compare_plot(cos, out_dir / "compare-euclidean.png", quantity="euclidean",
                                title="paper-example (co-simulation): Euclidean error"))
    both = {f"{r.metrics['variant']} ({r.metrics['mode']})": r.result for r in runs}
    colors = {f"{r.metrics['variant']} ({r.metrics['mode']})": f"C{DEMO_VARIANTS.index(r.metrics['variant'])}"
              for r in runs}
    files.append(P.compare_plot(both, out_dir / "cosim-vs-core.png", colors=colors,
                                dashed=[k for k in both if k.endswith("(core)")],
                                title=f"co-simulation (H = {H:g} s) vs monolithic core (dt = {dt:g} s)"))
    sr = SceneRun(scene, out_dir, runs, files)
    note = (f"Co-simulation: the FMU `{fmu_path.name}`, two instances, communication step H = {H:g} s, "
            f"{v0.cfg['run.method']} exchange, coupling forces held over each H. Core: `simulate_pair` with "
            f"dt = {dt:g} s, forces held over each dt. max|d - d_core| compares the two runs' d on the "
            f"common time grid.")
    sr.summary = report.write_summary(out_dir / "summary.md", title="fmu-sync demo: paper example",
                                      description=scene.description, rows=report.rows(runs, demo=True),
                                      settings=_settings_table(scene, list(scene.variants)), files=files,
                                      base=out_dir, notes=[note] + _error_notes(runs))
    return sr
