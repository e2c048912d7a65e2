"""The package's import structure: layers without circles, no private names across modules.

The layers are declared once, in pyproject.toml's ``[tool.importlinter]`` contract (import-linter
checks every import chain, direct or not, function-level imports included); this file also checks
what a layers contract cannot see: circles between modules of one package, and private names
(``_x``) imported from another module.
"""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

grimp = pytest.importorskip("grimp")  # (the test extra's import-linter brings it)

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "physhand_mj"


def _graph():
    return grimp.build_graph("physhand_mj", include_external_packages=False)


def test_the_layers_contract_is_kept():
    r = subprocess.run([sys.executable, "-c", "from importlinter.cli import lint_imports_command; lint_imports_command()"],
                       cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0 and "1 kept, 0 broken" in r.stdout, r.stdout[-3000:] + r.stderr[-2000:]


def test_no_import_circles_between_modules():
    g = _graph()
    edges = {m: g.find_modules_directly_imported_by(m) for m in g.modules}
    index, low, stack, on, circles, counter = {}, {}, [], set(), [], [0]

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                circles.append(sorted(comp))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in sorted(edges):
        if v not in index:
            visit(v)
    # a package's __init__ re-exporting its own submodules is not a circle: a submodule that imports
    # a sibling by its full name never runs through the package's __init__ in grimp's graph
    assert not circles, f"import circles: {circles}"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_no_private_name_imported_from_another_module():
    found = []
    for path in sorted(PKG.rglob("*.py")):
        mod = _module_name(path)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("physhand_mj"):
                for alias in node.names:
                    if alias.name.startswith("_") and not alias.name.startswith("__") and node.module != mod:
                        found.append(f"{mod}: from {node.module} import {alias.name}")
    assert not found, "private names imported across modules (make them public or move them): " + "; ".join(found)
