"""The package's layers point one way: no import cycle between its top-level parts, and
none between its modules.

Every import counts: at module level, inside functions (a lazy import is still a
dependency) and under ``TYPE_CHECKING``. ``from a.b import c`` depends on the module
``a.b.c`` when there is one, else on ``a.b``.
"""

import ast
from collections import defaultdict
from collections.abc import Iterable, Mapping
from pathlib import Path

import dynoplan

PACKAGE = Path(dynoplan.__file__).parent


def _modules(root: Path) -> dict[str, tuple[Path, bool]]:
    """Module name -> (file, is a package) for every ``.py`` file under ``root``."""
    found = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root.parent).with_suffix("").parts)
        package = parts[-1] == "__init__"
        if package:
            parts = parts[:-1]
        found[".".join(parts)] = (path, package)
    return found


def _import_graph(modules: Mapping[str, tuple[Path, bool]]) -> dict[str, set[str]]:
    """Module -> the package's modules it imports, anywhere in its file."""

    def known(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, (path, package) in modules.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parent = name.split(".") if package else name.split(".")[:-1]
                    parent = parent[:len(parent) - node.level + 1]
                    base = ".".join([*parent, *([node.module] if node.module else [])])
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                           for a in node.names]
            for target in targets:
                module = known(target)
                if module is not None and module != name:
                    graph[name].add(module)
    return graph


def _cycles(graph: Mapping[str, Iterable[str]]) -> list[set[str]]:
    """The strongly connected components of more than one node (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[set[str]] = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(graph[root]))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, edges = work[-1]
            for nxt in edges:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(graph.get(nxt, ()))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.add(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(component)
    return found


def _top_level(graph: Mapping[str, Iterable[str]]) -> dict[str, set[str]]:
    """The graph between the package's top-level parts (``dynoplan.X``)."""

    def part(module: str) -> str | None:
        parts = module.split(".")
        return parts[1] if len(parts) > 1 else None

    top: dict[str, set[str]] = defaultdict(set)
    for module, targets in graph.items():
        a = part(module)
        for target in targets:
            b = part(target)
            if a is not None and b is not None and a != b:
                top[a].add(b)
    return top


def test_the_checker_finds_a_cycle_through_a_function_local_import(tmp_path: Path):
    root = tmp_path / "pkg"
    (root / "low").mkdir(parents=True)
    (root / "high").mkdir()
    for folder in (root, root / "low", root / "high"):
        (folder / "__init__.py").write_text("")
    (root / "high" / "user.py").write_text("from pkg.low.base import thing\n")
    (root / "low" / "base.py").write_text(
        "def thing():\n    from pkg.high import user\n    return user\n")
    graph = _import_graph(_modules(root))
    assert _cycles(graph) == [{"pkg.high.user", "pkg.low.base"}]
    assert _cycles(_top_level(graph)) == [{"high", "low"}]
    (root / "low" / "base.py").write_text("def thing():\n    return 1\n")
    assert _cycles(_import_graph(_modules(root))) == []


def test_no_cycle_between_the_top_level_parts():
    graph = _top_level(_import_graph(_modules(PACKAGE)))
    for layer in ("reports", "envs", "pipeline", "models", "control", "planning"):
        assert layer in graph, f"dynoplan.{layer} imports nothing of the package?"
    assert _cycles(graph) == []


def test_no_cycle_between_modules():
    assert _cycles(_import_graph(_modules(PACKAGE))) == []
