"""1-DOF impact oscillator slave (FMU model identifier ``ImpactOscillator``).

    m q'' + c q' + k q = f0 + F cos(Omega t + phi) + tau,   q >= 0 (wall at q = 0),
    Newton restitution e at impacts.

The interface (names, defaults, bounds) and the conversion to the core's
``ImpactOscillator`` are the contract's (:data:`fmu_sync.fmus.contract.MODELS`).
Defaults: our own example (``scenes/forced-pair.toml``, system 1).
"""
from __future__ import annotations

from .contract import MODELS
from .slave import MechanicalSlave

__all__ = ["ImpactOscillatorSlave"]


class ImpactOscillatorSlave(MechanicalSlave):
    """Slave of the 1-DOF impact oscillator (core: ``ImpactOscillator``)."""

    CONTRACT = MODELS["impact-oscillator"]
    MODEL = CONTRACT.key
    MODEL_IDENTIFIER = CONTRACT.identifier
    MODULE_NAME = CONTRACT.module_name
    N = CONTRACT.n
    DESCRIPTION = CONTRACT.description
