"""2-DOF mechanical system slave (FMU model identifier ``MechanicalSystem2``).

    M q'' + C q' + K q = f0 + F cos(Omega t + phi) + tau,   g(q) = w^T q + g0 >= 0,

full (symmetric positive definite) M, full K and C, oblique wall w, Newton
restitution e. The distance of the master needs M, w, g0 and e: all readable
parameters. The interface and the conversion to the core's ``MechanicalSystem``
are the contract's (:data:`fmu_sync.fmus.contract.MODELS`). Defaults:
``scenes/two-dof.toml``, system 1.
"""
from __future__ import annotations

from .contract import MODELS
from .slave import MechanicalSlave

__all__ = ["MechanicalSystem2Slave"]


class MechanicalSystem2Slave(MechanicalSlave):
    """Slave of the 2-DOF system with an oblique wall (core: ``MechanicalSystem``)."""

    CONTRACT = MODELS["mechanical-system-2"]
    MODEL = CONTRACT.key
    MODEL_IDENTIFIER = CONTRACT.identifier
    MODULE_NAME = CONTRACT.module_name
    N = CONTRACT.n
    DESCRIPTION = CONTRACT.description
