# long module: one export pipeline (spec, C binary, carried code, model description, archive) read top to bottom
"""Export the fmu-sync slaves as FMI 2.0 (default) or FMI 3.0 co-simulation FMUs (SPEC §7).

    export_fmu("impact-oscillator", "io.fmu", {"e": 0.8, "solver.scheme": "theta"})
    fmu-sync export impact-oscillator -o io.fmu --set e=0.8 --set solver.scheme=theta
    fmu-sync export impact-oscillator -o io3.fmu --fmi-version 3

An FMI 3.0 FMU (``fmus/c/fmu_sync_fmi3.c`` over the same runtime, slave, contract
and stepper; docs/fmi3.md) declares event mode, early return at impacts, variable
communication steps and FMU states; q, u, tau (and other whole indexed families)
are FMI 3.0 arrays.

The FMU holds:

* ``binaries/linux64/<ModelIdentifier>.so`` — our FMI 2.0 binary: the FMI glue
  (``fmus/c/fmu_sync_fmi2.c``), the instance runtime that embeds Python
  (``fmus/c/fmu_sync_runtime.c``) and the stepper as native code: the numba cfunc
  compiled here to baseline x86-64 object code (:mod:`fmu_sync.native`) and linked
  with its support (``fmus/c/fmu_sync_native.c``), all by gcc (GUID and boot module
  compiled in). It loads libpython itself, so any C host can load the FMU;
* ``binaries/linux64/fmu_sync_process.so.1`` — the one record per process that every
  fmu-sync binary a host loads shares, so that one of them starts the interpreter
  (``fmus/c/fmu_sync_process.h``);
* ``resources/fmu_sync_code/`` — the Python code it runs (configuration, checks, state):
  only the modules its slave and stepper import (:func:`carried_modules`, the import
  closure with deferred imports), none importing ``fmu_sync``, run as plain Python
  (the carried package sets ``PLAIN_PYTHON``, ``core/jit.py``); so the importing machine
  needs Python with numpy only (no numba, nothing compiled there), and an edit of a core
  module the FMU does not run (``core/batch.py``) leaves its GUID unchanged;
  ``resources/fmu_sync_boot_<hash>.py`` sets it up;
* ``resources/fmu_sync_python.txt`` — the interpreter (``program``) and its
  libpython recorded at export (``FMU_SYNC_PYTHON`` overrides them at run time);
* ``resources/fmu_sync_build.json`` — model, content hash, the Python / numpy
  versions of the build and the numba / llvmlite versions and CPU of its native
  stepper; ``resources/fmu_sync_start.json`` — start values (the same as the
  ``start`` attributes of modelDescription.xml).

The archive is written directly, byte-for-byte reproducible (no timestamps,
deterministic GUID). When the stepper cannot be made native code (numba or llvmlite
outside the tested versions, a feature the binary cannot provide, no binutils), the
export fails (:class:`fmu_sync.native.NativeCodeError`), never the FMU on its target.
"""
from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from .fmus import contract
from . import __version__, native, package_files
from .fmu_docs import documentation_files
from .fmus.slave import model_guid

__all__ = ["MODELS", "export_fmu", "export_coupling", "main_export", "model_slave", "carried_files",
           "carried_modules", "bytecode", "build_binary", "stepper_cfunc", "constants_header", "fmu_guid",
           "write_archive", "MAX_SUBSTEPS", "COUPLING", "FMI_VERSIONS", "TARGET_REQUIRES", "target_requires"]

#: The export keys: the FMU contract's model registry.
MODELS = contract.MODELS
#: the range of each third-party package an FMU's carried code may import (pyproject.toml's
#: dependencies say the same, tests/test_fmu_travel.py checks it). The target needs those its
#: carried code imports (:func:`target_requires`), checked at instantiation (fmus/boot.py); the
#: export refuses a numpy outside it. numba and llvmlite are the export's alone, pinned to their
#: tested versions (fmu_sync.native.TESTED; numba 0.57.1 hung for 15 min in its inline pass).
TARGET_REQUIRES = {"numpy": ">=1.24"}
#: most internal steps one fmi2DoStep may take (larger steps are refused with fmi2Error)
MAX_SUBSTEPS = 10_000_000

_ZIP_DATE = (2020, 1, 1, 0, 0, 0)
#: the FMI versions an FMU can be exported for and their glue; every binary also compiles
#: the instance runtime (the Python embedding)
FMI_VERSIONS = (2, 3)
_C_GLUE = {2: "fmus/c/fmu_sync_fmi2.c", 3: "fmus/c/fmu_sync_fmi3.c"}
_C_RUNTIME = ("fmus/c/fmu_sync_runtime.c", "fmus/c/fmu_sync_python.c", "fmus/c/fmu_sync_native.c",
              "fmus/c/fmu_sync_verify.c")
#: the library beside the FMU's binary that holds the one record per process every fmu-sync binary shares
#: (fmus/c/fmu_sync_process.h: who starts the interpreter); a versioned shared-object name
PROCESS_LIB = "fmu_sync_process.so.1"
_C_PROCESS = "fmus/c/fmu_sync_process.c"
#: the resources that decide the FMU's behaviour, whose SHA-256 the binary checks at every instantiation
#: (fmus/c/fmu_sync_verify.c); the build record holds the carried code's hash, checked by the boot script
#: before it imports that code. The boot script (``fmu_sync_boot_<hash>.py``) is added per export.
VERIFIED = ("fmu_sync_build.json", "fmu_sync_start.json")
#: the binary's libraries. libdl.so.2 stays a dependency (gcc links --as-needed, and -ldl is an empty
#: archive since glibc 2.34): on glibc < 2.34 the old dlopen bound by fmu_sync_runtime.c lives there
#: (the glibc floor, docs/fmu.md "The binary")
_LIBS = ("-Wl,--no-as-needed", "-l:libdl.so.2", "-Wl,--as-needed", "-lpthread", "-lm")
#: the carried package's __init__ files: the real core/__init__.py imports every run API of the core
_CARRIED_INITS = {
    "__init__.py": b'"""fmu-sync model code carried by an FMU (the modules its slave and stepper import)."""\n'
                   b"#: run as plain Python (core/jit.py): the stepper is the binary's native code\n"
                   b"PLAIN_PYTHON = True\n",
    "core/__init__.py": b'"""The core modules an fmu-sync FMU runs (the import closure of its slave and stepper)."""\n',
}
#: the generated files of each declared model exported in this process: export key ->
#: {path in the carried package: content} (fmu_sync.user_export.resolve)
_GENERATED: dict[str, dict[str, bytes]] = {}
_USER_INIT = b'"""The model declaration this FMU was exported from (generated by fmu-sync export)."""\n'
#: the coupling FMU's export key (fmu_sync.fmus.coupling; not a mechanical model of the registry)
COUPLING = "coupling"
#: the modules of each kind of FMU: the C-facing instance (the build record's ``runtime``, which
#: makes the slave), the hot path (``stepper``) and the slave; a mechanical model of the registry
#: or the coupling. The carried code is the import closure of these (:func:`carried_modules`).
_KINDS = {
    "mechanical": {"runtime": "fmus.runtime", "stepper": "fmus.stepper", "slave": "fmus.slave"},
    COUPLING: {"runtime": "fmus.coupling_runtime", "stepper": "fmus.coupling_stepper", "slave": "fmus.coupling"},
}


def resolve(model) -> tuple[str, dict]:
    """(export key, extra start-file entries) of ``model``: a registered key, or a model
    declaration with a force law (:func:`fmu_sync.user_export.resolve`)."""
    if isinstance(model, str) and (model in MODELS or model == COUPLING):
        return model, {}
    from .user_export import resolve as resolve_declared
    key, files, record = resolve_declared(model)
    _GENERATED[key] = files
    return key, {"declaration": record}


def model_slave(model: str):
    """The slave of an export key ("impact-oscillator", "mechanical-system-2"): the one
    :class:`~fmu_sync.fmus.slave.MechanicalSlave` on the model's contract entry."""
    from .fmus.slave import slave
    return slave(model)


def _kind(model: str) -> dict:
    if model in _GENERATED:   # a declared model: its generated runtime registers its declaration
        return {**_KINDS["mechanical"], "runtime": "user.runtime"}
    return _KINDS[COUPLING if model == COUPLING else "mechanical"]


def _source(rel: str, model: str | None = None) -> bytes:
    """A package file ("core/exact.py", :func:`fmu_sync.package_files.read`), or a file generated for
    the declared ``model`` ("user/runtime.py", "user/model.py")."""
    if rel in _GENERATED.get(model, {}):
        return _GENERATED[model][rel]
    return package_files.read(rel)


def _nodes(tree):
    """Every node of ``tree`` but the bodies of ``if NUMBA:`` (core/jit.py): imports of the compiled
    mode only, which the carried code (plain Python) never runs."""
    import ast
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "NUMBA":
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))


#: (rel, sha256 of its source) -> its import statements (:func:`_imports`): parsed once per process
_IMPORTS: dict = {}


def _imports(rel: str, source: bytes) -> tuple[list, list]:
    """(the import statements of ``source`` that :func:`_nodes` walks, those of its top level and its
    classes' bodies); memoised on the source's content (an export parses ~40 files twice)."""
    import ast
    key = (rel, hashlib.sha256(source).digest())
    if key not in _IMPORTS:
        tree = ast.parse(source, rel)
        walked = [n for n in _nodes(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]
        top, todo = [], list(tree.body)
        while todo:
            node = todo.pop(0)
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                top.append(node)
            elif isinstance(node, ast.ClassDef):
                todo[:0] = node.body
        _IMPORTS[key] = (walked, top)
    return _IMPORTS[key]


def _imported_modules(rel: str, model: str | None = None) -> list[str]:
    """The core/fmus modules that module ``rel`` imports, deferred imports included
    (ValueError for an import of the host package ``fmu_sync`` or of a package)."""
    import ast
    out = []
    pkg = rel.split("/")[0]
    for node in _imports(rel, _source(rel, model))[0]:
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "fmu_sync" for a in node.names):
            raise ValueError(f"{rel} imports the host package fmu_sync: an FMU's code imports its own modules "
                             f"relatively")
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level == 0:
            if (node.module or "").split(".")[0] == "fmu_sync":
                raise ValueError(f"{rel} imports the host package ({node.module}): an FMU's code imports its "
                                 f"own modules relatively")
            continue
        base = [pkg] if node.level == 1 else []
        target = base + (node.module.split(".") if node.module else [])
        if len(target) == 2 and target[0] in ("core", "fmus", "user"):
            out.append(f"{target[0]}/{target[1]}.py")
        elif len(target) == 1 and target[0] in ("core", "fmus"):    # from . import stepper
            for a in node.names:
                sub = f"{target[0]}/{a.name}.py"
                try:
                    _source(sub, model)
                except OSError:
                    raise ValueError(f"{rel} imports {a.name} from the package {target[0]}: import it from "
                                     f"its module (the FMU carries only the modules it imports)") from None
                out.append(sub)
        else:
            raise ValueError(f"{rel}: import {'.' * node.level}{node.module or ''} is outside core/ and fmus/")
    return out


def carried_modules(model: str = "impact-oscillator") -> list[str]:
    """Paths ("core/exact.py", "fmus/slave.py") of the modules the FMU of ``model`` carries:
    the import closure, deferred imports included, of its kind's runtime, stepper and slave
    modules (a mechanical model does not carry the coupling's, nor the coupling the
    mechanical slave)."""
    roots = ["fmus/__init__.py"] + [m.replace(".", "/") + ".py" for m in _kind(model).values()]
    seen, todo = set(), roots
    while todo:
        rel = todo.pop()
        if rel not in seen and rel not in _CARRIED_INITS:
            seen.add(rel)
            todo.extend(_imported_modules(rel, model))
    return sorted(seen)


def carried_files(model: str = "impact-oscillator") -> list[tuple[str, bytes]]:
    """(path relative to the carried package, content) of the code the FMU of ``model`` runs
    (a declared model's: its generated ``user/`` package too, :mod:`fmu_sync.user_export`)."""
    inits = dict(_CARRIED_INITS)
    if model in _GENERATED:
        inits["user/__init__.py"] = _USER_INIT
    return sorted(inits.items()) + [(rel, _source(rel, model)) for rel in carried_modules(model)]


def bytecode(files: list[tuple[str, bytes]]) -> list[tuple[str, bytes]]:
    """The carried modules compiled for this Python (``<dir>/__pycache__/<name>.<tag>.pyc``), so
    that a target running the same Python version imports them without compiling (the
    cold start, docs/fmu.md); checked-hash pycs (PEP 552): valid whatever the files' dates after
    unzipping, ignored for a source they do not match, ignored by other Python versions
    (which compile the sources)."""
    import py_compile
    tag = sys.implementation.cache_tag
    if tag is None:      # pragma: no cover (an implementation without bytecode caching)
        return []
    out = []
    with tempfile.TemporaryDirectory(prefix="fmu-sync-pyc-") as tmp:
        for rel, data in files:
            src = Path(tmp, "src.py")
            src.write_bytes(data)
            folder, name = os.path.split(rel)
            pyc = Path(tmp, "out.pyc")
            py_compile.compile(str(src), cfile=str(pyc), dfile=rel, doraise=True,
                               invalidation_mode=py_compile.PycInvalidationMode.CHECKED_HASH)
            out.append((f"{folder + '/' if folder else ''}__pycache__/{name[:-3]}.{tag}.pyc", pyc.read_bytes()))
    return out


def _code_hash(files: list[tuple[str, bytes]]) -> str:
    # the same walk as fmus/boot.py:code_hash over the unpacked tree
    from fmu_sync.fmus.boot import code_hash
    with tempfile.TemporaryDirectory(prefix="fmu-sync-hash-") as tmp:
        for rel, data in files:
            p = Path(tmp, rel)
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
        return code_hash(tmp)


#: the work-array header slots the binary reads (fmus/stepper.py)
_C_SLOTS = ("H_LEN", "H_VERSION", "H_TIME", "H_PHASE", "H_DT", "H_CONFIGURED", "H_M", "H_SCHEME", "H_ITAU",
            "H_ITAUDOT", "H_FEEDTHROUGH", "H_MAXEV", "H_BOUND", "H_MODE", "H_REACHED", "H_PEND_U", "H_PEND_P",
            "H_ICOUNT")
_C_CODES = ("R_OK", "R_ROLLED_BACK", "R_EXACT_TAUDOT", "R_EXACT_EVENTS", "R_EXACT_STALL", "R_INADMISSIBLE",
            "MODE_FULL", "MODE_EARLY", "MODE_EARLY_EVENT", "MODE_APPLY_EVENT")
_CONSTANTS_H = "fmu_sync_constants.h"


def constants_header(guid: str = "", boot_module: str = "", max_substeps: int = MAX_SUBSTEPS) -> bytes:
    """``fmu_sync_constants.h``: every number the binary shares with the Python side, written
    from the Python definitions (stepper slots and return codes, phases, table codes, layout,
    scheme codes, limits; one version, ``stepper.WORK_VERSION``) and this export's GUID and
    boot module. The C sources include it; nothing of it is written by hand."""
    from .fmus import runtime as R
    from .fmus import slave, stepper as S
    lines = ["/* Generated by fmu_sync.export.constants_header from the Python definitions: do not edit. */",
             "#ifndef FMU_SYNC_CONSTANTS_H", "#define FMU_SYNC_CONSTANTS_H"]

    def define(name, value):
        lines.append(f"#define {name} {value}")
    define("FSR_VERSION", int(S.WORK_VERSION))
    for name in _C_SLOTS:
        define(f"FSR_{name}", getattr(S, name))
    for name in _C_CODES:
        define(f"FSR_{name}", getattr(S, name))
    for name, code in slave.PHASES.items():
        define(f"FSR_{name.upper()}", code)
    for name, code in R.TYPES.items():
        define(f"FSR_T_{name.upper()}", code)
    for name, code in R.CAUSALITIES.items():
        define(f"FSR_C_{name.upper()}", code)
    for i, name in enumerate(R.LAYOUT):
        define(f"FSR_L_{name.upper()}", i)
    define("FSR_L_N", len(R.LAYOUT))
    for name, value, _ in contract.SCHEME_ITEMS:
        define(f"FSR_SCHEME_{name.upper()}", value)
    define("FSR_MAX_SUBSTEPS", f"{float(max_substeps)!r}")
    # the GUID: a string constant of its own translation unit in the binary (build_binary), so that
    # the glue's text, hence its cached object (fmu_sync.native.c_objects), does not change with it
    lines += ["#ifdef FMU_SYNC_GUID", "extern const char FMU_SYNC_GUID[];", "#else"]
    define("FMU_SYNC_GUID", json.dumps(guid))
    lines.append("#endif")
    define("FMU_SYNC_BOOT", json.dumps(boot_module))
    define("FSR_PROCESS_LIB", json.dumps(PROCESS_LIB))
    # {name, sha256, ..., NULL} of the files the binary checks (VERIFIED), beside the GUID (build_binary)
    lines.append("extern const char *const fsr_files[];")
    return ("\n".join(lines + ["#endif", ""])).encode()


def stepper_cfunc(model: str = "impact-oscillator"):
    """The numba cfunc that is the stepper of ``model``'s FMU (its kind's stepper module's ``step``;
    a declared model's: the stepper with its force law compiled in, :mod:`fmu_sync.fmus.law_stepper`)."""
    import importlib
    if model in _GENERATED:
        from .fmus.law_stepper import law_stepper
        return law_stepper(contract.model(model).declaration.force, _compiling)
    return importlib.import_module(f"fmu_sync.{_kind(model)['stepper']}").step


def _compiling(law: str) -> None:
    """The progress line of a user force law's stepper compiling (a first export of its file)."""
    from .progress import note
    note(f"fmu-sync export: compiling the FMU stepper of force law {law!r} with numba (the first export "
         f"of this model file only; it can take a minute or more; later exports load it from the cache)")


def build_binary(out: Path, guid: str, boot_module: str, max_substeps: int = MAX_SUBSTEPS,
                 glue: str | None = None, fmi_version: int = 2, model: str = "impact-oscillator",
                 files: dict[str, bytes] | None = None) -> Path:
    """Compile the FMI binary (``glue``, a package path, :mod:`fmu_sync.package_files`, by default the
    FMI version's, the runtime with the
    generated constants header, :func:`fmu_sync.native.c_objects`, and ``model``'s stepper as
    native object code, :func:`fmu_sync.native.stepper_object`) with gcc (``$CC`` overrides) into ``out``;
    every symbol resolved at link time (libc, libm, libdl, libpthread; Python is looked up at run time).
    ``files``: {name in resources/: content} the binary accepts only unchanged (their SHA-256 compiled
    in beside the GUID, checked at every instantiation, fmus/c/fmu_sync_verify.c)."""
    srcs = [str(package_files.path(c)) for c in (glue or _C_GLUE[fmi_version], *_C_RUNTIME)]
    cc = os.environ.get("CC", "gcc")
    if shutil.which(cc) is None:
        raise RuntimeError(f"cannot build the FMU binary: C compiler {cc!r} not found (install gcc or set CC)")
    with tempfile.TemporaryDirectory(prefix="fmu-sync-h-") as inc:
        Path(inc, _CONSTANTS_H).write_bytes(constants_header(guid, boot_module, max_substeps))
        table = "".join(f"{json.dumps(name)}, \"{hashlib.sha256(data).hexdigest()}\", "
                        for name, data in sorted((files or {}).items()))
        Path(inc, "fmu_sync_guid.c").write_text(f"const char fsr_guid[] = {json.dumps(guid)};\n"
                                                f"const char *const fsr_files[] = {{{table}0}};\n")
        objs = native.c_objects(cc, ["-std=gnu11", "-O2", "-fPIC", "-fvisibility=hidden", "-DFMU_SYNC_GUID=fsr_guid"],
                                srcs + [str(Path(inc, "fmu_sync_guid.c"))], Path(inc))
        objs += native.stepper_objects(stepper_cfunc(model), Path(inc))
        cmd = [cc, "-std=gnu11", "-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-s",
               "-Wl,--no-undefined", "-o", str(out), *map(str, objs), *_LIBS]
        p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"cannot build the FMU binary ({' '.join(cmd)}):\n{p.stderr[-3000:]}")
    return out


def build_process_lib(out: Path) -> Path:
    """Compile :data:`PROCESS_LIB` (``fmus/c/fmu_sync_process.c``: it exports one symbol, the record
    every fmu-sync binary of a process shares) into ``out``."""
    cc = os.environ.get("CC", "gcc")
    with tempfile.TemporaryDirectory(prefix="fmu-sync-p-") as inc:
        objs = native.c_objects(cc, ["-std=gnu11", "-O2", "-fPIC", "-fvisibility=hidden"],
                                [str(package_files.path(_C_PROCESS))], Path(inc))
        cmd = [cc, "-shared", "-fPIC", "-s", f"-Wl,-soname,{PROCESS_LIB}", "-Wl,--no-undefined", "-o", str(out),
               *map(str, objs)]
        p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"cannot build the FMU binary ({' '.join(cmd)}):\n{p.stderr[-3000:]}")
    return out


def python_record() -> str:
    """resources/fmu_sync_python.txt: how the binary finds this interpreter from a plain C host."""
    libdir = sysconfig.get_config_var("LIBDIR") or ""
    soname = sysconfig.get_config_var("INSTSONAME") or sysconfig.get_config_var("LDLIBRARY") or ""
    lib = os.path.join(libdir, soname) if soname.endswith((".so", ".so.1.0")) or ".so." in soname else ""
    return (f"program={sys.executable}\nlibpython={lib}\n"
            f"version={'.'.join(map(str, sys.version_info[:3]))}\nprefix={sys.prefix}\n")


def _runtime_versions() -> dict:
    """What the target's Python is compared with (boot.check_runtime): Python and numpy;
    RuntimeError if numpy is outside TARGET_REQUIRES (numba and llvmlite, which the export
    alone needs, are checked against their tested versions by :func:`fmu_sync.native.check_versions`)."""
    import numpy
    from .fmus.boot import satisfies
    versions = {"python": ".".join(map(str, sys.version_info[:3])), "numpy": numpy.__version__}
    for dist, spec in TARGET_REQUIRES.items():
        if not satisfies(versions[dist], spec):
            raise RuntimeError(f"cannot export with {dist} {versions[dist]}: fmu-sync is tested with "
                               f"{dist}{spec} (pyproject.toml); install it: {sys.executable} -m pip install "
                               f"'{dist}{spec}'")
    return versions


def target_requires(model: str = "impact-oscillator") -> dict[str, str]:
    """{distribution: specifier} the target's Python needs for the FMU of ``model``: the
    third-party packages its carried code imports unconditionally when imported (an import
    inside a function, such as core/views.py's xarray, or under ``if``/``try``, such as
    core/jit.py's numba, is not needed), with their TARGET_REQUIRES range."""
    import ast
    names, where = set(), {}
    standard = set(sys.stdlib_module_names) | {"__future__"}
    for rel in carried_modules(model):
        for node in _imports(rel, _source(rel, model))[1]:
            if isinstance(node, ast.Import):
                found = {a.name.split(".")[0] for a in node.names}
            elif node.level == 0 and node.module:
                found = {node.module.split(".")[0]}
            else:
                continue
            names |= found
            for name in found - standard - set(TARGET_REQUIRES):
                where.setdefault(name, (rel, node.lineno))
    if where:
        allowed = ", ".join(f"{d}{spec}" for d, spec in TARGET_REQUIRES.items())
        said = []
        for name, (rel, line) in sorted(where.items()):
            file = (f"the model file {model.split(':')[0]}" if rel == "user/model.py" and ":" in model
                    else f"{rel} of the carried code")
            said.append(f"{file} imports {name} (line {line})")
        raise ValueError(f"cannot export the FMU of {model!r}: {'; '.join(said)}. An FMU's code runs on the "
                         f"target's Python, which is asked for these packages only: {allowed} (besides the "
                         f"standard library and the fmu_sync core the FMU carries). Remove that import from the "
                         f"top of the file: write the law with math and numpy, or import the package inside a "
                         f"function the FMU does not call")
    return {d: TARGET_REQUIRES[d] for d in TARGET_REQUIRES if d in names}


def _native_record() -> dict:
    """How the native stepper was made (informative: the target needs none of it)."""
    return {**native.check_versions(), "cpu": [cpu for cpu, _ in native.VARIANTS], "triple": native.TRIPLE}


def _model_description_xml(cls, starts: dict, guid: str, fmi_version: int = 2) -> bytes:
    root = cls.description(starts, guid, __version__, fmi_version)
    ET.indent(root, space="  ")
    buf = io.BytesIO()
    ET.ElementTree(root).write(buf, encoding="UTF-8", xml_declaration=True)
    return buf.getvalue() + b"\n"


def _identity(model: str, starts: dict, fmi_version: int = 2) -> tuple[list[tuple[str, bytes]], str, str]:
    """(carried files, their hash, GUID): the GUID changes with the model, the start
    values, the package version, the carried code, the C source and the FMI version, and nothing else."""
    code = carried_files(model)
    c_source = b"".join(map(package_files.read, package_files.listing("fmus/c", "*.[ch]"))) + constants_header()
    digest = _code_hash(code)
    return code, digest, model_guid(model, starts, digest + hashlib.sha256(c_source).hexdigest()
                                    + ("" if fmi_version == 2 else f"/fmi{fmi_version}"), __version__)


def fmu_guid(model: str = "impact-oscillator", start_values: dict | None = None, fmi_version: int = 2) -> str:
    """The GUID :func:`export_fmu` gives ``model`` with ``start_values``."""
    model, extra = resolve(model)
    starts = model_slave(model).normalize_start_values(dict(start_values or {}))
    return _identity(model, {**starts, **extra}, fmi_version)[2]


def export_fmu(model: str = "impact-oscillator", path=None, start_values: dict | None = None,
               fmi_version: int = 2) -> Path:
    """Build the FMU of ``model`` at ``path`` (default ``<ModelIdentifier>.fmu``) and return its path.

    ``start_values`` maps variable names (``"e"``, ``"solver.dt"``, ``"M[1,2]"``,
    ``"solver.scheme": "theta"`` ...) to start values of parameters or inputs; they
    are checked like the slave checks them at run time (bounds, a valid
    ``MechanicalSystem``, g(q_start) >= 0) and a ValueError names what is wrong.
    ``model = "coupling"`` is the coupling FMU of a pair (:func:`export_coupling`, FMI 2.0).
    ``fmi_version``: 2 (FMI 2.0) or 3 (FMI 3.0 with early return and event mode, docs/fmi3.md).
    """
    if fmi_version not in FMI_VERSIONS or isinstance(fmi_version, bool):
        raise ValueError(f"fmi_version must be one of {', '.join(map(str, FMI_VERSIONS))}, got {fmi_version!r}")
    native.require_export_versions()   # before any work: the numba the export is tested with
    if model == COUPLING:
        if fmi_version != 2:
            raise ValueError(f"the coupling FMU is exported for FMI 2.0 only, got fmi_version={fmi_version!r}")
        return export_coupling(path, start_values=start_values)
    model, extra = resolve(model)
    return _export(model_slave(model), model, path, start_values, extra, fmi_version)


def export_coupling(path=None, A=None, n: int = 1, start_values: dict | None = None, K=1.0,
                    units: dict | None = None) -> Path:
    """Build the coupling FMU (:mod:`fmu_sync.fmus.coupling`) of the graph ``A``
    (N x N weights; default the pair ``[[0, 1], [1, 0]]``) for systems with ``n``
    degrees of freedom. The weights of ``A`` are the start values of ``a[i,j]``;
    ``start_values`` sets any parameter (``"law[1]": "euclidean"``, ``"Kp": 2`` ...).
    Without a start value for Q, Q is the law's own metric
    :func:`fmu_sync.core.coupling.energy_metric` of the systems' stiffness ``K``
    (default 1.0, the impact-oscillator FMU's k), Kp and the graph. ``units``: the systems' units of
    q, u, tau (a model declaration's ``units``; default m, m/s, N), which its variables take."""
    native.require_export_versions()
    from .core.coupling import energy_metric
    from .core.network import weights
    from .fmus.contract import matrix
    from .fmus.coupling import CouplingSlave, CouplingSpec
    A = weights([[0.0, 1.0], [1.0, 0.0]] if A is None else A)
    spec = CouplingSpec.from_weights(A, n, units)
    cls = CouplingSlave(spec)
    starts = {f"a[{a + 1},{b + 1}]": float(A[a, b]) for i, j in spec.edges for a, b in ((i, j), (j, i))}
    starts.update(cls.normalize_start_values(dict(start_values or {})))
    q_names, kp_names = (["Q"], ["Kp"]) if n == 1 else (matrix("Q", n), matrix("Kp", n))
    if not any(k in starts for k in q_names):
        p = cls.start_parameters(starts)
        Kp = np.array([p[k] for k in kp_names]).reshape(n, n)
        starts.update(zip(q_names, (float(x) for x in energy_metric(K, Kp, A).reshape(-1))))
    return _export(cls, COUPLING, path, starts, {"structure": spec.as_dict()})


def _export(cls, model: str, path, start_values, start_extra: dict, fmi_version: int = 2) -> Path:
    starts = cls.normalize_start_values(dict(start_values or {}))
    all_starts = cls.start_parameters(starts)
    try:
        cls.configure(all_starts)
    except ValueError as exc:
        raise ValueError(f"{model}: {exc}") from None

    path = Path(path) if path is not None else Path(f"{cls.MODEL_IDENTIFIER}.fmu")
    if path.suffix != ".fmu":
        raise ValueError(f"the FMU file name must end in .fmu, got {str(path)!r}")
    _check_target(path)

    code, digest, guid = _identity(model, {**starts, **start_extra}, fmi_version)
    package = f"fmu_sync_m{digest[:16]}"
    boot_module = f"fmu_sync_boot_{digest[:16]}"
    declaration = start_extra.pop("declaration", None)
    build = {"model": model, "model_identifier": cls.MODEL_IDENTIFIER, "package": package, "code_hash": digest,
             "fmu_sync_version": __version__, "guid": guid,
             "built_with": _runtime_versions(), "requires": target_requires(model),
             "native_stepper": _native_record(),
             "max_substeps": MAX_SUBSTEPS, "fmi_version": fmi_version,
             "runtime": _kind(model)["runtime"], "stepper": _kind(model)["stepper"],
             **({"declaration": declaration} if declaration else {})}
    from fmu_sync.fmus.slave import START_FILE
    resources = {f"fmu_sync_code/{rel}": data for rel, data in code}
    resources.update({f"fmu_sync_code/{rel}": data for rel, data in bytecode(code)})
    resources.update({
        f"{boot_module}.py": package_files.read("fmus/boot.py"),
        "fmu_sync_build.json": (json.dumps(build, indent=2, sort_keys=True) + "\n").encode(),
        "fmu_sync_python.txt": python_record().encode(),
        START_FILE: (json.dumps({"model": model, "fmu_sync_version": __version__, "start": all_starts,
                                 **start_extra}, indent=2, sort_keys=True) + "\n").encode(),
    })
    with tempfile.TemporaryDirectory(prefix="fmu-sync-build-") as tmp:
        binary = build_binary(Path(tmp) / f"{cls.MODEL_IDENTIFIER}.so", guid, boot_module,
                              fmi_version=fmi_version, model=model,
                              files={n: resources[n] for n in (*VERIFIED, f"{boot_module}.py")}).read_bytes()
        process_lib = build_process_lib(Path(tmp) / PROCESS_LIB).read_bytes()
    platform = "linux64" if fmi_version == 2 else "x86_64-linux"
    description = _model_description_xml(cls, starts, guid, fmi_version)
    root = ET.fromstring(description)
    files: list[tuple[str, bytes]] = [
        ("modelDescription.xml", description),
        (f"binaries/{platform}/{cls.MODEL_IDENTIFIER}.so", binary),
        (f"binaries/{platform}/{PROCESS_LIB}", process_lib),
    ] + documentation_files(build, root.get("modelName"), root.get("description") or "", platform) + [
        (f"resources/{name}", data) for name, data in sorted(resources.items())]
    write_archive(path, files)
    return path


def _check_target(path: Path) -> None:
    """Refuse (:class:`~fmu_sync.output.OutputPathError`, naming ``path``) an FMU path that cannot be
    written: a folder, inside a file, in a folder that cannot be created or written (before anything
    is built); the folder is created."""
    from .output import OutputPathError, check_out_dir, make_out_dir, plain_os_error
    if path.is_dir():
        raise OutputPathError(f"cannot write the FMU {path}: it is a folder; give a file name ending in .fmu")
    try:
        make_out_dir(check_out_dir(path.parent))
        fd, probe = tempfile.mkstemp(prefix=".export-", suffix=".probe", dir=path.parent)
    except OutputPathError as exc:
        raise OutputPathError(f"cannot write the FMU {path}: {exc}") from None
    except OSError as exc:   # even root cannot create files in /sys or /proc
        raise OutputPathError(f"cannot write the FMU {path}: its folder {path.parent} does not take new files "
                              f"({plain_os_error(exc).split(' (')[0]}); choose another -o") from None
    os.close(fd)
    os.unlink(probe)


def write_archive(path: Path, files) -> None:
    """Write (name, bytes) pairs as a reproducible zip archive (fixed dates), atomically."""
    fd, tmp = tempfile.mkstemp(prefix=".export-", suffix=path.suffix, dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh, zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED) as zf:
            for name, data in files:
                info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = (0o755 if name.endswith(".so") else 0o644) << 16
                zf.writestr(info, data)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)      # as any other output file (mkstemp made it 0600)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _parse_set(items: list[str]) -> dict:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--set expects name=value, got {item!r}")
        out[name.strip()] = value.strip()
    return out


def main_export(argv=None) -> int:
    """``fmu-sync export MODEL -o PATH.fmu [--set name=value ...]``; returns the exit code."""
    parser = argparse.ArgumentParser(
        prog="fmu-sync export",
        description="Export an FMI 2.0 (or FMI 3.0: --fmi-version 3) co-simulation FMU of an fmu-sync model, "
                    "or the coupling FMU of a pair or network (the importing machine needs Python with numpy; "
                    "the stepper is compiled here into the FMU's binary; see docs/fmu.md).")
    parser.add_argument("model", help=f"model to export: {', '.join(sorted([*MODELS, COUPLING]))}, a built-in "
                                      f"declaration (pendulum, duffing) or a user's model file "
                                      f"path/to/model.py:name (docs/user-model.md)")
    parser.add_argument("-o", "--output", default=None,
                        help="FMU file to write (default: <ModelIdentifier>.fmu in the current folder)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="NAME=VALUE",
                        help="start value of a parameter or input, e.g. --set e=0.8 "
                             "--set solver.scheme=theta --set 'M[1,2]=0.3' (repeatable)")
    parser.add_argument("--fmi-version", type=int, choices=FMI_VERSIONS, default=2,
                        help="FMI version of the FMU: 2 (default) or 3 (FMI 3.0: event mode, early return "
                             "at impacts, arrays; see docs/fmi3.md; not for the coupling FMU)")
    parser.add_argument("--nodes", type=int, default=None,
                        help="coupling only: number of coupled systems N (default 2, the pair)")
    parser.add_argument("--graph", default="ring",
                        help="coupling only, with --nodes: ring, path, star or all-to-all (default ring)")
    parser.add_argument("--dof", type=int, default=1,
                        help="coupling only: degrees of freedom n of each system (default 1)")
    parser.add_argument("--list", action="store_true", help="list the model's variables and exit")
    args = parser.parse_args(argv)
    try:
        if args.model != COUPLING and (args.nodes is not None or args.dof != 1):
            raise ValueError(f"--nodes and --dof are options of the coupling FMU, not of {args.model}")
        if args.model == COUPLING:
            from .core.network import graph
            from .fmus.coupling import CouplingSlave, CouplingSpec
            A = graph(args.graph, 2 if args.nodes is None else args.nodes)
            cls = CouplingSlave(CouplingSpec.from_weights(A, args.dof))
        else:
            cls = model_slave(resolve(args.model)[0])
        if args.list:
            for v in cls.declare():
                unit = f" [{v.unit}]" if v.unit else ""
                start = f" = {v.start}" if v.start is not None else ""
                print(f"{v.name:<14} {v.causality:<9} {v.type:<11}{unit}{start}  {v.description}")
            return 0
        if args.model == COUPLING:
            if args.fmi_version != 2:
                raise ValueError("the coupling FMU is exported for FMI 2.0 only (--fmi-version 2)")
            path = export_coupling(args.output, A, args.dof, _parse_set(args.sets))
        else:
            path = export_fmu(args.model, args.output, _parse_set(args.sets), fmi_version=args.fmi_version)
    except (ValueError, native.NativeCodeError) as exc:
        print(f"fmu-sync export: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main_export())
