"""The implicit exchange on issue 33's stiff pair (``fmu-sync bench``, section ``implicit``).

Forced pair m = 1, k = 1, c = 0, f0 = 0.2, F = 0.5, Omega = 2.5, e = 0.9, slaves' solver.dt = 1e-3;
Euclidean law Kp = 100, Kd = 0.1 (omega_c H = 0.71 / 0.14 / 0.028 at the three H: the explicit
zero-order hold's bound is 4 zeta = 0.014); x1 = (1, 0), x2 = (0.2, 0.5); 20 s (our choice of
numbers, not the paper's). Truth: ``simulate_pair`` at dt = 1e-4; e1 = max |q1 - q1_truth| over the
first second. Per H: the explicit exchange (``allow_unstable=True``) against the implicit one
(``hold="foh"``, the line; ``"zoh"``, the mean): stable to the end?, max |q|, e1, FMU steps per
communication step (median, max), wall time per communication step, all in this process. MasterSim's
numbers are quoted from a run by hand (2026-11-28, /work/shared notes of issue 33), not measured here.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["run", "STIFF", "measure"]

STIFF = dict(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
X1, X2 = (1.0, 0.0), (0.2, 0.5)
GAINS = dict(Kp=100.0, Kd=0.1)
DT_SLAVE, DT_TRUTH = 1e-3, 1e-4
#: MasterSim 0.9's "Gauss-Seidel with iteration" on the same FMUs, by hand on 2026-11-28 (issue 33):
#: H -> (e1, iterations per step, wall time of the 20 s run)
MASTERSIM = {0.05: (0.32, "4.9–5.8", "4 s"), 0.01: (0.13, "5.5", "22.7 s"), 0.002: (0.033, "4.4", "91 s")}


EXCHANGES = (("explicit", dict(allow_unstable=True)), ("implicit, line (foh)", dict(exchange="implicit", hold="foh")),
             ("implicit, mean (zoh)", dict(exchange="implicit", hold="zoh")))


def measure(fmu: str, Hs, t_end: float, repeats: int = 3) -> tuple[dict, list]:
    """The truth's max |q| and each (H, exchange) row: dict(H, exchange, ok, qmax, e1, it_med, it_max,
    per_step, seconds (the median of ``repeats`` interleaved runs, after one warm-up run), note)."""
    from fmu_sync import cosimulate
    from fmu_sync.core import ImpactOscillator, RunFailed, simulate_pair
    truth = simulate_pair(ImpactOscillator(**STIFF), X1, X2, t_end, DT_TRUTH, coupling="euclidean", **GAINS)
    ref = dict(qmax=float(max(np.abs(truth.q1).max(), np.abs(truth.q2).max())))

    def one(H, kw):
        t0 = time.perf_counter()
        try:
            return cosimulate(fmu, X1, X2, t_end, H, "euclidean", **GAINS, **kw), "", time.perf_counter() - t0
        except RunFailed as exc:
            return exc.partial, str(exc).split(":")[0], time.perf_counter() - t0
    cosimulate(fmu, X1, X2, 1.0, 0.01, "euclidean", **GAINS, exchange="implicit", hold="foh")   # warm-up
    cases = [(H, name, kw) for H in Hs for name, kw in EXCHANGES]
    times = {(H, name): [] for H, name, _ in cases}
    for _ in range(repeats):
        for H, name, kw in cases:
            times[(H, name)].append(one(H, kw)[2])
    rows = []
    for H, name, kw in cases:
        r, note, _ = one(H, kw)
        sec = float(np.median(times[(H, name)]))
        k = int(round(H / DT_TRUTH))
        n = min(r.t.size, truth.t[::k].size)
        first = r.t[:n] <= 1.0 + 1e-9
        with np.errstate(invalid="ignore", over="ignore"):
            e1 = float(np.max(np.abs(r.q1[:n][first, 0] - truth.q1[::k][:n][first, 0])))
            qmax = float(max(np.abs(r.q1).max(), np.abs(r.q2).max()))
        it = r.info.get("iterations")
        rows.append(dict(H=H, exchange=name, ok=r.success and not note, qmax=qmax, e1=e1,
                         it_med=float(np.median(it)) if it is not None and len(it) else 1.0,
                         it_max=int(np.max(it)) if it is not None and len(it) else 1,
                         per_step=sec / max(1, r.t.size - 1), seconds=sec, note=note))
    return ref, rows


def run(quick: bool = False, smoke: bool = False, progress=None) -> str:
    """The section's markdown."""
    from fmu_sync import export_fmu
    t_end = 2.0 if smoke else 20.0
    Hs = (0.05, 0.01) if smoke else (0.05, 0.01, 0.002)
    with tempfile.TemporaryDirectory(prefix="fmu-sync-implicit-") as tmp:
        fmu = str(export_fmu("impact-oscillator", Path(tmp) / "stiff.fmu", {**STIFF, "solver.dt": DT_SLAVE}))
        ref, rows = measure(fmu, Hs, t_end, 1 if smoke else 3)
    if progress:
        progress(1.0)
    lines = ["## Implicit exchange on a stiff pair", "",
             f"Forced pair m = 1, k = 1, c = 0, f0 = 0.2, F = 0.5, Omega = 2.5, e = 0.9 (slaves: midpoint, "
             f"solver.dt = {DT_SLAVE:g}), Euclidean law Kp = {GAINS['Kp']:g}, Kd = {GAINS['Kd']:g}, x1 = {X1}, "
             f"x2 = {X2}, {t_end:g} s; truth: `simulate_pair` at dt = {DT_TRUTH:g} (max |q| = "
             f"{ref['qmax']:.3g}); e1 = max |q1 - q1_truth| over the first second. The explicit exchange "
             f"is refused at every H here (largest stable H 0.002); it runs with allow_unstable. Wall time "
             f"per communication step: the median of {1 if smoke else 3} interleaved runs in this process "
             f"(FMU-state rollback through the FMU's fmi2GetFMUstate/fmi2SetFMUstate).", "",
             "| H | exchange | to the end? | max \\|q\\| | e1 | FMU steps per step (median / max) | "
             "ms per step | run [s] |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ok = "yes" if r["ok"] else f"no ({r['note']})"
        lines.append(f"| {r['H']:g} | {r['exchange']} | {ok} | {r['qmax']:.3g} | {r['e1']:.3g} | "
                     f"{r['it_med']:g} / {r['it_max']} | {1e3 * r['per_step']:.3g} | {r['seconds']:.3g} |")
    by = {(r["H"], r["exchange"]): r for r in rows}
    line, mean, exp = (by.get((0.01, "implicit, line (foh)")), by.get((0.01, "implicit, mean (zoh)")),
                       by.get((0.002, "explicit")))
    if line and mean and exp:
        lines += ["", f"Implicit at H = 0.01 against explicit at H = 0.002, same process: wall time "
                      f"×{line['seconds'] / exp['seconds']:.2f} (line), ×{mean['seconds'] / exp['seconds']:.2f} "
                      f"(mean)."]
    lines += ["", "MasterSim (\"Gauss–Seidel with iteration\", FMU-state rollback, on the same FMUs through "
              "our coupling FMU), **measured by hand on 2026-11-28**, not by this benchmark: "
              + "; ".join(f"H = {H:g}: e1 = {e:g}, {it} iterations per step, {w} wall"
                          for H, (e, it, w) in MASTERSIM.items())
              + " (first order and overdamped).", ""]
    return "\n".join(lines)
