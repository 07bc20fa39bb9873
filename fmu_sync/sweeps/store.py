"""Sweep results on disk: finished chunks (for resuming) and the labelled Dataset.

Layout of an output folder ``DIR``:

* ``DIR/sweep.nc`` -- the finished sweep, an xarray Dataset in NetCDF-4
  (h5netcdf): one variable per metric, dimensions = the swept parameters (a
  grid) or ``run`` (random / Latin-hypercube samples, the parameters as
  coordinates); attributes: scene (name, file text, overrides, variant),
  sweep spec, versions, fingerprint.
* ``DIR/.partial/`` while the sweep runs: ``plan.json`` (its fingerprint) and
  one ``<chunk>.npz`` per finished chunk, written atomically. A restart with
  the same sweep and output skips those chunks; a finished ``sweep.nc`` with
  the same fingerprint is returned without running anything.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from ..core.batch import COL, STATUS_NAMES
from ..core.metrics import MAX_REL_ERR, MIN_DECADES, REASON_NAMES, RESOLVED, reason_text

__all__ = ["ChunkStore", "to_dataset", "write_dataset", "read_dataset", "RESULT_FILE", "VARIABLES"]

RESULT_FILE = "sweep.nc"

#: Dataset variables: name -> (column, dtype, units, long name).
VARIABLES = {
    "status": ("status", "int8", "", "0 ok, 1 diverged (stopped early), 2 refused before the first step"),
    "t_sync": ("t_sync", "f8", "s", "first sample time after which d stays below the threshold (inf: never)"),
    "decay_rate": ("decay_rate", "f8", "1/s", "decay rate of the envelope of d: median of its per-decade rates "
                   "(fmu_sync.core.metrics); meaningful only where rate_resolved"),
    "decay_rate_err": ("decay_rate_err", "f8", "1/s", "spread of the per-decade rates (uncertainty of decay_rate)"),
    "rate_code": ("rate_code", "int8", "", "verdict on decay_rate (fmu_sync.core.metrics.verdict)"),
    "rate_decades": ("rate_decades", "f8", "", "whole decades of d the decay window spans"),
    "t_fit": ("t_fit", "f8", "s", "time where the fitted envelope of d crosses the threshold"),
    "bound": ("bound", "f8", "", "ultimate bound: max d over the last 20 % of the run"),
    "d0": ("d0", "f8", "", "quotient distance d at t = 0"),
    "d_final": ("d_final", "f8", "", "d at the end of the run (or where it stopped)"),
    "d_max": ("d_max", "f8", "", "maximum of d over the samples"),
    "tau_max": ("tau_max", "f8", "N", "maximum |tau| of both systems over all steps"),
    "impacts1": ("impacts1", "f8", "", "steps with a positive percussion, system 1"),
    "impacts2": ("impacts2", "f8", "", "steps with a positive percussion, system 2"),
    "episodes1": ("episodes1", "f8", "", "contact episodes (runs of steps with percussion) of system 1; "
                  "NaN where not available (co-simulation)"),
    "episodes2": ("episodes2", "f8", "", "contact episodes of system 2"),
    "t_stop": ("t_stop", "f8", "s", "time reached (t_end unless the run failed)"),
    "steps": ("steps", "f8", "", "steps made"),
    "q1": ("q1", "f8", "m", "final position of system 1 (first coordinate)"),
    "u1": ("u1", "f8", "m/s", "final velocity of system 1 (first coordinate)"),
    "q2": ("q2", "f8", "m", "final position of system 2 (first coordinate)"),
    "u2": ("u2", "f8", "m/s", "final velocity of system 2 (first coordinate)"),
    "samples": ("samples", "f8", "", "samples of d used by the metrics"),
    "exchange_stable": ("exchange_stable", "f8", "", "1 if the coupling is stable at the step "
                        "(fmu_sync.core.exchange, the exchange of the run's scheme: held over dt by the midpoint "
                        "and theta, inside the step under the trapezoid); compiled runs run either way, others "
                        "are refused"),
    "measure": ("measure", "f8", "", "what d0, d_final, d_max, bound, t_sync and the decay rates measure: 0 the "
                "quotient distance d, 1 the Euclidean error ||x1 - x2|| of systems without one impact map "
                "(M, w, g0 or e differ; docs/design.md §2.5.3)"),
}


class ChunkStore:
    """Finished chunks of one sweep in ``DIR/.partial`` (or in memory without a folder)."""

    def __init__(self, out_dir, fingerprint: str, overwrite: bool = False):
        self.fingerprint = fingerprint
        self.mem: dict = {}
        self.dir = None
        if out_dir is None:
            return
        self.dir = Path(out_dir) / ".partial"
        plan = self.dir / "plan.json"
        if self.dir.exists():
            old = json.loads(plan.read_text()).get("fingerprint") if plan.exists() else None
            if old != fingerprint:
                if not overwrite:
                    raise FileExistsError(
                        f"{out_dir} holds the unfinished chunks of a different sweep (fingerprint "
                        f"{str(old)[:12]}, this one {fingerprint[:12]}): use another output folder or "
                        "overwrite=True (--overwrite) to discard them")
                shutil.rmtree(self.dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        plan.write_text(json.dumps({"fingerprint": fingerprint}))

    def done(self) -> set:
        if self.dir is None:
            return set(self.mem)
        return {p.stem for p in self.dir.glob("*.npz")}

    def save(self, cid: str, idx, rows, reasons) -> None:
        if self.dir is None:
            self.mem[cid] = (np.asarray(idx), np.asarray(rows), list(reasons))
            return
        tmp = self.dir / f"{cid}.tmp.npz"
        np.savez(tmp, idx=np.asarray(idx), rows=np.asarray(rows),
                 reasons=np.array(list(reasons), dtype=object).astype(str))
        os.replace(tmp, self.dir / f"{cid}.npz")

    def load(self, cid: str):
        if self.dir is None:
            return self.mem[cid]
        with np.load(self.dir / f"{cid}.npz", allow_pickle=False) as z:
            return z["idx"], z["rows"], [str(s) for s in z["reasons"]]

    def clear(self) -> None:
        if self.dir is not None and self.dir.exists():
            shutil.rmtree(self.dir)


def to_dataset(out: np.ndarray, reasons: list, keys: list, axes, runs: list, attrs: dict):
    """The labelled Dataset: dims = swept parameters (``axes`` given: a full grid, C order)
    or ``run`` (samples, parameters as coordinates)."""
    import xarray as xr

    R = out.shape[0]

    def labels(values):   # matrices or start states as coordinates: their text
        if any(isinstance(v, (list, tuple)) for v in values):
            return np.array([str(v) for v in values])
        return np.array(values)

    if axes is not None:
        shape = tuple(len(a) for a in axes)
        dims = tuple(keys)
        coords = {k: labels(a) for k, a in zip(keys, axes)}
    else:
        shape = (R,)
        dims = ("run",)
        coords = {"run": np.arange(R)}
        for k in keys:
            coords[k] = ("run", labels([r[k] for r in runs]))
    data = {}
    for name, (col, dtype, units, long) in VARIABLES.items():
        v = out[:, COL[col]]
        if dtype == "int8":
            v = np.where(np.isfinite(v), v, -1).astype(np.int8)
        data[name] = (dims, v.reshape(shape), {"units": units, "long_name": long} if units else
                      {"long_name": long})
    data["status"][2].update(flag_values=np.arange(len(STATUS_NAMES), dtype=np.int8),
                             flag_meanings=" ".join(STATUS_NAMES))
    data["rate_code"][2].update(flag_values=np.arange(len(REASON_NAMES), dtype=np.int8),
                                flag_meanings=" ".join(n.replace(" ", "_") for n in REASON_NAMES))
    ok = out[:, COL["status"]] == 0
    code = out[:, COL["rate_code"]]
    resolved = ok & (code == RESOLVED)
    data["rate_resolved"] = (dims, resolved.reshape(shape),
                             {"long_name": f"decay_rate means something: the run finished, its window spans at "
                                           f"least {MIN_DECADES} decades and the spread is at most "
                                           f"{MAX_REL_ERR:.0%} of it"})
    why = [("the run failed" if not o else reason_text(c, r, e, n)) if not rs else ""
           for o, rs, c, r, e, n in zip(ok, resolved, code, out[:, COL["decay_rate"]],
                                        out[:, COL["decay_rate_err"]], out[:, COL["rate_decades"]])]
    data["rate_reason"] = (dims, np.array(why, dtype=object).reshape(shape),
                           {"long_name": "why decay_rate means nothing ('' where rate_resolved)"})
    sync = ok & np.isfinite(out[:, COL["t_sync"]])
    data["synchronized"] = (dims, sync.reshape(shape),
                            {"long_name": "run finished and d stayed below the threshold from t_sync on"})
    data["reason"] = (dims, np.array([str(s) for s in reasons], dtype=object).reshape(shape),
                      {"long_name": "why the run failed or was refused ('' if it did not)"})
    return xr.Dataset(data, coords=coords, attrs=attrs)


def write_dataset(ds, path) -> Path:
    """NetCDF-4 via h5netcdf, atomically (``path`` appears complete or not at all)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    enc = {k: {"dtype": str} for k in ("reason", "rate_reason") if k in ds}
    ds.to_netcdf(tmp, engine="h5netcdf", encoding=enc)
    os.replace(tmp, path)
    return path


def read_dataset(path):
    """Load a sweep written by :func:`write_dataset` fully into memory."""
    import xarray as xr
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        return ds.load()
