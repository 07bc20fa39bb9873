"""Built-in nonlinear examples (docs/user-model.md): each a :class:`ForceLaw` and a system.

* :func:`Pendulum` — an impacting pendulum, ``m l² q'' = -m g l sin q - c q' + tau`` with a
  wall at the angle ``q_w`` (``g(q) = q_w - q >= 0``, the pendulum swings into it from below);
* :func:`DuffingOscillator` — a hardening spring against a wall with harmonic forcing,
  ``m q'' = -k q - k3 q³ - c q' + F cos(Omega t + phi) + tau``, wall at ``q = -g0``
  (``g(q) = q + g0 >= 0``, as :func:`ImpactOscillator`).

Both laws return a float (n = 1: the fast scalar path), declare their linear part (the
θ-scheme treats it implicitly) and the stiffness of their metric (docs/design.md §2.8.2); the
Duffing law declares its harmonic forcing (``forcing=``: the loops add it by the built-in
law's phasor recurrence, so the forced law costs what the built-in forced law costs).
They are ordinary user laws: a user file written the same way behaves the same.
"""
from __future__ import annotations

import math

from .declaration import POSITIVE_MIN, Model, Param
from .forcelaw import ForceLaw
from .model import MechanicalSystem

__all__ = ["pendulum_law", "duffing_law", "Pendulum", "DuffingOscillator", "PENDULUM", "DUFFING"]


def pendulum(q, u, tau, t, p):
    """h = -m g l sin q - c u + tau."""
    m, g, l, c = p[0], p[1], p[2], p[3]
    return -m * g * l * math.sin(q[0]) - c * u[0] + tau[0]


pendulum_law = ForceLaw(
    pendulum, n=1, name="pendulum",
    params=(Param("m", 1.0, "kg", POSITIVE_MIN, None, "bob mass"),
            Param("g", 9.81, "m/s2", 0.0, None, "gravity"),
            Param("l", 1.0, "m", POSITIVE_MIN, None, "rod length"),
            Param("c", 0.0, "N.m.s/rad", 0.0, None, "viscous damping at the pivot")),
    linear=lambda p: ([[0.0]], [[p[3]]]),                  # the damping; gravity stays explicit
    stiffness=lambda p: [[p[0] * p[1] * p[2]]])            # -dh/dq at the bottom, q = 0


def duffing(q, u, tau, t, p):
    """h = -k q - k3 q^3 - c u + tau (+ the declared forcing F cos(Omega t + phi), added by the loops)."""
    k, k3, c = p[0], p[1], p[2]
    x = q[0]
    return -k * x - k3 * x * x * x - c * u[0] + tau[0]


duffing_law = ForceLaw(
    duffing, n=1, name="duffing",
    params=(Param("k", 1.0, "N/m", 0.0, None, "linear stiffness"),
            Param("k3", 1.0, "N/m3", 0.0, None, "cubic (hardening) stiffness"),
            Param("c", 0.0, "N.s/m", 0.0, None, "viscous damping"),
            Param("F", 0.0, "N", None, None, "forcing amplitude"),
            Param("Omega", 1.0, "rad/s", 0.0, None, "forcing angular frequency"),
            Param("phi", 0.0, "rad", None, None, "forcing phase")),
    linear=lambda p: ([[p[0]]], [[p[2]]]),                 # k and c implicit (theta), k3 q^3 explicit
    forcing=lambda p: ((p[3], p[4], p[5]),))               # F cos(Omega t + phi): the loops' phasor


def Pendulum(m: float = 1.0, l: float = 1.0, g: float = 9.81, c: float = 0.0, q_w: float = 0.2,
             e: float = 0.8) -> MechanicalSystem:
    """The impacting pendulum: inertia ``m l²`` about the pivot, wall at the angle ``q_w`` (rad)."""
    return MechanicalSystem(M=[[float(m) * float(l) ** 2]], w=[-1.0], g0=q_w, e=e, force=pendulum_law,
                            params=dict(m=m, g=g, l=l, c=c))


def DuffingOscillator(m: float = 1.0, k: float = 1.0, k3: float = 1.0, c: float = 0.0, F: float = 0.0,
                      Omega: float = 1.0, phi: float = 0.0, g0: float = 0.0, e: float = 0.8) -> MechanicalSystem:
    """The Duffing oscillator against a wall at ``q = -g0``."""
    return MechanicalSystem(M=[[m]], w=[1.0], g0=g0, e=e, force=duffing_law,
                            params=dict(k=k, k3=k3, c=c, F=F, Omega=Omega, phi=phi))


# ---------------------------------------------------------------- the declarations (docs/design.md §2.1.1)
# The same two systems as Model declarations: the scenes' `model = "pendulum"` / `"duffing"`, and
# the pattern of a user's model file (a Model with force=law; the law's parameters are its own).
_E = Param("e", 0.8, "1", 0.0, 1.0, "Newton restitution coefficient at the wall")

#: the impacting pendulum (:func:`Pendulum`) as a declaration
PENDULUM = Model(
    name="pendulum", description="impacting pendulum m l^2 q'' = -m g l sin q - c q' + tau, wall q <= q_w",
    params=(Param("q_w", 0.2, "rad", None, None, "wall angle: g(q) = q_w - q >= 0"), _E),
    force=pendulum_law, geometry=("m", "l", "q_w", "e"), q_unit="rad", tau_unit="N.m",
    system=lambda p: MechanicalSystem(M=[[p.m * p.l ** 2]], w=[-1.0], g0=p.q_w, e=p.e, force=pendulum_law,
                                      params=p.of(pendulum_law)))

#: the Duffing oscillator against a wall (:func:`DuffingOscillator`) as a declaration
DUFFING = Model(
    name="duffing", description="Duffing oscillator m q'' = -k q - k3 q^3 - c q' + F cos(Omega t + phi) + tau, "
                                "wall q + g0 >= 0",
    params=(Param("m", 1.0, "kg", 1e-12, None, "mass"),
            Param("g0", 0.0, "m", None, None, "wall offset: g(q) = q + g0 >= 0"), _E),
    force=duffing_law, geometry=("m", "g0", "e"),
    system=lambda p: MechanicalSystem(M=[[p.m]], w=[1.0], g0=p.g0, e=p.e, force=duffing_law,
                                      params=p.of(duffing_law)))
