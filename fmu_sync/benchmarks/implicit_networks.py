"""The implicit exchange on networks with impacts (``fmu-sync bench``, section ``networks``; issue 39).

Rings of N forced impact oscillators (m = 1, k = 1, c = 0, f0 = 0.2, F = 0.5, Omega = 2.5, e = 0.9,
wall at q = 0; slaves' solver.dt = 1e-3), random starts q in [0.2, 1.5], u in [-0.5, 0.5] (seed 0),
Kp = 1, Kd = 0.5, H = 0.01, both laws (euclidean, switching), both holds (zoh, foh). Per case the
explicit and the implicit exchange: to the end?, FMU steps per communication step (median / max),
error max |q - q_core| against the monolithic core (``simulate_network``, dt = 1e-3) at the
communication points, wall time per node and communication step (one run each, this process) and
the implicit run's cost relative to the explicit one's. The tolerance rows: ``tol=1e-3``.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["run", "RING", "measure"]

RING = dict(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
GAINS = dict(Kp=1.0, Kd=0.5)
DT_SLAVE, DT_CORE, H = 1e-3, 1e-3, 0.01


def _starts(N: int, seed: int = 0):
    g = np.random.default_rng(seed)
    return [(g.uniform(0.2, 1.5), g.uniform(-0.5, 0.5)) for _ in range(N)]


def measure(fmu: str, N: int, law: str, hold: str, exchange: str, t_end: float, ref, tol=None) -> dict:
    """One run: dict(ok, note, t, it_med, it_max, err, us (µs per node and communication step), seconds)."""
    from fmu_sync import cosimulate_network
    from fmu_sync.core import RunFailed, ring
    t0 = time.perf_counter()
    note = ""
    try:
        r = cosimulate_network(fmu, _starts(N), ring(N), t_end, H, law, **GAINS, hold=hold, exchange=exchange, tol=tol)
    except RunFailed as exc:
        r, note = exc.partial, str(exc).split(":")[0]
    sec = time.perf_counter() - t0
    it = r.info.get("iterations") if r is not None else None
    err = np.nan
    if r is not None and r.t.size:
        idx = np.rint(r.t / DT_CORE).astype(int)
        err = float(np.abs(r.q[:, :, 0] - ref.q[idx, :, 0]).max())
    steps = max(1, int(r.info.get("steps") or (r.t.size - 1))) if r is not None else 1   # tol: the accepted steps
    return dict(ok=r is not None and r.success and not note, note=note, t=float(r.t[-1]) if r is not None else 0.0,
                it_med=float(np.median(it)) if it is not None and len(it) else 1.0,
                it_max=int(np.max(it)) if it is not None and len(it) else 1, err=err,
                us=1e6 * sec / (N * steps), seconds=sec)


def run(quick: bool = False, smoke: bool = False, progress=None) -> str:
    """The section's markdown."""
    from fmu_sync import export_fmu
    from fmu_sync.core import ImpactOscillator, ring, simulate_network
    Ns = (8,) if smoke else (8, 32, 64) if quick else (8, 32, 64, 256)
    t_end = 0.2 if smoke else 2.0 if quick else 5.0
    combos = [(law, hold) for law in ("euclidean", "switching") for hold in ("zoh", "foh")]
    if smoke:
        combos = combos[:1]
    tols = () if smoke else ((32,) if quick else (32, 64))
    rows, trows = [], []
    with tempfile.TemporaryDirectory(prefix="fmu-sync-networks-") as tmp:
        fmu = str(export_fmu("impact-oscillator", Path(tmp) / "io.fmu", {**RING, "solver.dt": DT_SLAVE}))
        measure(fmu, 8, "euclidean", "zoh", "implicit", 0.05, simulate_network(
            ImpactOscillator(**RING), _starts(8), ring(8), 0.05, DT_CORE, "euclidean", **GAINS))   # warm-up
        total = len(Ns) * len(combos) + 2 * len(tols)
        done = 0
        for N in Ns:
            refs = {law: simulate_network(ImpactOscillator(**RING), _starts(N), ring(N), t_end, DT_CORE, law, **GAINS)
                    for law in {c[0] for c in combos}}
            for law, hold in combos:
                ex = measure(fmu, N, law, hold, "explicit", t_end, refs[law])
                im = measure(fmu, N, law, hold, "implicit", t_end, refs[law])
                rows.append((N, law, hold, ex, im))
                done += 1
                if progress:
                    progress(done / total)
            if N in tols:
                for exchange in ("explicit", "implicit"):
                    trows.append((N, exchange, measure(fmu, N, "euclidean", "zoh", exchange, t_end, refs["euclidean"],
                                                       tol=1e-3)))
                    done += 1
    lines = ["## Implicit exchange on networks with impacts", "",
             f"Rings of N forced impact oscillators (m = 1, k = 1, c = 0, f0 = 0.2, F = 0.5, Omega = 2.5, e = 0.9, "
             f"wall at q = 0; slaves: solver.dt = {DT_SLAVE:g}), random starts q in [0.2, 1.5], u in [-0.5, 0.5] "
             f"(seed 0), Kp = {GAINS['Kp']:g}, Kd = {GAINS['Kd']:g}, H = {H:g}, {t_end:g} s. Error: max |q − q_core| "
             f"at the communication points against the monolithic core (`simulate_network`, dt = {DT_CORE:g}). "
             "Cost: wall time per node and communication step (one run each, this process); ×: the implicit "
             "run's time over the explicit one's. The implicit exchange: a secant per FMU composed with the "
             "law's exact Jacobian (docs/design.md §4.4).", "",
             "| N | law | hold | explicit: to the end? | error | µs/node-step | implicit: to the end? | "
             "FMU steps (median / max) | error | error / explicit's | µs/node-step | × |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    yn = (lambda r: "yes" if r["ok"] else f"no, t = {r['t']:.3g} ({r['note']})")
    for N, law, hold, ex, im in rows:
        lines.append(f"| {N} | {law} | {hold} | {yn(ex)} | {ex['err']:.3g} | {ex['us']:.3g} | {yn(im)} | "
                     f"{im['it_med']:g} / {im['it_max']} | {im['err']:.3g} | {im['err'] / ex['err']:.2f} | "
                     f"{im['us']:.3g} | {im['seconds'] / ex['seconds']:.2f} |")
    if rows:
        ims = [im for *_, ex, im in rows]
        ratio = [im["err"] / ex["err"] for *_, ex, im in rows]
        cost = [im["seconds"] / ex["seconds"] for *_, ex, im in rows]
        lines += ["", f"Implicit: {sum(r['ok'] for r in ims)} of {len(ims)} cases to the end, FMU steps per "
                      f"communication step median {min(r['it_med'] for r in ims):g}–{max(r['it_med'] for r in ims):g}, "
                      f"max {max(r['it_max'] for r in ims)}; error over the explicit run's {min(ratio):.2f}–"
                      f"{max(ratio):.2f}; wall time ×{min(cost):.2f}–×{max(cost):.2f} the explicit run's."]
    if trows:
        lines += ["", "Tolerance runs (`tol=1e-3`, euclidean, zoh):", "",
                  "| N | exchange | to the end? | FMU steps (median / max) | error | run [s] |", "|---|---|---|---|---|---|"]
        for N, exchange, r in trows:
            itv = f"{r['it_med']:g} / {r['it_max']}" if exchange == "implicit" else "—"
            lines.append(f"| {N} | {exchange} | {yn(r)} | {itv} | {r['err']:.3g} | {r['seconds']:.3g} |")
    lines.append("")
    if progress:
        progress(1.0)
    return "\n".join(lines)
