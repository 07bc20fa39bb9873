"""The FMU of a model declaration with a force law (docs/user-model.md "Export").

    fmu-sync export path/to/my_pendulum.py:pendulum -o pendulum.fmu
    fmu-sync export pendulum -o pendulum.fmu            # the built-in examples (core/examples.py)

:func:`resolve` turns the model into what :func:`fmu_sync.export.export_fmu` carries:

* the declaration registered in the FMU contract (:func:`fmu_sync.fmus.contract.declared`):
  its declared parameters are the FMU's parameters, with their units and ranges;
* the generated package ``user/`` of the carried code: ``user/model.py``, the user's file with
  its ``from fmu_sync.core[...] import ...`` lines turned into relative imports of the carried
  core (one line for one line: a traceback's line numbers stay the file's), and
  ``user/runtime.py``, the FMU's runtime module (the build record's ``runtime``), which registers
  the declaration and is the mechanical runtime otherwise. The carried code is the import
  closure of these, so the FMU's GUID follows the user's code;
* the build record's ``declaration``: ``{"builtin": name}`` or ``{"file", "name", "sha256",
  "source"}`` (the user's file as written: a master reading the FMU in another process loads
  the declaration from it, :func:`declaration_of`).

The user's law is compiled into the FMU binary's native stepper at export
(:mod:`fmu_sync.fmus.law_stepper`); on the target the carried code runs as plain Python (the
configuration and checks evaluate h with numpy alone).
"""
from __future__ import annotations

import ast
import functools
import hashlib
import importlib
from pathlib import Path

from .core.declaration import Model, ModelError
from .core.registry import builtin_models, load_model
from .fmus import contract
from .fmus.slave import unit_exponents

__all__ = ["resolve", "rewrite_imports", "declaration_of", "register_from", "fmu_model_of"]
#: where the built-in declarations live (module of the package, relative to the carried core)
_BUILTIN_MODULES = ("fmu_sync.core.examples", "fmu_sync.core.model")


def _relative(module: str, spec: str) -> str:
    """``..core.<name>`` of a core module ``fmu_sync.core.<name>`` (ModelError otherwise)."""
    parts = module.split(".")
    if len(parts) != 3 or parts[:2] != ["fmu_sync", "core"]:
        raise ModelError(f"model {spec!r}: an FMU carries the core only: the model file imports {module!r}; "
                         f"import from fmu_sync.core (from fmu_sync.core import Model, Param, ForceLaw, ...)")
    return f"..core.{parts[2]}"


def _home(obj, name: str, package: str, spec: str) -> str:
    """The core module defining ``obj``, imported as ``name`` from the package ``package``."""
    defined = isinstance(obj, type) or hasattr(obj, "__code__")     # a class or a function: its own module
    mod = getattr(obj, "__module__", None) if defined else None
    if mod and mod.startswith("fmu_sync.core.") and getattr(importlib.import_module(mod), name, None) is obj:
        return mod
    if mod and mod.startswith("fmu_sync") and not mod.startswith("fmu_sync.core"):
        _relative(mod, spec)       # outside the core: refused, naming it
    core = importlib.import_module("fmu_sync.core")
    for sub in sorted(vars(core)):
        m = getattr(core, sub)
        if getattr(m, "__name__", "").startswith("fmu_sync.core.") and getattr(m, name, None) is obj:
            return m.__name__
    raise ModelError(f"model {spec!r}: cannot tell which core module defines {name!r} of {package}; import it "
                     f"from its module (from fmu_sync.core.<module> import {name})")


def rewrite_imports(source: bytes, spec: str) -> bytes:
    """The user's file with its ``from fmu_sync...`` imports made relative imports of the carried
    core, line for line; ModelError for ``import fmu_sync`` or an import outside the core."""
    tree = ast.parse(source, spec)
    lines = source.decode("utf-8").splitlines(keepends=True)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "fmu_sync" for a in node.names):
            raise ModelError(f"model {spec!r} line {node.lineno}: write 'from fmu_sync.core import ...' (an FMU "
                             f"carries the core under another package name; 'import fmu_sync' cannot travel)")
        if not (isinstance(node, ast.ImportFrom) and node.level == 0 and node.module
                and node.module.split(".")[0] == "fmu_sync"):
            continue
        mod = importlib.import_module(node.module)
        stmts = []
        for a in node.names:
            if a.name == "*":
                raise ModelError(f"model {spec!r} line {node.lineno}: 'from {node.module} import *' cannot "
                                 f"travel in an FMU: name what you import")
            if hasattr(mod, "__path__"):          # a package: each name from the module defining it
                obj = getattr(mod, a.name, None)
                if obj is None:
                    raise ModelError(f"model {spec!r} line {node.lineno}: {node.module} has no {a.name!r}")
                target = _relative(_home(obj, a.name, node.module, spec), spec)
            else:
                target = _relative(node.module, spec)
            stmts.append(f"from {target} import {a.name}" + (f" as {a.asname}" if a.asname else ""))
        first, last = node.lineno - 1, node.end_lineno - 1
        indent = lines[first][:node.col_offset]
        if indent.strip():
            raise ModelError(f"model {spec!r} line {node.lineno}: put the import of {node.module} on its own line")
        tail = lines[last][node.end_col_offset:]
        lines[first] = indent + "; ".join(stmts) + tail
        for i in range(first + 1, last + 1):
            lines[i] = "\n"
    return "".join(lines).encode("utf-8")


def _runtime(key: str, source: str, attr: str) -> bytes:
    return (f'"""The runtime of this FMU (generated by fmu-sync export): the mechanical runtime, with the\n'
            f'model declaration it was exported from registered in the FMU contract."""\n'
            f"from ..fmus.contract import declared\n"
            f"from ..fmus.runtime import create\n"
            f"from {source} import {attr} as DECLARATION\n\n"
            f'__all__ = ["create", "DECLARATION", "KEY"]\n\n'
            f"KEY = {key!r}\n"
            f"declared(DECLARATION, KEY)\n").encode()


def _builtin_home(decl: Model) -> tuple[str, str] | None:
    for mod in _BUILTIN_MODULES:
        for attr, obj in vars(importlib.import_module(mod)).items():
            if obj is decl:
                return mod, attr
    return None


def _user_home(decl: Model) -> tuple[Path, str] | None:
    """(file, attribute) of a declaration defined in a user's model file loaded by load_model."""
    import sys
    for name, mod in list(sys.modules.items()):
        if name.startswith("fmu_sync_user_model_") and getattr(mod, "__file__", None):
            for attr, obj in vars(mod).items():
                if obj is decl:
                    return Path(mod.__file__), attr
    return None


def _key(decl: Model) -> str | None:
    """The export key of a declaration: a built-in's name, ``"file.py:name"`` of a user's file
    (None: neither, e.g. a Model made in a session)."""
    if _builtin_home(decl) is not None:
        return decl.name
    found = _user_home(decl)
    return None if found is None else f"{found[0].name}:{found[1]}"


def fmu_model_of(family: str, n: int):
    """The FMU contract's model of a scene's ``system.model`` with n degrees of freedom: a
    registered model, or the FMU of a declaration with a force law (a built-in one or a user's
    file, registered under the key :func:`resolve` exports it by); None if it has no FMU."""
    found = contract.model_for(family, n)
    if found is not None:
        return found
    try:
        decl = load_model(family)
    except ModelError:
        return None
    key = _key(decl)
    if decl.force is None or decl.n != n or key is None or key in contract.MODELS:
        return None
    have = contract.DECLARED.get(key)
    return have if have is not None and have.declaration is decl else contract.declared(decl, key)


def resolve(model) -> tuple[str, dict, dict]:
    """(export key, generated files of the carried package, the build record's ``declaration``)
    of ``model``: a built-in declaration's name ("pendulum", "duffing"), ``"path/to/model.py:name"``
    or a :class:`Model` (a built-in one, or one loaded from a user's file). ModelError (a
    ValueError) names what is wrong: no such file, no such name, no force law, a law numba
    cannot compile."""
    decl = load_model(model)
    home = _builtin_home(decl)
    if home is not None:
        mod, attr = home
        if decl.name not in builtin_models():
            raise ModelError(f"model {decl.name!r} is not a built-in declaration")
        key, files = decl.name, {}
        runtime = _runtime(key, _relative(mod, decl.name), attr)
        record = {"builtin": decl.name}
    else:
        found = _user_home(decl)
        if found is None:
            raise ModelError(f"model {decl.name!r}: export a user's model by its file, 'path/to/model.py:name' "
                             f"(the FMU carries the file)")
        path, attr = found
        text = path.read_bytes()
        spec = f"{path.name}:{attr}"
        key = spec
        files = {"user/model.py": rewrite_imports(text, spec)}
        runtime = _runtime(key, ".model", attr)
        record = {"file": path.name, "name": attr, "sha256": hashlib.sha256(text).hexdigest(),
                  "source": text.decode("utf-8")}
    files["user/runtime.py"] = runtime
    units = [(f"parameter {p.name}", p.unit) for p in decl.params] + [(f"{k}_unit", u) for k, u in decl.units.items()]
    for what, unit in units:   # each unit readable for <UnitDefinitions> before anything is compiled
        try:
            unit_exponents(unit)
        except ValueError as exc:
            raise ModelError(f"model {decl.name!r}, {what}: {exc}") from None
    fm = contract.declared(decl, key)
    fm.declaration.force.compile()      # LawRefused (a ValueError) names the law numba cannot compile
    return key, files, record


def declaration_of(build: dict) -> Model:
    """The declaration an FMU's build record names (``declaration``), loaded in this process:
    a built-in by name, a user's file from the source the record carries (ModelError if none)."""
    rec = build.get("declaration")
    if not isinstance(rec, dict):
        raise ModelError("the FMU's build record names no model declaration")
    if "builtin" in rec:
        return load_model(rec["builtin"])
    import os
    import tempfile
    # kept (numba's cache of the law reads its file): one folder per content, under the temp folder
    folder = Path(tempfile.gettempdir()) / f"fmu-sync-models-{os.getuid()}" / rec["sha256"][:32]
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / Path(rec["file"]).name
    if not path.is_file() or path.read_text(encoding="utf-8") != rec["source"]:
        path.write_text(rec["source"], encoding="utf-8")
    return load_model(f"{path}:{rec['name']}")


#: the build record inside an fmu-sync FMU
BUILD_RECORD = "resources/fmu_sync_build.json"


def build_record(fmu) -> dict | None:
    """The build record an fmu-sync FMU (an .fmu or its folder) carries (:data:`BUILD_RECORD`: its
    model's export key ``model`` and, for a declaration, the ``declaration`` it was exported from);
    None if it carries none (not such an FMU). Read once per process for a file that has not changed
    (a master reads it for each run, many runs of one FMU in a sweep worker)."""
    f = Path(fmu) / BUILD_RECORD if Path(fmu).is_dir() else Path(fmu)
    try:
        st = f.stat()
    except OSError:
        return None
    return _read_build(str(fmu), (st.st_mtime_ns, st.st_size))


@functools.lru_cache(maxsize=64)
def _read_build(fmu: str, stamp: tuple) -> dict | None:
    import json
    import zipfile
    try:
        if Path(fmu).is_dir():
            build = json.loads((Path(fmu) / BUILD_RECORD).read_text(encoding="utf-8"))
        else:
            with zipfile.ZipFile(fmu) as zf:
                build = json.loads(zf.read(BUILD_RECORD))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None
    return build if isinstance(build, dict) else None


def built_key(fmu) -> str | None:
    """The export key of the model an fmu-sync FMU was exported from (its build record), else None:
    what tells two registered declarations of one interface apart (:func:`.fmus.contract.identify`)."""
    key = (build_record(fmu) or {}).get("model")
    return key if isinstance(key, str) else None


def register_from(fmu) -> bool:
    """Register in the FMU contract the declaration an fmu-sync FMU (an .fmu or its folder) was
    exported from, if its build record names one; False if it names none (not such an FMU)."""
    build = build_record(fmu)
    if build is None or not isinstance(build.get("declaration"), dict):
        return False
    contract.declared(declaration_of(build), build.get("model"))
    return True
