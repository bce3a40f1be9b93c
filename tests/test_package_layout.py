"""The Python package is three rooms with no import cycles: ``csb`` the library a user imports,
``csb.studies`` the study framework and its shared set-ups, ``csb.bench`` the benchmarks and the
peers' adapters. The library never imports the other two (the command line, a thin layer over
all three, is the one exception), the studies never import the benchmarks, and no module
imports, at run time, a module that imports it back. Read from the source with ``ast``: every
import counts, at the top of a module or inside a function, but those under
``if TYPE_CHECKING:``, which never run."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "python"
PACKAGE = ROOT / "csb"
MODULES = {
    ".".join(p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__"): p
    for p in PACKAGE.rglob("*.py") if "scenes" not in p.parts
}
COMPILED = {"csb._core"}  # the extension module: imports of it are no edge of this graph


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imported(module: str, path: Path) -> set[str]:
    """The csb modules `module` imports at run time (a name imported from a package that is one
    of its modules counts as that module)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.split(".")[0] == "csb")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            if source.split(".")[0] == "csb":
                for a in node.names:
                    name = f"{source}.{a.name}"
                    if name not in COMPILED:
                        found.add(name if name in MODULES else source)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text(), str(path)))
    return {m for m in found if m in MODULES and m != module}


GRAPH = {m: _imported(m, p) for m, p in MODULES.items()}


def _room(module: str) -> str:
    for room in ("csb.studies", "csb.bench"):
        if module == room or module.startswith(room + "."):
            return room
    return "csb"


def test_the_three_rooms_exist():
    assert {"csb", "csb.scene", "csb.runner", "csb.view", "csb.studies", "csb.studies.collisions",
            "csb.studies.soft_bodies", "csb.studies.report", "csb.bench", "csb.bench.peers"} <= set(MODULES)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_rooms_depend_one_way(module):
    allowed = {"csb": {"csb"}, "csb.studies": {"csb", "csb.studies"}, "csb.bench": {"csb", "csb.studies", "csb.bench"}}
    if module == "csb.cli":  # the command line: a thin layer over the three
        return
    wrong = sorted(m for m in GRAPH[module] if _room(m) not in allowed[_room(module)])
    assert not wrong, f"{module} (in {_room(module)}) imports {wrong}"


def test_no_import_cycles():
    # Depth-first search for a back edge; the package's own __init__ is where its public names are
    # gathered, so an edge into a package from one of its modules is an import of a sibling.
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for n in sorted(GRAPH[m]):
            if state.get(n) == 1:
                cycle = stack[stack.index(n):] + [n]
                pytest.fail("import cycle: " + " -> ".join(cycle))
            if n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(GRAPH):
        if m not in state:
            visit(m)


def test_the_graph_is_read():
    # The reader finds the edges it must: a relative import, a name imported from a package that is
    # a module, an import inside a function; and skips the ones under TYPE_CHECKING.
    assert "csb.scene_file" in GRAPH["csb.runner"]
    assert "csb.mesh" in GRAPH["csb.studies.soft_bodies"]  # from ..mesh import
    assert "csb.bench" in GRAPH["csb.bench.peers"]
    assert "csb.runner" in GRAPH["csb.scene"]          # inside Scene.run
    assert "csb.scene" not in GRAPH["csb.runner"]      # only under TYPE_CHECKING
    assert "csb.studies.report" not in GRAPH["csb.cli"] and "csb.bench.peers" in GRAPH["csb.cli"]
