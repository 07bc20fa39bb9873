"""The master and its compiled loop talk by name (issue 43 item 3): one builder
(cosim_args.loop_arguments) makes the loop's arguments, state and work arrays as named tuples, the
flags are filled by name, and a per-step array is never written past the end the builder sized."""
from __future__ import annotations

import numpy as np
import pytest

from fmu_sync import cosim_args as args
from fmu_sync import cosim_loop as loop
from fmu_sync.core.errors import RunFailed
from fmu_sync.master import NetworkMaster, cosimulate

X1, X2 = (1.0, 0.0), (0.2, 0.5)
LAW = dict(coupling="switching", Kp=1.0, Kd=0.5)
FORCED = dict(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)


@pytest.fixture(scope="module")
def fmu(shared_fmu):
    return shared_fmu("impact-oscillator", 2, dict(FORCED, **{"solver.dt": 1e-3}))


def test_flags_are_filled_by_name():
    f = args.named_flags(gauss_seidel=1, delay=2, steps=7, max_iter=30)
    assert f.dtype == np.int64 and f.size == loop.FLAGS == len(loop.FLAG_NAMES)
    assert (f[loop.GAUSS_SEIDEL], f[loop.DELAY], f[loop.STEPS], f[loop.MAX_ITER]) == (1, 2, 7, 30)
    assert np.count_nonzero(f) == 4
    with pytest.raises(ValueError, match="unknown loop flag 'gauss_seidl'"):
        args.named_flags(gauss_seidl=1)


def test_the_builder_makes_named_structures_and_ptr_follows_held(fmu):
    m = NetworkMaster(fmu, [X1, X2], [[0.0, 1.0], [1.0, 0.0]], 0.2, 0.05, exchange="implicit", **LAW)
    m.run()
    a, s = m.loop_args, m.loop_state
    assert isinstance(a, args.LoopArgs) and isinstance(s, args.LoopState)
    assert isinstance(s.keep, args.Keep) and isinstance(s.w, args.Work) and isinstance(s.keep.iw, args.ImplicitWork)
    assert s.keep.iw is m.iw and a.flags[loop.IMPLICIT] == 1 and a.H == 0.05 and a.t_last == 0.2
    assert m.iw.iters.size == m.n_steps == 4 and np.all(m.iw.iters > 0)
    # every ptr slot is the address of the Held field of its name
    for name, arr in m.held._asdict().items():
        assert a.ptr[m.held._fields.index(name)] == arr.ctypes.data
    assert m.held.buf is s.w.buf and m.held.ibuf is s.keep.ibuf and m.held.saved is s.saved
    grown = args.with_room(m.iw, 10)
    assert grown.iters.size == 10 and np.array_equal(grown.iters[:4], m.iw.iters) and np.isnan(grown.resid[4:]).all()


def test_a_per_step_array_sized_too_short_stops_the_run_instead_of_overflowing(fmu, monkeypatch):
    """0.6.0's merge bug: the implicit exchange's third per-step array was not grown with the other two
    and written past its end. Now the kernel checks the index against the size the builder gave."""
    from fmu_sync import cosim_args
    made = cosim_args.implicit_work

    def short(N, n, E, steps, *args, **kw):
        return made(N, n, E, max(0, steps - 2) if steps else 0, *args, **kw)
    monkeypatch.setattr(cosim_args, "implicit_work", short)
    with pytest.raises(RunFailed, match="per-step arrays hold 4 steps, step 4 at t = 0.4") as err:
        cosimulate(fmu, X1, X2, 0.6, 0.1, exchange="implicit", **LAW)
    r = err.value.partial
    assert r.t[-1] == pytest.approx(0.4) and len(r.t) == 5     # the 4 steps that had room, recorded


def test_the_outcome_codes_are_one_list_and_distinct():
    """0.7.0's controller said FULL = 5, the loop's NOT_CONVERGED = 5: a not-converged implicit step at
    the floor under tol was taken for a full record (grow and retry). One list now."""
    from fmu_sync import cosim_adaptive as ad
    codes = (loop.DONE, loop.SLAVE_FAILED, loop.FORCE_BOUND, loop.STATE_DIVERGED, loop.DISTANCE_DIVERGED,
             loop.NOT_CONVERGED, loop.FULL, loop.NO_ROOM)
    assert len(set(codes)) == len(codes) and ad.FULL is loop.FULL
