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
