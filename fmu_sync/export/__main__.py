"""``python -m fmu_sync.export``: :func:`fmu_sync.export.main_export`."""
import sys

from .cli import main_export

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main_export())
