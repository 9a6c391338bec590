"""The one-way dependencies of docs/INTERFACES.md: nothing imports ``ground`` (emulator, protocol and firmware import it
neither at module level nor inside functions)."""

import ast
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _imports(path):
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.lineno, node.module


def test_nothing_below_ground_imports_ground():
    found = []
    for pkg in ("emulator", "protocol", "firmware"):
        for d, _, files in os.walk(os.path.join(ROOT, pkg)):
            for f in files:
                if f.endswith(".py"):
                    p = os.path.join(d, f)
                    found += ["%s:%d %s" % (os.path.relpath(p, ROOT), n, m) for n, m in _imports(p)
                              if m == "ground" or m.startswith("ground.")]
    assert not found, found
