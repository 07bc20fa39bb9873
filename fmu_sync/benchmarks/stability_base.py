"""Shared pieces of the stability benchmarks: the :class:`Row` of a case and small helpers."""
from __future__ import annotations

import math
from dataclasses import dataclass


__all__ = ["G", "ZETA", "Row", "osc", "fmt3", "div_ok"]

G = 9.81


ZETA = 0.5 / math.sqrt(2.0)          # the forced pair: Kp = 1, Kd = 0.5 -> zeta of the relative mode


@dataclass
class Row:
    group: str
    case: str
    method: str
    setting: str
    outcome: str
    measured: str
    criterion: str
    passed: bool
    seconds: float = 0.0
    value: float = math.nan          # the headline number (for tests and the CSV)

    CSV_FIELDS = ("group", "case", "method", "setting", "outcome", "measured", "criterion", "result",
                  "seconds", "value")

    def row(self) -> list:
        return [self.group, self.case, self.method, self.setting, self.outcome, self.measured,
                self.criterion, "pass" if self.passed else "FAIL", f"{self.seconds:.3g}", f"{self.value:.6g}"]


def osc(**kw):
    from fmu_sync.core import ImpactOscillator
    return ImpactOscillator(**kw)


def fmt3(x):
    return f"{x:.3g}"


def div_ok(msg: str) -> bool:
    """A divergence message must name the step and omega_max*dt."""
    return "dt =" in msg and "omega_max*dt" in msg
