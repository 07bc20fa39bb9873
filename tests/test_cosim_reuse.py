"""Instances kept between runs (fmu_sync.master.keep_instances, the sweep workers' setting):
a run on reset, reused instances gives bit for bit the record of a run on fresh ones."""
from __future__ import annotations

import numpy as np
import pytest

from fmu_sync.master import NetworkMaster, cosimulate, keep_instances

PAIR = [[0.0, 1.0], [1.0, 0.0]]
#: runs that leave the instances in different states (impacts, retakes, input derivatives, parameters)
RUNS = [
    dict(x=[(1.0, 0.0), (0.3, 0.5)], coupling="switching", Kp=1.0, Kd=0.5),
    dict(x=[(0.9, -0.2), (0.1, 0.8)], coupling="euclidean", Kp=2.0, Kd=0.3, event_aware=True,
         method="gauss-seidel", start_values=[{"e": 0.6, "k": 0.8}, {"e": 0.6, "k": 1.3}]),
    dict(x=[(0.5, 0.5), (1.2, 0.0)], coupling="switching", Kp=0.8, Kd=0.8, hold="foh"),
]


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    from fmpy import extract

    from fmu_sync.export import export_fmu
    tmp = tmp_path_factory.mktemp("reuse")
    fmu = export_fmu("impact-oscillator", tmp / "osc.fmu", {"solver.dt": 1e-3, "F": 0.5, "Omega": 2.5})
    folder = extract(str(fmu), unzipdir=str(tmp / "unpacked"))
    keep_instances(folder)
    return str(fmu), folder


def _master(path, r):
    kw = {k: v for k, v in r.items() if k != "x"}
    return NetworkMaster(path, r["x"], PAIR, 3.0, 0.01, **kw)


def _record(res):
    return [res.t, res.q, res.u, res.tau, res.d, res.branch, np.array(res.impacts)]


def test_reused_instances_reproduce_fresh_runs_bit_for_bit(fmus):
    fmu, folder = fmus
    fresh = [_record(_master(fmu, r).run()) for r in RUNS]   # an .fmu file: fresh instances, freed
    assert any(f[-1].sum() > 0 for f in fresh)
    previous = None
    for rnd in range(2):
        for r, ref in zip(RUNS, fresh):
            m = _master(folder, r)
            got = _record(m.run())
            for a, b in zip(got, ref):
                assert np.array_equal(a, b), (rnd, r)
            if previous is not None:   # the instances of the previous run, reset
                assert all(a is b for a, b in zip(m.slaves, previous.slaves)) and len(m.slaves) == len(previous.slaves)
            previous = m


def test_a_failed_run_does_not_spoil_the_kept_instances(fmus):
    fmu, folder = fmus
    with pytest.raises(ValueError):   # a start state inside the wall: refused after the instances started
        cosimulate(folder, (-0.5, 0.0), (1.0, 0.0), 1.0, 0.01, coupling="switching", Kp=1.0, Kd=0.5)
    r = RUNS[0]
    got = _record(_master(folder, r).run())
    ref = _record(_master(fmu, r).run())
    assert all(np.array_equal(a, b) for a, b in zip(got, ref))
