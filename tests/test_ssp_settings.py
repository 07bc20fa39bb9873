"""SSP packages as the truth (issue 44 items 5, 6, 8; issue 39 item 6): the connections run as
written or refused naming the connection; an inner FMU that refuses to instantiate is one
SlaveError carrying its logged reason (exit 2, one line); entries read with a size bound and
duplicate names refused; the run settings (exchange, hold, tol, H) kept in the package and
overridable with ``--set`` in ``fmu-sync run X.ssp``.

Every FMU is loaded in a child process (``python tests/test_ssp_settings.py SCENARIO ARGS.json
OUT.json``), as in tests/test_ssp.py; refusals before any instance exists run in pytest's process.
"""
from __future__ import annotations

import contextlib
import io
import json
import sys
import traceback
import zipfile
from pathlib import Path


# =============================================================== child side
def scenario_cli(a):
    """``fmu-sync run`` (fmu_sync.cli.main) of each case: exit status, stderr, what escaped."""
    from fmu_sync.cli import main
    out = {}
    for key, argv in a["cases"].items():
        err = io.StringIO()
        escaped = None
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                rc = main(argv)
        except BaseException:   # noqa: BLE001 -- what escaped is the finding
            rc, escaped = None, traceback.format_exc()
        out[key] = {"rc": rc, "stderr": err.getvalue(), "escaped": escaped}
    return out


def scenario_api_instantiate(a):
    """run_ssp of a package whose system FMUs' start file was edited: the exception's type and text."""
    from fmu_sync.ssp import run_ssp
    try:
        run_ssp(a["package"])
    except Exception as exc:   # noqa: BLE001 -- its type is the finding
        from fmu_sync.fmi_bridge import SlaveError
        return {"type": type(exc).__name__, "slave_error": isinstance(exc, SlaveError), "msg": str(exc),
                "call": getattr(exc, "call", None)}
    return {"type": None}


def scenario_host_guid(a):
    """FMUHost of an FMU given a model description with another GUID: what it raises."""
    from fmpy import read_model_description
    from fmu_sync.fmi_bridge import FMUHost, SlaveError
    md = read_model_description(a["fmu"])
    md.guid = "{00000000-0000-0000-0000-000000000000}"
    try:
        FMUHost(a["fmu"], instance_name="wrong", model_description=md)
    except SlaveError as exc:
        return {"msg": str(exc), "call": exc.call, "log": exc.log}
    return {"msg": None}


def scenario_settings(a):
    """run_ssp of a package with its own settings, and with overrides: what each run used."""
    from fmu_sync.ssp import run_ssp
    out = {}
    for key, kw in a["runs"].items():
        res = run_ssp(a["package"], **kw)
        out[key] = {k: res.info.get(k) for k in ("exchange", "hold", "tol")}
        out[key]["H"] = res.info["H_package"]
        out[key]["rows"] = len(res.t)
        out[key]["t_end"] = float(res.t[-1])
    return out


def _child_main(argv):
    name, args_path, out_path = argv
    Path(out_path).write_text(json.dumps(globals()[f"scenario_{name}"](json.loads(Path(args_path).read_text()))))


# =============================================================== parent side
import pytest  # noqa: E402

from fmu_sync.ssp import SSD, SspError, read_ssp, run_ssp, write_ssp  # noqa: E402
from _children import child  # noqa: E402


def _rezip(data: bytes, edits: dict, extra=()) -> bytes:
    """The zip archive ``data`` with entries edited (name -> function of the old bytes) and ``extra``
    (name, bytes) entries appended (a second entry of a name already there: a duplicate)."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as zi, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zo:
        for info in zi.infolist():
            raw = zi.read(info.filename)
            zo.writestr(info.filename, edits[info.filename](raw) if info.filename in edits else raw)
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)   # zipfile's "Duplicate name"
            for name, raw in extra:
                zo.writestr(name, raw)
    return out.getvalue()


def _sub(old: bytes, new: bytes):
    def edit(d: bytes) -> bytes:
        assert old in d, old
        return d.replace(old, new)
    return edit


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ssp-settings")
    return tmp, write_ssp("forced-pair", tmp / "pair.ssp", "switching", {"run.t_end": 0.2})


def _conn(a, ac, b, bc) -> bytes:
    return (f'<ssd:Connection startElement="{a}" startConnector="{ac}" endElement="{b}" '
            f'endConnector="{bc}" />').encode()


TAU1, TAU2 = _conn("coupling", "tau[1]", "system1", "tau"), _conn("coupling", "tau[2]", "system2", "tau")
Q1, U1 = _conn("system1", "q", "coupling", "q[1]"), _conn("system1", "u", "coupling", "u[1]")
#: the issue's four edits of the connections -> (edit of the .ssd, a part of the element named, of the reason)
CONNECTIONS = {
    "tau1-deleted": (_sub(TAU1, b""), "<ssd:Connections>", 'startConnector="tau[1]" endElement="system1"'),
    "tau-crossed": (lambda d: _sub(TAU2, _conn("coupling", "tau[2]", "system1", "tau"))(
        _sub(TAU1, _conn("coupling", "tau[1]", "system2", "tau"))(d)), 'startConnector="tau[1]"',
        "connects coupling.tau[1] to system1.tau, not to system2.tau"),
    "q-u-swapped": (lambda d: _sub(U1, _conn("system1", "q", "coupling", "u[1]"))(
        _sub(Q1, _conn("system1", "u", "coupling", "q[1]"))(d)), 'startConnector="u" endElement="coupling" '
        'endConnector="q[1]"', "connects system1.u to coupling.u[1], not to coupling.q[1]"),
    "connector-unknown": (_sub(Q1, _conn("system1", "position", "coupling", "q[1]")), 'startConnector="position"',
                          "system1.position is not an output that our master connects"),
}


@pytest.mark.parametrize("key", list(CONNECTIONS))
def test_edited_connections_are_refused_naming_the_connection(pair, key):
    """44.5: 0.6.0 ran each of these with a record identical to the unedited package's."""
    tmp, good = pair
    edit, element, reason = CONNECTIONS[key]
    bad = tmp / f"{key}.ssp"
    bad.write_bytes(_rezip(good.read_bytes(), {SSD: edit}))
    with pytest.raises(SspError) as exc:
        run_ssp(bad)
    assert exc.value.file == SSD and element in exc.value.element and reason in exc.value.reason, str(exc.value)
    assert "\n" not in str(exc.value)


def test_connections_written_are_the_ones_run(pair):
    """The writer's connections are the rule the runner checks (one function): the unedited package
    holds exactly them."""
    from fmu_sync.ssp.common import coupling_connections
    pkg = read_ssp(pair[1])
    assert sorted(pkg.connections) == sorted(coupling_connections(["system1", "system2"], ["q"], ["u"], ["tau"]))


def test_an_entry_above_the_size_bound_is_refused_unread(pair, monkeypatch):
    """44.8: an entry inflating above the bound is refused, naming it and its size (0.6.0 read it whole).
    The bound is lowered here so that the test stays small: the check is the same at 64 MiB."""
    import fmu_sync.ssp.reader as reader
    tmp, good = pair
    big = tmp / "big.ssp"
    big.write_bytes(_rezip(good.read_bytes(), {"resources/system1.ssv": lambda d: d + b" " * 3_000_000}))
    monkeypatch.setattr(reader, "MAX_ENTRY_BYTES", 2 * 2**20)
    with pytest.raises(SspError) as exc:
        read_ssp(big)
    assert exc.value.file == "resources/system1.ssv" and "above the 2,097,152 bytes" in exc.value.reason
    monkeypatch.undo()
    assert read_ssp(big).parameters["system1"]["m"] == 1.0       # below the default bound: read


def test_the_default_bound_refuses_400_MB(pair, tmp_path):
    """The issue's case at its size: an .ssv of 400 MB of blanks (about 400 kB compressed) is refused
    from its declared size, without inflating it."""
    import resource
    tmp, good = pair
    bomb = tmp_path / "bomb.ssp"
    with zipfile.ZipFile(good) as zi, zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as zo:
        for name in zi.namelist():
            if name != "resources/system1.ssv":
                zo.writestr(name, zi.read(name))
        with zo.open("resources/system1.ssv", "w", force_zip64=True) as f:
            chunk = b" " * 2**20
            for _ in range(400):
                f.write(chunk)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(SspError) as exc:
        read_ssp(bomb)
    assert "inflates to 419,430,400 bytes" in exc.value.reason
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000   # kB: never inflated


@pytest.mark.parametrize("name", [SSD, "resources/coupling.ssv"])
def test_duplicate_entry_names_are_refused(pair, name):
    """44.8: 0.6.0 used the last of two entries of one name without a word."""
    tmp, good = pair
    with zipfile.ZipFile(good) as zf:
        raw = zf.read(name)
    dup = tmp / "dup.ssp"
    dup.write_bytes(_rezip(good.read_bytes(), {}, [(name, raw)]))
    with pytest.raises(SspError) as exc:
        read_ssp(dup)
    assert exc.value.file == name and "two entries of this name" in exc.value.reason


def _edited_start(pair) -> Path:
    """The package with the start file inside both system FMUs edited (one value changed)."""
    tmp, good = pair
    start = "resources/fmu_sync_start.json"
    fmu_edit = lambda d: _rezip(d, {start: _sub(b'"k": 1.0', b'"k": 1.5')})   # noqa: E731
    bad = tmp / "edited-start.ssp"
    bad.write_bytes(_rezip(good.read_bytes(), {"resources/system1.fmu": fmu_edit, "resources/system2.fmu": fmu_edit}))
    return bad


@pytest.fixture(scope="module")
def runs(pair):
    tmp, good = pair
    bad = _edited_start(pair)
    cases = {"edited-start": ["run", str(bad), "-o", str(tmp / "o-bad"), "--quiet", "--no-plots"],
             "implicit-set": ["run", str(good), "-o", str(tmp / "o-set"), "--quiet", "--no-plots",
                              "--set", "run.exchange=implicit", "--set", "run.hold=foh", "--set", "run.H=0.02"],
             "bad-key": ["run", str(good), "-o", str(tmp / "o-key"), "--quiet", "--no-plots",
                         "--set", "coupling.Kp=3"]}
    return child(__file__, "cli", {"cases": cases}, tmp)


def test_cli_a_failed_instantiate_is_one_line_with_the_fmus_reason(runs):
    """44.6: 0.6.0 gave exit 1 and a 38-line traceback ending in ``Exception: Failed to instantiate model``."""
    got = runs["edited-start"]
    assert got["escaped"] is None, got["escaped"]
    lines = got["stderr"].strip().splitlines()
    assert got["rc"] == 2 and len(lines) == 1, got
    assert "fmi2Instantiate" in lines[0] and "fmu_sync_start.json" in lines[0] and "SHA-256" in lines[0], lines


def test_api_a_failed_instantiate_is_a_slave_error_with_the_fmus_reason(pair, tmp_path):
    """44.6: through the API 0.6.0 raised a bare Exception."""
    got = child(__file__, "api_instantiate", {"package": str(_edited_start(pair))}, tmp_path)
    assert got["slave_error"] and got["call"] == "fmi2Instantiate", got
    assert "fmu_sync_start.json" in got["msg"] and "changed after export" in got["msg"], got


def test_a_wrong_guid_is_a_slave_error_naming_the_guid(pair, tmp_path):
    """44.6: FMUHost itself (every master's one wrapper) raises the FMU's logged reason."""
    fmu = tmp_path / "system1.fmu"
    with zipfile.ZipFile(pair[1]) as zf:
        fmu.write_bytes(zf.read("resources/system1.fmu"))
    got = child(__file__, "host_guid", {"fmu": str(fmu)}, tmp_path)
    assert got["msg"] is not None and got["call"] == "fmi2Instantiate", got
    assert "GUID" in got["msg"] and "{00000000-0000-0000-0000-000000000000}" in got["msg"], got


def test_cli_set_on_a_package_takes_run_keys_only(runs):
    """39.6: --set run.exchange/hold/H is accepted for an SSP run; a key of the package's values is refused
    in one line naming it (0.6.0 refused every --set)."""
    assert runs["implicit-set"]["rc"] == 0, runs["implicit-set"]
    got = runs["bad-key"]
    assert got["rc"] == 2 and "coupling.Kp" in got["stderr"] and len(got["stderr"].strip().splitlines()) == 1, got


@pytest.fixture(scope="module")
def implicit(tmp_path_factory):
    """A scene with run.exchange = "implicit", run.hold = "foh" and run.tol written as a package (0.6.0
    dropped all three: its run then refused the package as unstable, or ran another exchange)."""
    tmp = tmp_path_factory.mktemp("ssp-implicit")
    return write_ssp("forced-pair", tmp / "imp.ssp", "switching", {
        "run.t_end": 0.1, "run.exchange": "implicit", "run.hold": "foh", "run.tol": 1e-3})


def test_the_package_keeps_the_run_settings(implicit):
    run = read_ssp(implicit).run
    assert run == {"exchange": "implicit", "hold": "foh", "tol": 1e-3, "event_aware": False, "H_min": None}


def test_a_package_without_them_runs_the_defaults(pair):
    """Packages of 0.6.0 (no fs:Run annotation) run as they did: explicit, zoh, no tol."""
    tmp, good = pair
    old = tmp / "old.ssp"
    old.write_bytes(_rezip(good.read_bytes(), {SSD: lambda d: d[:d.index(b"<ssc:Annotation type=\"org.fmu-sync")]
                                               + d[d.index(b"</ssd:Annotations>\n  </ssd:DefaultExperiment>"):]}))
    assert b"fmu-sync.run" not in zipfile.ZipFile(old).read(SSD)
    assert read_ssp(old).run == {"exchange": "explicit", "hold": "zoh", "tol": None, "event_aware": False,
                                 "H_min": None}


@pytest.mark.parametrize("edit, reason", [((b'exchange="implicit"', b'exchange="semi"'), "exchange 'semi' is not one of"),
                                          ((b'tol="0.001"', b'tol="-1"'), "tol '-1' must be > 0"),
                                          ((b'hold="foh"', b'hold="foh" speed="2"'), "unknown run setting 'speed'")])
def test_a_bad_run_setting_is_refused_naming_it(implicit, tmp_path, edit, reason):
    bad = tmp_path / "bad.ssp"
    bad.write_bytes(_rezip(implicit.read_bytes(), {SSD: _sub(*edit)}))
    with pytest.raises(SspError) as exc:
        read_ssp(bad)
    assert exc.value.element == "<ssd:DefaultExperiment> <fs:Run>" and reason in exc.value.reason


def test_run_ssp_uses_the_package_settings_and_the_overrides(implicit, tmp_path):
    """39.6: the package's exchange, hold and tol are the run's; settings= overrides each for one run."""
    got = child(__file__, "settings", {"package": str(implicit), "runs": {
        "package": {}, "explicit": {"settings": {"exchange": "explicit", "hold": "zoh", "tol": None}, "H": 0.005}}},
        tmp_path)
    assert got["package"]["exchange"] == "implicit" and got["package"]["hold"] == "foh", got
    assert got["package"]["tol"] == 1e-3 and got["package"]["t_end"] == pytest.approx(0.1), got
    ex = got["explicit"]
    assert ex["exchange"] == "explicit" and ex["hold"] == "zoh" and ex["tol"] is None and ex["H"] == 0.005, ex
    assert ex["rows"] == 21, ex       # every H = 0.005 over 0.1 s: the override's step, not the package's


def test_cli_ssp_overrides_are_checked_before_anything_runs():
    from fmu_sync.ssp.settings import overrides
    assert overrides({"run.tol": 1e-4, "run.exchange": "implicit", "run.H": 0.02}) == (
        {"H": 0.02}, {"tol": 1e-4, "exchange": "implicit"})
    for bad, part in (({"coupling.Kp": 2}, "takes --set run.t_end"), ({"run.tol": -1.0}, "finite number > 0"),
                      ({"run.tol": True}, "finite number > 0"), ({"run.event_aware": 1}, "true or false")):
        with pytest.raises(ValueError, match=part):
            overrides(bad)


if __name__ == "__main__":
    _child_main(sys.argv[1:])
