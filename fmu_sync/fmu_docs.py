"""The documentation an exported FMU carries (``documentation/_main.html`` in FMI 2.0, ``index.html``
in FMI 3.0): what the target machine needs, how the FMU finds its Python, the environment
variables it reads and the platform, written at export from the build record (docs/fmu.md
"What the target machine needs" is the long form)."""
from __future__ import annotations

from html import escape

__all__ = ["documentation_files", "ENTRY", "TESTED_PYTHON", "GLIBC_FLOOR", "ENVIRONMENT"]

#: the documentation's entry point per FMI version (FMI 2.0 §2.3 / FMI 3.0 §2.5 FMU distribution)
ENTRY = {2: "documentation/_main.html", 3: "documentation/index.html"}
#: the Python versions the FMU's code is tested with
TESTED_PYTHON = "3.10 to 3.13"
#: the oldest glibc the binary loads on (tests/test_fmu_portable.py)
GLIBC_FLOOR = "2.17"
#: the environment variables the FMU reads, and what for
ENVIRONMENT = (
    ("FMU_SYNC_PYTHON", "the Python interpreter to use in a plain C host (absolute path, e.g. a venv's bin/python); "
                        "ignored in a Python host, which runs the FMU in its own interpreter"),
    ("PATH", "searched for python3 when neither FMU_SYNC_PYTHON nor the interpreter recorded at export serves "
             "(/usr/local/bin:/usr/bin:/bin when unset)"),
    ("PYTHONPATH", "folders the chosen Python adds to its search path (numpy may be found there)"),
    ("FMU_SYNC_CACHE", "the folder the FMU's code is unpacked to once (default $XDG_CACHE_HOME/fmu-sync or "
                       "~/.cache/fmu-sync, else $TMPDIR, /tmp or /var/tmp)"),
    ("XDG_CACHE_HOME, HOME, TMPDIR", "where that default cache folder is"),
)


def _requirement_lines(requires: dict[str, str], built: dict) -> list[str]:
    return [f"<li><b>{escape(d)}</b> {escape(spec or '(any version)')} (this FMU was built with {escape(d)} "
            f"{escape(str(built.get(d)))})</li>" for d, spec in requires.items()]


def documentation_files(build: dict, model_name: str, description: str, platform: str) -> list[tuple[str, bytes]]:
    """(path in the .fmu, content) of the FMU's documentation; ``build``: the build record
    (resources/fmu_sync_build.json: requires, built_with, fmi_version, guid)."""
    fmi = int(build.get("fmi_version", 2))
    requires, built = build["requires"], build["built_with"]
    names = " ".join(f"python3-{d}" for d in requires)
    pip = " ".join(f"'{d}{s}'" for d, s in requires.items())
    env = "\n".join(f"<tr><td><code>{escape(k)}</code></td><td>{escape(v)}</td></tr>" for k, v in ENVIRONMENT)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{escape(model_name)}: what this FMU needs</title></head>
<body>
<h1>{escape(model_name)}</h1>
<p>{escape(description)}</p>
<p>FMI {fmi}.0 co-simulation FMU exported by fmu-sync {escape(str(build.get('fmu_sync_version')))}
(GUID <code>{escape(str(build.get('guid')))}</code>). fmu-sync itself is not needed to run it.</p>

<h2>Platform</h2>
<p>Linux on x86-64 (<code>binaries/{escape(platform)}/</code>), glibc {GLIBC_FLOOR} or newer (RHEL 7 and 8,
Ubuntu 20.04, Debian 11 and later). No other platform is included.</p>

<h2>What the target machine needs</h2>
<ul>
<li><b>Python</b> {TESTED_PYTHON} (built with Python {escape(str(built.get('python')))}), with its shared
library <code>libpython3.X.so.1.0</code> when the FMU is loaded by a C program (Debian/Ubuntu: the
<code>libpython3.X</code> package; python.org, conda, uv and pyenv builds with
<code>--enable-shared</code> have it). A Python host (fmpy, libcosimpy) runs the FMU in its own interpreter.</li>
{chr(10).join(_requirement_lines(requires, built))}
</ul>
<p>Each is checked when the FMU is instantiated: a missing or too old package makes the instantiation fail
(NULL, the reason logged) with the command that installs it, for example
<code>sudo apt-get install {escape(names)}</code> for a Debian/Ubuntu system Python or
<code>/path/to/venv/bin/python -m pip install {escape(pip)}</code> for a virtual environment.</p>

<h2>How the FMU finds its Python</h2>
<ol>
<li>In a Python host (fmpy, libcosimpy, a Python tool chain): that host's interpreter.</li>
<li><code>FMU_SYNC_PYTHON</code>, if set.</li>
<li>The interpreter recorded at export (<code>resources/fmu_sync_python.txt</code>), if it still exists,
its shared library is there and it has numpy.</li>
<li>Each <code>python3</code> on <code>PATH</code>, the first with numpy.</li>
</ol>
<p>This is decided from files, without running an interpreter. When none serves, the instantiation fails
with a message naming every interpreter tried, what it lacked, and the command that fixes it on that
machine.</p>

<h2>Environment variables</h2>
<table>
<tr><th>variable</th><th>use</th></tr>
{env}
</table>
</body></html>
"""
    return [(ENTRY[fmi], page.encode())]
