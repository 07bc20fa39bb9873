"""A tiny dependency-free progress indicator on stderr.

Usable wherever a ``progress(fraction_done)`` callback is accepted::

    with Progress("forced-pair") as bar:
        simulate_pair(..., progress=bar)

* stderr is a terminal: one bar redrawn in place (at most ~10 times a second);
* otherwise (a pipe, a log file): a plain ``label: 40%`` line every 10 %;
* under ``CI=true`` nothing is written unless ``force=True`` (or
  ``FMU_SYNC_PROGRESS=1``); ``FMU_SYNC_PROGRESS=0`` silences it everywhere.
"""
from __future__ import annotations

import math
import os
import sys
import time

__all__ = ["Progress", "scaled", "caches_cold", "note"]


def _env_flag(name: str) -> bool | None:
    v = os.environ.get(name, "").strip().lower()
    if v in ("1", "true", "yes", "on"):
        return True
    if v in ("0", "false", "no", "off"):
        return False
    return None


class Progress:
    """Callable progress reporter: ``bar(fraction)`` with ``fraction`` in [0, 1]."""

    def __init__(self, label: str = "", stream=None, force: bool | None = None,
                 width: int = 28, min_interval: float = 0.1):
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        if force is None:
            force = _env_flag("FMU_SYNC_PROGRESS")
        if force is None:
            force = not _env_flag("CI")
        self.enabled = bool(force)
        try:
            self.tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):
            self.tty = False
        self.width = width
        self.min_interval = min_interval
        self._start = time.monotonic()
        self._last_draw = -math.inf
        self._last_decile = -1
        self._drawn = False

    def __call__(self, fraction: float) -> None:
        if not self.enabled:
            return
        try:
            f = float(fraction)
        except (TypeError, ValueError):
            return
        f = 0.0 if not math.isfinite(f) else min(max(f, 0.0), 1.0)
        if self.tty:
            filled = int(round(f * self.width))
            elapsed = time.monotonic() - self._start
            eta = f"  ETA {elapsed * (1 - f) / f:4.0f} s" if 0.02 < f < 1.0 else ""
            label = f"{self.label} " if self.label else ""
            text = f"{label}[{'#' * filled}{'.' * (self.width - filled)}] {100 * f:5.1f}%{eta}"
        else:
            label = f"{self.label}: " if self.label else ""
            text = f"{label}{10 * int(f * 10 + 1e-9)}%"
        self.show(f, text)

    def show(self, fraction: float, text: str) -> None:
        """Draw ``text`` for progress ``fraction``: on a terminal in place (at most every
        ``min_interval`` s, always at 1), otherwise one line per 10 % reached."""
        if not self.enabled:
            return
        if self.tty:
            now = time.monotonic()
            if fraction < 1.0 and now - self._last_draw < self.min_interval:
                return
            self._last_draw = now
            self.stream.write("\r" + text + "   ")
            self.stream.flush()
            self._drawn = True
        else:
            decile = int(fraction * 10 + 1e-9)
            if decile > self._last_decile:
                self._last_decile = decile
                self.stream.write(text + "\n")
                self.stream.flush()

    def close(self) -> None:
        """End the bar's line (terminal mode); further calls print nothing new."""
        if self.enabled and self.tty and self._drawn:
            self.stream.write("\n")
            self.stream.flush()
        self._drawn = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def note(text: str, stream=None) -> None:
    """One line ``text`` on stderr (``stream``), written when a :class:`Progress` would draw
    (not under ``CI=true`` nor ``FMU_SYNC_PROGRESS=0``): what a long silent step is doing."""
    bar = Progress(stream=stream)
    if bar.enabled:
        bar.stream.write(text + "\n")
        bar.stream.flush()


def scaled(progress, start: float, stop: float):
    """Map a sub-task's ``fraction`` in [0, 1] onto ``[start, stop]`` of ``progress``."""
    if progress is None:
        return None

    def sub(fraction: float) -> None:
        progress(start + (stop - start) * min(max(float(fraction), 0.0), 1.0))

    return sub


def caches_cold() -> bool:
    """True when numba has no valid on-disk cache of the core's pair kernel yet (a
    fresh install, or the core changed): the first run then compiles its kernels."""
    try:
        from .core.loop import integrate_network
        cache_file = integrate_network._cache._cache_file
        return not cache_file._load_index()
    except Exception:  # numba internals moved: say nothing rather than guess
        return False
