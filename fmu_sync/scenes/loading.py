"""Loading a scene (docs/design.md §4.5): a TOML file (built-in name or path) and
overrides -> a validated :class:`Scene` of :class:`~.schema.Variant` runs."""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core import InadmissibleState, ModelError, load_model
from ..core.checks import check_start
from ..core.coupling import QUOTIENT_LAW_NAMES
from ..user_export import fmu_model_of
from . import SCENE_DIR, builtin_names
from .schema import (COSIM_KEYS, DISTANCE_PLOTS, KEYS, MODELS, MOREAU_SCHEMES, NAME_RE, NETWORK_PLOTS, REQUIRED,
                     SINGLE_PLOTS, TABLES, VARIANT_TABLES, BadValue, NetworkSpec, SceneError, Variant, model_name,
                     plots_for, show_value, system_keys)

__all__ = ["Scene", "load_scene", "as_scene", "list_scenes", "parse_override", "model_of"]


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
                raise SceneError(f"{ctx}: {prefix}{k} = {show_value(v)}: must be a table [{k}]")
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
        raise SceneError(f"{ctx}: description = {show_value(description)}: is not a string; allowed: a string")
    for k in base:
        if "." not in k:
            raise SceneError(f"{ctx}: unknown key {k} = {show_value(base[k])}; allowed at the top: "
                             f"description, [{'], ['.join(TABLES)}], [[runs]]")

    if runs is None:
        raw_variants = [({"name": path.stem, "description": ""}, {}, {})]
    else:
        if not isinstance(runs, list) or not runs or not all(isinstance(r, dict) for r in runs):
            raise SceneError(f"{ctx}: runs = {show_value(runs)}: must be one or more [[runs]] tables")
        raw_variants = []
        for i, r in enumerate(runs):
            where = f"runs[{i + 1}]."
            r = dict(r)
            head = {"name": r.pop("name", None), "description": r.pop("description", "")}
            if not isinstance(head["name"], str) or not NAME_RE.match(head["name"]):
                raise SceneError(f"{ctx}: {where}name = {show_value(head['name'])}: missing or not a valid name; "
                                 "allowed: a string of letters, digits, '-', '_', '.' (it names output files)")
            if not isinstance(head["description"], str):
                raise SceneError(f"{ctx}: {where}description = {show_value(head['description'])}: is not a string")
            flat = _flatten(r, ctx, where)
            for k, v in flat.items():
                if k.split(".")[0] not in VARIANT_TABLES:
                    raise SceneError(f"{ctx}: unknown key {where}{k} = {show_value(v)}; a variant may set keys of "
                                     f"[{'], ['.join(VARIANT_TABLES)}] (plots are set for the whole scene)")
            raw_variants.append((head, flat, {k: where + k for k in flat}))
        names = [h["name"] for h, _, _ in raw_variants]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise SceneError(f"{ctx}: runs[].name = {show_value(sorted(dup)[0])}: repeated; variant names must be unique")

    if variants:
        known = [h["name"] for h, _, _ in raw_variants]
        unknown = [n for n in variants if n not in known]
        if unknown:
            raise SceneError(f"{ctx}: no variant {unknown[0]!r}; variants: {', '.join(known)}")
        raw_variants = [rv for rv in raw_variants if rv[0]["name"] in variants]

    for key, value in overrides.items():
        table = key.split(".")[0]
        if key.count(".") != 1 or table not in TABLES:
            raise SceneError(f"{ctx}: --set {key} = {show_value(value)}: not a key of the scene; allowed: "
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
        cfg = _validate(merged, where, ctx, path.parent)
        built.append(_build_variant(head["name"], head["description"], cfg, where, ctx, merged))

    _check_cosim_keys(built, raw_variants, overrides, ctx)
    plots, compare = _resolve_plots(origin, ctx, built)
    return Scene(name=path.stem, path=path, description=description, variants=tuple(built),
                 plots=tuple(plots), compare=compare, overrides=overrides)


def _check_cosim_keys(built: list, raw_variants: list, overrides: dict, ctx: str) -> None:
    """A key of the co-simulation master that would do nothing is refused, naming the key and the
    mode: given with ``--set`` when no variant run co-simulates, or in a variant's own table that
    runs in the core. (A scene file's [run] table may hold them for ``--set run.mode=cosim``.)"""
    given = [k for k in overrides if k in COSIM_KEYS]
    if given and not any(v.mode == "cosim" for v in built):
        keys = ", ".join(f"--set {k} = {show_value(overrides[k])}" for k in given)
        raise SceneError(f"{ctx}: {keys}: does nothing here: a key of the co-simulation master, and every run of "
                         f"this command runs in the core (run.mode = 'core': {', '.join(v.name for v in built)}); "
                         f"allowed: add --set run.mode=cosim, or leave it out")
    for (head, flat, orig), v in zip(raw_variants, built):
        for key in flat:
            if key in COSIM_KEYS and v.mode != "cosim" and not orig[key].startswith("--set"):
                raise SceneError(f"{ctx}: {orig[key]} = {show_value(flat[key])}: does nothing in variant "
                                 f"{head['name']!r}, which runs in the core (run.mode = 'core'): it is a key of "
                                 f"the co-simulation master; allowed: run.mode = \"cosim\" in that variant, or "
                                 f"leave it out")


def as_scene(scene, overrides: dict | None = None, variants=None) -> Scene:
    """A :class:`Scene` from a name, a path or a Scene, with ``overrides`` applied and
    only the ``variants`` named kept (the one entry of every scene-running function)."""
    if not isinstance(scene, Scene):
        return load_scene(scene, overrides, variants)
    if overrides:
        scene = scene.with_overrides(overrides)
    if variants:
        scene = scene.select(variants)
    return scene


def _validate(flat: dict, where: dict, ctx: str, base=".") -> dict:
    """Check every dotted key against the schema of its table; return them with defaults filled."""
    def fail(key, value, problem, allowed):
        raise SceneError(f"{ctx}: {where.get(key, key)} = {show_value(value)}: {problem}; allowed: {allowed}")

    model = flat.get("system.model", REQUIRED)
    if model is REQUIRED:
        raise SceneError(f"{ctx}: system.model is missing; allowed: one of "
                         + ", ".join(f'"{m}"' for m in MODELS) + ', or "path/to/model.py:name"')
    try:
        model_name(model)
        declared = load_model(model, base)
    except BadValue as b:
        fail("system.model", model, b.problem, b.allowed)
    except ModelError as exc:
        fail("system.model", model, str(exc), "a built-in model or a file declaring that Model")
    if model not in MODELS:   # a user model: its path as found (the scene may be run from elsewhere)
        flat = {**flat, "system.model": f"{Path(base, model.rpartition(':')[0]).resolve()}:{model.rpartition(':')[2]}"}
    schema = {f"system.{k}": s for k, s in system_keys(declared).items()}
    for table, keys in KEYS.items():
        schema.update({f"{table}.{k}": s for k, s in keys.items()})

    cfg = {}
    for key, value in flat.items():
        if key not in schema:
            table = key.split(".")[0]
            known = [k.split(".", 1)[1] for k in schema if k.startswith(table + ".")]
            scope = f'[system] with model = "{model}"' if table == "system" else f"[{table}]"
            raise SceneError(f"{ctx}: unknown key {where.get(key, key)} = {show_value(value)}; allowed keys in "
                             f"{scope}: {', '.join(known)}")
        try:
            cfg[key] = schema[key][0](value)
        except BadValue as b:
            fail(key, value, b.problem, b.allowed)
    for key, (check, default, *_) in schema.items():
        if key not in cfg:
            if default is REQUIRED:
                raise SceneError(f"{ctx}: {key} is missing (required)")
            cfg[key] = default
    return cfg


def model_of(cfg: dict):
    """The declaration (:class:`~fmu_sync.core.Model`) of a variant's ``system.model``."""
    return load_model(cfg["system.model"])


def _make_system(cfg: dict):
    """The MechanicalSystem of the (validated) ``system.*`` keys of ``cfg``: the model's
    declaration checks its parameters and builds the system (docs/design.md §2.1.1)."""
    model = model_of(cfg)
    return model({k: cfg[f"system.{k}"] for k in model.names})


#: what run.mode = "cosim" allows, in words (the models with an FMU)
_WITH_FMU = ('"core", or a model with an FMU: impact-oscillator, mechanical-system with n = 2, or a declaration '
             'with a force law (pendulum, duffing, a user\'s model file)')


def _check_fmu(cfg: dict, n: int, fail) -> None:
    """run.mode = "cosim" needs an FMU of the variant's model (a declaration's: made from its defaults)."""
    try:
        found = fmu_model_of(cfg["system.model"], n)
    except ValueError as exc:
        fail("run.mode", "cosim", f"the FMU of {cfg['system.model']} cannot be made: {exc}", _WITH_FMU)
    if found is None:
        fail("run.mode", "cosim", f"there is no FMU for a {cfg['system.model']} with n = {n}", _WITH_FMU)


def _build_network(cfg: dict, system, ctx: str, fail, state_of) -> NetworkSpec:
    """The [network] table of a variant -> :class:`NetworkSpec` (graph, node systems, states)."""
    from ..core import network as net   # the core's graphs (ring, path, star, all-to-all)
    states_raw = cfg["network.states"]
    if states_raw is None:
        fail("network.states", None, "a network needs one start state per node", "a list of N states [q, u]")
    N = len(states_raw)
    g = cfg["network.graph"]
    if cfg["network.N"] is not None and cfg["network.N"] != N:
        fail("network.N", cfg["network.N"], f"differs from the number of start states ({N})",
             "N = len(network.states), or leave N out")
    if isinstance(g, str):
        w = cfg["network.weight"]
        if g == "star":
            if cfg["network.center"] > N:
                fail("network.center", cfg["network.center"], f"is not a node of {N}", f"1 .. {N}")
            A = net.star(N, w, cfg["network.center"] - 1)
        else:
            A = net.graph(g, N, w)
        kind = g
    else:
        A = np.array(g, dtype=float)
        if A.shape[0] != N:
            fail("network.graph", g, f"is {A.shape[0]} x {A.shape[0]}, there are {N} start states",
                 f"an {N} x {N} weight matrix")
        kind = "matrix"
    edges = net.edges_of(A)
    if not edges:
        fail("network.graph", g, "has no edge", "a graph with at least one weight > 0")
    laws = cfg["network.laws"]
    if laws is not None and len(laws) != len(edges):
        fail("network.laws", laws, f"has {len(laws)} laws for {len(edges)} edges {edges}",
             f"{len(edges)} law names, one per edge in the order {edges}")
    nodes = cfg["network.nodes"]
    if nodes is None:
        nodes = [{}] * N
    if len(nodes) != N:
        fail("network.nodes", nodes, f"has {len(nodes)} tables for {N} nodes", f"{N} tables ({{}} for the defaults)")
    model = model_of(cfg)
    schema = system_keys(model)
    systems = []
    for i, t in enumerate(nodes):
        if not t:
            systems.append(system)
            continue
        node_cfg = dict(cfg)
        for k, v in t.items():
            per_node = [x for x in schema if x != "model"]   # the geometry too: a quotient law refuses it (plan)
            if k not in per_node:
                fail("network.nodes", nodes, f"node {i + 1} sets {k}, which is not a per-node key",
                     "keys of [system]: " + ", ".join(per_node))
            try:
                node_cfg[f"system.{k}"] = schema[k][0](v)
            except BadValue as b:
                fail("network.nodes", nodes, f"node {i + 1}: {k} = {show_value(v)} {b.problem}", b.allowed)
        try:
            systems.append(_make_system(node_cfg))
        except ValueError as exc:
            fail("network.nodes", nodes, f"node {i + 1}: {exc}")
    quotient = [x for x in (laws or [cfg["coupling.law"]]) if x in QUOTIENT_LAW_NAMES]
    if quotient:   # a quotient law needs one impact map (the run plan's rule, core/plan.py)
        from ..core.plan import check_common_geometry
        try:
            check_common_geometry(systems, [f"node {i + 1}" for i in range(N)], f"the {quotient[0]} law")
        except ValueError as exc:
            fail("network.nodes", nodes, str(exc))
    states = tuple(state_of(f"network.states[{i + 1}]", x) for i, x in enumerate(states_raw))
    return NetworkSpec(A=A, graph=kind, systems=tuple(systems), states=states, nodes=tuple(dict(t) for t in nodes),
                       laws=tuple(laws) if laws is not None else None)


def _moreau() -> str:
    """The schemes a pair, a network or an n-DOF system may run, for an error message."""
    return " or ".join(f'"{k}"' for k in MOREAU_SCHEMES)


def _build_variant(name: str, description: str, cfg: dict, where: dict, ctx: str, raw: dict) -> Variant:
    def fail(key, value, problem, allowed=None):
        tail = f"; allowed: {allowed}" if allowed else ""
        value = raw.get(key, value)  # show the value as written
        raise SceneError(f"{ctx}: {where.get(key, key)} = {show_value(value)}: {problem}{tail}")

    try:
        system = _make_system(cfg)
    except ValueError as exc:
        raise SceneError(f"{ctx}: [system]: {exc}") from None
    n = system.n

    def state(key, v=None):
        v = cfg[key] if v is None else v
        if v is None:
            return None
        if len(v[0]) != n:
            fail(key, v, f"has {len(v[0])} entries per q and u, the system has n = {n}",
                 "[q, u]" if n == 1 else f"[[{n} positions], [{n} velocities]]")
        q, u = np.array(v[0]), np.array(v[1])
        try:   # the run plan's start check (docs/design.md §5.1.1), named as a scene key
            check_start(system, q, key)
        except InadmissibleState as exc:
            fail(key, v, f"violates the wall: {exc}", "states with g(q) >= 0")
        return (float(q[0]), float(u[0])) if n == 1 else (q, u)

    def square(key, v):
        a = np.array(v, dtype=float)
        if a.shape != (n, n):
            fail(key, v, f"is {a.shape[0]} x {a.shape[1]}, the system has n = {n}", f"a number or an {n} x {n} matrix")
        return a

    spec = None
    if cfg["network.graph"] is not None:
        if cfg["initial.x1"] is not None or cfg["initial.x2"] is not None:
            fail("initial.x1" if cfg["initial.x1"] is not None else "initial.x2", None,
                 "a network scene gives its start states in network.states", "leave [initial] out")
        spec = _build_network(cfg, system, ctx, fail, state)
        x1 = x2 = None
    else:
        net_keys = [k for k in ("network.states", "network.nodes", "network.laws", "network.N")
                    if cfg[k] is not None]
        if net_keys:
            fail(net_keys[0], cfg[net_keys[0]], "needs network.graph", 'network.graph = "ring" (or another graph)')
        if cfg["initial.x1"] is None:
            raise SceneError(f"{ctx}: initial.x1 is missing (required; a network scene sets network.graph "
                             "and network.states instead)")
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
    if spec is not None:
        if cfg["record.distance"] is None:
            cfg["record.distance"] = True
        if scheme == "exact":
            fail("solver.scheme", scheme, "the exact solver runs single 1-DOF systems only",
                 f"{_moreau()} for networks")
        if mode == "cosim":
            _check_fmu(cfg, n, fail)
    elif x2 is None:
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
                 f"{_moreau()} for pairs")
        if mode == "cosim":
            _check_fmu(cfg, n, fail)
    if scheme == "exact" and (n != 1):
        fail("solver.scheme", scheme, "the exact solver is for 1-DOF systems", _moreau())
    return Variant(name=name, description=description, cfg=cfg, system=system, x1=x1, x2=x2,
                   Kp=Kp, Kd=Kd, Q=Q, network=spec)


def _resolve_plots(origin: dict, ctx: str, variants: list) -> tuple[list, bool]:
    """Scene-wide [plot] settings (already type-checked; variants cannot set them) against the variants."""
    plots, compare = variants[0].cfg["plot.plots"], variants[0].cfg["plot.compare"]
    pair = any(v.pair for v in variants)
    all_d = all(v.has_distance for v in variants)
    net = any(v.is_network for v in variants)
    if plots is None:
        plots = plots_for(pair, all_d, net)
    for p in plots:
        for v in variants:
            if v.is_network and p not in NETWORK_PLOTS:
                raise SceneError(f"{ctx}: {origin.get('plot.plots', 'plot.plots')} = {show_value(plots)}: "
                                 f'"{p}" is not drawn for a network (variant {v.name!r}); allowed for '
                                 f"networks: {', '.join(NETWORK_PLOTS)}")
            if not v.pair and p not in SINGLE_PLOTS:
                raise SceneError(f"{ctx}: {origin.get('plot.plots', 'plot.plots')} = {show_value(plots)}: "
                                 f'"{p}" needs two systems (variant {v.name!r} has no initial.x2); '
                                 f"allowed for a single system: {', '.join(SINGLE_PLOTS)}")
            if p in DISTANCE_PLOTS and not v.has_distance:
                raise SceneError(f"{ctx}: {origin.get('plot.plots', 'plot.plots')} = {show_value(plots)}: "
                                 f'"{p}" needs the distance, but variant {v.name!r} computes none '
                                 f'(record.distance = false, coupling.law = "{v.law}"); '
                                 "set record.distance = true or drop the plot")
    if compare is None:
        compare = len(variants) > 1 and all_d
    elif compare and not all_d:
        raise SceneError(f"{ctx}: {origin.get('plot.compare', 'plot.compare')} = true: comparing d(t) needs "
                         "the distance in every variant; set record.distance = true or compare = false")
    return plots, compare


