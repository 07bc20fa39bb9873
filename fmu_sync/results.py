"""Reopening saved results (docs/results.md): :func:`load` reads a run's ``.npz``, ``.csv`` or
``.nc`` back into its result object (:class:`~fmu_sync.core.PairResult`,
:class:`~fmu_sync.core.result.NetworkResult`, :class:`~fmu_sync.core.SimulationResult`) and a
sweep's ``sweep.nc`` into its xarray Dataset; :func:`redraw` (``fmu-sync plot DIR``) draws a
finished run's plots again from its data.

Files of 0.2.0 describe themselves (the ``.npz`` member ``meta``, the ``.nc`` attributes, CSV
names with units and edges by their nodes); the pair and single-system files of 0.1.0 are
read too (their counts of impact steps are not in them: ``None``). A network file of 0.1.0
does not say which column is which node or edge and is refused.
"""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np

__all__ = ["load", "load_meta", "from_xarray", "redraw", "data_files"]

_PAIR = ("q1", "u1", "q2", "u2", "tau1", "tau2")


def load(path):
    """A saved run (``.npz``, ``.csv``, ``.nc``) as its result object; a sweep's ``.nc`` as
    its xarray Dataset. Raises FileNotFoundError or ValueError (what the file lacks)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path} is a folder; give one of its data files (.npz, .csv, .nc), or redraw its "
                         "plots with `fmu-sync plot DIR`")
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    kind = path.suffix.lower()
    if kind == ".npz":
        return _from_npz(path)
    if kind == ".csv":
        return _from_csv(path)
    if kind == ".nc":
        return _from_nc(path)
    raise ValueError(f"{path.name}: cannot load a {kind or 'suffix-less'} file; allowed: .npz, .csv (a run), "
                     ".nc (a run or a sweep)")


def load_meta(path) -> dict:
    """What a run's file keeps besides its arrays (layout, counts, settings, plots, title,
    wall): the ``.npz`` member ``meta`` or the ``.nc`` attributes; ``{}`` for a CSV or an
    older file."""
    path = Path(path)
    if path.suffix == ".npz":
        a = _npz_arrays(path)
        return json.loads(str(a["meta"])) if "meta" in a else {}
    if path.suffix == ".nc":
        import xarray as xr
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            out = {}
            for k in ("settings", "plots", "title", "wall"):
                if k in ds.attrs:
                    v = ds.attrs[k]
                    out[k] = json.loads(v) if isinstance(v, str) and v[:1] in "[{" else v
            return out
    return {}


# ---------------------------------------------------------------- npz
def _npz_arrays(path: Path) -> dict:
    """Every array of a ``.npz`` (never unpickled); a file that is not one, or is cut short or
    damaged, is a ValueError naming the file and what is wrong with it."""
    import zipfile
    import zlib
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path}: not a .npz archive (no zip directory: the file is truncated, damaged or of "
                         f"another kind, {path.stat().st_size} bytes); write it again")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError) as exc:
        if "pickle" in str(exc):
            raise ValueError(f"{path}: holds an array of Python objects, which fmu-sync never writes; not loaded "
                             "(unpickling a file runs its code)") from None
        raise ValueError(f"{path}: a damaged .npz archive, cannot read its arrays ({type(exc).__name__}: {exc}); "
                         "write it again") from None


def _from_npz(path: Path):
    from .core.result import NetworkResult, PairResult, SimulationResult
    a = _npz_arrays(path)
    meta = json.loads(str(a.pop("meta"))) if "meta" in a else None
    if meta is None:   # a file of 0.1.0: the layout from the array names
        if all(k in a for k in _PAIR):
            meta = {"kind": "pair", "impacts1": None, "impacts2": None}
        elif "percussion" in a:
            meta = {"kind": "single", "scheme": "", "dt": float("nan")}
        else:
            raise ValueError(f"{path.name}: a network record written before 0.2.0 does not say which columns "
                             "belong to which node and edge; run the scene again to get a file that does")
    need = {"pair": ("t",) + _PAIR, "single": ("t", "q", "u", "percussion"),
            "network": ("t", "q", "u", "tau")}[meta["kind"]]
    missing = [k for k in need if k not in a]
    if missing:
        raise ValueError(f"{path.name}: not a run record of fmu-sync: no array {', '.join(missing)}")
    t, info, error = a["t"], meta.get("info", {}), meta.get("error")
    if meta["kind"] == "single":
        return SimulationResult(t, a["q"], a["u"], a["percussion"], meta.get("scheme", ""),
                                float(meta.get("dt", float("nan"))), error=error)
    d = a.get("d")
    branch = None if d is None else a["branch"].astype(np.int64)
    if meta["kind"] == "pair":
        return PairResult(t, *(a[k] for k in _PAIR), d, branch, a.get("euclidean"),
                          impacts1=meta.get("impacts1"), impacts2=meta.get("impacts2"),
                          coupling=meta.get("coupling"), info=info, error=error)
    rows, N, n = len(t), int(meta["N"]), int(meta["n"])
    shape = lambda k: a[k].reshape(rows, N, n)  # noqa: E731
    return NetworkResult(t, shape("q"), shape("u"), shape("tau"), [tuple(e) for e in meta["edges"]], d, branch,
                         a.get("euclidean"), a.get("V") if d is not None else None,   # the Euclidean error kept

                         meta.get("impacts"), info=info, error=error)


# ---------------------------------------------------------------- csv
def _from_csv(path: Path):
    from .core.result import NetworkResult, PairResult, SimulationResult
    from .core.views import UNITS, branch_code, parse_header
    from .fmus.slave import unit_exponents
    with open(path, encoding="ascii") as fh:
        header = fh.readline().rstrip("\r\n").split(",")
    try:
        cols = [parse_header(h) for h in header]
    except ValueError as exc:
        raise ValueError(f"{path.name}: {exc}") from None
    own = {}   # a model's declared units of q, u, tau (Model.units): read back into info["units"]
    for (name, _, _, unit), h in zip(cols, header):
        if unit is not None and name in ("q", "u", "tau"):
            try:
                unit_exponents(unit)     # a unit a model can declare (its FMU's spelling)
            except ValueError as exc:
                raise ValueError(f"{path.name}: column {h!r} is in {unit}; fmu-sync writes {name} in {UNITS[name]} "
                                 f"or in the unit its model declares ({exc})") from None
            if own.setdefault(name, unit) != unit:
                raise ValueError(f"{path.name}: column {h!r} is in {unit}, another {name} column in {own[name]}")
        elif unit is not None and unit != UNITS[name] and not (name == "percussion" and unit.endswith(" s")):
            raise ValueError(f"{path.name}: column {h!r} is in {unit}; fmu-sync writes {name} in {UNITS[name]}")
    info = {"loaded_from": "csv", **({"units": own} if any(own[k] != UNITS[k] for k in own) else {})}
    bcols = [i for i, c in enumerate(cols) if c[0] == "branch"]
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64,
                          converters={i: branch_code for i in bcols}, encoding="ascii")
    except ValueError as exc:
        raise ValueError(f"{path}: {_bad_row(path, len(cols)) or exc}") from None
    if data.shape[1] != len(cols) and data.size:
        raise ValueError(f"{path.name}: rows have {data.shape[1]} values, the header names {len(cols)}")
    data = data.reshape(-1, len(cols))

    def pick(name, node=None, sub=None):
        idx = [i for i, c in enumerate(cols) if c[0] == name and c[1] == node and (sub is None or c[2] == sub)]
        return idx

    names = [c[0] for c in cols]
    t = data[:, names.index("t")]
    first = lambda name, node=None: next((i for i, c in enumerate(cols) if c[0] == name  # noqa: E731
                                          and (node is None or c[1] == node)), len(cols))
    # a network names its edges (d[1-2]) or lists all positions first (q1, q2, .., u1, ..);
    # a pair lists q1, u1, q2, u2
    network = any(c[2] and "-" in c[2] for c in cols) or first("q", 2) < first("u")
    if any(c[0] == "q" and c[1] is None and c[2] is not None for c in cols) and "tau" in names:
        raise ValueError(f"{path.name}: a network record written before 0.2.0 does not say which columns belong "
                         "to which node and edge; run the scene again to get a file that does")
    one = lambda name: data[:, pick(name)[0]] if pick(name) else None  # noqa: E731
    if "percussion" in names:
        return SimulationResult(t, data[:, pick("q")], data[:, pick("u")], data[:, pick("percussion")[0]], "",
                                float("nan"))
    if not network:
        arrays = [data[:, pick(k[:-1], int(k[-1]))] for k in _PAIR]
        d = one("d")
        return PairResult(t, *arrays, d, None if d is None else one("branch").astype(np.int64),
                          one("euclidean"), impacts1=None, impacts2=None, info=info)
    N = max(c[1] for c in cols if c[0] == "q")
    n = len(pick("q", 1))
    node = lambda k: np.stack([data[:, pick(k, i)] for i in range(1, N + 1)], axis=1)  # noqa: E731
    subs = [c[2] for c in cols if c[0] == "d" and c[2]]
    e_subs = [c[2] for c in cols if c[0] == "euclidean" and c[2]]   # without one impact map: the Euclidean error alone
    edges = [tuple(int(x) - 1 for x in s.split("-")) for s in (subs or e_subs)]
    d = data[:, pick("d")] if subs else None
    edge_cols = lambda k: data[:, [i for i, c in enumerate(cols) if c[0] == k and c[2] in (subs or e_subs)]]  # noqa: E731
    return NetworkResult(t, node("q"), node("u"), node("tau"), edges, d,
                         None if d is None else edge_cols("branch").astype(np.int64),
                         edge_cols("euclidean") if (subs or e_subs) else None, one("V"), None, info=info)


def _bad_row(path: Path, width: int) -> str:
    """The first line of a CSV whose values are not ``width`` numbers, in words ("" if none)."""
    with open(path, encoding="ascii", errors="replace") as fh:
        fh.readline()
        for i, line in enumerate(fh, start=2):
            cells = line.rstrip("\r\n").split(",")
            if len(cells) != width:
                return (f"line {i} has {len(cells)} values, the header names {width} (the file is truncated or "
                        "damaged there); write it again")
    return ""


# ---------------------------------------------------------------- nc
def _from_nc(path: Path):
    import xarray as xr
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        ds = ds.load()
    if "fmu_sync_result" in ds.attrs:
        return from_xarray(ds)
    if "status" in ds and "decay_rate" in ds:
        return ds
    raise ValueError(f"{path.name}: neither a run nor a sweep of fmu-sync (no attribute fmu_sync_result, no "
                     "variables status and decay_rate)")


def from_xarray(ds):
    """The result a :meth:`~fmu_sync.core.result.PairResult.to_xarray` Dataset was made of
    (same arrays, bit for bit)."""
    from .core.result import NetworkResult, PairResult, SimulationResult
    kind = ds.attrs.get("fmu_sync_result")
    if kind not in ("single", "pair", "network"):
        raise ValueError(f"not a run of fmu-sync (attribute fmu_sync_result = {kind!r}; allowed: single, pair, "
                         "network)")
    error = ds.attrs.get("error") or None
    info = {}
    for k, v in ds.attrs.items():
        if k.startswith("info:"):
            v = v.item() if isinstance(v, np.generic) else v
            try:
                info[k[5:]] = json.loads(v) if isinstance(v, str) and v[:1] in "[{" else v
            except ValueError:
                info[k[5:]] = v
    t = ds["t"].values
    if kind == "single":
        return SimulationResult(t, ds["q"].values, ds["u"].values, ds["percussion"].values,
                                str(ds.attrs.get("scheme", "")), float(ds.attrs.get("dt", float("nan"))),
                                error=error)
    has_d = "d" in ds
    get = lambda k: ds[k].values if has_d else None  # noqa: E731
    branch = None if not has_d else ds["branch"].values.astype(np.int64)
    if kind == "pair":
        q, u, tau = ds["q"].values, ds["u"].values, ds["tau"].values
        coupling = ds.attrs.get("coupling", "none")
        return PairResult(t, q[:, 0], u[:, 0], q[:, 1], u[:, 1], tau[:, 0], tau[:, 1], get("d"), branch,
                          get("euclidean"), impacts1=int(ds.attrs.get("impacts1", 0)),
                          impacts2=int(ds.attrs.get("impacts2", 0)),
                          coupling=None if coupling == "none" else coupling, info=info, error=error)
    edges = [(int(i) - 1, int(j) - 1) for i, j in zip(ds["edge_i"].values, ds["edge_j"].values)]
    return NetworkResult(t, ds["q"].values, ds["u"].values, ds["tau"].values, edges, get("d"), branch,
                         get("euclidean"), get("V"), json.loads(ds.attrs.get("impacts", "[]")), info=info,
                         error=error)


# ---------------------------------------------------------------- plots again
def data_files(folder) -> dict:
    """``{run name: its data file}`` in a run's output folder (npz preferred, then nc, then csv;
    partial records of failed runs are left out: they get no plots)."""
    folder = Path(folder)
    found = {}
    for suffix in (".csv", ".nc", ".npz"):   # later suffixes win
        for p in sorted(folder.glob(f"*{suffix}")):
            if p.name.endswith(f".partial{suffix}") or p.name == "sweep.nc":
                continue
            found[p.name[:-len(suffix)]] = p
    return dict(sorted(found.items()))


def redraw(folder, only=None) -> list[Path]:
    """Draw the plots of a finished run again from its data (``fmu-sync plot DIR``): each run's
    plots (those the scene asked for; ``only``: these kinds), the comparison of d when the
    folder has several runs with d, or a sweep's maps (``sweep.nc``). Returns the files written."""
    from . import plots as P
    from .scenes.schema import PLOTS, plots_for
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"no such folder: {folder}")
    only = list(only or [])
    bad = [k for k in only if k not in PLOTS]
    if bad:
        raise ValueError(f"--only {bad[0]}: not a plot; allowed: {', '.join(PLOTS)}")
    if (folder / "sweep.nc").is_file() and not data_files(folder):
        if only:
            raise ValueError(f"--only applies to the plots of runs; {folder} holds a sweep (its maps are drawn "
                             "without --only)")
        from .sweeps.plots import sweep_plots
        from .sweeps.store import read_dataset
        return sweep_plots(read_dataset(folder / "sweep.nc"), folder)
    files = data_files(folder)
    if not files:
        raise ValueError(f"{folder} holds no run data (.npz, .csv, .nc) and no sweep.nc; plots are drawn from a "
                         "run's data files (a run with --format none has none)")
    from .core.views import layout
    written, results, seen = [], {}, []
    for name, path in files.items():
        result = load(path)
        meta = load_meta(path)
        k = layout(result)
        seen.append(f"{name}: {_described(k)}")
        possible = plots_for(k["kind"] != "single", k["distance"], k["kind"] == "network")
        kinds = [p for p in only if p in possible] if only else [p for p in meta.get("plots", possible)
                                                                  if p in possible]
        wall = meta.get("wall")
        system = None if wall is None else SimpleNamespace(w=np.asarray(wall["w"], dtype=float),
                                                           g0=float(wall["g0"]))
        title = meta.get("title", name)
        for p in kinds:
            if P.skip_reason(p, result) is not None:
                continue
            written.append(P.PLOTTERS[p](result, folder / f"{name}-{p}.png", system=system, title=title))
        if k["distance"] and meta.get("plots", possible):   # runs drawn without plots (the demo's core
            results[name] = result                           # references) stay out of the comparison
    if only and not written:
        raise ValueError(f"--only {', '.join(only)}: not drawn for the runs in {folder} ({'; '.join(seen)}); "
                         f"a single system has {', '.join(plots_for(False, False, False))}, a network "
                         f"{', '.join(plots_for(True, True, True))}")
    if not only and len(results) > 1:
        written.append(P.compare_plot(results, folder / "compare-distance.png",
                                      title=f"{folder.name}: quotient distance d of each run"))
    return written


def _described(k: dict) -> str:
    return {"single": "a single system", "pair": "a pair", "network": "a network"}[k["kind"]] + \
        ("" if k["distance"] or k["kind"] == "single" else " without d")
