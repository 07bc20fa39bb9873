"""Running the FMUs (docs/design.md §4.3): fmpy vs the core, libcosimpy vs fmpy, FMU states,
bad input, and a clean exit of fresh processes.

Every FMU is loaded in a child process, never in the pytest process: the
scenarios below are plain functions of this file, run as
``python tests/test_fmu_run.py SCENARIO ARGS.json RESULT.json``; the tests
assert on the JSON they write and on the FMI status each call returned. The
child's exit status is checked too, so an FMU that crashes its host fails a
test instead of killing pytest. Plain C hosts: tests/test_fmu_c_host.py.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

DT = 1e-3            # internal step of the FMUs (the default solver.dt)
T_END = 10.0
EXIT_PROCESSES = 20  # python -m fmu_sync.benchmarks.fmu_cost --exit-check 200 runs the full claim


# =============================================================== child side
def _host(path, name="fmu"):
    from fmu_sync.fmi_bridge import FMUHost
    return FMUHost(path, instance_name=name, logging=True)


def _outputs(h, names):
    return h.get(names)


def scenario_reference(a):
    """fmpy runs (simulate_fmu and a hand loop) of both FMUs; the parent compares with the core."""
    from fmpy import simulate_fmu
    out = {}
    for key, H in (("io_H1", DT), ("io_H10", 10 * DT)):
        r = simulate_fmu(a["io"], stop_time=T_END, output_interval=H,
                         output=["q", "u", "impacts", "percussion", "gap", "energy"])
        out[key] = {n: r[n].tolist() for n in r.dtype.names}
    r = simulate_fmu(a["io_theta"], stop_time=T_END, output_interval=DT, output=["q", "u"])
    out["io_theta"] = {n: r[n].tolist() for n in r.dtype.names}
    r = simulate_fmu(a["ms2"], stop_time=T_END, output_interval=DT,
                     output=["q[1]", "q[2]", "u[1]", "u[2]", "gap", "impacts"])
    out["ms2"] = {n: r[n].tolist() for n in r.dtype.names}
    # The same loop libcosim runs: constant input, t = n H.
    h = _host(a["io"])
    h.initialize(0.0, {"tau": 0.05})
    qs = []
    for n in range(a["cosim_steps"]):
        assert h.do_step(n * DT, DT) == 0
        qs.append(h.get(["q", "u"]))
    h.close()
    out["io_loop"] = qs
    return out


def scenario_libcosim(a):
    """The 1-DOF FMU in libcosimpy (an independent importer)."""
    from libcosimpy.CosimEnums import CosimExecutionState
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave
    log_output_level(CosimLogLevel.ERROR)
    ex = CosimExecution.from_step_size(step_size=round(DT * 1e9))
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    idx = ex.add_local_slave(CosimLocalSlave(fmu_path=a["io"], instance_name="io"))
    vr = {v.name.decode(): v.reference for v in ex.slave_variables(idx)}
    ex.real_initial_value(idx, vr["tau"], 0.05)
    qs = []
    for _ in range(a["cosim_steps"]):
        assert ex.step(1)
        qs.append(obs.last_real_values(idx, [vr["q"], vr["u"]]))
    st = ex.status()
    return {"q_u": qs, "state": str(st.state), "error_code": str(st.error_code),
            "ok": st.state != CosimExecutionState.ERROR}


def _run(h, t, n, H, names, tau=None):
    rows = []
    for k in range(n):
        if tau is not None:
            h.set({name: tau(t, k) for name in tau.names})
        st = h.do_step(t, H)
        assert st == 0, (st, h.messages[-3:])
        t += H
        rows.append(h.get(names))
    return t, rows


class _Tau:
    def __init__(self, names):
        self.names = names

    def __call__(self, t, k):
        return 0.3 * math.sin(7.0 * t) + 0.01 * k


def scenario_state(a):
    """get/set and serialised FMU states reproduce a run bit for bit (both FMUs)."""
    res = {}
    for key, names, tau_names, starts in (
            ("io", ["q", "u", "gap", "energy", "impacts", "percussion"], ["tau"], {"solver.scheme": 2,
                                                                                  "solver.theta": 0.6}),
            ("ms2", ["q[1]", "q[2]", "u[1]", "u[2]", "gap", "energy", "impacts", "percussion"],
             ["tau[1]", "tau[2]"], {})):
        tau = _Tau(tau_names)
        # variable communication steps, not multiples of dt
        steps = [0.0137, 0.002, 0.0301, 0.0005, 0.011] * 40
        h = _host(a[key], "first")
        h.initialize(0.0, starts)
        t = 0.0
        for H in steps[:100]:
            t, _ = _run(h, t, 1, H, names, tau)
        st, s1 = h.get_state()
        assert st == 0
        blob = h.serialize_state(s1)
        at_save = h.get(names)
        ref = []
        t_save = t
        for H in steps[100:]:
            t, rows = _run(h, t, 1, H, names, tau)
            ref += rows
        t_end = t
        # 1) same instance, in-memory state
        assert h.set_state(s1) == 0
        back = h.get(names)
        t = t_save
        again = []
        for H in steps[100:]:
            t, rows = _run(h, t, 1, H, names, tau)
            again += rows
        # 2) a second instance from the serialised bytes
        g = _host(a[key], "second")
        g.initialize(0.0, starts)
        st_d, s2 = g.deserialize_state(blob)
        st_s = g.set_state(s2)
        from_bytes_at = g.get(names)
        t = t_save
        again2 = []
        for H in steps[100:]:
            t, rows = _run(g, t, 1, H, names, tau)
            again2 += rows
        res[key] = {
            "same_at_restore": back == at_save, "same_at_restore_bytes": from_bytes_at == at_save,
            "identical_in_memory": again == ref, "identical_from_bytes": again2 == ref,
            "statuses": [st_d, st_s], "t_end": t_end, "t_expected": sum(steps),
            "impacts": ref[-1][names.index("impacts")],
            "blob": blob.decode("utf-8"),
            "errors": h.errors(2) + g.errors(2),
        }
        h.free_state(s1)
        g.free_state(s2)
        h.close()
        g.close()
    return res


def scenario_instances(a):
    """Several instances of one FMU in one process, sharing one unpacked folder
    (what a master does): independent, and each the same as a lone run."""
    from fmpy import extract

    from fmu_sync.fmi_bridge import FMUHost
    d = extract(a["io"])
    refs = []
    hosts = []
    for i in range(4):
        h = FMUHost(d, instance_name=f"io{i}")
        hosts.append(h)
        # nothing per instance in the interpreter: no sys.path entry, no module
        refs.append((len(sys.path), len(sys.modules)))
        h.initialize(0.0, {"q_start": 0.5 + 0.1 * i, "e": 0.5 + 0.1 * i})
    rows = []
    for k in range(500):
        for i, h in enumerate(hosts):
            h.set({"tau": 0.1 * i})
            assert h.do_step(k * DT, DT) == 0
        rows.append([h.get(["q", "u"]) for h in hosts])
    for h in hosts:
        h.close()
    # each instance alone, in a fresh unzip of the same FMU
    alone = []
    for i in range(4):
        h = FMUHost(a["io"], instance_name=f"alone{i}")
        h.initialize(0.0, {"q_start": 0.5 + 0.1 * i, "e": 0.5 + 0.1 * i, "tau": 0.1 * i})
        for k in range(500):
            h.do_step(k * DT, DT)
        alone.append(h.get(["q", "u"]))
        h.close()
    import shutil
    shutil.rmtree(d, ignore_errors=True)
    return {"refcounts": refs, "last": rows[-1], "alone": alone}


def scenario_errors(a):
    """Every bad input gets the status FMI 2.0 prescribes and a log message; nothing breaks."""
    R = {}

    def fresh(key="io", starts=None, name="err", logging=True):
        from fmu_sync.fmi_bridge import FMUHost
        h = FMUHost(a[key], instance_name=name, logging=logging)
        return h, h.initialize(0.0, starts or {})

    # --- NaN / inf / huge input: fmi2SetReal returns fmi2Error and keeps the old value;
    # the instance stays usable (the next doStep runs with the old input).
    h, _ = fresh()
    assert h.do_step(0.0, 0.01) == 0
    tau0 = h.get(["tau"])[0]
    cases = []
    t = 0.01
    for bad in (math.nan, math.inf, -math.inf, 1e300, -1e13):
        st = h.set({"tau": bad})
        cases.append([st, h.get(["tau"])[0], h.do_step(t, 0.01)])
        t += 0.01
    fixed = [h.set({"tau": 0.2}), h.do_step(t, 0.01), h.get(["tau"])[0]]
    R["input"] = {"tau0": tau0, "cases": cases, "fixed": fixed, "errors": h.errors()}
    h.close()
    # the same with logging off: the same statuses, and the reason still reaches the logger
    h, _ = fresh(logging=False)
    R["input_nolog"] = {"set": h.set({"tau": math.nan}), "step": h.do_step(0.0, 0.01), "errors": h.errors()}
    h.close()

    # --- parameters outside their bounds: refused at fmi2SetReal/SetInteger (fmi2Error),
    # the start value is kept and the run goes on with it
    out = {}
    for name, value in (("e", 1.5), ("e", math.nan), ("m", -1.0), ("m", 0.0), ("solver.dt", 0.0),
                        ("solver.theta", 0.3), ("k", -2.0), ("u_start", 2e12), ("solver.scheme", 7)):
        h, st = fresh(starts={name: value})
        out[f"{name}={value}"] = {"init": st, "value": h.get([name])[0], "step": h.do_step(0.0, 0.01),
                                  "q": h.get(["q"])[0], "errors": h.errors()}
        st_r = h.call("reset")[0]
        h.initialize(0.0)
        out[f"{name}={value}"]["after_reset"] = [st_r, h.do_step(0.0, 0.01)]
        h.close()
    R["params"] = out

    # --- g(q_start) < 0 and an invalid mass matrix (only the whole model can tell: q_start
    # and g0 together, M as a whole): fmi2ExitInitializationMode returns fmi2Error and stays
    # in initialization mode; fixing the parameter and calling it again works
    out = {}
    for label, fmu, starts, fix in (("gap", "ms2", {"q_start[1]": -1.0}, {"q_start[1]": 0.6}),
                                    ("gap_1dof", "io", {"q_start": -0.1, "g0": 0.05}, {"g0": 0.1}),
                                    ("asymmetric", "ms2", {"M[1,2]": 0.7}, {"M[1,2]": 0.5}),
                                    ("not_pd", "ms2", {"M[1,2]": 3.0, "M[2,1]": 3.0}, {"M[1,2]": 0.5, "M[2,1]": 0.5}),
                                    ("w_zero", "ms2", {"w[1]": 0.0, "w[2]": 0.0}, {"w[1]": 1.0})):
        h, st = fresh(fmu, starts)
        r = {"init": st, "step": h.do_step(0.0, 0.01), "gap": h.get(["gap"])[0], "errors": h.errors()}
        r["fix"] = [h.set(fix), h.call("exitInitializationMode")[0], h.do_step(0.0, 0.01)]
        out[label] = r
        h.close()
    R["model"] = out

    # --- bad steps: each refused with fmi2Error; afterwards the run continues exactly
    # like a run that never saw them.
    h, _ = fresh()
    clean, _ = fresh(name="clean")
    for k in range(5):
        h.do_step(k * 0.01, 0.01)
        clean.do_step(k * 0.01, 0.01)
    t = 0.05
    statuses = {
        "negative": h.do_step(t, -0.01), "zero": h.do_step(t, 0.0), "nan": h.do_step(t, math.nan),
        "inf": h.do_step(t, math.inf), "wrong_time": h.do_step(t + 1.0, 0.01),
        "nan_time": h.do_step(math.nan, 0.01), "past": h.do_step(0.0, 0.01),
        "huge_H": h.do_step(t, 1e6),
    }
    h.do_step(t, -0.01)
    last_ok = h.last_successful_time()
    cont = [h.do_step(t, 0.01), h.do_step(t + 0.01, 0.02)]
    clean.do_step(t, 0.01)
    clean.do_step(t + 0.01, 0.02)
    R["steps"] = {"statuses": statuses, "continue": cont, "last_successful_time": last_ok,
                  "same_as_clean": h.get(["q", "u", "impacts"]) == clean.get(["q", "u", "impacts"]),
                  "messages": h.errors(2)}
    h.close()
    clean.close()

    # --- work guards on the internal step: too many internal steps, and a count that
    # would overflow a 64-bit integer
    out = {}
    for dt in (1e-12, 1e-300):
        h, st = fresh(starts={"solver.dt": dt})
        q0 = h.get(["q", "u"])
        out[repr(dt)] = {"init": st, "step": h.do_step(0.0, 0.01), "q_u": h.get(["q", "u"]), "q0": q0,
                         "errors": h.errors(2), "notices": h.errors(1)}
        h.close()
    R["guards"] = out

    # --- calls in the wrong state: fmi2Error with the state named, nothing changes
    from fmu_sync.fmi_bridge import FMUHost
    h = FMUHost(a["io"], instance_name="order", logging=True)
    w = {"step_before_init": h.do_step(0.0, 0.01), "get_before_init": h.call("getReal", [1])[0]}
    h.call("setupExperiment", None, 0.0)
    h.call("enterInitializationMode")
    w["step_in_init"] = h.do_step(0.0, 0.01)
    w["set_output"] = h.set({"q": 3.0})
    w["exit"] = h.call("exitInitializationMode")[0]
    h._stepping = True
    w["step_ok"] = h.do_step(0.0, 0.01)
    w["set_param_late"] = h.set({"e": 0.1})
    w["e_unchanged"] = h.get(["e"])[0]
    w["unknown_vr"] = [h.call("getReal", [999])[0], h.call("getReal", [4294967295])[0],
                       h.call("setReal", [4294967295], [2.0])[0], h.call("setReal", [4294967283], [2.0])[0],
                       h.call("getInteger", [4294967295])[0]]
    w["m_unchanged"] = h.get(["m"])[0]
    w["wrong_type"] = [h.call("setReal", [h.vr("impacts")], [1.0])[0], h.call("getReal", [h.vr("impacts")])[0]]
    w["step_ok2"] = h.do_step(0.01, 0.01)
    w["enter_init_again"] = h.call("enterInitializationMode")[0]
    w["exit_again"] = h.call("exitInitializationMode")[0]
    w["step_ok3"] = h.do_step(0.02, 0.01)
    w["terminate"] = h.call("terminate")[0]
    w["step_after_terminate"] = h.do_step(0.03, 0.01)
    w["set_after_terminate"] = h.set({"tau": 1.0})
    w["terminate_again"] = h.call("terminate")[0]
    w["get_after_terminate"] = h.call("getReal", [h.vr("q")])[0]
    w["dead"] = h.dead
    w["errors"] = h.errors(2)
    h._stepping = False
    h.close()
    R["order"] = w

    # --- a scheme known to diverge (midpoint, omega_max*dt = 100): refused at
    # fmi2ExitInitializationMode (fmi2Error), doStep then refused (wrong state)
    h, st = fresh(starts={"k": 1e8, "solver.dt": 1e-2, "q_start": 0.5, "solver.scheme": 0})   # 0: midpoint
    R["unstable"] = {"init": st, "step": h.do_step(0.0, 1.0), "errors": h.errors(2)}
    h.close()

    # --- a step that overflows (a forcing amplitude near the float range): rolled back,
    # fmi2Error, the state stays the last valid one
    h, _ = fresh(starts={"solver.dt": 1e-3, "q_start": 0.5, "F": 1.7e308})
    q0 = h.get(["q", "u"])
    R["diverge"] = {"step": h.do_step(0.0, 2.0), "q_u": h.get(["q", "u"]), "q0": q0,
                    "last_successful_time": h.last_successful_time(), "errors": h.errors(2),
                    "energy_finite": math.isfinite(h.get(["energy"])[0])}
    h.close()

    # --- bad FMU states: refused where they enter (deserialise / set), fmi2Error
    h, _ = fresh()
    g, _ = fresh("ms2", name="other")
    h.do_step(0.0, 0.01)
    st, s_other = g.get_state()
    other_blob = g.serialize_state(s_other)
    from fmu_sync.fmus.slave import seal, unseal
    st, s_good = h.get_state()
    good = json.loads(unseal(h.serialize_state(s_good)))
    q_before = h.get(["q", "u"])
    r = {"deserialize_garbage": h.deserialize_state(b"\x00not json")[0],
         "set_null": h.set_state(None)}
    r["deserialize_other"], s_wrong = h.deserialize_state(other_blob)
    corrupt = {}
    for label, change in (("q_nan_text", {"q": "nan"}), ("q_size", {"q": [0.5, 0.5]}),
                          ("q_inf", {"q": [1e400]}), ("impacts_float", {"impacts": 1.5}),
                          ("tau_big", {"tau": [1e300]}), ("param_bad", {"parameters": {**good["parameters"], "e": 2.0}}),
                          ("inside_wall", {"q": [-0.5]}), ("time_missing", {"time": None}),
                          ("q_huge", {"q": [1e300]}), ("u_huge", {"u": [-2e12]})):
        bad = {**good, **change}
        if change.get("time", 0) is None:
            del bad["time"]
        blob = seal(json.dumps(bad).encode())    # a valid checksum: the content is what is refused
        corrupt[label] = h.deserialize_state(blob)[0]
    r["corrupt"] = corrupt
    r["unchanged"] = q_before == h.get(["q", "u"])
    r["step_ok"] = h.do_step(0.01, 0.01)
    r["moved"] = q_before != h.get(["q", "u"])
    # a state the scheme itself produced in contact (slightly below the wall) is accepted
    r["errors"] = h.errors()
    R["state"] = r
    h.free_state(s_good)
    g.free_state(s_other)
    for x in (h, g):
        x.close()

    # --- instantiation refused: wrong GUID, Model Exchange, missing resources (NULL, reason logged)
    R["instantiate"] = _instantiate_cases(a["io"])
    return R


def _instantiate_cases(fmu_path):
    """fmi2Instantiate with a wrong GUID, as Model Exchange, and without resources:
    each returns NULL with the reason logged."""
    import ctypes
    import shutil

    from fmpy import extract, read_model_description
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE,
                           fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE)
    from fmpy import calloc, free
    md = read_model_description(fmu_path)
    d = extract(fmu_path)
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="raw")
    msgs = []

    def _log(env, name, status, cat, msg):
        msgs.append((int(status), (msg or b"").decode()))

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(_log)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    uri = (Path(d) / "resources").as_uri()
    out = {}
    for label, kind, guid, res in (("wrong_guid", 1, "{00000000-0000-0000-0000-000000000000}", uri),
                                   ("model_exchange", 0, md.guid, uri),
                                   ("no_resources", 1, md.guid, Path(d, "nowhere").as_uri()),
                                   ("not_a_file_uri", 1, md.guid, "http://example.com/r"),
                                   ("null_uri", 1, md.guid, None),
                                   ("ok", 1, md.guid, uri)):
        del msgs[:]
        c = fmu.fmi2Instantiate(b"raw", kind, guid.encode(), res.encode() if res else None,
                                ctypes.byref(cb), 0, 1)
        out[label] = {"null": not c, "messages": list(msgs)}
        if c:
            fmu.fmi2FreeInstance(c)
    # a NULL component: fmi2Error, no crash; freeing NULL does nothing
    from fmpy.fmi1 import FMICallException

    def raw(fn, *args):
        try:
            fn(*args)
            return 0
        except FMICallException as exc:
            return int(exc.status)

    vr = (ctypes.c_uint * 1)(0)
    val = (ctypes.c_double * 1)(0.0)
    out["null_component"] = [raw(fmu.fmi2DoStep, None, 0.0, 0.01, 1), raw(fmu.fmi2Terminate, None),
                             raw(fmu.fmi2SetReal, None, vr, 1, val), raw(fmu.fmi2GetReal, None, vr, 1, val)]
    fmu.fmi2FreeInstance(None)
    shutil.rmtree(d, ignore_errors=True)
    return out


def scenario_exit(a):
    """Load, run and free an FMU with plain fmpy, then exit normally."""
    import shutil

    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(a["io"])
    d = extract(a["io"])
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="exit")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    for k in range(50):
        fmu.doStep(k * 0.01, 0.01)
    q = fmu.getReal([1])[0]
    fmu.terminate()
    fmu.freeInstance()
    shutil.rmtree(d, ignore_errors=True)
    return {"q": q}


def _child_main(argv):
    name, args_path, out_path = argv
    args = json.loads(Path(args_path).read_text())
    result = globals()[f"scenario_{name}"](args)
    Path(out_path).write_text(json.dumps(result))


# =============================================================== parent side
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from fmu_sync.core import ImpactOscillator, MechanicalSystem, simulate  # noqa: E402
from fmu_sync.export import export_fmu  # noqa: E402


def _child(name: str, args_path: Path, tmp: Path, timeout: float = 300.0):
    fd, out_path = tempfile.mkstemp(prefix=f"{name}.", suffix=".out.json", dir=tmp)
    os.close(fd)
    out_path = Path(out_path)
    out_path.unlink()
    p = subprocess.run([sys.executable, __file__, name, str(args_path), str(out_path)],
                       capture_output=True, text=True, timeout=timeout)
    result = json.loads(out_path.read_text()) if out_path.exists() else None
    return p.returncode, result, p.stderr[-3000:]


@pytest.fixture(scope="module")
def runs(tmp_path_factory, shared_fmu):
    """Export the FMUs and run all scenario children, two at a time (2 cores)."""
    tmp = tmp_path_factory.mktemp("fmu_run")
    a = {
        "io": str(shared_fmu("impact-oscillator")),
        "io_theta": str(export_fmu("impact-oscillator", tmp / "io_theta.fmu",
                                   {"solver.scheme": "theta", "solver.theta": 0.75, "e": 0.6})),
        "ms2": str(shared_fmu("mechanical-system-2")),
        "cosim_steps": 3000,
    }
    args_path = tmp / "args.json"
    args_path.write_text(json.dumps(a))
    # export_fmu compiled the FMUs' stepper into the per-user cache: the children load it.
    names = ["reference", "libcosim", "state", "errors", "instances"] + ["exit"] * EXIT_PROCESSES
    with ThreadPoolExecutor(max_workers=2) as pool:
        done = list(pool.map(lambda n: (n, _child(n, args_path, tmp)), names))
    out = {"exit": []}
    for name, (rc, result, err) in done:
        if name == "exit":
            out["exit"].append((rc, result, err))
        else:
            out[name] = (rc, result, err)
    return out


def _ok(runs, name):
    rc, result, err = runs[name]
    assert rc == 0, f"child {name} exited with {rc}:\n{err}"
    return result


def _io_system(**kw):
    p = dict(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, phi=0.0, e=0.9)
    p.update(kw)
    return ImpactOscillator(**p)


def test_fmpy_matches_core_1dof(runs):
    r = _ok(runs, "reference")
    ref = simulate(_io_system(), (1.0, 0.0), T_END, DT, scheme="trapezoid")   # the FMU's default, the core's
    res = r["io_H1"]
    assert len(res["time"]) == len(ref.t)
    np.testing.assert_allclose(res["time"], ref.t, rtol=0, atol=1e-12)
    assert np.max(np.abs(np.array(res["q"]) - ref.q[:, 0])) <= 1e-12
    assert np.max(np.abs(np.array(res["u"]) - ref.u[:, 0])) <= 1e-12
    assert res["impacts"][-1] == ref.impacts > 0
    np.testing.assert_allclose(res["percussion"], ref.percussion, rtol=0, atol=1e-12)
    s = _io_system()
    assert np.max(np.abs(np.array(res["energy"]) - [s.energy(q, u) for q, u in zip(ref.q, ref.u)])) <= 1e-11
    np.testing.assert_array_equal(res["gap"], res["q"])  # w = 1, g0 = 0


def test_fmpy_matches_core_1dof_H_10dt(runs):
    r = _ok(runs, "reference")
    ref = simulate(_io_system(), (1.0, 0.0), T_END, DT, scheme="trapezoid", record_every=10)
    res = r["io_H10"]
    assert len(res["time"]) == len(ref.t)
    assert np.max(np.abs(np.array(res["q"]) - ref.q[:, 0])) <= 1e-12
    assert np.max(np.abs(np.array(res["u"]) - ref.u[:, 0])) <= 1e-12


def test_fmpy_matches_core_theta_scheme(runs):
    r = _ok(runs, "reference")
    ref = simulate(_io_system(e=0.6), (1.0, 0.0), T_END, DT, scheme="theta", theta=0.75)
    res = r["io_theta"]
    assert np.max(np.abs(np.array(res["q"]) - ref.q[:, 0])) <= 1e-12
    assert np.max(np.abs(np.array(res["u"]) - ref.u[:, 0])) <= 1e-12


def test_fmpy_matches_core_2dof(runs):
    r = _ok(runs, "reference")
    system = MechanicalSystem(M=[[2.0, 0.5], [0.5, 1.0]], K=[[3.0, -1.0], [-1.0, 2.0]],
                              C=[[0.02, 0.0], [0.0, 0.02]], f0=[0.1, 0.2], w=[1.0, 0.5], g0=0.0,
                              e=0.7, forcing=(([0.6, 0.0], 1.3, 0.0),))
    ref = simulate(system, ([0.6, 0.2], [0.0, 0.0]), T_END, DT)
    res = r["ms2"]
    for i in range(2):
        assert np.max(np.abs(np.array(res[f"q[{i + 1}]"]) - ref.q[:, i])) <= 1e-12
        assert np.max(np.abs(np.array(res[f"u[{i + 1}]"]) - ref.u[:, i])) <= 1e-12
    assert res["impacts"][-1] == ref.impacts > 0
    np.testing.assert_allclose(res["gap"], ref.q @ system.w + system.g0, rtol=0, atol=1e-12)


def test_libcosimpy_matches_fmpy(runs):
    cosim = _ok(runs, "libcosim")
    assert cosim["ok"], cosim
    fm = np.array(_ok(runs, "reference")["io_loop"])
    lc = np.array(cosim["q_u"])
    assert lc.shape == fm.shape == (3000, 2)
    assert np.max(np.abs(lc - fm)) <= 1e-12
    assert np.ptp(fm[:, 0]) > 0.1  # it moved


@pytest.mark.parametrize("key", ["io", "ms2"])
def test_fmu_state_round_trips_reproduce_the_run(runs, key):
    r = _ok(runs, "state")[key]
    assert r["statuses"] == [0, 0]
    assert r["same_at_restore"] and r["same_at_restore_bytes"]
    assert r["identical_in_memory"], "restoring the in-memory state did not reproduce the run bit for bit"
    assert r["identical_from_bytes"], "restoring the serialised state did not reproduce the run bit for bit"
    assert r["t_end"] == pytest.approx(r["t_expected"], abs=1e-12)   # variable steps accepted
    assert r["errors"] == []
    from fmu_sync.fmus.slave import unseal
    head = r["blob"].split("\n", 1)[0]         # the format and the sha256 of the JSON body
    assert head.startswith("fmu-sync-state/4 ") and len(head.split()[1]) == 64
    state = json.loads(unseal(r["blob"].encode()))   # JSON, everything that determines the future
    assert state["format"] == "fmu-sync-state/4"
    for k in ("time", "q", "u", "tau", "taudot", "vref", "impacts", "percussion", "parameters", "phase"):
        assert k in state
    assert state["parameters"]["solver.dt"] == DT


def test_several_instances_in_one_process(runs):
    r = _ok(runs, "instances")
    assert len(set(map(tuple, r["refcounts"]))) == 1, r["refcounts"]  # nothing grows per instantiation
    assert r["last"] == r["alone"]                         # independent, bit for bit
    assert len({tuple(x) for x in r["last"]}) == 4


ERROR = 3


def test_nan_inf_and_huge_input_are_refused(runs):
    r = _ok(runs, "errors")["input"]
    for set_st, tau_after, step in r["cases"]:
        assert set_st == ERROR          # fmi2SetReal refuses the value
        assert tau_after == r["tau0"]   # ... and keeps the old one
        assert step == 0                # the instance stays usable
    assert r["fixed"] == [0, 0, 0.2]
    text = " ".join(r["errors"])
    for bad in ("nan", "inf", "-inf", "1e+300", "-1e+13"):
        assert f"input tau = {bad} rejected" in text, bad
    assert "<= 1e+12" in text     # the documented bound is named


def test_refusals_are_logged_with_logging_off(runs):
    r = _ok(runs, "errors")["input_nolog"]
    assert r["set"] == ERROR and r["step"] == 0
    assert any("input tau = nan rejected" in m for m in r["errors"])


@pytest.mark.parametrize("case, words", [
    ("e=1.5", ["e", "<= 1"]), ("e=nan", ["e", "finite"]), ("m=-1.0", ["m", "> 0"]), ("m=0.0", ["m", "> 0"]),
    ("solver.dt=0.0", ["solver.dt", "> 0"]), ("solver.theta=0.3", ["solver.theta", ">= 0.5"]),
    ("k=-2.0", ["k", ">= 0"]), ("u_start=2000000000000.0", ["u_start", "<= 1e+12"]),
    ("solver.scheme=7", ["solver.scheme", "midpoint"]),
])
def test_parameter_out_of_bounds(runs, case, words):
    r = _ok(runs, "errors")["params"][case]
    name, value = case.split("=")
    assert r["init"] == ERROR            # the set call is refused
    assert r["value"] != float(value) if value != "nan" else not math.isnan(r["value"])
    assert r["step"] == 0 and math.isfinite(r["q"])   # the start value stays: still usable
    assert r["errors"] and all(w in r["errors"][0] for w in words), r["errors"]
    assert "rejected" in r["errors"][0]
    assert r["after_reset"] == [0, 0]


@pytest.mark.parametrize("case, words", [
    ("gap", ["q_start violates the constraint: g(q)", "< 0"]),
    ("gap_1dof", ["q_start violates the constraint: g(q)", "< 0"]), ("asymmetric", ["symmetric"]), ("not_pd", ["positive definite"]),
    ("w_zero", ["nonzero"]),
])
def test_invalid_model_is_refused(runs, case, words):
    r = _ok(runs, "errors")["model"][case]
    assert r["init"] == ERROR and r["step"] == ERROR      # exitInitializationMode refused; still initializing
    assert all(w in r["errors"][0] for w in words), r["errors"]
    assert "fmi2ExitInitializationMode" in r["errors"][0]
    assert r["fix"] == [0, 0, 0]                          # fixed parameters: it runs


def test_bad_communication_steps(runs):
    """Invalid doStep arguments are fmi2Error (FMI 2.0: fmi2Discard only for a step computed over a
    subinterval), with the reason logged; nothing changes."""
    r = _ok(runs, "errors")["steps"]
    assert set(r["statuses"].values()) == {ERROR}, r["statuses"]
    assert r["continue"] == [0, 0]
    assert r["last_successful_time"] == pytest.approx(0.05)
    assert r["same_as_clean"], "refused steps changed the state"
    msgs = " ".join(r["messages"])
    assert "step size -0.01 rejected" in msgs and "not the slave's time" in msgs
    assert "H = 1e+06" in msgs and "1e+09 internal steps" in msgs and "solver.dt = 0.001" in msgs


@pytest.mark.parametrize("dt, count", [("1e-12", "1e+10"), ("1e-300", "1e+298")])
def test_too_many_internal_steps_are_refused(runs, dt, count):
    r = _ok(runs, "errors")["guards"][dt]
    assert r["init"] == 0 and r["step"] == ERROR and r["q_u"] == r["q0"]
    msg = r["errors"][0]
    assert f"{count} internal steps" in msg and f"solver.dt = {dt}" in msg and "H = 0.01" in msg
    assert "10000000" in msg and "can never complete" in msg     # the documented limit
    # known from the parameters alone: said at fmi2ExitInitializationMode already (logged, status OK)
    notice = [m for m in r["notices"] if "fmi2ExitInitializationMode" in m]
    assert notice and f"{count} internal steps" in notice[0] and "default experiment" in notice[0], r["notices"]


def test_calls_in_the_wrong_state(runs):
    w = _ok(runs, "errors")["order"]
    assert w["step_before_init"] == ERROR and w["get_before_init"] == ERROR and w["step_in_init"] == ERROR
    assert w["set_output"] == ERROR and w["exit"] == 0 and w["step_ok"] == 0
    assert w["set_param_late"] == ERROR and w["e_unchanged"] == 0.9
    assert w["unknown_vr"] == [ERROR] * 5 and w["m_unchanged"] == 1.0
    assert w["wrong_type"] == [ERROR, ERROR]
    assert w["step_ok2"] == 0
    assert w["enter_init_again"] == ERROR and w["exit_again"] == ERROR and w["step_ok3"] == 0
    assert w["terminate"] == 0 and w["step_after_terminate"] == ERROR and w["set_after_terminate"] == ERROR
    assert w["terminate_again"] == ERROR and w["get_after_terminate"] == 0
    assert not w["dead"]
    text = " ".join(w["errors"])
    for words in ("call fmi2ExitInitializationMode first", "q is an output", "cannot set parameter e",
                  "unknown value reference 999", "unknown value reference 4294967295",
                  "unknown value reference 4294967283", "is impacts, of type Integer",
                  "fmi2DoStep refused in state 'terminated'", "fmi2SetReal refused in state 'terminated'",
                  "fmi2EnterInitializationMode refused in state 'step mode'"):
        assert words in text, words


def test_scheme_known_to_diverge_is_refused(runs):
    r = _ok(runs, "errors")["unstable"]
    assert r["init"] == ERROR and r["step"] == ERROR
    assert any("midpoint" in m and "omega_max*dt = 100" in m for m in r["errors"])


def test_divergence_is_rolled_back(runs):
    r = _ok(runs, "errors")["diverge"]
    assert r["step"] == ERROR
    assert r["q_u"] == r["q0"] and all(math.isfinite(x) for x in r["q_u"]) and r["energy_finite"]
    assert r["last_successful_time"] == 0.0
    assert any("non-finite" in m and "rolled back" in m for m in r["errors"])


def test_bad_fmu_state_is_refused(runs):
    r = _ok(runs, "errors")["state"]
    assert r["deserialize_garbage"] == ERROR and r["set_null"] == ERROR and r["deserialize_other"] == ERROR
    assert r["corrupt"] == {k: ERROR for k in r["corrupt"]}, r["corrupt"]
    assert r["unchanged"] and r["step_ok"] == 0 and r["moved"]
    text = " ".join(r["errors"])
    for words in ("cannot deserialise the FMU state", "state of model 'mechanical-system-2'",
                  "q must be a list of 1 finite numbers", "impacts must be a non-negative integer",
                  "input tau", "parameter e", "inside the wall", "penetration bound", "missing entry 'time'",
                  "q = [1e+300] out of range", "u = [-2000000000000.0] out of range", "<= 1e+12"):
        assert words in text, words


@pytest.mark.parametrize("case, words", [
    ("wrong_guid", ["GUID", "does not match"]), ("model_exchange", ["Model Exchange", "Co-Simulation only"]),
    ("no_resources", ["is not a folder"]), ("not_a_file_uri", ["not a file: URI"]), ("null_uri", ["NULL"]),
])
def test_instantiate_refusals(runs, case, words):
    r = _ok(runs, "errors")["instantiate"]
    assert r[case]["null"], r[case]
    assert r[case]["messages"] and r[case]["messages"][0][0] == ERROR
    assert all(w in r[case]["messages"][0][1] for w in words), r[case]["messages"]
    assert not r["ok"]["null"]


def test_null_component_is_refused(runs):
    assert _ok(runs, "errors")["instantiate"]["null_component"] == [ERROR] * 4


def test_fresh_processes_exit_cleanly(runs):
    """EXIT_PROCESSES fresh fmpy processes (python -m fmu_sync.benchmarks.fmu_cost --exit-check 200
    runs 200): all exit 0."""
    results = runs["exit"]
    assert len(results) == EXIT_PROCESSES
    failed = [(rc, err.strip().splitlines()[-1:] if err else "") for rc, _, err in results if rc != 0]
    assert not failed, f"{len(failed)} of {len(results)} processes exited non-zero: {failed[:3]}"
    assert all(math.isfinite(res["q"]) for _, res, _ in results)


if __name__ == "__main__":
    _child_main(sys.argv[1:])
