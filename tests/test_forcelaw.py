"""User force laws h(q, u, tau, t, p) (core/forcelaw.py, core/law_loops.py, docs/user-model.md)."""
from __future__ import annotations

import importlib.util
import textwrap

import numpy as np
import pytest

from fmu_sync.core import MechanicalSystem, ring, simulate, simulate_network, simulate_pair
from fmu_sync.core.declaration import Param
from fmu_sync.core.errors import LawRefused
from fmu_sync.core.examples import DuffingOscillator, Pendulum, duffing_law
from fmu_sync.core.forcelaw import ForceLaw
from fmu_sync.core.moreau import advance

from _law_reference import reference

LINEAR_SRC = '''
from fmu_sync.core import ForceLaw, Param


def spring(q, u, tau, t, p):
    return -p[0] * q[0] - p[1] * u[0] + tau[0]


law = ForceLaw(spring, (Param("k", 50.0, "N/m", 0.0), Param("c", 0.1, "N.s/m", 0.0)), n=1,
               linear=lambda p: ([[p[0]]], [[p[1]]]))
'''

PENDULUM_SRC = '''
import math

import numpy as np

from fmu_sync.core import ForceLaw, MechanicalSystem, Param


def h(q, u, tau, t, p):
    m, g, l, c = p[0], p[1], p[2], p[3]
    out = np.empty(1)
    out[0] = -m * g * l * math.sin(q[0]) - c * u[0] + tau[0]
    return out


law = ForceLaw(h, name="my_pendulum", n=1,
               params=(Param("m", 1.0, "kg", 1e-9, None, "mass"), Param("g", 9.81, "m/s2", 0.0),
                       Param("l", 0.5, "m", 1e-9, 10.0, "length"), Param("c", 0.05, "N.m.s/rad", 0.0)))


def system(m=1.0, l=0.5, c=0.05, q_w=0.25, e=0.8):
    return MechanicalSystem(M=[[m * l * l]], w=[-1.0], g0=q_w, e=e, force=law, params=dict(m=m, l=l, c=c))
'''


def load(tmp_path, name, src):
    path = tmp_path / f"{name}.py"
    path.write_text(textwrap.dedent(src))
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


# ------------------------------------------------------------------ the linear law as a user law
@pytest.mark.slow   # compiles the built-in and a user law's loops (cached afterwards)
@pytest.mark.parametrize("scheme", ["midpoint", "theta"])
def test_linear_user_law_is_the_builtin_step(tmp_path, scheme):
    """h = -k q - c u + tau written by the user runs the very arithmetic of the built-in law
    (with its linear part declared, the θ-scheme's S is the built-in one): equal to round-off."""
    law = load(tmp_path, "spring", LINEAR_SRC).law
    lin = MechanicalSystem(M=[[2.0]], K=[[50.0]], C=[[0.1]], f0=[0.0], w=[1.0], g0=0.05, e=0.7)
    usr = MechanicalSystem(M=[[2.0]], w=[1.0], g0=0.05, e=0.7, force=law)
    a = simulate(lin, (0.2, -1.0), 3.0, 1e-3, scheme=scheme)
    b = simulate(usr, (0.2, -1.0), 3.0, 1e-3, scheme=scheme)
    assert b.impacts > 3 and b.impacts == a.impacts
    np.testing.assert_allclose(b.q, a.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.u, a.u, rtol=0, atol=1e-11)
    assert usr.metric_source == "linear" and np.array_equal(usr.K, [[50.0]])


# ------------------------------------------------------------------ the built-in examples vs DOP853
CASES = {
    "pendulum": (lambda: Pendulum(c=0.1, q_w=0.3, e=0.8), (-1.0, 0.0)),
    "duffing": (lambda: DuffingOscillator(k=1.0, k3=0.5, c=0.05, F=0.5, Omega=1.2, g0=0.5, e=0.7), (0.0, 0.0)),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("scheme", ["midpoint", "theta"])
def test_examples_against_event_restarting_dop853(case, scheme):
    """First order in dt against an event-restarting DOP853 integration of the same law over
    10 s with impacts; error <= 1e-3 at dt = 1e-4."""
    make, x0 = CASES[case]
    s = make()
    q_ref, u_ref, impacts = reference(s, x0, 10.0)
    assert impacts >= 2
    err = []
    for dt in (1e-3, 1e-4):
        r = simulate(s, x0, 10.0, dt, scheme=scheme, record_every=1000)
        err.append(max(abs(r.q[-1, 0] - q_ref), abs(r.u[-1, 0] - u_ref)))
    assert err[1] <= 1e-3, err
    assert err[0] / err[1] > 5.0, err   # first order (10x smaller dt: ~10x smaller error)


@pytest.mark.slow   # compiles a law's coupled loop (cached afterwards)
@pytest.mark.parametrize("case", sorted(CASES))
def test_examples_synchronize_under_the_switching_law(case):
    make, x0 = CASES[case]
    s = make()
    r = simulate_pair(s, x0, (x0[0] + 0.1, 0.5), 20.0, 1e-3, coupling="switching", Kp=5.0, Kd=2.0,
                      record_every=10)
    assert r.impacts1 > 0 and r.impacts2 > 0
    assert r.d[-1] < 1e-6 * r.d[0]
    assert r.metric == "linearized" and r.info["lyapunov"] is False
    assert "linearized" in r.info["metric_note"]


def test_metric_growth_bound_on_random_pendulum_pairs():
    """docs/design.md §2.8.2: on branch E (PD law, wall out of reach) V = 1/2 (dq Q dq + du M du)
    with Q = m g l + 2 Kp grows at most as exp(gamma t), gamma = m g l (1 - cos q_max) / sqrt(M Q)."""
    rng = np.random.default_rng(27)
    for _ in range(8):
        m, l, c = rng.uniform(0.5, 2.0), rng.uniform(0.3, 1.5), rng.uniform(0.0, 0.3)
        Kp, Kd = rng.uniform(0.1, 20.0), rng.uniform(0.0, 2.0)
        s = Pendulum(m=m, l=l, c=c, q_w=3.1, e=0.5)
        x1, x2 = (rng.uniform(-1.2, 1.2), rng.uniform(-1, 1)), (rng.uniform(-1.2, 1.2), rng.uniform(-1, 1))
        r = simulate_pair(s, x1, x2, 5.0, 1e-3, coupling="euclidean", Kp=Kp, Kd=Kd, record_every=10)
        assert r.impacts1 == 0 and r.impacts2 == 0
        Q, M = float(np.asarray(r.info["Q"])[0, 0]), m * l * l
        assert Q == pytest.approx(m * 9.81 * l + 2 * Kp)
        dq, du = r.q1[:, 0] - r.q2[:, 0], r.u1[:, 0] - r.u2[:, 0]
        V = 0.5 * (Q * dq ** 2 + M * du ** 2)
        q_max = max(np.max(np.abs(r.q1)), np.max(np.abs(r.q2)))
        gamma = m * 9.81 * l * (1 - np.cos(q_max)) / np.sqrt(M * Q)
        assert np.all(V <= V[0] * np.exp(gamma * r.t) * (1 + 1e-3) + 1e-12)
        assert r.metric == "linearized"


# ------------------------------------------------------------------ a user's own file
def test_user_pendulum_file_runs_and_synchronizes(tmp_path):
    mod = load(tmp_path, "my_pendulum", PENDULUM_SRC)
    s = mod.system()
    r = simulate(s, (-0.8, 0.0), 10.0, 1e-4, record_every=1000)
    q_ref, u_ref, impacts = reference(s, (-0.8, 0.0), 10.0)
    assert impacts >= 2
    assert abs(r.q[-1, 0] - q_ref) < 1e-3 and abs(r.u[-1, 0] - u_ref) < 1e-3
    pr = simulate_pair(s, (-0.8, 0.0), (0.0, 1.0), 15.0, 1e-3, coupling="switching", Kp=2.0, Kd=1.0,
                       record_every=10)
    assert pr.impacts1 > 0 and pr.d[-1] < 1e-6 * pr.d[0]
    assert s.metric_source == "jacobian"   # -dh/dq at 0 = m g l
    assert s.K[0, 0] == pytest.approx(1.0 * 9.81 * 0.5, rel=1e-6)


def test_network_of_user_laws():
    systems = [Pendulum(c=c, q_w=0.3) for c in (0.1, 0.1, 0.1)]
    r = simulate_network(systems, [(-1.0, 0.0), (0.0, 1.0), (0.2, -1.0)], ring(3), 20.0, 1e-3, Kp=5.0,
                         Kd=2.0, record_every=10)
    assert r.d_max[-1] < 1e-6 * r.d_max[0]
    with pytest.raises(ValueError, match="share one force law"):
        simulate_pair((Pendulum(q_w=0.2), MechanicalSystem(M=[[1.0]], w=[-1.0], g0=0.2, e=0.8, force=duffing_law)),
                      (0.0, 0.0), (0.0, 0.0), 1.0, 1e-3, coupling="switching", Kp=1.0)


def test_the_communication_step_is_the_simulate_step():
    """law.kernels().advance (the FMU stepper's and master's step) over H = 10 dt equals simulate."""
    s = Pendulum(c=0.1, q_w=0.3)
    r = simulate(s, (-1.0, 0.0), 2.0, 1e-3, record_every=100)
    q, u = np.array([-1.0]), np.array([0.0])
    adv = s.force.kernels().advance
    for k in range(20):
        status, _, _ = adv(s.arrays(), s.p, q, u, k * 0.1, 0.1, 1e-3, np.zeros(1), 3, 0.5)   # 3: the default
        assert status == 0
    np.testing.assert_allclose([q[0], u[0]], [r.q[-1, 0], r.u[-1, 0]], atol=1e-9)


def test_theta_treats_the_declared_linear_part_implicitly():
    """A stiff linear part: the explicit midpoint is refused, the θ-scheme runs it stably."""
    s = DuffingOscillator(k=1e8, k3=1.0, c=0.0, g0=0.01, e=0.5)
    with pytest.raises(ValueError, match="omega_max"):
        simulate(s, (0.005, 0.0), 0.1, 1e-3, scheme="midpoint")
    r = simulate(s, (0.005, 0.0), 0.1, 1e-3, scheme="theta", theta=1.0)
    assert np.all(np.isfinite(r.q)) and np.max(np.abs(r.q)) <= 0.006


# ------------------------------------------------------------------ errors before anything runs
def _law(fn, n=1, **kw):
    return ForceLaw(fn, (Param("a", 1.0, "1", 0.0, 2.0),), n=n, **kw)


def test_errors_name_the_law_and_the_offence():
    def typo(q, u, tau, t, p):
        return undefined_name * q[0]   # noqa: F821

    def wrong_shape(q, u, tau, t, p):
        return np.zeros(3)

    def blows_up(q, u, tau, t, p):
        return np.array([1.0 / q[0]])

    def text(q, u, tau, t, p):
        return "force"

    cases = [(typo, "not numba-compilable"), (wrong_shape, r"shape \(3,\)"), (blows_up, "non-finite"),
             (text, "must return")]
    for fn, msg in cases:
        with pytest.raises(LawRefused, match=msg) as exc:
            s = MechanicalSystem(M=[[1.0]], w=[1.0], g0=0.0, e=0.5, force=_law(fn, stiffness=lambda p: [[1.0]]))
            simulate(s, (0.0, 0.0), 0.1, 1e-3)
        assert repr(fn.__name__) in str(exc.value)
    with pytest.raises(LawRefused, match=r"force law 'wrong_shape': parameter a = 3.0 is above .* in \[0, 2\]"):
        MechanicalSystem(M=[[1.0]], w=[1.0], force=_law(wrong_shape), params={"a": 3.0})
    with pytest.raises(LawRefused, match="has no parameter 'b'"):
        MechanicalSystem(M=[[1.0]], w=[1.0], force=_law(wrong_shape), params={"b": 1.0})
    with pytest.raises(ValueError, match="leave out"):
        MechanicalSystem(M=[[1.0]], K=[[1.0]], w=[1.0], force=_law(wrong_shape))
    with pytest.raises(LawRefused, match="exact solvers"):
        simulate(Pendulum(), (0.0, 0.0), 0.1, 1e-3, scheme="exact")


# ------------------------------------------------------------------ compiled once, cached by its code
def test_the_law_key_follows_the_file(tmp_path):
    a = load(tmp_path, "lawfile", LINEAR_SRC).law
    b = load(tmp_path, "lawfile_copy", LINEAR_SRC).law
    assert a.key == b.key and a.key is not None      # same code: the same cached kernels
    assert a.kernels() is b.kernels()
    c = load(tmp_path, "lawfile_edit", LINEAR_SRC.replace("p[1] * u[0]", "p[1] * u[0] * 1.0"))
    assert c.law.key != a.key                        # an edit: a new key, new kernels
    interactive = ForceLaw(eval("lambda q, u, tau, t, p: -q[0]"), (), n=1)
    assert interactive.key is None                   # no source file: compiled, not cached


KEYED_SRC = '''
from fmu_sync.core import ForceLaw, Param
import {helpers} as lib
from {helpers} import push

GAIN = 2.0
TABLE = {{"a": 1.0}}


def helper(x):
    return 0.5 * x


def h(q, u, tau, t, p):
    return -p[0] * helper(q[0]) * GAIN - push(u[0]) - lib.pull(t) + tau[0]{tail}


law = ForceLaw(h, (Param("k", {k}, "N/m", 0.0),), n=1)
'''


def test_the_law_key_is_what_numba_compiles_of_h(tmp_path, monkeypatch):
    """core/law_key.py: the key follows h's code, the helpers it calls (in its file or another) and the
    constants it reads; not a parameter's default, a line h does not read, or the file's place. A global
    of a kind the digest cannot vouch for keys the law by its whole file."""
    monkeypatch.syspath_prepend(str(tmp_path))
    for name, push, pull in (("helpers_a", "2.0", "0.0"), ("helpers_b", "3.0", "0.0"), ("helpers_c", "2.0", "0.0"),
                             ("helpers_d", "2.0", "1.0")):
        (tmp_path / f"{name}.py").write_text(f"def push(x):\n    return {push} * x\n\n\n"
                                             f"def pull(x):\n    return {pull} * x\n")

    def key(i, helpers="helpers_a", tail="", k="1.0", edit=lambda s: s):
        return load(tmp_path, f"keyed_{i}", edit(KEYED_SRC.format(helpers=helpers, tail=tail, k=k))).law.key

    base = key(0)
    assert base is not None
    assert key(1, k="7.0") == base                                        # a parameter's default
    assert key(2, edit=lambda s: s + "\nUNUSED = 1\n") == base             # a line h does not read
    assert key(3, helpers="helpers_c") == base                            # the same helper in another file
    assert key(4, helpers="helpers_b") != base                            # a helper of another file edited
    assert key(10, helpers="helpers_d") != base                           # one read as an attribute (lib.pull)
    assert key(5, edit=lambda s: s.replace("0.5 * x", "0.25 * x")) != base     # a helper of its file
    assert key(6, edit=lambda s: s.replace("GAIN = 2.0", "GAIN = 2.5")) != base  # a constant it reads
    assert key(7, edit=lambda s: s.replace("\ndef h(", "\n\ndef h(")) != base   # h's lines (its error path)
    opaque = key(8, tail=' * TABLE["a"]')                                 # a dict: not vouched for
    assert opaque != base and key(9, tail=' * TABLE["a"]', k="7.0") != opaque   # keyed by the whole file


def _fresh_process(code: str, **env) -> str:
    """What ``python -c code`` prints in a new process (``env`` added to this one's; no .pyc written: Python
    checks a .pyc by its source's mtime to the second, and these tests rewrite a file within one)."""
    import os
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1", **env})
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def test_a_helper_edited_in_another_file_is_followed_by_the_next_process(tmp_path):
    """h's own cached code (the start checks evaluate it) calls a helper of another file: after an edit
    of that file alone, a fresh process runs the edited helper (numba's own stamp would be h's file's,
    which did not change; core/_cache.py stamps h with the law's key too)."""
    (tmp_path / "lawfile_h.py").write_text(textwrap.dedent('''
        from fmu_sync.core import ForceLaw
        from lawhelp import push


        def h(q, u, tau, t, p):
            return -push(q[0])


        law = ForceLaw(h, (), n=1)
        '''))
    code = (f"import sys; sys.path.insert(0, {str(tmp_path)!r}); import numpy as np; from lawfile_h import law; "
            "print(law.evaluate(np.ones(1), np.zeros(1), np.zeros(1), 0.0, np.zeros(0))[0])")
    seen = []
    # the two versions differ in size too (a stale .pyc ran the old helper once on a clean clone: _fresh_process)
    for gain in ("2.0", "3.25"):
        (tmp_path / "lawhelp.py").write_text(f"from numba import njit\n\n\n@njit(cache=True)\ndef push(x):\n"
                                             f"    return {gain} * x\n")
        seen.append([float(x) for x in _fresh_process(code).split()])
    assert seen == [[-2.0], [-3.25]], seen


def test_an_edit_of_a_default_in_place_keeps_the_key_and_runs_in_the_next_process(tmp_path):
    """The same file edited where it lies (a parameter's default): the law's key stays, so its loops load
    from the cache; h's own cached entry follows the file (numba's entry names h's module, whose name
    follows the file's content: loading the old entry raised ModuleNotFoundError in 0.13.0's first draft)."""
    from _user_files import pendulum_file
    path = tmp_path / "edited_pendulum.py"
    code = (f"import numpy as np; from fmu_sync.core import load_model; law = load_model({str(path)!r} + ':pendulum').force; "
            "print(law.key, law.evaluate(np.array([0.5]), np.array([1.0]), np.zeros(1), 0.0, law.values())[0])")
    seen = []
    for q_w in ("0.3", "0.35"):
        path.write_text(pendulum_file("my_pendulum", "my-pendulum").replace('Param("q_w", 0.3,', f'Param("q_w", {q_w},'))
        seen.append(_fresh_process(code).split())
    assert seen[0] == seen[1] and len(seen[0][0]) == 64     # the same key, the same force
    assert float(seen[0][1]) == pytest.approx(-1.0 * 9.81 * 0.5 * np.sin(0.5) - 0.05 * 1.0)


def test_a_jitted_helper_of_the_laws_own_file_keys_the_law_by_the_files_content(tmp_path):
    """A law's cached loops find a compiled helper's environment by its module's name, and load_model names
    a model file's module after its content: with an @njit helper in the file, an edit of a default gives
    another key (found by hand: the old key's cached loops raised ModuleNotFoundError in the next process);
    without one (the guide's pendulum), the key stays."""
    from fmu_sync.core import load_model
    from _user_files import pendulum_file
    helped = pendulum_file("my_pendulum", "my-pendulum").replace("import math\n", "import math\n\nfrom numba import njit\n\n\n"
                                                                  "@njit\ndef grav(x):\n    return math.sin(x)\n", 1)
    helped = helped.replace("math.sin(q[0])", "grav(q[0])")
    keys = {}
    for name, src in (("plain", pendulum_file("my_pendulum", "my-pendulum")), ("helped", helped)):
        for q_w in ("0.3", "0.35"):
            path = tmp_path / f"{name}.py"
            path.write_text(src.replace('Param("q_w", 0.3,', f'Param("q_w", {q_w},'))
            keys.setdefault(name, []).append(load_model(f"{path}:pendulum").force.key)
    assert keys["plain"][0] == keys["plain"][1] and keys["helped"][0] != keys["helped"][1]


def test_the_law_key_is_the_same_in_every_process(tmp_path):
    """A set constant in h (a frozenset, whose order follows string hashing) gives one key whatever
    PYTHONHASHSEED: the compiled loops are found in the cache by the next process."""
    (tmp_path / "setlaw.py").write_text(textwrap.dedent('''
        from fmu_sync.core import ForceLaw


        def h(q, u, tau, t, p):
            return -q[0] if t in {"a", "b", "c", "d"} else -2.0 * q[0]


        law = ForceLaw(h, (), n=1)
        '''))
    code = f"import sys; sys.path.insert(0, {str(tmp_path)!r}); import setlaw; print(setlaw.law.key)"
    keys = {_fresh_process(code, PYTHONHASHSEED=seed) for seed in ("1", "2", "3")}
    assert len(keys) == 1 and len(keys.pop().strip()) == 64


def test_the_guide_example_file_runs(tmp_path, monkeypatch):
    """docs/user-model.md: its model file and its usage block, as written, run and synchronize."""
    from pathlib import Path
    text = (Path(__file__).resolve().parent.parent / "docs" / "user-model.md").read_text()
    blocks = [b.split("```", 1)[0] for b in text.split("```python\n")[1:]]
    (tmp_path / "my_pendulum.py").write_text(blocks[0])
    monkeypatch.chdir(tmp_path)
    ns = {}
    exec(compile(blocks[1].replace("print(", "(lambda *a: None)("), "user-model.md", "exec"), ns)
    assert ns["p"].d[-1] < 1e-6 * ns["p"].d[0] and ns["p"].impacts1 > 0
    assert ns["r"].impacts > 0 and ns["p"].metric == "linearized"


def test_the_declared_forcing_is_checked_and_reaches_the_loops_arrays():
    """ForceLaw(forcing=...): a malformed term is refused naming the law; a good one becomes the
    system's forcing (the loops' F, Omega, phi: added to h by their cos or phasor path)."""
    def h(q, u, tau, t, p):
        return -p[0] * q[0] + tau[0]

    prm = (Param("k", 1.0, "N/m", 0.0),)
    bad = ForceLaw(h, prm, n=1, name="bad_forcing", linear=lambda p: ([[p[0]]], [[0.0]]),
                   forcing=lambda p: ((1.0, 2.0),))
    with pytest.raises(LawRefused, match="'bad_forcing': forcing term 0 must be"):
        MechanicalSystem(M=[[1.0]], w=[1.0], g0=0.0, e=0.5, force=bad)
    good = ForceLaw(h, prm, n=1, linear=lambda p: ([[p[0]]], [[0.0]]), forcing=lambda p: ((0.5 * p[0], 2.0, 0.1),))
    s = MechanicalSystem(M=[[1.0]], w=[1.0], g0=0.0, e=0.5, force=good, params={"k": 3.0})
    assert s.forcing == (((1.5,), 2.0, 0.1),)
    sa = s.arrays()
    assert sa.F.tolist() == [[1.5]] and sa.Omega.tolist() == [2.0] and sa.phi.tolist() == [0.1]
    assert duffing_law.forcing_terms(np.array([1.0, 0.5, 0.0, 0.7, 1.3, 0.2])) == (((0.7,), 1.3, 0.2),)
