"""Co-simulation to a tolerance (``fmu-sync bench``, issue 34; docs/design.md §4.4.1), on the
public API: error against run time and communication steps for fixed H (zero- and first-order
hold) and for ``cosimulate(..., tol=T)``, and the measured error against the estimated one
(``info["error_estimate"]``).

Cases: the forced pair of the issue (m = 1, k = 1, c = 0, f0 = 0.2, F = 0.5, Omega = 2.5, e = 0.9,
switching law Kp = 1, Kd = 0.5, x1 = (1, 0), x2 = (0.2, 0.5), 5 s, impacts inside) and a ring of 8
of the same oscillators (switching law, Kp = 4, Kd = 2, 5 s). Slaves: midpoint with solver.dt =
1e-4; the reference is the core (``simulate_pair`` / ``simulate_network``) at dt = 1e-4, the
co-simulation's own limit H -> dt. Error: max over the record of |q - q_ref| (every node).
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["run", "measure", "PAIR", "DT"]

PAIR = dict(m=1.0, k=1.0, c=0.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
X1, X2 = (1.0, 0.0), (0.2, 0.5)
DT, T_END, H0 = 1e-4, 5.0, 0.05
RING_GAINS = dict(Kp=4.0, Kd=2.0)


def _ring_states(N: int = 8):
    return [(0.2 + 0.1 * i, 0.05 * (-1) ** i) for i in range(N)]


def _error(r, ref, network: bool) -> float:
    """max |q - q_ref| over the record's times (the reference interpolated) and every node."""
    if network:
        q, qr = np.asarray(r.q)[:, :, 0], np.asarray(ref.q)[:, :, 0]
    else:
        q = np.stack([r.q1[:, 0], r.q2[:, 0]], axis=1)
        qr = np.stack([ref.q1[:, 0], ref.q2[:, 0]], axis=1)
    return float(max(np.max(np.abs(q[:, i] - np.interp(r.t, ref.t, qr[:, i]))) for i in range(q.shape[1])))


#: the exchanges compared: name -> cosimulate keywords
EXCHANGES = {"explicit ZOH": dict(hold="zoh"), "explicit FOH": dict(hold="foh"),
             "implicit FOH": dict(exchange="implicit", hold="foh")}
#: the exchanges run to a tolerance
TOL_EXCHANGES = ("explicit ZOH", "implicit FOH")


def measure(fmu, network: bool, Hs, tols, t_end: float = T_END) -> list[dict]:
    """One row per run: the exchange (:data:`EXCHANGES`), ``fixed`` (step H) or ``tol`` (the
    tolerance, from H = 0.05), the communication steps (and rejected ones), the measured and
    estimated error, the wall time."""
    from fmu_sync import cosimulate, cosimulate_network
    from fmu_sync.core import ImpactOscillator, ring, simulate_network, simulate_pair
    system = ImpactOscillator(**PAIR)
    if network:
        states, A = _ring_states(), ring(8)
        ref = simulate_network([system] * 8, states, A, t_end, DT, coupling="switching", **RING_GAINS)

        def go(H, **kw):
            return cosimulate_network(fmu, states, A, t_end, H, coupling="switching", **RING_GAINS, **kw)
    else:
        ref = simulate_pair(system, X1, X2, t_end, DT, coupling="switching", Kp=1.0, Kd=0.5)

        def go(H, **kw):
            return cosimulate(fmu, X1, X2, t_end, H, coupling="switching", Kp=1.0, Kd=0.5, **kw)
    for name in TOL_EXCHANGES:   # compiles (numba cache) before anything is timed
        go(H0, tol=1.0, **EXCHANGES[name])
    rows = []
    for name, kw in EXCHANGES.items():
        for H in Hs:
            t0 = time.perf_counter()
            r = go(H, **kw)
            rows.append(dict(exchange=name, kind="fixed", step=H, steps=int(r.info["steps"]), rejected=0,
                             error=_error(r, ref, network), estimate=None, seconds=time.perf_counter() - t0))
    for name in TOL_EXCHANGES:
        for T in tols:
            t0 = time.perf_counter()
            r = go(H0, tol=T, **EXCHANGES[name])
            rows.append(dict(exchange=name, kind="tol", step=T, steps=int(r.info["steps"]),
                             rejected=int(r.info["rejected"]), error=_error(r, ref, network),
                             estimate=float(r.info["error_estimate"]), seconds=time.perf_counter() - t0,
                             H_min=float(r.info["step_lengths"].min()), H_max=float(r.info["step_lengths"].max())))
    return rows


def figure(rows, path, title: str):
    """Error against wall time: each exchange's fixed-H ladder and its runs to a tolerance."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(6.4, 4.6))
    ax = fig.add_subplot()
    for name in EXCHANGES:
        for kind, style in (("fixed", "o-"), ("tol", "s--")):
            pts = [r for r in rows if r["exchange"] == name and r["kind"] == kind and r["error"] > 0]
            if pts:
                ax.loglog([r["seconds"] for r in pts], [r["error"] for r in pts], style,
                          label=f"{name}, {'fixed H' if kind == 'fixed' else 'tol'}")
    est = [r for r in rows if r["kind"] == "tol" and r["estimate"]]
    if est:
        ax.loglog([r["seconds"] for r in est], [r["estimate"] for r in est], "kx", label="estimate (tol runs)")
    ax.set_xlabel("wall time [s]")
    ax.set_ylabel("max |q − q_ref|")
    ax.set_title(title)
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=110)
    return path


def _table(rows) -> list[str]:
    out = ["| run | H or tol | comm. steps (rejected) | max \\|q − q_ref\\| | estimate | estimate/error | "
           "H shortest … longest | wall [s] |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        est = "—" if r["estimate"] is None else f"{r['estimate']:.2e}"
        ratio = "—" if r["estimate"] is None or r["error"] == 0 else f"{r['estimate'] / r['error']:.1f}"
        span = f"{r['H_min']:.1e} … {r['H_max']:.1e}" if r["kind"] == "tol" else "—"
        name = f"{r['exchange']}, fixed H" if r["kind"] == "fixed" else f"{r['exchange']}, tol (H = {H0:g} first)"
        out.append(f"| {name} | {r['step']:.3g} | {r['steps']} ({r['rejected']}) | {r['error']:.2e} | {est} | "
                   f"{ratio} | {span} | {r['seconds']:.2f} |")
    return out


def run(quick: bool = False, out=None, smoke: bool = False) -> str:
    """The section's markdown; with ``out`` (a folder) also its figures
    ``work_precision_cosim_tol_<case>.png``."""
    from fmu_sync import export_fmu
    t_end = 1.0 if smoke else T_END
    Hs = [0.02] if smoke else [0.02 / 2 ** k for k in range(0, 8, 3 if quick else 1)]
    tols = [1e-2] if smoke else [1e-2, 1e-3] if quick else [1e-2, 1e-3, 1e-4, 1e-5, 1e-6]
    ring_tols = [1e-2, 1e-3] if quick else [1e-2, 1e-3, 1e-4]
    lines = ["## Co-simulation to a tolerance", "",
             "`cosimulate(..., tol=T)` (docs/design.md §4.4.1): H = 0.05 is the first and largest step, each "
             "step's coupling error is estimated and a step over its share T h/t_end is rolled back (FMU "
             "state) and retaken shorter; steps are whole multiples of the slaves' solver.dt = 1e-4. Fixed H: "
             "the ladder 0.02/2^k, explicit (zero- and first-order hold) and implicit. Error: max |q − q_ref| "
             "over every node, the reference the core at dt = 1e-4 (the co-simulation's limit H → dt); "
             "estimate: `info[\"error_estimate\"]` (q's unit, the same norm as T). Wall times of one process, "
             "same run.", ""]
    figs = []
    with tempfile.TemporaryDirectory(prefix="fmu-sync-bench-tol-") as tmp:
        fmu = str(export_fmu("impact-oscillator", Path(tmp) / "pair.fmu", {**PAIR, "solver.dt": DT}))
        pair = measure(fmu, False, Hs, tols, t_end)
        lines += [f"Forced pair (switching, Kp = 1, Kd = 0.5, x1 = {X1}, x2 = {X2}, {t_end:g} s, impacts inside):",
                  ""] + _table(pair) + [""]
        if out is not None:
            figs.append(figure(pair, Path(out) / "work_precision_cosim_tol_pair.png", "forced pair: co-simulation"))
        if not smoke:
            ring_rows = measure(fmu, True, Hs[::2], ring_tols, t_end)
            lines += [f"Ring of 8 (switching, Kp = {RING_GAINS['Kp']:g}, Kd = {RING_GAINS['Kd']:g}, {t_end:g} s):",
                      ""] + _table(ring_rows) + [""]
            if out is not None:
                figs.append(figure(ring_rows, Path(out) / "work_precision_cosim_tol_ring.png", "ring of 8: co-simulation"))
    if figs:
        lines += ["Diagrams: " + ", ".join(f"`{p.name}`" for p in figs) + ".", ""]
    return "\n".join(lines)
