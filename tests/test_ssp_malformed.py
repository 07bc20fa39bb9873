"""Malformed SSP packages (issue 35 item 4): every one is refused before anything runs with one
:class:`fmu_sync.ssp.SspError` naming the package, the file inside it, the element and what is
wrong; ``fmu-sync run X.ssp`` exits 2 with that one line and no traceback.

The CLI runs in a child process (``python tests/test_ssp_malformed.py cli ARGS.json OUT.json``):
every case through ``fmu_sync.cli.main`` there, the unedited package too (exit 0), so no FMU is
loaded in pytest's process.
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
    """``fmu-sync run`` of each package in this one process: exit status, stderr, and the
    traceback of anything that escaped ``main``. The unedited package's run compiles the master's
    driver: with the run's compile locks (tests/conftest.py) it loads it if a worker compiled it."""
    if a.get("locks"):
        from _shared_compile import install
        install(a["locks"])
    from fmu_sync.cli import main
    out = {}
    for key, pkg in a["packages"].items():
        err = io.StringIO()
        escaped = None
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                rc = main(["run", pkg, "-o", str(Path(a["out"]) / key), "--quiet", "--no-plots"])
        except BaseException:   # noqa: BLE001 -- what escaped is the finding
            rc, escaped = None, traceback.format_exc()
        out[key] = {"rc": rc, "stderr": err.getvalue(), "escaped": escaped}
    return out


def _child_main(argv):
    name, args_path, out_path = argv
    Path(out_path).write_text(json.dumps(globals()[f"scenario_{name}"](json.loads(Path(args_path).read_text()))))


# =============================================================== parent side
import subprocess  # noqa: E402

import pytest  # noqa: E402
from hypothesis import HealthCheck, assume, given, settings, strategies as st  # noqa: E402

from fmu_sync.ssp import SSD, SspError, run_ssp, write_ssp  # noqa: E402
from _children import child  # noqa: E402

SYS1, CPL = "resources/system1.ssv", "resources/coupling.ssv"
MAP = "resources/coupling-extra.ssm"
_BIND = b'<ssd:ParameterBinding source="resources/coupling.ssv" />'
_MAPPED = (b'<ssd:ParameterBinding source="resources/system1.ssv"><ssd:ParameterMapping source="'
           + MAP.encode() + b'" /></ssd:ParameterBinding>' + _BIND)


def _replace(old: bytes, new: bytes, count: int = 1):
    def edit(data: bytes) -> bytes:
        assert old in data, old
        return data.replace(old, new, count)
    return edit


#: case -> (edits of the archive's entries: bytes, None (removed) or a function of the old bytes;
#:          the file inside the package, a part of the element, a part of the reason)
CASES = {
    "not-a-zip": ("whole", None, None, "not a zip archive"),
    "ssd-truncated": ({SSD: lambda d: d[: len(d) // 2]}, SSD, "line ", "not well-formed XML"),
    "ssd-not-xml": ({SSD: b"this is not XML\n"}, SSD, "line 1", "not well-formed XML"),
    "ssd-not-ssp": ({SSD: _replace(b"ssd:SystemStructureDescription", b"ssd:Package", 2)}, SSD,
                    "root element <ssd:Package>", "must be <ssd:SystemStructureDescription>"),
    "ssd-missing": ({SSD: None}, SSD, None, "missing"),
    "component-fmu-missing": ({"resources/system1.fmu": None}, SSD, 'source="resources/system1.fmu"',
                              "refers to resources/system1.fmu, which the package does not hold"),
    "coupling-fmu-missing": ({"resources/coupling.fmu": None}, SSD, 'name="coupling"',
                             "refers to resources/coupling.fmu, which the package does not hold"),
    "component-not-an-fmu": ({"resources/system2.fmu": b"not a zip"}, "resources/system2.fmu",
                             'name="system2"', "not an FMU (not a zip archive)"),
    "ssv-missing": ({"resources/system2.ssv": None}, SSD, 'ParameterBinding source="resources/system2.ssv"',
                    "does not hold"),
    "ssv-not-xml": ({SYS1: lambda d: d[:200]}, SYS1, "line ", "not well-formed XML"),
    "ssv-not-ssv": ({SYS1: _replace(b"ssv:ParameterSet", b"ssv:Parameters2", 2)}, SYS1,
                    "root element <ssv:Parameters2>", "must be <ssv:ParameterSet>"),
    "value-abc": ({SYS1: _replace(b'<ssv:Real value="1.0" />', b'<ssv:Real value="abc" />')}, SYS1,
                  '<ssv:Parameter name="m">', "value 'abc' is not a number"),
    "value-nan": ({SYS1: _replace(b'<ssv:Real value="0.0" />', b'<ssv:Real value="nan" />')}, SYS1,
                  '<ssv:Parameter name="c">', "value 'nan' is not a finite number"),
    "value-inf": ({CPL: _replace(b'<ssv:Real value="1.0" />', b'<ssv:Real value="-inf" />')}, CPL,
                  '<ssv:Parameter name="a[1,2]">', "value '-inf' is not a finite number"),
    "value-missing": ({CPL: _replace(b'<ssv:Real value="1.0" />', b"<ssv:Real />")}, CPL,
                      '<ssv:Parameter name="a[1,2]">', "has no value attribute"),
    "value-out-of-range": ({SYS1: _replace(b'<ssv:Real value="1.0" />', b'<ssv:Real value="-1.0" />')}, SYS1,
                           '<ssv:Parameter name="m">', "must be > 0, got -1.0"),
    "parameter-unknown": ({SYS1: _replace(b'name="m"', b'name="mass"')}, SYS1, '<ssv:Parameter name="mass">',
                          "has no variable 'mass'"),
    "both-steps-nan": ({SSD: lambda d: d.replace(b'baseStepSize="0.01"', b'baseStepSize="nan"')
                        .replace(b'fixedStepSize="0.01"', b'fixedStepSize="nan"')}, SSD,
                       "<osp:FixedStepAlgorithm>", "baseStepSize 'nan' is not a finite number"),
    "steps-differ": ({SSD: _replace(b'fixedStepSize="0.01"', b'fixedStepSize="0.02"')}, SSD,
                     "fixedStepSize", "two different communication steps"),
    "stop-time-inf": ({SSD: _replace(b'stopTime="1.0"', b'stopTime="inf"')}, SSD, "<ssd:DefaultExperiment>",
                      "stopTime 'inf' is not a finite number"),
    "stop-time-zero": ({SSD: _replace(b'stopTime="1.0"', b'stopTime="0"')}, SSD, "<ssd:DefaultExperiment>",
                       "stopTime '0' must be > 0"),
    "ssm-missing": ({SSD: _replace(_BIND, _MAPPED)}, SSD, 'ParameterBinding source="resources/system1.ssv"',
                    f"refers to {MAP}, which the package does not hold"),
    "ssm-not-xml": ({SSD: _replace(_BIND, _MAPPED), MAP: b"<ssm:ParameterMapping"}, MAP, "line 1",
                    "not well-formed XML"),
    "connection-to-nothing": ({SSD: _replace(b'startElement="system2"', b'startElement="system9"')}, SSD,
                              'startElement="system9"', "not a component"),
    "geometry-differs": ({CPL: _replace(b'name="e">\n      <ssv:Real value="0.9"', b'name="e">\n      '
                                        b'<ssv:Real value="0.8"')}, CPL, "geometry", "e differs"),
}


def _edited(src: Path, dst: Path, edits) -> Path:
    if edits == "whole":
        dst.write_bytes(b"PK but not a zip archive")
        return dst
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for name in zin.namelist():
            if name in edits:
                e = edits[name]
                if e is None:
                    continue
                data = e(zin.read(name)) if callable(e) else e
            else:
                data = zin.read(name)
            zout.writestr(name, data)
        for name, e in edits.items():   # new entries
            if name not in zin.namelist() and isinstance(e, bytes):
                zout.writestr(name, e)
    return dst


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("malformed")
    good = write_ssp("forced-pair", tmp / "pair.ssp", "switching", {"run.t_end": 1.0})
    bad = {key: _edited(good, tmp / f"{key}.ssp", case[0]) for key, case in CASES.items()}
    return tmp, good, bad


@pytest.mark.parametrize("key", list(CASES))
def test_run_ssp_refuses_each_malformed_package_naming_where(pair, key):
    """run_ssp: one SspError (a ValueError) naming the package, the file inside it, the element, the reason."""
    _, _, bad = pair
    _, file, element, reason = CASES[key]
    with pytest.raises(SspError) as exc:
        run_ssp(bad[key])
    e = exc.value
    assert isinstance(e, ValueError) and e.package == str(bad[key])
    assert e.file == file and reason in e.reason, (e.file, e.element, e.reason)
    if element is not None:
        assert element in e.element, e.element
    msg = str(e)
    assert msg.startswith(f"SSP package {bad[key]}") and reason in msg and "\n" not in msg


@pytest.fixture(scope="module")
def cli(pair, compile_locks):
    tmp, good, bad = pair
    return child(__file__, "cli", {"packages": {"good": str(good), **{k: str(v) for k, v in bad.items()}},
                                   "out": str(tmp / "out"), "locks": compile_locks}, tmp)


@pytest.mark.parametrize("key", list(CASES))
def test_cli_run_exits_2_with_one_line_for_each_malformed_package(cli, pair, key):
    got = cli[key]
    assert got["escaped"] is None, got["escaped"]
    assert got["rc"] == 2, got
    lines = got["stderr"].strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"fmu-sync: error: SSP package {pair[2][key]}"), lines
    assert "Traceback" not in got["stderr"] and CASES[key][3] in lines[0]
    assert not (pair[0] / "out" / key).exists()     # nothing written


def test_cli_runs_the_unedited_package(cli):
    """The control: the package every case was edited from runs (exit 0)."""
    assert cli["good"]["rc"] == 0 and cli["good"]["escaped"] is None, cli["good"]


@pytest.mark.parametrize("key", ["ssd-truncated", "component-fmu-missing"])
def test_cli_in_its_own_process_exits_2_without_traceback(pair, key, tmp_path):
    """The issue's two cases as a user meets them: ``python -m fmu_sync.cli run X.ssp``."""
    p = subprocess.run([sys.executable, "-m", "fmu_sync.cli", "run", str(pair[2][key]), "-o", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
    assert p.stderr.startswith(f"fmu-sync: error: SSP package {pair[2][key]}, {CASES[key][1]}")


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_any_truncated_xml_file_is_refused_naming_it(pair, tmp_path, data):
    """Property: an .ssd or .ssv cut anywhere (so that it is no longer complete XML) is refused
    with an SspError naming that file and a line, never another exception."""
    _, good, _ = pair
    with zipfile.ZipFile(good) as zf:
        names = sorted(n for n in zf.namelist() if n.endswith((".ssd", ".ssv")))
        name = data.draw(st.sampled_from(names))
        raw = zf.read(name)
    cut = data.draw(st.integers(0, len(raw) - 1))
    from xml.etree import ElementTree as ET
    try:
        ET.fromstring(raw[:cut])
        assume(False)          # still complete XML (only trailing whitespace was cut)
    except ET.ParseError:
        pass
    bad = _edited(good, tmp_path / f"cut-{cut}.ssp", {name: raw[:cut]})
    with pytest.raises(SspError) as exc:
        run_ssp(bad)
    assert exc.value.file == name and exc.value.element.startswith("line "), str(exc.value)
    assert "not well-formed XML" in exc.value.reason


if __name__ == "__main__":
    _child_main(sys.argv[1:])
