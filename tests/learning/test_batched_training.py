"""Training in the batched environment: ``train --vec-env batch`` runs, logs and resumes as the other kinds
do, and refuses what it does not simulate."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.learning.config import RunConfig
from dyndlo_vision.learning.envs import make_vec_env
from dyndlo_vision.learning.train import train


def _config(**changes: object) -> RunConfig:
    base = RunConfig(
        task="time-oscillation", multi_step=False, algo="sac", timesteps=6, seed=1, n_envs=3, vec_env="batch",
        hyperparams={"learning_starts": 2, "batch_size": 4}, env_options={"layout": "diagonal"},
        eval_freq=100, eval_episodes=1, checkpoint_freq=3,
    )
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


def _episodes(monitor: Path) -> list[dict[str, str]]:
    lines = monitor.read_text().splitlines()
    assert lines[0].startswith("#{")
    return list(csv.DictReader(lines[1:]))


def test_a_batched_run_trains_logs_every_episode_and_resumes(tmp_path: Path) -> None:
    out = tmp_path / "run"
    summary = train(_config(), out, progress_bar=False)
    assert summary["env_steps_per_s"] > 0
    monitor = out / "monitor" / "batch.monitor.csv"
    first = _episodes(monitor)
    assert len(first) == 6 and {row["is_success"] for row in first} <= {"True", "False"}  # single-step
    assert json.loads((out / "config.json").read_text())["vec_env"] == "batch"
    train(_config(timesteps=12), out, resume=True, progress_bar=False)
    both = _episodes(monitor)
    assert both[: len(first)] == first and len(both) == 12  # a resumed run continues its episode log


def test_the_batched_kind_refuses_a_real_arm_and_unknown_kinds() -> None:
    with pytest.raises(ValueError, match="vec_env='batch' does not judge plans on a real arm.*'subproc'"):
        _config(task="tip-control", env_options={}, robot="gofa")
    with pytest.raises(ValueError, match="vec_env='threads'; expected 'subproc', 'dummy' or 'batch'"):
        _config(vec_env="threads")
    with pytest.raises(ValueError, match="vectorised environment 'threads'; expected one of"):
        make_vec_env(_config(), 1, 0, None, "threads")


def test_train_command_takes_the_batched_kind(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    code = main(["train", "--task", "time-oscillation", "--algo", "sac", "--timesteps", "4", "--n-envs", "2",
                 "--vec-env", "batch", "--env-option", "layout=diagonal", "--hp", "learning_starts=2",
                 "--hp", "batch_size=4", "--eval-freq", "100", "--eval-episodes", "1", "--out", str(out),
                 "--quiet"])
    assert code == 0
    assert (out / "model.zip").is_file() and (out / "monitor" / "batch.monitor.csv").is_file()


def test_a_batched_run_learns_exactly_what_a_dummy_run_learns(tmp_path: Path) -> None:
    # The same seeds give the same episodes, so SAC sees the same transitions and ends with the same weights:
    # a run's learning curve, and its steps to a success rate, do not depend on the kind.
    import torch
    from stable_baselines3 import SAC

    weights = []
    for kind in ("dummy", "batch"):
        out = tmp_path / kind
        # tip control: its targets are drawn from the seeds (task IV's episodes do not depend on them)
        train(_config(task="tip-control", env_options={}, vec_env=kind, n_envs=2, timesteps=8), out,
              progress_bar=False)
        weights.append(SAC.load(out / "model.zip").policy.state_dict())
    assert weights[0].keys() == weights[1].keys()
    for key in weights[0]:
        assert torch.equal(weights[0][key], weights[1][key]), key
