"""Exit status of the CLI: 0 ok, 2 refused before anything ran (bad input, an unstable
step), 3 a run that failed mid-way (record kept as partial, no plots), no numpy warnings."""
import numpy as np

from test_cli import run_cli

ISSUE = ["run", "forced-pair", "--variant", "switching", "--set", "run.mode=cosim", "--set", "coupling.Kp=1e5",
         "--set", "coupling.Kd=150", "--set", "run.t_end=5"]


def test_unstable_cosim_refused_before_the_first_step(tmp_path):
    out = run_cli(ISSUE + ["-o", str(tmp_path / "X")], tmp_path)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fmu-sync: error: ")
    # omega_c = sqrt(2 Kp / m) = 447.2 rad/s, H = 0.01: omega_c*H = 4.472; zeta = 0.3354,
    # bound min(4 zeta, 1/zeta) = 1.342: H_max = 1.342 / 447.2 = 3.0e-3 (2.99999775e-3 with k = 1 in
    # the map), named rounded down so that it is accepted
    assert "omega_c*H = 4.472" in lines[0] and "largest stable H = 0.002999" in lines[0]
    assert "refused before the first step" in lines[0]
    assert not (tmp_path / "X").exists() and not list(tmp_path.rglob("*.fmu"))


def test_forced_unstable_run_exits_3_without_plots(tmp_path):
    out = run_cli(ISSUE + ["-o", str(tmp_path / "X"), "--allow-unstable"], tmp_path)
    assert out.returncode == 3, out.stderr
    assert "RuntimeWarning" not in out.stderr and "Traceback" not in out.stderr
    assert "FAILED: switching" in out.stdout
    names = {p.name for p in (tmp_path / "X").iterdir()}
    assert not any(n.endswith(".png") for n in names), names
    assert {"switching.partial.csv", "switching.partial.npz", "summary.md"} <= names
    rec = np.load(tmp_path / "X" / "switching.partial.npz")
    assert np.all(np.isfinite(rec["q1"])) and rec["t"][-1] < 5.0
    assert "failed" in (tmp_path / "X" / "summary.md").read_text()


def test_core_unstable_refused_then_forced_with_set(tmp_path):
    core = ["run", "forced-pair", "--variant", "switching", "--set", "coupling.Kp=1e5", "--set", "coupling.Kd=150",
            "--set", "solver.dt=1e-2", "--set", "run.t_end=5", "--set", "run.record_every=1",
            "--set", "solver.scheme=midpoint"]   # it holds the coupling over dt (the default solves it inside)
    out = run_cli(core + ["-o", str(tmp_path / "a")], tmp_path)
    assert out.returncode == 2 and "omega_c*dt = 4.472" in out.stderr and not (tmp_path / "a").exists()
    out = run_cli(core + ["-o", str(tmp_path / "b"), "--set", "run.allow_unstable=true"], tmp_path)
    assert out.returncode == 3 and "RuntimeWarning" not in out.stderr
    assert (tmp_path / "b" / "switching.partial.npz").exists()
    assert not list((tmp_path / "b").glob("*.png"))


def test_cold_numba_cache_is_detected(tmp_path):
    """`compiling kernels, first run only` is printed when the pair kernel has no valid cache."""
    import os
    import subprocess
    import sys
    code = "from fmu_sync.progress import caches_cold; print(caches_cold())"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "empty-cache")}
    cold = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert cold.stdout.strip() == "True", cold.stderr
    from fmu_sync.core import ImpactOscillator, simulate_pair
    simulate_pair(ImpactOscillator(k=1.0, e=0.9), (1.0, 0.0), (0.5, 0.0), 0.01, 1e-3)   # fills the cache
    warm = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert warm.stdout.strip() == "False", warm.stderr
