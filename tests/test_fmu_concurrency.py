"""Many at once, and nothing foreign (issue 35; docs/fmu.md "The code cache" and "What the binary
checks"): FMUs instantiated by several processes and threads on one empty code cache under CPU load,
two different fmu-sync binaries started in threads of one plain C host, and an FMU that refuses
resources it was not exported with. FMUs are loaded in child processes only, never in pytest's."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from _children import compile_c_host, unpack_fmu
from test_fmu_c_host import _clean_env

THREADS_SRC = Path(__file__).parent / "c" / "fmu_threads.c"


@pytest.fixture(scope="module")
def hosts(tmp_path_factory, c_host):
    folder = tmp_path_factory.mktemp("threads-host")
    return {"host": c_host, "threads": compile_c_host(folder, THREADS_SRC, ("-ldl", "-lpthread"))}


@pytest.fixture(scope="module")
def unpacked(tmp_path_factory, shared_fmu):
    """model -> a function giving a fresh unpacked copy of its FMU (FMI 2.0; "io3": FMI 3.0)."""
    tmp = tmp_path_factory.mktemp("unpacked")

    def get(model: str, fmi_version: int = 2) -> Path:
        fmu = shared_fmu(model, fmi_version)
        return unpack_fmu(fmu, tmp / f"{model}{fmi_version}-{len(list(tmp.iterdir()))}")
    return get


class _Load:
    """One CPU-bound process for the duration (the machine under load)."""

    def __enter__(self):
        self.p = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        return self

    def __exit__(self, *exc):
        self.p.kill()
        self.p.wait()


# --------------------------------------------------------------- the code cache
def _code_tree(root: Path, files: int = 40) -> Path:
    src = root / "resources" / "fmu_sync_code"
    for i in range(files):
        d = src / f"pkg{i % 4}"
        d.mkdir(parents=True, exist_ok=True)
        (d / f"m{i}.py").write_text(f"X = {i}\n" + "# filler\n" * 200)
    return src


def test_a_published_copy_is_never_removed_under_a_reader(tmp_path, monkeypatch):
    """Threads unpacking one code into one empty cache, each reading every file of the copy it was
    given right after: every file is there for every thread, one copy is published, no temporary
    folder is left. (The copy that lost the race used to remove the published one.)"""
    from fmu_sync.fmus import boot
    src = _code_tree(tmp_path)
    build = {"code_hash": boot.code_hash(str(src)), "package": "fmu_sync_mstress"}
    names = sorted(p.relative_to(src) for p in src.rglob("*.py"))
    for rnd in range(6):
        monkeypatch.setenv("FMU_SYNC_CACHE", str(tmp_path / f"cache{rnd}"))
        errors, start = [], threading.Barrier(8)

        def one():
            start.wait()
            try:
                dest = Path(boot.unpack(str(src.parent), build))
                for rel in names:
                    (dest / build["package"] / rel).read_bytes()
            except Exception as exc:   # noqa: BLE001 (reported by the assertion)
                errors.append(repr(exc))
        threads = [threading.Thread(target=one) for _ in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert not errors, errors[:3]
        assert sorted(os.listdir(tmp_path / f"cache{rnd}")) == [build["code_hash"]]


def test_a_damaged_copy_is_set_aside_not_deleted(tmp_path, monkeypatch):
    """A copy whose files no longer match its hash is renamed away (a process may still read it) and
    a complete copy is published in its place."""
    from fmu_sync.fmus import boot
    src = _code_tree(tmp_path, files=3)
    build = {"code_hash": boot.code_hash(str(src)), "package": "fmu_sync_mdamaged"}
    monkeypatch.setenv("FMU_SYNC_CACHE", str(tmp_path / "cache"))
    dest = Path(boot.unpack(str(src.parent), build))
    edited = dest / build["package"] / "pkg0" / "m0.py"
    edited.write_text("X = 'edited'\n")
    held = open(edited)                                   # a reader of the damaged copy
    assert Path(boot.unpack(str(src.parent), build)) == dest
    assert (dest / build["package"] / "pkg0" / "m0.py").read_text().startswith("X = 0\n")
    aside = [p for p in (tmp_path / "cache").iterdir() if p.name.startswith(".damaged-")]
    assert len(aside) == 1 and (aside[0] / "copy" / build["package"] / "pkg0" / "m0.py").read_text() == "X = 'edited'\n"
    assert held.read() == "X = 'edited'\n"
    held.close()


_FMPY_THREADS = """
import json, sys, threading
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
folder, n = sys.argv[1], int(sys.argv[2])
md = read_model_description(folder + "/modelDescription.xml")
start, out = threading.Barrier(n), []
def one(k):
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName=f"i{k}")
    start.wait()
    try:
        fmu.instantiate(); fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode(); fmu.exitInitializationMode()
        [fmu.doStep(i * 0.01, 0.01) for i in range(10)]
        out.append(fmu.getReal([1])[0]); fmu.terminate(); fmu.freeInstance()
    except Exception as exc:
        out.append(repr(exc))
threads = [threading.Thread(target=one, args=(k,)) for k in range(n)]
[t.start() for t in threads]
[t.join() for t in threads]
print(json.dumps(out))
"""


@pytest.mark.slow
def test_processes_and_threads_on_an_empty_cache_under_load(tmp_path, unpacked):
    """3 rounds of 4 fmpy processes x 4 threads instantiating the FMU together on an empty code
    cache, one CPU-bound process beside them: 48 of 48 instances run, all with the same q."""
    folder = unpacked("impact-oscillator")
    results = []
    with _Load():
        for rnd in range(3):
            env = {**os.environ, "FMU_SYNC_CACHE": str(tmp_path / f"cache{rnd}")}
            procs = [subprocess.Popen([sys.executable, "-c", _FMPY_THREADS, str(folder), "4"], env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(4)]
            for p in procs:
                out, err = p.communicate(timeout=300)
                assert p.returncode == 0, err[-2000:]
                results += json.loads(out.strip().splitlines()[-1])
            assert sorted(os.listdir(tmp_path / f"cache{rnd}")) == [
                json.loads((folder / "resources" / "fmu_sync_build.json").read_text())["code_hash"]]
    failed = [r for r in results if not isinstance(r, float)]
    assert not failed and len(results) == 48, failed[:3]
    assert len(set(results)) == 1


# --------------------------------------------------------------- one interpreter start per process
@pytest.mark.slow
def test_two_fmus_instantiated_in_threads_of_a_c_host(hosts, unpacked, tmp_path):
    """A 1-DOF and a pendulum FMU (two fmu-sync binaries) in one plain C host, 4 threads each, all
    started together on an empty cache: every call of every thread returns fmi2OK, in 3 of 3 runs."""
    dirs = [unpacked("impact-oscillator"), unpacked("pendulum")]
    for run in range(3):
        env = _clean_env(FMU_SYNC_CACHE=str(tmp_path / f"cache{run}"))
        p = subprocess.run([str(hosts["threads"]), "4", *map(str, dirs)], capture_output=True, text=True,
                           timeout=300, env=env)
        assert p.returncode == 0, f"run {run}: {p.returncode}\n{p.stdout}\n{p.stderr[-2000:]}"
        assert p.stdout.count("status 0") == 8, p.stdout


def test_the_process_library_exports_only_its_record(unpacked):
    """binaries/<platform>/fmu_sync_process.so.1 is loaded RTLD_GLOBAL: it defines one dynamic symbol,
    so it can take the place of no other library's (the FMU binary, with the FMI functions, stays local)."""
    from fmu_sync.export import PROCESS_LIB
    for fmi_version, platform in ((2, "linux64"), (3, "x86_64-linux")):
        lib = unpacked("impact-oscillator", fmi_version) / "binaries" / platform / PROCESS_LIB
        p = subprocess.run(["nm", "-D", "--defined-only", str(lib)], capture_output=True, text=True, check=True)
        assert [line.split()[-1] for line in p.stdout.splitlines() if line.strip()] == ["fmu_sync_process_v1"]


# --------------------------------------------------------------- an FMU knows its own files
def _refusal(host: Path, folder: Path, *args) -> str:
    p = subprocess.run([str(host), str(folder), "--stop", "0.1", *args], capture_output=True, text=True,
                       timeout=120, env=_clean_env())
    assert p.returncode == 3 and "instantiate NULL" in p.stdout, (p.returncode, p.stdout, p.stderr[-2000:])
    return p.stderr


def test_foreign_resources_are_refused_naming_the_file(hosts, unpacked):
    """The 2-DOF FMU's resources/ and binaries/ unzipped over the 1-DOF FMU's folder, run with the
    1-DOF's modelDescription (the same carried code and boot script, another build record and start
    file): fmi2Instantiate refuses, naming the build record and both GUIDs. (The same with the Duffing
    FMU over the pendulum's folder: docs/fmu.md, measured by hand; exporting those two costs a minute.)"""
    folder = unpacked("impact-oscillator")
    other = unpacked("mechanical-system-2")
    guids = [json.loads((d / "resources" / "fmu_sync_build.json").read_text())["guid"] for d in (folder, other)]
    for sub in ("resources", "binaries"):
        shutil.copytree(other / sub, folder / sub, dirs_exist_ok=True)
    err = _refusal(hosts["host"], folder)
    assert "fmi2Instantiate: the resources folder" in err and "is not this FMU's" in err
    assert "resources/fmu_sync_build.json carries GUID" in err
    assert f"carries GUID '{guids[1]}', this binary's is '{guids[0]}'" in err


@pytest.mark.slow
def test_an_edited_start_file_is_refused_naming_it(hosts, unpacked):
    """q_start -0.8 -> -0.5 in the pendulum's resources/fmu_sync_start.json: refused, naming the file."""
    folder = unpacked("pendulum")
    start = folder / "resources" / "fmu_sync_start.json"
    text = start.read_text()
    assert '"q_start": -0.8' in text
    start.write_text(text.replace('"q_start": -0.8', '"q_start": -0.5'))
    err = _refusal(hosts["host"], folder)
    assert re.search(r"fmi2Instantiate: resources/fmu_sync_start.json in \S+ was changed after export", err)


@pytest.mark.parametrize("name", ["fmu_sync_build.json", "fmu_sync_start.json", "boot"])
@pytest.mark.parametrize("fmi_version", [2, 3])
def test_every_checked_file_is_refused_when_edited(hosts, unpacked, name, fmi_version):
    """A space added to the build record, the start file or the boot script of the 1-DOF FMU (FMI 2.0
    and 3.0): the instantiation call refuses, naming that file; the unedited copy runs."""
    folder = unpacked("impact-oscillator", fmi_version)
    args = ["--fmi3"] if fmi_version == 3 else []
    call = "fmi2Instantiate" if fmi_version == 2 else "fmi3InstantiateCoSimulation"
    res = folder / "resources"
    path = next(res.glob("fmu_sync_boot_*.py")) if name == "boot" else res / name
    original = path.read_bytes()
    path.write_bytes(original + b" ")
    err = _refusal(hosts["host"], folder, *args)
    assert f"{call}: resources/{path.name} in {res} was changed after export" in err
    path.write_bytes(original)
    p = subprocess.run([str(hosts["host"]), str(folder), "--stop", "0.1", *args], capture_output=True, text=True,
                       timeout=120, env=_clean_env())
    assert p.returncode == 0, p.stdout + p.stderr[-2000:]


def test_native_objects_cache_under_threads(tmp_path, monkeypatch):
    """fmu_sync.native.cached_object, one file name for two keys (as two exports' glue objects), 8
    threads at once, 20 rounds: every call gets its own key's object, whatever the other threads
    wrote (a file is written to a temporary one and renamed, and read whole with its key checked)."""
    from fmu_sync import native
    monkeypatch.setattr(native, "cache_dir", lambda: tmp_path)
    errors = []

    def one(k):
        key = f"{k % 2:064x}"
        for _ in range(20):
            native._OBJECTS.pop(key, None)          # this process's copy forgotten: the disk is read
            got = native.cached_object(key, "c-shared.o", lambda: key.encode() * 2000)
            if got != key.encode() * 2000:
                errors.append((k, got[:20]))
    monkeypatch.setattr(native, "_OBJECTS", {})
    threads = [threading.Thread(target=one, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors[:3]
    assert [p.name for p in tmp_path.iterdir()] == ["c-shared.o"]
