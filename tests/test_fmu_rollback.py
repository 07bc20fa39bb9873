"""Fast rollback (issue 33 item 4): our FMUs save and restore an FMU state natively (a copy of the
variable and work arrays in the binary, fmus/c/fmu_sync_runtime.c), without Python.

Reference: the Python restore the binary used before (``InstanceBase.set_state``: the state checked,
the parameters, the configuration and the outputs rebuilt), which ``fmi2DeSerializeFMUstate`` still
runs. A native restore must give the numbers that restore gives, bit for bit, and the run it rolls
back must repeat bit for bit; FMI's semantics hold (a state can be set many times, is freed once,
and another instance's state is refused with fmi2Error).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fmu_sync.master as master
from fmu_sync.fmi3_bridge import FMU3Host
from fmu_sync.fmi_bridge import FMUHost
from fmu_sync.master import cosimulate

from _master_reference import PythonMaster
from builtin_scenes import FORCED_GAINS as GAINS
from builtin_scenes import FORCED_X1 as X1
from builtin_scenes import FORCED_X2 as X2

ERROR = 3
#: (fmu key, the variables compared, the inputs driven, start values)
KINDS = {
    "io-theta": (["q", "u", "gap", "energy", "impacts", "percussion"], ["tau"], {"solver.scheme": 2,
                                                                                 "solver.theta": 0.6}),
    "io-exact": (["q", "u", "gap", "energy", "impacts", "percussion"], ["tau"], {}),
    "ms2": (["q[1]", "q[2]", "u[1]", "u[2]", "gap", "energy", "impacts", "percussion"], ["tau[1]", "tau[2]"], {}),
    "coupling": (["tau[1]", "tau[2]", "d[1]", "V[1]"], ["q[1]", "q[2]", "u[1]", "u[2]"], {}),
}


@pytest.fixture(scope="module")
def fmus(shared_fmu):
    return {"io-theta": str(shared_fmu()), "io-exact": str(shared_fmu(start_values={"solver.scheme": "exact"})),
            "ms2": str(shared_fmu("mechanical-system-2")),
            "coupling": str(shared_fmu("coupling")), "io3": str(shared_fmu(fmi_version=3))}


def _drive(h, t, steps, inputs, seed):
    """Step h from t through ``steps`` with inputs that vary with the step (a fixed sequence)."""
    rows = []
    for k, H in enumerate(steps):
        val = {name: 0.2 * math.sin(3.0 * t + j + seed) + 0.05 * k / len(steps) for j, name in enumerate(inputs)}
        if inputs[0].startswith("q"):      # the coupling: states above the wall (g = q + 1 > 0)
            val = {n: (abs(v) if n.startswith("q") else v) for n, v in val.items()}
        assert h.set(val) == 0, h.errors()
        assert h.do_step(t, H) <= 1, h.errors()
        t += H
        rows.append(h.get(KINDS_NAMES[h.kind]))
    return t, rows


KINDS_NAMES = {k: v[0] for k, v in KINDS.items()}


def _host(fmus, kind, name):
    h = FMUHost(fmus[kind], name)
    h.kind = kind
    return h


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=st.sampled_from(sorted(KINDS)), before=st.integers(1, 30), after=st.integers(1, 30),
       H=st.sampled_from([0.0137, 0.01, 0.002, 0.0301]), seed=st.integers(0, 5))
def test_native_restore_is_bitwise_the_python_restore_and_repeats_the_run(fmus, kind, before, after, H, seed):
    names, inputs, starts = KINDS[kind]
    h = _host(fmus, kind, "h")
    try:
        if kind.startswith("io"):
            starts = {**starts, "q_start": 0.3}
        assert h.initialize(0.0, starts) == 0, h.errors()
        t0, _ = _drive(h, 0.0, [H] * before, inputs, seed)
        st_, native = h.get_state()
        assert st_ == 0
        at_save = h.get(names)
        blob = h.serialize_state(native)
        _, ref = _drive(h, t0, [H] * after, inputs, seed + 1)
        # the native state, set twice (a state can be set many times)
        for _ in range(2):
            assert h.set_state(native) == 0, h.errors()
            assert h.get(names) == at_save
            _, again = _drive(h, t0, [H] * after, inputs, seed + 1)
            assert again == ref
        # the Python restore (deserialised into this instance): the same arrays, the same run
        st_, python = h.deserialize_state(blob)
        assert st_ == 0, h.errors()
        assert h.serialize_state(python) == blob     # every saved field equal
        assert h.set_state(python) == 0 and h.get(names) == at_save
        _, again = _drive(h, t0, [H] * after, inputs, seed + 1)
        assert again == ref
        assert h.free_state(native) == 0 and h.free_state(python) == 0
    finally:
        h.close()


def test_fmi3_native_restore_repeats_the_run_with_a_pending_impact(fmus):
    """FMI 3.0 shares the path: a state saved at an early return in event mode (the impact pending)
    restores natively and repeats the run bit for bit, the same as its deserialised copy."""
    with FMU3Host(fmus["io3"], "a") as h:
        assert h.initialize(0.0, {"q_start": 0.1, "u_start": -1.0}) == 0
        t = 0.0
        while not h.event_needed:
            assert h.do_step(t, 0.05) == 0
            t = h.last_time
        st_, s = h.get_state()
        blob = h.serialize_state(s)

        def run():
            assert h.handle_event() == 0
            out, tt = [], h.last_time
            for _ in range(20):
                assert h.do_step(tt, 0.01) == 0
                tt = h.last_time
                out.append(h.get(["q", "u", "impacts", "time"]))
            return out
        ref = run()
        assert h.set_state(s) == 0
        assert run() == ref
        st_, s2 = h.deserialize_state(blob)
        assert st_ == 0 and h.set_state(s2) == 0
        assert run() == ref
        h.free_state(s)
        h.free_state(s2)


def test_a_state_of_another_instance_is_refused(fmus, tmp_path):
    """Two instances of one loaded binary (one unpacked folder) and an instance of another FMU: a
    state is set, freed and overwritten by the instance that saved it only (fmi2Error, the reason
    logged, nothing changed)."""
    from fmpy import extract
    folder = extract(fmus["io-theta"], unzipdir=str(tmp_path / "io"))
    with FMUHost(folder, "a") as a, FMUHost(folder, "b") as b, FMUHost(fmus["ms2"], "c") as c:
        for x in (a, b, c):
            assert x.initialize(0.0) == 0
        assert a.do_step(0.0, 0.01) == 0
        _, sa = a.get_state()
        _, sc = c.get_state()
        q_b = b.get(["q", "u"])
        for host, state, words in ((b, sa, "an FMU state of another instance"),
                                   (a, sc, "not an FMU state of this FMU")):
            n0 = len(host.messages)
            assert host.set_state(state) == ERROR
            assert any(words in m for _, _, m in host.messages[n0:]), host.messages[n0:]
        assert b.get(["q", "u"]) == q_b                     # refused: nothing changed
        assert b.free_state(sa) == ERROR                    # only its owner frees it
        import ctypes                                       # nor overwrites it (fmi2GetFMUstate in place)
        handle = ctypes.c_void_p(sa.value)
        assert b.fmu.dll.fmi2GetFMUstate(b.fmu.component, ctypes.byref(handle)) == ERROR
        assert handle.value == sa.value
        assert a.free_state(sa) == 0
        assert c.free_state(sc) == 0


def test_event_aware_retakes_with_native_rollback_are_bitwise_the_python_restore(shared_fmu, monkeypatch):
    """The master's event-aware retake (the compiled loop, native fmi2SetFMUstate) against the Python
    reference loop restoring every retaken step from a deserialised copy of the state (the restore
    the binary used to make): the same numbers, bit for bit, with retakes."""
    fmu = shared_fmu(start_values={"solver.dt": 1e-3})
    args = dict(coupling="euclidean", event_aware=True, H_min=1e-3, **GAINS)
    new = cosimulate(fmu, X1, X2, 6.0, 1e-2, **args)

    def restore(self, state, t):
        st_, copy = self.deserialize_state(self.serialize_state(state))
        assert st_ == 0
        status = self.set_state(copy)
        self.free_state(copy)
        self.t = t
        return status

    with monkeypatch.context() as m:
        m.setattr(master, "NetworkMaster", PythonMaster)
        m.setattr(FMUHost, "restore", restore)
        ref = cosimulate(fmu, X1, X2, 6.0, 1e-2, **args)
    assert new.info["retaken_steps"] > 0
    assert new.info["retaken_steps"] == ref.info["retaken_steps"]
    for f in ("t", "q1", "u1", "q2", "u2", "tau1", "tau2", "d"):
        assert np.array_equal(getattr(new, f), getattr(ref, f), equal_nan=True), f
