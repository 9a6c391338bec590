"""The README stays short and true: at most 250 lines, no history in it, and every command it names exists as
written: each make target in the Makefile, each ``fps`` command's sub-commands and options in its parser, and a
whole command (one with ``-o``) parses as given."""

import argparse
import os
import re
import shlex

import pytest

from ground.cli import build_parser

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
README = open(os.path.join(ROOT, "README.md")).read()


def _spans():
    """Every code span and every line of a fenced block, whitespace folded (a span may break across lines)."""
    blocks = re.findall(r"```\n(.*?)```", README, re.S)
    text = re.sub(r"```\n.*?```", "", README, flags=re.S)
    out = [" ".join(s.split()) for s in re.findall(r"`([^`]+)`", text)]
    for b in blocks:
        out += [ln.split("#")[0].strip() for ln in b.splitlines()]
    return [s for s in out if s]


def test_the_readme_is_short_and_holds_no_history():
    assert README.count("\n") <= 250
    for word in ("this round", "last round", "rounds", "before the"):
        assert word not in README.lower(), word


ISSUE_NUMBER = re.compile(r"\bissues? ?#?[0-9]", re.I)


def test_no_source_or_document_cites_an_issue_number():
    """Users cannot look an issue number up: the code, its output and the docs say what is (CHANGELOG.md, the
    history, aside)."""
    import subprocess
    files = subprocess.run(["git", "ls-files", "*.py", "*.md", "Makefile"], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout.split()
    found = []
    for f in files:
        if f != "CHANGELOG.md":
            for n, line in enumerate(open(os.path.join(ROOT, f), encoding="utf-8"), 1):
                if ISSUE_NUMBER.search(line):
                    found.append("%s:%d" % (f, n))
    assert len(files) > 100 and not found, found


def test_every_make_target_the_readme_names_exists():
    makefile = open(os.path.join(ROOT, "Makefile")).read()
    targets = set(re.findall(r"^([a-z][\w-]*):", makefile, re.M))
    named = {s.split()[1] for s in _spans() if s.startswith("make ") and len(s.split()) > 1}
    assert {"hil", "test", "pil", "natmod"} <= named
    assert named <= targets, named - targets


def _parser_for(words):
    """The parser of ``fps words...`` (the deepest sub-command) and the words left."""
    p = build_parser(only=words[0])
    rest = list(words)
    while rest:
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or rest[0] not in subs[0].choices:
            break
        p = subs[0].choices[rest.pop(0)]
    return p, rest


FPS = [s for s in _spans() if s.startswith("fps ")]


def test_the_readme_names_fps_commands():
    assert len(FPS) >= 4


@pytest.mark.parametrize("span", FPS)
def test_every_fps_command_in_the_readme_exists_with_its_options(span):
    words = shlex.split(span)[1:]
    p, rest = _parser_for(words)
    flags = {o for a in p._actions for o in a.option_strings}
    for w in rest:
        if w.startswith("--"):
            assert w.split("=")[0] in flags, "%s: %s is not an option of it" % (span, w)
    if "-o" in rest:                          # a whole command: it parses as written
        try:
            p.parse_args(rest)
        except SystemExit as exc:
            pytest.fail("%s does not parse: exit %s" % (span, exc.code))
