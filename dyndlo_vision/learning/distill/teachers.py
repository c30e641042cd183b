"""Where the expert's plan comes from: a single-step policy's plan as it is (:class:`PolicyTeacher`), refined
for the episode's cable by search in simulation (:class:`CableSearchTeacher`, privileged), and corrected
late, from where the episode is, by search (:class:`ReplanSearch`, privileged)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["DISTILL_TASKS", "DEFAULT_TEACHERS", "TEACHER_TASK", "PolicyTeacher", "CableSearchTeacher",
           "ReplanSearch"]

#: The tasks distillation runs on: single-arm tasks without a fixed final point, whose one single-step plan
#: from t = 0 the expert can follow (task IV appends the goal to every plan; hooking is not measured).
DISTILL_TASKS = ("tip-control", "vaulting")
#: The default task (the one ``distill`` was first written for).
TEACHER_TASK = "tip-control"
#: Each task's default teacher: its shipped single-step policy.
DEFAULT_TEACHERS = {"tip-control": "tip-control-single-step", "vaulting": "vaulting"}


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
    """A privileged expert's correction from where the episode is now: the smallest change of a label that
    makes the episode succeed, found by search in simulation.

    Why: :class:`~dyndlo_vision.learning.distill.expert.PlanFollowingExpert` labels a state with the action
    that rejoins its one plan, made before the cable moved. The late commitment (``distill --teacher-commit
    K``) corrects that plan at decision K, once the cable has shown how it moves.

    From a :meth:`~dyndlo_vision.tasks.base.DynDLOEnv.snapshot` of the episode (the true cable, state and
    goal: privileged), a candidate action is scored by re-planning with it and coasting on that plan to the
    end of the episode (:meth:`~dyndlo_vision.tasks.base.DynDLOEnv.coast`, no further re-plans), by
    :meth:`CableSearchTeacher.score`. Candidates are drawn around ``start`` (the plan-following label) in
    widening rings (``sigmas``); the first ring with a candidate scoring below ``good_enough_m`` ends the
    search, and of those the one **nearest to** ``start`` is the answer. Many actions succeed from most
    states; taking whichever a search happens to find first made labels a student could not fit. Without a
    good candidate the best-scoring one is returned. The environment is restored afterwards, so the episode
    goes on as if nothing had been tried.

    Which candidates a search draws: ``candidates="episode"`` (default) draws new offsets for every episode
    and decision. Where many offsets succeed, the nearest of them then points anywhere, and two look-alike
    cables get unrelated labels. ``"shared"`` draws the same offsets in every search, so that look-alike
    states pick the same correction (what ``vaulting-multi-step`` was made with).

    Args:
        population: Candidates per ring.
        sigmas: Standard deviations of the rings (normalised action units), searched in this order.
        good_enough_m: A score below this is a success (``start`` itself: no search).
        candidates: ``"episode"`` or ``"shared"`` (above).
    """

    #: The values of ``candidates``.
    CANDIDATES = ("episode", "shared")

    def __init__(self, population: int = 12, sigmas: Sequence[float] = (0.05, 0.1, 0.2, 0.4),
                 good_enough_m: float = 0.03, candidates: str = "episode") -> None:
        if population < 1 or not sigmas or any(not 0 < sg < float("inf") for sg in sigmas):
            raise ValueError(f"need population >= 1 and positive finite sigmas; got population={population}, "
                             f"sigmas={sigmas!r}")
        if candidates not in self.CANDIDATES:
            raise ValueError(f"candidates {candidates!r}; expected one of {list(self.CANDIDATES)}")
        self.candidates = candidates
        self.population = int(population)
        self.sigmas = tuple(float(sg) for sg in sigmas)
        self.good_enough_m = float(good_enough_m)
        self.last_rollouts = 0
        self.last_start_score = float("nan")
        self.last_score = float("nan")

    def offsets(self, size: int, key: Sequence[int] | None = None) -> NDArray[np.float64]:
        """Every offset a search may try, ring after ring in ``sigmas`` order (``population`` rows per ring,
        ``(len(sigmas) * population, size)``). ``"shared"`` candidates are the same for every search (``key``
        is ignored); ``"episode"`` ones are drawn from ``key`` (the search's seed and time)."""
        if self.candidates == "shared":
            return self._drawn(size, np.random.default_rng(0x5EA))
        if key is None:
            raise ValueError("episode candidates are drawn from a key (seed, time in ms, 0x5EA); got None")
        return self._drawn(size, np.random.default_rng(list(key)))

    def _drawn(self, size: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """``population`` Gaussian offsets per ring, ring after ring in ``sigmas`` order."""
        return np.concatenate([sigma * rng.standard_normal((self.population, size)) for sigma in self.sigmas])

    def rings(self, size: int, key: Sequence[int] | None = None) -> list[NDArray[np.float64]]:
        """The offsets a search tries, as the rings it tries them in: ``sigmas`` rings of ``population``."""
        return list(self.offsets(size, key).reshape(len(self.sigmas), self.population, size))

    @staticmethod
    def coasted_score(env: Any, snapshot: Any, action: NDArray[np.floating[Any]]) -> float:
        """The score of re-planning with ``action`` at ``snapshot`` and coasting to the episode's end."""
        env.restore(snapshot)
        _, _, done, _, info = env.step(np.asarray(action, dtype=np.float32))
        while not done:
            _, _, done, _, info = env.coast()
        return CableSearchTeacher.score(info)

    def search(self, env: Any, start: NDArray[np.floating[Any]], seed: int) -> NDArray[np.float64]:
        """The answer for the multi-step ``env`` (unwrapped) now: ``start`` if it is good enough, else the
        nearest good candidate, else the best-scoring one (``start`` unless one scores better). ``env`` is
        left in the state it was in."""
        snapshot = env.snapshot()
        try:
            origin = np.clip(np.asarray(start, dtype=np.float64), -1.0, 1.0)
            best, best_score = origin, self.coasted_score(env, snapshot, origin)
            self.last_start_score, self.last_rollouts = best_score, 1
            episode = [int(seed), int(round(env.scene.time * 1000)), 0x5EA]
            for ring in self.rings(origin.size, episode):
                if best_score < self.good_enough_m:
                    break
                actions = np.clip(origin + ring, -1, 1)
                scores = np.array([self.coasted_score(env, snapshot, a) for a in actions])
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
