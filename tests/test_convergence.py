"""The convergence check (``fmu-sync run SCENE --convergence``): each variant rerun at its
step, /2 and /4, only the metrics kept; checked on a pair whose decay rate is known in
closed form."""
import csv
import math

import pytest

from fmu_sync.scenes.convergence import convergence, refined_overrides
from fmu_sync.scenes.loading import load_scene
from test_cli import run_cli

# f0 = 10 k keeps both oscillators far from the wall (q ~ 10 +- 1.5): no impacts, the
# switching law stays on branch E, where it is the PD law. The relative mode x = q1 - q2:
#   m x'' + (c + 2 Kd) x' + (k + 2 Kp) x = 0  ->  d ~ exp(-(c + 2 Kd)/(2 m) t)  (tests/test_metrics.py)
# Q = 1 (explicit): d oscillates under its envelope and the fit takes its peaks (with the default,
# the energy metric, d is monotone here and the rate's uncertainty grows: tests/test_lyapunov.py)
M, K, C, KP, KD = 2.0, 3.0, 0.1, 1.5, 0.6
SIGMA = (C + 2 * KD) / (2 * M)
LINEAR = f"""description = "linear coupled pair, no impacts (closed-form decay rate)"
[system]
model = "impact-oscillator"
m = {M}
k = {K}
c = {C}
f0 = {10 * K}
e = 0.9
[initial]
x1 = [10.0, 0.0]
x2 = [11.0, 0.5]
[coupling]
law = "switching"
Kp = {KP}
Kd = {KD}
Q = 1.0
[solver]
dt = 1e-4
[run]
t_end = 50.0
record_every = 100
"""


@pytest.fixture
def linear(tmp_path):
    path = tmp_path / "linear.toml"
    path.write_text(LINEAR)
    return path


def test_linear_pair_rates_match_the_closed_form_at_every_step(linear, tmp_path):
    cr = convergence(linear, tmp_path / "out")
    (vc,) = cr.variants
    assert [r.step for r in vc.rows] == pytest.approx([1e-4, 5e-5, 2.5e-5], rel=1e-12)
    assert [r.record_every for r in vc.rows] == [100, 200, 400]   # the same record times
    for r in vc.rows:
        # within 1e-4 relative of the closed form; the per-decade rates agree (a tiny spread)
        # (measured: 1.5e-4 relative, spread 1.2e-4 1/s from the 0.01 s record)
        assert r.rate == pytest.approx(SIGMA, rel=5e-4) and r.rate_err < 1e-3 * SIGMA, (r.rate, r.rate_err)
        assert r.reason == ""
        # d(0) = 1.118, so the fitted envelope reaches 1e-6 near ln(1.118e6)/sigma = 42.8 s (plus the
        # oscillation's phase); t_sync is within one period 2 pi / sqrt((k + 2 Kp)/m) of t_fit
        assert abs(r.t_sync - r.t_fit) < 2 * math.pi / math.sqrt((K + 2 * KP) / M)
        assert r.bound < 1e-5 and r.final_d < r.bound
    assert all(r.within for r in vc.rows[1:]) and vc.converged
    assert vc.verdict.startswith("rate converged: changes") and "within the rates' spreads" in vc.verdict
    # the files: a markdown table and a CSV with one row per step; no records
    names = {p.name for p in (tmp_path / "out").iterdir()}
    assert names == {"convergence.md", "convergence.csv"}
    rows = list(csv.DictReader(open(tmp_path / "out" / "convergence.csv")))
    assert [float(r["step"]) for r in rows] == pytest.approx([1e-4, 5e-5, 2.5e-5])
    assert float(rows[2]["rate"]) == pytest.approx(vc.rows[2].rate, rel=1e-15)
    md = (tmp_path / "out" / "convergence.md").read_text()
    assert md.count("| linear | solver.dt = ") == 3 and "rate converged" in md


def test_a_coarse_step_moves_the_rate_towards_the_closed_form(linear, tmp_path):
    # at dt = 1e-3 the zero-order hold shifts the rate by O(dt) (2.4e-4, 1.3e-4, 0.5e-4 relative at
    # dt, dt/2, dt/4): the error falls with the step (the midpoint named: it holds the coupling over
    # the step; under the default, the coupling inside the step, |rate - sigma| is 8.4e-5 1/s at each step)
    cr = convergence(linear, tmp_path / "out", overrides={"solver.dt": 1e-3, "run.record_every": 10,
                                                          "solver.scheme": "midpoint"})
    (vc,) = cr.variants
    rates = [r.rate for r in vc.rows]
    assert abs(rates[2] - SIGMA) < abs(rates[0] - SIGMA)


def _row(rate, err, reason=""):
    from fmu_sync.scenes.convergence import ConvergenceRow
    return ConvergenceRow(step=1e-3, dt=1e-3, record_every=1, rate=rate, rate_err=err, t_sync=1.0, t_fit=1.0,
                          bound=0.0, final_d=0.0, reason=reason)


def test_the_verdict_compares_intervals_and_never_two_unresolved_rates():
    from fmu_sync.scenes.convergence import compare_rows
    ok = [_row(0.50, 0.05), _row(0.54, 0.02), _row(0.47, 0.03)]
    verdict, converged = compare_rows(ok)
    assert [r.within for r in ok] == [None, True, False]          # 0.54-0.02 > 0.47+0.03: disjoint
    assert not converged and verdict.startswith("not converged: rate changes 13 %")
    unresolved = [_row(0.50, 0.05), _row(3.0, 2.0, "spread too large"), _row(0.48, 0.04)]
    verdict, converged = compare_rows(unresolved)
    assert [r.within for r in unresolved] == [None, None, None] and all(r.change != r.change for r in unresolved)
    assert not converged and verdict == "no verdict: the rate means nothing at some step (spread too large)"


def test_cosim_refines_H_and_keeps_dt_dividing_it():
    v = load_scene("forced-pair", {"run.mode": "cosim"}, ["switching"]).variants[0]   # H = 1e-2, dt = 1e-3
    o = [refined_overrides(v, k) for k in range(3)]
    assert [x["run.H"] for x in o] == pytest.approx([1e-2, 5e-3, 2.5e-3])
    assert [x["solver.dt"] for x in o] == pytest.approx([1e-3, 1e-3, 2.5e-3 / 3])
    # run.record_every counts solver.dt (issue 36): the same record times, every 0.01 s
    assert [x["run.record_every"] for x in o] == [10, 10, 12]
    assert [x["run.record_every"] * x["solver.dt"] for x in o] == pytest.approx([1e-2] * 3)
    w = load_scene("forced-pair", {"run.mode": "cosim", "solver.dt": 1e-2}, ["switching"]).variants[0]
    assert [refined_overrides(w, k)["solver.dt"] for k in range(3)] == pytest.approx([1e-2, 5e-3, 2.5e-3])


def test_cli_convergence_exits_0_and_writes_the_table(tmp_path):
    out = run_cli(["run", "forced-pair", "--variant", "switching", "--convergence", "--set", "run.t_end=8",
                   "--quiet", "-o", str(tmp_path / "X")], tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.count("| switching | solver.dt = ") == 3 and "switching: " in out.stdout
    assert {p.name for p in (tmp_path / "X").iterdir()} == {"convergence.md", "convergence.csv"}


def test_cli_convergence_refusals_exit_2(tmp_path):
    # the midpoint holds the coupling over dt, so its exchange limit refuses these gains (the default
    # trapezoid takes the coupling inside the step and runs them: tests/test_trapezoid.py)
    unstable = ["run", "forced-pair", "--variant", "switching", "--convergence", "--set", "coupling.Kp=1e5",
                "--set", "coupling.Kd=150", "--set", "solver.dt=1e-2", "--set", "run.t_end=5",
                "--set", "solver.scheme=midpoint"]
    out = run_cli(unstable + ["-o", str(tmp_path / "a")], tmp_path)
    assert out.returncode == 2 and "omega_c*dt = 4.472" in out.stderr, out.stderr
    assert not (tmp_path / "a").exists()
    out = run_cli(["run", "bouncing-ball", "--convergence", "-o", str(tmp_path / "b")], tmp_path)
    assert out.returncode == 2 and "single system" in out.stderr, out.stderr
    assert not (tmp_path / "b").exists()


def test_under_a_tolerance_the_check_refines_tol_and_says_so(tmp_path):
    """Issue 44 item 3: with run.tol the tolerance chooses the steps, so 0.6.0's rows "H, H/2, H/4"
    agreed to 0.001 % and the verdict said "rate converged" without a word of tol. Now the check
    refines run.tol (T, T/4, T/16), the rows and the verdict name it, and the records differ."""
    v = load_scene("forced-pair", {"run.mode": "cosim", "run.tol": 1e-3}, ["switching"]).variants[0]
    o = [refined_overrides(v, k) for k in range(3)]
    assert [x["run.tol"] for x in o] == pytest.approx([1e-3, 2.5e-4, 6.25e-5]) and all("run.H" not in x for x in o)
    out = run_cli(["run", "forced-pair", "--variant", "switching", "--convergence", "--set", "run.t_end=3",
                   "--set", "run.mode=cosim", "--set", "run.tol=1e-3", "-o", str(tmp_path / "T")], tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.count("| switching | run.tol = ") == 3 and "run.H = " not in out.stdout, out.stdout
    assert "switching at its tolerance run.tol, /4 and /16" in out.stderr, out.stderr
    with open(tmp_path / "T" / "convergence.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["step_name"] for r in rows] == ["run.tol"] * 3
    finals = [float(r["final_d"]) for r in rows]
    assert len(set(finals)) == 3, finals      # three different runs, not one run three times
