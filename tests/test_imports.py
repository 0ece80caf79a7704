"""The import graph of ``bench/`` and ``strategies/``: layers that point one way, no circles, and plugins
see only the public contract.

Every import counts, those inside functions too (a deferred import only hides a circle until the
day someone moves it to the top). For circles, imports under ``if TYPE_CHECKING:`` are left out (they
never run); for the layer order they count too, since a type named from a higher layer still ties a
lower module to it. The layer order is written in ``docs/architecture.md`` ("Layers").
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("bench", "strategies")

# The layers from the bottom: a module imports only from its own layer or the ones below it.
# Each entry: the layer's name and the module prefixes in it (the longest matching prefix decides).
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "errors, schema, names, files",
        ("bench", "bench.errors", "bench.schema", "bench.rundir", "bench.names", "bench.fileio", "bench.conf"),
    ),
    ("settings", ("bench.config",)),
    ("measure and metrics", ("bench.measure", "bench.metrics")),
    ("slam, datasets, the plugin contract", ("bench.slam", "bench.datasets", "bench.api", "strategies")),
    ("run", ("bench.run",)),
    ("sweep, report, viewer", ("bench.sweep", "bench.report", "bench.viewer")),
    (
        "cli",
        # the commands, and one kept at its documented path in its package (python -m bench.datasets.prepare)
        (
            "bench.cli",
            "bench.__main__",
            "bench.export",
            "bench.view",
            "bench.study",
            "bench.list_strategies",
            "bench.datasets.prepare",
        ),
    ),
)


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in sorted((REPO / pkg).rglob("*.py"))}


def _runtime_nodes(tree: ast.AST, typing: bool = False):
    """Every node except what sits under ``if TYPE_CHECKING:`` (with ``typing``, every node)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if not typing and isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                stack.extend(child.orelse)
                continue
            stack.append(child)


def imports_of(name: str, path: Path, modules: dict[str, Path], typing: bool = False) -> set[str]:
    """The project modules ``name`` imports (``from a import b`` is module ``a.b`` where that is one);
    with ``typing``, those under ``if TYPE_CHECKING:`` too."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in _runtime_nodes(ast.parse(path.read_text(), str(path)), typing):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        found.update(t for t in targets if t in modules and t != name)
    return found


def import_graph(typing: bool = False) -> dict[str, set[str]]:
    modules = _modules()
    return {name: imports_of(name, path, modules, typing) for name, path in modules.items()}


def layer_of(name: str) -> int:
    """The index in ``LAYERS`` of the layer whose longest prefix matches module ``name``."""
    best, best_len = -1, -1
    for i, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if (name == prefix or name.startswith(prefix + ".")) and len(prefix) > best_len:
                best, best_len = i, len(prefix)
    if best < 0:
        raise AssertionError(f"module {name} is in no layer; add its prefix to LAYERS (and docs/architecture.md)")
    return best


def upward_imports(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """Each import (importer, imported) from a lower layer up to a higher one."""
    return sorted((a, b) for a, targets in graph.items() for b in targets if layer_of(b) > layer_of(a))


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_checker_finds_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_the_graph_sees_deferred_imports():
    graph = import_graph()
    assert "bench.slam.strategy" in graph["bench.slam.system"]
    assert "bench.run.lifecycle" in graph["bench.cli.entry"]  # imported inside a function


@pytest.mark.parametrize("typing", [False, True], ids=["runtime", "with-type-only"])
def test_no_import_cycles_in_bench_and_strategies(typing):
    graph = import_graph(typing)
    found = cycles(graph)
    print(f"{len(graph)} modules, {sum(map(len, graph.values()))} imports, {len(found)} cycles")
    assert found == [], "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_the_checker_finds_an_upward_import():
    assert upward_imports(
        {"bench.run.setup": {"bench.cli.entry", "bench.errors"}, "bench.cli.entry": {"bench.run"}}
    ) == [("bench.run.setup", "bench.cli.entry")]
    assert layer_of("bench.config.settings") < layer_of("bench.slam.system") < layer_of("bench.run.loop")


def test_every_module_has_a_layer():
    for name in _modules():
        layer_of(name)


def test_no_import_points_up():
    """Each layer imports only from itself and the layers below it (docs/architecture.md, "Layers")."""
    found = upward_imports(import_graph(typing=True))
    names = [n for n, _ in LAYERS]
    assert found == [], f"{len(found)} imports point up: " + "; ".join(
        f"{a} ({names[layer_of(a)]}) -> {b} ({names[layer_of(b)]})" for a, b in found
    )


@pytest.mark.parametrize("name", sorted(n for n in _modules() if n.startswith("strategies")))
def test_strategies_use_only_the_public_contract(name):
    """A shipped strategy is written as a plugin is: ``bench.api`` (and the errors it re-exports), nothing else."""
    modules = _modules()
    used = {m for m in imports_of(name, modules[name], modules) if m.startswith("bench")}
    assert used <= {"bench.api"}, f"{name} imports {sorted(used - {'bench.api'})}; use bench.api"


def _main_of(name: str, path: Path, modules: dict[str, Path]) -> str | None:
    """The function ``python -m name`` runs (``module.function``), where the module has a ``__main__`` block
    calling a ``main`` it defines or imports; None for a module that is no command."""
    tree = ast.parse(path.read_text(), str(path))
    if not any(isinstance(n, ast.If) and "__main__" in ast.unparse(n.test) for n in tree.body):
        return None
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module in modules and any(a.name == "main" for a in node.names):
            return f"{node.module}.main"
    return f"{name}.main"


def test_one_module_path_per_command():
    """Each command runs under one ``python -m`` path: no two modules' ``__main__`` blocks run the same ``main``."""
    modules = _modules()
    runs: dict[str, list[str]] = {}
    for name, path in modules.items():
        target = _main_of(name, path, modules)
        if target is not None:
            runs.setdefault(target, []).append(name)
    twice = {t: sorted(m) for t, m in runs.items() if len(m) > 1}
    assert "bench.run.export.main" in runs, "the checker sees bench.export's command"
    assert twice == {}, f"commands with two module paths: {twice}"


def test_the_docs_name_the_same_layers():
    """docs/architecture.md's table of layers lists, row by row, the packages and modules of ``LAYERS``."""
    page = (REPO / "docs" / "architecture.md").read_text()
    section = page.split("## Layers", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| ") and line.split("|")[1].strip().isdigit()]
    assert len(rows) == len(LAYERS), f"docs/architecture.md lists {len(rows)} layers, LAYERS {len(LAYERS)}"
    for row, (layer, prefixes) in zip(rows, LAYERS, strict=True):
        for prefix in prefixes:
            if prefix != "bench":  # the package itself
                assert prefix.rpartition(".")[2] in row, f"layer '{layer}': {prefix} is not in its docs row: {row}"
