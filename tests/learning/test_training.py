"""Training end to end for a few hundred steps, checkpoints and resume, evaluation, policy files, plots."""

from __future__ import annotations

import json
import os
import signal
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import dyndlo_vision  # noqa: F401
from dyndlo_vision import policies
from dyndlo_vision.cli import main
from dyndlo_vision.learning import train as train_module
from dyndlo_vision.learning.config import RunConfig, load_hyperparams
from dyndlo_vision.learning.evaluate import evaluate, wilson_interval
from dyndlo_vision.learning.train import train

pytestmark = pytest.mark.slow


def _config(algo: str, timesteps: int, **extra: object) -> RunConfig:
    hp = {
        "ppo": {"n_steps": 32, "batch_size": 16, "n_epochs": 2},
        "sac": {"learning_starts": 16, "batch_size": 16},
    }
    return RunConfig(
        task="tip-control",
        multi_step=False,
        algo=algo,
        timesteps=timesteps,
        seed=3,
        n_envs=1,
        vec_env="dummy",
        hyperparams=hp[algo],
        eval_freq=32,
        eval_episodes=1,
        checkpoint_freq=16,
        **extra,
    )  # type: ignore[arg-type]


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_train_then_resume(tmp_path: Path, algo: str) -> None:
    out = tmp_path / "run"
    summary = train(_config(algo, 64), out, progress_bar=False)
    assert (out / "model.zip").is_file() and (out / "config.json").is_file()
    state = json.loads((out / "checkpoint" / "state.json").read_text())
    assert state["num_timesteps"] >= 64
    evaluations = np.load(out / "eval" / "evaluations.npz")
    assert summary["eval_timesteps"] == int(evaluations["timesteps"][-1]) >= 32
    # The summary reads the evaluation log: the last row's success fraction, the best row's.
    assert summary["eval_success_last"] == pytest.approx(float(evaluations["successes"][-1].mean()))
    assert summary["eval_success_best"] == pytest.approx(float(evaluations["successes"].mean(axis=1).max()))
    if algo == "sac":
        assert (out / "checkpoint" / "replay_buffer.pkl").is_file()
    episodes = sum(len(f.read_text().splitlines()) - 2 for f in (out / "monitor").glob("*.csv"))
    assert episodes >= 64  # single-step: one decision per episode

    with pytest.raises(ValueError, match="already holds a run"):
        train(_config(algo, 64), out, progress_bar=False)
    before = np.load(out / "eval" / "evaluations.npz")["timesteps"].tolist()
    train(_config(algo, 96), out, resume=True, progress_bar=False)
    state = json.loads((out / "checkpoint" / "state.json").read_text())
    assert state["num_timesteps"] >= 96
    monitor = (out / "monitor" / "env0.monitor.csv").read_text().splitlines()
    assert len(monitor) - 2 >= 96  # the resumed run appended to the episode log (header lines: 2)
    assert sum(line.startswith("#") for line in monitor) == 1
    after = np.load(out / "eval" / "evaluations.npz")["timesteps"].tolist()
    assert after[: len(before)] == before and len(after) > len(before)  # the curve continues
    model = policies.load(out / "model.zip")
    assert model.num_timesteps == state["num_timesteps"]
    if algo == "sac":
        from stable_baselines3 import SAC

        resumed = SAC.load(out / "checkpoint" / "model.zip")
        resumed.load_replay_buffer(out / "checkpoint" / "replay_buffer.pkl")
        assert resumed.replay_buffer.size() >= 96


def test_interrupted_run_keeps_a_checkpoint_and_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from stable_baselines3.common.callbacks import BaseCallback

    class Interrupt(BaseCallback):  # SIGTERM at step 40, as from `kill` (the handler turns it into Ctrl-C)
        def _on_step(self) -> bool:
            if self.num_timesteps >= 40:
                os.kill(os.getpid(), signal.SIGTERM)
            return True

    monkeypatch.setattr(train_module, "_eval_callback", lambda config, out: Interrupt())
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        train(_config("ppo", 64), out, progress_bar=False)
    state = json.loads((out / "checkpoint" / "state.json").read_text())
    assert state["num_timesteps"] == 40
    assert not (out / "model.zip").exists()  # the final policy appears only when the run completes
    monkeypatch.undo()
    train(_config("ppo", 64), out, resume=True, progress_bar=False)
    assert json.loads((out / "checkpoint" / "state.json").read_text())["num_timesteps"] >= 64


def test_wilson_interval_matches_closed_form() -> None:
    lo, hi = wilson_interval(90, 100)
    # Wilson score interval for 90/100 at z = 1.96: 0.8256 .. 0.9448 (textbook value).
    assert lo == pytest.approx(0.8256, abs=5e-4) and hi == pytest.approx(0.9448, abs=5e-4)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == pytest.approx(1.0)
    with pytest.raises(ValueError):
        wilson_interval(3, 0)


def test_evaluate_geometric_baseline_is_deterministic() -> None:
    from dyndlo_vision.tasks.baselines import GeometricLift

    env = gym.make("DynDLO/TimeOscillation-v0", target="down")
    policy = GeometricLift(env, total_time_s=1.468)
    report_a, _ = evaluate(policy, env, episodes=2, seed=5)
    report_b, _ = evaluate(policy, env, episodes=2, seed=5)
    assert report_a == report_b
    assert report_a["episodes"] == 2 and "trajectory_time_s_mean" in report_a
    with pytest.raises(ValueError, match="dt in"):
        GeometricLift(env, total_time_s=5.0)


def test_evaluate_random_actions_and_the_scripted_vault_by_name(tmp_path: Path) -> None:
    report = tmp_path / "random.json"
    args = ["evaluate", "random", "--task", "tip-control", "--episodes", "3", "--seed", "11"]
    assert main([*args, "--out", str(report)]) == 0
    first = json.loads(report.read_text())
    assert first["policy"] == "random" and first["task"] == "tip-control" and first["episodes"] == 3
    rewards = [e["reward"] for e in first["episodes_detail"]]
    assert main([*args, "--out", str(report)]) == 0  # the same seed: the same actions, the same episodes
    assert [e["reward"] for e in json.loads(report.read_text())["episodes_detail"]] == rewards
    assert main([*args[:-1], "12", "--out", str(report)]) == 0  # another seed: other actions
    assert [e["reward"] for e in json.loads(report.read_text())["episodes_detail"]] != rewards
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "random", "--episodes", "1"])  # no task to draw actions for
    assert exc.value.code == 2
    # The scripted vault by name: its task is known, and it vaults the nominal cable (here the rod's shape).
    rod = ["--env-option", "cable=rod"]
    assert main(["evaluate", "flick-vault", "--episodes", "1", *rod, "--out", str(report)]) == 0
    flick = json.loads(report.read_text())
    assert flick["task"] == "vaulting" and flick["successes"] == 1


def test_evaluate_with_cable_randomization_draws_one_cable_per_episode_from_its_seed(tmp_path: Path) -> None:
    from dyndlo_vision.tasks.tip_control import TipControl
    from dyndlo_vision.tasks.wrappers import DEFAULT_CABLE_RANGES

    nominal = TipControl().cable
    report = tmp_path / "report.json"
    args = ["evaluate", "tip-control-single-step", "--episodes", "3", "--seed", "7", "--randomize-cable"]
    assert main([*args, "--out", str(report)]) == 0
    first = json.loads(report.read_text())
    assert first["randomize_cable"] is True
    cables = [e["cable"] for e in first["episodes_detail"]]
    assert len({c["length_m"] for c in cables}) == 3  # a new cable every episode
    for cable in cables:
        for name, (lo, hi) in DEFAULT_CABLE_RANGES.items():
            assert lo <= cable[name] / getattr(nominal, name) <= hi, (name, cable)
    # The cable is drawn from the episode's seed: the same seeds give the same cables and outcomes.
    assert main([*args, "--out", str(report)]) == 0
    again = json.loads(report.read_text())
    assert [e["cable"] for e in again["episodes_detail"]] == cables
    assert [e["reward"] for e in again["episodes_detail"]] == [e["reward"] for e in first["episodes_detail"]]
    # Without the option, the nominal cable and no cable record.
    assert main(["evaluate", "tip-control-single-step", "--episodes", "1", "--out", str(report)]) == 0
    plain = json.loads(report.read_text())
    assert plain["randomize_cable"] is False and plain["episodes_detail"][0]["cable"] == {}
    assert plain["cable_ranges"] is None and first["cable_ranges"] == "training"
    # --cable-ranges beyond, as in demo, train and distill: the same seed, a cable from the wider ranges.
    assert main([*args[:-1], "--cable-ranges", "beyond", "--episodes", "1", "--out", str(report)]) == 0
    beyond = json.loads(report.read_text())
    assert beyond["randomize_cable"] is True and beyond["cable_ranges"] == "beyond"
    assert beyond["episodes_detail"][0]["cable"] != cables[0]


def test_bad_policy_files_get_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="neither a file nor a shipped policy"):
        policies.load(tmp_path / "missing.zip")
    text = tmp_path / "policy.zip"
    text.write_text("not a zip")
    with pytest.raises(ValueError, match="not a zip archive"):
        policies.load(text)
    corrupt = tmp_path / "corrupt.zip"
    with zipfile.ZipFile(corrupt, "w") as zf:
        zf.writestr("data", "{broken json")
    with pytest.raises(ValueError, match="could not be loaded"):
        policies.load(corrupt)


def test_policy_with_other_spaces_is_refused(tmp_path: Path) -> None:
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", gym.make("DynDLO/TipControl-v0"), n_steps=64)
    model.save(tmp_path / "tip.zip")
    dual = gym.make("DynDLO/Hooking-v0")
    with pytest.raises(ValueError, match="observation_space has shape"):
        policies.load(tmp_path / "tip.zip", env=dual)


def test_hyperparameter_files_have_the_paper_budgets() -> None:
    assert load_hyperparams("ppo", "tip-control", False)["n_timesteps"] == 400_000
    assert load_hyperparams("ppo", "tip-control", True)["n_timesteps"] == 5_000_000
    assert load_hyperparams("sac", "time-oscillation", False)["n_timesteps"] == 1_500_000
    with pytest.raises(ValueError, match="no ppo hyperparameters"):
        load_hyperparams("ppo", "time-oscillation", True)


def test_cli_rejects_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["train", "--hp", "n_steps", "--out", str(tmp_path / "x")])
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:
        main(["plot", str(tmp_path), "--out", str(tmp_path / "curves.png")])
    assert exc.value.code == 2
    assert not (tmp_path / "x").exists() and not (tmp_path / "curves.png").exists()


def test_plot_draws_runs(tmp_path: Path) -> None:
    for seed in (0, 1):
        run = tmp_path / f"run{seed}"
        (run / "eval").mkdir(parents=True)
        steps = np.array([100, 200, 300])
        successes = np.random.default_rng(seed).random((3, 5)) > 0.5
        np.savez(
            run / "eval" / "evaluations.npz",
            timesteps=steps,
            results=np.ones((3, 5)),
            ep_lengths=np.ones((3, 5)),
            successes=successes,
        )
        (run / "config.json").write_text(_config("ppo", 10).to_json())
    assert (
        main(["plot", str(tmp_path / "run0"), str(tmp_path / "run1"), "--out", str(tmp_path / "c.png")]) == 0
    )
    import cv2

    image = cv2.imread(str(tmp_path / "c.png"))
    assert image is not None and image.shape[0] > 200 and image.shape[1] > 400


def test_runs_group_by_everything_but_the_seed() -> None:
    from dataclasses import asdict

    from dyndlo_vision.learning.plots import group_name

    plain = asdict(RunConfig(task="time-oscillation", multi_step=False, algo="sac", timesteps=10, seed=1,
                             env_options={"target": "up"}))
    label = "time-oscillation single-step SAC target=up"
    assert group_name(plain) == group_name({**plain, "seed": 2}) == label
    assert group_name({**plain, "demonstrations": 500}).endswith("+500 demos")
    assert group_name({**plain, "env_options": {"target": "down"}}) != group_name(plain)


def test_training_with_the_fitted_observation_noise_and_cable_randomization(tmp_path: Path) -> None:
    from dyndlo_vision.learning.envs import make_training_env

    # What `train --obs-noise packaged` stores: the word, not a path into one install.
    config = _config("sac", 32, obs_noise="packaged", randomize_cable=True)
    env = make_training_env(config)
    assert type(env.env).__name__ == "NoisyObservation"  # Monitor(NoisyObservation(CableRandomization(...)))
    assert type(env.env.env).__name__ == "CableRandomization"
    train(config, tmp_path / "run", progress_bar=False)
    assert (tmp_path / "run" / "model.zip").is_file()
    with pytest.raises(SystemExit) as exc:
        main(["train", "--obs-noise", str(tmp_path / "missing.json"), "--out", str(tmp_path / "y")])
    assert exc.value.code == 2 and not (tmp_path / "y").exists()


def test_a_run_stored_with_the_shipped_noise_models_path_in_another_install_resumes_on_this_one(
    tmp_path: Path,
) -> None:
    config = _config("sac", 32, obs_noise="/tmp/another-copy/dyndlo_vision/data/noise_model_tracking.json")
    (tmp_path / "config.json").write_text(config.to_json())
    assert RunConfig.from_json(tmp_path / "config.json").obs_noise == "packaged"
    mine = str(tmp_path / "my_noise.json")
    (tmp_path / "config.json").write_text(_config("sac", 32, obs_noise=mine).to_json())
    assert RunConfig.from_json(tmp_path / "config.json").obs_noise == mine


def test_demonstrations_seed_the_replay_buffer_with_baseline_episodes(tmp_path: Path) -> None:
    from stable_baselines3 import SAC

    config = RunConfig(
        task="time-oscillation", multi_step=False, algo="sac", timesteps=4, seed=1, n_envs=1, vec_env="dummy",
        hyperparams={"learning_starts": 2, "batch_size": 4}, env_options={"layout": "diagonal"},
        eval_freq=100, eval_episodes=1, checkpoint_freq=100, demonstrations=3,
    )
    out = tmp_path / "run"
    summary = train(config, out, progress_bar=False)
    demo = json.loads((out / "demonstrations.json").read_text())
    assert demo["episodes"] == 3 and summary["demonstrations"] == demo
    model = SAC.load(out / "checkpoint" / "model.zip")
    model.load_replay_buffer(out / "checkpoint" / "replay_buffer.pkl")
    buffer = model.replay_buffer
    assert buffer.size() == 3 + 4  # the demonstrations, then the run's own steps
    assert np.all(buffer.dones[:7, 0] == 1.0)  # single-step: every transition ends its episode
    # The stored rewards are the environment's for the stored actions: replay the first demonstration.
    env = gym.make("DynDLO/TimeOscillation-v0", layout="diagonal")
    env.reset(seed=0)
    _, reward, *_ = env.step(buffer.actions[0, 0])
    assert reward == pytest.approx(float(buffer.rewards[0, 0]), abs=1e-6)
    episodes = sum(len(f.read_text().splitlines()) - 2 for f in (out / "monitor").glob("*.csv"))
    assert episodes == 3 + 4  # the demonstrations are real episodes, logged with the run's


def test_vaulting_demonstrations_are_scripted_vaults(tmp_path: Path) -> None:
    from dyndlo_vision.tasks.baselines import FlickVault

    # Only tasks whose registry row has a demonstrator accept them; hooking and tip control lack one.
    for task in ("hooking", "tip-control"):
        with pytest.raises(ValueError, match="demonstrations are available for single-step"):
            RunConfig(task=task, multi_step=False, algo="sac", timesteps=2, demonstrations=2)

    # One carry vaults the nominal cable of either model; it lifts the TCP above M and pays lambda_4
    # (reward 8). Holding still (the middle of every action range) does not vault.
    for model in ("rod", "chain"):
        env = gym.make("DynDLO/Vaulting-v0", cable=model)
        obs, _ = env.reset(seed=0)
        _, reward, _, _, info = env.step(FlickVault(env)(obs))
        assert info["is_success"] and reward == pytest.approx(8.0), model
    env = gym.make("DynDLO/Vaulting-v0")
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(env.action_space.shape, np.float32))
    assert not info["is_success"]
    with pytest.raises(ValueError, match="Vaulting"):
        FlickVault(gym.make("DynDLO/Hooking-v0"))
    with pytest.raises(ValueError, match="single-step"):
        FlickVault(gym.make("DynDLO/Vaulting-v0", multi_step=True))
    config = RunConfig(
        task="vaulting", multi_step=False, algo="sac", timesteps=2, seed=1, n_envs=1, vec_env="dummy",
        hyperparams={"learning_starts": 1, "batch_size": 2}, eval_freq=100, eval_episodes=1,
        checkpoint_freq=100, demonstrations=2,
    )
    train(config, tmp_path / "run", progress_bar=False)
    assert json.loads((tmp_path / "run" / "demonstrations.json").read_text())["episodes"] == 2


def test_a_crash_after_the_demonstrations_resumes_with_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from stable_baselines3 import SAC

    def crash(self: object, *args: object, **kwargs: object) -> None:
        raise RuntimeError("simulated crash")

    config = RunConfig(
        task="time-oscillation", multi_step=False, algo="sac", timesteps=3, seed=1, n_envs=1, vec_env="dummy",
        hyperparams={"learning_starts": 1, "batch_size": 2}, env_options={"layout": "diagonal"},
        eval_freq=100, eval_episodes=1, checkpoint_freq=100, demonstrations=2,
    )
    out = tmp_path / "run"
    monkeypatch.setattr(SAC, "learn", crash)
    with pytest.raises(RuntimeError, match="simulated crash"):
        train(config, out, progress_bar=False)
    monkeypatch.undo()
    train(config, out, resume=True, progress_bar=False)
    model = SAC.load(out / "checkpoint" / "model.zip")
    model.load_replay_buffer(out / "checkpoint" / "replay_buffer.pkl")
    assert model.replay_buffer.size() == 2 + 3  # the demonstrations survived the crash


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"algo": "ppo"}, "off-policy"),
        ({"task": "tip-control"}, "single-step"),
        ({"multi_step": True}, "single-step"),
        ({"demonstrations": -1}, "non-negative"),
    ],
)
def test_demonstrations_are_refused_where_they_cannot_apply(changes: dict, message: str) -> None:
    base = {"task": "time-oscillation", "multi_step": False, "algo": "sac", "timesteps": 10,
            "demonstrations": 5}
    with pytest.raises(ValueError, match=message):
        RunConfig(**{**base, **changes})


def test_evaluate_with_a_robot_reports_joint_feasibility(tmp_path: Path) -> None:
    """``--robot``: the report's 'joints' block counts the episodes whose plan the arm can follow, and those
    that succeed with one. The shipped tip-control policy whips faster than the GoFa's joints allow: its plans
    are refused, so no episode succeeds on the arm."""
    from dyndlo_vision.learning.evaluate import EpisodeRecord, joint_summary

    report = tmp_path / "report.json"
    args = ["evaluate", "tip-control-single-step", "--episodes", "2", "--robot", "gofa", "--out", str(report)]
    assert main(args) == 0
    data = json.loads(report.read_text())
    assert data["robot"] == "gofa" and data["successes"] == 0
    joints = data["joints"]
    assert joints["episodes"] == 2 and joints["feasible"] == 0 and joints["success_and_feasible"] == 0
    assert joints["acceleration_fraction_median"] > 1.0 and sum(joints["refusals"].values()) == 2
    assert data["avoid_rate"]["joints"] == 1.0
    details = data["episodes_detail"]
    assert all(d["joint_feasible"] is False for d in details)
    assert all("breaks the limit" in d["joint_limit_reason"] for d in details)
    # Without --robot: no judgement, no block.
    assert main(["evaluate", "tip-control-single-step", "--episodes", "1", "--out", str(report)]) == 0
    assert "joints" not in json.loads(report.read_text())
    # The summary's rule: success and feasible counts only episodes that are both.
    records = [EpisodeRecord(0, 1.0, True, 1, joint_feasible=False), EpisodeRecord(1, 1.0, True, 1,
               joint_feasible=True), EpisodeRecord(2, 1.0, False, 1, joint_feasible=True)]
    summary = joint_summary(records)
    assert (summary["feasible"], summary["success_and_feasible"]) == (2, 1)


def test_train_with_a_robot_judges_every_training_plan(tmp_path: Path) -> None:
    from dyndlo_vision.learning.envs import make_training_env

    with pytest.raises(ValueError, match="unknown robot 'kuka'"):
        _config("sac", 32, robot="kuka")
    config = _config("sac", 32, robot="gofa")
    assert RunConfig(**json.loads(config.to_json())).robot == "gofa"  # stored in config.json for --resume
    monitor = tmp_path / "env0"
    env = make_training_env(config, monitor)
    assert env.unwrapped.arm_check is not None and env.unwrapped.arm_check.arm.name == "gofa"
    env.reset(seed=1)
    env.step(env.action_space.sample())
    env.close()
    header = (tmp_path / "env0.monitor.csv").read_text().splitlines()[1]
    assert header.split(",")[-1] == "joint_feasible"
    with pytest.raises(ValueError, match="one TCP"):
        train(RunConfig(task="hooking", multi_step=False, algo="sac", timesteps=8, robot="gofa"),
              tmp_path / "hooking")
    assert not (tmp_path / "hooking").exists()  # refused before anything was written
