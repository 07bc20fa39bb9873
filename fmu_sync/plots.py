"""Plots of a run (docs/design.md §4.6), written as PNG files; headless (Agg canvas, no pyplot state).

Every ``plot_*`` function takes a :class:`~fmu_sync.core.result.PairResult`
(``positions`` and ``phase`` also a single-system
:class:`~fmu_sync.core.SimulationResult`), an output path, optionally the
:class:`~fmu_sync.core.MechanicalSystem` (for the wall ``g(q) = w.q + g0``;
default: the 1-DOF wall q = 0) and a title, and returns the path written.
"""
from __future__ import annotations

import os
import textwrap
from pathlib import Path
from typing import Mapping

import matplotlib
import matplotlib.transforms
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .report import SYNC_THRESHOLD, contact_starts, impact_records, is_network, is_pair, wall

__all__ = ["plot_positions", "plot_distance", "plot_lyapunov", "plot_forces", "plot_phase",
           "plot_impact_zoom", "impact_window", "tail_start", "PHASE_TURNS",
           "compare_plot", "skip_reason", "PLOTTERS", "save_figure", "lyapunov_note"]

STYLE = {
    "font.size": 11, "axes.titlesize": 12, "axes.labelsize": 11, "legend.fontsize": 9.5,
    "xtick.labelsize": 10, "ytick.labelsize": 10, "lines.linewidth": 1.2, "axes.grid": True,
    "grid.alpha": 0.3, "legend.framealpha": 0.85, "path.simplify": True,
}
COLORS = ("#1f77b4", "#d62728")      # system 1, system 2
WALL = "#555555"
DPI = 130


def _u(result, name: str) -> str:
    """The unit of ``name`` (q, u, tau) in the result's record: its model's declared units."""
    from .core.views import units_of
    return units_of(result)[name]


def _figure(nrows=1, height=4.2, width=8.0, sharex=True):
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(width, height), layout="constrained")
        FigureCanvasAgg(fig)
        axes = fig.subplots(nrows, 1, sharex=sharex, squeeze=False)[:, 0]
    return fig, axes


def _save(fig, path) -> Path:
    with matplotlib.rc_context(STYLE):
        return save_figure(fig, path, DPI)


def save_figure(fig, path, dpi) -> Path:
    """Write ``fig`` as the PNG ``path`` whole or not at all: drawn into a temporary file beside it,
    renamed when complete (an interrupted run, Ctrl-C or SIGTERM, leaves no truncated PNG)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        fig.savefig(tmp, dpi=dpi, format=path.suffix[1:] or "png")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
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
    """One title line: ``<scene, run>: <what the plot shows>``."""
    ax.set_title(f"{title}: {what}" if title else what)


#: legend labels are wrapped at this many characters (a legend beside the axes stays narrow)
LEGEND_WRAP = 34


def _legend(ax, fontsize=8.5):
    """The legend beside the axes, on the right (never over the data), long labels wrapped."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(handles, [textwrap.fill(x, LEGEND_WRAP) for x in labels], loc="upper left",
                  bbox_to_anchor=(1.01, 1.0), fontsize=fontsize)


def _wall_band(ax, horizontal=True, label="wall", at=0.0, above=False):
    """Draw the wall at ``at`` with a hatched forbidden side: below / left of it, or above / right
    (``above``: a wall the coordinate may not exceed, w < 0)."""
    lo, hi = ax.get_ylim() if horizontal else ax.get_xlim()
    span = max(hi - lo, 1e-12)
    lo, hi = min(lo, at - 0.04 * span), max(hi, at + 0.04 * span)
    a, b = (at, hi) if above else (lo, at)
    if horizontal:
        ax.axhspan(a, b, facecolor="none", edgecolor=WALL, hatch="///", alpha=0.35, lw=0)
        ax.axhline(at, color=WALL, lw=2.0, label=label)
        ax.set_ylim(lo, hi)
    else:
        ax.axvspan(a, b, facecolor="none", edgecolor=WALL, hatch="///", alpha=0.35, lw=0)
        ax.axvline(at, color=WALL, lw=2.0, label=label)
        ax.set_xlim(lo, hi)


class _Normal:
    """What the wall plots (positions, phase portrait, impact window) draw of each system, and
    their labels: one degree of freedom, q and u themselves with the wall at q = -g0/w (the
    forbidden side hatched: below for w > 0, above for w < 0); n > 1, the gap g = wᵀq + g0 and
    the normal velocity γ = wᵀu with the wall at g = 0."""

    def __init__(self, result, system, n):
        w, g0 = wall(system, n)
        self.w, self.g0, self.n = w, g0, n
        uq, uu = _u(result, "q"), _u(result, "u")
        if n == 1:
            self.wall_at, self.above = -g0 / w[0] + 0.0, bool(w[0] < 0.0)     # + 0.0: no "-0"
            self.pos_label, self.vel_label = f"position q [{uq}]", f"velocity u [{uu}]"
            sign = "≥" if w[0] > 0.0 else "≤"
            self.wall_label = f"wall q = {self.wall_at:.4g} {uq} (allowed: q {sign} {self.wall_at:.4g})"
        else:
            self.wall_at, self.above = 0.0, False
            self.pos_label = f"gap g = wᵀq + g0 [{uq}]"
            self.vel_label = f"normal velocity γ = wᵀu [{uu}]"
            self.wall_label = "wall g = 0"

    def pos(self, q):
        """q (n = 1) or the gap g = wᵀq + g0 of the records ``q`` (rows x n)."""
        q = np.asarray(q, dtype=float)
        return q[:, 0] if self.n == 1 else q @ self.w + self.g0

    def vel(self, u):
        """u (n = 1) or the normal velocity γ = wᵀu."""
        u = np.asarray(u, dtype=float)
        return u[:, 0] if self.n == 1 else u @ self.w

    def band(self, ax, horizontal=True):
        _wall_band(ax, horizontal, self.wall_label, self.wall_at, self.above)


def _network_positions(result, path, system=None, title=None) -> Path:
    t = np.asarray(result.t)
    q = np.asarray(result.q)
    N, n = q.shape[1], q.shape[2]
    nm = _Normal(result, system, n)
    fig, (ax,) = _figure(width=9.0)
    cmap = matplotlib.colormaps["viridis"]
    for i in range(N):
        ax.plot(t, nm.pos(q[:, i]), color=cmap(i / max(N - 1, 1)), lw=0.9, label=f"node {i + 1}")
    nm.band(ax)
    ax.set_ylabel(nm.pos_label)
    ax.set_xlabel("time t [s]")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8.5)
    _title(ax, title, f"{'positions' if n == 1 else 'gaps'} of the {N} nodes")
    return _save(fig, path)


def _network_distance(result, path, system=None, title=None) -> Path:
    t = np.asarray(result.t)
    fig, (ax,) = _figure(width=10.0)
    D = np.asarray(result.d)
    one = len(result.edges) == 1
    if not one:
        for k, (i, j) in enumerate(result.edges):
            ax.semilogy(t, _positive(D[:, k]), color="#7f7f7f", lw=0.6, alpha=0.6,
                        label=f"pairwise d of the {len(result.edges)} edges" if k == 0 else None)
    ax.semilogy(t, _positive(result.d_max), color="k", lw=1.8,
                label="quotient distance d" if one else "max d over the edges")
    ax.axhline(SYNC_THRESHOLD, color="k", ls=":", lw=1.0, label=f"sync threshold {SYNC_THRESHOLD:g}")
    _sync_marks(ax, result, t)
    _zero_note(ax, t, result.d_max, "k", "max d")
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("quotient distance d (P-norm)")
    _legend(ax)
    _title(ax, title, "quotient distance d" if one else "pairwise quotient distances and their maximum")
    return _save(fig, path)


def plot_positions(result, path, system=None, title=None) -> Path:
    """q(t) of each system with the wall and the starts of contact episodes marked (n > 1: the
    q components above, the gap g = wᵀq + g0 below)."""
    if is_network(result):
        return _network_positions(result, path, system, title)
    t = np.asarray(result.t)
    parts = _systems(result, system)
    n = parts[0][1].shape[1]
    nm = _Normal(result, system, n)
    fig, axes = _figure(2 if n > 1 else 1, height=6.4 if n > 1 else 4.2, width=9.0)
    if n > 1:
        ax = axes[0]
        styles = ("-", "--", ":", "-.")
        for k, (label, q, _, _) in enumerate(parts):
            for j in range(n):
                ax.plot(t, q[:, j], color=COLORS[k], ls=styles[j % 4], label=f"{label}: q[{j + 1}]")
        ax.set_ylabel(f"position q [{_u(result, 'q')}]")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
        _title(ax, title, "positions q (above) and the gap g = wᵀq + g0 (below)")
    ax = axes[-1]
    for k, (label, q, u, hits) in enumerate(parts):
        ax.plot(t, nm.pos(q), color=COLORS[k], ls="-" if k == 0 else "--", label=label)
        if hits.size:
            ax.plot(t[hits], np.full(hits.size, nm.wall_at), ls="none", marker="v" if k == 0 else "^", ms=5,
                    color=COLORS[k], mec="k", mew=0.5, label=f"contact episodes {label.split()[-1]} ({hits.size})"
                    if len(parts) > 1 else f"contact episodes ({hits.size})")
    nm.band(ax)
    ax.set_ylabel(nm.pos_label)
    ax.set_xlabel("time t [s]")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    if n == 1:
        _title(ax, title, "position q vs time, with the wall")
    return _save(fig, path)


def _zero_note(ax, t, y, color, name="d"):
    """Where ``y`` is exactly 0 a log axis draws nothing: say so on the plot (no silent stop).
    The time axis keeps the whole run (a log curve that ends early does not shorten it)."""
    if len(t):
        lo, hi = ax.get_xlim()
        t0, t1 = float(np.asarray(t)[0]), float(np.asarray(t)[-1])
        if t1 > t0:
            ax.set_xlim(min(lo, t0), max(hi, t1))
    y = np.asarray(y, dtype=float)
    zero = np.nonzero(y == 0.0)[0]
    if zero.size == 0:
        return
    t = np.asarray(t)
    stays = bool(np.all(y[zero[0]:] == 0.0))
    text = (f"{name} is exactly 0 from t = {t[zero[0]]:.4g} s on: a log axis cannot show it" if stays else
            f"{name} is exactly 0 in {zero.size} of the {len(t)} records (first at t = {t[zero[0]]:.4g} s): "
            "a log axis cannot show 0, so the curve has gaps there")
    trans = matplotlib.transforms.blended_transform_factory(ax.transData, ax.transAxes)
    ax.plot([t[zero[0]]], [0.02], transform=trans, ls="none", marker="v", ms=8, color=color, mec="k",
            clip_on=False, label=text)


def _sync_marks(ax, result, t):
    """t_sync (vertical line) and the fitted decay of d's envelope (dashed), when known."""
    m = None
    if hasattr(result, "sync"):
        try:
            m = result.sync(SYNC_THRESHOLD)
        except (ValueError, AttributeError):
            m = None
    if m is not None:
        t_sync = m.t_sync
    elif hasattr(result, "time_to_sync"):
        t_sync = result.time_to_sync(SYNC_THRESHOLD)
    else:
        return
    if m is not None and m.starts_below:
        ax.plot([], [], ls="none", label=f"d0 = {m.d0:.3g} already below {SYNC_THRESHOLD:g}: no t_sync")
    elif np.isfinite(t_sync) and t_sync > t[0]:
        ax.axvline(t_sync, color="k", ls="--", lw=0.9, label=f"t_sync = {t_sync:.4g} s (d < {SYNC_THRESHOLD:g} after)")
    elif not np.isfinite(t_sync):
        ax.plot([], [], ls="none", label=f"t_sync: d not below {SYNC_THRESHOLD:g} within t_end")
    if m is None:
        return
    if m.resolved:   # the fit line over the whole window, only for a rate that means something
        tt = np.linspace(m.t_from, m.t_to, 50)
        ax.semilogy(tt, np.exp(m.intercept - m.rate * tt), color="k", ls="-.", lw=1.2,
                    label=f"decay rate {m.rate:.3g} ± {m.rate_err:.1g} 1/s ({m.decades} decades)")
    elif np.isfinite(m.rate):
        ax.plot([], [], ls="none", label=f"decay rate — ({m.reason})")
    if not np.isfinite(m.t_sync) and np.isfinite(m.bound) and m.bound >= SYNC_THRESHOLD:
        # not synchronized within t_end: the level d stays at (practical synchronization)
        t_tail = t[-1] - 0.2 * (t[-1] - t[0])
        ax.hlines(m.bound, t_tail, t[-1], color="#d62728", lw=2.0,
                  label=f"ultimate bound {m.bound:.3g} (max d over the last 20 %)")


def plot_distance(result, path, system=None, title=None) -> Path:
    """Euclidean error ||x1 - x2||_P (peaking at impacts) and the quotient distance d, log axis,
    with t_sync and the fitted decay rate marked (a network: the pairwise d and their maximum)."""
    if is_network(result):
        return _network_distance(result, path, system, title)
    fig, (ax,) = _figure(width=10.0)
    t = np.asarray(result.t)
    ax.semilogy(t, _positive(result.euclidean), color="#ff7f0e", lw=1.0, label="Euclidean error ‖x1 − x2‖_P")
    ax.semilogy(t, _positive(result.d), color="#2ca02c", lw=1.8, label="quotient distance d")
    ax.axhline(SYNC_THRESHOLD, color="k", ls=":", lw=1.0, label=f"sync threshold {SYNC_THRESHOLD:g}")
    _sync_marks(ax, result, t)
    _zero_note(ax, t, result.d, "#2ca02c")
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("distance (P-norm)")
    _legend(ax)
    _title(ax, title, "Euclidean error vs quotient distance")
    return _save(fig, path)


def impact_window(result, system=None, halfwidth: float | None = None):
    """``(i0, i1, i_peak)``: the records around the largest peaking ``E - d`` of the
    Euclidean error over the quotient distance (an impact mismatch), or None."""
    if result.d is None or len(result.t) < 5:
        return None
    t = np.asarray(result.t)
    d, E = np.asarray(result.d), np.asarray(result.euclidean)
    gap = np.where(np.isfinite(E - d), E - d, 0.0)
    k = int(np.argmax(gap))
    if not gap[k] > 1e-3 * max(float(np.nanmax(E)), 1e-300):
        return None
    # the peaking episode: where the peaking stays above 5 % of its maximum
    lo = k
    while lo > 0 and gap[lo - 1] > 0.05 * gap[k]:
        lo -= 1
    hi = k
    while hi + 1 < len(t) and gap[hi + 1] > 0.05 * gap[k]:
        hi += 1
    span = max(t[hi] - t[lo], 20 * (t[1] - t[0]))
    w = halfwidth if halfwidth is not None else max(1.5 * span, 0.3)
    i0 = int(np.searchsorted(t, t[lo] - w))
    i1 = int(np.searchsorted(t, t[hi] + w, side="right"))
    return i0, min(i1, len(t)), k


def plot_impact_zoom(result, path, system=None, title=None) -> Path:
    """The paper's central point on one impact window: the positions with the wall (n > 1: the
    gaps); below, on a log axis, the Euclidean error jumping at the impact mismatch while the
    quotient distance d stays continuous (however small it is next to the jump)."""
    fig, (axq, ax) = _figure(2, height=6.4, width=9.0)
    # a scene run keeps the rows around its largest mismatch at every step (scenes/running.py)
    result = getattr(result, "impact_record", None) or result
    win = impact_window(result, system)
    t = np.asarray(result.t)
    if win is None:
        for a in (axq, ax):
            a.text(0.5, 0.5, "no impact mismatch in this run (the Euclidean error never exceeds d)",
                   ha="center", va="center", transform=a.transAxes)
        _title(axq, title, "impact window")
        return _save(fig, path)
    i0, i1, k = win
    sl = slice(i0, i1)
    parts = _systems(result, system)
    nm = _Normal(result, system, parts[0][1].shape[1])
    for c, (label, q, _, hits) in enumerate(parts):
        axq.plot(t[sl], nm.pos(q)[sl], color=COLORS[c], label=label)
        h = hits[(hits >= i0) & (hits < i1)]
        if h.size:
            axq.plot(t[h], np.full(h.size, nm.wall_at), ls="none", marker="v" if c == 0 else "^", ms=7,
                     color=COLORS[c], mec="k", mew=0.5, label=f"contact episode begins ({label})")
    nm.band(axq)
    axq.set_ylabel(nm.pos_label)
    _legend(axq)
    E, d = np.asarray(result.euclidean, dtype=float), np.asarray(result.d, dtype=float)
    ax.semilogy(t[sl], _positive(E[sl]), color="#ff7f0e", lw=1.4, label="Euclidean error ‖x1 − x2‖_P")
    ax.semilogy(t[sl], _positive(d[sl]), color="#2ca02c", lw=2.0, label="quotient distance d")
    shown = np.concatenate([E[sl], d[sl]])
    shown = shown[np.isfinite(shown) & (shown > 0.0)]
    if shown.size:
        ax.set_ylim(0.3 * float(shown.min()), 3.0 * float(shown.max()))
    _zero_note(ax, t[sl], d[sl], "#2ca02c")
    ax.annotate(f"Euclidean error {E[k] - d[k]:.3g} above d\n(one system hit the wall, the other not yet)",
                xy=(t[k], E[k]), xytext=(0.98, 0.5), textcoords="axes fraction", ha="right", fontsize=9,
                arrowprops=dict(arrowstyle="->", lw=0.8))
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("distance (P-norm, log)")
    _legend(ax)
    what = "impact window: d continuous, Euclidean error jumps"
    with matplotlib.rc_context(STYLE):
        fig.suptitle(f"{title}: {what}" if title else what, fontsize=11)
    return _save(fig, path)


def _coupled(result) -> bool:
    """Whether a coupling law acts in the run (a pair's ``coupling``, a network's ``info["coupling"]``)."""
    c = (getattr(result, "info", None) or {}).get("coupling") if is_network(result) else \
        getattr(result, "coupling", None)
    return any(x not in (None, "none") for x in (c if isinstance(c, (list, tuple)) else [c]))


def lyapunov_note(result) -> str | None:
    """None when the result says that V is a Lyapunov function of its law (``info["lyapunov"]``,
    a coupled run); else why V is not called one on the plots."""
    info = getattr(result, "info", None) or {}
    if not _coupled(result):
        return "uncoupled run: V is not a Lyapunov function here"
    if info.get("lyapunov"):
        return None
    if "lyapunov" not in info:
        return "the result does not say that V is a Lyapunov function of the law"
    return f"not a Lyapunov function of this run's law (metric: {info.get('metric', '?')}, see the summary)"


def plot_lyapunov(result, path, system=None, title=None) -> Path:
    """V(t) on a log axis: d²/2 for a pair, ½ Σ_edges a_ij d_ij² for a network; called a Lyapunov
    function only when the result says it is one (:func:`lyapunov_note`)."""
    fig, (ax,) = _figure(width=10.0)
    ax.semilogy(np.asarray(result.t), _positive(result.V), color="#9467bd", lw=1.5, label=_V_LABEL[is_network(result)])
    _zero_note(ax, result.t, result.V, "#9467bd", "V")
    note = lyapunov_note(result)
    if note is not None:
        ax.plot([], [], ls="none", label=note)
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("Lyapunov function V" if note is None else "V")
    _legend(ax)
    _title(ax, title, "Lyapunov function V(t)" if note is None else f"{_V_LABEL[is_network(result)]} vs time")
    return _save(fig, path)


def plot_forces(result, path, system=None, title=None) -> Path:
    """Coupling forces tau1(t), tau2(t) (held over each step); below, |tau| on a log axis
    (uncoupled: one panel saying so, no empty axes)."""
    t = np.asarray(result.t)
    taus = [np.asarray(tau).reshape(len(t), -1) for tau in (result.tau1, result.tau2)]
    if not any(np.any(np.nan_to_num(tau) != 0.0) for tau in taus):
        fig, (ax,) = _figure(height=3.0)
        ax.text(0.5, 0.5, "no coupling force: τ1 = τ2 = 0 throughout the run", ha="center", va="center",
                transform=ax.transAxes)
        ax.set_xlim(t[0], t[-1] if len(t) > 1 else t[0] + 1)
        ax.set_yticks([])
        ax.set_xlabel("time t [s]")
        _title(ax, title, f"coupling forces ({getattr(result, 'coupling', None) or 'none'})")
        return _save(fig, path)
    fig, (ax, axl) = _figure(2, height=6.4, width=10.0)
    norms = []
    for k, (name, tau) in enumerate(zip(("τ1", "τ2"), taus)):
        for j in range(tau.shape[1]):
            label = name if tau.shape[1] == 1 else f"{name}[{j + 1}]"
            ax.step(t, tau[:, j], where="pre", color=COLORS[k], ls="-" if j == 0 else "--", label=label)
        norms.append(np.linalg.norm(tau, axis=1))
        axl.semilogy(t, _positive(norms[-1]), color=COLORS[k], lw=1.0, label=f"|{name}|")
    if np.array_equal(norms[0] == 0.0, norms[1] == 0.0):   # the law's forces vanish together: one note
        _zero_note(axl, t, norms[0], "k", "|τ1| = |τ2|")
    else:
        for k, name in enumerate(("τ1", "τ2")):
            _zero_note(axl, t, norms[k], COLORS[k], f"|{name}|")
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_ylabel(f"coupling force τ [{_u(result, 'tau')}]")
    _legend(ax)
    axl.set_xlabel("time t [s]")
    axl.set_ylabel(f"|τ| [{_u(result, 'tau')}] (log)")
    _legend(axl)
    _title(ax, title, f"coupling forces ({getattr(result, 'coupling', None) or 'none'})")
    return _save(fig, path)


#: a phase portrait with more turns than this draws the earlier motion faint and only the
#: last PHASE_TURNS turns in full (a long run's orbits otherwise pile up into a tangle)
PHASE_TURNS = 8


def tail_start(y, turns: int = PHASE_TURNS) -> int:
    """First record of the last ``turns`` turns of an oscillation ``y`` (a velocity): counted
    by its sign changes (two per turn), ignoring values below 1e-3 of its largest (the
    chatter of a resting contact); 0 when the record has no more turns than that."""
    y = np.asarray(y, dtype=float)
    big = np.nonzero(np.abs(y) > 1e-3 * (np.nanmax(np.abs(y)) if y.size else 0.0))[0]
    if big.size < 2:
        return 0
    flips = big[1:][np.signbit(y[big[1:]]) != np.signbit(y[big[:-1]])]
    return 0 if flips.size <= 2 * turns else int(flips[-2 * turns - 1])


def plot_phase(result, path, system=None, title=None) -> Path:
    """Phase portrait (q, u) of each system with the wall (n > 1: the normal coordinates, gap
    g = wᵀq + g0 and normal velocity γ = wᵀu). A long run: the last :data:`PHASE_TURNS` turns in
    full, the motion before them faint."""
    parts = _systems(result, system)
    nm = _Normal(result, system, parts[0][1].shape[1])
    t = np.asarray(result.t)
    fig, (ax,) = _figure(height=5.6, width=6.8, sharex=False)
    start = min(tail_start(nm.vel(u)) for _, _, u, _ in parts)
    for k, (label, q, u, _) in enumerate(parts):
        x, y = nm.pos(q), nm.vel(u)
        if start > 0:
            ax.plot(x[:start + 1], y[:start + 1], color=COLORS[k], lw=0.5, alpha=0.18)
        # system 2 dashed: synchronized systems draw one curve, both stay visible
        ax.plot(x[start:], y[start:], color=COLORS[k], lw=0.9, alpha=0.9, ls="-" if k == 0 else (0, (4, 3)),
                label=label)
        ax.plot(x[:1], y[:1], ls="none", marker="o", ms=7, color=COLORS[k], mec="k")
        ax.plot(x[-1:], y[-1:], ls="none", marker="s", ms=6, color=COLORS[k], mec="k")
    ax.plot([], [], ls="none", marker="o", ms=7, color="w", mec="k", label="start")
    ax.plot([], [], ls="none", marker="s", ms=6, color="w", mec="k", label="end")
    if start > 0:
        ax.plot([], [], color="0.6", lw=0.5, label=f"before t = {t[start]:.4g} s (faint)")
    nm.band(ax, horizontal=False)
    ax.set_xlabel(nm.pos_label)
    ax.set_ylabel(nm.vel_label)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=3, frameon=False)
    what = "phase portrait" if start == 0 else \
        f"phase portrait, last {PHASE_TURNS} turns (t ≥ {t[start]:.4g} s)"
    _title(ax, title, what)
    return _save(fig, path)


#: the Lyapunov function's formula of a pair (False) and of a network (True)
_V_LABEL = {False: "V = d²/2", True: "V = ½ Σ_edges a_ij d_ij²"}
_LABELS = {"d": ("quotient distance d", "distance d (P-norm)"),
           "euclidean": ("Euclidean error ‖x1 − x2‖_P", "Euclidean error (P-norm)"),
           "V": ("V (pair: d²/2; network: ½ Σ_edges a_ij d_ij²)", "V")}


def compare_plot(results: Mapping[str, object], path, quantity: str = "d", title=None, dashed=(),
                 colors: Mapping[str, str] | None = None) -> Path:
    """One log-axis curve of ``quantity`` ("d", "euclidean" or "V") per labelled run.

    ``dashed``: labels drawn dashed; ``colors``: label -> matplotlib color (default: cycle).
    """
    if quantity not in _LABELS:
        raise ValueError(f"quantity must be one of {sorted(_LABELS)}, got {quantity!r}")
    what, ylabel = _LABELS[quantity]
    fig, (ax,) = _figure(width=10.0)
    for k, (label, r) in enumerate(results.items()):
        y = r.d_max if quantity == "d" and is_network(r) else getattr(r, quantity)
        if quantity == "euclidean" and is_network(r) and y is not None:
            y = np.max(y, axis=1)
        if y is None:
            continue
        color = (colors or {}).get(label, f"C{k % 10}")
        ax.semilogy(np.asarray(r.t), _positive(y), color=color, lw=1.3,
                    ls="--" if label in dashed else "-", label=label)
        _zero_note(ax, r.t, y, color, f"{quantity} of {label}")
    if quantity == "d":
        ax.axhline(SYNC_THRESHOLD, color="k", ls=":", lw=1.0, label=f"sync threshold {SYNC_THRESHOLD:g}")
    ax.set_xlabel("time t [s]")
    ax.set_ylabel(ylabel)
    _legend(ax)
    ax.set_title(title if title else f"{what} of each run")
    return _save(fig, path)


def plot_steps(result, path, system=None, title=None) -> Path:
    """The communication step H over time of a co-simulation to a tolerance (``info["step_lengths"]``, one
    per accepted step, drawn at each step's start; log axis), with its floor (solver.dt) and
    first step (docs/design.md §4.4.1)."""
    info = getattr(result, "info", None) or {}
    if info.get("tol") is None:
        raise ValueError("plot_steps needs a co-simulation to a tolerance (cosimulate(..., tol=T)): "
                         "info['step_lengths'] is then one length per communication step")
    H = np.asarray(info["step_lengths"], dtype=float)
    t0 = np.concatenate([[0.0], np.cumsum(H)[:-1]])
    fig, (ax,) = _figure(width=10.0)
    ax.step(t0, H, where="post", color="C0", lw=1.2, label=f"H ({len(H)} steps, {info['rejected']} rejected)")
    ax.axhline(info["step_unit"], color="k", ls=":", lw=1.0, label=f"floor: solver.dt = {info['step_unit']:g} s")
    ax.axhline(info["H_first"], color="k", ls="--", lw=1.0, label=f"first and largest H = {info['H_first']:g} s")
    ax.set_yscale("log")
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("communication step H [s]")
    _legend(ax)
    ax.set_title(title if title else f"communication step to tol = {info['tol']:g} "
                 f"(estimated error {info['error_estimate']:.2g})")
    return _save(fig, path)


def skip_reason(kind: str, result) -> str | None:
    """Why a plot of ``kind`` would say nothing for ``result`` (then the run writes no file), or None:
    an uncoupled run's forces are zero throughout."""
    if kind == "forces" and is_pair(result) and not is_network(result):
        taus = [np.nan_to_num(np.asarray(x, dtype=float)) for x in (result.tau1, result.tau2)]
        if not any(np.any(x != 0.0) for x in taus):
            return "no coupling force (τ1 = τ2 = 0 throughout the run)"
    return None


PLOTTERS = {"positions": plot_positions, "distance": plot_distance, "lyapunov": plot_lyapunov,
            "forces": plot_forces, "phase": plot_phase, "impact-zoom": plot_impact_zoom}
