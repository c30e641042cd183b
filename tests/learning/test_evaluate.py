"""``evaluate``: options checked before any episode, the policy's own task, progress on stderr.

(End-to-end evaluations of shipped and scripted policies are in test_training.py.)
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dyndlo_vision import policies
from dyndlo_vision.cli import main
from dyndlo_vision.learning import evaluate as evaluate_module
from dyndlo_vision.learning.evaluate import EpisodeRecord, evaluate


@pytest.fixture
def no_episodes(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make any episode an error: the tests using this must be refused before the first one."""

    def run_episode(*_: Any, **__: Any) -> None:
        raise AssertionError("an episode ran before the options were refused")

    monkeypatch.setattr(evaluate_module, "evaluate_episode", run_episode)


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one-line error of ``main(argv)``, which must exit with status 2."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2, argv
    return capsys.readouterr().err.strip().splitlines()[-1]


def test_bad_options_are_refused_before_any_episode(
    tmp_path: Path, no_episodes: None, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["evaluate", "random", "--task", "tip-control", "--episodes", "2"]
    missing = tmp_path / "missing"
    (tmp_path / "folder").mkdir()
    cases = {
        # option values -> what the error must name
        ("--out", str(missing / "r.json")): [str(missing), "--out", "does not exist"],
        ("--out", str(tmp_path / "folder")): ["--out", str(tmp_path / "folder"), "directory"],
        ("--video", str(missing / "v.mp4")): [str(missing), "--video", "does not exist"],
        ("--video", str(tmp_path / "folder")): ["--video", "directory"],
        ("--video", str(tmp_path / "v")): ["--video", ".mp4"],
        ("--out", str(tmp_path / "a.mp4"), "--video", str(tmp_path / "a.mp4")): ["same file"],
        ("--video", str(tmp_path / "v.mp4"), "--video-episodes", "0"): ["--video-episodes", "got 0"],
        ("--video", str(tmp_path / "v.mp4"), "--video-episodes", "3"): ["--video-episodes", "(2)", "got 3"],
        ("--video-episodes", "0"): ["--video-episodes", "got 0"],  # also without --video: a typo is a typo
        ("--geometric-time", "0"): ["--geometric-time", "got 0.0"],
        ("--geometric-time", "-1"): ["--geometric-time", "got -1.0"],
        ("--geometric-time", "nan"): ["--geometric-time", "got nan"],
    }
    for extra, expected in cases.items():
        message = _refused([*base, *extra], capsys)
        for text in expected:
            assert text in message, (extra, message)
    message = _refused(["evaluate", "random", "--task", "tip-control", "--episodes", "0"], capsys)
    assert "--episodes" in message and "got 0" in message
    # The geometric baseline's time is checked before its environment and trajectory are built.
    message = _refused(["evaluate", "geometric", "--episodes", "1", "--geometric-time", "0"], capsys)
    assert "--geometric-time" in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder"]  # nothing written


def test_video_episodes_default_fits_the_evaluated_episodes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The video replays evaluated episodes: by default 3, but never more than --episodes."""
    from dyndlo_vision.commands import evaluate as command

    shown: list[int] = []

    def write_video(
        path: Path,
        gym_id: str,
        multi_step: bool,
        options: Any,
        policy: Any,
        seed: int,
        episodes: int,
        *_: Any,
        **__: Any,
    ) -> None:
        shown.append(episodes)

    monkeypatch.setattr(command, "_write_video", write_video)
    video = str(tmp_path / "v.mp4")
    base = ["evaluate", "random", "--task", "tip-control", "--video", video, "--quiet"]
    assert main([*base, "--episodes", "1"]) == 0
    assert main([*base, "--episodes", "2", "--video-episodes", "2"]) == 0
    assert shown == [1, 2]


def test_a_policy_is_only_evaluated_on_its_own_task(
    tmp_path: Path, no_episodes: None, capsys: pytest.CaptureFixture[str]
) -> None:
    """Tip control and vaulting have the same spaces: only the metadata tells the policies apart."""
    message = _refused(
        ["evaluate", "tip-control-single-step", "--task", "vaulting", "--episodes", "1"], capsys
    )
    assert "'tip-control-single-step'" in message and "'tip-control'" in message and "'vaulting'" in message
    for scripted, own, other in (
        ("geometric", "time-oscillation", "vaulting"),
        ("flick-vault", "vaulting", "tip-control"),
    ):
        message = _refused(["evaluate", scripted, "--task", other, "--episodes", "1"], capsys)
        assert repr(own) in message and repr(other) in message, message
    # A copied policy file with its metadata beside it, and a training run's model.zip with its config.json.
    path, meta = policies.resolve("vaulting")
    shutil.copyfile(path, tmp_path / "mine.zip")
    (tmp_path / "mine.json").write_text(json.dumps(meta))
    message = _refused(["evaluate", str(tmp_path / "mine.zip"), "--task", "tip-control"], capsys)
    assert "'vaulting'" in message and "'tip-control'" in message
    run = tmp_path / "run"
    run.mkdir()
    shutil.copyfile(path, run / "model.zip")
    (run / "config.json").write_text(json.dumps({"task": "vaulting", "multi_step": False, "algo": "sac"}))
    message = _refused(["evaluate", str(run / "model.zip"), "--task", "tip-control"], capsys)
    assert "'vaulting'" in message and "'tip-control'" in message
    # Without metadata the task cannot be known: --task is needed (and trusted).
    shutil.copyfile(path, tmp_path / "bare.zip")
    message = _refused(["evaluate", str(tmp_path / "bare.zip"), "--episodes", "1"], capsys)
    assert "pass --task" in message


def test_a_policy_is_only_evaluated_in_its_own_mode(
    no_episodes: None, capsys: pytest.CaptureFixture[str]
) -> None:
    """Single- and multi-step episodes have the same spaces: only the metadata tells the modes apart."""
    message = _refused(["evaluate", "tip-control-single-step", "--multi-step", "--episodes", "1"], capsys)
    assert "single-step policy" in message and "--multi-step" in message
    message = _refused(["evaluate", "tip-control-multi-step", "--no-multi-step", "--episodes", "1"], capsys)
    assert "multi-step policy" in message and "--no-multi-step" in message


def test_repeating_the_policys_own_task_is_fine(tmp_path: Path) -> None:
    report = tmp_path / "r.json"
    argv = [
        "evaluate",
        "flick-vault",
        "--task",
        "vaulting",
        "--episodes",
        "1",
        "--quiet",
        "--out",
        str(report),
    ]
    assert main(argv) == 0
    assert json.loads(report.read_text())["task"] == "vaulting"


def test_progress_bar_on_stderr_unless_quiet(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["evaluate", "random", "--task", "tip-control", "--episodes", "2", "--seed", "3"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "2/2" in captured.err and "episode" in captured.err
    assert json.loads(captured.out)["episodes"] == 2  # the report alone on stdout
    assert main([*argv, "--quiet"]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and json.loads(captured.out)["episodes"] == 2


class _CountingEnv:
    """A stand-in environment: episode ``seed`` lasts two steps and succeeds for even seeds."""

    def reset(self, seed: int) -> tuple[np.ndarray, dict[str, Any]]:
        self.seed, self.steps = seed, 0
        return np.zeros(2), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.steps += 1
        done = self.steps == 2
        return np.zeros(2), 1.0, done, False, {"is_success": done and self.seed % 2 == 0}


def test_evaluate_reports_each_episode_as_it_ends() -> None:
    seen: list[EpisodeRecord] = []
    report, records = evaluate(lambda obs: obs, _CountingEnv(), episodes=3, seed=10, on_episode=seen.append)
    assert seen == records and [r.seed for r in seen] == [10, 11, 12]
    assert [r.success for r in seen] == [True, False, True] and report["successes"] == 2


def test_an_episode_without_a_trajectory_time_is_recorded_without_it() -> None:
    """Task IV reports trajectory_time_s = None when the tip never arrived (e.g. a plan an arm refused at
    once): the record leaves it out instead of failing on float(None)."""
    from dyndlo_vision.learning.evaluate import evaluate_episode

    class OneStep:
        def reset(self, seed: int) -> tuple[list[float], dict]:
            return [0.0], {}

        def step(self, action: object) -> tuple:
            info = {"is_success": False, "trajectory_time_s": None, "residual_oscillation_m": 0.0,
                    "sim_time_s": 0.0, "r_avoid": -50.0}
            return [0.0], -50.0, True, False, info

    record = evaluate_episode(OneStep(), lambda obs: 0, seed=3)
    assert "trajectory_time_s" not in record.extras and record.extras["sim_time_s"] == 0.0
    assert record.reward == -50.0 and record.terms["r_avoid"] == -50.0
