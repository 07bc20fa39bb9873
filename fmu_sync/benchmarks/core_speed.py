"""Core speed: the compiled kernels against a plain C loop compiled for the same target, in one run.

Machines here are shared and noisy, so every figure is a median over repeats,
and the headline numbers are *ratios* against a baseline measured in the same
run, interleaved with the measured code (C, numba, C, numba, ...).
"""
from __future__ import annotations

import math
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path


HERE = Path(__file__).resolve().parent

#: the forced oscillator of the speed target (issue 2)
OSC = dict(m=1.0, k=1.0, c=0.1, f0=0.3, F=1.0, Omega=1.2, e=0.8)
X0 = (1.0, 0.0)


#: compiler flags of the C baseline: the host CPU like numba (``-march=native``),
#: no floating-point contraction like numba (no FMA fusion: same roundings, so
#: the same final state bit for bit)
C_FLAGS = ["-O3", "-march=native", "-ffp-contract=off"]


def _build_c(workdir: Path, flags=None) -> Path | None:
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        return None
    exe = workdir / "moreau_loop"
    subprocess.run([cc, *(flags or C_FLAGS), "-o", str(exe), str(HERE / "moreau_loop.c"), "-lm"],
                   check=True)
    return exe


#: the schemes of the core-vs-C comparison and the C loop's theta argument (0: the midpoint)
C_THETA = {"trapezoid": 0.5, "midpoint": 0.0}


def _run_c(exe: Path, dt: float, n: int, phasor: bool, scheme: str = "trapezoid"):
    p = OSC
    args = [str(exe)] + [repr(float(x)) for x in (p["m"], p["k"], p["c"], p["f0"], p["F"], p["Omega"],
                                                   0.0, p["e"], X0[0], X0[1], dt)] + [str(n), str(int(phasor)),
                                                                                     repr(C_THETA[scheme])]
    out = subprocess.run(args, check=True, capture_output=True, text=True).stdout.split()
    return float(out[0]), float(out[1]), float(out[2])


def simulate_vs_c(repeats: int = 5, n_steps: int = 20_000_000, dt: float = 1e-5, scheme: str = "trapezoid"):
    """Steps per second of ``simulate`` (1-DOF fast path, ``scheme``: the default trapezoid or the
    midpoint), cos path and phasor path, each against its C twin compiled for the same target
    (:data:`C_THETA`), interleaved; same final states.

    The C loop's block length is the ``record_every`` of the numba run (100000):
    the same block structure, so the same arithmetic.
    """
    from fmu_sync.core import ImpactOscillator, simulate

    system = ImpactOscillator(**OSC)
    t_end = n_steps * dt
    for ph in (False, True):
        simulate(system, X0, 10 * dt, dt, phasor=ph, scheme=scheme)  # compile / load cache
    rows = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        exe = _build_c(Path(tmp))
        for _ in range(repeats):
            for ph in (False, True):
                c_sec, cq, cu = _run_c(exe, dt, n_steps, ph, scheme) if exe else (float("nan"),) * 3
                t = time.perf_counter()
                r = simulate(system, X0, t_end, dt, record_every=100_000, phasor=ph, scheme=scheme)
                nb_sec = time.perf_counter() - t
                rows[ph].append((c_sec, nb_sec, cq, r.q[-1, 0], cu, r.u[-1, 0]))
    out = dict(steps=n_steps, repeats=repeats, flags=" ".join(C_FLAGS), scheme=scheme)
    for ph, name in ((False, "cos"), (True, "phasor")):
        R = rows[ph]
        ratios = [r[0] / r[1] for r in R]
        out[name] = dict(
            c_Msteps=n_steps / statistics.median(r[0] for r in R) / 1e6,
            numba_Msteps=n_steps / statistics.median(r[1] for r in R) / 1e6,
            ratio=statistics.median(ratios), ratio_min=min(ratios), ratio_max=max(ratios),
            same_final_state=all(r[2] == r[3] and r[4] == r[5] for r in R),
            q=R[-1][3], u=R[-1][5], sec=[r[1] for r in R])
    speedup = [c[1] / p[1] for c, p in zip(rows[False], rows[True])]
    out["phasor_speedup"] = statistics.median(speedup)
    out["phasor_speedup_min"] = min(speedup)
    out["phasor_speedup_max"] = max(speedup)
    out["phasor_state_diff"] = max(abs(out["cos"]["q"] - out["phasor"]["q"]),
                                   abs(out["cos"]["u"] - out["phasor"]["u"]))
    return out


def scheme_cost(repeats: int = 5, n_steps: int = 5_000_000, dt: float = 1e-5, t_pair: float = 20.0,
                t_pair2: float = 50.0):
    """Seconds per step of the default scheme (trapezoid) over the midpoint's, interleaved in one run
    (issue 40 item 4: target <= 1.5): the 1-DOF forced oscillator (``simulate``, phasor path), the
    forced pair (``simulate_pair``, Euclidean and switching, Kp = 1, Kd = 0.5, record_every=1000: the
    trapezoid's coupling inside the step against the midpoint's held coupling) and the ``two-dof``
    scene's coupled 2-DOF pair (n > 1, its scene's gains, dt = 1e-3 over ``t_pair2``). CPU time of this
    process (numba runs on one thread), interleaved."""
    from fmu_sync.core import ImpactOscillator, simulate, simulate_pair

    osc = ImpactOscillator(**OSC)
    s = ImpactOscillator(m=1, k=1, c=0, f0=0.2, F=0.5, Omega=2.5, e=0.9)

    def single(scheme):
        return lambda: simulate(osc, X0, n_steps * dt, dt, record_every=100_000, scheme=scheme)

    def pair(scheme, law):
        return lambda: simulate_pair(s, (1.0, 0.0), (0.2, 0.5), t_pair, dt, coupling=law, Kp=1.0, Kd=0.5,
                                     record_every=1000, scheme=scheme)
    cases = {"single": single, "euclidean pair": lambda sc: pair(sc, "euclidean"),
             "switching pair": lambda sc: pair(sc, "switching")}
    from fmu_sync import load_scene
    two = load_scene("two-dof").variants[0]   # its wall in (impacts), Kp = 2, Kd = 1: n > 1, core/loop_implicit.py

    def pair2(scheme, law):
        return lambda: simulate_pair(two.system, two.x1, two.x2, t_pair2, 1e-3, coupling=law, Kp=two.Kp, Kd=two.Kd,
                                     record_every=1000, scheme=scheme)
    cases.update({"coupled 2-DOF pair (two-dof scene), Euclidean": lambda sc: pair2(sc, "euclidean"),
                  "coupled 2-DOF pair (two-dof scene), switching": lambda sc: pair2(sc, "switching")})
    out = {}
    for name, make in cases.items():
        runs = {sc: make(sc) for sc in ("trapezoid", "midpoint")}
        for r in runs.values():
            r()   # compile / load cache
        sec = {sc: [] for sc in runs}
        for _ in range(repeats):
            for sc, r in runs.items():
                t = time.process_time()   # CPU time: a shared machine's load stretches wall time unevenly
                r()
                sec[sc].append(time.process_time() - t)
        ratios = [a / b for a, b in zip(sec["trapezoid"], sec["midpoint"])]
        out[name] = dict(ratio=statistics.median(ratios), ratio_min=min(ratios), ratio_max=max(ratios))
    return out


def _osc_law(q, u, tau, t, p):
    """The forced oscillator OSC as a user force law: h = f0 - k q - c u + tau, its forcing
    F cos(Omega t) declared (``forcing=``: added by the loops' cos or phasor path)."""
    return p[2] - (p[0] * q[0] + p[1] * u[0]) + tau[0]


def _osc_cos_law(q, u, tau, t, p):
    """The forced oscillator with the cos written in h (a cos per step, whatever the path)."""
    return (p[2] + p[3] * math.cos(p[4] * t)) - (p[0] * q[0] + p[1] * u[0]) + tau[0]


def _spring_law(q, u, tau, t, p):
    """The unforced oscillator as a user force law (h = f0 - k q - c u + tau)."""
    return p[2] - (p[0] * q[0] + p[1] * u[0]) + tau[0]


def law_vs_linear(repeats: int = 5, n_steps: int = 5_000_000, dt: float = 1e-5):
    """Seconds per step of the forced oscillator OSC written as a user force law (its copy of the
    loop, core/law_loops.py) against the built-in linear law on the same system, interleaved:
    on the cos path and on the phasor path (the default of both), the forcing declared
    (``ForceLaw(forcing=...)``); and the same law with the cos written in h."""
    from fmu_sync.core import ForceLaw, ImpactOscillator, MechanicalSystem, Param, simulate

    params = tuple(Param(k, OSC[k]) for k in ("k", "c", "f0", "F", "Omega"))
    law = ForceLaw(_osc_law, n=1, name="forced_oscillator", params=params,
                   linear=lambda p: ([[p[0]]], [[p[1]]]), forcing=lambda p: ((p[3], p[4], 0.0),))
    cos_law = ForceLaw(_osc_cos_law, n=1, name="forced_oscillator_cos", params=params,
                       linear=lambda p: ([[p[0]]], [[p[1]]]))
    builtin = ImpactOscillator(**OSC)
    user = MechanicalSystem(M=[[OSC["m"]]], w=[1.0], g0=0.0, e=OSC["e"], force=law)
    cos_user = MechanicalSystem(M=[[OSC["m"]]], w=[1.0], g0=0.0, e=OSC["e"], force=cos_law)
    spring = ForceLaw(_spring_law, n=1, name="oscillator", params=tuple(Param(k, OSC[k]) for k in ("k", "c", "f0")),
                      linear=lambda p: ([[p[0]]], [[p[1]]]))
    free = ImpactOscillator(**{k: OSC[k] for k in ("m", "k", "c", "f0", "e")})
    free_user = MechanicalSystem(M=[[OSC["m"]]], w=[1.0], g0=0.0, e=OSC["e"], force=spring)
    t_end = n_steps * dt
    runs = {"cos": lambda: simulate(builtin, X0, t_end, dt, record_every=100_000, phasor=False),
            "phasor": lambda: simulate(builtin, X0, t_end, dt, record_every=100_000, phasor=True),
            "law_cos": lambda: simulate(user, X0, t_end, dt, record_every=100_000, phasor=False),
            "law": lambda: simulate(user, X0, t_end, dt, record_every=100_000, phasor=True),
            "cos_in_h": lambda: simulate(cos_user, X0, t_end, dt, record_every=100_000),
            "free": lambda: simulate(free, X0, t_end, dt, record_every=100_000),
            "free_law": lambda: simulate(free_user, X0, t_end, dt, record_every=100_000)}
    for run_ in runs.values():
        run_()   # compile / load cache
    sec = {name: [] for name in runs}
    final = {}
    for _ in range(repeats):
        for name, run_ in runs.items():
            t = time.perf_counter()
            r = run_()
            sec[name].append(time.perf_counter() - t)
            final[name] = (r.q[-1, 0], r.u[-1, 0])

    def ratio(a, b):
        return statistics.median(x / y for x, y in zip(sec[a], sec[b]))
    return dict(steps=n_steps, ns={k: 1e9 * statistics.median(v) / n_steps for k, v in sec.items()},
                ratio_cos=ratio("law_cos", "cos"), ratio_phasor=ratio("law", "phasor"),
                ratio_cos_in_h=ratio("cos_in_h", "phasor"), ratio_free=ratio("free_law", "free"),
                state_diff=max(abs(a - b) for a, b in zip(final["law_cos"], final["cos"])),
                state_diff_phasor=max(abs(a - b) for a, b in zip(final["law"], final["phasor"])))


def pair_speed(repeats: int = 5, t_end: float = 100.0, dt: float = 1e-5):
    """Steps per second of simulate_pair with the switching coupling (forced pair)."""
    from fmu_sync.core import ImpactOscillator
    from fmu_sync.core import simulate_pair

    s = ImpactOscillator(m=1, k=1, c=0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
    kw = dict(coupling="switching", Kp=1.0, Kd=0.5, record_every=1000)
    simulate_pair(s, (1.0, 0.0), (0.2, 0.5), 100 * dt, dt, **kw)
    n = int(round(t_end / dt))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        simulate_pair(s, (1.0, 0.0), (0.2, 0.5), t_end, dt, **kw)
        times.append(time.perf_counter() - t)
    med = statistics.median(times)
    return dict(steps=n, Msteps_median=n / med / 1e6, Msteps_min=n / max(times) / 1e6,
                Msteps_max=n / min(times) / 1e6)


def run(quick: bool = False) -> str:
    """Run all core speed measurements; return a markdown report."""
    reps = 3 if quick else 5
    sim = simulate_vs_c(repeats=reps, n_steps=5_000_000 if quick else 20_000_000)
    mid = simulate_vs_c(repeats=reps, n_steps=5_000_000 if quick else 20_000_000, scheme="midpoint")
    cost = scheme_cost(repeats=reps, n_steps=2_000_000 if quick else 5_000_000, t_pair=5.0 if quick else 20.0,
                       t_pair2=50.0 if quick else 200.0)
    from .distance_cost import measure
    dist = measure(n_calls=50_000 if quick else 200_000, repeats=reps)
    pair = pair_speed(repeats=reps, t_end=20.0 if quick else 100.0)
    law = law_vs_linear(repeats=reps, n_steps=2_000_000 if quick else 5_000_000)
    cos, ph = sim["cos"], sim["phasor"]
    lines = ["## Core speed", "", "Medians of %d interleaved repeats." % reps, "",
             f"C baseline `fmu_sync/benchmarks/moreau_loop.c`: the same operations in the same order as "
             f"the 1-DOF kernel, compiled `gcc {sim['flags']}` (numba compiles for the host CPU and "
             f"does not contract a*b+c into FMAs either). The rows without a scheme are the default, "
             f"`trapezoid` (the C loop with theta = 1/2); the midpoint's rows say so.", "",
             "| measurement | value | target |", "|---|---|---|",
             f"| `simulate` 1-DOF forced oscillator, {sim['steps']:.0e} steps, cos path "
             f"(`phasor=False`) | {cos['numba_Msteps']:.1f} Msteps/s | |",
             f"| C loop, cos path | {cos['c_Msteps']:.1f} Msteps/s | |",
             f"| ratio numba / C, cos path (median, min–max) | {cos['ratio']:.2f} ({cos['ratio_min']:.2f}–"
             f"{cos['ratio_max']:.2f}) | ≥ 0.9 |",
             f"| same final state as C, bit for bit (cos) | {cos['same_final_state']} | |",
             f"| `simulate` phasor path (default) | {ph['numba_Msteps']:.1f} Msteps/s | |",
             f"| C loop, phasor path | {ph['c_Msteps']:.1f} Msteps/s | |",
             f"| ratio numba / C, phasor path (median, min–max) | {ph['ratio']:.2f} ({ph['ratio_min']:.2f}–"
             f"{ph['ratio_max']:.2f}) | ≥ 0.9 |",
             f"| same final state as C, bit for bit (phasor) | {ph['same_final_state']} | |",
             f"| phasor path / cos path speed (numba, median, min–max) | {sim['phasor_speedup']:.2f} "
             f"({sim['phasor_speedup_min']:.2f}–{sim['phasor_speedup_max']:.2f}) | ≥ 2 |",
             f"| final state, phasor vs cos path, max abs difference | {sim['phasor_state_diff']:.1e} "
             f"| ≤ 1e-12 |"]
    for ph in ("cos", "phasor"):
        m = mid[ph]
        lines += [f"| midpoint: ratio numba / C, {ph} path (median, min–max) | {m['ratio']:.2f} "
                  f"({m['ratio_min']:.2f}–{m['ratio_max']:.2f}) | ≥ 0.9 |",
                  f"| midpoint: same final state as C, bit for bit ({ph}) | {m['same_final_state']} | |"]
    for name, c in cost.items():
        lines.append(f"| a step of the default (trapezoid) / a step of the midpoint, {name} (median, min–max) "
                     f"| {c['ratio']:.2f} ({c['ratio_min']:.2f}–{c['ratio_max']:.2f}) | ≤ 1.5 |")
    for label, ns in dist[1:]:
        target = "< 300 ns" if label.startswith("1-DOF") and "coupling" not in label else ""
        lines.append(f"| distance/coupling kernel, {label} | {ns:.0f} ns | {target} |")
    lines.append(f"| `simulate_pair` (trapezoid), switching coupling, record_every=1000 | "
                 f"{pair['Msteps_median']:.2f} Msteps/s ({pair['Msteps_min']:.2f}–{pair['Msteps_max']:.2f}) "
                 f"| ≥ 2 Msteps/s |")
    lines += [f"| user force law (the same forced oscillator as `h(q, u, tau, t, p)`, its forcing declared), "
              f"`simulate` (phasor path) | {law['ns']['law']:.1f} ns/step | |",
              f"| user law / built-in law, phasor path (the default of both; median) | {law['ratio_phasor']:.2f} "
              f"| ≤ 2 |",
              f"| user law / built-in law, cos path (`phasor=False`; median) | {law['ratio_cos']:.2f} | ≤ 2 |",
              f"| final state, user law vs built-in law, max abs difference (cos path; phasor path) | "
              f"{law['state_diff']:.1e}; {law['state_diff_phasor']:.1e} | |",
              f"| the cos written in h instead (no declared forcing) / built-in law, phasor path (median) | "
              f"{law['ratio_cos_in_h']:.2f} | |",
              f"| unforced oscillator: user law / built-in law (median) | {law['ratio_free']:.2f} | ≤ 2 |"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # pragma: no cover
    print(run())
