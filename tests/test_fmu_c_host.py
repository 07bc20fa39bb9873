"""The exported FMU in a plain C host (tests/c/fmu_host.c): no Python in the host
process, an empty environment (no venv on PATH, no LD_PRELOAD). The stand-in, in
CI, for third-party importers such as Reference-FMUs' fmusim or the FMU
Compliance Checker: the binary must find and start Python itself.

The reference results come from fmpy, run in a child process (no FMU is ever
loaded into the pytest process)."""
from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from _children import unpack_fmu
from fmu_sync.export import export_fmu

FRESH = 50
#: value references of the 1-DOF FMU: tau 0, q 1, u 2, gap 3, impacts 4, percussion 5, energy 6
VR_Q, VR_U, VR_GAP, VR_ENERGY, VR_TAU = 1, 2, 3, 6, 0


def _clean_env(**extra):
    """What a tool-chain user's C importer sees: no venv, no PYTHON*, no LD_PRELOAD."""
    env = {"HOME": os.environ.get("HOME", "/root"), "PATH": "/usr/bin:/bin"}
    for k in ("XDG_CACHE_HOME", "FMU_SYNC_CACHE", "NUMBA_CACHE_DIR", "TMPDIR"):
        if k in os.environ:
            env[k] = os.environ[k]
    env.update(extra)
    return env


@pytest.fixture(scope="module")
def setup(tmp_path_factory, shared_fmu, c_host):
    tmp = tmp_path_factory.mktemp("chost")
    fmu = shared_fmu("impact-oscillator")
    return {"tmp": tmp, "fmu": fmu, "host": c_host, "dir": unpack_fmu(fmu, tmp / "io")}


def _run_host(setup, *args, env=None, dir=None, timeout=120):
    cmd = [str(setup["host"]), str(dir or setup["dir"]), *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env or _clean_env())


def _read_csv(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return np.array([[float(x) for x in r] for r in rows[1:]])


def _fmpy_reference(fmu, tmp, stop, H, tau, names=("q", "u", "gap", "energy"), tau_name="tau"):
    code = (
        "import json, sys\n"
        "from fmpy import simulate_fmu\n"
        "import numpy as np\n"
        f"r = simulate_fmu({str(fmu)!r}, stop_time={stop!r}, output_interval={H!r}, "
        f"start_values={{{tau_name!r}: {tau!r}}}, output={list(names)!r})\n"
        "print(json.dumps({n: r[n].tolist() for n in r.dtype.names}))\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_c_host_fresh_processes_match_fmpy(setup):
    """FRESH fresh C-host processes: every exit code 0, every CSV the same, equal to fmpy's to 1e-12."""
    stop, H, tau = 5.0, 0.01, 0.05
    args = ["--stop", stop, "--step", H, "--set", f"{VR_TAU}={tau}",
            "--var", VR_Q, "--var", VR_U, "--var", VR_GAP, "--var", VR_ENERGY]

    def one(i):
        out = setup["tmp"] / f"run{i}.csv"
        p = _run_host(setup, *args, "--out", out)
        return p.returncode, p.stdout + p.stderr[-1500:], out

    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(one, range(FRESH)))
    bad = [(rc, msg) for rc, msg, _ in results if rc != 0]
    assert not bad, f"{len(bad)} of {FRESH} C-host processes failed: {bad[:2]}"
    first = _read_csv(results[0][2])
    for _, _, out in results[1:]:
        assert np.array_equal(_read_csv(out), first)
    ref = _fmpy_reference(setup["fmu"], setup["tmp"], stop, H, tau)
    assert first.shape == (len(ref["time"]), 5)
    np.testing.assert_allclose(first[:, 0], ref["time"], rtol=0, atol=1e-12)
    for j, name in enumerate(("q", "u", "gap", "energy"), start=1):
        assert np.max(np.abs(first[:, j] - np.array(ref[name]))) <= 1e-12, name
    assert np.ptp(first[:, 1]) > 0.1 and first[:, 3].min() >= -1e-3   # it moved and hit the wall


def test_c_host_two_dof_matches_fmpy(setup, shared_fmu):
    """The 2-DOF FMU (oblique wall) in the C host, against fmpy."""
    fmu = shared_fmu("mechanical-system-2")
    d = setup["tmp"] / "ms2"
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(d)
    from fmpy import read_model_description
    vr = {v.name: v.valueReference for v in read_model_description(str(fmu)).modelVariables}
    names = ["q[1]", "q[2]", "u[1]", "u[2]", "gap", "energy"]
    out = setup["tmp"] / "ms2.csv"
    p = _run_host(setup, "--stop", 5.0, "--step", 0.01, "--set", f"{vr['tau[1]']}=0.1", "--out", out,
                  *[a for n in names for a in ("--var", vr[n])], dir=d)
    assert p.returncode == 0, p.stdout + p.stderr
    got = _read_csv(out)
    ref = _fmpy_reference(fmu, setup["tmp"], 5.0, 0.01, 0.1, names, "tau[1]")
    for j, name in enumerate(names, start=1):
        assert np.max(np.abs(got[:, j] - np.array(ref[name]))) <= 1e-12, name
    assert got[:, 5].min() < 0.05   # it reached the wall


def test_c_host_runs_the_coupling_fmu(setup):
    """The coupling FMU (fmu_sync.fmus.coupling) in the C host: its outputs read right after
    fmi2SetReal of the inputs (direct feedthrough, before any doStep) and after a doStep equal
    the core's coupling_forces and quotient_distance."""
    from fmpy import read_model_description
    from fmu_sync.core import ImpactOscillator
    from fmu_sync.core.coupling import coupling_forces
    from fmu_sync.core.distance import quotient_distance
    from fmu_sync.export import export_coupling
    fmu = export_coupling(setup["tmp"] / "coupling.fmu", start_values={"Q": 3.0, "e": 0.9})
    d = setup["tmp"] / "coupling"
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(d)
    vr = {v.name: v.valueReference for v in read_model_description(str(fmu)).modelVariables}
    x1, x2 = (0.02, -0.8), (0.05, 0.6)            # on either side of an impact: not branch E
    system = ImpactOscillator(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
    names = ["tau[1]", "tau[2]", "d[1]", "euclidean[1]"]
    inputs = {"q[1]": x1[0], "q[2]": x2[0], "u[1]": x1[1], "u[2]": x2[1]}
    out = setup["tmp"] / "coupling.csv"
    p = _run_host(setup, "--stop", 0.02, "--step", 0.01, "--input-first", "--out", out,
                  *[a for k, v in inputs.items() for a in ("--input", f"{vr[k]}={v!r}")],
                  *[a for n in names for a in ("--var", vr[n])], dir=d)
    assert p.returncode == 0, p.stdout + p.stderr
    got = _read_csv(out)
    t1, t2 = coupling_forces(system, x1, x2, "switching", 1.0, 0.5, Q=3.0)
    dist = quotient_distance(system, x1, x2, Q=3.0, full=True)
    assert dist.branch != "E"
    for row in got:                                   # row 0: read after setReal, no doStep
        assert np.max(np.abs(row[1:4] - [t1[0], t2[0], dist.d])) <= 1e-15


@pytest.mark.parametrize("form", ["encoded", "raw_utf8", "file_colon_slash", "localhost"])
def test_resources_folder_with_cafe_and_plus(setup, form):
    """A folder named 'café +dir': percent-encoded, raw UTF-8, file:/ and file://localhost URIs."""
    d = setup["tmp"] / "café +dir" / "io"
    if not d.exists():
        shutil.copytree(setup["dir"], d)
    res = str(d / "resources")
    uri = {"encoded": None, "raw_utf8": "file://" + res, "file_colon_slash": "file:" + res,
           "localhost": "file://localhost" + res.replace(" ", "%20").replace("é", "%C3%A9")}[form]
    extra = ["--uri", uri] if uri else []
    out = setup["tmp"] / f"cafe_{form}.csv"
    p = _run_host(setup, "--stop", 1.0, "--var", VR_Q, "--out", out, *extra, dir=d)
    assert p.returncode == 0, p.stdout + p.stderr
    assert _read_csv(out).shape == (101, 2)


@pytest.mark.parametrize("args, rc, words", [
    (["--guid", "{wrong}"], 3, ["GUID '{wrong}' does not match"]),
    (["--type", "0"], 3, ["Model Exchange", "Co-Simulation only"]),
    (["--uri", "file:///nonexistent/resources"], 3, ["is not a folder"]),
    (["--uri", "file:///bad%zzescape"], 3, ["bad percent-encoding"]),
    (["--uri", "file://otherhost/x"], 3, ["only local files"]),
])
def test_c_host_instantiate_refusals(setup, args, rc, words):
    p = _run_host(setup, "--stop", 0.1, *args)
    assert p.returncode == rc, p.stdout + p.stderr
    assert "instantiate NULL" in p.stdout
    log = [ln for ln in p.stderr.splitlines() if ln.startswith("LOG 3 logStatusError")]
    assert log and all(w in log[0] for w in words), p.stderr


def test_c_host_refused_calls_return_error_and_discard(setup):
    """A refused parameter and a step that can never complete: fmi2Error, reason logged even with logging off."""
    p = _run_host(setup, "--stop", 0.02, "--step", 0.01, "--set", "14=1.5", "--nolog")  # vr 14: e
    assert p.returncode == 1
    assert "status fmi2SetReal 3" in p.stdout
    assert "parameter e = 1.5 rejected: must be finite, >= 0 and <= 1" in p.stderr
    p = _run_host(setup, "--stop", 1e6, "--step", 1e6)
    assert "status fmi2DoStep 3" in p.stdout
    assert "1e+09 internal steps" in p.stderr


def test_rss_does_not_grow_over_1000_instances(setup):
    """1000 instantiate / doStep / logged refusal / free cycles in one C process: RSS grows < 1 MB after 20."""
    p = _run_host(setup, "--cycles", 1000, "--step", 0.01, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr[-2000:]
    vals = dict(line.split() for line in p.stdout.splitlines() if line.startswith("rss_kb"))
    growth = int(vals["rss_kb_after_1000"]) - int(vals["rss_kb_after_20"])
    assert growth < 1024, f"RSS grew by {growth} kB from cycle 20 to 1000"
    assert p.stderr.count("unknown value reference 4294967295") == 1000   # each cycle logged one message


def test_python_override_variable(setup, tmp_path):
    """FMU_SYNC_PYTHON chooses the interpreter; one without numpy gives a clear error, no crash."""
    p = _run_host(setup, "--stop", 0.1, env=_clean_env(FMU_SYNC_PYTHON=sys.executable))
    assert p.returncode == 0, p.stdout + p.stderr
    p = _run_host(setup, "--stop", 0.1, env=_clean_env(FMU_SYNC_PYTHON="/nonexistent/python"))
    assert p.returncode == 3 and "FMU_SYNC_PYTHON = /nonexistent/python" in p.stderr
    bare = tmp_path / "bare"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(bare)], check=True, timeout=120)
    p = _run_host(setup, "--stop", 0.1, env=_clean_env(FMU_SYNC_PYTHON=str(bare / "bin" / "python")))
    assert p.returncode == 3, p.stdout + p.stderr
    assert "lacks numpy" in p.stderr and "numba" not in p.stderr and "FMU_SYNC_PYTHON" in p.stderr


@pytest.mark.parametrize("scheme", ["exact", "midpoint"])
def test_c_host_fmi3_early_return_and_event_mode_match_fmpy(setup, scheme):
    """The FMI 3.0 FMU in the C host (fresh processes, empty environment) with early
    return and event mode: the rows (grid points, and each impact twice: before and
    after event mode) equal fmpy's simulate_fmu with the same options."""
    start = {"k": 0.0, "f0": -9.81, "F": 0.0, "e": 0.8} if scheme == "exact" else {}
    fmu = export_fmu("impact-oscillator", setup["tmp"] / f"io3_{scheme}.fmu", {**start, "solver.scheme": scheme},
                     fmi_version=3)
    d = setup["tmp"] / f"io3_{scheme}"
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(d)
    os.chmod(next(d.glob("binaries/x86_64-linux/*.so")), 0o755)
    stop, H = 4.0, 0.01
    outs = []
    for i in range(3):
        out = setup["tmp"] / f"fmi3_{scheme}_{i}.csv"
        p = _run_host(setup, "--fmi3", "--early-return", "--event-mode", "--stop", stop, "--step", H,
                      "--var", VR_Q, "--var", VR_U, "--out", out, dir=d)
        assert p.returncode == 0, p.stdout + p.stderr[-1500:]
        outs.append(_read_csv(out))
    assert all(np.array_equal(o, outs[0]) for o in outs[1:])
    code = ("import json\nfrom fmpy import simulate_fmu\n"
            f"r = simulate_fmu({str(fmu)!r}, stop_time={stop!r}, output_interval={H!r}, output=['q', 'u'], "
            "early_return_allowed=True, use_event_mode=True)\n"
            "print(json.dumps({n: r[n].tolist() for n in r.dtype.names}))\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    ref = json.loads(p.stdout.strip().splitlines()[-1])
    got = outs[0]
    assert got.shape == (len(ref["time"]), 3) and len(ref["time"]) > int(stop / H) + 1   # early-return rows
    assert np.max(np.abs(got[:, 0] - np.array(ref["time"]))) <= 1e-12
    assert np.max(np.abs(got[:, 1] - np.array(ref["q"]))) <= 1e-12
    assert np.max(np.abs(got[:, 2] - np.array(ref["u"]))) <= 1e-12
