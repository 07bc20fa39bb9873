"""The exported FMUs travel: their binaries load on an older Linux (no glibc symbol version newer
than GLIBC_2.17: RHEL 7, Ubuntu 14.04 and later; the Reference-FMUs need 2.14), checked with
``objdump -T`` on the FMI 2.0, FMI 3.0 and coupling FMUs' binaries (docs/fmu.md "The binary"),
and each says in its documentation/ what the target needs."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import zipfile

import pytest

from fmu_sync.fmu_docs import ENTRY

#: the newest glibc symbol version the binary may need
GLIBC_FLOOR = (2, 17)
NEEDS_OBJDUMP = pytest.mark.skipif(shutil.which("objdump") is None, reason="objdump (binutils) not installed")


@pytest.fixture(scope="module")
def binaries(tmp_path_factory, shared_fmu):
    tmp = tmp_path_factory.mktemp("portable")
    fmus = {"fmi2": shared_fmu("impact-oscillator"), "fmi3": shared_fmu("impact-oscillator", 3),
            "coupling": shared_fmu("coupling")}
    out = {"fmus": fmus}
    for kind, fmu in fmus.items():
        with zipfile.ZipFile(fmu) as zf:
            so = [n for n in zf.namelist() if n.startswith("binaries/") and n.endswith(".so")]
            assert len(so) == 1, so
            out[kind] = tmp / f"{kind}.so"
            out[kind].write_bytes(zf.read(so[0]))
    return out


def _dynamic_symbols(path):
    """(name, version or None, undefined) for every dynamic symbol of the binary."""
    p = subprocess.run(["objdump", "-T", str(path)], capture_output=True, text=True, check=True)
    rows = []
    for line in p.stdout.splitlines():
        m = re.match(r"^[0-9a-f]+\s.*?\s(\*UND\*|\.\S+)\s+[0-9a-f]+\s+(?:\((\S+)\)|(\S+))?\s*(\S+)$", line)
        if m:
            rows.append((m.group(4), m.group(2) or m.group(3), m.group(1) == "*UND*"))
    assert rows, p.stdout
    return rows


@NEEDS_OBJDUMP
@pytest.mark.parametrize("kind", ["fmi2", "fmi3", "coupling"])
def test_no_glibc_symbol_newer_than_the_floor(binaries, kind):
    rows = _dynamic_symbols(binaries[kind])
    glibc = {name: tuple(int(x) for x in ver[len("GLIBC_"):].split("."))
             for name, ver, _ in rows if ver and ver.startswith("GLIBC_")}
    too_new = {n: v for n, v in glibc.items() if v > GLIBC_FLOOR}
    assert not too_new, f"{kind}: glibc symbols newer than GLIBC_{'.'.join(map(str, GLIBC_FLOOR))}: {too_new}"
    # the calls the floor is about are bound to their old versions, not merely absent
    assert {glibc.get(n) for n in ("dlopen", "dlsym", "dlerror")} == {(2, 2, 5)}, glibc
    assert "stat" not in glibc and "fstat" not in glibc
    # every undefined function comes from a versioned library (no unversioned symbol left to chance)
    loose = [n for n, ver, und in rows
             if und and ver in (None, "Base") and not n.startswith(("_ITM_", "__gmon_start__", "__cxa_finalize"))]
    assert not loose, f"{kind}: undefined symbols without a version: {loose}"


@NEEDS_OBJDUMP
def test_libdl_is_a_dependency(binaries):
    """On glibc < 2.34 dlopen lives in libdl.so.2: the binary must name it (gcc links --as-needed)."""
    p = subprocess.run(["objdump", "-p", str(binaries["fmi2"])], capture_output=True, text=True, check=True)
    needed = re.findall(r"NEEDED\s+(\S+)", p.stdout)
    assert "libdl.so.2" in needed and "libc.so.6" in needed, needed
    assert not any(n.startswith("libpython") for n in needed), needed


@pytest.mark.parametrize("kind", ["fmi2", "fmi3", "coupling"])
def test_the_fmu_says_what_it_needs(binaries, kind):
    """documentation/ (FMI 2.0: _main.html, FMI 3.0: index.html) names the platform, Python, each
    package the build record requires with its range, how the Python is found and the variables;
    needsExecutionTool is false (docs/fmu.md gives the reason)."""
    with zipfile.ZipFile(binaries["fmus"][kind]) as zf:
        build = json.loads(zf.read("resources/fmu_sync_build.json"))
        page = zf.read(ENTRY[build["fmi_version"]]).decode()
        md = zf.read("modelDescription.xml").decode()
    assert ENTRY[build["fmi_version"]].endswith("index.html" if kind == "fmi3" else "_main.html")
    text = re.sub(r"<[^>]+>", "", page).replace("&gt;", ">").replace("&lt;", "<")
    assert "Python" in text and "libpython3.X" in text and "glibc 2.17" in text
    assert ("binaries/x86_64-linux/" if kind == "fmi3" else "binaries/linux64/") in text
    assert build["requires"]["numpy"] and f"numpy {build['requires']['numpy']}" in text
    for dist, spec in build["requires"].items():
        assert f"{dist} {spec}" in text and f"built with {dist} {build['built_with'][dist]}" in text
    for name in ("FMU_SYNC_PYTHON", "FMU_SYNC_CACHE", "PATH", "python3", "fmu_sync_python.txt"):
        assert name in text, name
    assert re.search(r'needsExecutionTool="false"', md)
