"""Sweeps refuse what is too large or malformed before anything is built or written,
and leave nothing behind (issue 16, runs): fmu_sync/sweeps/budget.py."""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from fmu_sync import sweep
from fmu_sync.cli import main
from fmu_sync.sweeps import SweepInterrupted, budget
from fmu_sync.sweeps.budget import RUN_BYTES, SweepTooLarge, grid_size
from fmu_sync.sweeps.cli import _short

KP = ["--variant", "switching", "--quiet"]


def _tree(path):
    return sorted(str(p.relative_to(path)) for p in path.rglob("*")) if path.exists() else None


def test_grid_size_reads_the_specs_without_building_them():
    assert grid_size({"a.b": "logspace(-1,1,1e9)", "c.d": "[1, 2, 3]"}) == 3_000_000_000
    assert grid_size({"a.b": "linspace(0, 1, 41)", "c.d": np.arange(5), "e.f": 2.0}) == 41 * 5
    with pytest.raises(ValueError, match="n = 2.5 must be an integer"):
        grid_size({"a.b": "linspace(0, 1, 2.5)"})


def test_a_billion_runs_are_refused_before_any_allocation(tmp_path, capsys):
    """`--grid coupling.Kp='logspace(-1,1,1e9)'` was killed by the kernel (exit 137)."""
    out = tmp_path / "big"
    tracemalloc.start()
    code = main(["sweep", "forced-pair", *KP, "--grid", "coupling.Kp=logspace(-1,1,1e9)", "-o", str(out)])
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    err = capsys.readouterr().err
    assert code == 2 and not out.exists()
    assert "1e+09 runs" in err and "1.86 TiB" in err and "refused before running" in err
    assert peak < 50e6    # nothing of the size of the sweep was allocated (1e9 floats = 8 GB)


def test_time_and_memory_budgets(tmp_path):
    # 400 runs x 1e8 steps: about 4e10 / (1e7 x threads) s; refused under a one-minute budget
    with pytest.raises(SweepTooLarge, match="estimated time .* > budget 1 min"):
        sweep("forced-pair", variant="switching", grid={"coupling.Kp": "linspace(0.5, 2, 400)"},
              overrides={"run.t_end": 1e5}, max_time=60.0, out=tmp_path / "t", quiet=True)
    with pytest.raises(SweepTooLarge, match="memory .* > budget"):
        sweep("forced-pair", variant="switching", grid={"coupling.Kp": "linspace(0.5, 2, 400)"},
              max_memory=RUN_BYTES * 100, out=tmp_path / "m", quiet=True)
    assert not (tmp_path / "t").exists() and not (tmp_path / "m").exists()
    with pytest.raises(SweepTooLarge, match="runs > 10"):
        sweep("forced-pair", variant="switching", method="random", sample={"coupling.Kp": "uniform(1, 2)"},
              n=11, max_runs=10, quiet=True)


def test_the_memory_per_run_is_an_upper_estimate(tmp_path):
    """RUN_BYTES bounds what a sweep holds per run (measured: 1.27 KiB per run at 1500 runs,
    1.11 KiB at 6000, peak of the Python heap)."""
    kw = dict(variant="switching", grid={"coupling.Kp": "linspace(0.5, 2, 30)", "coupling.Kd": "linspace(0.1, 1, 50)"},
              overrides={"run.t_end": 0.01}, quiet=True, plots=False)
    sweep("forced-pair", out=tmp_path / "warm", **kw)   # imports, compiled code
    tracemalloc.start()
    ds = sweep("forced-pair", out=tmp_path / "s", **kw)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert ds["status"].size == 1500
    assert peak / 1500 < RUN_BYTES, peak / 1500


def test_duplicate_grid_keys_and_bad_keys_leave_nothing(tmp_path, capsys):
    out = tmp_path / "dup"
    assert main(["sweep", "forced-pair", *KP, "--grid", "coupling.Kp=[1,2]", "--grid", "coupling.Kp=[3]",
                 "-o", str(out)]) == 2
    assert "coupling.Kp is given twice" in capsys.readouterr().err and not out.exists()
    assert main(["sweep", "forced-pair", *KP, "--grid", "coupling.Kp=[1,2]", "--grid", "nosuch.key=[1]",
                 "-o", str(out)]) == 2
    assert "nosuch.key" in capsys.readouterr().err and not out.exists()
    assert main(["sweep", "forced-pair", *KP, "--grid", "coupling.Kp=[1,-2]", "-o", str(out)]) == 2
    assert not out.exists()


def test_output_path_errors_are_plain_words(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["sweep", "forced-pair", *KP, "--grid", "coupling.Kp=[1]", "-o", str(afile)]) == 2
    err = capsys.readouterr().err
    assert "is a file, not a folder" in err and "Errno" not in err
    assert main(["sweep", "forced-pair", *KP, "--grid", "coupling.Kp=[1]", "-o", str(afile / "sub")]) == 2
    err = capsys.readouterr().err
    assert "Errno" not in err and "which is a file" in err


def test_a_sweep_scene_with_a_replaced_grid_picks_its_maps(tmp_path, capsys):
    """`sweep basin --grid coupling.Kp=...` wrote sweep.nc, then failed in xarray (exit 2)."""
    out = tmp_path / "basin"
    code = main(["sweep", "basin", "--quiet", "--grid", "coupling.Kp=logspace(-1,1,3)", "--set", "run.t_end=2",
                 "-o", str(out)])
    text = capsys.readouterr().out
    assert code == 0 and sorted(p.name for p in out.iterdir()) == ["line.png", "sweep.nc"]
    assert "written to" in text
    # rerun: nothing computed, nothing written, and it says so
    stamp = (out / "sweep.nc").stat().st_mtime_ns
    assert main(["sweep", "basin", "--quiet", "--grid", "coupling.Kp=logspace(-1,1,3)", "--set", "run.t_end=2",
                 "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "written to" not in text and "already complete" in text and "nothing written" in text
    assert (out / "sweep.nc").stat().st_mtime_ns == stamp
    # two added keys of its own: a heat map over them
    out2 = tmp_path / "basin2"
    assert main(["sweep", "basin", "--quiet", "--grid", "coupling.Kp=[0.5,1]", "--grid", "coupling.Kd=[0.2,0.5]",
                 "--set", "run.t_end=2", "-o", str(out2)]) == 0
    assert (out2 / "map.png").is_file()


def test_divergence_reasons_are_cut_at_a_word():
    reason = ("a coupled state became non-finite at t = 12.5 with scheme='midpoint', dt = 0.01 "
              "(omega_max*dt = 0.01). The coupling forces are held over each step: lower Kp")
    short = _short(reason, 60)
    assert short.endswith(" ...") and reason.startswith(short[:-4]) and len(short) <= 64
    assert reason[len(short) - 4] == " "     # the cut falls between two words
    assert _short("x violates the constraint: g(q) < 0") == "x violates the constraint"


def test_an_interrupted_sweep_says_what_it_kept_and_resumes(tmp_path, monkeypatch):
    out = tmp_path / "s"
    kw = dict(variant="switching", grid={"coupling.Kp": "linspace(0.5, 2, 8)"}, overrides={"run.t_end": 0.5},
              chunk_size=2, plots=False, out=out)
    calls = []

    def stop(done, total, failed=0):
        calls.append(done)
        if done >= 4:
            raise KeyboardInterrupt

    with pytest.raises(SweepInterrupted, match=r"sweep interrupted: 4 of 8 runs kept in .*\.partial; rerun"):
        sweep("forced-pair", progress=stop, **kw)
    assert len(list((out / ".partial").glob("*.npz"))) == 2 and not (out / "sweep.nc").exists()
    ds = sweep("forced-pair", quiet=True, **kw)
    assert ds.attrs["reused_runs"] == 4 and ds.attrs["computed_runs"] == 4
    # interrupted before a chunk finished: nothing is left
    out2 = tmp_path / "s2"

    def stop_now(done, total, failed=0):
        raise KeyboardInterrupt
    with pytest.raises(SweepInterrupted, match="nothing kept"):
        sweep("forced-pair", progress=stop_now, **{**kw, "out": out2})
    assert not out2.exists()
