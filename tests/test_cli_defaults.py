"""Every option of every command states its default in --help (an option whose default is not None, False or
suppressed), so no command has a default a user cannot read."""

import argparse

from ground.cli import COMMANDS, build_parser


def _leaves(p, path):
    subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, p
    for a in subs:
        for name, sp in a.choices.items():
            yield from _leaves(sp, path + [name])


def all_commands():
    """(command words, parser) of every leaf command of ``fps``."""
    for name, _, _ in COMMANDS:
        p = build_parser(only=name)
        sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
        yield from _leaves(sub.choices[name], [name])


def _silent_default(a):
    trivial = any(a.default is v for v in (None, False, argparse.SUPPRESS))
    flag = isinstance(a, (argparse._StoreTrueAction, argparse._StoreFalseAction, argparse._HelpAction))
    return not (trivial or flag) and "default" not in (a.help or "")


def test_the_walk_sees_every_command():
    names = {" ".join(path) for path, _ in all_commands()}
    assert {"hil", "system", "adcs can", "adcs bps", "emulator serve", "distfile generate"} <= names


def test_every_option_states_its_default():
    silent = ["fps %s %s (default %r)" % (" ".join(path), max(a.option_strings, key=len), a.default)
              for path, p in all_commands() for a in p._actions if a.option_strings and _silent_default(a)]
    assert not silent, "options whose --help does not state their default: " + "; ".join(silent)


def _shared_table():
    """docs/CLI.md's "Shared options" table: {option: its default cell}."""
    import os
    import re
    text = open(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "CLI.md")).read()
    body = text.split("## Shared options", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in body.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].startswith("`--"):
            for opt in re.findall(r"`(--[a-z0-9-]+)`", cells[0]):
                rows[opt] = cells[2]
    return rows


def test_every_shared_option_whose_default_differs_is_in_the_docs_table():
    """An option several commands take, whose default is not the same on all of them, has a row in docs/CLI.md's
    "Shared options" table naming each command whose default is not the common one."""
    import collections
    defaults = collections.defaultdict(dict)
    for path, p in all_commands():
        for a in p._actions:
            if a.option_strings and a.dest != "help" and a.default is not argparse.SUPPRESS:
                defaults[max(a.option_strings, key=len)][" ".join(path)] = a.default
    rows, missing = _shared_table(), []
    for opt, by_cmd in defaults.items():
        common = collections.Counter(repr(v) for v in by_cmd.values()).most_common(1)[0][0]
        odd = sorted(c for c, v in by_cmd.items() if repr(v) != common)
        if len(by_cmd) < 2 or not odd:
            continue
        cell = rows.get(opt) or rows.get(opt.replace("--no-", "--"))
        if cell is None:
            missing.append("%s (no row)" % opt)
            continue
        missing += ["%s on fps %s" % (opt, c) for c in odd if "`%s`" % c not in cell and c.split()[-1] not in cell]
    assert not missing, "docs/CLI.md's shared options table leaves out: " + "; ".join(missing)


WHOLE_SESSION = ("whole session", "from power-on", "whole run")


def _options(name):
    """{command words: the action} of every command's visible option ``name``."""
    return {" ".join(path): a for path, p in all_commands() for a in p._actions
            if name in a.option_strings and a.help is not argparse.SUPPRESS}


def test_every_duration_is_the_window_collected():
    """--duration means one thing on every command: the seconds the run's statistics are collected over (for fps
    hil, the play); its --help says so, never the whole session (that is --session)."""
    from ground.adcs.options import WINDOW_WORD
    durations = _options("--duration")
    assert {"hil", "system", "adcs bps", "adcs sweep", "adcs stkf"} <= set(durations)
    odd = ["fps %s: %s" % (c, a.help) for c, a in durations.items()
           if WINDOW_WORD not in a.help or any(w in a.help for w in WHOLE_SESSION)]
    assert not odd, "--duration whose --help is not the window collected: " + "; ".join(odd)


def test_the_whole_session_is_named_session():
    """The whole session from power-on is --session, on the commands that fly one and nowhere else, and no other
    option's --help claims it."""
    sessions = _options("--session")
    assert set(sessions) == {"adcs can", "adcs bps"}
    assert all("whole session from power-on" in a.help and "default" in a.help for a in sessions.values())
    others = ["fps %s %s" % (" ".join(path), max(a.option_strings, key=len)) for path, p in all_commands()
              for a in p._actions if a.option_strings and "--session" not in a.option_strings
              and a.help and a.help is not argparse.SUPPRESS and "whole session" in a.help]
    assert not others, "options claiming the whole session besides --session: " + "; ".join(others)


def test_the_old_session_length_is_refused_by_name(tmp_path, capsys):
    """--duration on fps adcs can, or with the flight world on fps adcs bps, exits 2 naming the option to use; so
    does --session in the thesis world, or out of its range."""
    from ground.cli import main
    out = str(tmp_path / "o")
    for argv, names in ((["adcs", "can", "--duration", "5"], ("--session",)),
                        (["adcs", "bps", "--world", "flight", "--duration", "5"], ("--session", "--orbits")),
                        (["adcs", "bps", "--session", "5"], ("--duration",)),
                        (["adcs", "bps", "--world", "flight", "--session", "0"], ("--session must be in [1,",))):
        try:
            rc = main(argv + ["-o", out])
        except SystemExit as exc:
            rc = exc.code
        err = capsys.readouterr().err
        assert rc == 2 and all(n in err for n in names) and "Traceback" not in err, (argv, err)
