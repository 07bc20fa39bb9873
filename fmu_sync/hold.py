"""The master's input hold over a communication step (docs/design.md §2.6, §4.4).

``"zoh"``: each slave's input is held over the step. ``"foh"`` (first-order
hold): each slave also gets the input's slope, extrapolated from the coupling
history, ``(tau_i(t_k) - tau_i(t_{k-1})) / (t_k - t_{k-1})`` (0 on the first
step), through ``fmi2SetRealInputDerivatives``; the FMU must declare
``canInterpolateInputs`` and must not use ``solver.scheme = exact`` (constant
tau). Second order in H away from impacts; its exchange stability range is
:func:`fmu_sync.core.exchange.hold_bound`.
"""
from __future__ import annotations

from .core.exchange import HOLDS

__all__ = ["HOLDS", "check_hold_name", "check_hold", "check_schemes"]


def check_hold_name(hold: str) -> str:
    """``hold``, or ValueError naming the holds."""
    if hold not in HOLDS:
        raise ValueError(f"hold must be {' or '.join(repr(h) for h in HOLDS)}, got {hold!r}")
    return hold


def check_hold(hold: str, md, fmu: str) -> str:
    """``hold``, or ValueError for an unknown hold or ``"foh"`` with an FMU that cannot interpolate inputs
    (the strategies' holds: :mod:`fmu_sync.strategies`)."""
    check_hold_name(hold)
    if hold == "foh" and not (md.coSimulation is not None and md.coSimulation.canInterpolateInputs):
        raise ValueError(f"hold='foh' needs an FMU that interpolates its inputs (canInterpolateInputs = true, "
                         f"fmi2SetRealInputDerivatives); {fmu} declares canInterpolateInputs = false: use "
                         f"hold='zoh'")
    return hold


def check_schemes(hold: str, schemes) -> None:
    """ValueError if ``"foh"`` meets an instance with ``solver.scheme = exact`` (names from the FMU)."""
    for i, scheme in enumerate(schemes):
        if hold == "foh" and scheme == "exact":
            raise ValueError(f"hold='foh': instance {i + 1} has solver.scheme = exact, which holds its input "
                             f"constant over a step (the exact solver needs a constant tau): use hold='zoh' "
                             f"with it, or the midpoint/theta scheme")
