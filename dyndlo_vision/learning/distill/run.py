"""A distillation run: its configuration (:class:`DistillConfig`, stored as ``config.json`` so that the run
can be resumed) and its rounds (:func:`distill`): collect, fit the student on every round so far, save."""

from __future__ import annotations

import json
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dyndlo_vision.learning.distill.collection import (
    Episodes,
    check_teacher,
    collect,
    make_distill_env,
    with_history,
    with_noise,
)
from dyndlo_vision.learning.distill.student import fit_student, new_student
from dyndlo_vision.learning.distill.teachers import DISTILL_TASKS, TEACHER_TASK, ReplanSearch

__all__ = ["DistillConfig", "distill"]

#: Options added to :class:`DistillConfig` after runs were first stored, with the values those runs had.
_LATER_OPTIONS = {
    "cable_ranges": None,
    "teacher_search": False,
    "task": "tip-control",
    "expert_rounds": 1,
    "p_dlo_history": 0,
    "expert_smoothing": 0.0,
    "teacher_commit_decision": None,
    "search_candidates": "episode",
}
#: Options that stored runs may have and this version no longer has, with the value that meant "off": such a
#: run resumes only where it was off (each made the students worse and shaped no shipped policy).
_REMOVED_OPTIONS = {
    "student_noise": 0.0,
    "expert_noise": 0.0,
    "expert_speed_limit_m_s": None,
    "dagger_beta": 0.0,
    "expert_replan_mm": None,
    "expert_replan_anchor": "plan",
    "expert_replan_score": "coast",
    "decision_clock": False,
}
#: Options a resumed run may change: how many rounds of each kind run from here on, how many processes
#: collect (every episode is seeded on its own, so the data do not depend on it), and the noise model (every
#: fit draws the observations again through it, :func:`with_noise`).
_CHANGEABLE_OPTIONS = ("rounds", "expert_rounds", "workers", "noise_model")


@dataclass(frozen=True)
class DistillConfig:
    """A distillation run, stored as ``config.json`` in its folder so that it can be resumed.

    Attributes:
        teacher: Shipped name or path of the task's single-step policy.
        rounds: Rounds ``0 .. expert_rounds - 1``: the expert acts (behaviour cloning); later rounds: the
            student of the previous round acts and the expert labels (DAgger). One round is the default:
            DAgger rounds made the student worse in every measurement (docs/guides/multi-step-policies.md).
        episodes: Episodes per DAgger round.
        first_round_episodes: Episodes of every expert round.
        expert_rounds: Rounds in which the expert acts, each on new seeds: more behaviour-cloning data, added
            to a finished run by resuming it with more ``rounds`` and ``expert_rounds``.
        noise_model: Observation-noise model file the student sees P_DLO through, ``"packaged"`` for the
            shipped one (None: true state).
        seed: Episode seeds of round ``r`` are ``seed * 1_000_000 + r * 10_000 + i`` (evaluation seeds
            100000-100099 are never used with ``seed >= 1``).
        workers: Processes collecting episodes.
        net_arch: Hidden layers of the policy network.
        epochs: Passes over the aggregated data per round.
        task_options: Keyword options of the task's environment.
        cable_ranges: Every episode's cable is drawn from these named ranges (``wrappers.CABLE_RANGES``:
            ``"training"`` or ``"beyond"``); None: the task's nominal cable in every episode.
        teacher_search: The expert follows :class:`CableSearchTeacher`'s plan (the teacher's refined, with
            the episode's cable known) instead of the teacher's own.
        task: The task (:data:`DISTILL_TASKS`).
        p_dlo_history: H > 0: the student also reads how P_DLO moved over the last H decisions
            (:class:`~dyndlo_vision.tasks.wrappers.PDloHistory`), from which it can tell the cable. The round
            files keep the table-II observations; the history is added when the student is fitted.
        expert_smoothing: :class:`PlanFollowingExpert`'s ``smoothing`` (0: off).
        teacher_commit_decision: K: the teacher commits late. The expert follows the teacher's own plan
            (made without the cable) for K decisions; at decision K a privileged search
            (:class:`ReplanSearch`, from the true cable and state) corrects it where coasting on it fails, and
            the expert follows the correction from then on
            (:func:`~dyndlo_vision.learning.distill.collection.run_episode`). The student's labels then depend
            on the cable only once the cable has moved for K x 40 ms. None (default): off. Not
            with ``teacher_search``, which makes the plan for the cable at t = 0.
        search_candidates: :class:`ReplanSearch`'s ``candidates`` at the late commitment: ``"episode"``
            (default) new offsets in every search, ``"shared"`` the same offsets in every search, so that
            look-alike states get the same correction.
    """

    teacher: str = "tip-control-single-step"
    rounds: int = 1
    episodes: int = 200
    first_round_episodes: int = 400
    noise_model: str | None = None
    seed: int = 1
    workers: int = 2
    net_arch: tuple[int, ...] = (256, 256, 256)
    epochs: int = 300
    task_options: dict[str, Any] = field(default_factory=dict)
    cable_ranges: str | None = None
    teacher_search: bool = False
    task: str = TEACHER_TASK
    expert_rounds: int = 1
    p_dlo_history: int = 0
    expert_smoothing: float = 0.0
    teacher_commit_decision: int | None = None
    search_candidates: str = "episode"

    def __post_init__(self) -> None:
        for name in ("rounds", "episodes", "first_round_episodes", "workers", "epochs", "expert_rounds"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if self.episodes >= 10_000 or self.first_round_episodes >= 10_000:
            raise ValueError(
                f"at most 9999 episodes per round, got {self.episodes}/{self.first_round_episodes}"
            )
        if self.seed < 1:
            raise ValueError(f"seed must be >= 1 (seed 0 would reuse the evaluation seeds), got {self.seed}")
        if self.task not in DISTILL_TASKS:
            raise ValueError(f"task must be one of {list(DISTILL_TASKS)}, got {self.task!r}")
        if self.cable_ranges is not None:
            from dyndlo_vision.tasks.wrappers import cable_ranges_for

            cable_ranges_for(self.task, self.cable_ranges)  # an unknown name is refused here
        smoothing = self.expert_smoothing
        if isinstance(smoothing, bool) or not isinstance(smoothing, int | float) or not (
            0.0 <= smoothing < float("inf")
        ):
            raise ValueError(f"expert_smoothing must be finite and >= 0, got {smoothing!r}")
        history = self.p_dlo_history
        if isinstance(history, bool) or not isinstance(history, int) or history < 0:
            raise ValueError(f"p_dlo_history must be an integer >= 0 (0: no history), got {history!r}")
        commit = self.teacher_commit_decision
        if commit is not None:
            if isinstance(commit, bool) or not isinstance(commit, int) or commit < 1:
                raise ValueError(f"teacher_commit_decision must be a decision index >= 1 or None (off), "
                                 f"got {commit!r}")
            if self.teacher_search:
                raise ValueError("teacher_commit_decision and teacher_search exclude each other: the search "
                                 "makes the plan for the cable at t = 0, the late commitment after K "
                                 "decisions")
        if self.search_candidates not in ReplanSearch.CANDIDATES:
            raise ValueError(f"search_candidates {self.search_candidates!r}; expected one of "
                             f"{list(ReplanSearch.CANDIDATES)}")
        if self.search_candidates != "episode" and commit is None:
            raise ValueError(f"search_candidates {self.search_candidates!r} needs a search: the late "
                             "commitment (teacher_commit_decision)")
        if not self.net_arch or any(int(n) < 1 for n in self.net_arch):
            raise ValueError(f"net_arch must be positive layer sizes, got {self.net_arch!r}")
        object.__setattr__(self, "net_arch", tuple(int(n) for n in self.net_arch))

    def expert_acts(self, r: int) -> bool:
        """Whether the expert acts in round ``r`` (behaviour cloning) rather than the student (DAgger)."""
        return r < self.expert_rounds

    def round_seeds(self, r: int) -> list[int]:
        """Episode seeds of round ``r``."""
        n = self.first_round_episodes if self.expert_acts(r) else self.episodes
        return [self.seed * 1_000_000 + r * 10_000 + i for i in range(n)]

    def to_json(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {**self.__dict__, "net_arch": list(self.net_arch)}


def distill(
    config: DistillConfig,
    out: Path,
    resume: bool = False,
    log: Callable[[str], Any] = print,
    progress: bool = False,
    refit: bool = False,
) -> list[dict[str, Any]]:
    """Run DAgger rounds into ``out``.

    Each finished round leaves ``round<r>.npz``, ``model.zip`` (also kept as ``model_round<r>.zip``),
    ``model.json`` (and ``model_round<r>.json``, so that each round's student loads as the multi-step policy
    it is) and ``history.json``.

    An interrupted run resumes (``resume=True``) after its last finished round, reusing the data of a round
    that was collected but not yet trained on; a finished run resumed with more ``rounds`` goes on.

    The options, ``out`` and the teacher are checked before anything is written: a refused run leaves no
    folder. A new run that fails (other than by KeyboardInterrupt) before it saved any round data removes the
    ``config.json`` it wrote (and the folder, if it made it), so that the same command can simply be run
    again; an interrupted one keeps it for ``resume``.

    Args:
        config: The run's configuration (stored as ``config.json``).
        out: The run folder: new or empty, or with ``resume`` the folder of the same configuration.
        resume: Continue the run in ``out``.
        refit: With ``resume``: fit the student again from new weights on the run's finished rounds, round by
            round as the run did (each fit on the rounds up to it, warm-started from the last), through the
            run's noise model now, without collecting them again; then go on to any rounds beyond them. For a
            run whose noise model changed: the student it leaves is the one the whole run would have given
            under the new model wherever the expert acted in every round.
        log: Called with a line at the start and end of every round.
        progress: Show progress bars on stderr: every round's episodes, then its regression epochs.

    Returns:
        The per-round history (also ``history.json``).

    Raises:
        ValueError: ``out`` is not empty (without ``resume``) or holds another configuration, the teacher
            cannot be distilled (see :func:`check_teacher`), or ``refit`` without ``resume``, without finished
            rounds, or with fewer ``rounds`` than finished.
        FileNotFoundError: Nothing to resume in ``out``, or no such teacher.
    """
    import torch

    from dyndlo_vision import policies
    from dyndlo_vision._atomic import write_atomic
    from dyndlo_vision.tasks.noise import noise_model_file

    out = Path(out)
    if refit and not resume:
        raise ValueError("refit re-fits a run's finished rounds: it needs resume")
    config_file, history_file = out / "config.json", out / "history.json"
    # Everything that can refuse the run comes before the first write into ``out``.
    history = _stored_history(config, out, log) if resume else _new_run_history(out)
    refitted: dict[int, dict[str, Any]] = {}
    if refit:
        if not history:
            raise ValueError(f"nothing to refit: {out} has no finished round")
        if config.rounds < len(history):
            raise ValueError(
                f"refit fits all {len(history)} finished rounds again; rounds={config.rounds} is fewer"
            )
        refitted, history = {int(e["round"]): e for e in history}, []
    check_teacher(config.teacher, config.task_options, config.task)

    # Seeded after check_teacher, whose loading of the teacher draws from torch's generator: the student's
    # initial weights stay those of the seed.
    torch.manual_seed(config.seed)
    env = make_distill_env(config.task_options, config.noise_model, config.cable_ranges, config.task)
    model_file = out / "model.zip"
    if history:
        model = policies.load(model_file, env=env, algo="ppo")
        model = getattr(model, "sb3_model", model)  # the network itself, fitted on observations with history
    else:
        student_env = env
        if config.p_dlo_history:
            from dyndlo_vision.tasks.wrappers import StudentFeaturesWrapper

            student_env = StudentFeaturesWrapper(env, config.p_dlo_history)
        model = new_student(student_env, config.net_arch, config.seed)
    made_folder = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(config_file, lambda tmp: Path(tmp).write_text(json.dumps(config.to_json(), indent=2)))

    try:
        data = [Episodes.load(out / f"round{r}.npz") for r in range(len(history))]
        for r in range(len(history), config.rounds):
            start = time.monotonic()
            round_file = out / f"round{r}.npz"
            if round_file.is_file():
                episodes = Episodes.load(round_file)
                log(f"round {r}: reusing {round_file} ({len(episodes.successes)} episodes)")
            else:
                episodes = _collect_round(config, r, model_file, log, progress)
                episodes.save(round_file)
            collect_s = time.monotonic() - start
            data.append(episodes)
            with _bar(config.epochs, f"round {r} fit", "epoch", progress) as bar:
                seen = with_noise(Episodes.concatenate(data), noise_model_file(config.noise_model))
                losses = fit_student(
                    model,
                    with_history(seen, config.p_dlo_history),
                    epochs=config.epochs,
                    seed=config.seed + r,
                    on_epoch=_loss_reporter(bar),
                )
            model.save(model_file)
            shutil.copyfile(model_file, out / f"model_round{r}.zip")  # every round's student stays selectable
            entry = {
                **_round_entry(config, r, episodes, data, losses),
                "collect_s": round(collect_s, 1),
                "wall_s": round(time.monotonic() - start, 1),
            }
            if r in refitted:  # collected by the run before: its collection time is that run's
                entry = {**entry, "collect_s": refitted[r]["collect_s"], "refitted": True}
            history.append(entry)
            write_atomic(history_file, lambda tmp: Path(tmp).write_text(json.dumps(history, indent=2)))
            _write_metadata(out, config, history)
            _write_metadata(out, config, history, f"model_round{r}.json")
            log(json.dumps(entry))
    except Exception:
        # A new run that saved nothing but its config would block the same command ("not empty"): undo it.
        if not resume and out.is_dir() and {p.name for p in out.iterdir()} == {config_file.name}:
            config_file.unlink()
            if made_folder:
                out.rmdir()
        raise
    finally:
        env.close()
    return history


def _stored_history(config: DistillConfig, out: Path, log: Callable[[str], Any]) -> list[dict[str, Any]]:
    """The finished rounds of the run in ``out``, after checking that ``config`` may resume it.

    Raises:
        FileNotFoundError: ``out`` holds no run.
        ValueError: The run used a removed option, holds another configuration, or a finished round would
            change its kind.
    """
    from dyndlo_vision.tasks.noise import portable_noise_model

    config_file, history_file = out / "config.json", out / "history.json"
    if not config_file.is_file():
        raise FileNotFoundError(f"nothing to resume: {config_file} does not exist")
    stored = {**_LATER_OPTIONS, **json.loads(config_file.read_text())}
    for name, default in _REMOVED_OPTIONS.items():
        if stored.pop(name, default) != default:
            raise ValueError(f"{config_file}: the run used {name}, an option this version no longer has "
                             "(it made the students worse); it cannot be resumed")
    # A run stored before "packaged" was kept as the word holds the shipped model's path in its install.
    stored["noise_model"] = portable_noise_model(stored.get("noise_model"))
    wanted = json.loads(json.dumps(config.to_json()))
    if {k: v for k, v in stored.items() if k not in _CHANGEABLE_OPTIONS} != {
        k: v for k, v in wanted.items() if k not in _CHANGEABLE_OPTIONS
    }:
        raise ValueError(
            f"{config_file} holds another configuration ({stored}); resume with the same options "
            "(only --rounds, --expert-rounds, --workers and --obs-noise may change)"
        )
    if stored["noise_model"] != wanted["noise_model"]:
        log(f"noise model changed from {stored['noise_model']} to {wanted['noise_model']}: the student "
            "is fitted on every round's observations drawn again through the new one")
    history: list[dict[str, Any]] = json.loads(history_file.read_text()) if history_file.is_file() else []
    for entry in history:  # a finished round's kind cannot be changed afterwards
        was_expert = entry["acting"] == "expert"
        if was_expert != config.expert_acts(int(entry["round"])):
            raise ValueError(
                f"round {entry['round']} of {out} was {'an expert' if was_expert else 'a DAgger'} round; "
                f"expert_rounds={config.expert_rounds} would make it "
                f"{'a DAgger' if was_expert else 'an expert'} round"
            )
    return history


def _new_run_history(out: Path) -> list[dict[str, Any]]:
    """No rounds yet, after checking that ``out`` can hold a new run (new or empty folder).

    Raises:
        ValueError: ``out`` is a file or a folder that is not empty.
    """
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} is a file; expected a run folder")
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"{out} exists and is not empty; use --resume or another --out")
    return []


def _collect_round(config: DistillConfig, r: int, model_file: Path, log: Callable[[str], Any],
                   progress: bool) -> Episodes:
    """Round ``r``'s episodes: the expert acts in an expert round, else the student in ``model_file``."""
    seeds = config.round_seeds(r)
    expert = config.expert_acts(r)
    log(f"round {r}: {'expert' if expert else 'student'} acts, {len(seeds)} episodes")
    with _bar(len(seeds), f"round {r} episodes", "episode", progress) as bar:
        return collect(
            seeds,
            config.teacher,
            None if expert else str(model_file),
            config.noise_model,
            config.task_options,
            config.workers,
            task=config.task,
            cable_ranges=config.cable_ranges,
            teacher_search=config.teacher_search,
            expert_smoothing=config.expert_smoothing,
            commit_decision=config.teacher_commit_decision,
            search_candidates=config.search_candidates,
            on_episode=_success_counter(bar),
        )


def _round_entry(config: DistillConfig, r: int, episodes: Episodes, data: list[Episodes],
                 losses: dict[str, float]) -> dict[str, Any]:
    """Round ``r``'s line of ``history.json``, but for its times."""
    return {
        "round": r,
        "acting": "expert" if config.expert_acts(r) else f"student of round {r - 1}",
        "episodes": int(len(episodes.successes)),
        "samples": int(len(episodes.actions)),
        "total_samples": int(sum(len(d.actions) for d in data)),
        "success_rate": float(np.mean(episodes.successes)),
        "avoid_rate": float(np.mean(episodes.avoided)),
        "expert_fit_rms_mm": float(1000 * np.median(episodes.fit_rms_m)),
        "replanned_labels": int(episodes.replans.sum()),
        "obs_noise": config.noise_model,  # what the fit saw every round through
        **losses,
    }


def _bar(total: int, desc: str, unit: str, progress: bool) -> Any:
    """A progress bar on stderr, left in place when done as a record of the round (none without ``progress``).

    One bar at a time (no nesting): the round is in its description, and nested bars garble logs.
    """
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, disable=not progress, dynamic_ncols=True)


def _loss_reporter(bar: Any) -> Callable[[int, float], None]:
    """``on_epoch`` callback of :func:`fit_student`: advance ``bar`` and show the epoch's training loss."""

    def on_epoch(_epoch: int, loss: float) -> None:
        bar.set_postfix(mse=f"{loss:.2e}", refresh=False)
        bar.update(1)

    return on_epoch


def _success_counter(bar: Any) -> Callable[[int, bool], None]:
    """``on_episode`` callback of :func:`collect`: advance ``bar`` and show the successes so far."""
    successes = 0

    def on_episode(_seed: int, success: bool) -> None:
        nonlocal successes
        successes += bool(success)
        bar.set_postfix(successes=successes, refresh=False)
        bar.update(1)

    return on_episode


def _write_metadata(
    out: Path, config: DistillConfig, history: list[dict[str, Any]], name: str = "model.json"
) -> None:
    """``name`` (``model.json`` beside ``model.zip``, or a round's): what ``policies.load`` and ``evaluate``
    read. Without it a round's ``model_round<r>.zip`` would be described by the run's ``config.json``, which
    does not say that the student is multi-step, and would be run as a single-step plan."""
    from dyndlo_vision._atomic import write_atomic

    meta = {
        "task": config.task,
        "multi_step": True,
        "algo": "ppo",
        "env_options": config.task_options,
        "method": "distillation of a single-step policy (dyndlo_vision.learning.distill)",
        "teacher": config.teacher,
        "obs_noise": config.noise_model,
        "teacher_search": config.teacher_search,
        "cable_ranges": config.cable_ranges,
        "expert_rounds": config.expert_rounds,
        "p_dlo_history": config.p_dlo_history,
        "teacher_commit_decision": config.teacher_commit_decision,
        "search_candidates": config.search_candidates,
        "expert_smoothing": config.expert_smoothing,
        "rounds": len(history),
        "samples": history[-1]["total_samples"] if history else 0,
        "episodes": sum(h["episodes"] for h in history),
    }
    write_atomic(out / name, lambda tmp: Path(tmp).write_text(json.dumps(meta, indent=2)))
