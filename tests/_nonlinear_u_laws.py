"""Two user force laws nonlinear in u without a declared linear part (tests/test_trapezoid_general.py):
quadratic drag with a harmonic forcing written in h, and a van der Pol oscillator (one function); and an n = 2 law with
quadratic drag. In a file of their own, so that their compiled loops are cached on disk; ``drag_model``
declares the drag law's model, which test_trapezoid_general exports as a user's FMU: the FMU test's core
reference runs the loops the drag tests compile (one law key, issue 43 item 7)."""
import math

import numpy as np

from fmu_sync.core import ForceLaw, MechanicalSystem, Model, Param


def drag_vdp(q, u, tau, t, p):
    """k, cd, mu, F = p: -k q - cd u|u| + mu (1 - q^2) u + F cos 2.5t: the drag law (mu = 0) and the van der
    Pol oscillator (cd = F = 0) are this one function with other parameters, so one law key: their loops
    compile once for both (issue 43 item 7)."""
    return (-p[0] * q[0] - p[1] * u[0] * abs(u[0]) + p[2] * (1.0 - q[0] * q[0]) * u[0] + tau[0]
            + p[3] * math.cos(2.5 * t))


def drag2(q, u, tau, t, p):
    r = np.empty(2)
    r[0] = -2.0 * q[0] + q[1] - p[0] * u[0] * abs(u[0]) + tau[0]
    r[1] = q[0] - 2.0 * q[1] - p[0] * u[1] * abs(u[1]) + tau[1]
    return r


def _params(cd, mu, F):
    return (Param("k", 1.0, "N/m", 0.0, None, "stiffness"), Param("cd", cd, "N.s2/m2", 0.0, None, "quadratic drag"),
            Param("mu", mu, "N.s/m3", 0.0, None, "van der Pol damping"),
            Param("F", F, "N", None, None, "amplitude of the forcing at 2.5 rad/s"))


DRAG = ForceLaw(drag_vdp, name="drag", params=_params(0.3, 0.0, 0.5))
VDP = ForceLaw(drag_vdp, name="vdp", params=_params(0.0, 1.0, 0.0))
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
