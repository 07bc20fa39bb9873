"""The fmu-sync command line: runs, overrides, error path, progress display."""
import io
import json
import os
import subprocess
import sys
import types

import pytest

from fmu_sync.cli import main
from fmu_sync.progress import Progress, scaled

ENV = {**os.environ, "CI": "true"}   # no progress output in the subprocesses


def run_cli(args, cwd, timeout=300, check_modules=False):
    """Run ``fmu-sync ARGS`` in a fresh interpreter; optionally report which FMI packages it imported."""
    code = ("import json, sys\nfrom fmu_sync.cli import main\nrc = main(sys.argv[1:])\n"
            + ("print(json.dumps({m: m in sys.modules for m in ('fmpy', 'fmu_sync.master',"
               " 'fmu_sync.export')}))\n" if check_modules else "")
            + "sys.exit(rc)\n")
    return subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, capture_output=True, text=True,
                          env=ENV, timeout=timeout)


def test_core_only_single_scene_end_to_end(tmp_path):
    """bouncing-ball through the CLI: data, plots and summary written; no FMU built, fmpy never imported."""
    out = run_cli(["run", "bouncing-ball", "--set", "run.t_end=1.5", "--set", "system.e=0.7"], tmp_path,
                  check_modules=True)
    assert out.returncode == 0, out.stderr
    modules = json.loads(out.stdout.strip().splitlines()[-1])
    assert modules == {"fmpy": False, "fmu_sync.master": False, "fmu_sync.export": False}
    folder = tmp_path / "fmu-sync-out" / "bouncing-ball"
    for name in ("summary.md", "bouncing-ball.csv", "bouncing-ball.npz", "bouncing-ball-positions.png",
                 "bouncing-ball-phase.png"):
        assert (folder / name).stat().st_size > 0, name
    assert not list(tmp_path.rglob("*.fmu"))
    summary = (folder / "summary.md").read_text()
    assert "run.t_end" in summary and "`1.5`" in summary and "system.e" in summary and "`0.7`" in summary
    # the terminal summary table
    assert "impact steps" in out.stdout and "bouncing-ball" in out.stdout


def test_error_path_is_one_line_exit_2(tmp_path):
    out = run_cli(["run", "bouncing-ball", "-o", str(tmp_path / "o"), "--set", "coupling.Kpp=1"], tmp_path)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fmu-sync: error: ") and "coupling.Kpp" in lines[0]
    assert "Traceback" not in out.stderr and not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv,needle", [
    (["run", "no-such-scene"], "unknown scene 'no-such-scene'"),
    (["run", "missing.toml"], "scene file not found: missing.toml"),
    (["run", "bouncing-ball", "--set", "run.t_end"], "expected key=value"),
    (["run", "bouncing-ball", "--set", "solver.scheme=rk4"], 'solver.scheme = "rk4"'),
    (["run", "forced-pair", "--variant", "nope"], "no variant 'nope'"),
    (["validate", "missing.fmu"], "no such FMU: missing.fmu"),
])
def test_errors_in_process(argv, needle, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("fmu-sync: error: ") and needle in err and err.count("\n") == 1, err


def test_divergence_exits_2_naming_scene_and_step(tmp_path, capsys):
    scene = tmp_path / "stiff1.toml"
    scene.write_text('description = "x"\n[system]\nmodel = "impact-oscillator"\nk = 1e8\nf0 = -1.0\ne = 0.5\n'
                     "[initial]\nx1 = [1e-6, 0.0]\n[solver]\nscheme = \"midpoint\"\ndt = 1e-3\n[run]\nt_end = 1.0\n")
    # (the midpoint named: its limit omega_max*dt < 2 refuses; the default θ = ½ is unconditionally stable)
    assert main(["run", str(scene), "-o", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "scene 'stiff1'" in err and "dt = 0.001" in err and "omega_max*dt = 10" in err
    assert main(["run", str(scene), "-o", str(tmp_path / "o"), "--quiet", "--set", "solver.scheme=theta"]) == 0


def test_scenes_lists_descriptions(capsys):
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    for name in ("forced-pair", "zeno-table", "grazing", "bouncing-ball", "stiff-wall", "plastic", "elastic",
                 "two-dof"):
        assert name in out
    assert "Zeno" in out


def test_bench_is_delegated(monkeypatch):
    seen = []
    monkeypatch.setitem(sys.modules, "fmu_sync.benchmarks",
                        types.SimpleNamespace(main=lambda argv: seen.append(argv) or 0))
    assert main(["bench", "--quick", "-o", "somewhere"]) == 0
    assert seen == [["--quick", "-o", "somewhere"]]


def test_report_is_the_bench_section_of_that_name(monkeypatch, capsys):
    from fmu_sync.benchmarks import REPORTS, SECTIONS
    assert REPORTS == ("work-precision", "stability") and set(REPORTS) <= set(SECTIONS)
    seen = []
    monkeypatch.setitem(sys.modules, "fmu_sync.benchmarks",
                        types.SimpleNamespace(main=lambda argv: seen.append(argv) or 0, REPORTS=REPORTS))
    assert main(["report", "stability", "--quick", "-o", "somewhere"]) == 0
    assert main(["report", "work-precision"]) == 0
    assert seen == [["--only", "stability", "--quick", "-o", "somewhere"], ["--only", "work-precision"]]
    for bad in (["report"], ["report", "speed"], ["report", "--quick"]):
        assert main(bad) == 2, bad
        err = capsys.readouterr().err
        assert "work-precision | stability" in err and err.startswith("fmu-sync: error:"), err
    assert main(["report", "--help"]) == 0
    assert "work-precision" in capsys.readouterr().out
    assert len(seen) == 2         # nothing ran for the refused or help calls


def test_run_with_set_in_process(tmp_path, capsys):
    assert main(["run", "bouncing-ball", "-o", str(tmp_path), "--quiet", "--no-plots",
                 "--set", "run.t_end=0.5", "--set", "solver.dt=2e-4"]) == 0
    assert not list(tmp_path.glob("*.png"))
    text = (tmp_path / "summary.md").read_text()
    assert "`0.5`" in text and "`0.0002`" in text


# ------------------------------------------------------------------ progress display
def test_progress_plain_lines_every_ten_percent():
    buf = io.StringIO()
    bar = Progress("run", stream=buf, force=True)
    for i in range(101):
        bar(i / 100)
    bar.close()
    assert buf.getvalue().splitlines() == [f"run: {p}%" for p in range(0, 101, 10)]


def test_progress_silent_under_ci(monkeypatch):
    monkeypatch.setenv("CI", "true")
    monkeypatch.delenv("FMU_SYNC_PROGRESS", raising=False)
    buf = io.StringIO()
    bar = Progress("run", stream=buf)
    bar(0.5)
    bar(1.0)
    assert buf.getvalue() == ""
    monkeypatch.setenv("FMU_SYNC_PROGRESS", "1")
    bar = Progress("run", stream=buf)
    bar(1.0)
    assert buf.getvalue() == "run: 100%\n"


def test_progress_tty_bar():
    class Tty(io.StringIO):
        def isatty(self):
            return True
    buf = Tty()
    with Progress("x", stream=buf, force=True, min_interval=0.0) as bar:
        bar(0.25)
        bar(1.0)
    text = buf.getvalue()
    assert text.startswith("\rx [") and "25.0%" in text and "100.0%" in text and text.endswith("\n")


def test_scaled_progress():
    seen = []
    sub = scaled(seen.append, 0.5, 1.0)
    sub(0.0)
    sub(0.5)
    sub(2.0)
    assert seen == [0.5, 0.75, 1.0]
    assert scaled(None, 0, 1) is None


# ------------------------------------------------------------------ needs the master and the FMU export
# The following load the FMU in a subprocess; a clean exit (status 0) is required here.
def _finished(out, marker):
    return out.returncode == 0 and marker in out.stdout


def test_validate_reports_problems(tmp_path, capsys):
    import zipfile
    bad = tmp_path / "bad.fmu"
    with zipfile.ZipFile(bad, "w") as z:
        z.writestr("modelDescription.xml", '<fmiModelDescription fmiVersion="2.0" modelName="x"/>')
    junk = tmp_path / "junk.fmu"
    junk.write_text("not a zip")
    for f in (bad, junk):
        assert main(["validate", str(f)]) == 1
        out = capsys.readouterr().out
        assert "problem(s)" in out and "  - " in out


def test_export_and_validate(tmp_path):
    fmu = tmp_path / "osc.fmu"
    out = run_cli(["export", "impact-oscillator", "-o", str(fmu)], tmp_path)
    assert out.returncode == 0, out.stderr
    assert fmu.stat().st_size > 0
    out = run_cli(["validate", str(fmu)], tmp_path)
    assert out.returncode == 0 and "valid" in out.stdout, out.stdout + out.stderr


def test_demo_quick_end_to_end(tmp_path):
    """`fmu-sync demo`: FMU exported, three variants co-simulated and compared with the core
    (shortened to 5 s simulated; the full demo is 100 s, --quick 40 s)."""
    out = run_cli(["demo", "--quick", "--t-end", "5"], tmp_path, timeout=900)
    assert _finished(out, "written to"), out.stdout + out.stderr
    folder = tmp_path / "fmu-sync-demo"
    assert list(folder.glob("*.fmu"))
    summary = (folder / "summary.md").read_text()
    for variant in ("uncoupled", "euclidean", "switching"):
        assert f"| {variant} | cosim |" in summary and f"| {variant} | core |" in summary
        assert (folder / f"{variant}-cosim-distance.png").stat().st_size > 5000
        assert (folder / f"{variant}-cosim.csv").exists() and (folder / f"{variant}-core.npz").exists()
    assert (folder / "compare-distance.png").exists() and (folder / "cosim-vs-core.png").exists()
    assert "max|d - d_core|" in out.stdout


def test_version_is_the_one_in_pyproject():
    """pyproject.toml is the single source (through the installed metadata, fmu_sync._version)."""
    import tomllib
    from pathlib import Path

    import fmu_sync
    want = tomllib.loads((Path(__file__).resolve().parent.parent / "pyproject.toml").read_text())["project"]["version"]
    assert fmu_sync.__version__ == want
    out = subprocess.run([sys.executable, "-m", "fmu_sync.cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == f"fmu-sync {want}"
