"""The master's exchange loop as it was in Python, before the compiled loop (issue 18),
kept as the test reference: :class:`PythonMaster` is :class:`fmu_sync.master.NetworkMaster`
(same set-up, same checks) with the old per-step Python methods, calling the FMU through
fmpy's ``FMU2Slave`` one variable at a time, with issue 16's end rule (the last step
shortened to land on t_end, the final state always recorded) as that issue wrote it into this
loop. tests/test_cosim_loop.py compares the compiled loop against it bit for bit. Not part of
the library."""
from __future__ import annotations

import math
import shutil

import numpy as np

from fmu_sync.core.coupling import chain_work
from fmu_sync.core.exchange import exchange_limit
from fmu_sync.core.pair import coupling_step
from fmu_sync.fmus import contract
from fmu_sync.master import FmuInstance, NetworkMaster, SlaveError


class InputHistory:
    """The inputs given at the last communication point (the first-order hold's history)."""

    def __init__(self, N: int, n: int):
        self.tau, self.t = np.zeros((N, n)), None

    def slope(self, i: int, tau_i: np.ndarray, t: float) -> np.ndarray:
        """d tau_i/dt at t from the inputs at t and at the last communication point."""
        if self.t is None or not t > self.t:
            return np.zeros_like(tau_i)
        return (tau_i - self.tau[i]) / (t - self.t)

    def remember(self, tau: np.ndarray, t: float) -> None:
        self.tau[:] = tau
        self.t = t

    def save(self):
        return self.tau.copy(), self.t

    def restore(self, saved) -> None:
        self.tau[:], self.t = saved


class PythonMaster(NetworkMaster):
    """NetworkMaster with the old Python exchange loop."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.exchange = getattr(self, "step_" + self.method.replace("-", "_"))

    def _start(self, unzipdir: str) -> None:
        super()._start(unzipdir)
        n = self.model.n
        self.tau = np.zeros((self.N, n))
        self.history = InputHistory(self.N, n)
        self.t1, self.t2 = np.zeros(n), np.zeros(n)
        self.work = chain_work(n)

    def read(self, s: FmuInstance) -> list:
        v = np.asarray(s.get(self.model.q + self.model.u), dtype=np.float64)
        n = self.model.n
        return [v[:n].copy(), v[n:].copy()]

    # ------------------------------------------------------------ coupling
    def pair(self, k: int, x, want_d: bool):
        """The pairwise law of edge k = (i, j) at states x: fills t1 (on i), t2 (on j)."""
        i, j = self.edges[k]
        return coupling_step(self.laws[k], self.geo, self.Kp_m, self.Kd_m, x[i][0], x[i][1], x[j][0],
                             x[j][1], self.t1, self.t2, *self.work, want_d)

    def input_of(self, i: int, x) -> None:
        """tau_i = sum_j a_ij tau_i^(j) at states x (one node at a time)."""
        A, tau = self.A, self.tau
        tau[i] = 0.0
        for k, (a, b) in enumerate(self.edges):
            if i == a and A[a, b] > 0.0:
                self.pair(k, x, False)
                tau[i] += A[a, b] * self.t1
            elif i == b and A[b, a] > 0.0:
                self.pair(k, x, False)
                tau[i] += A[b, a] * self.t2

    def inputs(self, x) -> None:
        """tau_i for every i at states x: each edge's law evaluated once."""
        A, tau = self.A, self.tau
        tau[:] = 0.0
        for k, (a, b) in enumerate(self.edges):
            self.pair(k, x, False)
            if A[a, b] > 0.0:
                tau[a] += A[a, b] * self.t1
            if A[b, a] > 0.0:
                tau[b] += A[b, a] * self.t2

    def check_forces(self, i: int, t: float, h: float) -> None:
        if not np.all(np.abs(self.tau[i]) <= contract.INPUT_BOUND):   # also catches NaN
            lim = exchange_limit(self.system.M, self.Kp_m, self.Kd_m, h, self.A_coupled, hold=self.hold)
            raise SlaveError(f"system{i + 1}", t, "coupling", 3, [
                f"its coupling force became non-finite or exceeds the FMU's input bound "
                f"{contract.INPUT_BOUND:g} ({self.tau[i].tolist()}): the explicit "
                f"exchange is unstable for these gains and this step ({lim.message()}): lower "
                f"Kp or H, or add Kd"])

    def _give(self, i: int, s: FmuInstance, t: float, h: float) -> None:
        s.set(dict(zip(self.model.tau, self.tau[i])))
        if self.hold == "foh":   # after the value (setting an input resets its derivative); fmu_sync.hold
            s.set_input_derivatives((
                dict(zip(self.model.tau, self.history.slope(i, self.tau[i], t)))))
        s.do_step(t, h)

    # ------------------------------------------------------------ exchange strategies
    def step_jacobi(self, t: float, h: float, x) -> list:
        """Every instance gets its input from the same states x, then all step."""
        self.inputs(x)
        for i in range(self.N):
            self.check_forces(i, t, h)
        for i, s in enumerate(self.slaves):
            self._give(i, s, t, h)
        self.history.remember(self.tau, t)
        return [self.read(s) for s in self.slaves]

    def step_gauss_seidel(self, t: float, h: float, x) -> list:
        """Instances step in index order, each input from the newest states of the others."""
        x = [list(xi) for xi in x]
        for i, s in enumerate(self.slaves):
            self.input_of(i, x)
            self.check_forces(i, t, h)
            self._give(i, s, t, h)
            x[i] = self.read(s)
        self.history.remember(self.tau, t)
        return x

    def communication_step(self, t: float, x, impacts: list, h: float) -> tuple[list, list]:
        """One step of length h (H, or the shortened last one) from t; event-aware: retaken in
        pieces of H_min if an impact counter moved. Returns (new states, impact counters)."""
        if not self.event_aware:
            new = self.exchange(t, h, x)
            return new, [s.get_integer(contract.IMPACTS) for s in self.slaves]
        saved, history = [s.save() for s in self.slaves], self.history.save()
        new = self.exchange(t, h, x)
        now = [s.get_integer(contract.IMPACTS) for s in self.slaves]
        if now != impacts:
            self.history.restore(history)
            new, now = self.retake(t, x, saved, h)
        for s, st in zip(self.slaves, saved):
            s.free_state(st)
        return new, now

    def retake(self, t: float, x, saved, H: float) -> tuple[list, list]:
        """Restore every instance to t and retake [t, t + H] in pieces of about H_min."""
        self.retakes += 1
        for s, st in zip(self.slaves, saved):
            s.restore(st, t)
        pieces = max(1, int(math.ceil(H / self.H_min - 1e-9)))
        new = x
        for p in range(pieces):
            tp = t + p * (H / pieces)
            hp = (t + H) - tp if p == pieces - 1 else H / pieces
            new = self.exchange(tp, hp, new)
        return new, [s.get_integer(contract.IMPACTS) for s in self.slaves]

    # ------------------------------------------------------------ recording
    def record(self, row: int, t: float, x, held) -> None:
        self.T[row] = t
        for i in range(self.N):
            self.Qr[row, i], self.Ur[row, i] = x[i]
        self.TAU[row] = held
        if self.need_d:
            for k in range(len(self.edges)):
                self.D[row, k], self.BR[row, k], self.EU[row, k] = self.pair(k, x, True)

    def run(self, progress=None) -> NetworkResult:
        """Run to t_end; raises :class:`SlaveError` if a slave fails and
        :class:`SimulationDiverged` if a state or distance becomes non-finite
        (``partial``: the finite record so far)."""
        from fmpy import extract
        unzipdir = extract(self.fmu)  # one unpacked copy shared by all instances, removed at the end
        failure = None
        try:
            self._start(unzipdir)
            x = [self.read(s) for s in self.slaves]
            if self.coupled:
                self.inputs(x)
            self.record(0, 0.0, x, self.tau)
            row = 1
            imp = [s.get_integer(contract.IMPACTS) for s in self.slaves]
            n_steps, H = self.n_steps, self.H
            report_every = max(1, n_steps // 200)
            for k in range(n_steps):   # the last step lands on t_end: the final state is always a row
                final, h, t_next = (True, self.grid.dt_last, self.grid.t_end) if k == n_steps - 1 else \
                    (False, H, (k + 1) * H)
                try:
                    x, imp = self.communication_step(k * H, x, imp, h)
                except SlaveError as ex:
                    failure = ex
                    break
                if not all(np.all(np.isfinite(xi[0])) and np.all(np.isfinite(xi[1])) for xi in x):
                    failure = self.diverged(t_next, "a state")
                    break
                if (k + 1) % self.record_every == 0 or final:
                    self.record(row, t_next, x, self.tau.copy())
                    if self.need_d and not np.all(np.isfinite(self.D[row])):
                        failure = self.diverged(t_next, "a distance")
                        break
                    row += 1
                if progress is not None and (k + 1) % report_every == 0:
                    progress((k + 1) / n_steps)
            if progress is not None:
                progress(1.0)
        finally:
            for s in self.slaves:
                s.close()
            shutil.rmtree(unzipdir, ignore_errors=True)
        res = self.result(row, imp, None if failure is None else str(failure))
        if failure is not None:
            failure.partial = res
            raise failure
        return res




class PythonSspMaster(PythonMaster):
    """:class:`PythonMaster` with the other masters' delayed orders as issue 19 wrote them
    (Python step methods; ``fmu_sync.ssp_master.SspMaster`` runs them in the compiled loop)."""

    METHODS = PythonMaster.METHODS + ("delayed", "delayed-zero")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._next = None   # the forces transferred for the next step

    def step_delayed(self, t: float, h: float, x) -> list:
        fresh = self.tau.copy() if self._next is None else self._next
        self.inputs(x)
        self._next, self.tau = self.tau, fresh
        return self._step_all(t, h)

    def step_delayed_zero(self, t: float, h: float, x) -> list:
        if self._next is None:
            self._next, self.tau = np.zeros_like(self.tau), np.zeros_like(self.tau)
            return self._step_all(t, h)
        return self.step_delayed(t, h, x)

    def _step_all(self, t: float, h: float) -> list:
        for i, s in enumerate(self.slaves):
            self.check_forces(i, t, h)
            self._give(i, s, t, h)
        return [self.read(s) for s in self.slaves]

    def record(self, row: int, t: float, x, held) -> None:
        if row == 0 and self.method == "delayed-zero":   # the force held over the first step: 0
            held = np.zeros_like(held)
        super().record(row, t, x, held)
