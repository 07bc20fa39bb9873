"""The README and the docs pages: the Quickstart's two commands (CI runs the second), the README's
size, the demo table in one delimited place, and links that lead somewhere."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: pages other branches add (issues 19, 20, 21); a link to one of them may point nowhere until they
#: are merged — once a page exists, its links and anchors are checked like any other
PENDING = {"docs/results.md", "docs/ssp.md", "docs/fmi3.md", "docs/scene-keys.md"}


def _quickstart_commands(text: str) -> list[str]:
    """The non-empty lines of the first code block under the '## Quickstart' heading."""
    section = re.split(r"^## *Quick ?start\s*$", text, maxsplit=1, flags=re.M)
    assert len(section) == 2, "README.md has no '## Quickstart' section"
    block = re.search(r"^```[^\n]*\n(.*?)^```", section[1], re.S | re.M)
    assert block, "the Quickstart section has no code block"
    return [line.strip() for line in block.group(1).splitlines() if line.strip()]


def test_quickstart_holds_the_demo_then_the_test_command_ci_runs():
    demo, tests = _quickstart_commands(README.read_text())     # exactly two commands
    assert demo.endswith("fmu-sync demo")
    assert tests.endswith("python3 -m pytest -q")
    # PEP 668: a distribution's Python refuses pip outside a virtual environment; the first command
    # makes one and both install and run inside it
    venv = demo.split(" && ")[0].split()
    assert venv[:3] == ["python3", "-m", "venv"], demo
    env = venv[-1]
    for cmd in (demo, tests):
        for part in cmd.split(" && ")[1 if cmd is demo else 0:]:
            assert part.startswith(f"{env}/bin/"), part
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert any(tests in line for line in ci if not line.lstrip().startswith("#")), tests


def test_readme_is_short_and_the_reference_is_in_docs():
    text = README.read_text()
    assert len(text.splitlines()) <= 250
    pages = {p.name for p in (ROOT / "docs").glob("*.md")}
    assert {"core.md", "fmu.md", "cosimulation.md", "sweeps.md", "cli.md", "design.md", "benchmarks.md"} <= pages
    assert len(re.findall(r"^!\[", text, re.M)) == 1               # one picture


def test_the_demo_table_stands_in_one_delimited_place():
    text = README.read_text()
    assert text.count("<!-- demo table: begin") == 1 and text.count("<!-- demo table: end -->") == 1
    table = text.split("<!-- demo table: begin", 1)[1].split("<!-- demo table: end -->", 1)[0]
    rows = [line for line in table.splitlines() if line.startswith("|")]
    assert rows[0].startswith("| variant | mode | coupling |") and len(rows) >= 3
    outside = text.replace(table, "")
    assert "| variant | mode |" not in outside


def _anchor(heading: str) -> str:
    """GitHub's anchor of a markdown heading."""
    h = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return h.replace(" ", "-")


def test_local_links_lead_to_files_and_headings():
    bad = []
    for page in [README, *sorted((ROOT / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            rel = dest.relative_to(ROOT).as_posix() if dest.is_relative_to(ROOT) else str(dest)
            if not dest.exists():
                if rel not in PENDING:
                    bad.append(f"{page.name}: {target} (no such file)")
                continue
            if anchor and dest.suffix == ".md":
                heads = {_anchor(h) for h in re.findall(r"^#+ +(.*)$", dest.read_text(), re.M)}
                if anchor not in heads:
                    bad.append(f"{page.name}: {target} (no such heading in {rel})")
    assert not bad, "\n".join(bad)
