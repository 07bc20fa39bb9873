"""The fixed co-simulation runs of tests/test_master_regression.py (and of the script that saved
their records, tests/data/make_master_regression.py): one table, read by both."""
from __future__ import annotations

import numpy as np

from fmu_sync import cosimulate, cosimulate_network
from fmu_sync.core import ring

#: the FMU of every case: the scheme named, so the core's default scheme does not enter
FMU_START = {"e": 0.9, "solver.dt": 1e-3, "solver.scheme": "midpoint"}
X1, X2 = (1.0, 0.0), (0.2, 0.5)
RING = [(1.0, 0.0), (0.2, 0.5), (0.7, -0.3), (1.3, 0.2)]

#: name -> (keyword arguments, exact): exact cases are held bit for bit, the others (iterated
#: to a tolerance) to their own convergence
CASES = {
    "jacobi-zoh-switching": (dict(coupling="switching", Kp=1.0, Kd=0.5, H=0.01), True),
    "jacobi-foh-euclidean": (dict(coupling="euclidean", Kp=1.0, Kd=0.5, H=0.01, hold="foh"), True),
    "gauss-seidel-switching": (dict(coupling="switching", Kp=1.0, Kd=0.5, H=0.01, method="gauss-seidel"), True),
    "event-aware-switching": (dict(coupling="switching", Kp=1.0, Kd=0.5, H=0.02, event_aware=True), True),
    "uncoupled": (dict(coupling=None, H=0.01), True),
    "ring4-switching": (dict(coupling="switching", Kp=1.0, Kd=0.5, H=0.01, network=True), True),
    "implicit-zoh-euclidean": (dict(coupling="euclidean", Kp=100.0, Kd=0.1, H=0.01, exchange="implicit"), False),
    "implicit-foh-switching": (dict(coupling="switching", Kp=1.0, Kd=0.5, H=0.01, hold="foh",
                                    exchange="implicit"), False),
}
T_END = 3.0


def run_case(fmu, name: str) -> dict:
    """The record of one case: t, q, u, tau (and d where it is defined)."""
    kw = dict(CASES[name][0])
    if kw.pop("network", False):
        r = cosimulate_network(fmu, RING, ring(len(RING)), T_END, **kw)
        return {"t": r.t, "q": r.q, "u": r.u, "tau": r.tau}
    r = cosimulate(fmu, X1, X2, T_END, **kw)
    return {"t": r.t, "q": np.stack([r.q1, r.q2]), "u": np.stack([r.u1, r.u2]),
            "tau": np.stack([r.tau1, r.tau2]), "d": r.d}
