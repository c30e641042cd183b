"""Distil a single-step (plan once) policy into a multi-step (re-plan every 40 ms) policy by imitation.

Why: the multi-step task's reward is sparse (+100 for a hit, -50 for any limit broken, judged once at the end
of 40 decisions) and random re-planning breaks the speed limit in every episode; SAC at 35 000 steps never
hit the target, and the paper needed 5e6 PPO steps. A single-step policy already knows *which* whip hits the
target. What the multi-step policy must add is to keep following that whip while it re-plans every 40 ms from
the current position and velocity.

* :class:`PlanFollowingExpert` turns a single-step plan into multi-step actions: at each decision it finds,
  by bounded least squares, the action whose re-planned B-spline (from the commanded position *and velocity*
  now) stays closest to the rest of the single-step trajectory. It knows the time and the plan, which the
  multi-step observation (table II) does not contain, so it is a teacher, not a policy.
* :class:`CableSearchTeacher` is the privileged teacher: it knows the episode's cable and target and refines
  the single-step policy's plan for them by search in simulation (the cross-entropy method), so the expert
  follows a plan made for *this* cable, which the student must infer from what it observes.
* :class:`ReplanSearch` is the privileged expert off its plan: from a student's state it searches, in a copy
  of the episode, the re-plan that does best, where the plan-following expert's plan is out of reach.
* :func:`collect` runs episodes in which the student acts (with probability ``1 - beta``) or the expert does,
  and records the observation the student saw with the expert's action for it (DAgger, Ross et al. 2011).
* :func:`fit_student` regresses the mean of a stable-baselines3 PPO policy onto the aggregated labels, so the
  result is an ordinary PPO zip that ``policies.load``, ``evaluate`` and the control loop take.

With ``noise_model`` the episodes run under :class:`~dyndlo_vision.tasks.wrappers.NoisyObservation`: the
student sees the corrupted P_DLO (and learns to act on it), the expert is unaffected (it reads the true
state).
The student is fitted on the rounds' observations drawn again from their true state through the run's noise
model (:func:`with_noise`), so a resumed run may change the model (``--obs-noise``, for another tracker): its
earlier demonstrations then teach the student to read P_DLO as the new tracker gives it.
"""

from __future__ import annotations

import contextlib
import json
import queue as queue_module
import shutil
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from dyndlo_vision.trajectory import ActionSpec, BSplineTrajectory

__all__ = [
    "PlanFollowingExpert",
    "PolicyTeacher",
    "CableSearchTeacher",
    "ReplanSearch",
    "DistillConfig",
    "check_teacher",
    "collect",
    "fit_student",
    "distill",
]

#: Options added to :class:`DistillConfig` after runs were first stored, with the values those runs had.
_LATER_OPTIONS = {
    "cable_ranges": None,
    "teacher_search": False,
    "student_noise": 0.0,
    "task": "tip-control",
    "expert_rounds": 1,
    "expert_noise": 0.0,
    "p_dlo_history": 0,
    "expert_smoothing": 0.0,
    "dagger_beta": 0.0,
    "expert_replan_mm": None,
    "decision_clock": False,
    "expert_replan_anchor": "plan",
    "expert_replan_score": "coast",
    "teacher_commit_decision": None,
    "search_candidates": "episode",
}
#: Options a resumed run may change: how many rounds of each kind run from here on, how many processes
#: collect (every episode is seeded on its own, so the data do not depend on it), and the noise model (every
#: fit draws the observations again through it, :func:`with_noise`).
_CHANGEABLE_OPTIONS = ("rounds", "expert_rounds", "workers", "noise_model")

#: The tasks distillation runs on: single-arm tasks without a fixed final point, whose one single-step plan
#: from t = 0 the expert can follow (task IV appends the goal to every plan; hooking is not measured).
DISTILL_TASKS = ("tip-control", "vaulting")
#: The default task (the one ``distill`` was first written for).
TEACHER_TASK = "tip-control"
#: Each task's default teacher: its shipped single-step policy.
DEFAULT_TEACHERS = {"tip-control": "tip-control-single-step", "vaulting": "vaulting"}


class PlanFollowingExpert:
    """Multi-step actions that keep following one single-step plan.

    Args:
        spec: The task's action spec (multi-step and single-step share it).
        samples: Times at which the re-plan is compared with the reference, spread over the rest of the
            reference (at least ``spec``'s shortest plan) plus ``tail_s``.
        early_s: The re-plan is executed only until the next decision; errors in the first ``early_s`` (at
            ``early_samples`` more times) count ``early_weight`` times more while the reference still moves.
            Once it has ended, every sample counts the same: holding its end point with the first 40 ms
            weighted up is unstable (each re-plan starts from the last one's velocity, and on the vault the
            commanded speed grew by about 20 % per decision, 0.3 to 4.6 m/s; docs/RESULTS.md).
        speed_limit_m_s: Commanded TCP speeds above this are penalised (``speed_weight`` metres of residual
            per m/s of excess), so that corrections from states off the plan stay inside v_max (1.8 m/s); None
            (default, what the shipped policy was made with) turns the penalty off.
        max_nfev: Evaluation budget of each least-squares fit (warm-started from the previous action).
        smoothing: Weight (metres of residual per normalised action unit) of a term that keeps each action
            near the previous one. Many actions re-plan the rest of a plan almost equally well, and without
            it the fit picks among them by where its search happens to stop: on the vault consecutive
            labels jumped by 0.6 (mean squared change) for a residual under 1 mm, and the student could not
            fit them. 0 (default, what the shipped policies were made with) turns it off.
    """

    def __init__(
        self,
        spec: ActionSpec,
        samples: int = 30,
        tail_s: float = 0.1,
        early_s: float = 0.04,
        early_samples: int = 10,
        early_weight: float = 10.0,
        speed_limit_m_s: float | None = None,
        speed_weight: float = 0.2,
        max_nfev: int = 60,
        smoothing: float = 0.0,
    ) -> None:
        if spec.append_final_point:
            raise ValueError("PlanFollowingExpert needs an ActionSpec without a fixed final point")
        self.spec = spec
        self.samples = int(samples)
        self.tail_s = float(tail_s)
        self.early_s = float(early_s)
        self.early_samples = int(early_samples)
        self.early_weight = float(early_weight)
        self.speed_limit_m_s = speed_limit_m_s
        self.speed_weight = float(speed_weight)
        self.max_nfev = int(max_nfev)
        if not (isinstance(smoothing, int | float) and 0.0 <= smoothing < float("inf")):
            raise ValueError(f"smoothing must be a finite weight >= 0, got {smoothing!r}")
        self.smoothing = float(smoothing)
        self.reference: BSplineTrajectory | None = None
        self._last: NDArray[np.float64] | None = None
        self.last_rms_m = 0.0

    def start(self, plan_action: NDArray[np.floating[Any]], home: NDArray[np.float64]) -> NDArray[np.float64]:
        """Take the single-step plan (its normalised action from ``home`` at rest, t = 0); return it.

        At t = 0 from rest the multi-step re-plan of this action *is* the single-step trajectory.
        """
        a = np.clip(np.asarray(plan_action, dtype=np.float64), -1.0, 1.0)
        points, times = self.spec.decode(a, home, 0.0)
        self.reference = BSplineTrajectory(points, times)
        self._last = a
        self.last_rms_m = 0.0
        return a.copy()

    def adopt(self, action: NDArray[np.floating[Any]], t: float, position: NDArray[np.float64],
              velocity: NDArray[np.float64]) -> None:
        """Follow from now on the plan that ``action`` makes at ``t`` from the commanded ``position`` and
        ``velocity`` (a re-plan found by :class:`ReplanSearch`) instead of the plan taken at :meth:`start`."""
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        points, times = self.spec.decode(a, np.asarray(position, dtype=np.float64), t)
        v0 = np.asarray(velocity, dtype=np.float64)
        self.reference = BSplineTrajectory(points, times, start_velocity=v0)
        self._last = a
        self.last_rms_m = 0.0

    def act(
        self, t: float, position: NDArray[np.float64], velocity: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """The action whose re-plan from the commanded ``position``/``velocity`` at ``t`` follows the plan."""
        if self.reference is None or self._last is None:
            raise RuntimeError("call start() with the single-step plan first")
        ref = self.reference
        horizon = max(ref.t_end - t, self.spec.num_intervals * self.spec.dt_s[0]) + self.tail_s
        early = np.linspace(0.002, self.early_s, self.early_samples)
        ts = t + np.concatenate([early, np.linspace(self.early_s, horizon, self.samples + 1)[1:]])
        early_weight = self.early_weight if t < ref.t_end else 1.0
        weight = np.where(ts - t <= self.early_s + 1e-9, early_weight, 1.0)[:, None]
        target = ref.position(ts)
        p0 = np.asarray(position, dtype=np.float64)
        v0 = np.asarray(velocity, dtype=np.float64)
        previous = self._last.copy()

        def residuals(a: NDArray[np.float64]) -> NDArray[np.float64]:
            points, times = self.spec.decode(a, p0, t)
            plan = BSplineTrajectory(points, times, start_velocity=v0)
            terms = [((plan.position(ts) - target) * weight).ravel()]
            if self.speed_limit_m_s is not None:
                excess = np.linalg.norm(plan.velocity(ts), axis=1) - self.speed_limit_m_s
                terms.append(self.speed_weight * np.maximum(excess, 0.0))
            if self.smoothing > 0.0:
                terms.append(self.smoothing * (a - previous))
            return np.concatenate(terms) if len(terms) > 1 else terms[0]

        guess = np.clip(self._last, -0.999, 0.999)
        sol = least_squares(residuals, guess, bounds=(-1.0, 1.0), diff_step=1e-3, max_nfev=self.max_nfev)
        self._last = sol.x
        self.last_rms_m = float(np.sqrt(np.mean(sol.fun[: 3 * len(ts)] ** 2)))
        return np.asarray(sol.x, dtype=np.float64)


# ---------------------------------------------------------------------------------------------- teachers
class PolicyTeacher:
    """The plan of a single-step policy, from the observation at t = 0 (it knows only what it observes)."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy

    def plan_for(self, env: Any, seed: int) -> NDArray[np.float32]:
        """The policy's action for the (true) observation of ``env``'s episode, just reset."""
        action, _ = self.policy.predict(env.observation(), deterministic=True)
        return np.asarray(action, dtype=np.float32)


class CableSearchTeacher:
    """A privileged teacher: the single-step plan for *this* cable and target, found by search in simulation.

    It knows what no policy observes: the episode's cable parameters and target. It starts from the
    single-step policy's plan, rolls it out in a single-step copy of the task built with that cable, and,
    when the plan is not good enough (see ``good_enough_m``), refines it by the cross-entropy method:
    ``iterations`` generations of ``population`` plans drawn around the mean, the ``elite`` best re-centring
    it. A plan scores its closest tip-to-target-centre distance plus 1 m for any avoid condition or
    divergence; the search stops at the first generation whose best plan scores below ``good_enough_m``.

    Args:
        policy: The single-step policy whose plan the search starts from.
        task_options: The task environment's options (the episode's cable is swapped in per call).
        task: The task (see :data:`DISTILL_TASKS`).
        population, iterations, elite: The cross-entropy method's sizes.
        sigma: Initial standard deviation of the plans drawn (normalised action units); shrinks by
            ``sigma_decay`` per generation, to at least ``min_sigma``.
        good_enough_m: Stop once a plan without avoid condition passes this close to the target's centre.
    """

    def __init__(
        self,
        policy: Any,
        task_options: dict[str, Any] | None = None,
        population: int = 32,
        iterations: int = 4,
        elite: int = 6,
        sigma: float = 0.2,
        sigma_decay: float = 0.6,
        min_sigma: float = 0.05,
        good_enough_m: float = 0.03,
        task: str = TEACHER_TASK,
    ) -> None:
        from dyndlo_vision.tasks.registry import make_env

        if not (1 <= elite <= population) or iterations < 1 or sigma <= 0 or min_sigma <= 0:
            raise ValueError(
                f"need 1 <= elite <= population, iterations >= 1 and positive sigmas; got elite={elite}, "
                f"population={population}, iterations={iterations}, sigma={sigma}, min_sigma={min_sigma}"
            )
        self.policy = policy
        self.population, self.iterations, self.elite = int(population), int(iterations), int(elite)
        self.sigma, self.sigma_decay, self.min_sigma = float(sigma), float(sigma_decay), float(min_sigma)
        self.good_enough_m = float(good_enough_m)
        self.env = make_env(task, multi_step=False, **(task_options or {}))
        self.last_rollouts = 0
        self.last_score = float("nan")

    @staticmethod
    def score(info: dict[str, Any]) -> float:
        """Lower is better: closest tip-target distance (m), plus 1 for any avoid condition or divergence.

        A task without a tip-target distance (vaulting) scores 0 for a success and 1 + (1 - its progress)
        for a failure (``vault_progress``, 0 when not reported), plus the same 1 for an avoid condition."""
        bad = any(info["avoid"].values()) or bool(info.get("diverged", False))
        if "min_distance_m" in info:
            closeness = float(info["min_distance_m"])
        else:
            closeness = 0.0 if info["is_success"] else 2.0 - float(info.get("vault_progress", 0.0))
        return closeness + (1.0 if bad else 0.0)

    def rollout(self, action: NDArray[np.floating[Any]], cable: Any, goal: NDArray[np.float64],
                seed: int) -> dict[str, Any]:
        """The single-step episode of ``action`` with this cable and target; its final ``info``."""
        self.env.reset(seed=seed, options={"cable": cable, "goal": goal})
        return self.env.step(np.asarray(action, dtype=np.float32))[4]

    def search(self, start: NDArray[np.floating[Any]], cable: Any, goal: NDArray[np.float64],
               seed: int) -> NDArray[np.float32]:
        """The best plan found from ``start`` for this cable and goal (``start`` itself if it is good)."""
        best = np.clip(np.asarray(start, dtype=np.float64), -1.0, 1.0)
        info = self.rollout(best, cable, goal, seed)
        best_score, self.last_rollouts = self.score(info), 1
        rng = np.random.default_rng([int(seed), 0x5EA])
        mean, sigma = best.copy(), self.sigma
        for _ in range(self.iterations):
            if best_score < self.good_enough_m:
                break
            plans = np.clip(mean + sigma * rng.standard_normal((self.population, best.size)), -1.0, 1.0)
            scores = np.array([self.score(self.rollout(a, cable, goal, seed)) for a in plans])
            self.last_rollouts += len(plans)
            if scores.min() < best_score:
                best, best_score = plans[int(np.argmin(scores))], float(scores.min())
            mean = plans[np.argsort(scores)[: self.elite]].mean(axis=0)
            sigma = max(self.min_sigma, sigma * self.sigma_decay)
        self.last_score = best_score
        return best.astype(np.float32)

    def plan_for(self, env: Any, seed: int) -> NDArray[np.float32]:
        """The searched plan for the episode ``env`` (unwrapped, just reset with ``seed``) runs."""
        start, _ = self.policy.predict(env.observation(), deterministic=True)
        return self.search(start, env.task.cable, env.goal, seed)

    def close(self) -> None:
        self.env.close()


class ReplanSearch:
    """A privileged expert's re-plan from where the episode is now: the smallest correction of a label that
    makes the episode succeed, found by search in simulation.

    Why: :class:`PlanFollowingExpert` labels a state with the action that rejoins its one plan. From the
    states a student visits, that plan is often out of reach (its fit residual there was 6-26 mm against
    0.4-2.5 mm on its own states), so the label is a compromise between a time-indexed reference and the
    limits, and DAgger rounds made the students worse (docs/RESULTS.md, sessions 14-18). DAgger needs a label
    that is a good action from *any* state.

    From a :meth:`~dyndlo_vision.tasks.base.DynDLOEnv.snapshot` of the episode (the true cable, state and
    goal: privileged), a candidate action is scored by re-planning with it and coasting on that plan to the
    end of the episode (:meth:`~dyndlo_vision.tasks.base.DynDLOEnv.coast`, no further re-plans), by
    :meth:`CableSearchTeacher.score`. Candidates are drawn around ``start`` (the plan-following label) in
    widening rings (``sigmas``); the first ring with a candidate scoring below ``good_enough_m`` ends the
    search, and of those the one **nearest to** ``start`` is the answer. Many actions succeed from most
    states; taking whichever a search happens to find first made labels a student could not fit (a
    cross-entropy search, docs/RESULTS.md, session 20). Without a good candidate the best-scoring one is
    returned. The environment is restored afterwards, so the episode goes on as if nothing had been tried.

    With a ``follower`` (the student), a candidate is scored with the follower re-planning every decision
    after it, from the true observation, instead of coasting: the label is then an action after which the
    student's own feedback succeeds (cost-to-go under the learner, as in AggreVaTe), not one that succeeds
    open loop. A follower with student features (a P_DLO history or clock) gets its own copy of them for every
    roll-out: it goes on from the episode's history and comes back unchanged.

    Which candidates a search draws: ``candidates="episode"`` (default) draws new offsets for every episode
    and decision. Where many offsets succeed, the nearest of them then points anywhere, and two look-alike
    cables get unrelated labels: on the vault the corrections at the late commitment had no common direction
    (docs/RESULTS.md, session 25). ``"shared"`` draws the same offsets in every search, so that look-alike
    states pick the same correction. ``"line:N"`` searches along one line only: the direction of shared
    offset ``N`` (row ``N`` of the ``"shared"`` offsets; ``N = (ring - 1) * population + i`` for the offset
    ``benchmarks/correction_directions.py`` names "ring R #i"), at the lengths ``LINE_LENGTHS`` on either
    side, shortest first. Every correction is then a multiple of one vector, a single number a student can
    learn as a function of the cable; with shared offsets the 57 corrections of session 28's vault expert
    used 15 unrelated offsets (docs/RESULTS.md, session 29).

    Args:
        population: Candidates per ring.
        sigmas: Standard deviations of the rings (normalised action units), searched in this order.
        good_enough_m: A score below this is a success (``start`` itself: no search).
        follower: What acts after the candidate (``predict(obs, deterministic=True)``); None: coast.
        candidates: ``"episode"``, ``"shared"`` or ``"line:N"`` (above).
    """

    #: The values of ``candidates`` besides ``"line:N"``.
    CANDIDATES = ("episode", "shared")
    #: Lengths along a ``"line:N"`` search's unit direction (normalised action units), each tried on both
    #: sides, shortest first; the span of session 29's probe (docs/RESULTS.md).
    LINE_LENGTHS = (0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6)

    @classmethod
    def line_offset(cls, candidates: str, population: int = 12, rings: int = 4) -> int | None:
        """The shared offset a ``"line:N"`` value names (N), None for ``"episode"`` and ``"shared"``.
        Anything else, or N outside the ``rings * population`` shared offsets, is refused."""
        if candidates in cls.CANDIDATES:
            return None
        expected = (f"expected one of {list(cls.CANDIDATES)} or 'line:N' with N a shared offset, "
                    f"0-{rings * population - 1}")
        head, _, tail = str(candidates).partition(":")
        if head != "line" or not tail.isdigit():
            raise ValueError(f"candidates {candidates!r}; {expected}")
        index = int(tail)
        if index >= rings * population:
            raise ValueError(f"candidates {candidates!r}: no shared offset {index}; {expected}")
        return index

    def __init__(self, population: int = 12, sigmas: Sequence[float] = (0.05, 0.1, 0.2, 0.4),
                 good_enough_m: float = 0.03, follower: Any = None, candidates: str = "episode") -> None:
        if population < 1 or not sigmas or any(not 0 < sg < float("inf") for sg in sigmas):
            raise ValueError(f"need population >= 1 and positive finite sigmas; got population={population}, "
                             f"sigmas={sigmas!r}")
        self.line = self.line_offset(candidates, population, len(sigmas))
        self.candidates = candidates
        self.population = int(population)
        self.sigmas = tuple(float(sg) for sg in sigmas)
        self.good_enough_m = float(good_enough_m)
        self.follower = follower
        self.last_rollouts = 0
        self.last_start_score = float("nan")
        self.last_score = float("nan")

    def offsets(self, size: int, key: Sequence[int] | None = None) -> NDArray[np.float64]:
        """Every offset a search may try, ring after ring, one row each: ``"episode"`` and ``"shared"``
        in ``sigmas`` order (``population`` rows per ring, ``(len(sigmas) * population, size)``), ``"line:N"``
        as :meth:`rings` gives them. ``"shared"`` and ``"line:N"`` candidates are the same for every search
        (``key`` is ignored); ``"episode"`` ones are drawn from ``key`` (the search's seed and time)."""
        if self.line is not None:
            return np.concatenate(self.rings(size, key))
        if self.candidates == "shared":
            return self._drawn(size, np.random.default_rng(0x5EA))
        if key is None:
            raise ValueError("episode candidates are drawn from a key (seed, time in ms, 0x5EA); got None")
        return self._drawn(size, np.random.default_rng(list(key)))

    def _drawn(self, size: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """``population`` Gaussian offsets per ring, ring after ring in ``sigmas`` order."""
        return np.concatenate([sigma * rng.standard_normal((self.population, size)) for sigma in self.sigmas])

    def rings(self, size: int, key: Sequence[int] | None = None) -> list[NDArray[np.float64]]:
        """The offsets a search tries, as the rings it tries them in: ``sigmas`` rings of ``population``
        offsets, or for ``"line:N"`` one ring per length of :attr:`LINE_LENGTHS`, holding ``+length * d``
        and ``-length * d`` for the unit direction ``d`` of shared offset N."""
        if self.line is None:
            return list(self.offsets(size, key).reshape(len(self.sigmas), self.population, size))
        direction = self.line_direction(size)
        return [np.stack([length * direction, -length * direction]) for length in self.LINE_LENGTHS]

    def line_direction(self, size: int) -> NDArray[np.float64]:
        """A ``"line:N"`` search's unit direction: shared offset N, normalised.

        Raises:
            ValueError: The candidates are not a line.
        """
        if self.line is None:
            raise ValueError(f"search candidates {self.candidates!r} are not a line ('line:N')")
        row = self._drawn(size, np.random.default_rng(0x5EA))[self.line]  # the "shared" offset N
        return row / np.linalg.norm(row)

    @staticmethod
    def coasted_score(env: Any, snapshot: Any, action: NDArray[np.floating[Any]]) -> float:
        """The score of re-planning with ``action`` at ``snapshot`` and coasting to the episode's end."""
        env.restore(snapshot)
        _, _, done, _, info = env.step(np.asarray(action, dtype=np.float32))
        while not done:
            _, _, done, _, info = env.coast()
        return CableSearchTeacher.score(info)

    def followed_score(self, env: Any, snapshot: Any, action: NDArray[np.floating[Any]]) -> float:
        """The score of re-planning with ``action`` at ``snapshot``, then with the follower at every later
        decision (on a copy of it, from the true observation)."""
        import copy

        follower = self.follower
        if hasattr(follower, "features"):  # a HistoryPolicy: its own copy of the episode's history and clock
            follower = copy.copy(follower)
            follower.features = copy.deepcopy(self.follower.features)
        env.restore(snapshot)
        obs, _, done, _, info = env.step(np.asarray(action, dtype=np.float32))
        while not done:
            a, _ = follower.predict(obs, deterministic=True)
            obs, _, done, _, info = env.step(np.asarray(a, dtype=np.float32))
        return CableSearchTeacher.score(info)

    def _score(self, env: Any, snapshot: Any, action: NDArray[np.floating[Any]]) -> float:
        if self.follower is None:
            return self.coasted_score(env, snapshot, action)
        return self.followed_score(env, snapshot, action)

    def search(self, env: Any, start: NDArray[np.floating[Any]], seed: int) -> NDArray[np.float64]:
        """The answer for the multi-step ``env`` (unwrapped) now: ``start`` if it is good enough, else the
        nearest good candidate, else the best-scoring one (``start`` unless one scores better). ``env`` is
        left in the state it was in."""
        snapshot = env.snapshot()
        try:
            origin = np.clip(np.asarray(start, dtype=np.float64), -1.0, 1.0)
            best, best_score = origin, self._score(env, snapshot, origin)
            self.last_start_score, self.last_rollouts = best_score, 1
            episode = [int(seed), int(round(env.scene.time * 1000)), 0x5EA]
            for ring in self.rings(origin.size, episode):
                if best_score < self.good_enough_m:
                    break
                actions = np.clip(origin + ring, -1, 1)
                scores = np.array([self._score(env, snapshot, a) for a in actions])
                self.last_rollouts += len(actions)
                good = np.flatnonzero(scores < self.good_enough_m)
                if good.size:
                    nearest = good[np.argmin(np.linalg.norm(actions[good] - origin, axis=1))]
                    best, best_score = actions[nearest], float(scores[nearest])
                elif scores.min() < best_score:
                    best, best_score = actions[int(np.argmin(scores))], float(scores.min())
            self.last_score = best_score
            return best
        finally:
            env.restore(snapshot)


# ---------------------------------------------------------------------------------------------- episodes
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


def with_history(data: Episodes, length: int, clock: bool = False) -> Episodes:
    """``data`` with the student's features appended to its observations: the P_DLO history of ``length``
    periods, then the decision clock if ``clock`` (neither: unchanged).

    Episodes are told apart by their seeds; within one, the rows are in time order (:func:`collect`).
    """
    if not length and not clock:
        return data
    from dyndlo_vision.tasks.wrappers import StudentFeatures

    features = StudentFeatures(data.observations.shape[1], length, clock)
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


def run_mixed_episode(
    env: Any,
    teacher: Any,
    expert: PlanFollowingExpert,
    seed: int,
    student: Any = None,
    beta: float = 1.0,
    rng: np.random.Generator | None = None,
    student_noise: float = 0.0,
    expert_noise: float = 0.0,
    replan: ReplanSearch | None = None,
    replan_residual_m: float = 0.002,
    replan_anchor: str = "plan",
    commit: ReplanSearch | None = None,
    commit_decision: int = 0,
) -> dict[str, Any]:
    """One multi-step episode: the student acts with probability ``1 - beta`` per decision, else the expert.

    With ``replan``, wherever the expert's fit residual exceeds ``replan_residual_m`` (its plan is out of
    reach from here) and no limit has been broken yet, the label is the search's re-plan from the true state
    instead, when that scores better than the plan-following label, and the expert follows the new plan from
    then on (:meth:`PlanFollowingExpert.adopt`).

    With ``replan_anchor="student"`` the search is centred on the *student's* action instead, at every
    decision the student takes while no limit is broken: the label is the student's own action where coasting
    on it succeeds, else the nearest good correction of it. The plan-following label depends on which of many
    good plans the expert chose for the episode, which the student cannot see once it is off that plan;
    labels anchored on the student depend only on its observation and the true state (docs/RESULTS.md,
    session 21).

    With ``commit`` the teacher commits late: its plan (``teacher``'s, made without the cable) is followed
    for the first ``commit_decision`` decisions; at that decision, from wherever the episode is and whoever
    acted, ``commit`` searches the nearest good correction of the plan-following label (privileged: the true
    cable and state; none when coasting on the label already succeeds or a limit is broken), and the expert
    follows that plan from then on. Until the cable has moved, nothing the student observes tells it the
    cable's stiffness, so a plan made for it at t = 0 labels look-alike early states differently
    (docs/RESULTS.md, session 21: the episode's plan explained half of the labels' conflict); here the labels
    before the commitment are the same for every cable of a length, and the cable-dependent part comes when
    the cable has shown how it moves.

    ``student_noise`` is the standard deviation of Gaussian noise added to the student's executed action (in
    the normalised [-1, 1] action units, then clipped): it drives the roll-in to states the noiseless student
    would not reach, which the expert then labels. ``expert_noise`` does the same to the expert's executed
    action (DART: the expert's roll-out strays a little from its plan, and its labels show how to rejoin it).
    The label is never noisy.

    Returns:
        ``observations`` (as the student saw them), ``true_observations`` (the simulator's state) and
        ``actions`` (the expert's label for every observation), ``success``, ``avoid``
        (any avoid condition), ``fit_rms_m`` (median residual of the expert's fits), ``replans`` (labels that
        came from the search) and ``info``.
    """
    rng = rng or np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    if student is not None and hasattr(student, "reset"):
        student.reset()  # a student with a P_DLO history (policies.HistoryPolicy) starts afresh
    u = env.unwrapped
    plan = teacher.plan_for(u, seed)  # the teacher sees the true state (and, if privileged, more)
    observations, true_obs, labels, rms = [], [], [], []
    done, k, info, replans = False, 0, {}, 0
    if replan_anchor not in ("plan", "student"):
        raise ValueError(f"replan_anchor {replan_anchor!r}; expected 'plan' or 'student'")
    if commit is not None and (isinstance(commit_decision, bool) or not isinstance(commit_decision, int)
                               or commit_decision < 1):
        raise ValueError(f"commit_decision must be a decision index >= 1, got {commit_decision!r}")
    while not done:
        student_action = None
        if student is not None and rng.random() >= beta:
            student_action, _ = student.predict(obs, deterministic=True)
            if student_noise > 0.0:
                student_action = np.clip(
                    student_action + rng.normal(0.0, student_noise, np.shape(student_action)), -1.0, 1.0
                )
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
        if replan is not None and not u.monitor.any_avoid:
            if replan_anchor == "student" and student_action is not None:
                label = replan.search(u, student_action, seed).astype(np.float32)
                if replan.last_score < replan.last_start_score:  # the student's own action was corrected
                    replans += 1
                if k:
                    expert.adopt(label, t, *commanded)
            elif k and expert.last_rms_m > replan_residual_m:
                found = replan.search(u, label, seed)
                if replan.last_score < replan.last_start_score:
                    label = found
                    expert.adopt(label, t, *commanded)
                    replans += 1
        action = label if student_action is None else student_action
        if expert_noise > 0.0 and student_action is None:
            action = np.clip(label + rng.normal(0.0, expert_noise, np.shape(label)), -1.0, 1.0)
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
    task = job.get("task", TEACHER_TASK)
    env = make_distill_env(job["task_options"], job["noise_model"], job.get("cable_ranges"), task)
    policy = policies.load(job["teacher"])
    teacher: Any = PolicyTeacher(policy)
    if job.get("teacher_search"):
        teacher = CableSearchTeacher(policy, job["task_options"], task=task)
    student = policies.load(job["student"], env=env, algo="ppo") if job["student"] else None
    expert = PlanFollowingExpert(
        env.unwrapped.spec_actions, speed_limit_m_s=job["speed_limit"], smoothing=job.get("smoothing", 0.0)
    )
    commit_decision = job.get("commit_decision")
    candidates = job.get("search_candidates", "episode")
    commit = ReplanSearch(candidates=candidates) if commit_decision is not None else None
    replan_mm = job.get("replan_mm")
    replan = None
    if replan_mm is not None:
        replan = ReplanSearch(follower=student if job.get("replan_score") == "student" else None,
                              candidates=candidates)
    parts = []
    for seed in job["seeds"]:
        ep = run_mixed_episode(
            env,
            teacher,
            expert,
            int(seed),
            student,
            job["beta"],
            np.random.default_rng([int(seed), job["round"]]),
            job.get("student_noise", 0.0),
            job.get("expert_noise", 0.0),
            replan,
            1e-3 * replan_mm if replan_mm is not None else 0.0,
            job.get("replan_anchor", "plan"),
            commit,
            commit_decision or 0,
        )
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
    beta: float = 1.0,
    noise_model: str | None = None,
    task_options: dict[str, Any] | None = None,
    workers: int = 1,
    round_index: int = 0,
    speed_limit_m_s: float | None = None,
    on_episode: Callable[[int, bool], None] | None = None,
    student_noise: float = 0.0,
    expert_noise: float = 0.0,
    cable_ranges: str | None = None,
    teacher_search: bool = False,
    task: str = TEACHER_TASK,
    expert_smoothing: float = 0.0,
    replan_residual_mm: float | None = None,
    replan_anchor: str = "plan",
    replan_score: str = "coast",
    commit_decision: int | None = None,
    search_candidates: str = "episode",
) -> Episodes:
    """Run one DAgger round's episodes (one per seed) in ``workers`` processes.

    Args:
        seeds: Episode seeds (goal and noise).
        teacher: Shipped name or path of the single-step policy whose plans the expert follows.
        student: Path of the PPO student acting with probability ``1 - beta`` (None: the expert always acts).
        beta: Probability that the expert's action is executed at a decision.
        noise_model: Observation-noise model file the student's observations are corrupted with.
        task_options: Keyword options of the task environment.
        workers: Processes (each builds its own environment).
        round_index: Mixed into the per-episode random stream that picks who acts.
        speed_limit_m_s: The expert's speed penalty threshold (None: off).
        student_noise: Standard deviation of the noise on the student's executed actions (see
            :func:`run_mixed_episode`).
        expert_noise: The same for the expert's executed actions.
        cable_ranges: Draw every episode's cable from these named ranges (None: the nominal cable).
        teacher_search: The teacher's plan is refined for each episode's cable and target by search
            (:class:`CableSearchTeacher`, privileged) instead of taken from the policy as it is.
        task: The task (:data:`DISTILL_TASKS`).
        expert_smoothing: :class:`PlanFollowingExpert`'s ``smoothing``.
        replan_residual_mm: Where the expert's fit residual exceeds this, its label is :class:`ReplanSearch`'s
            re-plan from the true state (see :func:`run_mixed_episode`); None: never.
        replan_anchor: Where that search is centred: ``"plan"`` (the plan-following label) or ``"student"``
            (the student's action, at every decision it takes; see :func:`run_mixed_episode`).
        replan_score: How the search scores a candidate: ``"coast"`` (its plan followed to the end) or
            ``"student"`` (the student re-planning after it; :class:`ReplanSearch`'s ``follower``).
        commit_decision: The teacher commits late: its plan is followed until this decision, where a
            privileged search corrects it for the episode's cable and state (see :func:`run_mixed_episode`);
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
            "beta": float(beta),
            "noise_model": noise_model,
            "task_options": dict(task_options or {}),
            "round": round_index,
            "speed_limit": speed_limit_m_s,
            "student_noise": float(student_noise),
            "expert_noise": float(expert_noise),
            "cable_ranges": cable_ranges,
            "teacher_search": bool(teacher_search),
            "task": task,
            "smoothing": float(expert_smoothing),
            "replan_mm": None if replan_residual_mm is None else float(replan_residual_mm),
            "replan_anchor": replan_anchor,
            "replan_score": replan_score,
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


# ---------------------------------------------------------------------------------------------- student
def new_student(env: Any, net_arch: Sequence[int], seed: int) -> Any:
    """A PPO model whose policy will be fitted (observation -> mean action); log std starts at -2."""
    from stable_baselines3 import PPO

    kwargs = {"net_arch": {"pi": list(net_arch), "vf": [64, 64]}, "log_std_init": -2.0}
    return PPO("MlpPolicy", env, policy_kwargs=kwargs, seed=seed, device="cpu", verbose=0)


def fit_student(
    model: Any,
    data: Episodes,
    epochs: int = 300,
    batch_size: int = 256,
    lr: float = 1e-3,
    validation_fraction: float = 0.1,
    seed: int = 0,
    on_epoch: Callable[[int, float], Any] | None = None,
) -> dict[str, float]:
    """Regress the PPO policy's mean action onto the expert's actions (mean squared error, Adam, cosine lr).

    Whole episodes (by seed) are held out for validation (none when there is only one episode). Returns the
    final training and validation loss (NaN without validation episodes). ``on_epoch`` is called with the
    epoch's index and training loss after every epoch (e.g. for a progress bar).
    """
    import torch

    rng = np.random.default_rng(seed)
    episodes = np.unique(data.seeds)
    n_held = max(1, int(len(episodes) * validation_fraction)) if len(episodes) > 1 else 0  # keep one to train
    held = set(rng.choice(episodes, size=n_held, replace=False))
    val = np.isin(data.seeds, list(held))
    obs = torch.as_tensor(data.observations, dtype=torch.float32)
    act = torch.as_tensor(data.actions, dtype=torch.float32)
    train_idx = np.flatnonzero(~val)
    policy = model.policy
    params = [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters()]
    optimiser = torch.optim.Adam(params, lr=lr)
    steps = epochs * max(1, int(np.ceil(len(train_idx) / batch_size)))
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=steps, eta_min=lr * 0.05)

    def mean_action(x: torch.Tensor) -> torch.Tensor:
        features = policy.extract_features(x, policy.pi_features_extractor)
        return policy.action_net(policy.mlp_extractor.forward_actor(features))

    policy.set_training_mode(True)
    train_loss = float("nan")
    for epoch in range(epochs):
        order = rng.permutation(train_idx)
        total = 0.0
        for start in range(0, len(order), batch_size):
            batch = torch.as_tensor(order[start : start + batch_size])
            loss = torch.mean((mean_action(obs[batch]) - act[batch]) ** 2)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            total += float(loss.detach()) * len(batch)
        train_loss = total / len(order)
        if on_epoch is not None:
            on_epoch(epoch, train_loss)
    policy.set_training_mode(False)
    with torch.no_grad():
        val_loss = float(torch.mean((mean_action(obs[val]) - act[val]) ** 2)) if val.any() else float("nan")
    return {"train_mse": train_loss, "validation_mse": val_loss}


# ---------------------------------------------------------------------------------------------- DAgger
@dataclass(frozen=True)
class DistillConfig:
    """A distillation run, stored as ``config.json`` in its folder so that it can be resumed.

    Attributes:
        teacher: Shipped name or path of the task's single-step policy.
        rounds: Rounds ``0 .. expert_rounds - 1``: the expert acts (behaviour cloning); later rounds: the
            student of the previous round acts and the expert labels (DAgger). One round is the default:
            DAgger rounds made the student worse in our measurements (docs/RESULTS.md).
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
        expert_speed_limit_m_s: :class:`PlanFollowingExpert`'s ``speed_limit_m_s``.
        task_options: Keyword options of the task's environment.
        cable_ranges: Every episode's cable is drawn from these named ranges (``wrappers.CABLE_RANGES``:
            ``"training"`` or ``"beyond"``); None: the task's nominal cable in every episode.
        teacher_search: The expert follows :class:`CableSearchTeacher`'s plan (the teacher's refined, with
            the episode's cable known) instead of the teacher's own.
        student_noise: Noise on the student's executed actions in the DAgger rounds (see
            :func:`run_mixed_episode`).
        task: The task (:data:`DISTILL_TASKS`).
        expert_noise: Noise on the expert's executed actions in the expert rounds after round 0 (DART; see
            :func:`run_mixed_episode`): round 0 shows the plan, later ones how to rejoin it.
        p_dlo_history: H > 0: the student also reads how P_DLO moved over the last H decisions
            (:class:`~dyndlo_vision.tasks.wrappers.PDloHistory`), from which it can tell the cable. The round
            files keep the table-II observations; the history is added when the student is fitted.
        decision_clock: The student also reads the time since the episode began
            (:class:`~dyndlo_vision.tasks.wrappers.DecisionClock`). The expert's label re-plans the rest of
            a plan in time, so states that look alike at different phases of it get different labels; with
            the clock the student can tell them apart. Added, like the history, when the student is fitted.
            Measured on tip control (docs/RESULTS.md, session 21): the DAgger labels' conflicts did not come
            from time, and the clock did not stop a DAgger round from hurting.
        expert_smoothing: :class:`PlanFollowingExpert`'s ``smoothing`` (0: off).
        dagger_beta: In DAgger rounds, the probability that the expert's action, not the student's, is
            executed at a decision (DAgger's beta; 0: the student acts throughout). The expert's
            plan-following labels are only good near its plan; with some of its own actions executed, the
            roll-in should stay nearer to it. Measured on the vault student (docs/RESULTS.md, session 18):
            at 0.5 every roll-in broke an avoid condition (two plans alternating every 40 ms), the residual
            barely fell, and the refitted student vaulted 12 of 50 (40 without the round).
        expert_replan_mm: In DAgger rounds, where the plan-following expert's fit residual exceeds this many
            mm, the label is :class:`ReplanSearch`'s re-plan from the student's state (privileged: the true
            cable and state), and the expert follows that plan from then on. None (default): the
            plan-following label everywhere. Expert rounds are not affected. Measured on tip control
            (docs/RESULTS.md, session 20): with it a DAgger round left the student worse (56 of 100 on issue
            16's ranges) than the plan-following round (84) and than round 0 alone (90); it stays opt-in.
        expert_replan_anchor: ``"plan"``: the search starts from the plan-following label, where its residual
            exceeds ``expert_replan_mm``; ``"student"``: from the student's own action, at every decision it
            takes (``expert_replan_mm`` must be set, and is not used then): the label is its action where
            coasting on it succeeds, else the nearest good correction (:func:`run_mixed_episode`).
        expert_replan_score: How the re-planning expert scores a candidate: ``"coast"`` (its plan followed
            to the end, open loop) or ``"student"`` (the student re-planning every decision after it, from the
            true observation; :class:`ReplanSearch`'s ``follower``).
        teacher_commit_decision: K: the teacher commits late. The expert follows the teacher's own plan
            (made without the cable) for K decisions; at decision K a privileged search
            (:class:`ReplanSearch`, from the true cable and state) corrects it where coasting on it fails, and
            the expert follows the correction from then on (:func:`run_mixed_episode`). The student's labels
            then depend on the cable only once the cable has moved for K x 40 ms. None (default): off. Not
            with ``teacher_search``, which makes the plan for the cable at t = 0.
        search_candidates: :class:`ReplanSearch`'s ``candidates`` wherever it searches (the late commitment,
            the re-planning expert): ``"episode"`` (default) new offsets in every search, ``"shared"`` the
            same offsets in every search, so that look-alike states get the same correction; ``"line:N"``
            only multiples of shared offset N's direction (a correction is then one number).
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
    expert_speed_limit_m_s: float | None = None
    task_options: dict[str, Any] = field(default_factory=dict)
    cable_ranges: str | None = None
    teacher_search: bool = False
    student_noise: float = 0.0
    task: str = TEACHER_TASK
    expert_rounds: int = 1
    expert_noise: float = 0.0
    p_dlo_history: int = 0
    expert_smoothing: float = 0.0
    dagger_beta: float = 0.0
    expert_replan_mm: float | None = None
    decision_clock: bool = False
    expert_replan_anchor: str = "plan"
    expert_replan_score: str = "coast"
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
        limit = self.expert_speed_limit_m_s
        if limit is not None and not (isinstance(limit, int | float) and 0 < limit < float("inf")):
            raise ValueError(f"expert_speed_limit_m_s must be a positive speed in m/s or None, got {limit!r}")
        if self.task not in DISTILL_TASKS:
            raise ValueError(f"task must be one of {list(DISTILL_TASKS)}, got {self.task!r}")
        if self.cable_ranges is not None:
            from dyndlo_vision.tasks.wrappers import cable_ranges_for

            cable_ranges_for(self.task, self.cable_ranges)  # an unknown name is refused here
        for name in ("student_noise", "expert_noise", "expert_smoothing"):
            noise = getattr(self, name)
            number = isinstance(noise, int | float) and not isinstance(noise, bool)
            if not (number and 0.0 <= noise < float("inf")):
                raise ValueError(f"{name} must be finite and >= 0, got {noise!r}")
        beta = self.dagger_beta
        if isinstance(beta, bool) or not isinstance(beta, int | float) or not 0.0 <= beta < 1.0:
            raise ValueError(f"dagger_beta must be in [0, 1) (1: the student would never act), got {beta!r}")
        replan = self.expert_replan_mm
        if replan is not None and (isinstance(replan, bool) or not isinstance(replan, int | float)
                                   or not 0.0 <= replan < float("inf")):
            raise ValueError(f"expert_replan_mm must be a residual in mm >= 0, or None (off); got {replan!r}")
        history = self.p_dlo_history
        if isinstance(history, bool) or not isinstance(history, int) or history < 0:
            raise ValueError(f"p_dlo_history must be an integer >= 0 (0: no history), got {history!r}")
        for name, (default, other) in {"expert_replan_anchor": ("plan", "student"),
                                       "expert_replan_score": ("coast", "student")}.items():
            value = getattr(self, name)
            if value not in (default, other):
                raise ValueError(f"{name} must be {default!r} or {other!r}, got {value!r}")
            if value != default and replan is None:
                raise ValueError(f"{name} {value!r} needs the re-planning expert (expert_replan_mm)")
        commit = self.teacher_commit_decision
        if commit is not None:
            if isinstance(commit, bool) or not isinstance(commit, int) or commit < 1:
                raise ValueError(f"teacher_commit_decision must be a decision index >= 1 or None (off), "
                                 f"got {commit!r}")
            if self.teacher_search:
                raise ValueError("teacher_commit_decision and teacher_search exclude each other: the search "
                                 "makes the plan for the cable at t = 0, the late commitment after K "
                                 "decisions")
        try:
            ReplanSearch.line_offset(self.search_candidates)
        except ValueError as err:
            raise ValueError(f"search_candidates: {err}") from None
        if self.search_candidates != "episode" and commit is None and replan is None:
            raise ValueError(f"search_candidates {self.search_candidates!r} needs a search: the late "
                             "commitment (teacher_commit_decision) or the re-planning expert "
                             "(expert_replan_mm)")
        if not isinstance(self.decision_clock, bool):
            raise ValueError(f"decision_clock must be True or False, got {self.decision_clock!r}")
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
    from dyndlo_vision.tasks.noise import noise_model_file, portable_noise_model

    out = Path(out)
    if refit and not resume:
        raise ValueError("refit re-fits a run's finished rounds: it needs resume")
    config_file, history_file = out / "config.json", out / "history.json"
    # Everything that can refuse the run comes before the first write into ``out``.
    if resume:
        if not config_file.is_file():
            raise FileNotFoundError(f"nothing to resume: {config_file} does not exist")
        stored = {**_LATER_OPTIONS, **json.loads(config_file.read_text())}
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
    else:
        if out.exists() and not out.is_dir():
            raise ValueError(f"{out} is a file; expected a run folder")
        if out.exists() and any(out.iterdir()):
            raise ValueError(f"{out} exists and is not empty; use --resume or another --out")
        history = []
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
        if config.p_dlo_history or config.decision_clock:
            from dyndlo_vision.tasks.wrappers import StudentFeaturesWrapper

            student_env = StudentFeaturesWrapper(env, config.p_dlo_history, config.decision_clock)
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
                seeds = config.round_seeds(r)
                expert = config.expert_acts(r)
                log(f"round {r}: {'expert' if expert else 'student'} acts, {len(seeds)} episodes")
                with _bar(len(seeds), f"round {r} episodes", "episode", progress) as bar:
                    episodes = collect(
                        seeds,
                        config.teacher,
                        None if expert else str(model_file),
                        1.0 if expert else config.dagger_beta,
                        config.noise_model,
                        config.task_options,
                        config.workers,
                        r,
                        config.expert_speed_limit_m_s,
                        on_episode=_success_counter(bar),
                        student_noise=0.0 if expert else config.student_noise,
                        expert_noise=config.expert_noise if expert and r > 0 else 0.0,
                        cable_ranges=config.cable_ranges,
                        teacher_search=config.teacher_search,
                        task=config.task,
                        expert_smoothing=config.expert_smoothing,
                        replan_residual_mm=None if expert else config.expert_replan_mm,
                        replan_anchor=config.expert_replan_anchor,
                        replan_score=config.expert_replan_score,
                        commit_decision=config.teacher_commit_decision,
                        search_candidates=config.search_candidates,
                    )
                episodes.save(round_file)
            collect_s = time.monotonic() - start
            data.append(episodes)
            with _bar(config.epochs, f"round {r} fit", "epoch", progress) as bar:
                seen = with_noise(Episodes.concatenate(data), noise_model_file(config.noise_model))
                losses = fit_student(
                    model,
                    with_history(seen, config.p_dlo_history, config.decision_clock),
                    epochs=config.epochs,
                    seed=config.seed + r,
                    on_epoch=_loss_reporter(bar),
                )
            model.save(model_file)
            shutil.copyfile(model_file, out / f"model_round{r}.zip")  # every round's student stays selectable
            entry = {
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
        "method": "DAgger distillation of a single-step policy (dyndlo_vision.learning.distill)",
        "teacher": config.teacher,
        "obs_noise": config.noise_model,
        "teacher_search": config.teacher_search,
        "cable_ranges": config.cable_ranges,
        "student_noise": config.student_noise,
        "dagger_beta": config.dagger_beta,
        "expert_rounds": config.expert_rounds,
        "expert_noise": config.expert_noise,
        "p_dlo_history": config.p_dlo_history,
        "decision_clock": config.decision_clock,
        "expert_replan_mm": config.expert_replan_mm,
        "expert_replan_anchor": config.expert_replan_anchor,
        "expert_replan_score": config.expert_replan_score,
        "expert_smoothing": config.expert_smoothing,
        "rounds": len(history),
        "samples": history[-1]["total_samples"] if history else 0,
        "episodes": sum(h["episodes"] for h in history),
    }
    write_atomic(out / name, lambda tmp: Path(tmp).write_text(json.dumps(meta, indent=2)))
