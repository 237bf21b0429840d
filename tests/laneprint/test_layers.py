"""The layers across packages: a module imports (even lazily, inside a function) only its own layer or below.

Top to bottom: the application (`laneprint.app`: command line, end-to-end run, check, report
command, reference pages), the dashboard, rl, clustering, indicators, ingest, and the shared
base (every other module of `laneprint`, the simulator included). A module belongs to the
layer of the longest matching prefix, so `laneprint.app.cli` is the application while
`laneprint.workspace` is the base. (import-linter's layers contract cannot take a layer
that is a parent package of another, hence this test on its graph library, grimp.)
"""

from __future__ import annotations

import grimp
import pytest

LAYERS = ["laneprint.app", "dashboard", "rl", "clustering", "indicators", "ingest", "laneprint"]  # top to bottom
PACKAGES = ["laneprint", "ingest", "indicators", "clustering", "rl", "dashboard"]


def layer(module: str) -> str | None:
    """The layer of a module: the longest layer name that is the module or a package holding it."""
    found = [name for name in LAYERS if module == name or module.startswith(name + ".")]
    return max(found, key=len) if found else None


def upward_imports(graph: grimp.ImportGraph) -> list[str]:
    """Every import of a module from a layer above its own, as 'importer -> imported (line)'."""
    rank = {name: i for i, name in enumerate(LAYERS)}
    bad = []
    for importer in sorted(graph.modules):
        for imported in sorted(graph.find_modules_directly_imported_by(importer)):
            if rank[layer(imported)] < rank[layer(importer)]:
                lines = graph.get_import_details(importer=importer, imported=imported)
                bad.append(f"{importer} -> {imported} (line {', '.join(str(d['line_number']) for d in lines)})")
    return bad


def build() -> grimp.ImportGraph:
    return grimp.build_graph(*PACKAGES, cache_dir=None)  # no cache folder written into the tree


@pytest.fixture(scope="module")
def graph() -> grimp.ImportGraph:
    return build()


def test_every_module_has_a_layer(graph):
    assert [m for m in sorted(graph.modules) if layer(m) is None] == []


def test_no_module_imports_a_layer_above_its_own(graph):
    assert upward_imports(graph) == []


def test_an_upward_import_is_caught():
    """The check itself: the base importing a stage, and a stage importing the application, are refused."""
    graph = build()
    graph.add_import(importer="laneprint.workspace", imported="rl.runs", line_number=1, line_contents="import rl.runs")
    graph.add_import(importer="ingest.cli", imported="laneprint.app.cli", line_number=1, line_contents="import x")
    assert upward_imports(graph) == [
        "ingest.cli -> laneprint.app.cli (line 1)",
        "laneprint.workspace -> rl.runs (line 1)",
    ]
