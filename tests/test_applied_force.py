"""What the record's tau is under the implicit exchange (issue 39 item 7): the row at t_k holds the law
at the states of t_k, while the FMUs integrated the line from it to the law at the step's end (held as
its mean with the zero-order hold). :func:`fmu_sync.applied.applied_forces` gives that force; checked
against the closed-form flow of the undamped oscillator q'' = -k q + tau / m under the force each way
(an independent reference: the FMU's own step is a midpoint scheme at solver.dt)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fmu_sync.applied import applied_forces
from fmu_sync.master import cosimulate

FREE = dict(m=1.0, k=1.0, c=0.0, f0=0.0, F=0.0, Omega=2.5, e=0.9, g0=10.0)   # the wall far away: no impact
H = 0.01


@pytest.fixture(scope="module")
def fmu(tmp_path_factory):
    from fmu_sync.export import export_fmu
    return str(export_fmu("impact-oscillator", tmp_path_factory.mktemp("applied") / "free.fmu",
                          {**FREE, "solver.dt": 1e-4}))


def _flow(q0, u0, f, h, k=1.0, m=1.0):
    """Closed form of m q'' = -k q + f (f constant) over h."""
    w = math.sqrt(k / m)
    qs = f / k
    return (qs + (q0 - qs) * math.cos(w * h) + u0 / w * math.sin(w * h),
            -(q0 - qs) * w * math.sin(w * h) + u0 * math.cos(w * h))


def _misfit(res, force):
    """Largest error of system 1's next recorded state against the closed-form step under ``force``."""
    worst = 0.0
    q1, u1, force = np.ravel(res.q1), np.ravel(res.u1), np.ravel(force)
    for k in range(len(force)):
        q, u = _flow(q1[k], u1[k], force[k], res.t[k + 1] - res.t[k])
        worst = max(worst, abs(q - q1[k + 1]), abs(u - u1[k + 1]))
    return worst


def test_implicit_zoh_applies_the_mean_of_the_two_ends_not_the_recorded_tau(fmu):
    res = cosimulate(fmu, (1.0, 0.0), (0.2, 0.5), 0.5, H, "euclidean", 1.0, 0.5, exchange="implicit")
    t, start, end = applied_forces(res)
    start1, end1 = np.ravel(np.asarray(start)[:, 0]), np.ravel(np.asarray(end)[:, 0])
    np.testing.assert_array_equal(start1, np.ravel(res.tau1)[1:-1])    # the recorded tau is the line's start
    applied = _misfit(res, 0.5 * (start1 + end1))
    recorded = _misfit(res, np.ravel(res.tau1)[1:-1])
    assert applied < 2e-9, applied                # the FMU's midpoint steps at 1e-4 s, nothing more
    assert recorded > 50 * applied, (recorded, applied)    # the recorded tau is not what was integrated


def test_explicit_zoh_applies_the_recorded_tau(fmu):
    res = cosimulate(fmu, (1.0, 0.0), (0.2, 0.5), 0.5, H, "euclidean", 1.0, 0.5)
    _, start, end = applied_forces(res)
    np.testing.assert_array_equal(start, end)
    assert _misfit(res, np.asarray(start)[:, 0]) < 2e-9


def test_a_thinned_record_cannot_say_it(fmu):
    res = cosimulate(fmu, (1.0, 0.0), (0.2, 0.5), 0.2, H, "euclidean", 1.0, 0.5, exchange="implicit",
                     record_every=2)
    with pytest.raises(ValueError, match="thinned"):
        applied_forces(res)
