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

from .archive import FMI_VERSIONS, VERIFIED, export_coupling, export_fmu, fmu_guid, write_archive
from .binary import (MAX_SUBSTEPS, PROCESS_LIB, TARGET_REQUIRES, build_binary, build_process_lib, constants_header,
                     python_record, runtime_versions, stepper_cfunc, target_requires)
from .carried import COUPLING, MODELS, bytecode, carried_files, carried_modules, model_slave, resolve
from .cli import main_export

#: the former private name (tests and tools that read the versions an export records)
_runtime_versions = runtime_versions

__all__ = ["MODELS", "export_fmu", "export_coupling", "main_export", "model_slave", "carried_files",
           "carried_modules", "bytecode", "build_binary", "stepper_cfunc", "constants_header", "fmu_guid",
           "write_archive", "MAX_SUBSTEPS", "COUPLING", "FMI_VERSIONS", "TARGET_REQUIRES", "target_requires",
           "resolve", "PROCESS_LIB", "VERIFIED", "build_process_lib", "python_record", "runtime_versions"]
