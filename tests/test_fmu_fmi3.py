"""The FMI 3.0 FMU (``fmu-sync export --fmi-version 3``): validation, early return
at impacts, event mode, statuses, FMU states, arrays.

References: the FMI 2.0 FMU of the same model (the numbers an FMI 3.0 run must
reproduce), the closed-form impact time of a dropped ball (sqrt(2 h / g)) and
fmpy's own validation and ``simulate_fmu`` as the third-party importer.
"""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fmu_sync.fmi3_bridge import ERROR, OK, WARNING, FMU3Host
from fmu_sync.fmi_bridge import FMUHost

BALL = {"k": 0.0, "f0": -9.81, "F": 0.0, "e": 0.8, "q_start": 1.0, "u_start": 0.0}


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    from fmu_sync.export import export_fmu
    d = tmp_path_factory.mktemp("fmi3")
    out = {}
    for key, model, starts in (("ball", "impact-oscillator", {**BALL, "solver.scheme": "exact"}),
                               ("osc", "impact-oscillator", {"solver.dt": 1e-3}),
                               ("ms", "mechanical-system-2", {})):
        for v in (2, 3):
            out[key, v] = str(export_fmu(model, d / f"{key}{v}.fmu", starts, fmi_version=v))
    return out


def _fmpy_run(path, stop, dt, **kw):
    from fmpy import simulate_fmu
    return simulate_fmu(path, stop_time=stop, output_interval=dt, **kw)


@pytest.mark.parametrize("key", ["ball", "osc", "ms"])
def test_fmi3_validates_and_fmpy_with_early_return_gives_the_fmi2_numbers(fmus, key):
    from fmpy.validation import validate_fmu
    assert validate_fmu(fmus[key, 3]) == []
    stop, dt = 4.0, 0.01
    r2 = _fmpy_run(fmus[key, 2], stop, dt)
    r3 = _fmpy_run(fmus[key, 3], stop, dt, early_return_allowed=True, use_event_mode=True)
    n = 2 if key == "ms" else 1
    q2 = np.column_stack([r2[f"q[{i + 1}]"] for i in range(n)] if n > 1 else [r2["q"]])
    t3 = r3["time"]
    # the early returns add rows at the impact instants (twice: before and after event mode)
    assert len(t3) > len(r2) and np.sum(np.diff(r3["impacts"]) > 0) >= 1
    assert np.any(np.diff(t3) == 0.0)
    grid = r2["time"]
    idx = np.array([np.flatnonzero(np.isclose(t3, t, rtol=0, atol=1e-12))[-1] for t in grid])
    q3 = np.asarray(r3["q"]).reshape(len(t3), n)[idx]
    assert np.max(np.abs(q3 - q2)) < 1e-12


@pytest.mark.parametrize("event_mode", [False, True])
def test_exact_ball_returns_early_at_the_impact_and_continues_bit_for_bit(fmus, event_mode):
    t_hit = math.sqrt(2.0 / 9.81)
    v_hit = math.sqrt(2.0 * 9.81)
    with FMU3Host(fmus["ball", 3], "b3", event_mode=event_mode) as h, FMUHost(fmus["ball", 2], "b2") as g:
        assert h.initialize(0.0) == OK and g.initialize(0.0) == OK
        assert h.do_step(0.0, 1.0) == OK
        assert h.early_return and h.event_needed == event_mode
        assert abs(h.last_time - t_hit) < 1e-12
        q, u, P, n = h.get(["q", "u", "percussion", "impacts"])
        assert abs(q) < 1e-12
        if event_mode:        # the left limit; event mode applies the impact
            assert abs(u + v_hit) < 1e-12 and P == 0.0 and n == 0
            assert h.handle_event() == OK
            q, u, P, n = h.get(["q", "u", "percussion", "impacts"])
        assert abs(u - 0.8 * v_hit) < 1e-12 and abs(P - 1.8 * v_hit) < 1e-12 and n == 1
        assert h.do_step(h.last_time, 1.0 - h.last_time) == OK
        assert not h.early_return and h.last_time == 1.0
        assert g.do_step(0.0, 1.0) == OK
        assert h.get(["q", "u", "impacts"]) == g.get(["q", "u", "impacts"])     # bit for bit


def test_without_early_return_the_step_handles_the_impact_like_fmi2(fmus):
    with FMU3Host(fmus["ball", 3], "b3", early_return=False, event_mode=True) as h, \
            FMUHost(fmus["ball", 2], "b2") as g:
        assert h.initialize(0.0) == OK and g.initialize(0.0) == OK
        for k in range(30):
            assert h.do_step(0.1 * k, 0.1) == OK and g.do_step(0.1 * k, 0.1) == OK
            assert not h.early_return and not h.event_needed
            assert h.get(["q", "u", "percussion", "impacts"]) == g.get(["q", "u", "percussion", "impacts"])


@settings(max_examples=15, deadline=None)
@given(h0=st.floats(0.01, 5.0), g=st.floats(0.5, 30.0), H=st.floats(0.05, 3.0))
def test_exact_early_return_time_is_the_closed_form_impact_time(fmus, h0, g, H):
    """Property: a ball dropped from h0 under gravity g returns early at sqrt(2 h0 / g)
    when that instant lies inside the step, else completes the step."""
    with FMU3Host(fmus["ball", 3], "p", event_mode=False) as h:
        assert h.initialize(0.0, {"q_start": h0, "f0": -g}) == OK
        assert h.do_step(0.0, H) == OK
        t_hit = math.sqrt(2.0 * h0 / g)
        if t_hit < H * (1 - 1e-12):
            assert h.early_return and abs(h.last_time - t_hit) <= 1e-12 * max(1.0, t_hit)
        elif t_hit > H * (1 + 1e-12):
            assert not h.early_return and h.last_time == H


def test_moreau_early_return_at_the_end_of_the_impacting_internal_step(fmus):
    with FMU3Host(fmus["osc", 3], "m3", event_mode=False) as h, FMUHost(fmus["osc", 2], "m2") as g:
        assert h.initialize(0.0) == OK and g.initialize(0.0) == OK
        t, early = 0.0, []
        while t < 3.0 - 1e-12:
            n0 = h.get(["impacts"])[0]
            assert h.do_step(t, min(0.25, 3.0 - t)) == OK
            if h.early_return:
                early.append(h.last_time)
                # stopped at an internal step boundary (dt = 1e-3), with a percussion
                assert abs(h.last_time / 1e-3 - round(h.last_time / 1e-3)) < 1e-6
                assert h.get(["percussion"])[0] > 0 and h.get(["impacts"])[0] == n0 + 1
            t = h.last_time
        assert early
        for k in range(12):
            assert g.do_step(0.25 * k, 0.25) == OK
        assert abs(h.get(["q"])[0] - g.get(["q"])[0]) < 1e-12


def test_invalid_calls_return_error_with_a_logged_reason(fmus):
    with FMU3Host(fmus["ball", 3], "x", event_mode=False) as h:
        assert h.do_step(0.0, 0.1) == ERROR
        assert "fmi3DoStep refused in state 'instantiated'" in h.errors()[-1]
        assert h.initialize(0.0) == OK
        assert h.call("enterEventMode")[0] == ERROR and "eventModeUsed = false" in h.errors()[-1]
        assert h.call("updateDiscreteStates")[0] == ERROR and "step mode" in h.errors()[-1]
        assert h.set({"q": 0.5}) == ERROR and "is an output" in h.errors()[-1]
        assert h.set({"e": 0.5}) == ERROR and "cannot set parameter e" in h.errors()[-1]
        assert h.call("getFloat64", [999], 1)[0] == ERROR and "unknown value reference 999" in h.errors()[-1]
        assert h.call("getFloat64", [h.vr("q")], 2)[0] == ERROR and "nValues = 2" in h.errors()[-1]
        assert h.call("getInt64", [h.vr("q")], 1)[0] == ERROR and "of type Float64" in h.errors()[-1]
        assert h.call("getBoolean", [0], 1)[0] == ERROR and "no variables of this type" in h.errors()[-1]
        assert h.call("fmi3EnterConfigurationMode", h.fmu.component)[0] == ERROR
        assert "fmi3EnterConfigurationMode: not provided" in h.errors()[-1]
        assert h.get(["time"]) == [0.0]
        assert h.do_step(0.0, 0.1) == OK and h.get(["time"]) == [0.1]     # still usable


def test_pending_impact_survives_a_serialized_state_and_a_skipped_event_mode(fmus):
    with FMU3Host(fmus["ball", 3], "a") as h, FMU3Host(fmus["ball", 3], "b") as k:
        assert h.initialize(0.0) == OK and k.initialize(0.0) == OK
        assert h.do_step(0.0, 1.0) == OK and h.event_needed
        st, s = h.get_state()
        blob = h.serialize_state(s)
        st, s2 = k.deserialize_state(blob)
        assert st == OK and k.set_state(s2) == OK
        assert k.get(["q", "u", "time"]) == h.get(["q", "u", "time"])
        assert h.handle_event() == OK and k.handle_event() == OK
        assert k.get(["u", "impacts"]) == h.get(["u", "impacts"])
        assert k.do_step(k.last_time, 0.3) == OK and h.do_step(h.last_time, 0.3) == OK
        assert k.get(["q", "u"]) == h.get(["q", "u"])
        # an importer that steps on without event mode: the impact is applied first, and the step
        # returns fmi3Warning (the raw status: fmpy's wrapper passes a warning on silently), its reason logged
        import ctypes
        assert k.do_step(k.last_time, 1.0) == OK and k.event_needed
        flags = [ctypes.c_bool() for _ in range(3)] + [ctypes.c_double()]
        status = k.fmu.fmi3DoStep(k.fmu.component, k.last_time, 0.1, False, *(ctypes.byref(f) for f in flags))
        assert status == WARNING
        assert any(s == WARNING and "pending for event mode" in m for s, _, m in k.messages)
        assert k.get(["impacts"])[0] == 2


def test_two_dof_arrays_match_the_fmi2_scalars(fmus):
    with FMU3Host(fmus["ms", 3], "a", early_return=False) as h, FMUHost(fmus["ms", 2], "b") as g:
        assert h.initialize(0.0, {"q_start": [0.4, 0.1]}) == OK
        assert g.initialize(0.0, {"q_start[1]": 0.4, "q_start[2]": 0.1}) == OK
        assert h.get(["q"]) == [g.get(["q[1]", "q[2]"])]
        for k in range(200):
            assert h.do_step(0.01 * k, 0.01) == OK and g.do_step(0.01 * k, 0.01) == OK
        assert h.get(["q", "u"]) == [g.get(["q[1]", "q[2]"]), g.get(["u[1]", "u[2]"])]
        assert h.get(["q[2]"]) == g.get(["q[2]"])
        assert h.set({"tau": [1.0, 2.0, 3.0]}) == ERROR and "nValues = 3" in h.errors()[-1]


# ------------------------------------------------------------ the master
def test_master_drives_fmi3_with_early_return_and_exchanges_at_impacts(fmus, tmp_path, monkeypatch):
    from fmu_sync.early_return import cosimulate_early_return
    from fmu_sync.master import cosimulate, cosimulate_network
    x1, x2, T, H = (1.0, 0.0), (0.2, 0.5), 3.0, 0.01
    kw = dict(coupling="switching", Kp=1.0, Kd=0.5)
    r2 = cosimulate(fmus["osc", 2], x1, x2, T, H, event_aware=True, **kw)
    assert r2.info["retaken_steps"] >= 1
    # the compiled loop calls FMI 2.0 functions: an FMI 3.0 FMU is refused before anything runs
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile
    monkeypatch.setattr(tempfile, "tempdir", None)
    for run in (lambda: cosimulate(fmus["osc", 3], x1, x2, T, H, event_aware=True, **kw),
                lambda: cosimulate_network(fmus["osc", 3], [x1, x2, x1], np.ones((3, 3)) - np.eye(3), T, H)):
        with pytest.raises(ValueError, match="FMI 3.0 FMU.*cosimulate_early_return"):
            run()
    assert list(tmp_path.iterdir()) == []          # nothing unpacked, nothing left behind
    # without coupling the stops change nothing: the plain exchange's numbers (the FMU's own round-off)
    u2 = cosimulate(fmus["osc", 2], x1, x2, T, H)
    u3 = cosimulate_early_return(fmus["osc", 3], x1, x2, T, H)
    assert u3.impacts1 >= 1 and u3.info["early_stops"] == u3.impacts1 + u3.impacts2
    assert np.max(np.abs(u3.q1 - u2.q1)) < 1e-12 and np.max(np.abs(u3.q2 - u2.q2)) < 1e-12
    assert np.max(np.abs(u3.d - u2.d)) < 1e-12      # the distances of the record: the core's law
    # coupled, up to the first impact: the compiled loop's Jacobi exchange (the core's network_forces)
    c2 = cosimulate(fmus["osc", 2], x1, x2, T, H, **kw)
    e3 = cosimulate_early_return(fmus["osc", 3], x1, x2, T, H, **kw)
    before = e3.t <= e3.info["stop_times"][0]
    assert 0 < before.sum() < len(e3.t)
    for a, b in ((e3.q1, c2.q1), (e3.q2, c2.q2), (e3.tau1, c2.tau1), (e3.d, c2.d)):
        assert np.max(np.abs(a[before] - b[before])) < 1e-10
    # coupled: one stop per impact instant (the two systems hit the wall at different times here)
    assert np.all(np.diff(e3.info["stop_times"]) > 0) and np.all(np.fmod(e3.info["stop_times"], H) > 1e-9)
    assert e3.impacts1 >= 1 and e3.impacts2 >= 1
    assert e3.info["early_stops"] == e3.impacts1 + e3.impacts2 and e3.info["method"] == "early-return"
    assert np.max(np.abs(e3.q1 - r2.q1)) < 0.01          # the same motion, forces exchanged elsewhere
    assert np.max(np.abs(e3.tau1 - c2.tau1)) > 1e-6       # ... and exchanged at other instants
    with pytest.raises(ValueError, match="FMI 3.0"):
        cosimulate_early_return(fmus["osc", 2], x1, x2, T, H, **kw)


def test_early_return_run_that_fails_keeps_the_record_and_frees_everything(fmus):
    from fmu_sync.early_return import cosimulate_early_return
    from fmu_sync.master import SlaveError
    with pytest.raises(SlaveError, match="input bound") as exc:
        cosimulate_early_return(fmus["osc", 3], (1.0, 0.0), (0.2, 0.5), 1.0, 0.01, coupling="euclidean",
                                Kp=1e14, allow_unstable=True)
    p = exc.value.partial
    assert exc.value.call == "coupling" and "input bound" in p.error and len(p.t) >= 1
    assert np.all(np.isfinite(p.q1)) and p.info["method"] == "early-return"


def test_do_step_goes_through_the_runtime_checks(fmus):
    """fmi3DoStep shares the runtime's doStep checks (fsr_step): an invalid step size or
    time, a step past stopTime are fmi3Error with the reason logged, nothing changed."""
    with FMU3Host(fmus["ball", 3], "c", event_mode=False) as h:
        assert h.call("enterInitializationMode", None, 0.0, 0.3)[0] == OK
        assert h.exit_initialization() == OK
        assert h.do_step(0.0, 0.0) == ERROR and "must be finite and > 0" in h.errors()[-1]
        assert h.do_step(0.5, 0.1) == ERROR and "is not the slave's time" in h.errors()[-1]
        assert h.do_step(0.0, 0.2) == OK
        assert h.do_step(0.2, 0.2) == ERROR and "past the experiment's stopTime = 0.3" in h.errors()[-1]
        assert h.get(["time"]) == [0.2]
        assert h.do_step(0.2, 0.1) == OK and h.get(["time"]) == [0.30000000000000004]


def test_the_runtime_messages_name_the_fmi3_calls(fmus):
    """The Python runtime's replies in an FMI 3.0 FMU name the FMI 3.0 calls (fmi3DeserializeFMUState,
    fmi3SetFMUState, fmi3ExitInitializationMode), never an FMI 2.0 one; the FMI 2.0 FMU names its own."""
    from fmu_sync.fmi_bridge import SlaveError
    from fmu_sync.fmus.slave import seal
    bad = seal(b'{"format": "nonsense"}')
    for v, names in ((3, ("fmi3DeserializeFMUState", "fmi3ExitInitializationMode", "fmi3Reset")),
                     (2, ("fmi2DeSerializeFMUstate", "fmi2ExitInitializationMode", "fmi2Reset"))):
        host = FMU3Host(fmus["ball", 3], "m", event_mode=False) if v == 3 else FMUHost(fmus["ball", 2], "m")
        with host as h:
            assert h.enter_initialization(0.0) == OK
            assert h.deserialize_state(bad)[0] == ERROR
            assert h.set({"m": -1.0}) == ERROR          # below its min: refused at the set itself
            # midpoint with omega*dt = 10: refused at the exit of initialization
            assert h.set({"solver.scheme": 0, "k": 1e8, "solver.dt": 1e-3}) == OK
            assert h.exit_initialization() == ERROR
            logged = [m for s, _, m in h.messages if s >= ERROR]
            assert any(m.startswith(names[0] + ": ") for m in logged), logged
            assert any(m.startswith(names[1] + ": invalid configuration") and names[2] in m for m in logged)
            other = "fmi2" if v == 3 else "fmi3"
            assert not any(other in m for s, _, m in h.messages), [m for _, _, m in h.messages if other in m]
    # the master's wrapper names them too, with the FMI 3.0 status prefix
    from fmu_sync.fmi3_bridge import open_host
    from fmu_sync.master import model_description
    from fmpy import extract
    d = extract(fmus["ball", 3])
    h = open_host(d, model_description(d), "r", raises=True)
    try:
        h.enter_initialization(0.0)
        with pytest.raises(SlaveError, match=r"fmi3DeserializeFMUState returned fmi3Error: "
                                             r"fmi3DeserializeFMUState: ") as err:
            h.deserialize_state(bad)
        assert (err.value.slave, err.value.call, err.value.status) == ("r", "fmi3DeserializeFMUState", ERROR)
    finally:
        h.close()
        import shutil
        shutil.rmtree(d, ignore_errors=True)
