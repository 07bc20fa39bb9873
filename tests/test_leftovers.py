"""`fmu-sync run` leaves nothing half-written: interrupts (Ctrl-C, SIGTERM) keep the
finished variants with a summary and say so in one line; a folder holding another
scene's results is refused unless --overwrite; errors in plain words (issue 16)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fmu_sync.cli import main
from fmu_sync.scenes.running import RunInterrupted, run_scene

SHORT = ["--set", "run.t_end=1", "--quiet"]


def _names(path: Path):
    return sorted(p.name for p in path.iterdir()) if path.exists() else None


def test_run_refuses_a_folder_with_another_scenes_results(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["run", "grazing", *SHORT, "--no-plots", "-o", str(out)]) == 0
    before = _names(out)
    assert "summary.md" in before
    assert main(["run", "forced-pair", *SHORT, "--no-plots", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "holds the results of Scene `grazing`" in err and "--overwrite" in err
    assert _names(out) == before                          # nothing mixed in
    # the same scene again is not another scene's results
    assert main(["run", "grazing", *SHORT, "--no-plots", "-o", str(out)]) == 0
    # --overwrite: the old results go, the new ones come
    assert main(["run", "forced-pair", *SHORT, "--no-plots", "--overwrite", "-o", str(out)]) == 0
    after = _names(out)
    assert set(before) & set(after) == {"summary.md"}     # grazing's files are gone
    assert (out / "summary.md").read_text().startswith("# Scene `forced-pair`")


def test_output_folder_errors_are_plain_words(tmp_path, capsys):
    afile = tmp_path / "f"
    afile.write_text("x")
    assert main(["run", "forced-pair", *SHORT, "-o", str(afile)]) == 2
    assert main(["run", "forced-pair", *SHORT, "-o", str(afile / "x")]) == 2
    if Path("/proc/self").is_dir():
        assert main(["run", "forced-pair", *SHORT, "-o", "/proc/x"]) == 2
    err = capsys.readouterr().err
    assert "Errno" not in err and err.count("fmu-sync: error:") == 2 + Path("/proc/self").is_dir()
    assert not Path("/proc/x").exists()


def _interrupt_at(lo, hi):
    def progress(f):
        if lo <= f < hi:
            raise KeyboardInterrupt
    return progress


@pytest.mark.parametrize("lo, hi, where", [(0.4, 0.6, "running"), (0.6, 0.66, "writing")])
def test_interrupt_after_the_first_variant_keeps_it_with_a_summary(tmp_path, lo, hi, where):
    """Ctrl-C in the second variant (while it runs, or while its plots are written): the
    first variant is kept complete with summary.md, nothing of the second stays."""
    out = tmp_path / "o"
    with pytest.raises(RunInterrupted) as info:
        run_scene("forced-pair", out, overrides={"run.t_end": 1.0}, progress=_interrupt_at(lo, hi))
    msg = str(info.value)
    assert msg.startswith("interrupted during variant 'euclidean': kept uncoupled in ")
    assert "--variant euclidean --variant switching" in msg and "\n" not in msg
    names = _names(out)
    assert "summary.md" in names and not any(n.startswith(("euclidean", "switching")) for n in names)
    assert {"uncoupled.csv", "uncoupled.npz"} <= set(names)
    plots = [n for n in names if n.endswith(".png")]
    assert all(n.startswith("uncoupled-") for n in plots) and len(plots) >= 2
    assert "| uncoupled" in (out / "summary.md").read_text()


def test_interrupt_in_the_first_variant_leaves_nothing(tmp_path):
    out = tmp_path / "o"
    with pytest.raises(RunInterrupted, match="nothing kept"):
        run_scene("forced-pair", out, overrides={"run.t_end": 1.0}, progress=_interrupt_at(0.05, 0.3))
    assert not out.exists()


def test_sigterm_of_a_run_leaves_nothing_and_says_so(tmp_path):
    out = tmp_path / "o"
    env = {**os.environ, "FMU_SYNC_PROGRESS": "0"}
    cmd = [sys.executable, "-m", "fmu_sync.cli", "run", "forced-pair", "--variant", "switching", "--set",
           "run.t_end=200000", "--set", "run.record_every=10000", "--format", "npz", "-o", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 120
        while not out.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert out.exists(), proc.communicate(timeout=60)
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted during variant 'switching': nothing kept" in err
    assert not out.exists()
