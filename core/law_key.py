"""What a force law's compiled code is made of: the key of its cached loops and FMU stepper
(docs/design.md §2.8, docs/user-model.md "Compilation and the cache").

numba compiles h from its code and from the globals it reads, frozen at compile time: the
functions it calls (their code and globals in turn, in any file), the constants and arrays it
reads, the modules it names (a library -- math, numpy, numba -- by its name; a module of the
user's by what the code reads of it: ``mylib.helper``). :func:`code_digest` is a sha256 of
exactly these, so a law's copies of the loops (:meth:`fmu_sync.core.ForceLaw.kernels`) are
compiled again when any of them changes and not when the rest of the file does (a parameter's
default, a description, the model declaration, another law): two files whose h is the same
code share their compiled loops. The code's line numbers are part of it (numba's error path
reports them), and so is the module name of each compiled function h calls: a law's cached
loops find that function's environment by it (a helper ``@njit`` in the law's own file, which
:func:`fmu_sync.core.load_model` loads under a name that follows the file's content, keys the
law by that content again). A global this digest cannot vouch for (an object of another type:
a class instance, a dict) makes it ``None``, and the law is then keyed by its whole source
file, as any law was before 0.13.0.
"""
from __future__ import annotations

import builtins
import hashlib
import types as pytypes

import numpy as np

__all__ = ["code_digest"]

#: the version of this digest's rules (a change of the rules changes every key)
VERSION = b"law-code-1"
_SCALARS = (bool, int, float, complex, str, bytes, type(None))
#: modules whose types and functions a law may name as globals (``from math import sin``)
_LIBRARIES = ("builtins", "math", "cmath", "numpy", "numba")


class _Opaque(Exception):
    """A global the digest cannot vouch for: the law is keyed by its file."""


def code_digest(fn) -> bytes | None:
    """sha256 of what numba compiles for the function ``fn`` (a plain Python function): its code,
    defaults, closure and the globals its code names, recursively; None when one of them is of
    a kind it cannot vouch for (the caller then keys the law by its whole file)."""
    h = hashlib.sha256(VERSION)
    try:
        _function(h, fn, set())
    except _Opaque:
        return None
    return h.digest()


def _function(h, fn, seen: set) -> None:
    if id(fn) in seen:   # recursion: named once
        h.update(f"again {fn.__qualname__}\0".encode())
        return
    seen.add(id(fn))
    h.update(f"function {fn.__qualname__}\0".encode())
    _code(h, fn.__code__)
    _value(h, fn.__defaults__, seen)
    _value(h, tuple(sorted((fn.__kwdefaults__ or {}).items())), seen)
    for cell in fn.__closure__ or ():
        try:
            _value(h, cell.cell_contents, seen)
        except ValueError:    # an empty cell
            raise _Opaque from None
    g = fn.__globals__
    names = sorted(_names(fn.__code__))
    for name in names:
        if name in g:
            h.update(f"global {name}\0".encode())
            _value(h, g[name], seen)
            _attributes(h, g[name], names, seen)
        elif hasattr(builtins, name):
            h.update(f"builtin {name}\0".encode())
        # else the name of an attribute (``math.sin``'s ``sin``): in the code's names already


def _attributes(h, module, names, seen: set) -> None:
    """What the code may read of a user's module it names (``mylib.helper``): its attributes of the
    code's names, recursively for its submodules (a library module is its name alone)."""
    if not isinstance(module, pytypes.ModuleType) or _in_library(module.__name__) or id(module) in seen:
        return
    seen.add(id(module))
    for name in names:
        if hasattr(module, name):
            h.update(f"attribute {name}\0".encode())
            _value(h, getattr(module, name), seen)
            _attributes(h, getattr(module, name), names, seen)


def _names(code) -> set:
    names = set(code.co_names)
    for c in code.co_consts:
        if isinstance(c, pytypes.CodeType):
            names |= _names(c)
    return names


def _code(h, code) -> None:
    h.update(repr((code.co_argcount, code.co_posonlyargcount, code.co_kwonlyargcount, code.co_flags,
                   code.co_firstlineno, code.co_names, code.co_varnames, code.co_freevars,
                   code.co_cellvars)).encode())
    h.update(code.co_code)
    h.update(code.co_linetable)
    for c in code.co_consts:
        if isinstance(c, pytypes.CodeType):
            _code(h, c)
        else:
            h.update(_const(c).encode() + b"\0")


def _const(c) -> str:
    """A constant's text, the same in every process (a frozenset's order follows string hashing)."""
    if isinstance(c, (tuple, frozenset)):
        items = [_const(x) for x in c]
        return f"{type(c).__name__}({', '.join(sorted(items) if isinstance(c, frozenset) else items)})"
    return f"{type(c).__name__}:{c!r}"


def _value(h, v, seen: set) -> None:
    if isinstance(v, _SCALARS) or isinstance(v, np.generic):
        h.update(f"{type(v).__name__}:{v!r}\0".encode())
    elif isinstance(v, (tuple, list)):    # a namedtuple's fields too
        h.update(f"{type(v).__name__}{getattr(v, '_fields', '')}[{len(v)}]\0".encode())
        for x in v:
            _value(h, x, seen)
    elif isinstance(v, np.ndarray):
        h.update(f"array {v.dtype.str} {v.shape}\0".encode())
        h.update(np.ascontiguousarray(v).tobytes())
    elif isinstance(v, pytypes.ModuleType):   # a library by its name; a user's by what is read of it (_attributes)
        h.update(f"module {v.__name__ if _in_library(v.__name__) else ''}\0".encode())
    elif _library(v):    # numba compiles its own implementation of these, not their Python code
        h.update(f"library {v.__module__}.{getattr(v, '__qualname__', v.__name__)}\0".encode())
    elif isinstance(v, pytypes.FunctionType):
        _function(h, v, seen)
    elif callable(v) and isinstance(getattr(v, "py_func", None), pytypes.FunctionType):   # a numba dispatcher
        # its module's name too: code compiled with a call to it finds its environment by that name when
        # loaded from the cache (a module loaded by load_model is named after its file's content)
        options = getattr(v, "targetoptions", {})
        h.update(f"jit {v.py_func.__module__} {sorted((k, repr(x)) for k, x in options.items())}\0".encode())
        _function(h, v.py_func, seen)
    else:
        raise _Opaque


def _library(v) -> bool:
    """A function, ufunc or type of one of :data:`_LIBRARIES` (``math.sin``, ``np.sum``, ``float``)."""
    module = getattr(v, "__module__", None)
    return callable(v) and isinstance(module, str) and _in_library(module) and hasattr(v, "__name__")


def _in_library(module_name: str) -> bool:
    """Whether the module ``module_name`` belongs to one of :data:`_LIBRARIES`."""
    return module_name.split(".")[0] in _LIBRARIES
