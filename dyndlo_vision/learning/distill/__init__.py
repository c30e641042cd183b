"""Distil a single-step (plan once) policy into a multi-step (re-plan every 40 ms) policy by imitation.

Why: the multi-step task's reward is sparse (+100 for a hit, -50 for any limit broken, judged once at the end
of 40 decisions) and random re-planning breaks the speed limit in every episode; SAC at 35 000 steps never
hit the target, and the paper needed 5e6 PPO steps. A single-step policy already knows *which* whip hits the
target. What the multi-step policy must add is to keep following that whip while it re-plans every 40 ms from
the current position and velocity.

One module per part:

* :mod:`.expert`: :class:`PlanFollowingExpert` turns a single-step plan into multi-step labels.
* :mod:`.teachers`: where that plan comes from: the single-step policy (:class:`PolicyTeacher`), refined for
  the episode's cable by search in simulation (:class:`CableSearchTeacher`, privileged), or corrected late
  from where the episode is (:class:`ReplanSearch`, privileged).
* :mod:`.collection`: episodes in which the expert (behaviour cloning) or the latest student (DAgger, Ross
  et al. 2011) acts and the expert labels every decision, in worker processes (:func:`collect`), and the data
  set they make (:class:`Episodes`).
* :mod:`.student`: :func:`fit_student` regresses the mean of a stable-baselines3 PPO policy onto the labels,
  so the result is an ordinary PPO zip that ``policies.load``, ``evaluate`` and the control loop take.
* :mod:`.run`: a resumable run of rounds (:class:`DistillConfig`, :func:`distill`).

With a noise model the episodes run under :class:`~dyndlo_vision.tasks.wrappers.NoisyObservation`: the
student sees the corrupted P_DLO (and learns to act on it), the expert is unaffected (it reads the true
state). The student is fitted on the rounds' observations drawn again from their true state through the run's
noise model (:func:`with_noise`), so a resumed run may change the model (``--obs-noise``, for another
tracker): its earlier demonstrations then teach the student to read P_DLO as the new tracker gives it.
"""

from __future__ import annotations

from dyndlo_vision.learning.distill.collection import (
    Episodes,
    check_teacher,
    collect,
    episode_cables,
    load_rounds,
    make_distill_env,
    run_episode,
    with_history,
    with_noise,
)
from dyndlo_vision.learning.distill.expert import PlanFollowingExpert
from dyndlo_vision.learning.distill.run import DistillConfig, distill
from dyndlo_vision.learning.distill.student import fit_student, new_student
from dyndlo_vision.learning.distill.teachers import (
    DEFAULT_TEACHERS,
    DISTILL_TASKS,
    TEACHER_TASK,
    CableSearchTeacher,
    PolicyTeacher,
    ReplanSearch,
)

__all__ = [
    "DEFAULT_TEACHERS",
    "DISTILL_TASKS",
    "TEACHER_TASK",
    "CableSearchTeacher",
    "DistillConfig",
    "Episodes",
    "PlanFollowingExpert",
    "PolicyTeacher",
    "ReplanSearch",
    "check_teacher",
    "collect",
    "distill",
    "episode_cables",
    "fit_student",
    "load_rounds",
    "make_distill_env",
    "new_student",
    "run_episode",
    "with_history",
    "with_noise",
]
