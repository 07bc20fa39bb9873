"""The smoke set of an environment with another numba (issue 41), run by .ci/numba-range in each
environment it builds: the core, the master on an FMU exported elsewhere (explicit and implicit),
a built-in scene and a local sweep from the command line, and the export's own word. Prints one
JSON line of findings; exits 1 if any check fails.

    python .ci/numba_smoke.py FMU WORKDIR EXPECT_NUMBA EXPORT_OK
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
import traceback
from pathlib import Path


def main(fmu: str, work: str, expect: str, export_ok: str) -> int:
    import numba
    import numpy as np
    out = {"numba": numba.__version__, "numpy": np.__version__, "checks": {}}
    work = Path(work)
    cli = [sys.executable, "-m", "fmu_sync.cli"]

    def check(name, fn):
        t0 = time.perf_counter()
        try:
            fn()
            out["checks"][name] = f"ok ({time.perf_counter() - t0:.1f} s)"
        except Exception:  # noqa: BLE001 - the finding is the point
            out["checks"][name] = "FAILED: " + traceback.format_exc(limit=3).strip().splitlines()[-1]

    def kept():
        assert numba.__version__ == expect, f"numba {numba.__version__}, expected the user's {expect}"

    def core():
        from fmu_sync.core import ImpactOscillator, simulate, simulate_pair, sync_rate
        from fmu_sync.core.exact import simulate_exact  # noqa: F401 (imports on every numba)
        osc = ImpactOscillator(m=1, k=1, c=0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
        r = simulate(osc, (1.0, 0.0), t_end=5, dt=1e-3)
        assert np.all(np.isfinite(r.q)) and r.q.min() >= -1e-2
        p = simulate_pair(osc, (1.0, 0.0), (0.2, 0.5), t_end=20, dt=1e-3, coupling="switching", Kp=1.0, Kd=0.5)
        assert p.d[-1] < 0.1 * p.d.max()
        s = sync_rate(osc, "switching", 4, x1=(1.0, 0.0), x2=(0.2, 0.5), t_end=100, dt=1e-3, Kp=1.0, Kd=0.5)
        assert s.n_resolved >= 1, s.text()

    def master():
        from fmu_sync import cosimulate
        for exchange in ("explicit", "implicit"):
            r = cosimulate(fmu, (1.0, 0.0), (0.2, 0.5), 5.0, 0.01, "switching", 1.0, 0.5, exchange=exchange)
            assert r.success and abs(r.t[-1] - 5.0) < 1e-12

    def scene():
        p = subprocess.run(cli + ["run", "forced-pair", "--variant", "switching", "--set", "run.t_end=5",
                                  "-o", str(work / "scene"), "--quiet", "--no-plots"], capture_output=True, text=True)
        assert p.returncode == 0, p.stderr[-500:]

    def sweep():
        p = subprocess.run(cli + ["sweep", "forced-pair", "--variant", "switching", "--grid", "coupling.Kp=[0.5,2.0]",
                                  "--set", "run.t_end=5", "--workers", "1", "-o", str(work / "sweep"), "--quiet",
                                  "--no-plots"], capture_output=True, text=True)
        assert p.returncode == 0, p.stderr[-500:]

    def export():
        target = work / "x.fmu"
        p = subprocess.run(cli + ["export", "impact-oscillator", "-o", str(target)], capture_output=True, text=True)
        if export_ok == "yes":
            assert p.returncode == 0 and target.is_file(), p.stderr[-500:]
        else:
            lines = p.stderr.strip().splitlines()
            assert p.returncode == 2 and len(lines) == 1 and "fmu-sync[export]" in lines[0], p.stderr[-800:]
            assert not target.exists()
            out["export_refusal"] = lines[0]

    for name, fn in (("numba kept", kept), ("core", core), ("master on an existing FMU", master),
                     ("fmu-sync run", scene), ("local sweep", sweep), ("export", export)):
        check(name, fn)
    rc = 0 if all(v.startswith("ok") for v in out["checks"].values()) else 1
    if export_ok != "yes" and out["checks"]["export"].startswith("ok"):
        out["checks"]["export"] = "refused in one line" + out["checks"]["export"][2:]
    print(json.dumps(out))
    return rc


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
