"""The structure figures of issue 61, computed from a tree's own code with ``ast``.

    python profiling/import_figures.py [ROOT]     # ROOT: a checkout (default: this one)

Why: "layers that point one way" is a claim about the import graph; this prints the figures that
show it, measured the same way for any commit (check one out with ``git worktree add``), so a
before/after table is two runs of this script. The graph and the layer order are
``tests/test_imports.py``'s (this checkout's), applied to ROOT's modules:

- imports that point up: (importer, imported) pairs of modules whose layer is higher for the
  imported one; counted with the imports under ``if TYPE_CHECKING:`` and, in brackets, without;
- circles: strongly connected components of the module graph, with and without type-only imports;
- private names that cross modules: ``from M import _x`` (or ``import`` of a ``_module`` as a name)
  where M is another project module; each imported name counts once per importing file;
- functions of 90 lines or more (decorators left out, docstring included).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "tests"))

import test_imports as graph_module  # noqa: E402  (tests/ is not a package)

LONG_LINES = 90


def private_imports(modules: dict[str, Path]) -> list[tuple[str, str, str]]:
    """(importer, imported module, name) for each ``_name`` imported from another project module."""
    found = []
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not isinstance(node, ast.ImportFrom):
                continue
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            if base not in modules or base == name:
                continue
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__"):
                    found.append((name, base, alias.name))
    return found


def long_functions(modules: dict[str, Path], root: Path) -> list[tuple[int, str]]:
    found = []
    for path in modules.values():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = (node.end_lineno or node.lineno) - node.lineno + 1
                if lines >= LONG_LINES:
                    found.append((lines, f"{path.relative_to(root)}:{node.name}"))
    return sorted(found, reverse=True)


def main(root: Path) -> None:
    graph_module.REPO = root
    modules = graph_module._modules()
    full = {n: graph_module.imports_of(n, p, modules, typing=True) for n, p in modules.items()}
    runtime = {n: graph_module.imports_of(n, p, modules) for n, p in modules.items()}
    up, up_runtime = graph_module.upward_imports(full), graph_module.upward_imports(runtime)
    print(f"{root}: {len(modules)} modules, {sum(map(len, full.values()))} imports")
    print(f"imports that point up: {len(up)} (without type-only: {len(up_runtime)})")
    for a, b in up:
        print(f"  {a} -> {b}")
    for label, g in (("circles", runtime), ("circles with type-only imports", full)):
        found = graph_module.cycles(g)
        print(f"{label}: {len(found)}" + "".join(f"\n  {' <-> '.join(c)}" for c in found))
    private = private_imports(modules)
    print(f"private names imported across modules: {len(private)} in {len({a for a, _, _ in private})} files")
    for a, b, n in private:
        print(f"  {a} <- {b}.{n}")
    long = long_functions(modules, root)
    print(f"functions of {LONG_LINES}+ lines: {len(long)}")
    for lines, where in long:
        print(f"  {lines:4d} {where}")


if __name__ == "__main__":
    main(Path(sys.argv[1]).resolve() if len(sys.argv) > 1 else HERE)
