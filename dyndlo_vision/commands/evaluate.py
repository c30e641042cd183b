"""``dyndlo-vision evaluate``: success rate (95% interval), reward and its terms over many episodes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from dyndlo_vision._atomic import write_atomic, write_video_atomic

HELP = "evaluate a policy (shipped name, .zip, 'geometric', 'flick-vault' or 'random') over N episodes"


#: Scripted policies ``evaluate`` takes by name, with the task each belongs to (None: any task).
SCRIPTED = {"geometric": "time-oscillation", "flick-vault": "vaulting", "random": None}


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``evaluate``."""
    from dyndlo_vision.learning.config import TASK_NAMES

    p.add_argument(
        "policy",
        help="shipped policy name, path to a stable-baselines3 .zip, 'geometric' (task IV's baseline), "
        "'flick-vault' (the scripted vault of task II) or 'random' (uniform actions seeded by --seed: the "
        "task's chance level; needs --task)",
    )
    p.add_argument(
        "--task",
        choices=sorted(TASK_NAMES),
        default=None,
        help="default: the policy's own task (from its metadata)",
    )
    p.add_argument(
        "--multi-step",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="default: the policy's own mode",
    )
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=100_000, help="first episode seed (default: 100000, unseen)")
    p.add_argument("--env-option", action="append", metavar="KEY=VALUE", help="task option (repeatable)")
    p.add_argument(
        "--geometric-time",
        type=float,
        default=1.35,
        help="trajectory time of the geometric baseline in s (default 1.35)",
    )
    p.add_argument(
        "--randomize-cable",
        action="store_true",
        help="a new cable (length, mass, E, damping; training's --randomize-cable ranges) every episode, "
        "drawn from the episode's seed: success under cable variation, also for tasks with a fixed start",
    )
    p.add_argument("--out", default=None, help="JSON report path (default: print only)")
    p.add_argument("--video", default=None, help="MP4 of the first --video-episodes episodes")
    p.add_argument("--video-episodes", type=int, default=3)


def run(args: argparse.Namespace) -> int:
    """Load the policy, run the episodes, print and write the report."""
    import dyndlo_vision  # noqa: F401
    from dyndlo_vision import policies
    from dyndlo_vision.commands.train import parse_assignments
    from dyndlo_vision.learning.config import env_id
    from dyndlo_vision.learning.evaluate import evaluate, records_as_dicts

    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    options = parse_assignments(args.env_option, "--env-option")
    meta: dict[str, Any] = {}
    if args.policy not in SCRIPTED:
        _, meta = policies.resolve(args.policy)
    task = args.task or meta.get("task") or SCRIPTED.get(args.policy)
    if task is None:
        raise ValueError(f"{args.policy!r} has no metadata naming its task: pass --task")
    multi_step = args.multi_step if args.multi_step is not None else bool(meta.get("multi_step", False))
    options = {**meta.get("env_options", {}), **options}
    env = _make_env(env_id(task), multi_step, options, args.randomize_cable)
    if args.policy == "geometric":
        from dyndlo_vision.tasks.baselines import GeometricLift

        policy: Any = GeometricLift(env, args.geometric_time)
    elif args.policy == "flick-vault":
        from dyndlo_vision.tasks.baselines import FlickVault

        policy = FlickVault(env)
    elif args.policy == "random":
        from dyndlo_vision.tasks.baselines import RandomActions

        policy = RandomActions(env, seed=args.seed)
    else:
        policy = policies.load(args.policy, env=env, algo=meta.get("algo"))
    for path in (args.out, args.video):
        if path is not None and not Path(path).parent.exists():
            raise ValueError(f"output folder {Path(path).parent} does not exist")
    report, records = evaluate(policy, env, args.episodes, args.seed)
    report.update(
        {
            "policy": str(args.policy),
            "task": task,
            "multi_step": multi_step,
            "env_options": options,
            "randomize_cable": bool(args.randomize_cable),
        }
    )
    print(json.dumps({k: v for k, v in report.items() if k != "episodes_detail"}, indent=2))
    if args.out:
        full = {**report, "episodes_detail": records_as_dicts(records)}
        write_atomic(Path(args.out), lambda p: Path(p).write_text(json.dumps(full, indent=2)))
        print(f"wrote {args.out}")
    if args.video:
        if args.policy == "random":
            policy = RandomActions(env, seed=args.seed)  # the video replays the evaluated episodes' actions
        _write_video(
            Path(args.video),
            env_id(task),
            multi_step,
            options,
            policy,
            args.seed,
            args.video_episodes,
            args.randomize_cable,
        )
        print(f"wrote {args.video}")
    return 0


def _make_env(
    gym_id: str,
    multi_step: bool,
    options: dict[str, Any],
    randomize_cable: bool,
    render_mode: str | None = None,
) -> Any:
    """The evaluated environment; with ``randomize_cable`` a new cable every episode, drawn from its seed."""
    import gymnasium as gym

    env = gym.make(gym_id, multi_step=multi_step, render_mode=render_mode, **options)
    if randomize_cable:
        from dyndlo_vision.control.wrappers import CableRandomization

        env = CableRandomization(env, every_episodes=1)
    return env


def _write_video(
    path: Path,
    gym_id: str,
    multi_step: bool,
    options: dict[str, Any],
    policy: Any,
    seed: int,
    episodes: int,
    randomize_cable: bool = False,
) -> None:
    """Render episodes at 25 Hz of simulated time to an MP4, atomically (the same cables as evaluated)."""
    import numpy as np

    from dyndlo_vision.learning.evaluate import as_action_fn

    env = _make_env(gym_id, multi_step, options, randomize_cable, render_mode="rgb_array")
    base = env.unwrapped
    act = as_action_fn(policy)
    frames: list[np.ndarray] = []
    for i in range(episodes):
        obs, _ = env.reset(seed=seed + i)
        # Set after reset: a new cable rebuilds the environment, which clears the hook.
        base.frame_hook = lambda e: frames.append(e.render())  # every 40 ms of simulated time
        frames.append(base.render())
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(act(obs))
            done = terminated or truncated
    env.close()
    write_video_atomic(path, frames)
