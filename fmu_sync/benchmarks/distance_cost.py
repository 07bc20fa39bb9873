"""Cost of the compiled quotient-distance and coupling kernels (ns per call).

    python -m fmu_sync.benchmarks.distance_cost [--n-calls 200000] [--repeats 15]
    (also part of `fmu-sync bench`)

Each timing runs the kernel in a loop inside an njit function (no Python
overhead per call); the state is copied into fixed (n,) arrays before each call,
as a simulation loop would hold it (or read as scalars for the 1-DOF scalar
kernels).  Reports the median over repeated batches of the thread CPU time,
minus the cost of the empty loop.
Kernels: the scalar 1-DOF ones (distance1, coupling_kernel1: floats in/out)
and the array ones (distance_kernel, coupling_kernel: any n, numba-inlined
into the loop).  Cases:
  near     1-DOF, x2 = x1 + O(1e-3) noise (typical synchronising run: branch E, pruned)
  random   1-DOF, independent random states around the wall (all branches occur)
  impact   1-DOF, both states close to the wall with opposite normal velocities
           (J12/J21 need the Newton solve)
  worst    every branch evaluated (pruning off) on the 'impact' states
  2-DOF    the same kernels for n = 2 (non-diagonal M, Q, oblique wall), 'random'
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit

from fmu_sync.core.kernels import (SWITCHING, core_2d, coupling_kernel, coupling_kernel1, distance1,
                                   distance_kernel, distance_kernel_unpruned, gain_matrix, make_geometry)


@njit(cache=True, inline="always")
def _vectors(n):
    """Four work vectors of length n."""
    return np.empty(n), np.empty(n), np.empty(n), np.empty(n)


@njit(cache=True, inline="always")
def _read_row(i, Q1, U1, Q2, U2, q1, u1, q2, u2):
    """Copy the states of call ``i`` into the work vectors (the same copy in every timed loop
    and in its baseline)."""
    for j in range(Q1.shape[1]):
        q1[j] = Q1[i, j]
        u1[j] = U1[i, j]
        q2[j] = Q2[i, j]
        u2[j] = U2[i, j]


@njit(cache=True)
def _loop_distance(geo, Q1, U1, Q2, U2, unpruned):
    n = Q1.shape[1]
    q1, u1, q2, u2 = _vectors(n)
    c1q, c1u, c2q, c2u = _vectors(n)
    acc = 0.0
    for i in range(Q1.shape[0]):
        _read_row(i, Q1, U1, Q2, U2, q1, u1, q2, u2)
        if unpruned:
            d, b = distance_kernel_unpruned(geo, q1, u1, q2, u2, c1q, c1u, c2q, c2u)
        else:
            d, b = distance_kernel(geo, q1, u1, q2, u2, c1q, c1u, c2q, c2u)
        acc += d + b
    return acc


@njit(cache=True)
def _loop_copy_only(Q1, U1, Q2, U2):
    n = Q1.shape[1]
    q1, u1, q2, u2 = _vectors(n)
    acc = 0.0
    for i in range(Q1.shape[0]):
        _read_row(i, Q1, U1, Q2, U2, q1, u1, q2, u2)
        acc += q1[0] + u2[0]
    return acc


@njit(cache=True)
def _loop_coupling(geo, Kp, Kd, Q1, U1, Q2, U2):
    n = Q1.shape[1]
    q1, u1, q2, u2 = _vectors(n)
    t1 = np.empty(n)
    t2 = np.empty(n)
    c1q, c1u, c2q, c2u = _vectors(n)
    acc = 0.0
    for i in range(Q1.shape[0]):
        _read_row(i, Q1, U1, Q2, U2, q1, u1, q2, u2)
        d, b = coupling_kernel(SWITCHING, geo, Kp, Kd, q1, u1, q2, u2, t1, t2, c1q, c1u, c2q, c2u)
        acc += d + t1[0] + t2[0]
    return acc


@njit(cache=True)
def _loop_distance1(sg, Q1, U1, Q2, U2, unpruned):
    acc = 0.0
    for i in range(Q1.shape[0]):
        if unpruned:   # the 1-DOF planar problem with every branch evaluated
            X1 = (sg.w1 * Q1[i, 0] + sg.g0) / sg.sqrtWQ
            X2 = (sg.w1 * Q2[i, 0] + sg.g0) / sg.sqrtWQ
            Y1 = sg.w1 * U1[i, 0] / sg.sqrtW
            Y2 = sg.w1 * U2[i, 0] / sg.sqrtW
            r = core_2d(X1, Y1, X2, Y2, X1 - X2, Y1 - Y2, sg.e, sg.k, False)
            acc += r[0] + r[2]
        else:
            r1 = distance1(sg, Q1[i, 0], U1[i, 0], Q2[i, 0], U2[i, 0])
            acc += r1[0] + r1[2]
    return acc


@njit(cache=True)
def _loop_coupling1(sg, kp, kd, Q1, U1, Q2, U2):
    acc = 0.0
    for i in range(Q1.shape[0]):
        t1, t2, d, b = coupling_kernel1(SWITCHING, sg, kp, kd, Q1[i, 0], U1[i, 0], Q2[i, 0], U2[i, 0])
        acc += t1 + t2 + d
    return acc


@njit(cache=True)
def _loop_scalar_read_only(Q1, U1, Q2, U2):
    acc = 0.0
    for i in range(Q1.shape[0]):
        acc += Q1[i, 0] + U1[i, 0] * Q2[i, 0] + U2[i, 0]
    return acc


def _median_ns(fn, args, n_calls, repeats):
    """Median over ``repeats`` batches of the thread's CPU time per call (CPU
    time, not wall time: robust when other processes share the machine)."""
    fn(*args)  # compile / warm up
    times = []
    for _ in range(repeats):
        t0 = time.thread_time()
        fn(*args)
        times.append(time.thread_time() - t0)
    return 1e9 * float(np.median(times)) / n_calls


def _states(rng, n_calls, case, n=1):
    if case == "near":
        Q1 = rng.uniform(0.0, 1.0, (n_calls, n))
        U1 = rng.uniform(-1.0, 1.0, (n_calls, n))
        return Q1, U1, Q1 + 1e-3 * rng.standard_normal((n_calls, n)), U1 + 1e-3 * rng.standard_normal((n_calls, n))
    if case == "random":
        return (rng.uniform(-0.2, 1.0, (n_calls, n)), rng.uniform(-2.0, 2.0, (n_calls, n)),
                rng.uniform(-0.2, 1.0, (n_calls, n)), rng.uniform(-2.0, 2.0, (n_calls, n)))
    if case == "impact":  # x1 just before, x2 just after an impact (or vice versa)
        s = rng.choice([-1.0, 1.0], (n_calls, 1))
        return (rng.uniform(1e-4, 0.05, (n_calls, n)), s * rng.uniform(-2.0, -0.2, (n_calls, n)),
                rng.uniform(1e-4, 0.05, (n_calls, n)), -s * rng.uniform(-2.0, -0.2, (n_calls, n)))
    raise ValueError(case)


def measure(n_calls: int = 200_000, repeats: int = 15, seed: int = 1) -> list[tuple[str, float | str]]:
    """Rows ``(label, ns per call)`` of every case (see the module docstring)."""
    rng = np.random.default_rng(seed)
    N, R = n_calls, repeats
    geo1 = make_geometry([[1.0]], [1.0], 0.0, 0.8)
    geo2 = make_geometry([[2.0, 0.5], [0.5, 1.0]], [1.0, -0.3], 0.2, 0.8, [[1.5, 0.3], [0.3, 0.7]])
    rows = []
    base = _median_ns(_loop_copy_only, _states(rng, N, "near"), N, R)
    base1 = _median_ns(_loop_scalar_read_only, _states(rng, N, "near"), N, R)
    rows.append(("(loop overhead, subtracted: arrays / scalars)", f"{base:.1f} / {base1:.1f}"))
    kp, kd = gain_matrix(1.0, 1), gain_matrix(0.5, 1)
    for case in ("near", "random", "impact"):
        S = _states(rng, N, case)
        rows.append((f"1-DOF {case}: distance1 (scalars)",
                     _median_ns(_loop_distance1, (geo1.scalar, *S, False), N, R) - base1))
        rows.append((f"1-DOF {case}: distance_kernel (arrays)",
                     _median_ns(_loop_distance, (geo1, *S, False), N, R) - base))
    S = _states(rng, N, "impact")
    rows.append(("1-DOF worst, all branches: planar core (scalars)",
                 _median_ns(_loop_distance1, (geo1.scalar, *S, True), N, R) - base1))
    rows.append(("1-DOF worst, all branches: distance_kernel (arrays)",
                 _median_ns(_loop_distance, (geo1, *S, True), N, R) - base))
    S = _states(rng, N, "random")
    rows.append(("1-DOF random: switching coupling1 (scalars)",
                 _median_ns(_loop_coupling1, (geo1.scalar, 1.0, 0.5, *S), N, R) - base1))
    rows.append(("1-DOF random: switching coupling_kernel (arrays)",
                 _median_ns(_loop_coupling, (geo1, kp, kd, *S), N, R) - base))
    S = _states(rng, N, "random", n=2)
    rows.append(("2-DOF random: distance_kernel", _median_ns(_loop_distance, (geo2, *S, False), N, R) - base))
    rows.append(("2-DOF worst, all branches: distance_kernel",
                 _median_ns(_loop_distance, (geo2, *S, True), N, R) - base))
    rows.append(("2-DOF random: switching coupling_kernel", _median_ns(
        _loop_coupling, (geo2, gain_matrix(1.0, 2), gain_matrix(0.5, 2), *S), N, R) - base))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-calls", type=int, default=200_000)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    for name, ns in measure(a.n_calls, a.repeats, a.seed):
        print(f"{name:52s} {ns if isinstance(ns, str) else f'{ns:8.1f}'} ns/call")


if __name__ == "__main__":
    main()
