"""The package's own files found in one place through the installed package (fmu_sync.package_files,
issue 43.4), and ``__version__`` from the installed metadata."""
import importlib.util
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest

import fmu_sync
from fmu_sync import export, package_files


def _module_file(rel: str) -> Path:
    """Python's own import system: where the module of package path ``rel`` ("core/exact.py") lives."""
    spec = importlib.util.find_spec("fmu_sync." + rel.removesuffix(".py").replace("/", "."))
    return Path(spec.origin)


@pytest.mark.parametrize("model", ["impact-oscillator", "mechanical-system-2", export.COUPLING])
def test_every_carried_module_is_the_file_python_imports(model):
    """What the FMU carries is byte for byte the module the package runs, found by its import name."""
    rels = export.carried_modules(model)
    assert "fmus/slave.py" in rels and any(r.startswith("core/") for r in rels)
    for rel in rels:
        assert package_files.path(rel).samefile(_module_file(rel)), rel
    carried = dict(export.carried_files(model))
    assert all(carried[rel] == _module_file(rel).read_bytes() for rel in rels)


def test_the_c_sources_are_the_fmus_package_folder():
    c_dir = _module_file("fmus/__init__.py").parent / "c"
    want = sorted(f"fmus/c/{p.name}" for p in c_dir.iterdir() if p.suffix in (".c", ".h"))
    assert package_files.listing("fmus/c", "*.[ch]") == want and "fmus/c/fmu_sync_fmi2.c" in want
    assert package_files.read("fmus/boot.py") == _module_file("fmus/boot.py").read_bytes()


@pytest.mark.parametrize("rel", ["fmu_sync/cli.py", "tests/conftest.py", "core/../pyproject.toml", "core",
                                 "fmus//slave.py", "/etc/passwd", "core/./exact.py"])
def test_a_path_outside_the_packages_is_refused_naming_it(rel):
    with pytest.raises(OSError, match=r"no package file '.*'.*\['core', 'fmus'\]") as err:
        package_files.read(rel)
    assert repr(rel) in str(err.value) and "\n" not in str(err.value)


def test_an_edit_of_a_carried_file_seen_through_the_one_place_changes_the_guid(monkeypatch):
    """export reads every carried file through package_files.read: an edit there is an edit of the FMU."""
    guid = export.fmu_guid("impact-oscillator")
    read = package_files.read
    monkeypatch.setattr(package_files, "read", lambda rel: read(rel) + (b"\n" if rel == "fmus/c/fmu_sync_native.c"
                                                                        else b""))
    assert export.fmu_guid("impact-oscillator") != guid


def test_version_comes_from_the_installed_metadata(monkeypatch):
    assert fmu_sync.__version__ == version("fmu-sync")
    monkeypatch.setattr(fmu_sync, "_metadata_version", lambda dist: "9.8.7")   # pyproject.toml says otherwise
    assert fmu_sync._version() == "9.8.7"

    def missing(dist):
        raise PackageNotFoundError(dist)
    monkeypatch.setattr(fmu_sync, "_metadata_version", missing)
    assert fmu_sync._version() == "0+unknown"
