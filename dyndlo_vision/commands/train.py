"""``dyndlo-vision train``: train PPO or SAC on a DynDLO task, with checkpoints, evaluation and resume."""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

if TYPE_CHECKING:
    from dyndlo_vision.learning.config import RunConfig

HELP = "train a policy (PPO/SAC) on a task; resumable"


def parse_assignments(items: list[str] | None, flag: str) -> dict[str, Any]:
    """``["a=1", "b=[64, 64]"]`` -> ``{"a": 1, "b": [64, 64]}`` (values parsed as YAML)."""
    result: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"{flag} {item!r}: expected KEY=VALUE")
        try:
            result[key] = yaml.safe_load(value)
        except yaml.YAMLError as err:
            raise ValueError(f"{flag} {item!r}: the value is not valid YAML ({err})") from err
    return result


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``train``."""
    from dyndlo_vision.commands import _options as options
    from dyndlo_vision.policies import ALGORITHMS
    from dyndlo_vision.tasks.registry import TASKS

    p.epilog = ("Random cables (--randomize-cable, --cable-ranges) are drawn every 10 training episodes; the "
                "evaluations during training keep the nominal cable.")
    options.add_task(p)
    options.add_multi_step(p)
    p.add_argument(
        "--algo",
        choices=sorted(ALGORITHMS),
        default=None,
        help="default: the paper's for the task ("
        + ", ".join(f"{entry.algo} for {name}" for name, entry in TASKS.items())
        + ")",
    )
    p.add_argument(
        "--timesteps", type=int, default=None, help="total decisions (default: the paper's budget)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the learner; training episodes use seed + k")
    p.add_argument(
        "--out", default=None, help="run folder (default: runs/<task>[-multi-step]-<algo>-s<seed>)"
    )
    p.add_argument("--n-envs", type=int, default=None, help="parallel environments (default: from the YAML)")
    p.add_argument("--vec-env", choices=["subproc", "dummy", "batch"], default="subproc",
                   help="environments in worker processes, in this one, or one batched environment (the "
                        "physics of all in one call on C threads; the same episodes; not with --robot)")
    p.add_argument(
        "--hp", action="append", metavar="KEY=VALUE", help="override a hyperparameter (repeatable)"
    )
    options.add_env_option(p)
    options.add_obs_noise(p)
    options.add_cable_options(p)
    p.add_argument(
        "--demonstrations", type=int, default=0, metavar="N",
        help="SAC, single-step task IV or vaulting: seed the replay buffer with N perturbed episodes of "
             "the task's scripted baseline (geometric lift; scripted vault) before learning (default 0, as "
             "in the paper)",
    )
    options.add_robot(p)
    p.add_argument("--eval-freq", type=int, default=2000, help="evaluate every N steps (default 2000)")
    p.add_argument("--eval-episodes", type=int, default=20,
                   help="episodes per evaluation (seeds seed + 10000 on)")
    p.add_argument(
        "--checkpoint-freq", type=int, default=2000, help="checkpoint every N steps (default 2000)"
    )
    options.add_resume(p)
    options.add_quiet(p)


def run(args: argparse.Namespace) -> int:
    """Resolve the configuration (a new one, or the stored one on ``--resume``), then train.

    Returns 0 when the run completes, 130 when Ctrl-C (or SIGTERM) stopped it. Bad input raises
    ValueError (the CLI's exit status 2) before anything is written.
    """
    from dyndlo_vision.learning.train import has_checkpoint, train
    from dyndlo_vision.tasks.registry import task_entry

    entry = task_entry(args.task)
    algo = args.algo or entry.algo
    out = Path(args.out or f"runs/{entry.hyperparams_key(bool(args.multi_step))}-{algo}-s{args.seed}")
    config = _resumed_config(args, out) if args.resume else _new_config(args, algo)
    try:
        summary = train(config, out, resume=args.resume, progress_bar=not args.quiet)
    except KeyboardInterrupt:
        if has_checkpoint(out):
            print(f"interrupted; resume with: dyndlo-vision train --resume --out {shlex.quote(str(out))}")
        else:
            print(f"interrupted before the first checkpoint: nothing to resume (what it wrote in {out} "
                  "is removed)")
        return 130
    print(json.dumps(summary, indent=2))
    print(f"wrote {out / 'model.zip'}")
    return 0


def _new_config(args: argparse.Namespace, algo: str) -> RunConfig:
    """The RunConfig of a new run: the YAML entry of the task and mode, overridden by the options."""
    from dyndlo_vision.commands._options import random_cables
    from dyndlo_vision.learning.config import RANDOMIZE_CABLE_EVERY, RunConfig, load_hyperparams
    from dyndlo_vision.tasks.noise import resolve_noise_model_path

    obs_noise = resolve_noise_model_path(args.obs_noise)
    cables = random_cables(args, every_episodes=RANDOMIZE_CABLE_EVERY)
    multi_step = bool(args.multi_step)
    entry = load_hyperparams(algo, args.task, multi_step)
    hyperparams = {**entry["hyperparams"], **parse_assignments(args.hp, "--hp")}
    return RunConfig(
        task=args.task,
        multi_step=multi_step,
        algo=algo,
        timesteps=args.timesteps if args.timesteps is not None else int(entry["n_timesteps"]),
        seed=args.seed,
        n_envs=args.n_envs if args.n_envs is not None else int(entry["n_envs"]),
        vec_env=args.vec_env,
        policy=entry.get("policy", "MlpPolicy"),
        hyperparams=hyperparams,
        env_options=parse_assignments(args.env_option, "--env-option"),
        obs_noise=obs_noise,
        randomize_cable=cables is not None,
        cable_ranges="training" if cables is None else cables.ranges,
        eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes,
        checkpoint_freq=args.checkpoint_freq,
        demonstrations=args.demonstrations,
        robot=args.robot,
    )


def _resumed_config(args: argparse.Namespace, out: Path) -> RunConfig:
    """The stored RunConfig of the run in ``out``, with ``--timesteps`` as its new budget if given.

    Without ``--timesteps`` the stored budget stands: the YAML's (the paper's) budget is not a request to
    train on, and taking it would turn a resumed 2 000-step run into a 400 000-step one.
    """
    from dyndlo_vision.learning.config import RunConfig

    stored = RunConfig.from_json(out / "config.json")
    return stored if args.timesteps is None else dataclasses.replace(stored, timesteps=args.timesteps)
