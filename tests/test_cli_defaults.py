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
