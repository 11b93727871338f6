"""The layering of contfil: imports point only downward, and no module circles.

The map and the rule are in ``docs/dev/architecture.md``; this test is the
rule's enforcement. A lower layer that imports a higher one fails here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx
import pytest

ROOT = Path(__file__).resolve().parents[1] / "contfil"

#: Layers, lowest first; a module may import only its own layer or lower ones.
#: Longest prefix wins, so engine sub-layers refine the engine layer.
LAYERS: list[tuple[str, ...]] = [
    ("contfil", "contfil.errors", "contfil.protocol", "contfil._blas_threads"),
    ("contfil.engine.branch", "contfil.engine.problems.base"),
    ("contfil.engine.linalg", "contfil.engine.flows"),
    ("contfil.engine.events",),
    ("contfil.engine.problems",),
    ("contfil.engine.continuation",),
    ("contfil.engine.switching",),
    ("contfil.engine",),
    ("contfil.analysis",),
    ("contfil.models",),
    ("contfil.graph",),
    ("contfil.store",),
    ("contfil.explore",),
    ("contfil.plot",),
    ("contfil.app", "contfil.__main__"),
]


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _layer(module: str) -> int:
    best, best_len = -1, -1
    for k, prefixes in enumerate(LAYERS):
        for pre in prefixes:
            if (module == pre or module.startswith(pre + ".")) and len(pre) > best_len:
                best, best_len = k, len(pre)
    return best


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _runtime_imports(path: Path, module: str) -> set[str]:
    """Modules of contfil imported at run time (``TYPE_CHECKING`` blocks excluded)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    is_pkg = path.name == "__init__.py"
    out: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for sub in child.orelse:
                    visit(sub)
                continue
            if isinstance(child, ast.Import):
                out.update(a.name for a in child.names if a.name.startswith("contfil"))
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = module.split(".")
                    base = base if is_pkg else base[:-1]
                    base = base[: len(base) - (child.level - 1)]
                    target = ".".join(base + ([child.module] if child.module else []))
                else:
                    target = child.module or ""
                if target.startswith("contfil"):
                    out.add(target)
                    # ``from pkg import mod`` imports the submodule
                    for a in child.names:
                        if (ROOT.parent / (target + "." + a.name).replace(".", "/")).with_suffix(
                                ".py").exists():
                            out.add(target + "." + a.name)
            visit(child)

    visit(tree)
    return out


def _graph() -> nx.DiGraph:
    g = nx.DiGraph()
    for path in sorted(ROOT.rglob("*.py")):
        mod = _module_name(path)
        g.add_node(mod)
        for imp in _runtime_imports(path, mod):
            if imp != mod:
                g.add_edge(mod, imp)
    return g


def test_every_module_has_a_layer() -> None:
    missing = [m for m in _graph() if _layer(m) < 0]
    assert not missing, f"modules outside the layer map: {missing}"


def test_imports_point_down() -> None:
    g = _graph()
    upward = [f"{a} (layer {_layer(a)}) imports {b} (layer {_layer(b)})"
              for a, b in g.edges if _layer(b) > _layer(a)]
    assert not upward, "upward imports:\n" + "\n".join(upward)


def test_no_import_cycles() -> None:
    g = _graph()
    # a package's __init__ re-exporting its own submodules is not a circle
    g.remove_edges_from([(a, b) for a, b in list(g.edges) if b.startswith(a + ".")])
    cycles = [c for c in nx.strongly_connected_components(g) if len(c) > 1]
    assert not cycles, f"import circles: {cycles}"


def test_the_checker_sees_an_upward_import(tmp_path: Path) -> None:
    """The rule bites: an engine module importing the graph is reported."""
    bad = tmp_path / "contfil" / "engine" / "bad.py"
    bad.parent.mkdir(parents=True)
    bad.write_text("from contfil.graph.branch_graph import BranchGraph\n"
                   "if TYPE_CHECKING:\n    from contfil.app.cli import main\n")
    global ROOT
    saved, ROOT = ROOT, tmp_path / "contfil"
    try:
        imps = _runtime_imports(bad, "contfil.engine.bad")
    finally:
        ROOT = saved
    assert "contfil.graph.branch_graph" in imps and "contfil.app.cli" not in imps
    assert _layer("contfil.graph.branch_graph") > _layer("contfil.engine.bad")


@pytest.mark.parametrize("module", ["contfil.engine.problems.shooting",
                                    "contfil.models.filament.model",
                                    "contfil.app.cli"])
def test_layers_are_ordered(module: str) -> None:
    assert 0 < _layer(module) < len(LAYERS)
