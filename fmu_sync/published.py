"""``fmu-sync docs``: the numbers and figures the README and docs/ publish, written by the commands
that measure them (docs/benchmarks.md, "Published numbers").

    fmu-sync docs --list                       # every block: page, command, cost
    fmu-sync docs --regenerate [--only NAME]   # rerun the commands, rewrite the blocks and figures
    fmu-sync docs --check [--only NAME]        # rerun them, change nothing; exit 1 on a stale number

A **block** is the text between two marker lines of a page (``<!-- published: NAME begin ...`` and
``<!-- published: NAME end -->``; the README's demo table keeps its own markers), replaced whole by
the text its command prints now (the marker rule is the bench's, :func:`fmu_sync.benchmarks.publish`).
Several blocks share one run (a **source**: the demo, the SSP packages in our master's orders, the
convergence check, the network scenes), which runs once per call. ``--check`` compares the text, so
a number counts as stale when it prints differently at its published digits. Figures are copied from
the run that draws them. Timings are not here: ``fmu-sync bench --publish docs/benchmarks.md``
writes them (measured, dated, not reproducible to the digit). tests/test_published.py checks that
every block stands in its page and reruns the cheap sources.
"""
from __future__ import annotations

import argparse
import difflib
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["Block", "BLOCKS", "SOURCES", "ROOT", "markers", "main"]

#: the source checkout whose README.md and docs/ are published (an editable install's)
ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Block:
    name: str
    page: str                           #: relative to ROOT
    source: str                         #: the key of the run it comes from (:data:`SOURCES`)
    render: Callable[[object], str]     #: the source's output -> the block's markdown
    begin: str = ""                     #: marker lines (default ``<!-- published: NAME begin`` / ``end -->``)
    end: str = ""
    figures: tuple = ()                 #: (file in the source's folder, file under ROOT) copied on --regenerate

    def markers(self) -> tuple[str, str]:
        return markers(self.name) if not self.begin else (self.begin, self.end)


def markers(name: str) -> tuple[str, str]:
    return f"<!-- published: {name} begin", f"<!-- published: {name} end -->"


# ---------------------------------------------------------------- sources (one run each)
SSP_ORDERS = (("jacobi", "ours, jacobi"), ("delayed", "delayed (libcosim)"), ("delayed-zero", "delayed-zero (fmpy)"))
SSP_PACKAGES = (("forced pair, switching", "forced-pair", "switching"), ("ring-8", "ring-8", None))
SSP_T_END = 60.0


def _run_demo(tmp: Path):
    from .scenes.demo import run_demo
    return run_demo(tmp / "demo")


def _run_ssp_orders(tmp: Path):
    """Each package run by our master in each order (60 s at the package's H)."""
    from .ssp import run_ssp, write_ssp
    out = []
    for label, scene, variant in SSP_PACKAGES:
        p = write_ssp(scene, tmp / f"{scene}.ssp", variant, {"run.t_end": SSP_T_END})
        out.append((label, [(method, run_ssp(p, method=method)) for method, _ in SSP_ORDERS]))
    return out


def _run_convergence(tmp: Path):
    from .scenes.convergence import convergence
    return convergence("forced-pair", tmp / "convergence", variants=["switching"])


NETWORK_RUNS = (("ring-8", "core"), ("ring-8", "cosim"), ("mismatched-pair", "core"), ("mismatched-pair", "cosim"))


def _run_networks(tmp: Path):
    from .scenes.running import run_scene
    return [(scene, mode, run_scene(scene, tmp / f"{scene}-{mode}", {"run.mode": mode}, plots=False))
            for scene, mode in NETWORK_RUNS]


def _run_work_precision(tmp: Path):
    from .benchmarks import main as bench
    bench(["--only", "work-precision", "-o", str(tmp / "work-precision")])
    return tmp / "work-precision"


#: name -> (run(tmp) -> output, the command a reader runs, cheap enough for the test suite)
SOURCES = {
    "demo": (_run_demo, "fmu-sync demo", False),
    "ssp-orders": (_run_ssp_orders, "fmu-sync ssp forced-pair --variant switching -o pair.ssp && "
                   "fmu-sync run pair.ssp --method ORDER --set run.t_end=60 (and ring-8)", True),
    "convergence": (_run_convergence, "fmu-sync run forced-pair --variant switching --convergence", True),
    "networks": (_run_networks, "fmu-sync run ring-8 | mismatched-pair [--set run.mode=cosim]", True),
    "work-precision": (_run_work_precision, "fmu-sync report work-precision", False),
}


# ---------------------------------------------------------------- renderings
def _g(x: float, fmt: str = ".3g") -> str:
    return "never" if np.isinf(x) else format(x, fmt)


def _demo_table(sr) -> str:
    """The demo's summary table and, below it, its ensemble table (fmu_sync.ensemble)."""
    from .ensemble import HEADER, table_rows
    from .report import md_table, rows
    text = "\n".join(md_table(*rows(sr.runs, demo=True)))
    if sr.ensembles:
        n = sr.ensembles[0][3].n_starts
        text += (f"\n\nThe decay rate over {n} start states (`fmu-sync demo` writes it too; `fmu-sync run SCENE "
                 f"--starts {n}`):\n\n" + "\n".join(md_table(list(HEADER), table_rows(sr.ensembles))))
    return text


def _demo_impact(sr) -> str:
    """The co-simulated switching run's first impacts and the Euclidean error against d between them."""
    from .report import impact_records
    run = next(r for r in sr.runs if r.name == "switching-cosim")
    res = run.result
    first = [float(res.t[impact_records(res, i, run.variant.system)[0]]) for i in (1, 2)]
    a, b = sorted(first)
    win = (res.t >= a) & (res.t <= b)
    gap = np.asarray(res.euclidean)[win] - np.asarray(res.d)[win]
    return (f"In the impact window of the co-simulated switching run (`fmu-sync demo`), system 1 first hit the "
            f"wall at t = {first[0]:.3g} s and system 2 at t = {first[1]:.3g} s; in between, the Euclidean "
            f"error stood up to {gap.max():.3g} above d (median {np.median(gap):.3g}), while d itself did not jump "
            f"(the table's max(|x1-x2|-d) is the largest such gap over the whole run).")


def _ssp_orders(out) -> str:
    lines = [f"| package | order | t_sync (d < 1e-6) | decay rate (1/s) | max d at {SSP_T_END:g} s |",
             "|---|---|---:|---|---:|"]
    why = []
    for label, runs in out:
        for k, (method, r) in enumerate(runs):
            m = r.sync()
            rate = f"{m.rate:.2g} ± {m.rate_err:.1g}" if m.resolved else "—"
            if not m.resolved:
                why.append(f"{label}, {dict(SSP_ORDERS)[method]}: {m.reason}")
            lines.append(f"| {label if k == 0 else ''} | {dict(SSP_ORDERS)[method]} | {_g(m.t_sync, '.4g')} s | "
                         f"{rate} | {_g(float(r.d_max[-1]), '.2g')} |")
    if why:
        lines += ["", "A rate shown as — is not resolved (`SyncMetrics.reason`):", ""] + [f"- {w}" for w in why]
    label, runs = out[0]
    x = {m: np.concatenate([r.q.reshape(len(r.t), -1), r.u.reshape(len(r.t), -1)], axis=1) for m, r in runs}
    t = runs[0][1].t
    dev = [float(np.max(np.abs(x[m][t <= 1.0] - x["jacobi"][t <= 1.0]))) for m, _ in SSP_ORDERS[1:]]
    lines += ["", f"In the first second ({label}), the states of the delayed orders differ from Jacobi's by "
              f"{dev[0]:.2g} (libcosim's) and {dev[1]:.2g} (fmpy's)."]
    return "\n".join(lines)


def _convergence(run) -> str:
    from .scenes.convergence import format_table, verdicts
    return "\n".join([format_table(run.variants), ""] + [f"Verdict: {v}" for v in verdicts(run.variants)])


def _networks(out) -> str:
    from .report import md_table, rows
    lines = []
    for scene, mode, sr in out:
        lines += [f"`fmu-sync run {scene}" + (" --set run.mode=cosim`" if mode == "cosim" else "`") + ":", ""]
        lines += md_table(*rows([r for r in sr.runs if r.result is not None])) + [""]
    ring = next(sr for s, _, sr in out if s == "ring-8").runs[0].variant
    lam = np.sort(np.linalg.eigvalsh(np.diag(ring.network.A.sum(1)) - ring.network.A))[1]
    Kd, m = float(ring.cfg["coupling.Kd"]), float(ring.network.systems[0].M[0, 0])
    lines.append(f"Without impacts the ring's slowest relative mode would decay at λ₂·Kd/(2m) = "
                 f"{lam:.3g}·{Kd:g}/(2·{m:g}) = {lam * Kd / (2 * m):.3g} 1/s.")
    return "\n".join(lines)


def _work_precision_caption(folder: Path) -> str:
    """What the figure is, and the machine line of the run that drew it (its timings depend on the load)."""
    machine = next((line[2:] for line in (folder / "benchmarks.md").read_text().splitlines()
                    if line.startswith("- machine:")), "machine: not recorded")
    return ("The work–precision diagrams of the forced pair (the `forced-pair` scene: our parameters) and of the "
            "smooth damped pair (`damped-pair`: the wall far away, truth DOP853; the default `trapezoid` beside the "
            "midpoint and θ; on the forced pair with impacts every Moreau scheme is first order), as "
            "`fmu-sync report work-precision` drew them (one `work_precision_<scene>_<metric>.png` per scene and "
            "metric; the numbers at a line's ends are its coarsest and finest step: dt, rtol for solve_ivp, H for "
            "the co-simulation). The errors are reproducible; the run "
            f"times are this run's, {machine}.")


BLOCKS = (
    Block("demo-table", "README.md", "demo", _demo_table,
          "<!-- demo table: begin", "<!-- demo table: end -->",
          figures=(("cosim-vs-core.png", "docs/demo-cosim-vs-core.png"),
                   ("switching-cosim-impact-zoom.png", "docs/demo-impact-window.png"),
                   ("switching-cosim-distance.png", "docs/demo-switching-distance.png"))),
    Block("demo-impact", "docs/benchmarks.md", "demo", _demo_impact),
    Block("ssp-orders", "docs/ssp.md", "ssp-orders", _ssp_orders),
    Block("convergence", "docs/benchmarks.md", "convergence", _convergence),
    Block("networks", "docs/benchmarks.md", "networks", _networks),
    Block("work-precision-figure", "docs/benchmarks.md", "work-precision", _work_precision_caption,
          figures=(("work_precision_forced-pair_max_q.png", "docs/work-precision-forced-pair.png"),
                   ("work_precision_damped-pair_q.png", "docs/work-precision-damped-pair.png"))),
)


# ---------------------------------------------------------------- publishing
def _select(only) -> list[Block]:
    names = [b.name for b in BLOCKS] + list(SOURCES)
    bad = [n for n in only or () if n not in names]
    if bad:
        raise ValueError(f"--only {bad[0]!r}: no such block or source; choose among {', '.join(names)}")
    return [b for b in BLOCKS if not only or b.name in only or b.source in only]


def _rendered(blocks, tmp: Path, progress=print) -> dict:
    """Run each needed source once; {block name: markdown}."""
    outputs, out = {}, {}
    for b in blocks:
        if b.source not in outputs:
            progress(f"running {b.source}: {SOURCES[b.source][1]}")
            outputs[b.source] = SOURCES[b.source][0](tmp)
        out[b.name] = b.render(outputs[b.source]).rstrip() + "\n"
    return out


def main(argv=None) -> int:
    from .benchmarks import generated_part, publish
    p = argparse.ArgumentParser(prog="fmu-sync docs", description="The numbers and figures of the README and "
                                "docs/, written between markers by the commands that measure them.")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--regenerate", action="store_true", help="rerun the commands; rewrite the blocks and figures")
    g.add_argument("--check", action="store_true", help="rerun the commands; exit 1 where a page differs")
    g.add_argument("--list", action="store_true", help="list the blocks")
    p.add_argument("--only", action="append", metavar="NAME", help="a block or a source (repeatable)")
    args = p.parse_args(argv)
    blocks = _select(args.only)
    if args.list:
        for b in blocks:
            fn, cmd, cheap = SOURCES[b.source]
            print(f"{b.name:22s} {b.page:20s} {'(suite)' if cheap else '       '} {cmd}")
        return 0
    missing = sorted({b.page for b in blocks if not (ROOT / b.page).is_file()})
    if missing:
        raise ValueError(f"fmu-sync docs rewrites a source checkout's pages (an editable install); {ROOT} has no "
                         f"{', '.join(missing)}")
    for b in blocks:                                        # every page has its markers before anything runs
        generated_part(ROOT / b.page, *b.markers())
    with tempfile.TemporaryDirectory(prefix="fmu-sync-docs-") as tmp:
        new = _rendered(blocks, Path(tmp), lambda s: print(s, file=sys.stderr))
        stale = []
        for b in blocks:
            old = generated_part(ROOT / b.page, *b.markers())
            if old != new[b.name]:
                stale.append(b)
                diff = difflib.unified_diff(old.splitlines(), new[b.name].splitlines(), f"{b.page} (published)",
                                            f"{b.name} (now)", lineterm="", n=0)
                print("\n".join(diff))
            if args.regenerate:
                publish(new[b.name], ROOT / b.page, *b.markers())
                for src, dest in b.figures:
                    shutil.copyfile(Path(tmp) / b.source / src, ROOT / dest)
    verb = "changed (rewritten)" if args.regenerate else "stale"
    print(f"{len(stale)} of {len(blocks)} blocks {verb}" + (f": {', '.join(b.name for b in stale)}" if stale else ""))
    return 1 if stale and args.check else 0
