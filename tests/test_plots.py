"""Plots (headless PNG) and the summary report, on results built here: two uncoupled
``simulate`` runs packed into a PairResult with a stand-in distance (the plots and
metrics only read the fields, so this does not depend on simulate_pair)."""
import io
import math

import numpy as np
import pytest

from builtin_scenes import FORCED_PAIR
from fmu_sync import plots, report
from fmu_sync.core import ImpactOscillator, MechanicalSystem, simulate
from fmu_sync.core.result import PairResult

PNG = b"\x89PNG\r\n\x1a\n"


def fake_pair(system, x1, x2, t_end=12.0, dt=1e-3, every=10, coupling="switching"):
    r1 = simulate(system, x1, t_end, dt, record_every=every)
    r2 = simulate(system, x2, t_end, dt, record_every=every)
    dq, du = r1.q - r2.q, r1.u - r2.u
    E = np.sqrt(np.sum(dq**2, axis=1) + np.einsum("ij,jk,ik->i", du, system.M, du))
    d = np.minimum(E, np.exp(-2.0 * r1.t))      # smooth, decaying stand-in for the quotient distance
    d[-5:] = 0.0                                 # exact zeros must not break the log axes
    tau1 = -1.0 * dq - 0.5 * du
    return PairResult(r1.t, r1.q, r1.u, r2.q, r2.u, tau1, -tau1, d, np.zeros(len(d), dtype=np.int64), E,
                      impacts1=r1.impacts, impacts2=r2.impacts, coupling=coupling)


@pytest.fixture(scope="module")
def osc():
    return ImpactOscillator(**FORCED_PAIR)


@pytest.fixture(scope="module")
def pair(osc):
    return fake_pair(osc, (1.0, 0.0), (0.2, 0.5))


@pytest.fixture(scope="module")
def two_dof():
    s = MechanicalSystem(M=[[2, 0.5], [0.5, 1]], K=[[3, -1], [-1, 2]], C=0.02 * np.eye(2), f0=[0.1, 0.2],
                         w=[1, 0.5], g0=0.0, e=0.7, forcing=(([0.6, 0.0], 1.3, 0.0),))
    return s, fake_pair(s, ([0.6, 0.2], [0, 0]), ([0.2, -0.1], [0.3, -0.2]))


def check_png(path, min_bytes=8000):
    data = path.read_bytes()
    assert data[:8] == PNG and len(data) > min_bytes, (path, len(data))


@pytest.mark.parametrize("kind", sorted(plots.PLOTTERS))
def test_each_plot_is_written(tmp_path, pair, osc, kind):
    p = plots.PLOTTERS[kind](pair, tmp_path / f"{kind}.png", system=osc, title="forced-pair: test")
    assert p == tmp_path / f"{kind}.png"
    check_png(p)


@pytest.mark.parametrize("kind", sorted(plots.PLOTTERS))
def test_two_dof_plots(tmp_path, two_dof, kind):
    s, r = two_dof
    check_png(plots.PLOTTERS[kind](r, tmp_path / f"{kind}.png", system=s))


def test_single_system_plots_and_compare(tmp_path, osc, pair):
    r = simulate(ImpactOscillator(f0=-9.81, e=0.8), (1.0, 0.0), 3.0, 1e-3)
    check_png(plots.plot_positions(r, tmp_path / "p.png"))
    check_png(plots.plot_phase(r, tmp_path / "ph.png"))
    other = fake_pair(osc, (1.0, 0.0), (0.5, 0.0), t_end=6.0, coupling=None)
    check_png(plots.compare_plot({"switching": pair, "uncoupled": other}, tmp_path / "c.png"))
    check_png(plots.compare_plot({"a (cosim)": pair, "a (core)": other}, tmp_path / "e.png",
                                 quantity="euclidean", dashed=["a (core)"]))
    with pytest.raises(ValueError, match="quantity"):
        plots.compare_plot({"a": pair}, tmp_path / "x.png", quantity="energy")


def test_plots_are_headless_and_leave_pyplot_alone(tmp_path):
    """No display needed, no global pyplot state touched (Figure + Agg canvas)."""
    import subprocess
    import sys
    code = ("import sys, numpy as np; from fmu_sync import plots; from fmu_sync.core.result import PairResult; "
            "t = np.linspace(0, 1, 50); z = np.zeros((50, 1)); q = np.abs(np.sin(9 * t))[:, None]; "
            "r = PairResult(t, q, z, z, z, z, z, np.exp(-t), np.zeros(50, int), np.exp(-t)); "
            f"plots.plot_distance(r, {str(tmp_path / 'h.png')!r}); "
            "print('matplotlib.pyplot' in sys.modules)")
    env = {k: v for k, v in __import__("os").environ.items() if k not in ("DISPLAY", "MPLBACKEND")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
    check_png(tmp_path / "h.png", min_bytes=2000)


# ------------------------------------------------------------------ report
def test_impact_rows_match_the_percussions(osc):
    ball = ImpactOscillator(f0=-9.81, e=0.8)
    r = simulate(ball, (1.0, 0.0), 3.0, 1e-3, record_every=5)
    rows = report.impact_rows(r.t, r.q, r.u)
    starts = np.nonzero((r.percussion > 0) & ~np.concatenate(([False], r.percussion[:-1] > 0)))[0]
    assert rows.size >= 5
    assert set(rows) <= set(np.nonzero(r.percussion > 0)[0]), "every detected impact is a real one"
    assert abs(rows.size - starts.size) <= 2
    # no impact is claimed in free flight above the wall (turning points of an oscillator)
    free = simulate(ImpactOscillator(k=1.0, f0=2.0), (2.5, 0.0), 20.0, 1e-3, record_every=10)
    assert report.impact_rows(free.t, free.q, free.u).size == 0


def test_pair_metrics(pair, osc):
    m = report.metrics(pair, osc)
    assert m["kind"] == "pair" and m["coupling"] == "switching"
    assert m["t_sync"] == pytest.approx(pair.time_to_sync(1e-6))
    assert m["final_d"] == 0.0
    assert m["peak_tau"] == pytest.approx(max(np.abs(pair.tau1).max(), np.abs(pair.tau2).max()))
    assert m["peaking"] == pytest.approx(np.max(pair.euclidean - pair.d))
    assert m["impact_records"] > 0 and m["dE_impact"] > m["dV_impact"] >= 0.0
    assert (m["impacts1"], m["impacts2"]) == (pair.impacts1, pair.impacts2)
    nod = PairResult(pair.t, pair.q1, pair.u1, pair.q2, pair.u2, pair.tau1, pair.tau2, None, None, None)
    m = report.metrics(nod, osc)
    assert m["t_sync"] is None and m["final_d"] is None


def test_tables_and_summary(tmp_path, pair, osc):
    class Run:
        def __init__(self, name, result):
            self.name, self.metrics = name, report.metrics(result, osc)
    runs = [Run("switching", pair), Run("never", fake_pair(osc, (1.0, 0.0), (0.5, 0.0), t_end=3.0))]
    runs[1].metrics["t_sync"] = math.inf
    header, table = report.rows(runs)
    assert header[0] == "variant" and len(table) == 2 and table[1][2] == "not within t_end"
    buf = io.StringIO()
    report.print_table(header, table, file=buf)
    lines = buf.getvalue().splitlines()
    assert len(lines) == 4 and len({len(line.rstrip()) for line in lines[:2]}) == 1
    p = report.write_summary(tmp_path / "summary.md", "Scene `x`", "desc", (header, table),
                             settings=[("run.t_end", "12.0")], files=[tmp_path / "a.csv"], base=tmp_path)
    text = p.read_text()
    assert text.startswith("# Scene `x`") and "| switching |" in text and "[`a.csv`](a.csv)" in text


def test_write_data_roundtrip(tmp_path, pair):
    csv, npz = report.write_data(pair, tmp_path / "run")
    head = csv.read_text().splitlines()[0].split(",")
    assert head[:3] == ["t [s]", "q1 [m]", "u1 [m/s]"] and "d" in head and "V" in head
    data = np.loadtxt(csv, delimiter=",", skiprows=1, usecols=range(len(head) - 1))   # branch: names
    assert data.shape == (len(pair.t), len(head) - 1)
    assert np.allclose(np.load(npz)["d"], pair.d)
    r = simulate(ImpactOscillator(f0=-9.81, e=0.8), (1.0, 0.0), 1.0, 1e-3)
    csv, npz = report.write_data(r, tmp_path / "single")
    assert csv.read_text().splitlines()[0] == "t [s],q [m],u [m/s],percussion [N s]"
    assert np.array_equal(np.load(npz)["percussion"], r.percussion)


def test_max_abs_difference(pair):
    assert report.max_abs_difference(pair, pair) == 0.0
    shifted = PairResult(pair.t, pair.q1, pair.u1, pair.q2, pair.u2, pair.tau1, pair.tau2, pair.d + 1e-3,
                         pair.branch, pair.euclidean)
    assert report.max_abs_difference(pair, shifted) == pytest.approx(1e-3)
    fine = PairResult(pair.t[::2], *(a[::2] for a in (pair.q1, pair.u1, pair.q2, pair.u2, pair.tau1,
                                                       pair.tau2)), pair.d[::2], None, None)
    assert report.max_abs_difference(fine, pair) == 0.0
    nod = PairResult(pair.t, pair.q1, pair.u1, pair.q2, pair.u2, pair.tau1, pair.tau2, None, None, None)
    assert report.max_abs_difference(nod, pair) is None


# ------------------------------------------------------------------ what the figures say
def _texts(fig_path_fn, *args, **kw):
    """Run a plotter with Figure.savefig captured: the figure's texts and legend labels."""
    from matplotlib.figure import Figure
    seen = {}
    orig = Figure.savefig

    def capture(self, path, **k):
        seen["fig"] = self
        return orig(self, path, **k)
    Figure.savefig = capture
    try:
        fig_path_fn(*args, **kw)
    finally:
        Figure.savefig = orig
    fig = seen["fig"]
    out = [t.get_text() for t in fig.findobj(lambda o: hasattr(o, "get_text"))]
    for ax in fig.axes:
        out.append("TITLE:" + ax.get_title())
        leg = ax.get_legend()
        if leg is not None:
            out += [t.get_text() for t in leg.get_texts()]
    return fig, [t.replace("\n", " ") for t in out]     # wrapped legend labels read as one line


def _inside_and_beside(fig):
    """Every title and legend lies inside the figure, and no legend covers its axes' data area."""
    fig.canvas.draw()
    R = fig.canvas.get_renderer()
    W, H = fig.bbox.width, fig.bbox.height
    for ax in fig.axes:
        for art in [ax.title] + ([ax.get_legend()] if ax.get_legend() else []):
            b = art.get_window_extent(R)
            assert b.x0 >= -0.5 and b.x1 <= W + 0.5 and b.y0 >= -0.5 and b.y1 <= H + 0.5, (art, b, W, H)
        leg = ax.get_legend()
        if leg is not None:
            assert not leg.get_window_extent(R).overlaps(ax.get_window_extent(R)), ax.get_ylabel()


def test_impact_zoom_window_shows_the_jump_with_d_continuous(osc):
    """A real coupled pair: the zoom window holds the largest peaking of the Euclidean error
    over d; inside it E jumps by O(1) between two records while d changes by O(dt) only."""
    from fmu_sync.core import simulate_pair
    r = simulate_pair(osc, (1.0, 0.0), (0.2, 0.5), 20.0, 1e-3, coupling="switching", Kp=1.0, Kd=0.5,
                      record_every=10)
    i0, i1, k = plots.impact_window(r, osc)
    assert i0 < k < i1
    E, d = r.euclidean[i0:i1], r.d[i0:i1]
    assert np.max(np.abs(np.diff(E))) > 0.5                 # the Euclidean error jumps ...
    assert np.max(np.abs(np.diff(d))) < 0.05                # ... the quotient distance does not
    assert r.euclidean[k] - r.d[k] == pytest.approx(np.max(r.euclidean - r.d))


def test_titles_single_and_zero_noted(tmp_path, pair, osc):
    fig, texts = _texts(plots.plot_distance, pair, tmp_path / "d.png", system=osc, title="scene, run")
    titles = [t for t in texts if t.startswith("TITLE:") and t != "TITLE:"]
    assert titles == ["TITLE:scene, run: Euclidean error vs quotient distance"]
    assert any("d is exactly 0 from t = " in t for t in texts), texts      # no silent stop
    assert any(t.startswith("t_sync") for t in texts)
    _, texts = _texts(plots.compare_plot, {"a": pair}, tmp_path / "c.png", title="only this")
    assert [t for t in texts if t.startswith("TITLE:")] == ["TITLE:only this"]



def test_forces_with_exact_zeros_one_note_inside_the_figure(tmp_path, pair, osc):
    """τ exactly 0 in some records (the switching law at d = 0): the note is drawn once, every
    title and legend lies inside the figure and beside the data (issue 28: twice, run off the left
    edge, the title cut)."""
    tau1 = np.where((pair.d == 0.0).reshape(pair.tau1.shape[0], -1), 0.0, pair.tau1)
    tau1[100:110] = 0.0
    r = PairResult(pair.t, pair.q1, pair.u1, pair.q2, pair.u2, tau1, -tau1, pair.d, pair.branch, pair.euclidean,
                   coupling="switching")
    fig, texts = _texts(plots.plot_forces, r, tmp_path / "f.png", system=osc, title="forced-pair, switching")
    notes = [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()
             if "exactly 0" in t.get_text().replace("\n", " ")]
    notes += [t.get_text() for ax in fig.axes for t in ax.texts if "exactly 0" in t.get_text()]
    assert len(notes) == 1, notes
    assert "TITLE:forced-pair, switching: coupling forces (switching)" in texts
    _inside_and_beside(fig)


@pytest.mark.parametrize("kind", ["distance", "lyapunov", "forces", "positions"])
def test_legends_beside_the_data(tmp_path, pair, osc, kind):
    """The legends of the time plots (the ultimate-bound line of an uncoupled run among them) lie
    beside the axes, inside the figure."""
    unc = PairResult(pair.t, pair.q1, pair.u1, pair.q2, pair.u2, pair.tau1, pair.tau2, pair.euclidean * 0.9,
                     pair.branch, pair.euclidean, coupling=None)
    fig, texts = _texts(plots.PLOTTERS[kind], unc, tmp_path / "x.png", system=osc, title="forced-pair, uncoupled")
    if kind == "distance":
        assert any(t.startswith("ultimate bound") for t in texts), texts
    _inside_and_beside(fig)

def test_uncoupled_forces_one_panel_no_empty_axes(tmp_path, pair, osc):
    z = np.zeros_like(pair.tau1)
    unc = PairResult(pair.t, pair.q1, pair.u1, pair.q2, pair.u2, z, z, pair.d, pair.branch, pair.euclidean)
    fig, texts = _texts(plots.plot_forces, unc, tmp_path / "f.png", system=osc)
    assert len(fig.axes) == 1 and any("no coupling force" in t for t in texts)
    fig, _ = _texts(plots.plot_forces, pair, tmp_path / "g.png", system=osc)
    assert len(fig.axes) == 2 and all(ax.lines for ax in fig.axes)


_SAVE_LOOP = """
import signal
import sys
import numpy as np
# Ctrl-C raises KeyboardInterrupt even when pytest was started with SIGINT ignored (a background job of a
# non-interactive shell): else the child ignores the signal and writes all 1000 figures (minutes)
signal.signal(signal.SIGINT, signal.default_int_handler)
from fmu_sync import plots
from fmu_sync.core.result import PairResult
t = np.linspace(0.0, 100.0, 200001)
x = np.sin(t)[:, None]
d = np.exp(-0.1 * t)
r = PairResult(t, x, x, -x, -x, x, -x, d, np.zeros(t.size, dtype=np.int64), 2 * d, impacts1=0, impacts2=0,
               coupling="switching")
print("ready", flush=True)
for i in range(1000):
    plots.plot_forces(r, f"{sys.argv[1]}/f{i}.png", title="interrupted")
"""


def test_an_interrupted_plot_leaves_no_truncated_png(tmp_path):
    """SIGINT (Ctrl-C) while figures are written: every PNG left is whole (it ends with its IEND
    chunk) and no temporary file stays (issue 28: a 124-byte PNG of the interrupted variant)."""
    import random
    import signal
    import subprocess
    import sys
    import time
    rng = random.Random(28)
    for k in range(3):
        out = tmp_path / f"try{k}"
        out.mkdir()
        p = subprocess.Popen([sys.executable, "-c", _SAVE_LOOP, str(out)], stdout=subprocess.PIPE, text=True)
        assert p.stdout.readline().strip() == "ready"
        while not list(out.glob("f1.png")) and p.poll() is None:
            time.sleep(0.02)
        time.sleep(rng.uniform(0.0, 0.5))
        # Ctrl-C, pressed again while the child runs: CPython ignores a KeyboardInterrupt raised inside a
        # weakref callback ("Exception ignored in: <function TransformNode.set_children.<locals>.<lambda>>",
        # matplotlib's transforms), so one Ctrl-C can be lost (seen once in a clean-clone run: the child wrote on)
        for _ in range(12):
            p.send_signal(signal.SIGINT)
            try:
                p.wait(timeout=5)
                break
            except subprocess.TimeoutExpired:
                continue
        assert p.wait(timeout=5) is not None
        files = sorted(out.iterdir())
        assert files and all(f.suffix == ".png" and not f.name.startswith(".") for f in files), files
        for f in files:
            assert f.read_bytes().endswith(b"IEND\xaeB`\x82"), (f, f.stat().st_size)


# ------------------------------------------------------------------ labels match the drawn data (issue 36)
def _figure_of(plotter, *args, **kw):
    return _texts(plotter, *args, **kw)[0]


def _lines(ax):
    """The drawn (non-empty) lines of ``ax``: their data and labels."""
    return [(ln.get_xydata(), ln.get_label()) for ln in ax.get_lines() if len(ln.get_xydata())]


def _one_dof_wall(w):
    """A forced 1-DOF oscillator with the wall at q = 0.8 on the side of ``w`` (w = +1: q >= 0.8,
    w = -1: q <= 0.8), and a pair of runs from x1 = (0, 0), x2 = (-0.5, 0.4) (w = +1: mirrored)."""
    s = MechanicalSystem(M=[[1.0]], K=[[1.0]], C=[[0.05]], f0=[0.0], w=[float(w)], g0=-0.8 * w, e=0.7,
                         forcing=(([0.6], 1.3, 0.0),))
    x1, x2 = ((0.0, 0.0), (-0.5, 0.4)) if w < 0 else ((1.6, 0.0), (2.1, -0.4))
    return s, fake_pair(s, x1, x2, t_end=12.0)


@pytest.mark.parametrize("w", [1.0, -1.0])
def test_wall_plots_draw_q_and_u_with_the_wall_on_its_side(tmp_path, w):
    """1-DOF, w = ±1 (issue 36: the phase portrait said "position q" and drew the gap and -u;
    its start markers sat at (0.8, 0) and (1.3, -0.4) for x1 = (0, 0), x2 = (-0.5, 0.4)): the
    phase portrait, the positions plot and the impact window draw q and u as labelled, the wall
    at q = 0.8 with its forbidden side hatched on the side w forbids."""
    s, r = _one_dof_wall(w)
    q_wall = 0.8
    fig = _figure_of(plots.plot_phase, r, tmp_path / "ph.png", system=s, title="t")
    ax = fig.axes[0]
    assert ax.get_xlabel() == "position q [m]" and ax.get_ylabel() == "velocity u [m/s]"
    lines = _lines(ax)
    starts = [xy[0].tolist() for xy, _ in lines if len(xy) == 1][::2]     # start, end markers per system
    assert starts == [[r.q1[0, 0], r.u1[0, 0]], [r.q2[0, 0], r.u2[0, 0]]]
    curves = {lab: xy for xy, lab in lines if lab in ("system 1", "system 2")}
    for i, lab in ((1, "system 1"), (2, "system 2")):
        q, u = getattr(r, f"q{i}")[:, 0], getattr(r, f"u{i}")[:, 0]
        xy = curves[lab]
        np.testing.assert_array_equal(xy, np.column_stack([q, u])[len(q) - len(xy):])
    walls = [xy for xy, lab in lines if lab.startswith("wall q = 0.8 m")]
    assert len(walls) == 1 and np.all(walls[0][:, 0] == q_wall)
    span = ax.patches[0]                                                   # the forbidden side, hatched
    x = span.get_patch_transform().transform(span.get_path().vertices)[:, 0]
    assert (x.max() <= q_wall + 1e-12) if w > 0 else (x.min() >= q_wall - 1e-12), x
    allowed = np.concatenate([r.q1[:, 0], r.q2[:, 0]])
    assert np.all(allowed * w >= q_wall * w - 1e-4)                        # the run stays on the allowed side

    fig = _figure_of(plots.plot_positions, r, tmp_path / "p.png", system=s, title="scene")
    ax = fig.axes[0]
    assert ax.get_ylabel() == "position q [m]" and ax.get_title().startswith("scene: position q")
    curves = {lab: xy for xy, lab in _lines(ax)}
    np.testing.assert_array_equal(curves["system 1"], np.column_stack([r.t, r.q1[:, 0]]))
    np.testing.assert_array_equal(curves["system 2"], np.column_stack([r.t, r.q2[:, 0]]))
    assert any(lab.startswith("contact episodes") and np.all(xy[:, 1] == q_wall) for xy, lab in _lines(ax))

    fig = _figure_of(plots.plot_impact_zoom, r, tmp_path / "z.png", system=s)
    axq, axd = fig.axes[:2]
    i0, i1, _ = plots.impact_window(r, s)
    assert axq.get_ylabel() == "position q [m]"
    curves = {lab: xy for xy, lab in _lines(axq)}
    np.testing.assert_array_equal(curves["system 1"], np.column_stack([r.t, r.q1[:, 0]])[i0:i1])
    assert axd.get_yscale() == "log"                                       # d readable next to the jump
    drawn_d = {lab: xy for xy, lab in _lines(axd)}["quotient distance d"]
    np.testing.assert_array_equal(drawn_d[:, 1], np.where(r.d > 0, r.d, np.nan)[i0:i1])


def test_oblique_wall_plots_label_the_gap_and_the_normal_velocity(tmp_path, two_dof):
    """n = 2, oblique wall w = (1, 0.5): the phase portrait draws (g, γ) = (wᵀq + g0, wᵀu), so labelled."""
    s, r = two_dof
    w = np.asarray(s.w)
    ax = _figure_of(plots.plot_phase, r, tmp_path / "ph.png", system=s).axes[0]
    assert ax.get_xlabel() == "gap g = wᵀq + g0 [m]" and ax.get_ylabel() == "normal velocity γ = wᵀu [m/s]"
    xy = {lab: xy for xy, lab in _lines(ax)}["system 2"]
    np.testing.assert_allclose(xy, np.column_stack([r.q2 @ w + s.g0, r.u2 @ w])[len(r.t) - len(xy):], rtol=0,
                               atol=1e-15)
    fig = _figure_of(plots.plot_positions, r, tmp_path / "p.png", system=s, title="two-dof")
    assert fig.axes[0].get_ylabel() == "position q [m]" and fig.axes[1].get_ylabel().startswith("gap g = wᵀq")
    assert fig.axes[0].get_title().startswith("two-dof: positions q")


def test_v_is_called_a_lyapunov_function_only_when_the_result_says_so(tmp_path, pair, osc):
    from dataclasses import replace
    cases = {"yes": replace(pair, info={"lyapunov": True, "metric": "energy"}),
             "user metric": replace(pair, info={"lyapunov": False, "metric": "user"}),
             "uncoupled": replace(pair, coupling=None, info={"lyapunov": True, "metric": "energy"}),
             "unsaid": replace(pair, info={})}
    for name, r in cases.items():
        fig, texts = _texts(plots.plot_lyapunov, r, tmp_path / "v.png", system=osc, title=name)
        ax = fig.axes[0]
        if name == "yes":
            assert ax.get_ylabel() == "Lyapunov function V" and ax.get_title() == "yes: Lyapunov function V(t)"
        else:   # V, with the reason it is not called a Lyapunov function in the legend
            assert ax.get_ylabel() == "V" and ax.get_title() == f"{name}: V = d²/2 vs time"
            assert not any("Lyapunov function V" in t for t in texts), (name, texts)
            assert plots.lyapunov_note(r) in [t.get_text().replace("\n", " ") for t in ax.get_legend().get_texts()]
    _, texts = _texts(plots.compare_plot, {"a": cases["uncoupled"]}, tmp_path / "c.png", quantity="V")
    assert not any("Lyapunov" in t for t in texts)
