"""The master's compiled exchange loop (fmu_sync/cosim_loop.py, docs/design.md §4.4).

Reference: the Python exchange loop the master had before (tests/_master_reference.py,
``PythonMaster``, calling fmpy's FMU2Slave one variable at a time). The compiled loop must
give the same numbers bit for bit, for our FMU on the scenes and for a C FMU with the
contract's variables (tests/contract_fmu/oscillator.c), and must end with ``SlaveError``
(instance, time, call, the FMU's reason, the partial record) on every failing status.
"""
import re
import shutil
import subprocess
import zipfile
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import pytest

import fmu_sync.master as master
from fmu_sync.fmus import contract
from fmu_sync.master import SlaveError, cosimulate, cosimulate_network
from fmu_sync.scenes.loading import load_scene
from fmu_sync.scenes.running import export_for, run_variant

from _master_reference import PythonMaster
from builtin_scenes import FORCED_GAINS as GAINS
from builtin_scenes import FORCED_PAIR as PAPER
from builtin_scenes import FORCED_X1 as X1
from builtin_scenes import FORCED_X2 as X2

FIELDS = ("t", "q", "u", "tau", "d", "branch", "euclidean", "V")
C_SOURCE = Path(__file__).parent / "contract_fmu" / "oscillator.c"
FAIL_VARS = ("fail_call", "fail_step", "fail_status")
CALL_CODES = {"fmi2DoStep": 1, "fmi2SetReal": 2, "fmi2GetReal": 3, "fmi2GetInteger": 4, "fmi2GetFMUstate": 5,
              "fmi2SetRealInputDerivatives": 6}


def same(a, b) -> None:
    """Two NetworkResults (or PairResults) hold identical numbers (NaN where NaN)."""
    for f in FIELDS + ("q1", "u1", "q2", "u2", "tau1", "tau2"):
        x, y = getattr(a, f, None), getattr(b, f, None)
        assert (x is None) == (y is None), f
        if x is not None:
            assert np.array_equal(x, y, equal_nan=True), f
    assert a.info.get("retaken_steps") == b.info.get("retaken_steps")
    assert getattr(a, "impacts", None) == getattr(b, "impacts", None)
    if hasattr(a, "impacts1"):
        assert (a.impacts1, a.impacts2) == (b.impacts1, b.impacts2)
    assert a.error == b.error


def both(monkeypatch, fn):
    """``fn()`` with the compiled loop, then with the Python reference loop."""
    new = fn()
    with monkeypatch.context() as m:
        m.setattr(master, "NetworkMaster", PythonMaster)
        ref = fn()
    return new, ref


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    from fmu_sync.export import export_fmu
    start = dict(PAPER)
    start["solver.dt"] = 1e-3
    return export_fmu("impact-oscillator", tmp_path_factory.mktemp("fmu") / "osc.fmu", start)


# ------------------------------------------------------------ our FMU, bit for bit
@pytest.mark.parametrize("kw", [
    dict(method="jacobi"),
    dict(method="gauss-seidel"),
    dict(hold="foh", Kd=0.5),
    dict(hold="foh", method="gauss-seidel"),
    dict(coupling="euclidean", event_aware=True, H_min=1e-3),
    dict(coupling="euclidean", event_aware=True, hold="foh"),
    dict(record_every=7, record_distance=False, coupling=None),
    dict(start_values=[{}, {"k": 1.05}], record_every=3),
])
def test_pair_is_bitwise_the_python_loop(fmu, monkeypatch, kw):
    args = dict(coupling="switching", **GAINS)
    args.update(kw)
    new, ref = both(monkeypatch, lambda: cosimulate(fmu, X1, X2, 8.0, 1e-2, **args))
    same(new, ref)
    if kw.get("event_aware"):
        assert new.info["retaken_steps"] > 0


@pytest.mark.parametrize("kw", [
    dict(record_every=7),
    dict(method="gauss-seidel", hold="foh", record_every=3),
    dict(coupling="euclidean", event_aware=True, H_min=1e-3, record_every=4),
])
def test_a_run_ending_between_communication_points_is_bitwise_the_python_loop(fmu, monkeypatch, kw):
    """t_end not a multiple of H (issue 16): the last step shortened to t_end - k H, the final
    state recorded though record_every does not divide the steps, as the Python loop does it."""
    args = dict(coupling="switching", **GAINS)
    args.update(kw)
    t_end, H = 4.0037, 1e-2   # 401 steps, the last one 0.0037 long
    new, ref = both(monkeypatch, lambda: cosimulate(fmu, X1, X2, t_end, H, **args))
    same(new, ref)
    every = kw["record_every"]
    assert new.success and len(new.t) == -(-401 // every) + 1
    assert new.t[-1] == t_end and new.t[-2] == (400 // every) * every * H
    assert np.all(np.isfinite(new.q1[-1])) and np.all(np.isfinite(new.d))
    if kw.get("event_aware"):
        assert new.info["retaken_steps"] > 0


def test_network_with_mixed_laws_and_directed_weights_is_bitwise_the_python_loop(fmu, monkeypatch):
    from fmu_sync.core.network import star
    A = star(4)
    A[0, 1] = 0.5
    xs = [(0.2 + 0.3 * i, 0.1 * i) for i in range(4)]
    for method in ("jacobi", "gauss-seidel"):
        new, ref = both(monkeypatch, lambda: cosimulate_network(
            fmu, xs, A, 6.0, 1e-2, coupling=["switching", "euclidean", None], Kp=2.0, Kd=1.0, method=method,
            start_values=[{"solver.dt": 1e-2, "k": k} for k in (1.0, 1.05, 0.95, 1.02)]))
        same(new, ref)


@pytest.mark.parametrize("method", ["delayed", "delayed-zero"])
def test_the_other_masters_orders_are_bitwise_the_python_loop(fmu, method):
    """SspMaster's delayed orders (libcosim's, fmpy's: flags[DELAY]) against issue 19's Python
    step methods, on a pair and on a network with mixed laws; and what they hold: step k at
    the forces of x_{k-1} (delayed: step 0 at x_0's), delayed-zero 0 over steps 0 and 1."""
    from fmu_sync.core.network import network_forces, star
    from fmu_sync.ssp_master import SspMaster
    from _master_reference import PythonSspMaster
    A = star(3)
    A[0, 1] = 0.5
    runs = [([X1, X2], [[0.0, 1.0], [1.0, 0.0]], "switching", {}),
            ([(0.2 + 0.3 * i, 0.1 * i) for i in range(3)], A, ["switching", "euclidean"],
             dict(start_values=[{"k": k} for k in (1.0, 1.05, 0.95)], record_every=3))]
    for states, W, law, kw in runs:
        args = (fmu, states, W, 6.0, 1e-2, law, GAINS["Kp"], GAINS["Kd"])
        m = SspMaster(*args, method=method, **kw)
        new = m.run()
        same(new, PythonSspMaster(*args, method=method, **kw).run())
        assert new.success and new.impacts[0] > 0
        if kw:   # record_every = 3: the rows skip the steps
            continue
        a = m.loop_args
        laws, geo, Kp, Kd, E2, W2 = a.laws, a.geo, a.Kp, a.Kd, a.E2, a.W2
        w = m.loop_state.w
        F = np.zeros_like(m.Qr[0])
        for k in range(len(m.T) - 1):   # row k + 1 holds the force over step k
            network_forces(laws, geo, Kp, Kd, E2, W2, m.Qr[max(k - 1, 0)], m.Ur[max(k - 1, 0)], F, *w[:6], False,
                           *w[6:9], m.hp, m.T[max(k - 1, 0)])
            want = 0.0 * F if method == "delayed-zero" and k < 2 else F
            assert np.array_equal(m.TAU[k + 1], want), k
        assert np.array_equal(m.TAU[0], 0.0 * F if method == "delayed-zero" else m.TAU[1])


@pytest.mark.parametrize("kw, words", [(dict(hold="foh"), "hold='foh'"), (dict(event_aware=True), "event_aware=True")])
def test_the_other_masters_orders_refuse_what_they_do_not_have(fmu, kw, words):
    from fmu_sync.ssp_master import SspMaster
    with pytest.raises(ValueError, match=f"libcosim's exchange order.*{re.escape(words)}"):
        SspMaster(fmu, [X1, X2], [[0.0, 1.0], [1.0, 0.0]], 1.0, 1e-2, method="delayed", **kw)


SCENES = [("forced-pair", {}), ("mismatched-pair", {}), ("ring-8", {}), ("two-dof", {}),
          ("forced-pair", {"run.method": "gauss-seidel", "run.hold": "foh"})]


@pytest.mark.parametrize("scene, over", SCENES)
def test_scenes_cosimulated_are_bitwise_the_python_loop(scene, over, tmp_path, monkeypatch):
    """The demo (forced-pair, all its variants) and the test scenes, co-simulated."""
    sc = load_scene(scene, {"run.t_end": 3.0, "run.mode": "cosim", **over})
    fmus = {}
    for v in sc.variants:
        key = (v.cfg["system.model"], v.system.n)
        if key not in fmus:
            fmus[key] = export_for(v, tmp_path / f"{len(fmus)}")
        new, ref = both(monkeypatch, lambda: run_variant(v, fmus[key]))
        same(new, ref)


# ------------------------------------------------------------ a C FMU with the contract's variables
def _xml(decl, identifier: str) -> str:
    rows, outputs = [], []
    for k, v in enumerate(decl):
        typ = "Integer" if v.type in ("Integer", "Enumeration") else "Real"
        attrs = f'name={quoteattr(v.name)} valueReference="{k}" causality="{v.causality}" variability="{v.variability}"'
        if v.initial:
            attrs += f' initial="{v.initial}"'
        start = "" if v.causality == "output" else f' start="{v.start if typ == "Integer" else float(v.start)!r}"'
        rows.append(f"    <ScalarVariable {attrs}><{typ}{start}/></ScalarVariable>")
        if v.causality == "output":
            outputs.append(k + 1)
    unknowns = "".join(f'<Unknown index="{i}"/>' for i in outputs)
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription fmiVersion="2.0" modelName="{identifier}" '
            f'guid="{{5b1c0f8e-3a49-4d4f-9a55-0c0ffee00018}}" variableNamingConvention="structured">\n'
            f'  <CoSimulation modelIdentifier="{identifier}" canHandleVariableCommunicationStepSize="true" '
            f'canInterpolateInputs="true" canGetAndSetFMUstate="true"/>\n  <ModelVariables>\n'
            + "\n".join(rows) + f"\n  </ModelVariables>\n  <ModelStructure><Outputs>{unknowns}</Outputs>"
            f"<InitialUnknowns>{unknowns}</InitialUnknowns></ModelStructure>\n</fmiModelDescription>\n")


@pytest.fixture(scope="module")
def c_fmu(tmp_path_factory):
    """tests/contract_fmu/oscillator.c built with gcc, its interface the contract's 1-DOF
    model (value references and start values generated here) plus the failure switch."""
    if shutil.which("gcc") is None:  # pragma: no cover - CI has gcc
        pytest.fail("gcc is needed to build the C test FMU")
    decl = contract.model("impact-oscillator").declare()
    decl = [contract.Var(v.name, "Integer" if v.type == "Enumeration" else v.type, v.causality, v.variability,
                         v.description, v.initial, start=(0 if v.type == "Enumeration" else v.start))
            for v in decl]
    decl += [contract.Var(n, "Integer", "parameter", "fixed", "failure switch", "exact", start=s)
             for n, s in zip(FAIL_VARS, (0, -1, 3))]
    d = tmp_path_factory.mktemp("cfmu")
    cname = (lambda name: name.replace(".", "_"))
    header = [f"#define VR_{cname(v.name)} {k}" for k, v in enumerate(decl)]
    header += [f"#define NV {len(decl)}", "static const double START[NV] = {"
               + ", ".join(repr(float(v.start)) if v.start is not None else "0.0" for v in decl) + "};"]
    (d / "contract_vars.h").write_text("\n".join(header) + "\n")
    so = d / "CContractOscillator.so"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O2", "-Wall", "-Werror", f"-I{d}", "-o", str(so),
                    str(C_SOURCE), "-lm"], check=True)
    fmu = d / "CContractOscillator.fmu"
    with zipfile.ZipFile(fmu, "w") as zf:
        zf.writestr("modelDescription.xml", _xml(decl, "CContractOscillator"))
        zf.write(so, "binaries/linux64/CContractOscillator.so")
    return fmu


C_START = {"k": 1.0, "c": 0.0, "f0": 0.2, "F": 0.5, "Omega": 2.5, "e": 0.9, "solver.dt": 1e-3}


@pytest.mark.parametrize("kw", [dict(), dict(method="gauss-seidel"), dict(hold="foh"),
                                dict(coupling="euclidean", event_aware=True)])
def test_a_c_fmu_with_the_contract_is_driven_like_the_python_loop(c_fmu, monkeypatch, kw):
    args = dict(coupling="switching", Kp=GAINS["Kp"], Kd=GAINS["Kd"], start_values=C_START)
    args.update(kw)
    new, ref = both(monkeypatch, lambda: cosimulate(c_fmu, X1, X2, 40.0, 1e-2, **args))
    same(new, ref)
    assert new.success and new.impacts1 > 3
    if kw.get("event_aware"):
        assert new.info["retaken_steps"] > 0
    elif kw.get("method") == "gauss-seidel":   # an O(H) residual (tests/test_master.py)
        assert new.d[-1] < 1e-2 * new.d[0]
    else:  # the C oscillators are pulled together by the coupling
        assert new.d[-1] < 1e-3 * new.d[0]


def _failing(c_fmu, call, status, step, **kw):
    """A pair whose instance 2 answers ``call`` with ``status`` after ``step`` doSteps."""
    sv = [dict(C_START), {**C_START, "fail_call": CALL_CODES[call], "fail_step": step, "fail_status": status}]
    return cosimulate(c_fmu, X1, X2, 2.0, 1e-2, coupling="switching", Kp=GAINS["Kp"], Kd=GAINS["Kd"],
                      start_values=sv, **kw)


@pytest.mark.parametrize("call, status, kw", [
    ("fmi2DoStep", 2, {}), ("fmi2DoStep", 3, {}), ("fmi2DoStep", 4, {}),
    ("fmi2DoStep", 3, dict(method="gauss-seidel")),
    ("fmi2SetReal", 3, {}), ("fmi2GetReal", 4, {}), ("fmi2GetInteger", 2, {}),
    ("fmi2GetFMUstate", 3, dict(event_aware=True)),
    ("fmi2SetRealInputDerivatives", 3, dict(hold="foh")),
])
def test_a_failing_slave_raises_slave_error_with_the_partial_record(c_fmu, monkeypatch, call, status, kw):
    step = 37
    with pytest.raises(SlaveError) as err:
        _failing(c_fmu, call, status, step, **kw)
    e = err.value
    assert (e.slave, e.call, e.status) == ("system2", call, status)
    label = {2: "Discard", 3: "Error", 4: "Fatal"}[status]
    done = step - 1 if call == "fmi2DoStep" else step
    assert f"{call} returned fmi2{label}: {call}: injected failure after {done} doSteps" in str(e)
    res = e.partial
    assert res is not None and res.error == str(e) and not res.success
    # the record ends at the last completed step; a get fails after its step's doStep (t + H),
    # the other calls at the step's start
    after = call in ("fmi2GetReal", "fmi2GetInteger")
    assert e.t == pytest.approx(res.t[-1] + (1e-2 if after else 0.0), abs=1e-12)
    if not kw.get("event_aware"):   # (retaken steps count as doSteps too)
        assert res.t[-1] == pytest.approx((step - (call != "fmi2SetReal" and call != "fmi2SetRealInputDerivatives"))
                                          * 1e-2, abs=1e-12)
    assert np.all(np.isfinite(res.q1)) and np.all(np.isfinite(res.d))
    if call == "fmi2GetReal" and status == 4:
        return  # the Python loop read q and u in two calls and tripped over its own dead instance
    # the same failure, the same record and message from the Python reference loop
    with monkeypatch.context() as m:
        m.setattr(master, "NetworkMaster", PythonMaster)
        with pytest.raises(SlaveError) as ref:
            _failing(c_fmu, call, status, step, **kw)
    same(res, ref.value.partial)


def test_a_warning_does_not_end_the_run(c_fmu):
    sv = [dict(C_START), {**C_START, "fail_call": 1, "fail_step": 5, "fail_status": 1}]
    r = cosimulate(c_fmu, X1, X2, 1.0, 1e-2, coupling="switching", Kp=1.0, Kd=1.0, start_values=sv)
    assert r.success and r.t[-1] == pytest.approx(1.0)


def test_a_failure_before_the_first_step_has_no_partial_record(c_fmu):
    sv = [{**C_START, "fail_call": CALL_CODES["fmi2GetInteger"], "fail_step": 0, "fail_status": 3}, dict(C_START)]
    with pytest.raises(SlaveError, match=r"slave 'system1' failed at t = 0: fmi2GetInteger returned fmi2Error") as err:
        cosimulate(c_fmu, X1, X2, 1.0, 1e-2, coupling="switching", Kp=1.0, Kd=1.0, start_values=sv)
    assert err.value.partial is None


def test_progress_is_reported_between_chunks(fmu):
    seen = []
    cosimulate(fmu, X1, X2, 5.0, 1e-2, coupling="switching", progress=seen.append, **GAINS)
    assert len(seen) > 10 and seen == sorted(seen) and seen[-1] == 1.0


def test_ctrl_c_between_chunks_stops_the_run_and_leaves_nothing_behind(fmu, monkeypatch, tmp_path):
    import fmpy
    made = []
    real_extract = fmpy.extract

    def extract(path, *a, **k):
        made.append(real_extract(path, *a, **k))
        return made[-1]
    monkeypatch.setattr(fmpy, "extract", extract)

    def interrupt(fraction):
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        cosimulate(fmu, X1, X2, 5.0, 1e-2, coupling="switching", progress=interrupt, **GAINS)
    assert made and not any(Path(d).exists() for d in made)


@pytest.mark.parametrize("call, status", [("fmi2DoStep", 3), ("fmi2DoStep", 2), ("fmi2SetReal", 3),
                                          ("fmi2GetReal", 4), ("fmi2GetInteger", 3)])
def test_the_master_host_raises_slave_error_at_the_failing_call(c_fmu, tmp_path, call, status):
    """The master's one wrapper of an instance (master.open_instance: the FMUHost with raises=True)
    raises SlaveError at the failing call itself, naming the instance, the time, the FMI call, the
    status and the FMU's logged reason; the same host without raises returns the status."""
    from fmpy import extract

    from fmu_sync.fmi_bridge import FMUHost
    d = extract(str(c_fmu), str(tmp_path / "u"))
    md = master.model_description(d)
    sv = {"fail_call": CALL_CODES[call], "fail_step": 3, "fail_status": status}
    s = master.open_instance(d, md, "osc7")
    p = FMUHost(d, instance_name="probe", model_description=md)
    try:
        for h in (s, p):
            h.initialize(0.5, {**C_START, **sv})
            for k in range(2):
                h.do_step(0.5 + 0.1 * k, 0.1)
        assert s.t == pytest.approx(0.7)
        act = {"fmi2DoStep": lambda h: h.do_step(0.7, 0.1), "fmi2SetReal": lambda h: h.set({"tau": 0.0}),
               "fmi2GetReal": lambda h: h.get(["q"]), "fmi2GetInteger": lambda h: h.get_integer("impacts")}[call]
        if call != "fmi2DoStep":
            for h in (s, p):
                h.do_step(0.7, 0.1)
        with pytest.raises(SlaveError) as err:
            act(s)
        e = err.value
        assert (e.slave, e.call, e.status) == ("osc7", call, status)
        assert e.t == pytest.approx(0.7 if call == "fmi2DoStep" else 0.8)
        assert "injected failure" in e.log[-1] and f"{call}: injected failure" in str(e)
        assert str(e).startswith(f"slave 'osc7' failed at t = {e.t:.6g}: {call} returned fmi2")
        act(p)                                   # the probing host: a status, no exception
        assert p.last_status == status and "injected failure" in p.errors(min_status=1)[-1]
    finally:
        s.close()
        p.close()
