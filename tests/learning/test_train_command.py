"""``train`` when things go wrong: resuming with another budget."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.learning import train as train_module
from dyndlo_vision.learning.config import RunConfig
from dyndlo_vision.learning.train import check_run


def _refuses(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run the CLI, expect exit status 2, return its error message."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    return capsys.readouterr().err


@pytest.fixture
def no_environments(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if train gets as far as starting the training environments (which writes monitor/)."""

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("train started its environments before refusing the input")

    monkeypatch.setattr(train_module, "make_vec_env", refuse)


def _config(**changes: Any) -> RunConfig:
    """A tiny SAC run on the cheapest task, in this process."""
    base = RunConfig(
        task="time-oscillation", multi_step=False, algo="sac", timesteps=4, seed=1, n_envs=1, vec_env="dummy",
        hyperparams={"learning_starts": 2, "batch_size": 4}, env_options={"layout": "diagonal"},
        eval_freq=100, eval_episodes=1, checkpoint_freq=2,
    )
    return dataclasses.replace(base, **changes)


def _fake_run(out: Path, timesteps: int, done: int) -> None:
    """A run folder with a stored budget and a checkpoint at ``done`` steps (its weights are never read)."""
    (out / "checkpoint").mkdir(parents=True)
    (out / "config.json").write_text(_config(timesteps=timesteps).to_json())
    (out / "checkpoint" / "model.zip").write_bytes(b"not read: the budget is checked first")
    (out / "checkpoint" / "state.json").write_text(json.dumps({"num_timesteps": done, "wall_s": 1.0}))


@pytest.mark.parametrize(("budget", "done", "timesteps"), [(2000, 500, 200), (2000, 2100, 2050)])
def test_resume_refuses_a_budget_below_the_stored_one_or_the_steps_done(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_environments: None, budget: int, done: int,
    timesteps: int,
) -> None:
    out = tmp_path / "run"
    _fake_run(out, budget, done)
    message = _refuses(["train", "--resume", "--out", str(out), "--timesteps", str(timesteps)], capsys)
    assert f"--timesteps {timesteps}" in message and f"budget of {budget}" in message
    assert f"{done} done" in message


def test_resume_keeps_or_extends_the_stored_budget(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "run"
    _fake_run(out, 2000, 500)
    assert check_run(_config(timesteps=2000), out, resume=True).timesteps == 2000
    assert check_run(_config(timesteps=3000), out, resume=True).timesteps == 3000
    # The command line: without --timesteps the stored budget stands (not the YAML's 1.5 million).
    seen: list[RunConfig] = []
    monkeypatch.setattr(train_module, "train", lambda config, out, **kw: seen.append(config) or {})
    assert main(["train", "--resume", "--out", str(out)]) == 0
    assert main(["train", "--resume", "--out", str(out), "--timesteps", "2500"]) == 0
    assert [c.timesteps for c in seen] == [2000, 2500]
    assert seen[0] == _config(timesteps=2000)  # the stored configuration, not one built from the options
