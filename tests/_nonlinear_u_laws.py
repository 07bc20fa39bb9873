"""Two user force laws nonlinear in u without a declared linear part (tests/test_trapezoid_general.py):
quadratic drag with a harmonic forcing written in h, and a van der Pol oscillator; and an n = 2 law with
quadratic drag. In a file of their own, so that their compiled loops are cached on disk; ``drag_model``
declares the drag law's model, which test_trapezoid_general exports as a user's FMU: the FMU test's core
reference runs the loops the drag tests compile (one law key, issue 43 item 7)."""
import math

import numpy as np

from fmu_sync.core import ForceLaw, MechanicalSystem, Model, Param


def drag(q, u, tau, t, p):
    return -p[0] * q[0] - p[1] * u[0] * abs(u[0]) + tau[0] + 0.5 * math.cos(2.5 * t)


def vdp(q, u, tau, t, p):
    return -q[0] + p[0] * (1.0 - q[0] * q[0]) * u[0] + tau[0]


def drag2(q, u, tau, t, p):
    r = np.empty(2)
    r[0] = -2.0 * q[0] + q[1] - p[0] * u[0] * abs(u[0]) + tau[0]
    r[1] = q[0] - 2.0 * q[1] - p[0] * u[1] * abs(u[1]) + tau[1]
    return r


DRAG = ForceLaw(drag, params=(Param("k", 1.0, "N/m", 0.0, None, "stiffness"),
                              Param("cd", 0.3, "N.s2/m2", 0.0, None, "quadratic drag")))
VDP = ForceLaw(vdp, params=(Param("mu", 1.0, "1", 0.0, None, "van der Pol damping"),))
DRAG2 = ForceLaw(drag2, n=2, params=(Param("cd", 0.3, "N.s2/m2", 0.0, None, "quadratic drag"),))

drag_model = Model("drag", "an oscillator with quadratic drag and a harmonic forcing written in h",
                   params=(Param("g0", 10.0, "m", None, None, "wall offset"),
                           Param("e", 0.8, "1", 0.0, 1.0, "restitution")),
                   force=DRAG, geometry=("g0", "e"),
                   system=lambda p: MechanicalSystem(M=[[1.0]], w=[1.0], g0=p.g0, e=p.e, force=DRAG,
                                                     params=p.of(DRAG)))


def rhs_drag(q, u, t, p=(1.0, 0.3)):
    return -p[0] * q - p[1] * u * abs(u) + 0.5 * math.cos(2.5 * t)


def rhs_vdp(q, u, t, mu=1.0):
    return -q + mu * (1.0 - q * q) * u
