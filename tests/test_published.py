"""The docs' published numbers (fmu_sync/published.py, ``fmu-sync docs``): every block stands once in
its page, and the cheap ones print now what the pages publish (a stale number fails here; the demo's
and the figures' are checked by ``fmu-sync docs --check``, too long for the suite)."""
import subprocess
import sys

import pytest

from fmu_sync.benchmarks import generated_part
from fmu_sync.published import BLOCKS, ROOT, SOURCES, main


def test_every_block_stands_once_in_its_page_with_its_figures():
    for b in BLOCKS:
        text = generated_part(ROOT / b.page, *b.markers())     # one pair of markers, in order
        assert text.strip(), f"{b.name}: empty in {b.page}: run fmu-sync docs --regenerate --only {b.name}"
        for _, dest in b.figures:
            assert (ROOT / dest).is_file(), dest
    assert {b.source for b in BLOCKS} == set(SOURCES)


def test_the_pages_quote_no_paper_example():
    """Our parameters are never the paper's: no page or figure name says so."""
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        assert "paper-example" not in page.read_text(), page.name
    assert b"paper-example" not in (ROOT / "docs" / "work-precision-forced-pair.png").read_bytes()


def test_an_unknown_block_is_refused():
    with pytest.raises(ValueError, match="no such block or source; choose among demo-table"):
        main(["--check", "--only", "nonesuch"])


def test_a_stale_number_fails_the_check(tmp_path, monkeypatch, capsys):
    """--check reruns a source and exits 1 when the page prints something else (a source stood in
    for by a constant here; the real sources are rerun below)."""
    import fmu_sync.published as pub
    page = tmp_path / "page.md"
    page.write_text("a\n<!-- published: x begin -->\nrate 0.5\n<!-- published: x end -->\nb\n")
    monkeypatch.setattr(pub, "ROOT", tmp_path)
    monkeypatch.setattr(pub, "BLOCKS", (pub.Block("x", "page.md", "fake", lambda out: f"rate {out}"),))
    monkeypatch.setitem(pub.SOURCES, "fake", (lambda tmp: 0.52, "fake", True))
    assert pub.main(["--check"]) == 1
    assert "-rate 0.5\n+rate 0.52" in capsys.readouterr().out
    assert "rate 0.5\n" in page.read_text()                    # --check changes nothing
    assert pub.main(["--regenerate"]) == 0 and pub.main(["--check"]) == 0
    assert page.read_text() == "a\n<!-- published: x begin -->\nrate 0.52\n<!-- published: x end -->\nb\n"


@pytest.mark.slow
def test_the_cheap_published_numbers_are_what_their_commands_print_now(tmp_path):
    """The SSP orders, the convergence check and the network scenes, rerun (in a child process:
    it loads FMUs): exit 1 and a diff if a page is stale (then: fmu-sync docs --regenerate)."""
    cheap = [name for name, (_, _, is_cheap) in SOURCES.items() if is_cheap]
    assert {"ssp-orders", "convergence", "networks"} <= set(cheap)
    args = [a for name in cheap for a in ("--only", name)]
    p = subprocess.run([sys.executable, "-m", "fmu_sync.cli", "docs", "--check", *args], capture_output=True,
                       text=True, timeout=1200, cwd=tmp_path)
    assert p.returncode == 0, p.stdout[-4000:] + p.stderr[-2000:]
