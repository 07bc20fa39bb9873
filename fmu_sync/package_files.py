"""fmu-sync's own files, found through the installed package: the one place that does it.

The repository keeps ``core/``, ``fmus/`` and ``fmu_sync/`` at the top level, and pyproject.toml's
``package-dir`` maps the first two into ``fmu_sync.core`` and ``fmu_sync.fmus`` (docs/design.md).
What needs a source file of the FMU's carried code (the export: the Python modules it carries, the C
sources of its binary, the boot script) asks here by the file's path inside the *installed* package,
``"core/exact.py"`` or ``"fmus/c/fmu_sync_fmi2.c"``; the package's location comes from
:func:`importlib.resources.files`, so a wheel, an editable install and a checkout resolve alike and no
copy of the mapping exists outside pyproject.toml.
"""
from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["PACKAGES", "path", "read", "listing"]

#: the first part of a package path -> the installed package it names
PACKAGES = {"core": "fmu_sync.core", "fmus": "fmu_sync.fmus"}


def path(rel: str) -> Path:
    """The file ``rel`` ("core/exact.py", "fmus/c/fmu_sync_runtime.c") of the installed package, on disk
    (a C compiler reads it); OSError naming ``rel`` for a path outside :data:`PACKAGES` or one that
    climbs out of its package."""
    top, _, rest = rel.partition("/")
    parts = rest.split("/")
    if top not in PACKAGES or not rest or any(p in ("", ".", "..") for p in parts):
        raise OSError(f"no package file {rel!r}: a path inside one of {sorted(PACKAGES)} "
                      "(\"core/exact.py\", \"fmus/c/fmu_sync_fmi2.c\")")
    found = files(PACKAGES[top]).joinpath(*parts)
    if not isinstance(found, Path):   # a zipped install: the export compiles these files with gcc
        raise OSError(f"package file {rel!r} is not on disk ({found}): install fmu-sync unzipped")
    return found


def read(rel: str) -> bytes:
    """The content of :func:`path` (``rel``)."""
    return path(rel).read_bytes()


def listing(folder: str, pattern: str) -> list[str]:
    """The package paths of the files in package folder ``folder`` ("fmus/c") matching the glob
    ``pattern`` ("*.[ch]"), sorted."""
    return sorted(f"{folder}/{p.name}" for p in path(folder).glob(pattern) if p.is_file())
