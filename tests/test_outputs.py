"""Outputs that scale: estimates before the run, the budget, chunked writing with
bounded memory, user-chosen formats, output-path errors, partial records."""
import json
import tracemalloc
import zipfile

import numpy as np
import pytest

from fmu_sync import load_scene, run_scene
from fmu_sync.cli import main
from fmu_sync.core import ImpactOscillator, simulate_pair
from fmu_sync.output import (OutputPathError, OutputTooLarge, RecordWriter, check_budget, estimate,
                             pair_columns, parse_formats, parse_size)


def test_estimate_matches_the_record_written(tmp_path):
    """Rows and values of the estimate are those of the record; the disk estimate bounds the files."""
    scene = load_scene("forced-pair", {"run.t_end": 3.0, "run.record_every": 7}, ["switching"])
    (v,) = scene.variants
    est = estimate(v, ("csv", "npz"))
    sr = run_scene(scene, tmp_path, plots=False)
    r = sr.runs[0].result
    assert est.rows == len(r.t) == 3000 // 7 + 2      # the final state (t = 3) is the last row
    assert r.t[-1] == 3.0 and r.t[-2] == pytest.approx(7 * (3000 // 7) * 1e-3)
    assert est.values_per_row == 11          # t, q1, u1, q2, u2, tau1, tau2, d, V, euclidean, branch
    sizes = sum(p.stat().st_size for p in tmp_path.glob("switching.*"))
    assert 0.3 * est.disk < sizes <= est.disk
    assert est.record_bytes == 8 * est.rows * est.values_per_row


def test_huge_run_refused_with_estimate_and_record_every():
    scene = load_scene("forced-pair", {"run.t_end": 1e6, "solver.dt": 1e-6}, ["switching"])
    (v,) = scene.variants
    with pytest.raises(OutputTooLarge) as err:
        check_budget(v, ("csv", "npz"), can_stream=True)
    msg = str(err.value)
    assert "1e+12 steps" in msg and "TiB" in msg and "refused before running" in msg
    every = int(msg.split("run.record_every = ")[1].split()[0])
    v2 = load_scene("forced-pair", {"run.t_end": 1e6, "solver.dt": 1e-6, "run.record_every": every},
                    ["switching"]).variants[0]
    check_budget(v2, ("csv", "npz"), can_stream=True)           # the suggestion fits
    # npz only: a quarter of the disk
    assert estimate(v, ("npz",)).disk * (25 + 8) == pytest.approx(estimate(v, ("csv", "npz")).disk * 8)


def test_cli_refuses_huge_run_before_running(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["run", "forced-pair", "--set", "run.t_end=1e6", "--set", "solver.dt=1e-6", "-o", str(out),
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "refused before running" in err and "record_every" in err
    assert not out.exists()


def test_streamed_run_bounded_memory_and_identical_files(tmp_path):
    """A record 30x the memory budget: written in chunks, tracemalloc peak under the budget,
    files identical to those of the whole-record run."""
    over = {"run.t_end": 40.0, "solver.dt": 1e-4, "run.record_every": 1}
    scene = load_scene("forced-pair", over, ["switching"])
    est = estimate(scene.variants[0])
    budget = 4 * 1024**2
    assert est.record_bytes > 8 * budget
    run_scene(scene, tmp_path / "whole", plots=False)            # warm-up (compilation) and reference
    tracemalloc.start()
    try:
        sr = run_scene(scene, tmp_path / "stream", plots=False, max_memory=budget)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert sr.runs[0].streamed
    assert peak < budget, f"peak {peak / 2**20:.2f} MiB, budget {budget / 2**20:.0f} MiB"
    a, b = np.load(tmp_path / "whole" / "switching.npz"), np.load(tmp_path / "stream" / "switching.npz")
    assert sorted(a.files) == sorted(b.files)
    for k in a.files:
        if k == "meta":   # the run's layout, counts and settings: the same for both
            assert json.loads(str(a[k])) == json.loads(str(b[k]))
        else:
            assert np.array_equal(a[k], b[k], equal_nan=True), k
    assert (tmp_path / "whole" / "switching.csv").read_bytes() == (tmp_path / "stream" / "switching.csv").read_bytes()
    # the streamed metrics equal those of the whole record
    whole = run_scene(scene, tmp_path / "whole2", plots=False, formats=()).runs[0].metrics
    m = sr.runs[0].metrics
    for k in ("t_sync", "final_d", "euclid_max", "peaking", "peak_tau", "impacts1", "episodes1", "episodes2",
              "dV_impact", "dE_impact"):
        assert m[k] == pytest.approx(whole[k], rel=1e-12), k


def test_sink_chunks_reproduce_the_whole_record():
    osc = ImpactOscillator(m=1, k=1, c=0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
    args = (osc, (1.0, 0.0), (0.2, 0.5), 10.0, 1e-3)
    kw = dict(coupling="switching", Kp=1.0, Kd=0.5, record_every=3)
    full = simulate_pair(*args, **kw)
    parts = []
    last = simulate_pair(*args, **kw, sink=parts.append, chunk_rows=50)
    assert len(parts) == -(-(len(full.t) - 1) // 50)
    for k in ("t", "q1", "u1", "q2", "u2", "tau1", "tau2", "d", "branch", "euclidean"):
        assert np.array_equal(np.concatenate([getattr(p, k) for p in parts]), getattr(full, k)), k
    assert last.t[-1] == full.t[-1] and last.info["rows"] == len(full.t) and last.impacts1 == full.impacts1


def test_tau_row0_is_the_force_at_the_start():
    """Row 0 holds the forces computed from the start states (those held over the first step)."""
    from fmu_sync.core import coupling_forces
    osc = ImpactOscillator(m=1, k=1, c=0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
    # the midpoint holds the start's force over the first step (the trapezoid's row 0 is its first step's)
    r = simulate_pair(osc, (1.0, 0.0), (0.2, 0.5), 0.1, 1e-3, coupling="switching", Kp=1.0, Kd=0.5, scheme="midpoint")
    t1, t2 = coupling_forces(osc, (1.0, 0.0), (0.2, 0.5), "switching", Kp=1.0, Kd=0.5)[:2]
    assert r.tau1[0, 0] == pytest.approx(float(np.ravel(t1)[0]), abs=1e-15) and r.tau1[0, 0] != 0.0
    assert r.tau1[1, 0] == r.tau1[0, 0]            # held over the first step
    u = simulate_pair(osc, (1.0, 0.0), (0.2, 0.5), 0.1, 1e-3)
    assert np.all(u.tau1 == 0.0)


def test_formats_choice(tmp_path):
    sr = run_scene("forced-pair", tmp_path, overrides={"run.t_end": 1.0}, variants=["switching"],
                   plots=False, formats=("npz",))
    assert {p.name for p in tmp_path.iterdir()} == {"switching.npz", "summary.md"}
    assert parse_formats("npz,csv") == ("npz", "csv") and parse_formats("none") == ()
    with pytest.raises(ValueError, match="unknown data format 'hdf5'"):
        parse_formats("csv,hdf5")
    assert parse_size("2GB") == 2 * 1024**3 and parse_size("1.5 MiB") == int(1.5 * 1024**2)
    with pytest.raises(ValueError):
        parse_size("lots")


def test_record_writer_partial_and_abort(tmp_path):
    cols = pair_columns(1, False)
    w = RecordWriter(tmp_path / "r", cols)
    for k in range(3):
        w.append({name: np.full((4, 1) if width == 1 and name != "t" else (4,), k, float) for name, width in cols})
    files = w.close(partial=True)
    assert sorted(p.name for p in files) == ["r.partial.csv", "r.partial.npz"]
    assert np.load(tmp_path / "r.partial.npz")["t"].shape == (12,)
    assert len((tmp_path / "r.partial.csv").read_text().splitlines()) == 13
    w = RecordWriter(tmp_path / "s", cols)
    w.abort()
    assert {p.name for p in tmp_path.iterdir()} == {"r.partial.csv", "r.partial.npz"}
    with zipfile.ZipFile(tmp_path / "r.partial.npz") as z:
        assert sorted(z.namelist()) == sorted(f"{n}.npy" for n, _ in cols)


@pytest.mark.parametrize("make", ["file", "inside-file"])
def test_output_path_errors_are_one_line(tmp_path, capsys, make):
    f = tmp_path / "f"
    f.write_text("x")
    out = f if make == "file" else f / "sub"
    assert main(["run", "bouncing-ball", "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("fmu-sync: error: the output path") and err.count("\n") == 1
    with pytest.raises(OutputPathError):
        run_scene("bouncing-ball", out)
