"""The ``touchloc`` command.

Each subpackage that offers commands has a ``_cli.py`` module with a
``register(subparsers)`` function; this module only collects them.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from .errors import TouchlocError

#: modules whose register(subparsers) adds subcommands, in help order
COMMAND_MODULES = [
    "touchloc._demo",
    "touchloc.belief._cli",
    "touchloc.planners._cli",
    "touchloc.dnf._cli",
    "touchloc.hardware._cli",
    "touchloc.recognition._cli",
    "touchloc.mapping._cli",
    "touchloc.experiments._cli",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="touchloc", description="Bayesian tactile localisation and mapping.")
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue  # that subpackage offers no commands (yet)
            raise
        mod.register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.version:
        from . import __version__

        print(__version__)
        return 0
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        with warnings.catch_warnings():
            if not getattr(args, "verbose", False):
                warnings.simplefilter("ignore", category=UserWarning)
            return int(args.func(args) or 0)
    except TouchlocError as exc:
        print(f"touchloc {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
