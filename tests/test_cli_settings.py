"""A key or an option that does nothing, or a budget that is not kept, is refused or said (issue 44
items 2, 3, 4; issue 39 item 7's record interval; the interrupt message under --no-plots). Every
refusal here comes before anything runs: ``fmu-sync run`` in this process, nothing loaded."""
from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest

from fmu_sync.cli import main
from fmu_sync.scenes.loading import load_scene


def _cli(argv):
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        rc = main(argv)
    return rc, err.getvalue(), out.getvalue()


def test_a_tolerance_run_over_the_budgets_is_refused_before_running(tmp_path):
    """44.2: 0.6.0 ran the issue's case and wrote 76,744 rows (19.9 MiB) past --max-disk 5MB: the up-front
    estimate took t_end / H rows where tol records each accepted step, down to solver.dt."""
    rc, err, _ = _cli(["run", "forced-pair", "--set", "run.mode=cosim", "--variant", "switching", "--set",
                       "run.tol=1e-300", "--max-memory", "4MB", "--max-disk", "5MB", "-o", str(tmp_path / "o"),
                       "--quiet"])
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert "refused before running" in err and "1e+05 steps" in err, err
    assert not (tmp_path / "o").exists()


def test_a_tolerance_run_is_estimated_at_its_worst_case():
    from fmu_sync.output import estimate
    v = load_scene("forced-pair", {"run.mode": "cosim", "run.tol": 1e-3, "run.t_end": 10.0,
                                   "run.record_every": 1}, ["switching"]).variants[0]
    fixed = load_scene("forced-pair", {"run.mode": "cosim", "run.t_end": 10.0, "run.record_every": 1},
                       ["switching"]).variants[0]
    dt, H = v.cfg["solver.dt"], v.cfg["run.H"]
    assert estimate(v).steps == round(10.0 / dt) and estimate(fixed).steps == round(10.0 / H)


@pytest.mark.parametrize("keys", [["run.tol=1e-4", "run.exchange=implicit"], ["run.hold=foh"], ["run.H=0.02"]])
def test_cosim_keys_in_a_core_run_are_refused_naming_key_and_mode(tmp_path, keys):
    """44.4: 0.6.0 ran them (exit 0) and nothing said the keys did nothing."""
    argv = ["run", "forced-pair", "--variant", "switching", "-o", str(tmp_path / "o"), "--quiet"]
    for k in keys:
        argv += ["--set", k]
    rc, err, _ = _cli(argv)
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert all(f"--set {k.split('=')[0]}" in err for k in keys) and "run.mode = 'core'" in err, err
    assert not (tmp_path / "o").exists()


def test_a_scene_mixing_modes_runs_and_says_which_variants_a_key_misses(tmp_path):
    """The keys apply to the co-simulated variants of a scene whose variants mix modes: not refused,
    the note names the core ones (terminal and summary.md)."""
    from fmu_sync.cli import _idle_keys
    scene = tmp_path / "mixed.toml"
    scene.write_text('[system]\nmodel = "impact-oscillator"\nm = 1.0\nk = 1.0\nc = 0.0\nf0 = 0.2\nF = 0.5\n'
                     'Omega = 2.5\ne = 0.9\n[initial]\nx1 = [1.0, 0.0]\nx2 = [0.2, 0.5]\n'
                     '[run]\nt_end = 1.0\n[[runs]]\nname = "core"\n[[runs]]\nname = "co"\nrun.mode = "cosim"\n')
    note = _idle_keys(load_scene(scene, {"run.tol": 1e-3}))
    assert note is not None and "--set run.tol" in note and "not to core (run.mode = 'core')" in note
    assert _idle_keys(load_scene(scene, {"run.tol": 1e-3}, ["co"])) is None


def test_record_interval_of_a_cosimulated_network_is_its_communication_step():
    """39.7: summary.md said 1e-05 s (solver.dt) for a network whose rows come every H."""
    from fmu_sync.output import estimate, record_steps
    from fmu_sync.scenes.running import record_interval
    v = load_scene("ring-8", {"run.mode": "cosim", "solver.dt": 1e-5, "run.record_every": 1,
                              "run.t_end": 1.0}).variants[0]
    seconds, words = record_interval(v)
    assert seconds == pytest.approx(v.cfg["run.H"]) and record_steps(v.cfg) == 1 and "run.H = 0.01 s" in words
    assert estimate(v).steps == 100


def test_record_interval_of_a_tolerance_run_says_rows_per_accepted_step():
    from fmu_sync.scenes.running import record_interval
    v = load_scene("forced-pair", {"run.mode": "cosim", "run.tol": 1e-3}, ["switching"]).variants[0]
    assert "accepted step" in record_interval(v)[1] and "each between solver.dt" in record_interval(v)[1]


def test_a_cosimulated_network_records_at_the_interval_it_says(tmp_path):
    """The record itself: ring-8 co-simulated (record_every = 10 steps of solver.dt = 1e-3 s, H = 0.01 s)
    has a row every 0.01 s, the interval summary.md gives (0.6.0 recorded every 10 steps of H, 0.1 s)."""
    from fmu_sync.scenes.running import record_interval, run_scene
    sr = run_scene("ring-8", tmp_path, overrides={"run.mode": "cosim", "run.t_end": 0.2}, plots=False)
    run = sr.runs[0]
    assert np.allclose(np.diff(run.result.t), record_interval(run.variant)[0])
    assert "| record interval | `0.01 s" in sr.summary.read_text()


def test_the_interrupt_message_lists_no_plots_under_no_plots(tmp_path):
    """Also seen in 44: an interrupted run under --no-plots said it kept "(data, plots, summary.md)"."""
    from fmu_sync.scenes.running import run_scene
    seen = []

    def progress(x):
        seen.append(x)
        if x > 0.5:
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt) as exc:
        run_scene("forced-pair", tmp_path / "o", overrides={"run.t_end": 1.0}, plots=False, progress=progress)
    msg = str(exc.value)
    assert "kept uncoupled" in msg and "(data, summary.md)" in msg and "plots" not in msg, msg
