"""Boot script of an fmu-sync FMU (``resources/fmu_sync_boot_<hash>.py``).

Imported once per process by the FMU's binary (resources/ briefly on sys.path),
with the standard library only. For each fmi2Instantiate, :func:`instantiate`:

1. reads ``resources/fmu_sync_build.json`` (model, package name, content hash,
   the packages the target needs with their ranges, ``requires``, and the versions
   the FMU was built with) and checks the running environment: a required package
   missing or out of its range is an error naming the command that installs it for
   this Python (fmi2Instantiate returns NULL with the reason logged), other versions
   than the build's are logged as warnings. numba is not needed: the stepper is
   native code in the binary, and the carried code runs as plain Python
   (``core/jit.py``), importing nothing that compiles;
2. uses a complete copy of the carried code already in a cache folder (even a
   read-only one), else copies it (``resources/fmu_sync_code``) once to a per-user
   cache folder keyed on its content, ``$FMU_SYNC_CACHE`` or
   ``$XDG_CACHE_HOME/fmu-sync`` or ``~/.cache/fmu-sync`` (else ``$TMPDIR``,
   ``/tmp`` or ``/var/tmp``/fmu-sync-<uid>; none writable: an error that names
   them and says to set FMU_SYNC_CACHE), ``<folder>/<hash>/<package>``, published whole by a
   rename and never removed or replaced (:func:`unpack`);
3. imports the build's ``runtime`` module (``fmus.runtime`` for a mechanical model,
   ``fmus.coupling_runtime`` for the coupling FMU) from there (a package name unique to the
   content: two FMUs of different code coexist in one process) and returns a
   new instance (``runtime.create(resources, model, max_substeps, fmi_version, stepper)``;
   ``stepper``: the address of the binary's native stepper, handed over by the binary).

Its messages name the instantiation call of the build's FMI version.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import tempfile

BUILD_FILE = "fmu_sync_build.json"
CODE_DIR = "fmu_sync_code"
#: the temporary folders tried after $TMPDIR (when the user's cache folder is not writable)
TMP_DIRS = ("/tmp", "/var/tmp")
#: the instantiation call of each FMI version (the build record's fmi_version)
INSTANTIATE = {2: "fmi2Instantiate", 3: "fmi3InstantiateCoSimulation"}
_checked: dict[str, list[str]] = {}


def code_hash(root: str) -> str:
    """sha256 over the relative paths and contents of the ``*.py`` files under ``root``."""
    h = hashlib.sha256()
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
        rel = os.path.relpath(dirpath, root).replace(os.sep, "/")
        for name in sorted(filenames):
            if name.endswith(".py"):
                h.update(f"{rel}/{name}\n".encode())
                with open(os.path.join(dirpath, name), "rb") as f:
                    h.update(f.read())
    return h.hexdigest()


class Broken(str):
    """What :func:`_version` returns for a module that is there but fails to import: the error."""


def _version(dist: str) -> str | None:
    """The version of the module ``dist`` (its ``__version__``; "unknown" without one; None if it is
    not installed; :class:`Broken` with the error if importing it raises anything else, e.g. an
    AttributeError of a damaged or mismatched installation). The FMU imports numpy anyway;
    importlib.metadata would add ~40 ms to a cold start."""
    import importlib
    try:
        module = importlib.import_module(dist)
    except ModuleNotFoundError as exc:
        if exc.name == dist:
            return None
        return Broken(f"{type(exc).__name__}: {exc}")
    except Exception as exc:
        return Broken(f"{type(exc).__name__}: {exc}")
    return str(getattr(module, "__version__", "unknown"))


def _has(module: str) -> bool:
    """Whether this interpreter can import ``module`` (found, without importing it)."""
    import importlib.util
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def _vtuple(v: str) -> tuple[int, ...]:
    """(1, 26, 4) of "1.26.4" (a pre-release "2.0.0rc1" counts as 2.0.0)."""
    out = []
    for part in v.split("."):
        digits = ""
        for ch in part:
            if not ch.isdigit():
                break
            digits += ch
        if not digits:
            break
        out.append(int(digits))
    return tuple(out)


def satisfies(version: str, spec: str) -> bool:
    """Whether ``version`` meets a PEP 440 specifier set of plain releases (">=0.59,<0.69")."""
    import operator
    ops = {">=": operator.ge, "<=": operator.le, "==": operator.eq, "!=": operator.ne, ">": operator.gt,
           "<": operator.lt}
    have = _vtuple(version)
    for clause in filter(None, (c.strip() for c in spec.split(","))):
        op = next(o for o in (">=", "<=", "==", "!=", ">", "<") if clause.startswith(o))
        want = _vtuple(clause[len(op):].strip())
        n = max(len(have), len(want))
        if not ops[op](have + (0,) * (n - len(have)), want + (0,) * (n - len(want))):
            return False
    return True


#: how the binary chose this interpreter in a plain C host (set by fmus/c/fmu_sync_runtime.c)
CHOSEN = ""


class SetupError(RuntimeError):
    """The FMU cannot be set up in this process; the message says what to do."""


def _advice(embedded: bool) -> str:
    """Where the environment of the FMU's Python is chosen, in the host at hand."""
    if embedded:
        return ("this importer is a plain C program: the FMU chose this Python itself (FMU_SYNC_PYTHON, else the "
                "interpreter recorded at export, else python3 on PATH" + (f"; tried {CHOSEN}" if CHOSEN else "")
                + ")")
    return (f"this importer is itself a Python process ({sys.executable}) and the FMU runs in its "
            f"interpreter (FMU_SYNC_PYTHON is ignored in a Python host)")


def install_command(reqs: dict, reinstall: bool = False) -> str:
    """The one command that installs ``reqs`` ({"numpy": ">=1.24"}) for this interpreter: pip in a venv
    or an ordinary installation (pip bootstrapped first with ``-m ensurepip`` where pip is absent), the
    distribution's packages for a Debian/Ubuntu system Python (PEP 668: pip is refused there);
    ``reinstall``: replace a broken installation (pip's ``--force-reinstall``)."""
    import sysconfig
    names = " ".join(f"'{d}{spec}'" if spec else d for d, spec in reqs.items())
    managed = sys.prefix == sys.base_prefix and os.path.isfile(
        os.path.join(sysconfig.get_path("stdlib"), "EXTERNALLY-MANAGED"))
    debian = os.path.isfile("/etc/debian_version")
    if managed and debian:
        return ("sudo apt-get install " + ("--reinstall " if reinstall else "")
                + " ".join(f"python3-{d}" for d in reqs))
    if managed:
        return (f"python3 -m venv ~/fmu-python && ~/fmu-python/bin/python -m pip install {names} (this system "
                f"Python refuses pip, PEP 668), then set FMU_SYNC_PYTHON=~/fmu-python/bin/python")
    pip = f"{sys.executable} -m pip install {'--force-reinstall ' if reinstall else ''}{names}"
    if _has("pip"):
        return pip
    if _has("ensurepip"):
        return f"{sys.executable} -m ensurepip && {pip} (this Python has no pip: ensurepip installs it)"
    platform = " (Debian/Ubuntu: sudo apt-get install python3-venv python3-pip)" if debian else ""
    return (f"install pip for {sys.executable}, which has neither pip nor ensurepip{platform}, then {pip}")


def check_runtime(built: dict, embedded: bool = False, call: str = INSTANTIATE[2],
                  requires: dict | None = None) -> list[str]:
    """Messages about the running environment versus the build (E: missing or too old, W: other
    than the build's); ``requires``: the build record's {distribution: specifier} (by default
    numpy, any version); ``embedded``: the binary started this interpreter (a C host),
    else the host's own; ``call``: the instantiation call the messages name."""
    out = []
    requires = {"numpy": ""} if requires is None else requires
    where = f"the Python environment {sys.prefix} (Python {sys.version.split()[0]}, {sys.executable})"
    py_now = ".".join(map(str, sys.version_info[:3]))
    if py_now.split(".")[:2] != str(built.get("python")).split(".")[:2]:   # patch releases share the ABI
        out.append(f"W:{call}: running on Python {py_now}; the FMU was built with Python "
                   f"{built.get('python')} (its code is plain Python)")
    missing, old = [], []
    for dist, spec in requires.items():
        have = _version(dist)
        if isinstance(have, Broken):
            out.append(f"E:{call}: {dist} in {where} is broken: importing it raises {have}; {_advice(embedded)}: "
                       f"reinstall it there: {install_command({dist: spec}, reinstall=True)}"
                       + (", or set FMU_SYNC_PYTHON to an interpreter with a working one" if embedded else ""))
        elif have is None:
            missing.append(dist)
        elif have != "unknown" and spec and not satisfies(have, spec):
            old.append(f"{dist} {have} (needs {dist}{spec})")
        elif have != built.get(dist):
            out.append(f"W:{call}: {dist} {have} in {where}; the FMU was built with {dist} {built.get(dist)}")
    if missing or old:
        bad = {d: requires[d] for d in requires if d in missing or any(o.startswith(d + " ") for o in old)}
        what = "; ".join([f"lacks {d} (the FMU needs {d}{requires[d]}, built with {built.get(d)})"
                          for d in missing] + [f"has {o}" for o in old])
        todo = f"install {' and '.join(bad)} there: {install_command(bad)}"
        todo += (", or set FMU_SYNC_PYTHON to an interpreter that has them" if embedded else
                 ", or run the importer from an environment that has them")
        out.append(f"E:{call}: {where} {what}; {_advice(embedded)}: {todo}")
    return out


def _home() -> tuple[str | None, str]:
    """(the user's home folder, "") if it exists, else (None, why it is not used): a HOME that is empty or
    names no folder is never created (nor is ``.cache`` put under the file-system root)."""
    home = os.environ.get("HOME")
    if home is None:
        home = os.path.expanduser("~")
        home = None if home == "~" else home
    if not home:
        return None, "HOME is empty"
    if not os.path.isdir(home):
        return None, f"HOME={home} does not exist (not created)"
    return home, ""


def _cache_candidates() -> list[tuple[str, str]]:
    """(where it comes from, folder) in the order tried (``~/.cache`` only under an existing home)."""
    uid = os.getuid() if hasattr(os, "getuid") else 0
    xdg = os.environ.get("XDG_CACHE_HOME")
    xdg = xdg if xdg and os.path.isabs(xdg) else None     # XDG: a relative path is ignored
    home, _ = _home()
    out = []
    if os.environ.get("FMU_SYNC_CACHE"):
        out.append(("FMU_SYNC_CACHE", os.environ["FMU_SYNC_CACHE"]))
    if xdg:
        out.append(("XDG_CACHE_HOME", os.path.join(xdg, "fmu-sync")))
    elif home:
        out.append(("HOME", os.path.join(home, ".cache", "fmu-sync")))
    for label, tmp in (("TMPDIR", os.environ.get("TMPDIR")),) + tuple((d, d) for d in TMP_DIRS):
        if tmp:
            out.append((label, os.path.join(tmp, f"fmu-sync-{uid}")))
    return out


def _unwritable(base: str) -> str | None:
    """None if ``base`` is (made) a writable folder, else why it is not."""
    try:
        os.makedirs(base, exist_ok=True)
        return None if os.access(base, os.W_OK) else "not writable"
    except OSError as exc:
        return exc.strerror or str(exc)


def cache_root(embedded: bool = False) -> str:
    """The first writable cache folder; SetupError naming every folder tried and what to do."""
    home, why = _home()
    tried = [] if home or os.environ.get("XDG_CACHE_HOME") else [f"~/.cache/fmu-sync (HOME): {why}"]
    for label, base in _cache_candidates():
        why = _unwritable(base)
        if why is None:
            return base
        tried.append(f"{base} ({label}): {why}")
    where = ("in the environment of the program that loads the FMU" if embedded else
             f"in this Python process (os.environ['FMU_SYNC_CACHE'] before loading the FMU, or in the "
             f"shell that starts {sys.executable})")
    raise SetupError(f"no writable folder for the FMU's code and its compiled cache; tried "
                     f"{'; '.join(tried)}. Set FMU_SYNC_CACHE to a writable folder {where}")


def _complete(dest: str, digest: str, package: str) -> bool:
    """Whether ``dest`` is a published copy of the code ``digest``: its marker, and its files hash to it."""
    return os.path.isfile(os.path.join(dest, ".complete")) and code_hash(os.path.join(dest, package)) == digest


def _set_aside(root: str, dest: str, digest: str) -> None:
    """Move a damaged copy at ``dest`` out of the way by renaming it (``.damaged-<hash>-<pid>-<n>`` in
    ``root``), never deleting it: a process may still be importing from it. Gone already: nothing to do."""
    aside = tempfile.mkdtemp(prefix=f".damaged-{digest[:12]}-{os.getpid()}-", dir=root)
    try:
        os.rename(dest, os.path.join(aside, "copy"))
    except FileNotFoundError:              # another process set it aside first
        os.rmdir(aside)
    except OSError as exc:
        os.rmdir(aside)
        raise SetupError(f"the cached copy of the FMU's code {dest} is damaged and cannot be set aside "
                         f"({exc.strerror or exc}): remove it when no process uses it") from None


def unpack(resources_dir: str, build: dict, embedded: bool = False) -> str:
    """The folder to put on sys.path (holds ``<package>/``): going through the cache folders in order
    (:func:`_cache_candidates`), the first that holds a complete copy of this code (even a read-only
    one), up to the first writable one, where a copy is made if it holds none (so a set
    FMU_SYNC_CACHE is where the copy is, not a folder further down the list).

    Safe under any concurrency (processes, threads, several FMUs, docs/fmu.md "The code cache"):
    a copy is made in a temporary folder and published whole by renaming it to ``<root>/<hash>``;
    a published copy is never removed or replaced (its name is its content's hash, so it never
    changes); one that fails its hash is set aside by a rename (:func:`_set_aside`), not deleted."""
    digest, package = build["code_hash"], build["package"]
    for _, base in _cache_candidates():   # in order: a complete copy is used where it is (read-only or
        if _complete(os.path.join(base, digest), digest, package):     # not), up to the first writable
            return os.path.join(base, digest)                           # folder, where one is made
        if _unwritable(base) is None:
            break
    root = cache_root(embedded)
    dest = os.path.join(root, digest)
    src = os.path.join(resources_dir, CODE_DIR)
    if code_hash(src) != digest:
        raise SetupError(f"the FMU's code in {src} does not match its recorded hash {digest[:12]}: "
                         f"the FMU is damaged (export it again)")
    tmp = tempfile.mkdtemp(prefix=f".{digest[:12]}.", dir=root)
    try:
        shutil.copytree(src, os.path.join(tmp, package))
        with open(os.path.join(tmp, ".complete"), "w") as f:
            f.write(digest + "\n")
        for _ in range(3):
            try:
                os.rename(tmp, dest)       # atomic; refused when dest exists (not empty)
                return dest
            except OSError:
                if _complete(dest, digest, package):    # another process or thread published it first
                    return dest
                if os.path.lexists(dest):
                    _set_aside(root, dest, digest)
        raise SetupError(f"cannot publish the FMU's code in {dest}: the folder keeps being replaced by "
                         f"copies that do not match the hash {digest[:12]}")
    finally:
        if os.path.isdir(tmp):             # not published: our own temporary copy
            shutil.rmtree(tmp, ignore_errors=True)


def instantiate(resources_dir: str, instance_name: str, guid: str, embedded: int = 0, stepper: int = 0):
    """(reply, instance or None) for the binary; never raises. ``embedded``: the
    binary started this interpreter (a plain C host), else it is the host's own;
    ``stepper``: the address of the binary's native stepper."""
    msgs: list[str] = []
    call = INSTANTIATE[2]
    try:
        with open(os.path.join(resources_dir, BUILD_FILE), "rb") as f:   # bytes: no text decoder per call
            build = json.loads(f.read())
        fmi_version = int(build.get("fmi_version", 2))
        call = INSTANTIATE[fmi_version]
        key = build["code_hash"]
        if key not in _checked:
            _checked[key] = check_runtime(build["built_with"], bool(embedded), call, build.get("requires"))
            if embedded and CHOSEN:
                _checked[key].insert(0, f"I:{call}: Python chosen: {sys.executable} (Python "
                                        f"{sys.version.split()[0]}); tried {CHOSEN}")
        msgs += _checked[key]
        if any(m.startswith("E:") for m in msgs):
            return "\x1e".join(msgs), None
        package = build["package"]
        if package not in sys.modules:
            path = unpack(resources_dir, build, bool(embedded))
            if path not in sys.path:
                sys.path.insert(0, path)
        import importlib
        runtime = importlib.import_module(f"{package}.{build['runtime']}")
        reply, inst = runtime.create(resources_dir, build["model"], float(build.get("max_substeps", "inf")),
                                     fmi_version, stepper)
        if reply:
            msgs.append(reply)
        return "\x1e".join(msgs), inst
    except SetupError as exc:
        msgs.append(f"E:{call}: {exc}")
        return "\x1e".join(msgs), None
    except Exception as exc:
        import traceback
        tb = traceback.format_exc(limit=4).replace("\x1e", " ")
        msgs.append(f"E:{call}: cannot set up the Python slave: {exc!r}\n{tb}")
        return "\x1e".join(msgs), None
