"""Collecting demonstrations: episodes in which the expert labels every decision, run in worker processes,
and the data set they make (:class:`Episodes`), with the student's view of it drawn again through a noise
model (:func:`with_noise`) and its features appended (:func:`with_history`)."""

from __future__ import annotations

import contextlib
import queue as queue_module
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.learning.distill.expert import PlanFollowingExpert
from dyndlo_vision.learning.distill.teachers import (
    DEFAULT_TEACHERS,
    DISTILL_TASKS,
    TEACHER_TASK,
    CableSearchTeacher,
    PolicyTeacher,
    ReplanSearch,
)

__all__ = ["Episodes", "load_rounds", "episode_cables", "with_history", "with_noise", "run_episode",
           "make_distill_env", "check_teacher", "collect"]


@dataclass
class Episodes:
    """What :func:`collect` gathered: observations with the expert's actions, and how the episodes ended.

    Rows (``observations`` to ``seeds``) are decisions, each episode's in time order. The per-episode arrays
    (``successes`` and after) are in the order the episodes' seeds first appear in ``seeds``
    (:attr:`episode_seeds`), which is the order the workers' chunks were joined in, not sorted.
    """

    observations: NDArray[np.float32]
    true_observations: NDArray[np.float32]
    actions: NDArray[np.float32]
    seeds: NDArray[np.int64]
    successes: NDArray[np.bool_]
    avoided: NDArray[np.bool_]
    fit_rms_m: NDArray[np.float64]
    #: Per episode: labels that came from :class:`ReplanSearch` (0 for files written before it existed).
    replans: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def episode_seeds(self) -> NDArray[np.int64]:
        """The seed of each episode, in the order of the per-episode arrays."""
        _, first = np.unique(self.seeds, return_index=True)
        return self.seeds[np.sort(first)]

    @staticmethod
    def concatenate(parts: Sequence[Episodes]) -> Episodes:
        """All ``parts`` in one."""
        return Episodes(
            *(np.concatenate([getattr(p, f) for p in parts]) for f in Episodes.__dataclass_fields__)
        )

    def save(self, path: Path) -> None:
        """Write to ``path`` (.npz) atomically."""
        from dyndlo_vision._atomic import write_atomic

        def write(tmp: str) -> None:
            with open(tmp, "wb") as f:
                np.savez_compressed(f, **{k: getattr(self, k) for k in Episodes.__dataclass_fields__})

        write_atomic(path, write)

    @staticmethod
    def load(path: Path) -> Episodes:
        """Read a file written by :meth:`save`."""
        with np.load(path) as data:
            fields = {k: data[k] for k in Episodes.__dataclass_fields__ if k in data}
        fields.setdefault("replans", np.zeros(len(fields["successes"]), dtype=np.int64))
        return Episodes(**fields)


def load_rounds(run: Path, rounds: Sequence[int] | None = None) -> Episodes:
    """A distillation run's round files (``round<r>.npz`` in the folder ``run``), those of ``rounds`` or all,
    in one.

    Raises:
        FileNotFoundError: A round asked for has no file, or the run has none.
    """
    run = Path(run)
    files = sorted(run.glob("round*.npz"), key=lambda p: int(p.stem[5:]))
    if rounds is not None:
        files = [run / f"round{r}.npz" for r in rounds]
    missing = [str(f) for f in files if not f.is_file()]
    if missing or not files:
        raise FileNotFoundError(f"no round data: {missing or run}")
    return Episodes.concatenate([Episodes.load(f) for f in files])


def episode_cables(data: Episodes, config: dict[str, Any]) -> NDArray[np.float64] | None:
    """Each decision's cable as factors of the nominal one (length, mass, Young's modulus, damping), drawn
    again from its episode's seed as the run drew it; None for a run on the nominal cable. ``config`` is the
    run's ``config.json``."""
    from dyndlo_vision.tasks.wrappers import cable_for_seed, cable_ranges_for

    ranges = config.get("cable_ranges")
    if ranges is None:
        return None
    task = config.get("task", TEACHER_TASK)
    env = make_distill_env(config.get("task_options", {}), None, None, task)
    nominal = env.unwrapped.task.cable
    env.close()
    factors = cable_ranges_for(task, ranges)
    rows = {}
    for seed in data.episode_seeds.tolist():
        c = cable_for_seed(nominal, factors, seed)
        rows[seed] = [c.length_m / nominal.length_m, c.mass_kg / nominal.mass_kg,
                      c.young_pa / nominal.young_pa, c.damping_s / nominal.damping_s]
    return np.array([rows[s] for s in data.seeds.tolist()])


def with_history(data: Episodes, length: int) -> Episodes:
    """``data`` with the student's features appended to its observations: the P_DLO history of ``length``
    periods (0: unchanged).

    Episodes are told apart by their seeds; within one, the rows are in time order (:func:`collect`).
    """
    if not length:
        return data
    from dyndlo_vision.tasks.wrappers import StudentFeatures

    features = StudentFeatures(data.observations.shape[1], length)
    return replace(data, observations=features.stack(data.observations, data.seeds))


def with_noise(data: Episodes, model: Any) -> Episodes:
    """``data`` with its observations drawn again from ``true_observations`` through another noise model.

    Each episode gets what :class:`~dyndlo_vision.tasks.wrappers.NoisyObservation` would have given it under
    ``model`` (an :class:`~dyndlo_vision.tasks.noise.ObservationNoiseModel`, or the path of one; ``None``:
    the true observations): one draw per decision, in time order, from the noise stream of the episode's
    seed. The expert's labels never depended on the noise (the expert reads the true state), so a run's
    demonstrations can teach a student for a tracker other than the one they were collected under. What the
    episodes visited still depends on the student that drove them, through the noise it saw then.
    Re-noising with the model the episodes were collected under gives back their observations exactly.
    """
    from dyndlo_vision.tasks.base import CONTROL_PERIOD_S
    from dyndlo_vision.tasks.noise import NoiseProcess
    from dyndlo_vision.tasks.wrappers import corrupt_observation, observation_layout

    true_obs = data.true_observations
    if model is None:
        return replace(data, observations=true_obs.copy())
    observation_layout(true_obs.shape[1])  # refuses any other width before the first draw
    process = NoiseProcess(model, CONTROL_PERIOD_S, multi_step=True)
    out = true_obs.copy()
    for seed in data.episode_seeds:
        process.reset(int(seed))
        for row in np.flatnonzero(data.seeds == seed):  # an episode's rows are in time order
            out[row] = corrupt_observation(process, true_obs[row])
    return replace(data, observations=out)


def run_episode(
    env: Any,
    teacher: Any,
    expert: PlanFollowingExpert,
    seed: int,
    student: Any = None,
    commit: ReplanSearch | None = None,
    commit_decision: int = 0,
) -> dict[str, Any]:
    """One multi-step episode, labelled by the expert at every decision: the expert acts (behaviour cloning),
    or the ``student`` does when one is given (DAgger: the expert labels the states the student reaches).

    With ``commit`` the teacher commits late: its plan (``teacher``'s, made without the cable) is followed
    for the first ``commit_decision`` decisions; at that decision, from wherever the episode is and whoever
    acted, ``commit`` searches the nearest good correction of the plan-following label (privileged: the true
    cable and state; none when coasting on the label already succeeds or a limit is broken), and the expert
    follows that plan from then on. Until the cable has moved, nothing the student observes tells it the
    cable's stiffness, so a plan made for it at t = 0 labels look-alike early states differently; here the
    labels before the commitment are the same for every cable of a length, and the cable-dependent part comes
    when the cable has shown how it moves.

    Returns:
        ``observations`` (as the student saw them), ``true_observations`` (the simulator's state) and
        ``actions`` (the expert's label for every observation), ``success``, ``avoid``
        (any avoid condition), ``fit_rms_m`` (median residual of the expert's fits), ``replans`` (labels that
        came from the search) and ``info``.
    """
    if commit is not None and (isinstance(commit_decision, bool) or not isinstance(commit_decision, int)
                               or commit_decision < 1):
        raise ValueError(f"commit_decision must be a decision index >= 1, got {commit_decision!r}")
    obs, _ = env.reset(seed=seed)
    if student is not None and hasattr(student, "reset"):
        student.reset()  # a student with a P_DLO history (policies.HistoryPolicy) starts afresh
    u = env.unwrapped
    plan = teacher.plan_for(u, seed)  # the teacher sees the true state (and, if privileged, more)
    observations, true_obs, labels, rms = [], [], [], []
    done, k, info, replans = False, 0, {}, 0
    while not done:
        student_action = None
        if student is not None:
            student_action, _ = student.predict(obs, deterministic=True)
        t = u.scene.time
        commanded = u.replanner.commanded_state(t) if k else None
        if k == 0:
            label = expert.start(plan, u.scene.gripper_home[0])
        else:
            label = expert.act(t, *commanded)
            rms.append(expert.last_rms_m)
        # Once a limit is broken no continuation can score below 1 (an avoid condition stays): no search.
        if commit is not None and k == commit_decision and not u.monitor.any_avoid:
            found = commit.search(u, label, seed)
            if commit.last_score < commit.last_start_score:
                label = found.astype(np.float32)
                expert.adopt(label, t, *commanded)
                replans += 1
        action = label if student_action is None else student_action
        observations.append(np.asarray(obs, dtype=np.float32))
        true_obs.append(u.observation())
        labels.append(label.astype(np.float32))
        obs, _, terminated, truncated, info = env.step(np.asarray(action, dtype=np.float32))
        done = terminated or truncated
        k += 1
    return {
        "observations": np.array(observations),
        "true_observations": np.array(true_obs),
        "actions": np.array(labels),
        "success": bool(info["is_success"]),
        "avoid": any(info["avoid"].values()),
        "fit_rms_m": float(np.median(rms)) if rms else 0.0,
        "replans": replans,
        "info": info,
    }


def make_distill_env(
    task_options: dict[str, Any], noise_model: str | None, cable_ranges: str | None = None,
    task: str = TEACHER_TASK,
) -> Any:
    """The task's multi-step environment, under the noise model when one is given; with ``cable_ranges``
    (a name of ``wrappers.CABLE_RANGES``) every episode's cable is drawn from its seed."""
    from dyndlo_vision.tasks.registry import make_env
    from dyndlo_vision.tasks.wrappers import cable_ranges_for

    randomise = {}
    if cable_ranges is not None:
        randomise = {"randomize_cable_every": 1, "cable_ranges": cable_ranges_for(task, cable_ranges)}
    return make_env(task, multi_step=True, obs_noise=noise_model or None, **randomise, **task_options)


def check_teacher(
    teacher: str, task_options: dict[str, Any] | None = None, task: str = TEACHER_TASK
) -> None:
    """Refuse a teacher whose plans the expert cannot follow, before any work or output.

    The expert re-plans *one* single-step plan of ``task`` (the teacher's action at t = 0 from the task
    environment's observation), so the teacher must be a single-step policy of that task. The task and mode
    come from its metadata; a file without metadata is only checked for the task's single-step spaces
    (a policy of another single-arm task has the same shapes and cannot be told apart).

    Raises:
        FileNotFoundError: ``teacher`` is neither a file nor a shipped policy.
        ValueError: Its metadata names another task or the multi-step mode, or its spaces do not match.
    """
    from dyndlo_vision import policies
    from dyndlo_vision.tasks.registry import make_env

    _, meta = policies.resolve(teacher)
    if task not in DISTILL_TASKS:
        raise ValueError(f"distill runs on the tasks {list(DISTILL_TASKS)}, got {task!r}")
    teacher_task = meta.get("task")
    example = DEFAULT_TEACHERS[task]
    if teacher_task is not None and teacher_task != task:
        raise ValueError(
            f"teacher {teacher!r} is a {teacher_task!r} policy; distill needs a single-step {task!r} policy "
            f"(e.g. {example}): the expert follows {task} plans"
        )
    if meta.get("multi_step"):
        raise ValueError(
            f"teacher {teacher!r} is a multi-step policy; distill needs a single-step {task!r} "
            f"policy, whose one plan the expert follows (e.g. {example})"
        )
    env = make_env(task, multi_step=False, **(task_options or {}))
    try:
        policies.load(teacher, env=env)  # a corrupt file or other spaces: refused here, not in a worker
    finally:
        env.close()


def _collect_chunk(job: dict[str, Any], on_episode: Callable[[int, bool], None] | None = None) -> Episodes:
    """Run the episodes of ``job["seeds"]`` (see :func:`collect`), reporting each one as it ends.

    Each finished episode is passed as ``(seed, success)`` to ``on_episode`` and put on ``job["progress"]``
    (a queue shared with the parent process), when given.
    """
    import torch

    from dyndlo_vision import policies

    torch.set_num_threads(1)
    task = job["task"]
    env = make_distill_env(job["task_options"], job["noise_model"], job["cable_ranges"], task)
    policy = policies.load(job["teacher"])
    teacher: Any = PolicyTeacher(policy)
    if job["teacher_search"]:
        teacher = CableSearchTeacher(policy, job["task_options"], task=task)
    student = policies.load(job["student"], env=env, algo="ppo") if job["student"] else None
    expert = PlanFollowingExpert(env.unwrapped.spec_actions, smoothing=job["smoothing"])
    commit_decision = job["commit_decision"]
    commit = ReplanSearch(candidates=job["search_candidates"]) if commit_decision is not None else None
    parts = []
    for seed in job["seeds"]:
        ep = run_episode(env, teacher, expert, int(seed), student, commit, commit_decision or 0)
        if on_episode is not None:
            on_episode(int(seed), ep["success"])
        if job.get("progress") is not None:
            job["progress"].put((int(seed), ep["success"]))
        n = len(ep["actions"])
        parts.append(
            Episodes(
                ep["observations"],
                ep["true_observations"],
                ep["actions"],
                np.full(n, seed, dtype=np.int64),
                np.array([ep["success"]]),
                np.array([ep["avoid"]]),
                np.array([ep["fit_rms_m"]]),
                np.array([ep["replans"]], dtype=np.int64),
            )
        )
    env.close()
    if hasattr(teacher, "close"):
        teacher.close()
    return Episodes.concatenate(parts)


def collect(
    seeds: Sequence[int],
    teacher: str,
    student: str | None = None,
    noise_model: str | None = None,
    task_options: dict[str, Any] | None = None,
    workers: int = 1,
    *,
    task: str = TEACHER_TASK,
    cable_ranges: str | None = None,
    teacher_search: bool = False,
    expert_smoothing: float = 0.0,
    commit_decision: int | None = None,
    search_candidates: str = "episode",
    on_episode: Callable[[int, bool], None] | None = None,
) -> Episodes:
    """Run one round's episodes (one per seed) in ``workers`` processes.

    Args:
        seeds: Episode seeds (goal, cable and noise).
        teacher: Shipped name or path of the single-step policy whose plans the expert follows.
        student: Path of the PPO student that acts in every episode (a DAgger round); None: the expert acts.
        noise_model: Observation-noise model file the student's observations are corrupted with.
        task_options: Keyword options of the task environment.
        workers: Processes (each builds its own environment).
        task: The task (:data:`DISTILL_TASKS`).
        cable_ranges: Draw every episode's cable from these named ranges (None: the nominal cable).
        teacher_search: The teacher's plan is refined for each episode's cable and target by search
            (:class:`CableSearchTeacher`, privileged) instead of taken from the policy as it is.
        expert_smoothing: :class:`PlanFollowingExpert`'s ``smoothing``.
        commit_decision: The teacher commits late: its plan is followed until this decision, where a
            privileged search corrects it for the episode's cable and state (see :func:`run_episode`);
            None: never.
        search_candidates: :class:`ReplanSearch`'s ``candidates`` for those searches.
        on_episode: Called in this process with ``(seed, success)`` of every episode as it ends, in the order
            they end (e.g. for a progress bar). The returned data do not depend on it.
    """
    seeds = [int(s) for s in seeds]
    jobs = [
        {
            "seeds": seeds[i::workers],
            "teacher": teacher,
            "student": student,
            "noise_model": noise_model,
            "task_options": dict(task_options or {}),
            "cable_ranges": cable_ranges,
            "teacher_search": bool(teacher_search),
            "task": task,
            "smoothing": float(expert_smoothing),
            "commit_decision": commit_decision,
            "search_candidates": search_candidates,
        }
        for i in range(workers)
    ]
    jobs = [j for j in jobs if j["seeds"]]
    if workers <= 1 or len(jobs) <= 1:
        return Episodes.concatenate([_collect_chunk(j, on_episode) for j in jobs])
    context = get_context("forkserver")
    with contextlib.ExitStack() as stack:
        # Workers report finished episodes through a manager's queue: its put() returns once the manager
        # holds the item, so when every future is done every report can be read without waiting. (Entered
        # before the pool, so that it shuts down after the workers.)
        progress = stack.enter_context(context.Manager()).Queue() if on_episode is not None else None
        pool = stack.enter_context(ProcessPoolExecutor(len(jobs), mp_context=context))
        futures = [pool.submit(_collect_chunk, {**job, "progress": progress}) for job in jobs]
        if on_episode is not None and progress is not None:
            pending = set(futures)
            while True:
                for seed, success in _drain(progress):
                    on_episode(seed, success)
                if not pending:
                    break
                _, pending = wait(pending, timeout=0.5, return_when=FIRST_COMPLETED)
        # In job order (not completion order): the data, and so the fit, are those of a run without progress.
        return Episodes.concatenate([f.result() for f in futures])


def _drain(progress: Any) -> Iterator[tuple[int, bool]]:
    """The items now on the queue ``progress``, without waiting for more."""
    while True:
        try:
            yield progress.get_nowait()
        except queue_module.Empty:
            return
