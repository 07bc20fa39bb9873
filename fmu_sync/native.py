"""The FMU's stepper as native code, compiled at export (docs/design.md §4.3, docs/fmu.md).

An FMU's hot path is one numba ``cfunc`` (``fmus/stepper.py``, ``fmus/coupling_stepper.py``).
At export, :func:`stepper_object` turns it into an ELF object for the baseline x86-64
instruction set, which :func:`fmu_sync.export.build_binary` links into the FMU's binary as
the function ``fsr_native_step`` (``fmus/c/fmu_sync_runtime.c`` calls it per doStep). The
machine that runs the FMU compiles nothing and needs no numba.

How (numba and llvmlite internals, hence the pinned versions of :data:`TESTED`):

1. the cfunc's LLVM module *for linking* (``_library._get_module_for_linking()``: the cfunc
   wrapper, its callee and every numba function it reaches -- numba links the libraries of
   all callees into it, so a function the stepper calls, a user's force law included, is in
   it whether it is inlined or not; from a fresh compile or from numba's cache alike);
2. every definition made internal but the entry, renamed ``fsr_native_step``;
3. object code from a target machine for each of :data:`VARIANTS`, position-independent
   (it goes into a shared library): ``cpu="x86-64"`` (SSE2: any x86-64 CPU), and
   ``x86-64-v3`` (AVX2), which the binary picks when it is loaded on a CPU that has it
   (the baseline code measured 3-8% slower per call; both give the same numbers: no fused
   multiply-add without numba's fastmath, tested bit for bit);
4. its undefined symbols classified (:func:`link_names`): C library functions (``cos``,
   ``exp``, ``memcpy`` ...) bound to their oldest glibc version, so that the binary needs no
   newer glibc than the exporting one's 2.2.5 symbols; numba's runtime functions and the
   CPython calls of the cfunc wrapper's error path renamed ``fsrx_<name>``, provided by
   ``fmus/c/fmu_sync_native.c`` (allocation: a small runtime of our own; error path:
   stubs that flag the call so that the step fails with fmi2Error instead of reporting
   success); anything else fails the export (:class:`NativeCodeError`) naming the symbol.

Steps 2-4 (LLVM's code generation, ~3 s a variant) are done once per machine for a given
compiled stepper: the finished object is cached (:func:`cached_object`), in this process and
on disk beside numba's own cache (the folder numba's cache locators choose for this file:
``NUMBA_CACHE_DIR``, else ``fmu_sync/__pycache__``, else the user-wide cache), one file per
(stepper, variant), keyed by the sha256 of everything the object is a function of: the
stepper's LLVM module (so any change of the code it compiles, and of numba, invalidates it,
as numba's stamp does), the variant's CPU and entry name, the triple, the llvmlite version
and this file's own source. A ring of N systems exports N FMUs and emits its stepper once.
The binary's C sources are compiled the same way (:func:`c_objects`), keyed by the source as
preprocessed, so only a file whose text changes with the export (the glue, which holds the
GUID) is compiled again.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

__all__ = ["ENTRY", "CPU", "VARIANTS", "TRIPLE", "GLIBC_BASE", "LIBC", "RUNTIME", "TESTED", "NativeCodeError",
           "ExportNeedsNumba", "require_export_versions", "EXPORT_EXTRA",
           "check_versions", "stepper_object", "stepper_objects", "link_names", "cached_object", "cache_dir",
           "c_objects"]

#: the C name of the stepper in the binary (fmus/c/fmu_sync_native.h: the variant the CPU runs)
ENTRY = "fsr_native_step"
#: the instruction set every x86-64 CPU runs (SSE2): the stepper's baseline
CPU = "x86-64"
#: (LLVM cpu, C name) of each compiled variant of the stepper; fmus/c/fmu_sync_native.c
#: chooses one when the binary is loaded (__builtin_cpu_supports)
VARIANTS = ((CPU, "fsr_native_step_base"), ("x86-64-v3", "fsr_native_step_v3"))
TRIPLE = "x86_64-unknown-linux-gnu"
#: the glibc version every C library function of the object binds to (x86-64's first)
GLIBC_BASE = "GLIBC_2.2.5"
#: C library functions the compiled code may call (libm's and the memory functions)
LIBC = frozenset("""
    acos acosh asin asinh atan atan2 atanh cbrt ceil copysign cos cosh erf erfc exp exp2 expm1
    fabs floor fma fmax fmin fmod frexp hypot ldexp lgamma log log10 log1p log2 nextafter pow
    round sin sincos sinh sqrt tan tanh tgamma trunc memcpy memmove memset memcmp
""".split())
#: numba runtime and CPython functions (and the exception objects) the compiled code may
#: reference, provided under ``fsrx_<name>`` by fmus/c/fmu_sync_native.c
RUNTIME = frozenset("""
    NRT_Allocate NRT_Free NRT_MemInfo_alloc NRT_MemInfo_alloc_aligned NRT_MemInfo_call_dtor
    NRT_MemInfo_new_varsize_dtor NRT_MemInfo_varsize_realloc NRT_MemInfo_varsize_alloc
    NRT_MemInfo_varsize_free
    numba_gil_ensure numba_gil_release numba_unpickle numba_do_raise
    numba_runtime_build_excinfo_struct
    PyErr_Clear PyErr_SetNone PyErr_SetString PyErr_WriteUnraisable PyErr_Occurred
    PyUnicode_FromString PyUnicode_FromKindAndData PyBytes_FromStringAndSize PyObject_Hash
    PyTuple_Pack Py_DecRef Py_IncRef
    PyExc_RuntimeError PyExc_StopIteration PyExc_SystemError PyExc_ValueError
    PyExc_ZeroDivisionError PyExc_IndexError PyExc_TypeError PyExc_OverflowError
    PyExc_AssertionError
""".split())
#: numba and llvmlite versions the emission was tested with ([first, last] minor releases,
#: as pinned in pyproject.toml): the module access above uses their internals
TESTED = {"numba": ((0, 68), (0, 68)), "llvmlite": ((0, 50), (0, 50))}


class NativeCodeError(RuntimeError):
    """The stepper cannot be compiled to native code for the FMU (the export fails)."""


class ExportNeedsNumba(ValueError):
    """The installed numba or llvmlite is outside the range the FMU export is tested with: refused
    before any work (the core, the master and the sweeps run on any numba the package allows)."""


#: how to get an export environment (docs/install.md)
EXPORT_EXTRA = 'pip install "fmu-sync[export]"'


def require_export_versions() -> dict:
    """The numba and llvmlite the export runs with, or :class:`ExportNeedsNumba` in one line: the
    versions found, the versions the export supports, and how to get them. Called first by every
    export entry point (``export_fmu``, ``export_coupling``, ``fmu-sync export``, a co-simulated
    scene, the demo, ``fmu-sync ssp``), so nothing is written when it refuses."""
    try:
        return check_versions()
    except NativeCodeError as exc:
        found = []
        for dist in TESTED:
            try:
                found.append(f"{dist} {__import__(dist).__version__}")
            except ImportError:
                found.append(f"no {dist}")
        want = ", ".join(f"{d} {lo[0]}.{lo[1]}.x" + (f"-{hi[0]}.{hi[1]}.x" if hi != lo else "")
                         for d, (lo, hi) in TESTED.items())
        raise ExportNeedsNumba(
            f"exporting an FMU compiles its native stepper from numba's compiled module, which is tested "
            f"with {want} only; this environment has {', '.join(found)} (the core, the master on existing "
            f"FMUs and the sweeps run on it). Export from an environment with the tested versions, e.g. "
            f"a separate venv: {EXPORT_EXTRA}") from (None if "installed" in str(exc) else exc)


def _minor(version: str) -> tuple[int, int]:
    m = re.match(r"(\d+)\.(\d+)", version)
    return (int(m.group(1)), int(m.group(2))) if m else (0, 0)


def check_versions() -> dict:
    """{"numba": version, "llvmlite": version}; NativeCodeError outside :data:`TESTED`."""
    try:
        import llvmlite
        import numba
    except ImportError as exc:
        raise NativeCodeError(f"exporting an FMU compiles its stepper with numba: {exc}") from None
    found = {"numba": numba.__version__, "llvmlite": llvmlite.__version__}
    for dist, (lo, hi) in TESTED.items():
        if not lo <= _minor(found[dist]) <= hi:
            raise NativeCodeError(
                f"{dist} {found[dist]} is installed; the FMU's native stepper is emitted with "
                f"{dist} {lo[0]}.{lo[1]}.x to {hi[0]}.{hi[1]}.x only (it reads numba's compiled "
                f"module; pyproject.toml pins the tested range): install {dist} in that range")
    return found


def _target_machine(cpu: str):
    import llvmlite.binding as llvm
    try:
        llvm.initialize_native_target()
        llvm.initialize_native_asmprinter()
    except Exception:   # pragma: no cover (llvmlite versions that initialise by themselves)
        pass
    target = llvm.Target.from_triple(TRIPLE)
    return target.create_target_machine(cpu=cpu, features="", opt=3, reloc="pic", codemodel="default")


def _tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        raise NativeCodeError(f"cannot link the FMU's native stepper: the binutils tool {name!r} is not on "
                              f"PATH (install binutils, which the C compiler uses too)")
    return path


def _undefined(obj: Path) -> list[str]:
    p = subprocess.run([_tool("nm"), "-u", "--format=posix", str(obj)], capture_output=True, text=True)
    if p.returncode != 0:
        raise NativeCodeError(f"cannot read the symbols of the stepper's object code: {p.stderr.strip()}")
    return sorted({line.split()[0] for line in p.stdout.splitlines() if line.strip()})


def link_names(undefined) -> dict[str, str]:
    """{symbol: the name it is linked as} for the undefined symbols of the stepper's object;
    NativeCodeError naming every symbol the binary cannot provide."""
    out, unknown = {}, []
    for name in undefined:
        if name == "_GLOBAL_OFFSET_TABLE_":
            continue
        if name in LIBC:
            out[name] = f"{name}@{GLIBC_BASE}"
        elif name in RUNTIME:
            out[name] = f"fsrx_{name}"
        else:
            unknown.append(name)
    if unknown:
        raise NativeCodeError(
            f"the stepper's compiled code calls {', '.join(unknown)}, which the FMU binary does not provide "
            f"(it provides the C library's maths and memory functions and numba's allocation runtime): "
            f"the stepper, or a function it calls, uses a numba feature outside what a native FMU "
            f"supports; write it with numpy arrays, scalars and math functions (docs/fmu.md)")
    return out


def stepper_objects(stepper, folder: Path) -> list[Path]:
    """The native objects of the numba cfunc ``stepper``, one per :data:`VARIANTS`, in ``folder``."""
    return [stepper_object(stepper, Path(folder) / f"{name}.o", cpu, name) for cpu, name in VARIANTS]


#: finished objects of this process: cache key -> object bytes
_OBJECTS: dict[str, bytes] = {}
_SELF: bytes | None = None


def _self_source() -> bytes:
    global _SELF
    if _SELF is None:
        _SELF = Path(__file__).read_bytes()
    return _SELF


def _anchor():  # pragma: no cover (never called: numba's cache locators take a function of this file)
    pass


def cache_dir() -> Path | None:
    """The folder of the on-disk object cache: the one numba's cache locators choose for this file
    (``NUMBA_CACHE_DIR``, else ``__pycache__`` beside it, else the user-wide cache), its
    ``fmu_sync_native`` subfolder; None if none of them can be written."""
    from numba.core import caching
    for cls in caching.CacheImpl._locator_classes:
        try:
            loc = cls.from_function(_anchor, __file__)
            if loc is None:
                continue
            loc.ensure_cache_path()
            folder = Path(loc.get_cache_path()) / "fmu_sync_native"
            folder.mkdir(exist_ok=True)
            return folder
        except OSError:
            continue
    return None


def cached_object(key: str, name: str, make) -> bytes:
    """The object for ``key`` (hex sha256): this process's, else the disk cache's file ``name``
    when it holds ``key``, else ``make()`` (then kept in both). The file is the key's 64 characters
    followed by the object; written whole (a temporary file renamed), so a reader never sees half
    of one; a folder that cannot be written only means no disk cache."""
    if key in _OBJECTS:
        return _OBJECTS[key]
    folder = cache_dir()
    path = folder / name if folder is not None else None
    tag = key.encode()
    if path is not None:
        try:
            data = path.read_bytes()
        except OSError:
            data = b""
        if data[:len(tag)] == tag and len(data) > len(tag):
            _OBJECTS[key] = data[len(tag):]
            return _OBJECTS[key]
    code = make()
    _OBJECTS[key] = code
    if path is not None:
        tmp = None
        try:
            fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{name}.")
            with os.fdopen(fd, "wb") as f:
                f.write(tag + code)
            os.chmod(tmp, 0o644)
            os.replace(tmp, path)
        except OSError:
            if tmp is not None and os.path.exists(tmp):
                os.unlink(tmp)
    return code


def stepper_object(stepper, out: Path, cpu: str = CPU, entry: str = VARIANTS[0][1]) -> Path:
    """Write the native object of the numba cfunc ``stepper`` for ``cpu`` (its function named
    ``entry``) to ``out`` (made once per machine, :func:`cached_object`)."""
    versions = check_versions()
    if not hasattr(stepper, "_library") or not hasattr(stepper, "native_name"):
        raise NativeCodeError(f"{stepper!r} is not a compiled numba cfunc (was numba imported in plain mode?)")
    try:
        module = stepper._library._get_module_for_linking()
        text = str(module)
    except Exception as exc:
        raise NativeCodeError(f"cannot read the compiled module of the stepper from numba: {exc!r}") from None
    fixed = re.search(r"inttoptr \(i64 ([1-9]\d{4,})", text)
    if fixed:
        raise NativeCodeError(
            f"the stepper calls or reads something through an address of this process "
            f"({int(fixed.group(1)):#x}: a ctypes/cffi function, a function passed as a first-class "
            f"value, or an array baked in as a constant), which does not exist in the FMU's process: "
            f"call numba functions by name (a global or a closure variable of the stepper) and pass "
            f"data through the work array")
    h = hashlib.sha256()
    for part in (text.encode(), cpu.encode(), entry.encode(), TRIPLE.encode(), versions["llvmlite"].encode(),
                 _self_source()):
        h.update(hashlib.sha256(part).digest())
    py = getattr(stepper, "_pyfunc", None)
    who = f"{py.__module__}.{py.__qualname__}" if py is not None else stepper.native_name
    name = f"{who}-{entry}.o"
    out = Path(out)
    out.write_bytes(cached_object(h.hexdigest(), name, lambda: _emit(stepper, module, out, cpu, entry)))
    return out


def _emit(stepper, module, out: Path, cpu: str, entry: str) -> bytes:
    """Steps 2-4: the object code of ``module`` (the stepper's, for linking) for ``cpu``, written to
    ``out`` with its symbols renamed; its bytes."""
    try:
        module = module.clone()
        wrapper = module.get_function(stepper.native_name)
    except Exception as exc:
        raise NativeCodeError(f"cannot read the compiled module of the stepper from numba: {exc!r}") from None
    for fn in module.functions:
        if not fn.is_declaration:
            fn.linkage = "internal"
    for gv in module.global_variables:
        if not gv.is_declaration:
            gv.linkage = "internal"
    wrapper.linkage = "external"
    wrapper.visibility = "hidden"
    wrapper.name = entry
    module.triple = TRIPLE
    try:
        module.verify()
        code = _target_machine(cpu).emit_object(module)
    except Exception as exc:
        raise NativeCodeError(f"LLVM could not emit the stepper for {cpu}: {exc}") from None
    out.write_bytes(code)
    names = link_names(_undefined(out))
    with tempfile.TemporaryDirectory(prefix="fmu-sync-native-") as tmp:
        table = os.path.join(tmp, "names")
        Path(table).write_text("".join(f"{a} {b}\n" for a, b in names.items()))
        p = subprocess.run([_tool("objcopy"), f"--redefine-syms={table}", str(out)], capture_output=True, text=True)
    if p.returncode != 0:
        raise NativeCodeError(f"cannot rename the symbols of the stepper's object code: {p.stderr.strip()}")
    return out.read_bytes()


_CC_ID: dict[str, bytes] = {}


def _cc_identity(cc: str) -> bytes:
    """The compiler's path and ``--version`` (a cached object of another compiler is not this one's)."""
    if cc not in _CC_ID:
        p = subprocess.run([cc, "--version"], capture_output=True)
        _CC_ID[cc] = (shutil.which(cc) or cc).encode() + b"\0" + p.stdout
    return _CC_ID[cc]


def c_objects(cc: str, flags: list[str], sources: list[str], folder: Path) -> list[Path]:
    """The object of each C source, ``cc flags -I folder -c`` (``folder``: the export's generated
    header), in ``folder``; each made once per machine (:func:`cached_object`), keyed by the source
    as preprocessed (``-E -P``: every header it includes, the export's constants included), the
    flags and the compiler. RuntimeError with the compiler's message if one fails."""
    out = []
    for src in sources:
        obj = Path(folder) / f"{Path(src).stem}.o"
        pre = subprocess.run([cc, *flags, f"-I{folder}", "-E", "-P", src], capture_output=True)
        if pre.returncode != 0:
            raise RuntimeError(f"cannot build the FMU binary ({cc} -E {src}):\n{pre.stderr.decode()[-3000:]}")
        h = hashlib.sha256()
        for part in (_cc_identity(cc), "\0".join(flags).encode(), pre.stdout, _self_source()):
            h.update(hashlib.sha256(part).digest())

        def compile_(src=src, obj=obj):
            cmd = [cc, *flags, f"-I{folder}", "-c", src, "-o", str(obj)]
            p = subprocess.run(cmd, capture_output=True, text=True)
            if p.returncode != 0:
                raise RuntimeError(f"cannot build the FMU binary ({' '.join(cmd)}):\n{p.stderr[-3000:]}")
            return obj.read_bytes()

        obj.write_bytes(cached_object(h.hexdigest(), f"c-{Path(src).stem}.o", compile_))
        out.append(obj)
    return out
