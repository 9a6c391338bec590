"""The one-way dependencies of the README's layout, for every pair of the tree's packages: each package imports
only the packages its rule names (``ALLOWED``), at module level and inside functions alike."""

import ast
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGES = ("protocol", "firmware", "emulator", "tools", "ground", "bench", "tests")
# The README's rule: the flight code on the contract; the emulator hosts the flight code (the player, the ADCS app
# in process); the tools build the firmware and start its boards; fps uses them all; the benchmarks measure fps.
ALLOWED = {
    "protocol": (),
    "firmware": ("protocol",),
    "emulator": ("firmware", "protocol"),
    "tools": ("emulator", "firmware", "protocol"),
    "ground": ("tools", "emulator", "firmware", "protocol"),
    "bench": ("ground", "tools", "emulator", "firmware", "protocol"),
    "tests": ("ground", "tools", "emulator", "firmware", "protocol"),
}
# Not yet as the rule says (each a known debt, listed so that nothing else joins it).
KNOWN = {}


def _imports(path):
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.lineno, node.module


def _edges():
    out = {}
    for pkg in PACKAGES:
        for d, _, files in os.walk(os.path.join(ROOT, pkg)):
            for f in files:
                if f.endswith(".py"):
                    p = os.path.join(d, f)
                    rel = os.path.relpath(p, ROOT)
                    for n, m in _imports(p):
                        top = m.split(".")[0]
                        if top in PACKAGES and top != pkg:
                            out.setdefault((pkg, top), []).append((rel, n, m))
    return out


def test_every_package_pair_follows_the_rule():
    bad = []
    for (a, b), where in sorted(_edges().items()):
        if b in ALLOWED[a]:
            continue
        known = KNOWN.get((a, b), set())
        bad += ["%s:%d imports %s (%s may import %s)" % (f, n, m, a, ", ".join(ALLOWED[a]) or "nothing")
                for f, n, m in where if f not in known]
    assert not bad, "\n".join(bad)


def test_the_rule_is_a_layering_and_the_readme_states_it():
    order = {p: i for i, p in enumerate(PACKAGES)}
    for a, allowed in ALLOWED.items():
        assert all(order[b] < order[a] for b in allowed), (a, allowed)      # no cycle can form
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    for a in PACKAGES[:-2]:
        rule = "`%s → %s`" % (a, ", ".join(ALLOWED[a]) or "nothing")
        assert rule in text, rule
