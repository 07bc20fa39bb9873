"""1-DOF impact oscillator slave (FMU model identifier ``ImpactOscillator``).

    m q'' + c q' + k q = f0 + F cos(Omega t + phi) + tau,   q >= 0 (wall at q = 0),
    Newton restitution e at impacts.

Defaults: the paper example (``scenes/paper-example.toml``, system 1).
"""
from __future__ import annotations

from ..core.model import ImpactOscillator

from ._xml import POSITIVE_MIN, SCHEME_TYPE, Var
from .slave import INPUT_BOUND, MechanicalSlave

__all__ = ["ImpactOscillatorSlave"]


def _param(name, unit, description, start, min=None, max=None):
    return Var(name, "Real", "parameter", "fixed", description, initial="exact", unit=unit,
               min=min, max=max, start=start)


def solver_variables(dt: float = 1e-3) -> list[Var]:
    """solver.dt, solver.scheme, solver.theta (shared by all slaves)."""
    return [
        _param("solver.dt", "s", "Internal Moreau step; the last internal step of a "
               "communication step is shortened to land on the communication point (> 0)",
               dt, min=POSITIVE_MIN),
        Var("solver.scheme", "Enumeration", "parameter", "fixed",
            "Time-stepping scheme of the internal steps (midpoint or theta)",
            initial="exact", start=1, declared_type=SCHEME_TYPE),
        _param("solver.theta", "1", "Theta of the Moreau-Jean scheme (used when solver.scheme = theta)",
               0.5, min=0.5, max=1.0),
    ]


def output_variables(n: int, depends: dict) -> list[Var]:
    """Outputs q, u, gap, impacts, percussion, energy (q[i], u[i] for n > 1)."""
    def idx(base, i):
        return base if n == 1 else f"{base}[{i + 1}]"

    out = []
    for i in range(n):
        out.append(Var(idx("q", i), "Real", "output", "continuous",
                       "Generalized position" + ("" if n == 1 else f" {i + 1}"), initial="calculated",
                       unit="m", initial_depends=tuple(depends[idx("q", i)])))
    for i in range(n):
        out.append(Var(idx("u", i), "Real", "output", "continuous",
                       "Generalized velocity" + ("" if n == 1 else f" {i + 1}")
                       + " (right limit after an impact)", initial="calculated",
                       unit="m/s", initial_depends=tuple(depends[idx("u", i)])))
    out += [
        Var("gap", "Real", "output", "continuous",
            "Gap g(q) = w^T q + g0 to the wall (>= 0 up to the scheme's O(dt) penetration)",
            initial="calculated", unit="m", initial_depends=tuple(depends["gap"])),
        Var("impacts", "Integer", "output", "discrete",
            "Number of internal steps with a positive contact percussion since the start",
            initial="calculated", min=0),
        Var("percussion", "Real", "output", "discrete",
            "Contact percussion (impulse) summed over the last communication step",
            initial="calculated", unit="N.s", min=0.0),
        Var("energy", "Real", "output", "continuous",
            "Mechanical energy 1/2 u^T M u + 1/2 q^T K q - f0^T q (without forcing and input)",
            initial="calculated", unit="J", initial_depends=tuple(depends["energy"])),
    ]
    return out


class ImpactOscillatorSlave(MechanicalSlave):
    """Slave of the 1-DOF impact oscillator (core: ``ImpactOscillator``)."""

    MODEL = "impact-oscillator"
    MODEL_IDENTIFIER = "ImpactOscillator"
    N = 1
    DESCRIPTION = ("1-DOF impact oscillator m q'' + c q' + k q = f0 + F cos(Omega t + phi) + tau, "
                   "q >= 0, Newton restitution e; Moreau time-stepping (fmu-sync core)")

    @classmethod
    def declare(cls) -> list[Var]:
        inputs = [Var("tau", "Real", "input", "continuous", "Control force (held over each communication step)",
                      unit="N", start=0.0, min=-INPUT_BOUND, max=INPUT_BOUND)]
        outputs = output_variables(1, {
            "q": ["q_start"], "u": ["u_start"], "gap": ["q_start"],
            "energy": ["m", "k", "f0", "q_start", "u_start"],
        })
        params = [
            _param("m", "kg", "Mass (> 0)", 1.0, min=POSITIVE_MIN),
            _param("k", "N/m", "Spring stiffness", 1.0, min=0.0),
            _param("c", "N.s/m", "Viscous damping", 0.0, min=0.0),
            _param("f0", "N", "Constant force", 0.2),
            _param("F", "N", "Amplitude of the harmonic force F cos(Omega t + phi)", 0.5),
            _param("Omega", "rad/s", "Angular frequency of the harmonic force", 2.5, min=0.0),
            _param("phi", "rad", "Phase of the harmonic force", 0.0),
            _param("e", "1", "Newton restitution coefficient at the wall", 0.9, min=0.0, max=1.0),
            _param("q_start", "m", "Initial position (the wall is q = 0: q_start >= 0)", 1.0, min=0.0),
            _param("u_start", "m/s", "Initial velocity", 0.0),
        ]
        return inputs + outputs + params + solver_variables()

    @classmethod
    def build_system(cls, p: dict):
        return ImpactOscillator(m=p["m"], k=p["k"], c=p["c"], f0=p["f0"], F=p["F"],
                                Omega=p["Omega"], e=p["e"], phi=p["phi"])

    @classmethod
    def start_state(cls, p: dict):
        return [p["q_start"]], [p["u_start"]]
