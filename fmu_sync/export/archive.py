"""Writing an FMU (:mod:`fmu_sync.export`): its identity (GUID), the model description, the resources,
the binaries and the reproducible archive."""
from __future__ import annotations

import hashlib
import io
import json
import os
import tempfile
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from .. import __version__, native, package_files
from ..fmu_docs import documentation_files
from ..fmus.slave import model_guid
from .binary import (FMI_VERSIONS, MAX_SUBSTEPS, PROCESS_LIB, build_binary, build_process_lib, constants_header,
                     native_record, python_record, runtime_versions, target_requires)
from .carried import COUPLING, bytecode, carried_files, code_hash_of, kind_of, model_slave, resolve

_ZIP_DATE = (2020, 1, 1, 0, 0, 0)
#: the resources that decide the FMU's behaviour, whose SHA-256 the binary checks at every instantiation
#: (fmus/c/fmu_sync_verify.c); the build record holds the carried code's hash, checked by the boot script
#: before it imports that code. The boot script (``fmu_sync_boot_<hash>.py``) is added per export.
VERIFIED = ("fmu_sync_build.json", "fmu_sync_start.json")


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
    digest = code_hash_of(code)
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
    from ..core.coupling import energy_metric
    from ..core.network import weights
    from ..fmus.contract import matrix
    from ..fmus.coupling import CouplingSlave, CouplingSpec
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
             "built_with": runtime_versions(), "requires": target_requires(model),
             "native_stepper": native_record(),
             "max_substeps": MAX_SUBSTEPS, "fmi_version": fmi_version,
             "runtime": kind_of(model)["runtime"], "stepper": kind_of(model)["stepper"],
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
    from ..output import OutputPathError, check_out_dir, make_out_dir, plain_os_error
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
