"""The SSP package in masters other than ours (docs/ssp.md): OMSimulator and libcosim run it at
its own step with no API call, and a master that ignores the package's bindings (fmpy's
``simulate_ssp`` without ``parameter_set``) still starts the systems where the scene does.

OMSimulator is not on PyPI in a usable form: the tests that need it run where
``FMU_SYNC_OMSIMULATOR`` names the folder its install archive was unpacked into (``.ci/run``
unpacks ``../shared/tools/omsimulator-install.tgz`` when it is there) or where ``OMSimulator``
is importable, and skip elsewhere, saying why. As in tests/test_ssp.py every FMU is loaded in a
child process (``python tests/test_other_masters.py SCENARIO ARGS.json RESULT.json``).
"""
from __future__ import annotations

import json
import os
import sys
import zipfile
from pathlib import Path

ENV = "FMU_SYNC_OMSIMULATOR"


def oms_path() -> str | None:
    """The folder holding OMSimulator's Python package: from ``$FMU_SYNC_OMSIMULATOR`` (the
    folder the install archive was unpacked into, or its install prefix), else None."""
    root = os.environ.get(ENV)
    if not root:
        return None
    for cand in (Path(root) / "install" / "lib" / "x86_64-linux-gnu", Path(root) / "lib" / "x86_64-linux-gnu",
                 Path(root)):
        if (cand / "OMSimulator" / "__init__.py").is_file():
            return str(cand)
    return None


# =============================================================== child side
def _dsres(path):
    """A Modelica result file (.mat, dsres layout) as {name: (times, values)} of its series."""
    import numpy as np
    import scipy.io
    m = scipy.io.loadmat(path, chars_as_strings=False)
    raw = m["name"]
    names = ["".join(raw[:, j]).rstrip("\x00 ") for j in range(raw.shape[1])]
    info, data = m["dataInfo"], m["data_2"]
    t = data[0]
    out = {}
    for j, name in enumerate(names):
        if info[0, j] == 2:
            col = int(info[1, j])
            out[name] = np.sign(col) * data[abs(col) - 1]
    return t, out


def scenario_omsimulator(a):
    """OMSimulator runs the package as it is: no setFixedStepSize, no setStopTime."""
    sys.path.insert(0, a["oms"])
    from OMSimulator import SSP
    res = str(Path(a["tmp"]) / "oms.mat")
    m = SSP(a["package"]).instantiate()
    m.setResultFile(res)
    m.initialize()
    m.simulate()
    m.terminate()
    m.delete()
    t, series = _dsres(res)
    return {"t": t.tolist(), **{k: v.tolist() for k, v in series.items()
                                if k.rsplit(".", 1)[-1] in ("q", "u") or ".coupling.d[" in k}}


def scenario_libcosim(a):
    """libcosim steps the package with no step size given: its clock after each step."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    log_output_level(CosimLogLevel.ERROR)
    ex = CosimExecution.from_ssp_file(a["package"])
    times = []
    for _ in range(a["steps"]):
        ex.step(1)
        times.append(ex.status().current_time * 1e-9)
    return {"t": times}


def scenario_fmpy_bare(a):
    """fmpy's runner with its defaults: no parameter_set (the bindings are ignored), no step size."""
    from fmpy.ssp.simulation import simulate_ssp
    r = simulate_ssp(a["package"], stop_time=a["t_end"])
    return {"q": [float(r["system1.q"][0]), float(r["system2.q"][0])],
            "u": [float(r["system1.u"][0]), float(r["system2.u"][0])]}


def _child_main(argv):
    name, args_path, out_path = argv
    args = json.loads(Path(args_path).read_text())
    Path(out_path).write_text(json.dumps(globals()[f"scenario_{name}"](args)))


# =============================================================== parent side
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from fmu_sync.ssp import NS, SSD, SsdError, read_ssp, run_ssp, write_ssp  # noqa: E402
from _children import child  # noqa: E402

T = 10.0      # long enough for impacts of both systems and the coupling to act
H = 0.01


def _child(name: str, args: dict, tmp: Path, timeout: float = 900.0):
    return child(__file__, name, args, tmp, timeout)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("masters")
    return tmp, write_ssp("forced-pair", tmp / "pair.ssp", "switching", {"run.t_end": T, "run.H": H})


def test_the_package_names_its_step_for_omsimulator_and_libcosim(pair):
    """The system carries OMSimulator's fixed-step solver with H, every component its solver's name."""
    from xml.etree import ElementTree as ET
    with zipfile.ZipFile(pair[1]) as zf:
        root = ET.fromstring(zf.read(SSD))
    q = lambda p, t: f"{{{NS[p]}}}{t}"   # noqa: E731
    system = root.find(q("ssd", "System"))
    info = system.find(f"{q('ssd', 'Annotations')}/{q('ssc', 'Annotation')}[@type='org.openmodelica']//"
                       f"{q('oms', 'SimulationInformation')}")
    assert info is not None and info.attrib == {"name": "fixedstep", "method": "oms_ma", "fixedStepSize": "0.01"}
    comps = system.findall(f"{q('ssd', 'Elements')}/{q('ssd', 'Component')}")
    assert len(comps) == 3
    for c in comps:
        ci = c.find(f"{q('ssd', 'Annotations')}//{q('oms', 'SimulationInformation')}")
        assert ci is not None and ci.attrib == {"name": "fixedstep"}, c.get("name")
    assert read_ssp(pair[1]).H == H


def test_a_package_with_two_different_steps_is_refused(pair, tmp_path):
    bad = tmp_path / "bad.ssp"
    with zipfile.ZipFile(pair[1]) as zin, zipfile.ZipFile(bad, "w") as zout:
        for item in zin.namelist():
            data = zin.read(item)
            if item == SSD:
                data = data.replace(b'fixedStepSize="0.01"', b'fixedStepSize="0.001"')
            zout.writestr(item, data)
    with pytest.raises(SsdError, match=r"two different communication steps.*0\.01.*0\.001"):
        read_ssp(bad)


def test_each_system_fmu_starts_where_the_scene_does_and_our_master_refuses_two_models(pair, tmp_path):
    """One FMU file per system with that system's start state; our master still runs one model and
    refuses systems' FMUs that differ in what no binding sets."""
    from fmu_sync.export import export_fmu
    from fmu_sync.scenes.loading import as_scene
    v = as_scene("forced-pair").variant("switching")
    starts = []
    with zipfile.ZipFile(pair[1]) as zf:
        for i in (1, 2):
            with zipfile.ZipFile(__import__("io").BytesIO(zf.read(f"resources/system{i}.fmu"))) as fz:
                s = json.loads(fz.read("resources/fmu_sync_start.json"))["start"]
            starts.append((s["q_start"], s["u_start"]))
    assert starts == [tuple(map(float, v.x1)), tuple(map(float, v.x2))] and starts[0] != starts[1]
    other = export_fmu("impact-oscillator", tmp_path / "theta.fmu", {"solver.scheme": "theta"})
    bad = tmp_path / "two-models.ssp"
    with zipfile.ZipFile(pair[1]) as zin, zipfile.ZipFile(bad, "w") as zout:
        for item in zin.namelist():
            zout.writestr(item, other.read_bytes() if item == "resources/system2.fmu" else zin.read(item))
    with pytest.raises(SsdError, match="solver.scheme"):
        run_ssp(bad)


@pytest.mark.slow
def test_fmpy_without_bindings_or_step_still_starts_the_systems_apart(pair):
    """fmpy's defaults (no parameter_set, step stop_time/100) cannot run the scene as a synchronized
    pair from t = 0: its FMUs' own start values are the scene's."""
    from fmu_sync.scenes.loading import as_scene
    v = as_scene("forced-pair").variant("switching")
    r = _child("fmpy_bare", {"package": str(pair[1]), "t_end": 1.0}, pair[0])
    # fmpy's first record is after its first step (1/100 of the run here)
    assert r["q"] == pytest.approx([float(v.x1[0]), float(v.x2[0])], abs=0.02)
    assert r["u"] == pytest.approx([float(v.x1[1]), float(v.x2[1])], abs=0.02)
    assert abs(r["q"][0] - r["q"][1]) > 0.5


@pytest.mark.slow
def test_libcosim_steps_at_the_packages_step_with_no_step_given(pair):
    r = _child("libcosim", {"package": str(pair[1]), "steps": 50}, pair[0])
    assert np.allclose(r["t"], H * np.arange(1, 51), rtol=0, atol=1e-9)


@pytest.mark.slow
def test_omsimulator_runs_the_package_at_its_step_and_equals_our_jacobi(pair):
    """OMSimulator (where installed) with no API call but the result file: its stop time and step are
    the package's, and its oms_ma order is our undelayed Jacobi exchange (q, u, d to 1e-9)."""
    path = oms_path()
    if path is None:
        pytest.skip(f"OMSimulator is not installed: set {ENV} to the folder its install archive was "
                    f"unpacked into (.ci/run does it when ../shared/tools/omsimulator-install.tgz exists)")
    r = _child("omsimulator", {"oms": path, "package": str(pair[1]), "tmp": str(pair[0])}, pair[0])
    t = np.array(r["t"])
    k = np.rint(t / H).astype(int)                        # its clock adds H up: equal to k H to 1e-9
    assert np.max(np.abs(t - k * H)) < 1e-9 and np.array_equal(np.unique(k), np.arange(int(T / H) + 1))
    ours = run_ssp(pair[1], method="jacobi")
    last = np.array([np.flatnonzero(k == j)[-1] for j in np.unique(k)])   # it writes a step's row twice
    for i in (1, 2):
        for k, x in enumerate(("q", "u")):
            theirs = np.array(r[f"forced-pair.system{i}.{x}"])[last]
            assert np.max(np.abs(theirs - ours_col(ours, x, i - 1))) < 1e-9, (i, x)
    d = np.array(r["forced-pair.coupling.d[1]"])[last]
    assert np.max(np.abs(d[1:] - ours.d[1:, 0])) < 1e-9


def ours_col(res, x, i):
    return getattr(res, x)[:, i, 0]


if __name__ == "__main__":
    _child_main(sys.argv[1:])
