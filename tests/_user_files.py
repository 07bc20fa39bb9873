"""A user's model file, as a user would write it (tests only): the impacting pendulum of
docs/user-model.md, under the law and model names a test gives it."""

from pathlib import Path

#: the guide's own lines up to its ``law = ForceLaw(``: imports and h, so that h is the guide's code on the
#: guide's lines and every pendulum file of the tests shares the guide's compiled loops and FMU stepper
#: (core/law_key.py: the law's key is what numba compiles of h, not the file's other lines)
_GUIDE = (Path(__file__).resolve().parent.parent / "docs" / "user-model.md").read_text()
_HEAD = _GUIDE.split("```python\n", 1)[1].split("law = ForceLaw(", 1)[0]

_PENDULUM = _HEAD.replace("{", "{{").replace("}", "}}") + '''\
# a user's impacting pendulum: h = -m g l sin q - c u + tau, wall at q = q_w{doc_units}
law = ForceLaw(h, n=1, name="{law}",
               params=(Param("m", 1.0, "kg", 1e-9, None, "bob mass"),
                       Param("g", 9.81, "m/s2", 0.0, None, "gravity"),
                       Param("l", 0.5, "m", 1e-9, None, "rod length"),
                       Param("c", 0.05, "N.m.s/rad", 0.0, None, "damping at the pivot")),
               linear=lambda p: ([[0.0]], [[p[3]]]))

pendulum = Model("{model}", "a user's impacting pendulum",
                 params=(Param("q_w", 0.3, "rad", None, None, "wall angle"),
                         Param("e", 0.7, "1", 0.0, 1.0, "restitution")),
                 force=law, geometry=("m", "l", "q_w", "e"),{units}
                 system=lambda p: MechanicalSystem(M=[[p.m * p.l ** 2]], w=[-1.0], g0=p.q_w, e=p.e,
                                                   force=law, params=p.of(law)))
'''


def pendulum_file(law: str, model: str, units: bool = False) -> str:
    """The source of the pendulum file; ``units``: it declares q in rad and tau in N.m (else the
    default units, m and N)."""
    return _PENDULUM.format(law=law, model=model, doc_units="; q in rad" if units else "",
                            units=' q_unit="rad", tau_unit="N.m",' if units else "")


#: the pendulum (q in rad) of the user-file scene and SSP tests (tests/test_user_model_scenes.py,
#: tests/test_ssp_user_models.py); its h, the guide's, has the law key of every pendulum file here, and its law
#: the name and parameters of tests/test_fmu_user_model.py's: one FMU stepper for both (fmus/law_stepper.py)
SCENE_PENDULUM = pendulum_file("my_pendulum", "scene-pendulum", units=True)
