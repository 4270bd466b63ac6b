"""The import graph of the stand's packages has no circle: no strongly connected component of more than one module.

grimp sees every import, function-local ones too, so a circle cannot hide behind a lazy import. A circle makes
the import order matter and each module of it depend on all the others (issue 23, "the core without circles").
"""

from __future__ import annotations

import grimp

PACKAGES = ("stand", "drivers", "sim", "star_screen")


def strongly_connected(graph) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative: no recursion
    limit on a long chain of imports), each sorted, largest first."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    out: list[list[str]] = []
    edges = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    counter = 0
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, 0)]
        while work:
            node, i = work.pop()
            if i == 0:
                index[node] = low[node] = counter
                counter += 1
                stack.append(node)
                on_stack.add(node)
            succ = edges.get(node, [])
            if i < len(succ):
                work.append((node, i + 1))
                nxt = succ[i]
                if nxt not in index:
                    work.append((nxt, 0))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            if low[node] == index[node]:
                comp = []
                while True:
                    m = stack.pop()
                    on_stack.discard(m)
                    comp.append(m)
                    if m == node:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
    return sorted(out, key=lambda c: (-len(c), c))


def test_strongly_connected_finds_a_circle_and_nothing_else():
    g = grimp.ImportGraph()
    for m in ("a", "b", "c", "d", "e"):
        g.add_module(m)
    for importer, imported in (("a", "b"), ("b", "c"), ("c", "a"), ("c", "d"), ("d", "e")):
        g.add_import(importer=importer, imported=imported)
    assert strongly_connected(g) == [["a", "b", "c"]]
    g.add_import(importer="e", imported="d")
    assert strongly_connected(g) == [["a", "b", "c"], ["d", "e"]]


def test_no_import_circle():
    graph = grimp.build_graph(*PACKAGES)
    circles = strongly_connected(graph)
    assert not circles, "import circles (modules that import each other, directly or through others): " + "; ".join(
        f"{len(c)} modules: {', '.join(c)}" for c in circles)


#: The command layer loads its sub-commands and benches on use, so that ``stand --help`` or one command does not
#: import every other one (OpenCV, matplotlib, Dask...): a function-local import there is the design.
COMMAND_LAYER = ("stand/cli.py", "stand/commands/", "stand/benches/")


def _local_stand_imports(path) -> list[tuple[int, str]]:
    """(line, module) of each import of a ``stand`` module inside a function of ``path``."""
    import ast

    tree = ast.parse(path.read_text())
    found = []
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").split(".")[0] == "stand"):
                    found.append((node.lineno, node.module or "."))
                elif isinstance(node, ast.Import) and any(a.name.split(".")[0] == "stand" for a in node.names):
                    found.append((node.lineno, node.names[0].name))
    return sorted(set(found))


def test_the_core_imports_other_stand_modules_at_the_top_or_says_why_not():
    """Outside the command layer a function-local import of another stand module is either gone (nothing to dodge:
    there is no circle) or marked ``# lazy: <why>`` on the line above (a figure module that loads matplotlib only
    when a report is drawn)."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    unexplained = []
    for path in sorted((root / "stand").rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel.startswith(COMMAND_LAYER):
            continue
        lines = path.read_text().splitlines()
        for lineno, module in _local_stand_imports(path):
            above = lines[lineno - 2].strip() if lineno >= 2 else ""
            if not above.startswith("# lazy:"):
                unexplained.append(f"{rel}:{lineno} imports {module} inside a function")
    assert unexplained == [], "\n".join(unexplained)
