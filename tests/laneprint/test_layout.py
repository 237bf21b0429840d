"""The packages' layering: no module imports, even lazily inside a function, a module that imports it back."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def import_graph(package: str) -> dict[str, set[str]]:
    """Module -> the modules of the same package it imports (anywhere in its body)."""
    mods = {
        ".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__"): p
        for p in (ROOT / package).rglob("*.py")
    }
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            graph[mod] |= {
                n
                for n in names
                if n in mods and n != mod and not mod.startswith(n + ".") and not (mods[n].name == "__init__.py")
            }
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every import circle found by depth-first search (each reported once per entry point)."""
    found, state = [], {}

    def visit(node: str, stack: list[str]) -> None:
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                found.append(stack[stack.index(nxt) :] + [nxt])
            elif nxt not in state:
                visit(nxt, stack + [nxt])
        state[node] = "done"

    for n in sorted(graph):
        if n not in state:
            visit(n, [n])
    return found


@pytest.mark.parametrize("package", ["ingest", "indicators", "clustering", "rl", "laneprint"])
def test_no_import_circles(package):
    assert cycles(import_graph(package)) == []


TEST_TOOLS = {
    "laneprint/crash_harness.py": "tests/crash/crash_harness.py",
    "rl/testing.py": "tests/support/rl_workspaces.py",
    "ingest/mutations.py": "tests/support/ingest_mutations.py",
    "ingest/stack_examples.py": "tests/support/stack_examples.py",
    "indicators/synthetic.py": "tests/support/synthetic_decisions.py",
}


@pytest.mark.parametrize("product, support", sorted(TEST_TOOLS.items()))
def test_the_product_packages_hold_no_test_tools(product, support):
    assert not (ROOT / product).exists()
    assert (ROOT / support).exists()


def test_no_product_module_imports_the_test_tools():
    """The product never imports `tests` (the test tools are not installed with it)."""
    found = []
    for package in ["laneprint", "ingest", "indicators", "clustering", "rl", "dashboard"]:
        for path in (ROOT / package).rglob("*.py"):
            text = path.read_text()
            if "tests" not in text:  # no import of it can be there: parsing only the others keeps this test quick
                continue
            for node in ast.walk(ast.parse(text)):
                names = (
                    [node.module or ""]
                    if isinstance(node, ast.ImportFrom)
                    else [a.name for a in node.names]
                    if isinstance(node, ast.Import)
                    else []
                )
                found += [f"{path.relative_to(ROOT)}: {n}" for n in names if n.split(".")[0] == "tests"]
    assert found == []
