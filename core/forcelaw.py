"""User force laws ``h(q, u, tau, t, p)`` (docs/design.md §2.8, docs/user-model.md).

A :class:`ForceLaw` is a Python function written for numba's nopython mode, with its
parameters declared once (:class:`fmu_sync.core.declaration.Param`: name, default, unit,
min/max, description) and, optionally, the linear part the θ-scheme treats implicitly and
the stiffness of the synchronization metric. A system takes it as
``MechanicalSystem(M=..., w=..., g0=..., e=..., force=law, params={...})``.

Compilation: the law is compiled once per process into its own copies of the loop templates
of :mod:`.moreau` and :mod:`.loop` (their ``TEMPLATES``) with its force (:mod:`.law_loops`) in place of
the built-in law's (:meth:`ForceLaw.kernels`), which call it from the compiled step; the
copies are cached on disk (numba ``cache=True``) under the law's :attr:`ForceLaw.key`: the
sha256 of what numba compiles of h (:mod:`.law_key`: its code and the globals it reads, the
functions it calls in any file included, recursively; a global of another kind: the whole
source file), h's name, the dimension and whether the law declares a linear part and a
forcing; the core's own stamp is added by the cache locator (core/_cache.py). So an edit of h
or of what it calls recompiles, an edit of the rest of the file (a parameter's default, the
model) does not. A law defined where no source file exists (a REPL) compiles every process
(no cache).

The built-in linear law is not a ForceLaw: systems without ``force=`` run the same templates
compiled with the built-in force (:func:`.moreau.force`, :func:`.loop.net_force`).
"""
from __future__ import annotations

import hashlib
import inspect
import re
import types as pytypes

import numpy as np

from . import law_loops, loop, moreau
from .coupling import METRIC_SOURCES  # noqa: F401 (re-exported: how a law's K_m was obtained)
from .errors import LawRefused
from .jit import NUMBA, njit
from .law_key import code_digest

if NUMBA:   # compiled mode; the code an FMU carries runs h as plain Python (core/jit.py)
    from numba import types
    from ._cache import LAW_KEY, depends_on_core, law_function

__all__ = ["ForceLaw", "force_law", "LawKernels", "METRIC_SOURCES"]


#: the signature every law is compiled for: h(q, u, tau, t, p) (None in plain Python)
LAW_SIGNATURE = None
if NUMBA:
    _ARR = types.Array(types.float64, 1, "C")
    LAW_SIGNATURE = (_ARR, _ARR, _ARR, types.float64, _ARR)

_KERNELS: dict = {}   # (law key (or id), trapezoid) -> LawKernels, one compilation per process


class LawKernels(pytypes.SimpleNamespace):
    """The law's compiled loops: ``integrate`` (:func:`.moreau.integrate_with` or, n = 1,
    ``integrate1_with``), ``advance`` (:func:`.moreau.advance_with`), ``advance_in`` (the FMU
    stepper's), ``network`` (:func:`.loop.integrate_network`) and its ``force``, ``force1``."""


def _source_file(fn):
    try:
        path = inspect.getsourcefile(fn)
    except TypeError:
        return None
    if path is None:
        return None
    try:
        with open(path, "rb") as f:
            return path, f.read()
    except OSError:
        return None


class ForceLaw:
    """A force law ``h(q, u, tau, t, p) -> (n,) array`` (or a float for n = 1).

    Parameters
    ----------
    h : function
        Written for numba nopython mode (a plain function, or an ``@njit`` one); q, u, tau:
        float64 (n,) arrays, t: float, p: the float64 parameter array in the order of
        ``params``. It is the whole generalized force (linear part included).
    params : sequence of Param
        The parameters (``fmu_sync.core.declaration.Param``: name, default, unit, min, max,
        description), declared once; ``p[i]`` is ``params[i]``.
    n : int
        Degrees of freedom.
    name : str
        Used in every message (default: ``h.__name__``).
    linear : callable ``linear(p) -> (K_L, C_L)``, optional
        A linear part ``-K_L q - C_L u`` contained in h: the θ-scheme treats it implicitly
        (S = M + θ dt C_L + θ² dt² K_L) and the rest explicitly; it is also the default
        stiffness of the metric.
    stiffness : callable ``stiffness(p) -> K_m``, optional
        The stiffness of the synchronization metric (Q = K_m + 2 Kp, docs/design.md §2.8.2).
    forcing : callable ``forcing(p) -> [(F, Omega, phi), ...]``, optional
        Harmonic forcing ``sum_j F_j cos(Omega_j t + phi_j)`` (``F_j``: n numbers, or one for
        n = 1) *not* written in h: the loops add it to h at each step's force point, by the
        built-in law's phasor recurrence (``simulate(phasor=True)``, the default) or a cos per
        step, so a forced law costs what the built-in forced law costs (docs/design.md §2.8).
    """

    def __init__(self, h, params=(), n: int = 1, name: str | None = None, linear=None, stiffness=None,
                 forcing=None):
        py = getattr(h, "py_func", h)    # an @njit function: its Python function
        if not callable(py):
            raise TypeError(f"a force law needs a function h(q, u, tau, t, p), got {h!r}")
        self.name = str(name or getattr(py, "__name__", "law"))
        self.params = tuple(params)
        self.n = int(n)
        if self.n < 1:
            raise ValueError(f"force law {self.name!r}: n must be >= 1, got {n}")
        names = [prm.name for prm in self.params]
        shaped = [prm.name for prm in self.params if tuple(getattr(prm, "shape", ())) != ()]
        if shaped:
            raise ValueError(f"force law {self.name!r}: the parameters of h are scalars (p is a float array), "
                             f"got shaped parameters {shaped}")
        if len(set(names)) != len(names):
            raise ValueError(f"force law {self.name!r}: parameter names repeat: {names}")
        self.linear = linear
        self.stiffness = stiffness
        self.forcing = forcing
        self.py_func = py
        src = _source_file(py)
        self.source = src[0] if src else None
        if src:   # what numba compiles (core/law_key.py), else the whole file
            code = code_digest(py)
            hsh = hashlib.sha256(b"code:" + code if code is not None else b"file:" + src[1])
            hsh.update(f"{py.__qualname__}|{self.n}|{linear is not None}|{forcing is not None}".encode())
            self.key = hsh.hexdigest()
        else:
            self.key = None
        # inlined into the step (numba IR): no call with array arguments per step
        if self.source is not None and NUMBA:   # h's own cache is stamped with the core too (our flags live there)
            depends_on_core(self.source)
            law_function(py, self.key)          # and keyed by what it compiles (core/law_key.py)
        # error_model="numpy": 1/0 is inf (a non-finite force: refused at the start, a divergence
        # mid-run), never a ZeroDivisionError raised out of a compiled loop
        self.dispatcher = njit(cache=self.key is not None, inline="always", error_model="numpy")(py)
        self._returns = None
        self._u_linear = None

    @property
    def names(self) -> tuple:
        """The parameter names, in the order of ``p``."""
        return tuple(prm.name for prm in self.params)

    def __repr__(self):
        return f"ForceLaw({self.name!r}, n={self.n}, params={[p.name for p in self.params]})"

    # ------------------------------------------------------------------ parameters
    def values(self, values=None, **kw) -> np.ndarray:
        """The parameter array ``p`` from a mapping and/or keywords: defaults filled, each value
        checked against its declared range; an unknown name is refused (LawRefused naming it)."""
        given = dict(values or {}, **kw)
        known = {prm.name for prm in self.params}
        unknown = sorted(set(given) - known)
        if unknown:
            raise LawRefused(f"force law {self.name!r} has no parameter {unknown[0]!r}; "
                             f"its parameters: {sorted(known)}")
        p = np.empty(len(self.params))
        for i, prm in enumerate(self.params):   # the declaration's own check (Param.check)
            try:
                p[i] = prm.check(given.get(prm.name, prm.default), f"force law {self.name!r}")
            except ValueError as exc:
                raise LawRefused(str(exc)) from None
        return p

    def linear_part(self, p):
        """``(K_L, C_L)`` (n x n float arrays; zeros if the law declares none)."""
        n = self.n
        if self.linear is None:
            return np.zeros((n, n)), np.zeros((n, n))
        KL, CL = self.linear(p)
        return (np.array(KL, dtype=np.float64).reshape(n, n), np.array(CL, dtype=np.float64).reshape(n, n))

    def forcing_terms(self, p) -> tuple:
        """The declared harmonic forcing at parameters ``p``: ``((F, Omega, phi), ...)`` with ``F``
        a tuple of n floats (empty without ``forcing``); a malformed term is refused naming the law."""
        if self.forcing is None:
            return ()
        terms = []
        for j, term in enumerate(self.forcing(p)):
            try:
                F, Om, ph = term
                F = np.array(F, dtype=np.float64, ndmin=1).reshape(self.n)
                terms.append((tuple(float(x) for x in F), float(Om), float(ph)))
            except (TypeError, ValueError):
                raise LawRefused(f"force law {self.name!r}: forcing term {j} must be (F, Omega, phi) with F "
                                 f"{self.n} number(s), got {term!r}") from None
        return tuple(terms)

    @property
    def linear_in_u(self) -> bool:
        """Whether h is linear in u through its declared part alone: ``h(q, u2) - h(q, u1) = -C_L (u2 - u1)``
        (to 1e-10 relative) at 8 fixed pseudo-random points (q, u1, u2 in [-2, 2]^n, t in [0, 10], tau = 0)
        for the default parameters and for every parameter moved by 1 (or halfway into its range). Such a law
        runs the trapezoid as it stands (no second evaluation, :func:`.law_loops.heun`); a law that raises or
        returns non-finite values at a probe counts as nonlinear (the corrected step is right for both)."""
        if self._u_linear is None:
            self._u_linear = self._probe_linear_in_u()
        return self._u_linear

    def _probe_linear_in_u(self) -> bool:
        rng = np.random.default_rng(40)
        n = self.n
        try:
            moved = []
            for prm in self.params:
                v = float(prm.default) + 1.0
                if prm.max is not None and v > prm.max:
                    v = 0.5 * (float(prm.default) + prm.max)
                moved.append(v)
            for p in (self.values(), np.array(moved)):
                CL = self.linear_part(p)[1]
                for _ in range(8):
                    q, u1, u2 = (rng.uniform(-2.0, 2.0, n) for _ in range(3))
                    t = float(rng.uniform(0.0, 10.0))
                    h1 = self.evaluate(q, u1, np.zeros(n), t, p)
                    h2 = self.evaluate(q, u2, np.zeros(n), t, p)
                    d = (h2 - h1) + CL @ (u2 - u1)
                    scale = np.abs(h1) + np.abs(h2) + np.abs(CL) @ np.abs(u2 - u1) + 1e-300
                    if not np.all(np.abs(d) <= 1e-10 * scale):
                        return False
        except (LawRefused, ValueError, TypeError, FloatingPointError):
            return False
        return True

    def metric_stiffness(self, p):
        """``(K_m, source)``: the metric's stiffness (:data:`METRIC_SOURCES`, docs/design.md §2.8.2)."""
        n = self.n
        if self.stiffness is not None:
            return np.array(self.stiffness(p), dtype=np.float64).reshape(n, n), "declared"
        if self.linear is not None:
            return self.linear_part(p)[0], "linear"
        K = np.empty((n, n))
        z = np.zeros(n)
        for j in range(n):
            hq = 1e-6
            qp, qm = z.copy(), z.copy()
            qp[j], qm[j] = hq, -hq
            K[:, j] = -(self.evaluate(qp, z, z, 0.0, p) - self.evaluate(qm, z, z, 0.0, p)) / (2 * hq)
        return 0.5 * (K + K.T), "jacobian"

    # ------------------------------------------------------------------ compiling and checking
    def compile(self):
        """Compile h for :data:`LAW_SIGNATURE`; returns ``"array"`` or ``"scalar"`` (its
        return form). Raises :class:`LawRefused` naming the law if numba cannot compile it or it
        returns something else than an (n,) float array (or a float for n = 1)."""
        if self._returns is not None:
            return self._returns
        if not NUMBA:   # plain Python (an FMU's carried code): h runs as written, its result checked by check()
            self._returns = "plain"
            return self._returns
        try:
            self.dispatcher.compile(LAW_SIGNATURE)
        except Exception as exc:   # numba's typing/lowering errors have no common public base
            first = re.sub(r"\x1b\[[0-9;]*m", "", str(exc)).strip().splitlines()   # numba's colours
            raise LawRefused(f"force law {self.name!r} is not numba-compilable in nopython mode as "
                             f"h(q, u, tau, t, p) with float64 arrays q, u, tau, p and a float t: "
                             f"{type(exc).__name__}: {' '.join(first[:6])}") from None
        rt = self.dispatcher.overloads[LAW_SIGNATURE].signature.return_type
        if isinstance(rt, types.Array) and rt.ndim == 1 and isinstance(rt.dtype, types.Float):
            self._returns = "array"
        elif isinstance(rt, (types.Float, types.Integer)) and self.n == 1:
            self._returns = "scalar"
        else:
            raise LawRefused(f"force law {self.name!r} must return {self._allowed()}; numba types what it returns "
                             f"as {rt}{self._never_returns(rt)}")
        return self._returns

    def _allowed(self) -> str:
        """What h must return, in words."""
        return f"a float64 array of shape ({self.n},)" + (" or a float" if self.n == 1 else "") + f" (n = {self.n})"

    def _never_returns(self, rt) -> str:
        """For a return type ``none`` (every path raises, or h has no return): what calling h at rest
        (q = u = tau = 0, t = 0, the default parameters) does, in words."""
        if str(rt) != "none":
            return ""
        z = np.zeros(self.n)
        try:
            self.py_func(z, z.copy(), z.copy(), 0.0, np.array([prm.default for prm in self.params], dtype=float))
        except Exception as exc:
            return (f" (it never returns a value: called at q = u = tau = 0, t = 0 with the default parameters "
                    f"it raises {type(exc).__name__}: {exc})")
        return " (it never returns a value: add a return statement)"

    def evaluate(self, q, u, tau, t, p) -> np.ndarray:
        """h at one point, as an (n,) array (compiled; for checks and the metric)."""
        self.compile()
        args = [np.ascontiguousarray(x, dtype=np.float64).reshape(-1) for x in (q, u, tau)]
        try:
            r = self.dispatcher(*args, float(t), np.ascontiguousarray(p, dtype=np.float64))
        except Exception as exc:   # an exception the law raises itself (numba: raise ...)
            raise LawRefused(f"force law {self.name!r} raised {type(exc).__name__}: {exc} at q = "
                             f"{args[0].tolist()}, u = {args[1].tolist()}, t = {float(t):g}") from None
        r = np.array(r, dtype=np.float64, ndmin=1)
        if r.shape != (self.n,):
            raise LawRefused(f"force law {self.name!r} returned an array of shape {r.shape} at q = "
                             f"{args[0].tolist()}, u = {args[1].tolist()}, t = {float(t):g}; it must return "
                             f"{self._allowed()}")
        return r

    def check(self, p, q, u, tau=None, t: float = 0.0, where: str = "the start state"):
        """Before a run: compilable, the right shape, finite at ``(q, u, tau, t)``."""
        n = self.n
        tau = np.zeros(n) if tau is None else tau
        r = self.evaluate(q, u, tau, t, p)   # its shape checked there
        if not np.all(np.isfinite(r)):
            vals = ", ".join(f"{prm.name} = {v:g}" for prm, v in zip(self.params, p))
            raise LawRefused(f"force law {self.name!r} returned non-finite values {r.tolist()} at {where} "
                             f"q = {np.asarray(q).tolist()}, u = {np.asarray(u).tolist()}, t = {t:g} "
                             f"({vals})")

    def kernels(self, trapezoid: bool = False) -> LawKernels:
        """The law's loops: the built-in loops' templates (:data:`.moreau.TEMPLATES`) with the
        law's force (:mod:`.law_loops`), compiled once per process and cached on disk under
        :attr:`key` (lazily compiled on first call). ``trapezoid``: the copies of the default scheme,
        whose force takes the explicit part of h at the step's middle velocity
        (:func:`.law_loops.heun`: second order between impacts) when h is not :attr:`linear_in_u`; the
        other schemes' copies otherwise."""
        trapezoid = bool(trapezoid) and not self.linear_in_u   # linear in u: the trapezoid as it stands
        k = (self.key or id(self), trapezoid)
        if k in _KERNELS:
            return _KERNELS[k]
        kind = self.compile()
        cache = self.key is not None
        tag = f"{kind}_trapezoid" if trapezoid else kind

        def specialise(fn, g, name, inline):
            py = getattr(fn, "py_func", fn)
            f = pytypes.FunctionType(py.__code__, g, name, py.__defaults__, py.__closure__)
            f.__qualname__ = f"{name}_{tag}"
            f.__module__ = py.__module__
            g[name] = njit(cache=cache, inline=inline, error_model="numpy")(f)

        own = dict(vars(law_loops), law_h=self.dispatcher, HEUN=bool(trapezoid), **{LAW_KEY: self.key})
        for name, inline in law_loops.OWN.items():
            src = {"law_into": "_h_scalar" if kind == "scalar" else "_h_array",
                   "law_h1": "_h1_scalar" if kind == "scalar" else "_h1_array"}.get(name, name)
            specialise(getattr(law_loops, src), own, name, inline)
        loops = dict(vars(moreau), force=own["force"], force1=own["force1"], **{LAW_KEY: self.key})
        for name, inline in moreau.TEMPLATES.items():
            specialise(getattr(moreau, name), loops, name, inline)
        net = dict(vars(loop), net_force=own["net_force"], net_force1=own["net_force1"], HEUN=bool(trapezoid),
                   **{LAW_KEY: self.key})
        for name, inline in loop.TEMPLATES.items():   # n = 1: the n > 1 parts as stand-ins (law_loops.N1_STANDINS)
            fn = getattr(law_loops, law_loops.N1_STANDINS[name]) if self.n == 1 and name in law_loops.N1_STANDINS \
                else getattr(loop, name)
            specialise(fn, net, name, inline)
        ns = LawKernels(force=own["force"], force1=own["force1"],
                        integrate=loops["integrate1_with"] if self.n == 1 else loops["integrate_with"],
                        advance=loops["advance_with"], advance_in=loops["advance_in"],
                        network=net["integrate_network"])
        _KERNELS[k] = ns
        return ns


def force_law(params=(), n: int = 1, name: str | None = None, linear=None, stiffness=None, forcing=None):
    """Decorator: ``@force_law(params=(...), n=1) def h(q, u, tau, t, p): ...`` -> :class:`ForceLaw`."""
    def wrap(h):
        return ForceLaw(h, params=params, n=n, name=name, linear=linear, stiffness=stiffness, forcing=forcing)
    return wrap
