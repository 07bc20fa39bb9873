"""The built-in scenes' numbers for the tests, read from the TOML files (the only
place a built-in scene is defined), never retyped."""
from fmu_sync import load_scene

_SYSTEM_KEYS = ("m", "k", "c", "f0", "F", "Omega", "e")


def oscillator_params(scene: str, variant: str | None = None) -> dict:
    """ImpactOscillator keyword arguments of a built-in 1-DOF scene."""
    s = load_scene(scene)
    v = s.variant(variant) if variant else s.variants[0]
    return {k: v.cfg[f"system.{k}"] for k in _SYSTEM_KEYS}


_FP = load_scene("forced-pair").variant("switching")
#: the forced-pair scene (our own parameters, not the paper's): system, states, gains
FORCED_PAIR = oscillator_params("forced-pair", "switching")
FORCED_X1, FORCED_X2 = _FP.x1, _FP.x2
FORCED_GAINS = dict(Kp=_FP.Kp, Kd=_FP.Kd)
