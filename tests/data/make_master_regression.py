"""Writes tests/data/master_regression.npz: fixed co-simulation runs of 0.6.0's master, the
numbers that tests/test_master_regression.py holds every later master to (explicit strategies
bit for bit, iterated ones to their convergence). Run from the repository root:

    python tests/data/make_master_regression.py

Only rerun it on purpose (a deliberate change of the master's numbers, said in the CHANGELOG).
The FMU's internal scheme is named (midpoint, solver.dt = 1e-3), so a change of the core's
default scheme does not move these numbers."""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _master_regression_cases import CASES, FMU_START, run_case  # noqa: E402

from fmu_sync.export import export_fmu  # noqa: E402


def main() -> None:
    out = Path(__file__).with_name("master_regression.npz")
    with tempfile.TemporaryDirectory() as tmp:
        fmu = export_fmu("impact-oscillator", Path(tmp) / "io.fmu", FMU_START)
        arrays = {}
        for name in CASES:
            for key, value in run_case(fmu, name).items():
                arrays[f"{name}/{key}"] = value
    np.savez_compressed(out, **arrays)
    print(f"{out}: {len(CASES)} runs")


if __name__ == "__main__":
    main()
