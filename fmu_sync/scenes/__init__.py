"""Scenes: what to simulate, how, and what to write out (docs/design.md §4.5).

The package: :mod:`.schema` (keys, checkers, :class:`~.schema.Variant`),
:mod:`.loading` (TOML -> :class:`~.loading.Scene`), :mod:`.running` (variants ->
core or master -> data, plots, summary), :mod:`.demo` (the README's demo), and the
built-in ``*.toml`` scenes next to them: they are the only place a built-in scene
is defined.

A scene is a TOML file. Built-in scenes live in ``fmu_sync/scenes/``; any other
file can be given by path. Format (every key is checked; unknown keys, wrong
types and bad values raise :class:`SceneError` naming file, key and value)::

    description = "one line shown by `fmu-sync scenes`"

    [system]                    # the mechanical system (docs/design.md §2.1), SI units
    model = "impact-oscillator" # m q'' + c q' + k q = f0 + F cos(Omega t + phi) + tau, q >= 0
    m = 1.0                     # kg, > 0            (default 1)
    k = 1.0                     # N/m, >= 0          (default 0)
    c = 0.0                     # N s/m, >= 0        (default 0)
    f0 = 0.2                    # N                  (default 0)
    F = 0.5                     # N                  (default 0)
    Omega = 2.5                 # rad/s              (default 0)
    phi = 0.0                   # rad                (default 0)
    e = 0.9                     # restitution in [0, 1] (required)
    # or model = "mechanical-system" with
    #   M (n x n, required), K, C (n x n, default 0), f0 (n, default 0),
    #   w (n, required, nonzero), g0 (default 0), e (required),
    #   forcing = [{F = [..n..], Omega = 1.3, phi = 0.0}, ...]   (default none)

    [initial]
    x1 = [1.0, 0.0]             # [q, u]; for n > 1: [[q1, .., qn], [u1, .., un]]
    x2 = [0.2, 0.5]             # optional: without x2 the scene is a single system

    [network]                   # instead of [initial]: N >= 2 systems on a graph (see ring-8.toml)
    graph = "ring"              # "ring" | "path" | "star" | "all-to-all" | N x N weight matrix
    weight = 1.0                # edge weight of a named graph (default 1); center = 1: a star's hub
    states = [[1.0, 0.0], ...]  # one start state per node (N = len(states))
    nodes = [{}, {k = 1.05}]    # optional: [system] keys per node (not m/M, w, g0, e: common)
    laws = ["switching", ...]   # optional: one law per edge, order (1,2), (1,3), .., (2,3), ..

    [coupling]                  # pair and network scenes only
    law = "switching"           # "none" | "switching" | "euclidean"   (default "none")
    Kp = 1.0                    # >= 0, number or n x n matrix         (default 0)
    Kd = 0.5                    # >= 0, number or n x n matrix         (default 0)
    Q = "energy"                # position weight of the norm: "energy" (default: K + 2 Kp, the law's own
                                # metric, V = d^2/2 a Lyapunov function) or a number > 0 / SPD n x n

    [solver]
    scheme = "trapezoid"        # "trapezoid" | "midpoint" | "theta" | "exact" (default: the core's,
                                # trapezoid; exact: single 1-DOF systems)
    dt = 1e-3                   # internal step, s, > 0 (default 1e-3)
    theta = 0.5                 # in [0.5, 1], for scheme = "theta" (default 0.5)

    [run]
    t_end = 100.0               # s, > 0 (required)
    mode = "core"               # "core" (monolithic numba run) | "cosim" (FMU + master)
    H = 1e-2                    # communication step of the master, s, > 0 (cosim)
    H_min = 1e-4                # smallest retaken step with event_aware (optional)
    method = "jacobi"           # "jacobi" | "gauss-seidel" (cosim)
    event_aware = false         # cosim: retake steps that contain an impact
    tol = 1e-4                  # cosim: co-simulate to this tolerance (q's unit; H: the first, largest step)
    record_every = 10           # keep every k-th step (core: steps dt; cosim: steps H)
    allow_unstable = false      # run even if the held coupling exchange is unstable at this step
                                # (refused before the first step by default; CLI: --allow-unstable)

    [record]
    distance = true             # compute d, branch, V, Euclidean error (pairs; default true)
    formats = ["csv", "npz"]    # data files to write: any of "csv", "npz", "nc" (CLI: --format npz,csv,nc)

    [plot]
    plots = ["positions", "distance", "impact-zoom", "lyapunov", "forces", "phase"]
                                # impact-zoom: one impact window, Euclidean error vs d (linear axes)
    compare = true              # d(t) of all variants on one axis (default: when >= 2 variants)

    [[runs]]                    # optional variants; each one is a run of its own.
    name = "uncoupled"          # used in file names: letters, digits, - _ .
    description = "no coupling"
    coupling.law = "none"       # any key of [system] [initial] [coupling] [solver] [run] [record]

A scene without ``[[runs]]`` has one run named after the scene. Each variant is
the top-level tables with the variant's keys laid over them. ``--set`` style
overrides (``{"coupling.Kp": 2}``) replace a key everywhere, variants included.

Only what a scene names is built: a core scene never exports an FMU nor imports
fmpy, a single system runs :func:`fmu_sync.core.simulate` (no master,
no distance), and the distance is computed only when recorded or needed by the
coupling law.
"""
from pathlib import Path

#: Folder holding the built-in ``*.toml`` scenes.
SCENE_DIR = Path(__file__).resolve().parent

__all__ = ["SCENE_DIR", "builtin_names"]


def builtin_names() -> list[str]:
    """Names (file stems) of the built-in scenes, sorted."""
    return sorted(p.stem for p in SCENE_DIR.glob("*.toml"))
