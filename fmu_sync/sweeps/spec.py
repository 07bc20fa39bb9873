"""What a sweep varies: parameter names, value specs, grids and samples.

A swept parameter is any scene key (``coupling.Kp``, ``system.e``,
``solver.dt``, ``run.H``, ``coupling.law`` ...), ``variant`` (the scene's
``[[runs]]`` names) or a component of a 1-DOF start state:
``initial.q1``, ``initial.u1``, ``initial.q2``, ``initial.u2``.

Value specs (strings, as on the command line, or Python values):

* grids: ``linspace(a, b, n)``, ``logspace(a, b, n)`` (decades, as numpy),
  ``[v1, v2, ...]`` (TOML list, may hold strings), a single value, or any
  sequence / numpy array;
* samples (``method="random"`` or ``"lhs"``): ``uniform(a, b)``,
  ``loguniform(a, b)`` or a list to draw from.
"""
from __future__ import annotations

import itertools
import math
import re
import tomllib

import numpy as np

__all__ = ["SweepSpecError", "parse_values", "parse_distribution", "grid_runs", "sample_runs",
           "STATE_ALIASES", "canonical"]


class SweepSpecError(ValueError):
    """A sweep parameter or value spec is invalid (the message names it and what is allowed)."""


#: 1-DOF start-state components: alias -> (scene key, index in [q, u]).
STATE_ALIASES = {"initial.q1": ("initial.x1", 0), "initial.u1": ("initial.x1", 1),
                 "initial.q2": ("initial.x2", 0), "initial.u2": ("initial.x2", 1)}

_CALL = re.compile(r"^\s*([a-z]+)\s*\((.*)\)\s*$")
_GRID_HELP = "linspace(a, b, n), logspace(a, b, n), a list [v1, v2, ...] or a single value"
_SAMPLE_HELP = "uniform(a, b), loguniform(a, b) (0 < a < b) or a list [v1, v2, ...] to draw from"


def canonical(key: str) -> str:
    """Check the form of a parameter name (the scene checks the key itself)."""
    if not isinstance(key, str) or not key:
        raise SweepSpecError(f"sweep parameter {key!r}: expected a scene key such as coupling.Kp")
    if key == "variant" or key in STATE_ALIASES:
        return key
    if key.count(".") != 1:
        raise SweepSpecError(f"sweep parameter {key!r}: not a scene key; allowed: table.key (e.g. "
                             f"coupling.Kp, system.e, solver.dt, run.H), variant, or one of "
                             f"{', '.join(STATE_ALIASES)}")
    return key


def _numbers(args: str, count: int, what: str, key: str):
    try:
        vals = tomllib.loads(f"v = [{args}]")["v"]
    except tomllib.TOMLDecodeError:
        vals = None
    if vals is None or len(vals) != count or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                     for v in vals):
        raise SweepSpecError(f"{key}={what}({args}): expected {count} numbers")
    return vals


def parse_values(key: str, spec) -> list:
    """The grid values of one parameter (a list of Python scalars or strings)."""
    if isinstance(spec, str):
        m = _CALL.match(spec)
        if m and m.group(1) in ("linspace", "logspace"):
            a, b, n = _numbers(m.group(2), 3, m.group(1), key)
            if int(n) != n or n < 1:
                raise SweepSpecError(f"{key}={spec}: n = {n} must be an integer >= 1")
            f = np.linspace if m.group(1) == "linspace" else np.logspace
            return [float(x) for x in f(float(a), float(b), int(n))]
        if m:
            raise SweepSpecError(f"{key}={spec}: unknown function {m.group(1)!r}; allowed: {_GRID_HELP}")
        try:
            v = tomllib.loads(f"v = {spec}")["v"]
        except tomllib.TOMLDecodeError:
            v = spec  # a bare word: a string value (e.g. switching)
        spec = v
    if isinstance(spec, np.ndarray):
        spec = spec.tolist()
    if isinstance(spec, (list, tuple)):
        if not spec:
            raise SweepSpecError(f"{key}: empty list of values; allowed: {_GRID_HELP}")
        return [v.item() if isinstance(v, np.generic) else v for v in spec]
    if isinstance(spec, np.generic):
        spec = spec.item()
    return [spec]


def parse_distribution(key: str, spec):
    """``("uniform", a, b)``, ``("loguniform", a, b)`` or ``("choice", [values])``."""
    if isinstance(spec, tuple) and len(spec) == 3 and spec[0] in ("uniform", "loguniform"):
        kind, a, b = spec
    elif isinstance(spec, str) and _CALL.match(spec):
        m = _CALL.match(spec)
        kind = m.group(1)
        if kind not in ("uniform", "loguniform"):
            raise SweepSpecError(f"{key}={spec}: unknown distribution {kind!r}; allowed: {_SAMPLE_HELP}")
        a, b = _numbers(m.group(2), 2, kind, key)
    else:
        values = parse_values(key, spec)
        return ("choice", values)
    a, b = float(a), float(b)
    if not (math.isfinite(a) and math.isfinite(b) and a < b) or (kind == "loguniform" and a <= 0):
        raise SweepSpecError(f"{key}={kind}({a:g}, {b:g}): need finite a < b"
                             + (" and a > 0" if kind == "loguniform" else ""))
    return (kind, a, b)


def grid_runs(grid: dict) -> tuple[list[str], list[list], list[dict]]:
    """Full grid: ``(keys, axis values, runs)``; runs in C order (last key fastest)."""
    keys = [canonical(k) for k in grid]
    axes = [parse_values(k, grid[k]) for k in keys]
    runs = [dict(zip(keys, combo)) for combo in itertools.product(*axes)]
    return keys, axes, runs


def sample_runs(sample: dict, n: int, method: str, seed: int) -> tuple[list[str], list[dict]]:
    """``n`` random (``method="random"``) or Latin-hypercube (``"lhs"``) draws, seeded."""
    if method not in ("random", "lhs"):
        raise SweepSpecError(f"method = {method!r}; allowed: grid, random, lhs")
    n = int(n)
    if n < 1:
        raise SweepSpecError(f"a {method} sample needs n >= 1 runs, got {n}")
    keys = [canonical(k) for k in sample]
    rng = np.random.default_rng(seed)
    cols = {}
    for k in keys:
        dist = parse_distribution(k, sample[k])
        if method == "lhs":
            u = (rng.permutation(n) + rng.random(n)) / n   # one draw in each of n strata
        else:
            u = rng.random(n)
        if dist[0] == "uniform":
            cols[k] = (dist[1] + (dist[2] - dist[1]) * u).tolist()
        elif dist[0] == "loguniform":
            la, lb = math.log(dist[1]), math.log(dist[2])
            cols[k] = np.exp(la + (lb - la) * u).tolist()
        else:
            vals = dist[1]
            cols[k] = [vals[min(int(x * len(vals)), len(vals) - 1)] for x in u]
    runs = [{k: cols[k][i] for k in keys} for i in range(n)]
    return keys, runs
