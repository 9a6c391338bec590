"""No import circles among the repository's modules, imports inside functions included (they hide a circle at
import time, not in the design): each package's modules form a directed graph without a cycle."""

import ast
import os
import subprocess

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGES = ("protocol", "firmware", "emulator", "ground", "tools", "bench")


def import_graph():
    """{module: modules of ours it imports anywhere in its file}."""
    files = subprocess.run(["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    mods = {}
    for f in files:
        if f.startswith(PACKAGES) and os.path.exists(os.path.join(ROOT, f)):
            m = f[:-3].replace("/", ".")
            mods[m[:-9] if m.endswith(".__init__") else m] = f

    def c_extension(name):
        """A module built from a C source of ours (e.g. the truth's kernel): it imports none of our modules."""
        return os.path.exists(os.path.join(ROOT, name.replace(".", "/") + ".c"))

    def ours(name):
        if c_extension(name):
            return None
        while name and name not in mods:
            name = name.rsplit(".", 1)[0] if "." in name else ""
        return name or None

    graph = {}
    for m, f in mods.items():
        deps = set()
        for node in ast.walk(ast.parse(open(os.path.join(ROOT, f)).read())):
            if isinstance(node, ast.Import):
                deps.update(ours(a.name) for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for a in node.names:
                    full = node.module + "." + a.name
                    deps.add(ours(full) if full in mods or c_extension(full) else ours(node.module))
        deps.discard(None)
        deps.discard(m)
        graph[m] = deps
    return graph


def cycles(graph):
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index, low, on, stack, out = {}, {}, set(), [], []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    x = stack.pop()
                    on.discard(x)
                    comp.append(x)
                    if x == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_the_finder_finds_a_circle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circles():
    g = import_graph()
    assert len(g) > 100 and "ground.hil" in g["ground.system.run"]
    assert cycles(g) == []
