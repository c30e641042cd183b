"""Command-line entry point: ``dyndlo-vision <command>`` (also ``python -m dyndlo_vision``).

Each command lives in its own module under :mod:`dyndlo_vision.commands`; this file only dispatches.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from dyndlo_vision.commands import COMMANDS


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with one subparser per command."""
    parser = argparse.ArgumentParser(
        prog="dyndlo-vision", description="Dynamic cable manipulation in MuJoCo."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for name, module_name in COMMANDS.items():
        module = importlib.import_module(f"dyndlo_vision.commands.{module_name}")
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(run=module.run, parser=p)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and run the chosen command.

    A command signals bad input by raising ``ValueError``; it becomes a one-line error and exit status 2.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args))
    except (ValueError, FileNotFoundError) as err:
        args.parser.error(str(err))
        return 2  # unreachable: error() exits


if __name__ == "__main__":
    sys.exit(main())
