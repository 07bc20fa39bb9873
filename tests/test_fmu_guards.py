"""Steps that can never complete, and the FMU's other guards (docs/design.md §5.1).

Every standard importer must stop with the reason: a doStep that can never
complete (too many internal steps, a state that turns non-finite) is fmi2Error,
so fmpy's ``simulate_fmu`` and ``fmpy simulate`` end at once with a non-zero
exit (they retried a discarded step forever before). Also: stopTime enforced, a
time that cannot advance refused, the exact scheme's work guard, serialized
states protected by a checksum (random bit flips refused, never a crash), the
cache-folder and numba messages for the host at hand, and the exported file's mode.

FMUs run in child processes (``python tests/test_fmu_guards.py SCENARIO FMU``),
never in the pytest process; the child prints one JSON line.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import stat
import subprocess
import sys
import time
from pathlib import Path

ERROR = 3


# =============================================================== child side
def _fresh(path, starts=None, start_time=0.0, name="guard"):
    from fmu_sync.fmi_bridge import FMUHost
    h = FMUHost(path, instance_name=name, logging=True)
    return h, h.initialize(start_time, starts or {})


def scenario_time(fmu):
    """stopTime enforced; a start time where t + H == t refused."""
    from fmu_sync.fmi_bridge import FMUHost
    out = {}
    h = FMUHost(fmu, instance_name="stop", logging=True)
    h.call("setupExperiment", None, 0.0, 0.05)            # stopTime = 0.05
    h.call("enterInitializationMode")
    h.exit_initialization()
    out["to_stop"] = [h.do_step(k * 0.01, 0.01) for k in range(5)]
    q = h.get(["q", "u"])
    out["past_stop"] = h.do_step(0.05, 0.01)
    out["past_stop_unchanged"] = h.get(["q", "u"]) == q
    out["stop_errors"] = h.errors()
    h.close()
    h, st = _fresh(fmu, start_time=1e300, name="late")
    q = h.get(["q", "u"])
    out["late_init"] = st
    out["late_steps"] = [h.do_step(1e300, 0.01) for _ in range(3)]
    out["late_unchanged"] = h.get(["q", "u"]) == q
    out["late_errors"] = h.errors()
    h.close()
    return out


def scenario_exact_guard(fmu):
    """The exact scheme's work guard: a doStep of H = 1e9 fails (rolled back) instead of running on."""
    h, st = _fresh(fmu, name="exact")
    q = h.get(["q", "u"])
    t0 = time.perf_counter()
    status = h.do_step(0.0, 1e9)
    seconds = time.perf_counter() - t0
    out = {"init": st, "status": status, "seconds": seconds, "unchanged": h.get(["q", "u"]) == q,
           "errors": h.errors(), "then": h.do_step(0.0, 0.01)}
    h.close()
    return out


def scenario_bit_flips(fmu, flips=2000, seed=16):
    """2000 serialized states, each with one random bit flipped: deserialise and restore each."""
    import random
    h, _ = _fresh(fmu, name="flips")
    for k in range(10):
        h.do_step(k * 0.01, 0.01)
    st, state = h.get_state()
    blob = h.serialize_state(state)
    ref = h.get(["q", "u"])
    rng = random.Random(seed)
    refused = accepted = 0
    reasons = set()
    for _ in range(flips):
        bad = bytearray(blob)
        bit = rng.randrange(8 * len(bad))
        bad[bit // 8] ^= 1 << (bit % 8)
        n0 = len(h.messages)
        s, restored = h.deserialize_state(bytes(bad))
        if s >= ERROR:
            refused += 1
            reasons.update(m.split(": ")[-1][:40] for _, _, m in h.messages[n0:])
        else:
            accepted += 1
            h.set_state(restored)
            h.free_state(restored)
        del h.messages[:]
    s_ok, good = h.deserialize_state(blob)
    out = {"bytes": len(blob), "refused": refused, "accepted": accepted, "reasons": sorted(reasons)[:5],
           "good": s_ok, "good_restores": h.set_state(good), "same": h.get(["q", "u"]) == ref}
    h.free_state(good)
    h.free_state(state)
    h.close()
    return out


def scenario_simulate_fmu(fmu):
    """fmpy's simulate_fmu with a step that can never complete: it raises at once, reason logged."""
    from fmpy import simulate_fmu
    out = {}
    for label, starts in (("dt", {"solver.dt": 1e-12}), ("overflow", {"F": 1e300})):
        msgs = []
        t0 = time.perf_counter()
        try:
            simulate_fmu(fmu, stop_time=1.0, start_values=starts,
                         logger=lambda *a: msgs.append(a[-1].decode() if isinstance(a[-1], bytes) else str(a[-1])))
            raised = None
        except Exception as exc:                     # fmpy.fmi1.FMICallException
            raised = [type(exc).__name__, int(getattr(exc, "status", -1))]
        out[label] = {"raised": raised, "seconds": time.perf_counter() - t0, "messages": msgs}
    return out


def scenario_init_outputs(fmu):
    """Outputs read in initialization mode while the parameters are not a valid system (M not
    symmetric): fmi2GetReal's status (the raw call) and the log; then the parameters made valid."""
    import ctypes
    from fmu_sync.fmi_bridge import FMUHost
    h = FMUHost(fmu, instance_name="init", logging=True)
    h.call("setupExperiment", None, 0.0, None)
    h.call("enterInitializationMode")
    h.set({"M[1,2]": 0.3})   # M[2,1] = 0.5: not symmetric
    names = ["gap", "energy"]
    vr = (ctypes.c_uint * 2)(*[h.vr(n) for n in names])
    val = (ctypes.c_double * 2)()
    out = {"status": int(h.fmu.fmi2GetReal(h.fmu.component, vr, 2, val)), "values": [repr(v) for v in val],
           "log": " ".join(h.errors(min_status=1))}
    h.set({"M[1,2]": 0.5})
    out["valid_status"] = int(h.fmu.fmi2GetReal(h.fmu.component, vr, 2, val))
    out["valid_values"] = list(val)
    h.close()
    return out


def _coupling_slave(fmu, calls, messages):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
    md = read_model_description(str(fmu))
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu)), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="wall", fmiCallLogger=calls.append)

    def log(env, name, status, category, message):
        messages.append([int(status), message.decode()])
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(log)
    s.instantiate(callbacks=cb, loggingOn=True)
    s._keep = cb
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    return s, {v.name: v.valueReference for v in md.modelVariables}


def scenario_coupling_wall(fmu):
    """The coupling FMU given system states inside the wall: the status of each call (fmpy's
    call log) and the warnings; a state deep inside (q[1] = -0.5), then a Moreau-sized one."""
    calls, messages, out = [], [], {}
    s, vr = _coupling_slave(fmu, calls, messages)
    ins = [vr[k] for k in ("q[1]", "u[1]", "q[2]", "u[2]")]
    outs = [vr[k] for k in ("tau[1]", "tau[2]", "d[1]")]

    def status(label, f):
        n = len(calls)
        value = f()
        out[label] = {"status": calls[n:][-1].rsplit("-> ", 1)[-1], "value": value,
                      "log": [m for st, m in messages if st == 1]}
        messages.clear()
    s.setReal(ins, [-0.5, 0.0, 0.3, 0.0])
    status("deep_get", lambda: list(s.getReal(outs)))
    status("deep_step", lambda: s.doStep(0.0, 0.01))
    # after a step of H = 0.01: 1 mm inside at 0.5 m/s outward (an impact at e = 0.9 from ~0.56 m/s)
    s.setReal(ins, [-1e-3, 0.5, 0.3, 0.0])
    status("moreau_get", lambda: list(s.getReal(outs)))
    status("moreau_step", lambda: s.doStep(0.01, 0.01))
    s.setReal(ins, [-0.5, 0.5, 0.3, 0.0])
    status("deep_again", lambda: list(s.getReal(outs)))
    s.terminate()
    s.freeInstance()
    return out


def scenario_natural_cosim(package):
    """fmpy's SSP runner over a package (two oscillator FMUs through the coupling FMU): the
    status of every FMI call and the states' deepest penetration."""
    import fmpy.ssp.simulation as sim
    from fmu_sync.ssp import fmpy_parameter_set, read_ssp
    calls = []
    make = sim.FMU2Slave
    sim.FMU2Slave = lambda **kw: make(fmiCallLogger=calls.append, **kw)
    H = read_ssp(package).H
    r = sim.simulate_ssp(str(package), stop_time=100.0 - H / 2, step_size=H,
                         parameter_set=fmpy_parameter_set(package))
    statuses = {}
    for c in calls:
        if " -> " in c and c.startswith("fmi2") and not c.startswith(("fmi2Instantiate", "fmi2FreeInstance")):
            key = c.rsplit(" -> ", 1)[-1]
            statuses[key] = statuses.get(key, 0) + 1
    q = [float(min(r["system1.q"].min(), r["system2.q"].min())), int((r["system1.q"] < 0).sum()
                                                                    + (r["system2.q"] < 0).sum())]
    return {"statuses": statuses, "min_q": q[0], "inside": q[1]}


def _child_main(argv):
    name, fmu = argv
    print(json.dumps(globals()[f"scenario_{name}"](fmu)))


# =============================================================== parent side
import pytest  # noqa: E402

from fmu_sync.export import export_fmu  # noqa: E402


def _child(name, fmu, timeout=300):
    p = subprocess.run([sys.executable, __file__, name, str(fmu)], capture_output=True, text=True,
                       timeout=timeout)
    assert p.returncode == 0, f"child {name} exited with {p.returncode}:\n{p.stderr[-3000:]}"
    return json.loads(p.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, shared_fmu):
    tmp = tmp_path_factory.mktemp("guards")
    return {"io": shared_fmu("impact-oscillator"),
            "exact": shared_fmu(start_values={"solver.scheme": "exact"}),
            "tmp": tmp}


def test_simulate_fmu_stops_at_a_step_that_can_never_complete(fmus):
    r = _child("simulate_fmu", fmus["io"])
    for label, words in (("dt", ["1e+10 internal steps", "can never complete"]),
                         ("overflow", ["non-finite", "rolled back", "can never complete"])):
        assert r[label]["raised"] == ["FMICallException", ERROR], r[label]
        text = " ".join(r[label]["messages"])
        assert all(w in text for w in words), r[label]["messages"]


@pytest.mark.parametrize("start, words", [("solver.dt=1e-12", "internal steps"), ("F=1e300", "non-finite")])
def test_fmpy_simulate_command_ends_with_the_reason(fmus, start, words):
    """``fmpy simulate`` ends (non-zero exit, reason printed) instead of retrying one step forever."""
    name, value = start.split("=")
    p = subprocess.run([sys.executable, "-m", "fmpy", "simulate", str(fmus["io"]), "--stop-time", "1",
                        "--start-values", name, value], capture_output=True, text=True, timeout=300,
                       cwd=fmus["tmp"])
    assert p.returncode != 0
    out = p.stdout + p.stderr
    assert words in out and "can never complete" in out and "status 3" in out, out[-2000:]


def test_stop_time_and_a_time_that_cannot_advance(fmus):
    r = _child("time", fmus["io"])
    assert r["to_stop"] == [0] * 5                         # steps up to stopTime itself are fine
    assert r["past_stop"] == ERROR and r["past_stop_unchanged"]
    assert any("past the experiment's stopTime = 0.05" in m for m in r["stop_errors"]), r["stop_errors"]
    assert r["late_init"] == 0 and r["late_steps"] == [ERROR] * 3 and r["late_unchanged"]
    assert any("cannot advance" in m and "t = 1e+300" in m for m in r["late_errors"]), r["late_errors"]


def test_exact_scheme_work_guard(fmus):
    from fmu_sync.fmus.stepper import EXACT_MAX_EVENTS
    r = _child("exact_guard", fmus["exact"])
    assert r["init"] == 0 and r["status"] == ERROR and r["unchanged"]
    assert any(f"more than {EXACT_MAX_EVENTS} events" in m and "work guard" in m for m in r["errors"]), r["errors"]
    assert r["then"] == 0                                  # the instance stays usable


def test_random_bit_flips_of_a_serialized_state_are_refused(fmus):
    r = _child("bit_flips", fmus["io"])
    assert r["refused"] + r["accepted"] == 2000
    assert r["refused"] >= 0.999 * 2000, r
    assert r["good"] == 0 and r["good_restores"] == 0 and r["same"]


def test_exported_fmu_is_readable_by_others(tmp_path):
    old = os.umask(0o022)
    try:
        path = export_fmu("impact-oscillator", tmp_path / "io.fmu")
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


# --------------------------------------------------------------- messages for the host at hand
def test_missing_numpy_in_a_python_host_names_that_host(monkeypatch):
    """numpy is what the target needs; numba is not asked for (the stepper is native code)."""
    from fmu_sync.fmus import boot
    monkeypatch.setattr(boot, "_version", lambda dist: None)
    py_host = " ".join(boot.check_runtime({"numpy": "1"}, embedded=False))
    assert "lacks numpy" in py_host and sys.executable in py_host and "-m pip install numpy" in py_host
    assert "numba" not in py_host
    assert "FMU_SYNC_PYTHON is ignored" in py_host and "set FMU_SYNC_PYTHON" not in py_host
    c_host = " ".join(boot.check_runtime({"numpy": "1"}, embedded=True))
    assert "lacks numpy" in c_host and "set FMU_SYNC_PYTHON" in c_host and "plain C program" in c_host


def test_no_writable_cache_folder_gives_the_advice(tmp_path, monkeypatch):
    """Every candidate unusable (here: below a regular file): the advice, not a raw OSError."""
    from fmu_sync.fmus import boot
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.delenv("FMU_SYNC_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker / "cache"))
    monkeypatch.setenv("TMPDIR", str(blocker / "tmp"))
    monkeypatch.setattr(boot, "TMP_DIRS", (str(blocker / "tmp2"), str(blocker / "vartmp")))
    with pytest.raises(boot.SetupError) as exc:
        boot.cache_root(embedded=False)
    text = str(exc.value)
    assert "no writable folder for the FMU's code" in text and "Set FMU_SYNC_CACHE" in text
    assert str(blocker / "cache") in text and "vartmp" in text and "Not a directory" in text


def test_a_read_only_cache_that_holds_the_code_is_used(tmp_path, monkeypatch):
    """Nothing is compiled on the target, so a cache folder that already holds the unpacked code
    is all the FMU needs, writable or not (here: every folder refused as unwritable)."""
    from fmu_sync.fmus import boot
    res = tmp_path / "resources"
    (res / boot.CODE_DIR / "core").mkdir(parents=True)
    (res / boot.CODE_DIR / "__init__.py").write_text("")
    (res / boot.CODE_DIR / "core" / "m.py").write_text("X = 1\n")
    build = {"code_hash": boot.code_hash(str(res / boot.CODE_DIR)), "package": "fmu_sync_mtest"}
    monkeypatch.setenv("FMU_SYNC_CACHE", str(tmp_path / "cache"))
    first = boot.unpack(str(res), build)
    assert Path(first, build["package"], "core", "m.py").read_text() == "X = 1\n"

    def unwritable(embedded=False):
        raise boot.SetupError("no writable folder")
    monkeypatch.setattr(boot, "cache_root", unwritable)
    assert boot.unpack(str(res), build) == first
    Path(first, build["package"], "core", "m.py").write_text("X = 2\n")     # damaged: not used
    with pytest.raises(boot.SetupError):
        boot.unpack(str(res), build)


_RO = shutil.which("unshare") and subprocess.run(
    ["unshare", "-rm", "sh", "-c", "mount --bind -o ro /tmp /tmp && ! touch /tmp/.fmu-sync-ro-probe"],
    capture_output=True).returncode == 0


@pytest.mark.skipif(not _RO, reason="needs unshare -rm (user + mount namespaces) for read-only bind mounts; "
                                    "test_no_writable_cache_folder_gives_the_advice covers the message")
def test_read_only_home_and_tmp_in_a_real_importer(fmus, tmp_path):
    """HOME, /tmp and /var/tmp read-only (bind mounts in a private mount namespace): fmpy's
    simulate_fmu fails at fmi2Instantiate with the advice, and FMU_SYNC_CACHE fixes it."""
    import zipfile
    home, unz, cache = tmp_path / "home", tmp_path / "unz", tmp_path / "cache"
    for d in (home, cache):
        d.mkdir()
    with zipfile.ZipFile(fmus["io"]) as zf:           # fmpy itself needs a writable temp folder to unzip
        zf.extractall(unz)
    code = ("from fmpy import simulate_fmu\n"
            "msgs = []\n"
            "try:\n"
            f"    simulate_fmu({str(unz)!r}, stop_time=0.02, logger=lambda *a: msgs.append(str(a[-1])))\n"
            "    print('RAN')\n"
            "except Exception as exc:\n"
            "    print('FAILED', type(exc).__name__)\n"
            "print('\\n'.join(msgs))\n")
    script = tmp_path / "run.py"
    script.write_text(code)
    ro = (f"mount --bind -o ro {home} {home} && mount --bind -o ro /tmp /tmp && "
          f"mount --bind -o ro /var/tmp /var/tmp")
    env = {k: v for k, v in os.environ.items() if k not in ("FMU_SYNC_CACHE", "XDG_CACHE_HOME", "TMPDIR")}
    env["HOME"] = str(home)

    def run(extra=""):
        return subprocess.run(["unshare", "-rm", "sh", "-c", f"{ro}{extra} && {sys.executable} {script}"],
                              capture_output=True, text=True, timeout=300, env=env, cwd=home)
    p = run()
    out = p.stdout + p.stderr
    assert "FAILED" in out and "no writable folder for the FMU's code" in out, out[-3000:]
    assert "FileNotFoundError" not in out and "Set FMU_SYNC_CACHE" in out
    env["FMU_SYNC_CACHE"] = str(cache)
    p = run(f" && mount -t tmpfs none {cache}")             # a writable folder, named by FMU_SYNC_CACHE
    assert "RAN" in p.stdout, (p.stdout + p.stderr)[-3000:]


if __name__ == "__main__":
    _child_main(sys.argv[1:])


def test_outputs_in_initialization_mode_with_invalid_parameters_warn_with_the_reason(tmp_path):
    """NaN outputs while the parameters are not a valid system came with fmi2OK and no word (issue 28):
    now fmi2Warning, the reason logged; valid parameters give numbers and fmi2OK again."""
    fmu = export_fmu("mechanical-system-2", tmp_path / "m2.fmu")
    r = _child("init_outputs", fmu)
    assert r["status"] == 1 and r["values"] == ["nan", "nan"], r
    assert "not a valid system yet" in r["log"] and "symmetric" in r["log"], r["log"]
    assert r["valid_status"] == 0 and all(math.isfinite(v) for v in r["valid_values"]), r


def test_coupling_fmu_warns_of_states_inside_the_wall_beyond_the_moreau_penetration(tmp_path):
    """q[1] = -0.5 with the wall at 0 was fmi2OK, tau = +-0.5, no word (issue 28): now fmi2Warning
    (tau and d still computed) with the reason naming the system, its gap and the allowed bound; a
    penetration a Moreau step of H can leave (1 mm at 0.5 m/s, H = 0.01 s: bound 11 mm) stays fmi2OK."""
    from fmu_sync.export import export_coupling
    fmu = export_coupling(tmp_path / "c.fmu", n=1, start_values={"M": 1.0, "e": 0.9})
    r = _child("coupling_wall", fmu)
    for key in ("deep_get", "deep_step", "deep_again"):
        assert r[key]["status"] == "WARNING", (key, r[key])
        (msg,) = r[key]["log"]
        assert "system 1 inside the wall" in msg and "g(q) = w^T q + g0 = -0.5 m" in msg, msg
    assert "penetration 0 m (no step taken yet" in r["deep_get"]["log"][0]      # not "-0 m" (issue 35)
    assert "-0 m" not in r["deep_get"]["log"][0]
    # 2 H v = 2 (0.01) (0.5 / 0.9) = 0.0111, below the kept 1 mm of the contact before
    assert "-0.0121 m (2 H v with H = 0.01 s" in r["deep_again"]["log"][0]
    assert r["deep_get"]["value"][:2] == [0.8, -0.8] and math.isfinite(r["deep_get"]["value"][2])
    for key in ("moreau_get", "moreau_step"):
        assert r[key]["status"] == "OK" and not r[key]["log"], (key, r[key])


@pytest.mark.parametrize("scene, variant", [("forced-pair", "switching"), ("plastic", "plastic")])
def test_a_real_cosimulation_through_the_coupling_fmu_has_no_false_alarm(tmp_path, scene, variant):
    """Two oscillator FMUs through the coupling FMU in fmpy's SSP runner over 100 s: the Moreau
    penetrations the systems really have (e = 0.9 impacts; e = 0 contacts that last) are there
    and every FMI call returns fmi2OK."""
    from fmu_sync.ssp import write_ssp
    r = _child("natural_cosim", write_ssp(scene, tmp_path / f"{scene}.ssp", variant=variant))
    assert set(r["statuses"]) == {"OK"} and r["statuses"]["OK"] > 100_000, r
    assert r["inside"] >= 2 and -1e-3 < r["min_q"] < 0.0, r
