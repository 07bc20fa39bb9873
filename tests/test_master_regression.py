"""The master's numbers held across its restructurings (issue 43, item 6): fixed runs saved from
0.6.0 (tests/data/master_regression.npz, written by tests/data/make_master_regression.py) and
rerun here. The explicit strategies (Jacobi and Gauss–Seidel, both holds, the event-aware
retake, a network) must give the same record bit for bit; the iterated implicit exchange, whose
iteration may change, the same states to its own convergence (its recorded tau is not compared:
which force the record shows under the implicit exchange is documented, docs/cosimulation.md)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from _master_regression_cases import CASES, FMU_START, run_case

SAVED = Path(__file__).with_name("data") / "master_regression.npz"


@pytest.fixture(scope="module")
def saved():
    with np.load(SAVED) as z:
        return {k: z[k] for k in z.files}


@pytest.fixture(scope="module")
def fmu(shared_fmu):
    return shared_fmu("impact-oscillator", start_values=FMU_START)


@pytest.mark.parametrize("name", sorted(CASES))
def test_a_saved_run_is_reproduced(fmu, saved, name):
    exact = CASES[name][1]
    now = run_case(fmu, name)
    keys = [k for k in now if f"{name}/{k}" in saved]
    assert {"t", "q", "u"} <= set(keys)
    for k in keys:
        was = saved[f"{name}/{k}"]
        if exact:
            np.testing.assert_array_equal(now[k], was, err_msg=f"{name}: {k} changed")
        elif k != "tau":
            assert now[k].shape == was.shape, f"{name}: {k} has {now[k].shape} rows, was {was.shape}"
            np.testing.assert_allclose(now[k], was, rtol=0, atol=1e-6, err_msg=f"{name}: {k} moved")
