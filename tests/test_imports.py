"""Module structure (docs/design.md §3): every project module imports on its own,
in any order, in a fresh interpreter, and there is no import cycle among the
project's modules, counting deferred imports inside functions too."""
import ast
import json
import pkgutil
import random
import subprocess
import sys
from pathlib import Path

import pytest

import fmu_sync


def _modules() -> dict[str, Path]:
    """Every module of the installed project: name -> file."""
    import fmu_sync.core
    import fmu_sync.fmus
    out = {}
    for pkg in (fmu_sync, fmu_sync.core, fmu_sync.fmus):  # core/ and fmus/ are folders of their own
        out[pkg.__name__] = Path(pkg.__file__)
        for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
            spec = info.module_finder.find_spec(info.name)
            out[info.name] = Path(spec.origin)
    return out


MODULES = _modules()


def test_the_three_source_folders_are_all_seen():
    names = set(MODULES)
    assert {"fmu_sync.core.model", "fmu_sync.fmus.contract", "fmu_sync.master",
            "fmu_sync.scenes.loading", "fmu_sync.benchmarks.stability"} <= names
    assert len(names) > 30


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_every_module_imports_in_a_random_order(seed):
    order = sorted(MODULES)
    random.Random(seed).shuffle(order)
    code = ("import importlib, json, sys\n"
            "for name in json.loads(sys.argv[1]):\n"
            "    importlib.import_module(name)\n"
            "print('ok')\n")
    out = subprocess.run([sys.executable, "-c", code, json.dumps(order)], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "ok", (order, out.stderr[-2000:])


def _imports(name: str, path: Path) -> set[str]:
    """Project modules that ``name`` imports anywhere (module level or inside functions)."""
    is_pkg = path.name == "__init__.py"
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = name if is_pkg else name.rsplit(".", 1)[0]
            for _ in range(node.level - 1):
                base = base.rsplit(".", 1)[0]
            mod = (f"{base}.{node.module}" if node.module else base) if node.level else node.module
            targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
        else:
            continue
        found |= {t for t in targets if t in MODULES and t != name}
    # a package importing its own submodules (re-exports) is not a dependency back
    return {t for t in found if not (is_pkg and t.startswith(name + "."))}


def test_no_import_cycles():
    graph = {name: _imports(name, path) for name, path in MODULES.items()}
    WHITE, GREY, BLACK = 0, 1, 2
    color = dict.fromkeys(graph, WHITE)
    cycles = []

    def visit(v, stack):
        color[v] = GREY
        stack.append(v)
        for w in sorted(graph[v]):
            if color[w] == GREY:
                cycles.append(stack[stack.index(w):] + [w])
            elif color[w] == WHITE:
                visit(w, stack)
        stack.pop()
        color[v] = BLACK

    for v in sorted(graph):
        if color[v] == WHITE:
            visit(v, [])
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def _absolute(name: str, path: Path, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    for _ in range(node.level - 1):
        base = base.rsplit(".", 1)[0]
    return f"{base}.{node.module}" if node.module else base


def _private(part: str) -> bool:
    return part.startswith("_") and not part.startswith("__")


def test_no_private_name_is_imported_across_modules():
    """A private name stays in its module; a private module stays in its package."""
    bad = []
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            mod = _absolute(name, path, node)
            if not mod.startswith("fmu_sync"):
                continue
            targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in MODULES else mod for a in node.names]
            for a, target in zip(node.names, targets):
                if target == mod and _private(a.name):
                    bad.append(f"{name}: from {mod} import {a.name}")
                parts = target.split(".")
                for i, p in enumerate(parts):
                    owner = ".".join(parts[:i])
                    if _private(p) and not (name == owner or name.startswith(owner + ".")):
                        bad.append(f"{name}: imports the private module {target}")
    assert not bad, "\n".join(bad)


#: most lines of a module without a reason (issue 17)
MAX_LINES = 650
#: the one-line reason a longer module gives at its top (its first line)
LONG_REASON = "# long module: "


def _long_reason(path: Path) -> str:
    """The reason in the module's first line, "" if there is none (or only a word or two)."""
    first = (path.read_text().splitlines() or [""])[0]
    reason = first[len(LONG_REASON):].strip() if first.startswith(LONG_REASON) else ""
    return reason if len(reason) >= 10 else ""


def test_no_module_is_over_650_lines_without_a_reason_at_its_top():
    lines = {n: len(p.read_text().splitlines()) for n, p in MODULES.items()}
    assert {n: k for n, k in lines.items() if k > MAX_LINES and not _long_reason(MODULES[n])} == {}


def test_the_size_rule_reads_the_reason_at_the_top_only(tmp_path):
    top = tmp_path / "top.py"
    top.write_text("# long module: one numerical kernel that reads best in one piece\n\"\"\"Doc.\"\"\"\n")
    low = tmp_path / "low.py"
    low.write_text("\"\"\"Doc.\"\"\"\n# long module: one numerical kernel that reads best in one piece\n")
    bare = tmp_path / "bare.py"
    bare.write_text("# long module: \n")
    assert _long_reason(top) and not _long_reason(low) and not _long_reason(bare)


def test_benchmarks_use_the_public_api_only():
    """Benchmarks import the public API (fmu_sync, fmu_sync.core and its documented
    kernels/checks modules, the FMU contract), never a module's internals."""
    public = {"fmu_sync", "fmu_sync.core", "fmu_sync.core.kernels", "fmu_sync.core.checks",
              "fmu_sync.fmus.contract", "fmu_sync.progress"}
    bad = []
    for name, path in MODULES.items():
        if not name.startswith("fmu_sync.benchmarks"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                mod = _absolute(name, path, node)
                if mod.startswith("fmu_sync") and not mod.startswith("fmu_sync.benchmarks") and mod not in public:
                    bad.append(f"{name}: from {mod} import {', '.join(a.name for a in node.names)}")
            elif isinstance(node, ast.Import):
                bad += [f"{name}: import {a.name}" for a in node.names
                        if a.name.startswith("fmu_sync") and a.name not in public]
    assert not bad, "\n".join(bad)
