"""Work-precision analysis: measured orders, cost crossovers, tables and the markdown report."""
from __future__ import annotations

import math
import statistics

import numpy as np

from .csv_rows import write_records
from .work_precision_cases import LADDERS, METHOD_DOC, Point, SCENES, horizon, pair_metrics

__all__ = ["measured_order", "slope_stderr", "cost_crossover", "midpoint_vs_exact", "cosim_h_dependence",
           "best_vs_ivp", "closer_at_equal_time", "table", "report", "write_csv"]


# ------------------------------------------------------------------ analysis
def _curve(points, scene, metric, method):
    pts = [p for p in points if p.scene == scene and p.metric == metric and p.method == method
           and math.isfinite(p.error) and math.isfinite(p.seconds)]
    return sorted(pts, key=lambda p: p.step)


def measured_order(points, scene, metric, method="midpoint", min_step=0.0, floor=0.0):
    """Least-squares slope of log(error) vs log(step) (points with error > floor, step >= min_step)."""
    pts = [p for p in _curve(points, scene, metric, method) if p.error > floor and p.step >= min_step]
    if len(pts) < 3:
        return math.nan, pts
    x = np.log10([p.step for p in pts])
    y = np.log10([p.error for p in pts])
    return float(np.polyfit(x, y, 1)[0]), pts


def slope_stderr(pts) -> float:
    """Standard error of the least-squares slope (scatter of the points about the line)."""
    if len(pts) < 4:
        return math.nan
    x = np.log10([p.step for p in pts])
    y = np.log10([p.error for p in pts])
    _, cov = np.polyfit(x, y, 1, cov=True)
    return float(math.sqrt(cov[0, 0]))


def _interp_loglog(xs, ys, x):
    """Piecewise-linear interpolation in log-log (xs increasing); nan outside."""
    lx, ly = np.log10(xs), np.log10(ys)
    v = math.log10(x)
    if v < lx[0] or v > lx[-1]:
        return math.nan
    return 10 ** float(np.interp(v, lx, ly))


def _pareto(c):
    """(errors, seconds) of the Pareto front, by increasing error."""
    # Pareto front: walking to larger errors, keep a run only if it is cheaper than every
    # run with a smaller error (dominated runs say nothing about the attainable cost)
    c = sorted(c, key=lambda p: (p.error, p.seconds))
    keep, best = [], math.inf
    for p in c:
        if p.seconds < best:
            keep.append(p)
            best = p.seconds
    return np.array([p.error for p in keep]), np.array([p.seconds for p in keep])


def cost_crossover(points, scene, metric, a, b):
    """Error level below which method ``a`` becomes cheaper (or dearer) than ``b``.

    The Pareto fronts seconds(error) of both methods are interpolated in log-log on their
    common error range; returns a dict: crossing error (or None), which method is cheaper at
    the small- and the large-error end and by how much, the common range.
    """
    ca = [p for p in _curve(points, scene, metric, a) if p.error > 0]
    cb = [p for p in _curve(points, scene, metric, b) if p.error > 0]
    if len(ca) < 2 or len(cb) < 2:
        return None
    ea, sa = _pareto(ca)
    eb, sb = _pareto(cb)
    if len(ea) < 2 or len(eb) < 2:
        return dict(overlap=False, a_range=(ea[0], ea[-1]), b_range=(eb[0], eb[-1]))
    lo, hi = max(ea[0], eb[0]), min(ea[-1], eb[-1])
    if not lo < hi:
        return dict(overlap=False, a_range=(ea[0], ea[-1]), b_range=(eb[0], eb[-1]))
    grid = np.logspace(math.log10(lo), math.log10(hi), 200)
    ra = np.array([_interp_loglog(ea, sa, g) for g in grid])
    rb = np.array([_interp_loglog(eb, sb, g) for g in grid])
    diff = np.log10(ra) - np.log10(rb)
    s = np.sign(diff)
    crossings = [float(grid[i]) for i in range(len(grid) - 1) if s[i] != 0 and s[i + 1] != 0 and s[i] != s[i + 1]]
    cross = crossings[0] if len(crossings) == 1 else None
    return dict(overlap=True, crossing=cross, crossings=crossings, range=(lo, hi),
                cheaper_coarse=a if diff[-1] < 0 else b, cheaper_fine=a if diff[0] < 0 else b,
                ratio_coarse=float(10 ** -diff[-1]), ratio_fine=float(10 ** -diff[0]))


def midpoint_vs_exact(points, scene, metric):
    """dt below which the midpoint run costs more than the exact solver (log-log interpolation)."""
    mid = _curve(points, scene, metric, "midpoint")
    ex = [p for p in points if p.scene == scene and p.metric == metric and p.method == "exact"
          and math.isfinite(p.seconds)]
    if not mid or not ex:
        return None
    tx = ex[0].seconds
    steps = np.array([p.step for p in mid])          # increasing: fine -> coarse
    secs = np.array([p.seconds for p in mid])
    errs = np.array([p.error for p in mid])
    if np.all(secs <= tx):
        return dict(dt=None, exact_seconds=tx, note="the midpoint is cheaper than the exact solver over "
                    f"the whole ladder (dt >= {steps[0]:g})")
    if np.all(secs > tx):
        return dict(dt=None, exact_seconds=tx, note="the exact solver is cheaper than every midpoint run "
                    f"(dt <= {steps[-1]:g})")
    for i in range(len(steps) - 2, -1, -1):           # coarsest crossing
        if (secs[i] > tx) != (secs[i + 1] > tx):
            x = np.interp(math.log10(tx), sorted([math.log10(secs[i]), math.log10(secs[i + 1])]),
                          [math.log10(steps[i + 1]), math.log10(steps[i])]
                          if secs[i] > secs[i + 1] else [math.log10(steps[i]), math.log10(steps[i + 1])])
            dt = 10 ** float(x)
            e0, e1 = errs[i], errs[i + 1]
            err = (_interp_loglog(steps[i:i + 2], np.maximum([e0, e1], 1e-300), dt)
                   if e0 > 0 and e1 > 0 else math.nan)
            return dict(dt=dt, err=err, exact_seconds=tx)
    return None


def closer_at_equal_time(points, scene, metric, a="trapezoid", b="midpoint"):
    """How much closer ``a`` is than ``b`` at equal run time: at each run of ``a`` whose time lies in
    ``b``'s range, b's error there (log-log interpolation of b's error against its run time) over a's
    error. Returns (median, min, count) or None when the time ranges do not overlap."""
    ca = [p for p in _curve(points, scene, metric, a) if p.error > 0]
    cb = sorted((p for p in _curve(points, scene, metric, b) if p.error > 0), key=lambda p: p.seconds)
    if len(ca) < 1 or len(cb) < 2:
        return None
    ts, es = np.array([p.seconds for p in cb]), np.array([p.error for p in cb])
    ratios = []
    for p in ca:
        if ts[0] <= p.seconds <= ts[-1]:
            i = min(int(np.searchsorted(ts, p.seconds)), len(ts) - 1)
            i = max(i, 1)
            e = _interp_loglog(ts[i - 1:i + 1], es[i - 1:i + 1], p.seconds) if ts[i - 1] < ts[i] else es[i]
            if math.isfinite(e):
                ratios.append(e / p.error)
    if not ratios:
        return None
    return statistics.median(ratios), min(ratios), len(ratios)


#: error levels of the "best method vs solve_ivp" comparison
LEVELS = tuple(10.0 ** -k for k in range(2, 11))
#: the project's own methods (single system)
OWN_METHODS = ("midpoint", "theta0.5", "theta1", "trapezoid", "exact")
#: verified accuracy of the exact solvers against DOP853 (tests/test_exact.py: 1e-12 on the
#: 1-DOF closed forms; tests/test_exact_nd.py: 1e-10 asserted on the two-dof scene)
EXACT_VERIFIED = {1: 1e-12, 2: 1e-10}


def best_vs_ivp(points, scene, metric, n_dof=1):
    """At each error level 1e-2..1e-10: the cheapest run of the project's own methods with
    error <= level (the exact solver counts with its verified accuracy where its error is the
    reference's 0) against the cheapest solve_ivp run with error <= level.

    Returns rows (level, own method, own seconds, solve_ivp seconds or nan, ok) with ok =
    own <= solve_ivp (True where solve_ivp never reaches the level)."""
    rows = []
    pts = [p for p in points if p.scene == scene and p.metric == metric and math.isfinite(p.seconds)]
    for lev in LEVELS:
        own = []
        for p in pts:
            if p.method not in OWN_METHODS or not math.isfinite(p.error):
                continue
            err = p.error
            if p.method == "exact" and err == 0.0:
                err = EXACT_VERIFIED.get(n_dof, EXACT_VERIFIED[2])
            if err <= lev:
                own.append((p.seconds, p.method, p.step))
        ivp = [p.seconds for p in pts if p.method == "solve_ivp" and math.isfinite(p.error) and p.error <= lev]
        best = min(own) if own else (math.nan, "none", math.nan)
        tivp = min(ivp) if ivp else math.nan
        ok = (not math.isnan(best[0])) and (math.isnan(tivp) or best[0] <= tivp)
        rows.append((lev, best[1], best[2], best[0], tivp, ok))
    return rows


def cosim_h_dependence(points, scene, metric):
    """Slope of log error vs log H for each co-simulation variant and the event-aware gain."""
    out = {}
    for m in ("cosim", "cosim-ea", "cosim-fine", "cosim-fine-ea", "cosim-fine-implicit"):
        slope, pts = measured_order(points, scene, metric, m)
        if pts:
            out[m] = dict(slope=slope, errors={p.step: p.error for p in pts},
                          seconds={p.step: p.seconds for p in pts})
    return out


# ------------------------------------------------------------------ report
def _fmt(x, digits=3):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    if x == 0:
        return "0"
    return f"{x:.{digits}g}"


def table(points, scene, metric) -> str:
    pts = [p for p in points if p.scene == scene and p.metric == metric]
    order = list(METHOD_DOC)
    pts.sort(key=lambda p: (order.index(p.method) if p.method in order else 99, -p.step))
    base = [p for p in pts if p.method == "midpoint" and abs(p.step - 1e-3) < 1e-12]
    b = base[0].seconds if base and math.isfinite(base[0].seconds) else math.nan
    lines = [f"| method | step | error | seconds (median) | repeats | spread | cost / midpoint dt=1e-3 |",
             "|---|---|---|---|---|---|---|"]
    for p in pts:
        err = _fmt(p.error) if not p.note or p.method == "exact" else f"{_fmt(p.error)} ({p.note})"
        lines.append(f"| {p.method} | {p.step:.3g} | {err} | {_fmt(p.seconds)} | {p.repeats} | "
                     f"{p.spread:.2f} | {_fmt(p.seconds / b) if math.isfinite(b) else 'n/a'} |")
    return "\n".join(lines)


def _crossover_line(points, scene, metric, a, b, findings) -> str | None:
    cx = cost_crossover(points, scene, metric, a, b)
    if cx is None:
        return None
    findings.setdefault("crossover", {})[f"{scene}/{metric}: {a} vs {b}"] = cx
    head = f"- **{a} vs {b}, {scene} / {metric}**: "
    if not cx["overlap"]:
        return (head + f"error ranges do not overlap ({a} {_fmt(cx['a_range'][0])}–{_fmt(cx['a_range'][1])}, "
                f"{b} {_fmt(cx['b_range'][0])}–{_fmt(cx['b_range'][1])}).")
    if len(cx["crossings"]) > 1:
        return (head + f"the cost curves cross {len(cx['crossings'])} times on {_fmt(cx['range'][0])}–"
                f"{_fmt(cx['range'][1])} (differences within the timing noise, largest ×"
                f"{_fmt(max(cx['ratio_fine'], 1 / cx['ratio_fine'], cx['ratio_coarse'], 1 / cx['ratio_coarse']), 2)}"
                " at the ends): no clear winner.")
    if cx["crossing"] is not None:
        return (head + f"equal cost at error ≈ {_fmt(cx['crossing'])} (crossover); {cx['cheaper_coarse']} is "
                f"cheaper for larger errors, {cx['cheaper_fine']} for smaller.")
    f = max(cx["ratio_fine"], 1 / cx["ratio_fine"])
    c = max(cx["ratio_coarse"], 1 / cx["ratio_coarse"])
    return (head + f"no crossover on the common error range {_fmt(cx['range'][0])}–{_fmt(cx['range'][1])}: "
            f"{cx['cheaper_fine']} is cheaper for the same error throughout (×{_fmt(f, 2)} at the small-error "
            f"end, ×{_fmt(c, 2)} at the large-error end).")


def _interpretations(points, findings, mode) -> list[str]:
    """The report's one-line findings (each also kept in ``findings``)."""
    return (_order_lines(points, findings, mode) + _exact_lines(points, findings)
            + _best_lines(points, findings) + _cosim_lines(points, findings)
            + _overhead_lines(points, findings))


def _order_lines(points, findings, mode) -> list[str]:
    """The measured orders of the midpoint."""
    lad = LADDERS[mode]
    out = []
    for scene, metric, kw in (("bouncing-ball", "rest_time", {}), ("bouncing-ball", "max_q", {}),
                              ("forced-pair", "max_q", {}),
                              ("forced-pair", "d", dict(min_step=10 * lad["dt_ref_pair"])),
                              ("zeno-table", "max_q", {}), ("grazing", "max_q", {}),
                              ("two-dof", "max_q", {})):
        slope, pts = measured_order(points, scene, metric, "midpoint", **kw)
        if pts:
            findings.setdefault("order", {})[f"{scene}/{metric}"] = slope
            out.append(f"- **Measured order, midpoint, {scene} / {metric}**: slope of log error vs log dt = "
                       f"{_fmt(slope)} ± {_fmt(slope_stderr(pts), 2)} (least squares, dt {pts[0].step:g}–"
                       f"{pts[-1].step:g}, {len(pts)} points).")
    # the default scheme (trapezoid) beside the midpoint and theta: orders, and error at equal run time
    for scene, metric, kw in (("damped-pair", "max_q", {}), ("damped-pair", "q", {}),
                              ("forced-pair", "max_q", {}),
                              ("forced-pair", "d", dict(min_step=10 * lad["dt_ref_pair"]))):
        orders = {}
        for m in ("trapezoid", "midpoint", "theta0.5", "theta1"):
            slope, pts = measured_order(points, scene, metric, m, **kw)
            if pts and math.isfinite(slope):
                orders[m] = slope
        if not orders:
            continue
        findings.setdefault("scheme_order", {})[f"{scene}/{metric}"] = orders
        line = (f"- **Orders, {scene} / {metric}**: " + ", ".join(f"{m} {_fmt(v, 3)}" for m, v in orders.items())
                + " (slope of log error vs log dt)")
        eq = closer_at_equal_time(points, scene, metric)
        if eq is not None:
            findings.setdefault("closer_at_equal_time", {})[f"{scene}/{metric}"] = eq
            line += (f"; at equal run time the trapezoid is ×{_fmt(eq[0], 3)} closer than the midpoint (median over "
                     f"{eq[2]} runs, least ×{_fmt(eq[1], 3)})")
        out.append(line + ".")
    return out


def _exact_lines(points, findings) -> list[str]:
    """Exact vs midpoint, solve_ivp vs midpoint."""
    out = []
    for scene, metric in (("bouncing-ball", "max_q"), ("forced-pair", "max_q"), ("zeno-table", "max_q"),
                          ("grazing", "max_q"), ("two-dof", "max_q")):
        mx = midpoint_vs_exact(points, scene, metric)
        if mx is not None:
            findings.setdefault("exact_crossover", {})[scene] = mx
            if mx.get("dt") is not None:
                out.append(f"- **Crossover midpoint / exact, {scene}**: the exact solver ({_fmt(mx['exact_seconds'])} s) "
                           f"is cheaper than a midpoint run with dt < {_fmt(mx['dt'])} s (midpoint error there "
                           f"≈ {_fmt(mx['err'])}).")
            else:
                out.append(f"- **Midpoint / exact, {scene}**: {mx['note']} (exact: {_fmt(mx['exact_seconds'])} s).")
        line = _crossover_line(points, scene, metric, "midpoint", "solve_ivp", findings)
        if line:
            out.append(line)
    return out


def _best_lines(points, findings) -> list[str]:
    """The project's best method against solve_ivp at every error level."""
    out = []
    for sc in SCENES:
        n_dof = 2 if sc.system is not None else 1
        for metric in sc.metrics:
            rows = best_vs_ivp(points, sc.name, metric, n_dof)
            if not any(math.isfinite(r[3]) for r in rows):
                continue
            findings.setdefault("best_vs_ivp", {})[f"{sc.name}/{metric}"] = rows
            bad = [r for r in rows if not r[5]]
            cells = ", ".join(f"{_fmt(r[0], 1)}: {r[1]} {_fmt(r[3], 2)} s vs "
                              f"{_fmt(r[4], 2) + ' s' if math.isfinite(r[4]) else 'not reached'}"
                              for r in rows)
            verdict = ("at least as cheap as solve_ivp at every level" if not bad else
                       "NOT cheaper at " + ", ".join(_fmt(r[0], 1) for r in bad))
            out.append(f"- **Best own method vs solve_ivp, {sc.name} / {metric}**: {verdict} "
                       f"(level: cheapest own run with error ≤ level vs cheapest solve_ivp run; {cells}).")
        if sc.pair is not None:
            out.append(f"- **Best own method vs solve_ivp, {sc.name} / {pair_metrics(sc)[0]}**: solve_ivp is not run "
                       "on the coupled pair (no baseline): no comparison.")
    return out


def _cosim_lines(points, findings) -> list[str]:
    """The co-simulation's error against H."""
    out = []
    for scene, metric in (("forced-pair", "d"), ("bouncing-ball", "rest_time"), ("bouncing-ball", "max_q"),
                          ("forced-pair", "max_q")):
        dep = cosim_h_dependence(points, scene, metric)
        if not dep:
            continue
        findings.setdefault("cosim", {})[f"{scene}/{metric}"] = dep
        parts = [f"{m}: slope {_fmt(v['slope'], 2)}" for m, v in dep.items()]
        line = f"- **Co-simulation error vs H, {scene} / {metric}**: " + ", ".join(parts)
        if "cosim" in dep and "cosim-ea" in dep:
            ratios = [dep["cosim"]["errors"][h] / dep["cosim-ea"]["errors"][h]
                      for h in dep["cosim"]["errors"] if h in dep["cosim-ea"]["errors"]
                      and dep["cosim-ea"]["errors"][h] > 0]
            costs = [dep["cosim-ea"]["seconds"][h] / dep["cosim"]["seconds"][h]
                     for h in dep["cosim"]["seconds"] if h in dep["cosim-ea"]["seconds"]]
            if ratios:
                line += (f"; event-aware changes the error by ×{_fmt(1 / statistics.median(ratios), 2)} "
                         f"(median over H, range ×{_fmt(1 / max(ratios), 2)}–×{_fmt(1 / min(ratios), 2)}) "
                         f"at ×{_fmt(statistics.median(costs), 2)} the cost")
        out.append(line + ".")
        for a, b in (("cosim-ea", "cosim"), ("cosim-fine", "cosim"), ("cosim-fine-ea", "cosim-ea")):
            if a in dep and b in dep:
                cl = _crossover_line(points, scene, metric, a, b, findings)
                if cl:
                    out.append(cl)
    return out


def _overhead_lines(points, findings) -> list[str]:
    """The cost of the FMU path against the core midpoint at dt = H."""
    out = []
    ratios = []
    for scene in {p.scene for p in points}:
        for p in points:
            if p.scene == scene and p.method == "cosim" and p.metric != "d":
                m = [q for q in points if q.scene == scene and q.metric == p.metric and q.method == "midpoint"
                     and abs(q.step - p.step) < 1e-12]
                if m and m[0].seconds > 0:
                    ratios.append(p.seconds / m[0].seconds)
    if ratios:
        findings["cosim_over_core"] = statistics.median(ratios)
        out.append(f"- **FMU overhead**: an uncoupled co-simulation with slave dt = H gives the same numbers as "
                   f"the core midpoint at dt = H, at ×{_fmt(statistics.median(ratios), 2)} the run time "
                   f"(median over scenes and H; two FMU instances, one master exchange per step).")
    return out


def report(points, mode, seconds) -> tuple[str, dict]:
    findings: dict = {}
    lad = LADDERS[mode]
    lines = ["## Work–precision: error against run time", "",
             f"Mode {mode}: medians of up to {lad['repeats']} interleaved repeats, {seconds:.0f} s.", ""]
    lines.append("Methods: " + "; ".join(f"`{k}` = {v}" for k, v in METHOD_DOC.items()) + ".")
    lines.append("")
    lines.append("Errors: `max_q` = max |q − q_exact| over the run's output times (exact = core/exact.py, "
                 "core/exact_nd.py for two-dof); "
                 "`rest_time` = |t_rest − t_inf| with t_inf in closed form; `d` = max |d − d_ref| of the "
                 "coupled pair (switching coupling, Kp = 1, Kd = 0.5) on a 10 ms grid, d_ref from "
                 f"`simulate_pair` (trapezoid) at dt = {lad['dt_ref_pair']:g} (the exact solver does not apply to a "
                 "coupled pair); `q` = max |q_i − q_i,DOP853| of the smooth damped pair (damped-pair: m = 1, k = 1, "
                 "c = 0.1, F = 0.5, Ω = 2.5, the wall 100 m away, Kp = 1, Kd = 0.5) on the 10 ms grid, DOP853 at "
                 "rtol = atol = 1e-12. Horizons: " + ", ".join(
                     f"{s.name} {horizon(s, mode):g} s"
                     for s in SCENES) + ".")
    lines.append("")
    lines.append("### Findings")
    lines.append("")
    lines += _interpretations(points, findings, mode)
    lines.append("")
    for scene in SCENES:
        for metric in scene.metrics + (pair_metrics(scene) if scene.pair else ()):
            if not any(p.scene == scene.name and p.metric == metric for p in points):
                continue
            lines.append(f"### {scene.name} — {metric}")
            lines.append("")
            lines.append(table(points, scene.name, metric))
            lines.append("")
    return "\n".join(lines) + "\n", findings


def write_csv(points, path) -> None:
    write_records(points, Point.CSV_FIELDS, path)
