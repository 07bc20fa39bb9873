"""Co-simulation hold (zero- vs first-order) and the exact FMU slave, on the public API.

Three measurements, from one run of ``fmu-sync bench`` (section ``hold``):

1. **Order in H of the coupling error**: a pair of 1-DOF FMUs (midpoint,
   ``solver.dt`` = 1e-4) coupled by the switching law, co-simulated by
   :func:`fmu_sync.cosimulate` with ``hold="zoh"`` and ``hold="foh"`` at a
   ladder of H, against a fine monolithic :func:`fmu_sync.core.simulate_pair`
   (dt = 2e-6): max |q error| and max |d error| over the communication points,
   and the observed order log2(e(2H)/e(H)). Two cases: far from the wall (f0 = 5,
   no impact: the smooth order) and the forced pair with impacts (the whole run).
2. **Stability range** of the exchange under each hold: the limit of omega*H
   from the hold map (:func:`fmu_sync.core.hold_bound`) for a few
   damping ratios.
3. **Exact slave**: the ``solver.scheme = exact`` FMU run by fmpy at H = 0.01 over a
   run with accumulations (zeno table) against ``simulate(..., scheme="exact")``.
"""
from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["run", "measure_orders"]

FAR = dict(m=1.0, k=1.0, c=0.0, f0=5.0, F=0.5, Omega=2.5, phi=0.0, e=0.9)
FAR_X = ((5.5, 0.0), (4.5, 0.3))
GAINS = dict(Kp=1.0, Kd=0.5)
DT_SLAVE, DT_REF = 1e-4, 2e-6


def measure_orders(fmu: str, params: dict, x1, x2, t_end: float, Hs, gains=GAINS,
                   dt_ref: float = DT_REF) -> dict:
    """Errors (q, d) of the co-simulation with each hold at each H against the fine
    monolithic run, and the observed orders. ``fmu``: an impact-oscillator FMU
    exported with ``params`` (and ``solver.dt``)."""
    from fmu_sync import cosimulate
    from fmu_sync.core import ImpactOscillator, simulate_pair
    ref = simulate_pair(ImpactOscillator(**params), x1, x2, t_end, dt_ref, coupling="switching", **gains)
    out = {"H": list(Hs), "impacts": (int(ref.impacts1), int(ref.impacts2))}
    for hold in ("zoh", "foh"):
        eq, ed = [], []
        for H in Hs:
            r = cosimulate(fmu, x1, x2, t_end, H, coupling="switching", hold=hold, **gains)
            k = int(round(H / dt_ref))
            # the rows at whole communication steps (a run also records t_end itself when H does not
            # divide it; the reference has no row there)
            n = min(r.t.size, ref.t[::k].size)
            if not np.allclose(r.t[:n], ref.t[::k][:n], rtol=0.0, atol=1e-9):
                raise RuntimeError(f"hold bench: record times of H = {H} and the reference differ")
            eq.append(max(float(np.max(np.abs(r.q1[:n, 0] - ref.q1[::k][:n, 0]))),
                          float(np.max(np.abs(r.q2[:n, 0] - ref.q2[::k][:n, 0])))))
            ed.append(float(np.max(np.abs(r.d[:n] - ref.d[::k][:n]))))
        out[hold] = {"q": eq, "d": ed,
                     "order_q": [math.log2(a / b) for a, b in zip(eq[:-1], eq[1:])],
                     "order_d": [math.log2(a / b) for a, b in zip(ed[:-1], ed[1:])]}
    return out


def _table(res: dict) -> list[str]:
    rows = ["| H | ZOH max err q | ZOH max err d | FOH max err q | FOH max err d | order q ZOH / FOH | "
            "order d ZOH / FOH |", "|---|---|---|---|---|---|---|"]
    z, f = res["zoh"], res["foh"]
    for i, H in enumerate(res["H"]):
        oq = od = ""
        if i > 0:
            oq = f"{z['order_q'][i - 1]:.2f} / {f['order_q'][i - 1]:.2f}"
            od = f"{z['order_d'][i - 1]:.2f} / {f['order_d'][i - 1]:.2f}"
        rows.append(f"| {H:g} | {z['q'][i]:.3e} | {z['d'][i]:.3e} | {f['q'][i]:.3e} | {f['d'][i]:.3e} | "
                    f"{oq} | {od} |")
    return rows


def _exact_slave(fmu_dir: Path) -> tuple[float, float, int, int]:
    """max |q|, |u| deviation of the exact FMU slave from the core exact solver, zeno table."""
    from fmu_sync import export_fmu
    from fmu_sync.core import ImpactOscillator, simulate
    from fmpy import simulate_fmu
    p = dict(m=1.0, k=0.0, c=0.0, f0=-1.0, F=2.0, Omega=3.0, phi=0.0, e=0.5)
    path = export_fmu("impact-oscillator", fmu_dir / "exact.fmu", {**p, "solver.scheme": "exact",
                                                                   "q_start": 0.0, "u_start": 0.0})
    H, n = 0.01, 1000
    r = simulate_fmu(str(path), stop_time=n * H, output_interval=H, output=["q", "u"])
    rows = np.column_stack([r["q"], r["u"]])
    ref = simulate(ImpactOscillator(**p), (0.0, 0.0), n * H, H, scheme="exact")
    return (float(np.max(np.abs(rows[:, 0] - ref.q[:, 0]))), float(np.max(np.abs(rows[:, 1] - ref.u[:, 0]))),
            int(ref.events.n_impacts), int(ref.events.zeno_times.size))


def run(quick: bool = False, smoke: bool = False, progress=None) -> str:
    """The section's markdown."""
    from fmu_sync import export_fmu
    from fmu_sync.core import hold_bound
    lines = ["## Co-simulation hold: zero- vs first-order", "", "The exact slave is compared too.", ""]
    Hs = (0.04, 0.02) if smoke else ((0.08, 0.04, 0.02, 0.01) if quick else (0.16, 0.08, 0.04, 0.02, 0.01))
    t_end = 2.0 if smoke else 10.0
    with tempfile.TemporaryDirectory(prefix="fmu-sync-hold-") as tmp:
        d = Path(tmp)
        far = export_fmu("impact-oscillator", d / "far.fmu", {**FAR, "solver.dt": DT_SLAVE})
        res = measure_orders(str(far), FAR, *FAR_X, t_end, Hs)
        if progress:
            progress(0.4)
        lines += [f"Far from the wall (f0 = 5, x1 = {FAR_X[0]}, x2 = {FAR_X[1]}, Kp = {GAINS['Kp']}, "
                  f"Kd = {GAINS['Kd']}, t_end = {t_end:g}; impacts in the reference: {res['impacts']}), "
                  f"slaves: midpoint with solver.dt = {DT_SLAVE:g}; reference: simulate_pair with dt = "
                  f"{DT_REF:g}:", ""] + _table(res) + [""]
        from fmu_sync import load_scene
        v = load_scene("forced-pair").variant("switching")
        params = {k: v.cfg[f"system.{k}"] for k in ("m", "k", "c", "f0", "F", "Omega", "e")}
        x1, x2 = v.x1, v.x2
        gains = dict(Kp=v.Kp, Kd=v.Kd)
        imp = export_fmu("impact-oscillator", d / "impacts.fmu", {**params, "solver.dt": DT_SLAVE})
        res2 = measure_orders(str(imp), params, x1, x2, t_end, Hs, gains=gains)
        if progress:
            progress(0.8)
        lines += [f"With impacts (forced pair, x1 = {tuple(map(float, np.ravel(x1)))}, x2 = "
                  f"{tuple(map(float, np.ravel(x2)))}, Kp = {gains['Kp']}, Kd = {gains['Kd']}; impacts in "
                  f"the reference: {res2['impacts']}), whole run:", ""] + _table(res2) + [""]
        zetas = (0.05, 0.1, 0.25, 0.5, 1.0, 2.0)
        lines += ["Stability of the exchange (limit of omega*H of a relative mode with damping ratio "
                  "zeta, from the hold map; `fmu_sync.core.hold_bound`, used by the master's up-front "
                  "check with its hold):", "",
                  "| zeta | " + " | ".join(f"{z:g}" for z in zetas) + " |",
                  "|---|" + "---|" * len(zetas),
                  "| ZOH | " + " | ".join(f"{hold_bound(z, 'zoh'):.3f}" for z in zetas) + " |",
                  "| FOH | " + " | ".join(f"{hold_bound(z, 'foh'):.3f}" for z in zetas) + " |", ""]
        if not smoke:
            eq, eu, n_imp, n_zeno = _exact_slave(d)
            lines += [f"Exact slave (solver.scheme = exact, zeno table, H = 0.01, 1000 steps, {n_imp} "
                      f"impacts and {n_zeno} completed accumulations): max |q - q_exact| = {eq:.2e}, "
                      f"max |u - u_exact| = {eu:.2e} against `simulate(..., scheme='exact')`.", ""]
    if progress:
        progress(1.0)
    return "\n".join(lines)
