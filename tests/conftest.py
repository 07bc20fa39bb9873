"""Session fixtures shared by test modules (one build per session instead of one per module)."""
from __future__ import annotations

import os

import pytest

from _children import compile_c_host
from _shared_compile import install as install_compile_locks


#: the files that cost most, heaviest first: the workers take them first, so the run does not end on one
#: of them while the other worker idles (longest processing time first). Measured 2026-11-29 in a serial
#: cold run (`-n 0`, 1278 s, docs/design.md §5.6); with xdist's default order (most tests first) these came
#: 13th-74th of 95 files. The other files follow, most tests first (xdist's own order).
HEAVY_FIRST = ("test_applied_force.py", "test_trapezoid_general.py", "test_fmu_user_model.py", "test_forcelaw.py",
               "test_bench.py", "test_law_failure.py", "test_mixed_systems.py", "test_ssp_user_models.py",
               "test_cli.py", "test_fmu_concurrency.py")


def pytest_collection_modifyitems(session, config, items):
    """Files in the order :data:`HEAVY_FIRST`, then by their number of tests (pyproject's
    ``--no-loadscope-reorder`` leaves the order to this hook); a file's tests keep their order."""
    count: dict = {}
    for it in items:
        count[it.path.name] = count.get(it.path.name, 0) + 1
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda it: (rank.get(it.path.name, len(rank)), -count[it.path.name], it.path.name))


@pytest.fixture(scope="session")
def shared_fmu(tmp_path_factory):
    """``shared_fmu(model="impact-oscillator", fmi_version=2, start_values=None)``: the FMU
    ``export_fmu`` makes of these (``"coupling"``: the pair's coupling FMU), exported once per
    session. Shared by every module that asks: read it, unpack it, never change the file."""
    folder = tmp_path_factory.mktemp("shared-fmus")
    made = {}
    names = {"impact-oscillator": "io", "mechanical-system-2": "ms2", "coupling": "coupling"}

    def fmu(model: str = "impact-oscillator", fmi_version: int = 2, start_values: dict | None = None):
        key = (model, fmi_version, tuple(sorted((start_values or {}).items())))
        if key not in made:
            from fmu_sync.export import export_fmu
            name = f"{names.get(model, model)}{'' if fmi_version == 2 else fmi_version}"
            made[key] = export_fmu(model, folder / f"{name}_{len(made)}.fmu", start_values, fmi_version)
        return made[key]
    return fmu


@pytest.fixture(scope="session")
def c_host(tmp_path_factory):
    """tests/c/fmu_host.c compiled once per session: the plain C importer."""
    return compile_c_host(tmp_path_factory.mktemp("c-host"))


@pytest.fixture(scope="session", autouse=True)
def compile_locks(tmp_path_factory):
    """Under xdist: each cached numba kernel compiled by one worker, loaded from the cache by the
    other (tests/_shared_compile.py); the locks sit in the run's own folder shared by its workers.
    Its value (None without xdist): that folder, for a child process that compiles kernels of its
    own to join (``_shared_compile.install``)."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return None
    folder = str(tmp_path_factory.getbasetemp().parent / "numba-compile-locks")
    install_compile_locks(folder)
    return folder
