"""The ``merlin`` command. Each subcommand lives in its own module under :mod:`merlin.commands` and
registers itself through ``register(subparsers)``; this file only discovers and dispatches them.

Exit codes, for every subcommand: 0 success, 1 a check or expectation failed, 2 invalid input (the message
names the file, key and value).
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
from typing import NoReturn

import merlin.commands
from merlin._exit import freeze_for_exit
from merlin.config.loader import ConfigError


def build_parser() -> argparse.ArgumentParser:
    from merlin import __version__

    parser = argparse.ArgumentParser(prog="merlin", description="Merlin trusted autopilot")
    parser.add_argument("--version", action="version", version=f"merlin {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for mod in sorted(pkgutil.iter_modules(merlin.commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"merlin.commands.{mod.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    # The command writes its plots to files: matplotlib's file-only backend, unless the user chose one
    # (MPLBACKEND). Only the command chooses; the plotting modules leave an importer's backend alone.
    # Set in the environment so that the worker processes of `merlin campaign` and `merlin demo` inherit it.
    os.environ.setdefault("MPLBACKEND", "Agg")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        rc = args.func(args)
    except ConfigError as exc:
        print(f"merlin {args.command}: {exc}", file=sys.stderr)
        return 2
    return int(rc or 0)


def entry() -> NoReturn:
    """The ``merlin`` program (the console script and ``python -m merlin.cli``): :func:`main`, then exit
    without the collector's last walks over everything alive (:mod:`merlin._exit`)."""
    rc = main()
    freeze_for_exit()
    sys.exit(rc)


if __name__ == "__main__":
    entry()
