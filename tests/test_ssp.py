"""The coupling FMU and the SSP package (docs/ssp.md): schema validity, the coupling
FMU's outputs against the core, libcosim and fmpy's SSP runner running the package,
and our master reproducing each one's exchange order.

As in tests/test_fmu_run.py, every FMU is loaded in a child process
(``python tests/test_ssp.py SCENARIO ARGS.json RESULT.json``), never in pytest's.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

SCHEMA = "SystemStructureDescription.xsd", "SystemStructureParameterValues.xsd"


# =============================================================== child side
def _slave(fmu, name):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    md = read_model_description(fmu, validate=True)
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=name)
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    return s, {v.name: v.valueReference for v in md.modelVariables}, md


def scenario_outputs(a):
    """Set the coupling FMU's inputs and read its outputs, before (feedthrough) and after a doStep."""
    out = {}
    for key, case in a["cases"].items():
        s, vr, md = _slave(case["fmu"], key)
        ins = [v.name for v in md.modelVariables if v.causality == "input"]
        reals = [v.name for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
        ints = [v.name for v in md.modelVariables if v.causality == "output" and v.type == "Integer"]
        rows, t = [], 0.0
        for x in case["inputs"]:
            s.setReal([vr[n] for n in ins], x)
            peek = dict(zip(reals, s.getReal([vr[n] for n in reals])))
            peek.update(zip(ints, s.getInteger([vr[n] for n in ints])))
            s.doStep(t, 0.01)
            t += 0.01
            after = dict(zip(reals, s.getReal([vr[n] for n in reals])))
            rows.append({"peek": peek, "after": after})
            if len(rows) == 1:   # save the FMU state after the first row (and as bytes)
                saved = s.getFMUstate()
                blob = s.serializeFMUstate(saved)
        s.setFMUstate(saved)
        restored = s.getReal([vr[n] for n in reals])
        s.setFMUstate(s.deSerializeFMUstate(blob))
        rows.append({"restored": dict(zip(reals, restored)),
                     "deserialized": dict(zip(reals, s.getReal([vr[n] for n in reals])))})
        s.freeFMUstate(saved)
        s.terminate()
        s.freeInstance()
        out[key] = {"inputs": ins, "rows": rows}
    return out


def scenario_overflow(a):
    """A coupling FMU whose forces exceed what the systems accept (Kp = 1e6 on inputs 1e12 apart: |tau| =
    2e18 > contract.INPUT_BOUND): the doStep's status and log."""
    from fmu_sync.fmi_bridge import FMUHost
    with FMUHost(a["fmu"], "overflow") as h:
        h.enter_initialization(0.0)
        h.exit_initialization({"Kp": 1e6, "Kd": 0.0})
        h.set({"q[1]": 1e12, "q[2]": -1e12})
        status = h.do_step(0.0, 0.01)
        return {"status": status, "log": h.errors()}


def scenario_validate(a):
    """fmpy's validation of every FMU inside the packages."""
    from fmpy.validation import validate_fmu
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for pkg in a["packages"]:
            with zipfile.ZipFile(pkg) as zf:
                for name in zf.namelist():
                    if name.endswith(".fmu"):
                        p = Path(tmp, Path(pkg).stem + "_" + Path(name).name)
                        p.write_bytes(zf.read(name))
                        out[f"{Path(pkg).name}:{name}"] = [str(x) for x in validate_fmu(str(p))]
    return out


def _libcosim(path, t_end, record):
    """libcosim runs the package as it is; d of every edge per step, the systems' (q, u) on request."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from fmu_sync.ssp import read_ssp
    log_output_level(CosimLogLevel.ERROR)
    pkg = read_ssp(path)
    ex = CosimExecution.from_ssp_file(path)
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    comps = sorted((c for c in pkg.sources if c.startswith("system")), key=lambda c: int(c[6:]))
    idx = {c: ex.slave_index_from_instance_name(c) for c in comps + ["coupling"]}
    names = {c: {v.name.decode(): v.reference for v in ex.slave_variables(idx[c])} for c in idx}
    dvr = [r for n, r in names["coupling"].items() if n.startswith("d[")]
    D, X = [], []
    for _ in range(int(round(t_end / pkg.H))):
        ex.step(1)
        D.append(obs.last_real_values(idx["coupling"], dvr))
        if record:
            X.append([obs.last_real_values(idx[c], [names[c]["q"], names[c]["u"]]) for c in comps])
    return {"d": D, "x": X}


def scenario_libcosim(a):
    return {key: _libcosim(p, a["t_end"], key == "switching") for key, p in a["packages"].items()}


def scenario_fmpy(a):
    """fmpy's SSP runner, given the package's bindings as its parameter set."""
    from fmpy.ssp.simulation import simulate_ssp
    from fmu_sync.ssp import fmpy_parameter_set
    p = a["package"]
    r = simulate_ssp(p, stop_time=a["t_end"] - a["H"] / 2, step_size=a["H"], parameter_set=fmpy_parameter_set(p))
    bare = simulate_ssp(p, stop_time=2 * a["H"] - a["H"] / 2, step_size=a["H"])   # without the bindings
    return {"x": [[[float(r[f"system{i}.q"][k]), float(r[f"system{i}.u"][k])] for i in (1, 2)]
                  for k in range(len(r))],
            "d": [float(v) for v in r["coupling.d[1]"]],
            "bare_q": [float(bare["system1.q"][0]), float(bare["system2.q"][0])]}


def scenario_master(a):
    """Our master runs the package in each exchange order."""
    from fmu_sync.ssp import run_ssp
    out = {}
    for method in ("jacobi", "delayed", "delayed-zero"):
        r = run_ssp(a["package"], method=method, t_end=a["t_end"])
        out[method] = {"x": [[[float(r.q[k, i, 0]), float(r.u[k, i, 0])] for i in range(2)]
                             for k in range(1, len(r.t))], "d": r.d[:, 0].tolist(), "t": r.t.tolist()}
    return out


def _child_main(argv):
    name, args_path, out_path = argv
    args = json.loads(Path(args_path).read_text())
    Path(out_path).write_text(json.dumps(globals()[f"scenario_{name}"](args)))


# =============================================================== parent side
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from fmu_sync.core import ImpactOscillator, MechanicalSystem  # noqa: E402
from fmu_sync.core.coupling import coupling_forces  # noqa: E402
from fmu_sync.core.distance import quotient_distance  # noqa: E402
from fmu_sync.export import export_coupling  # noqa: E402
from fmu_sync.ssp import run_ssp, write_ssp  # noqa: E402
from _children import child  # noqa: E402

T_SYNC = 60.0          # the claim: d < 1e-6 by t = 60 s
T_CMP = 20.0           # the exchange-order comparisons (a third of the run: enough impacts)
BRANCHES = ("E", "J12", "J21", "J2")
KP, KD, Q = 1.0, 0.5, 3.0
IO = ImpactOscillator(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
MS2 = MechanicalSystem(M=[[2.0, 0.5], [0.5, 1.0]], K=np.eye(2), C=np.zeros((2, 2)), f0=np.zeros(2),
                       w=[1.0, 0.5], g0=0.1, e=0.7)


def _child(name: str, args: dict, tmp: Path, timeout: float = 900.0):
    return child(__file__, name, args, tmp, timeout)


def _states_by_branch(system, rng, per_branch=4, Q_=Q):
    """Random state pairs near the wall until every branch of the distance has per_branch of them."""
    n = system.n
    found = {b: [] for b in BRANCHES}
    for _ in range(200000):
        xs = []
        for _ in range(2):
            u = rng.normal(0.0, 1.0, n)
            q = rng.uniform(-0.5, 0.5, n)
            g = system.gap(q)
            q = q - (g - rng.uniform(0.0, 0.3)) * system.w / float(system.w @ system.w)   # 0 <= gap <= 0.3
            xs.append((q, u))
        b = quotient_distance(system, xs[0], xs[1], Q=Q_, full=True)[1]
        if len(found[b]) < per_branch:
            found[b].append(xs)
        if all(len(v) == per_branch for v in found.values()):
            return found
    raise AssertionError(f"branches not all reached: { {b: len(v) for b, v in found.items()} }")


def _inputs(xs):
    """Input vector q[1..N] (node-major, then dof), u[1..N]: the coupling FMU's order."""
    return [float(a) for x in xs for a in np.ravel(x[0])] + [float(a) for x in xs for a in np.ravel(x[1])]


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("coupling")
    rng = np.random.default_rng(19)
    cases = {}
    for key, system, extra in (("io", IO, {"M": 1.0, "e": 0.9}),
                               ("ms2", MS2, {"M[1,1]": 2.0, "M[1,2]": 0.5, "M[2,1]": 0.5, "M[2,2]": 1.0,
                                             "w[1]": 1.0, "w[2]": 0.5, "g0": 0.1, "e": 0.7})):
        n = system.n
        Qs = {"Q": Q} if n == 1 else {"Q[1,1]": Q, "Q[2,2]": Q}
        Kps = {"Kp": KP, "Kd": KD} if n == 1 else {"Kp[1,1]": KP, "Kp[2,2]": KP, "Kd[1,1]": KD, "Kd[2,2]": KD}
        fmu = export_coupling(tmp / f"{key}.fmu", n=n, start_values={**extra, **Qs, **Kps})
        found = _states_by_branch(system, rng)
        pairs = [xs for b in BRANCHES for xs in found[b]]
        cases[key] = {"fmu": str(fmu), "inputs": [_inputs(xs) for xs in pairs], "pairs": pairs,
                      "branches": [b for b in BRANCHES for _ in found[b]], "system": system}
    # a ring of 5 with a law per edge and unequal weights
    A = np.array([[0, 1.0, 0, 0, 0.5], [2.0, 0, 1, 0, 0], [0, 1, 0, 0.7, 0], [0, 0, 1.3, 0, 1], [1, 0, 0, 1, 0]])
    laws = ["switching", "euclidean", "none", "switching", "switching"]   # edges (1,2) (1,5) (2,3) (3,4) (4,5)
    ring = export_coupling(tmp / "ring.fmu", A, 1, {"M": 1.0, "e": 0.9, "Q": Q, "Kp": KP, "Kd": KD,
                                                    **{f"law[{k + 1}]": x for k, x in enumerate(laws)}})
    states = [[(rng.uniform(0, 0.3, 1), rng.normal(0, 1, 1)) for _ in range(5)] for _ in range(8)]
    cases["ring"] = {"fmu": str(ring), "inputs": [_inputs(xs) for xs in states], "states": states,
                     "A": A, "laws": laws}
    args = {"cases": {k: {"fmu": c["fmu"], "inputs": c["inputs"]} for k, c in cases.items()}}
    return cases, _child("outputs", args, tmp)


@pytest.mark.parametrize("key", ["io", "ms2"])
def test_coupling_fmu_outputs_equal_the_core(fmus, key):
    """tau, d, branch and the Euclidean error, read right after setting the inputs (direct
    feedthrough) and after a doStep, equal the core's coupling_forces / quotient_distance
    to 1e-15 on every branch."""
    cases, got = fmus
    case, rows = cases[key], got[key]["rows"]
    n = case["system"].n
    names = ["tau[1]", "tau[2]"] if n == 1 else ["tau[1,1]", "tau[1,2]", "tau[2,1]", "tau[2,2]"]
    assert rows[-1]["restored"] == rows[-1]["deserialized"] == rows[0]["after"]   # FMU state: inputs and outputs
    seen = set()
    for (x1, x2), b, row in zip(case["pairs"], case["branches"], rows):
        t1, t2 = coupling_forces(case["system"], x1, x2, "switching", KP, KD, Q=Q)
        d, branch = quotient_distance(case["system"], x1, x2, Q=Q, full=True)[:2]
        eu = np.sqrt(np.sum(Q * (x1[0] - x2[0]) ** 2) + (x1[1] - x2[1]) @ case["system"].M @ (x1[1] - x2[1]))
        for r in (row["peek"], row["after"]):
            assert np.max(np.abs(np.array([r[k] for k in names]) - np.concatenate([t1, t2]))) <= 1e-15
            assert abs(r["d[1]"] - d) <= 1e-15
            assert abs(r["V[1]"] - 0.5 * d * d) <= 1e-15
            assert abs(r["euclidean[1]"] - eu) <= 1e-14 * max(1.0, eu)
        assert BRANCHES[row["peek"]["branch[1]"]] == branch == b
        seen.add(branch)
    assert seen == set(BRANCHES)


def test_a_failed_coupling_step_speaks_of_the_coupling(fmus, tmp_path):
    """A doStep whose coupling forces exceed the systems' input bound is fmi2Error with a reason about
    the coupling's outputs, not the mechanical models' state bounds or solver.dt."""
    cases, _ = fmus
    got = _child("overflow", {"fmu": cases["io"]["fmu"]}, tmp_path)
    assert got["status"] == 3, got
    msg = got["log"][-1]
    assert "rolled back" in msg and "outputs computed from the current inputs are not finite" in msg
    assert "exceeds |tau| <= 1e+12" in msg
    assert "solver.dt" not in msg and "|q|" not in msg


def test_coupling_fmu_network_sums_the_edges(fmus):
    """A ring of 5, a law per edge, unequal weights: tau_i = sum_j a_ij tau_i^(j) of the core's pairwise law."""
    cases, got = fmus
    case = cases["ring"]
    from fmu_sync.core.network import edges_of
    edges = edges_of(case["A"])
    for xs, row in zip(case["states"], got["ring"]["rows"]):
        tau = np.zeros(5)
        for (i, j), law in zip(edges, case["laws"]):
            t1, t2 = coupling_forces(IO, xs[i], xs[j], law, KP, KD, Q=Q)
            tau[i] += case["A"][i, j] * t1[0]
            tau[j] += case["A"][j, i] * t2[0]
        for r in (row["peek"], row["after"]):
            np.testing.assert_allclose([r[f"tau[{i + 1}]"] for i in range(5)], tau, rtol=0, atol=1e-15)
            for k, (i, j) in enumerate(edges):
                assert r[f"d[{k + 1}]"] == pytest.approx(quotient_distance(IO, xs[i], xs[j], Q=Q), abs=1e-15)


# ---------------------------------------------------------------- the package
@pytest.fixture(scope="module")
def packages(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ssp")
    t = {"run.t_end": T_SYNC}
    pk = {"switching": write_ssp("forced-pair", tmp / "pair.ssp", "switching", t),
          "uncoupled": write_ssp("forced-pair", tmp / "uncoupled.ssp", "uncoupled", t),
          "ring": write_ssp("ring-8", tmp / "ring8.ssp", None, t)}
    return tmp, {k: str(v) for k, v in pk.items()}


def test_package_is_valid_against_the_ssp_schema(packages):
    from lxml import etree
    import fmpy
    schema_dir = Path(fmpy.__file__).parent / "ssp" / "schema"
    ssd, ssv = (etree.XMLSchema(file=str(schema_dir / f)) for f in SCHEMA)
    for p in packages[1].values():
        with zipfile.ZipFile(p) as zf:
            names = zf.namelist()
            assert "SystemStructure.ssd" in names
            for name in names:
                if name.endswith((".ssd", ".ssv")):
                    schema = ssd if name.endswith(".ssd") else ssv
                    assert schema.validate(etree.fromstring(zf.read(name))), (p, name, str(schema.error_log))
    with zipfile.ZipFile(packages[1]["ring"]) as zf:
        ssd_text = zf.read("SystemStructure.ssd").decode()
        fmus_inside = [n for n in zf.namelist() if n.endswith(".fmu")]
    assert ssd_text.count("<ssd:Component ") == 9 and ssd_text.count("<ssd:Connection ") == 24
    assert len(fmus_inside) == 9   # one oscillator FMU file per system (its start values), the coupling


@pytest.mark.slow
def test_every_fmu_inside_passes_fmpy_validation(packages):
    tmp, pk = packages
    res = _child("validate", {"packages": list(pk.values())}, tmp)
    assert len(res) == 2 + 2 + 8 + 3 and all(v == [] for v in res.values()), res   # systems + couplings


@pytest.fixture(scope="module")
def libcosim(packages):
    tmp, pk = packages
    return _child("libcosim", {"packages": pk, "t_end": T_SYNC}, tmp)


@pytest.mark.slow
def test_libcosim_runs_the_package_and_synchronizes(libcosim):
    d = np.array(libcosim["switching"]["d"])[:, 0]
    assert d[-1] < 1e-6 and np.max(d[-100:]) < 1e-6
    du = np.array(libcosim["uncoupled"]["d"])[:, 0]
    assert np.max(du[-1000:]) > 1e-2          # the uncoupled pair does not synchronize
    dr = np.array(libcosim["ring"]["d"])
    assert dr.shape[1] == 8 and np.max(dr[-1]) < 1e-6 < np.max(dr[0])


@pytest.fixture(scope="module")
def master(packages):
    tmp, pk = packages
    return _child("master", {"package": pk["switching"], "t_end": T_CMP}, tmp)


@pytest.mark.slow
def test_master_in_libcosims_order_reproduces_libcosim(libcosim, master):
    lc = np.array(libcosim["switching"]["x"])[: int(round(T_CMP / 0.01))]
    ours = np.array(master["delayed"]["x"])
    assert ours.shape == lc.shape
    assert np.max(np.abs(ours - lc)) <= 1e-9
    assert np.max(np.abs(np.array(master["jacobi"]["x"]) - lc)) > 1e-3   # the order matters


@pytest.mark.slow
def test_fmpy_runs_the_package_and_our_master_reproduces_it(packages, master):
    tmp, pk = packages
    fm = _child("fmpy", {"package": pk["switching"], "t_end": T_CMP, "H": 0.01}, tmp)
    x = np.array(fm["x"])
    ours = np.array(master["delayed-zero"]["x"])
    assert ours.shape == x.shape
    assert np.max(np.abs(ours - x)) <= 1e-9
    assert fm["d"][-1] < 1e-2 * fm["d"][1]
    # without the bindings fmpy's runner starts every system at its FMU's own start state: the scene's
    assert abs(fm["bare_q"][0] - fm["bare_q"][1]) > 0.5


@pytest.mark.slow
def test_run_ssp_refuses_a_coupling_geometry_that_differs(packages, tmp_path):
    """An edited package whose coupling e is not the systems' is refused before any run."""
    src = packages[1]["switching"]
    bad = tmp_path / "bad.ssp"
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(bad, "w") as zout:
        for item in zin.namelist():
            data = zin.read(item)
            if item == "resources/coupling.ssv":
                data = data.replace(b'name="e">\n      <ssv:Real value="0.9"', b'name="e">\n      <ssv:Real value="0.8"')
                assert b'value="0.8"' in data
            zout.writestr(item, data)
    with pytest.raises(ValueError, match="e differs"):
        run_ssp(bad)


@pytest.mark.parametrize("scene, variant, words", [
    ("forced-pair", None, ["variants uncoupled, euclidean, switching", "--variant"]),
    ("forced-pair", "nonesuch", ["no variant 'nonesuch'"]),
    ("bouncing-ball", None, ["single system"]),
])
def test_write_ssp_refuses_what_is_not_a_coupled_variant(tmp_path, scene, variant, words):
    with pytest.raises(ValueError) as exc:
        write_ssp(scene, tmp_path / "x.ssp", variant)
    assert all(w in str(exc.value) for w in words), str(exc.value)
    assert not list(tmp_path.iterdir())


def test_write_ssp_refuses_a_wrong_suffix(tmp_path):
    with pytest.raises(ValueError, match="must end in .ssp"):
        write_ssp("forced-pair", tmp_path / "x.zip", "switching")


def test_cli_export_coupling_lists_a_network_interface(capsys):
    from fmu_sync.export import main_export
    assert main_export(["coupling", "--nodes", "8", "--graph", "ring", "--list"]) == 0
    out = capsys.readouterr().out.splitlines()
    names = [line.split()[0] for line in out]
    assert names[:8] == [f"q[{i}]" for i in range(1, 9)] and "tau[8]" in names and "d[8]" in names
    assert "law[8]" in names and "a[8,1]" in names and "d[9]" not in names
    assert main_export(["impact-oscillator", "--nodes", "3", "--list"]) == 2
    assert "--nodes and --dof are options of the coupling FMU" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_runs_a_package_in_our_master(packages, tmp_path):
    """``fmu-sync run FILE.ssp --method delayed`` (in a child process): the record is written."""
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "fmu_sync.cli", "run", packages[1]["switching"], "--method",
                        "delayed", "-o", str(out), "--quiet"], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "method delayed" in p.stdout and "t_sync(1e-6)" in p.stdout
    rec = np.load(out / "result.npz")
    assert rec["d"].shape == (int(T_SYNC / 0.01) + 1, 1) and rec["d"][-1, 0] < 1e-6



def test_a_package_run_writes_what_a_scene_run_writes(tmp_path):
    """``fmu-sync run pair.ssp -o D`` (a child process): a record that ``fmu_sync.load`` reads with
    its ``meta``, the network plots, a summary; ``fmu-sync plot D`` draws them again (issue 28)."""
    import fmu_sync
    from fmu_sync.results import load_meta
    pkg = write_ssp("forced-pair", tmp_path / "pair.ssp", "switching", {"run.t_end": 2.0})
    out = tmp_path / "D"
    p = subprocess.run([sys.executable, "-m", "fmu_sync.cli", "run", str(pkg), "-o", str(out), "--quiet"],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    r = fmu_sync.load(out / "result.npz")
    assert r.q.shape == (201, 2, 1) and r.edges == [(0, 1)] and r.impacts is not None
    meta = load_meta(out / "result.npz")
    assert meta["title"] == "pair.ssp" and meta["settings"]["method"] == "jacobi" and meta["wall"]["g0"] == 0.0
    assert np.array_equal(fmu_sync.load(out / "result.csv").d, r.d)
    summary = (out / "summary.md").read_text()
    assert summary.startswith("# Package `pair.ssp`") and "result-distance.png" in summary
    pngs = sorted(f.name for f in out.glob("*.png"))
    assert pngs == ["result-distance.png", "result-lyapunov.png", "result-positions.png"]
    for f in out.glob("*.png"):
        f.unlink()
    p = subprocess.run([sys.executable, "-m", "fmu_sync.cli", "plot", str(out)], capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    assert sorted(f.name for f in out.glob("*.png")) == pngs

if __name__ == "__main__":
    _child_main(sys.argv[1:])
