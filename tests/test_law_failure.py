"""A user force law that fails mid-run (issue 36 item 1, docs/design.md §5.1): h raising at t > 5 or
turning NaN there ends the run as a failure carrying the record up to the last good step
(``.partial``), h's own message, the time and the state; the scene run exits 3 and keeps
``NAME.partial.csv``. Laws that never return or return the wrong shape are refused naming the law.
The laws live in a model file written here (as a user would: numba caches them by that file); the raising,
and the NaN law are one function h_late told apart by a parameter (``fails``), so one law key: their loops
compile once (issue 43 item 7), each law keeps its own name in the messages. They declare their linear part
(h is linear in u; t_fail defaults past every run, so the law's probe sees it), so the trapezoid runs the
same copy of the loops as the midpoint, with its own coefficients: one copy for both schemes."""
import importlib.util
import sys

import numpy as np
import pytest

from fmu_sync.cli import main
from fmu_sync.core import (ForceLawFailed, LawRefused, MechanicalSystem, RunFailed, SimulationDiverged, ring,
                           simulate, simulate_network, simulate_pair)

MODEL_FILE = '''"""Failing force laws (tests/test_law_failure.py): a linear oscillator whose h raises, or
returns NaN, after t_fail."""
import math

import numpy as np

from fmu_sync.core import ForceLaw, MechanicalSystem, Model, Param


def h_late(q, u, tau, t, p):
    """fails = p[3]: 0 raises after t_fail, 1 returns NaN after t_fail."""
    if t > p[2]:
        if p[3] >= 1.0:
            return math.nan
        raise ValueError("boom late")
    return -p[0] * q[0] - p[1] * u[0] + tau[0]


def h_always(q, u, tau, t, p):
    raise ValueError("never works")


def h_wide(q, u, tau, t, p):
    return np.array([-q[0], 0.0])


def params(fails):
    return (Param("k", 4.0, "N/m", 0.0, None, "stiffness"), Param("c", 0.1, "N.s/m", 0.0, None, "damping"),
            Param("t_fail", 99.0, "s", None, None, "when h fails (by default past every run here)"),
            Param("fails", fails, "1", 0.0, 1.0, "how h fails after t_fail: 0 raises, 1 returns NaN"))


def linear(p):
    return [[p[0]]], [[p[1]]]


raising = ForceLaw(h_late, n=1, name="late_raiser", params=params(0.0), linear=linear)
nan_law = ForceLaw(h_late, n=1, name="late_nan", params=params(1.0), linear=linear)
always = ForceLaw(h_always, n=1, name="always_raises", params=params(0.0))
wide = ForceLaw(h_wide, n=1, name="too_wide", params=params(0.0))

late = Model("late-raiser", "an oscillator whose law raises after t_fail",
             params=(Param("g0", 0.8, "m", None, None, "wall"), Param("e", 0.8, "1", 0.0, 1.0, "restitution")),
             force=raising, geometry=("g0", "e"),
             system=lambda p: MechanicalSystem(M=[[1.0]], w=[1.0], g0=p.g0, e=p.e, force=raising,
                                               params=p.of(raising)))
'''

SCENE = '''description = "a law that raises at t > 5 (tests/test_law_failure.py)"

[system]
model = "failing_laws.py:late"
t_fail = 5.0

[initial]
x1 = [0.0, 0.5]
x2 = [0.2, 0.0]

[coupling]
law = "switching"
Kp = 1.0
Kd = 0.5

[solver]
dt = 1e-3

[run]
t_end = 5.5
record_every = 3

[[runs]]
name = "boom"
'''

X1, X2, T_END, DT = (0.0, 0.5), (0.2, 0.0), 5.5, 1e-3


@pytest.fixture(scope="module")
def laws(tmp_path_factory):
    folder = tmp_path_factory.mktemp("failing-laws")
    path = folder / "failing_laws.py"
    path.write_text(MODEL_FILE)
    spec = importlib.util.spec_from_file_location("failing_laws", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["failing_laws"] = mod
    spec.loader.exec_module(mod)
    (folder / "boom.toml").write_text(SCENE)
    mod.folder = folder
    return mod


def _system(law):
    """The system whose law fails at t > 5."""
    return MechanicalSystem(M=[[1.0]], w=[1.0], g0=0.8, e=0.8, force=law, params={"t_fail": 5.0})


def _reference(law):
    """The system of a law that does not fail (t_fail at its default, past the run's end): its run to t = 5 is
    what the record up to the failure must equal."""
    return MechanicalSystem(M=[[1.0]], w=[1.0], g0=0.8, e=0.8, force=law)


@pytest.mark.parametrize("every", [1, 7])
def test_raising_law_keeps_the_record(laws, every):
    """h raising at t > 5: ForceLawFailed (a RunFailed) with h's text, the law, the time and the
    state; .partial reaches the last good step (t = 5: its step's force point is past 5) whatever
    record_every, and equals the run of a law that does not fail there."""
    with pytest.raises(ForceLawFailed) as err:
        simulate(_system(laws.raising), X1, T_END, DT, record_every=every)
    e = err.value
    msg = str(e)
    assert "boom late" in msg and "late_raiser" in msg and "ValueError" in msg and "t = 5 " in msg
    p = e.partial
    assert p is not None and not p.success and p.error == msg
    assert p.t[-1] == pytest.approx(5.0, abs=1e-9) and np.all(np.isfinite(p.q))
    ref = simulate(_reference(laws.raising), X1, 5.0, DT, record_every=every)
    assert np.allclose(p.t[:-1], ref.t[:-1]) and p.t[-1] == pytest.approx(ref.t[-1])
    assert np.max(np.abs(p.q - ref.q)) < 1e-12 and np.max(np.abs(p.u - ref.u)) < 1e-12
    assert f"q = [{p.q[-1, 0]:.9g}]" in msg and f"u = [{p.u[-1, 0]:.9g}]" in msg


@pytest.mark.parametrize("scheme", ["midpoint", "trapezoid"])
@pytest.mark.parametrize("every, sink", [(1, False), (7, False), (7, True)])
def test_raising_law_in_a_pair(laws, every, sink, scheme):
    """The pair (also streamed to a sink): the same failure, the record up to t = 5, both states
    named; the rows sent to the sink are the partial record. The trapezoid (the coupling inside the
    step) evaluates the law at a step's end (t = 5 + round-off > t_fail) before it records that step:
    its record ends one step earlier, at the last state recorded before the law raised."""
    got = []
    kw = dict(sink=got.append, chunk_rows=250) if sink else {}
    with pytest.raises(ForceLawFailed) as err:
        simulate_pair(_system(laws.raising), X1, X2, T_END, DT, coupling="switching", Kp=1.0, Kd=0.5,
                      record_every=every, scheme=scheme, **kw)
    msg = str(err.value)
    assert "boom late" in msg and "system 1" in msg and "system 2" in msg
    ref = simulate_pair(_reference(laws.raising), X1, X2, 5.0, DT, coupling="switching", Kp=1.0, Kd=0.5,
                        record_every=every, scheme=scheme)
    p = err.value.partial
    if sink:
        t = np.concatenate([c.t for c in got])
        q1 = np.concatenate([c.q1 for c in got])
        assert p.t[-1] == t[-1]
    else:
        t, q1 = p.t, p.q1
    assert np.all(np.diff(t) > 0)
    if scheme == "midpoint":
        assert t[-1] == pytest.approx(5.0) and len(t) == len(ref.t)
        assert np.max(np.abs(q1 - ref.q1)) < 1e-12
    else:   # the record rows, then the last good step (4.999, a row of the reference with every = 1)
        assert t[-1] == pytest.approx(5.0 - DT) and np.allclose(t[:-1], ref.t[:len(t) - 1])
        assert np.max(np.abs(q1[:-1] - ref.q1[:len(t) - 1])) < 1e-12
        last = simulate_pair(_reference(laws.raising), X1, X2, t[-1], DT, coupling="switching", Kp=1.0, Kd=0.5,
                             scheme=scheme, record_every=10 ** 6)
        assert abs(q1[-1, 0] - last.q1[-1, 0]) < 1e-12
    assert p.error == msg and np.all(np.isfinite(p.d))


def test_nan_law_names_the_law(laws):
    """h returning NaN at t > 5: SimulationDiverged with .partial to t = 5 whose message names the
    force law, not the coupling's stability (single system, pair, network)."""
    s = _system(laws.nan_law)
    with pytest.raises(SimulationDiverged) as err:
        simulate(s, X1, T_END, DT, record_every=4)
    assert err.value.partial.t[-1] == pytest.approx(5.0) and "late_nan" in str(err.value)
    for every in (1, 4):
        with pytest.raises(SimulationDiverged) as err:
            simulate_pair(s, X1, X2, T_END, DT, coupling="switching", Kp=1.0, Kd=0.5, record_every=every)
        msg = str(err.value)
        assert "force law 'late_nan' returned the non-finite force h = [nan]" in msg
        assert "Kp" not in msg and "exchange" not in msg and "stable only" not in msg
        p = err.value.partial
        assert p.t[-1] == pytest.approx(5.0) and np.all(np.isfinite(p.q1)) and np.all(np.isfinite(p.d))
    with pytest.raises(SimulationDiverged) as err:
        simulate_network(s, [X1, X2, (0.1, 0.1)], ring(3), T_END, DT, coupling="switching", Kp=1.0, Kd=0.5,
                         record_every=7)
    p = err.value.partial
    assert "late_nan" in str(err.value) and "node 1" in str(err.value)
    assert p.t[-1] == pytest.approx(5.0) and np.all(np.isfinite(p.q)) and np.all(np.isfinite(p.d))


def test_scene_run_exits_3_with_the_partial_record(laws, tmp_path, capsys):
    """The CLI: a scene whose law raises mid-run exits 3 (a run failed), keeps NAME.partial.csv up
    to the failure and says h's message."""
    out = tmp_path / "out"
    code = main(["run", str(laws.folder / "boom.toml"), "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 3, err
    with open(out / "boom.partial.csv") as f:
        rows = [line.split(",") for line in f if line.strip()]
    t = [float(r[0]) for r in rows if not r[0].lstrip().startswith(("#", "t"))]
    # the scene runs the default, the trapezoid: the law raises at the end of the step to t = 5, so the
    # record ends with the last good state, t = 4.999, after the row at 4.998 (test_raising_law_in_a_pair)
    assert t[-1] == pytest.approx(5.0 - DT) and t[-2] == pytest.approx(4.998)
    assert "boom late" in (out / "summary.md").read_text()


def test_refusals_name_the_law(laws):
    """A law that always raises and a 1-DOF law returning a (2,) array are refused before anything
    runs, naming the law, what it raised or returned and what is expected."""
    with pytest.raises(LawRefused) as err:
        simulate(_system(laws.always), X1, 1.0, DT)
    msg = str(err.value)
    assert "always_raises" in msg and "never works" in msg and "shape (1,)" in msg
    with pytest.raises(LawRefused) as err:
        simulate(_system(laws.wide), X1, 1.0, DT)
    msg = str(err.value)
    assert "too_wide" in msg and "shape (2,)" in msg and "shape (1,)" in msg
    assert not isinstance(err.value, RunFailed)


def test_a_model_file_importing_scipy_is_refused_in_words(tmp_path):
    """Export of a model file that imports scipy (issue 36 item 6): the message names the file and
    the line, the packages the target's Python is asked for (the allowed list) and what to do."""
    pytest.importorskip("scipy")
    from fmu_sync.export import TARGET_REQUIRES, resolve, target_requires
    from _user_files import pendulum_file
    path = tmp_path / "sci_pendulum.py"
    path.write_text("import scipy  # noqa: F401\n" + pendulum_file("sci_pendulum", "sci-pendulum"))
    key, _ = resolve(f"{path}:pendulum")
    with pytest.raises(ValueError) as err:
        target_requires(key)
    msg = str(err.value)
    assert "the model file sci_pendulum.py imports scipy (line 1)" in msg
    assert all(f"{d}{spec}" in msg for d, spec in TARGET_REQUIRES.items()) and "standard library" in msg
    assert "Remove that import" in msg and "TARGET_REQUIRES" not in msg
