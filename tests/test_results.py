"""Results a user can reopen (docs/results.md): files that describe themselves, fmu_sync.load
(npz, csv, nc; files of 0.1.0 too), fmu-sync plot DIR, the result views (to_xarray,
to_dataframe, plot, repr), the scene-key reference, scenes --show, LICENSE, CHANGELOG, version."""
import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fmu_sync
from fmu_sync import report
from fmu_sync.cli import main
from fmu_sync.core import ImpactOscillator, simulate
from fmu_sync.core.network import edges_of, ring
from fmu_sync.core.result import NetworkResult, PairResult, SimulationResult

ROOT = Path(__file__).resolve().parent.parent
PAIR_FIELDS = ("t", "q1", "u1", "q2", "u2", "tau1", "tau2", "d", "euclidean", "branch")
NET_FIELDS = ("t", "q", "u", "tau", "d", "euclidean", "branch", "V")


def same_bits(a, b) -> bool:
    """Equal arrays bit for bit (shape, dtype kind and every bit: -0.0 differs from 0.0)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return False
    if a.dtype.kind == "f" or b.dtype.kind == "f":
        return np.array_equal(a.astype(np.float64).view(np.uint64), b.astype(np.float64).view(np.uint64))
    return np.array_equal(a, b)


# floats a record can hold: any finite value (subnormals, -0.0, huge), never NaN
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@st.composite
def pairs(draw):
    rows = draw(st.integers(1, 6))
    n = draw(st.integers(1, 2))
    arr = lambda *shape: np.array(draw(st.lists(finite, min_size=int(np.prod(shape)),  # noqa: E731
                                                max_size=int(np.prod(shape))))).reshape(shape)
    branch = np.array(draw(st.lists(st.integers(-1, 3), min_size=rows, max_size=rows)), dtype=np.int64)
    return PairResult(arr(rows), arr(rows, n), arr(rows, n), arr(rows, n), arr(rows, n), arr(rows, n),
                      arr(rows, n), np.minimum(np.abs(arr(rows)), 1e150), branch, np.abs(arr(rows)), impacts1=draw(st.integers(0, 9)),
                      impacts2=3, coupling="switching", info={"mode": "core", "dt": 0.001})


@st.composite
def networks(draw):
    rows, N, n = draw(st.integers(1, 4)), draw(st.integers(2, 5)), draw(st.integers(1, 2))
    edges = edges_of(ring(N, 1.0))
    E = len(edges)
    arr = lambda *shape: np.array(draw(st.lists(finite, min_size=int(np.prod(shape)),  # noqa: E731
                                                max_size=int(np.prod(shape))))).reshape(shape)
    branch = np.array(draw(st.lists(st.integers(-1, 3), min_size=rows * E, max_size=rows * E)),
                      dtype=np.int64).reshape(rows, E)
    return NetworkResult(arr(rows), arr(rows, N, n), arr(rows, N, n), arr(rows, N, n), edges,
                         np.abs(arr(rows, E)), branch, np.abs(arr(rows, E)), np.abs(arr(rows)),
                         [int(x) for x in draw(st.lists(st.integers(0, 50), min_size=N, max_size=N))],
                         info={"mode": "core", "coupling": "switching"})


# ---------------------------------------------------------------- round trips
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(r=pairs())
def test_a_pair_written_and_loaded_back_is_bit_for_bit_the_same(tmp_path_factory, r):
    out = tmp_path_factory.mktemp("pair")
    files = report.write_data(r, out / "run", ("csv", "npz", "nc"))
    assert sorted(p.suffix for p in files) == [".csv", ".nc", ".npz"]
    for p in files:
        back = fmu_sync.load(p)
        assert isinstance(back, PairResult)
        for k in PAIR_FIELDS:
            assert same_bits(getattr(back, k), getattr(r, k)), (p.suffix, k)
        if p.suffix != ".csv":   # counts and coupling are not columns of a CSV
            assert (back.impacts1, back.impacts2, back.coupling) == (r.impacts1, r.impacts2, r.coupling)
            assert back.info["dt"] == 0.001


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(r=networks())
def test_a_network_written_and_loaded_back_is_bit_for_bit_the_same(tmp_path_factory, r):
    out = tmp_path_factory.mktemp("net")
    for p in report.write_data(r, out / "ring", ("csv", "npz", "nc")):
        back = fmu_sync.load(p)
        assert isinstance(back, NetworkResult)
        assert [tuple(e) for e in back.edges] == [tuple(e) for e in r.edges], p.suffix
        for k in NET_FIELDS:
            assert same_bits(getattr(back, k), getattr(r, k)), (p.suffix, k)
        if p.suffix != ".csv":
            assert back.impacts == r.impacts and back.info["coupling"] == "switching"


def test_a_single_system_round_trip(tmp_path):
    r = simulate(ImpactOscillator(m=1.0, k=0.0, c=0.0, f0=-9.81, e=0.7), (1.0, 0.0), 1.5, 1e-3, record_every=5)
    for p in report.write_data(r, tmp_path / "ball", ("csv", "npz", "nc")):
        back = fmu_sync.load(p)
        assert isinstance(back, SimulationResult)
        for k in ("t", "q", "u", "percussion"):
            assert same_bits(getattr(back, k), getattr(r, k)), (p.suffix, k)
        assert back.impacts == r.impacts
        if p.suffix != ".csv":
            assert (back.scheme, back.dt) == (r.scheme, r.dt)


# ---------------------------------------------------------------- the files describe themselves
def test_csv_names_units_edges_and_branches_with_the_digits_they_need(tmp_path):
    N = 8
    edges = edges_of(ring(N, 1.0))
    rows = 3
    t = np.array([0.0, 0.1, 0.2])
    z = np.zeros((rows, N, 1))
    d = np.full((rows, len(edges)), 0.2)
    branch = np.tile(np.array([0, 1, 2, 3, -1, 0, 0, 0]), (rows, 1))
    r = NetworkResult(t, z + 0.2, z, z, edges, d, branch, d, np.full(rows, 0.2), [0] * N)
    csv = report.write_data(r, tmp_path / "ring-8", ("csv",))[0]
    head, first = csv.read_text().splitlines()[:2]
    names = head.split(",")
    assert names[:3] == ["t [s]", "q1 [m]", "q2 [m]"] and "u8 [m/s]" in names and "tau1 [N]" in names
    assert [n for n in names if n.startswith("d[")] == ["d[1-2]", "d[1-8]", "d[2-3]", "d[3-4]", "d[4-5]",
                                                         "d[5-6]", "d[6-7]", "d[7-8]"]
    cells = dict(zip(names, first.split(",")))
    assert cells["q1 [m]"] == "0.2" and cells["t [s]"] == "0.0"   # not 0.20000000000000001
    assert [cells[f"branch[{a + 1}-{b + 1}]"] for a, b in edges[:5]] == ["E", "J12", "J21", "J2", "none"]
    pair = PairResult(t, t[:, None], t[:, None], t[:, None], t[:, None], t[:, None], t[:, None], t, t.astype(int) * 0,
                      t)
    head = report.write_data(pair, tmp_path / "p", ("csv",))[0].read_text().splitlines()[0]
    assert head == "t [s],q1 [m],u1 [m/s],q2 [m],u2 [m/s],tau1 [N],tau2 [N],d,V,euclidean,branch"


def test_files_of_0_1_0_are_read(tmp_path):
    """0.1.0 wrote CSV names without units, %.17g numbers, branch codes as floats, and npz
    files without the meta member: pairs and single systems load; networks are refused."""
    rng = np.random.default_rng(1)
    rows = 7
    a = {k: rng.normal(size=(rows, 1)) for k in ("q1", "u1", "q2", "u2", "tau1", "tau2")}
    t = np.linspace(0.0, 0.6, rows)
    d = np.abs(rng.normal(size=rows))
    E = d + 0.1
    br = np.array([0, 1, 2, 3, 0, 0, 1])
    block = np.column_stack([t] + [a[k] for k in ("q1", "u1", "q2", "u2", "tau1", "tau2")]
                            + [d, d**2 / 2, E, br.astype(float)])
    np.savetxt(tmp_path / "old.csv", block, delimiter=",", header="t,q1,u1,q2,u2,tau1,tau2,d,V,euclidean,branch",
               comments="", fmt="%.17g")
    np.savez_compressed(tmp_path / "old.npz", t=t, d=d, branch=br, euclidean=E, V=d**2 / 2, **a)
    for name in ("old.csv", "old.npz"):
        r = fmu_sync.load(tmp_path / name)
        assert same_bits(r.t, t) and same_bits(r.d, d) and same_bits(r.euclidean, E) and list(r.branch) == list(br)
        for k, v in a.items():
            assert same_bits(getattr(r, k), v), (name, k)
        assert r.impacts1 is None    # not in a file of 0.1.0
    np.savetxt(tmp_path / "single.csv", np.column_stack([t, d, E, d]), delimiter=",", header="t,q,u,percussion",
               comments="", fmt="%.17g")
    s = fmu_sync.load(tmp_path / "single.csv")
    assert isinstance(s, SimulationResult) and same_bits(s.q[:, 0], d) and same_bits(s.percussion, d)
    np.savetxt(tmp_path / "net.csv", np.column_stack([t, d, d, d, d, d, d, d]), delimiter=",",
               header="t,q[1],q[2],u[1],u[2],tau[1],tau[2],d[1]", comments="", fmt="%.17g")
    np.savez(tmp_path / "net.npz", t=t, q=np.zeros((rows, 2)), u=np.zeros((rows, 2)), tau=np.zeros((rows, 2)))
    for name in ("net.csv", "net.npz"):
        with pytest.raises(ValueError, match="before 0.2.0 does not say which columns"):
            fmu_sync.load(tmp_path / name)


def test_load_says_what_it_cannot_read(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        fmu_sync.load(tmp_path / "nothing.npz")
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(ValueError, match=r"allowed: \.npz, \.csv"):
        fmu_sync.load(tmp_path / "x.txt")
    with pytest.raises(ValueError, match="is a folder"):
        fmu_sync.load(tmp_path)
    (tmp_path / "bad.csv").write_text("t [s],speed\n0.0,1.0\n")
    with pytest.raises(ValueError, match="unknown column 'speed'"):
        fmu_sync.load(tmp_path / "bad.csv")
    (tmp_path / "ft.csv").write_text("t [s],q [ft],u [m/s],percussion [N s]\n0.0,1.0,0.0,0.0\n")
    with pytest.raises(ValueError, match="in ft; fmu-sync writes q in m"):
        fmu_sync.load(tmp_path / "ft.csv")



def test_load_of_a_damaged_file_names_it_and_gives_no_unsafe_advice(tmp_path):
    """A garbage or cut-short .npz, a cut-short .csv, a member of an object array: a ValueError that
    names the file and the damage, never numpy's advice to unpickle or to "use usecols" (issue 28)."""
    r = simulate(ImpactOscillator(m=1.0, k=0.0, c=0.0, f0=-9.81, e=0.7), (1.0, 0.0), 1.5, 1e-3)
    npz, csv = report.write_data(r, tmp_path / "ball", ("npz", "csv"))[::-1]
    data = npz.read_bytes()
    cases = {"garbage.npz": b"garbage" * 20, "cut.npz": data[: len(data) // 2],
             "cut.csv": csv.read_bytes()[: len(csv.read_bytes()) // 2]}
    np.savez(tmp_path / "objects.npz", t=np.array([object()], dtype=object))
    damaged = bytearray(data)      # the zip directory intact, a compressed member garbled
    mid = data.index(b"q.npy") + 200
    damaged[mid:mid + 64] = b"\xff" * 64
    cases["damaged.npz"] = bytes(damaged)
    for name, blob in cases.items():
        (tmp_path / name).write_bytes(blob)
    for name in [*cases, "objects.npz"]:
        with pytest.raises(ValueError) as info:
            fmu_sync.load(tmp_path / name)
        msg = str(info.value)
        assert name in msg and "allow_pickle" not in msg and "usecols" not in msg, msg
        assert re.search(r"truncated|damaged|never writes", msg), msg
    with pytest.raises(ValueError, match=r"cut\.csv: line \d+ has \d+ values, the header names 4"):
        fmu_sync.load(tmp_path / "cut.csv")

def test_a_sweep_nc_loads_as_its_dataset(tmp_path):
    from fmu_sync.core.batch import COL
    from fmu_sync.sweeps.store import to_dataset, write_dataset
    out = np.zeros((4, max(COL.values()) + 1))
    out[:, COL["decay_rate"]] = [0.1, 0.2, 0.3, 0.4]
    ds = to_dataset(out, [""] * 4, ["coupling.Kp"], [np.array([1.0, 2.0, 3.0, 4.0])], [], {"scene": "x"})
    write_dataset(ds, tmp_path / "sweep.nc")
    back = fmu_sync.load(tmp_path / "sweep.nc")
    assert back["decay_rate"].values.tolist() == [0.1, 0.2, 0.3, 0.4] and back.attrs["scene"] == "x"


# ---------------------------------------------------------------- views
def test_to_xarray_has_units_long_names_dimensions_and_settings():
    N = 4
    edges = edges_of(ring(N, 1.0))
    rows = 5
    t = np.linspace(0, 1, rows)
    q = np.arange(rows * N * 2, dtype=float).reshape(rows, N, 2)
    d = np.ones((rows, len(edges)))
    r = NetworkResult(t, q, q, q, edges, d, np.zeros((rows, len(edges)), dtype=np.int64), d, np.ones(rows),
                      [1, 2, 3, 4], info={"mode": "core", "dt": 0.01, "coupling": "switching"})
    ds = r.to_xarray({"coupling.Kp": 4.0})
    assert dict(ds.sizes) == {"t": rows, "node": N, "dof": 2, "edge": len(edges)}
    assert ds["t"].attrs["units"] == "s" and list(ds["edge"].values) == ["1-2", "1-4", "2-3", "3-4"]
    for name, v in ds.data_vars.items():
        assert "units" in v.attrs and v.attrs["long_name"], name
    assert ds["q"].attrs["units"] == "m" and ds["u"].attrs["units"] == "m/s" and ds["tau"].attrs["units"] == "N"
    assert ds.attrs["info:dt"] == 0.01 and ds.attrs["coupling.Kp"] == 4.0 and ds.attrs["fmu_sync_result"] == "network"
    assert np.array_equal(ds["q"].sel(node=3, dof=2).values, q[:, 2, 1])


def test_repr_dataframe_and_plot_of_a_run():
    from matplotlib.figure import Figure
    osc = ImpactOscillator(m=1.0, k=1.0, f0=0.2, F=0.5, Omega=2.5, e=0.9)
    r1 = simulate(osc, (1.0, 0.0), 5.0, 1e-3, record_every=10)
    r2 = simulate(osc, (0.2, 0.5), 5.0, 1e-3, record_every=10)
    E = np.hypot(r1.q[:, 0] - r2.q[:, 0], r1.u[:, 0] - r2.u[:, 0])
    p = PairResult(r1.t, r1.q, r1.u, r2.q, r2.u, 0 * r1.q, 0 * r1.q, E, np.zeros(len(E), dtype=np.int64), E,
                   coupling=None)
    text = repr(p)
    assert text.startswith("PairResult(501 records, t = 0 .. 5 s") and len(text) < 160 and "ok" in text
    assert repr(r1).startswith("SimulationResult(") and "impact steps" in repr(r1) and len(repr(r1)) < 160
    df = p.to_dataframe()
    assert list(df.columns)[:3] == ["t [s]", "q1 [m]", "u1 [m/s]"] and len(df) == 501
    assert set(df["branch"].astype(str)) == {"E"}
    assert isinstance(p.plot(), Figure) and isinstance(r1.plot(), Figure)


# ---------------------------------------------------------------- the command line
def test_run_without_plots_then_plot_draws_them_from_the_data(tmp_path, capsys):
    """The issue's example: run --no-plots, then `fmu-sync plot D` writes the plots; the npz loads back."""
    D = tmp_path / "D"
    assert main(["run", "forced-pair", "--variant", "switching", "--no-plots", "--quiet", "--set", "run.t_end=8",
                 "--format", "csv,npz,nc", "-o", str(D)]) == 0
    assert not list(D.glob("*.png"))
    assert main(["plot", str(D)]) == 0
    drawn = sorted(p.name for p in D.glob("*.png"))
    assert drawn == sorted(f"switching-{k}.png" for k in ("positions", "distance", "impact-zoom", "lyapunov",
                                                            "forces", "phase"))
    assert all((D / n).read_bytes()[:4] == b"\x89PNG" for n in drawn)
    r = fmu_sync.load(D / "switching.npz")
    assert np.array_equal(r.d, np.load(D / "switching.npz")["d"])
    assert np.array_equal(fmu_sync.load(D / "switching.nc").d, r.d)
    assert r.coupling == "switching" and r.impacts1 > 0
    ds = r.to_xarray()
    assert all("units" in v.attrs for v in ds.data_vars.values())
    for p in D.glob("*.png"):
        p.unlink()
    assert main(["plot", str(D), "--only", "phase"]) == 0
    assert [p.name for p in D.glob("*.png")] == ["switching-phase.png"]
    capsys.readouterr()
    assert main(["plot", str(D), "--only", "nonsense"]) == 2
    assert "--only nonsense: not a plot; allowed: positions" in capsys.readouterr().err
    assert main(["plot", str(tmp_path / "nowhere")]) == 2


def test_scene_key_reference_is_generated_from_the_schema():
    from fmu_sync.scenes.reference import keys_markdown
    from fmu_sync.scenes.schema import KEYS, SYSTEM_KEYS
    page = (ROOT / "docs" / "scene-keys.md").read_text(encoding="utf-8")
    assert page == keys_markdown(), "docs/scene-keys.md is stale: regenerate it with keys_markdown()"
    for table, keys in [*KEYS.items(), *(("system", k) for k in SYSTEM_KEYS.values())]:
        for k in keys:
            assert f"| `{k}` |" in page, (table, k)
    assert "| `dt` | number | `0.001` | a finite real number > 0 | s |" in page


def test_scenes_show_prints_toml_that_loads_back_to_the_same_scene(tmp_path, capsys):
    from fmu_sync.scenes import builtin_names
    from fmu_sync.scenes.loading import load_scene
    for name in builtin_names():
        assert main(["scenes", "--show", name]) == 0
        text = capsys.readouterr().out
        tomllib.loads(text)
        path = tmp_path / f"{name}.toml"
        path.write_text(text)
        a, b = load_scene(name), load_scene(path)
        assert (a.description, a.plots, a.compare) == (b.description, b.plots, b.compare), name
        assert [v.name for v in a.variants] == [v.name for v in b.variants]
        for va, vb in zip(a.variants, b.variants):
            assert {k: x for k, x in va.cfg.items() if not k.startswith("plot.")} == \
                {k: x for k, x in vb.cfg.items() if not k.startswith("plot.")}, (name, va.name)
    assert main(["scenes", "--show", "no-such-scene"]) == 2


# ---------------------------------------------------------------- plots that say what they show
def test_phase_portrait_of_a_long_run_draws_the_last_turns():
    from fmu_sync.plots import PHASE_TURNS, tail_start
    t = np.linspace(0, 100, 20001)
    u = np.cos(2 * np.pi * t / 2.0)     # 50 turns
    i = tail_start(u)
    assert 2 * (PHASE_TURNS - 1) < (t[-1] - t[i]) < 2 * (PHASE_TURNS + 1)
    assert tail_start(u[:3000]) == 0    # 7.5 turns: drawn whole
    chatter = np.where(t > 50, 1e-9 * (-1) ** np.arange(t.size), u)   # a resting contact's chatter
    assert t[tail_start(chatter)] < 50 - 2 * (PHASE_TURNS - 1)


def test_plot_words(tmp_path):
    import matplotlib
    matplotlib.use("Agg")
    from fmu_sync.plots import _V_LABEL, _zero_note, _figure
    assert _V_LABEL[True] == "V = ½ Σ_edges a_ij d_ij²" and _V_LABEL[False] == "V = d²/2"
    fig, (ax,) = _figure()
    y = np.array([1.0, 0.0, 1.0, 0.0, 1.0])
    _zero_note(ax, np.arange(5.0), y, "k")
    (label,) = ax.get_legend_handles_labels()[1]
    assert "gaps" in label and "exactly 0 in 2 of the 5 records" in label and "(gaps)" not in label
    from fmu_sync.scenes import builtin_names
    from fmu_sync.scenes.loading import load_scene
    for name in builtin_names():
        sc = load_scene(name)
        if any(v.pair and not v.is_network and v.has_distance for v in sc.variants):
            assert "impact-zoom" in sc.plots, name


def test_log_colour_bars_have_plain_tick_labels():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm
    from fmu_sync.sweeps.plots import _colorbar
    fig, ax = plt.subplots()
    norm = LogNorm(0.003, 40.0)
    m = ax.pcolormesh(np.array([[0.003, 40.0]]), norm=norm)
    cb = _colorbar(fig, m, ax, "rate", norm)
    fig.canvas.draw()
    labels = [x.get_text() for x in cb.ax.get_yticklabels() if x.get_text()]
    plt.close(fig)
    assert labels and all(re.fullmatch(r"[0-9.]+", s) for s in labels), labels
    assert "10" in labels and "0.01" in labels


# ---------------------------------------------------------------- license, changelog, version
def test_license_changelog_and_version():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"   # an SPDX expression
    lic = (ROOT / "LICENSE").read_text()
    assert lic.startswith("MIT License") and "the fmu-sync authors" in lic and "WITHOUT WARRANTY" in lic
    log = (ROOT / "CHANGELOG.md").read_text()
    versions = re.findall(r"^## (\d+\.\d+\.\d+)(?! \(unreleased\))", log, flags=re.M)   # the released ones
    assert versions[:1] == [project["version"]] and "0.1.0" in versions
    assert fmu_sync.__version__ == project["version"]
    from fmu_sync.cli import _parser
    with pytest.raises(SystemExit):
        _parser().parse_args(["--version"])


def test_version_is_printed(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"fmu-sync {fmu_sync.__version__}"
    assert json.dumps(fmu_sync.__version__)
