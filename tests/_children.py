"""Running a test module's scenario in a child process (``python MODULE SCENARIO ARGS.json OUT.json``):
FMUs are loaded there, never in pytest's process (docs/design.md: teardown at exit)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path


def child(module: str, name: str, args: dict, tmp: Path, timeout: float = 900.0):
    """Run ``scenario_<name>(args)`` of the test module file ``module`` in a fresh process; its JSON."""
    args_path = tmp / f"{name}.args.json"
    args_path.write_text(json.dumps(args))
    out_path = tmp / f"{name}.out.json"
    p = subprocess.run([sys.executable, module, name, str(args_path), str(out_path)],
                       capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, f"child {name} exited with {p.returncode}:\n{p.stderr[-3000:]}"
    return json.loads(out_path.read_text())


#: the plain C importer of tests/test_fmu_c_host.py and tests/test_fmu_travel.py
HOST_SRC = Path(__file__).parent / "c" / "fmu_host.c"


def compile_c_host(folder: Path, src: Path = HOST_SRC, libs: tuple = ("-ldl",)) -> Path:
    """The C host ``src`` (by default :data:`HOST_SRC`) compiled into ``folder``, named after it."""
    host = folder / Path(src).stem
    p = subprocess.run(["gcc", "-O2", "-Wall", "-o", str(host), str(src), *libs], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    return host


def unpack_fmu(fmu: Path, folder: Path) -> Path:
    """The FMU ``fmu`` unpacked into ``folder``, its binary executable (as an importer leaves it)."""
    import os
    import zipfile
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(folder)
    for so in folder.glob("binaries/*/*.so"):
        os.chmod(so, 0o755)
    return folder
