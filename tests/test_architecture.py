"""The import graph of igljoin follows docs/architecture.md: imports point down, no cycle.

Every ``import`` of one igljoin module by another counts, at module level and
inside functions (a function-level import is still a dependency). The
packages ``io`` and ``viz`` count as one unit each, as the architecture page
lists them; ``igljoin/__init__.py`` is the public facade above everything and
is left out.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "igljoin"
PACKAGES = ("io", "viz")  # sub-packages that are one unit of the architecture


def _unit(path: Path) -> str:
    """Architecture unit of a source file: its module name, or its sub-package's name."""
    rel = path.relative_to(PACKAGE)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _imported_units(path: Path) -> set[str]:
    """The igljoin units a file imports, anywhere in the file (module or function level)."""
    rel = path.relative_to(PACKAGE)
    depth = len(rel.parts) - 1  # 0 for igljoin/x.py, 1 for igljoin/io/x.py
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                base = node.module or ""
            else:
                up = node.level - 1  # levels above the file's own package
                if up > depth:
                    continue
                here = list(rel.parts[: depth - up])
                base = ".".join(["igljoin", *here, *([node.module] if node.module else [])])
            # ``from igljoin import a, b`` names modules; ``from igljoin.x import y`` names x
            if base in ("igljoin",):
                targets = [f"igljoin.{a.name}" for a in node.names]
            else:
                targets = [base]
        for name in targets:
            parts = name.split(".")
            if parts[0] != "igljoin" or len(parts) < 2:
                continue
            out.add(parts[1])
    own = _unit(path)
    return {u for u in out if u != own}


def import_graph() -> dict[str, set[str]]:
    """Unit -> units it imports, over every igljoin source file but ``__init__.py``."""
    graph: dict[str, set[str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        if path == PACKAGE / "__init__.py":
            continue
        unit = _unit(path)
        graph.setdefault(unit, set()).update(_imported_units(path))
    modules = {p.stem for p in PACKAGE.glob("*.py")} | set(PACKAGES)
    return {u: {v for v in deps if v in modules} for u, deps in graph.items()}


def architecture_order() -> dict[str, int]:
    """Rank of each unit on docs/architecture.md (0 at the top; one line may list two)."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    block = re.search(r"```\n(.*?)```", text, re.S).group(1)
    rank: dict[str, int] = {}
    row = 0
    for line in block.splitlines():
        if not line or line[0].isspace():
            continue  # a continued description
        names = re.match(r"([\w/.]+(?:, [\w/.]+)*)\s", line).group(1)
        for name in names.split(", "):
            rank[name.removesuffix(".py").removesuffix("/")] = row
        row += 1
    return rank


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``graph`` as a list of units, or None."""
    state: dict[str, int] = {}  # 1 on the current path, 2 done
    path: list[str] = []

    def visit(u: str) -> list[str] | None:
        state[u] = 1
        path.append(u)
        for v in sorted(graph.get(u, ())):
            if state.get(v) == 1:
                return path[path.index(v) :] + [v]
            if v not in state and (found := visit(v)):
                return found
        path.pop()
        state[u] = 2
        return None

    for u in sorted(graph):
        if u not in state and (found := visit(u)):
            return found
    return None


def test_the_import_graph_has_no_cycle():
    graph = import_graph()
    assert len(graph) > 20 and graph["join"], "the parser found the package's imports"
    assert _cycle(graph) is None, f"import cycle: {' -> '.join(_cycle(graph))}"


def test_every_module_is_on_the_architecture_page():
    rank = architecture_order()
    missing = sorted(set(import_graph()) - set(rank))
    assert not missing, f"modules missing from docs/architecture.md: {missing}"
    stale = sorted(set(rank) - set(import_graph()))
    assert not stale, f"docs/architecture.md lists modules that do not exist: {stale}"


def test_imports_point_down_the_architecture_page():
    rank = architecture_order()
    upward = sorted(
        f"{u} imports {v}" for u, deps in import_graph().items() for v in deps if rank[v] < rank[u]
    )
    assert not upward, f"imports that point up docs/architecture.md: {upward}"


def test_the_checks_catch_a_cycle_and_an_upward_import():
    """The helpers above find what they are for (a graph with a known cycle)."""
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None
    graph = import_graph()
    assert "weld" in graph["result"]  # result welds its join
    assert "result" not in graph["weld"] and "join" not in graph["result"]
