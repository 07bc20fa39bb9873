"""One csv writer for the reports' records (work-precision points, stability rows)."""
from __future__ import annotations

import csv

__all__ = ["write_records"]


def write_records(records, fields, path) -> None:
    """Write the header ``fields``, then one line ``r.row()`` per record, to ``path``."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(fields)
        for r in records:
            w.writerow(r.row())
