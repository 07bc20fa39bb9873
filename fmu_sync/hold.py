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

__all__ = ["HOLDS", "check_hold", "check_schemes", "check_implicit", "rollback_strategy", "check_rollback"]


def check_hold(hold: str, md, fmu: str) -> str:
    """``hold``, or ValueError for an unknown hold or ``"foh"`` with an FMU that cannot interpolate inputs."""
    if hold not in HOLDS:
        raise ValueError(f"hold must be {' or '.join(repr(h) for h in HOLDS)}, got {hold!r}")
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


def check_implicit(exchange: str, method: str, event_aware: bool) -> None:
    """ValueError if ``exchange="implicit"`` meets Gauss–Seidel or the event-aware retake."""
    if exchange != "implicit":
        return
    if method != "jacobi" or event_aware:
        raise ValueError(f"exchange='implicit' iterates every step to its end states, so it takes "
                         f"method='jacobi' (its predictor) and no event_aware retake; got method={method!r}, "
                         f"event_aware={event_aware!r}")


def rollback_strategy(exchange: str, event_aware: bool, tol=None) -> str | None:
    """The strategy of a run that sets the FMUs back to a saved state (None: none does): the
    tolerance controller (rejected steps), the implicit exchange (every iterate) and the
    event-aware retake (a step with an impact)."""
    if tol is not None:
        return "tol"
    if exchange == "implicit":
        return "exchange='implicit'"
    return "event_aware=True" if event_aware else None


def check_rollback(strategy: str | None, md, fmu: str) -> None:
    """The one check of the capability every state-restoring strategy needs: ValueError, before
    any instance exists, if ``strategy`` sets FMU states back and the FMU declares
    ``canGetAndSetFMUstate = false`` (the binary's functions are checked when it is loaded)."""
    if strategy and not (md.coSimulation is not None and md.coSimulation.canGetAndSetFMUstate):
        raise ValueError(f"{strategy} sets the FMUs back to a saved state with fmi2GetFMUstate/fmi2SetFMUstate; "
                         f"{fmu} declares canGetAndSetFMUstate = false: run it without {strategy} (the explicit "
                         f"exchange at a fixed H)")
