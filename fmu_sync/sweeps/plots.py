"""Maps of a sweep: heat maps over two swept parameters, basins, sample scatter plots.

* :func:`heat_map` -- decay rate and t_sync over two parameters (e.g. Kp, Kd),
  runs that diverged / were refused / did not synchronize marked, and the
  zero-order-hold stability limit of the relative mode drawn:
  ``omega_c h = min(4 zeta, 1/zeta)`` with ``omega_c = sqrt(2 Kp / m)``,
  ``zeta = Kd / (m omega_c)`` and ``h`` the exchange step (``run.H`` when
  co-simulated; ``solver.dt`` in the core under a scheme that holds the forces over dt
  the same way: the midpoint and θ; not drawn for the core's default, the trapezoid, whose
  coupling is inside the step: :func:`fmu_sync.core.plan.coupling_exchange`); the bound is
  :func:`fmu_sync.core.exchange.zoh_bound`.
* :func:`basin` -- the decay rate of d over a start state (q0, u0), runs that do not
  synchronize marked.
* :func:`line_plot` -- one swept parameter: decay rate and t_sync against it.
* :func:`sweep_plots` -- the maps that fit a Dataset (called by ``sweep(out=...)``).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..core.plan import coupling_exchange
from ..plots import save_figure

__all__ = ["heat_map", "basin", "scatter", "line_plot", "sweep_plots", "zoh_margin", "LABELS", "axis_label", "key_unit"]

#: the name an axis of a swept key shows (its unit comes from the scene schema or the model's
#: declaration, :func:`axis_label`); other keys show themselves
LABELS = {"coupling.Kp": "$K_p$", "coupling.Kd": "$K_d$", "solver.dt": "dt", "run.H": "H",
          "system.e": "restitution e", "system.m": "m", "initial.q1": "$q_1(0)$", "initial.u1": "$u_1(0)$",
          "initial.q2": "$q_2(0)$", "initial.u2": "$u_2(0)$"}
_ZOH_KEYS = ("coupling.Kp", "coupling.Kd", "solver.dt", "run.H", "system.m")
_STATE_KEYS = ("initial.q1", "initial.u1", "initial.q2", "initial.u2")


def _plt():
    import matplotlib
    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "ps", "cairo"):
        try:
            matplotlib.use("Agg")
        except Exception:  # pragma: no cover
            pass
    import matplotlib.pyplot as plt
    return plt


def _is_log(v) -> bool:
    v = np.asarray(v, dtype=float)
    if v.size < 3 or np.any(v <= 0):
        return False
    r = v[1:] / v[:-1]
    return bool(v.max() / v.min() > 20 and np.allclose(r, r[0], rtol=1e-6))


def _edges(v, log):
    v = np.asarray(v, dtype=float)
    if v.size == 1:
        return np.array([v[0] * 0.9, v[0] * 1.1]) if log else np.array([v[0] - 0.5, v[0] + 0.5])
    x = np.log(v) if log else v
    mid = 0.5 * (x[1:] + x[:-1])
    e = np.concatenate(([x[0] - (mid[0] - x[0])], mid, [x[-1] + (x[-1] - mid[-1])]))
    return np.exp(e) if log else e


def key_unit(key: str, model=None) -> str:
    """The unit of the swept scene key ``key`` ("table.name"): a ``[system]`` key's as ``model``
    (the scene's :class:`~fmu_sync.core.Model`) declares it, ``initial.q1`` .. ``initial.u2`` the
    model's units of q and u, any other key's from the scene schema; "" when it has none (or
    dimensionless)."""
    from ..scenes.schema import KEYS, system_keys
    from .spec import STATE_ALIASES
    table, _, name = key.partition(".")
    if key in STATE_ALIASES:
        return model.units["q" if name.startswith("q") else "u"] if model is not None else ""
    if table == "system":
        found = system_keys(model).get(name) if model is not None else None
    else:
        found = KEYS.get(table, {}).get(name)
    return found.unit if found is not None else ""


def axis_label(key: str, model=None) -> str:
    """An axis of the swept key ``key``: its name (:data:`LABELS`, else the key) and its unit,
    ``"system.k12 [N/m]"`` (:func:`key_unit`)."""
    unit = key_unit(key, model)
    return f"{LABELS.get(key, key)} [{unit}]" if unit else LABELS.get(key, key)


def _model(ds):
    """The model declaration of the sweep's scene variant (for its parameters' units), or None."""
    v = _base_variant(ds)
    if v is None:
        return None
    from ..scenes.loading import model_of
    try:
        return model_of(v.cfg)
    except Exception:   # a model file gone since the sweep: the axes without units
        return None


def _labels(ds, *keys) -> list:
    """The axis labels of ``keys`` of the sweep ``ds`` (its model loaded once)."""
    model = _model(ds)
    return [axis_label(k, model) for k in keys]


def _base_variant(ds):
    """The scene variant the sweep was made from (for the parameters it did not sweep)."""
    from ..scenes.loading import load_scene
    try:
        sc = load_scene(ds.attrs["scene_file"], json.loads(ds.attrs.get("overrides", "{}")),
                        [ds.attrs["variant"]] if ds.attrs.get("variant") else None)
        return sc.variants[0]
    except Exception:
        return None


def zoh_margin(Kp, Kd, h, m):
    """``omega_c h / h*(zeta)`` of the relative mode of a 1-DOF pair, with ``h*`` the core's
    :func:`fmu_sync.core.exchange.zoh_bound`: the held exchange is stable below 1.
    A pair's relative mode has ``omega_c = sqrt(2 Kp / m)``, ``zeta = Kd / (m omega_c)``;
    without Kp the limit is ``2 Kd h / m < 2``; without Kd no step is stable (inf)."""
    from ..core.exchange import zoh_bound
    Kp, Kd, h, m = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (Kp, Kd, h, m)))
    out = np.empty(Kp.shape)
    for i in np.ndindex(Kp.shape):
        wc = math.sqrt(2.0 * Kp[i] / m[i])
        if wc > 0.0:
            bound = zoh_bound(Kd[i] / (m[i] * wc))
            out[i] = wc * h[i] / bound if bound > 0.0 else np.inf
        else:
            out[i] = Kd[i] * h[i] / m[i]
    return out if out.shape else float(out)


def _zoh_line(ax, ds, x, y, xlog, ylog):
    """Draw the ZOH limit where the two axes are parameters of it; return whether drawn."""
    if not ({x, y} & set(_ZOH_KEYS)):
        return False
    v = _base_variant(ds)
    if v is None or v.system.n != 1 or v.law == "none":
        return False
    cfg = v.cfg
    cosim = cfg["run.mode"] == "cosim"
    if not cosim and coupling_exchange(cfg["solver.scheme"], [v.system]) == "implicit":
        return False   # the core's coupling inside the step: no held exchange, no ZOH limit
    hkey = "run.H" if cosim else "solver.dt"
    base = {"coupling.Kp": float(np.asarray(v.Kp).ravel()[0]), "coupling.Kd": float(np.asarray(v.Kd).ravel()[0]),
            hkey: cfg[hkey], "system.m": float(v.system.M[0, 0])}
    xv, yv = np.asarray(ds[x].values, float), np.asarray(ds[y].values, float)
    xs = np.geomspace(xv.min(), xv.max(), 300) if xlog else np.linspace(xv.min(), xv.max(), 300)
    ys = np.geomspace(yv.min(), yv.max(), 300) if ylog else np.linspace(yv.min(), yv.max(), 300)
    X, Y = np.meshgrid(xs, ys)
    p = {k: np.full_like(X, val) for k, val in base.items()}
    if x in p:
        p[x] = X
    if y in p:
        p[y] = Y
    M = zoh_margin(p["coupling.Kp"], p["coupling.Kd"], p[hkey], p["system.m"])
    Mf = np.where(np.isfinite(M), M, 1e6)
    if not (np.nanmin(Mf) < 1.0 < np.nanmax(Mf)):
        return False
    ax.contourf(X, Y, Mf, levels=[1.0, np.inf], colors="none", hatches=["//"])
    ax.contour(X, Y, Mf, levels=[1.0], colors="white", linewidths=2.6)
    ax.contour(X, Y, Mf, levels=[1.0], colors="crimson", linewidths=1.4, linestyles="--")
    ax.plot([], [], color="crimson", ls="--", lw=1.4,
            label=f"ZOH limit $\\omega_c h = \\min(4\\zeta, 1/\\zeta)$, h = {'H' if cosim else 'dt'}"
                  f" = {base[hkey]:g} s" if hkey not in (x, y)
            else "ZOH limit $\\omega_c h = \\min(4\\zeta, 1/\\zeta)$")
    from matplotlib.patches import Patch
    ax.legend_handles_extra = getattr(ax, "legend_handles_extra", []) + [
        Patch(facecolor="none", edgecolor="0.3", hatch="//", label="beyond the ZOH limit (unstable exchange)")]
    return True


#: the cells of a map without a colour-scale value: colours apart from each other, from viridis, from
#: the diverged red and the refused black (two greys were hard to tell apart)
NOT_SYNCHRONIZED = "#de77ae"
NO_RATE = "0.8"


def _masks(da_status, sync):
    st = np.asarray(da_status)
    return st == 1, st == 2, (st == 0) & ~np.asarray(sync)


def _overlay(ax, XE, YE, mask, color, label):
    """Cells where ``mask`` holds painted ``color``, with a legend entry."""
    if not mask.any():
        return
    from matplotlib.patches import Patch
    Z = np.where(mask, 1.0, np.nan)
    ax.pcolormesh(XE, YE, Z.T, cmap=_single(color), shading="flat", alpha=0.85)
    ax.legend_handles_extra = getattr(ax, "legend_handles_extra", []) + [
        Patch(facecolor=color, alpha=0.85, label=label)]


def _single(color):
    from matplotlib.colors import ListedColormap
    return ListedColormap([color])


def _two_d(ds, x, y):
    """The Dataset reduced to dims (x, y): other dims at their first value; note of them."""
    others = [d for d in ds.dims if d not in (x, y)]
    note = ", ".join(f"{d} = {ds[d].values[0]}" for d in others)
    sub = ds.isel({d: 0 for d in others}).transpose(x, y)
    return sub, note


def resolved_rate(sub) -> np.ndarray:
    """The decay rate where the run succeeded and the rate is resolved (the cell's own
    ``rate_resolved`` flag, :mod:`fmu_sync.core.metrics`), NaN elsewhere."""
    rate = np.asarray(sub["decay_rate"].values, dtype=float)
    if "rate_resolved" not in sub:   # a sweep.nc written before cells carried their verdict: none shown
        return np.full(rate.shape, np.nan)
    ok = (np.asarray(sub["status"].values) == 0) & np.asarray(sub["rate_resolved"].values, dtype=bool)
    return np.where(ok, rate, np.nan)


def _colorbar(fig, mappable, ax, label, norm):
    """A colour bar; on a log norm, ticks at 1, 2, 5 x 10^k written as plain numbers (0.05, 2, 40),
    not as powers (4x10^1)."""
    cb = fig.colorbar(mappable, ax=ax, label=label)
    if norm is not None:
        from matplotlib.ticker import FuncFormatter, LogLocator
        lo, hi = norm.vmin, norm.vmax
        subs = (1.0,) if hi / lo > 1e4 else (1.0, 2.0, 5.0) if hi / lo > 20 else (1.0, 1.5, 2.0, 3.0, 5.0, 7.0)
        cb.locator = LogLocator(subs=subs)
        cb.formatter = FuncFormatter(lambda v, _: f"{v:.3g}")
        cb.minorticks_off()
        cb.update_ticks()
    return cb


def heat_map(ds, x: str, y: str, path, title: str | None = None) -> Path:
    """Decay rate and t_sync over (x, y), failures marked, the ZOH limit drawn."""
    plt = _plt()
    from matplotlib.colors import LogNorm
    sub, note = _two_d(ds, x, y)
    xv, yv = sub[x].values.astype(float), sub[y].values.astype(float)
    xlog, ylog = _is_log(xv), _is_log(yv)
    XE, YE = _edges(xv, xlog), _edges(yv, ylog)
    div, ref, nosync = _masks(sub["status"].values, sub["synchronized"].values)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.4), constrained_layout=True)
    rate = resolved_rate(sub)
    ts = np.where(sub["synchronized"].values, sub["t_sync"].values, np.nan)
    xlabel, ylabel = _labels(ds, x, y)
    panels = [(axes[0], rate, "decay rate of d (1/s, log scale)", "viridis", "log"),
              (axes[1], ts, "t_sync: time to d < %.0e (s)" % ds.attrs.get("threshold", 1e-6), "magma_r",
               "log")]
    for ax, Z, clabel, cmap, scale in panels:
        finite = Z[np.isfinite(Z)]
        norm = None
        if scale == "log" and finite.size and finite.min() > 0:
            norm = LogNorm(vmin=finite.min(), vmax=finite.max())
        elif scale == "log" and finite.size and finite.max() > 0:   # rates <= 0: no decay, shown as such
            Z = np.where(Z > 0, Z, np.nan)
            norm = LogNorm(vmin=float(np.nanmin(Z)), vmax=float(np.nanmax(Z)))
        kw = {} if norm else dict(vmin=float(np.nanmin(finite)) if finite.size else 0,
                                  vmax=float(np.nanmax(finite)) if finite.size else 1)
        m = ax.pcolormesh(XE, YE, Z.T, cmap=cmap, norm=norm, shading="flat", **kw)
        _colorbar(fig, m, ax, clabel, norm)
        if ax is axes[1]:
            _overlay(ax, XE, YE, nosync & ~div & ~ref, NOT_SYNCHRONIZED, "not synchronized by t_end")
        else:
            _overlay(ax, XE, YE, (sub["status"].values == 0) & ~np.isfinite(rate), NO_RATE,
                     "no resolved decay rate (under 2 decades or 20 samples, or spread > 50 %)")
        _overlay(ax, XE, YE, div, "#b2182b", "diverged (stopped early)")
        _overlay(ax, XE, YE, ref, "black", "refused (invalid start)")
        drawn = _zoh_line(ax, ds, x, y, xlog, ylog)
        if xlog:
            ax.set_xscale("log")
        if ylog:
            ax.set_yscale("log")
        ax.set_xlim(XE[0], XE[-1])
        ax.set_ylim(YE[0], YE[-1])
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        handles = getattr(ax, "legend_handles_extra", [])
        if drawn:
            handles = ax.get_legend_handles_labels()[0] + handles
        if handles:
            ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.0, -0.12), fontsize=8, frameon=False)
    n, nf = int(ds["status"].size), int((ds["status"].values != 0).sum())
    head = title or (f"{ds.attrs['sweep_scene']}: " if ds.attrs.get("sweep_scene") else "sweep of ") + \
        ds.attrs.get("scene", "")
    v = ds.attrs.get("variant")
    fig.suptitle(f"{head}{' (' + v + ')' if v else ''}: {n} runs, {nf} failed"
                 + (f"  [{note}]" if note else ""), fontsize=12)
    path = Path(path)
    save_figure(fig, path, 110)
    plt.close(fig)
    return path


def basin(ds, x: str, y: str, path, title: str | None = None) -> Path:
    """Basin of synchronization over a start state: the decay rate of d where the run
    synchronizes (t_sync is ill-conditioned: it moves with every near-threshold crossing;
    the fitted rate does not), runs that do not synchronize marked."""
    plt = _plt()
    from matplotlib.colors import LogNorm
    sub, note = _two_d(ds, x, y)
    xv, yv = sub[x].values.astype(float), sub[y].values.astype(float)
    XE, YE = _edges(xv, False), _edges(yv, False)
    div, ref, nosync = _masks(sub["status"].values, sub["synchronized"].values)
    rate = np.where(sub["synchronized"].values, resolved_rate(sub), np.nan)
    rate = np.where(rate > 0, rate, np.nan)
    fig, ax = plt.subplots(figsize=(7.5, 5.8), constrained_layout=True)
    finite = rate[np.isfinite(rate)]
    # the whole range of rates (a nearly uniform map says: the rate hardly depends on the start;
    # clipping to percentiles would paint the fit's scatter as structure)
    norm = LogNorm(vmin=finite.min(), vmax=max(finite.max(), finite.min() * 1.001)) if finite.size else None
    m = ax.pcolormesh(XE, YE, rate.T, cmap="viridis", norm=norm, shading="flat")
    _colorbar(fig, m, ax, "decay rate of d (1/s, log scale)" + (f"; median {np.median(finite):.3g}" if finite.size
                                                                 else ""), norm)
    _overlay(ax, XE, YE, nosync & ~div & ~ref, NOT_SYNCHRONIZED, "not synchronized by t_end")
    _overlay(ax, XE, YE, ~nosync & ~div & ~ref & ~np.isfinite(rate), NO_RATE,
             "synchronized, no decay window resolved")
    _overlay(ax, XE, YE, div, "#b2182b", "diverged")
    _overlay(ax, XE, YE, ref, "black", "refused (start violates the wall)")
    v = _base_variant(ds)
    if v is not None and v.system.n == 1:
        other = "x1" if x.endswith("2") else "x2"
        q, u = getattr(v, other)
        ax.plot([q], [u], marker="*", ms=14, color="white", mec="black", ls="none",
                label=f"the other system's start ({q:g}, {u:g})")
        if x.startswith("initial.q") and XE[0] < 0 < XE[-1]:
            ax.axvline(0.0, color="black", lw=1.5)
    handles = ax.get_legend_handles_labels()[0] + getattr(ax, "legend_handles_extra", [])
    if handles:   # below the map, never over its cells
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.0, -0.1), ncol=2, fontsize=8, frameon=False)
    ax.set_xlim(XE[0], XE[-1])
    ax.set_ylim(YE[0], YE[-1])
    xlabel, ylabel = _labels(ds, x, y)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    n, nf = int(ds["status"].size), int((ds["status"].values != 0).sum())
    fig.suptitle((title or f"basin of synchronization, {ds.attrs.get('scene', '')}"
                  + (f" ({ds.attrs['variant']})" if ds.attrs.get("variant") else ""))
                 + f": {n} runs, {nf} failed" + (f"  [{note}]" if note else ""), fontsize=11)
    path = Path(path)
    save_figure(fig, path, 110)
    plt.close(fig)
    return path


def scatter(ds, x: str, y: str, path) -> Path:
    """Random / LHS samples: every sample is drawn. The decay rate colours each run that has one
    (filled: resolved; open: a rate the fit does not resolve, :func:`resolved_rate`); runs without a
    rate in grey, failures marked; the legend counts each kind."""
    plt = _plt()
    from matplotlib.colors import Normalize
    fig, ax = plt.subplots(figsize=(7.5, 5.8), constrained_layout=True)
    xv, yv = ds[x].values.astype(float), ds[y].values.astype(float)
    st = ds["status"].values
    rate = np.asarray(ds["decay_rate"].values, dtype=float)
    done = st == 0
    good = done & np.isfinite(resolved_rate(ds))
    loose = done & np.isfinite(rate) & ~good
    none = done & ~np.isfinite(rate)
    shown = rate[good | loose]
    norm = Normalize(vmin=shown.min(), vmax=max(shown.max(), shown.min() + 1e-12)) if shown.size else None
    m = ax.scatter(xv[good], yv[good], c=rate[good], cmap="viridis", norm=norm, s=18,
                   label=f"decay rate resolved ({int(good.sum())})")
    if loose.any():
        cmap = plt.get_cmap("viridis")
        ax.scatter(xv[loose], yv[loose], facecolors="none", edgecolors=cmap(norm(rate[loose])), s=22, lw=1.2,
                   label=f"decay rate not resolved, open ({int(loose.sum())})")
    if none.any():
        ax.scatter(xv[none], yv[none], color="0.6", marker=".", s=20,
                   label=f"no decay rate ({int(none.sum())})")
    if norm is not None:
        fig.colorbar(m, ax=ax, label="decay rate of d (1/s)")
    for code, color, label in ((1, "#b2182b", "diverged"), (2, "black", "refused")):
        sel = st == code
        if sel.any():
            ax.scatter(xv[sel], yv[sel], marker="x", color=color, s=24, label=f"{label} ({int(sel.sum())})")
    if _is_log(np.sort(xv)) or (np.all(xv > 0) and xv.max() / xv.min() > 50):
        ax.set_xscale("log")
    if np.all(yv > 0) and yv.max() / yv.min() > 50:
        ax.set_yscale("log")
    xlabel, ylabel = _labels(ds, x, y)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(0.0, -0.1), ncol=2, frameon=False)
    ax.set_title(f"{ds.attrs.get('method', '')} sample of {ds.attrs.get('scene', '')}: {st.size} runs, all drawn, "
                 f"{int((st != 0).sum())} failed")
    path = Path(path)
    save_figure(fig, path, 110)
    plt.close(fig)
    return path


def line_plot(ds, x: str, path) -> Path:
    """One swept parameter: decay rate (with its uncertainty) and t_sync against it, one line
    per combination of the other swept values (up to 8), failures marked."""
    plt = _plt()
    import itertools
    others = [d for d in ds.dims if d != x]
    combos = list(itertools.product(*(range(ds.sizes[d]) for d in others)))[:8]
    xv = ds[x].values.astype(float)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), constrained_layout=True)
    for n, combo in enumerate(combos):
        sub = ds.isel(dict(zip(others, combo))) if others else ds
        label = ", ".join(f"{d} = {ds[d].values[i]}" for d, i in zip(others, combo)) or None
        ok = sub["status"].values == 0
        rate = resolved_rate(sub)
        err = np.where(np.isfinite(rate), sub["decay_rate_err"].values, np.nan)
        ts = np.where(sub["synchronized"].values, sub["t_sync"].values, np.nan)
        c = f"C{n}"
        axes[0].errorbar(xv, rate, yerr=err, color=c, marker="o", ms=3, capsize=2, label=label)
        axes[1].plot(xv, ts, color=c, marker="o", ms=3, label=label)
        bad = sub["status"].values != 0
        for ax in axes:
            if bad.any():
                ax.plot(xv[bad], np.zeros(bad.sum()), "x", color="#b2182b", ms=7,
                        label="diverged / refused" if n == 0 else None)
    log = _is_log(xv)
    (xlabel,) = _labels(ds, x)
    for ax, yl in ((axes[0], "decay rate of d (1/s)"), (axes[1], "t_sync (s)")):
        if log:
            ax.set_xscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(yl)
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
    n, nf = int(ds["status"].size), int((ds["status"].values != 0).sum())
    fig.suptitle(f"sweep of {ds.attrs.get('scene', '')}: {n} runs, {nf} failed; t_sync where synchronized",
                 fontsize=11)
    path = Path(path)
    save_figure(fig, path, 110)
    plt.close(fig)
    return path


def sweep_plots(ds, out_dir, axes: dict | None = None) -> list[Path]:
    """The maps that fit the Dataset: basin (two start-state axes), heat map (two swept
    numeric parameters) or a scatter plot (samples). ``axes`` may name ``x``, ``y``."""
    out_dir = Path(out_dir)
    axes = axes or {}
    swept = json.loads(ds.attrs.get("swept", "[]"))
    numeric = [k for k in swept if np.issubdtype(np.asarray(ds[k].values).dtype, np.number)]
    x, y = axes.get("x"), axes.get("y")
    if x is None or y is None:
        if "run" in ds.dims:
            cand = numeric
        else:
            cand = [k for k in numeric if ds.sizes.get(k, 0) > 1]
        if len(cand) == 1 and "run" not in ds.dims:
            return [line_plot(ds, cand[0], out_dir / "line.png")]
        if len(cand) < 2:
            return []
        x, y = cand[0], cand[1]
    if "run" in ds.dims:
        return [scatter(ds, x, y, out_dir / "samples.png")]
    if x in _STATE_KEYS and y in _STATE_KEYS:
        return [basin(ds, x, y, out_dir / "basin.png")]
    return [heat_map(ds, x, y, out_dir / "map.png")]
