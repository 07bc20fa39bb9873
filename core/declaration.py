"""Model declarations (i27-model owns this module; this is the subset the force laws use).

:class:`Param`: a parameter declared once (name, default, unit, range, description).
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Param"]


@dataclass(frozen=True)
class Param:
    """A parameter declared once: name, default, SI unit (FMI spelling), inclusive range, description."""

    name: str
    default: object
    unit: str = "1"
    min: float | None = None
    max: float | None = None
    description: str = ""
    shape: tuple = ()
