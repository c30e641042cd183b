"""``dyndlo-vision evaluate``: success rate (95% interval), reward and its terms over many episodes."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dyndlo_vision._atomic import write_atomic
from dyndlo_vision._video import write_video_atomic

if TYPE_CHECKING:
    from dyndlo_vision.tasks.wrappers import RandomCables

HELP = "evaluate a policy (shipped name, .zip, 'geometric', 'flick-vault' or 'random') over N episodes"


#: The chance-level policy, for any task; the scripted baselines come from the task registry.
RANDOM = "random"


def scripted_policies() -> dict[str, str | None]:
    """Scripted policies ``evaluate`` takes by name, with the task each belongs to (None: any task)."""
    from dyndlo_vision.tasks.registry import TASKS

    own = {entry.baseline: name for name, entry in TASKS.items() if entry.baseline is not None}
    return {**own, RANDOM: None}


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``evaluate``."""
    from dyndlo_vision.commands import _options as options

    p.epilog = ("With --robot, the report's 'joints' block gives the joint-feasible fraction and the "
                "successes with feasible plans.")
    p.add_argument(
        "policy",
        help="shipped policy name, path to a stable-baselines3 .zip, 'geometric' (task IV's baseline), "
        "'flick-vault' (the scripted vault of task II) or 'random' (uniform actions seeded by --seed: the "
        "task's chance level; needs --task)",
    )
    options.add_task(p, default=None, help="the task (default: the policy's own, from its metadata)")
    options.add_multi_step(p)
    options.add_episodes(p, default=100)
    options.add_first_seed(p)
    options.add_env_option(p)
    p.add_argument(
        "--geometric-time",
        type=float,
        default=1.35,
        help="trajectory time of the geometric baseline in s (default 1.35)",
    )
    options.add_cable_options(p)
    options.add_robot(p)
    p.add_argument("--out", default=None, help="JSON report path (default: print only)")
    p.add_argument("--video", default=None, help="MP4 (.mp4) of the first --video-episodes episodes")
    p.add_argument(
        "--video-episodes",
        type=int,
        default=None,
        help="evaluated episodes the video shows, 1 to --episodes (default: 3, or --episodes if fewer)",
    )
    options.add_quiet(p)


def run(args: argparse.Namespace) -> int:
    """Load the policy, run the episodes, print and write the report."""
    import dyndlo_vision  # noqa: F401
    from dyndlo_vision import policies
    from dyndlo_vision.commands._options import random_cables
    from dyndlo_vision.commands.train import parse_assignments
    from dyndlo_vision.learning.evaluate import evaluate, records_as_dicts
    from dyndlo_vision.tasks.baselines import GeometricLift, RandomActions
    from dyndlo_vision.tasks.registry import task_entry

    # Every option is checked before any episode runs: a bad one must not cost the minutes of a long run.
    video_episodes = check_options(args)
    cables = random_cables(args)
    options = parse_assignments(args.env_option, "--env-option")
    meta: dict[str, Any] = {}
    if args.policy not in scripted_policies():
        _, meta = policies.resolve(args.policy)
    task = policy_task(args.policy, args.task, meta)
    multi_step = policy_mode(args.policy, args.multi_step, meta)
    options = {**meta.get("env_options", {}), **options}
    robot = args.robot or meta.get("robot")
    env = _make_env(task, multi_step, options, cables, robot=robot)
    entry = task_entry(task)
    policy: Any
    if args.policy == RANDOM:
        policy = RandomActions(env, seed=args.seed)
    elif args.policy == entry.baseline and entry.baseline_class is not None:
        # The geometric lift's trajectory time is its one option on the command line.
        extra = {"total_time_s": args.geometric_time} if entry.baseline_class is GeometricLift else {}
        policy = entry.baseline_class(env, **extra)
    else:
        policy = policies.load(args.policy, env=env, algo=meta.get("algo"))
    with _progress_bar(args.episodes, f"evaluate {args.policy}", args.quiet) as bar:
        report, records = evaluate(policy, env, args.episodes, args.seed, on_episode=_counting(bar))
    report.update(
        {
            "policy": str(args.policy),
            "task": task,
            "multi_step": multi_step,
            "env_options": options,
            "randomize_cable": cables is not None,
            "cable_ranges": None if cables is None else cables.ranges,
            "robot": robot,
        }
    )
    print(json.dumps({k: v for k, v in report.items() if k != "episodes_detail"}, indent=2))
    if args.out:
        full = {**report, "episodes_detail": records_as_dicts(records)}
        write_atomic(Path(args.out), lambda p: Path(p).write_text(json.dumps(full, indent=2)))
        print(f"wrote {args.out}")
    if args.video:
        if args.policy == RANDOM:
            policy = RandomActions(env, seed=args.seed)  # the video replays the evaluated episodes' actions
        _write_video(
            Path(args.video),
            task,
            multi_step,
            options,
            policy,
            args.seed,
            video_episodes,
            cables,
            progress=not args.quiet,
        )
        print(f"wrote {args.video}")
    return 0


def check_options(args: argparse.Namespace) -> int:
    """Check the options that are only used after the episodes (and the counts); return the video's episodes.

    Raises:
        ValueError: Naming the bad option, its value and what was expected.
    """
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    if not (math.isfinite(args.geometric_time) and args.geometric_time > 0):
        raise ValueError(f"--geometric-time must be a positive time in s, got {args.geometric_time}")
    # The video replays evaluated episodes (same seeds, same cables, same random actions), so it can show
    # at most --episodes of them; an explicit larger count is an error, the default shrinks to fit.
    video_episodes = min(3, args.episodes) if args.video_episodes is None else args.video_episodes
    if not 1 <= video_episodes <= args.episodes:
        raise ValueError(
            f"--video-episodes must be between 1 and --episodes ({args.episodes}), got {video_episodes}"
        )
    for option, path in (("--out", args.out), ("--video", args.video)):
        if path is None:
            continue
        if Path(path).is_dir():
            raise ValueError(f"{option} {path} is a directory; expected a file path")
        if not Path(path).parent.is_dir():
            raise ValueError(f"{option} {path}: output folder {Path(path).parent} does not exist")
    if args.video is not None and Path(args.video).suffix.lower() != ".mp4":
        raise ValueError(f"--video {args.video}: expected a .mp4 path (OpenCV picks the container by it)")
    if (
        args.out is not None
        and args.video is not None
        and Path(args.out).resolve() == Path(args.video).resolve()
    ):
        raise ValueError(
            f"--out and --video are the same file {args.out}; the video would overwrite the report"
        )
    return video_episodes


def policy_task(policy: str, task: str | None, meta: dict[str, Any]) -> str:
    """The task to evaluate ``policy`` on: its own (metadata or scripted), which ``--task`` may only repeat.

    Raises:
        ValueError: ``task`` differs from the policy's own, or neither names one.
    """
    scripted = scripted_policies()
    own = scripted.get(policy) if policy in scripted else meta.get("task")
    if task is not None and own is not None and task != own:
        # Observation and action shapes can agree across tasks (tip control and vaulting: 12 and 9), so the
        # policy would run without complaint and report a meaningless success rate.
        raise ValueError(
            f"policy {policy!r} is a {own!r} policy but --task is {task!r}; "
            f"leave out --task or pass --task {own}"
        )
    chosen = task or own
    if chosen is None:
        raise ValueError(f"{policy!r} has no metadata naming its task: pass --task")
    return chosen


def policy_mode(policy: str, multi_step: bool | None, meta: dict[str, Any]) -> bool:
    """The mode to evaluate ``policy`` in: its own (metadata), which ``--[no-]multi-step`` may only repeat.

    Raises:
        ValueError: ``multi_step`` differs from the mode the policy was trained in.
    """
    own = meta.get("multi_step")
    if multi_step is not None and own is not None and bool(own) != multi_step:
        # Both modes have the same spaces: a single-step policy would run re-planning without complaint.
        mode = {True: "multi-step", False: "single-step"}
        option = "--multi-step" if multi_step else "--no-multi-step"
        raise ValueError(
            f"policy {policy!r} is a {mode[bool(own)]} policy but {option} asks for {mode[multi_step]} "
            "episodes; leave the option out"
        )
    return bool(own) if multi_step is None else multi_step


def _progress_bar(total: int, desc: str, quiet: bool) -> Any:
    """A progress bar over episodes on stderr (none with ``quiet``)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="episode", file=sys.stderr, disable=quiet, dynamic_ncols=True)


def _counting(bar: Any) -> Callable[[Any], None]:
    """``on_episode`` callback: advance ``bar`` and show the successes so far."""
    successes = 0

    def on_episode(record: Any) -> None:
        nonlocal successes
        successes += bool(record.success)
        bar.set_postfix(successes=successes, refresh=False)
        bar.update(1)

    return on_episode


def _make_env(
    task: str,
    multi_step: bool,
    options: dict[str, Any],
    cables: RandomCables | None,
    render_mode: str | None = None,
    robot: str | None = None,
) -> Any:
    """The evaluated environment; with ``cables`` a new cable every episode, drawn from its seed; with
    ``robot`` every plan judged on that arm's joint limits."""
    from dyndlo_vision.tasks.registry import make_env

    randomise = {} if cables is None else cables.env_options(task)
    return make_env(task, multi_step=multi_step, render_mode=render_mode, robot=robot, **randomise, **options)


def _write_video(
    path: Path,
    task: str,
    multi_step: bool,
    options: dict[str, Any],
    policy: Any,
    seed: int,
    episodes: int,
    cables: RandomCables | None = None,
    progress: bool = False,
) -> None:
    """Render episodes at 25 Hz of simulated time to an MP4, atomically (the same cables as evaluated)."""
    import numpy as np

    from dyndlo_vision.learning.evaluate import as_action_fn

    env = _make_env(task, multi_step, options, cables, render_mode="rgb_array")
    base = env.unwrapped
    act = as_action_fn(policy)
    frames: list[np.ndarray] = []
    base.frame_hook = lambda e: frames.append(e.render())  # every 40 ms simulated; kept across cables
    with _progress_bar(episodes, f"video {path.name}", not progress) as bar:
        for i in range(episodes):
            obs, _ = env.reset(seed=seed + i)
            frames.append(base.render())
            done = False
            while not done:
                obs, _, terminated, truncated, _ = env.step(act(obs))
                done = terminated or truncated
            bar.update(1)
    env.close()
    write_video_atomic(path, frames)
