"""`fmu-sync bench`: the whole pipeline (work-precision with the FMU co-simulation, stability,
CSVs, diagrams, benchmarks.md) at --smoke size, in a child process (the FMU is never loaded in
the pytest process, see tests/test_fmu_run.py). --smoke shrinks ladders, horizons and repeats
and skips the core speed section; its numbers mean nothing, only the files are checked."""
import csv
import math
import os
import subprocess
import sys

import pytest

import fmu_sync.benchmarks as bench_pkg
from fmu_sync.benchmarks import work_precision as wp

ENV = {**os.environ, "CI": "true"}


PAGE_HEAD = "# A docs page\n\nwritten by hand\n"
PAGE_TAIL = "\n## Measured by hand\n\nkept as it is\n"


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    page = out / "page.md"
    page.write_text(f"{PAGE_HEAD}{bench_pkg.BEGIN} -->\nold numbers\n{bench_pkg.END}{PAGE_TAIL}")
    code = "import sys\nfrom fmu_sync.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    p = subprocess.run([sys.executable, "-c", code, "bench", "--quick", "--smoke", "-o", str(out),
                        "--publish", str(page)],
                       capture_output=True, text=True, env=ENV, timeout=900, cwd=out)   # a hang guard: a cold cache compiles everything
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-4000:]
    return out, p


def _read(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_files_are_written(bench):
    out, _ = bench
    for name in ("benchmarks.md", "work_precision.csv", "stability.csv"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    pngs = sorted(p.name for p in out.glob("work_precision_*.png"))
    assert "work_precision_bouncing-ball_rest_time.png" in pngs
    assert "work_precision_forced-pair_d.png" in pngs
    for p in out.glob("*.png"):
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_work_precision_csv(bench):
    out, _ = bench
    rows = _read(out / "work_precision.csv")
    assert list(rows[0]) == list(wp.Point.CSV_FIELDS)
    methods = {r["method"] for r in rows}
    assert {"midpoint", "theta0.5", "theta1", "exact", "solve_ivp", "cosim", "cosim-ea",
            "cosim-fine", "cosim-fine-ea"} <= methods
    assert {r["scene"] for r in rows} == {s.name for s in wp.SCENES}
    for r in rows:
        step, err, sec, rep = float(r["step"]), float(r["error"]), float(r["seconds"]), int(r["repeats"])
        assert step > 0 and sec > 0 and rep >= 1, r
        assert math.isfinite(err) or r["note"], r        # a missing error always says why
    # the exact solver is the reference (error 0), except against the closed-form rest time
    ex = [r for r in rows if r["method"] == "exact"]
    assert all(float(r["error"]) == 0.0 for r in ex if r["metric"] == "max_q")
    assert all(float(r["error"]) < 1e-12 for r in ex if r["metric"] == "rest_time")
    # an uncoupled co-simulation with slave dt = H is the core midpoint at dt = H
    for r in rows:
        if r["method"] == "cosim" and r["metric"] == "max_q":
            mid = [m for m in rows if m["method"] == "midpoint" and m["scene"] == r["scene"]
                   and m["metric"] == "max_q" and float(m["step"]) == float(r["step"])]
            if mid:
                assert float(r["error"]) == pytest.approx(float(mid[0]["error"]), rel=1e-9, abs=1e-15)


def test_stability_csv(bench):
    out, _ = bench
    rows = _read(out / "stability.csv")
    assert rows and {r["result"] for r in rows} <= {"pass", "FAIL"}
    groups = {r["group"] for r in rows}
    assert {"stiff-wall", "restitution", "zeno", "grazing", "coupling", "scale", "large-dt"} <= groups
    coup = [r for r in rows if r["method"].startswith("co-simulation") and "jacobi" in r["method"]]
    assert coup and all(r["result"] == "pass" for r in coup)


def test_bench_md_and_stdout(bench):
    out, p = bench
    md = (out / "benchmarks.md").read_text()
    assert md.startswith("# fmu-sync benchmarks\n\nWritten by `fmu-sync bench --quick --smoke -o ")
    for head in ("# fmu-sync benchmarks", "## Core speed", "## Work–precision", "## Stability",
                 "Measured order, midpoint, bouncing-ball", "Measured order, midpoint, forced-pair",
                 "## Co-simulation hold: zero- vs first-order", "| FOH | "):
        assert head in md, head
    assert "## Work–precision" in p.stdout and "## Stability" in p.stdout


def test_section_headings_are_stable_so_the_docs_links_hold(bench):
    """run details go below a heading, never into it: a published page keeps every anchor the
    docs link to (#core-speed, #fmu-cost, ...), and a heading the docs page has is found again"""
    import re
    from pathlib import Path
    out, _ = bench
    heads = re.findall(r"^## +(.*)$", (out / "benchmarks.md").read_text(), re.M)
    assert len(heads) >= 3
    assert not [h for h in heads if re.search(r"[0-9(]", h)], heads
    docs = (Path(__file__).resolve().parents[1] / "docs" / bench_pkg.PAGE).read_text()
    docs_heads = set(re.findall(r"^## +(.*)$", docs, re.M))
    missing = [h for h in heads if h not in docs_heads]
    assert not missing, missing


def test_publish_replaces_only_the_generated_part(bench):
    out, _ = bench
    report = (out / "benchmarks.md").read_text()
    page = (out / "page.md").read_text()
    assert page == f"{PAGE_HEAD}{bench_pkg.BEGIN} -->\n{report.rstrip()}\n{bench_pkg.END}{PAGE_TAIL}"
    assert "old numbers" not in page


@pytest.mark.parametrize("text", ["no markers\n", f"{bench_pkg.END}\n{bench_pkg.BEGIN} -->\n",
                                  f"{bench_pkg.BEGIN} -->\n{bench_pkg.BEGIN} -->\n{bench_pkg.END}\n"])
def test_publish_to_a_page_without_its_markers_is_refused_before_running(tmp_path, text):
    page = tmp_path / "page.md"
    page.write_text(text)
    with pytest.raises(ValueError, match="--publish .*page.md: the page must hold one line starting"):
        bench_pkg.main(["--smoke", "-o", str(tmp_path / "out"), "--publish", str(page)])
    assert not (tmp_path / "out").exists() and page.read_text() == text
    with pytest.raises(ValueError, match="not a file in an existing folder"):
        bench_pkg.main(["--smoke", "-o", str(tmp_path / "out"), "--publish", str(tmp_path / "no" / "p.md")])


def test_publish_to_a_new_page_writes_the_markers(tmp_path):
    page = bench_pkg.publish("# report\n\nnumbers\n", tmp_path / "new.md")
    text = page.read_text()
    assert text.startswith(bench_pkg.BEGIN) and text.endswith(bench_pkg.END + "\n")
    bench_pkg.publish("# report\n\nother numbers\n", page)        # and it can be refreshed
    assert "other numbers" in page.read_text() and "\nnumbers" not in page.read_text()


def test_the_published_docs_page_has_its_markers():
    from pathlib import Path
    text = (Path(__file__).resolve().parents[1] / "docs" / bench_pkg.PAGE).read_text()
    assert text.count(bench_pkg.BEGIN) == 1 and text.count(bench_pkg.END) == 1
    assert text.index(bench_pkg.BEGIN) < text.index(bench_pkg.END)
