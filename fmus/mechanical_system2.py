"""2-DOF mechanical system slave (FMU model identifier ``MechanicalSystem2``).

    M q'' + C q' + K q = f0 + F cos(Omega t + phi) + tau,   g(q) = w^T q + g0 >= 0,

full (symmetric positive definite) M, full K and C, oblique wall w, Newton
restitution e. The distance of the master needs M, w, g0 and e: all readable
parameters. Defaults: ``scenes/two-dof.toml``, system 1.
"""
from __future__ import annotations

from ..core.model import MechanicalSystem

from ._xml import POSITIVE_MIN, Var
from .impact_oscillator import _param, output_variables, solver_variables
from .slave import INPUT_BOUND, MechanicalSlave

__all__ = ["MechanicalSystem2Slave"]

N = 2
_M = ((2.0, 0.5), (0.5, 1.0))
_K = ((3.0, -1.0), (-1.0, 2.0))
_C = ((0.02, 0.0), (0.0, 0.02))


def _matrix_params(sym, unit, what, values, diag_min):
    out = []
    for i in range(N):
        for j in range(N):
            out.append(_param(f"{sym}[{i + 1},{j + 1}]", unit, f"{what}, row {i + 1}, column {j + 1}",
                              values[i][j], min=diag_min if i == j else None))
    return out


def _vector_params(sym, unit, what, values, min=None):
    return [_param(f"{sym}[{i + 1}]", unit, f"{what}, component {i + 1}", values[i], min=min)
            for i in range(N)]


class MechanicalSystem2Slave(MechanicalSlave):
    """Slave of the 2-DOF system with an oblique wall (core: ``MechanicalSystem``)."""

    MODEL = "mechanical-system-2"
    MODEL_IDENTIFIER = "MechanicalSystem2"
    N = N
    DESCRIPTION = ("2-DOF mechanical system M q'' + C q' + K q = f0 + F cos(Omega t + phi) + tau "
                   "with the unilateral constraint w^T q + g0 >= 0 and Newton restitution e; "
                   "Moreau time-stepping (fmu-sync core)")

    @classmethod
    def declare(cls) -> list[Var]:
        M = [f"M[{i},{j}]" for i in (1, 2) for j in (1, 2)]
        K = [f"K[{i},{j}]" for i in (1, 2) for j in (1, 2)]
        f0 = ["f0[1]", "f0[2]"]
        qs = ["q_start[1]", "q_start[2]"]
        us = ["u_start[1]", "u_start[2]"]
        inputs = [Var(f"tau[{i + 1}]", "Real", "input", "continuous",
                      f"Control force on coordinate {i + 1} (B = I; held over each communication step)",
                      unit="N", start=0.0, min=-INPUT_BOUND, max=INPUT_BOUND) for i in range(N)]
        outputs = output_variables(N, {
            "q[1]": ["q_start[1]"], "q[2]": ["q_start[2]"],
            "u[1]": ["u_start[1]"], "u[2]": ["u_start[2]"],
            "gap": ["w[1]", "w[2]", "g0"] + qs,
            "energy": M + K + f0 + qs + us,
        })
        params = (
            _matrix_params("M", "kg", "Mass matrix (symmetric positive definite)", _M, POSITIVE_MIN)
            + _matrix_params("K", "N/m", "Stiffness matrix", _K, 0.0)
            + _matrix_params("C", "N.s/m", "Damping matrix", _C, 0.0)
            + _vector_params("f0", "N", "Constant force", (0.1, 0.2))
            + _vector_params("F", "N", "Amplitude of the harmonic force F cos(Omega t + phi)", (0.6, 0.0))
            + [_param("Omega", "rad/s", "Angular frequency of the harmonic force", 1.3, min=0.0),
               _param("phi", "rad", "Phase of the harmonic force", 0.0)]
            + _vector_params("w", "1", "Wall normal w in g(q) = w^T q + g0 (not zero)", (1.0, 0.5))
            + [_param("g0", "m", "Wall offset g0 in g(q) = w^T q + g0", 0.0),
               _param("e", "1", "Newton restitution coefficient at the wall", 0.7, min=0.0, max=1.0)]
            + _vector_params("q_start", "m", "Initial position (g(q_start) >= 0)", (0.6, 0.2))
            + _vector_params("u_start", "m/s", "Initial velocity", (0.0, 0.0))
        )
        return inputs + outputs + params + solver_variables()

    @classmethod
    def build_system(cls, p: dict):
        def mat(sym):
            return [[p[f"{sym}[{i + 1},{j + 1}]"] for j in range(N)] for i in range(N)]

        def vec(sym):
            return [p[f"{sym}[{i + 1}]"] for i in range(N)]

        F = vec("F")
        forcing = ((F, p["Omega"], p["phi"]),) if any(x != 0.0 for x in F) else ()
        return MechanicalSystem(M=mat("M"), K=mat("K"), C=mat("C"), f0=vec("f0"), w=vec("w"),
                                g0=p["g0"], e=p["e"], forcing=forcing)

    @classmethod
    def start_state(cls, p: dict):
        return ([p["q_start[1]"], p["q_start[2]"]], [p["u_start[1]"], p["u_start[2]"]])
