"""The command-line entry point: version, help texts, and bad paths as clean errors."""

from __future__ import annotations

import argparse

import pytest

import dyndlo_vision
from dyndlo_vision import cli
from dyndlo_vision.commands import COMMANDS


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"dyndlo-vision {dyndlo_vision.__version__}"


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = cli.build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def test_every_command_is_registered() -> None:
    assert set(_subparsers()) == set(COMMANDS)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_option_is_documented_with_its_default(command: str) -> None:
    """Every option has a help text, and one with a default shows it."""
    parser = _subparsers()[command]
    text = " ".join(parser.format_help().split())  # help lines wrap anywhere
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        name = action.option_strings[0] if action.option_strings else action.dest
        assert action.help, f"{command} {name} has no help text"
        if action.option_strings and action.default not in (None, False, argparse.SUPPRESS):
            shown = action.help % {"default": action.default} if "%(" in action.help else action.help
            assert "default" in shown or f"(default: {action.default})" in text, f"{command} {name}"


def test_help_formatter_appends_the_default_once() -> None:
    parser = argparse.ArgumentParser(formatter_class=cli.HelpFormatter)
    parser.add_argument("--alpha", type=int, default=3, help="alpha")
    parser.add_argument("--beta", type=int, default=4, help="beta (default 4)")
    parser.add_argument("--gamma", action="store_true", help="gamma")
    text = " ".join(parser.format_help().split())
    assert "alpha (default: 3)" in text
    assert "beta (default 4)" in text and "(default: 4)" not in text
    assert "gamma (default" not in text


@pytest.mark.parametrize(
    "error",
    [ValueError("bad value"), FileExistsError("x exists"), IsADirectoryError("d"), PermissionError("p")],
)
def test_bad_input_errors_exit_2_with_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], error: Exception
) -> None:
    def fail(args: argparse.Namespace) -> int:
        raise error

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            action.choices["plot"].set_defaults(run=fail)
    with pytest.raises(SystemExit) as exc:
        cli.main(["plot", "somewhere"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert str(error) in err and "Traceback" not in err


def test_a_bug_is_not_turned_into_an_input_error(monkeypatch: pytest.MonkeyPatch) -> None:
    def fail(args: argparse.Namespace) -> int:
        raise KeyError("a bug")

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            action.choices["plot"].set_defaults(run=fail)
    with pytest.raises(KeyError):
        cli.main(["plot", "somewhere"])
