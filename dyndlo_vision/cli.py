"""Command-line entry point: ``dyndlo-vision <command>`` (also ``python -m dyndlo_vision``).

Each command lives in its own module under :mod:`dyndlo_vision.commands`; this file only dispatches.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from dyndlo_vision.commands import COMMANDS

#: Errors about the user's paths that are bad input, not bugs: a one-line message and exit status 2.
_INPUT_ERRORS = (
    ValueError,
    FileNotFoundError,
    FileExistsError,
    IsADirectoryError,
    NotADirectoryError,
    PermissionError,
)


class HelpFormatter(argparse.HelpFormatter):
    """Shows every option's default, unless its help text already states one or there is none to show."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        shown = bool(action.option_strings) and action.default not in (None, False, argparse.SUPPRESS)
        if shown and "default" not in text and "%(default)" not in text:
            text = f"{text} (default: %(default)s)" if text else "(default: %(default)s)"
        return text


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("dyndlo_vision")
    except PackageNotFoundError:  # run from a source tree that was never installed
        from dyndlo_vision import __version__

        return __version__


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with one subparser per command."""
    parser = argparse.ArgumentParser(
        prog="dyndlo-vision", description="Dynamic cable manipulation in MuJoCo."
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, module_name in COMMANDS.items():
        module = importlib.import_module(f"dyndlo_vision.commands.{module_name}")
        p = sub.add_parser(name, help=module.HELP, description=module.HELP, formatter_class=HelpFormatter)
        module.add_arguments(p)
        p.set_defaults(run=module.run, parser=p)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and run the chosen command.

    A command signals bad input by raising ``ValueError`` (or an ``OSError`` about a path it was given:
    missing, existing, a folder where a file was expected, no permission); it becomes a one-line error and
    exit status 2.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args))
    except _INPUT_ERRORS as err:
        args.parser.error(str(err))
        return 2  # unreachable: error() exits


if __name__ == "__main__":
    sys.exit(main())
