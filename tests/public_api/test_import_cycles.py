"""No import circle anywhere: not between sibling packages (import-linter's
``acyclic_siblings`` contract checks that in CI's lint step) and not between two modules of
the same package either (e.g. ``fpscan.service.jobs.queue`` and ``fpscan.service.jobs.work`` once imported
each other). The import graph is grimp's (import-linter's own engine), with the imports made
inside functions included: a lazy import still ties two modules together."""
from __future__ import annotations

import grimp

PACKAGES = ("fpscan",)


def strongly_connected(adjacent: dict[str, set[str]]) -> list[list[str]]:
    """The groups of two or more modules that reach each other (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []
    counter = 0
    for root in sorted(adjacent):
        if root in index:
            continue
        work = [(root, iter(sorted(adjacent[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(adjacent.get(w, ())))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    group = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        group.append(w)
                        if w == v:
                            break
                    if len(group) > 1:
                        groups.append(sorted(group))
    return groups


def test_the_finder_sees_a_circle():
    """The oracle itself: a circle of three and a tail are told apart."""
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"e"}}
    assert strongly_connected(graph) == [["a", "b", "c"]]


def test_no_module_imports_itself_back():
    graph = grimp.build_graph(*PACKAGES)
    adjacent = {m: set(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    assert len(adjacent) > 100  # the whole product was read
    circles = strongly_connected(adjacent)
    assert circles == [], "modules that import each other (directly or around a circle): " + "; ".join(
        " <-> ".join(c) for c in circles)
