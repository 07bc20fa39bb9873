"""A scene's summary metrics and impact window come from every step, whatever the record's interval
(issue 36 item 3): the same scene at run.record_every = 1 and 10 has the same metrics, and the
impact window of the coarse run holds the mismatch of the fine one at the step's resolution; and
run.record_every counts solver.dt in both modes (a co-simulated record has the core's interval)."""
import math

import numpy as np
import pytest

from fmu_sync import load_scene, report
from fmu_sync.output import record_steps
from fmu_sync.plots import impact_window
from fmu_sync.scenes.running import record_interval, run_scene

SCENE, T_END = "forced-pair", 8.0


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = {}
    for k in (1, 10):
        d = tmp_path_factory.mktemp(f"every-{k}")
        out[k] = run_scene(SCENE, d, overrides={"run.t_end": T_END, "run.record_every": k}, plots=False).runs
    return out


def _same(a, b):
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def test_metrics_do_not_depend_on_record_every(runs):
    """Every metric of every variant is the same at record_every = 1 and 10 (only the record's row
    count differs), and equals report.metrics of the record_every = 1 record (every step)."""
    for fine, coarse in zip(runs[1], runs[10]):
        want = fine.result.t[::10]
        if want[-1] != fine.result.t[-1]:   # the final state is always a row
            want = np.append(want, fine.result.t[-1])
        rows = np.searchsorted(fine.result.t, want)
        assert np.array_equal(coarse.result.t, want)
        assert np.array_equal(coarse.result.q1, fine.result.q1[rows])
        for key, value in fine.metrics.items():
            if key != "records":
                assert _same(value, coarse.metrics[key]), (fine.name, key, value, coarse.metrics[key])
        ref = report.metrics(fine.result, fine.variant.system)
        for key in ("euclid_max", "peaking", "dV_impact", "dE_impact", "peak_tau", "episodes1", "episodes2",
                    "t_sync", "final_d", "impacts1", "impacts2", "rate", "bound"):
            if key in ref:
                assert _same(ref[key], fine.metrics[key]), (fine.name, key)
    # the decimated record alone would not give them: the maxima over its rows are smaller
    r = runs[10][0].result
    if r.d is not None:
        assert float(np.max(r.euclidean - r.d)) <= runs[10][0].metrics["peaking"]


def test_impact_window_holds_the_fine_runs_mismatch(runs):
    """The coarse run's impact window is the fine run's: rows at every step around the largest
    E - d, the same peak at the same time."""
    checked = 0
    for fine, coarse in zip(runs[1], runs[10]):
        if fine.result.d is None:
            continue
        w = impact_window(fine.result, fine.variant.system)
        rec = coarse.result.impact_record
        if w is None:
            continue
        k = w[2]
        peak = (fine.result.euclidean - fine.result.d)[k]
        assert rec is not None and np.allclose(np.diff(rec.t), fine.variant.cfg["solver.dt"])
        wc = impact_window(rec, coarse.variant.system)
        assert rec.t[wc[2]] == pytest.approx(fine.result.t[k])
        assert (rec.euclidean - rec.d)[wc[2]] == pytest.approx(peak, rel=1e-12)
        checked += 1
    assert checked


def test_record_every_counts_solver_dt_in_both_modes():
    """One scene records at one interval in the core and in co-simulation: k steps of solver.dt,
    in co-simulation the nearest whole number of steps of run.H (at least one)."""
    for k, H, dt, want in ((10, 1e-2, 1e-3, 1), (30, 1e-2, 1e-3, 3), (1, 1e-2, 1e-3, 1), (25, 1e-2, 1e-3, 2),
                           (5, 1e-3, 1e-3, 5)):
        keys = {"run.record_every": k, "solver.dt": dt}
        cosim = load_scene(SCENE, {**keys, "run.mode": "cosim", "run.H": H}).variants[0]
        core = load_scene(SCENE, {**keys, "run.mode": "core"}).variants[0]
        assert record_steps(cosim.cfg) == want and record_steps(core.cfg) == k
        assert record_interval(cosim)[0] == pytest.approx(want * H)
        assert record_interval(core)[0] == pytest.approx(k * dt)
        if (k * dt / H) == round(k * dt / H):   # a whole number of H: the same interval
            assert record_interval(cosim)[0] == pytest.approx(record_interval(core)[0])

