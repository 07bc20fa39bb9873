"""fmi2Reset reuses an instance (docs/cosimulation.md): a reset instance, set up again with the
same start values, runs bit for bit as a fresh one, whatever it ran before (another
scheme, other parameters, impacts, a failed step).

The FMU is loaded in a child process, as in tests/test_fmu_run.py:
``python tests/test_fmu_reset.py ARGS.json RESULT.json``.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

from fmu_sync.fmus.contract import SCHEME_ITEMS

CODE = {item: value for item, value, _ in SCHEME_ITEMS}
OUT = ["q", "u", "gap", "energy", "impacts", "percussion"]
STEPS = 400
H = 0.01

#: (label, start values): the runs compared; each is run fresh and after a reset from every other
CASES = [
    ("midpoint", {"q_start": 0.8, "u_start": -0.3, "e": 0.7, "F": 0.6, "solver.dt": 1e-3}),
    ("theta", {"q_start": 0.5, "u_start": 0.4, "k": 2.0, "solver.scheme": CODE["theta"], "solver.theta": 0.75,
               "solver.dt": 2e-3}),
    ("exact", {"q_start": 0.2, "u_start": -1.0, "e": 0.5, "F": 0.0, "solver.scheme": CODE["exact"]}),
]


def _run(h, starts: dict) -> list:
    """Initialise with ``starts`` and run STEPS steps of a time-varying input; the outputs per step."""
    assert h.initialize(0.0, starts) == 0, h.messages[-3:]
    rows, t = [], 0.0
    for k in range(STEPS):
        assert h.set({"tau": 0.4 * math.sin(3.0 * t) - 0.1}) == 0
        assert h.do_step(t, H) == 0, h.messages[-3:]
        t = (k + 1) * H
        rows.append(h.get(OUT))
    return rows


def _child_main(args_path: str, out_path: str) -> None:
    from fmu_sync.fmi_bridge import FMUHost
    fmu = json.loads(Path(args_path).read_text())["fmu"]
    out = {}
    for label, starts in CASES:
        h = FMUHost(fmu, instance_name="fresh", logging=True)
        out[f"fresh {label}"] = _run(h, starts)
        h.close()
    h = FMUHost(fmu, instance_name="reused", logging=True)
    h.initialize(0.0, {"tau": 0.0})
    assert h.do_step(0.0, 1e9) == 3   # a refused step (too many internal steps) before the first reset
    for before in CASES:
        for label, starts in CASES:
            assert h.call("reset")[0] == 0, h.messages[-3:]
            out[f"after {before[0]}: {label}"] = _run(h, starts)
            assert h.call("reset")[0] == 0
            _run(h, before[1])   # leave the instance in the state of another run
    h.close()
    Path(out_path).write_text(json.dumps(out))


def test_a_reset_instance_runs_bit_for_bit_as_a_fresh_one(tmp_path):
    from fmu_sync.export import export_fmu
    fmu = export_fmu("impact-oscillator", tmp_path / "io.fmu")
    args = tmp_path / "args.json"
    args.write_text(json.dumps({"fmu": str(fmu)}))
    out = tmp_path / "out.json"
    p = subprocess.run([sys.executable, __file__, str(args), str(out)], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    r = json.loads(out.read_text())
    for label, _ in CASES:
        fresh = r[f"fresh {label}"]
        assert len(fresh) == STEPS and fresh[-1][4] > 0   # impacts happened
        reused = [k for k in r if k.endswith(f": {label}")]
        assert len(reused) == len(CASES)
        for key in reused:
            assert r[key] == fresh, key   # JSON floats round-trip exactly: bit for bit
    # the cases differ from each other (a reset that kept nothing would not be tested otherwise)
    assert r["fresh midpoint"] != r["fresh theta"] != r["fresh exact"]


if __name__ == "__main__":
    _child_main(*sys.argv[1:])
