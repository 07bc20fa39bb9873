"""Scenes as text, generated from the schema (:mod:`.schema`): the scene-key reference
(``docs/scene-keys.md``: every key with its type, default, allowed values and unit) and a
scene printed as TOML with every key (``fmu-sync scenes --show NAME``), which loads back to
the same scene."""
from __future__ import annotations

import json
import math

from .loading import Scene, as_scene, model_of
from .schema import KEYS, MODELS, REQUIRED, SYSTEM_KEYS, TABLES, BadValue

__all__ = ["key_rows", "keys_markdown", "scene_toml", "toml_value"]

_TYPES = {"_number": "number", "_integer": "integer", "_boolean": "boolean", "choice": "string", "_text": "string", "model_name": "string",
          "_vector": "array of numbers", "_matrix": "matrix (array of rows)", "_gain": "number or matrix",
          "_weight": "number or matrix", "_state": "[q, u]", "_plots": "array of strings",
          "_formats": "array of strings", "_graph": "string or matrix", "_states": "array of [q, u]",
          "_nodes": "array of tables", "_laws": "array of strings", "_forcing": "array of tables"}


def _type(check) -> str:
    name = check.__qualname__.split(".")[0]
    return _TYPES.get(name, name.lstrip("_"))


def _allowed(check) -> str:
    """The checker's own statement of what it allows (the text of its error messages)."""
    try:
        check(object())
    except BadValue as b:
        return b.allowed
    return "any value"   # pragma: no cover - every checker refuses an arbitrary object


def _default(key) -> str:
    if key.default is REQUIRED:
        return "required"
    if key.default is None:
        return "—"
    return f"`{toml_value(key.default)}`"


def key_rows():
    """``(table, key, type, default, allowed, unit, meaning)`` of every scene key."""
    rows = []
    for model, keys in SYSTEM_KEYS.items():
        for k, key in keys.items():
            if k == "model" and model != "impact-oscillator":
                continue
            table = "system" if k == "model" else f"system ({model})"
            rows.append((table, k, _type(key.check), _default(key), _allowed(key.check), key.unit, key.doc))
    for table, keys in KEYS.items():
        for k, key in keys.items():
            rows.append((table, k, _type(key.check), _default(key), _allowed(key.check), key.unit, key.doc))
    return rows


def keys_markdown() -> str:
    """``docs/scene-keys.md``: the reference of every scene key, generated from the schema."""
    cell = lambda s: str(s).replace("|", "\\|")  # noqa: E731
    lines = ["# Scene keys", "",
             "<!-- generated from fmu_sync/scenes/schema.py by fmu_sync.scenes.reference.keys_markdown(); "
             "tests/test_results.py checks that this page is up to date -->", "",
             "Every key a scene file may set (docs/design.md §4.5), SI units throughout. A scene is a TOML file: "
             "the tables below, an optional `description` and optional `[[runs]]` variants (each with a `name`, "
             "a `description` and keys of the tables other than `[plot]`, written `table.key = value`). "
             "`fmu-sync scenes --show NAME` prints a built-in scene with every key; `--set table.key=value` "
             "overrides a key from the command line. The `[system]` keys are the declared parameters of the "
             "model (docs/design.md §2.1.1): the built-in models' below; a user model, "
             "`model = \"path/to/model.py:name\"` (a path relative to the scene file), takes the parameters "
             "its `Model` declares, with their defaults, units and ranges (`fmu-sync scenes --show` prints them, "
             "and the units of q, u and tau the model declares: `Model(q_unit=..., u_unit=..., tau_unit=...)`, "
             "default m, m/s, N; the pendulum's q is in rad). Such a scene runs in both modes: `run.mode = "
             "\"core\"` (the default) or `\"cosim\"` (`--set run.mode=cosim`: the model's FMU is exported "
             "once for the scene run, into the output folder, and two instances or a network of them are "
             "co-simulated by the master; docs/user-model.md).",
             ""]
    current = None
    for table, k, typ, default, allowed, unit, doc in key_rows():
        if table != current:
            current = table
            lines += ["", f"## [{table}]", "", "| key | type | default | allowed | unit | meaning |",
                      "|---|---|---|---|---|---|"]
        lines.append(f"| `{k}` | {cell(typ)} | {cell(default)} | {cell(allowed)} | {cell(unit) or '—'} | "
                     f"{cell(doc)} |")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- a scene as TOML
def toml_value(v) -> str:
    """A TOML value (inline): numbers in their shortest repr, strings quoted, arrays, inline tables."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if hasattr(v, "tolist"):
        return toml_value(v.tolist())
    raise TypeError(f"no TOML form for {type(v).__name__} {v!r}")


def _written(key: str, v):
    """A validated value in the form a scene file writes it."""
    if key == "system.forcing":
        return [{"F": list(F), "Omega": Om, "phi": ph} for F, Om, ph in v]
    if key in ("initial.x1", "initial.x2"):
        return _state(v)
    if key == "network.states":
        return [_state(x) for x in v]
    return v


def _state(v):
    q, u = v
    return [q[0], u[0]] if len(q) == 1 else [list(q), list(u)]


def scene_toml(scene) -> str:
    """The scene (a :class:`Scene`, built-in name or path) as TOML with every key set (defaults
    filled): keys equal in all variants in the tables, the others in each ``[[runs]]``."""
    sc: Scene = as_scene(scene)
    variants = sc.variants
    keys = [k for k in variants[0].cfg if not k.startswith("plot.")]
    common = [k for k in keys if all(v.cfg[k] == variants[0].cfg[k] for v in variants)]
    lines = [f"# scene {sc.name!r} ({sc.path}) with every key, defaults filled (fmu-sync scenes --show)"]
    if sc.overrides:
        lines.append("# overrides: " + ", ".join(f"{k}={x!r}" for k, x in sc.overrides.items()))
    lines.append(f"description = {toml_value(sc.description)}")
    for table in TABLES:
        if table == "network" and variants[0].cfg["network.graph"] is None:
            continue
        body = [f"{k.split('.', 1)[1]} = {toml_value(_written(k, variants[0].cfg[k]))}"
                for k in common if k.split(".")[0] == table and variants[0].cfg[k] is not None]
        if table == "plot":
            body = [f"plots = {toml_value(list(sc.plots))}", f"compare = {toml_value(bool(sc.compare))}"]
        decl = model_of(variants[0].cfg) if table == "system" else None
        if decl is not None and (variants[0].cfg["system.model"] not in MODELS or decl.force is not None):
            # a user model or a force law's declaration: its parameters and units
            body = [f"# {decl.name}: {decl.description}",
                    "# units: " + ", ".join(f"{k} [{u}]" for k, u in decl.units.items())] + [
                f"#   {p.name} [{p.unit}]: {p.description} ({p.allowed()})" for p in decl.params] + body
        if body:
            lines += ["", f"[{table}]"] + body
    if len(variants) > 1 or variants[0].name != sc.path.stem:
        for v in variants:
            lines += ["", "[[runs]]", f"name = {toml_value(v.name)}", f"description = {toml_value(v.description)}"]
            lines += [f"{k} = {toml_value(_written(k, v.cfg[k]))}" for k in keys
                      if k not in common and v.cfg[k] is not None]
    return "\n".join(lines) + "\n"
