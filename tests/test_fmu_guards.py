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
def fmus(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("guards")
    return {"io": export_fmu("impact-oscillator", tmp / "io.fmu"),
            "exact": export_fmu("impact-oscillator", tmp / "exact.fmu", {"solver.scheme": "exact"}),
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
