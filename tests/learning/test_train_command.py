"""``train`` when things go wrong: bad input refused up front, failed runs cleaned up, Ctrl-C, resuming."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import dyndlo_vision
from dyndlo_vision.cli import main
from dyndlo_vision.learning import train as train_module
from dyndlo_vision.learning.config import RunConfig
from dyndlo_vision.learning.train import check_run, close_vec_env, train


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


def _noise_file(tmp_path: Path, text: str) -> str:
    path = tmp_path / "noise.json"
    path.write_text(text)
    return str(path)


# Each case: extra arguments, what the message must say. The user's commands: SAC, subprocess workers.
BAD_INPUT: list[tuple[list[str], list[str]]] = [
    (["--hp", "bogus=1"], ["'bogus'", "valid:", "learning_starts", "gradient_steps"]),
    (["--hp", "seed=1"], ["'seed'", "--seed"]),
    (["--env-option", "bogus=2"], ["'bogus'", "for tip-control"]),
    (["--timesteps", "0"], ["timesteps=0", "positive"]),
    (["--n-envs", "0"], ["n_envs=0", "positive"]),
    (["--eval-freq", "0"], ["eval_freq=0", "positive"]),
    (["--checkpoint-freq", "-5"], ["checkpoint_freq=-5", "positive"]),
]


@pytest.mark.parametrize(("extra", "expected"), BAD_INPUT)
def test_bad_input_is_refused_before_anything_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_environments: None, extra: list[str],
    expected: list[str],
) -> None:
    out = tmp_path / "run"
    argv = ["train", "--task", "tip-control", "--algo", "sac", "--timesteps", "50", "--out", str(out), *extra]
    message = _refuses(argv, capsys)
    for text in expected:
        assert text in message, (text, message)
    assert not out.exists()


@pytest.mark.parametrize(
    ("text", "expected"),
    [("{broken", "not valid JSON"), ('{"format": 1}', "format is 1"), ("[1, 2]", "expected a JSON object")],
)
def test_a_malformed_noise_file_is_refused_before_anything_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_environments: None, text: str, expected: str
) -> None:
    noise = _noise_file(tmp_path, text)
    out = tmp_path / "run"
    message = _refuses(["train", "--task", "tip-control", "--algo", "sac", "--obs-noise", noise,
                        "--out", str(out)], capsys)
    assert noise in message and expected in message and "Traceback" not in message
    assert not out.exists()


def test_an_out_path_that_cannot_be_a_folder_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_environments: None
) -> None:
    regular = tmp_path / "notes.txt"
    regular.write_text("mine")
    message = _refuses(["train", "--out", str(regular)], capsys)
    assert str(regular) in message and "not a folder" in message
    message = _refuses(["train", "--out", str(regular / "run")], capsys)
    assert str(regular) in message and "not a folder" in message
    assert regular.read_text() == "mine"


def _config(**changes: Any) -> RunConfig:
    """A tiny SAC run on the cheapest task, in this process."""
    base = RunConfig(
        task="time-oscillation", multi_step=False, algo="sac", timesteps=4, seed=1, n_envs=1, vec_env="dummy",
        hyperparams={"learning_starts": 2, "batch_size": 4}, env_options={"layout": "diagonal"},
        eval_freq=100, eval_episodes=1, checkpoint_freq=2,
    )
    return dataclasses.replace(base, **changes)


@pytest.mark.parametrize("error", [RuntimeError("simulated crash"), KeyboardInterrupt()])
def test_a_run_failing_before_its_first_checkpoint_takes_back_what_it_wrote(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, error: BaseException
) -> None:
    def fail(config: RunConfig, out: Path) -> None:  # after config.json, monitor/ and the model exist
        assert (out / "config.json").is_file() and (out / "monitor").is_dir()
        raise error

    monkeypatch.setattr(train_module, "_eval_callback", fail)
    # A new folder (and a new parent): all of it goes.
    with pytest.raises(type(error)):
        train(_config(), tmp_path / "new" / "run", progress_bar=False)
    assert not (tmp_path / "new").exists()
    # ... unless another run has meanwhile started in the new parent (seeds launched together).
    def fail_beside_another(config: RunConfig, out: Path) -> None:
        (out.parent / "seed1" / "config.json").parent.mkdir()
        (out.parent / "seed1" / "config.json").write_text("another run's")
        raise error

    monkeypatch.setattr(train_module, "_eval_callback", fail_beside_another)
    with pytest.raises(type(error)):
        train(_config(), tmp_path / "runs" / "seed0", progress_bar=False)
    assert [p.name for p in (tmp_path / "runs").iterdir()] == ["seed1"]
    assert (tmp_path / "runs" / "seed1" / "config.json").read_text() == "another run's"
    # A folder that was there, with something of the user's in it: only what the run added goes.
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    with pytest.raises(type(error)):
        train(_config(), mine, progress_bar=False)
    assert [p.name for p in mine.iterdir()] == ["notes.txt"] and (mine / "notes.txt").read_text() == "keep me"
    check_run(_config(), mine)  # the same run can start again


def test_a_folder_left_by_an_older_failed_run_gets_a_clear_message(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], no_environments: None
) -> None:
    out = tmp_path / "run"
    (out / "monitor").mkdir(parents=True)
    (out / "config.json").write_text(_config().to_json())
    message = _refuses(["train", "--out", str(out)], capsys)
    assert "before its first checkpoint" in message and "delete the folder" in message
    message = _refuses(["train", "--resume", "--out", str(out)], capsys)
    assert "no checkpoint" in message
    assert sorted(p.name for p in out.iterdir()) == ["config.json", "monitor"]  # never deleted for the user


@pytest.mark.slow
def test_a_resumed_run_that_fails_keeps_its_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "run"
    train(_config(), out, progress_bar=False)
    before = sorted(p.relative_to(out) for p in out.rglob("*"))

    def fail(config: RunConfig, out: Path) -> None:
        raise RuntimeError("simulated crash")

    monkeypatch.setattr(train_module, "_eval_callback", fail)
    with pytest.raises(RuntimeError, match="simulated crash"):
        train(_config(timesteps=8), out, resume=True, progress_bar=False)
    after = sorted(p.relative_to(out) for p in out.rglob("*"))
    assert set(before) <= set(after)


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


def test_ctrl_c_before_the_first_checkpoint_says_there_is_nothing_to_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def interrupted(config: RunConfig, out: Path, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(train_module, "train", interrupted)
    assert main(["train", "--out", str(tmp_path / "run")]) == 130
    printed = capsys.readouterr().out
    assert "nothing to resume" in printed and "--resume" not in printed


def test_a_ctrl_c_while_a_checkpoint_is_written_waits_for_the_checkpoint(tmp_path: Path) -> None:
    """A Ctrl-C that lands while the model is being saved does not cut the checkpoint: it is written whole
    (model, replay buffer, state), then the interrupt is raised. Cut mid-write, torch's zip writer replaced
    the KeyboardInterrupt by its own RuntimeError and ``train`` exited 1, not 130 (session 32). seg-train's
    checkpoint is held the same way."""

    class Model:
        num_timesteps = 7
        replay_buffer = object()

        def save(self, path: Path) -> None:
            Path(path).write_bytes(b"first half ")
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C mid-write
            time.sleep(0.05)
            with Path(path).open("ab") as f:
                f.write(b"second half")

        def save_replay_buffer(self, path: Path) -> None:
            Path(path).write_bytes(b"buffer")

    before = signal.getsignal(signal.SIGINT)  # SIG_IGN under a runner started in the background
    with pytest.raises(KeyboardInterrupt):
        train_module.save_checkpoint(Model(), tmp_path, 1.5)
    ckpt = tmp_path / train_module.CHECKPOINT_DIR
    assert (ckpt / "model.zip").read_bytes() == b"first half second half"
    assert (ckpt / "replay_buffer.pkl").read_bytes() == b"buffer"
    assert json.loads((ckpt / "state.json").read_text())["num_timesteps"] == 7
    assert signal.getsignal(signal.SIGINT) is before  # the handler is put back
    # seg-train's checkpoints are held the same way
    from dyndlo_vision.learning import segtrain

    class Interrupting:
        def __reduce__(self) -> tuple[Any, tuple[()]]:  # pickled by torch.save: Ctrl-C mid-write
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            return (dict, ())

    with pytest.raises(KeyboardInterrupt):
        segtrain._atomic_save({"step": 3, "x": Interrupting()}, tmp_path / "seg.pt")
    import torch

    assert torch.load(tmp_path / "seg.pt", weights_only=False)["step"] == 3

    class Quiet(Model):
        def save(self, path: Path) -> None:
            Path(path).write_bytes(b"quiet")

    train_module.save_checkpoint(Quiet(), tmp_path, 2.0)  # no signal, no interrupt
    assert (ckpt / "model.zip").read_bytes() == b"quiet"


@pytest.mark.slow
def test_close_vec_env_copes_with_a_dead_worker() -> None:
    from dyndlo_vision.learning.envs import make_vec_env

    vec = make_vec_env(_config(n_envs=2, vec_env="subproc"), 2, 0, None, "subproc")
    vec.reset()
    victim = vec.processes[1]
    os.kill(victim.pid, signal.SIGKILL)  # as a signal meant for the trainer could, or the OOM killer
    victim.join()
    close_vec_env(vec)  # SubprocVecEnv.close() alone: BrokenPipeError
    assert vec.closed and not any(p.is_alive() for p in vec.processes)


@pytest.mark.slow
def test_close_vec_env_after_a_ctrl_c_inside_step_wait_does_not_hang() -> None:
    """Ctrl-C while the trainer reads the workers' step results (SubprocVecEnv.step_wait) leaves ``waiting``
    set with some results already read. SubprocVecEnv.close() then waits for those again, for ever: a CI run
    hung 600 s after "interrupted at step 2" (session 27)."""
    import threading

    from dyndlo_vision.learning.envs import make_vec_env

    vec = make_vec_env(_config(n_envs=2, vec_env="subproc"), 2, 0, None, "subproc")
    vec.reset()
    vec.step_async(np.array([vec.action_space.sample() for _ in range(2)]))
    vec.remotes[0].recv()  # step_wait interrupted after the first worker's result
    closer = threading.Thread(target=close_vec_env, args=(vec,), daemon=True)
    closer.start()
    closer.join(timeout=60)
    hung = closer.is_alive()
    if hung:  # leave no workers behind
        for process in vec.processes:
            process.kill()
    assert not hung, "close_vec_env waited for a step result that had already been read"
    assert vec.closed and not any(p.is_alive() for p in vec.processes)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "dyndlo_vision", "train", "--quiet", *args]


def _default_sigint() -> None:
    """In the child before exec: SIGINT's default action, whatever the test runner inherited."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _env() -> dict[str, str]:
    """This process's environment, importing the same dyndlo_vision as this test in the subprocess."""
    root = str(Path(dyndlo_vision.__file__).resolve().parents[1])
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p)}


@pytest.mark.slow
def test_ctrl_c_with_subprocess_workers_exits_130_and_the_run_resumes(tmp_path: Path) -> None:
    out = tmp_path / "run"
    log = tmp_path / "train.log"
    # The first checkpoint comes at step 2; the 38 steps after it (episodes of ~0.1 s of compute each,
    # slower under load) leave ample time to interrupt the run before it completes.
    budget = 40
    command = _cli("--task", "tip-control", "--algo", "sac", "--timesteps", str(budget), "--vec-env",
                   "subproc", "--n-envs", "2", "--checkpoint-freq", "2", "--eval-freq", "1000",
                   "--eval-episodes", "1", "--out", str(out))
    state = out / "checkpoint" / "state.json"
    with log.open("w") as sink:
        # Its own process group, which a terminal's Ctrl-C signals as a whole: trainer and workers alike. With
        # SIGINT's default action, as in a terminal: a test runner started in the background by a
        # non-interactive shell (`nohup .ci/run &`) ignores SIGINT; its children inherit that, and Python
        # keeps an inherited SIG_IGN, so the trainer never saw the Ctrl-C (it ran to completion, session 10).
        proc = subprocess.Popen(command, stdout=sink, stderr=subprocess.STDOUT, start_new_session=True,
                                env=_env(), preexec_fn=_default_sigint)
        try:
            deadline = time.monotonic() + 600  # a hang guard only: start-up takes ~20 s on a loaded machine
            while not state.is_file():
                assert proc.poll() is None, f"train exited ({proc.returncode}) early:\n{log.read_text()}"
                assert time.monotonic() < deadline, f"no checkpoint:\n{log.read_text()}"
                time.sleep(0.1)
            os.killpg(proc.pid, signal.SIGINT)
            returncode = proc.wait(timeout=600)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    output = log.read_text()
    assert returncode == 130, output
    assert f"resume with: dyndlo-vision train --resume --out {out}" in output
    assert "Traceback" not in output
    assert "workers had already exited" not in output  # the workers ignored Ctrl-C and were closed in order
    steps = json.loads(state.read_text())["num_timesteps"]
    assert steps < budget, "the run finished before it was interrupted: raise the budget of this test"
    assert not (out / "model.zip").exists()

    # The hint's command, as printed: continues to the stored budget and completes.
    done = subprocess.run(_cli("--resume", "--out", str(out)), capture_output=True, text=True, env=_env(),
                          timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert budget <= json.loads(state.read_text())["num_timesteps"] < budget + 2
    assert (out / "model.zip").is_file()


@pytest.mark.parametrize(
    ("task", "algo"),
    [("tip-control", "ppo"), ("vaulting", "ppo"), ("hooking", "ppo"), ("time-oscillation", "sac")],
)
def test_each_task_trains_with_the_papers_algorithm_by_default(
    task: str, algo: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Section V: PPO for tasks I-III, SAC for task IV; the run folder and the paper's budget follow."""
    from dyndlo_vision.learning.config import load_hyperparams

    seen: list[tuple[RunConfig, Path]] = []

    def record(config: RunConfig, out: Path, **kwargs: Any) -> dict[str, Any]:
        seen.append((config, out))
        return {}

    monkeypatch.setattr(train_module, "train", record)
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--task", task, "--quiet"]) == 0
    (config, out), = seen
    assert config.algo == algo and out == Path(f"runs/{task}-{algo}-s0")
    assert config.timesteps == load_hyperparams(algo, task, False)["n_timesteps"]  # the paper's budget


def test_cable_ranges_reach_the_training_environments(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``train --cable-ranges beyond`` (as in demo, evaluate and distill) trains on cables drawn from the
    wider ranges, every 10 episodes; config.json keeps the ranges, and one stored before they were an option
    loads with the training ranges."""
    from dyndlo_vision.learning.envs import make_training_env
    from dyndlo_vision.tasks.wrappers import BEYOND_TRAINING_CABLE_RANGES

    seen: list[RunConfig] = []

    def capture(config: RunConfig, *args: object, **kwargs: object) -> None:
        seen.append(config)
        raise KeyboardInterrupt

    monkeypatch.setattr(train_module, "make_vec_env", capture)
    out = tmp_path / "r"
    argv = ["train", "--algo", "sac", "--timesteps", "50", "--cable-ranges", "beyond", "--out", str(out)]
    assert main(argv) == 130
    (config,) = seen
    assert config.randomize_cable and config.cable_ranges == "beyond"
    env = make_training_env(config)
    wrapper = env.env  # inside the Monitor
    assert wrapper.ranges == BEYOND_TRAINING_CABLE_RANGES and wrapper.every_episodes == 10
    env.close()
    older = {k: v for k, v in json.loads(config.to_json()).items() if k != "cable_ranges"}
    (tmp_path / "config.json").write_text(json.dumps(older))
    assert RunConfig.from_json(tmp_path / "config.json").cable_ranges == "training"
    with pytest.raises(ValueError, match="cable_ranges='beyond' draws random cables: it needs"):
        dataclasses.replace(config, randomize_cable=False)
