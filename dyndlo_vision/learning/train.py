"""Train a policy on a DynDLO task with stable-baselines3, resumably.

A run folder holds::

    config.json              the resolved RunConfig (what to resume with)
    checkpoint/model.zip     latest weights and optimiser state, written atomically
    checkpoint/replay_buffer.pkl   (SAC) the replay buffer, so a resumed run keeps its experience
    checkpoint/state.json    steps done, wall time so far
    monitor/env*.monitor.csv per-episode reward, length, success of the training environments
    eval/evaluations.npz     EvalCallback: timesteps, episode rewards, successes
    tb/                      TensorBoard logs
    model.zip, summary.json  the final policy and the run's figures (wall time, env steps/s, success)
    demonstrations.json      (``--demonstrations N``) the baseline episodes that seeded SAC's replay buffer

Everything that can be checked is checked before the folder is touched (:func:`check_run`); a new run that
fails before its first checkpoint takes back what it wrote, so the same command can simply be run again.

The command line is ``dyndlo-vision train`` (:mod:`dyndlo_vision.commands.train`).
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import logging
import os
import shutil
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np

from dyndlo_vision._atomic import interrupts_held, write_atomic
from dyndlo_vision.learning.config import RunConfig
from dyndlo_vision.learning.envs import make_training_env, make_vec_env
from dyndlo_vision.policies import algorithm_class

log = logging.getLogger(__name__)

CHECKPOINT_DIR = "checkpoint"
DEMONSTRATIONS_FILE = "demonstrations.json"
#: Constructor arguments of the algorithm that :func:`train` sets itself, so hyperparameters may not.
RESERVED_HYPERPARAMS = ("policy", "env", "seed", "verbose", "tensorboard_log")


def valid_hyperparams(algo: str) -> list[str]:
    """Names the hyperparameters of ``algo`` may have: its constructor's keyword arguments, less reserved."""
    params = inspect.signature(algorithm_class(algo).__init__).parameters
    return sorted(
        name
        for name, param in params.items()
        if param.kind in (param.POSITIONAL_OR_KEYWORD, param.KEYWORD_ONLY)
        and name != "self"
        and not name.startswith("_")
        and name not in RESERVED_HYPERPARAMS
    )


def check_hyperparams(algo: str, hyperparams: dict[str, Any]) -> None:
    """Refuse hyperparameter names the algorithm's constructor does not take.

    Raises:
        ValueError: Naming the bad keys and listing the valid ones.
    """
    reserved = [key for key in hyperparams if key in RESERVED_HYPERPARAMS]
    if reserved:
        raise ValueError(
            f"hyperparameter(s) {reserved} cannot be set with --hp: train sets "
            f"{list(RESERVED_HYPERPARAMS)} itself (the seed with --seed)"
        )
    valid = valid_hyperparams(algo)
    unknown = [key for key in hyperparams if key not in valid]
    if unknown:
        raise ValueError(f"unknown {algo} hyperparameter(s) {unknown}; valid: {', '.join(valid)}")


def has_checkpoint(out: Path) -> bool:
    """Whether ``out`` holds a complete checkpoint to resume from (state.json is written last)."""
    ckpt = Path(out) / CHECKPOINT_DIR
    return (ckpt / "model.zip").is_file() and (ckpt / "state.json").is_file()


def _check_out(out: Path) -> None:
    """Refuse an output path that cannot become a run folder, before anything is created."""
    if out.exists() and not out.is_dir():
        raise ValueError(
            f"--out {out}: exists and is not a folder (expected a run folder to create or resume)"
        )
    existing = next(p for p in (out.absolute(), *out.absolute().parents) if p.exists())
    if not existing.is_dir():
        raise ValueError(f"--out {out}: cannot create it, {existing} is not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"--out {out}: cannot write in {existing} (permission denied)")


def check_run(config: RunConfig, out: Path, resume: bool = False) -> RunConfig:
    """Check a run before anything is written; return the configuration to run with.

    A new run needs an output path that can become a folder and holds no other run, hyperparameters the
    algorithm takes, and environments that can be made (task options, observation-noise file). A resumed
    run takes its stored configuration; ``config.timesteps`` may keep or extend its budget, never shrink it.

    Raises:
        ValueError: Naming what is wrong: the path, a hyperparameter, a task option, the noise-model file,
            a budget below the stored one or below the steps already done, a run without checkpoint.
        FileNotFoundError: If ``resume`` and ``out`` holds no ``config.json``, or the noise-model file is
            missing.
    """
    _check_out(out)
    if resume:
        stored = RunConfig.from_json(out / "config.json")
        if not has_checkpoint(out):
            raise ValueError(
                f"{out} has no checkpoint to resume from ({out / CHECKPOINT_DIR / 'state.json'} is missing)"
            )
        done = _steps_done(out / CHECKPOINT_DIR)
        # Shrinking the budget would be silently ignored (or, below the steps done, meaningless): refuse it.
        if config.timesteps != stored.timesteps and config.timesteps < max(stored.timesteps, done):
            raise ValueError(
                f"--timesteps {config.timesteps} on --resume: the run in {out} has a budget of "
                f"{stored.timesteps} steps, {done} done; a resumed run keeps its budget (leave --timesteps "
                f"out) or extends it (--timesteps {max(stored.timesteps + 1, done)} or more)"
            )
        config = dataclasses.replace(stored, timesteps=config.timesteps)
    else:
        if (out / "config.json").exists():
            if has_checkpoint(out):
                raise ValueError(
                    f"{out} already holds a run; pass --resume to continue it or choose another --out"
                )
            raise ValueError(
                f"{out} holds a run that stopped before its first checkpoint (config.json, no "
                f"{CHECKPOINT_DIR}/): there is nothing to resume; delete the folder or choose another --out"
            )
        check_hyperparams(config.algo, config.hyperparams)  # (a resumed run loads its model instead)
    from dyndlo_vision.tasks.noise import SHIPPED_NOISE_MODELS, ObservationNoiseModel

    if config.obs_noise and config.obs_noise not in SHIPPED_NOISE_MODELS:
        if not Path(config.obs_noise).is_file():
            raise FileNotFoundError(f"observation-noise model {config.obs_noise}: no such file")
        ObservationNoiseModel.load(config.obs_noise)  # ValueError naming the file and what is wrong
    # One environment made here, in this process: a bad task option (or anything else an environment
    # refuses) is a clean ValueError now, instead of a dead worker process after the folder exists.
    make_training_env(config).close()
    return config


class _Footprint:
    """What a new run adds to the file system, so that a run failing before its first checkpoint can
    take back exactly that: the folders it created, or the entries it added to a folder that existed."""

    def __init__(self, out: Path) -> None:
        self.out = out.absolute()
        self.new_folders: list[Path] = []  # the folders this run creates, ``out`` first, then its parents
        path = self.out
        while not path.exists() and not path.is_symlink():
            self.new_folders.append(path)
            path = path.parent
        self.before = set() if self.new_folders else set(self.out.iterdir())

    def remove(self) -> None:
        """Delete what was created since ``__init__``; nothing that was there before."""
        if self.new_folders:
            shutil.rmtree(self.out, ignore_errors=True)
            # A new parent may meanwhile hold other runs (seeds started together into a new runs/):
            # remove it only while empty.
            for parent in self.new_folders[1:]:
                try:
                    parent.rmdir()
                except OSError:
                    break
            return
        for entry in self.out.iterdir():
            if entry in self.before:
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
            else:
                entry.unlink(missing_ok=True)


class _RunCallbacks:
    """Builds the callbacks: checkpoints, progress bar, and the wall-clock bookkeeping."""

    @staticmethod
    def build(config: RunConfig, out: Path, state: dict[str, Any], progress_bar: bool) -> list[Any]:
        from stable_baselines3.common.callbacks import BaseCallback

        class Checkpoint(BaseCallback):  # type: ignore[misc]
            """Save weights (+ replay buffer) every ``checkpoint_freq`` steps, atomically."""

            def __init__(self) -> None:
                super().__init__()
                self.last = 0
                self.t0 = time.perf_counter()
                self.wall0 = float(state.get("wall_s", 0.0))

            def _on_step(self) -> bool:
                if self.num_timesteps - self.last >= config.checkpoint_freq:
                    self.save()
                return True

            def save(self) -> None:
                save_checkpoint(self.model, out, self.wall0 + time.perf_counter() - self.t0)
                self.last = self.num_timesteps

        class Progress(BaseCallback):  # type: ignore[misc]
            """A tqdm bar over environment steps (stderr)."""

            def _on_training_start(self) -> None:
                from tqdm import tqdm

                self.bar = tqdm(
                    total=config.timesteps, initial=self.num_timesteps, unit="step", dynamic_ncols=True
                )

            def _on_step(self) -> bool:
                self.bar.update(self.num_timesteps - self.bar.n)
                return True

            def _on_training_end(self) -> None:
                self.bar.close()

        callbacks: list[Any] = [Checkpoint()]
        if progress_bar:
            callbacks.append(Progress())
        return callbacks


def save_checkpoint(model: Any, out: Path, wall_s: float) -> None:
    """Write model, replay buffer (off-policy) and state atomically to ``out/checkpoint``.

    A Ctrl-C or SIGTERM while it writes is held until the checkpoint is whole, then raised as
    KeyboardInterrupt (:func:`~dyndlo_vision._atomic.interrupts_held`).
    """
    ckpt = out / CHECKPOINT_DIR
    ckpt.mkdir(parents=True, exist_ok=True)
    with interrupts_held():
        write_atomic(ckpt / "model.zip", lambda p: model.save(p))
        if hasattr(model, "replay_buffer") and model.replay_buffer is not None:
            write_atomic(ckpt / "replay_buffer.pkl", lambda p: model.save_replay_buffer(p))
        state = {"num_timesteps": int(model.num_timesteps), "wall_s": wall_s, "time": time.time()}
        write_atomic(ckpt / "state.json", lambda p: Path(p).write_text(json.dumps(state, indent=2)))


def _eval_callback(config: RunConfig, out: Path) -> Any:
    from stable_baselines3.common.callbacks import EvalCallback

    # One environment (the same episodes in either kind); a batched run evaluates in a batched one.
    kind = "batch" if config.vec_env == "batch" else "dummy"
    eval_env = make_vec_env(config, 1, config.seed + 10_000, None, kind, randomize=False)
    callback = EvalCallback(
        eval_env,
        n_eval_episodes=config.eval_episodes,
        eval_freq=max(1, config.eval_freq // config.n_envs),
        log_path=str(out / "eval"),
        best_model_save_path=str(out / "eval"),
        deterministic=True,
        verbose=0,
    )
    _restore_evaluations(callback, out / "eval" / "evaluations.npz")
    return callback


def _restore_evaluations(callback: Any, path: Path) -> None:
    """Carry a resumed run's earlier evaluations over, so evaluations.npz keeps the whole learning curve."""
    if not path.is_file():
        return
    try:
        data = np.load(path)
        callback.evaluations_timesteps = [int(t) for t in data["timesteps"]]
        callback.evaluations_results = [list(r) for r in data["results"]]
        callback.evaluations_length = [list(n) for n in data["ep_lengths"]]
        if "successes" in data:
            callback.evaluations_successes = [list(x) for x in data["successes"]]
    except (OSError, KeyError, ValueError) as err:
        log.warning("could not read earlier evaluations from %s (%s): the curve restarts here", path, err)


def train(config: RunConfig, out: Path, resume: bool = False, progress_bar: bool = True) -> dict[str, Any]:
    """Train (or resume) a run in ``out`` and return its summary (also written to ``out/summary.json``).

    Everything is checked first (:func:`check_run`). A new run that fails or is interrupted before its
    first checkpoint removes what it wrote; after that, it leaves a checkpoint to resume from. SIGTERM
    ends the run like Ctrl-C: checkpoint, then KeyboardInterrupt.

    Raises:
        ValueError: If ``out`` holds another run and ``resume`` is False, holds no checkpoint to resume,
            or the configuration is refused (see :func:`check_run`).
        KeyboardInterrupt: On Ctrl-C or SIGTERM, after saving a checkpoint when training had started.
    """
    out = Path(out)
    config = check_run(config, out, resume)
    footprint = None if resume else _Footprint(out)
    previous = signal.signal(signal.SIGTERM, _raise_keyboard_interrupt)
    try:
        return _train(config, out, resume, progress_bar)
    except BaseException:
        if footprint is not None and not has_checkpoint(out):
            # Nothing to resume from: a folder holding only config.json and monitor/ could be neither
            # resumed nor started again, so take it back and let the same command run afresh.
            footprint.remove()
            log.warning("the run stopped before its first checkpoint: removed what it wrote in %s", out)
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)


def _train(config: RunConfig, out: Path, resume: bool, progress_bar: bool) -> dict[str, Any]:
    """The body of :func:`train`, on a checked configuration."""
    import torch

    config_file = out / "config.json"
    ckpt = out / CHECKPOINT_DIR
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(config_file, lambda p: Path(p).write_text(config.to_json()))
    torch.set_num_threads(1)  # one core per process: the environments take the others

    state: dict[str, Any] = {}
    if config.vec_env == "subproc" and config.n_envs > 1:  # make_vec_env's condition for worker processes
        _start_forkserver_ignoring_sigint()
    vec = make_vec_env(
        config,
        config.n_envs,
        config.seed + (_steps_done(ckpt) if resume else 0),
        out / "monitor",
        config.vec_env,
        append_monitor=resume,  # a resumed run continues its episode log
    )
    cls = algorithm_class(config.algo)
    try:
        if resume:
            state = json.loads((ckpt / "state.json").read_text())
            model = cls.load(ckpt / "model.zip", env=vec, tensorboard_log=str(out / "tb"))
            if (ckpt / "replay_buffer.pkl").is_file():
                model.load_replay_buffer(ckpt / "replay_buffer.pkl")
            log.info("resuming %s at step %d", out, model.num_timesteps)
        else:
            try:
                model = cls(
                    config.policy,
                    vec,
                    seed=config.seed,
                    verbose=0,
                    tensorboard_log=str(out / "tb"),
                    **config.hyperparams,
                )
            # A hyperparameter of the right name but a wrong value (SB3 checks some values with assert).
            except (TypeError, ValueError, AssertionError) as err:
                raise ValueError(
                    f"{config.algo} refused the hyperparameters {config.hyperparams}: {err}"
                ) from err
            if config.demonstrations:
                from dyndlo_vision.learning.demonstrations import seed_replay_buffer

                t_demo = time.perf_counter()
                demo = seed_replay_buffer(model, vec, config, config.demonstrations, config.seed)
                demo["wall_s"] = round(time.perf_counter() - t_demo, 1)
                state["wall_s"] = demo["wall_s"]  # the run's wall time includes them
                text = json.dumps(demo, indent=2)
                write_atomic(out / DEMONSTRATIONS_FILE, lambda p: Path(p).write_text(text))
                save_checkpoint(model, out, demo["wall_s"])  # resumable from here, demonstrations included
                log.info("replay buffer seeded with %s", demo)
        callbacks = _RunCallbacks.build(config, out, state, progress_bar) + [_eval_callback(config, out)]
        remaining = config.timesteps - int(model.num_timesteps)
        t0 = time.perf_counter()
        steps0 = int(model.num_timesteps)
        interrupted = False
        try:
            if remaining > 0:
                model.learn(remaining, callback=callbacks, reset_num_timesteps=not resume, tb_log_name="run")
        except KeyboardInterrupt:
            interrupted = True
            log.warning("interrupted at step %d: checkpoint saved, resume with --resume", model.num_timesteps)
        wall = float(state.get("wall_s", 0.0)) + time.perf_counter() - t0
        save_checkpoint(model, out, wall)
        if interrupted:
            raise KeyboardInterrupt
        write_atomic(out / "model.zip", lambda p: model.save(p))
    finally:
        close_vec_env(vec)
    summary = summarize(
        out,
        wall_s=wall,
        steps_this_session=int(model.num_timesteps) - steps0,
        session_s=time.perf_counter() - t0,
    )
    write_atomic(out / "summary.json", lambda p: Path(p).write_text(json.dumps(summary, indent=2)))
    return summary


def _start_forkserver_ignoring_sigint() -> None:
    """Start multiprocessing's fork server with SIGINT ignored, so the environment workers ignore it too.

    A terminal's Ctrl-C reaches the whole foreground process group. Workers that took it would die
    mid-step and leave this process unable to close them (EOFError); ignoring it, they live on until
    :func:`close_vec_env`, while this process turns Ctrl-C into a checkpoint. The fork server is exec'd
    and keeps an inherited SIG_IGN (Python leaves an ignored SIGINT alone), and every process it forks
    starts with its SIGINT handling. Only starting it is shielded, a matter of milliseconds, so a Ctrl-C
    is hardly ever lost; a fork server started earlier by someone else is left as it is (then
    :func:`close_vec_env` still copes with workers that died).
    """
    from multiprocessing import forkserver

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        forkserver.ensure_running()
    finally:
        signal.signal(signal.SIGINT, previous)


def close_vec_env(vec: Any, grace_s: float = 2.0) -> None:
    """Close a vectorised environment, also when some of its worker processes are already gone, and also
    when a Ctrl-C struck while this process was reading the workers' step results.

    SubprocVecEnv.close() talks to every worker and raises EOFError or BrokenPipeError if one has died
    (killed, or struck by a signal meant for this process), which would hide the run's own outcome (a
    checkpoint and a resume hint) behind a traceback: stop the remaining workers instead.

    A Ctrl-C inside ``step_wait`` leaves the environment ``waiting`` with some workers' results already
    read; close() would then wait for those again, for ever (a CI run hung so). So the results
    still on their way are read first, until none has arrived for ``grace_s``, and ``waiting`` is cleared.
    """
    if getattr(vec, "waiting", False) and getattr(vec, "remotes", None):
        _drain_interrupted_step(vec.remotes, grace_s)
        vec.waiting = False
    try:
        vec.close()
    except (EOFError, OSError) as err:
        log.warning("environment workers had already exited (%s: %s); stopping the rest",
                    type(err).__name__, err)
        for process in getattr(vec, "processes", []):
            if process.is_alive():
                process.terminate()
            process.join()
        for remote in getattr(vec, "remotes", []):
            remote.close()
        vec.closed = True


def _drain_interrupted_step(remotes: list[Any], grace_s: float) -> None:
    """Read the one step result each worker may still owe, giving up on a worker silent for ``grace_s``
    (its result was read before the interrupt, or it is stuck: close() and its fallback deal with it)."""
    from multiprocessing.connection import wait

    pending = list(remotes)
    while pending:
        ready = wait(pending, timeout=grace_s)
        if not ready:
            return
        for remote in ready:
            try:
                remote.recv()
            except Exception:  # noqa: BLE001  a dead worker, or a message the interrupt left half read
                log.debug("an interrupted step result could not be read", exc_info=True)
            pending.remove(remote)


def _raise_keyboard_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def _steps_done(ckpt: Path) -> int:
    try:
        return int(json.loads((ckpt / "state.json").read_text())["num_timesteps"])
    except (OSError, ValueError, KeyError):
        return 0


def summarize(out: Path, wall_s: float, steps_this_session: int, session_s: float) -> dict[str, Any]:
    """Figures of a run: steps, wall time, env steps/s, last and best evaluated success rate."""
    summary: dict[str, Any] = {
        "wall_s": round(wall_s, 1),
        "env_steps_per_s": round(steps_this_session / session_s, 2) if session_s > 0 else None,
        "cpu_count": os.cpu_count(),
    }
    demos = out / DEMONSTRATIONS_FILE
    if demos.is_file():
        summary["demonstrations"] = json.loads(demos.read_text())
    evals = out / "eval" / "evaluations.npz"
    if evals.is_file():
        data = np.load(evals)
        steps = data["timesteps"]
        summary["eval_timesteps"] = int(steps[-1]) if len(steps) else 0
        if "successes" in data and len(data["successes"]):
            rates = data["successes"].mean(axis=1)
            summary["eval_success_last"] = float(rates[-1])
            summary["eval_success_best"] = float(rates.max())
            hit = np.nonzero(rates >= 0.9)[0]
            summary["first_step_at_90pct"] = int(steps[hit[0]]) if len(hit) else None
        summary["eval_reward_last"] = float(data["results"][-1].mean()) if len(steps) else None
    return summary
