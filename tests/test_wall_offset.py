"""The 1-DOF wall offset g0 (docs/design.md §2.1): ImpactOscillator(..., g0) in the user's
coordinates against the hand-shifted model (gap coordinates x = q + g0, constant force
f0 + k g0, start x0 = q0 + g0, wall at x = 0), in the core, the pair, the network, the exact
solver, the FMU and the master."""
import numpy as np
import pytest

from fmu_sync.core import ImpactOscillator, simulate, simulate_network, simulate_pair

G0 = 0.05
P = dict(m=2.0, k=50.0, c=0.1, e=0.7, f0=-1.0, F=8.0, Omega=4.0, phi=0.3)
X1, X2 = (0.1, 0.0), (0.3, -0.5)
TOL = 1e-12


def _user():
    return ImpactOscillator(**P, g0=G0)


def _shifted():
    """The same oscillator by hand: gap coordinates, wall at x = 0."""
    return ImpactOscillator(**{**P, "f0": P["f0"] + P["k"] * G0})


def _shift(x):
    return (x[0] + G0, x[1])


def _close(a, b, what):
    err = float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
    assert err <= TOL, f"{what}: max |difference| = {err:.3g} > {TOL:g}"


def test_g0_is_the_wall_of_the_oscillator_and_m_is_not_a_count():
    s = _user()
    assert s.g0 == G0 and s.w.tolist() == [1.0] and s.gap(-G0) == 0.0
    assert s.n_inputs == 1 and not hasattr(s, "m")
    with pytest.raises(ValueError, match="g0 must be finite"):
        ImpactOscillator(**P, g0=float("inf"))


@pytest.mark.parametrize("scheme", ["midpoint", "theta", "exact"])
def test_single_run_matches_the_hand_shifted_model(scheme):
    a = simulate(_user(), X1, 6.0, 1e-3, scheme=scheme)
    b = simulate(_shifted(), _shift(X1), 6.0, 1e-3, scheme=scheme)
    assert a.impacts == b.impacts > 3
    assert np.array_equal(a.t, b.t)
    _close(a.q[:, 0] + G0, b.q[:, 0], "q + g0")
    _close(a.u, b.u, "u")
    assert -G0 - 1e-3 < float(np.min(a.q[:, 0])) < -0.9 * G0     # the wall stands at q = -g0


def test_pair_matches_the_hand_shifted_model():
    kw = dict(coupling="switching", Kp=20.0, Kd=2.0)
    a = simulate_pair(_user(), X1, X2, 6.0, 1e-3, **kw)
    b = simulate_pair(_shifted(), _shift(X1), _shift(X2), 6.0, 1e-3, **kw)
    assert (a.impacts1, a.impacts2) == (b.impacts1, b.impacts2) and a.impacts1 > 3
    _close(a.q1 + G0, b.q1, "q1 + g0")
    _close(a.q2 + G0, b.q2, "q2 + g0")
    _close(a.d, b.d, "d")
    assert np.array_equal(a.branch, b.branch)


def test_network_matches_the_hand_shifted_model():
    A = np.ones((3, 3)) - np.eye(3)
    states = [X1, X2, (0.2, 0.4)]
    a = simulate_network(_user(), states, A, 4.0, 1e-3, Kp=20.0, Kd=2.0)
    b = simulate_network(_shifted(), [_shift(x) for x in states], A, 4.0, 1e-3, Kp=20.0, Kd=2.0)
    _close(a.q + G0, b.q, "q + g0")
    _close(a.u, b.u, "u")


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    from fmu_sync.export import export_fmu
    return export_fmu("impact-oscillator", tmp_path_factory.mktemp("g0") / "osc.fmu", {**P, "solver.dt": 1e-3})


def test_fmu_has_g0_and_its_outputs_are_in_the_user_coordinates(fmu):
    from fmpy import read_model_description, simulate_fmu
    g0 = {v.name: v for v in read_model_description(str(fmu)).modelVariables}["g0"]
    assert (g0.causality, g0.variability, g0.unit) == ("parameter", "fixed", "m")
    out = ["q", "u", "gap"]
    a = simulate_fmu(str(fmu), stop_time=3.0, output_interval=1e-3, output=out,
                     start_values={"g0": G0, "q_start": X1[0]})
    b = simulate_fmu(str(fmu), stop_time=3.0, output_interval=1e-3, output=out,
                     start_values={"f0": P["f0"] + P["k"] * G0, "q_start": X1[0] + G0})
    core = simulate(_user(), X1, 3.0, 1e-3)
    _close(a["q"] + G0, b["q"], "FMU q + g0")
    _close(a["gap"], a["q"] + G0, "FMU gap")
    _close(a["q"], core.q[:, 0], "FMU q against the core")
    assert float(np.min(a["q"])) < 0.0


def test_master_matches_the_hand_shifted_model(fmu):
    from fmu_sync.master import cosimulate
    kw = dict(coupling="switching", Kp=20.0, Kd=2.0)
    a = cosimulate(fmu, X1, X2, 4.0, 1e-3, start_values={"g0": G0}, **kw)
    b = cosimulate(fmu, _shift(X1), _shift(X2), 4.0, 1e-3, start_values={"f0": P["f0"] + P["k"] * G0}, **kw)
    # the FMU's default trapezoid under the explicit exchange (the coupling held): the core's theta = 1/2
    core = simulate_pair(_user(), X1, X2, 4.0, 1e-3, scheme="theta", theta=0.5, **kw)
    assert a.error is None and a.impacts1 > 2
    _close(a.q1 + G0, b.q1, "cosim q1 + g0")
    _close(a.d, b.d, "cosim d")
    _close(a.q1, core.q1, "cosim q1 against the core")
