"""Every pointer an output or a help text gives to the documentation names a file that exists, and a section
("docs/X.md, "Heading"") that begins one of its headings; no output points to an issue number."""

import glob
import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SOURCES = [p for d in ("ground", "emulator", "protocol", "firmware", "tools") for p in
           glob.glob(os.path.join(ROOT, d, "**", "*.py"), recursive=True)]
FILE = re.compile(r"\b((?:docs/)?[A-Z][A-Z_0-9]*\.md)\b")
SECTION = re.compile(r"\b((?:docs/)?[A-Z][A-Z_0-9]*\.md),? (?:\\?[\"'“])([^\"'\\”\n]+)(\\?[\"'”])?")


def _path(name):
    for p in (os.path.join(ROOT, name), os.path.join(ROOT, "docs", name), os.path.join(ROOT, "protocol", name)):
        if os.path.exists(p):
            return p
    return None


def _headings(path):
    with open(path, encoding="utf-8") as f:
        return [ln.lstrip("#").strip() for ln in f if ln.startswith("#")]


def test_every_docs_file_and_section_named_exists():
    bad = []
    for src in SOURCES:
        with open(src, encoding="utf-8") as f:
            text = f.read()
        for name in set(FILE.findall(text)):
            if name not in ("CHANGELOG.md",) and _path(name) is None:
                bad.append("%s: %s (no such file)" % (os.path.relpath(src, ROOT), name))
        for name, sec, closed in SECTION.findall(text):
            p = _path(name)
            heads = _headings(p) if p else []
            sec = sec.strip()                    # a heading's first words name it ("Disturbance models")
            if p and sec and not any(h.startswith(sec) for h in heads):
                bad.append("%s: %s, \"%s\" (no such section)" % (os.path.relpath(src, ROOT), name, sec))
    assert not bad, "\n".join(bad)


def test_no_output_points_to_an_issue_number():
    hits = []
    for src in SOURCES:
        with open(src, encoding="utf-8") as f:
            for n, line in enumerate(f, 1):
                if re.search(r"\bissues? #?\d+", line) and ("print(" in line or '"' in line):
                    hits.append("%s:%d" % (os.path.relpath(src, ROOT), n))
    assert not hits, hits


def test_the_checker_catches_a_missing_section():
    m = SECTION.findall('see docs/ADCS.md, "No such section here"')
    assert m and m[0][1] not in _headings(_path(m[0][0]))
