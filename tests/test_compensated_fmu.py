"""The compensated switching law through the coupling FMU and in an SSP package (docs/design.md
§2.5.2, docs/ssp.md): law code 3 with the systems' force law as the coupling FMU's parameters.

Two system FMUs and the coupling FMU, driven by fmpy in Jacobi order at H = dt (each system's
(q, u) into the coupling, its tau back, then every doStep), give the core's
``simulate_pair(..., coupling="switching-compensated")`` to round-off; the bouncing balls keep
V non-increasing through it. The FMUs are the ones inside one written package (one export for
the module). As in tests/test_ssp.py, every FMU is loaded in a child process
(``python tests/test_compensated_fmu.py SCENARIO ARGS.json RESULT.json``).
"""
from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path


# =============================================================== child side
def jacobi(system_fmu, coupling_fmu, systems, coupling, H, steps):
    """Rows ``[t, q1, u1, q2, u2, tau1, tau2, d]``: at each communication point the systems' (q, u)
    into the coupling FMU, its tau (computed from them, held over the step) into the systems, then
    every doStep(t, H). ``systems``: each instance's start values; ``coupling``: the coupling's."""
    from fmu_sync.fmi_bridge import FMUHost
    hosts = [FMUHost(system_fmu, f"system{i + 1}") for i in range(2)] + [FMUHost(coupling_fmu, "coupling")]
    try:
        for h, values in zip(hosts, systems + [coupling]):
            assert h.initialize(0.0, values) == 0, h.errors()
        s1, s2, c = (h.fmu for h in hosts)
        xs = [[h.vr("q"), h.vr("u")] for h in hosts[:2]]
        ts = [h.vr("tau") for h in hosts[:2]]
        cin = [hosts[2].vr(k) for k in ("q[1]", "q[2]", "u[1]", "u[2]")]
        cout = [hosts[2].vr(k) for k in ("tau[1]", "tau[2]", "d[1]")]
        rows = []
        for k in range(steps + 1):
            t = k * H
            x1, x2 = s1.getReal(xs[0]), s2.getReal(xs[1])
            c.setReal(cin, [x1[0], x2[0], x1[1], x2[1]])
            tau1, tau2, d = c.getReal(cout)
            rows.append([t, x1[0], x1[1], x2[0], x2[1], tau1, tau2, d])
            if k == steps:
                break
            s1.setReal([ts[0]], [tau1])
            s2.setReal([ts[1]], [tau2])
            for s in (s1, s2, c):
                s.doStep(t, H)
        return rows
    finally:
        for h in hosts:
            h.close()


def scenario_drive(a):
    return {key: jacobi(a["system"], a["coupling"], r["systems"], r["coupling"], r["H"], r["steps"])
            for key, r in a["runs"].items()}


def scenario_refused(a):
    """A coupling FMU of n = 2 given law[1] = switching-compensated: exitInitializationMode's status and log."""
    from fmu_sync.fmi_bridge import FMUHost
    with FMUHost(a["fmu"], "refused") as h:
        h.enter_initialization(0.0)
        status = h.exit_initialization({"law[1]": 3})
        return {"status": status, "log": h.errors()}


def _child_main(argv):
    name, args_path, out_path = argv
    args = json.loads(Path(args_path).read_text())
    Path(out_path).write_text(json.dumps(globals()[f"scenario_{name}"](args)))


if __name__ == "__main__":
    _child_main(sys.argv[1:])
    sys.exit(0)


# =============================================================== parent side
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from fmu_sync.core import ImpactOscillator, simulate_pair  # noqa: E402
from fmu_sync.core.coupling import LAWS, energy_metric  # noqa: E402
from _children import child  # noqa: E402

LAW = "switching-compensated"
BALL = dict(m=1.0, k=0.0, c=0.0, f0=-9.81, F=0.0, Omega=0.0, phi=0.0, e=0.8)
FORCED = dict(m=1.0, k=1.0, c=0.05, f0=-0.5, F=0.5, Omega=2.5, phi=0.3, e=0.9)   # h depends on t
#: (system, x1, x2, Kp, Kd, dt, t_end): the issue's first bouncing-ball start pair at the weakest
#: gains, and a forced pair with a force toward the wall
RUNS = {"balls": (BALL, (1.0, 0.0), (0.5, 0.0), 0.1, 0.1, 1e-3, 3.0),
        "forced": (FORCED, (1.0, 0.0), (0.2, 0.5), 1.0, 0.5, 1e-3, 3.0)}


def drive_args(system_fmu, coupling_fmu, runs, law=LAW):
    """The child's runs: each system's and the coupling's start values for (system, x1, x2, Kp, Kd, dt, t_end)."""
    from fmu_sync.fmus.contract import scheme_value
    from fmu_sync.fmus.coupling import force_names
    out = {}
    for key, (p, x1, x2, kp, kd, dt, t_end) in runs.items():
        systems = [{**p, "g0": 0.0, "q_start": x[0], "u_start": x[1], "solver.dt": dt,
                    "solver.scheme": scheme_value("midpoint")} for x in (x1, x2)]   # the core's, below
        Q = float(energy_metric(p["k"], np.array([[kp]]), np.array([[0.0, 1.0], [1.0, 0.0]]))[0, 0])
        coupling = {"law[1]": LAWS[law], "Kp": kp, "Kd": kd, "Q": Q, "M": p["m"], "e": p["e"], "g0": 0.0,
                    **{f"{a}[{i}]": p[a] for i in (1, 2) for a in force_names()}}
        out[key] = {"systems": systems, "coupling": coupling, "H": dt, "steps": int(round(t_end / dt))}
    return {"system": str(system_fmu), "coupling": str(coupling_fmu), "runs": out}


def core_rows(p, x1, x2, kp, kd, dt, t_end, law=LAW):
    """The core's run as the driver's rows (tau of row k: the force held over the step from t_k)."""
    s = ImpactOscillator(**p)
    r = simulate_pair(s, x1, x2, t_end, dt, coupling=law, Kp=kp, Kd=kd, scheme="midpoint")   # the explicit
    tau1 = np.append(r.tau1[1:, 0], np.nan)
    tau2 = np.append(r.tau2[1:, 0], np.nan)
    return np.column_stack([r.t, r.q1[:, 0], r.u1[:, 0], r.q2[:, 0], r.u2[:, 0], tau1, tau2, r.d])


@pytest.fixture(scope="module")
def package(tmp_path_factory):
    """One package with the compensated law (the zeno-table scene: a force toward the wall and a
    harmonic one), its system and coupling FMUs unpacked for the driver."""
    from fmu_sync.ssp import write_ssp
    tmp = tmp_path_factory.mktemp("compensated")
    p = write_ssp("zeno-table", tmp / "zeno.ssp", None, {"coupling.law": LAW, "run.t_end": 2.0, "run.H": 1e-3})
    with zipfile.ZipFile(p) as zf:
        for name in ("system1.fmu", "coupling.fmu"):
            (tmp / name).write_bytes(zf.read(f"resources/{name}"))
    return tmp, p


@pytest.fixture(scope="module")
def driven(package):
    tmp, _ = package
    runs = {**RUNS, "balls-switching": RUNS["balls"]}
    args = drive_args(tmp / "system1.fmu", tmp / "coupling.fmu", {k: v for k, v in runs.items() if k != "balls-switching"})
    args["runs"].update(drive_args(tmp / "system1.fmu", tmp / "coupling.fmu", {"balls-switching": RUNS["balls"]},
                                   "switching")["runs"])
    return child(__file__, "drive", args, tmp)


@pytest.mark.parametrize("key", list(RUNS))
def test_the_coupling_fmu_is_the_cores_compensated_law_at_H_dt(driven, key):
    """States, forces and d through the coupling FMU equal the core's run to round-off, on a jump
    branch too (where the law compensates h at the chain ends, at the states' time)."""
    got = np.array(driven[key], dtype=float)
    ref = core_rows(*RUNS[key])
    assert got.shape == ref.shape
    states = np.abs(got[:, 1:5] - ref[:, 1:5]).max()
    forces = np.nanmax(np.abs(got[:-1, 5:7] - ref[:-1, 5:7]))
    d = np.abs(got[:, 7] - ref[:, 7]).max()
    assert states <= 1e-12 and forces <= 1e-11 and d <= 1e-12, (states, forces, d)
    # the law did compensate (it differs from switching on this run)
    sw = core_rows(*RUNS[key], law="switching")
    assert np.nanmax(np.abs(sw[:-1, 5:7] - ref[:-1, 5:7])) > 1e-3


def test_V_does_not_grow_through_the_coupling_fmu_on_the_bouncing_balls(driven):
    """The issue's bouncing balls at Kp = Kd = 0.1 through the coupling FMU: V/V0 <= 1.02 with
    law 3, where law 0 (switching) on the same driver lets V grow."""
    V = {k: 0.5 * np.array(driven[k], dtype=float)[:, 7] ** 2 for k in ("balls", "balls-switching")}
    assert V["balls"].max() <= 1.02 * V["balls"][0]
    assert V["balls-switching"].max() > 2.0 * V["balls-switching"][0]


def test_a_package_with_the_compensated_law_is_valid_binds_h_and_runs_as_the_core(package, tmp_path):
    """The package validates against SSP 1.0 (its parameter mappings too), binds the coupling's
    k[i] .. phi[i] from the systems' own .ssv, runs in `fmu-sync run X.ssp` as the core does,
    and a coupling given another force law is refused."""
    from lxml import etree
    import fmpy

    from fmu_sync.scenes.loading import as_scene
    from fmu_sync.ssp import SsdError, read_ssp, run_ssp
    _, p = package
    schema = Path(fmpy.__file__).parent / "ssp" / "schema"
    schemas = {ext: etree.XMLSchema(file=str(schema / f"SystemStructure{x}.xsd"))
               for ext, x in ((".ssd", "Description"), (".ssv", "ParameterValues"), (".ssm", "ParameterMapping"))}
    with zipfile.ZipFile(p) as zf:
        names = [n for n in zf.namelist() if Path(n).suffix in schemas]
        assert sum(n.endswith(".ssm") for n in names) == 2
        for n in names:
            s = schemas[Path(n).suffix]
            assert s.validate(etree.fromstring(zf.read(n))), (n, str(s.error_log))
        assert b"k[1]" not in zf.read("resources/coupling.ssv")      # h only from the systems' values
    pkg = read_ssp(p)
    for i in (1, 2):
        assert {a: pkg.parameters["coupling"][f"{a}[{i}]"] for a in ("k", "f0", "F", "Omega")} == \
               {a: pkg.parameters[f"system{i}"][a] for a in ("k", "f0", "F", "Omega")}
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-m", "fmu_sync.cli", "run", str(p), "-o", str(out), "--quiet"],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    rec = np.load(out / "result.npz")
    v = as_scene("zeno-table").variants[0]
    dt = v.cfg["solver.dt"]
    c = simulate_pair(v.system, v.x1, v.x2, 2.0, dt, coupling=LAW, Kp=v.cfg["coupling.Kp"], Kd=v.cfg["coupling.Kd"])
    np.testing.assert_allclose(rec["t"], c.t, rtol=0, atol=1e-12)           # the package's H is dt
    np.testing.assert_allclose(rec["d"][:, 0], c.d, rtol=0, atol=1e-9)
    assert np.any(np.asarray(c.branch) != 0)
    # another force law for the coupling than the systems': refused, naming it
    bad = tmp_path / "bad.ssp"
    with zipfile.ZipFile(p) as zin, zipfile.ZipFile(bad, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "resources/coupling.ssv":
                data = data.replace(b"</ssv:Parameters>", b'<ssv:Parameter name="f0[2]"><ssv:Real value="-3.0"/>'
                                                          b"</ssv:Parameter></ssv:Parameters>")
            zout.writestr(item, data)
    with pytest.raises(SsdError, match=r"f0\[2\] = -3.0 differs from system2's f0 = -1.0"):
        run_ssp(bad)


def test_a_configuration_the_core_refuses_is_fmi2Error_at_initialization(tmp_path):
    """law[1] = switching-compensated on a coupling FMU of 2-DOF systems: fmi2Error at
    exitInitializationMode with the core's reason logged (no crash)."""
    from fmu_sync.export import export_coupling
    fmu = export_coupling(tmp_path / "c2.fmu", n=2)
    got = child(__file__, "refused", {"fmu": str(fmu)}, tmp_path)
    assert got["status"] == 3, got
    assert "implemented for 1-DOF systems (n = 1), got n = 2" in got["log"][-1]
    from fmu_sync.core.compensation import check_compensated   # the one rule, its other refusal
    from fmu_sync.core.errors import LawRefused
    from fmu_sync.core.examples import Pendulum
    with pytest.raises(LawRefused, match="force law 'pendulum'"):
        check_compensated(1, Pendulum().force)
