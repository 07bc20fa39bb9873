"""Outputs that scale: the size of a run's record estimated before the run, a
budget for memory and disk, the output folder checked up front, and a record
writer that appends rows in chunks (CSV and/or NPZ, the user's choice).

* :func:`estimate` — rows, columns, memory and disk of a variant's record,
  computed from the scene's settings alone (nothing runs).
* :func:`check_budget` — refuses (:class:`OutputTooLarge`, a ValueError) a run
  whose record exceeds the disk budget, or whose whole record would exceed
  the memory budget and cannot be streamed to disk; the message gives the
  estimate and the smallest ``run.record_every`` that fits.
* :func:`check_out_dir` — an output path that is a file, or a folder that
  cannot be written, is refused before anything runs (:class:`OutputPathError`).
* :class:`RecordWriter` — ``append(columns)`` chunk after chunk; CSV rows are
  appended to the file, NPZ arrays go to raw temporary files and are packed
  into the ``.npz`` (one ``.npy`` member per array, zip64) at :meth:`close`,
  so memory stays at one chunk whatever the length of the run.
"""
from __future__ import annotations

import math
import os
import re
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .core.checks import record_rows, run_steps

__all__ = ["record_steps", "FORMATS", "DEFAULT_MAX_MEMORY", "DEFAULT_MAX_DISK", "OutputTooLarge", "OutputPathError",
           "Estimate", "parse_size", "format_size", "parse_formats", "estimate", "check_budget",
           "check_out_dir", "make_out_dir", "plain_os_error", "results_in", "run_grid", "RecordWriter", "pair_columns", "network_columns", "single_columns", "WRITE_ROWS"]

#: data files of a run: CSV (one row per record), NPZ (numpy arrays and the layout), NetCDF
#: (the result's xarray Dataset; needs the whole record in memory)
FORMATS = ("csv", "npz", "nc")
#: memory a run may use for its record unless the user raises it (``--max-memory``)
DEFAULT_MAX_MEMORY = 2 * 1024**3
#: disk a run may write unless the user raises it (``--max-disk``)
DEFAULT_MAX_DISK = 20 * 1024**3
#: rows per chunk when writing a record held in memory
WRITE_ROWS = 65536
#: bytes of one value in the CSV (at most 17 significant digits, sign, exponent and a separator)
CSV_BYTES = 25
#: a whole-record run holds the record about this many times (the core's arrays,
#: the arrays derived for metrics and plots)
WHOLE_FACTOR = 3.0


class OutputTooLarge(ValueError):
    """The run's record would exceed the memory or disk budget."""


class OutputPathError(ValueError):
    """The output folder cannot be used (it is a file, or not writable)."""


_UNITS = {"": 1, "b": 1, "k": 1024, "kb": 1024, "kib": 1024, "m": 1024**2, "mb": 1024**2, "mib": 1024**2,
          "g": 1024**3, "gb": 1024**3, "gib": 1024**3, "t": 1024**4, "tb": 1024**4, "tib": 1024**4}


def parse_size(text) -> int:
    """``"2GB"``, ``"500 MiB"``, ``"1e9"`` (bytes) -> bytes (units are binary: 1 GB = 1024**3 B)."""
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        value, unit = float(text), ""
    else:
        m = re.fullmatch(r"\s*([0-9.]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*", str(text))
        if not m or m.group(2).lower() not in _UNITS:
            raise ValueError(f"a size must be a number with an optional unit (B, KB, MB, GB, TB), got {text!r}")
        value, unit = float(m.group(1)), m.group(2).lower()
    size = value * _UNITS[unit]
    if not (math.isfinite(size) and size > 0):
        raise ValueError(f"a size must be positive and finite, got {text!r}")
    return int(size)


def format_size(n: float) -> str:
    for unit, f in (("TiB", 1024**4), ("GiB", 1024**3), ("MiB", 1024**2), ("KiB", 1024)):
        if n >= f:
            return f"{n / f:.3g} {unit}"
    return f"{int(n)} B"


def parse_formats(value) -> tuple[str, ...]:
    """``"npz,csv"`` or ``["npz"]`` -> ``("npz", "csv")``; ``"none"`` or ``[]`` -> ``()``."""
    items = value.split(",") if isinstance(value, str) else list(value)
    out = []
    for f in items:
        f = str(f).strip().lower()
        if f in ("", "none"):
            continue
        if f not in FORMATS:
            raise ValueError(f"unknown data format {f!r}; allowed: {', '.join(FORMATS)} (comma separated), "
                             "or none")
        if f not in out:
            out.append(f)
    return tuple(out)


# ---------------------------------------------------------------- columns
def pair_columns(n: int, distance: bool) -> list[tuple[str, int]]:
    """``(name, width)`` of a pair record's arrays, in CSV order."""
    cols = [("t", 1)] + [(k, n) for k in ("q1", "u1", "q2", "u2", "tau1", "tau2")]
    if distance:
        cols += [("d", 1), ("V", 1), ("euclidean", 1), ("branch", 1)]
    return cols


def network_columns(N: int, n: int, E: int, distance) -> list[tuple[str, int]]:
    """A network record: states and forces of the N nodes (node-major), d, euclidean and
    branch of the E edges, V and the largest pairwise distance d_max. ``distance="euclidean"``
    (systems without a common impact geometry, docs/design.md §2.5.3): the edges' Euclidean error
    alone, instead of d, branch, V and d_max."""
    cols = [("t", 1), ("q", N * n), ("u", N * n), ("tau", N * n)]
    if distance == "euclidean":
        cols += [("euclidean", E)]
    elif distance:
        cols += [("d", E), ("euclidean", E), ("branch", E), ("V", 1), ("d_max", 1)]
    return cols


def single_columns(n: int) -> list[tuple[str, int]]:
    return [("t", 1), ("q", n), ("u", n), ("percussion", 1)]


def csv_names(columns, layout: dict | None = None) -> list[str]:
    """CSV header of a record: with its ``layout`` (:func:`fmu_sync.core.views.layout`) the names
    with units and edges by their nodes (:func:`fmu_sync.core.views.column_headers`)."""
    if layout is not None:
        from .core.views import column_headers
        return [h for name, width in columns for h in column_headers(name, width, layout)]
    names = []
    for name, width in columns:
        if width == 1:
            names.append(name)
        else:
            names += [f"{name}[{j + 1}]" for j in range(width)]
    return names


# ---------------------------------------------------------------- estimate
@dataclass(frozen=True)
class Estimate:
    """Size of one variant's record (before the run)."""

    name: str
    steps: int
    record_every: int
    rows: int
    values_per_row: int
    formats: tuple

    @property
    def record_bytes(self) -> float:
        """The record's arrays in memory (float64)."""
        return 8.0 * self.rows * self.values_per_row

    @property
    def memory(self) -> float:
        """Peak memory of a run that holds its whole record (estimate)."""
        return WHOLE_FACTOR * self.record_bytes

    @property
    def disk(self) -> float:
        """Bytes written for the chosen formats (CSV: 25 B per value; NPZ: 8 B per value, an upper bound)."""
        per = (CSV_BYTES if "csv" in self.formats else 0) + 8 * sum(f in self.formats for f in ("npz", "nc"))
        return float(self.rows * self.values_per_row * per)

    def describe(self) -> str:
        return (f"{self.steps:.4g} steps recorded every {self.record_every}: {self.rows:.4g} rows x "
                f"{self.values_per_row} values = {format_size(self.record_bytes)} in memory "
                f"(a run holding it all: about {format_size(self.memory)}), "
                f"{format_size(self.disk)} on disk as {'+'.join(self.formats) or 'no data files'}")


def run_grid(cfg) -> tuple[int, float, str]:
    """Steps of a variant's run (the last one shortened to land on run.t_end), its step and the step's key."""
    coupled = cfg.get("initial.x2") is not None or cfg.get("network.graph") is not None   # a pair or a network
    step, name = (cfg["run.H"], "run.H") if cfg["run.mode"] == "cosim" and coupled else (cfg["solver.dt"], "solver.dt")
    return run_steps(cfg["run.t_end"], step).steps, step, name


def record_steps(cfg) -> int:
    """``run.record_every`` in steps of the variant's run grid (:func:`run_grid`). The key counts
    steps of ``solver.dt`` in both modes, so one scene records at one interval, k dt, in the core
    and in co-simulation; a co-simulation records at communication points, every
    max(1, round(k dt / H)) steps of ``run.H`` (the nearest whole number of them, at least one)."""
    k = int(cfg["run.record_every"])
    _, step, name = run_grid(cfg)
    if name == "solver.dt":
        return k
    return max(1, round(k * cfg["solver.dt"] / step))


def estimate(variant, formats=("csv", "npz")) -> Estimate:
    """The record size of a :class:`~fmu_sync.scenes.schema.Variant` (nothing runs). A run to a
    tolerance (``run.tol``) records every accepted step, as short as ``solver.dt``: its worst case,
    t_end / solver.dt rows, is the estimate."""
    cfg = variant.cfg
    steps, _, name = run_grid(cfg)
    every = record_steps(cfg)
    if cfg["run.mode"] == "cosim" and variant.pair and cfg.get("run.tol") is not None:
        # tol chooses the steps, each at least solver.dt (its floor): the worst case, a step of solver.dt
        # all along, recorded every record_steps accepted steps (fmu_sync.cosim_adaptive)
        steps = max(steps, run_steps(cfg["run.t_end"], cfg["solver.dt"]).steps)
    n = variant.system.n
    if variant.is_network:
        A = variant.network.A
        E = int(np.count_nonzero(np.triu(A + A.T, 1)))
        cols = network_columns(variant.network.N, n, E, variant.has_distance)
    elif variant.pair:
        cols = pair_columns(n, variant.has_distance)
    else:
        cols = single_columns(n)
    return Estimate(variant.name, steps, every, record_rows(steps, every), sum(w for _, w in cols),
                    tuple(formats))


def check_budget(variant, formats, max_memory: float = DEFAULT_MAX_MEMORY,
                 max_disk: float = DEFAULT_MAX_DISK, can_stream: bool = False,
                 label: str = "") -> tuple[Estimate, bool]:
    """Refuse a record above the budget; returns ``(estimate, stream)``.

    ``stream``: the whole record exceeds ``max_memory`` but the run can write it
    in chunks while it runs (``can_stream``); its memory is then bounded by
    ``max_memory``. Refused (:class:`OutputTooLarge`) when the disk estimate
    exceeds ``max_disk`` or the memory estimate exceeds ``max_memory`` and the
    run cannot stream; the message names the estimate and the smallest
    ``run.record_every`` that fits.
    """
    est = estimate(variant, formats)
    over_disk = est.disk > max_disk
    over_mem = est.memory > max_memory
    if not over_disk and (not over_mem or can_stream):
        return est, over_mem
    ratio = max(est.disk / max_disk if over_disk else 0.0,
                est.memory / max_memory if over_mem and not can_stream else 0.0)
    every = max(est.record_every + 1, math.ceil(est.record_every * ratio * 1.05))
    if variant.mode == "cosim" and variant.cfg.get("run.tol") is not None:
        hint = ("a run to a tolerance records every accepted step, down to solver.dt (the worst case is the "
                "estimate): shorten run.t_end, raise solver.dt (the floor of its steps)")
    elif every > est.steps:
        hint = "shorten run.t_end or raise the step"
    else:   # the key counts solver.dt (record_steps)
        _, step, name = run_grid(variant.cfg)
        key = every if name == "solver.dt" else math.ceil(every * step / variant.cfg["solver.dt"] * (1 - 1e-9))
        hint = f"set run.record_every = {key} (or larger)"
    what = (f"disk {format_size(est.disk)} > budget {format_size(max_disk)} (--max-disk)" if over_disk else
            f"memory {format_size(est.memory)} > budget {format_size(max_memory)} (--max-memory; this "
            f"run cannot write its record in chunks)")
    who = f"{label}: " if label else ""
    raise OutputTooLarge(f"{who}refused before running: the record is too large: {what}. Estimate: "
                         f"{est.describe()}. {hint}, choose fewer formats (--format), or raise the budget.")


def check_out_dir(path) -> Path:
    """Refuse an output folder that is a file or cannot be written (before anything runs)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputPathError(f"the output path {path} is a file, not a folder; choose another -o")
    probe = path
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise OutputPathError(f"the output path {path} lies inside {probe}, which is a file; choose another -o")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputPathError(f"the output folder {path} is not writable ({probe} does not allow writing); "
                              "choose another -o")
    return path


def make_out_dir(path) -> bool:
    """Create the output folder (after every check passed); returns whether it was created.
    A folder that cannot be made is an :class:`OutputPathError` in plain words."""
    path = Path(path)
    created = not path.exists()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(f"cannot create the output folder {path}: {plain_os_error(exc)}; "
                              "choose another -o") from None
    return created


def plain_os_error(exc: OSError) -> str:
    """An OSError in words, without the ``[Errno N]`` prefix."""
    what = (exc.strerror or type(exc).__name__).lower()
    return f"{what} ({exc.filename})" if exc.filename else what


def results_in(path, title: str, overwrite: bool = False) -> list[Path]:
    """Refuse a folder holding the results (``summary.md``) of something other than ``title``
    (e.g. ``Scene `forced-pair```) unless ``overwrite``; returns the files of those old
    results (the summary and the files it lists) for the caller to remove once every
    check has passed."""
    path = Path(path)
    summary = path / "summary.md"
    if not summary.is_file():
        return []
    lines = summary.read_text(encoding="utf-8", errors="replace").splitlines()
    head = lines[0][2:].strip() if lines and lines[0].startswith("# ") else "unknown results"
    if head == title:
        return []
    if not overwrite:
        raise OutputPathError(f"the output folder {path} holds the results of {head} (summary.md): "
                              f"choose another -o, or --overwrite to replace them")
    old = [summary]
    for line in lines:
        m = re.match(r"- \[`([^`]+)`\]", line)
        if m and not Path(m.group(1)).is_absolute() and ".." not in Path(m.group(1)).parts:
            old.append(path / m.group(1))
    return old


# ---------------------------------------------------------------- writing
class RecordWriter:
    """Writes a record chunk by chunk: ``<stem>.csv`` and/or ``<stem>.npz``.

    ``columns``: ``[(name, width), ...]`` (:func:`pair_columns`); ``append``
    takes a dict ``name -> array`` of equal row counts. ``layout`` names the CSV
    columns (:func:`csv_names`); ``meta`` (a JSON-able dict: the layout, counts and
    settings) is stored in the ``.npz`` as the member ``meta`` (a JSON string), so
    :func:`fmu_sync.load` can rebuild the result. CSV numbers carry the digits they
    need (shortest repr), branches their names. ``close(partial=...)``
    finishes the files (a partial record is named ``<stem>.partial.csv`` /
    ``.partial.npz``) and returns their paths. ``abort()`` removes everything.
    """

    def __init__(self, stem, columns, formats=FORMATS, layout: dict | None = None, meta: dict | None = None):
        self.stem = Path(stem)
        self.columns = list(columns)
        self.formats = tuple(f for f in formats if f in ("csv", "npz"))
        self.meta = meta
        self.rows = 0
        self._csv = None
        self._raw = {}
        self._tmpdir = None
        self.stem.parent.mkdir(parents=True, exist_ok=True)
        if "csv" in self.formats:
            self._csv_path = self.stem.with_name(self.stem.name + ".csv.tmp")
            self._csv = open(self._csv_path, "w", encoding="ascii", newline="\n")
            names = csv_names(self.columns, layout)
            self._csv.write(",".join(names) + "\n")
            self._branch = tuple(i for i, h in enumerate(names) if h.startswith("branch"))
        if "npz" in self.formats:
            self._tmpdir = Path(tempfile.mkdtemp(prefix=".record-", dir=self.stem.parent))
            for name, _ in self.columns:
                self._raw[name] = open(self._tmpdir / f"{name}.raw", "wb")
        self._dtypes = {}
        self._tails = {}

    def append(self, data: dict) -> None:
        arrays = []
        rows = None
        for name, width in self.columns:
            a = np.asarray(data[name])
            self._tails.setdefault(name, a.shape[1:])
            rows = len(a) if rows is None else rows
            if len(a) != rows:
                raise ValueError(f"column {name} has {len(a)} rows, expected {rows}")
            arrays.append((name, a))
        if not rows:
            return
        if self._csv is not None:
            from .core.views import csv_lines
            block = np.column_stack([a.reshape(rows, -1).astype(np.float64, copy=False) for _, a in arrays])
            self._csv.writelines(csv_lines(block, self._branch))
        for name, a in arrays:
            if name in self._raw:
                self._dtypes.setdefault(name, a.dtype)
                self._raw[name].write(np.ascontiguousarray(a, dtype=self._dtypes[name]).tobytes())
        self.rows += rows

    def close(self, partial: bool = False) -> list[Path]:
        files = []
        tag = ".partial" if partial else ""
        if self._csv is not None:
            self._csv.close()
            path = self.stem.with_name(self.stem.name + tag + ".csv")
            os.replace(self._csv_path, path)
            files.append(path)
            self._csv = None
        if self._raw:
            path = self.stem.with_name(self.stem.name + tag + ".npz")
            tmp = path.with_name(path.name + ".tmp")
            with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
                if self.meta is not None:
                    import io
                    import json
                    buf = io.BytesIO()
                    np.lib.format.write_array(buf, np.array(json.dumps(self.meta)), allow_pickle=False)
                    zf.writestr("meta.npy", buf.getvalue())
                for name, width in self.columns:
                    fh = self._raw.pop(name)
                    fh.close()
                    dtype = np.dtype(self._dtypes.get(name, np.float64))
                    shape = (self.rows,) + tuple(self._tails.get(name, () if width == 1 else (width,)))
                    with zf.open(f"{name}.npy", "w", force_zip64=True) as out, \
                            open(fh.name, "rb") as src:
                        np.lib.format.write_array_header_1_0(
                            out, {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                                  "shape": shape})
                        while True:
                            buf = src.read(1 << 18)
                            if not buf:
                                break
                            out.write(buf)
            os.replace(tmp, path)
            files.append(path)
        self._cleanup()
        return files

    def abort(self) -> None:
        if self._csv is not None:
            self._csv.close()
            self._csv = None
            if self._csv_path.exists():
                self._csv_path.unlink()
        for fh in self._raw.values():
            fh.close()
        self._raw = {}
        self._cleanup()

    def _cleanup(self):
        if self._tmpdir is not None and self._tmpdir.exists():
            for f in self._tmpdir.iterdir():
                f.unlink()
            self._tmpdir.rmdir()
        self._tmpdir = None
