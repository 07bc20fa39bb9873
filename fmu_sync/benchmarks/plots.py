"""Work–precision diagrams (log–log error vs run time), headless (Agg, no pyplot state)."""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = ["work_precision_plot", "work_precision_plots"]

STYLE = {"font.size": 10, "axes.grid": True, "grid.alpha": 0.3, "legend.fontsize": 8.5,
         "legend.framealpha": 0.85, "lines.linewidth": 1.3}
MARKERS = {"midpoint": ("o", "#1f77b4"), "theta0.5": ("s", "#2ca02c"), "theta1": ("D", "#17becf"),
           "trapezoid": ("h", "#000000"),
           "solve_ivp": ("^", "#d62728"), "cosim": ("v", "#9467bd"), "cosim-ea": ("P", "#e377c2"),
           "cosim-fine": ("<", "#8c564b"), "cosim-fine-ea": (">", "#bcbd22"),
           "cosim-fine-implicit": ("X", "#ff7f0e"), "exact": ("*", "#000000")}
DPI = 120
#: the legend's name of a core scheme (the rest show their method name); a pair's θ = ½ holds the
#: coupling over the step, the default (trapezoid) solves it inside the step
LEGEND = {"midpoint": "midpoint (first order)", "theta1": "θ = 1", "trapezoid": "trapezoid (the default)"}
PAIR_METRICS = ("d", "q")


def legend_name(method: str, metric: str) -> str:
    """The legend entry of ``method`` on a diagram of ``metric``."""
    if method == "theta0.5":
        return "θ = ½, coupling held over the step" if metric in PAIR_METRICS else "θ = ½"
    return LEGEND.get(method, method)


def work_precision_plot(points, scene: str, metric: str, path) -> Path | None:
    """One diagram: error vs seconds, one line per method (ordered by step), the exact solver a point.

    Errors of exactly 0 (the exact solver measured against itself) cannot be drawn on a log
    axis: they are drawn on the bottom edge with an open marker and said so in the legend.
    """
    pts = [p for p in points if p.scene == scene and p.metric == metric
           and math.isfinite(p.seconds) and p.seconds > 0 and math.isfinite(p.error)]
    if not pts:
        return None
    pos = [p.error for p in pts if p.error > 0]
    if not pos:
        return None
    floor = min(pos) / 10.0
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(7.5, 5.0), layout="constrained")
        FigureCanvasAgg(fig)
        ax = fig.subplots()
        methods = []
        for p in pts:
            if p.method not in methods:
                methods.append(p.method)
        for m in methods:
            mp = sorted((p for p in pts if p.method == m), key=lambda p: p.step)
            marker, color = MARKERS.get(m, ("x", None))
            xs = np.array([p.seconds for p in mp])
            ys = np.array([p.error for p in mp])
            zero = ys <= 0
            if m == "exact" or len(mp) == 1:
                label = "exact (reference)" if m == "exact" else m
                if zero.any():
                    ax.scatter(xs[zero], np.full(zero.sum(), floor), marker=marker, s=140, facecolors="none",
                               edgecolors=color, label=f"{label}: error 0, drawn at the floor")
                if (~zero).any():
                    ax.scatter(xs[~zero], ys[~zero], marker=marker, s=140, color=color, label=label)
                continue
            name = legend_name(m, metric)
            if m == "trapezoid":     # the default scheme: drawn on top, open markers (theta0.5 coincides alone)
                ax.plot(xs[~zero], ys[~zero], marker=marker, color=color, label=name, markersize=8,
                        markerfacecolor="none", zorder=4, linewidth=1.8)
            else:
                ax.plot(xs[~zero], ys[~zero], marker=marker, color=color, label=name, markersize=5)
            # label the coarsest and the finest step of each line
            for p in (mp[0], mp[-1]):
                if p.error > 0:
                    ax.annotate(f"{p.step:g}", (p.seconds, p.error), textcoords="offset points",
                                xytext=(4, 3), fontsize=7, color=color)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("run time (s, median of repeats)")
        unit = {"rest_time": "rest-time error |t_rest − t_inf| (s)", "max_q": "max position error (m)",
                "d": "max |d − d_ref| (quotient distance)",
                "q": r"max $|q_i - q_i^{\mathrm{DOP853}}|$ over both systems (m)"}.get(metric, metric)
        ax.set_ylabel(unit)
        ref = pts[0].reference
        ax.set_title(f"Work–precision: {scene}, {metric} (reference: {ref})", fontsize=10)
        ax.legend(loc="best")
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=DPI)
    return path


def work_precision_plots(points, out_dir) -> list[Path]:
    out = []
    keys = []
    for p in points:
        if (p.scene, p.metric) not in keys:
            keys.append((p.scene, p.metric))
    for scene, metric in keys:
        path = work_precision_plot(points, scene, metric, Path(out_dir) / f"work_precision_{scene}_{metric}.png")
        if path is not None:
            out.append(path)
    return out
