"""``fps adcs``: the ground-side attitude and orbit filters. Each sub-command lives in its own module and
registers itself with ``register(subparsers, name, help)``."""

import importlib

SUBCOMMANDS = (
    ("stkf", "ground.adcs.stkf_cli", "satellite tracking KF with the EAFLS for delayed GNSS (Sec. 5.5)"),
)


def register(sub, name, help_):
    p = sub.add_parser(name, help=help_, description="Ground-side attitude and orbit filters (thesis Ch. 4-5).")
    s = p.add_subparsers(dest="adcs_command", metavar="FILTER")
    for n, mod, h in SUBCOMMANDS:
        importlib.import_module(mod).register(s, n, h)

    def func(a):
        p.print_help()
        return 2
    p.set_defaults(func=func)
