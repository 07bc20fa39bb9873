"""Where models are found (docs/design.md §2.1.1): the built-in declarations by name, and a
user's model file ``"path/to/model.py:name"``."""
from __future__ import annotations

import hashlib
import importlib.util
import sys
from pathlib import Path

from .declaration import Model, ModelError
from .examples import DUFFING, PENDULUM
from .model import IMPACT_OSCILLATOR, MECHANICAL_SYSTEM

__all__ = ["builtin_models", "load_model"]


def builtin_models() -> dict:
    """name -> :class:`Model` of the built-in models: the linear ones (core/model.py) and the
    nonlinear examples (core/examples.py)."""
    return {m.name: m for m in (IMPACT_OSCILLATOR, MECHANICAL_SYSTEM, PENDULUM, DUFFING)}


def load_model(spec, base=None) -> Model:
    """The model of ``spec``: a :class:`Model`, a built-in name (:func:`builtin_models`) or ``"path/to/model.py:name"`` (a relative path is taken from
    ``base``, e.g. the scene file's folder). The file is imported once per content (its
    module name carries the content's hash). :class:`ModelError` names what is wrong."""
    if isinstance(spec, Model):
        return spec
    BUILTIN_MODELS = builtin_models()
    if not isinstance(spec, str):
        raise ModelError(f"a model is a Model, a built-in name or 'path/to/model.py:name', got {spec!r}")
    if spec in BUILTIN_MODELS:
        return BUILTIN_MODELS[spec]
    path, sep, name = spec.rpartition(":")
    if not sep or not path.endswith(".py") or not name.isidentifier():
        raise ModelError(f"model {spec!r} is neither a built-in model ({', '.join(BUILTIN_MODELS)}) "
                         f"nor 'path/to/model.py:name'")
    file = Path(path).expanduser()
    if not file.is_absolute() and base is not None:
        file = Path(base) / file
    if not file.is_file():
        raise ModelError(f"model {spec!r}: no file {file}")
    text = file.read_bytes()
    modname = f"fmu_sync_user_model_{file.stem}_{hashlib.sha256(text).hexdigest()[:16]}"
    module = sys.modules.get(modname)
    if module is None:
        loader_spec = importlib.util.spec_from_file_location(modname, file)
        module = importlib.util.module_from_spec(loader_spec)
        sys.modules[modname] = module
        try:
            loader_spec.loader.exec_module(module)
        except Exception as exc:
            del sys.modules[modname]
            raise ModelError(f"model {spec!r}: importing {file} failed: {type(exc).__name__}: {exc}") from exc
    obj = getattr(module, name, None)
    if not isinstance(obj, Model):
        found = [k for k, v in vars(module).items() if isinstance(v, Model)]
        raise ModelError(f"model {spec!r}: {file} has no Model named {name!r}"
                         + (f" (it has {', '.join(found)})" if found else " (it declares no Model)"))
    return obj
