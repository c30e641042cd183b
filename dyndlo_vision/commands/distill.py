"""``dyndlo-vision distill``: a multi-step policy from a single-step one, by imitation."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = (
    "distil a single-step policy (tip control or vaulting) into a multi-step (re-planning) PPO policy by "
    "imitation (behaviour cloning, optional DAgger rounds); resumable"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``distill``."""
    from dyndlo_vision.commands import _options as options

    p.epilog = ("With --resume, --obs-noise may change: every fit draws all rounds' observations again "
                "through the new model.")
    # The tasks with a shipped single-step teacher (learning.distill.DEFAULT_TEACHERS; not imported here: it
    # loads torch).
    options.add_task(p, choices=("tip-control", "vaulting"))
    p.add_argument(
        "--teacher",
        default=None,
        help="shipped name or .zip of a single-step policy of the task (default: tip-control-single-step, "
        "or vaulting for --task vaulting)",
    )
    p.add_argument(
        "--rounds",
        type=int,
        default=1,
        help="rounds: the first --expert-rounds are behaviour cloning, later ones DAgger (default 1; DAgger "
        "rounds made every student worse, docs/guides/multi-step-policies.md)",
    )
    p.add_argument(
        "--expert-rounds",
        type=int,
        default=1,
        help="rounds in which the expert acts, each on new seeds (default 1); resume a finished run with "
        "more --rounds and --expert-rounds to add behaviour-cloning data",
    )
    p.add_argument(
        "--dagger-episodes", type=int, default=200, help="episodes of every DAgger round (default 200)"
    )
    p.add_argument(
        "--first-round-episodes", type=int, default=400, help="episodes of every expert round (default 400)"
    )
    options.add_obs_noise(p)
    options.add_env_option(p)
    p.add_argument("--seed", type=int, default=1, help="episode seeds start at SEED * 1e6 (default 1)")
    p.add_argument("--workers", type=int, default=2, help="processes collecting episodes (default 2)")
    p.add_argument(
        "--epochs", type=int, default=300, help="regression passes over the data per round (default 300)"
    )
    options.add_cable_options(p)
    p.add_argument(
        "--teacher-search",
        action="store_true",
        help="privileged teacher: refine the teacher's plan for each episode's cable and target by search in "
        "simulation (it knows the cable; the student does not)",
    )
    p.add_argument(
        "--teacher-commit",
        type=int,
        default=None,
        metavar="K",
        help="privileged teacher that commits late: follow the teacher's plan for K decisions, then correct "
        "it for the episode's cable and state by search in simulation; pick K from when P_DLO shows the "
        "cable; not with --teacher-search (default: off)",
    )
    p.add_argument(
        "--search-candidates",
        choices=("episode", "shared"),
        default="episode",
        help="the offsets the late commitment's search (--teacher-commit) tries: new ones for every episode "
        "(episode, default), or the same ones in every search, so that look-alike states get the same "
        "correction (shared)",
    )
    p.add_argument(
        "--expert-smoothing",
        type=float,
        default=0.0,
        metavar="WEIGHT",
        help="keep each of the expert's actions near its previous one, with this weight (metres of fit "
        "residual per action unit; e.g. 0.1): smooth labels a student can fit (default 0: off)",
    )
    p.add_argument(
        "--p-dlo-history",
        type=int,
        default=0,
        metavar="H",
        help="the student also reads P_DLO's velocity over the last 1..H decisions, from which it can tell "
        "how the cable moves (default 0: the table-II observation only)",
    )
    p.add_argument(
        "--out", default=None, help="run folder (default: runs/<task>-multi-step-distill-s<seed>)"
    )
    options.add_resume(p)
    p.add_argument(
        "--refit",
        action="store_true",
        help="with --resume: fit the student again from new weights on the finished rounds (as the run did, "
        "round by round), through --obs-noise now, without collecting them again; then go on",
    )
    options.add_quiet(p)


def run(args: argparse.Namespace) -> int:
    """Resolve the options, then run the rounds."""
    from dyndlo_vision import policies
    from dyndlo_vision.commands._options import random_cables
    from dyndlo_vision.commands.train import parse_assignments
    from dyndlo_vision.learning.distill import DEFAULT_TEACHERS, DistillConfig, distill
    from dyndlo_vision.tasks.noise import resolve_noise_model_path

    noise = resolve_noise_model_path(args.obs_noise)
    cables = random_cables(args)
    options = parse_assignments(args.env_option, "--env-option")
    teacher = args.teacher or DEFAULT_TEACHERS[args.task]
    _, teacher_meta = policies.resolve(teacher)
    config = DistillConfig(
        task=args.task,
        teacher=teacher,
        task_options={**teacher_meta.get("env_options", {}), **options},
        rounds=args.rounds,
        expert_rounds=args.expert_rounds,
        episodes=args.dagger_episodes,
        first_round_episodes=args.first_round_episodes,
        noise_model=noise,
        seed=args.seed,
        workers=args.workers,
        epochs=args.epochs,
        cable_ranges=None if cables is None else cables.ranges,
        teacher_search=args.teacher_search,
        teacher_commit_decision=args.teacher_commit,
        search_candidates=args.search_candidates,
        p_dlo_history=args.p_dlo_history,
        expert_smoothing=args.expert_smoothing,
    )
    out = Path(args.out or f"runs/{args.task}-multi-step-distill-s{args.seed}")
    try:
        history = distill(config, out, resume=args.resume, progress=not args.quiet, refit=args.refit)
    except KeyboardInterrupt:
        if (out / "config.json").is_file():
            print(
                f"interrupted; resume with: dyndlo-vision distill --resume --out {out} (and the same options)"
            )
        else:  # stopped while the run was being set up: there is nothing to resume
            print("interrupted before the run started")
        return 130
    print(json.dumps(history[-1], indent=2))
    print(f"wrote {out / 'model.zip'}")
    return 0
