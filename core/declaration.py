"""The one model declaration (docs/design.md §2.1.1): parameters declared once, and the
:class:`Model` that maps their values to a :class:`~fmu_sync.core.MechanicalSystem`.

Like Reference-FMUs' ``config.h`` + ``model.c``: a :class:`Model` lists its parameters
(:class:`Param`: name, default, unit, min/max, description) and says how their values
make the system (M, w, g0, e and the force law). Everything else is generic and reads the
declaration: the core's checks (:meth:`Model.__call__`), the FMU's parameters
(``fmus/contract.py``) and the scenes' ``[system]`` keys (``fmu_sync/scenes/schema.py``).
Built-in models are declarations (core/model.py, core/examples.py); a user model is the
same kind of object, found by ``"path/to/model.py:name"`` (:func:`.registry.load_model`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = ["Param", "Model", "Values", "ModelError", "POSITIVE_MIN", "DEFAULT_UNITS"]

#: Smallest positive normal double: the inclusive ``min`` of a parameter that must be > 0
#: (m > 0, dt > 0), in the core's checks, the scenes and the FMU's ``min`` alike.
POSITIVE_MIN = 2.2250738585072014e-308

#: The units of q, u and tau of a model that declares none (SI, a translational coordinate): the
#: record's units (core/views.py), the FMU's variables (fmus/contract.py) and the plots read them
#: through :attr:`Model.units`.
DEFAULT_UNITS = {"q": "m", "u": "m/s", "tau": "N"}


#: the parameter shapes a declaration knows, in words
SHAPES = {(): "a finite real number", ("n",): "a list of n finite numbers",
          ("n", "n"): "an n x n matrix (list of rows) of finite numbers",
          ("terms",): "a list of harmonic terms (F, Omega, phi)"}


class ModelError(ValueError):
    """A model declaration, or values given to it, are invalid (the message names the
    model, the parameter, the offending value and what is allowed)."""


def _fmt(x) -> str:
    return f"{x:g}" if isinstance(x, float) else repr(x)


@dataclass(frozen=True)
class Param:
    """One declared parameter.

    ``shape``: ``()`` a real number; ``("n",)`` a vector and ``("n", "n")`` a matrix of the
    model's n degrees of freedom (``min``/``max`` bound every entry of a vector and the
    diagonal of a matrix); ``("terms",)`` a list of harmonic terms ``(F, Omega, phi)``.
    ``default`` None: required for a number; for a vector or a matrix, None means zeros
    unless ``required`` is set.
    """

    name: str
    default: object = None
    unit: str = "1"
    min: float | None = None
    max: float | None = None
    description: str = ""
    shape: tuple = ()
    required: bool = False

    def __post_init__(self):
        if self.default is None and self.shape == ():
            object.__setattr__(self, "required", True)
        if self.shape not in SHAPES:
            raise ModelError(f"parameter {self.name}: shape {self.shape!r} is not one of {', '.join(map(repr, SHAPES))}")

    def allowed(self) -> str:
        """The admissible values, in words (used in every error message)."""
        what = SHAPES[self.shape]
        lo = None if self.min is None else ("> 0" if self.min == POSITIVE_MIN else f">= {_fmt(self.min)}")
        hi = None if self.max is None else f"<= {_fmt(self.max)}"
        if lo and hi and self.min != POSITIVE_MIN:
            return f"{what} in [{_fmt(self.min)}, {_fmt(self.max)}]"
        bounds = " and ".join(b for b in (lo, hi) if b)
        where = {(): "", ("n",): " (every entry)", ("n", "n"): " (on the diagonal)", ("terms",): ""}[self.shape]
        return what + (f" {bounds}{where}" if bounds else "")

    def check(self, value, owner: str = ""):
        """The value as float / float64 array (terms: a tuple of triples); :class:`ModelError`
        naming ``owner``, the parameter, the value and :meth:`allowed` otherwise."""
        def bad(problem):
            who = f"{owner}: " if owner else ""
            return ModelError(f"{who}parameter {self.name} = {value!r} {problem}; allowed: {self.allowed()}")
        if self.shape == ("terms",):
            return value
        if self.shape == ():
            if isinstance(value, bool):
                raise bad("is a bool")
            try:
                x = float(value)
            except (TypeError, ValueError):
                raise bad("is not a real number") from None
            entries = np.array([x])
        else:
            try:
                x = np.array(value, dtype=np.float64, ndmin=len(self.shape))
            except (TypeError, ValueError):
                raise bad("is not numeric") from None
            if x.ndim != len(self.shape) or (x.ndim == 2 and x.shape[0] != x.shape[1]):
                raise bad(f"has shape {x.shape}")
            entries = np.diag(x) if x.ndim == 2 else x
        # a scalar by math: numpy's reduction of a scalar looks a name up afresh each call, and CPython's
        # type attribute cache keeps such names (each FMU instance grew the process: issue 35)
        if not (math.isfinite(x) if isinstance(x, float) else np.all(np.isfinite(x))):
            raise bad("is not finite")
        if self.min is not None and np.any(entries < self.min):
            raise bad("is below the declared minimum")
        if self.max is not None and np.any(entries > self.max):
            raise bad("is above the declared maximum")
        return x




class Values(dict):
    """Checked parameter values of a model: a dict that also reads as attributes (``p.m``)."""

    def of(self, law) -> dict:
        """The values of a force law's own parameters (``MechanicalSystem(force=law, params=p.of(law))``)."""
        return {prm.name: self[prm.name] for prm in law.params}

    def __getattr__(self, name):
        try:
            return self[name]
        except KeyError:
            raise AttributeError(f"no parameter {name!r} (the model declares {', '.join(self)})") from None


@dataclass(frozen=True)
class Model:
    """A model declaration: its parameters and how their values make the system.

    ``system(p)`` receives the checked :class:`Values` (every declared parameter, defaults
    filled) and returns the :class:`~fmu_sync.core.MechanicalSystem` (M, w, g0, e, force law).
    ``n`` is the number of degrees of freedom when fixed (None: it follows from a shaped
    parameter, e.g. the mass matrix). ``force``: the model's force law (a
    :class:`~fmu_sync.core.ForceLaw`); its declared parameters join the model's (a name the
    model declares itself, e.g. a mass both in M and in h, is the model's), and
    ``system`` passes them on as ``MechanicalSystem(..., force=law, params=p.of(law))``. ``geometry`` names the parameters that fix the impact
    geometry (M, w, g0, e): common to every node of a network, and all an importer of the
    FMU needs for the distance and the coupling. Calling the model checks the values and
    builds the system: ``IMPACT_OSCILLATOR(m=2, k=50, e=0.7, g0=0.05)``. ``q_unit``, ``u_unit``,
    ``tau_unit``: the units of q, u and tau (:attr:`units`; default m, m/s, N).
    """

    name: str
    description: str
    params: tuple
    system: Callable
    n: int | None = None
    geometry: tuple = ()
    values: Callable | None = None   #: optional inverse: system -> parameter values (built-ins)
    force: object = None             #: the force law (a ForceLaw; None: the built-in linear law)
    q_unit: str = DEFAULT_UNITS["q"]  #: unit of the coordinates q (and of the gap g(q)), e.g. "rad"
    u_unit: str | None = None        #: unit of the velocities u (None: q_unit + "/s")
    tau_unit: str = DEFAULT_UNITS["tau"]   #: unit of the generalized forces tau (e.g. "N.m" for an angle)

    def __post_init__(self):
        if self.force is not None:   # the law's parameters are the model's too, declared once (in the law)
            own = [p.name for p in self.params]
            object.__setattr__(self, "params", tuple(self.params) + tuple(
                p for p in self.force.params if p.name not in own))
            if self.n is None:
                object.__setattr__(self, "n", self.force.n)
        names = [p.name for p in self.params]
        dup = sorted({x for x in names if names.count(x) > 1})
        if dup:
            raise ModelError(f"model {self.name!r} declares the parameter(s) {', '.join(dup)} twice")
        unknown = [g for g in self.geometry if g not in names]
        if unknown:
            raise ModelError(f"model {self.name!r}: geometry names undeclared parameters {', '.join(unknown)}")
        if not callable(self.system):
            raise ModelError(f"model {self.name!r}: system must be a callable p -> MechanicalSystem, "
                             f"got {self.system!r}")

    @property
    def units(self) -> dict:
        """``{"q": ..., "u": ..., "tau": ...}``: the units this model declares (:data:`DEFAULT_UNITS`
        where it declares none), carried into its FMU, its results and their plots."""
        return {"q": self.q_unit, "u": self.u_unit or f"{self.q_unit}/s", "tau": self.tau_unit}

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise ModelError(f"model {self.name!r} has no parameter {name!r}; it declares "
                         f"{', '.join(p.name for p in self.params)}")

    @property
    def names(self) -> tuple:
        return tuple(p.name for p in self.params)

    def defaults(self) -> dict:
        """The declared defaults (required parameters left out)."""
        return {p.name: p.default for p in self.params if p.default is not None}

    def check(self, values: dict | None = None, **kw) -> Values:
        """Every parameter checked against its declaration, defaults filled; unknown or
        missing (required) names are a :class:`ModelError` naming them."""
        given = {**(values or {}), **kw}
        unknown = [k for k in given if k not in self.names]
        if unknown:
            raise ModelError(f"model {self.name!r} has no parameter {', '.join(map(str, unknown))}; "
                             f"it declares {', '.join(self.names)}")
        out = Values()
        for p in self.params:
            if p.name in given and given[p.name] is not None:
                out[p.name] = p.check(given[p.name], f"model {self.name!r}")
            elif p.required or (p.default is None and p.shape == ()):
                raise ModelError(f"model {self.name!r}: parameter {p.name} is required "
                                 f"({p.description or p.allowed()})")
            else:
                out[p.name] = p.default
        return out

    def __call__(self, values: dict | None = None, **kw):
        """The system of these parameter values (checked first)."""
        system = self.system(self.check(values, **kw))
        if self.n is not None and system.n != self.n:
            raise ModelError(f"model {self.name!r} declares n = {self.n} degrees of freedom, "
                             f"its system has n = {system.n}")
        return system
