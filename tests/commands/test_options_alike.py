"""One option, one name, one default, one meaning, in every command.

Every command's parser is read. An option that two or more commands take must be the same in each: its
destination, action, default, type, choices, nargs, metavar, whether it is required, and its help text.
:data:`OWN` lists the differences a command needs, each with the reason and the command's own value, so
that a change to one of those is caught too. The shared options are defined once
(``dyndlo_vision/commands/_options.py``); this test is what keeps a command from defining its own copy.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import pytest

from dyndlo_vision import cli

ROOT = Path(__file__).resolve().parents[2]
#: The commands the same options must hold across, at the least.
MAIN_COMMANDS = ("demo", "track", "segment", "run", "train", "evaluate")
FIELDS = ("dest", "action", "default", "type", "choices", "nargs", "metavar", "required", "help")
#: A command's own value that is not pinned here (a help text, which says the command's own default).
ANY = object()
_OUT = {c: ANY for c in ("demo", "track", "calibrate", "evaluate", "plot", "train", "distill", "seg-data",
                         "seg-train", "segment", "run")}

#: (option, field) -> (why, {command: its own value}). The commands not named must agree with each other.
OWN: dict[tuple[str, str], tuple[str, dict[str, Any]]] = {
    # Every command writes its own kind of output (a folder, a CSV, a JSON file, a PNG), named its own way.
    ("--out", "default"): ("each command's own output", _OUT),
    ("--out", "help"): ("each command's own output", _OUT),
    ("--out", "metavar"): ("each command's own output", _OUT),
    ("--out", "required"): ("each command's own output", _OUT),
    ("--episodes", "default"): (
        "the demo films its first episode, one by default; an evaluation needs many for its 95 % interval",
        {"demo": 1, "evaluate": 100},
    ),
    # --seed is the run's seed everywhere, but what it seeds is each command's: the first episode (demo,
    # evaluate: these two agree), the learner (train), the distillation's episodes, a dataset, a network.
    **{("--seed", field): ("what the seed draws is the command's own", values) for field, values in (
        ("default", {"train": 0, "distill": 1, "seg-data": 0, "seg-train": 0}),
        ("help", {"train": ANY, "distill": ANY, "seg-data": ANY, "seg-train": ANY}),
    )},
    ("--task", "choices"): (
        "demo runs the tasks whose scene has a loop camera and a shipped policy; distill the tasks with a "
        "shipped single-step teacher",
        {"demo": ["tip-control", "vaulting"], "distill": ["tip-control", "vaulting"]},
    ),
    ("--task", "default"): ("evaluate takes the policy's own task", {"evaluate": None}),
    ("--task", "help"): ("evaluate takes the policy's own task", {"evaluate": ANY}),
    ("--obs-noise", "help"): (
        "demo's model is the one of --observation noisy, by default the task's own loop tracker's; training "
        "sees the true P_DLO unless given one",
        {"demo": ANY},
    ),
    # The segmenter suits what is segmented: a video with a static background (track), single photos with no
    # background to learn (segment), the simulated loop's scene (demo: its cameras, and no HSV bounds).
    ("--segmenter", "default"): (
        "each command's input has its own best segmenter",
        {"demo": None, "track": "background", "segment": "learned"},
    ),
    ("--segmenter", "choices"): ("the loop's segmenters are learned and background", {
        "demo": ["learned", "background"]}),
    ("--segmenter", "help"): ("demo's default is the scene's own", {"demo": ANY}),
    ("--segmenter-model", "help"): (
        "the help names the command's own default network: the loop's, the half-resolution one for videos, "
        "the photo one for photos",
        {"demo": ANY, "track": ANY, "segment": ANY},
    ),
    ("--fps", "help"): (
        "track reads the frames at this rate, calibrate writes it into the file it makes",
        {"track": ANY, "calibrate": ANY},
    ),
    **{(f"--{name}", field): (
        "calibrate --scene takes the loop camera's 640x480 unless told (None: photos refuse the option); "
        "seg-data renders its training images at half that",
        values,
    ) for name, size in (("width", 320), ("height", 240)) for field, values in (
        ("default", {"calibrate": None, "seg-data": size}),
        ("help", {"calibrate": ANY}),
    )},
}
#: Spellings of a shared option that no command may use: the option's one name is the value.
RETIRED = {"--model": "--segmenter-model"}


def parsers() -> dict[str, argparse.ArgumentParser]:
    parser = cli.build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def describe(action: argparse.Action) -> dict[str, Any]:
    return {
        "dest": action.dest,
        "action": type(action).__name__,
        "default": action.default,
        "type": getattr(action.type, "__name__", action.type),
        "choices": None if action.choices is None else list(action.choices),
        "nargs": action.nargs,
        "metavar": action.metavar,
        "required": action.required,
        "help": action.help,
    }


def options_by_name(commands: dict[str, argparse.ArgumentParser]) -> dict[str, dict[str, dict[str, Any]]]:
    """Option string -> {command: its description}."""
    table: dict[str, dict[str, dict[str, Any]]] = {}
    for command, parser in commands.items():
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            for option in action.option_strings:
                table.setdefault(option, {})[command] = describe(action)
    return table


def differences(table: dict[str, dict[str, dict[str, Any]]]) -> tuple[list[str], set[tuple[str, str]]]:
    """What differs that :data:`OWN` does not allow, and the entries of OWN that are needed."""
    problems: list[str] = []
    needed: set[tuple[str, str]] = set()
    for option, per_command in sorted(table.items()):
        if len(per_command) < 2:
            continue
        for field in FIELDS:
            values = {command: d[field] for command, d in per_command.items()}
            if len({repr(v) for v in values.values()}) == 1:
                continue
            why, own = OWN.get((option, field), ("", {}))
            rest = {c: v for c, v in values.items() if c not in own}
            if len({repr(v) for v in rest.values()}) > 1:
                problems.append(f"{option} {field} differs: {rest}")
            for command, value in own.items():
                if command in values and value is not ANY and values[command] != value:
                    problems.append(
                        f"{option} {field} of {command} is {values[command]!r}; OWN says {value!r}"
                    )
            if own:
                needed.add((option, field))
    return problems, needed


def test_every_main_command_is_read() -> None:
    assert set(MAIN_COMMANDS) <= set(parsers())


def test_an_option_is_the_same_in_every_command_that_takes_it() -> None:
    problems, _ = differences(options_by_name(parsers()))
    assert not problems, "\n".join(problems)


def test_every_allowed_difference_is_still_one() -> None:
    """An entry of OWN whose option no longer differs, or no longer exists, must go."""
    table = options_by_name(parsers())
    _, needed = differences(table)
    assert set(OWN) == needed, f"not needed: {sorted(set(OWN) - needed)}"
    for (option, _field), (why, own) in OWN.items():
        assert why and set(own) <= set(table[option]), (option, sorted(set(own) - set(table[option])))


def test_no_command_uses_a_retired_spelling() -> None:
    for command, parser in parsers().items():
        for action in parser._actions:
            for option in action.option_strings:
                assert option not in RETIRED, f"{command} {option}: the option is {RETIRED[option]}"


def test_the_run_files_segmenter_is_the_loops() -> None:
    """``run`` reads its options from a YAML file: its ``camera.segmenter`` takes the loop's segmenters, as
    ``demo --segmenter`` does, and defaults to the one the simulated loop takes in tip control's scene."""
    import yaml

    from dyndlo_vision.control.run_config import SEGMENTERS, TASKS, parse_run_config
    from dyndlo_vision.control.sim_perception import DEFAULT_LOOP_SEGMENTER, LOOP_SEGMENTERS

    demo = options_by_name(parsers())
    assert sorted(SEGMENTERS) == sorted(demo["--segmenter"]["demo"]["choices"]) == sorted(LOOP_SEGMENTERS)
    assert set(TASKS) <= set(demo["--task"]["demo"]["choices"])
    example = ROOT / "examples" / "run-gofa-dry.yaml"
    data = yaml.safe_load(example.read_text(encoding="utf-8"))
    del data["camera"]["segmenter"]
    assert parse_run_config(data, example).camera.segmenter == DEFAULT_LOOP_SEGMENTER[1]


@pytest.mark.parametrize("field, command, value", [
    ("default", "evaluate", 0),  # evaluating on the seeds training starts from
    ("help", "train", "no progress bar"),
])
def test_a_command_that_drifts_is_caught(field: str, command: str, value: Any) -> None:
    """The check itself: one command's copy of a shared option, changed, is reported."""
    commands = parsers()
    option = {"default": "--seed", "help": "--quiet"}[field]
    (action,) = [a for a in commands[command]._actions if option in a.option_strings]
    setattr(action, field, value)
    problems, _ = differences(options_by_name(commands))
    assert any(p.startswith(f"{option} {field}") for p in problems), problems


def test_the_segmenter_model_help_names_the_network_each_command_runs() -> None:
    """``--segmenter-model``'s help states the default network from the constant the command runs with
    (``segment``: the photo network; ``track``: ``onnx_bytes()``'s; ``demo``: the loop's), not a copy."""
    from dyndlo_vision.tracking.networks import LOOP_NAME, PHOTO_NAME, SHIPPED_NAME

    helps = {command: action.help for command, parser in parsers().items() for action in parser._actions
             if "--segmenter-model" in action.option_strings}
    expected = {"segment": PHOTO_NAME, "track": SHIPPED_NAME, "demo": LOOP_NAME}
    assert set(helps) == set(expected)
    for command, name in expected.items():
        assert helps[command].endswith(f"; default: {name}"), (command, helps[command])
