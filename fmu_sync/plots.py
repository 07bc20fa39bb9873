"""Plots of a run (docs/design.md §4.6), written as PNG files; headless (Agg canvas, no pyplot state).

Every ``plot_*`` function takes a :class:`~fmu_sync.core.result.PairResult`
(``positions`` and ``phase`` also a single-system
:class:`~fmu_sync.core.SimulationResult`), an output path, optionally the
:class:`~fmu_sync.core.MechanicalSystem` (for the wall ``g(q) = w.q + g0``;
default: the 1-DOF wall q = 0) and a title, and returns the path written.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .report import SYNC_THRESHOLD, contact_starts, impact_records, is_pair, wall

__all__ = ["plot_positions", "plot_distance", "plot_lyapunov", "plot_forces", "plot_phase",
           "compare_plot", "PLOTTERS"]

STYLE = {
    "font.size": 11, "axes.titlesize": 12, "axes.labelsize": 11, "legend.fontsize": 9.5,
    "xtick.labelsize": 10, "ytick.labelsize": 10, "lines.linewidth": 1.2, "axes.grid": True,
    "grid.alpha": 0.3, "legend.framealpha": 0.85, "path.simplify": True,
}
COLORS = ("#1f77b4", "#d62728")      # system 1, system 2
WALL = "#555555"
DPI = 130


def _figure(nrows=1, height=4.2, width=8.0, sharex=True):
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(width, height), layout="constrained")
        FigureCanvasAgg(fig)
        axes = fig.subplots(nrows, 1, sharex=sharex, squeeze=False)[:, 0]
    return fig, axes


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with matplotlib.rc_context(STYLE):
        fig.savefig(path, dpi=DPI)
    return path


def _systems(result, system=None):
    """[(label, q, u, impact rows)] for one or two systems."""
    if is_pair(result):
        return [(f"system {i}", np.asarray(getattr(result, f"q{i}")), np.asarray(getattr(result, f"u{i}")),
                 impact_records(result, i, system)) for i in (1, 2)]
    return [("system", np.asarray(result.q), np.asarray(result.u), contact_starts(result.percussion))]


def _positive(y):
    """Values <= 0 cannot be drawn on a log axis: mask them."""
    y = np.asarray(y, dtype=float)
    return np.where(y > 0.0, y, np.nan)


def _title(ax, title, what):
    ax.set_title(f"{title}\n{what}" if title else what)


def _wall_band(ax, horizontal=True, label="wall"):
    """Draw the wall at 0 with a hatched forbidden side (below / left)."""
    if horizontal:
        lo, hi = ax.get_ylim()
        span = hi - lo
        ax.axhspan(min(lo, -0.04 * span), 0.0, facecolor="none", edgecolor=WALL, hatch="///", alpha=0.35, lw=0)
        ax.axhline(0.0, color=WALL, lw=2.0, label=label)
        ax.set_ylim(min(lo, -0.04 * span), hi)
    else:
        lo, hi = ax.get_xlim()
        span = hi - lo
        ax.axvspan(min(lo, -0.04 * span), 0.0, facecolor="none", edgecolor=WALL, hatch="///", alpha=0.35, lw=0)
        ax.axvline(0.0, color=WALL, lw=2.0, label=label)
        ax.set_xlim(min(lo, -0.04 * span), hi)


def plot_positions(result, path, system=None, title=None) -> Path:
    """q(t) of each system with the wall and the impacts marked (n > 1: q components and the gap g)."""
    t = np.asarray(result.t)
    parts = _systems(result, system)
    n = parts[0][1].shape[1]
    w, g0 = wall(system, n)
    fig, axes = _figure(2 if n > 1 else 1, height=6.4 if n > 1 else 4.2, width=9.0)
    if n > 1:
        ax = axes[0]
        styles = ("-", "--", ":", "-.")
        for k, (label, q, _, _) in enumerate(parts):
            for j in range(n):
                ax.plot(t, q[:, j], color=COLORS[k], ls=styles[j % 4], label=f"{label}: q[{j + 1}]")
        ax.set_ylabel("position q [m]")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
        _title(ax, title, "positions")
    ax = axes[-1]
    for k, (label, q, u, hits) in enumerate(parts):
        g = q @ w + g0
        ax.plot(t, g, color=COLORS[k], label=label)
        if hits.size:
            ax.plot(t[hits], np.zeros(hits.size), ls="none", marker="v" if k == 0 else "^", ms=5,
                    color=COLORS[k], mec="k", mew=0.5, label=f"impacts {label.split()[-1]} ({hits.size})"
                    if len(parts) > 1 else f"impacts ({hits.size})")
    _wall_band(ax)
    ax.set_ylabel("gap g(q) = w·q + g0 [m]" if n > 1 else "position q [m]")
    ax.set_xlabel("time t [s]")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    if n == 1:
        _title(ax, title, "position vs time (wall at q = 0)")
    return _save(fig, path)


def plot_distance(result, path, system=None, title=None) -> Path:
    """Euclidean error ||x1 - x2||_P (peaking at impacts) and the quotient distance d, log axis."""
    fig, (ax,) = _figure()
    t = np.asarray(result.t)
    ax.semilogy(t, _positive(result.euclidean), color="#ff7f0e", lw=1.0, label="Euclidean error ‖x1 − x2‖_P")
    ax.semilogy(t, _positive(result.d), color="#2ca02c", lw=1.8, label="quotient distance d")
    ax.axhline(SYNC_THRESHOLD, color="k", ls=":", lw=1.0, label=f"sync threshold {SYNC_THRESHOLD:g}")
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("distance (P-norm)")
    ax.legend(loc="best")
    _title(ax, title, "Euclidean error vs quotient distance")
    return _save(fig, path)


def plot_lyapunov(result, path, system=None, title=None) -> Path:
    """V(t) = d²/2 on a log axis."""
    fig, (ax,) = _figure()
    ax.semilogy(np.asarray(result.t), _positive(result.V), color="#9467bd", lw=1.5, label="V = d²/2")
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("Lyapunov function V")
    ax.legend(loc="best")
    _title(ax, title, "Lyapunov function V(t)")
    return _save(fig, path)


def plot_forces(result, path, system=None, title=None) -> Path:
    """Coupling forces tau1(t), tau2(t) (held over each step); below, |tau| on a log axis."""
    fig, (ax, axl) = _figure(2, height=6.4)
    t = np.asarray(result.t)
    for k, (name, tau) in enumerate((("τ1", result.tau1), ("τ2", result.tau2))):
        tau = np.asarray(tau).reshape(len(t), -1)
        for j in range(tau.shape[1]):
            label = name if tau.shape[1] == 1 else f"{name}[{j + 1}]"
            ax.step(t, tau[:, j], where="pre", color=COLORS[k], ls="-" if j == 0 else "--", label=label)
        axl.semilogy(t, _positive(np.linalg.norm(tau, axis=1)), color=COLORS[k], lw=1.0, label=f"|{name}|")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_ylabel("coupling force τ [N]")
    ax.legend(loc="upper right")
    axl.set_xlabel("time t [s]")
    axl.set_ylabel("|τ| [N] (log)")
    axl.legend(loc="upper right")
    _title(ax, title, f"coupling forces ({getattr(result, 'coupling', None) or 'none'})")
    return _save(fig, path)


def plot_phase(result, path, system=None, title=None) -> Path:
    """Phase portrait (q, u) of each system with the wall (n > 1: normal coordinates (g, w·u))."""
    parts = _systems(result, system)
    n = parts[0][1].shape[1]
    w, g0 = wall(system, n)
    fig, (ax,) = _figure(height=5.6, width=6.8, sharex=False)
    for k, (label, q, u, _) in enumerate(parts):
        x, y = q @ w + g0, u @ w
        ax.plot(x, y, color=COLORS[k], lw=0.8, alpha=0.85, label=label)
        ax.plot(x[:1], y[:1], ls="none", marker="o", ms=7, color=COLORS[k], mec="k")
        ax.plot(x[-1:], y[-1:], ls="none", marker="s", ms=6, color=COLORS[k], mec="k")
    ax.plot([], [], ls="none", marker="o", ms=7, color="w", mec="k", label="start")
    ax.plot([], [], ls="none", marker="s", ms=6, color="w", mec="k", label="end")
    _wall_band(ax, horizontal=False)
    ax.set_xlabel("gap g = w·q + g0 [m]" if n > 1 else "position q [m]")
    ax.set_ylabel("normal velocity w·u [m/s]" if n > 1 else "velocity u [m/s]")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=len(parts) + 3, frameon=False)
    _title(ax, title, "phase portrait")
    return _save(fig, path)


_LABELS = {"d": ("quotient distance d", "distance d (P-norm)"),
           "euclidean": ("Euclidean error ‖x1 − x2‖_P", "Euclidean error (P-norm)"),
           "V": ("Lyapunov function V = d²/2", "V")}


def compare_plot(results: Mapping[str, object], path, quantity: str = "d", title=None, dashed=(),
                 colors: Mapping[str, str] | None = None) -> Path:
    """One log-axis curve of ``quantity`` ("d", "euclidean" or "V") per labelled run.

    ``dashed``: labels drawn dashed; ``colors``: label -> matplotlib color (default: cycle).
    """
    if quantity not in _LABELS:
        raise ValueError(f"quantity must be one of {sorted(_LABELS)}, got {quantity!r}")
    what, ylabel = _LABELS[quantity]
    fig, (ax,) = _figure()
    for k, (label, r) in enumerate(results.items()):
        y = getattr(r, quantity)
        if y is None:
            continue
        color = (colors or {}).get(label, f"C{k % 10}")
        ax.semilogy(np.asarray(r.t), _positive(y), color=color, lw=1.3,
                    ls="--" if label in dashed else "-", label=label)
    if quantity == "d":
        ax.axhline(SYNC_THRESHOLD, color="k", ls=":", lw=1.0, label=f"sync threshold {SYNC_THRESHOLD:g}")
    ax.set_xlabel("time t [s]")
    ax.set_ylabel(ylabel)
    ax.legend(loc="best")
    _title(ax, title, f"{what}: comparison")
    return _save(fig, path)


PLOTTERS = {"positions": plot_positions, "distance": plot_distance, "lyapunov": plot_lyapunov,
            "forces": plot_forces, "phase": plot_phase}
