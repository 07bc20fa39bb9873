"""Self-describing views of a result (docs/design.md §5.2): the record's column names with
units, the CSV text of its rows, an xarray Dataset (and back), a pandas DataFrame, a
quick-look matplotlib Figure and a short repr.

One rule for the names: :func:`column_headers` names every scalar column of a record
(``t [s]``, ``q1 [m]``, ``tau1 [N]``, a network's edges by their nodes ``d[1-2]``) and
:func:`parse_header` reads them back (also the names of files written before 0.2.0:
``t``, ``q1``, ``q[1]``). xarray, pandas and matplotlib are imported inside the
functions that use them: the core itself needs numpy and numba only.
"""
from __future__ import annotations

import json
import math
import re

import numpy as np

from .declaration import DEFAULT_UNITS
from .distance import BRANCH_NAMES

__all__ = ["BRANCH_LABELS", "branch_label", "branch_code", "UNITS", "LONG_NAMES", "layout", "column_headers", "parse_header", "csv_lines", "record_arrays",
           "to_xarray", "to_dataframe", "figure", "short_repr", "plain_settings"]

#: a branch code's name; code -1 (BRANCH_NONE: an uncoupled edge, no branch chosen) is "none"
BRANCH_LABELS = tuple(BRANCH_NAMES) + ("none",)


def branch_label(code) -> str:
    """``0`` -> ``"E"``, ..., ``3`` -> ``"J2"``, ``-1`` -> ``"none"``."""
    code = int(code)
    return "none" if code < 0 else BRANCH_NAMES[code]


def branch_code(label: str) -> int:
    """The inverse of :func:`branch_label`; also reads the float codes of older files ("0", "3.0")."""
    if label == "none":
        return -1
    if label in BRANCH_NAMES:
        return BRANCH_NAMES.index(label)
    try:
        code = float(label)
    except ValueError:
        code = math.nan
    if code not in (-1, 0, 1, 2, 3):
        raise ValueError(f"unknown branch {label!r}; allowed: {', '.join(BRANCH_LABELS)} (or codes -1 .. 3)")
    return int(code)


#: units of the record's quantities (SI, docs/design.md §5.3); d, V and the Euclidean
#: error are P-norms (q^T Q q + u^T M u)^(1/2): their unit is that of the norm
UNITS = {"t": "s", **DEFAULT_UNITS, "percussion": "N s", "d": "P-norm",
         "euclidean": "P-norm", "V": "P-norm^2", "d_max": "P-norm", "branch": ""}
LONG_NAMES = {
    "t": "time",
    "q": "generalized position",
    "u": "generalized velocity",
    "tau": "coupling force held over the step that ends at t (row 0: the forces at the start)",
    "percussion": "contact percussion over the steps that end at t",
    "d": "quotient distance d (P-norm, impacts identified)",
    "euclidean": "Euclidean error ||x1 - x2||_P",
    "V": "Lyapunov function V = 1/2 sum_edges a_ij d_ij^2 (a pair: d^2/2)",
    "d_max": "largest pairwise quotient distance",
    "branch": "winning branch of the quotient distance: " + ", ".join(BRANCH_NAMES) + " (none: not computed)",
}


def units_info(model) -> dict:
    """``{"units": {"q": .., "u": .., "tau": ..}}`` for a run's ``info`` when its model (a
    :class:`~fmu_sync.core.Model`) declares units other than the defaults, else ``{}``."""
    return {} if model.units == DEFAULT_UNITS else {"units": dict(model.units)}


def units_of(result) -> dict:
    """:data:`UNITS` with the run's declared units of q, u and tau (``result.info["units"]``,
    :func:`units_info`)."""
    info = getattr(result, "info", None) or {}
    return units_with(info.get("units") or {})


def units_with(own: dict) -> dict:
    """:data:`UNITS` with declared units ``own`` of q, u and tau (the percussion in tau's unit times s)."""
    return {**UNITS, **own, **({"percussion": f"{own['tau']} s"} if "tau" in own else {})}


def _kind(result) -> str:
    if hasattr(result, "edges"):
        return "network"
    return "pair" if hasattr(result, "q2") else "single"


def layout(result) -> dict:
    """``kind`` ("single", "pair", "network"), ``n`` (degrees of freedom), ``N`` (systems),
    ``edges`` (network) and ``distance`` (whether d was recorded) of a result."""
    kind = _kind(result)
    rows = len(result.t)
    own = {"units": units_of(result)} if (getattr(result, "info", None) or {}).get("units") else {}
    if kind == "network":
        q = np.asarray(result.q)
        return dict(kind=kind, N=int(q.shape[1]), n=int(q.shape[2]),
                    edges=[[int(i), int(j)] for i, j in result.edges], distance=result.d is not None, **own)
    if kind == "pair":
        return dict(kind=kind, N=2, n=int(np.asarray(result.q1).reshape(rows, -1).shape[1]), edges=[[0, 1]],
                    distance=result.d is not None, **own)
    return dict(kind=kind, N=1, n=int(np.asarray(result.q).reshape(rows, -1).shape[1]), edges=[],
                distance=False, **own)


def _unit(base: str, units: dict | None = None) -> str:
    u = (units or UNITS).get(base, "")
    return f" [{u}]" if u and u not in ("P-norm", "P-norm^2") else ""


def column_headers(name: str, width: int, lay: dict) -> list[str]:
    """CSV names of one record array (``name`` of width ``width``) in a record of layout ``lay``."""
    n = lay["n"]
    base = name.rstrip("12") if lay["kind"] == "pair" and name[:-1] in ("q", "u", "tau") else name
    unit = _unit(base, lay.get("units"))
    if lay["kind"] == "network" and name in ("q", "u", "tau"):
        return [f"{name}{i + 1}{'' if n == 1 else f'[{j + 1}]'}{unit}" for i in range(lay["N"]) for j in range(n)]
    if lay["kind"] == "network" and name in ("d", "euclidean", "branch"):
        return [f"{name}[{i + 1}-{j + 1}]" for i, j in lay["edges"]]
    if width == 1 and name not in ("q", "u", "q1", "u1", "q2", "u2", "tau1", "tau2"):
        return [f"{name}{unit}"]
    return [f"{name}{unit}" if n == 1 else f"{name}[{j + 1}]{unit}" for j in range(width)]


_HEADER = re.compile(r"^(?P<name>[A-Za-z_]+?)(?P<node>\d+)?(?:\[(?P<sub>\d+(?:-\d+)?)\])?(?: \[(?P<unit>[^\]]*)\])?$")


def parse_header(text: str) -> tuple[str, int | None, str | None, str | None]:
    """``"q3[2] [m]"`` -> ``("q", 3, "2", "m")``; ``"d[1-2]"`` -> ``("d", None, "1-2", None)``;
    ``"d_max"`` -> ``("d_max", None, None, None)``. Raises ValueError for a name it does not know."""
    m = _HEADER.match(text.strip())
    if not m or m.group("name") not in UNITS:
        raise ValueError(f"unknown column {text!r}; columns are t, q, u, tau, percussion, d, V, euclidean, "
                         "branch, d_max with node numbers, [index] or [i-j] and [unit]")
    node = m.group("node")
    return m.group("name"), (int(node) if node else None), m.group("sub"), m.group("unit")


def csv_lines(block: np.ndarray, branch_columns=()):
    """CSV text of a float block (rows x columns), 1024 rows per yielded string (memory: one
    part at a time): each number with the digits it needs (Python's shortest repr, which
    reads back to the same float), the branch columns as names (E, J12, J21, J2, none)."""
    if block.shape[0] == 0:
        return
    k = block.shape[1]
    line = ",".join("%s" if c in branch_columns else "%r" for c in range(k)) + "\n"
    for a in range(0, block.shape[0], 1024):
        part = block[a:a + 1024].tolist()
        for r in part if branch_columns else ():
            for c in branch_columns:
                r[c] = branch_label(r[c])
        yield (line * len(part)) % tuple(x for r in part for x in r)


def record_arrays(result) -> list[tuple[str, np.ndarray]]:
    """The record as ``(name, 2-D array rows x width)`` in file order (the CSV's column groups)."""
    lay = layout(result)
    rows = len(result.t)
    two = lambda a: np.asarray(a).reshape(rows, -1)  # noqa: E731
    if lay["kind"] == "network":
        out = [("t", two(result.t))] + [(k, two(getattr(result, k))) for k in ("q", "u", "tau")]
        if lay["distance"]:
            out += [("d", two(result.d)), ("euclidean", two(result.euclidean)), ("branch", two(result.branch)),
                    ("V", two(result.V)), ("d_max", two(result.d_max))]
        return out
    if lay["kind"] == "pair":
        out = [("t", two(result.t))] + [(k, two(getattr(result, k))) for k in ("q1", "u1", "q2", "u2", "tau1",
                                                                              "tau2")]
        if lay["distance"]:
            out += [("d", two(result.d)), ("V", two(result.V)), ("euclidean", two(result.euclidean)),
                    ("branch", two(result.branch))]
        return out
    return [("t", two(result.t)), ("q", two(result.q)), ("u", two(result.u)), ("percussion", two(result.percussion))]


# ---------------------------------------------------------------- settings as attributes
def plain_settings(d: dict, prefix: str = "") -> dict:
    """A dict with JSON-able values only (numbers, strings, booleans, short lists; arrays as
    lists; None and long arrays dropped): the settings a file keeps."""
    out = {}
    for k, v in (d or {}).items():
        if v is None:
            continue
        if isinstance(v, np.ndarray):
            if v.size > 64:
                continue
            v = v.tolist()
        elif isinstance(v, (np.generic,)):
            v = v.item()
        elif isinstance(v, tuple):
            v = list(v)
        try:
            json.dumps(v)
        except TypeError:
            continue
        out[f"{prefix}{k}"] = v
    return out


def _attr(v):
    """A netCDF attribute: numbers and strings as they are, booleans as 0/1, the rest as JSON."""
    if isinstance(v, bool):
        return int(v)
    if isinstance(v, (int, float, str)):
        return v
    return json.dumps(v)


# ---------------------------------------------------------------- xarray
def to_xarray(result, settings: dict | None = None):
    """An :class:`xarray.Dataset`: coordinate ``t`` (s), dimensions ``node`` (the systems,
    numbered from 1), ``dof`` and ``edge`` (a network's coupled pairs, labelled "i-j");
    every variable has ``units`` and ``long_name``; the run's settings (``result.info``,
    the coupling, ``settings``) are attributes."""
    import xarray as xr

    lay = layout(result)
    units = units_of(result)
    rows = len(result.t)
    n = lay["n"]
    coords = {"t": ("t", np.asarray(result.t), {"units": "s", "long_name": "time"}),
              "dof": ("dof", np.arange(1, n + 1), {"long_name": "degree of freedom"})}
    data = {}

    def var(name, dims, values):
        data[name] = (dims, values, {"units": units[name], "long_name": LONG_NAMES[name]})

    kind = lay["kind"]
    if kind == "single":
        for k in ("q", "u"):
            var(k, ("t", "dof"), np.asarray(getattr(result, k)).reshape(rows, n))
        var("percussion", ("t",), np.asarray(result.percussion))
    else:
        coords["node"] = ("node", np.arange(1, lay["N"] + 1), {"long_name": "system (node of the graph)"})
        if kind == "pair":
            for k in ("q", "u", "tau"):
                var(k, ("t", "node", "dof"), np.stack([np.asarray(getattr(result, f"{k}{i}")).reshape(rows, -1)
                                                       for i in (1, 2)], axis=1))
        else:
            for k in ("q", "u", "tau"):
                var(k, ("t", "node", "dof"), np.asarray(getattr(result, k)))
        if kind == "network":
            e = np.asarray(lay["edges"], dtype=np.int64).reshape(-1, 2) + 1
            coords["edge"] = ("edge", [f"{i}-{j}" for i, j in e], {"long_name": "coupled pair i-j"})
            coords["edge_i"] = ("edge", e[:, 0], {"long_name": "first node of the edge"})
            coords["edge_j"] = ("edge", e[:, 1], {"long_name": "second node of the edge"})
        if lay["distance"]:
            edim = ("t",) if kind == "pair" else ("t", "edge")
            if kind == "network":
                var("d_max", ("t",), np.asarray(result.d_max))
            var("d", edim, np.asarray(result.d))
            var("euclidean", edim, np.asarray(result.euclidean))
            var("V", ("t",), np.asarray(result.V))
            var("branch", edim, np.asarray(result.branch))
            data["branch"][2].update(flag_values=np.arange(-1, len(BRANCH_NAMES), dtype=np.int8),
                                     flag_meanings=" ".join(("none",) + tuple(BRANCH_NAMES)))
    attrs = {"fmu_sync_result": kind, "success": int(result.success), "message": result.message}
    if getattr(result, "error", None):
        attrs["error"] = result.error
    if kind == "pair":
        attrs.update(impacts1=int(result.impacts1), impacts2=int(result.impacts2),
                     coupling=result.coupling or "none")
    elif kind == "network":
        attrs["impacts"] = json.dumps([int(x) for x in result.impacts])
    else:
        attrs.update(scheme=result.scheme, dt=float(result.dt), impacts=int(result.impacts))
    info = plain_settings(getattr(result, "info", {}) or {})
    attrs.update({f"info:{k}": _attr(v) for k, v in info.items()})
    attrs.update({k: _attr(v) for k, v in plain_settings(settings or {}).items()})
    return xr.Dataset(data, coords=coords, attrs=attrs)


def to_dataframe(result):
    """A :class:`pandas.DataFrame` with the CSV's columns (names with units, edges by their
    nodes, branches by name), indexed by row."""
    import pandas as pd

    lay = layout(result)
    cols = {}
    for name, a in record_arrays(result):
        for j, h in enumerate(column_headers(name, a.shape[1], lay)):
            cols[h] = (pd.Categorical([branch_label(c) for c in a[:, j]], BRANCH_LABELS) if name == "branch"
                       else a[:, j])
    return pd.DataFrame(cols)


# ---------------------------------------------------------------- figure and repr
def figure(result):
    """A quick-look :class:`matplotlib.figure.Figure` (no pyplot state): positions over time
    and, when recorded, the quotient distance d with the Euclidean error (log axis)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    lay = layout(result)
    t = np.asarray(result.t)
    two = lay["distance"]
    fig = Figure(figsize=(8.0, 6.0 if two else 3.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2 if two else 1, 1, sharex=True, squeeze=False)[:, 0]
    ax = axes[0]
    if lay["kind"] == "single":
        ax.plot(t, np.asarray(result.q).reshape(len(t), -1)[:, 0], label="q")
    elif lay["kind"] == "pair":
        for i in (1, 2):
            ax.plot(t, np.asarray(getattr(result, f"q{i}")).reshape(len(t), -1)[:, 0], label=f"q{i}")
    else:
        for i in range(lay["N"]):
            ax.plot(t, np.asarray(result.q)[:, i, 0], lw=0.8, label=f"q{i + 1}")
    ax.set_ylabel(f"position q [{units_of(result)['q']}]" + ("" if lay["n"] == 1 else " (first coordinate)"))
    ax.legend(loc="upper right", fontsize=8, ncol=2 if lay["N"] > 4 else 1)
    ax.set_title(short_repr(result), fontsize=10)
    if two:
        ax = axes[1]
        d = np.asarray(result.d_max if lay["kind"] == "network" else result.d, dtype=float)
        E = np.asarray(result.euclidean, dtype=float).reshape(len(t), -1).max(axis=1)
        ax.semilogy(t, np.where(E > 0, E, np.nan), color="#ff7f0e", lw=1.0,
                    label="Euclidean error" + (" (max over the edges)" if lay["kind"] == "network" else ""))
        ax.semilogy(t, np.where(d > 0, d, np.nan), color="#2ca02c", lw=1.6,
                    label="quotient distance d" + (" (max over the edges)" if lay["kind"] == "network" else ""))
        ax.set_ylabel("distance (P-norm)")
        ax.legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time t [s]")
    return fig


def short_repr(result) -> str:
    """``PairResult(5001 records, t = 0 .. 50 s, n = 1, coupling switching, final d 3.1e-09, ok)``."""
    lay = layout(result)
    t = np.asarray(result.t)
    span = f"t = {t[0]:g} .. {t[-1]:g} s" if t.size else "empty"
    parts = [f"{t.size} records", span, f"n = {lay['n']}"]
    if lay["kind"] == "network":
        parts.insert(2, f"N = {lay['N']}, {len(lay['edges'])} edges")
    if lay["kind"] == "single":
        parts.append(f"scheme {result.scheme}, dt = {result.dt:g} s, {result.impacts} impact steps")
    else:
        c = getattr(result, "coupling", None) if lay["kind"] == "pair" else result.info.get("coupling")
        parts.append("coupling not in the file" if result.info.get("loaded_from") == "csv" else
                     f"coupling {c or 'none'}")
        if lay["distance"] and t.size:
            d = result.d_max if lay["kind"] == "network" else result.d
            parts.append(f"final {'max ' if lay['kind'] == 'network' else ''}d {float(d[-1]):.3g}")
    parts.append("ok" if result.success else f"FAILED: {result.message}")
    return f"{type(result).__name__}({', '.join(parts)})"
